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
        if len(positions):
            far = np.linalg.norm(positions, axis=1) + lights.gpu_scene.radius
            # The surface's normal as the views' axis: shaders/shadow_maps.glsl keeps only what is in front.
            views = cube_views(positions, far, self.map_size, axes=normals)
            lights.set_views(lights.fixed_views, views, self.map_size)
        lights.upload()  # the light records too, which every frame sets
        lights.clear_vertex_tiles()
        lights.draw(lights.fixed_views + np.flatnonzero(faces_front(normals)))

    def release(self) -> None:
        """Nothing of its own: the lights own the atlas."""


def faces_front(normals: np.ndarray) -> np.ndarray:
    """Per surface normal (M, 3) and cube face (in the order of `CUBE_FACES`), whether any direction
    of the face leaves the front of the surface: the others are never looked up. (M, 6) booleans.
    A face spans tan 45 degrees widened by the guard texels, at most 1 + 2 GUARD_TEXELS / 8 for the
    smallest map."""
    along = normals @ np.asarray(CUBE_FACES, dtype=np.float64).T  # (M, 6)
    across = np.abs(normals).sum(axis=1, keepdims=True) - np.abs(along)
    return along + across * (1.0 + 2.0 * GUARD_TEXELS / 8) > 0.0


VISIBILITY = LightVisibility(
    name="exact",
    summary="a cube of shadow maps per light vertex, rasterized from the triangles",
    settings=ExactSettings,
    maps=ExactShadowMaps,
)
