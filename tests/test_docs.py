"""The documentation site (mkdocs.yml): it builds strictly (a broken link or reference fails), its
generated reference covers every command, registered unit and declared setting, and its pages
open from the file system in a real browser without console errors."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from evalkit.core.settings import RenderSettings, declared
from evalkit.reference_docs import commands
from gpu_impl.registry import all_units

REPO = Path(__file__).resolve().parent.parent
PAGES = (
    "index",
    "guide",
    "method",
    "ARCHITECTURE",
    "reference/cli",
    "reference/settings",
    "reference/api",
    "changelog",
)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        env=env,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    return out


def test_the_reference_covers_every_command_unit_and_setting(site):
    cli = (site / "reference" / "cli.html").read_text()
    names = [name for name, _ in commands()]
    assert len(names) >= 13 and all(f"<code>{name}</code>" in cli for name in names), names
    settings = (site / "reference" / "settings.html").read_text()
    units = all_units()
    declared_names = {f.name for f in declared(RenderSettings)} | {
        f.name for unit in units for f in declared(unit.settings)
    }
    missing = [n for n in declared_names | {u.name for u in units} if f"<code>{n}</code>" not in settings]
    assert not missing, missing


def test_the_pages_open_from_the_file_system_without_console_errors(site, browser):
    for page in PAGES:
        browser.get((site / f"{page}.html").as_uri())
        assert browser.title, page
        severe = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
        assert not severe, (page, severe)
