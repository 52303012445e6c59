"""Exact shadow maps for light vertices: a cube of shadow maps per vertex, rasterized from the
scene's triangles (those of the clusters each face sees) into tiles of the shadow atlas
(shaders/lights/shadow_maps.glsl), looked up with the same filtering and bias as the point lights' maps
(shaders/include/light_visibility_exact.glsl). Faces wholly behind the vertex's surface are never looked
up, so they are not drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evalkit.core.settings import setting
from gpu_impl.layout import LIGHT_VISIBILITY_EXACT
from gpu_impl.lights import CUBE_FACES, GUARD_TEXELS, cube_views
from gpu_impl.units import LightVisibility, TuneTerms

# Measured on cornell-box (B=3, K=32, R=128, 128x128, 32 frames x 16 paths): maps of 128 and 256
# texels gave the same errors there; 256 keeps contact shadows (a ball on a floor seen close under
# an area light: +9 % direct light at 32 texels, +1.4 % at 64, within its interval at 256;
# docs/results/decisions.toml: light-vertex-map-size). `evalkit tune` chooses a smaller size where a scene allows it.
DEFAULT_MAP_SIZE = 256


@dataclass(frozen=True)
class ExactSettings:
    light_sample_map_size: int = setting(
        DEFAULT_MAP_SIZE,
        "texels per side of each light vertex's shadow cube faces",
        minimum=8,
        unit="texels",
        symbol="M",
    )


class ExactShadowMaps:
    """Each light vertex's six cube faces (`tiles_per_vertex`) in the shadow atlas of
    `gpu_impl.lights.ShadowLights`, drawn from the triangles every frame (the clusters each face
    sees: `gpu_impl.lights.view_clusters`)."""

    tiles_per_vertex = 6
    map_size_setting = "light_sample_map_size"  # what a limit error names beside the light paths
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
            # The surface's normal as the views' axis: shaders/lights/shadow_maps.glsl keeps only what is in front.
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


def _time(x: dict) -> list:
    # t_texels: clearing, drawing and filtering the maps' texels, M^2 a face, for the frame's light
    # vertices (V light paths; the 8 emitter samples of eye paths). Their triangles' cost is the
    # strategy's t_light. Atrium, bidirectional, K=8 R=256 S=16 V=64: a frame took 4.0 s with 256
    # texels and 2.4 s with 32 (docs/results/decisions.toml: light-vertex-map-size).
    M = x["light_sample_map_size"]
    return [x["frames"] * (M / 256.0) ** 2 * x.get("light_paths", 8) / 8.0]


VISIBILITY = LightVisibility(
    name="exact",
    summary="a cube of shadow maps per light vertex, rasterized from the triangles",
    settings=ExactSettings,
    maps=ExactShadowMaps,
    tune=TuneTerms(
        axes={"light_sample_map_size": [32, 64, 128, 256]},
        time_terms=("t_texels",),
        time=_time,
        # A cycle of 5 against the bundle methods' 10 or 13 runs, the light paths' 3 and the eye
        # paths' 4, so that the map size moves apart from every other setting.
        calibration=tuple({"light_sample_map_size": m} for m in (32, 256, 64, 128, 256)),
        # m(M): the squared bias of a map's texel, as b is of a bundle pixel: the light leaked or
        # hidden beside contacts and edges is a band a texel or so wide. The direct light of a
        # close-up of a ball and a box on a floor under an area light, over Mitsuba's: 1.092 and
        # 0.971 with maps of 32 texels, 1.014 and 0.985 with 64, 1.003 and 1.000 with 256
        # (docs/results/decisions.toml: light-vertex-map-size): no one power of M, so renders at each M measure it.
        measured={"m": ("light_sample_map_size",)},
    ),
)
