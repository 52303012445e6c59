"""Pictures of images and errors for people to look at: tonemapped 8-bit sRGB PNGs and per-pixel
error maps in magma. The report, `evalkit check` and `evalkit compare --maps` all draw them here."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPORT_EXPOSURE = 0.0


def pyplot():
    """matplotlib.pyplot on the Agg backend (files, no display), imported at first use: it is slow
    to import, and most commands draw nothing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def tonemap(image: np.ndarray, exposure: float = REPORT_EXPOSURE) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB: scale by 2^exposure, clip to [0, 1], the sRGB curve."""
    x = np.clip(image * 2.0**exposure, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (srgb * 255 + 0.5).astype(np.uint8)


def save_png(rgb8: np.ndarray, path: Path) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb8).save(path)


def error_map_png(values: np.ndarray, path: Path, vmax: float | None = None) -> float:
    """A per-pixel error map in magma, 0 .. vmax (default: its 99th percentile); returns vmax."""
    import matplotlib

    vmax = float(vmax if vmax is not None else max(np.quantile(values, 0.99), 1e-12))
    rgba = matplotlib.colormaps["magma"](np.clip(values / vmax, 0, 1))
    save_png((rgba[..., :3] * 255 + 0.5).astype(np.uint8), path)
    return vmax
