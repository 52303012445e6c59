"""Pictures of images and errors for people to look at: tonemapped 8-bit sRGB PNGs (the tonemap is
evalkit.core.display's) and per-pixel error maps in magma. `evalkit view`, `evalkit check` and
`evalkit compare --maps` draw them here."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evalkit.core.atomic import atomic_path

REPORT_EXPOSURE = 0.0


def pyplot():
    """matplotlib.pyplot on the Agg backend (files, no display), imported at first use: it is slow
    to import, and most commands draw nothing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(rgb8: np.ndarray, path: Path) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Image.fromarray(rgb8).save(tmp)


def save_figure(fig, path: Path, dpi: int = 90) -> None:
    """A matplotlib figure as a PNG, whole or not at all."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)


def error_map_vmax(values: np.ndarray) -> float:
    """The top of an error map's colour scale: its 99th percentile (a few hot pixels would leave
    the rest of the map black)."""
    return float(max(np.quantile(values, 0.99), 1e-12))


def error_map_png(values: np.ndarray, path: Path, vmax: float | None = None) -> float:
    """A per-pixel error map in magma, 0 .. vmax (default `error_map_vmax`); returns vmax."""
    import matplotlib

    vmax = float(vmax if vmax is not None else error_map_vmax(values))
    rgba = matplotlib.colormaps["magma"](np.clip(values / vmax, 0, 1))
    save_png((rgba[..., :3] * 255 + 0.5).astype(np.uint8), path)
    return vmax
