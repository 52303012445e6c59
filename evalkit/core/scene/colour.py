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


def rounded(c) -> tuple:
    """A colour's channels to 4 decimals, as warnings print them."""
    return tuple(round(float(x), 4) for x in c)


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted: 8-bit texture values (scaled to [0, 1]) to linear."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def wrap_texel(i: np.ndarray, n: int, wrap_mode: str) -> np.ndarray:
    """Texel indices ``i`` (any integers, negative too) wrapped into [0, n) as Mitsuba's bitmap
    texture wraps them: ``repeat`` (period n), ``mirror`` (period 2n, the second half reversed) or
    ``clamp``."""
    if wrap_mode == "clamp":
        return np.clip(i, 0, n - 1)
    period = 2 * n if wrap_mode == "mirror" else n
    m = np.mod(i, period)
    return np.where(m < n, m, period - 1 - m)


def texture_uv(uv: np.ndarray, to_uv: np.ndarray | None) -> np.ndarray:
    """The mesh's uv (N, 2) carried into texture space by the 3x3 affine ``to_uv`` (None: identity)."""
    uv = np.asarray(uv, dtype=np.float64)
    if to_uv is None:
        return uv
    return uv @ to_uv[:2, :2].T + to_uv[:2, 2]


def sample_texture(
    texture: np.ndarray,
    uv: np.ndarray,
    to_uv: np.ndarray | None = None,
    wrap_mode: str = "repeat",
    filter_type: str = "bilinear",
) -> np.ndarray:
    """The texture at the mesh's uv (N, 2) as Mitsuba's bitmap texture looks it up: uv through
    ``to_uv``, then texel (row, col) centred at ((row + 0.5) / H, (col + 0.5) / W) in (v, u),
    ``bilinear`` or ``nearest``, wrapped by `wrap_texel`. Returns (N, 3) float64. The shaders'
    `material_albedo` (gpu_impl/shaders/include/scene.glsl) is the same lookup."""
    h, w = texture.shape[:2]
    t = texture.astype(np.float64)
    uv = texture_uv(uv, to_uv)

    def at(yy, xx):
        return t[wrap_texel(yy, h, wrap_mode), wrap_texel(xx, w, wrap_mode)]

    if filter_type == "nearest":
        return at(np.floor(uv[:, 1] * h).astype(np.int64), np.floor(uv[:, 0] * w).astype(np.int64))
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    return (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1)) + fy * (
        (1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1)
    )
