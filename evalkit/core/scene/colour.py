"""Colour and texture helpers of the scene model: rgb triples, the sRGB transfer function, and
texture lookups as Mitsuba makes them."""

from __future__ import annotations

import numpy as np

from evalkit.core.scene.model import RGB


def rgb(value) -> RGB:
    """Any scalar or 3-vector as an rgb tuple of floats."""
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3:
        raise ValueError(f"expected a scalar or an rgb triple, got {a.size} values")
    return (float(a[0]), float(a[1]), float(a[2]))


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted: 8-bit texture values (scaled to [0, 1]) to linear."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with repeat wrapping at uv (N, 2), Mitsuba's convention: texel (row, col)
    has its centre at ((row + 0.5) / H, (col + 0.5) / W) in (v, u). Returns (N, 3) float64."""
    h, w = texture.shape[:2]
    x = np.asarray(uv[:, 0], dtype=np.float64) * w - 0.5
    y = np.asarray(uv[:, 1], dtype=np.float64) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    t = texture.astype(np.float64)

    def at(yy, xx):
        return t[np.mod(yy, h), np.mod(xx, w)]

    return (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1)) + fy * (
        (1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1)
    )
