"""Direction sets and the BundleSet type: frames, line geometry, .npz round trips and bad files."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from evalkit.core.bundleset import SPLAT_PRIM_ID, BundleSet, DirectionSet, orthonormal_frames
from evalkit.core.errors import InputError


def test_directions_are_independent_and_uniform_over_the_sphere():
    sets = [DirectionSet.make(16, seed=3, frame=f).directions for f in range(2000)]
    d = np.concatenate(sets)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    # Uniform: each coordinate is uniform in [-1, 1] (Archimedes), so each octant holds 1/8.
    octants = np.bincount((d > 0) @ np.array([1, 2, 4]), minlength=8) / len(d)
    assert np.abs(octants - 0.125).max() < 0.008  # 4.5 standard deviations of 32,000 draws
    # Independent within a set: the cosine between two of a frame's directions is uniform in
    # [-1, 1] too. An evenly spread set has no pair closer than its spacing (cos near 1).
    cos = np.concatenate([(s @ s.T)[np.triu_indices(16, 1)] for s in sets])
    assert np.mean(cos > 0.9) == pytest.approx(0.05, abs=0.003)


def test_frames_are_right_handed_and_orthonormal_even_at_the_poles(rng):
    d = np.concatenate([rng.normal(size=(1000, 3)), [[0, 0, 1], [0, 0, -1], [0, 0, -1 + 1e-12]]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    u, v = orthonormal_frames(d)
    for a, b in ((u, v), (u, d), (v, d)):
        assert np.abs(np.einsum("ij,ij->i", a, b)).max() < 1e-12
    assert np.allclose(np.cross(u, v), d, atol=1e-12)


def test_direction_sets_are_seeded_and_change_per_frame():
    a, b = DirectionSet.make(64, seed=5, frame=2), DirectionSet.make(64, seed=5, frame=2)
    assert np.array_equal(a.directions, b.directions) and np.array_equal(a.jitter, b.jitter)
    c = DirectionSet.make(64, seed=5, frame=3)
    assert not np.allclose(a.directions, c.directions)
    assert np.abs(a.jitter).max() <= 0.5 and np.abs(a.jitter).max() > 0.3
    assert not DirectionSet.make(64, jitter=False).jitter.any()


def small_bundles(method="exact", nodes_per_list=None) -> BundleSet:
    K, R = 2, 3
    ds = DirectionSet.make(K, seed=1)
    lengths = np.array(nodes_per_list if nodes_per_list is not None else [0, 1, 2] * 6)
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    m = int(offsets[-1])
    rng = np.random.default_rng(0)
    depth = np.concatenate([np.sort(rng.uniform(0, 2, n)) for n in lengths]).astype(np.float32)
    normal = np.tile(np.float32([0, 0, 1]), (m, 1))
    return BundleSet(
        method,
        ds,
        np.zeros(3),
        1.0,
        R,
        offsets,
        depth,
        normal,
        np.full((m, 3), 0.5, np.float32),
        np.zeros((m, 3), np.float32),
        np.arange(m, dtype=np.int32),
        np.zeros(m, np.int32),
        params={"seed": 1},
        stats={"nodes": m},
    )


def test_line_origins_follow_the_documented_grid():
    b = small_bundles()
    ds = b.directions
    o = b.line_origins(1)
    assert o.shape == (9, 3)
    # Line (i, j) = (2, 1) is list 1 * 3 + 2; its origin sits on the entry plane at depth 0.
    s = b.radius * (2 * (2 + 0.5 + ds.jitter[1, 0]) / 3 - 1)
    t = b.radius * (2 * (1 + 0.5 + ds.jitter[1, 1]) / 3 - 1)
    expected = s * ds.axis_u[1] + t * ds.axis_v[1] - b.radius * ds.directions[1]
    assert np.allclose(o[5], expected)
    assert np.allclose(o @ ds.directions[1], -b.radius)


def test_npz_round_trip_keeps_every_field(tmp_path):
    b = small_bundles()
    b.save(tmp_path / "b.npz")
    c = BundleSet.load(tmp_path / "b.npz")
    for name in ("offsets", *BundleSet.NODE_FIELDS):
        assert np.array_equal(getattr(b, name), getattr(c, name)), name
    assert np.array_equal(b.directions.jitter, c.directions.jitter)
    assert (c.method, c.radius, c.resolution, c.params, c.stats) == (
        b.method,
        b.radius,
        b.resolution,
        b.params,
        b.stats,
    )


def test_npz_round_trip_keeps_the_splats(tmp_path):
    b = small_bundles("imperfect")
    m = b.node_count
    b = replace(
        b,
        prim_id=np.full(m, SPLAT_PRIM_ID, np.int32),
        splat_triangle=np.arange(m, dtype=np.int32) % 5,
        splat_centre=np.random.default_rng(1).random((m, 3)),
    )
    assert b.check() is None
    b.save(tmp_path / "b.npz")
    c = BundleSet.load(tmp_path / "b.npz")
    for name in BundleSet.SPLAT_FIELDS:
        assert np.array_equal(getattr(b, name), getattr(c, name)), name
    assert np.array_equal(c.node_triangle(), np.arange(m) % 5)
    assert "splat nodes without" in replace(b, splat_triangle=None, splat_centre=None).check()


def test_bad_bundle_files_are_one_line_errors(tmp_path):
    with pytest.raises(InputError, match="missing.npz: no such file"):
        BundleSet.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="junk.npz: not a BundleSet .npz file"):
        BundleSet.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(InputError, match="other.npz: not a BundleSet file: missing"):
        BundleSet.load(tmp_path / "other.npz")


def test_check_finds_unsorted_lists_and_bad_offsets(tmp_path):
    b = small_bundles()
    assert b.check() is None
    b.depth[[1, 2]] = b.depth[[2, 1]]  # list 2 holds nodes 1 and 2
    assert "not sorted" in b.check()
    b.save(tmp_path / "b.npz")
    with pytest.raises(InputError, match="not sorted"):
        BundleSet.load(tmp_path / "b.npz")
    c = small_bundles()
    c.offsets = c.offsets[:-1]
    assert "offsets has shape" in c.check()
