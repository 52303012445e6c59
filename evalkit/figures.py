"""Pictures of images and errors for people to look at: tonemapped 8-bit sRGB PNGs (the tonemap is
evalkit.core.display's) and per-pixel error maps in magma. `evalkit view`, `evalkit check` and
`evalkit compare --maps` draw them here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evalkit.core.atomic import atomic_path
from evalkit.core.display import tonemap
from evalkit.core.exr import read_exr

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


def teaser(rows: list[dict], out: Path, path: Path) -> None:
    """The README's picture, from a finished `evalkit demo` in ``out`` (its ``rows``): each bundle
    method's total image, Mitsuba's reference and the last method's HDR-FLIP map against it, each
    titled with the figures its row holds (FLIP, relMSE)."""
    runs = [r for r in rows if r.get("status") == "ok"]
    panels = [
        (read_exr(Path(out) / "runs" / r["run_id"] / "total.exr")[0], f"{r['method']} bundles\n"
         f"FLIP {r['total_flip']:.3f}, relMSE {r['total_relmse']:.4f}")
        for r in runs
    ]  # fmt: skip
    first, last = runs[0], runs[-1]
    spp = json.loads((Path(first["reference"]) / "manifest.json").read_text())["spp"]
    panels.append((read_exr(Path(first["reference"]) / "total.exr")[0], f"Mitsuba 3\n{spp} spp path tracer"))
    flip = np.load(Path(out) / "runs" / last["run_id"] / "total_flip_map.npy")
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels) + 1, figsize=(2.6 * (len(panels) + 1), 3.0))
    for ax, (image, title) in zip(axes, panels):
        ax.imshow(tonemap(image, REPORT_EXPOSURE))
        ax.set_title(title, fontsize=9)
    axes[-1].imshow(flip, cmap="magma", vmin=0.0, vmax=1.0)
    axes[-1].set_title(f"HDR-FLIP, {last['method']} vs Mitsuba\n0 (black) to 1", fontsize=9)
    for ax in axes:
        ax.set_axis_off()
    fig.suptitle(
        f"{first['scene']}, {first['bounces']} bounces, K={first['directions']}, R={first['resolution']}, "
        f"{first['frames']} frames (made by `evalkit demo --figure`)",
        fontsize=9,
    )
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.92))
    save_figure(fig, Path(path), dpi=100)
    plt.close(fig)
