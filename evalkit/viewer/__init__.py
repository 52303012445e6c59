"""The reports' HDR image comparison viewer: `viewer.js` and `viewer.css` in this folder, the
markup of one viewer per group of images (`group_html`), and each image's pixels as half floats in
a small script of its own (`image_data`), which the page loads when the group is first shown.

A group is images of one size compared with each other: a run's test image, its reference and its
error maps. The viewer shows one at a time with shared zoom, pan and exposure, lists every image's
RGB values at the cursor, and draws error maps through a colour map with a colour bar. Pages are
self-contained and work from file:// (scripts, not fetches; nothing from a network). Its keys are
listed at the top of viewer.js and in docs/getting-started.md.
"""

from __future__ import annotations

import base64
import functools
import html
import json
from pathlib import Path

import numpy as np

from evalkit.core.atomic import write_text

ASSETS = Path(__file__).parent
DISPLAY = (512, 384)  # the canvas fits the image into this, in CSS pixels
COLORMAP_STEPS = 64


def head() -> str:
    """The viewer's style and script, inline: what a page with viewers carries in its head."""
    css = (ASSETS / "viewer.css").read_text()
    js = (ASSETS / "viewer.js").read_text()
    return f"<style>{css}</style><script>{js}</script>"


def image_data(folder: Path, name: str, image: np.ndarray, immutable: bool = False) -> str:
    """``image`` (H, W, 3) or (H, W) as half floats in ``folder/viewer/<name>.js``; returns that
    script's path relative to ``folder``. An ``immutable`` image (a finished reference's) that is
    there already is not written again."""
    src = f"viewer/{name}.js"
    path = folder / src
    if not (immutable and path.is_file()):
        image = np.asarray(image, dtype=np.float32)
        if image.ndim == 2:  # a map of one value per pixel: the viewer reads its first channel
            image = np.repeat(image[..., None], 3, axis=2)
        height, width = image.shape[:2]
        half = np.ascontiguousarray(image[..., :3], dtype="<f2")
        payload = base64.b64encode(half.tobytes()).decode("ascii")
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, f"evalkitViewer.loaded({json.dumps(name)}, {width}, {height}, {json.dumps(payload)});\n")
    return src


@functools.lru_cache
def colormap(name: str = "magma") -> list[list[int]]:
    """A matplotlib colour map as COLORMAP_STEPS 8-bit RGB steps (error maps' colours)."""
    from matplotlib import colormaps

    steps = colormaps[name](np.linspace(0.0, 1.0, COLORMAP_STEPS))[:, :3]
    return (np.round(steps * 255)).astype(int).tolist()


def group_html(images: list[dict], size: tuple[int, int], exposure: float = 0.0, caption: str = "") -> str:
    """One viewer over ``images``: dicts of ``name``, ``label`` and ``src`` (from `image_data`),
    and for an error map ``vmax`` (its colour bar's top; the map is drawn in magma). ``size``:
    the images' (width, height)."""
    width, height = size
    scale = min(DISPLAY[0] / width, DISPLAY[1] / height)
    scale = float(np.floor(scale)) if scale >= 1 else scale  # whole pixels where they are enlarged
    magma = colormap()
    entries = []
    for image in images:
        entry = {k: image[k] for k in ("name", "label", "src")}
        if image.get("vmax") is not None:
            entry.update(colormap=magma, vmax=float(image["vmax"]))
        entries.append(entry)
    group = {
        "size": [width, height],
        "display": [max(1, round(width * scale)), max(1, round(height * scale))],
        "exposure": exposure,
        "images": entries,
    }
    label = f"<p class='ek-caption'>{html.escape(caption)}</p>" if caption else ""
    return f"{label}<div class='ek-viewer' data-group='{html.escape(json.dumps(group), quote=True)}'></div>"
