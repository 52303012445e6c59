"""GL perfect and imperfect bundles against exact float64 lines on analytic scenes, overflow
handling, the node budget, determinism and the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bundle_oracle import agreement, exact_lists
from conftest import run_evalkit
from evalkit.core.bundleset import FRAME_PADDING, SPLAT_PRIM_ID, BundleSet, DirectionSet
from evalkit.core.scene import Material, Mesh, assemble, load_scene
from evalkit.core.scene.model import sample_texture
from evalkit.core.scene.tessellate import box
from gpu_impl.bundles import NodeBudgetExceeded, trace_bundles

# Matching tolerance for perfect bundles: float32 depth of a point within the bounding sphere.
PERFECT_DEPTH_TOLERANCE = 1e-5
QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])


def scene_of(meshes, materials):
    return assemble("analytic", "analytic", meshes, materials, [], camera=None)


def textured_quad():
    texture = np.random.default_rng(7).uniform(0.05, 0.95, (8, 8, 3)).astype(np.float32)
    mesh = Mesh("quad", QUAD, QUAD_FACES, 0, uvs=QUAD[:, :2].copy())
    return scene_of([mesh], [Material("checker", texture=texture, emission=(0.0, 0.0, 0.0))])


def nested_boxes():
    meshes = [Mesh(f"box{i}", *box(np.full(3, -s), np.full(3, s)), i) for i, s in enumerate((1.0, 0.6, 0.3))]
    return scene_of(meshes, [Material("outer", albedo=(0.8, 0.2, 0.2)), Material("middle", albedo=(0.2, 0.8, 0.2)),
                             Material("inner", albedo=(0.2, 0.2, 0.8), emission=(2.0, 1.0, 0.5))])


def coplanar_stack():
    """Quads stacked 0.1 apart plus two exactly coincident ones: duplicates a renderer must keep."""
    meshes = [Mesh(f"q{i}", QUAD + [0.0, 0.0, z], QUAD_FACES, 0) for i, z in enumerate((0.0, 0.1, 0.2, 0.2))]
    return scene_of(meshes, [Material("grey")])


SCENES = {"quad": textured_quad, "nested-boxes": nested_boxes, "coplanar-stack": coplanar_stack,
          "cornell-box": lambda: load_scene("cornell-box")}


def build(gl, scene, method="perfect", K=12, R=40, seed=3, **kw) -> BundleSet:
    return trace_bundles(gl, scene, DirectionSet.make(K, seed=seed), method, resolution=R, **kw)


@pytest.mark.parametrize("name", SCENES)
def test_perfect_bundles_agree_with_exact_lines(gl, name):
    scene = SCENES[name]()
    bundles = build(gl, scene)
    assert bundles.check() is None
    result = agreement(bundles, exact_lists(scene, bundles), PERFECT_DEPTH_TOLERANCE * bundles.radius)
    assert result["exact_nodes"] > 4000
    assert result["agreement"] >= 0.995, result
    assert result["spurious"] <= 0.005 * result["exact_nodes"], result


def hit_points(bundles: BundleSet) -> np.ndarray:
    """Scene-space position of every node (float64)."""
    lists = bundles.node_lists()
    R2 = bundles.resolution**2
    k = lists // R2
    origins = np.concatenate([bundles.line_origins(i) for i in range(bundles.directions.count)])
    return origins[lists] + bundles.depth[:, None].astype(np.float64) * bundles.directions.directions[k]


def test_perfect_nodes_carry_normal_albedo_emission_and_primitive(gl):
    scene = textured_quad()
    bundles = build(gl, scene)
    p = hit_points(bundles) + scene.origin
    assert np.abs(p[:, 2]).max() < 1e-5  # on the quad's plane
    assert np.allclose(bundles.normal, [0, 0, 1], atol=1e-4)
    expected = sample_texture(scene.materials[0].texture, p[:, :2])
    assert np.abs(bundles.albedo - expected).max() < 2e-3  # half-float storage
    assert set(np.unique(bundles.prim_id)) == {0, 1}
    below = p[:, 0] > p[:, 1]  # the diagonal splits the quad into faces 0 (x > y) and 1
    assert np.mean((bundles.prim_id == 0) == below) > 0.999

    boxes = nested_boxes()
    b = build(gl, boxes, K=4, R=32)
    inner = b.material == 2
    assert inner.any() and np.allclose(b.emission[inner], [2.0, 1.0, 0.5]) and not b.emission[~inner].any()
    assert np.allclose(b.albedo[inner], [0.2, 0.2, 0.8], atol=1e-3)
    # Flat boxes: every normal is an axis, within octahedral precision.
    assert np.abs(np.abs(b.normal).max(axis=1) - 1).max() < 1e-4


def test_coincident_triangles_are_kept_and_counted_redundant(gl):
    bundles = build(gl, coplanar_stack(), K=4, R=32)
    exact = exact_lists(coplanar_stack(), bundles)
    doubles = sum(int(np.sum(np.diff(ref[:, 0]) == 0)) for lists in exact for ref in lists)
    assert doubles > 500
    assert bundles.stats["redundant_nodes"] == doubles


def flat_square(size: float = 1.0):
    return scene_of([Mesh("square", QUAD * size, QUAD_FACES, 0, uvs=QUAD[:, :2].copy())],
                    [Material("checker", texture=textured_quad().materials[0].texture)])


@pytest.mark.parametrize("splat_scale", [1.0, 1.5, 2.0])
def test_imperfect_hole_rate_follows_the_coverage_model(gl, splat_scale):
    # N splats of radius r on area A miss a point with probability exp(-N pi r^2 / A) =
    # exp(-splat_scale^2); the circular cut-out makes each splat cover exactly pi r^2, so the
    # nodes per surface crossing are splat_scale^2.
    scene = flat_square()
    bundles = build(gl, scene, "imperfect", K=8, R=64, points=8192, splat_scale=splat_scale)
    assert (bundles.prim_id == SPLAT_PRIM_ID).all() and (bundles.material == 0).all()
    result = agreement(bundles, exact_lists(scene, bundles), 1e-5 * bundles.radius)
    holes = 1 - result["agreement"]
    model = math.exp(-splat_scale**2)
    assert abs(holes - model) < 0.15 * model + 0.004, (holes, model)
    overlap = bundles.node_count / result["exact_nodes"]
    assert abs(overlap - splat_scale**2) < 0.05 * splat_scale**2 + 0.02, overlap


def test_splat_uvs_keep_texture_detail_inside_a_splat(gl):
    # Splats much larger than a texel: the albedo must follow the texture under each pixel centre,
    # not stay at the splat centre's colour.
    scene = flat_square()
    bundles = build(gl, scene, "imperfect", K=4, R=64, points=512, splat_scale=2.0)
    p = hit_points(bundles) + scene.origin
    expected = sample_texture(scene.materials[0].texture, p[:, :2])
    assert np.abs(bundles.albedo - expected).max() < 2e-3
    assert bundles.stats["redundant_nodes"] > 0.5 * bundles.node_count


def test_overflow_reruns_and_loses_no_node(gl):
    scene = nested_boxes()
    for method in ("perfect", "imperfect"):
        reference = build(gl, scene, method, K=8, R=32, points=2048)
        assert reference.stats["overflow_reruns"] == 0
        small = build(gl, scene, method, K=8, R=32, points=2048, initial_capacity=100)
        assert small.stats["overflow_reruns"] == 1 and small.stats["capacity"] >= small.node_count
        for name in ("offsets", *BundleSet.NODE_FIELDS):
            assert np.array_equal(getattr(small, name), getattr(reference, name)), (method, name)


def test_node_budget_is_a_clear_error_with_the_memory_needed(gl):
    with pytest.raises(NodeBudgetExceeded, match=r"analytic: perfect bundles \(K=8, R=32\) need [\d,]+ nodes = .* over the node budget"):
        build(gl, nested_boxes(), K=8, R=32, node_budget=64 * 1024)


def test_same_seed_same_lists_and_atlas_batching_changes_nothing(gl):
    scene = nested_boxes()
    for method in ("perfect", "imperfect"):
        a = build(gl, scene, method, K=10, R=16, points=1024, seed=11)
        b = build(gl, scene, method, K=10, R=16, points=1024, seed=11, max_atlas_size=32)  # 4 directions per draw
        c = build(gl, scene, method, K=10, R=16, points=1024, seed=12)
        for name in ("offsets", *BundleSet.NODE_FIELDS):
            assert np.array_equal(getattr(a, name), getattr(b, name)), (method, name)
        assert not np.array_equal(a.offsets, c.offsets)


def test_cli_builds_and_saves_bundles(tmp_path):
    out = tmp_path / "sub" / "b.npz"
    r = run_evalkit("bundles", "cornell-box", "--method", "imperfect", "--directions", "8", "--resolution", "32",
                    "--points", "2048", "--seed", "4", "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    stats = summary["stats"]
    assert summary["nodes"] == stats["nodes"] > 0
    assert stats["overflow_reruns"] == 0 and stats["gpu_bytes"] > stats["node_bytes"] > 0
    assert set(stats["gpu_ms"]) == {"points", "lists", "resolve"}
    loaded = BundleSet.load(out)
    assert loaded.node_count == summary["nodes"] and loaded.params["seed"] == 4


@pytest.mark.parametrize("name", ["cornell-box", "furnace", "atrium"])
def test_every_builtin_scene_builds_both_ways(gl, name):
    scene = load_scene(name)
    # Cauchy-Crofton: lines through the bounding sphere cross its surfaces depth_complexity times on
    # average, and each crossing yields splat_scale^2 splat nodes on average.
    crossings = scene.features().depth_complexity
    for method, per_crossing in (("perfect", 1.0), ("imperfect", 2.0**2)):
        b = build(gl, scene, method, K=16, R=64, points=4096, splat_scale=2.0)
        assert b.check() is None
        assert b.params["scene"] == name and b.params["scene_hash"] == scene.content_hash()
        lines = b.list_count * math.pi / 4 / FRAME_PADDING**2
        assert b.node_count / lines == pytest.approx(crossings * per_crossing, rel=0.1), method


def test_cli_reports_an_exceeded_budget_in_one_line(tmp_path):
    r = run_evalkit("bundles", "cornell-box", "--method", "perfect", "--directions", "8", "--resolution", "32",
                    "--node-budget", "10kB", "--out", str(tmp_path / "b.npz"))
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "over the node budget" in r.stderr and "Traceback" not in r.stderr
