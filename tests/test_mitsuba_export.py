"""The Mitsuba export renders the same thing as the scene it came from.

Two renders of one scene with different seeds differ by Monte Carlo noise only; the export
passes when it differs from the original by no more than that (1.5x margin over the measured
seed-to-seed relMSE; relMSE in the tev form with eps = 0.01), and its mean radiance matches to
within 1 %. The original's pixel filter is set to box, like the export's, so that the two films
integrate the same footprint.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import relmse, write_texture

from evalkit.core.scene import load_scene
from evalkit.core.scene.mitsuba_io import load_mitsuba_dict, to_mitsuba_dict

SIZE, SPP, MAX_DEPTH = 32, 256, 4
NOISE_MARGIN = 1.5
MEAN_TOLERANCE = 0.01


def render(mi, scene_dict, seed):
    d = dict(scene_dict)
    d["integrator"] = {"type": "path", "max_depth": MAX_DEPTH}
    return np.array(mi.render(mi.load_dict(d), spp=SPP, seed=seed), dtype=np.float64)


def box_filtered(scene_dict, size=SIZE):
    d = dict(scene_dict)
    sensor = dict(d["sensor"])
    sensor["film"] = {**sensor["film"], "rfilter": {"type": "box"}, "width": size, "height": size}
    d["sensor"] = sensor
    return d


def assert_renders_alike(mi, images, original: dict, exported: dict):
    a = render(mi, original, seed=0)
    b = render(mi, original, seed=1)
    c = render(mi, exported, seed=2)
    noise = relmse(b, a)
    images.relmse_at_most("export", c[..., :3], a[..., :3], NOISE_MARGIN * noise)
    assert c.mean() == pytest.approx(a.mean(), rel=MEAN_TOLERANCE)


def test_cornell_box_export_renders_like_mi_cornell_box(mi, images):
    scene = load_scene("cornell-box")
    exported = to_mitsuba_dict(scene, mi, width=SIZE, height=SIZE)
    assert_renders_alike(mi, images, box_filtered(mi.cornell_box()), exported)


def test_textured_sphere_scene_export_renders_like_the_original(mi, tmp_path, images):
    write_texture(tmp_path / "t.png", size=16)
    T = mi.ScalarTransform4f
    original = {
        "type": "scene",
        "sensor": {
            "type": "perspective",
            "fov": 45,
            "to_world": T().look_at(origin=[0, 1, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE, "rfilter": {"type": "box"}},
        },
        "floor": {
            "type": "rectangle",
            "to_world": T().rotate([1, 0, 0], -90).scale(3),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "bitmap", "filename": str(tmp_path / "t.png")}},
        },
        "ball": {
            "type": "sphere",
            "center": [0, 0.6, 0],
            "radius": 0.6,
            "bsdf": {
                "type": "twosided",
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.3, 0.2]}},
            },
        },
        "sun": {"type": "directional", "direction": [0.3, -1, -0.2], "irradiance": 3.0},
        "sky": {"type": "constant", "radiance": 0.2},
        "lamp": {"type": "point", "position": [1, 2, 1], "intensity": 2.0},
    }
    scene = load_mitsuba_dict(original, name="sphere-scene")
    assert scene.features().textures
    assert_renders_alike(mi, images, original, to_mitsuba_dict(scene, mi))
