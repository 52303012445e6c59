"""Exact shadow maps for light vertices: a cube of shadow maps per vertex, rasterized from the
scene's triangles (those of the clusters each face sees) into tiles of the shadow atlas
(shaders/shadow_maps.glsl), looked up with the same filtering and bias as the point lights' maps
(shaders/light_visibility_exact.glsl). Faces wholly behind the vertex's surface are never looked
up, so they are not drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evalkit.core.settings import setting
from gpu_impl.layout import LIGHT_VISIBILITY_EXACT
from gpu_impl.lights import CUBE_FACES, GUARD_TEXELS, cube_views
from gpu_impl.units import LightVisibility

# Measured on cornell-box (B=3, K=32, R=128, 128x128, 32 frames x 16 paths): maps of 128 and 256
# texels gave the same errors there; 256 keeps contact shadows of larger scenes.
DEFAULT_MAP_SIZE = 256


@dataclass(frozen=True)
class ExactSettings:
    light_sample_map_size: int = setting(
        DEFAULT_MAP_SIZE, "texels per side of each light vertex's shadow cube faces", minimum=8, unit="texels"
    )


class ExactShadowMaps:
    """Each light vertex's six cube faces (`tiles_per_vertex`) in the shadow atlas of
    `gpu_impl.lights.ShadowLights`, drawn from the triangles every frame (the clusters each face
    sees: `gpu_impl.lights.view_clusters`)."""

    tiles_per_vertex = 6
    nbytes = 0  # the maps live in the shadow atlas

    def __init__(self, gl, gpu_scene, settings: ExactSettings):
        self.map_size = settings.light_sample_map_size

    def defines(self) -> dict:
        return {"LIGHT_VISIBILITY": LIGHT_VISIBILITY_EXACT}

    def check(self, light_vertices: int) -> None:
        """Nothing beyond the atlas, which `ShadowLights` checks."""

    def render(self, lights, positions: np.ndarray, normals: np.ndarray, seed: int, frame: int) -> None:
        """The cube views of the vertices at ``positions`` (relative to the bundle centre), with
        their surfaces' ``normals``, set in the lights' view table after the fixed lights' views,
        and drawn (the same for every ``seed`` and ``frame``)."""
        far_base = lights.gpu_scene.radius
        drawn = []
        for m, (position, normal) in enumerate(zip(positions, normals)):
            first = lights.fixed_views + self.tiles_per_vertex * m
            far = float(np.linalg.norm(position)) + far_base
            # The surface's normal as the views' axis: shaders/shadow_maps.glsl keeps only what is in front.
            for f, view in enumerate(cube_views(position, far, self.map_size, axis=normal)):
                lights.set_view(first + f, view, self.map_size)
                if faces_front(CUBE_FACES[f], normal):
                    drawn.append(first + f)
        lights.upload()
        lights.draw(drawn, clear=True)

    def release(self) -> None:
        """Nothing of its own: the lights own the atlas."""


def faces_front(face: tuple, normal: np.ndarray) -> bool:
    """Whether any direction of the cube face around axis ``face`` leaves the front of a surface with
    this normal: the others are never looked up. A face spans tan 45 degrees widened by the guard
    texels, at most 1 + 2 GUARD_TEXELS / 8 for the smallest map."""
    a = np.asarray(face, dtype=np.float64)
    return float(a @ normal) + float(np.abs(normal).sum() - abs(a @ normal)) * (1.0 + 2.0 * GUARD_TEXELS / 8) > 0.0


VISIBILITY = LightVisibility(
    name="exact",
    summary="a cube of shadow maps per light vertex, rasterized from the triangles",
    settings=ExactSettings,
    maps=ExactShadowMaps,
)
