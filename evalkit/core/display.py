"""How results show themselves to a person: linear RGB tonemapped to 8-bit sRGB (the reports' and
`evalkit view`'s pictures, evalkit/figures.py), and the small HTML pieces notebooks show for
`RenderResult`, `BundleSet`, a bundle comparison and a study's rows (their ``_repr_html_``)."""

from __future__ import annotations

import base64
import html
import io

import numpy as np


def tonemap(image: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB: scale by 2^exposure, clip to [0, 1], the sRGB curve (NaN black)."""
    x = np.clip(np.nan_to_num(image * 2.0**exposure, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (srgb * 255 + 0.5).astype(np.uint8)


def image_html(image: np.ndarray, caption: str, exposure: float = 0.0, width: int = 192) -> str:
    """A linear RGB image tonemapped into an inline PNG, with its caption."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(tonemap(image, exposure)).save(buffer, format="png")
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return (
        f"<figure style='display:inline-block;margin:4px'><img width='{width}' style='image-rendering:pixelated' "
        f"src='data:image/png;base64,{data}'><figcaption style='font-size:11px'>{html.escape(caption)}</figcaption>"
        "</figure>"
    )


def fields_html(title: str, fields: dict) -> str:
    """A titled two-column table of names and values."""
    rows = "".join(
        f"<tr><th style='text-align:left'>{html.escape(str(k))}</th><td style='text-align:left'>"
        f"{html.escape(_text(v))}</td></tr>"
        for k, v in fields.items()
    )
    return f"<div><b>{html.escape(title)}</b><table>{rows}</table></div>"


def bars_html(title: str, labels: list[str], counts: list[int], width: int = 240) -> str:
    """A horizontal bar chart as a table (a histogram a notebook shows without a plot library)."""
    top = max(max(counts, default=0), 1)
    rows = "".join(
        f"<tr><td style='text-align:right'>{html.escape(label)}</td><td style='text-align:left'>"
        f"<div style='background:#47a;height:10px;width:{max(1, round(width * c / top)) if c else 0}px;"
        f"display:inline-block'></div> {c:,}</td></tr>"
        for label, c in zip(labels, counts)
    )
    return f"<div><b>{html.escape(title)}</b><table>{rows}</table></div>"


def _text(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, tuple | list | np.ndarray) and len(value) <= 4:
        return "(" + ", ".join(_text(v) for v in value) + ")"
    return str(value)
