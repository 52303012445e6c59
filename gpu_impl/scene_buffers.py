"""A `Scene` uploaded to the GPU once, and shared by the bundle builders and the renderer."""

from __future__ import annotations

import numpy as np

from evalkit.core.bundleset import FRAME_PADDING
from evalkit.core.scene import Scene
from evalkit.core.scene.edges import edge_pairs, smooth_surfaces, solid_triangles, splat_cuts, triangle_neighbours
from gpu_impl.context import GLContext
from gpu_impl.layout import (
    BINDINGS,
    BSDF_ROUGH_CONDUCTOR,
    BSDF_ROUGH_PLASTIC,
    MATERIAL,
    MATERIAL_NEAREST,
    MATERIAL_TEXTURED,
    MATERIAL_TWOSIDED,
    MATERIAL_VERTEX_COLORS,
    MATERIAL_WRAP_CLAMP,
    MATERIAL_WRAP_MIRROR,
    MICROFACET_BECKMANN,
    MICROFACET_GGX,
    NO_TRIANGLE,
    TEXELS_PER_TRIANGLE,
    TRIANGLE,
    TRIANGLE_CUT,
    TRIANGLE_SMOOTH,
    TRIANGLE_SOLID,
    TRIANGLE_TURNED,
    VERTEX,
)

# Triangles per cluster of the culled raster passes (shadow maps), runs of the scene's own order:
# meshes list neighbours together, and their shared vertices stay near in the draw. How far (times
# the frame radius) a cluster's box is widened.
CLUSTER_TRIANGLES = 128
CLUSTER_PADDING = 1e-5
# The imperfect bundles' points: every smooth surface gets at least this many points' share of the
# CDF per direction, and the boost takes at most this share of the points from larger surfaces
# (surface_weights). A surface smaller than a point's share of the area got a point in only some
# directions; a line through it found nothing in the rest: on atrium (K=16, R=128, N=16384, s=2.5)
# 55 % of the leaks lay on surfaces of less than one point's share, 2.3 % of the crossings
# (docs/results/decisions.toml: small-surfaces-get-points).
SURFACE_LEAST_POINTS = 2
SURFACE_POINTS_SHARE = 0.1


class GpuScene:
    """The scene's triangles, materials and textures in GPU buffers (shaders/include/scene.glsl).

    Positions are uploaded as float32 relative to the bounding-sphere centre, where float32 keeps
    the most precision; ``centre`` (float64, scene space) and ``radius`` (the padded frame radius)
    place them back. ``scene`` is the host scene (the pose on the GPU), ``arrays`` its flattened
    copy that primitive ids refer to, and ``features`` what it uses. The maker releases it
    (`release`, or use it as a context manager).
    """

    def __init__(self, gl: GLContext, scene: Scene, sphere: tuple[np.ndarray, float] | None = None):
        self.gl = gl
        self.scene = scene
        self.features = scene.features()
        self.arrays = a = scene.arrays()
        centre, radius = sphere if sphere is not None else scene.bounding_sphere()
        self.centre = np.asarray(centre, dtype=np.float64)
        self.radius = radius * FRAME_PADDING
        self.triangle_count = len(a.faces)
        self._solid = None  # `solids`, found when a pass first needs them
        self._cuts = self._surfaces = None  # `splat_facts`, found when splats first need them
        self._cluster_bounds = None  # `cluster_bounds`, found when a pass first culls
        self._triangle_texels = None  # `triangle_texels`, made when splat builders first read them

        materials = np.zeros(len(scene.materials), dtype=MATERIAL)
        textures = []  # every texture of the scene in one texel buffer: materials', then the environment map's

        def place(texture: np.ndarray) -> int:
            """Append ``texture`` (H, W, 3) to the texel buffer; its first texel."""
            textures.append(texture)
            return sum(t.shape[0] * t.shape[1] for t in textures[:-1])

        for i, m in enumerate(scene.materials):
            materials["albedo"][i, :3] = m.albedo
            materials["emission"][i, :3] = m.emission
            flags = MATERIAL_TWOSIDED if m.twosided else 0
            to_uv = np.eye(3) if m.to_uv is None else m.to_uv
            materials["to_uv_u"][i, :3], materials["to_uv_v"][i, :3] = to_uv[0], to_uv[1]
            if m.texture is not None:
                h, w = m.texture.shape[:2]
                materials["texture"][i, :3] = (place(m.texture), w, h)
                flags |= MATERIAL_TEXTURED | (MATERIAL_NEAREST if m.filter_type == "nearest" else 0)
                flags |= {"repeat": 0, "mirror": MATERIAL_WRAP_MIRROR, "clamp": MATERIAL_WRAP_CLAMP}[m.wrap_mode]
            if m.vertex_colors:
                flags |= MATERIAL_VERTEX_COLORS
            materials["texture"][i, 3] = flags
            if m.gloss is not None:
                g = m.gloss
                kind = BSDF_ROUGH_CONDUCTOR if g.kind == "roughconductor" else BSDF_ROUGH_PLASTIC
                distribution = MICROFACET_GGX if g.distribution == "ggx" else MICROFACET_BECKMANN
                # A plastic's coat table, one value a texel (bsdf.glsl reads its red); a conductor has none.
                table = np.asarray(g.transmittance, np.float32)[None, :, None]
                first = place(np.repeat(table, 3, axis=2)) if g.transmittance else 0
                materials["gloss"][i] = (kind, distribution, first, int(g.nonlinear))
                materials["specular"][i] = (*g.specular_reflectance, g.alpha)
                materials["eta"][i] = (*g.eta, g.internal_reflectance)
                materials["k"][i, :3] = g.k
        # The environment map's first texel, or None (environment.glsl reads it from the same buffer).
        envmap = next((light.envmap for light in scene.lights if light.kind == "envmap"), None)
        self.envmap_first = place(envmap) if envmap is not None else None
        texels = (
            np.concatenate([np.asarray(t, dtype=np.float32).reshape(-1) for t in textures])
            if textures
            else np.zeros(3, np.float32)
        )

        # The area CDF for area-weighted point sampling (shaders/include/area_sampling.glsl) over the
        # triangles in the order of a space-filling curve through their centroids, so that
        # stratifying the CDF stratifies the surface however the mesh orders its triangles. The
        # imperfect shadow maps' points draw from it; the imperfect bundles' from their own
        # (`surface_area_cdf`), which keeps each surface's triangles in this order.
        self.curve_order = morton_order(a.positions[a.faces].mean(axis=1))
        cdf, guide = area_cdf(a.tri_area, self.curve_order)

        # The raster passes draw each triangle with a provoking vertex (its last) of its own, which
        # hands them the triangle's index as a flat attribute (shaders/bundles/perfect_bundles.glsl): on a
        # CPU rasterizer that costs a fraction of gl_PrimitiveID.
        self.raster_faces, self.raster_sources = provoking_vertices(a.faces, len(a.positions))
        raster_triangle = np.zeros(len(self.raster_sources), dtype=np.uint32)
        raster_triangle[self.raster_faces[:, 2]] = np.arange(len(a.faces), dtype=np.uint32)
        self.buffers = {
            **{name: gl.buffer(data) for name, data in self._geometry(a).items()},
            "INDICES": gl.buffer(a.faces.astype(np.uint32).tobytes()),
            "RASTER_INDICES": gl.buffer(self.raster_faces.astype(np.uint32).tobytes()),
            "RASTER_TRIANGLE": gl.buffer(raster_triangle.tobytes()),
            "MATERIALS": gl.buffer(materials.tobytes()),
            "TEXELS": gl.buffer(texels.tobytes()),
            "AREA_CDF": gl.buffer(cdf.tobytes()),
            "CDF_GUIDE": gl.buffer(guide.tobytes()),
        }

    def solids(self) -> np.ndarray:
        """Per triangle, whether it bounds a solid (`solid_triangles`; TRIANGLE_SOLID in the triangle
        records). Only the shadow maps' second surfaces ask (gpu_impl/lights.py), so it is found,
        and uploaded, the first time they do: 2 M triangles take seconds. Rigid poses keep it."""
        if self._solid is None:
            self._solid = solid_triangles(self.arrays.positions, self.arrays.faces)
            self.buffers["TRIANGLES"].write(self._triangles(self.arrays))
        return self._solid

    def splat_facts(self) -> None:
        """Find, and upload, what splats and lookups need of each triangle: the lines that cut its
        splats (`evalkit.core.scene.edges.splat_cuts`: its sharp edges and its flat neighbours';
        TRIANGLE_CUT in the triangle records), its smooth surface (`smooth_surfaces`) and the
        triangles across its edges (`triangle_neighbours`), with the edge pairs found once for all.
        The SPLAT_SHAPES buffer holds the cut lines (shaders/include/scene.glsl: splat_shape), the
        triangle texels all three (`triangle_texels`). Found the first time splats or lookups ask;
        rigid poses keep them."""
        if self._cuts is None:
            a = self.arrays
            pairs = edge_pairs(a.positions, a.faces, a.tri_normal) if len(a.faces) else None
            first, lines = splat_cuts(a.positions, a.faces, a.tri_normal, pairs=pairs)
            self._surfaces = smooth_surfaces(a.positions, a.faces, a.tri_normal, pairs=pairs)
            across, turned = triangle_neighbours(a.positions, a.faces, a.tri_normal, pairs=pairs)
            # The triangles across each edge (NO_TRIANGLE: none; the top bit: turned the other way).
            flagged = across.astype(np.uint32) | np.where(turned, TRIANGLE_TURNED, 0).astype(np.uint32)
            self._across = np.where(across < 0, NO_TRIANGLE, flagged)
            self._cut_first, self._cut_lines = first, lines.astype(np.float32).view(np.uint32).reshape(-1, 3)
            # Word t: where triangle t's cut lines start; word T: where the last one's end. Then
            # three words a line.
            head = (len(first) + 3 * first).astype(np.uint32)
            words = np.concatenate([head, self._cut_lines.reshape(-1)])
            self.buffers["SPLAT_SHAPES"] = self.gl.buffer(words.tobytes())
            self._cuts = np.diff(first)
            self.buffers["TRIANGLES"].write(self._triangles(a))

    def surfaces(self) -> np.ndarray:
        """Per triangle, its smooth surface (`smooth_surfaces`): what the imperfect bundles' point
        CDF gives each a share of (`surface_area_cdf`), and what tells a lookup's splats of the
        vertex's own surface (shaders/include/bundle_step.glsl: own_surface)."""
        self.splat_facts()
        return self._surfaces

    def splat_shapes(self) -> np.ndarray:
        """Per triangle, how many lines cut its splats (`splat_facts`)."""
        self.splat_facts()
        return self._cuts

    def cluster_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The corners (lowest, highest; (C, 3) each, relative to the bundle centre) of the box
        around each run of `CLUSTER_TRIANGLES` triangles in the scene's order: a pass that draws
        only what lies in a view draws the runs whose boxes reach into it (gpu_impl/lights.py:
        `view_clusters`). Boxes are widened by `CLUSTER_PADDING` of the frame radius, more than
        float32 clipping rounds. Found the first time a pass asks, and again after a pose."""
        if self._cluster_bounds is None:
            corners = self.arrays.positions[self.arrays.faces] - self.centre  # (T, 3, 3)
            pad = CLUSTER_PADDING * self.radius
            starts = np.arange(0, self.triangle_count, CLUSTER_TRIANGLES)
            lo = np.minimum.reduceat(corners.min(axis=1), starts) - pad
            hi = np.maximum.reduceat(corners.max(axis=1), starts) + pad
            self._cluster_bounds = (lo, hi)
        return self._cluster_bounds

    def triangle_texels(self):
        """The triangles as the splat passes and the lookups read them (shaders/include/common.glsl:
        TRIANGLE_TEXELS), a texture of `TEXELS_PER_TRIANGLE` texels a triangle: its three corners
        as the vertex records hold them, each with its vertex index, its normal as the triangle
        records hold it with the texel of its first cut line, then the triangles across its edges
        with its smooth surface (`splat_facts`); a record past the last with where its lines end;
        then the cut lines, a texel each.
        RGBA32UI, so every float's bits come back as they are. Made the first time they ask; poses
        rewrite the corners and normals (the cut lines, in barycentrics, stay)."""
        if self._triangle_texels is None:
            self.splat_facts()
            records = TEXELS_PER_TRIANGLE * (self.triangle_count + 1) + len(self._cut_lines)
            self._triangle_texels = self.gl.record_texture(records, 4, "u4", "triangle texels of the scene")
            self._write_triangle_texels(self.arrays)
        return self._triangle_texels

    def _write_triangle_texels(self, a) -> None:
        texture = self._triangle_texels
        texels = np.zeros((texture.width * texture.height, 4), np.uint32)
        T = len(a.faces)
        records = texels[: TEXELS_PER_TRIANGLE * (T + 1)].reshape(T + 1, TEXELS_PER_TRIANGLE, 4)
        corners = records[:T]
        corners[:, :3, :3] = self._positions(a)[a.faces].view(np.uint32)
        corners[:, :3, 3] = a.faces
        corners[:, 3, :3] = a.tri_normal.astype(np.float32).view(np.uint32)
        lines = TEXELS_PER_TRIANGLE * (T + 1)
        records[:, 3, 3] = lines + self._cut_first  # the texel of its first cut line; past the last, their end
        corners[:, 4, :3] = self._across
        corners[:, 4, 3] = self._surfaces
        texels[lines : lines + len(self._cut_lines), :3] = self._cut_lines
        texture.write(texels.tobytes())

    def _positions(self, a) -> np.ndarray:
        """Vertex positions as the GPU holds them: float32, relative to the bounding-sphere centre."""
        return (a.positions - self.centre).astype(np.float32)

    def _geometry(self, a) -> dict[str, bytes]:
        """The buffers that move with the geometry: positions (the raster passes' vertices),
        vertex records (position, normal, uv, colour: what shaders read) and triangle records."""
        positions = self._positions(a)
        vertices = np.zeros(len(positions), dtype=VERTEX)
        vertices["position"], vertices["normal"] = positions, a.normals
        vertices["uv"], vertices["color"] = a.uvs, a.colors
        return {
            "POSITIONS": positions[self.raster_sources].tobytes(),
            "VERTICES": vertices.tobytes(),
            "TRIANGLES": self._triangles(a),
        }

    def _triangles(self, a) -> bytes:
        """The triangle records: geometric normal, material and flags (TRIANGLE_SOLID once `solids`
        has been found, TRIANGLE_CUT once `splat_shapes` has)."""
        triangles = np.zeros(len(a.faces), dtype=TRIANGLE)
        triangles["normal"] = a.tri_normal
        triangles["material_flags"] = a.tri_material.astype(np.uint32) | np.where(
            a.tri_smooth, TRIANGLE_SMOOTH, 0
        ).astype(np.uint32)
        if self._solid is not None:
            triangles["material_flags"] |= np.where(self._solid, TRIANGLE_SOLID, 0).astype(np.uint32)
        if self._cuts is not None:
            triangles["material_flags"] |= np.where(self._cuts > 0, TRIANGLE_CUT, 0).astype(np.uint32)
        return triangles.tobytes()

    def pose(self, scene: Scene) -> None:
        """Upload ``scene``, the same scene posed at another time (rigid motion: same triangles,
        materials and areas). It must stay inside this scene's bundle frame."""
        a = scene.arrays()
        if len(a.faces) != self.triangle_count:
            raise ValueError(f"a posed scene must have the same {self.triangle_count} triangles, got {len(a.faces)}")
        reach = float(np.linalg.norm(a.positions - self.centre, axis=1).max())
        if reach > self.radius:
            raise ValueError(
                f"{scene.name}: the moving geometry reaches {reach:.6g} from the bundle centre, "
                f"outside the frame radius {self.radius:.6g}"
            )
        for name, data in self._geometry(a).items():
            self.buffers[name].write(data)
        if self._triangle_texels is not None:
            self._write_triangle_texels(a)
        self.scene, self.arrays = scene, a
        self._cluster_bounds = None

    @property
    def nbytes(self) -> int:
        texels = self._triangle_texels
        return sum(b.size for b in self.buffers.values()) + (0 if texels is None else 16 * texels.width * texels.height)

    def bind(self) -> None:
        """Bind every scene buffer shaders read at its storage binding (layout.BINDINGS); positions
        reach the raster passes through their vertex arrays."""
        for name, buffer in self.buffers.items():
            if name in BINDINGS:
                buffer.bind_to_storage_buffer(BINDINGS[name])

    def vertex_array(self, program, *extra):
        """A new vertex array of the indexed triangles for ``program``: positions, and on each
        triangle's provoking vertex its index (``in_triangle``, for a flat varying); the raster
        passes read the rest from storage. ``extra``: more (buffer, format, name) content, such as
        a per-instance attribute. The caller owns and releases it."""
        b = self.buffers
        content = [(b["POSITIONS"], "3f", "in_position"), (b["RASTER_TRIANGLE"], "1u", "in_triangle"), *extra]
        return self.gl.vertex_array(
            program, content, index_buffer=b["RASTER_INDICES"], index_element_size=4, skip_errors=True
        )

    def release(self) -> None:
        for buffer in self.buffers.values():
            buffer.release()
        self.buffers.clear()
        if self._triangle_texels is not None:
            self._triangle_texels.release()
            self._triangle_texels = None

    def __enter__(self) -> GpuScene:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def area_cdf(weights: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inclusive CDF of the triangles' sampling ``weights`` (T,) in ``order``, as records of
    (cdf float32, triangle uint32), and a guide to it (uint32): for u in [b / G, (b + 1) / G) the
    answer lies between entries guide[b] and guide[b + 1], so a search takes a step or two instead
    of log2(T). Summed in float64; the last entry is exactly 1 so every u in [0, 1) finds a
    triangle. A triangle under float32's resolution of the CDF (about 6e-8 of the total) is
    sampled in proportion to rounding, not weight."""
    cdf = np.zeros(len(order), dtype=[("cdf", "<f4"), ("triangle", "<u4")])
    cdf["cdf"] = np.cumsum(weights[order]) / weights.sum()
    cdf["cdf"][-1] = 1.0
    cdf["triangle"] = order
    buckets = 1 << min(20, max(1, int(np.ceil(np.log2(len(order))))))
    guide = np.searchsorted(cdf["cdf"], np.arange(buckets + 1) / buckets, side="right").clip(0, len(order) - 1)
    return cdf, guide.astype(np.uint32)


def surface_weights(areas: np.ndarray, surfaces: np.ndarray, points: int) -> np.ndarray:
    """Per triangle, its weight in the imperfect bundles' point CDF: its area, scaled up on the
    smooth surfaces (``surfaces``, `evalkit.core.scene.edges.smooth_surfaces`) too small for
    `SURFACE_LEAST_POINTS` of ``points`` per direction, so that each gets that share of the CDF.
    The boost takes at most `SURFACE_POINTS_SHARE` of the points from the rest (when the scene has
    more small surfaces than that pays for, each gets the same smaller share)."""
    area = np.bincount(surfaces, weights=areas)
    total, k = area.sum(), SURFACE_LEAST_POINTS
    # With the b smallest surfaces raised to the least weight f, the total weight is rest_b + b f
    # (rest_b: the others' area). f solves f = k (rest_b + b f) / N for the b whose surfaces it
    # lies above and the others below; or, where that spends more than the share, rest_b + b f =
    # total / (1 - share). Both sides grow with f, so the least of the consistent answers holds.
    smallest = np.sort(area)
    b = np.arange(len(smallest) + 1)
    rest = total - np.concatenate([[0.0], np.cumsum(smallest)])
    below, above = np.concatenate([[0.0], smallest]), np.concatenate([smallest, [np.inf]])
    with np.errstate(divide="ignore", invalid="ignore"):
        shared = np.where(points > k * b, k * rest / (points - k * b), np.inf)
        capped = np.where(b > 0, (total / (1 - SURFACE_POINTS_SHARE) - rest) / b, np.inf)
    least = min(f[(f >= below) & (f <= above)].min(initial=np.inf) for f in (shared, capped))
    scale = np.maximum(area, least) / np.maximum(area, 1e-300)
    return areas * scale[surfaces]


def surface_area_cdf(
    arrays, surfaces: np.ndarray, points: int, curve_order: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """The imperfect bundles' point CDF (`area_cdf`) for ``points`` per direction: weights from
    `surface_weights`, each smooth surface's triangles in one run (in ``curve_order``, the
    triangles along the Morton curve, within it; the surfaces along the curve through their
    centroids), so that stratified points give a
    surface with 2 / N of the CDF a point in every direction (a run of 1 / N misses one direction
    in six on average: its two strata's points can both fall outside it). Also the weights' total
    over the area's: how much denser the points are than area alone would make them, which the
    splat radius' unit takes in."""
    weights = surface_weights(arrays.tri_area, surfaces, points)
    centroids = arrays.positions[arrays.faces].mean(axis=1)
    area = np.bincount(surfaces, weights=arrays.tri_area)
    surface_centroids = (
        np.stack([np.bincount(surfaces, weights=centroids[:, i] * arrays.tri_area) for i in range(3)], axis=1)
        / np.maximum(area, 1e-300)[:, None]
    )
    surface_rank = np.empty(len(area), np.int64)
    surface_rank[morton_order(surface_centroids)] = np.arange(len(area))
    curve_rank = np.empty(len(centroids), np.int64)
    curve_rank[curve_order] = np.arange(len(centroids))
    order = np.lexsort((curve_rank, surface_rank[surfaces])).astype(np.uint32)
    cdf, guide = area_cdf(weights, order)
    return cdf, guide, float(weights.sum() / arrays.tri_area.sum())


def morton_order(points: np.ndarray) -> np.ndarray:
    """The order of ``points`` (M, 3) along a Morton (Z-order) curve through their bounding box, 21
    bits per axis: nearby points come out near each other in the order."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    cells = ((points - lo) / np.maximum(hi - lo, 1e-300) * (2**21 - 1)).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(21):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable").astype(np.uint32)


def provoking_vertices(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (T, 3) whose last (provoking) vertex belongs to no other triangle's last corner,
    with their corners rotated (the winding kept), and for every vertex of that layout the scene
    vertex it copies: each triangle takes one of its own vertices that is still free, and a
    triangle whose three are taken gets a copy of its first."""
    T = len(faces)
    chosen = np.full(T, -1, dtype=np.int64)  # the corner that is provoking
    taken = np.zeros(vertex_count, dtype=bool)
    for corner in range(3):
        open_ = np.nonzero(chosen < 0)[0]
        vertex = faces[open_, corner]
        free = ~taken[vertex]
        _, first = np.unique(vertex[free], return_index=True)  # one triangle per free vertex
        winners = open_[free][first]
        chosen[winners] = corner
        taken[faces[winners, corner]] = True
    rows = np.arange(T)
    copies = np.nonzero(chosen < 0)[0]
    chosen[copies] = 0
    # Rotate each triangle so its provoking corner comes last: (a, b, c) -> (b, c, a) or (c, a, b).
    order = (np.arange(3)[None, :] + chosen[:, None] + 1) % 3
    raster = faces[rows[:, None], order].astype(np.int64)
    sources = np.concatenate([np.arange(vertex_count), faces[copies, 0]])
    raster[copies, 2] = vertex_count + np.arange(len(copies))
    return raster, sources
