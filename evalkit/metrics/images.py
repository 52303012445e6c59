"""Image metrics of a test image against a reference, and the bias/variance split over seeds.

Every metric returns a `Metric`: its value, its per-pixel map (H, W) and the parameters it used,
so a number is never reported without what made it. Images are linear RGB (H, W, 3), as the
renderer and Mitsuba's rgb variants write them.

- ``mse``: mean of (t - r)^2 over pixels and channels.
- ``relmse``: mean of (t - r)^2 / (r^2 + eps), tev's form; eps (default 0.01) keeps dark pixels
  from dominating.
- ``smape``: mean of |t - r| / (|t| + |r| + eps), tev's form (in [0, 1)).
- ``flip``: HDR-FLIP (Andersson et al. 2021) through `flip-evaluator`, at 67 pixels per degree,
  ACES tone mapping and the exposure range FLIP picks from the reference; undefined (NaN, with
  the reason in its parameters) for a black reference, which leaves that range empty.
- ``delta_e2000``: CIEDE2000 through colour-science, after a stated exposure (2^exposure scale),
  clipping to [0, 1] (the display) and the sRGB primaries' D65 XYZ -> CIELAB.

Maps of the per-channel metrics are their per-pixel means over the three channels.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evalkit.core.errors import InputError

RELMSE_EPSILON = 0.01
SMAPE_EPSILON = 0.01
FLIP_PPD = 67.0
FLIP_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # FLIP's linear RGB to Y
FLIP_BLACK = 2.0 * float(np.finfo(np.float32).eps)
DELTA_E_EXPOSURE = 0.0
METRICS = ("mse", "relmse", "smape", "flip", "delta_e2000")


@dataclass
class Metric:
    name: str
    value: float
    map: np.ndarray
    params: dict = field(default_factory=dict)


def non_finite_pixels(image: np.ndarray) -> str | None:
    """How many pixels of an (H, W, 3) image hold NaN or Inf and where the first is; None if none."""
    bad = ~np.isfinite(image).all(axis=2)
    if not bad.any():
        return None
    y, x = np.argwhere(bad)[0]
    return f"{int(bad.sum())} pixel(s) are NaN or Inf, the first at x={x}, y={y}"


def check_images(test: np.ndarray, ref: np.ndarray, test_name: str = "test", ref_name: str = "reference") -> None:
    """`InputError` naming the image when the two are not comparable: shape, NaN or Inf."""
    for image, name in ((test, test_name), (ref, ref_name)):
        if image.ndim != 3 or image.shape[2] != 3:
            raise InputError(name, f"expected an (H, W, 3) RGB image, got shape {image.shape}")
        bad = non_finite_pixels(image)
        if bad:
            raise InputError(name, bad)
    if test.shape != ref.shape:
        raise InputError(
            test_name, f"is {test.shape[1]}x{test.shape[0]} but {ref_name} is {ref.shape[1]}x{ref.shape[0]}"
        )


def mse(test: np.ndarray, ref: np.ndarray) -> Metric:
    m = ((test - ref) ** 2).mean(axis=2)
    return Metric("mse", float(m.mean()), m)


def relmse(test: np.ndarray, ref: np.ndarray, eps: float = RELMSE_EPSILON) -> Metric:
    m = ((test - ref) ** 2 / (ref**2 + eps)).mean(axis=2)
    return Metric("relmse", float(m.mean()), m, {"epsilon": eps})


def smape(test: np.ndarray, ref: np.ndarray, eps: float = SMAPE_EPSILON) -> Metric:
    m = (np.abs(test - ref) / (np.abs(test) + np.abs(ref) + eps)).mean(axis=2)
    return Metric("smape", float(m.mean()), m, {"epsilon": eps})


def flip(test: np.ndarray, ref: np.ndarray, ppd: float = FLIP_PPD) -> Metric:
    import flip_evaluator

    # FLIP needs non-negative HDR input; the renderer and Mitsuba never write negative radiance,
    # but a difference image (indirect = total - direct) can be -1e-9, which is clamped.
    ref = np.maximum(ref, 0)
    # HDR-FLIP's exposures run from the reference's brightest luminance to its median, the median
    # floored at float32's epsilon: a reference darker than that floor (black: no indirect light in
    # the scene, say) leaves the range empty, and flip-evaluator then ends the process. FLIP is
    # undefined there: NaN, and the parameters say why.
    brightest = float((ref @ FLIP_LUMINANCE).max())
    if brightest < FLIP_BLACK:
        why = f"the reference is black: its brightest luminance {brightest:.3g} is below {FLIP_BLACK:.3g}"
        return Metric("flip", float("nan"), np.zeros(ref.shape[:2]), {"dynamic_range": "HDR", "undefined": why})
    error_map, mean, used = flip_evaluator.evaluate(
        ref.astype(np.float32),
        np.maximum(test, 0).astype(np.float32),
        "HDR",
        applyMagma=False,
        parameters={"ppd": ppd},
    )
    error_map = np.asarray(error_map, dtype=np.float64).reshape(ref.shape[:2])
    return Metric("flip", float(mean), error_map, {"dynamic_range": "HDR", **{k: _plain(v) for k, v in used.items()}})


def delta_e2000(test: np.ndarray, ref: np.ndarray, exposure: float = DELTA_E_EXPOSURE) -> Metric:
    import colour

    def lab(image):
        display = np.clip(image * 2.0**exposure, 0.0, 1.0)
        xyz = colour.RGB_to_XYZ(display, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])

    m = np.asarray(colour.delta_E(lab(test), lab(ref), method="CIE 2000"), dtype=np.float64)
    return Metric(
        "delta_e2000",
        float(m.mean()),
        m,
        {"exposure": exposure, "display": "linear sRGB x 2^exposure clipped to [0, 1], D65"},
    )


def compare_images(
    test: np.ndarray, ref: np.ndarray, metrics=METRICS, test_name: str = "test", ref_name: str = "reference", **params
) -> dict[str, Metric]:
    """Every metric named in ``metrics``; ``params`` override a metric's parameters by name
    (``relmse_eps``, ``smape_eps``, ``flip_ppd``, ``exposure``)."""
    check_images(test, ref, test_name, ref_name)
    t, r = test.astype(np.float64), ref.astype(np.float64)
    calls = {
        "mse": lambda: mse(t, r),
        "relmse": lambda: relmse(t, r, params.get("relmse_eps", RELMSE_EPSILON)),
        "smape": lambda: smape(t, r, params.get("smape_eps", SMAPE_EPSILON)),
        "flip": lambda: flip(t, r, params.get("flip_ppd", FLIP_PPD)),
        "delta_e2000": lambda: delta_e2000(t, r, params.get("exposure", DELTA_E_EXPOSURE)),
    }
    unknown = set(metrics) - set(calls)
    if unknown:
        raise InputError("metrics", f"unknown metric(s) {', '.join(sorted(unknown))}; known: {', '.join(METRICS)}")
    return {name: calls[name]() for name in metrics}


def bias_variance(
    images: list[np.ndarray], ref: np.ndarray, ref_variance: np.ndarray | None = None, eps: float = RELMSE_EPSILON
) -> dict:
    """Split the error of a stochastic method over n seeds into bias and variance (Celarek et al.,
    CGF 2019), relative to the reference as relMSE is: per pixel and channel w = 1 / (r^2 + eps).

    - ``relmse`` per seed: its mean, standard deviation and range (the error is a distribution);
    - ``variance``: mean of w s^2, s^2 the unbiased per-pixel variance across seeds;
    - ``bias2``: mean of w (m - r)^2, m the mean over seeds, less what noise puts there: s^2 / n
      from the seeds and the reference's own variance of its mean (when given). It can come out
      slightly negative when the bias is below the noise; it is reported as measured.

    So the expected relMSE of one seed is about ``bias2 + variance`` (plus the reference's variance).
    """
    n = len(images)
    if n < 2:
        raise ValueError(f"bias and variance need at least 2 seeds, got {n}")
    stack = np.stack([np.asarray(i, dtype=np.float64) for i in images])
    r = ref.astype(np.float64)
    w = 1.0 / (r**2 + eps)
    per_seed = np.array([float(np.mean(w * (s - r) ** 2)) for s in stack])
    mean = stack.mean(axis=0)
    s2 = stack.var(axis=0, ddof=1)
    noise = s2 / n + (ref_variance.astype(np.float64) if ref_variance is not None else 0.0)
    return {
        "seeds": n,
        "epsilon": eps,
        "relmse_mean": float(per_seed.mean()),
        "relmse_std": float(per_seed.std(ddof=1)),
        "relmse_min": float(per_seed.min()),
        "relmse_max": float(per_seed.max()),
        "bias2": float(np.mean(w * ((mean - r) ** 2 - noise))),
        "variance": float(np.mean(w * s2)),
        "reference_variance": float(np.mean(w * ref_variance)) if ref_variance is not None else None,
        "per_seed_relmse": per_seed.tolist(),
    }


def _plain(value):
    """JSON-ready: numpy scalars to Python numbers."""
    return value.item() if hasattr(value, "item") else value
