"""Property tests (hypothesis; derandomized in CI): GL perfect bundles under rigid transforms of
the whole scene, under permutation of triangles and vertices, and under splitting a triangle in
two; the same seed gives the same bundles."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_bundles import build, nested_boxes, scene_of
from test_stress import transformed

from evalkit.core.bundleset import DirectionSet
from evalkit.core.scene import Mesh
from evalkit.metrics.bundles import compare_bundles
from gpu_impl.registry import METHODS
from references.embree import ExactTracer

EXAMPLES = settings(max_examples=6)


def rotation(q) -> np.ndarray:
    """The rotation of a (non-zero) quaternion."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


quaternions = st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1)


@EXAMPLES
@given(q=quaternions, log_scale=st.floats(-3, 4), shift=st.tuples(*[st.floats(-1e5, 1e5)] * 3))
def test_rigid_transforms_and_scale_keep_perfect_bundles_exact(gl, q, log_scale, shift):
    scene = transformed(nested_boxes(), 10.0**log_scale, rotation(q), shift)
    directions = DirectionSet.make(6, seed=1)
    r = compare_bundles(build(gl, scene, "perfect", K=6, R=32, seed=1), ExactTracer(scene).bundles(directions, 32))
    assert r["agreement"] >= 0.995 and r["spurious_rate"] <= 0.005, r


@EXAMPLES
@given(data=st.data())
def test_permuting_triangles_and_vertices_changes_only_primitive_ids(gl, data):
    base = nested_boxes()
    meshes, prim_map, offset = [], [], 0
    for m in base.meshes:
        faces = data.draw(st.permutations(range(len(m.faces))))
        verts = np.array(data.draw(st.permutations(range(len(m.positions)))))
        inverse = np.argsort(verts)  # new index of each old vertex
        meshes.append(Mesh(m.name, m.positions[verts] + base.origin, inverse[m.faces[faces]], m.material))
        prim_map.append(offset + np.array(faces))
        offset += len(m.faces)
    permuted = scene_of(meshes, base.materials)
    a, b = build(gl, base, "perfect", K=6, R=32), build(gl, permuted, "perfect", K=6, R=32)
    assert np.array_equal(a.offsets, b.offsets)
    assert np.array_equal(a.depth, b.depth)  # bitwise: the same triangles, drawn in another order
    old_of_new = np.concatenate(prim_map)
    lists = a.node_lists()
    assert sorted(zip(lists, a.prim_id)) == sorted(zip(lists, old_of_new[b.prim_id]))


@EXAMPLES
@given(triangle=st.integers(0, 11), t=st.floats(0.05, 0.95))
def test_splitting_triangles_in_two_keeps_coverage_watertight(gl, triangle, t):
    # Split one of the outer box's triangles in two at a point of the edge (a, b) it shares with
    # its neighbour (a box face's diagonal; the faces have their own vertices), and the neighbour
    # too, so the mesh stays conforming. (Splitting one side only leaves a T-junction, which no
    # rasterizer keeps watertight: the new vertex snaps off the neighbour's edge.)
    base = nested_boxes()
    m = base.meshes[0]
    edges = [tuple(np.roll(m.faces[triangle], -e)[:2]) for e in range(3)]
    shared = [(p, q) for p, q in edges if sum(p in f and q in f for f in m.faces) == 2]
    a, b = shared[0]
    new = len(m.positions)
    positions = np.vstack([m.positions, (1 - t) * m.positions[a] + t * m.positions[b]]) + base.origin
    faces = []
    for face in m.faces:
        ring = list(face)
        if a in ring and b in ring:  # this triangle and its neighbour across (a, b)
            i = ring.index(a)
            if ring[(i + 1) % 3] == b:
                _, _, other = np.roll(face, -i)
                faces += [[a, new, other], [new, b, other]]
            else:  # the neighbour runs b -> a
                i = ring.index(b)
                _, _, other = np.roll(face, -i)
                faces += [[b, new, other], [new, a, other]]
        else:
            faces.append(list(face))
    assert len(faces) == len(m.faces) + 2
    split = scene_of(
        [
            Mesh(m.name, positions, np.array(faces), m.material),
            *[Mesh(x.name, x.positions + base.origin, x.faces, x.material) for x in base.meshes[1:]],
        ],
        base.materials,
    )
    before, after = build(gl, base, "perfect", K=6, R=48), build(gl, split, "perfect", K=6, R=48)
    # Every line crosses the split surface exactly as often as before: no line falls through
    # the new edges (a hole) or is counted on both sides of one (a duplicate).
    assert np.array_equal(before.list_lengths(), after.list_lengths())
    assert np.abs(before.depth - after.depth).max() <= 1e-5 * before.radius


@EXAMPLES
@given(seed=st.integers(0, 2**31 - 1), method=st.sampled_from(METHODS.names))
def test_the_same_seed_gives_the_same_bundles(gl, seed, method):
    scene = nested_boxes()
    a = build(gl, scene, method, K=4, R=32, seed=seed, points=2048)
    b = build(gl, scene, method, K=4, R=32, seed=seed, points=2048)
    for name in ("offsets", *a.NODE_FIELDS):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
