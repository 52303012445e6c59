"""What the user cache knows of a scene, brought to its renders: the bundle resolution R that
`evalkit scene info` advised (`cached_resolution_advice`) and the import check of `evalkit scene
check` (`evalkit.fidelity`). `render` is `gpu_impl.api.render` with both applied
(`known_to_the_cache`); `evalkit.render` and `evalkit render` are this one."""

from __future__ import annotations

from pathlib import Path

from evalkit.core import cache
from evalkit.core.scene import Scene, load_scene
from evalkit.fidelity import fidelity_of, summary_line
from evalkit.metrics.bundles import resolution_advice
from gpu_impl import api
from references.embree import ExactTracer

# The code the advice comes from: a change to it makes the cached advice stale.
ADVICE_SOURCES = [
    Path(__file__).parent / "metrics" / "bundles.py",
    Path(__file__).parent.parent / "references" / "embree.py",
]


def cached_resolution_advice(scene: Scene, seed: int = 0, probe: bool = True, bounces: int = 1) -> dict | None:
    """`resolution_advice` for ``scene`` at ``bounces``, from the user cache where it is; else
    probed and cached (``probe``) or None. A probe builds the scene's exact tracer and its
    triangles' neighbours, which grow with the scene (benchmarks/resolution_probe.py times it): it
    is kept by the scene's content, the bounce count and the code that makes the advice."""
    key = f"advice-{scene.content_hash()}-B{bounces}-seed{seed}-{cache.code_hash(*ADVICE_SOURCES)}"
    advice = cache.load("facts", key)
    if advice is None and probe:
        advice = resolution_advice(scene, ExactTracer(scene), bounces=bounces, seed=seed)
        cache.store("facts", key, advice)
    return advice


def advised(advice: dict) -> str:
    """The advice in a few words: the least R, or that none probed was enough."""
    recommended = advice["recommended"]
    return f"R >= {recommended}" if recommended else f"more than R={max(advice['wrong_lookups_per_path'])}"


def below_advice(scene: Scene, resolution: int, bounces: int) -> str | None:
    """A warning when ``resolution`` is under the R that `evalkit scene info` advised for ``scene``
    (its default seed's advice, when cached: a render does not wait for the probe). The advice for
    the render's own bounce count where it is cached, else for fewer bounces: more bounces never
    need a coarser R, so a render under that advice is under its own."""
    for b in range(bounces, 0, -1):
        advice = cached_resolution_advice(scene, probe=False, bounces=b)
        if advice is not None:
            break
    else:
        return None
    if advice["recommended"] is not None and resolution >= advice["recommended"]:
        return None
    rate = advice["wrong_lookups_per_path"].get(resolution)
    return (
        f"R={resolution} is under what `evalkit scene info --bounces {b}` advises for {scene.name}, {advised(advice)}"
        + (f" (wrong next hits per path: {100 * rate:.1f} % at R={resolution})" if rate is not None else "")
        + ': paths pass surfaces the rays meet, a bias no frame count removes (docs/reference/metrics.md, "Choosing R")'
    )


def known_to_the_cache(scene: Scene, result) -> None:
    """Adds to a render's ``result`` what the cache knows of ``scene``: a warning where its R is
    under the advice, and the import check's figures in its statistics (timings.json) with a
    warning where the check failed."""
    below = below_advice(scene, result.params["resolution"], result.params["bounces"])
    if below:
        result.warnings.append(below)
    fidelity = fidelity_of(scene)
    if fidelity is None:
        return
    result.stats["import_fidelity"] = {
        k: fidelity.get(k) for k in ("passed", "verdict", "tolerance", "settings", "mitsuba", "evalkit")
    } | {"total": fidelity["images"]["total"]}
    if not fidelity["passed"]:
        result.warnings.append(summary_line(fidelity))


def render(scene, settings=None, gl=None, progress=None):
    """`gpu_impl.api.render` (the same arguments), with what the user cache knows of the scene
    (`known_to_the_cache`)."""
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    result = api.render(scene, settings, gl=gl, progress=progress)
    known_to_the_cache(scene, result)
    return result
