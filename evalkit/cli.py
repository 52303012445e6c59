"""The `evalkit` command line.

Bad input (`InputError`) prints one line, ``evalkit: error: <source>: <problem>``, and exits 2;
``--verbose`` shows the traceback. With ``--json`` the last line on stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import signal
import sys
import traceback
from pathlib import Path

import numpy as np

from evalkit.advice import advised, cached_resolution_advice, render
from evalkit.check import calibrate, evaluate, junit_xml
from evalkit.core.bundleset import BundleSet, DirectionSet
from evalkit.core.display import tonemap
from evalkit.core.errors import InputError, check_output
from evalkit.core.exr import read_exr, write_exr
from evalkit.core.scene import builtin_names, load_scene
from evalkit.core.scene.summary import scene_summary
from evalkit.core.settings import DEPTH_TOLERANCE, PRESETS, RenderSettings, declared
from evalkit.demo import run_demo, summary_lines
from evalkit.doctor import diagnose, report_lines
from evalkit.fidelity import DEFAULT_WIDTH, TOLERANCE, check_scene, fidelity_of, ratio_text, summary_line
from evalkit.figures import REPORT_EXPOSURE, error_map_png, save_png, teaser
from evalkit.metrics.bundles import compare_bundles, scene_surfaces
from evalkit.metrics.confidence import confidence, pool_renders
from evalkit.metrics.images import (
    DELTA_E_EXPOSURE,
    FLIP_PPD,
    METRICS,
    RELMSE_EPSILON,
    SMAPE_EPSILON,
    compare_images,
    non_finite_pixels,
)
from evalkit.records import study_record, write_record
from evalkit.study.executors import run_study
from evalkit.study.spec import load_study
from evalkit.thresholds import DEFAULT_THRESHOLDS, load_thresholds
from evalkit.tune import CALIBRATION_SHARE, Candidate, bias_text, settings_text, tune
from gpu_impl.api import trace_bundles
from gpu_impl.context import format_bytes
from gpu_impl.registry import KINDS, METHODS, all_units, owners, resolve
from gpu_impl.renderer import write_render
from references.embree import ExactTracer
from references.mitsuba import STORE_VARIABLE, export_reference, reference


def _doctor(args) -> int:
    results = diagnose()
    for line in report_lines(results):
        print(line)
    ok = all(r["ok"] for r in results.values())
    if args.json:
        print(json.dumps({"ok": ok, **results}))
    return 0 if ok else 1


def _bsdf_text(material: dict) -> str:
    """A material's BSDF as `evalkit scene info` prints it: a diffuse albedo, or the glossy lobe
    and what it reflects (a conductor has no diffuse albedo)."""
    b = material["bsdf"]
    if material["vertex_colors"]:
        return f"vertex colours (mean {_vec(material['albedo'])})"
    if b["type"] == "diffuse":
        return f"albedo {_vec(material['albedo'])}"
    lobe = f"{b['type']} ({b['distribution']}, alpha {b['alpha']:.4g})"
    if b["type"] == "roughconductor":
        return f"{lobe}, eta {_vec(b['eta'])}, k {_vec(b['k'])}"
    return f"{lobe}, index {b['int_ior / ext_ior']:.4g} over albedo {_vec(material['albedo'])}"


def _scene_check(args) -> int:
    bar = ProgressLine(quiet=args.json)
    try:
        result = check_scene(
            args.scene,
            bounces=args.bounces,
            spp=args.spp,
            chunks=args.chunks,
            width=args.width,
            height=args.height,
            seed=args.seed,
            tolerance=args.tolerance,
            bundles=None
            if args.render is None
            else RenderSettings(
                method=args.render, directions=args.directions, resolution=args.resolution, frames=args.frames
            ),
            progress=bar,
        )
    finally:
        bar.close()
    w, h = result["settings"]["size"]
    print(f"scene       {result['scene']}  ({result['source']})")
    print(
        f"check       the file as Mitsuba loads it against the toolkit's import of it, both rendered by Mitsuba: "
        f"{w}x{h}, {args.spp} spp in {args.chunks} chunks, B={args.bounces}, seed {args.seed}"
    )
    for name, image in result["images"].items():
        ratios = "  ".join(ratio_text(r) for r in image["ratio"])
        print(
            f"{name:<11} mean ratio (r, g, b) {ratios}; relMSE {image['relmse']:.3g}; "
            f"{100 * (1 - image['z_outside_share']):.2f} % of pixels pass the z-test"
        )
    if result["compared"] == "geometry":
        print(
            "compared    geometry and normals alone, both grey under a constant sky: Mitsuba reads no MTL, and a "
            "PLY's colours as raw codes"
        )
    camera = result["camera"]
    if camera is not None:
        print(
            f"camera      the import's rays against the file's sensor's: up to {camera['angle_degrees']:.3g} degrees "
            f"and {camera['offset']:.3g} bounding radii apart"
        )
    for w in result["approximations"]:
        print(f"import      {w}")
    if result["bundles"] is not None:
        ratios = "  ".join(f"{name} {ratio_text(r)}" for name, r in result["bundles"]["ratio"].items())
        print(f"bundles     {args.render} bundles' image means over Mitsuba's render of the file: {ratios}")
    print(summary_line(result))
    if args.json:
        print(json.dumps(result))
    return 0 if result["passed"] else 1


def _scene_info(args) -> int:
    scene = load_scene(args.scene)
    info = scene_summary(scene)
    f = info["features"]
    print(f"scene       {info['name']}  ({info['source']})")
    print(
        f"triangles   {info['triangles']:,} in {info['meshes']} meshes, {info['degenerate_removed']} degenerate removed"
    )
    print(
        f"bounds      {_vec(info['bounds']['min'])} .. {_vec(info['bounds']['max'])}, "
        f"bounding radius {info['bounding_radius']:.4g}"
    )
    print(f"area        {info['surface_area']:.6g}, depth complexity {f['depth_complexity']:.3f} surfaces per line")
    for m in info["materials"]:
        tex = f", texture {m['texture'][1]}x{m['texture'][0]}" if m["texture"] else ""
        emit = f", emission {_vec(m['emission'])}" if max(m["emission"]) > 0 else ""
        note = f" [{m['source_bsdf']}, approximated]" if m["approximated"] else ""
        print(f"material    {m['name']}: {_bsdf_text(m)}{tex}{emit}{', two-sided' if m['twosided'] else ''}{note}")
    for light in info["lights"]:
        print(f"light       {light['kind']}: {_vec(light['intensity'])}")
    c = info["camera"]
    print(
        f"camera      at {_vec(c['position'])}, fov {c['fov']:.4g} deg along {c['fov_axis']}, "
        f"{c['width']}x{c['height']}"
    )
    print(
        f"features    textures={f['textures']} emitters={f['emitters']} environment={f['environment']} "
        f"lights={','.join(f['light_types']) or '-'} vertex_colors={f['vertex_colors']}"
    )
    advice = cached_resolution_advice(scene, args.seed, bounces=args.bounces)
    probed = ", ".join(f"{100 * e:.1f} % at R={r}" for r, e in advice["wrong_lookups_per_path"].items())
    print(
        f"resolution  {advised(advice)} at B={advice['bounces']}: wrong next hits per path {probed} "
        f'(target {100 * advice["target"]:.0f} %, docs/reference/metrics.md "Choosing R")'
    )
    info["resolution"] = advice
    fidelity = fidelity_of(scene)
    if fidelity is not None:
        print(f"import      {summary_line(fidelity)}")
        info["import_fidelity"] = fidelity
    for w in info["warnings"]:
        print(f"warning     {w}")
    if args.json:
        print(json.dumps(info))
    return 0


def _bundles(args) -> int:
    scene = load_scene(args.scene)
    defaults = RenderSettings()
    K, R = args.directions or defaults.directions, args.resolution or defaults.resolution
    directions = DirectionSet.make(K, seed=args.seed, frame=args.frame, jitter=not args.no_jitter)
    if args.method == "exact":
        bundles = ExactTracer(scene, threads=args.threads).bundles(directions, R)
        stats = bundles.stats
        detail = (
            f"{stats['casts']:,} Embree casts on {stats['threads']} thread(s), re-cast offset "
            f"{bundles.params['recast_epsilon']:.3g}, {bundles.params['coincidence_layers']} coincidence layer(s)"
        )
        per_thread = stats["nodes"] / max(stats["wall_s"], 1e-9) / stats["threads"] / 1e6
        timing = f"wall {1e3 * stats['wall_s']:.1f} ms, {per_thread:.2f} M hits/s per thread"
        described = "exact"
    else:
        settings = settings_from_args(args, BUNDLE_FLAGS + METHOD_FLAGS)
        bundles, detail, timing = _gl_bundles(scene, directions, settings)
        described = resolve(settings).describe()
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    bundles.save(args.out)
    summary = bundles.summary()
    radius = bundles.params.get("splat_radius")
    print(
        f"bundles     {described} on {scene.name}: K={K} R={R}"
        + ("" if radius is None else f" splat radius {radius:.4g} (scale {bundles.params['splat_scale']:.3g})")
    )
    print(
        f"nodes       {bundles.node_count:,}, longest list {summary['max_list_length']}, "
        f"{summary['empty_lists']:,} of {bundles.list_count:,} lists empty"
    )
    print(f"work        {detail}")
    print(f"time        {timing}")
    print(f"written     {args.out}")
    if args.json:
        print(json.dumps({"out": args.out, **summary}))
    return 0


def _gl_bundles(scene, directions, settings):
    try:
        bundles = trace_bundles(scene, directions, settings)
    except ValueError as e:
        raise InputError("evalkit bundles", str(e)) from None
    stats = bundles.stats
    detail = (
        f"{stats['redundant_nodes']:,} redundant nodes, {format_bytes(stats['node_bytes'])} of nodes, "
        f"{format_bytes(stats['gpu_bytes'])} on the GPU in all, {stats['overflow_reruns']} overflow re-run(s)"
    )
    passes = ", ".join(f"{k} {v:.1f}" if v is not None else f"{k} n/a" for k, v in stats["gpu_ms"].items())
    return bundles, detail, f"gpu ms {passes} ({stats['gpu_timing']}); wall {stats['wall_ms']:.1f} ms"


def _bundle_surfaces(args, test: BundleSet, exact: BundleSet):
    """The smooth surfaces of the scene the bundles were built from (what tells a leak from an
    offset), or None with a warning when that scene cannot be read as it was."""
    spec = args.scene or test.params.get("scene_source")
    why = None
    if spec is None:
        why = f"{args.test} does not record where its scene came from; pass --scene"
    else:
        try:
            scene = load_scene(spec)
        except InputError as e:
            why = f"{e}; pass --scene"
        else:
            if scene.content_hash() not in (test.params.get("scene_hash"), exact.params.get("scene_hash")):
                why = f"{spec} is not the scene {args.test} was built from (its content hash differs)"
    if why:
        print(f"evalkit: warning: holes not told apart (leaks, offsets, coincident): {why}", file=sys.stderr)
        return None
    return scene_surfaces(scene)


def _compare_bundles(args) -> int:
    test, exact = BundleSet.load(args.test), BundleSet.load(args.exact)
    if exact.method != "exact":
        print(
            f"evalkit: warning: {args.exact}: method is '{exact.method}', not 'exact'; "
            "it is used as the reference anyway",
            file=sys.stderr,
        )
    surfaces = _bundle_surfaces(args, test, exact) if test.has_splats else None
    try:
        r = compare_bundles(test, exact, depth_tolerance=args.depth_tolerance, surfaces=surfaces)
    except ValueError as e:
        raise InputError(args.test, f"cannot be compared with {args.exact}: {e}") from None
    per = r["per_direction"]
    print(
        f"compare     {test.method} ({args.test}) against {exact.method} ({args.exact}): "
        f"K={r['directions']} R={r['resolution']}"
    )
    print(f"tolerance   depth {r['depth_tolerance']:g} x radius = {r['depth_tolerance_absolute']:.4g} scene units")
    print(f"nodes       exact {r['exact_nodes']:,}, test {r['test_nodes']:,}, matched {r['matched']:,}")
    print(f"{'':16}{'aggregate':>12}{'best dir':>12}{'median dir':>12}{'worst dir':>12}")
    for name in ("hole_rate", "spurious_rate", "redundant_rate"):
        values = np.sort(per[name])
        print(f"{name:16}{r[name]:12.4%}{values[0]:12.4%}{np.median(values):12.4%}{values[-1]:12.4%}")
    e = r["depth_error"]
    print(
        f"depth error mean {e['mean']:.3g}, rms {e['rms']:.3g}, p99 {e['p99']:.3g}, max {e['max']:.3g} (x radius); "
        f"same primitive {r['same_prim_rate']:.4%}"
    )
    print(
        f"agreement   {r['agreement']:.4%} of exact nodes matched; "
        f"{r['spurious_per_crossing']:.4f} spurious nodes per exact crossing"
    )
    if r["leak_rate"] is not None:
        print(
            f"holes       {r['leak_rate']:.4%} leaks (no node of the surface within a splat's reach), "
            f"{r['offset_rate']:.4%} offsets, {r['coincident_rate']:.4%} coincident"
        )
    if args.json:
        print(json.dumps(r))
    return 0


def _reference(args) -> int:
    scene = load_scene(args.scene).at(args.time)
    bar = ProgressLine(quiet=args.json)
    try:
        ref = reference(
            scene,
            bounces=args.bounces,
            spp=args.spp,
            width=args.width,
            height=args.height,
            seed=args.seed,
            chunks=args.chunks,
            variant=args.variant,
            store=args.store and Path(args.store),
            progress=bar,
            wait=args.wait,
        )
    except ValueError as e:
        raise InputError("evalkit reference", str(e)) from None
    finally:
        bar.close()
    written = export_reference(ref, args.out)
    m = ref.manifest
    print(
        f"reference   {scene.name}: {m['bounces']} bounce(s), {m['width']}x{m['height']}, "
        f"{m['spp']} spp in {m['chunks']} chunks, "
        f"seed {m['seed']}, Mitsuba {m['mitsuba']} {m['variant']}"
    )
    how = "reused" if ref.reused else f"rendered in {m['render_s']:.1f} s"
    print(f"store       {ref.path} ({how})")
    for line in _image_lines(ref.images, ref.variances):
        print(line)
    for w in m["warnings"]:
        print(f"warning     {w}")
    print(f"written     {args.out}: {', '.join(p.name for p in written)}")
    if args.json:
        print(json.dumps({"out": str(args.out), "store": str(ref.path), "reused": ref.reused, **m}))
    return 0


class ProgressLine:
    """Counters ("frame 3/16: ...", "chunk 5/32: ...") on one line rewritten in place on a
    terminal, with the time left the line carries; nothing under --json or without a terminal (a
    log keeps the summary). Other lines (waiting for a lock, resuming) are printed as notes."""

    COUNTER = re.compile(r"^(frame|chunk) \d+/\d+")

    def __init__(self, quiet: bool = False):
        self.live = not quiet and sys.stdout.isatty()
        self.shown = False

    def __call__(self, line: str) -> None:
        if not self.COUNTER.match(line):
            self.close()
            print(f"note        {line}", flush=True)
        elif self.live:
            print(f"\r\033[Kprogress    {line}", end="", flush=True)
            self.shown = True

    def close(self) -> None:
        if self.shown:
            print("\r\033[K", end="", flush=True)
            self.shown = False


def _image_lines(images: dict, variances: dict | None) -> list[str]:
    """Each image's per-channel mean and, with its variance, the mean per-pixel standard error:
    what render, reference and view print alike."""
    lines = []
    for name, image in images.items():
        line = f"{name:12}mean {_vec(image.reshape(-1, 3).mean(axis=0))}"
        if variances is not None and name in variances:
            line += f", pixel std. error {_vec(np.sqrt(variances[name]).reshape(-1, 3).mean(axis=0))}"
        lines.append(line)
    return lines


def _view(args) -> int:
    image, provenance = read_exr(args.image)
    save_png(tonemap(image, args.exposure), Path(args.png))
    name = Path(args.image).stem
    variance_path = Path(args.image).with_name(f"{name}_variance.exr")
    variances = {name: read_exr(variance_path)[0]} if variance_path.is_file() else None
    print(f"image       {args.image}: {image.shape[1]}x{image.shape[0]}, {provenance.get('image', 'no provenance')}")
    for line in _image_lines({name: image}, variances):
        print(line)
    bad = non_finite_pixels(image)
    if bad:
        print(f"warning     {bad} (NaN shown black)")
    print(f"written     {args.png}: exposure {args.exposure:g} stops, clipped to [0, 1], sRGB")
    return 0


def _render(args) -> int:
    scene = load_scene(args.scene)
    settings = settings_from_args(args, RENDER_FLAGS + UNIT_FLAGS)
    bar = ProgressLine(quiet=args.json)
    try:
        result = render(scene, settings, progress=bar)
    except ValueError as e:
        raise InputError("evalkit render", str(e)) from None
    finally:
        bar.close()
    written = write_render(result, args.out)
    p, t = result.params, result.timings
    print(
        f"render      {resolve(settings).describe()} bundles on {scene.name}: {p['width']}x{p['height']} "
        f"(supersampling {p['supersampling']}), {p['bounces']} bounce(s), K={p['directions']} R={p['resolution']}, "
        f"{p['frames_rendered']} frame(s), {p['paths_per_pixel']} paths per pixel, seed {p['seed']}"
    )
    gpu = format_bytes(result.stats["gpu_bytes"])
    print(f"memory      {result.stats['nodes_median']:,} nodes per frame (median), {gpu} on the GPU")
    print(f"time        per frame, median ms ({t['method']}):")
    for name, ms in t["median_ms"].items():
        print(f"  {name:22}{'n/a' if ms is None else f'{ms:10.2f}'}")
    print(f"wall        {t['wall_s']:.2f} s")
    for line in _image_lines(result.images, result.variances):
        print(line)
    for w in result.warnings:
        print(f"warning     {w}")
    print(f"written     {args.out}: {', '.join(path.name for path in written)}")
    if args.json:
        print(
            json.dumps(
                {
                    "out": str(args.out),
                    "timings_ms": t["median_ms"],
                    "wall_s": t["wall_s"],
                    "stats": result.stats,
                    "params": result.params,
                    "warnings": result.warnings,
                }
            )
        )
    return 0


def _compare(args) -> int:
    test, test_variance, test_meta = _test_image(args.test)
    test_name = " + ".join(args.test)
    ref, ref_meta = read_exr(args.ref)
    metrics = compare_images(
        test,
        ref,
        args.metrics,
        test_name,
        args.ref,
        relmse_eps=args.relmse_eps,
        smape_eps=args.smape_eps,
        flip_ppd=args.flip_ppd,
        exposure=args.exposure,
    )
    print(f"compare     {test_name} against {args.ref} ({test.shape[1]}x{test.shape[0]})")
    if len(args.test) > 1:
        seeds = ", ".join(str(s) for s in test_meta["seed"])
        print(f"pooled      {len(args.test)} renders (seeds {seeds}), {test_meta['frames']} frames")
    for m in metrics.values():
        params = ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in m.params.items())
        print(f"{m.name:12}{m.value:12.6g}   {params}")
    if args.maps:
        out = Path(args.maps)
        out.mkdir(parents=True, exist_ok=True)
        for m in metrics.values():
            provenance = {"metric": m.name, "test": args.test, "reference": args.ref, "value": m.value, **m.params}
            write_exr(out / f"{m.name}.exr", np.repeat(m.map[..., None], 3, axis=2).astype(np.float32), provenance)
            vmax = error_map_png(m.map, out / f"{m.name}.png")
            print(f"map         {out / (m.name + '.exr')} and .png (magma, 0..{vmax:.3g})")
    confidence = _confidence(args.ref, test, test_variance, test_meta, ref, ref_meta)
    if args.json:
        result = {name: {"value": m.value, "params": m.params} for name, m in metrics.items()}
        if len(args.test) > 1:
            result["pooled"] = {"renders": args.test, "seeds": test_meta["seed"], "frames": test_meta["frames"]}
        print(json.dumps({**result, **confidence}, default=float))
    return 0


def _variance_of(path: str) -> np.ndarray | None:
    """The ``<stem>_variance.exr`` beside an image, if there is one."""
    sibling = Path(path).with_name(f"{Path(path).stem}_variance.exr")
    return read_exr(sibling)[0] if sibling.is_file() else None


def _test_image(paths: list[str]) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """The test image, its variance of the mean (or None) and provenance; several renders are
    pooled into one (`pool_renders`)."""
    renders = []
    for path in paths:
        image, meta = read_exr(path)
        renders.append((path, image, _variance_of(path), meta))
    if len(renders) == 1:
        return renders[0][1], renders[0][2], renders[0][3]
    return pool_renders(renders)


def _confidence(ref_path, test, test_variance, test_meta, ref, ref_meta) -> dict:
    """`evalkit.metrics.confidence.confidence` as far as the files allow, printed. The ratio's
    interval takes the test's frame means and, for a Mitsuba reference, the variance beside it (its
    ``_variance.exr`` sibling); against another of the toolkit's renders, that render's frame means
    (`render_ratio`: paired frame by frame where the counts match)."""
    ref_variance = _variance_of(ref_path)
    out = confidence(
        test, test_variance, test_meta.get("frame_means"), ref, ref_variance, ref_meta.get("frame_means") or None
    )
    r = out.get("render_ratio") or out.get("mean_ratio")
    if r is not None:
        if "render_ratio" in out:
            counted = (
                f"{r['frames'][0]} frame pairs" if r["paired"] else "unpaired: {} and {} frames".format(*r["frames"])
            )
        else:
            counted = f"{r['frames']} frames"
        channels = ", ".join(_interval(c) for c in r["per_channel"])
        print(f"mean ratio  {_interval(r['all'])} ({r['level']:.0%} interval, {counted}); rgb {channels}")
    if ref_variance is None:
        print(f"{'z-test' if r is not None else 'confidence':12}none: the reference has no _variance.exr beside it")
    elif "z_test" in out:
        z = out["z_test"]
        print(
            f"z-test      {z['outside_share']:.3%} of {z['tested']:,} values outside |z| > {z['threshold']:.2f} "
            f"(alpha {z['alpha']:g}, Sidak)"
        )
    return out


def _interval(r: dict) -> str:
    return f"{r['ratio']:.4f}" + ("" if r["lo"] is None else f" [{r['lo']:.4f}, {r['hi']:.4f}]")


def _study(args) -> int:
    study = load_study(args.study)
    out = args.out or f"out/studies/{study.name}"
    rows = run_study(
        study,
        out,
        workers=args.workers,
        executor=args.executor,
        scheduler=args.scheduler,
        command="evalkit " + " ".join(sys.argv[1:]),
        wait=args.wait,
    )
    ok = sum(r["status"] == "ok" for r in rows)
    print(f"study       {study.name}: {ok} of {len(rows)} runs ok")
    print(f"results     {out}/results.csv")
    print(f"report      {out}/report.html")
    if args.record:
        command = "evalkit " + shlex.join(sys.argv[1:])
        print(f"record      {write_record(args.record, study_record(study, rows, out), command)}")
    return 0 if ok == len(rows) else 1


def _tune(args) -> int:
    result = tune(
        args.scene,
        args.budget,
        method=args.method,
        strategy=args.strategy,
        light_visibility=args.light_visibility,
        metric=args.metric,
        out=args.out,
        width=args.width,
        height=args.height,
        bounces=args.bounces,
        spp=args.spp,
        reference_spp=args.reference_spp,
        seed=args.seed,
        calibration_share=args.calibration_share,
        check=not args.no_check,
        grid=args.grid,
        pin=dict(args.pin or ()),
        progress=(lambda line: None) if args.json else print,
    )
    rec, predicted = result["recommended"], result["predicted"]
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"recommended {settings_text(rec)} ({len(result['candidates'])} candidates, chosen by {result['chosen_by']})")
    print(f"predicted   {predicted['time_s']:.3g} s, {result['metric']} {predicted['error']:.4g}")
    if "measured" in result:
        measured = result["measured"]
        print(
            f"measured    {measured['time_s']:.3g} s, {result['metric']} {measured['error']:.4g} "
            f"(time {measured['time_s'] / result['budget_s']:.2f}x the budget, "
            f"error {measured['error'] / predicted['error']:.2f}x the predicted)"
        )
    for c in result["candidates"]:
        if Candidate.of(c) != Candidate.of(rec):
            print(
                f"other       {settings_text(c)}: predicted {c['predicted_time_s']:.3g} s, {c['predicted_error']:.4g}"
                + (
                    f"; measured {c['measured']['time_s']:.3g} s, {c['measured']['error']:.4g}"
                    if "measured" in c
                    else ""
                )
            )
    if "grid" in result:
        grid = result["grid"]
        print(
            f"grid        best of {grid['runs']} runs within the budget: {settings_text(grid['best'])}"
            + f", {grid['best']['time_s']:.3g} s, {result['metric']} {grid['best']['error']:.4g}"
            + (f" (the recommendation's measured error is {grid['ratio']:.2f}x it)" if "ratio" in grid else "")
        )
    for name, terms in result["measured_bias"].items():
        for term, table in terms.items():
            print(f"bias        {name}: {term} measured at {bias_text(table)}")
    for name, idle in result["idle"].items():
        settings = ", ".join(f"{k}={v}" for k, v in idle.items())
        print(f"idle        {name}: {settings} left at the default (its renders draw no light vertex's map)")
    calibration = result["calibration"]
    print(
        f"calibration {calibration['runs']} runs, {calibration['render_s']:.1f} s of render time "
        f"({calibration['render_s'] / result['budget_s']:.2f}x the budget), {calibration['run_s']:.1f} s in all "
        f"(cached in {' and '.join(calibration['folders'])})"
    )
    for w in result["warnings"]:
        print(f"warning     {w}")
    print(f"report      {result['report']}")
    return 0


def _demo(args) -> int:
    rows = run_demo(args.out, command="evalkit " + " ".join(sys.argv[1:]))
    for line in summary_lines(rows):
        print(line)
    print(f"report      {Path(args.out).resolve() / 'report.html'}")
    if args.figure:
        teaser(rows, Path(args.out), Path(args.figure))
        print(f"figure      {args.figure}")
    return 0 if all(r["status"] == "ok" for r in rows) else 1


def _check(args) -> int:
    cases = load_thresholds(args.thresholds)
    if args.case:
        unknown = set(args.case) - {c.name for c in cases}
        if unknown:
            known = ", ".join(c.name for c in cases)
            raise InputError(args.thresholds, f"no case named {', '.join(sorted(unknown))}; known: {known}")
        cases = [c for c in cases if c.name in args.case]
    if args.calibrate:
        lo, _, hi = args.calibrate.partition("-")
        seeds = list(range(int(lo), int(hi or lo) + 1))
        print(f"{'case':40}{'mean':>12}{'std':>12}{'min':>12}{'max':>12}  per seed")
        for case in cases:
            c = calibrate(case, seeds, Path(args.out) / "calibration")
            print(
                f"{case.name:40}{c['mean']:12.6g}{c['std']:12.4g}{c['min']:12.6g}{c['max']:12.6g}  "
                + ", ".join(f"{v:.6g}" for v in c["values"]),
                flush=True,
            )
        return 0
    outcomes = []
    print(f"{'case':40}{'result':>8}  value against threshold")
    for case in cases:
        o = evaluate(case, args.out)
        outcomes.append(o)
        print(
            f"{case.name:40}{'pass' if o.passed else 'FAIL':>8}  {o.message}"
            + ("" if o.passed else f" (see {o.folder})"),
            flush=True,
        )
    junit_xml(outcomes, args.junit or Path(args.out) / "junit.xml")
    failed = sum(not o.passed for o in outcomes)
    print(
        f"check       {len(outcomes) - failed} of {len(outcomes)} cases pass; "
        f"JUnit XML in {args.junit or Path(args.out) / 'junit.xml'}"
    )
    return 1 if failed else 0


def parse_bytes(text: str) -> int:
    """A byte count: a plain integer or one with a unit (KiB, MiB, GiB, kB, MB, GB)."""
    units = {"kib": 2**10, "mib": 2**20, "gib": 2**30, "kb": 10**3, "mb": 10**6, "gb": 10**9, "b": 1}
    t = text.strip().lower()
    for unit, size in units.items():
        if t.endswith(unit):
            number, scale = t[: -len(unit)], size
            break
    else:
        number, scale = t, 1
    try:
        value = float(number) * scale
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a byte count (e.g. 1073741824, 512MiB, 1GiB)") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"'{text}' must be positive")
    return int(value)


# Settings whose flag is not named after them (the setting says what it keeps, the flag what it changes).
FLAG_NAMES = {"rotate_directions": "--fixed-directions", "light_visibility": "--shadow-maps"}
FLAG_HELP = {
    "rotate_directions": "every frame along frame 0's directions: a static scene builds its bundles once "
    "(faster, correlated)"
}
FLAG_TYPES = {"node_budget": parse_bytes}
# `evalkit render`'s flags: every RenderSettings field (the units' names aside: --method, --strategy
# and --shadow-maps offer the registered ones) and every registered unit's settings.
RENDER_FLAGS = [(None, f) for f in declared(RenderSettings) if f.name not in KINDS]
# A setting two units declare (the eye and bidirectional strategies' light_samples) is one flag.
UNIT_FLAGS = list({f.name: (unit, f) for unit in all_units() for f in declared(unit.settings)}.values())
# `evalkit bundles`' flags: the list layout and the node budget, and the bundle methods' settings.
BUNDLE_FLAGS = [(None, f) for f in declared(RenderSettings) if f.name in ("directions", "resolution", "node_budget")]
METHOD_FLAGS = [(unit, f) for unit in METHODS for f in declared(unit.settings)]


def add_setting_flags(parser: argparse.ArgumentParser, flags: list) -> None:
    """A flag per declared setting ((unit or None, field) pairs), its help and default from the
    declaration; a flag not given leaves the setting to its default (None)."""
    for unit, f in flags:
        name = FLAG_NAMES.get(f.name, "--" + f.name.replace("_", "-"))
        default = format_bytes(f.default) if f.name in FLAG_TYPES else f.default
        whose = " and ".join(u.name for u in owners(f.name)) if unit else ""
        text = (f"{whose}: " if unit else "") + FLAG_HELP.get(f.name, f.metadata["help"])
        text += "" if f.default is None or f.name in FLAG_HELP else f" (default {default})"
        if f.type == "bool":
            if f.default and f.name not in FLAG_NAMES:  # a flag that turns off what is on by default
                name = "--no-" + f.name.replace("_", "-")
                text = (f"{whose}: " if unit else "") + f"turn off: {f.metadata['help']} (on by default)"
            parser.add_argument(name, dest=f.name, action="store_const", const=not f.default, default=None, help=text)
        else:
            kind = FLAG_TYPES.get(f.name) or _setting_type(f)
            metavar = "BYTES" if f.name in FLAG_TYPES else f.metadata["symbol"]
            choices = f.metadata["choices"]
            parser.add_argument(name, dest=f.name, type=kind, choices=choices, default=None, metavar=metavar, help=text)


def settings_from_args(args, flags: list) -> RenderSettings:
    """The `RenderSettings` of the flags given, over ``--preset``'s values where they apply. A unit's
    setting given for a unit the command does not use is a warning, and left out."""
    names = [f.name for _, f in flags] + list(KINDS)
    explicit = {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}
    preset = PRESETS[args.preset] if getattr(args, "preset", None) else {}
    try:
        resolved = resolve(RenderSettings(**{**preset, **explicit}), inapplicable="drop")
    except ValueError as e:
        raise InputError(f"evalkit {args.command}", str(e)) from None
    kept = {n for n, _ in resolved.settings.options}
    chosen = {unit.kind: unit.name for unit in resolved.units.values()}
    for name in explicit:
        whose = owners(name)
        if whose and name not in kept:
            flag, kind = "--" + name.replace("_", "-"), whose[0].kind
            print(
                f"evalkit: warning: {flag} is a setting of the {' and '.join(u.name for u in whose)} {kind}, "
                f"not of this {args.command}'s {chosen[kind]} {kind}: it is ignored",
                file=sys.stderr,
            )
    return resolved.settings


def _number(kind: str, minimum: float | None = None, positive: bool = False, finite: bool = True):
    """An argparse type: an int or a float (``kind``) in a range, checked as the command line is read."""

    def parse(text: str):
        try:
            value = int(text) if kind == "int" else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"'{text}' is not {'an integer' if kind == 'int' else 'a number'}"
            ) from None
        if positive and not (value > 0 and math.isfinite(value)):
            raise argparse.ArgumentTypeError(f"{value} must be positive and finite")
        if minimum is not None and not value >= minimum:
            raise argparse.ArgumentTypeError(f"{value} must be at least {minimum}")
        if finite and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{value} must be finite")
        return value

    return parse


def _setting_type(f):
    """The argparse type of a declared setting: its number type and its declared range."""
    kind, m = f.type.split(" ")[0], f.metadata
    return _number(kind, m["minimum"], m["positive"], m["finite"]) if kind in ("int", "float") else str


_positive_int, _non_negative_int, _positive_float = (
    _number("int", 1),
    _number("int", 0),
    _number("float", positive=True),
)


def _pin(value: str) -> tuple[str, int | float]:
    """evalkit tune's --pin: SETTING=VALUE, the value a number."""
    name, _, number = value.partition("=")
    try:
        parsed = float(number)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not SETTING=NUMBER") from None
    if not name or not math.isfinite(parsed):
        raise argparse.ArgumentTypeError(f"{value!r} is not SETTING=NUMBER")
    return name, int(parsed) if parsed.is_integer() else parsed


def _spp_or_tune(value: str) -> int | None:
    """evalkit tune's --spp: eye paths per pixel per frame, or "tune" (None: the tuner chooses)."""
    if value == "tune":
        return None
    try:
        return _positive_int(value)
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"{e}, or tune") from None


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, as every other bad input's (exit 2)."""

    def error(self, message: str):
        self.exit(2, f"evalkit: error: {self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="evalkit", description=__doc__.splitlines()[0])
    parser.add_argument("--verbose", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "doctor", help="check GL (EGL), Mitsuba (+LLVM) and Embree; exit 1 with fixes if one is unusable"
    )
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_doctor)

    scene = sub.add_parser("scene", help="scene commands").add_subparsers(dest="scene_command", required=True)
    p = scene.add_parser(
        "info", help="triangles, bounds, materials, lights, features, warnings and the bundle resolution R it needs"
    )
    p.add_argument(
        "scene",
        help="a built-in name (" + ", ".join(builtin_names()) + ") or a .xml/.obj/.ply/.gltf/.glb path",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the eye vertices and directions that probe R")
    p.add_argument(
        "--bounces",
        type=int,
        default=1,
        help="the bounce count the advised R is for: every bounce looks up bundles once more (default 1)",
    )
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_scene_info)
    p = scene.add_parser(
        "check",
        help="render a Mitsuba XML file (or an OBJ or PLY file's geometry) and the toolkit's import of it with "
        "Mitsuba and compare them: the image mean per channel with its 95 %% interval, relMSE, the z-test, the "
        "camera; exit 1 unless it passes",
    )
    p.add_argument("scene", help="a Mitsuba .xml file, or an .obj or .ply file")
    p.add_argument("--bounces", type=int, default=1)
    p.add_argument("--spp", type=int, default=64, help="samples per pixel of each render")
    p.add_argument("--chunks", type=int, default=8, help="chunks the spp are rendered in (the noise comes from them)")
    p.add_argument("--width", type=int, default=DEFAULT_WIDTH, help="the film's width (the camera's aspect kept)")
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tolerance", type=float, default=TOLERANCE, help="of the total image's mean, per channel")
    p.add_argument(
        "--render",
        choices=METHODS.names,
        help="also render the import with these bundles and compare it with Mitsuba's render of the file",
    )
    p.add_argument("--directions", type=int, default=64, help="K of --render")
    p.add_argument("--resolution", type=int, default=128, help="R of --render")
    p.add_argument("--frames", type=int, default=32, help="frames of --render")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_scene_check)

    p = sub.add_parser(
        "bundles",
        help="build ray bundles on the GPU (a registered bundle method), or exact ones with Embree, and save a "
        "BundleSet .npz",
    )
    p.add_argument("scene", help="a built-in name or a scene file")
    p.add_argument("--method", choices=(*METHODS.names, "exact"), required=True)
    add_setting_flags(p, BUNDLE_FLAGS + METHOD_FLAGS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frame", type=int, default=0, help="frame index: a new rotation (and jitter) of the direction set")
    p.add_argument("--no-jitter", action="store_true", help="no sub-pixel jitter of the bundle grids")
    p.add_argument("--threads", type=_positive_int, default=None, help="exact: Embree threads (default: every core)")
    p.add_argument("--out", required=True, metavar="FILE.npz")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_bundles)

    p = sub.add_parser(
        "compare-bundles",
        help="hole, spurious and redundant rates and depth error of a BundleSet against the exact one",
    )
    p.add_argument("test", metavar="TEST.npz")
    p.add_argument("exact", metavar="EXACT.npz")
    p.add_argument(
        "--scene",
        help="the scene the bundles were built from (default: the one TEST.npz records), whose surfaces "
        "tell a splat's leaks from its offsets",
    )
    p.add_argument(
        "--depth-tolerance",
        type=_positive_float,
        default=DEPTH_TOLERANCE,
        metavar="T",
        help=f"nodes within T x the frame radius are the same surface (default {DEPTH_TOLERANCE:g})",
    )
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_compare_bundles)

    p = sub.add_parser(
        "render", help="render direct, indirect and total images with paths over ray bundles (the registered units)"
    )
    p.add_argument("scene", help="a built-in name or a scene file")
    for field, registry in KINDS.items():
        name = FLAG_NAMES.get(field, "--" + field.replace("_", "-"))
        what = f"the {registry.kind}" + (f" (default {registry.default.name})" if field != "method" else "")
        p.add_argument(name, dest=field, choices=registry.names, required=field == "method", default=None, help=what)
    add_setting_flags(p, RENDER_FLAGS + UNIT_FLAGS)
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default=None,
        help="paper: the poster's 1920x1024, 2x2 supersampling, K=256, R=128, N=16384 (explicit options override it)",
    )
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_render)

    p = sub.add_parser(
        "compare",
        help="MSE, relMSE, SMAPE, FLIP and Delta E 2000 of a test image against a reference, with error maps; "
        "several test images (renders of one setting under different seeds) are pooled into one",
    )
    p.add_argument("test", metavar="TEST.exr", nargs="+")
    p.add_argument("ref", metavar="REF.exr")
    p.add_argument("--metrics", nargs="+", choices=METRICS, default=list(METRICS))
    p.add_argument(
        "--relmse-eps", type=_positive_float, default=RELMSE_EPSILON, help=f"relMSE epsilon (default {RELMSE_EPSILON})"
    )
    p.add_argument(
        "--smape-eps", type=_positive_float, default=SMAPE_EPSILON, help=f"SMAPE epsilon (default {SMAPE_EPSILON})"
    )
    p.add_argument(
        "--flip-ppd", type=_positive_float, default=FLIP_PPD, help=f"FLIP pixels per degree (default {FLIP_PPD:g})"
    )
    p.add_argument(
        "--exposure",
        type=float,
        default=DELTA_E_EXPOSURE,
        help="Delta E 2000: exposure (stops) before clipping to the display",
    )
    p.add_argument("--maps", metavar="DIR", help="write each metric's per-pixel map as DIR/<metric>.exr and .png")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_compare)

    p = sub.add_parser("view", help="an EXR as an sRGB PNG at an exposure, with its per-channel statistics")
    p.add_argument("image", metavar="IMAGE.exr")
    p.add_argument("--png", required=True, metavar="OUT.png")
    p.add_argument(
        "--exposure", type=float, default=REPORT_EXPOSURE, help=f"stops (default {REPORT_EXPOSURE:g}, as reports)"
    )
    p.set_defaults(run=_view)

    p = sub.add_parser(
        "study", help="run a study (a TOML grid of runs): results table, plots and an HTML report; resumable"
    )
    p.add_argument("study", metavar="STUDY.toml")
    p.add_argument("--out", metavar="DIR", help="default: out/studies/<name>")
    p.add_argument(
        "--workers",
        type=_positive_int,
        default=1,
        help="runs at once (default 1: GL on llvmpipe already uses every core)",
    )
    p.add_argument(
        "--executor",
        choices=("local", "dask"),
        default="local",
        help="local processes, or Dask (a LocalCluster of --workers, or --scheduler)",
    )
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask: an existing scheduler, e.g. tcp://host:8786")
    p.add_argument("--wait", action="store_true", help="wait for another study writing to --out, rather than refuse")
    p.add_argument(
        "--record", metavar="JSON", help="also save the rows with the command and versions there (docs/results/data/)"
    )
    p.set_defaults(run=_study)

    p = sub.add_parser(
        "check", help="run declared accuracy cases against their thresholds: table, JUnit XML, exit 1 on any regression"
    )
    p.add_argument(
        "thresholds",
        nargs="?",
        default=str(DEFAULT_THRESHOLDS),
        metavar="THRESHOLDS.toml",
        help="default: the toolkit's own (evalkit/thresholds.toml)",
    )
    p.add_argument("--case", nargs="+", metavar="NAME", help="only these cases")
    p.add_argument(
        "--out",
        default="out/check",
        metavar="DIR",
        help="runs, and on failure images, references and error maps (default out/check)",
    )
    p.add_argument("--junit", metavar="FILE", help="JUnit XML (default DIR/junit.xml)")
    p.add_argument(
        "--calibrate", metavar="SEEDS", help="instead: run each case over seeds, e.g. 0-4, and print the spread"
    )
    p.set_defaults(run=_check)

    p = sub.add_parser(
        "tune",
        help="the settings with the least predicted error within a time budget, from fitted time and error models, "
        "checked by a render",
    )
    p.add_argument("scene", help="a built-in name or a scene file")
    p.add_argument(
        "--budget",
        type=float,
        required=True,
        metavar="SECONDS",
        help="render time (every frame, after shader compilation)",
    )
    p.add_argument("--method", default="both", metavar="|".join((*METHODS.names, "both")), help="default both")
    for field in ("strategy", "light_visibility"):
        registry = KINDS[field]
        p.add_argument(
            FLAG_NAMES.get(field, f"--{field}"),
            dest=field,
            metavar="|".join((*registry.names, "both")),
            help=f"default {registry.default.name}; both: the measurement chooses",
        )
    p.add_argument(
        "--metric",
        default="indirect_relmse",
        metavar="IMAGE_METRIC",
        help="what to minimise against the Mitsuba reference, e.g. indirect_relmse (default), total_relmse, total_flip",
    )
    p.add_argument("--width", type=_positive_int, default=128)
    p.add_argument("--height", type=_positive_int, default=128)
    p.add_argument("--bounces", type=_positive_int, default=3)
    p.add_argument(
        "--spp",
        type=_spp_or_tune,
        default=16,
        metavar="S|tune",
        help="eye paths per pixel per frame (default 16; tune: tuned as well, from 1 to 128)",
    )
    p.add_argument("--reference-spp", type=_positive_int, default=16384, help="the Mitsuba reference's (default 16384)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--calibration-share",
        type=_positive_float,
        default=CALIBRATION_SHARE,
        metavar="X",
        help=f"the calibration's render time in budgets (default {CALIBRATION_SHARE:g}; "
        "each run renders at least one frame)",
    )
    p.add_argument(
        "--pin",
        type=_pin,
        action="append",
        metavar="SETTING=VALUE",
        help="keep a setting the tuner would choose at this value, by name or symbol (M=256, directions=32); "
        "repeatable",
    )
    p.add_argument("--no-check", action="store_true", help="recommend without rendering the recommendation")
    p.add_argument(
        "--grid",
        metavar="DIR",
        help="a grid study's folder (studies/tune_check.toml): compare with its best run within the budget",
    )
    p.add_argument("--out", metavar="DIR", help="default: out/tune/<scene>")
    p.add_argument(
        "--json", action="store_true", help="print one JSON object: recommended, predicted, measured, models"
    )
    p.set_defaults(run=_tune)

    p = sub.add_parser(
        "demo",
        help="the main job: the bundle methods on cornell-box against Mitsuba and Embree, every metric, a report",
    )
    p.add_argument("--out", default="out/demo", metavar="DIR", help="default: out/demo")
    p.add_argument(
        "--figure", metavar="PNG", help="also draw the README's picture there (make teaser: docs/images/teaser.png)"
    )
    p.set_defaults(run=_demo)

    p = sub.add_parser(
        "reference",
        help="Mitsuba 3 path-traced direct, indirect and total images with variances (stored, reused, resumable)",
    )
    p.add_argument("scene", help="a built-in name or a scene file")
    p.add_argument("--bounces", type=int, default=1, metavar="B", help="indirect bounces (default 1)")
    p.add_argument("--spp", type=_positive_int, default=1024, help="samples per pixel (default 1024)")
    p.add_argument("--width", type=_positive_int, default=None, help="default: the scene camera's")
    p.add_argument("--height", type=_positive_int, default=None, help="default: the scene camera's")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--time", type=float, default=0.0, help="animated scenes: the time (s) to pose the scene at (default 0)"
    )
    p.add_argument(
        "--chunks",
        type=_positive_int,
        default=None,
        help="spp chunks (progress, resume, variance; default min(32, spp))",
    )
    p.add_argument(
        "--variant",
        default=None,
        help="Mitsuba variant (default: cuda_ad_rgb with a GPU, else llvm_ad_rgb, else scalar_rgb)",
    )
    p.add_argument(
        "--store",
        default=None,
        help=f"reference store (default: the committed CI store where it has the reference, else ${STORE_VARIABLE}, "
        "else the user cache's references/: $EVALKIT_CACHE, else $XDG_CACHE_HOME/evalkit, else ~/.cache/evalkit)",
    )
    p.add_argument(
        "--wait", action="store_true", help="wait for another process rendering this reference, then reuse it"
    )
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_reference)
    return parser


# Each command's output arguments: (argument, is a folder).
OUTPUTS = {
    _bundles: [("out", False)],
    _render: [("out", True)],
    _compare: [("maps", True)],
    _study: [("out", True), ("record", False)],
    _check: [("out", True), ("junit", False)],
    _tune: [("out", True)],
    _demo: [("out", True)],
    _reference: [("out", True)],
    _view: [("png", False)],
}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        # Every output path is checked before anything is loaded or rendered.
        for name, folder in OUTPUTS.get(args.run, ()):
            if getattr(args, name, None):
                check_output(getattr(args, name), folder)
        return args.run(args)
    except InputError as e:
        if args.verbose:
            traceback.print_exc()
        print(f"evalkit: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader stopped early (`evalkit scene info X | head`): nothing is wrong. Python would
        # flush stdout once more at exit and print that failure too, so stdout goes to devnull.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + int(signal.SIGPIPE)
    except OSError as e:  # the machine, not the input: a full disk, a read-only or vanished folder
        if args.verbose:
            traceback.print_exc()
        print(f"evalkit: error: {e.filename or 'evalkit'}: {e.strerror or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("evalkit: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
