"""evalkit: the toolkit users call for ray-bundle global illumination.

In Python, one call per job::

    import evalkit
    result = evalkit.render("cornell-box", evalkit.RenderSettings(method="imperfect", frames=8))
    bundles = evalkit.trace_bundles("cornell-box", evalkit.DirectionSet.make(32, seed=0))

Scene model and importers (`evalkit.core.scene`), settings (`evalkit.core.settings`), diagnostics
(`evalkit.doctor`) and the command line (`evalkit.cli`). Importing this package is cheap: Mitsuba,
trimesh and OpenGL are loaded only by the functions that need them.
"""

from evalkit.core import VERSION

__version__ = VERSION

# What `import evalkit` offers, and the module each comes from (loaded at first use).
_EXPORTS = {
    "render": "evalkit.advice",
    "trace_bundles": "gpu_impl.api",
    "RenderSettings": "evalkit.core.settings",
    "load_scene": "evalkit.core.scene",
    "DirectionSet": "evalkit.core.bundleset",
    "reference": "references.mitsuba",
    "compare_images": "evalkit.metrics.images",
    "mean_ratio": "evalkit.metrics.confidence",
    "render_ratio": "evalkit.metrics.confidence",
    "check_scene": "evalkit.fidelity",
}


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'evalkit' has no attribute {name!r}")
    import importlib  # deferred: the GL and Mitsuba stacks load only when asked for

    return getattr(importlib.import_module(_EXPORTS[name]), name)
