"""The eye-path renderer: analytic furnace values, convergence to the committed Mitsuba references,
shadow-mapped direct light against Mitsuba, bounce accounting, determinism and the CLI.

Every threshold here was measured with the command in its comment, then given a margin; the
comments give the measured values.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import describe_interval, mean_interval, relmse, render_with, run_evalkit

from evalkit.core.exr import read_exr
from evalkit.core.scene import Light, Material, Mesh, assemble, load_scene
from evalkit.core.scene.assemble import look_at
from evalkit.core.scene.builtin import furnace_radiance
from evalkit.core.scene.model import Camera
from evalkit.core.scene.tessellate import box
from evalkit.core.settings import RenderSettings
from gpu_impl.lights import EmitterSamples
from gpu_impl.registry import resolve
from references.mitsuba import DEFAULT_STORE, load_reference, reference, store_entry


def render(gl, scene, **settings):
    return render_with(gl, scene, **settings)


def block_mean(image: np.ndarray, b: int) -> np.ndarray:
    h, w, _ = image.shape
    return image.reshape(h // b, b, w // b, b, 3).mean(axis=(1, 3))


# -- furnace: every surface emits 1 and reflects 0.5, so bounce j adds 0.5^j exactly --------------

# The frame's K directions are independent, so every frame's image mean scatters by about 9 %
# (the mean of 2 cos over 16 random directions): 1024 frames bring that to 0.3 %. Measured (16x16,
# K=16, R=128, 1024 frames, seeds 0-2, no NEE): indirect B=1 -0.47 %, -0.52 %, -1.05 %; B=3
# -0.73 %, -0.97 %, -1.36 % (R=256, seed 0: -0.60 %). What is left is light lost where a line
# beside the vertex leaves the cube at a concave edge (it falls with R) and the scatter. The target
# is 1 %: met by seed 0 at R=128, not by the mean of seeds 0-2 at B=3 (-1.02 % +- 0.18 %).
FURNACE_TOLERANCE = 0.01


def furnace_ratio(gl, resolution, frames, bounces=1, light_samples=0, seed=0):
    """The furnace's (16x16, K=16) direct and indirect image means over the analytic values."""
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
    return (
        result.images["direct"].mean() / furnace_radiance(2),
        result.images["indirect"].mean() / (furnace_radiance(bounces + 2) - furnace_radiance(2)),
    )


@pytest.mark.parametrize("bounces", [1, 3])
def test_furnace_matches_the_analytic_radiance(gl, bounces):
    # The bundles' transport alone: paths find the emitting walls by hitting them.
    direct, indirect = furnace_ratio(gl, 128, 1024, bounces)
    assert direct == pytest.approx(1.0, abs=FURNACE_TOLERANCE)
    assert indirect == pytest.approx(1.0, abs=FURNACE_TOLERANCE)


@pytest.mark.slow
@pytest.mark.parametrize("bounces", [1, 3])
def test_furnace_matches_the_analytic_radiance_with_next_event_estimation(gl, bounces):
    # Every wall emits: multiple importance sampling splits each wall's light between the emitter
    # samples and the bundle paths. The frame's 8 shared samples make seeds scatter, so the test
    # takes four. Measured (R=128, 1024 frames, indirect, seeds 0-3): B=1 -0.42, -0.10, -1.51,
    # -0.88 % (mean -0.73 %); before the bundle paths' weight took the distance to the emitter's
    # plane (shaders/eye_paths.glsl), -1.09, -0.77, -2.16, -1.55 %. B=3 -0.58, -0.36, -1.57, -0.90 %
    # (mean -0.85 %). Direct: -0.20 to +0.08 %.
    direct, indirect = np.mean(
        [furnace_ratio(gl, 128, 1024, bounces, light_samples=8, seed=seed) for seed in range(4)], axis=0
    )
    assert direct == pytest.approx(1.0, abs=FURNACE_TOLERANCE)
    assert indirect == pytest.approx(1.0, abs=FURNACE_TOLERANCE)


def test_no_light_is_lost_behind_concave_edges(gl):
    # A vertex near a concave edge (the floor by a wall) takes a line up to a bundle pixel beside
    # it, which may pass behind the wall: it met the wall's back and the path ended. Skipping nodes
    # whose plane the vertex cannot reach (shaders/eye_paths.glsl) keeps that light. At R = 32,
    # 1024 frames, seed 0, B=1: indirect -5.7 % before, -1.26 % after (lines that leave the cube
    # beside the edge still lose light, O(1/R)).
    _, indirect = furnace_ratio(gl, 32, 1024)
    assert indirect == pytest.approx(1.0, abs=0.02)


def test_furnace_bias_falls_as_the_bundle_resolution_grows(gl):
    # The light still lost at concave edges is O(1/R). Measured (seed 0, B=1, 1024 frames):
    # indirect -2.82 % at R = 16, -0.65 % at R = 64; 1024 frames keep the scatter (0.3 %) below it.
    errors = [1.0 - furnace_ratio(gl, R, 1024)[1] for R in (16, 64)]
    assert errors[0] > 0 and errors[1] < 0.5 * errors[0]


# -- cornell-box against the committed Mitsuba references (128x128, 16384 spp) --------------------


def cornell_reference(bounces):
    scene = load_scene("cornell-box")
    return scene, load_reference(
        store_entry(scene.name, scene.content_hash(), bounces, 16384, 128, 128, 0, DEFAULT_STORE)
    )


# Noise dominates these images: per-pixel relMSE falls as 1 / paths. Measured (seed 0, B=3, K=32,
# R=256, spp 16, 128x128; the command is the test itself): 8 frames, indirect relMSE 0.329; 32
# frames 0.0855 (3.85x lower). Averaged over 8x8 blocks at 32 frames: direct 0.0091, indirect 0.0052,
# still mostly noise (8 frames: 0.045, 0.0099). The threshold is the larger measured value plus 60 %.
CORNELL_BLOCK_RELMSE = 0.015


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


@pytest.mark.slow
@pytest.mark.parametrize("bounces", [1, 3])
def test_cornell_box_at_256_directions_converges_to_within_one_percent(gl, images, bounces):
    # The paper's K. The indirect mean's bias is O(1/R), and positive on cornell-box (K=256, 64
    # frames x 16 paths, seeds 0-3, B=1, per channel): +1.9 to +2.3 % at R = 64, +0.9 to +1.1 % at
    # R = 128, +0.3 to +0.4 % at R = 256; B=3 at R = 128: +1.0 to +1.1 %. This test (seed 0, R = 256):
    # B=1 +0.83 / +0.37 / +0.59 %, relMSE 0.00038 (0.0062 at 4 frames); B=3 +0.85 / +0.32 / +0.51 %,
    # relMSE 0.00062 (0.0099), the same before and after the emitter-plane weight. Noise falls with
    # paths down to that bias. docs/MEASURED_FACTS.md says where the bias comes from.
    scene, ref = cornell_reference(bounces)
    settings = dict(bounces=bounces, directions=256, resolution=256, spp=16, width=128, height=128)
    few = render(gl, scene, frames=4, **settings)
    many = render(gl, scene, frames=64, **settings)
    test, reference = many.images["indirect"], ref.images["indirect"]
    ratio = test.reshape(-1, 3).mean(axis=0) / reference.reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(ratio - 1) <= 0.01), images.keep("indirect", test, reference, f"indirect mean ratio {ratio}")
    assert relmse(test, reference) < 0.5 * relmse(few.images["indirect"], reference)
    images.relmse_at_most("indirect", test, reference, 0.002)


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
    positions, normals, intensities, densities = samples.frame_lights(seed=0, frame=3)
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


@pytest.mark.parametrize("light", [SKY, ENVMAP], ids=["constant", "envmap"])
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


@pytest.mark.parametrize("method", ["perfect", "imperfect"])
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
    # A budget shorter than any frame still renders one: the same image as a one-frame render.
    one, budgeted = render(gl, scene, frames=1, **kw), render(gl, scene, frames=50, time_budget=1e-6, **kw)
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


@pytest.mark.parametrize("name", ["cornell-box", "furnace", "atrium"])
def test_cli_renders_every_builtin_scene_both_ways(tmp_path, name):
    for method in ("perfect", "imperfect"):
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
    # A hit moves off its node onto the ray (shaders/eye_paths.glsl), where no node's precomputed
    # light can follow: lighting is the imperfect method's setting alone.
    with pytest.raises(ValueError, match="lighting is a setting of the imperfect bundle method, not of"):
        resolve(RenderSettings(method="perfect", lighting="precomputed"))
    kw = dict(method="perfect", bounces=1, directions=4, resolution=32, frames=2, width=16, height=16)
    assert render(gl, lit_stage(LAMP), **kw).stats["lighting_frames"] == {"lazy": 2}


def test_auto_lighting_picks_the_cheaper_way_per_frame(gl):
    # A small image has few paths: lighting their hits costs less than lighting every splat point.
    scene = lit_stage(LAMP)
    small = render(
        gl, scene, method="imperfect", bounces=1, directions=16, resolution=64, frames=2, width=16, height=16
    )
    assert small.stats["lighting_frames"] == {"lazy": 2}
    # Fixed directions on a static scene: the irradiance of splat points made in frame 0 serves every
    # frame (1,024 points, against 16,384 paths: precomputing is the cheaper way).
    reused = render(
        gl, scene, method="imperfect", points=256, bounces=1, directions=4, resolution=16, frames=3, width=64,
        height=64, spp=4, rotate_directions=False,
    )  # fmt: skip
    assert reused.stats["lighting_frames"] == {"precomputed": 3}
    assert [fr.get("irradiance") is not None for fr in reused.timings["frames_ms"]] == [True, False, False]
