"""Embree exact bundles and next-hit queries against float64 brute force, their precision cases
(coplanar stacks, thin slabs, shared edges, scale and distance from the origin), the bundle
comparison's counts on known answers, GL perfect bundles against exact ones, and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from bundle_oracle import agreement, exact_lists
from conftest import run_evalkit
from test_bundles import QUAD, QUAD_FACES, build, coplanar_stack, nested_boxes, scene_of, textured_quad

from evalkit.core.bundleset import BundleSet, DirectionSet
from evalkit.core.scene import Material, Mesh, load_scene
from evalkit.core.scene.tessellate import box, unit_sphere
from evalkit.metrics.bundles import compare_bundles
from references.embree import ExactTracer, coincident_pairs

# Exact depths are float64 plane depths stored as float32: a few 1e-8 of the radius.
EXACT_DEPTH_TOLERANCE = 1e-6


def thin_slabs():
    """Parallel quads 1e-3, 1e-5 and 1e-7 apart (relative to about unit size); the last gap is
    below the re-cast offset, so only the coincidence layers can find both."""
    zs = (0.0, 1e-3, 1e-3 + 1e-5, 1e-3 + 1e-5 + 1e-7)
    return scene_of(
        [Mesh(f"slab{i}", QUAD + [0.0, 0.0, z], QUAD_FACES, 0) for i, z in enumerate(zs)], [Material("grey")]
    )


def exact(scene, K=8, R=32, seed=3) -> BundleSet:
    return ExactTracer(scene).bundles(DirectionSet.make(K, seed=seed), R)


@pytest.mark.parametrize("make", [textured_quad, nested_boxes, coplanar_stack, thin_slabs], ids=lambda f: f.__name__)
def test_exact_bundles_equal_float64_brute_force(make):
    scene = make()
    bundles = exact(scene)
    assert bundles.check() is None
    oracle = exact_lists(scene, bundles)
    result = agreement(bundles, oracle, EXACT_DEPTH_TOLERANCE * bundles.radius)
    assert result["exact_nodes"] > 1000
    assert result["matched"] == result["exact_nodes"] and result["spurious"] == 0, result
    assert result["same_prim"] == 1.0, result


def brute_force_coincident_pairs(p: np.ndarray, n: np.ndarray, tolerance: float) -> set:
    """Every pair of triangles (corners ``p`` (T, 3, 3), unit normals ``n``) in one plane within
    ``tolerance`` whose interiors overlap by more than it along every edge's axis in that plane."""
    found = set()
    for a in range(len(p)):
        for b in range(a + 1, len(p)):
            if abs(abs(n[a] @ n[b]) - 1.0) > 1e-9 or np.abs((p[b] - p[a, 0]) @ n[a]).max() > tolerance:
                continue
            overlaps = True
            for t in (a, b):
                for e in range(3):
                    axis = np.cross(n[a], p[t, (e + 1) % 3] - p[t, e])
                    axis /= np.linalg.norm(axis)
                    pa, pb = p[a] @ axis, p[b] @ axis
                    overlaps &= min(pa.max(), pb.max()) - max(pa.min(), pb.min()) > tolerance
            if overlaps:
                found.add((a, b))
    return found


def test_coincident_pairs_are_those_of_a_test_of_every_pair():
    """`coincident_pairs` (plane bins, a sweep, a 2-D test of touching pairs, then the test in the
    plane) finds the pairs a test of every pair finds: a floor tessellated into 128 triangles that
    only touch, a box standing on it (its bottom coincident with the floor), a doubled triangle, a
    triangle a tenth of the tolerance above the floor and one ten tolerances above it."""
    cell = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    floor = [(cell + [x, 0.0, z]) * 0.25 for x in range(8) for z in range(8)]
    quads = [q[[0, 2, 1]] for q in floor] + [q[[0, 3, 2]] for q in floor]
    cube, cube_faces = box(np.array([0.5, 0.0, 0.5]), np.array([1.1, 0.8, 1.1]))  # from the floor up
    triangles = np.concatenate(
        [
            np.stack(quads),
            cube[cube_faces],
            [quads[5], quads[40] + [0.0, 1e-7, 0.0], quads[41] + [0.0, 1e-5, 0.0]],
        ]
    )
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    positions, faces = triangles.reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3)
    tolerance = 1e-6
    fast = {tuple(pair) for pair in coincident_pairs(positions, faces, n, tolerance).tolist()}
    assert fast == brute_force_coincident_pairs(triangles, n, tolerance)
    last = len(triangles) - 1
    assert {(5, last - 2), (40, last - 1)} <= fast and not any(last in pair for pair in fast)
    assert sum(a >= 128 for a, b in fast) == 0 and sum(b >= 128 and b < last - 2 for a, b in fast) >= 2


def test_coincident_and_thin_surfaces_are_every_one_a_node():
    stack = exact(coplanar_stack())
    assert stack.params["coincidence_layers"] == 2 and stack.params["coincident_pairs"] == 2  # (4, 6) and (5, 7)
    # The two coincident quads (triangles 4, 5 and 6, 7) and the two slabs 1e-7 apart are crossed
    # by exactly the same lines.
    for bundles in (stack, exact(thin_slabs())):
        prim = bundles.prim_id
        assert np.isin(prim, (4, 5)).sum() == np.isin(prim, (6, 7)).sum() > 500
    assert stack.params["recast_epsilon"] > 1e-7 * stack.radius  # the slabs' last gap is below the offset


def test_closed_meshes_are_watertight_on_every_line():
    # A line enters a closed mesh as often as it leaves it, so lists have even length, also where
    # lines pass through the shared edges and vertices of a fine tessellation. The one exception
    # is by design: a line that clips a cube's edge within the re-cast offset (about 4e-6 r) enters
    # and leaves closer together than the offset, and the two crossings are one node.
    positions, faces, normals, uvs = unit_sphere((96, 48))
    sphere = scene_of([Mesh("sphere", positions, faces, 0, normals)], [Material("grey")])
    cube = scene_of([Mesh("cube", *box(np.full(3, -1.0), np.full(3, 1.0), subdivisions=8), 0)], [Material("grey")])
    for scene, odd_allowed in ((sphere, 0), (cube, 2)):
        lengths = exact(scene, K=16, R=64).list_lengths()
        assert (lengths % 2).sum() <= odd_allowed and (lengths > 0).sum() > 30000


def test_next_hit_through_shared_edges_and_vertices_never_leaks():
    positions, faces = box(np.full(3, -1.0), np.full(3, 1.0), subdivisions=4)
    tracer = ExactTracer(scene_of([Mesh("cube", positions, faces, 0)], [Material("grey")]))
    g = np.linspace(-1.0, 1.0, 9)[1:-1]  # the inner grid lines of the subdivided top face: shared edges and vertices
    xx, yy = np.meshgrid(g, g)
    origins = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, 5.0)], axis=1)
    hits = tracer.next_hit(origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1)))
    assert (hits.prim_id >= 0).all()
    assert np.allclose(hits.depth, 4.0, atol=1e-12) and np.allclose(hits.point[:, 2], 1.0, atol=1e-12)
    assert np.allclose(hits.geometric_normal, [0.0, 0.0, 1.0])


def first_hits(scene, origins, directions):
    """Brute-force float64 first hits: (t, prim) per ray."""
    a = scene.arrays()
    tri = a.positions[a.faces]
    p0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    pvec = np.cross(directions[:, None], e2[None])
    det = np.einsum("tj,ltj->lt", e1, pvec)
    inv = 1.0 / np.where(np.abs(det) > 1e-300, det, np.inf)
    s = origins[:, None] - p0[None]
    u = np.einsum("ltj,ltj->lt", s, pvec) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("lj,ltj->lt", directions, q) * inv
    t = np.einsum("tj,ltj->lt", e2, q) * inv
    t = np.where((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9), t, np.inf)
    return t.min(axis=1), np.where(np.isfinite(t.min(axis=1)), t.argmin(axis=1), -1)


def test_next_hit_equals_brute_force_with_attributes(rng):
    scene = load_scene("cornell-box")
    tracer = ExactTracer(scene)
    origins = rng.uniform(-0.9, 0.9, (4000, 3)) + tracer.centre
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    hits = tracer.next_hit(origins, directions)
    t, prim = first_hits(scene, origins, directions)
    agree = hits.prim_id == prim
    # Ties at shared edges may pick either triangle, at the same depth.
    assert agree.mean() > 0.999 and np.allclose(hits.depth, t, rtol=0, atol=1e-9)
    hit = np.isfinite(t)
    assert hit.mean() > 0.5 and (hits.prim_id[~hit] == -1).all()
    assert np.allclose(hits.point[hit], origins[hit] + t[hit, None] * directions[hit], atol=1e-9)
    a = scene.arrays()
    both = agree & hit
    assert np.array_equal(hits.material[both], a.tri_material[prim[both]])
    emissive = np.array([m.emissive for m in scene.materials])[hits.material]
    assert (hits.emission[emissive] > 0).all() and not hits.emission[~emissive].any()
    assert np.allclose(np.linalg.norm(hits.normal[hit], axis=1), 1.0) and not hits.normal[~hit].any()


def test_exact_lists_do_not_change_with_scale_or_distance_from_the_origin():
    base = nested_boxes()
    reference = exact(base)
    for scale, shift in ((1e-3, 0.0), (1e4, 0.0), (1.0, 1e5), (1e-3, 1e5)):
        meshes = [Mesh(m.name, m.positions * scale + shift, m.faces, m.material) for m in base.meshes]
        moved = exact(scene_of(meshes, base.materials))
        assert np.array_equal(moved.offsets, reference.offsets), (scale, shift)
        assert np.array_equal(moved.prim_id, reference.prim_id), (scale, shift)
        depth = moved.depth / moved.radius - reference.depth / reference.radius
        assert np.abs(depth).max() < 1e-6, (scale, shift)


def rebuilt(template: BundleSet, lists: np.ndarray, depth: np.ndarray, prim: np.ndarray) -> BundleSet:
    """A BundleSet on ``template``'s lines with the given nodes (sorted here)."""
    order = np.lexsort((prim, depth, lists))
    lists, depth, prim = lists[order], depth[order], prim[order]
    offsets = np.zeros(template.list_count + 1, np.int64)
    np.cumsum(np.bincount(lists, minlength=template.list_count), out=offsets[1:])
    m = len(depth)
    return BundleSet(
        "test",
        template.directions,
        template.centre,
        template.radius,
        template.resolution,
        offsets,
        depth.astype(np.float32),
        np.zeros((m, 3), np.float32),
        np.zeros((m, 3), np.float32),
        np.zeros((m, 3), np.float32),
        prim.astype(np.int32),
        np.zeros(m, np.int32),
    )


def test_compare_bundles_counts_known_holes_spurious_and_redundant_nodes():
    truth = exact(nested_boxes())  # surfaces far apart: every exact node is its own cluster
    lists, depth, prim = truth.node_lists(), truth.depth.astype(np.float64), truth.prim_id
    tau = 1e-4 * truth.radius
    i = np.arange(len(depth))
    keep = i % 10 != 0  # every 10th exact node missing: holes
    dup = keep & (i % 7 == 1)  # a second node on a kept surface: redundant
    fake = i % 13 == 2  # a node before the line enters the scene: spurious
    error = 0.2 * tau * np.sin(i)  # depth errors within the tolerance
    test = rebuilt(
        truth,
        np.concatenate([lists[keep], lists[dup], lists[fake]]),
        np.concatenate([depth[keep] + error[keep], depth[dup] + 0.5 * tau, np.full(fake.sum(), -0.05 * truth.radius)]),
        np.concatenate([prim[keep], prim[dup], prim[fake]]),
    )
    r = compare_bundles(test, truth)
    assert r["exact_nodes"] == len(depth) and r["test_nodes"] == keep.sum() + dup.sum() + fake.sum()
    assert r["holes"] == (~keep).sum() and r["redundant"] == dup.sum() and r["spurious"] == fake.sum()
    assert r["matched"] == keep.sum() and r["agreement"] == pytest.approx(keep.mean())
    assert r["same_prim_rate"] == 1.0
    assert r["depth_error"]["max"] == pytest.approx(np.abs(error[keep]).max() / truth.radius, rel=1e-3, abs=1e-7)
    holes_k = np.bincount(lists[~keep] // truth.resolution**2, minlength=8) / np.bincount(
        lists // truth.resolution**2, minlength=8
    )
    assert np.allclose(r["per_direction"]["hole_rate"], holes_k)
    with pytest.raises(ValueError, match="not on the same lines"):
        compare_bundles(test, exact(nested_boxes(), seed=4))


def test_coincident_exact_nodes_need_one_test_node_each():
    truth = exact(coplanar_stack())
    lists, depth, prim = truth.node_lists(), truth.depth.astype(np.float64), truth.prim_id
    # Keep one node of each coincident pair: triangles 4, 5 and 6, 7 are the two quads at z = 0.2.
    keep = prim < 6
    r = compare_bundles(rebuilt(truth, lists[keep], depth[keep], prim[keep]), truth)
    assert r["holes"] == (~keep).sum() > 500 and r["redundant"] == 0 and r["spurious"] == 0
    doubled = rebuilt(
        truth,
        np.concatenate([lists, lists[~keep]]),
        np.concatenate([depth, depth[~keep]]),
        np.concatenate([prim, prim[~keep]]),
    )
    r = compare_bundles(doubled, truth)
    assert r["holes"] == 0 and r["redundant"] == (~keep).sum()


def test_gl_perfect_bundles_agree_with_exact_bundles_on_builtin_scenes(gl):
    for name in ("cornell-box", "furnace", "atrium"):
        scene = load_scene(name)
        ds = DirectionSet.make(8, seed=5)
        truth = ExactTracer(scene).bundles(ds, 64)
        r = compare_bundles(build(gl, scene, K=8, R=64, seed=5), truth)
        assert r["exact_nodes"] > 10000
        assert r["agreement"] >= 0.995 and r["spurious_rate"] <= 0.005, (name, r)
        assert r["depth_error"]["p99"] < 1e-5, (name, r["depth_error"])


def test_cli_exact_bundles_and_compare_bundles(tmp_path):
    common = ["cornell-box", "--directions", "8", "--resolution", "32", "--seed", "2"]
    assert run_evalkit("bundles", *common, "--method", "exact", "--out", str(tmp_path / "exact.npz")).returncode == 0
    assert (
        run_evalkit("bundles", *common, "--method", "perfect", "--out", str(tmp_path / "perfect.npz")).returncode == 0
    )
    r = run_evalkit("compare-bundles", str(tmp_path / "perfect.npz"), str(tmp_path / "exact.npz"), "--json")
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["agreement"] >= 0.995 and result["depth_tolerance"] == 1e-4 and "tolerance" in r.stdout
    assert len(result["per_direction"]["hole_rate"]) == 8
    other = run_evalkit(
        "bundles",
        "cornell-box",
        "--directions",
        "8",
        "--resolution",
        "16",
        "--method",
        "exact",
        "--out",
        str(tmp_path / "other.npz"),
    )
    assert other.returncode == 0
    bad = run_evalkit("compare-bundles", str(tmp_path / "perfect.npz"), str(tmp_path / "other.npz"))
    assert bad.returncode == 2 and "not on the same lines" in bad.stderr and bad.stderr.count("\n") == 1
    missing = run_evalkit("compare-bundles", str(tmp_path / "nope.npz"), str(tmp_path / "exact.npz"))
    assert missing.returncode == 2 and "nope.npz: no such file" in missing.stderr
    # Splats: the scene the file records tells leaks from offsets; another scene is refused.
    splats = str(tmp_path / "imperfect.npz")
    assert run_evalkit("bundles", *common, "--method", "imperfect", "--out", splats).returncode == 0
    r = run_evalkit("compare-bundles", splats, str(tmp_path / "exact.npz"), "--json")
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert r.returncode == 0 and "leaks" in r.stdout and not r.stderr, r.stderr
    assert result["leak_rate"] + result["offset_rate"] + result["coincident_rate"] == pytest.approx(result["hole_rate"])
    r = run_evalkit("compare-bundles", splats, str(tmp_path / "exact.npz"), "--scene", "furnace", "--json")
    assert r.returncode == 0 and json.loads(r.stdout.strip().splitlines()[-1])["leak_rate"] is None
    assert "holes not told apart (leaks, offsets, coincident): furnace is not the scene" in r.stderr
    assert r.stderr.count("\n") == 1


def test_cached_exact_bundles_on_other_lines_are_made_again(tmp_path):
    # A study's cache from before a change of the direction generator holds the same K, R and seed
    # on other lines; comparing GL bundles with it would fail, so it is rebuilt.
    from evalkit.study.artefacts import exact_bundles

    scene, run = load_scene("cornell-box"), {"directions": 4, "resolution": 16, "seed": 1}
    made = exact_bundles(scene, run, tmp_path)
    cache = next((tmp_path / "cache").glob("exact-*.npz"))
    ExactTracer(scene).bundles(DirectionSet.make(4, seed=2), 16).save(cache)
    again = exact_bundles(scene, run, tmp_path)
    assert again.directions.same_as(made.directions) and again.node_count == made.node_count
    assert BundleSet.load(cache).directions.same_as(made.directions)
