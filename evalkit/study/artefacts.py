"""What the runs of a study share, made once: Mitsuba references and Embree exact bundles (and the
Embree scene that traces them). The process's GL context is `gpu_impl.context.default_context`.

`prepare_artefacts` makes the references and exact bundles before any run starts (and before any
worker process does), so parallel runs never render the same reference twice.
"""

from __future__ import annotations

from pathlib import Path

from evalkit.core.bundleset import BundleSet, DirectionSet
from evalkit.core.scene import Scene, load_scene
from references.embree import ExactTracer
from references.mitsuba import COMMITTED_STORE, Reference, load_reference, reference, store_entry


def film_size(scene: Scene, run: dict) -> tuple[int, int]:
    """The run's image size: its width and height, or the scene camera's where it leaves them out."""
    return scene.camera.film_size(run["width"], run["height"])


def prepare_artefacts(runs: list[dict], measure: dict, out: Path, progress=print) -> None:
    """The Mitsuba references and exact bundles that ``runs`` need, each made once."""
    scenes, made = {}, set()
    for run in runs:
        scene = scenes.setdefault(run["scene"], load_scene(run["scene"]))
        ref_key = ("reference", run["scene"], run["bounces"], film_size(scene, run))
        if measure["images"] and ref_key not in made:
            made.add(ref_key)
            reference_for(scene, run, measure, out, progress)
        exact_key = ("exact", run["scene"], run["directions"], run["resolution"], run["seed"])
        if measure["bundles"] and run["method"] != "mitsuba" and exact_key not in made:
            made.add(exact_key)
            exact_bundles(scene, run, out)


def reference_for(scene: Scene, run: dict, measure: dict, out: Path, progress=print) -> Reference:
    """The committed reference when the store has it, else one rendered into ``reference_store`` of
    ``measure`` (default: the study folder's references/), or found there from an earlier run."""
    width, height = film_size(scene, run)
    args = dict(
        bounces=int(run["bounces"]),
        spp=int(measure["reference_spp"]),
        width=width,
        height=height,
        seed=int(measure["reference_seed"]),
    )
    committed = store_entry(scene.name, scene.content_hash(), store=COMMITTED_STORE, **args)
    if (committed / "manifest.json").is_file():
        return load_reference(committed)
    store = Path(measure["reference_store"]) if measure["reference_store"] else out / "references"
    # A run needing a reference another run (or study) is rendering waits for it, then reuses it.
    return reference(
        scene, **args, store=store, wait=True, progress=lambda line: progress(f"reference {scene.name}: {line}")
    )


def exact_bundles(scene: Scene, run: dict, out: Path) -> BundleSet:
    """Embree's exact bundles on the run's lines (frame 0 of its seed), cached in the study folder."""
    path = (
        out / "cache" / f"exact-{scene.name}-{scene.content_hash()[:12]}"
        f"-K{run['directions']}-R{run['resolution']}-seed{run['seed']}.npz"
    )
    directions = DirectionSet.make(int(run["directions"]), seed=int(run["seed"]))
    if path.is_file():
        cached = BundleSet.load(path)
        # A cache made before the direction generator changed holds other lines: made again.
        if cached.directions.same_as(directions):
            return cached
    path.parent.mkdir(parents=True, exist_ok=True)
    bundles = exact_tracer(scene).bundles(directions, int(run["resolution"]))
    bundles.save(path)  # whole or not at all
    return bundles


_TRACERS: dict[str, ExactTracer] = {}


def exact_tracer(scene: Scene) -> ExactTracer:
    """One Embree scene per scene and process: its BVH is built once, not once per run."""
    key = scene.content_hash()
    if key not in _TRACERS:
        _TRACERS[key] = ExactTracer(scene)
    return _TRACERS[key]
