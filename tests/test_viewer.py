"""The reports' image viewer (evalkit/viewer) in a real browser: headless Chromium driven by
Selenium (Debian's chromium and chromium-driver, which `make test` installs) opens a study report
from file://, switches images with the keyboard, zooms, changes the exposure, and reads back the
pixel values the page shows, which must equal the EXRs' to half-float precision."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from evalkit.core.exr import read_exr
from evalkit.report import write_report
from evalkit.study.executors import run_study
from evalkit.study.run import versions
from evalkit.study.spec import study_from_dict
from references.mitsuba import load_reference

STUDY = {
    "name": "viewer",
    "defaults": {"scene": "lit-room", "bounces": 1, "directions": 4, "resolution": 32, "frames": 2, "spp": 2},
    "grid": [{"method": ["perfect", "imperfect"], "width": 48}],
    "measure": {"images": ["indirect", "total"], "metrics": ["relmse", "flip"], "reference_spp": 64},
}


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("viewer")
    rows = run_study(study_from_dict(STUDY), out, progress=lambda line: None)
    assert [r["status"] for r in rows] == ["ok", "ok"]
    return out, rows


def wait_for(driver, script: str, timeout: float = 10.0):
    """Poll ``script`` (a JS expression) until it is truthy; returns its value."""
    end = time.perf_counter() + timeout
    while time.perf_counter() < end:
        value = driver.execute_script(f"return {script}")
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {script}")


def open_first_viewer(driver, path: Path) -> float:
    """Open a report and scroll to its first viewer, as a reader does; returns the seconds until
    that viewer shows its image."""
    start = time.perf_counter()
    driver.get(path.as_uri())
    driver.execute_script("document.querySelector('.ek-viewer').scrollIntoView()")
    wait_for(driver, "document.querySelector('.ek-viewer').dataset.state === 'ready'")
    return time.perf_counter() - start


def viewer_state(driver, n: int = 0) -> dict:
    return driver.execute_script(f"return {{...document.querySelectorAll('.ek-viewer')[{n}].dataset}}")


def test_the_viewer_switches_zooms_exposes_and_shows_the_exrs_values(browser, report, tmp_path):
    from selenium.webdriver.common.action_chains import ActionChains

    out, rows = report
    open_first_viewer(browser, out / "report.html")
    root = browser.find_element("css selector", ".ek-viewer")
    canvas = root.find_element("css selector", "canvas")
    group = json.loads(root.get_attribute("data-group"))
    assert [image["label"].split()[0] for image in group["images"]] == ["perfect", "reference", "relmse", "flip"]
    ActionChains(browser).move_to_element(root).click(root.find_element("css selector", "button")).perform()

    keys = ActionChains(browser)
    keys.send_keys("2").perform()
    assert viewer_state(browser)["index"] == "1" and viewer_state(browser)["shown"].startswith("ref-")
    keys.send_keys(" ").perform()  # flip back
    assert viewer_state(browser)["index"] == "0"
    keys.send_keys("e").send_keys("e").perform()
    assert float(viewer_state(browser)["exposure"]) == 1.0
    keys.send_keys("E").perform()
    assert float(viewer_state(browser)["exposure"]) == 0.5
    fit = float(viewer_state(browser)["scale"])
    keys.send_keys("+").perform()
    assert float(viewer_state(browser)["scale"]) == 2 * fit
    keys.send_keys("0").perform()
    assert float(viewer_state(browser)["scale"]) == fit
    browser.save_screenshot(str(tmp_path / "viewer.png"))  # kept with the test's output
    assert (tmp_path / "viewer.png").stat().st_size > 10_000

    # The values under the cursor, at 10 random pixels, against the EXRs the run wrote.
    width, height = group["size"]
    test = read_exr(out / "runs" / rows[0]["run_id"] / "indirect.exr")[0]
    reference = load_reference(rows[0]["reference"]).images["indirect"]
    cw, ch = group["display"]
    rng = np.random.default_rng(0)
    for x, y in zip(rng.integers(0, width, 10), rng.integers(0, height, 10)):
        offset = ((cw - width * fit) / 2, (ch - height * fit) / 2)
        px, py = offset[0] + (x + 0.5) * fit, offset[1] + (y + 0.5) * fit
        ActionChains(browser).move_to_element_with_offset(canvas, px - cw / 2, py - ch / 2).perform()
        assert viewer_state(browser)["cursor"] == f"{x},{y}"
        for row, exr in ((0, test), (1, reference)):
            cells = root.find_elements("css selector", f"tr[data-image='{row}'] td")
            shown = np.array([float(c.text) for c in cells])
            expected = exr[y, x].astype(np.float64)
            assert np.all(np.abs(shown - expected) <= 2.0**-11 * np.abs(expected) + 2.0**-24), (x, y, shown, expected)


def test_a_100_run_report_shows_its_first_image_within_3_seconds(browser, report, tmp_path):
    # A report of 100 runs (the two runs' outputs copied under 100 run ids): every viewer's markup
    # is in the page, and each loads its images only when it scrolls into view.
    out, rows = report
    many = []
    for i in range(100):
        row = {**rows[i % 2], "run_id": f"run{i:03d}", "seed": 0}
        shutil.copytree(out / "runs" / rows[i % 2]["run_id"], tmp_path / "runs" / row["run_id"])
        many.append(row)
    study = study_from_dict({**STUDY, "report": {"images": 100}})
    meta = {"command": "test", "versions": versions(), "executor": "local", "workers": 1, "finished": "now"}
    write_report(study, many, tmp_path, meta, [], progress=lambda line: None)
    assert (tmp_path / "report.html").read_text().count("class='ek-viewer'") == 200

    seconds = open_first_viewer(browser, tmp_path / "report.html")
    loaded = browser.execute_script("return document.querySelectorAll('script[src]').length")
    written = len(list(tmp_path.glob("viewer/*.js")))
    print(f"first image shown after {seconds:.2f} s; {loaded} image scripts loaded of {written}")
    assert seconds < 3.0
    assert loaded < 100  # only what is in view (and near it) was loaded


def test_the_results_table_sorts_and_hides_groups_of_columns(browser, report):
    out, rows = report
    browser.get((out / "report.html").as_uri())
    table = browser.find_element("css selector", "table.ek-table")
    column = {th.text: th for th in table.find_elements("css selector", "tr.ek-columns th") if th.text}
    group = {th.text: th for th in table.find_elements("css selector", "tr.ek-groups th")}
    assert list(group) == ["settings", "bundle metrics", "image metrics", "timings"]

    def values(name: str) -> list[str]:
        return browser.execute_script(
            "const t = document.querySelector('table.ek-table');"
            f"const i = [...t.querySelectorAll('tr.ek-columns th')].findIndex(th => th.textContent === {name!r});"
            "return [...t.tBodies[0].rows].map(r => r.cells[i].textContent);"
        )

    column["method"].click()
    assert values("method") == ["imperfect", "perfect"]
    column["method"].click()
    assert values("method") == ["perfect", "imperfect"]
    assert values("points") == ["", "16384"]  # a setting perfect bundles do not have: left empty
    timings = table.find_elements("css selector", "td.ek-g3")
    assert timings and not any(td.is_displayed() for td in timings)  # collapsed at first
    group["timings"].click()
    assert all(td.is_displayed() for td in timings)
    group["settings"].click()
    assert not column["method"].is_displayed()
