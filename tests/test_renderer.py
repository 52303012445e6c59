"""The eye-path renderer: analytic furnace values, convergence to the committed Mitsuba references,
shadow-mapped direct light against Mitsuba, bounce accounting, determinism and the CLI.

Every threshold here was measured with the command in its comment, then given a margin; the
comments give the measured values.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import cornell_reference, describe_interval, mean_interval, relmse, render_with, run_evalkit

from evalkit.core.exr import read_exr
from evalkit.core.scene import Light, Material, Mesh, Scene, assemble, load_scene
from evalkit.core.scene.assemble import look_at
from evalkit.core.scene.builtin import furnace_radiance
from evalkit.core.scene.model import Camera
from evalkit.core.scene.tessellate import box, unit_sphere
from evalkit.core.settings import RenderSettings
from evalkit.metrics.confidence import mean_ratio
from gpu_impl.lights import EmitterSamples
from gpu_impl.registry import METHODS, resolve
from references.mitsuba import reference


def render(gl, scene, **settings):
    return render_with(gl, scene, **settings)


def block_mean(image: np.ndarray, b: int) -> np.ndarray:
    h, w, _ = image.shape
    return image.reshape(h // b, b, w // b, b, 3).mean(axis=(1, 3))


# -- furnace: every surface emits 1 and reflects 0.5, so bounce j adds 0.5^j exactly --------------

# The frame's K directions are independent, so every frame's image mean scatters by about 9 %
# (the mean of 2 cos over 16 random directions): 1024 frames leave a 95 % interval of about
# +-0.9 % on the indirect mean. Measured (16x16, K=16, R=128, 1024 frames, no NEE), ratio and
# interval: B=1 seed 0 0.9971 [0.9886, 1.0056], seed 1 0.9961 [0.9875, 1.0048], seed 2 0.9913
# [0.9826, 0.9999]; B=3 0.9947 [0.9855, 1.0038], 0.9922 [0.9829, 1.0016], 0.9887 [0.9792,
# 0.9982]; direct 0.9976 to 0.9998, +-0.3 %. Before eye paths landed where their ray does
# (shaders/paths/eye_paths.glsl), B=1 -0.47, -0.52, -1.05 % and B=3 -0.73, -0.97, -1.36 %.
FURNACE_TOLERANCE = 0.01


def furnace_ratio(gl, resolution, frames, bounces=1, light_samples=0, seed=0):
    """The furnace's (16x16, K=16) direct and indirect frame means over the analytic values (F, 3)."""
    result = render(
        gl,
        load_scene("furnace"),
        bounces=bounces,
        directions=16,
        resolution=resolution,
        frames=frames,
        width=16,
        height=16,
        light_samples=light_samples,
        seed=seed,
    )
    assert np.allclose(result.images["total"], result.images["direct"] + result.images["indirect"])
    exact = {"direct": furnace_radiance(2), "indirect": furnace_radiance(bounces + 2) - furnace_radiance(2)}
    return {name: result.frame_means[name] / value for name, value in exact.items()}


def interval(frame_ratios) -> dict:
    """The mean and 95 % interval of frame ratios to an exact value (no reference noise); a list of
    several renders' ratios pools their frames."""
    frames = np.concatenate(frame_ratios) if isinstance(frame_ratios, list) else frame_ratios
    ones = np.ones((4, 4, 3))
    return mean_ratio(frames, ones, 0 * ones)["all"]


@pytest.mark.long
@pytest.mark.parametrize("bounces", [1, 3])
def test_furnace_matches_the_analytic_radiance(gl, bounces):
    # The bundles' transport alone: paths find the emitting walls by hitting them.
    ratios = furnace_ratio(gl, 128, 1024, bounces)
    direct, indirect = interval(ratios["direct"]), interval(ratios["indirect"])
    assert direct["lo"] >= 1 - FURNACE_TOLERANCE and direct["hi"] <= 1 + FURNACE_TOLERANCE, describe_interval(direct)
    assert indirect["ratio"] == pytest.approx(1.0, abs=FURNACE_TOLERANCE), describe_interval(indirect)
    assert indirect["lo"] >= 1 - 2 * FURNACE_TOLERANCE and indirect["hi"] <= 1 + 2 * FURNACE_TOLERANCE


@pytest.mark.slow
@pytest.mark.parametrize("bounces", [1, 3])
def test_furnace_matches_the_analytic_radiance_with_next_event_estimation(gl, bounces):
    # Every wall emits: multiple importance sampling splits each wall's light between the emitter
    # samples and the bundle paths. The frame's 8 shared samples make seeds scatter, so the test
    # pools the frames of four. This test's own settings were not re-measured after eye paths came
    # to land where their ray does; the furnace with the same M=8 at K=256, R=128, 128x128, B=1,
    # 64 frames, seeds 0-3 pooled: indirect 1.0014 [0.9907, 1.0121], direct 1.0040 [0.9987, 1.0093].
    ratios = [furnace_ratio(gl, 128, 1024, bounces, light_samples=8, seed=seed) for seed in range(4)]
    direct = interval([r["direct"] for r in ratios])
    indirect = interval([r["indirect"] for r in ratios])
    assert direct["lo"] >= 1 - FURNACE_TOLERANCE and direct["hi"] <= 1 + FURNACE_TOLERANCE, describe_interval(direct)
    assert indirect["ratio"] == pytest.approx(1.0, abs=FURNACE_TOLERANCE), describe_interval(indirect)
    assert indirect["lo"] >= 1 - 1.5 * FURNACE_TOLERANCE and indirect["hi"] <= 1 + 1.5 * FURNACE_TOLERANCE


@pytest.mark.parametrize("resolution", [16, 32])
def test_no_light_is_lost_behind_concave_edges(gl, resolution):
    # A vertex near a concave edge (the floor by a wall) has lines up to a bundle pixel beside it,
    # which may pass behind the wall and meet its back: skipping nodes whose plane the ray cannot
    # reach, landing where the ray meets the surface another line finds, and letting no line vote
    # that passes under the vertex's surface and meets nothing keep that light. Measured (seed 0,
    # B=1, 1024 frames), indirect ratio and interval: R = 16 0.9922 [0.9836, 1.0007], R = 32 0.9959
    # [0.9874, 1.0044], R = 64 0.9968 [0.9884, 1.0053]. Before the lines voted (the open side's line
    # deciding alone): 0.9889 [0.9802, 0.9976], 0.9951 [0.9865, 1.0036], 0.9967; before landing on
    # the ray's point, -1.26 % at R = 32 and -2.82 % at R = 16; before skipping unreachable planes,
    # -5.7 % at R = 32. tests/test_bundle_metrics.py counts the lookups that leave the box.
    indirect = interval(furnace_ratio(gl, resolution, 1024)["indirect"])
    assert indirect["lo"] >= 0.98 and indirect["hi"] <= 1.02, describe_interval(indirect)


def test_coherent_paths_keep_each_pixels_estimate_and_spread_the_image_mean(gl):
    # Paths of 32 neighbouring samples sharing each bounce's bundle: each pixel's estimate is as
    # unbiased and as noisy as with a choice per path, while the frames' image means spread more
    # (the choice is shared: neighbours' errors are correlated). docs/method.md: coherent paths.
    furnace = load_scene("furnace")
    exact = furnace_radiance(3) - furnace_radiance(2)
    own, shared = (
        render(gl, furnace, directions=16, resolution=32, frames=256, width=16, height=16, coherent_paths=t)
        for t in (1, 32)
    )
    ratio = interval(shared.frame_means["indirect"] / exact)
    assert ratio["lo"] <= 1.0 <= ratio["hi"], describe_interval(ratio)
    pixel_variance = shared.variances["indirect"].mean() / own.variances["indirect"].mean()
    assert pixel_variance == pytest.approx(1.0, abs=0.1)
    spread = shared.frame_means["indirect"].std(axis=0).mean() / own.frame_means["indirect"].std(axis=0).mean()
    assert spread > 1.5


# -- cornell-box against the committed Mitsuba references (128x128, 16384 spp) --------------------


# Noise dominates these images: per-pixel relMSE falls as 1 / paths. Measured (seed 0, B=3, K=32,
# R=256, spp 16, 128x128; the command is the test itself): 8 frames, indirect relMSE 0.329; 32
# frames 0.0855 (3.85x lower). Averaged over 8x8 blocks at 32 frames: direct 0.0091, indirect 0.0052,
# still mostly noise (8 frames: 0.045, 0.0099). The threshold is the larger measured value plus 60 %.
CORNELL_BLOCK_RELMSE = 0.015


@pytest.mark.long
def test_cornell_box_converges_to_the_mitsuba_reference(gl, images):
    scene, ref = cornell_reference(3)
    errors = {}
    for frames in (8, 32):
        result = render(
            gl, scene, bounces=3, directions=32, resolution=256, spp=16, frames=frames, width=128, height=128
        )
        errors[frames] = relmse(result.images["indirect"], ref.images["indirect"])
    # Noise falls as 1 / frames: 4x the frames must at least halve the error.
    assert errors[32] < 0.5 * errors[8], images.keep(
        "indirect",
        result.images["indirect"],
        ref.images["indirect"],
        f"indirect relMSE {errors}: not halved by 4x the frames",
    )
    for name in ("direct", "indirect"):
        images.relmse_at_most(
            f"{name}-8x8-blocks",
            block_mean(result.images[name], 8),
            block_mean(ref.images[name], 8),
            CORNELL_BLOCK_RELMSE,
        )


@pytest.mark.slow
def test_cornell_box_indirect_relmse_reaches_the_convergence_target(gl, images):
    # With next-event estimation. Before it, 12288 paths per pixel gave indirect relMSE 0.0118:
    # paths found cornell's small light only by hitting it.
    scene, ref = cornell_reference(3)
    result = render(gl, scene, bounces=3, directions=32, resolution=256, spp=64, frames=192, width=128, height=128)
    images.relmse_at_most("indirect", result.images["indirect"], ref.images["indirect"], 0.002)


def cornell_indirect_ratios(gl, bounces: int, resolution: int, seeds: int) -> list[dict]:
    """cornell-box at the paper's K=256 (128x128, 128 frames x 16 paths a seed): the indirect
    mean over Mitsuba's per channel, with its 95 % interval over the frames of every seed."""
    scene, ref = cornell_reference(bounces)
    settings = dict(bounces=bounces, directions=256, resolution=resolution, spp=16, frames=128, width=128, height=128)
    frames = np.concatenate([render(gl, scene, seed=seed, **settings).frame_means["indirect"] for seed in range(seeds)])
    return mean_ratio(frames, ref.images["indirect"], ref.variances["indirect"])["per_channel"]


@pytest.mark.slow
@pytest.mark.parametrize("bounces", [1, 3])
def test_cornell_box_at_256_directions_is_within_one_percent_at_r64(gl, bounces):
    # Paths land where their ray meets the surface (shaders/paths/eye_paths.glsl), so the O(1/R) bias of
    # taking one line's node is gone. Measured with this test's settings (R=64, seeds 0-3),
    # indirect ratio per channel and 95 % interval: B=1 0.9982 [0.9955, 1.0009], 1.0019 [0.9990,
    # 1.0048], 0.9990 [0.9953, 1.0027]; B=3 1.0002 [0.9971, 1.0034], 1.0042 [1.0007, 1.0076],
    # 1.0006 [0.9964, 1.0048]. Before: +1.9 to +2.3 % at B=1.
    per_channel = cornell_indirect_ratios(gl, bounces, resolution=64, seeds=4)
    for channel in per_channel:
        assert channel["lo"] >= 0.99 and channel["hi"] <= 1.01, [describe_interval(c) for c in per_channel]


@pytest.mark.slow
@pytest.mark.parametrize("bounces", [1, 3])
def test_cornell_box_at_256_directions_is_within_half_a_percent_at_r128(gl, bounces):
    # Measured with this test's settings (R=128, seeds 0-7: 1024 frames; on an idle 2-core
    # machine 49 min at B=1, about 1.5 h at B=3), indirect ratio per channel and 95 % interval:
    # B=1 0.9993 [0.9974, 1.0013], 1.0007 [0.9986, 1.0028], 0.9994 [0.9967, 1.0020]; B=3 1.0006
    # [0.9984, 1.0029], 1.0019 [0.9995, 1.0044], 1.0001 [0.9970, 1.0031]. Seeds 0-3 alone reach
    # past 0.5 % (B=1 red 0.9975 [0.9948, 1.0002], B=3 green 1.0031 [0.9996, 1.0065]): noise.
    per_channel = cornell_indirect_ratios(gl, bounces, resolution=128, seeds=8)
    for channel in per_channel:
        assert channel["lo"] >= 0.995 and channel["hi"] <= 1.005, [describe_interval(c) for c in per_channel]


def test_the_lit_room_is_lit_only_after_a_bounce(gl):
    # The scene for strategies that start paths at the lights: the spot light's patch on the
    # ceiling is out of view, so the direct image is black and every pixel's light is indirect;
    # with 4 paths a pixel, few pixels' paths find the patch at all (4 % at seed 0).
    result = render(gl, load_scene("lit-room"), bounces=1, directions=16, resolution=64, frames=2, spp=2)
    assert result.images["direct"].max() == 0.0
    found = (result.images["indirect"].max(axis=2) > 0).mean()
    assert 0 < found < 0.25, found


# -- next-event estimation for emissive triangles -------------------------------------------------


def test_next_event_estimation_cuts_the_noise_of_a_small_emitter(gl, images):
    # Measured (seed 0, B=1, K=32, R=128, 128x128, 8 frames x 4 spp): indirect relMSE 0.83 without
    # next-event estimation, 0.0114 with 8 emitter samples per frame; direct 0.94 and 0.00077.
    # Thresholds: the measured values plus about a third (indirect) and twice (direct).
    scene, ref = cornell_reference(1)
    settings = dict(bounces=1, directions=32, resolution=128, spp=4, frames=8, width=128, height=128)
    off = render(gl, scene, light_samples=0, **settings)
    on = render(gl, scene, light_samples=8, **settings)
    assert any("next-event estimation is off" in w for w in off.warnings)
    assert not any("next-event estimation" in w for w in on.warnings)
    assert on.params["light_samples"] == 8 and off.params["light_samples"] == 0
    error_off = relmse(off.images["indirect"], ref.images["indirect"])
    images.relmse_at_most("indirect", on.images["indirect"], ref.images["indirect"], min(0.015, error_off / 20))
    images.relmse_at_most("direct", on.images["direct"], ref.images["direct"], 0.0015)


def test_emitter_samples_follow_emitted_power_and_sum_to_it():
    quad = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    meshes = [
        Mesh("bright", quad, faces, 0),
        Mesh("dim", quad * 2.0 + [3, 0, 0], faces, 1),
        Mesh("wall", quad + [0, 0, 2], faces, 2),
    ]
    materials = [
        Material("bright", emission=(8.0, 8.0, 8.0)),
        Material("dim", emission=(1.0, 1.0, 1.0)),
        Material("wall"),
    ]
    scene = assemble("lamps", "lamps", meshes, materials, [], None)
    samples = EmitterSamples(scene, 60)
    positions, normals, intensities, densities = samples.frame_lights(seed=0, frame=3)[:4]
    # Power 8 x 1 against 1 x 4: two thirds of the samples on the bright quad, stratified exactly.
    bright = positions[:, 0] < 2.0 - scene.origin[0]  # the bright quad spans x 0..1, the dim one 3..5
    assert np.count_nonzero(bright) == 40
    assert np.allclose(np.abs(normals[:, 2]), 1.0)
    # Each sample carries W / M of the power: the sum is the emitters' sum of L_e A, whatever was drawn.
    assert intensities.sum(axis=0) == pytest.approx([12.0, 12.0, 12.0])
    assert np.allclose(densities, 60 * np.where(bright, 8.0, 1.0) / 12.0)  # M p(y) = M w(y) / W
    again = samples.frame_lights(seed=0, frame=3)
    assert np.array_equal(positions, again[0]) and not np.array_equal(
        positions, samples.frame_lights(seed=0, frame=4)[0]
    )


def test_bad_next_event_settings_are_one_line_errors():
    for field, value in (("light_samples", -1), ("light_sample_map_size", 4)):
        with pytest.raises(ValueError, match=field):
            resolve(RenderSettings(**{field: value}))
    bad = run_evalkit("render", "cornell-box", "--method", "perfect", "--light-samples", "-2", "--out", "/tmp/unused")
    assert bad.returncode == 2 and "-2 must be at least 0" in bad.stderr and "Traceback" not in bad.stderr


# -- shadow-mapped lights against Mitsuba --------------------------------------------------------


def lit_stage(*lights: Light, eye=(0.0, 4.0, 4.5), target=(0.0, 0.3, 0.0), fov=45.0, size=64):
    """A floor with a box on it, lit by ``lights``, seen from above at an angle (by default)."""
    floor = np.array([[-2.0, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]])
    meshes = [
        Mesh("floor", floor, np.array([[0, 2, 1], [0, 3, 2]]), 0),
        Mesh("box", *box(np.array([-0.5, 0.0, -0.5]), np.array([0.5, 1.0, 0.5])), 1),
    ]
    materials = [Material("floor", albedo=(0.7, 0.7, 0.7)), Material("box", albedo=(0.8, 0.3, 0.2))]
    camera = Camera(look_at(list(eye), list(target), [0, 1, 0]), fov=fov, fov_axis="x", width=size, height=size)
    return assemble("stage", "stage", meshes, materials, list(lights), camera)


SUN = Light("directional", (3.0, 3.0, 3.0), direction=np.array([0.4, -1.0, 0.3]) / np.linalg.norm([0.4, -1.0, 0.3]))
LAMP = Light("point", (8.0, 7.0, 6.0), position=np.array([-1.5, 2.5, 1.0]))
SPOT = Light(
    "spot",
    (20.0, 20.0, 20.0),
    position=np.array([1.5, 3.0, 1.5]),
    direction=np.array([-0.4, -1.0, -0.4]) / np.linalg.norm([-0.4, -1.0, -0.4]),
    cutoff_angle=35.0,
    beam_width=25.0,
)

# Measured relMSE of the direct image against Mitsuba's (1024 spp, 64x64, 16 frames, shadow maps
# 1024^2): directional 9.8e-4, point 1.1e-4, spot 1.6e-4 (Mitsuba's own noise: 4e-5 or less).
# What is left is shadow-map aliasing and bias at shadow edges. Threshold: 3x the worst.
DIRECT_RELMSE = 0.003


@pytest.mark.parametrize("light", [SUN, LAMP, SPOT], ids=["directional", "point", "spot"])
def test_shadow_mapped_direct_light_matches_mitsuba(gl, tmp_path, images, light):
    scene = lit_stage(light)
    ref = reference(scene, bounces=0, spp=1024, width=64, height=64, store=tmp_path, progress=lambda line: None)
    result = render(gl, scene, bounces=0, directions=4, resolution=32, frames=16, width=64, height=64)
    assert ref.images["direct"].mean() > 0.02
    images.relmse_at_most("direct", result.images["direct"], ref.images["direct"], DIRECT_RELMSE)
    assert not result.images["indirect"].any()  # bounces=0: no indirect light at all


# -- environment light against Mitsuba -----------------------------------------------------------


def sky_stage(light: Light, size: int = 32):
    """The stage seen from low down: the sky fills the top of the image (its top 3/16)."""
    return lit_stage(light, eye=(0.0, 1.6, 4.5), target=(0.0, 0.7, 0.0), fov=60.0, size=size)


SKY = Light("constant", (0.9, 1.0, 1.2))
_TURN = np.array([[np.cos(0.6), 0, np.sin(0.6), 0], [0, 1, 0, 0], [-np.sin(0.6), 0, np.cos(0.6), 0], [0, 0, 0, 1.0]])
# Random texels: any misplaced texel shows. Turned about y, so the map's frame is checked too.
ENVMAP = Light(
    "envmap",
    (1.5, 1.5, 1.5),
    envmap=(0.2 + np.random.default_rng(7).random((8, 16, 3))).astype(np.float32),
    to_world=_TURN,
)

# Measured (seed 0, 32x32, B=1, K=16, R=128, 256 frames; Mitsuba 1024 spp; before nodes behind
# concave edges were skipped), relMSE with both
# images divided by the reference's mean (indirect light is dim: relMSE's 0.01 floor would hide
# it): direct constant 5.6e-4, envmap 6.9e-4; indirect in 4x4 blocks 4.4e-3 and 5.3e-3,
# means 1.012 and 1.018 of Mitsuba's; the sky pixels 3.4e-6 (7.2e-4 with texel rows at
# (j + 0.5) / H, the convention before Mitsuba's was checked). Thresholds: 3x (sky: 10x), and
# the mean within 6 % (frame-to-frame noise: about 2 %).
ENVIRONMENT_DIRECT_RELMSE, ENVIRONMENT_INDIRECT_BLOCK_RELMSE, SKY_RELMSE = 0.002, 0.016, 3.4e-5


def normalized(image: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return image / ref.mean(), ref / ref.mean()


@pytest.mark.parametrize("light", [SKY, pytest.param(ENVMAP, marks=pytest.mark.long)], ids=["constant", "envmap"])
def test_environment_light_matches_mitsuba(gl, tmp_path, images, light):
    scene = sky_stage(light)
    ref = reference(scene, bounces=1, spp=1024, width=32, height=32, store=tmp_path, progress=lambda line: None)
    result = render(gl, scene, bounces=1, directions=16, resolution=128, frames=256, width=32, height=32)
    images.relmse_at_most(
        "direct", *normalized(result.images["direct"], ref.images["direct"]), ENVIRONMENT_DIRECT_RELMSE
    )
    indirect = normalized(block_mean(result.images["indirect"], 4), block_mean(ref.images["indirect"], 4))
    images.relmse_at_most("indirect-4x4-blocks", *indirect, ENVIRONMENT_INDIRECT_BLOCK_RELMSE)
    assert indirect[0].mean() == pytest.approx(1.0, abs=0.06)
    # Where the camera sees the sky, the image is the environment's lookup itself: no noise.
    images.relmse_at_most("sky", result.images["direct"][:6], ref.images["direct"][:6], SKY_RELMSE)


def sun_box() -> Scene:
    """A floor and a box (14 triangles) under a sky whose sun, 4 texels of 8192, carries 63 % of its
    power: what a real sky map is like, and what K bundle directions a frame almost never meet."""
    h, w = 64, 128
    up = np.cos(np.arange(h) / (h - 1) * np.pi)[:, None, None]
    sky = np.where(up > 0, np.array([0.3, 0.45, 0.8]), np.array([0.1, 0.09, 0.08])) * np.ones((h, w, 3))
    sky[12:14, 40:42] = [4000.0, 3800.0, 3400.0]
    floor = Mesh("floor", *box(np.array([-2.0, -0.1, -2.0]), np.array([2.0, 0.0, 2.0])), 0)
    cube = Mesh("cube", *box(np.array([-0.5, 0.0, -0.5]), np.array([0.5, 1.0, 0.5])), 1)
    materials = [Material("floor", albedo=(0.6, 0.6, 0.6)), Material("cube", albedo=(0.7, 0.4, 0.3))]
    camera = Camera(look_at([2.5, 2.2, 3.0], [0, 0.3, 0], [0, 1, 0]), fov=45.0, fov_axis="x", width=32, height=24)
    sun = Light("envmap", (1.0, 1.0, 1.0), envmap=sky.astype(np.float32), to_world=np.eye(4))
    return assemble("sun-box", "sun-box", [floor, cube], materials, [sun], camera)


@pytest.mark.long
def test_a_sun_in_the_environment_map_is_sampled_where_its_power_is(gl, tmp_path):
    # Measured (this test's settings, Mitsuba 1024 spp), ratio to Mitsuba with its 95 % interval over
    # the frames, seeds 0, 1, 2: with 32 environment samples a frame, direct 1.0008 [0.970, 1.031],
    # 1.0008 [0.978, 1.024], 0.9900 [0.962, 1.018], indirect 0.959 [0.898, 1.020], 0.991 [0.932,
    # 1.049], 1.028 [0.951, 1.105]; without them (the bundles alone meet the sun) direct 0.89
    # [0.03, 1.75], 2.05 [0.34, 3.76], 0.71 [-0.30, 1.72], indirect 0.88, 0.78, 0.62 with
    # intervals as wide. Bounds: direct within 5 %, indirect 12 % (twice the intervals' half-widths).
    scene = sun_box()
    ref = reference(scene, bounces=1, spp=1024, width=32, height=24, store=tmp_path, progress=lambda line: None)
    kw = dict(bounces=1, directions=32, resolution=128, frames=64, width=32, height=24)
    sampled = render(gl, scene, environment_samples=32, **kw)
    direct, indirect = (mean_interval(sampled, ref, name) for name in ("direct", "indirect"))
    assert direct["lo"] >= 0.95 and direct["hi"] <= 1.05, describe_interval(direct)
    assert indirect["lo"] >= 0.88 and indirect["hi"] <= 1.12, describe_interval(indirect)
    alone = render(gl, scene, environment_samples=0, **kw)
    bundles_alone = mean_interval(alone, ref, "direct")
    assert bundles_alone["hi"] - bundles_alone["lo"] > 0.5, describe_interval(bundles_alone)
    # and the render says so: its 2048 directions are expected to meet the sky's brightest quarter 1.5 times
    assert any("heavy-tailed" in w for w in alone.warnings) and not any("heavy-tailed" in w for w in sampled.warnings)


def sky_stage_renders(gl, tmp_path, frames: int, strategies=("eye", "bidirectional")):
    """The sky stage under the map, B=2: Mitsuba's reference and a render per strategy (V=32:
    about 6 light paths a frame hit the stage, the rest miss it)."""
    scene = sky_stage(ENVMAP, size=16)
    ref = reference(scene, bounces=2, spp=4096, width=16, height=16, store=tmp_path, progress=lambda line: None)
    # Eye paths without environment samples: the bundles alone against the light paths.
    kw = dict(bounces=2, directions=16, resolution=128, frames=frames, width=16, height=16, light_paths=32)
    kw["environment_samples"] = 0
    return ref, {strategy: render(gl, scene, strategy=strategy, **kw) for strategy in strategies}


@pytest.mark.long
def test_light_paths_from_the_environment_cut_the_noise_of_its_indirect_light(gl, tmp_path):
    # The environment is the stage's only light, so every light path starts there. Measured (this
    # test's settings), indirect relMSE with both images divided by the reference's mean: eye
    # paths 0.667, bidirectional 0.062, 11x lower (at 64 frames 0.226 and 0.034; over seeds 0-4
    # bidirectional 0.028 to 0.074); a frame takes 1.8x as long (light paths 137 ms, bundles
    # 172 ms). Threshold: a quarter of eye paths'.
    ref, renders = sky_stage_renders(gl, tmp_path, frames=32)
    assert renders["bidirectional"].stats["light_path_vertices_median"] > 0
    errors = {
        name: relmse(*normalized(result.images["indirect"], ref.images["indirect"])) for name, result in renders.items()
    }
    assert errors["bidirectional"] < 0.25 * errors["eye"], errors
    assert np.isfinite(renders["bidirectional"].images["indirect"]).all()


@pytest.mark.slow
def test_light_paths_from_the_environment_keep_the_mean_of_its_indirect_light(gl, tmp_path):
    # Every path that reaches the environment is weighted against the light paths from it, so a
    # weight that does not sum to 1 shows in the mean. Measured, ratio to Mitsuba and 95 %
    # interval: bidirectional 1.0178 [0.9872, 1.0484] (this test: 2048 frames, 6 min here); at
    # 1024 frames (disk points drawn in another basis of the same disk) bidirectional 0.9891
    # [0.9482, 1.0299] and eye paths 1.0248 [0.9916, 1.0581].
    # Eye paths are unbiased on this small image (B=1, 16x16, seeds 0-3 x 1024 frames: 1.0033
    # [0.9845, 1.0220]; the 1.068 of one seed's 512 frames quoted here before was noise). The
    # bound, 6 %, is twice the interval's half-width at 2048 frames (about 3 %).
    ref, renders = sky_stage_renders(gl, tmp_path, frames=2048, strategies=("bidirectional",))
    whole = mean_interval(renders["bidirectional"], ref, "indirect")
    assert whole["lo"] >= 0.94 and whole["hi"] <= 1.06, describe_interval(whole)


def test_no_path_turns_back_along_the_bundle_it_arrived_by(gl, tmp_path):
    # With K = 4, a path that may take its last bundle again does so at 1 bounce in 4, back to the
    # surface it came from and not to the sky: the indirect light fell 13 % short of Mitsuba's
    # (0.869, mean of seeds 0-3 at 256 frames). Measured with the fix (seeds 0-3, this test's
    # settings, before nodes behind concave edges were skipped):
    # ratio 0.992, 1.028, 1.012, 0.989: frame-to-frame noise of about 2 %.
    scene = sky_stage(SKY, size=16)
    ref = reference(scene, bounces=1, spp=4096, width=16, height=16, store=tmp_path, progress=lambda line: None)
    result = render(gl, scene, bounces=1, directions=4, resolution=64, frames=1024, width=16, height=16)
    assert result.images["indirect"].mean() / ref.images["indirect"].mean() == pytest.approx(1.0, abs=0.05)


def test_bounce_accounting_matches_mitsubas_max_depth(gl, tmp_path):
    # Light from the point lamp reflected once more (B = 1) lands in indirect, as in Mitsuba's
    # max_depth 3 minus max_depth 2. Measured, mean ratio and 95 % interval (seeds 0, 1, 2): direct
    # 1.0010 [0.9937, 1.0082], 0.9993 [0.9922, 1.0064], 1.0018 [0.9944, 1.0092]; indirect 1.0406
    # [0.9197, 1.1616], 1.0399 [0.9210, 1.1587], 1.0713 [0.9917, 1.1510]: 16 frames of 32
    # directions leave the indirect mean +-12 % of noise (a bare 4 % bound on it was luck).
    scene = lit_stage(LAMP)
    ref = reference(scene, bounces=1, spp=256, width=64, height=64, store=tmp_path, progress=lambda line: None)
    result = render(gl, scene, bounces=1, directions=32, resolution=128, frames=16, spp=4, width=64, height=64)
    direct, indirect = mean_interval(result, ref, "direct"), mean_interval(result, ref, "indirect")
    assert direct["lo"] >= 0.985 and direct["hi"] <= 1.015, describe_interval(direct)
    assert indirect["lo"] <= 1.0 <= indirect["hi"], describe_interval(indirect)


# -- determinism, outputs and the CLI ------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS.names)
def test_same_seed_same_image_and_a_new_seed_changes_it(gl, method):
    scene = load_scene("cornell-box")
    kw = dict(method=method, bounces=2, directions=8, resolution=32, points=4096, frames=2, width=32, height=32)
    a, b, c = render(gl, scene, **kw), render(gl, scene, **kw), render(gl, scene, seed=1, **kw)
    for name in ("direct", "indirect"):
        assert np.array_equal(a.images[name], b.images[name])
        assert not np.array_equal(a.images[name], c.images[name])
        assert np.isfinite(a.images[name]).all() and (a.images[name] >= 0).all()


def test_a_time_budget_ends_the_render_with_the_frames_rendered_so_far(gl):
    scene = load_scene("cornell-box")
    kw = dict(bounces=1, directions=8, resolution=32, width=32, height=32)
    # A budget shorter than any frame still renders one: the same image as a one-frame render. The
    # frames asked for may be more than memory could list (the renderer keeps nothing per frame).
    one, budgeted = render(gl, scene, frames=1, **kw), render(gl, scene, frames=10**12, time_budget=1e-6, **kw)
    assert budgeted.params["frames_rendered"] == 1 and budgeted.params["paths_per_pixel"] == 1
    assert np.array_equal(one.images["indirect"], budgeted.images["indirect"])
    # A budget past the frame limit renders every frame.
    full = render(gl, scene, frames=3, time_budget=1e6, **kw)
    assert full.params["frames_rendered"] == 3 and full.params["paths_per_pixel"] == 3
    with pytest.raises(ValueError, match="time_budget must be non-negative and finite seconds, got -1"):
        resolve(RenderSettings(time_budget=-1.0))


def test_imperfect_bundles_render_the_furnace_close_to_its_value(gl):
    # Holes let paths escape, so imperfect bundles lose light; at the default splat scale the loss
    # stays small. Measured (seed 0, 16x16, K=16, R=128, N=16384, 16 frames): direct 1.4954
    # (-0.3 %), indirect 0.2438 (-2.5 %).
    result = render(
        gl,
        load_scene("furnace"),
        method="imperfect",
        bounces=1,
        directions=16,
        resolution=128,
        points=16384,
        frames=16,
        width=16,
        height=16,
    )
    assert result.images["direct"].mean() == pytest.approx(furnace_radiance(2), rel=0.02)
    assert result.images["indirect"].mean() == pytest.approx(furnace_radiance(3) - furnace_radiance(2), rel=0.05)


@pytest.mark.parametrize("name", ["cornell-box", "furnace", pytest.param("atrium", marks=pytest.mark.long)])
def test_cli_renders_every_builtin_scene_both_ways(tmp_path, name):
    for method in METHODS.names:
        out = tmp_path / method
        r = run_evalkit(
            "render",
            name,
            "--method",
            method,
            "--width",
            "24",
            "--height",
            "16",
            "--directions",
            "4",
            "--resolution",
            "32",
            "--points",
            "1024",
            "--bounces",
            "1",
            "--frames",
            "2",
            "--out",
            str(out),
            "--json",
        )
        assert r.returncode == 0, r.stderr
        summary = json.loads(r.stdout.strip().splitlines()[-1])
        assert summary["params"]["method"] == method and summary["timings_ms"]["bundles"] > 0
        for image in ("direct", "indirect", "total"):
            rgb, provenance = read_exr(out / f"{image}.exr")
            assert rgb.shape == (16, 24, 3) and np.isfinite(rgb).all() and (rgb >= 0).all()
            assert provenance["scene_hash"] == summary["params"]["scene_hash"] and provenance["image"] == image
        timings = json.loads((out / "timings.json").read_text())
        assert {"bundles", "gbuffer", "bounce_1", "resolve"} <= set(timings["timings"]["median_ms"])


def test_cli_preset_and_bad_settings(tmp_path):
    r = run_evalkit(
        "render",
        "furnace",
        "--method",
        "perfect",
        "--preset",
        "paper",
        "--width",
        "16",
        "--height",
        "8",
        "--resolution",
        "16",
        "--directions",
        "2",
        "--points",
        "64",
        "--out",
        str(tmp_path / "p"),
        "--json",
    )
    assert r.returncode == 0, r.stderr
    params = json.loads(r.stdout.strip().splitlines()[-1])["params"]
    assert params["supersampling"] == 2 and params["width"] == 16  # the preset, with explicit options on top
    r = run_evalkit("render", "furnace", "--method", "perfect", "--bounces", "-1", "--out", str(tmp_path / "q"))
    assert r.returncode == 2 and "bounces" in r.stderr and "Traceback" not in r.stderr


# -- animation ------------------------------------------------------------------------------------


@pytest.mark.long
def test_animated_scene_moves_rigidly_and_renders_each_pose(gl):
    scene = load_scene("atrium-animated")
    assert scene.animated and not scene.at(3.0).animated
    ball0, ball3 = scene.at(0.0).meshes[-1], scene.at(3.0).meshes[-1]
    assert np.allclose(ball0.triangle_areas(), ball3.triangle_areas())  # rigid: areas (and point sampling) unchanged
    assert not np.allclose(ball0.positions, ball3.positions)
    assert scene.at(0.0).content_hash() != scene.at(3.0).content_hash()
    kw = dict(method="imperfect", bounces=1, directions=4, resolution=32, points=2048, frames=1, width=24, height=16)
    at3 = render(gl, scene, time=3.0, **kw)
    assert np.array_equal(at3.images["total"], render(gl, scene.at(3.0), **kw).images["total"])
    assert not np.array_equal(at3.images["total"], render(gl, scene, time=0.0, **kw).images["total"])
    moving = render(gl, scene, time=0.0, time_step=1.5, **{**kw, "frames": 3})  # a new pose every frame
    assert np.isfinite(moving.images["total"]).all() and moving.images["total"].mean() > 0


# -- where node light is computed -----------------------------------------------------------------


def test_precomputed_and_lazy_lighting_render_the_same_image(gl, images):
    # Precomputed: the irradiance of every splat point once per frame; lazy: at each path's hits. A
    # splat point is lit at its centre, its hits up to a splat radius away, so shadow edges may move
    # by that much. Both must agree within the noise of one seed against another.
    method = "imperfect"
    scene = lit_stage(LAMP, SUN)
    kw = dict(method=method, bounces=2, directions=16, resolution=64, points=8192, frames=4, spp=2, width=48, height=48)
    precomputed = render(gl, scene, lighting="precomputed", **kw)
    lazy = render(gl, scene, lighting="lazy", **kw)
    other_seed = render(gl, scene, lighting="lazy", seed=1, **kw)
    assert precomputed.stats["lighting_frames"] == {"precomputed": 4} and lazy.stats["lighting_frames"] == {"lazy": 4}
    assert precomputed.timings["median_ms"]["irradiance"] > 0 and "irradiance" not in lazy.timings["median_ms"]
    noise = relmse(other_seed.images["indirect"], lazy.images["indirect"])
    images.relmse_at_most("indirect", precomputed.images["indirect"], lazy.images["indirect"], 0.25 * noise)
    assert np.array_equal(precomputed.images["direct"], lazy.images["direct"])  # the G-buffer's own light


def test_perfect_bundles_light_each_hit_where_its_ray_lands(gl):
    # A hit moves off its node onto the ray (shaders/paths/eye_paths.glsl), where no node's precomputed
    # light can follow: lighting is the imperfect method's setting alone.
    with pytest.raises(ValueError, match="lighting is a setting of the imperfect bundle method, not of"):
        resolve(RenderSettings(method="perfect", lighting="precomputed"))
    kw = dict(method="perfect", bounces=1, directions=4, resolution=32, frames=2, width=16, height=16)
    assert render(gl, lit_stage(LAMP), **kw).stats["lighting_frames"] == {"lazy": 2}


# Fixed directions on a static scene with 1,024 splat points against 16,384 paths: where auto
# precomputes the splat points' light, once for every frame.
FEW_POINTS_MANY_PATHS = dict(
    method="imperfect", points=256, bounces=1, directions=4, resolution=16, width=64, height=64, spp=4,
    rotate_directions=False,
)  # fmt: skip


def test_auto_lighting_picks_the_cheaper_way_per_frame(gl):
    # A small image has few paths: lighting their hits costs less than lighting every splat point.
    scene = lit_stage(LAMP)
    small = render(
        gl, scene, method="imperfect", lighting="auto", bounces=1, directions=16, resolution=64, frames=2, width=16,
        height=16,
    )  # fmt: skip
    assert small.stats["lighting_frames"] == {"lazy": 2}
    # Fixed directions on a static scene: the irradiance of splat points made in frame 0 serves every
    # frame (1,024 points, against 16,384 paths: precomputing is the cheaper way).
    reused = render(gl, scene, lighting="auto", frames=3, **FEW_POINTS_MANY_PATHS)
    assert reused.stats["lighting_frames"] == {"precomputed": 3}
    assert [fr.get("irradiance") is not None for fr in reused.timings["frames_ms"]] == [True, False, False]


def test_imperfect_bundles_light_each_hit_where_it_lands_by_default(gl):
    # A splat centre's light stands in for its hits' only with `lighting` precomputed or auto: a
    # centre may lie in a crevice the hits, which rays see, seldom reach (atrium's indirect light 3 %
    # darker; docs/results/decisions.toml: lazy-lighting-default). The configuration in which auto
    # precomputes (above) is lit lazily by default.
    default = render(gl, lit_stage(LAMP), frames=2, **FEW_POINTS_MANY_PATHS)
    assert default.params["lighting"] == "lazy" and default.stats["lighting_frames"] == {"lazy": 2}


# -- contact shadows --------------------------------------------------------------------------------


def contact_scene(light: str, view: str) -> Scene:
    """A ball and a box resting on a 20 x 20 floor, lit from 6 units up by a point light or an
    emissive quad (next-event estimation), seen low and close at a contact: the crevice under the
    ball, the foot of the box. Shadow-map bias grows with the texel, the texel with the distance."""
    floor = np.array([[-10.0, 0, -10], [10, 0, -10], [10, 0, 10], [-10, 0, 10]])
    p, f, n, uv = unit_sphere((64, 32))
    meshes = [
        Mesh("floor", floor, np.array([[0, 2, 1], [0, 3, 2]]), 0),
        Mesh("ball", p * 0.5 + [-0.8, 0.5, 0.0], f, 1, normals=n, uvs=uv),
        Mesh("box", *box(np.array([0.4, 0.0, -0.4]), np.array([1.2, 0.8, 0.4])), 1),
    ]
    materials = [Material("floor", albedo=(0.7, 0.7, 0.7)), Material("object", albedo=(0.6, 0.6, 0.6))]
    lights = []
    if light == "point":
        lights = [Light("point", (48.0, 48.0, 48.0), position=np.array([0.3, 6.0, 1.2]))]
    else:
        quad = np.array([[-0.4, 6.0, 0.8], [0.6, 6.0, 0.8], [0.6, 6.0, 1.6], [-0.4, 6.0, 1.6]])
        meshes.append(Mesh("lamp", quad, np.array([[0, 1, 2], [0, 2, 3]]), 2))
        materials.append(Material("lamp", albedo=(0.0, 0.0, 0.0), emission=(60.0, 60.0, 60.0)))
    eye, target = {"ball": ([-2.0, 0.3, 1.0], [-0.8, 0.08, 0.0]), "box": ([0.8, 0.6, 1.7], [0.8, 0.05, 0.45])}[view]
    camera = Camera(look_at(eye, target, [0, 1, 0]), fov=30.0, fov_axis="x", width=48, height=48)
    return assemble(f"contact-{light}-{view}", "contact", meshes, materials, lights, camera)


@pytest.mark.parametrize("light", ["point", pytest.param("area", marks=pytest.mark.long)])
@pytest.mark.parametrize("view", ["ball", "box"])
def test_contact_shadows_match_mitsuba(gl, tmp_path, images, light, view):
    # Light leaking under objects resting on a floor (shadow-map bias near the contact) would
    # brighten the whole close-up. Measured, direct mean ratio and 95 % interval (seed 0): point
    # ball 1.0007 [0.9915, 1.0099], area ball 1.0033 [0.9941, 1.0124]; box views within 1 % too.
    # The intervals, +-1 %, would show a leak of the 10 % once reported.
    scene = contact_scene(light, view)
    ref = reference(scene, bounces=1, spp=4096, width=48, height=48, store=tmp_path, progress=lambda line: None)
    result = render(gl, scene, bounces=1, directions=32, resolution=128, frames=32, spp=4, width=48, height=48)
    direct = mean_interval(result, ref, "direct")
    assert direct["hi"] - direct["lo"] < 0.03, describe_interval(direct)  # enough frames to see a leak
    if not direct["lo"] <= 1.0 <= direct["hi"]:
        pytest.fail(images.keep("direct", result.images["direct"], ref.images["direct"], describe_interval(direct)))


def test_an_orthographic_camera_sees_what_mitsubas_does(gl, tmp_path):
    # Measured (this test's settings): direct relMSE 0.012 against Mitsuba's 256 spp; 0.33 and 0.17
    # with the render mirrored left to right or top to bottom.
    scene = load_scene(str(Path(__file__).parent / "data" / "import_corpus" / "orthographic.xml"))
    assert scene.camera.orthographic
    ref = reference(scene, bounces=1, spp=256, width=48, height=32, store=tmp_path, progress=lambda line: None)
    result = render(gl, scene, bounces=1, directions=16, resolution=128, frames=8, width=48, height=32)
    a, b = result.images["direct"], ref.images["direct"]
    assert relmse(a, b) < 0.04 and min(relmse(a[:, ::-1], b), relmse(a[::-1], b)) > 0.1


def test_a_black_environment_map_renders_black_without_samples_to_draw(gl):
    scene = sun_box()
    black = replace(scene, lights=[replace(scene.lights[0], envmap=np.zeros_like(scene.lights[0].envmap))])
    result = render(gl, black, bounces=1, directions=4, resolution=32, frames=1, width=8, height=6)
    assert all(not image.any() for image in result.images.values())
