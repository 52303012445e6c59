"""OBJ, PLY, glTF and GLB files through trimesh, with their materials and textures.

trimesh is lenient: garbage and empty files come back as empty scenes, and with ``process=True``
NaN vertices vanish with their faces. So the file is loaded with ``process=False`` (nothing is
dropped behind our back) and `assemble` validates what came back.

Material mapping: a PBR material's base colour (factor times texture) or a simple material's
diffuse colour and image become the albedo; 8-bit textures are sRGB and are linearised; factors
are linear. glTF ``doubleSided`` maps to a two-sided material; OBJ and PLY have no such notion and
are imported two-sided. Vertex or face colours on a mesh without a material become its
reflectance (`_colors`). A glTF metallic-roughness material becomes a rough conductor or a rough
plastic (`_gloss` says how), with a warning, since glTF's BRDF is neither exactly. A file with no
emissive material gets a default sun, and a file without a camera (OBJ and PLY have none; a glTF
file's is read by `_gltf_camera`) a default one, both stated in the scene's warnings.
"""

from __future__ import annotations

import json
import math
import os
from typing import NamedTuple

import numpy as np

from evalkit.core.errors import InputError
from evalkit.core.scene.assemble import assemble, default_sun, face_colors_at_corners
from evalkit.core.scene.colour import rgb, rounded, srgb_to_linear
from evalkit.core.scene.gloss import metallic_roughness
from evalkit.core.scene.mesh_lines import check_obj, check_ply
from evalkit.core.scene.model import Camera, Gloss, Material, Mesh, Scene


class OwnReading(NamedTuple):
    """What the toolkit reads from a mesh file itself, where trimesh drops it: per OBJ material its
    map_Kd (`_mtl_maps`), per named glTF material its emissive strength (`_emissive_strengths`)."""

    map_kd: dict
    emissive_strengths: dict


def load_mesh_file(path: str | os.PathLike) -> Scene:
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(path, "file not found")
    if os.path.getsize(path) == 0:
        raise InputError(path, "the file is empty")
    extension = os.path.splitext(path)[1].lower()
    obj_text = None
    if extension in (".obj", ".ply"):  # text records checked to the line first (mesh_lines)
        with open(path, "rb") as f:
            data = f.read()
        if extension == ".obj":
            obj_text = data.decode("utf-8", "replace")
            check_obj(path, obj_text)
        else:
            check_ply(path, data)
    import trimesh

    try:
        loaded = trimesh.load(path, force="scene", process=False, validate=False)
    except IndexError as e:
        raise InputError(path, f"a face refers to a vertex that does not exist ({e})") from None
    except Exception as e:  # trimesh raises many types for unreadable input; all mean the same here
        raise InputError(
            path, f"cannot be read as {os.path.splitext(path)[1].lstrip('.').upper()}: {type(e).__name__}: {e}"
        ) from None

    warnings: list[str] = []
    doc = _gltf_document(path) if extension in (".gltf", ".glb") else {}
    own = OwnReading(_mtl_maps(path, obj_text) if obj_text is not None else {}, _emissive_strengths(doc, warnings))
    materials: list[Material] = []
    material_index: dict[int, int] = {}
    meshes: list[Mesh] = []
    for node in loaded.graph.nodes_geometry:
        transform, geometry_name = loaded.graph[node]
        geometry = loaded.geometry[geometry_name]
        if not isinstance(geometry, trimesh.Trimesh):
            warnings.append(f"'{geometry_name}' is a {type(geometry).__name__}, not a triangle mesh; it is left out")
            continue
        transform = np.asarray(transform, dtype=np.float64)
        mesh = _mesh(path, node, geometry, transform, materials, material_index, own, warnings)
        if mesh is not None:
            meshes.append(mesh)
    if not meshes:
        raise InputError(path, "no triangle geometry in the file (empty, or not a mesh this reader understands)")
    lights = []
    if not any(m.emissive for m in materials):
        lights.append(default_sun())
        warnings.append("no emissive material in the file; a default sun (directional light) is used")
    name = os.path.splitext(os.path.basename(path))[0]
    camera = None
    if doc:
        try:
            camera = _gltf_camera(doc)
        except (KeyError, IndexError, TypeError, ValueError, ZeroDivisionError) as e:
            raise InputError(path, f"its camera cannot be read: {type(e).__name__}: {e}") from None
        lights_left_out = len(doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", []))
        if lights_left_out:
            warnings.append(f"{lights_left_out} KHR_lights_punctual light(s) left out (their units are photometric)")
        transformed = [
            m.get("name", str(i))
            for i, m in enumerate(doc.get("materials", []))
            if "KHR_texture_transform" in json.dumps(m)
        ]
        if transformed:
            names = ", ".join(transformed)
            warnings.append(f"the texture transforms (KHR_texture_transform) of material(s) {names} left out")
    return assemble(name, path, meshes, materials, lights, camera=camera, warnings=warnings)


# MTL texture options and how many values each takes (a range: -o, -s and -t take one to three).
MTL_OPTIONS = {
    "-blendu": (1, 1), "-blendv": (1, 1), "-cc": (1, 1), "-clamp": (1, 1), "-mm": (2, 2), "-o": (1, 3),
    "-s": (1, 3), "-t": (1, 3), "-texres": (1, 1), "-bm": (1, 1), "-boost": (1, 1), "-imfchan": (1, 1), "-type": (1, 1),
}  # fmt: skip


def _mtl_maps(obj_path: str, obj_text: str) -> dict[str, tuple[str, dict, str]]:
    """Per material of the MTL files the OBJ text names, its map_Kd: (the image's path, its
    options, the MTL file), read here because trimesh takes an option for part of the file name
    and then drops the texture without a word."""
    folder = os.path.dirname(os.path.abspath(obj_path))
    libraries = [name for line in obj_text.splitlines() if line.startswith("mtllib") for name in line.split()[1:]]
    maps, material = {}, None
    for library in libraries:
        mtl = os.path.join(folder, library)
        if not os.path.isfile(mtl):
            continue  # trimesh reads what it finds; a missing library leaves its materials white, as it says
        with open(mtl, encoding="utf-8", errors="replace") as f:
            for line in f:
                words = line.split()
                if words[:1] == ["newmtl"] and len(words) > 1:
                    material = " ".join(words[1:])
                elif words[:1] and words[0].lower() == "map_kd" and material is not None:
                    options, i = {}, 1
                    while i < len(words) - 1 and words[i].lower() in MTL_OPTIONS:
                        least, most = MTL_OPTIONS[words[i].lower()]
                        values = words[i + 1 : i + 1 + least]
                        for extra in words[i + 1 + least : i + 1 + most]:
                            try:
                                float(extra)
                            except ValueError:
                                break
                            values.append(extra)
                        options[words[i].lower()] = values
                        i += 1 + len(values)
                    image = os.path.join(os.path.dirname(mtl), " ".join(words[i:]))
                    maps[material] = (image, options, mtl)
    return maps


def _emissive_strengths(doc: dict, warnings: list[str]) -> dict[str, float]:
    """Per named glTF material, its KHR_materials_emissive_strength, which multiplies its emissive
    factor (trimesh drops it); that of an unnamed material, which trimesh's materials cannot be
    matched to, is named in a warning."""
    strengths, unnamed = {}, 0
    for m in doc.get("materials", []):
        strength = m.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength")
        if strength is None:
            continue
        if "name" in m:
            strengths[m["name"]] = float(strength)
        else:
            unnamed += 1
    if unnamed:
        what = "the emissive strength (KHR_materials_emissive_strength)"
        warnings.append(f"{what} of {unnamed} unnamed material(s) left out")
    return strengths


def _mtl_image(name: str, file: str, options: dict, mtl: str, warnings: list[str]):
    """A map_Kd's image, and its lookup (`_mtl_lookup`)."""
    from PIL import Image

    try:
        image = Image.open(file)
        image.load()
    except (OSError, ValueError) as e:
        why = f"{type(e).__name__}: {e}"
        raise InputError(mtl, f"material '{name}': its map_Kd '{file}' cannot be read: {why}") from None
    return image, _mtl_lookup(name, options, warnings)


def _mtl_lookup(name: str, options: dict, warnings: list[str]) -> dict:
    """A map_Kd's options as the texture lookup's: -s and -o scale and offset the uvs, u' = s u + o
    (three.js's and Blender's reading), in our uvs whose v runs down the image; -clamp on clamps.
    Any other option is left out, with a warning."""

    def triple(key, default):
        v = [float(x) for x in options.get(key, [])]
        return v + [default] * (2 - len(v))

    (su, sv), (ou, ov) = triple("-s", 1.0)[:2], triple("-o", 0.0)[:2]
    lookup = {}
    if "-s" in options or "-o" in options:
        lookup["to_uv"] = np.array([[su, 0.0, ou], [0.0, sv, 1.0 - sv - ov], [0.0, 0.0, 1.0]])
    if options.get("-clamp", ["off"])[0].lower() == "on":
        lookup["wrap_mode"] = "clamp"
    left_out = sorted(set(options) - {"-s", "-o", "-clamp"})
    if left_out:
        warnings.append(f"material '{name}': its map_Kd options {', '.join(left_out)} left out")
    return lookup


# glTF cameras look along -z with +x to the right; Mitsuba's camera space looks along +z with +x
# to the left: a half turn about y.
GLTF_TO_MITSUBA_CAMERA = np.diag([-1.0, 1.0, -1.0, 1.0])
GLTF_FILM_HEIGHT = 512  # glTF gives a camera an aspect ratio, not a film


def _gltf_camera(doc: dict) -> Camera | None:
    """The first camera of a glTF document's scene (breadth first), placed by the transforms of
    every node above it, as the toolkit's camera; None without one. trimesh reads only a camera on
    a root node, and only a perspective one, so the file's own description is read here."""
    nodes, cameras = doc.get("nodes", []), doc.get("cameras", [])
    scenes = doc.get("scenes") or [{"nodes": list(range(len(nodes)))}]
    queue = [(i, np.eye(4)) for i in scenes[doc.get("scene", 0)].get("nodes", [])]
    while queue:
        i, above = queue.pop(0)
        node = nodes[i]
        world = above @ _gltf_node_matrix(node)
        if "camera" in node:
            return _camera_of(cameras[node["camera"]], world)
        queue.extend((child, world) for child in node.get("children", []))
    return None


def _gltf_document(path: str) -> dict:
    """A glTF file's JSON; of a GLB, its first chunk alone (not its binary buffers)."""
    with open(path, "rb") as f:
        data = f.read(20)
        if data[:4] == b"glTF":  # a 12-byte header, then the JSON chunk's length, type and text
            data = f.read(int.from_bytes(data[12:16], "little"))
        else:
            data += f.read()
    try:
        doc = json.loads(data)
    except ValueError as e:
        raise InputError(path, f"its glTF JSON cannot be read: {e}") from None
    if not isinstance(doc, dict):
        raise InputError(path, "its glTF JSON is not an object")
    return doc


def _gltf_node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    x, y, z, w = node.get("rotation", (0.0, 0.0, 0.0, 1.0))
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = rotation * np.asarray(node.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)
    m[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return m


def _camera_of(camera: dict, world: np.ndarray) -> Camera:
    """A glTF camera at the node transform ``world`` (its scale dropped: a camera's transform
    places it, and Mitsuba refuses a scaled one)."""
    to_world = world.copy()
    to_world[:3, :3] /= np.linalg.norm(to_world[:3, :3], axis=0)
    to_world = to_world @ GLTF_TO_MITSUBA_CAMERA
    if camera.get("type") == "orthographic":
        o = camera["orthographic"]
        xmag, ymag = float(o["xmag"]), float(o["ymag"])
        width = max(1, round(GLTF_FILM_HEIGHT * xmag / ymag))
        # Mitsuba's orthographic camera sees x in [-1, 1] across its film: its scale is the half-width.
        to_world = to_world @ np.diag([xmag, xmag, 1.0, 1.0])
        near, far = float(o.get("znear", 1e-3)), float(o.get("zfar", 1e4))
        return Camera(to_world, 0.0, "x", width, GLTF_FILM_HEIGHT, near_clip=near, far_clip=far, kind="orthographic")
    p = camera["perspective"]
    width = max(1, round(GLTF_FILM_HEIGHT * float(p.get("aspectRatio", 1.0))))
    near, far = float(p.get("znear", 1e-3)), float(p.get("zfar", 1e4))
    return Camera(to_world, math.degrees(float(p["yfov"])), "y", width, GLTF_FILM_HEIGHT, near_clip=near, far_clip=far)


def _mesh(path, node, geometry, transform, materials, material_index, own, warnings) -> Mesh | None:
    vertices = np.asarray(geometry.vertices, dtype=np.float64)
    faces = np.asarray(geometry.faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:  # e.g. an OBJ 'v' line with two coordinates
        raise InputError(
            path,
            f"mesh '{node}': vertex positions came back with shape {vertices.shape}, not (n, 3); "
            f"is a vertex line missing a coordinate?",
        )
    if len(faces) == 0:
        warnings.append(f"'{node}' has no faces; it is left out")
        return None
    if faces.ndim != 2 or faces.shape[1] != 3:  # e.g. a binary PLY whose faces all have two vertices
        raise InputError(path, f"mesh '{node}': faces came back with shape {faces.shape}, not (n, 3) triangles")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        worst = int(faces.min()) if faces.min() < 0 else int(faces.max())
        raise InputError(path, f"mesh '{node}': face index {worst} is out of range for {len(vertices)} vertices")
    with np.errstate(invalid="ignore"):  # NaN vertices are reported by assemble, naming the file
        positions = vertices @ transform[:3, :3].T + transform[:3, 3]
    normals = None
    # trimesh computes normals on demand; only normals that the file itself carried are kept.
    if "vertex_normals" in geometry._cache.cache:
        normals = np.asarray(geometry.vertex_normals, dtype=np.float64) @ np.linalg.inv(transform[:3, :3])
    if np.linalg.det(transform[:3, :3]) < 0:
        faces = faces[:, ::-1]
    visual = geometry.visual
    uvs = None
    uv = getattr(visual, "uv", None)
    if uv is not None and len(uv) == len(vertices):
        uvs = np.asarray(uv, dtype=np.float64).copy()
        uvs[:, 1] = 1.0 - uvs[:, 1]  # trimesh: v up from the image's bottom row; ours: row = v * H
    colors = _colors(path, visual)
    if colors is not None and getattr(visual, "kind", None) == "face":
        positions, faces, normals, uvs, colors = face_colors_at_corners(positions, faces, normals, uvs, colors)
    key = id(getattr(visual, "material", visual))
    if key not in material_index:
        material_index[key] = len(materials)
        materials.append(_material(path, node, visual, uvs is not None, colors, own, warnings))
    return Mesh(str(node), positions, faces, material_index[key], normals, uvs, colors=colors)


def _colors(path: str, visual) -> np.ndarray | None:
    """A mesh's vertex or face colours as linear reflectance, or None. glTF's are linear (its
    specification); PLY's and OBJ's 8-bit colours are sRGB, as their textures are."""
    kind = getattr(visual, "kind", None) if getattr(visual, "material", None) is None else None
    if kind not in ("vertex", "face"):
        return None
    codes = np.asarray(visual.vertex_colors if kind == "vertex" else visual.face_colors, dtype=np.float64)[:, :3]
    linear = path.lower().endswith((".gltf", ".glb"))
    return codes / 255.0 if linear else srgb_to_linear(codes / 255.0)


def _material(path: str, node, visual, has_uvs: bool, colors, own: OwnReading, warnings: list[str]) -> Material:
    material = getattr(visual, "material", None)
    if material is None:  # ColorVisuals: per-vertex or per-face colours, or none
        if colors is None:
            return Material(f"{node}.default", albedo=(0.5, 0.5, 0.5), twosided=True, source_bsdf="none")
        kind = f"{visual.kind} colors"
        return Material(f"{node}.colors", rgb(colors.mean(axis=0)), twosided=True, source_bsdf=kind, vertex_colors=True)

    name = getattr(material, "name", None) or f"{node}.material"
    kind = type(material).__name__
    lookup = {}
    if kind == "PBRMaterial":
        factor = _color(material.baseColorFactor, default=(1.0, 1.0, 1.0))
        image = material.baseColorTexture
        emission = rgb(material.emissiveFactor) if material.emissiveFactor is not None else (0.0, 0.0, 0.0)
        emission = rgb(np.asarray(emission) * own.emissive_strengths.get(name, 1.0))
        if material.emissiveTexture is not None and max(emission) > 0.0:
            raise InputError(path, f"material '{name}': textured emission (emissiveTexture) is not supported")
        left_out = []
        if material.normalTexture is not None:
            left_out.append("its normal map (the mesh's normals shade it)")
        if material.alphaMode not in (None, "OPAQUE"):
            left_out.append(f"its alpha mode {material.alphaMode} (rendered opaque)")
        if left_out:
            warnings.append(f"material '{name}': {' and '.join(left_out)} left out")
        color_0 = getattr(visual, "vertex_attributes", {}).get("color")
        if color_0 is not None:  # glTF's base colour is the factor times COLOR_0 (linear)
            mean = np.asarray(color_0, dtype=np.float64)[:, :3].mean(axis=0) / 255.0
            factor = rgb(np.asarray(factor) * mean)
            warnings.append(
                f"material '{name}': its COLOR_0 vertex colours are approximated by their mean {rounded(mean)} "
                "(a glossy base takes no vertex colours)"
            )
        twosided = bool(material.doubleSided)
        approximated = True  # glTF's BRDF is not Mitsuba's rough conductor or plastic (`_gloss`)
    else:  # SimpleMaterial (OBJ/MTL)
        factor, emission = _mtl(material, name, warnings)
        image = getattr(material, "image", None)
        twosided, approximated = True, False
        if name in own.map_kd:
            image, lookup = _mtl_image(name, *own.map_kd[name], warnings)
    texture = None
    if image is not None:
        if not has_uvs:
            warnings.append(f"material '{name}': has a texture but the mesh has no uvs; its mean colour is used")
        texels = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
        texture = (srgb_to_linear(texels) * np.asarray(factor)).astype(np.float32)
        if not has_uvs:
            factor, texture = rgb(texture.reshape(-1, 3).mean(axis=0)), None
    albedo = rgb(texture.reshape(-1, 3).mean(axis=0)) if texture is not None else rgb(factor)
    gloss = _gloss(material, name, albedo, warnings) if kind == "PBRMaterial" else None
    if gloss is not None and gloss.kind == "roughconductor":
        albedo, texture = (0.0, 0.0, 0.0), None  # a metal has no diffuse base
    lookup = lookup if texture is not None else {}
    return Material(
        name, albedo, texture, emission, twosided, source_bsdf=kind, approximated=approximated, gloss=gloss, **lookup
    )


# glTF's dielectrics reflect 4 % at normal incidence: Mitsuba's rough plastic of index 1.5.
GLTF_DIELECTRIC_IOR = 1.5


def _gloss(material, name: str, base: tuple, warnings: list[str]) -> Gloss:
    """A glTF metallic-roughness material as the `Gloss` nearest it (evalkit/core/scene/gloss.py:
    metallic_roughness), with the specification's defaults: metallic 1, roughness 1."""
    metallic = 1.0 if material.metallicFactor is None else float(material.metallicFactor)
    roughness = 1.0 if material.roughnessFactor is None else float(material.roughnessFactor)
    gloss, what = metallic_roughness(base, metallic, roughness, GLTF_DIELECTRIC_IOR)
    if material.metallicRoughnessTexture is not None:
        what += "; its metallic-roughness texture is replaced by its factors"
    what += "; its base colour factor as trimesh reads it, rounded to 8 bits (within 1/510)"
    warnings.append(f"material '{name}' (glTF metallic-roughness) is approximated as {what}")
    return gloss


def _mtl(material, name: str, warnings: list[str]) -> tuple[tuple, tuple]:
    """An MTL material's diffuse colour (Kd) and emitted radiance (Ke), read from its statements
    as written: trimesh's own colours are rounded to 8 bits, and it has no emission. A specular
    (Ks) or a transparency (d, Tr) is left out, with a warning."""
    statements = getattr(material, "kwargs", None) or {}

    def values(key):
        v = statements.get(key)
        try:
            return None if v is None else np.asarray(v, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            warnings.append(f"material '{name}': its {key.capitalize()} {v} is not numbers; left out")
            return None

    kd, ke, ks = values("kd"), values("ke"), values("ks")
    diffuse = rgb(kd[:3]) if kd is not None and kd.size >= 3 else _color(getattr(material, "diffuse", None), (0.8,) * 3)
    emission = rgb(ke[:3]) if ke is not None and ke.size >= 3 else (0.0, 0.0, 0.0)
    left_out = []
    if ks is not None and ks.size >= 3 and ks[:3].max() > 0.0:
        left_out.append(f"its specular Ks {rounded(ks[:3])}")
    opacity, transparency = values("d"), values("tr")
    if (opacity is not None and opacity[:1].min(initial=1.0) < 1.0) or (
        transparency is not None and transparency[:1].max(initial=0.0) > 0.0
    ):
        left_out.append("its transparency (d, Tr)")
    if left_out:
        warnings.append(f"material '{name}': {' and '.join(left_out)} left out; rendered diffuse with Kd")
    return diffuse, emission


def _color(value, default):
    """A linear colour factor; trimesh hands some out as 0..255 integers."""
    if value is None:
        return default
    c = np.asarray(value).reshape(-1)[:3]
    return rgb(c / 255.0 if np.issubdtype(c.dtype, np.integer) else c)
