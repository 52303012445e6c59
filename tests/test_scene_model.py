"""The Scene model: validation, degenerate removal, recentring, features and content hash."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evalkit.core.errors import InputError
from evalkit.core.scene import Material, Mesh, assemble
from evalkit.core.scene.assemble import default_camera, look_at
from evalkit.core.scene.edges import _runs, flat_neighbours, sharp_edges
from evalkit.core.scene.model import Light
from evalkit.core.scene.tessellate import box, unit_sphere

QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])


def scene_of(*meshes, materials=None, lights=(), source="test.obj"):
    materials = materials or [Material("m")]
    return assemble("test", source, list(meshes), materials, list(lights), camera=None)


def test_nan_and_inf_vertices_are_errors_naming_file_and_vertex():
    for bad in (np.nan, np.inf, -np.inf):
        p = QUAD.copy()
        p[2, 1] = bad
        with pytest.raises(
            InputError, match=r"test\.obj: mesh 'q': 1 vertices have NaN or Inf coordinates \(first: vertex 2\)"
        ):
            scene_of(Mesh("q", p, QUAD_FACES, 0))


def test_out_of_range_and_negative_indices_are_errors():
    with pytest.raises(InputError, match="face index 4 is out of range for 4 vertices"):
        scene_of(Mesh("q", QUAD, np.array([[0, 1, 4]]), 0))
    with pytest.raises(InputError, match="face index -1 is out of range"):
        scene_of(Mesh("q", QUAD, np.array([[0, 1, -1]]), 0))


def test_huge_coordinates_are_errors():
    with pytest.raises(InputError, match="beyond the supported"):
        scene_of(Mesh("q", QUAD * 1e19, QUAD_FACES, 0))


def test_no_geometry_is_an_error():
    with pytest.raises(InputError, match="no triangle geometry"):
        scene_of()
    with pytest.raises(InputError, match="is empty"):
        scene_of(Mesh("q", QUAD, np.zeros((0, 3), int), 0))


def test_all_degenerate_is_no_geometry():
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    with pytest.raises(InputError, match=r"no triangle geometry \(1 triangles, all degenerate\)"):
        scene_of(Mesh("l", line, np.array([[0, 1, 2]]), 0))


def test_degenerate_triangles_are_removed_and_counted():
    p = np.vstack([QUAD, [[2, 0, 0], [3, 0, 0]]])  # 4, 5 collinear with 1
    faces = np.vstack([QUAD_FACES, [[1, 4, 5], [0, 0, 2]]])
    s = scene_of(Mesh("q", p, faces, 0))
    assert s.degenerate_removed == 2
    assert s.triangle_count == 2
    assert len(s.meshes[0].positions) == 4  # unused vertices go too
    assert any("2 degenerate triangle(s)" in w for w in s.warnings)
    assert s.surface_area() == pytest.approx(1.0)


def test_sliver_that_is_not_degenerate_is_kept():
    sliver = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-9, 0]], float)  # sin(angle) ~ 4e-9 >> 1e-12
    assert scene_of(Mesh("s", sliver, np.array([[0, 1, 2]]), 0)).triangle_count == 1


def test_zero_area_emitter_is_an_error():
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    mats = [Material("m"), Material("lamp", emission=(5, 5, 5))]
    with pytest.raises(InputError, match="emitter 'lamp' has zero area"):
        scene_of(Mesh("q", QUAD, QUAD_FACES, 0), Mesh("lamp", line, np.array([[0, 1, 2]]), 1), materials=mats)


def test_negative_light_or_reflectance_is_an_error():
    # A negative emitter was taken for no emitter, without a word (a Mitsuba area light's
    # radiance is not range-checked as a diffuse reflectance is).
    q = Mesh("q", QUAD, QUAD_FACES, 0)
    for material, message in [
        (Material("lamp", emission=(5, -5, 5)), "material 'lamp' emission is negative \\(down to -5\\)"),
        (Material("paint", albedo=(0.5, -0.1, 0.5)), "material 'paint' albedo is negative"),
        (Material("map", texture=np.full((2, 2, 3), -1.0, np.float32)), "material 'map' texture is negative"),
    ]:
        with pytest.raises(InputError, match=message):
            scene_of(q, materials=[material])


def test_bad_lights_are_errors():
    q = Mesh("q", QUAD, QUAD_FACES, 0)
    with pytest.raises(InputError, match="point light position contains NaN"):
        scene_of(q, lights=[Light("point", (1, 1, 1), position=np.array([np.nan, 0, 0]))])
    with pytest.raises(InputError, match="negative intensity"):
        scene_of(q, lights=[Light("directional", (-1, 1, 1), direction=np.array([0, -1.0, 0]))])
    with pytest.raises(InputError, match="cutoff angle"):
        scene_of(
            q,
            lights=[Light("spot", (1, 1, 1), position=np.zeros(3), direction=np.array([0, -1.0, 0]), cutoff_angle=0.0)],
        )


def test_far_from_origin_geometry_keeps_float32_precision_after_recentring():
    # Two parallel quads 1e-4 apart, 1e4 from the world origin: in float32 world coordinates
    # they collapse to one depth (docs/results/decisions.toml: float32-far-from-origin); recentred they stay distinct.
    offset = np.array([1e4, -1e4, 1e4])
    a, b = QUAD + offset, QUAD + offset + [0, 0, 1e-4]
    assert np.float32(a[0, 2]) == np.float32(b[0, 2])
    s = scene_of(Mesh("a", a, QUAD_FACES, 0), Mesh("b", b, QUAD_FACES, 0))
    za = np.float32(s.meshes[0].positions[0, 2])
    zb = np.float32(s.meshes[1].positions[0, 2])
    assert zb - za == pytest.approx(1e-4, rel=1e-3)
    np.testing.assert_allclose(s.origin, offset + [0.5, 0.5, 5e-5])
    # the camera and point lights move with the geometry
    s2 = assemble(
        "t",
        "t",
        [Mesh("a", a, QUAD_FACES, 0)],
        [Material("m")],
        [Light("point", (1, 1, 1), position=offset + [0.5, 0.5, 2.0])],
        default_camera(a.min(0), a.max(0)),
    )
    np.testing.assert_allclose(s2.lights[0].position, [0, 0, 2.0])
    assert np.linalg.norm(s2.camera.position) < 10


def test_depth_complexity_is_the_crofton_mean_crossing_count():
    # A closed sphere is crossed exactly twice by every line through its bounding sphere.
    p, f, n, uv = unit_sphere((256, 128))
    s = scene_of(Mesh("s", p, f, 0, n, uv))
    assert s.features().depth_complexity == pytest.approx(2.0, rel=2e-3)
    # A cube: area 24, bounding radius sqrt(3): 24 / (2 pi 3).
    p, f = box(-np.ones(3), np.ones(3))
    assert scene_of(Mesh("b", p, f, 0)).features().depth_complexity == pytest.approx(24 / (6 * math.pi))


def test_features_report_what_the_scene_uses():
    tex = np.full((4, 4, 3), 0.5, np.float32)
    mats = [Material("plain"), Material("tex", texture=tex), Material("lamp", emission=(1, 1, 1))]
    q = Mesh("q", QUAD, QUAD_FACES, 0)
    f = scene_of(q, materials=mats).features()
    assert (f.textures, f.emitters, f.environment, f.light_types) == (False, False, None, ())
    lights = [Light("constant", (0.2, 0.2, 0.2)), Light("point", (1, 1, 1), position=np.ones(3))]
    f = scene_of(
        q, Mesh("t", QUAD + 2, QUAD_FACES, 1), Mesh("l", QUAD + 4, QUAD_FACES, 2), materials=mats, lights=lights
    ).features()
    assert f.textures and f.emitters and f.environment == "constant"
    assert f.light_types == ("area", "constant", "point")
    assert f.triangle_count == 6


def test_content_hash_is_stable_and_sensitive():
    def make(albedo=0.5, z=0.0):
        return scene_of(Mesh("q", QUAD + [0, 0, z], QUAD_FACES, 0), materials=[Material("m", albedo=(albedo,) * 3)])

    h = make().content_hash()
    assert make().content_hash() == h
    assert make(albedo=0.51).content_hash() != h
    assert make(z=1e-9).content_hash() != h


def test_look_at_matches_mitsuba(mi):
    m = look_at([1, 2, 3], [0, 0.5, -1], [0, 1, 0])
    ref = np.array(mi.ScalarTransform4f().look_at(origin=[1, 2, 3], target=[0, 0.5, -1], up=[0, 1, 0]).matrix)
    np.testing.assert_allclose(m, ref, atol=1e-6)


def _normals(positions, faces):
    n = np.cross(positions[faces[:, 1]] - positions[faces[:, 0]], positions[faces[:, 2]] - positions[faces[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_sharp_edges_are_convex_creases_and_boundaries():
    """Where imperfect bundles' splats end (evalkit.core.scene.edges.sharp_edges): every edge of a box
    seen from outside, none seen from inside (a room's corners are concave), a quad's outline but
    not its diagonal, and none of a finely tessellated sphere."""
    p, f = box(np.zeros(3), np.ones(3), subdivisions=2)
    sharp = sharp_edges(p, f, _normals(p, f))
    # Each face's 2 x 2 quads: the edges on the face's outline are the box's edges, the rest lie flat.
    corners = p[f]
    ends = np.stack([corners, np.roll(corners, -1, axis=1)], axis=2)  # (T, 3 edges, 2 ends, 3)
    a, b = ends[:, :, 0], ends[:, :, 1]
    on_box_edge = ((a == b) & np.isin(a, [0.0, 1.0])).sum(axis=2) >= 2  # it runs along two of the box's planes
    assert sharp.sum() == 12 * 2 * 2 and np.array_equal(sharp, on_box_edge)  # edges x halves x sides

    p, f = box(np.zeros(3), np.ones(3), subdivisions=2, inward=True)
    assert not sharp_edges(p, f, _normals(p, f)).any()

    sharp = sharp_edges(QUAD, QUAD_FACES, _normals(QUAD, QUAD_FACES))
    # Faces (0, 1, 2) and (0, 2, 3): the diagonal is edge 2 of the first and edge 0 of the second.
    assert np.array_equal(sharp, [[True, True, False], [False, True, True]])

    p, f, _, _ = unit_sphere((48, 24))
    assert not sharp_edges(p, f, _normals(p, f)).any()
    assert sharp_edges(p, f, _normals(p, f), crease_degrees=2.0).any()  # its facets part by 7.5 degrees
    assert sharp_edges(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3))).shape == (0, 3)


def test_flat_neighbours_lie_in_the_triangles_plane():
    """Whose sharp edges cut a triangle's splats too (evalkit.core.scene.edges.flat_neighbours):
    across a quad's diagonal its other half, across a face's inner edges of a subdivided box the
    neighbours on the same face, never across the box's edges, nor between triangles facing
    opposite ways."""
    across = flat_neighbours(QUAD, QUAD_FACES, _normals(QUAD, QUAD_FACES))
    # The diagonal is edge 2 of the first triangle and edge 0 of the second.
    assert np.array_equal(across, [[-1, -1, 1], [0, -1, -1]])

    p, f = box(np.zeros(3), np.ones(3), subdivisions=2)
    across = flat_neighbours(p, f, _normals(p, f))
    sharp = sharp_edges(p, f, _normals(p, f))
    assert np.array_equal(across >= 0, ~sharp)  # every inner edge of a face, and nothing else
    t, e = np.nonzero(across >= 0)
    u = across[t, e]
    # A triangle of the same plane that holds the edge's two ends.
    assert all(f[t[i], e[i]] in f[u[i]] and f[t[i], (e[i] + 1) % 3] in f[u[i]] for i in range(len(t)))
    offsets = p[f[u]] - p[f[t, 0]][:, None, :]  # the neighbour's corners from the triangle's first
    assert np.abs(np.einsum("ijk,ik->ij", offsets, _normals(p, f)[t])).max() < 1e-12

    flipped = np.array([[0, 1, 2], [0, 3, 2]])  # the second faces down
    assert (flat_neighbours(QUAD, flipped, _normals(QUAD, flipped)) < 0).all()
    assert flat_neighbours(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3))).shape == (0, 3)


def test_runs_number_rows_as_unique_does_with_one_sort():
    # evalkit.core.scene.edges._runs: the welding of vertices and the numbering of edges, which
    # np.unique of rows did several times as slowly; equal rows must get one id, in sorted order.
    rows = np.random.default_rng(0).integers(-3, 3, (500, 3)).astype(np.float64)
    rows[7] = -0.0  # equal to 0.0, as np.unique takes it
    ids, counts, order = _runs(*rows.T)
    _, expected, expected_counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    assert np.array_equal(ids, expected.ravel()) and np.array_equal(counts, expected_counts)
    same = np.diff(ids[order]) == 0  # equal rows in their own order
    assert np.all(np.diff(ids[order]) >= 0) and np.all(np.diff(order)[same] > 0)
    assert [len(x) for x in _runs(np.zeros(0))] == [0, 0, 0]
