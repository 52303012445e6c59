"""The coverage model of imperfect-bundle holes: the fit recovers known constants, the Dr.Jit
recommendation agrees with the closed form, and on measured bundles the hole rate falls and the
redundant nodes rise with the splat scale as the model says."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import trace
from test_bundles import edge_gain

from evalkit.core.bundleset import DirectionSet
from evalkit.core.scene import load_scene
from evalkit.metrics.bundles import compare_bundles, scene_surfaces
from evalkit.metrics.hole_model import analyse, fit, recommend, validate
from references.embree import ExactTracer

SCALES = np.array([0.5, 0.75, 1.0, 1.5, 2.0, 3.0])


@pytest.mark.parametrize("q", [2.0, 3.2])
def test_the_fit_recovers_the_constants_of_model_data(rng, q):
    c, cn = 1.3, 0.8
    scales = SCALES[SCALES <= 2.0]  # holes above one in 1e7 crossings, as measured ones are
    noise = np.exp(rng.normal(0, 0.03, (2, len(scales))))
    model = fit(scales, np.exp(-c * scales**q) * noise[0], cn * scales**2 * noise[1], np.full(len(scales), 1e7))
    assert model["c"] == pytest.approx(c, rel=0.05)
    assert model["q"] == pytest.approx(q, rel=0.03)
    assert model["c_nodes"] == pytest.approx(cn, rel=0.03)
    assert model["max_ratio_error"] < 0.1


def test_the_recommendation_is_the_minimum_of_the_model_cost():
    for c, cn, cost in ((1.0, 1.0, 0.01), (1.3, 0.8, 0.002), (0.7, 1.2, 0.05)):
        rec = recommend(c, cn, cost)
        assert rec["splat_scale"] == pytest.approx(math.sqrt(math.log(c / (cost * cn)) / c), rel=1e-3)
        assert rec["closed_form"] == pytest.approx(rec["splat_scale"], rel=1e-3)
    # Stratified points (q > 2): no closed form; the gradient descent finds the searched minimum.
    rec = recommend(0.9, 1.0, 0.01, h0=0.001, q=3.5)
    assert rec["closed_form"] is None and rec["splat_scale"] == pytest.approx(rec["searched"], rel=1e-3)


def test_validation_finds_the_grid_minimum_and_the_regret():
    hole = np.exp(-(SCALES**2))
    nodes = SCALES**2
    best = validate(2.0, SCALES, hole, nodes, node_cost=0.01)
    assert best["measured_best_scale"] == 2.0 and best["regret"] == 0.0
    off = validate(0.5, SCALES, hole, nodes, node_cost=0.01)
    assert off["nearest_grid_scale"] == 0.5 and off["regret"] > 1.0


def test_measured_holes_fall_and_redundant_nodes_rise_with_the_splat_scale(gl):
    scene = load_scene("cornell-box")
    directions = DirectionSet.make(8, seed=3)
    exact = ExactTracer(scene).bundles(directions, 64)
    rows = []
    for scale in (0.5, 0.75, 1.0, 1.5, 2.0):
        bundles = trace(
            gl,
            scene,
            directions,
            "imperfect",
            resolution=64,
            points=4096,
            splat_scale=scale,
            sampler="random",
            merge=False,
        )
        r = compare_bundles(bundles, exact, surfaces=scene_surfaces(scene))
        rows.append(
            {
                "scene": "cornell-box",
                "sampler": "random",
                "points": 4096,
                "splat_scale": scale,
                "nodes_per_crossing": bundles.stats["covered_nodes"] / r["exact_nodes"],
                **r,
            }
        )
    holes = [r["hole_rate"] for r in rows]
    redundant = [r["redundant_rate"] for r in rows]
    assert all(a > b for a, b in zip(holes, holes[1:])), holes
    assert all(a < b for a, b in zip(redundant, redundant[1:])), redundant
    (model, _) = analyse(rows)  # the point count's own fit, then the fit over all point counts
    assert model["points"] == 4096
    # Measured: c 0.98, h0 0.006, hole rates predicted within 0.93 % (ratio) over s = 0.5 .. 2;
    # c_n 1.066: raw nodes are s^2 per crossing plus what cut splats gain at sharp edges
    # (`edge_gain`, 0.031 at s = 0.5 to 0.122 at s = 2 here; c_n was 0.999 before cut splats grew
    # to cover their edges). Asserted with a 5x margin, c near the ideal 1, and c_n above 1 and
    # under 1 plus the largest gain.
    assert model["max_ratio_error"] < 0.05, model
    assert 0.8 < model["c"] < 1.2 and 1.8 < model["q"] < 2.2 and model["h0"] < 0.02
    assert 1.0 < model["c_nodes"] < 1 + edge_gain(scene, bundles.params["splat_radius"]), model
