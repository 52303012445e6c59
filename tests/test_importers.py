"""Importers: Mitsuba XML (through Mitsuba), mesh files (through trimesh), built-in scenes, and the
one-line errors for bad files."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from conftest import write_texture
from PIL import Image

from evalkit.core.bsdf import fresnel_conductor
from evalkit.core.errors import InputError
from evalkit.core.scene import load_scene
from evalkit.core.scene.builtin import FURNACE_ALBEDO, FURNACE_EMISSION, furnace_radiance
from evalkit.core.scene.colour import srgb_to_linear
from evalkit.core.scene.edges import triangle_neighbours
from evalkit.core.scene.mitsuba_io import SMOOTH_ALPHA, SPHERE_SEGMENTS, load_mitsuba_dict, to_mitsuba_dict


def xml_scene(tmp_path, body: str, name: str = "scene.xml") -> str:
    path = tmp_path / name
    path.write_text(f'<scene version="3.0.0">\n{body}\n</scene>\n')
    return str(path)


@pytest.fixture
def mixed_xml(tmp_path):
    """An XML scene with an obj and a ply mesh, a sphere, a textured diffuse, a plastic, a medium,
    and point, spot, directional and constant emitters."""
    (tmp_path / "quad.obj").write_text(
        "v -2 0 -2\nv 2 0 -2\nv 2 0 2\nv -2 0 2\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 3/3 2/2\nf 1/1 4/4 3/3\n"
    )
    trimesh.creation.icosphere(subdivisions=2, radius=0.4).apply_translation([1, 0.4, 0]).export(tmp_path / "ball.ply")
    write_texture(tmp_path / "tex.png")
    return xml_scene(
        tmp_path,
        """
  <sensor type="perspective"><float name="fov" value="40"/><string name="fov_axis" value="y"/>
    <transform name="to_world"><lookat origin="0, 3, 6" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="48"/><integer name="height" value="32"/></film></sensor>
  <bsdf type="twosided" id="floor"><bsdf type="diffuse">
    <texture type="bitmap" name="reflectance"><string name="filename" value="tex.png"/></texture></bsdf></bsdf>
  <bsdf type="plastic" id="plastic"><rgb name="diffuse_reflectance" value="0.2, 0.4, 0.6"/></bsdf>
  <medium type="homogeneous" id="fog"/>
  <shape type="obj"><string name="filename" value="quad.obj"/><ref id="floor"/></shape>
  <shape type="ply"><string name="filename" value="ball.ply"/><ref id="plastic"/></shape>
  <shape type="ply"><string name="filename" value="ball.ply"/><ref id="plastic"/>
    <transform name="to_world"><translate x="-2"/></transform></shape>
  <shape type="sphere"><point name="center" x="-1" y="0.5" z="0"/><float name="radius" value="0.5"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf><ref name="interior" id="fog"/></shape>
  <emitter type="point"><point name="position" x="0" y="3" z="0"/><rgb name="intensity" value="5, 4, 3"/></emitter>
  <emitter type="spot"><transform name="to_world"><lookat origin="0, 4, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
    <float name="cutoff_angle" value="30"/></emitter>
  <emitter type="directional"><vector name="direction" x="0" y="-1" z="0"/>
    <rgb name="irradiance" value="2, 2, 2"/></emitter>
  <emitter type="constant"><rgb name="radiance" value="0.1, 0.1, 0.1"/></emitter>
""",
    )


def test_mitsuba_xml_with_obj_ply_sphere_textures_and_lights(mixed_xml, tmp_path):
    s = load_scene(mixed_xml)
    names = {m.name for m in s.materials}
    assert {"floor", "plastic"} <= names
    floor = next(m for m in s.materials if m.name == "floor")
    # the bitmap comes back linear and in Mitsuba's orientation (texel row = v * H)
    texels = np.asarray(Image.open(tmp_path / "tex.png"), dtype=np.float64) / 255
    np.testing.assert_allclose(floor.texture, srgb_to_linear(texels), atol=2e-3)
    assert floor.twosided and not floor.approximated
    plastic = next(m for m in s.materials if m.name == "plastic")
    assert plastic.approximated and plastic.albedo == pytest.approx((0.2, 0.4, 0.6), abs=1e-5)
    assert plastic.gloss.kind == "roughplastic" and plastic.gloss.alpha == SMOOTH_ALPHA
    # warned once per BSDF even though two shapes use it
    assert sum("BSDF 'plastic' (SmoothPlastic) is smooth" in w for w in s.warnings) == 1
    assert any("participating media" in w for w in s.warnings)
    assert s.features().approximated_bsdfs == ("plastic (SmoothPlastic)",)
    assert s.degenerate_removed == 0  # the tessellation itself makes no degenerate triangles
    # the sphere is tessellated; its area is that of the analytic sphere to 0.1 %
    n_phi, n_theta = SPHERE_SEGMENTS
    sphere = [m for m in s.meshes if len(m.faces) == 2 * n_phi * (n_theta - 1)]
    assert len(sphere) == 1
    assert sphere[0].triangle_areas().sum() == pytest.approx(np.pi, rel=1e-3)
    assert sorted(light.kind for light in s.lights) == ["constant", "directional", "point", "spot"]
    spot = next(light for light in s.lights if light.kind == "spot")
    np.testing.assert_allclose(spot.direction, [0, -1, 0], atol=1e-6)
    assert spot.cutoff_angle == pytest.approx(30)
    point = next(light for light in s.lights if light.kind == "point")
    np.testing.assert_allclose(point.position + s.origin, [0, 3, 0], atol=1e-6)
    assert s.camera.fov_axis == "x" and (s.camera.width, s.camera.height) == (48, 32)
    f = s.features()
    assert f.textures and f.environment == "constant" and f.light_types == ("constant", "directional", "point", "spot")


def test_mitsuba_dict_envmap_roundtrip(mi):
    env = np.random.default_rng(3).random((8, 16, 3)).astype(np.float32)
    s = load_mitsuba_dict(
        {"type": "scene", "e": {"type": "envmap", "bitmap": mi.Bitmap(env), "scale": 2.0}, "r": {"type": "rectangle"}},
        name="env",
    )
    (light,) = s.lights
    assert light.kind == "envmap" and light.intensity == (2.0, 2.0, 2.0)
    np.testing.assert_allclose(light.envmap, env, rtol=1e-6)
    assert any("no camera" in w for w in s.warnings)


@pytest.mark.parametrize(
    "body, message",
    [
        ('<shape type="obj"><string name="filename" value="nowhere.obj"/></shape>', "Mitsuba could not load it"),
        (
            '<shape type="rectangle"/><shape type="rectangle">'
            '<emitter type="area"><rgb name="radiance" value="1,1,1"/></emitter>'
            '<transform name="to_world"><scale x="0" y="0" z="1"/></transform></shape>',
            "zero area",
        ),
        (  # found by `make fuzz-soak`: a zero radius made the normals' transform singular (LinAlgError)
            '<shape type="rectangle"/><shape type="sphere"><float name="radius" value="0"/>'
            '<emitter type="area"><rgb name="radiance" value="1,1,1"/></emitter></shape>',
            "zero area",
        ),
    ],
)
def test_mitsuba_errors_are_one_line_and_name_the_file(tmp_path, body, message):
    path = xml_scene(tmp_path, body)
    with pytest.raises(InputError, match=message) as e:
        load_scene(path)
    assert str(e.value).startswith(path) and "\n" not in str(e.value)


def test_the_scenes_integrator_sampler_and_film_are_ignored_with_a_note(tmp_path, monkeypatch):
    # A polarized integrator and a spectral film stop Mitsuba loading the file in an RGB variant;
    # the toolkit uses neither. The mesh path is relative to the file, not to the working folder.
    (tmp_path / "meshes").mkdir()
    trimesh.creation.box().export(tmp_path / "meshes" / "box.obj")
    path = tmp_path / "polarized.xml"
    path.write_text(
        '<scene version="3.0.0"><integrator type="stokes"><integrator type="path"/></integrator>'
        '<sensor type="perspective"><float name="fov" value="40"/><sampler type="multijitter"/>'
        '<film type="specfilm"><integer name="width" value="24"/><integer name="height" value="16"/>'
        '<rfilter type="gaussian"/></film></sensor>'
        '<shape type="obj"><string name="filename" value="meshes/box.obj"/></shape>'
        '<emitter type="constant"/></scene>'
    )
    monkeypatch.chdir("/")
    scene = load_scene(path)
    assert scene.triangle_count == 12 and (scene.camera.width, scene.camera.height) == (24, 16)
    notes = [w for w in scene.warnings if "is not used" in w]
    assert len(notes) == 3 and "integrator 'stokes'" in notes[0] and "sampler 'multijitter'" in notes[1]
    assert "film 'specfilm' is not used but for its width and height" in notes[2]
    # A real error in such a file still names the file's own line.
    path.write_text(path.read_text().replace("meshes/box.obj", "meshes/none.obj"))
    with pytest.raises(InputError, match="polarized.xml: Mitsuba could not load it: .*line 1"):
        load_scene(path)


def test_malformed_xml(tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text('<scene version="3.0.0"><shape type="obj">\n</scene>')
    with pytest.raises(InputError, match=r"bad\.xml: malformed XML: mismatched tag: line 2"):
        load_scene(path)


def test_obj_with_mtl_texture(tmp_path):
    texels = write_texture(tmp_path / "t.png")
    (tmp_path / "m.mtl").write_text("newmtl painted\nKd 1 1 1\nmap_Kd t.png\n")
    path = tmp_path / "m.obj"
    path.write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl painted\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    s = load_scene(path)
    (mat,) = s.materials
    np.testing.assert_allclose(mat.texture, srgb_to_linear(texels / 255.0), atol=1e-6)
    # OBJ's vt (0, 0) is the image's bottom-left: our uv (0, 1), i.e. the last row
    np.testing.assert_allclose(s.meshes[0].uvs[0], [0, 1])
    assert mat.twosided
    assert any("default sun" in w for w in s.warnings) and any("default camera" in w for w in s.warnings)


def test_obj_map_kd_options_scale_and_offset_the_uvs_and_the_rest_are_said(tmp_path):
    # trimesh took "-s 2 3 1 t.png" for a file name and dropped the texture without a word.
    texels = write_texture(tmp_path / "t.png")
    (tmp_path / "m.mtl").write_text("newmtl tiles\nKd 1 1 1\nmap_Kd -s 2 3 1 -o 0.25 0.5 -clamp on -bm 0.5 t.png\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl tiles\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    s = load_scene(tmp_path / "m.obj")
    (mat,) = s.materials
    np.testing.assert_allclose(mat.texture, srgb_to_linear(texels / 255.0), atol=1e-6)
    assert mat.wrap_mode == "clamp"
    # OBJ's (u, v) (v up the image) looks up (2 u + 0.25, 3 v + 0.5) there; our v runs down it
    for u, v in [(0.0, 0.0), (0.3, 0.7), (1.0, 1.0)]:
        mapped = mat.to_uv @ [u, 1.0 - v, 1.0]
        np.testing.assert_allclose(mapped[:2], [2 * u + 0.25, 1.0 - (3 * v + 0.5)], atol=1e-12)
    assert "material 'tiles': its map_Kd options -bm left out" in s.warnings
    (tmp_path / "m.mtl").write_text("newmtl tiles\nmap_Kd gone.png\n")
    with pytest.raises(InputError, match="material 'tiles': its map_Kd '.*gone.png' cannot be read") as e:
        load_scene(tmp_path / "m.obj")
    assert str(e.value).startswith(str(tmp_path / "m.mtl"))


def test_an_mtl_colour_that_is_not_numbers_is_left_out_and_said(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl bad\nKd 0.5 0.5 0.5\nKe a b c\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl bad\nf 1 2 3\n")
    s = load_scene(tmp_path / "m.obj")
    assert s.materials[0].emission == (0.0, 0.0, 0.0) and s.materials[0].albedo == (0.5, 0.5, 0.5)
    assert "material 'bad': its Ke ['a', 'b', 'c'] is not numbers; left out" in s.warnings


def test_obj_materials_emit_their_ke_and_keep_their_kd_and_say_what_they_leave_out(tmp_path):
    # MTL's Ke was dropped (the lamp went dark and a default sun lit the scene instead), and Kd was
    # read from trimesh's 8-bit copy (0.7 became 0.698).
    (tmp_path / "m.mtl").write_text(
        "newmtl white\nKd 0.7 0.6 0.5\nnewmtl lamp\nKd 0 0 0\nKe 10 9 8\n"
        "newmtl shiny\nKd 0.2 0.2 0.2\nKs 0.5 0.5 0.5\nd 0.8\n"
    )
    quads = "".join(
        f"v -1 {y} -1\nv 1 {y} -1\nv 1 {y} 1\nv -1 {y} 1\nusemtl {m}\nf {4 * i + 1} {4 * i + 3} {4 * i + 2}\n"
        for i, (y, m) in enumerate([(0, "white"), (2, "lamp"), (1, "shiny")])
    )
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + quads)
    s = load_scene(tmp_path / "m.obj")
    mats = {m.name: m for m in s.materials}
    assert mats["white"].albedo == (0.7, 0.6, 0.5) and mats["lamp"].emission == (10.0, 9.0, 8.0)
    assert not any("default sun" in w for w in s.warnings)
    (left,) = [w for w in s.warnings if "left out" in w]
    assert left.startswith("material 'shiny': its specular Ks (0.5, 0.5, 0.5) and its transparency (d, Tr)")


def test_gltf_vertex_colours_under_a_material_are_averaged_into_it_and_said(tmp_path):
    # COLOR_0 multiplies a glTF material's base colour; under a material trimesh keeps it aside,
    # and it was dropped without a word.
    m = trimesh.creation.box()
    m.visual.vertex_colors = np.tile([200, 50, 100, 255], (len(m.vertices), 1)).astype(np.uint8)
    m.export(tmp_path / "painted.glb")

    def material(doc):
        pbr = {"baseColorFactor": [0.5, 0.5, 0.5, 1.0], "metallicFactor": 0.0}
        doc["materials"] = [{"name": "paint", "pbrMetallicRoughness": pbr}]
        doc["meshes"][0]["primitives"][0]["material"] = 0
        return doc

    rewrite_glb(tmp_path / "painted.glb", material)
    s = load_scene(tmp_path / "painted.glb")
    (mat,) = s.materials
    assert mat.albedo == pytest.approx((0.5 * 200 / 255, 0.5 * 50 / 255, 0.5 * 100 / 255), abs=3e-3)
    said = "its COLOR_0 vertex colours are approximated by their mean (0.7843, 0.1961, 0.3922)"
    assert any(said in w for w in s.warnings), s.warnings


def test_a_gltf_emissive_strength_multiplies_the_emission(tmp_path):
    # KHR_materials_emissive_strength (Blender writes it for lamps brighter than 1) was dropped by
    # trimesh: a lamp of strength 40 lit at 1/40 of its power.
    m = trimesh.creation.box()
    lamp = trimesh.visual.material.PBRMaterial(emissiveFactor=[1.0, 0.5, 0.25])
    m.visual = trimesh.visual.TextureVisuals(material=lamp)
    m.export(tmp_path / "lamp.glb")

    def strong(doc):
        (material,) = doc["materials"]
        material["name"] = "lamp"
        material["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": 40.0}}
        return doc

    rewrite_glb(tmp_path / "lamp.glb", strong)
    (mat,) = load_scene(tmp_path / "lamp.glb").materials
    assert mat.emission == pytest.approx((40.0, 20.0, 10.0))

    def unnamed(doc):  # trimesh's materials cannot be matched to the file's without a name: said
        del doc["materials"][0]["name"]
        return doc

    rewrite_glb(tmp_path / "lamp.glb", unnamed)
    s = load_scene(tmp_path / "lamp.glb")
    assert s.materials[0].emission == pytest.approx((1.0, 0.5, 0.25))
    assert "the emissive strength (KHR_materials_emissive_strength) of 1 unnamed material(s) left out" in s.warnings


def test_a_gltf_material_says_what_it_leaves_out_and_refuses_textured_emission(tmp_path):
    # A normal map and an alpha mask were dropped without a word (foliage rendered as opaque quads),
    # and an emissive texture's factor was taken as the whole emission.
    image = Image.new("RGB", (4, 4), (200, 100, 50))
    m = trimesh.creation.box()
    uv = np.random.default_rng(0).random((len(m.vertices), 2))
    pbr = trimesh.visual.material.PBRMaterial
    leaf = pbr(normalTexture=image, alphaMode="MASK", alphaCutoff=0.5)
    m.visual = trimesh.visual.TextureVisuals(uv=uv, material=leaf)
    m.export(tmp_path / "leaf.glb")
    s = load_scene(tmp_path / "leaf.glb")
    assert any(
        "its normal map (the mesh's normals shade it) and its alpha mode MASK (rendered opaque) left out" in w
        for w in s.warnings
    ), s.warnings
    m.visual = trimesh.visual.TextureVisuals(uv=uv, material=pbr(emissiveFactor=[1, 1, 1], emissiveTexture=image))
    m.export(tmp_path / "screen.glb")
    with pytest.raises(InputError, match="textured emission \\(emissiveTexture\\) is not supported") as e:
        load_scene(tmp_path / "screen.glb")
    assert "\n" not in str(e.value)


def rewrite_glb(path, edit) -> None:
    """A GLB file with its JSON chunk changed by ``edit`` (a function of the parsed JSON)."""
    data = path.read_bytes()
    length = int.from_bytes(data[12:16], "little")
    doc = edit(json.loads(data[20 : 20 + length]))
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + length :]
    body = len(text).to_bytes(4, "little") + b"JSON" + text + rest
    path.write_bytes(data[:8] + (12 + len(body)).to_bytes(4, "little") + body)


def test_a_gltf_camera_is_the_scenes_camera_wherever_its_node_is(tmp_path):
    # A glTF's camera was dropped ("no camera in the input"), and trimesh reads only a root node's.
    scene = trimesh.Scene(trimesh.creation.box())
    scene.set_camera(angles=(0.3, 0.5, 0.0), distance=4.0, fov=(50.0, 40.0))
    scene.export(tmp_path / "seen.glb")
    s = load_scene(tmp_path / "seen.glb")
    assert not any("no camera" in w for w in s.warnings)
    placed = np.asarray(trimesh.load(tmp_path / "seen.glb", force="scene").camera_transform)
    np.testing.assert_allclose(s.camera.to_world[:3, :3], placed[:3, :3] @ np.diag([-1.0, 1.0, -1.0]), atol=1e-9)
    np.testing.assert_allclose(s.camera.position + s.origin, placed[:3, 3], atol=1e-9)
    assert (s.camera.fov, s.camera.fov_axis, s.camera.width / s.camera.height) == (pytest.approx(40.0), "y", 1.25)

    def nest(doc):  # the camera under a parent moved by 5 along z and scaled by 2 (a camera keeps no scale)
        (i,) = [n for n, node in enumerate(doc["nodes"]) if "camera" in node]
        doc["nodes"].append({"translation": [0.0, 0.0, 5.0], "scale": [2.0, 2.0, 2.0], "children": [i]})
        roots = doc["scenes"][doc.get("scene", 0)]["nodes"]
        roots[roots.index(i)] = len(doc["nodes"]) - 1
        box = {"xmag": 3.0, "ymag": 2.0, "znear": 0.1, "zfar": 50.0}
        doc["cameras"][0] = {"type": "orthographic", "orthographic": box}
        return doc

    rewrite_glb(tmp_path / "seen.glb", nest)
    s = load_scene(tmp_path / "seen.glb")
    assert s.camera.orthographic and (s.camera.width, s.camera.height) == (768, 512)
    np.testing.assert_allclose(s.camera.position + s.origin, 2.0 * placed[:3, 3] + [0.0, 0.0, 5.0], atol=1e-9)
    # an orthographic camera's scale is its half-width: xmag
    np.testing.assert_allclose(np.linalg.norm(s.camera.to_world[:3, :3], axis=0), [3.0, 3.0, 1.0], atol=1e-9)

    def lit(doc):  # punctual lights, whose photometric units the toolkit does not read, are said
        doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": 20.0}]}}
        doc.setdefault("extensionsUsed", []).append("KHR_lights_punctual")
        return doc

    rewrite_glb(tmp_path / "seen.glb", lit)
    assert (
        "1 KHR_lights_punctual light(s) left out (their units are photometric)"
        in load_scene(tmp_path / "seen.glb").warnings
    )

    def tiled(doc):  # a texture transform, which trimesh drops, is said too
        transform = {"KHR_texture_transform": {"scale": [4.0, 4.0]}}
        doc["materials"] = [{"name": "floor", "pbrMetallicRoughness": {"extensions": transform}}]
        return doc

    rewrite_glb(tmp_path / "seen.glb", tiled)
    assert "the texture transforms (KHR_texture_transform) of material(s) floor left out" in (
        load_scene(tmp_path / "seen.glb").warnings
    )


@pytest.mark.parametrize("ext", ["gltf", "glb", "ply"])
def test_gltf_glb_ply(tmp_path, ext):
    m = trimesh.creation.box(extents=[1, 2, 3])
    m.visual = trimesh.visual.TextureVisuals(
        uv=np.random.default_rng(0).random((len(m.vertices), 2)),
        material=trimesh.visual.material.PBRMaterial(
            baseColorFactor=[0.2, 0.4, 0.6, 1.0],
            emissiveFactor=[1.0, 0.5, 0.0],
            metallicFactor=0.0,
            roughnessFactor=0.5,
        ),
    )
    path = tmp_path / f"box.{ext}"
    m.export(path)
    s = load_scene(path)
    assert s.triangle_count == 12
    np.testing.assert_allclose(s.bounds()[1] - s.bounds()[0], [1, 2, 3])
    if ext != "ply":  # PLY carries no materials
        (mat,) = s.materials
        assert mat.albedo == pytest.approx((0.2, 0.4, 0.6), abs=3e-3)
        assert mat.gloss.kind == "roughplastic" and mat.gloss.alpha == pytest.approx(0.25)  # roughness^2
        assert mat.approximated and any("glTF metallic-roughness" in w for w in s.warnings)
        assert any("base colour factor as trimesh reads it, rounded to 8 bits" in w for w in s.warnings)
        assert mat.emission == pytest.approx((1.0, 0.5, 0.0))
        assert not any("default sun" in w for w in s.warnings)


@pytest.mark.parametrize("normals", ["", '<boolean name="face_normals" value="true"/>'])
def test_a_mesh_with_flip_normals_faces_the_other_way(tmp_path, normals):
    # Mitsuba turns a mesh's normals where it shades it: an emitter lights the other side. The
    # import kept the file's winding, and such a lamp lit nothing (the import check: 0 of the image).
    (tmp_path / "up.obj").write_text(
        "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvn 0 1 0\nf 1//1 3//1 2//1\nf 1//1 4//1 3//1\n"
    )
    s = load_scene(
        xml_scene(
            tmp_path,
            f'<shape type="obj"><string name="filename" value="up.obj"/>{normals}'
            '<boolean name="flip_normals" value="true"/><emitter type="area"/></shape>',
        )
    )
    a = s.arrays()
    assert np.allclose(a.tri_normal, [0, -1, 0])
    if not normals:  # the file's vertex normals turn with the faces
        assert a.tri_smooth.all() and np.allclose(a.normals, [0, -1, 0])


@pytest.mark.parametrize("ext, decode", [("ply", srgb_to_linear), ("glb", lambda c: c)])
def test_mesh_vertex_colors_are_the_reflectance_decoded_as_the_format_says(tmp_path, ext, decode):
    # PLY's 8-bit colours are sRGB, as its textures are; glTF's COLOR_0 is linear (its specification).
    # They were averaged into one albedo, with only a warning.
    m = trimesh.creation.icosphere(subdivisions=1)
    codes = np.random.default_rng(3).integers(0, 256, (len(m.vertices), 4)).astype(np.uint8)
    m.visual.vertex_colors = codes
    m.export(tmp_path / f"ball.{ext}")
    s = load_scene(tmp_path / f"ball.{ext}")
    (mesh,), (mat,) = s.meshes, s.materials
    assert mat.vertex_colors and not mat.approximated and mat.texture is None
    assert not any("colour" in w for w in s.warnings), s.warnings
    # trimesh keeps a PLY's vertices in their order; glTF's exporter may merge or reorder them
    found = {tuple(np.round(p, 5)): c for p, c in zip(mesh.positions + s.origin, mesh.colors)}
    for p, c in zip(m.vertices, codes[:, :3] / 255.0):
        assert found[tuple(np.round(p, 5))] == pytest.approx(decode(c), abs=1e-6)


def test_face_colors_give_each_corner_its_face_colour(tmp_path):
    m = trimesh.creation.box()
    colors = np.random.default_rng(4).integers(0, 256, (len(m.faces), 4)).astype(np.uint8)
    m.visual.face_colors = colors
    m.export(tmp_path / "box.ply")
    s = load_scene(tmp_path / "box.ply")
    (mesh,), (mat,) = s.meshes, s.materials
    assert mat.vertex_colors and not mat.approximated
    assert len(mesh.positions) == 3 * len(mesh.faces) == 36  # corners unshared
    expected = srgb_to_linear(colors[:, :3] / 255.0)
    np.testing.assert_allclose(mesh.colors.reshape(-1, 3, 3), np.repeat(expected[:, None], 3, axis=1), atol=1e-9)
    # The box's faces still meet across their edges: the corners are welded by position there.
    across, _ = triangle_neighbours(mesh.positions, mesh.faces, s.arrays().tri_normal)
    assert (across >= 0).all()


@pytest.mark.parametrize(
    "factors, alpha", [({"metallicFactor": 1.0, "roughnessFactor": 0.3}, 0.09), ({}, 1.0)], ids=["metal", "defaults"]
)
def test_a_gltf_metal_is_a_rough_conductor_reflecting_its_base_colour_head_on(tmp_path, factors, alpha):
    # glTF's defaults are metallic 1 and roughness 1: a material that names neither is a rough metal.
    m = trimesh.creation.box()
    m.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(baseColorFactor=[0.9, 0.6, 0.3, 1.0], **factors)
    )
    m.export(tmp_path / "metal.glb")
    (mat,) = load_scene(tmp_path / "metal.glb").materials
    gloss = mat.gloss
    assert gloss.kind == "roughconductor" and gloss.distribution == "ggx" and gloss.alpha == pytest.approx(alpha)
    assert mat.albedo == (0.0, 0.0, 0.0)
    head_on = fresnel_conductor(np.ones(1), np.asarray(gloss.eta), np.asarray(gloss.k))[0]
    assert head_on == pytest.approx(np.array([0.9, 0.6, 0.3]), abs=5e-3)


PLY_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
)
BAD_FILES = {
    "nan.obj": ("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "NaN or Inf coordinates"),
    "inf.obj": ("v 0 0 0\nv 1 0 0\nv 0 inf 0\nf 1 2 3\n", "NaN or Inf coordinates"),
    "range.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "line 4: face v index 9 names none of the 3 'v' above it"),
    # Met by a new user: trimesh dropped the face silently, or answered with numpy's words and no line.
    "two-index-face.obj": (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\n",
        "line 4: a face needs 3 vertices or more, found 2",
    ),
    "past-the-end.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 5\n", "line 5: face v index 5 names none of the 4"),
    "word-index.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 4 x\n", "line 5: face v index 'x' is not an integer"),
    "texcoord-range.obj": (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n",
        "line 5: face vt index 2 names none of the 1",
    ),
    "two-index-face.ply": (
        PLY_HEADER + "0 0 0\n1 0 0\n0 1 0\n2 0 1\n3 0 1 2\n",
        "line 13: a face needs 3 vertices or more, found 2",
    ),
    "word-index.ply": (
        PLY_HEADER + "0 0 0\n1 0 0\n0 1 0\n3 0 1 x\n3 0 1 2\n",
        "line 13: 'vertex_indices' value 'x' is not a number",
    ),
    "index-range.ply": (
        PLY_HEADER + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 3\n",
        r"line 14: face vertex index 3 is not one of 0\.\.2",
    ),
    "short-vertex.ply": (
        PLY_HEADER + "0 0 0\n1 0\n0 1 0\n3 0 1 2\n3 0 1 2\n",
        "line 11: vertex record has 2 values, 'z' is missing",
    ),
    "cut-short.ply": (PLY_HEADER + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "line 14: the file ends inside element 'face'"),
    "empty.obj": ("", "the file is empty"),
    "garbage.obj": (bytes(range(256)) * 4, "no triangle geometry|cannot be read"),
    "garbage.ply": (b"ply\nformat nonsense\n" + bytes(range(256)), "cannot be read|no triangle geometry"),
    "garbage.glb": (b"glTF" + bytes(range(200)), "cannot be read|no triangle geometry"),
    "nofaces.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangle geometry"),
    "flat.obj": ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "all degenerate"),
    # Found by tests/test_fuzz_importers.py: trimesh returns (n, 2) positions, which crashed the import.
    "two-coordinates.obj": ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "line 2: 'v' needs 3 numbers, found 2"),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_mesh_files(tmp_path, name):
    content, message = BAD_FILES[name]
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(InputError, match=message) as e:
        load_scene(path)
    assert str(e.value).startswith(str(path)) and "\n" not in str(e.value)


def test_missing_files_and_unknown_names(tmp_path):
    for name in ("missing.obj", "missing.xml"):
        with pytest.raises(InputError, match="file not found"):
            load_scene(tmp_path / name)
    with pytest.raises(InputError, match="not a built-in scene"):
        load_scene("no-such-scene")
    (tmp_path / "x.fbx").write_text("x")
    with pytest.raises(InputError, match="unsupported file type '.fbx'"):
        load_scene(tmp_path / "x.fbx")


def test_cornell_box_is_mitsubas_own(mi):
    s = load_scene("cornell-box")
    ref = mi.load_dict(mi.cornell_box())
    ref_area = sum(float(np.array(sh.surface_area()).ravel()[0]) for sh in ref.shapes())
    assert s.surface_area() == pytest.approx(ref_area, rel=1e-6)
    assert s.triangle_count == 36
    assert s.features().light_types == ("area",)
    assert s.camera.fov == pytest.approx(39.3077, rel=1e-5) and (s.camera.width, s.camera.height) == (256, 256)


def test_furnace_is_closed_uniform_and_analytic():
    s = load_scene("furnace")
    (mat,) = s.materials
    assert mat.albedo == (FURNACE_ALBEDO,) * 3 and mat.emission == (FURNACE_EMISSION,) * 3
    # closed: every edge is shared by exactly two triangles, wound oppositely
    mesh = trimesh.Trimesh(s.meshes[0].positions, s.meshes[0].faces, process=True)
    assert mesh.is_watertight and mesh.is_winding_consistent
    # front sides face inward: the signed volume of an inward-wound closed mesh is negative
    assert mesh.volume == pytest.approx(-8.0)
    assert furnace_radiance(1) == 1.0 and furnace_radiance(2) == 1.5
    assert furnace_radiance(200) == pytest.approx(FURNACE_EMISSION / (1 - FURNACE_ALBEDO))


def test_atrium_is_large_textured_and_lit():
    s = load_scene("atrium")
    f = s.features()
    assert f.triangle_count >= 250_000
    assert f.textures and set(f.light_types) == {"directional", "point"}
    assert s.degenerate_removed == 0
    assert load_scene("atrium").content_hash() == s.content_hash()  # deterministic


def _reflectance_at(mi, bsdf, uv):
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(uv))
    si.uv = mi.Point2f(uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32))
    si.wi = mi.Vector3f(0, 0, 1)
    return np.array(bsdf.eval_diffuse_reflectance(si)).reshape(3, -1).T


@pytest.mark.parametrize(
    "texture",
    [
        '<texture type="bitmap" name="reflectance"><string name="filename" value="tex.png"/>'
        '<string name="wrap_mode" value="mirror"/><string name="filter_type" value="nearest"/>'
        '<transform name="to_uv"><scale x="2" y="5"/><translate x="0.25"/></transform></texture>',
        '<texture type="bitmap" name="reflectance"><string name="filename" value="tex.png"/>'
        '<string name="wrap_mode" value="clamp"/><transform name="to_uv"><scale x="3" y="-2"/></transform></texture>',
        '<texture type="checkerboard" name="reflectance"><rgb name="color0" value="0.1, 0.2, 0.3"/>'
        '<rgb name="color1" value="0.8, 0.7, 0.6"/><transform name="to_uv"><scale x="4" y="3"/></transform></texture>',
    ],
)
def test_texture_transforms_wrap_modes_filters_and_checkerboards_import_and_export_exactly(mi, tmp_path, texture):
    from evalkit.core.scene.colour import sample_texture
    from evalkit.core.scene.mitsuba_io import _bsdf_dict

    write_texture(tmp_path / "tex.png", size=8)
    body = f'<shape type="rectangle"><bsdf type="diffuse" id="tiles">{texture}</bsdf></shape>'
    s = load_scene(xml_scene(tmp_path, body))
    (mat,) = s.materials
    assert not mat.approximated and not any("tiles" in w for w in s.warnings), s.warnings
    original = mi.load_string(f'<scene version="3.0.0">{body}</scene>'.replace("tex.png", str(tmp_path / "tex.png")))
    bsdf = original.shapes()[0].bsdf()
    uv = np.random.default_rng(2).uniform(-1.5, 2.5, (5000, 2))
    truth = _reflectance_at(mi, bsdf, uv)
    ours = sample_texture(mat.texture, uv, mat.to_uv, mat.wrap_mode, mat.filter_type)
    off = np.abs(ours - truth).max(axis=1) > 1e-4
    # nearest lookups within float32 rounding of a texel border may take its neighbour
    assert off.mean() < 0.002, off.mean()
    exported = _reflectance_at(mi, mi.load_dict(_bsdf_dict(mi, mat)), uv)
    assert (np.abs(exported - truth).max(axis=1) > 1e-4).mean() < 0.002


def test_a_blend_with_a_conductor_never_becomes_a_diffuse_albedo_above_one(tmp_path):
    body = (
        '<shape type="rectangle"><bsdf type="blendbsdf" id="gold"><float name="weight" value="0.5"/>'
        '<bsdf type="roughconductor"><string name="material" value="Au"/></bsdf><bsdf type="diffuse"/></bsdf></shape>'
    )
    s = load_scene(xml_scene(tmp_path, body))
    (mat,) = s.materials
    assert mat.approximated and max(mat.albedo) <= 1.0
    assert any("BSDF 'gold' (BlendBSDF)" in w and "clamped to 1" in w for w in s.warnings), s.warnings


def test_instances_cylinders_and_flipped_shapes_import_as_mitsuba_sees_them(mi, tmp_path):
    # A shape group instanced three times (its shapes' transforms composed with the instances'),
    # an open cylinder and a sphere whose normals are flipped: the imported scene, exported back, is
    # hit by the same rays at the same distances from the same side as Mitsuba's own load of the file.
    body = """
  <shape type="shapegroup" id="post">
    <shape type="cylinder"><float name="radius" value="0.2"/>
      <transform name="to_world"><scale z="1.5"/><rotate x="1" angle="-90"/></transform></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="0.5"/><translate y="1.5"/></transform></shape>
  </shape>
  <shape type="instance"><ref id="post"/><transform name="to_world"><translate x="-0.6"/><rotate y="1" angle="30"/>
    </transform></shape>
  <shape type="instance"><ref id="post"/><transform name="to_world"><translate x="0.6"/><rotate y="1" angle="30"/>
    </transform></shape>
  <shape type="instance"><ref id="post"/><transform name="to_world"><translate z="-2"/></transform></shape>
  <shape type="sphere"><point name="center" x="0" y="0.5" z="1.5"/><float name="radius" value="0.4"/>
    <boolean name="flip_normals" value="true"/></shape>
"""
    path = xml_scene(tmp_path, body)
    s = load_scene(path)
    assert len(s.meshes) == 7 and not s.warnings[:-1], s.warnings  # 3 posts x 2 shapes, 1 sphere
    original = mi.load_file(path)
    imported = mi.load_dict(to_mitsuba_dict(s, mi))
    rng = np.random.default_rng(4)
    origin = rng.normal(size=(20000, 3)) * 3.0 + [0, 0.75, 0]
    direction = rng.uniform([-1.0, 0.0, -2.2], [1.0, 1.6, 1.9], (20000, 3)) - origin  # through the scene's bounds
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)

    def cast(scene, shift):
        ray = mi.Ray3f(mi.Point3f(*(origin - shift).T.astype(np.float32)), mi.Vector3f(*direction.T.astype(np.float32)))
        si = scene.ray_intersect(ray)
        t = np.array(si.t)
        facing = np.sum(np.array(si.n).T * direction, axis=1) < 0
        return np.where(np.isfinite(t), t, -1.0), facing

    t0, f0 = cast(original, np.zeros(3))
    t1, f1 = cast(imported, s.origin)
    hit = t0 > 0
    assert hit.mean() > 0.3
    same = (np.abs(t0 - t1) < 2e-3 * np.maximum(t0, 1.0)) & (f0 == f1)
    # tessellation: rays grazing the 128-sided cylinder and sphere may hit one and miss the other
    assert same.mean() > 0.995, same.mean()


@pytest.mark.parametrize(
    "body, message",
    [
        (
            '<shape type="bsplinecurve"><string name="filename" value="c.txt"/></shape>',
            "plugin BSplineCurve is not supported",
        ),
        (
            '<sensor type="radiancemeter"><film type="hdrfilm"><integer name="width" value="1"/>'
            '<integer name="height" value="1"/></film></sensor>',
            "sensor plugin RadianceMeter is not supported",
        ),
        (
            '<emitter type="spot"><texture type="bitmap" name="texture"><string name="filename" value="tex.png"/>'
            "</texture></emitter>",
            "spot light: a projected texture is not supported",
        ),
        (
            '<shape type="rectangle" id="lamp"><emitter type="area"><texture type="bitmap" name="radiance">'
            '<string name="filename" value="tex.png"/></texture></emitter></shape>',
            "shape 'lamp': textured area emission is not supported",
        ),
        (
            '<shape type="ply" id="box"><string name="filename" value="colours.ply"/><bsdf type="blendbsdf" id="paint">'
            '<texture type="mesh_attribute" name="weight"><string name="name" value="vertex_color"/></texture>'
            '<bsdf type="diffuse"/><bsdf type="conductor"/></bsdf></shape>',
            "BSDF 'paint': a mesh_attribute texture is supported as a diffuse reflectance of a mesh's vertex or face",
        ),
        (
            '<shape type="ply" id="box"><string name="filename" value="rgb.ply"/><bsdf type="blendbsdf" id="paint">'
            '<float name="weight" value="0.5"/><bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance">'
            '<string name="name" value="vertex_color"/></texture></bsdf><bsdf type="conductor"/></bsdf></shape>',
            r"BSDF 'paint' \(BlendBSDF\): vertex or face colours are supported on diffuse BSDFs only",
        ),
        (
            '<shape type="ply" id="box"><string name="filename" value="colours.ply"/><bsdf type="diffuse">'
            '<texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/></texture>'
            "</bsdf></shape>",
            "shape 'box': mesh attribute 'vertex_color' has 32 values for 8 elements, not 3",  # RGBA
        ),
        (
            '<shape type="sphere" id="ball"><bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance">'
            '<string name="name" value="vertex_color"/></texture></bsdf></shape>',
            r"shape 'ball' \(Sphere\): a mesh_attribute texture needs a mesh's attributes",
        ),
        ('<emitter type="projector"/>', "emitter plugin Projector is not supported"),
        (  # Mitsuba loads a volume texture without its volume, and crashes evaluating it
            '<shape type="sphere"><bsdf type="diffuse" id="fog"><texture type="volume" name="reflectance"/></bsdf>'
            "</shape>",
            r"BSDF 'fog' \(SmoothDiffuse\): a volume texture is not supported",
        ),
        (
            '<shape type="sphere"><bsdf type="diffuse" id="fog"><texture type="volume" name="reflectance">'
            '<volume type="constvolume" name="volume"><rgb name="value" value="0.2, 0.4, 0.6"/></volume></texture>'
            "</bsdf></shape>",
            r"BSDF 'fog' \(SmoothDiffuse\): a volume texture is not supported",
        ),
    ],
)
def test_what_the_toolkit_cannot_represent_is_refused_in_one_line(tmp_path, body, message):
    (tmp_path / "c.txt").write_text("0 0 0 0.1\n1 0 0 0.1\n2 1 0 0.1\n3 1 0 0.1\n")
    write_texture(tmp_path / "tex.png")
    box = trimesh.creation.box()
    box.visual.vertex_colors = np.full((len(box.vertices), 4), 200, dtype=np.uint8)
    box.export(tmp_path / "colours.ply")
    rgb = "".join(f"{x} {y} {z} 0.5 0.4 0.3\n" for x, y, z in box.vertices)
    faces = "".join(f"3 {a} {b} {c}\n" for a, b, c in box.faces)
    header = "".join(f"property float {p}\n" for p in "xyzrgb")
    (tmp_path / "rgb.ply").write_text(
        f"ply\nformat ascii 1.0\nelement vertex 8\n{header}element face 12\nproperty list uchar int vertex_indices\n"
        f"end_header\n{rgb}{faces}"
    )
    path = xml_scene(tmp_path, '<shape type="rectangle"/>' + body)
    with pytest.raises(InputError, match=message) as e:
        load_scene(path)
    assert str(e.value).startswith(path) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "body, message",
    [
        (
            '<shape type="sphere"><bsdf type="diffuse"><texture type="bitmap" name="reflectance"/></bsdf></shape>',
            "texture 'reflectance': a bitmap texture without a filename",
        ),
        ('<shape type="sphere"><bsdf type="blendbsdf" id="mix"/></shape>', "bsdf 'mix': a blendbsdf without a weight"),
        ('<include filename="parts.xml"/>', "parts.xml: a blendbsdf without a weight"),  # named in the file it is in
        (
            '<shape type="ply"><string name="filename" value="far.ply"/></shape>',
            "far.ply: face index 99 is out of range for 3 vertices",
        ),
    ],
)
def test_what_crashes_mitsubas_loader_is_refused_before_it_loads(tmp_path, body, message):
    """Mitsuba 3.9's loader dies of a segmentation fault on these (no exception to catch), or reads
    a PLY's faces past its vertices: the importer refuses them in one line before Mitsuba sees
    them, in files, included files and dicts."""
    xml_scene(tmp_path, '<shape type="sphere"><bsdf type="blendbsdf"/></shape>', name="parts.xml")
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    header += "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    corners = np.eye(3, dtype="<f4").tobytes()
    (tmp_path / "far.ply").write_bytes(header.encode() + corners + b"\x03" + np.array([0, 1, 99], "<i4").tobytes())
    path = xml_scene(tmp_path, body)
    with pytest.raises(InputError, match=message) as e:
        load_scene(path)
    assert "(Mitsuba" in str(e.value) and "\n" not in str(e.value)
    d = {"type": "scene", "ball": {"type": "sphere", "bsdf": {"type": "diffuse", "reflectance": {"type": "bitmap"}}}}
    with pytest.raises(InputError, match="d: 'reflectance': a bitmap texture without a filename"):
        load_mitsuba_dict(d, name="d")
    with pytest.raises(InputError, match="far.ply: face index 99 is out of range for 3 vertices"):
        load_mitsuba_dict({"type": "scene", "mesh": {"type": "ply", "filename": str(tmp_path / "far.ply")}}, name="d")
