"""Glossy BSDFs: the Python mirror (evalkit/core/bsdf.py) evaluates as Mitsuba does, the GLSL
library (gpu_impl/shaders/include/bsdf.glsl) as the mirror does, and the Mitsuba importer and export carry
rough conductors and rough plastics both ways with their parameters."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import describe_interval, mean_interval, render_with
from test_renderer import DIRECT_RELMSE, LAMP, SPOT, lit_stage

from evalkit.core.bsdf import eval_bsdf, fresnel_conductor, lobe_directions, microfacet_d, rough_plastic_tables
from evalkit.core.errors import InputError
from evalkit.core.mitsuba_env import mitsuba
from evalkit.core.scene import assemble, load_scene
from evalkit.core.scene.assemble import look_at
from evalkit.core.scene.builtin import glossy_box
from evalkit.core.scene.gloss import metallic_roughness
from evalkit.core.scene.mitsuba_io import load_mitsuba_dict, to_mitsuba_dict
from evalkit.core.scene.model import Camera, Gloss, Light, Material, Mesh
from evalkit.core.scene.summary import scene_summary
from evalkit.core.scene.tessellate import unit_sphere
from gpu_impl.layout import BINDINGS
from gpu_impl.scene_buffers import GpuScene
from gpu_impl.shader_source import expand_includes, with_header
from references.mitsuba import reference

ETA, K, SPECULAR, BASE = (0.2, 0.9, 1.1), (3.9, 2.4, 2.2), (0.9, 0.8, 0.7), (0.2, 0.3, 0.5)
COPPER_ETA, COPPER_K = (0.2010, 0.9237, 1.1022), (3.9133, 2.4530, 2.1421)  # Mitsuba's "Cu" in RGB


def hemisphere(rng, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    return v


def direction_pairs(rng, n: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (wi, wo) about the normal +z: half of them near the mirror direction, where a lobe of
    roughness alpha has its peak, and some below the surface."""
    wi, wo = hemisphere(rng, n), hemisphere(rng, n)
    near = n // 2
    wo[:near] = np.array([-1.0, -1.0, 1.0]) * wi[:near] + rng.normal(scale=alpha, size=(near, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    return wi, wo


def mitsuba_dict(kind: str, distribution: str, alpha: float) -> dict:
    common = {"type": kind, "distribution": distribution, "alpha": alpha}
    common["specular_reflectance"] = {"type": "rgb", "value": list(SPECULAR)}
    if kind == "roughconductor":
        return {**common, "eta": {"type": "rgb", "value": list(ETA)}, "k": {"type": "rgb", "value": list(K)}}
    base = {"type": "rgb", "value": list(BASE)}
    return {**common, "int_ior": 1.5, "ext_ior": 1.0, "nonlinear": True, "diffuse_reflectance": base}


def material(kind: str, distribution: str, alpha: float) -> Material:
    if kind == "roughconductor":
        return Material("m", (0.0, 0.0, 0.0), gloss=Gloss(kind, distribution, alpha, ETA, K, SPECULAR))
    table, internal = rough_plastic_tables(distribution, alpha, 1.5)
    gloss = Gloss(kind, distribution, alpha, (1.5,) * 3, specular_reflectance=SPECULAR, nonlinear=True,
                  transmittance=table, internal_reflectance=internal)  # fmt: skip
    return Material("m", BASE, gloss=gloss)


CASES = [(k, d, a) for k in ("roughconductor", "roughplastic") for d in ("beckmann", "ggx") for a in (0.05, 0.3)]


@pytest.mark.parametrize("kind, distribution, alpha", CASES)
def test_the_mirror_evaluates_as_mitsuba(kind, distribution, alpha):
    mi = mitsuba("scalar_rgb")
    bsdf, ctx = mi.load_dict(mitsuba_dict(kind, distribution, alpha)), mi.BSDFContext()
    wi, wo = direction_pairs(np.random.default_rng(1), 400, alpha)
    truth = []
    for a, b in zip(wi, wo):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*a)
        truth.append(np.array(bsdf.eval(ctx, si, mi.Vector3f(*b))))
    truth = np.array(truth)
    ours = eval_bsdf(material(kind, distribution, alpha), np.tile([0.0, 0.0, 1.0], (len(wi), 1)), wi, wo)
    # Mitsuba's float32 against float64: peaks reach a few hundred.
    assert np.abs(ours - truth).max() <= 1e-4 * max(1.0, np.abs(truth).max()), (ours - truth).max()
    assert truth.max() > (50.0 if alpha < 0.1 else 0.5)  # the peak was sampled


# The GLSL library run on directions from a buffer, for the materials of an uploaded scene.
PROBE = """
#include "common.glsl"
#include "scene.glsl"
#include "bsdf.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_SCAN_DATA) readonly buffer Probe { vec4 probe[]; };  // n (w: material), wi, wo
layout(std430, binding = BINDING_NODE_ATTRIBUTES) buffer Values { vec4 values[]; };
uniform uint count;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= count) return;
    uint m = uint(probe[3u * i].w);
    vec3 n = probe[3u * i].xyz, wi = probe[3u * i + 1u].xyz, wo = probe[3u * i + 2u].xyz;
    values[i] = vec4(bsdf_cos(m, materials[m].albedo.rgb, n, wi, wo), 0.0);
}
"""


def test_the_shaders_evaluate_as_the_mirror(gl):
    scene = glossy_box(0.05)
    rng = np.random.default_rng(2)
    rows, expected = [], []
    for m, mat in enumerate(scene.materials):
        wi, wo = direction_pairs(rng, 256, 0.05)
        n = np.tile([0.0, 0.0, 1.0], (len(wi), 1))
        expected.append(eval_bsdf(mat, n, wi, wo))
        rows.append(
            np.stack([np.c_[n, np.full(len(n), m)], np.c_[wi, np.zeros(len(n))], np.c_[wo, np.zeros(len(n))]], 1)
        )
    probe = np.concatenate(rows).astype(np.float32)
    expected = np.concatenate(expected)
    assert {m.gloss.kind for m in scene.materials if m.gloss} == {"roughconductor", "roughplastic"}
    source = with_header(expand_includes(PROBE), "COMPUTE_SHADER", {"GLOSSY": 1, "TEXTURES": 0})
    shader = gl.ctx.compute_shader(source)
    with GpuScene(gl, scene) as gpu_scene:
        gpu_scene.bind()
        inputs, values = gl.buffer(probe.tobytes()), gl.buffer(reserve=16 * len(expected))
        inputs.bind_to_storage_buffer(BINDINGS["SCAN_DATA"])
        values.bind_to_storage_buffer(BINDINGS["NODE_ATTRIBUTES"])
        shader["count"] = len(expected)
        shader.run((len(expected) + 63) // 64)
        ours = np.frombuffer(values.read(), np.float32).reshape(-1, 4)[:, :3]
        inputs.release()
        values.release()
    assert np.abs(ours - expected).max() <= 2e-4 * max(1.0, np.abs(expected).max()), np.abs(ours - expected).max()
    assert expected.max() > 50.0


def test_mitsuba_rough_bsdfs_import_exactly_and_export_the_same():
    scene = glossy_box(0.2)
    glossy = {m.source_bsdf: m for m in scene.materials if m.gloss is not None}
    assert set(glossy) == {"RoughConductor", "RoughPlastic"} and not scene.warnings
    assert not any(m.approximated for m in scene.materials)
    conductor, plastic = glossy["RoughConductor"].gloss, glossy["RoughPlastic"].gloss
    assert conductor.distribution == "ggx" and conductor.alpha == pytest.approx(0.2)
    assert conductor.eta == pytest.approx(COPPER_ETA, abs=1e-3) and conductor.k == pytest.approx(COPPER_K, abs=1e-3)
    assert glossy["RoughConductor"].albedo == (0.0, 0.0, 0.0)
    assert plastic.eta[0] == pytest.approx(1.4896, abs=1e-4) and len(plastic.transmittance) == 64
    mi = mitsuba()
    again = load_mitsuba_dict(to_mitsuba_dict(scene, mi), name="again")
    for before, after in zip(scene.materials, again.materials):
        assert after.gloss == before.gloss and after.albedo == pytest.approx(before.albedo)


@pytest.mark.parametrize(
    "bsdf, problem",
    [
        ({"type": "roughconductor", "alpha_u": 0.1, "alpha_v": 0.3}, "anisotropic roughness"),
        ({"type": "roughconductor", "alpha": {"type": "checkerboard"}}, "a textured alpha"),
        (
            {"type": "twosided", "bsdf": {"type": "roughconductor"}, "bsdf2": {"type": "diffuse"}},
            "a different BSDF on each side",
        ),
    ],
)
def test_what_a_gloss_cannot_hold_is_refused_in_one_line(bsdf, problem):
    mi = mitsuba()
    d = mi.cornell_box()
    d["floor"]["bsdf"] = bsdf
    with pytest.raises(InputError, match=problem) as caught:
        load_mitsuba_dict(d, name="refused")
    assert "\n" not in str(caught.value)


def glossy_stage(*lights):
    """test_renderer's stage with a rough plastic floor and a rough copper box."""
    scene = lit_stage(*lights)
    table, internal = rough_plastic_tables("ggx", 0.2, 1.5)
    plastic = Gloss("roughplastic", "ggx", 0.2, (1.5,) * 3, transmittance=table, internal_reflectance=internal)
    copper = Gloss("roughconductor", "beckmann", 0.1, COPPER_ETA, COPPER_K)
    floor, box = scene.materials
    materials = [replace(floor, gloss=plastic), replace(box, albedo=(0.0, 0.0, 0.0), gloss=copper)]
    return assemble("glossy-stage", "glossy-stage", scene.meshes, materials, scene.lights, scene.camera)


@pytest.mark.parametrize(
    "light, strategy",
    [(LAMP, "eye"), (SPOT, "eye"), pytest.param(LAMP, "bidirectional", marks=pytest.mark.long)],
    ids=["point", "spot", "point-bidirectional"],
)
def test_glossy_surfaces_reflect_light_as_mitsuba(gl, tmp_path, images, light, strategy):
    # Bidirectional paths: light paths from the lamp bounce off the glossy surfaces and connect to
    # the eye paths' vertices, the BSDF evaluated at both ends of each connection.
    scene = glossy_stage(light)
    ref = reference(scene, bounces=1, spp=1024, width=64, height=64, store=tmp_path, progress=lambda line: None)
    result = render_with(gl, scene, bounces=1, directions=64, resolution=128, frames=64, width=64, height=64,
                         strategy=strategy)  # fmt: skip
    assert ref.images["direct"].max() > 4.0 * ref.images["direct"].mean()  # a highlight
    images.relmse_at_most("direct", result.images["direct"], ref.images["direct"], DIRECT_RELMSE)
    for channel in mean_interval(result, ref, "indirect", channels=True):
        assert abs(channel["ratio"] - 1.0) <= 0.02 or channel["lo"] <= 1.0 <= channel["hi"], describe_interval(channel)


def white_conductor_sphere(alpha: float, size: int = 32):
    """A sphere of a rough conductor that reflects everything (F = 1: eta 0, k 1, Mitsuba's
    default) under a constant sky of radiance 1: each pixel on it is the BSDF's directional albedo
    at the view angle, all of it reflected sky, and nothing it reflects is occluded."""
    positions, faces, normals, uvs = unit_sphere((64, 32))
    mesh = Mesh("sphere", positions, faces, 0, normals=normals, uvs=uvs)
    white = Material("white", (0.0, 0.0, 0.0), gloss=Gloss("roughconductor", "ggx", alpha, (0.0,) * 3, (1.0,) * 3))
    eye = look_at([0.0, 0.0, 3.2], [0.0, 0.0, 0.0], [0, 1, 0])
    camera = Camera(eye, fov=45.0, fov_axis="x", width=size, height=size)
    return assemble("white-sphere", "white-sphere", [mesh], [white], [Light("constant", (1.0, 1.0, 1.0))], camera)


@pytest.mark.long
@pytest.mark.parametrize("candidates", [0, 32], ids=["uniform", "bsdf-weighted"])
def test_a_white_rough_conductor_reflects_its_directional_albedo(gl, tmp_path, candidates):
    # The furnace of a glossy BSDF: every path ends in the sky after one reflection, so the image is
    # the integral of f cos over the hemisphere, which the uniform choice estimates plainly and the
    # BSDF-weighted one by resampling; both must find Mitsuba's, which samples the BSDF itself.
    scene = white_conductor_sphere(0.2)
    ref = reference(scene, bounces=0, spp=1024, width=32, height=32, store=tmp_path, progress=lambda line: None)
    result = render_with(gl, scene, bounces=0, directions=256, resolution=64, frames=32, width=32, height=32,
                         bsdf_candidates=candidates)  # fmt: skip
    sphere = np.linalg.norm(np.indices((32, 32)) - 15.5, axis=0) < 9.0  # well inside the sphere's outline
    ours, truth = result.images["direct"][sphere].mean(), ref.images["direct"][sphere].mean()
    assert 0.8 < truth < 0.99  # a rough lobe loses some energy: a directional albedo below 1
    assert ours == pytest.approx(truth, rel=0.01), (ours, truth)


@pytest.mark.parametrize("alpha", [0.05, 0.1, 0.3, 0.5])
def test_half_a_ggx_lobe_lies_within_the_cone_that_k_lobe_counts(alpha):
    # K_lobe's cone: half of D's projected mass lies within tan(theta_h) <= alpha (integrated
    # numerically from the mirror's D), and the cone about the reflected direction has twice that
    # half-angle, so a frame's K hemisphere directions expect K (1 - cos 2 arctan alpha) in it.
    theta = np.linspace(0.0, np.pi / 2, 200001)
    cos = np.cos(theta)
    density = microfacet_d("ggx", alpha, cos) * cos * np.sin(theta) * 2 * np.pi
    mass = np.cumsum(density) * (theta[1] - theta[0])
    assert mass[-1] == pytest.approx(1.0, abs=1e-3)
    assert np.interp(np.arctan(alpha), theta, mass) == pytest.approx(0.5, abs=1e-3)
    assert lobe_directions(alpha) == pytest.approx(1.0 / (1.0 - np.cos(2.0 * np.arctan(alpha))))


@pytest.mark.slow
@pytest.mark.parametrize("alpha, bounces", [(0.1, 1), (0.1, 3), (0.3, 1), (0.3, 3)])
def test_glossy_box_means_are_mitsubas_within_one_percent(gl, alpha, bounces):
    # The rough plastic floor and rough copper sphere, at the bundles' full settings (K = 256,
    # R = 256), against a 4096-spp reference (the user cache keeps it): each channel's mean within
    # 1 % and its 95 % interval inside 2 %. 4 x 4 G-buffer samples a pixel: a frame's one sub-pixel
    # jitter moves the edge of the light, a hundred times brighter than the walls, for the whole
    # image at once, and a single sample a pixel leaves the direct image's frame means +-5 % apart.
    # About 6 minutes a case on 2 cores.
    scene = glossy_box(alpha)
    ref = reference(scene, bounces=bounces, spp=4096, width=64, height=64, progress=lambda line: None)
    result = render_with(gl, scene, bounces=bounces, directions=256, resolution=256, frames=64, width=64, height=64,
                         supersampling=4, seed=1)  # fmt: skip
    for image in ("direct", "indirect"):
        for c in mean_interval(result, ref, image, channels=True):
            assert abs(c["ratio"] - 1.0) <= 0.01 and c["lo"] >= 0.98 and c["hi"] <= 1.02, (image, describe_interval(c))


def test_glossy_box_takes_its_roughness_after_its_name_and_scene_info_lists_each_bsdf():
    scene = load_scene("glossy-box-0.3")
    bsdfs = {m["source_bsdf"]: m["bsdf"] for m in scene_summary(scene)["materials"]}
    conductor = bsdfs["RoughConductor"]
    assert conductor["type"] == "roughconductor" and conductor["alpha"] == pytest.approx(0.3)
    assert bsdfs["RoughPlastic"]["distribution"] == "ggx" and bsdfs["SmoothDiffuse"] == {"type": "diffuse"}
    with pytest.raises(InputError, match="glossy-box-ALPHA"):
        load_scene("glossy-box-3")


def test_precomputed_lighting_of_glossy_materials_is_refused_in_one_line(gl):
    with pytest.raises(InputError, match="use --lighting lazy or auto") as caught:
        render_with(gl, glossy_stage(LAMP), width=8, height=8, directions=4, resolution=16, method="imperfect",
                    lighting="precomputed")  # fmt: skip
    assert "glossy materials (floor, box)" in str(caught.value) and "\n" not in str(caught.value)


def test_a_principled_bsdf_becomes_the_nearest_gloss_and_says_what_it_leaves_out():
    mi = mitsuba()
    metal = {"type": "principled", "base_color": {"type": "rgb", "value": [0.9, 0.6, 0.3]}, "metallic": 0.8,
             "roughness": 0.4, "clearcoat": 0.3}  # fmt: skip
    for bsdf, kind, alpha in ((metal, "roughconductor", 0.16), ({"type": "principled"}, "roughplastic", 0.25)):
        d = mi.cornell_box()
        d["floor"]["bsdf"] = bsdf
        scene = load_mitsuba_dict(d, name="principled")
        (mat,) = [m for m in scene.materials if m.source_bsdf == "Principled"]
        assert mat.gloss.kind == kind and mat.gloss.alpha == pytest.approx(alpha) and mat.approximated
        (warning,) = [w for w in scene.warnings if "(Principled)" in w]
        assert "roughness^2" in warning and ("clearcoat 0.3 ignored" in warning) == (kind == "roughconductor")
        if kind == "roughconductor":  # the base colour is the metal's reflectance head-on
            head_on = fresnel_conductor(np.ones(1), np.asarray(mat.gloss.eta), np.asarray(mat.gloss.k))[0]
            assert head_on == pytest.approx([0.9, 0.6, 0.3], abs=1e-4)
        else:  # Mitsuba's default specular 0.5 is a dielectric of index 1.5
            assert mat.gloss.eta[0] == pytest.approx(1.5) and mat.albedo == pytest.approx((0.5, 0.5, 0.5))


@pytest.mark.parametrize(("metallic", "kind", "taken"), [(0.5, "roughconductor", 1), (0.49, "roughplastic", 0)])
def test_a_partly_metallic_material_is_said_to_be_what_it_becomes(metallic, kind, taken):
    # Half metallic becomes a metal; the note said "taken as 0" (Python rounds 0.5 to even).
    gloss, what = metallic_roughness((0.8, 0.5, 0.3), metallic, 0.4)
    assert gloss.kind == kind and f"metallic {metallic:g} is taken as {taken}" in what
