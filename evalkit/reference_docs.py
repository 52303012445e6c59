"""The documentation site's reference pages, generated from the code itself so they cannot drift:
the command line from `evalkit.cli.build_parser`, and every declared setting and registered unit
from `RenderSettings` and `gpu_impl.registry` (docs/hooks.py puts them in the site)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

from evalkit.cli import build_parser
from evalkit.core.exr import read_exr
from evalkit.core.scene.builtin import BUILTIN_SCENES
from evalkit.core.settings import IMAGES, RenderSettings, declared
from evalkit.metrics.images import METRICS
from evalkit.records import read_record
from gpu_impl.api import render
from gpu_impl.registry import KINDS
from gpu_impl.renderer import write_render
from references.mitsuba import COMMITTED_STORE


def commands(
    parser: argparse.ArgumentParser | None = None, prefix: str = "evalkit"
) -> list[tuple[str, argparse.ArgumentParser]]:
    """Every command (``evalkit scene info`` ...) with its parser, depth first."""
    parser = parser or build_parser()
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                subcommands = commands(sub, f"{prefix} {name}")
                found += subcommands or [(f"{prefix} {name}", sub)]
    return found


def _helps(parser: argparse.ArgumentParser) -> dict[str, str]:
    """The one-line help of each subcommand of ``parser``, by name."""
    helps = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps.update({a.dest: a.help or "" for a in action._choices_actions})
    return helps


def cli_markdown() -> str:
    """The command line reference: per command, what it does, its usage and every argument."""
    root = build_parser()
    lines = [
        "# Command line",
        "",
        "Generated from the parser (`evalkit.cli.build_parser`). Bad input prints one line naming the "
        "file and the problem and exits 2; `--json` ends the output with one JSON object.",
        "",
        "`SCENE` is a built-in scene, "
        + ", ".join(f"`{name}`" for name in BUILTIN_SCENES)
        + " (`evalkit/core/scene/builtin.py` says what each is for), or a path to a Mitsuba XML, OBJ, PLY, "
        "glTF or GLB file ([scenes and importers](scenes.md)).",
        "",
    ]
    for name, parser in commands(root):
        words = name.split()
        help_text = _helps(_parser_at(root, words[1:-1])).get(words[-1], "")
        lines += [f"## `{name}`", "", help_text, "", "```", parser.format_usage().strip(), "```", ""]
        rows = []
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            flag = ", ".join(f"`{o}`" for o in action.option_strings) or f"`{action.dest}`"
            default = "" if action.default in (None, argparse.SUPPRESS, False) else f"`{action.default}`"
            rows.append(f"| {flag} | {default} | {_cell(action.help or '')} |")
        if rows:
            lines += ["| argument | default | meaning |", "|---|---|---|", *rows, ""]
    return "\n".join(lines)


def _parser_at(root: argparse.ArgumentParser, words: list[str]) -> argparse.ArgumentParser:
    parser = root
    for word in words:
        parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[word]
    return parser


def settings_markdown() -> str:
    """Every declared setting: `RenderSettings`' own, then each registered unit's, with its default,
    range and meaning."""
    lines = [
        "# Settings and units",
        "",
        "Generated from the declarations (`evalkit.core.settings.setting`) and the registries "
        "(`gpu_impl.registry`). A unit's settings are flags of `evalkit render` and parameters of "
        "study files; a setting given to a unit the render does not use is a warning.",
        "",
        "## Render settings (`RenderSettings`)",
        "",
        *_settings_table(RenderSettings),
    ]
    for kind, registry in KINDS.items():
        lines += [f"## {registry.kind.capitalize()}s (`{kind}`)", ""]
        for unit in registry:
            lines += [f"### `{unit.name}`", "", unit.summary, ""]
            lines += _settings_table(unit.settings) if declared(unit.settings) else ["No settings of its own.", ""]
    return "\n".join(lines)


def _settings_table(settings_type) -> list[str]:
    rows = ["| setting | default | range | meaning |", "|---|---|---|---|"]
    for f in declared(settings_type):
        m = f.metadata
        default = f.default if f.default is not dataclasses.MISSING else None
        if m["choices"]:
            allowed = " / ".join(f"`{c}`" for c in m["choices"])
        elif m["positive"]:
            allowed = "> 0"
        elif m["minimum"] is not None and m["maximum"] is not None:
            allowed = f"{m['minimum']:g} to {m['maximum']}"
        elif m["minimum"] is not None:
            allowed = f">= {m['minimum']:g}"
        else:
            allowed = ""
        unit = f" {m['unit']}" if m["unit"] else ""
        rows.append(f"| `{f.name}` | `{default}`{unit} | {allowed} | {_cell(m['help'])} |")
    return [*rows, ""]


def _cell(text: str) -> str:
    return text.replace("%%", "%").replace("|", "\\|").replace("\n", " ")


# -- output files ------------------------------------------------------------------------------

# The renders the output page is generated from: their files are written and read back, so the page
# lists what a render writes, and every key needs its line below (a key without one fails the build).
# One render takes every kind's first registered unit, one its last, at a tiny size.
OUTPUT_RENDER = RenderSettings(bounces=2, directions=4, resolution=16, width=8, height=8, frames=2, spp=1)


def output_renders() -> dict[str, RenderSettings]:
    """The renders of the output page, by a label naming their units."""
    renders = {}
    for end in (0, -1):
        units = {kind: list(registry)[end].name for kind, registry in KINDS.items()}
        label = ", ".join(f"{KINDS[kind].kind} {name}" for kind, name in units.items())
        renders[label] = dataclasses.replace(OUTPUT_RENDER, **units)
    return renders


# The passes `timings.json` times (`median_ms`, `frames_ms`; a study's `ms_<pass>` columns), and the
# bundle build's own, which tracers time as `bundles.<pass>` (gpu_impl/bundles.py, methods/).
PASSES = {
    "frame": "the whole frame",
    "bundles": "the bundle build",
    "bundles.points": "imperfect bundles: the splat points",
    "bundles.lists": "the lists: rasterized, or the splats counted and scattered",
    "bundles.resolve": "the lists sorted (and merged)",
    "shadow_maps": "the shadow maps of point, spot and directional lights",
    "environment_samples": "the environment samples' directions and shadow maps",
    "emitter_samples": "the emitter samples' points and shadow maps",
    "light_paths": "bidirectional paths: the light paths and their vertices' shadow maps",
    "gbuffer": "the camera's G-buffer and first hits, lit",
    "irradiance": "imperfect bundles: the splat points' precomputed light",
    "bounce": "bounce {} of the eye paths",
    "resolve": "the path sums resolved into the images",
}


def pass_meaning(name: str) -> str | None:
    """What pass ``name`` times (`PASSES`), its bounce number aside; None where nothing says."""
    kind, _, number = name.partition("_")
    if kind == "bounce" and number.isdigit():
        return PASSES["bounce"].format(number)
    return PASSES.get(name)


# What each key of a render's record means, where it is not a declared setting (the settings page has
# those): timings.json's three sections, and the EXR header's own keys.
RENDER_KEYS = {
    "params": {
        "evalkit": "the toolkit's version",
        "scene": "the scene's name",
        "scene_source": "the file or built-in name the scene was loaded from",
        "scene_hash": "SHA-256 of the scene's content: geometry, materials, lights, camera",
        "posed_scene_hash": "the same, of the scene posed at the render's `time`",
        "frames_rendered": "the frames rendered (fewer than `frames` where `time_budget` ran out)",
        "paths_per_pixel": "`supersampling`\u00b2 x `spp` x the frames rendered",
        "shader_variant": "the defines the frame's shaders were compiled with: the scene's features and settings",
        "gl": "the GL vendor, renderer, version, EGL device and llvmpipe threads",
        "merged": "whether the imperfect bundles' redundant nodes were merged",
        "crease_degrees": "splats end at convex creases sharper than this",
        "splat_growth": "how a splat cut at sharp edges grows",
        "flat_degrees": "neighbours within this angle count as one plane, whose sharp edges cut the splat too",
        "surface_least_points": "the points' share every smooth surface has at least",
        "point_density": "the points over those the area alone would give",
    },
    "stats": {
        "nodes_median": "nodes per frame, median over frames",
        "nodes_max": "nodes per frame, most",
        "overflow_reruns": "raster passes run again with a larger node buffer",
        "max_list_length": "the longest list, in nodes",
        "paths_per_frame": "eye paths a frame traces",
        "bounce_passes": "bounce passes run per frame",
        "bounce_passes_skipped": "bounce passes skipped once no path was alive",
        "bundles_reused": "frames that reused the first frame's bundles (`rotate_directions` off)",
        "lighting_frames": "frames whose splat light was precomputed or lazy",
        "gpu_bytes": "GPU memory the bundles and lights took",
        "import_fidelity": "the scene's last `evalkit scene check`, where one was run",
        "light_path_vertices_median": "light path vertices per frame, median over frames",
    },
    "timings": {
        "method": "how passes were timed: GL timer queries on a GPU, host time around glFinish on llvmpipe",
        "median_ms": "per pass, the median over frames, in ms",
        "frames_ms": "per frame, each pass's time in ms",
        "wall_s": "the render's wall time, in s",
    },
    "exr": {
        "image": "which image: direct, indirect, total or a variance",
        "frame_means": "each frame's image mean, per channel: the confidence intervals' data",
        "warnings": "what the import and render approximated or skipped",
        "variance": "what a variance image holds",
    },
}


def outputs_markdown(results_data: Path) -> str:
    """The files a render writes and what each key in them means, generated from renders made while
    the page is built (`output_renders`), so it lists what the code writes; and the results columns
    of the studies recorded in ``results_data``."""
    helps = _declared_settings()
    seen: dict[str, dict[str, set]] = {section: {} for section in (*RENDER_KEYS, "passes")}
    files: dict[str, set] = {}
    renders = output_renders()
    with tempfile.TemporaryDirectory() as tmp:
        for label, settings in renders.items():
            out = Path(tmp) / str(len(files))
            written = write_render(render("cornell-box", settings), out)
            files[label] = {p.name for p in written}
            record = json.loads((out / "timings.json").read_text())
            for section in ("params", "stats", "timings"):
                for key in record[section]:
                    seen[section].setdefault(key, set()).add(label)
            for name in record["timings"]["median_ms"]:
                seen["passes"].setdefault(name, set()).add(label)
            for path in written:
                if path.suffix == ".exr":
                    for key in read_exr(path)[1]:
                        if key not in record["params"]:
                            seen["exr"].setdefault(key, set()).add(label)
    missing = [
        f"{section}.{key}"
        for section, keys in seen.items()
        for key in keys
        if (pass_meaning(key) is None if section == "passes" else key not in RENDER_KEYS[section])
        and not (section == "params" and key in helps)
    ]
    if missing:
        raise ValueError(f"evalkit/reference_docs.py: RENDER_KEYS has no line for {', '.join(sorted(missing))}")
    labels = list(renders)
    lines = [
        "# Output files",
        "",
        "What the toolkit writes, and what each key in it means. The render's part is generated while "
        "the site is built from the files that renders of `cornell-box` write (" + "; ".join(labels) + "), "
        "so it lists what the code writes now; a key marked with one of them is written by that kind of render "
        "only. Declared settings link to [settings and units](settings.md).",
        "",
        "## A render's folder",
        "",
        "`evalkit render SCENE --out DIR`, and `gpu_impl.renderer.write_render(result, DIR)` in Python:",
        "",
        "| file | what it holds |",
        "|---|---|",
        *(f"| `{name}` | {RENDER_FILES[_file_kind(name)]} |" for name in sorted(set().union(*files.values()))),
        "",
    ]
    sections = {
        "params": "`timings.json`: `params`, every setting and version that made the images (the EXR headers too)",
        "stats": "`timings.json`: `stats`",
        "timings": "`timings.json`: `timings`",
        "passes": "`timings.json`: the passes `median_ms` and `frames_ms` time",
        "exr": "EXR headers: beside `params`, as `evalkit.<key>` attributes",
    }
    for section, title in sections.items():
        lines += [f"### {title}", "", "| key | meaning | written by |", "|---|---|---|"]
        for key in sorted(seen[section]):
            if section == "passes":
                meaning = pass_meaning(key)
            else:
                meaning = RENDER_KEYS[section].get(key) or f"[setting](settings.md): {helps[key]}"
            by = "every render" if seen[section][key] == set(labels) else "; ".join(sorted(seen[section][key]))
            lines.append(f"| `{key}` | {_cell(meaning)} | {by} |")
        lines.append("")
    lines += _manifest_markdown() + _study_columns_markdown(results_data, helps)
    return "\n".join(lines)


RENDER_FILES = {
    "image": "the image: float32 linear RGB, ZIP-compressed, its provenance in the header",
    "variance": "the per-pixel variance of the image's mean, from the spread of the frames (two frames or more)",
    "timings": "per-pass timings, statistics, the parameters and the warnings, as JSON",
}


def _file_kind(name: str) -> str:
    return "timings" if name == "timings.json" else "variance" if name.endswith("_variance.exr") else "image"


def _declared_settings() -> dict[str, str]:
    """Every declared setting's help, by name: `RenderSettings`' own, then every registered unit's."""
    fields = [*declared(RenderSettings), *(f for r in KINDS.values() for unit in r for f in declared(unit.settings))]
    return {f.name: f.metadata["help"] for f in reversed(fields)}


# A stored reference's manifest.json (references.mitsuba), key by key.
MANIFEST_KEYS = {
    "store_format": "the store's layout version",
    "scene": "the scene's name",
    "scene_source": "the file or built-in name the scene was loaded from",
    "scene_hash": "SHA-256 of the scene's content, part of the store's key",
    "bounces": "the bounce count B: direct is Mitsuba's `max_depth` 2, total B + 2",
    "spp": "samples per pixel",
    "seed": "the seed of the first chunk",
    "chunks": "the seeded chunks the samples were rendered in; their spread gives the variances",
    "width": "image width in pixels",
    "height": "image height in pixels",
    "integrator": "the integrator and how indirect was made",
    "variance": "what the variance images hold",
    "mitsuba": "Mitsuba's version",
    "variant": "Mitsuba's variant",
    "evalkit": "the toolkit's version",
    "warnings": "what the export approximated",
    "render_s": "the render's wall time, in s",
    "files": "the images, by name",
}


def _manifest_markdown() -> list[str]:
    manifests = sorted(COMMITTED_STORE.glob("*/*/manifest.json"))
    keys = sorted({key for path in manifests for key in json.loads(path.read_text())})
    missing = [key for key in keys if key not in MANIFEST_KEYS]
    if missing:
        raise ValueError(f"evalkit/reference_docs.py: MANIFEST_KEYS has no line for {', '.join(missing)}")
    return [
        "## A reference's folder",
        "",
        "`evalkit reference SCENE --out DIR`, and the reference store: `direct.exr`, `indirect.exr`, "
        "`total.exr` and their `_variance.exr` (the per-pixel variance of the mean from the spread of the "
        "chunks), and `manifest.json`, written last. Its keys, from the committed store (`references/store/`):",
        "",
        "| key | meaning |",
        "|---|---|",
        *(f"| `{key}` | {_cell(MANIFEST_KEYS[key])} |" for key in keys),
        "",
    ]


# A study's results columns that are neither settings nor of a pattern below (evalkit.study.run).
STUDY_COLUMNS = {
    "run_id": "the run's folder under `runs/`, a hash of its parameters",
    "scene": "the scene: a built-in name or a file",
    "status": "`ok`, or what failed",
    "scene_hash": "SHA-256 of the scene's content",
    "reference": "the reference's folder",
    "warnings": "what the import and render approximated or skipped",
    "run_s": "the run's wall time, measuring included, in s",
    "wall_s": "the render's wall time, in s",
    "frames_rendered": "the frames rendered",
    "paths_per_pixel": "paths a pixel averages",
    "nodes_per_frame": "nodes per frame, median",
    "gl_renderer": "the GL renderer",
    "exact_nodes": "nodes of Embree's exact bundles on the same lines",
    "test_nodes": "nodes of the run's bundles",
    "agreement": "exact nodes matched, over all exact nodes",
    "hole_rate": "exact nodes no test node matches ([bundle comparison](ground_truths.md#bundle-comparison))",
    "leak_rate": "holes with no node of their surface within a splat's reach",
    "offset_rate": "holes with such a node beyond the depth tolerance",
    "coincident_rate": "holes where two coincident surfaces got one node",
    "spurious_rate": "test nodes with no exact node, over test nodes",
    "spurious_per_crossing": "spurious nodes per exact node",
    "redundant_rate": "test nodes beyond one per surface crossing, over test nodes",
    "same_prim_rate": "matched nodes of the same primitive",
    "raw_nodes": "nodes written before merging",
    "nodes_per_crossing": "lines splats cover per exact node (the nodes without merging)",
    "written_nodes_per_crossing": "nodes written per exact node",
    "kept_nodes_per_crossing": "nodes kept per exact node",
    "depth_error_rms": "RMS depth error of matched nodes, in frame radii",
    "offset_splat_radii_p50": "offsets' depth gap in splat radii, median",
    "offset_splat_radii_p90": "offsets' depth gap in splat radii, 90th percentile",
    "worst_direction_hole_rate": "the hole rate of the worst direction",
    "next_hit_error_rate": "lookups landing elsewhere than the exact ray ([metrics](metrics.md#bundle-metrics))",
    "next_hit_exact_floor": "the same for exact bundles: the floor from the lines beside the vertex",
    "wrong_lookups_per_path": "wrong next hits a path of the run's bounces expects",
    "next_hit_false_miss_rate": "lookups that miss where the ray hits",
    "next_hit_wrong_surface_rate": "lookups that land on another surface",
    "next_hit_lookups": "lookups made",
    "build_ms": "the bundle build's passes, in ms",
    "build_wall_ms": "the bundle build's wall time, in ms",
}


def _study_column(column: str, settings: dict[str, str]) -> str | None:
    """What a results column means, by name; None where nothing says."""
    if column in STUDY_COLUMNS:
        return STUDY_COLUMNS[column]
    if column in settings:
        return f"the run's [setting](settings.md): {settings[column]}"
    if column.startswith("version_"):
        return f"the version of {column[len('version_') :]}"
    if column.startswith("ms_"):
        meaning = pass_meaning(column[3:])
        return meaning and f"{meaning}: the pass's median ms over frames (`timings.json`: `median_ms`)"
    if column.startswith("hole_rate_slope"):
        return "the hole rate among crossings of a slope bin (|cos| between line and surface, `SLOPE_BINS`)"
    image, _, rest = column.partition("_")
    if image in IMAGES:
        if rest in METRICS:
            return f"`{rest}` of the {image} image against the reference ([metrics](metrics.md))"
        return {
            "mean_error": f"the {image} image's mean over the reference's, less 1",
            "mean_ratio": f"the {image} image's mean over the reference's",
            "mean_ratio_lo": "its 95 % interval's lower end",
            "mean_ratio_hi": "its 95 % interval's upper end",
            "z_outside": f"share of the {image} image's pixel values the z-test rejects",
        }.get(rest)
    return None


def _study_columns_markdown(results_data: Path, settings: dict[str, str]) -> list[str]:
    columns = set()
    for path in sorted(results_data.glob("*.json")):
        record = read_record(path)
        if "study" in record:
            columns.update(key for row in record["rows"] for key in row)
    missing = sorted(c for c in columns if _study_column(c, settings) is None)
    if missing:
        raise ValueError(f"evalkit/reference_docs.py: no meaning for the results columns {', '.join(missing)}")
    return [
        "## A study's folder",
        "",
        "`evalkit study STUDY.toml --out DIR`: `results.jsonl` (a row per run, appended as it finishes), "
        "`results.csv` (the same table), `report.html`, and per run `runs/<run_id>/` with its images and "
        "error maps. The columns of the recorded studies (`docs/results/data/`):",
        "",
        "| column | meaning |",
        "|---|---|",
        *(f"| `{c}` | {_cell(_study_column(c, settings))} |" for c in sorted(columns)),
        "",
    ]
