"""A predictive model of imperfect-bundle holes, fitted to measured sweeps, and the splat scale it
recommends.

Coverage model. N points fall uniformly on a surface of area A, each the centre of a splat of
radius r. A line crossing the surface at a point finds no splat there (a hole) when no centre
lies within r of it: for a Poisson process, P(hole) = exp(-N pi r^2 / A). With the splat scale s
(r = s sqrt(A / (pi N)), `gpu_impl.bundles`), N pi r^2 / A = s^2, so

    P(hole) ~ h0 + (1 - h0) exp(-c s^q),        nodes per surface crossing ~ c_n s^2,

with q = 2 for independent points (the sampler "random"); points stratified over the surface
(the sampler "stratified", shaders/bundles/splat_points.glsl) leave no large gaps, so their holes fall
faster with the splat size, q > 2. c absorbs what the ideal model leaves out (the per-direction
point sets, splats cut at triangle edges), and the second line is the expected number of splats
covering a point, each one node before merging (the lines splats cover: BundleTracer's
``covered_nodes``). The model is fitted to leaks (evalkit/metrics/bundles.py): lines that cross a
surface and find no node of it. A hole counts offsets too: on a curved, tessellated surface a
splat lies in its own triangle's plane, so where it overhangs a neighbouring triangle its depth
is off that triangle's by more than the comparison's tolerance, however many splats cover it,
a floor no splat size removes (atrium: holes 9.1 %, leaks 0.2 % at s = 2.5). h0 is what floor
the leaks keep. The constants are fitted per sampler and
point count N (and over all N), so the model says how far the measurements depart from the ideal
c = c_n = 1, q = 2, h0 = 0 of independent points.

Recommendation. For a stated node cost lambda (the hole rate one extra node per crossing is worth),
the splat scale minimises cost(s) = P(hole) + lambda * nodes per crossing. It is found by gradient
descent with Dr.Jit's automatic differentiation on the fitted model and checked against a direct
search of the same cost (for q = 2 also the closed form s*^2 = ln(c (1 - h0) / (lambda c_n)) / c),
then validated against the measured cost on the sweep's grid.
"""

from __future__ import annotations

import math

import numpy as np

from evalkit.metrics.fitting import drjit, gradient_descent

DEFAULT_NODE_COST = 0.01
# Hole rates below one hole in the measured nodes are not measured: they are floored at 1 / nodes.


def fit(scale: np.ndarray, hole_rate: np.ndarray, nodes_per_crossing: np.ndarray, exact_nodes: np.ndarray) -> dict:
    """Fit c, q and h0 (least squares on log P(hole)) and c_n (least squares on log nodes per
    crossing) with Dr.Jit AD; returns the constants and how well the model predicts the measurements."""
    s2 = np.asarray(scale, dtype=np.float64) ** 2
    hole = np.maximum(np.asarray(hole_rate, dtype=np.float64), 1.0 / np.asarray(exact_nodes, dtype=np.float64))
    nodes = np.asarray(nodes_per_crossing, dtype=np.float64)
    log_hole, log_nodes = np.log(hole), np.log(nodes)

    _, Float = drjit()
    s2_, lh, ln = (Float(a) for a in (s2, log_hole, log_nodes))  # once: a conversion per step cost 16x the step

    def loss(dr, log_c, log_half_q, log_cn, logit_h0):
        h0 = 1.0 / (1.0 + dr.exp(-logit_h0))
        model_hole = dr.log(h0 + (1.0 - h0) * dr.exp(-dr.exp(log_c) * dr.exp(dr.exp(log_half_q) * dr.log(s2_))))
        model_nodes = log_cn + dr.log(s2_)
        return dr.mean(dr.square(model_hole - lh)) + dr.mean(dr.square(model_nodes - ln))

    log_c, log_half_q, log_cn, logit_h0 = gradient_descent(loss, [0.0, 0.0, 0.0, -12.0], steps=3000, rate=0.05)
    c, q, cn, h0 = math.exp(log_c), 2.0 * math.exp(log_half_q), math.exp(log_cn), 1.0 / (1.0 + math.exp(-logit_h0))
    predicted = hole_rate_model(s2, c, h0, q)
    ratio = predicted / hole
    return {
        "c": c,
        "q": q,
        "h0": h0,
        "c_nodes": cn,
        "samples": int(len(s2)),
        # Prediction error: of the hole rate, as a ratio (log-space) and in absolute terms.
        "median_ratio_error": float(np.median(np.abs(np.log(ratio)))),
        "max_ratio_error": float(np.max(np.abs(np.log(ratio)))),
        "max_abs_error": float(np.max(np.abs(predicted - hole))),
        "nodes_max_ratio_error": float(np.max(np.abs(np.log(cn * s2 / nodes)))),
    }


def hole_rate_model(s2, c: float, h0: float = 0.0, q: float = 2.0):
    """The model's P(hole) at squared splat scales ``s2``."""
    return h0 + (1.0 - h0) * np.exp(-c * np.asarray(s2, dtype=np.float64) ** (q / 2.0))


def recommend(c: float, c_nodes: float, node_cost: float = DEFAULT_NODE_COST, h0: float = 0.0, q: float = 2.0) -> dict:
    """The splat scale minimising P(hole) + node_cost c_n s^2, by Dr.Jit AD (gradient descent on
    log s), with a direct search of the same cost beside it as a check (and, for q = 2, the closed
    form)."""

    def cost(dr, log_s):
        s2 = dr.exp(2 * log_s)
        return h0 + (1.0 - h0) * dr.exp(-c * dr.exp(q * log_s)) + node_cost * c_nodes * s2

    (log_s,) = gradient_descent(cost, [0.0], steps=800, rate=0.02)
    grid = np.exp(np.linspace(math.log(0.05), math.log(20.0), 200001))
    searched = float(grid[np.argmin(hole_rate_model(grid**2, c, h0, q) + node_cost * c_nodes * grid**2)])
    ratio = c * (1.0 - h0) / (node_cost * c_nodes)
    closed = (math.sqrt(math.log(ratio) / c) if ratio > 1 else 0.0) if q == 2.0 else None
    s = math.exp(log_s)
    hole = float(hole_rate_model(s * s, c, h0, q))
    return {
        "node_cost": node_cost,
        "splat_scale": s,
        "searched": searched,
        "closed_form": closed,
        "predicted_hole_rate": hole,
        "predicted_nodes_per_crossing": c_nodes * s * s,
        "predicted_cost": hole + node_cost * c_nodes * s * s,
    }


def validate(
    recommended: float,
    scale: np.ndarray,
    hole_rate: np.ndarray,
    nodes_per_crossing: np.ndarray,
    node_cost: float = DEFAULT_NODE_COST,
) -> dict:
    """The measured cost on the sweep's grid: its best scale, and the regret of taking the grid
    scale nearest (in log) to the recommendation instead."""
    scale = np.asarray(scale, dtype=np.float64)
    measured = np.asarray(hole_rate) + node_cost * np.asarray(nodes_per_crossing)
    best = int(np.argmin(measured))
    nearest = int(np.argmin(np.abs(np.log(scale) - math.log(recommended))))
    return {
        "measured_best_scale": float(scale[best]),
        "measured_best_cost": float(measured[best]),
        "nearest_grid_scale": float(scale[nearest]),
        "nearest_grid_cost": float(measured[nearest]),
        "regret": float(measured[nearest] / measured[best] - 1.0),
    }


def analyse(rows: list[dict], node_cost: float = DEFAULT_NODE_COST, rate: str = "leak_rate") -> list[dict]:
    """Fit, recommend and validate per scene, sampler and point count (and over all point counts),
    from study rows of imperfect bundles (columns splat_scale, sampler, points, ``rate``,
    nodes_per_crossing, exact_nodes). ``rate``: the leaks by default, the lines that cross a
    surface and find no node of it (evalkit/metrics/bundles.py); ``hole_rate`` counts the offset
    surfaces of curved geometry too, a floor no splat size removes."""
    out = []
    for scene, sampler in sorted({(r["scene"], r.get("sampler", "random")) for r in rows}):
        mine = [r for r in rows if r["scene"] == scene and r.get("sampler", "random") == sampler]
        for points in [*sorted({int(r["points"]) for r in mine}), None]:
            group = [r for r in mine if points is None or int(r["points"]) == points]
            if len({r["splat_scale"] for r in group}) < 2:
                continue
            col = {
                k: np.array([float(r[k]) for r in group])
                for k in ("splat_scale", rate, "nodes_per_crossing", "exact_nodes")
            }
            model = fit(col["splat_scale"], col[rate], col["nodes_per_crossing"], col["exact_nodes"])
            rec = recommend(model["c"], model["c_nodes"], node_cost, model["h0"], model["q"])
            entry = {
                "scene": scene,
                "sampler": sampler,
                "points": points if points is not None else "all",
                **model,
                **rec,
            }
            if points is not None:  # one point count: the grid is one curve to validate on
                order = np.argsort(col["splat_scale"])
                entry.update(
                    validate(
                        rec["splat_scale"],
                        col["splat_scale"][order],
                        col[rate][order],
                        col["nodes_per_crossing"][order],
                        node_cost,
                    )
                )
            out.append(entry)
    return out
