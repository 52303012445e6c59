"""A `Scene` uploaded to the GPU once, and shared by the bundle builders and the renderer."""

from __future__ import annotations

import numpy as np

from evalkit.core.bundleset import FRAME_PADDING
from evalkit.core.scene import Scene
from gpu_impl.context import GLContext
from gpu_impl.layout import BINDINGS, MATERIAL, MATERIAL_TEXTURED, MATERIAL_TWOSIDED, TRIANGLE, TRIANGLE_SMOOTH


class GpuScene:
    """The scene's triangles, materials and textures in GPU buffers (shaders/scene.glsl).

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

        materials = np.zeros(len(scene.materials), dtype=MATERIAL)
        texels, first = [], 0
        for i, m in enumerate(scene.materials):
            materials["albedo"][i, :3] = m.albedo
            materials["emission"][i, :3] = m.emission
            flags = MATERIAL_TWOSIDED if m.twosided else 0
            if m.texture is not None:
                h, w = m.texture.shape[:2]
                materials["texture"][i, :3] = (first, w, h)
                flags |= MATERIAL_TEXTURED
                texels.append(np.ascontiguousarray(m.texture, dtype=np.float32).reshape(-1))
                first += h * w
            materials["texture"][i, 3] = flags
        texels = np.concatenate(texels) if texels else np.zeros(3, dtype=np.float32)

        # Inclusive area CDF for area-weighted point sampling, summed in float64. Its last entry is
        # exactly 1 so every u in [0, 1) finds a triangle. A triangle under float32's resolution
        # of the CDF (about 6e-8 of the total area) is sampled in proportion to rounding, not area.
        cdf = np.cumsum(a.tri_area) / a.tri_area.sum()
        cdf[-1] = 1.0

        self.buffers = {
            **{name: gl.buffer(data) for name, data in self._geometry(a).items()},
            "UVS": gl.buffer(a.uvs.astype(np.float32).tobytes()),
            "INDICES": gl.buffer(a.faces.astype(np.uint32).tobytes()),
            "MATERIALS": gl.buffer(materials.tobytes()),
            "TEXELS": gl.buffer(texels.astype(np.float32).tobytes()),
            "AREA_CDF": gl.buffer(cdf.astype(np.float32).tobytes()),
        }

    def _geometry(self, a) -> dict[str, bytes]:
        """The buffers that move with the geometry: positions, vertex normals, triangle records."""
        triangles = np.zeros(len(a.faces), dtype=TRIANGLE)
        triangles["normal"] = a.tri_normal
        triangles["material_flags"] = a.tri_material.astype(np.uint32) | np.where(a.tri_smooth, TRIANGLE_SMOOTH, 0).astype(np.uint32)
        return {"POSITIONS": (a.positions - self.centre).astype(np.float32).tobytes(),
                "NORMALS": a.normals.astype(np.float32).tobytes(), "TRIANGLES": triangles.tobytes()}

    def pose(self, scene: Scene) -> None:
        """Upload ``scene``, the same scene posed at another time (rigid motion: same triangles,
        materials and areas). It must stay inside this scene's bundle frame."""
        a = scene.arrays()
        if len(a.faces) != self.triangle_count:
            raise ValueError(f"a posed scene must have the same {self.triangle_count} triangles, got {len(a.faces)}")
        reach = float(np.linalg.norm(a.positions - self.centre, axis=1).max())
        if reach > self.radius:
            raise ValueError(f"{scene.name}: the moving geometry reaches {reach:.6g} from the bundle centre, "
                             f"outside the frame radius {self.radius:.6g}")
        for name, data in self._geometry(a).items():
            self.buffers[name].write(data)
        self.scene, self.arrays = scene, a

    @property
    def nbytes(self) -> int:
        return sum(b.size for b in self.buffers.values())

    def bind(self) -> None:
        """Bind every scene buffer at its storage binding (context.BINDINGS)."""
        for name, buffer in self.buffers.items():
            buffer.bind_to_storage_buffer(BINDINGS[name])

    def vertex_array(self, program):
        """A new vertex array of the indexed triangles for ``program`` (positions only: the raster
        passes read the rest from storage); the caller owns and releases it."""
        b = self.buffers
        content = [(b["POSITIONS"], "3f", "in_position")]
        return self.gl.vertex_array(program, content, index_buffer=b["INDICES"], index_element_size=4, skip_errors=True)

    def release(self) -> None:
        for buffer in self.buffers.values():
            buffer.release()
        self.buffers.clear()

    def __enter__(self) -> "GpuScene":
        return self

    def __exit__(self, *exc) -> None:
        self.release()
