"""Triangle grids for analytic shapes: Mitsuba's sphere, disk and cylinder on import, and the built-in scenes."""

from __future__ import annotations

import math

import numpy as np


def grid_faces(rows: int, cols: int) -> np.ndarray:
    """Two triangles per cell of a (rows+1) x (cols+1) row-major vertex grid, wound so that the
    front side faces d(row) x d(col)."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    a = (r * (cols + 1) + c).ravel()
    b, d = a + 1, a + cols + 1
    return np.concatenate([np.stack([a, d, b], -1), np.stack([b, d, d + 1], -1)])


def surface(fn, rows: int, cols: int):
    """A parametric surface P = fn(u, v) sampled on a (rows+1) x (cols+1) grid over [0, 1]^2.

    Returns (positions, faces, normals, uvs) with smooth normals from the finite-difference
    tangents (front side along dP/du x dP/dv) and uv = (v, u).
    """
    u, v = np.meshgrid(np.linspace(0, 1, rows + 1), np.linspace(0, 1, cols + 1), indexing="ij")
    p = fn(u, v)
    n = np.cross(np.gradient(p, axis=0), np.gradient(p, axis=1))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return p.reshape(-1, 3), grid_faces(rows, cols), n.reshape(-1, 3), np.stack([v, u], -1).reshape(-1, 2)


def unit_sphere(segments: tuple[int, int]):
    """Unit sphere, outward, with Mitsuba's uv (u = phi / 2pi, v = theta / pi) and exact normals.

    ``segments`` is (longitude, latitude). Returns (positions, faces, normals, uvs).
    """
    n_phi, n_theta = segments
    t, p = np.meshgrid(np.linspace(0.0, math.pi, n_theta + 1), np.linspace(0.0, 2 * math.pi, n_phi + 1), indexing="ij")
    pos = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    uv = np.stack([p / (2 * math.pi), t / math.pi], axis=-1).reshape(-1, 2)
    faces = grid_faces(n_theta, n_phi)
    # The grid's cells at the poles have two corners on the pole: keep their one real triangle.
    pole = (faces // (n_phi + 1) == 0).sum(axis=1) >= 2
    pole |= (faces // (n_phi + 1) == n_theta).sum(axis=1) >= 2
    return pos, faces[~pole], pos.copy(), uv


def unit_disk(segments: int):
    """Unit disk in z = 0 facing +z, as a fan, with Mitsuba's polar uv (u = r, v = phi / 2pi)."""
    phi = np.linspace(0.0, 2 * math.pi, segments + 1)
    rim = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=-1)
    pos = np.vstack([[0.0, 0.0, 0.0], rim])
    uv = np.vstack([[0.0, 0.0], np.stack([np.ones_like(phi), phi / (2 * math.pi)], axis=-1)])
    k = np.arange(1, segments + 1)
    faces = np.stack([np.zeros_like(k), k, k + 1], axis=-1)
    return pos, faces, np.tile([0.0, 0.0, 1.0], (len(pos), 1)), uv


def unit_cylinder(segments: int):
    """Mitsuba's cylinder: radius 1 around z from z = 0 to 1, open ends, outward, with its uv
    (u = phi / 2pi, v = z) and exact normals. Returns (positions, faces, normals, uvs)."""
    phi, z = np.meshgrid(np.linspace(0.0, 2 * math.pi, segments + 1), [0.0, 1.0], indexing="ij")
    normals = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=-1).reshape(-1, 3)
    pos = normals + np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1).reshape(-1, 3)
    uv = np.stack([phi / (2 * math.pi), z], axis=-1).reshape(-1, 2)
    return pos, grid_faces(segments, 1), normals, uv  # front side along d(phi) x d(z): outward


def box(lo: np.ndarray, hi: np.ndarray, subdivisions: int = 1, inward: bool = False):
    """An axis-aligned box [lo, hi], each face split into subdivisions^2 quads, front sides facing
    out (or in). Returns (positions, faces); faces share no vertices, so shading stays flat."""
    positions, faces = [], []
    t = np.linspace(0.0, 1.0, subdivisions + 1)
    for axis in range(3):
        b, c = (axis + 1) % 3, (axis + 2) % 3
        for is_hi, side in ((False, lo), (True, hi)):
            grid = np.zeros((subdivisions + 1, subdivisions + 1, 3))
            grid[..., axis] = side[axis]
            grid[..., b] = (lo[b] + t * (hi[b] - lo[b]))[:, None]
            grid[..., c] = (lo[c] + t * (hi[c] - lo[c]))[None, :]
            f = grid_faces(subdivisions, subdivisions)  # front side along e_b x e_c = +e_axis
            if is_hi == inward:
                f = f[:, ::-1]
            faces.append(f + sum(len(p) for p in positions))
            positions.append(grid.reshape(-1, 3))
    return np.concatenate(positions), np.concatenate(faces)


def subdivide(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray | None, uvs: np.ndarray | None, n: int):
    """Every triangle split into n^2 (each edge into n parts) in its own plane, with normals and
    uvs interpolated linearly (normals renormalized). The same surface with n^2 times the
    triangles; new vertices are not shared between the original triangles.

    Returns (positions, faces, normals, uvs)."""
    # Barycentrics (b1, b2) of the (n + 1)(n + 2) / 2 grid points of one triangle, and its n^2 faces.
    points = [(i, j) for i in range(n + 1) for j in range(n + 1 - i)]
    index = {p: k for k, p in enumerate(points)}
    local = []
    for i in range(n):
        for j in range(n - i):
            local.append((index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]))
            if i + j < n - 1:
                local.append((index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]))
    b = np.array(points, dtype=np.float64) / n
    weights = np.stack([1.0 - b[:, 0] - b[:, 1], b[:, 0], b[:, 1]], axis=1)  # (P, 3)

    def interpolate(attribute):
        return np.einsum("pc,fcd->fpd", weights, attribute[faces]).reshape(-1, attribute.shape[1])

    new_faces = (np.arange(len(faces))[:, None, None] * len(points) + np.array(local)[None]).reshape(-1, 3)
    new_normals = None
    if normals is not None:
        new_normals = interpolate(normals)
        new_normals /= np.linalg.norm(new_normals, axis=1, keepdims=True)
    return interpolate(positions), new_faces, new_normals, (interpolate(uvs) if uvs is not None else None)
