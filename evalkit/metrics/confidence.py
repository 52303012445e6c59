"""How sure a comparison of a render with its reference is.

- `mean_ratio`: the ratio of the image means, test over reference, with a confidence interval
  that holds both images' noise. The test's noise comes from its frames: a render's frames are
  independent estimates (each draws new directions, jitter and paths), so the spread of the
  frames' image means gives the standard error of their mean, with F - 1 degrees of freedom
  (Student's t). Within a frame the pixels share one set of bundles and are correlated, so the
  per-pixel variances could not give it. The reference's pixels are independent (Mitsuba seeds
  every pixel's sampler apart), so the standard error of its image mean is the root of the summed
  per-pixel variances of the mean over the number of values. The two combine by the delta method
  (relative errors add in quadrature) with Welch-Satterthwaite's degrees of freedom.
- `render_ratio`: the same ratio between two of the toolkit's renders (two methods, say), from
  both renders' frames. With as many frames on both sides the frames pair up; two renders of one
  seed draw the same directions and jitter frame by frame, so the noise they share cancels and the
  interval is a fraction of the unpaired one (the bias of one method against another, measured).
- `pool_renders`: one estimate from renders of the same settings under different seeds, so that
  a long check runs in pieces (on several machines, or over several sessions): their frames
  together, as if one render had made them all.
- `z_test`: Mitsuba's render tests' per-pixel test (src/render/tests/test_renders.py): each
  pixel and channel's difference over the root of the two variances of the mean, a two-sided
  test at level alpha with a Sidak correction for the number of values; the share of values the
  noise cannot explain, and the map of |z| (the largest over channels).

A finite bundle set is a biased discretisation, so the z-test rejects even perfect bundles where
the bias shows; the share it rejects says where, and how much of the image, the bias exceeds the
noise. The ratio's interval says how large it is overall.
"""

from __future__ import annotations

import math

import numpy as np

from evalkit.core.errors import InputError

LEVEL = 0.95  # the confidence of the intervals
Z_ALPHA = 0.01  # the z-test's family-wise significance (Mitsuba's render tests use 0.01)


def mean_ratio(test_frame_means: np.ndarray, ref: np.ndarray, ref_variance: np.ndarray, level: float = LEVEL) -> dict:
    """The test's image mean over the reference's, per channel and over all channels, with its
    ``level`` interval. ``test_frame_means``: (F, 3), each frame's image mean per channel (the
    render's ``frame_means``); ``ref``, ``ref_variance``: (H, W, 3), the reference and its
    per-pixel variance of the mean. With one frame the test's noise is unknown: no interval."""
    frames = np.asarray(test_frame_means, dtype=np.float64).reshape(-1, 3)
    ref, var = np.asarray(ref, dtype=np.float64), np.asarray(ref_variance, dtype=np.float64)
    count = ref.shape[0] * ref.shape[1]
    # Per channel, then over all three (the channels' mean: its frames' means, its summed variance).
    items = [(frames[:, c], ref[..., c].mean(), var[..., c].sum() / count**2) for c in range(3)]
    items.append((frames.mean(axis=1), ref.mean(), var.sum() / (3 * count) ** 2))
    rows = []
    for f, mr, vr in items:
        mt = float(f.mean())
        row = _row(mt / mr if mr > 0 else math.nan, ref_se=math.sqrt(vr))
        if len(f) > 1 and mr > 0 and mt > 0:
            a = (f.std(ddof=1) / math.sqrt(len(f)) / mt) ** 2  # relative variances
            _widen(row, a, vr / mr**2, len(f) - 1, math.inf, level)
            row["test_se"] = math.sqrt(a) * mt
        rows.append(row)
    return {"level": level, "frames": len(frames), "per_channel": rows[:3], "all": rows[3]}


def render_ratio(test_frame_means: np.ndarray, base_frame_means: np.ndarray, level: float = LEVEL) -> dict:
    """The test render's image mean over another render's (a base: another method, say), from
    both renders' frame means (F, 3), per channel and over all channels, with its ``level``
    interval. A render's pixels share their frame's bundles, so its image mean's noise comes from
    its frames, never from its per-pixel variances.

    With as many frames on both sides the frames pair up, test frame i with base frame i, and the
    ratio's noise is that of t_i - r b_i (the ratio estimator's delta method, Student's t with F - 1
    degrees of freedom). Pairs are independent of one another whatever the two renders drew, so
    the interval holds for any two renders; it is narrow where the two share their seed, since
    then frame i of both draws the same directions and camera jitter (common random numbers) and
    the noise they share cancels. With other counts: both spreads, as `mean_ratio` combines them
    (``paired`` is False)."""
    test = np.asarray(test_frame_means, dtype=np.float64).reshape(-1, 3)
    base = np.asarray(base_frame_means, dtype=np.float64).reshape(-1, 3)
    paired = len(test) == len(base)
    columns = [(test[:, c], base[:, c]) for c in range(3)] + [(test.mean(axis=1), base.mean(axis=1))]
    rows = []
    for t, b in columns:
        mt, mb = float(t.mean()), float(b.mean())
        row = _row(mt / mb if mb > 0 else math.nan)
        if mt > 0 and mb > 0 and min(len(t), len(b)) > 1:
            if paired:
                residual = t - row["ratio"] * b
                _widen(row, residual.var(ddof=1) / len(t) / mt**2, 0.0, len(t) - 1, math.inf, level)
            else:
                a, c = t.var(ddof=1) / len(t) / mt**2, b.var(ddof=1) / len(b) / mb**2
                _widen(row, a, c, len(t) - 1, len(b) - 1, level)
        rows.append(row)
    return {"level": level, "frames": [len(test), len(base)], "paired": paired, "per_channel": rows[:3], "all": rows[3]}


def _row(ratio: float, ref_se: float | None = None) -> dict:
    return {"ratio": ratio, "lo": None, "hi": None, "test_se": None, "ref_se": ref_se}


def _widen(row: dict, a: float, b: float, dof_a: float, dof_b: float, level: float) -> None:
    """Sets the interval of ``row``'s ratio from the two relative variances of its means, ``a``
    and ``b``, of ``dof_a`` and ``dof_b`` degrees of freedom: the delta method (relative errors
    add in quadrature), Student's t with Welch-Satterthwaite's degrees of freedom."""
    from scipy import stats

    parts = [v * v / d for v, d in ((a, dof_a), (b, dof_b)) if v > 0 and math.isfinite(d)]
    dof = (a + b) ** 2 / sum(parts) if parts else math.inf
    q = float(stats.t.ppf(0.5 + level / 2, dof)) if math.isfinite(dof) else float(stats.norm.ppf(0.5 + level / 2))
    half = q * math.sqrt(a + b) * row["ratio"]
    row.update(lo=row["ratio"] - half, hi=row["ratio"] + half)


def within(ratio: dict, bound: float) -> bool:
    """Whether the interval of a `mean_ratio` entry lies inside 1 +- ``bound``."""
    return ratio["lo"] is not None and 1 - bound <= ratio["lo"] and ratio["hi"] <= 1 + bound


# What may differ between renders pooled into one estimate: what seeds them, what their frames
# came to, and where they ran. Everything else in their provenance must match.
POOLED_FREELY = ("seed", "frames", "frames_rendered", "paths_per_pixel", "frame_means", "time_budget", "warnings", "gl")


Render = tuple[str, np.ndarray, np.ndarray | None, dict]  # path, image, variance of its mean, provenance


def pool_renders(renders: list[Render]) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """One render from several of the same settings and different seeds: each (path, image,
    per-pixel variance of its mean or None, provenance with ``frame_means``). Every frame weighs
    the same: the image is the frames' mean (each render's image weighted by its frames), its
    variance of the mean sums (F_i / F)^2 var_i (None where a render has none), and the frame means
    are all of them, in order. Renders of one seed share their frames, and renders of other
    settings estimate something else: both are refused, naming the file."""
    first_path, first_image, _, first = renders[0]
    seeds: dict[int, str] = {}
    for path, image, _, meta in renders:
        if not meta.get("frame_means"):
            raise InputError(path, "has no frame means: only the toolkit's renders can be pooled")
        if image.shape != first_image.shape:
            (h, w), (fh, fw) = image.shape[:2], first_image.shape[:2]
            raise InputError(path, f"is {w}x{h} and {first_path} {fw}x{fh}: images of two sizes do not pool")
        differ = sorted(k for k in set(meta) | set(first) if k not in POOLED_FREELY and meta.get(k) != first.get(k))
        if differ:
            shown = ", ".join(f"{k} {meta.get(k)!r} against {first.get(k)!r}" for k in differ[:3])
            raise InputError(path, f"has other settings than {first_path} ({shown}): it estimates something else")
        seed = meta.get("seed")
        if seed in seeds:
            raise InputError(path, f"has seed {seed}, as {seeds[seed]} has: the same frames twice")
        seeds[seed] = path
    counts = np.array([len(r[3]["frame_means"]) for r in renders], dtype=np.float64)
    weights = counts / counts.sum()
    image = sum(w * r[1].astype(np.float64) for w, r in zip(weights, renders))
    have_variance = all(r[2] is not None for r in renders)
    variance = sum(w * w * r[2].astype(np.float64) for w, r in zip(weights, renders)) if have_variance else None
    pooled = {
        **first,
        "seed": list(seeds),
        "frames": int(counts.sum()),
        "frames_rendered": int(counts.sum()),
        "paths_per_pixel": sum(r[3].get("paths_per_pixel", 0) for r in renders),
        "frame_means": [m for r in renders for m in r[3]["frame_means"]],
        "warnings": list(dict.fromkeys(w for r in renders for w in r[3].get("warnings", []))),
        "pooled": [r[0] for r in renders],
    }
    return image.astype(np.float32), None if variance is None else variance.astype(np.float32), pooled


def z_test(test: np.ndarray, test_variance: np.ndarray, ref: np.ndarray, ref_variance: np.ndarray,
           alpha: float = Z_ALPHA) -> dict:  # fmt: skip
    """The per-pixel two-sided z-test of test against reference at family-wise level ``alpha``
    (Sidak over every pixel and channel): the share of values outside, the threshold on |z|, and
    the map of the largest |z| over channels (H, W). Values with no variance on either side are
    left out (the count says how many were tested)."""
    from scipy import stats

    var = np.asarray(test_variance, dtype=np.float64) + np.asarray(ref_variance, dtype=np.float64)
    diff = np.asarray(test, dtype=np.float64) - np.asarray(ref, dtype=np.float64)
    tested = var > 0
    z = np.zeros_like(diff)
    z[tested] = diff[tested] / np.sqrt(var[tested])
    n = int(tested.sum())
    alpha_each = 1.0 - (1.0 - alpha) ** (1.0 / max(n, 1))  # Sidak
    threshold = float(stats.norm.isf(alpha_each / 2))
    outside = int((np.abs(z) > threshold).sum())
    return {
        "alpha": alpha,
        "tested": n,
        "threshold": threshold,
        "outside": outside,
        "outside_share": outside / n if n else math.nan,
        "map": np.abs(z).max(axis=2),
    }


def confidence(
    test: np.ndarray,
    test_variance: np.ndarray | None,
    frame_means: np.ndarray | None,
    ref: np.ndarray,
    ref_variance: np.ndarray | None,
    ref_frame_means: np.ndarray | None = None,
) -> dict:
    """How sure the comparison of a render's image with a reference is, as far as what is known
    allows; what `evalkit compare` prints and a study's rows hold. ``render_ratio`` where the
    reference is another render with its frames' means (never from a render's per-pixel variances:
    they would make its image mean look surer than it is), else ``mean_ratio`` where the test has
    frame means and the reference a variance; ``z_test`` (without its map) where both have a
    variance. Keys are left out where their inputs are missing."""
    out = {}
    if frame_means is not None and ref_frame_means is not None:
        out["render_ratio"] = render_ratio(np.asarray(frame_means), np.asarray(ref_frame_means))
    elif frame_means is not None and ref_variance is not None:
        out["mean_ratio"] = mean_ratio(np.asarray(frame_means), ref, ref_variance)
    if test_variance is not None and ref_variance is not None:
        out["z_test"] = {k: v for k, v in z_test(test, test_variance, ref, ref_variance).items() if k != "map"}
    return out
