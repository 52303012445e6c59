"""The documentation site (mkdocs.yml): it builds strictly (a broken link or reference fails), its
generated reference covers every command, registered unit and declared setting, and its pages
open from the file system in a real browser without console errors."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import run_evalkit

from evalkit import fidelity
from evalkit.core.settings import DEFAULT_NODE_BUDGET, RenderSettings, declared
from evalkit.metrics import confidence
from evalkit.metrics.bundles import NEXT_HIT_ERROR_TARGET
from evalkit.records import read_record, write_record
from evalkit.reference_docs import commands
from evalkit.results_docs import PAGES as RESULT_PAGES
from evalkit.results_docs import decisions_markdown, read_decisions, results_pages, study_markdown
from evalkit.tune.calibration import BUDGET_TOLERANCE
from gpu_impl.layout import UNIFORM_BLOCK_BYTES
from gpu_impl.methods.imperfect import DEFAULT_SPLAT_SCALE
from gpu_impl.registry import all_units
from gpu_impl.scene_buffers import SURFACE_POINTS_SHARE

REPO = Path(__file__).resolve().parent.parent
PAGES = (
    "index",
    "getting-started",
    "howto",
    "tutorials/quick_start",
    "tutorials/bundles",
    "tutorials/poster_question",
    "tutorials/ci",
    "method",
    "ARCHITECTURE",
    "reference/cli",
    "reference/settings",
    "reference/api",
    "reference/outputs",
    "reference/scenes",
    "reference/rendering",
    "reference/metrics",
    "results/bundles",
    "results/hole_vs_splat",
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


@pytest.mark.long
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
    # The output files' page lists what renders wrote while it was built: each file, and every key.
    outputs = (site / "reference" / "outputs.html").read_text()
    for name in ("timings.json", "indirect.exr", "indirect_variance.exr", "frame_means", "median_ms", "scene_hash"):
        assert f"<code>{name}</code>" in outputs, name


@pytest.mark.long
def test_the_pages_open_from_the_file_system_without_console_errors(site, browser):
    for page in PAGES:
        browser.get((site / f"{page}.html").as_uri())
        assert browser.title, page
        severe = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
        assert not severe, (page, severe)


@pytest.mark.long
@pytest.mark.parametrize(
    "page, notebook, shown",
    [
        ("quick_start", "quick_start.ipynb", ["data:image/png;base64,", "lines by nodes on them", "class='ek-table"]),
        ("bundles", "bundles_tutorial.ipynb", ["perfect against exact", "imperfect against exact", "4 of 4 runs ok"]),
        ("poster_question", "poster_question.ipynb", ["7 of 7 runs ok", "bidirectional", "mitsuba"]),
        ("ci", "ci_tutorial.ipynb", ["import fidelity passed", "over 4 seeds", "1 of 1 cases pass", "(exit status 1)"]),
    ],
)
def test_a_tutorial_is_its_notebook_run_when_the_site_was_built(site, page, notebook, shown):
    """A tutorial page holds every code cell of its notebook and what each shows, run at build
    time (the quick start: the render's picture, the bundles, their comparison and the study's
    table), and says what ran it."""
    html = (site / "tutorials" / f"{page}.html").read_text()
    cells = json.loads((REPO / "docs" / notebook).read_text())["cells"]
    code = [c for c in cells if c["cell_type"] == "code"]
    assert html.count('<div class="ek-output">') == len(code) and all(s in html for s in shown)
    ran = rf"Run when this page was built: <code>docs/{notebook}</code>, evalkit [\d.]+, .+, 20\d\d-\d\d-\d\d"
    assert re.search(ran, html)


@pytest.mark.long
def test_every_results_page_comes_from_a_data_file_that_names_its_command_and_versions(site):
    data = sorted((REPO / "docs" / "results" / "data").glob("*.json"))
    benchmarks = {read_record(path).get("benchmark") for path in data} - {None}
    assert benchmarks == set(RESULT_PAGES)  # a file for every benchmark's page; the others are studies
    nav = (REPO / "mkdocs.yml").read_text()
    for path in data:
        record = read_record(path)
        assert f"results/{path.stem}.md" in nav, path  # every data file's page is in the navigation
        page = (site / "results" / f"{path.stem}.html").read_text()
        assert f"docs/results/data/{path.name}" in page and record["record"]["command"] in page
        assert all(f"{k} {v}" in page for k, v in record["record"]["versions"].items() if v)  # None: not there


def test_a_record_keeps_its_command_and_versions_and_a_file_without_them_is_refused(tmp_path):
    report = {"benchmark": "bundles", "x": 1.5}
    path = write_record(tmp_path / "data" / "b.json", report, "python benchmarks/b.py --k 8")
    record = read_record(path)
    assert record["x"] == 1.5 and record["record"]["command"].endswith("benchmarks/b.py --k 8")
    assert record["record"]["versions"]["python"]
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "c.json").write_text('{"benchmark": "bundles"}')
    with pytest.raises(ValueError, match="c.json: not a results record"):
        results_pages(tmp_path / "bad", tmp_path)


DECISIONS = REPO / "docs" / "results" / "decisions.toml"


def test_every_decision_the_code_and_pages_cite_is_on_the_decisions_page():
    decisions = read_decisions(DECISIONS)
    ids = {d["id"] for d in decisions["decision"]} | set(decisions["topics"])  # a topic's anchor too
    cited = {}
    for folder in ("evalkit", "gpu_impl", "references", "tests", "benchmarks", "docs", "studies"):
        for path in (REPO / folder).rglob("*"):
            if path.suffix in {".py", ".glsl", ".md", ".toml"}:
                for ref in re.findall(r"decisions\.(?:toml:?\s+|md#)([a-z0-9]+(?:-[a-z0-9]+)+)", path.read_text()):
                    cited.setdefault(ref, path.relative_to(REPO).as_posix())
    assert len(cited) > 20 and {ref: path for ref, path in cited.items() if ref not in ids} == {}
    page = decisions_markdown(decisions, "docs/results/decisions.toml")
    assert all(f'<a id="{i}"></a>' in page for i in ids)


@pytest.mark.parametrize(
    "change, error",
    [
        (lambda d: d["decision"].append(dict(d["decision"][0])), "name more than one decision"),
        (lambda d: d["decision"][0].update(topic="nowhere"), "has topic 'nowhere'"),
        (lambda d: d["decision"][0].update(evidence="see [there](#no-such-id)"), "links to #no-such-id"),
        (lambda d: d["decision"][0].pop("decision"), "lacks decision"),
        (lambda d: d["decision"].clear(), "no [topics] table or no [[decision]]"),
    ],
)
def test_a_decisions_file_with_a_broken_decision_is_refused_by_name(tmp_path, change, error):
    data = {"decision": [{"id": "a", "topic": "lookups", "title": "A", "decision": "D.", "evidence": "E [a](#a)."}]}
    change(data)
    path = tmp_path / "decisions.toml"
    decisions = ("[[decision]]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in d.items()) for d in data["decision"])
    path.write_text("[topics]\nlookups = 'Lookups'\n" + "".join(decisions))
    with pytest.raises(ValueError, match=f"decisions.toml: .*{re.escape(error)}"):
        read_decisions(path)


HOWTO_BLOCKS = re.findall(r"```python\n(.*?)```", (REPO / "docs" / "howto.md").read_text(), re.S)


@pytest.mark.parametrize("block", range(len(HOWTO_BLOCKS)))
def test_the_how_to_pages_python_blocks_run_as_written(tmp_path, block):
    (tmp_path / "block.py").write_text(HOWTO_BLOCKS[block])
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    r = subprocess.run([sys.executable, "block.py"], cwd=tmp_path, capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.strip(), "every block prints what it found"


def test_a_study_recorded_with_its_command_becomes_a_results_page(tmp_path):
    study = tmp_path / "splats.toml"
    study.write_text(
        'name = "splats"\ntitle = "Holes against splat scale"\ndescription = "A test study."\nreduced = "K=4."\n'
        '[defaults]\nscene = "cornell-box"\nmethod = "imperfect"\ndirections = 4\nresolution = 64\npoints = 4096\n'
        "[[grid]]\nsplat_scale = [1.2, 1.8]\n"
        "[measure]\nbundles = true\nrender = false\nimages = []\neye_vertices = 256\n"
        '[[plot]]\ntitle = "Holes against s"\nx = "splat_scale"\ny = "hole_rate"\n'
    )
    data = tmp_path / "docs" / "results" / "data"
    r = run_evalkit("study", str(study), "--out", str(tmp_path / "out"), "--record", str(data / "splats.json"))
    assert r.returncode == 0, r.stderr
    record = read_record(data / "splats.json")
    command = f"evalkit study {study} --out {tmp_path / 'out'} --record {data / 'splats.json'}"
    assert record["record"]["command"] == command
    assert record["varying"] == ["splat_scale"] and len(record["rows"]) == 2
    page = results_pages(data, tmp_path / "docs")["results/splats.md"]
    assert page.startswith("# Holes against splat scale") and "docs/results/data/splats.json" in page
    header = next(line for line in page.splitlines() if line.startswith("| splat_scale"))
    assert "hole_rate" in header and "nodes_per_crossing" in header
    # The study's plot, drawn from the recorded rows into the page itself.
    assert '## Holes against s\n\n<img alt="Holes against s" src="data:image/png;base64,' in page
    holes = {row["splat_scale"]: row["hole_rate"] for row in record["rows"]}
    assert f"| 1.2 | {holes[1.2]:.4g} |" in page  # each row's value as the study measured it


def test_a_study_page_gives_each_images_mean_over_the_reference_with_its_interval():
    row = {"status": "ok", "method": "perfect", "total_relmse": 0.01, "total_z_outside": 0.002}
    row |= {"total_mean_ratio": 0.99871, "total_mean_ratio_lo": 0.99512, "total_mean_ratio_hi": 1.00234}
    one_frame = {**row, "method": "one frame", "total_mean_ratio_lo": None, "total_mean_ratio_hi": None}
    data = {
        "title": "Accuracy",
        "description": "D.",
        "reduced": "R.",
        "varying": ["method"],
        "rows": [row, {"status": "ok", "method": "mitsuba", "total_relmse": 0.02}, one_frame],
        "record": {"command": "evalkit study a.toml", "date": "2026-12-02", "versions": {"python": "3.11"}},
    }
    page = study_markdown(data, "docs/results/data/a.json").splitlines()
    assert "| method | total_relmse | total_z_outside | total mean / reference [95 %] |" in page
    assert "| perfect | 0.01 | 0.002 | 0.9987 [0.9951, 1.0023] |" in page
    assert "| mitsuba | 0.02 | - | - |" in page  # Mitsuba's runs are not compared so
    assert "| one frame | 0.01 | 0.002 | 0.9987 (one frame: no interval) |" in page
    # A study that names its report's columns gets those on its page, a mean ratio with its interval.
    named = study_markdown({**data, "columns": ["method", "total_mean_ratio", "nodes"]}, "a.json").splitlines()
    assert "| method | total mean / reference [95 %] |" in named  # no row has "nodes"
    assert "| perfect | 0.9987 [0.9951, 1.0023] |" in named


def test_a_study_page_sets_each_strategy_at_its_best_settings_against_the_other_at_matched_time():
    # Two strategies, three settings each, one seed: eye paths' error falls as 1/time, bidirectional
    # paths' is half of it at every time, so each of their settings beats eye paths' front and no
    # eye setting beats theirs (each compared within the other's range of times only).
    rows = [
        {"status": "ok", "scene": "s", "method": "perfect", "strategy": strategy, "frames": f, "spp": 4, "seed": 0,
         "wall_s": float(f), "indirect_relmse": scale / f}
        for strategy, scale in (("eye", 1.0), ("bidirectional", 0.5)) for f in (2, 8, 32)
    ]  # fmt: skip
    spec = {"x": "wall_s", "y": "indirect_relmse", "versus": "strategy"}
    data = {
        "title": "T", "description": "D.", "reduced": "R.", "varying": ["strategy", "frames"], "rows": rows,
        "plots": [spec], "record": {"command": "evalkit study b.toml", "date": "2026-12-02", "versions": {}},
    }  # fmt: skip
    page = study_markdown(data, "b.json")
    assert (
        "- s, at matched wall_s: 3 of 3 settings on strategy bidirectional's Pareto front have less indirect_relmse "
        "than eye's front" in page
    )
    assert "- s, at matched wall_s: 0 of 3 settings on strategy eye's Pareto front" in page
    assert "| s | bidirectional | perfect | - | 4 | 8 | 1 | 8 | 0.0625 | eye | 0.125 | 0.5 | bidirectional |" in page


# -- numbers typed by hand ------------------------------------------------------------------------

# A measured-looking number in prose: one with a unit of time, size or ratio, or a decimal. Code
# (commands, parameters), maths and link targets are not prose; "1920 x 1024" is a size, not a ratio.
UNIT = r"(?:%|x\b(?!\s*\d)|ms\b|s\b|min\b|minutes?\b|seconds?\b|hours?\b|[KMG]i?B\b|fps\b)"
MEASURED = re.compile(rf"(?<![\w.\-/])(\d[\d,]*(?:\.\d+)?)\s?{UNIT}|(?<![\w.\-/])\d+\.\d+(?![\w.])")
NOT_PROSE = re.compile(r"```.*?```|`[^`\n]*`|\\\(.*?\\\)|\\\[.*?\\\]|\$\$.*?\$\$|\]\([^)]*\)|<!--.*?-->", re.S)
# A version names what it versions: "Python 3.11", "OpenGL 4.5", "Apache 2.0".
VERSIONED = ("Python", "OpenGL", "GL", "GLSL", "Mesa", "LLVM", "Apache", "MPL", "version", "to")
# The constants of the method the pages state, each the value in the code that it states.
CONSTANTS = {
    "95 %": confidence.LEVEL == 0.95,
    "1 %": NEXT_HIT_ERROR_TARGET == 0.01 and fidelity.TOLERANCE == 0.01,
    "99.75 %": fidelity.Z_SHARE == 0.9975,
    "10 %": SURFACE_POINTS_SHARE == 0.1 and BUDGET_TOLERANCE == 0.1,
    "1.8": DEFAULT_SPLAT_SCALE == 1.8,
    "0.05": RenderSettings().self_hit_bias == 0.05,
    "2 GiB": DEFAULT_NODE_BUDGET == 2 << 30,
    "64 KiB": UNIFORM_BLOCK_BYTES == 64 << 10,
}


def markdown_sources():
    """Every Markdown source of the README and the site: pages, and the tutorials' text cells."""
    for path in [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]:
        yield path, path.read_text()
    for path in sorted((REPO / "docs").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        yield path, "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")


def hand_typed_numbers(text: str) -> list[str]:
    """The measured-looking numbers in ``text``'s prose that are neither versions nor constants."""
    prose = NOT_PROSE.sub(" ", text)
    found = []
    for match in MEASURED.finditer(prose):
        before = prose[: match.start()].split()
        if before and before[-1] in VERSIONED:
            continue
        if " ".join(match.group(0).split()) not in CONSTANTS:
            found.append(match.group(0).strip())
    return found


def test_no_page_holds_a_measured_number_typed_by_hand():
    assert all(CONSTANTS.values())  # each constant the pages may state is the code's
    typed = {str(path.relative_to(REPO)): hand_typed_numbers(text) for path, text in markdown_sources()}
    assert {page: numbers for page, numbers in typed.items() if numbers} == {}


# History written in place: the pages say what is, the changelog what changed, and a decision's
# evidence names its record, not when someone measured it.
DIARY = re.compile(r"\b(?:today'?s?|yesterday|this session|an? (?:earlier|previous) session)\b", re.I)


def test_no_page_or_decision_is_written_as_a_diary():
    texts = [*markdown_sources(), (DECISIONS, DECISIONS.read_text())]
    found = {str(path.relative_to(REPO)): DIARY.findall(text) for path, text in texts}
    assert {path: words for path, words in found.items() if words} == {}
    assert DIARY.findall("measured today, in an earlier session") == ["today", "an earlier session"]


def test_the_number_check_finds_measurements_but_not_versions_sizes_code_or_constants():
    text = (
        "Built in 57 s (3.2x faster, 12.5 % holes, 1.5 GiB) with Python 3.11 on OpenGL 4.5: "
        "`evalkit render --frames 64`, 1920 x 1024 pixels, a 95 % interval, \\(\\alpha = 0.5\\).\n"
        "```\nbuilt in 4.2 ms\n```\n0.966 of the reference."
    )
    assert hand_typed_numbers(text) == ["57 s", "3.2x", "12.5 %", "1.5 GiB", "0.966"]
