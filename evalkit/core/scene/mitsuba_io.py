"""Mitsuba 3 scenes in and out: XML files and dicts are loaded by Mitsuba itself, then read back
through its public object API; a `Scene` exports to a Mitsuba dict that renders the same thing.

Import rules:
- meshes (obj, ply, serialized, and the mesh-backed rectangle and cube) are copied as Mitsuba holds
  them, in world space; sphere, disk and cylinder are tessellated (`SPHERE_SEGMENTS`,
  `DISK_SEGMENTS`, `CYLINDER_SEGMENTS`), their ``flip_normals`` kept;
- shape groups and their instances (XML files) are flattened before Mitsuba loads the file: each
  instance becomes copies of its group's shapes under the composed transforms;
- the albedo of every BSDF is its ``eval_diffuse_reflectance``, sampled at the texel centres of
  its bitmap (or on a `BAKE_RESOLUTION` grid for a procedural texture), so any texture plugin and
  any ``to_uv`` transform come out right. ``diffuse``, ``roughconductor`` and ``roughplastic``
  (alone or in ``twosided``) map exactly, with their parameters as Mitsuba holds them (a textured
  roughness, specular reflectance or index, or an anisotropic roughness, is refused); the smooth
  ``conductor`` and ``plastic`` become the rough ones of roughness `SMOOTH_ALPHA`, and a
  ``principled`` the nearest of them (evalkit/core/scene/gloss.py), each with a warning;
  every other BSDF is approximated as diffuse with a warning, once per BSDF, recorded in the scene;
- emitters: area (uniform radiance), point, spot (without a projected texture), directional,
  constant and envmap; media are named in a warning;
- sensors: perspective and orthographic;
- anything the toolkit cannot represent is refused in one line that names it (another shape or
  sensor plugin, a textured area emitter or spot light, vertex and face colours), never dropped;
- the scene's integrator, its sensor's sampler and its film (but the film's width and height) are
  not used: the toolkit renders with its own settings and references with its own path tracer.
  They are named in a warning, and a file that Mitsuba cannot load because of them alone (an
  integrator that needs a polarized variant, a spectral film) is loaded without them.
"""

from __future__ import annotations

import contextlib
import copy
import os
import re
import xml.etree.ElementTree as ElementTree

import numpy as np

from evalkit.core.bsdf import MIN_ALPHA, rough_plastic_tables
from evalkit.core.errors import InputError
from evalkit.core.mitsuba_env import mitsuba
from evalkit.core.scene.assemble import assemble, face_colors_at_corners
from evalkit.core.scene.colour import rgb, rounded, sample_texture
from evalkit.core.scene.gloss import metallic_roughness
from evalkit.core.scene.model import FILTER_TYPES, WRAP_MODES, Camera, Gloss, Light, Material, Mesh, Scene
from evalkit.core.scene.tessellate import unit_cylinder, unit_disk, unit_sphere

SPHERE_SEGMENTS = (128, 64)  # (longitude, latitude): area within 0.1 % of the analytic sphere
DISK_SEGMENTS = 128
CYLINDER_SEGMENTS = 128  # area within 0.01 % of the analytic cylinder's
BAKE_RESOLUTION = 256
# A texture whose lookups differ from Mitsuba's by more than this (relative to its largest value)
# at probed uvs is reported as approximated: float32 bilinear weights differ by ~1e-6.
TEXTURE_TOLERANCE = 1e-4
# Mitsuba's glossy plugins the toolkit renders, as their `Gloss` kind.
GLOSSY_PLUGINS = {
    "RoughConductor": "roughconductor",
    "RoughPlastic": "roughplastic",
    "SmoothConductor": "roughconductor",
    "SmoothPlastic": "roughplastic",
    "Principled": "principled",  # the nearest of the two (`_principled`)
}
# A smooth (delta) lobe is reached by no finite set of bundle directions: a smooth conductor or
# plastic is rendered as the rough one of this GGX roughness, with a warning (the scene check
# measures what that changes).
SMOOTH_PLUGINS = ("SmoothConductor", "SmoothPlastic")
SMOOTH_ALPHA = 0.05


def load_mitsuba_file(path: str | os.PathLike, variant: str | None = None) -> Scene:
    """Load a Mitsuba XML scene file (relative mesh and texture paths resolve from its folder)."""
    path = os.fspath(path)
    mi = mitsuba(variant)
    mi_scene, unused = _load_xml(mi, path, flatten=True)
    name = os.path.splitext(os.path.basename(path))[0]
    return from_mitsuba_scene(mi, mi_scene, name=name, source=path, notes=unused)


def load_mitsuba_original(path: str | os.PathLike, variant: str | None = None):
    """(Mitsuba, the file as Mitsuba itself loads it): its instances kept, only what the toolkit
    never uses taken out (integrators, samplers, films but their size), for `evalkit.fidelity`."""
    mi = mitsuba(variant)
    return mi, _load_xml(mi, os.fspath(path), flatten=False)[0]


def _load_xml(mi, path: str, flatten: bool):
    """(the loaded ``mi.Scene``, notes naming the file's render settings left out)."""
    if not os.path.isfile(path):
        raise InputError(path, "file not found")
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as e:
        raise InputError(path, f"malformed XML: {e}") from None
    _refuse_loader_crashes_xml(path, root)
    unused = _render_settings(root)
    flattened = flatten and _flatten_instances(path, root)

    def load_edited():
        with _resolving_from(mi, os.path.dirname(os.path.abspath(path))):
            return mi.load_string(ElementTree.tostring(root, encoding="unicode"))

    try:
        return (load_edited() if flattened else mi.load_file(path)), unused
    except Exception as e:  # Mitsuba reports every load problem as a RuntimeError with its own text
        if flattened or not unused:
            raise InputError(path, f"Mitsuba could not load it: {_last_line(e)}") from None
        # Loaded again without what the toolkit does not use; the first error names the file's
        # own lines, so it is the one reported if that fails too.
        try:
            return load_edited(), unused
        except Exception:
            raise InputError(path, f"Mitsuba could not load it: {_last_line(e)}") from None


def _loader_crash(plugin, names: set) -> str | None:
    """What Mitsuba's loader would crash on (a segmentation fault, which no handler catches) in a
    plugin of type ``plugin`` given the properties ``names``, instead of refusing it; None if nothing."""
    if plugin == "bitmap" and not {"filename", "data"} & names:
        return "a bitmap texture without a filename"
    if plugin == "blendbsdf" and "weight" not in names:
        return "a blendbsdf without a weight"
    return None


def _refuse_ply_crash(path: str) -> None:
    """Mitsuba's PLY loader takes face indices unchecked: one past the vertices crashed it (a
    segmentation fault) or was read from memory past them."""
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh", process=False, validate=False)
    except Exception:
        return  # unreadable: Mitsuba's own error says why
    faces = np.asarray(mesh.faces)
    if faces.size and (faces.min() < 0 or faces.max() >= len(mesh.vertices)):
        worst = int(faces.min()) if faces.min() < 0 else int(faces.max())
        raise InputError(
            path,
            f"face index {worst} is out of range for {len(mesh.vertices)} vertices (Mitsuba's PLY loader reads past "
            "them, and crashes or reads garbage)",
        )


def _refuse_loader_crashes_xml(path: str, root, seen: tuple = ()) -> None:
    """Refuses what Mitsuba's loader would crash on in the file at ``path``, a file it includes or a
    PLY mesh it names."""
    folder = os.path.dirname(os.path.abspath(path))
    for element in root.iter():
        if element.tag == "include" and element.get("filename"):
            included = os.path.join(folder, element.get("filename"))
            if os.path.isfile(included) and included not in seen:  # Mitsuba names a missing one
                try:
                    _refuse_loader_crashes_xml(included, ElementTree.parse(included).getroot(), (*seen, included))
                except ElementTree.ParseError as e:
                    raise InputError(included, f"malformed XML: {e}") from None
        if element.tag == "shape" and element.get("type") == "ply":
            filename = next((child.get("value") for child in element if child.get("name") == "filename"), None)
            if filename and os.path.isfile(os.path.join(folder, filename)):
                _refuse_ply_crash(os.path.join(folder, filename))
        problem = _loader_crash(element.get("type"), {child.get("name") for child in element})
        if problem:
            label = element.get("id") or element.get("name")
            where = f"{element.tag} '{label}': " if label else ""
            raise InputError(path, f"{where}{problem} (Mitsuba crashes loading it)")


def _refuse_loader_crashes_dict(source: str, value, key: str = "scene") -> None:
    """`_refuse_loader_crashes_xml` for a scene dict."""
    if isinstance(value, dict):
        filename = value.get("filename")
        if value.get("type") == "ply" and isinstance(filename, str) and os.path.isfile(filename):
            _refuse_ply_crash(filename)
        problem = _loader_crash(value.get("type"), set(value))
        if problem:
            raise InputError(source, f"'{key}': {problem} (Mitsuba crashes loading it)")
        for k, v in value.items():
            _refuse_loader_crashes_dict(source, v, k)


def _flatten_instances(path: str, root) -> bool:
    """Replaces every ``instance`` in ``root`` by copies of its shape group's shapes, each with the
    instance's transform composed after its own, and removes the shape groups; returns whether
    there were any. Mitsuba's Python API does not expose an instance's shapes, so the file is
    flattened before Mitsuba loads it; a group of groups' instances is flattened first."""
    parents = {child: parent for parent in root.iter() for child in parent}
    groups = {g.get("id"): g for g in root.iter("shape") if g.get("type") == "shapegroup"}
    if not groups and not any(e.get("type") == "instance" for e in root.iter("shape")):
        return False

    def expand(instance, depth=0):
        ref = instance.find("ref")
        name = None if ref is None else ref.get("id")
        if name not in groups:
            raise InputError(path, f"an instance refers to shape group '{name}', which the file does not define")
        if depth > 16:
            raise InputError(path, f"shape group '{name}' instances itself")
        ops = [op for t in instance.findall("transform") if t.get("name") == "to_world" for op in t]
        copies = []
        for shape in groups[name].findall("shape"):
            inner = expand(shape, depth + 1) if shape.get("type") == "instance" else [copy.deepcopy(shape)]
            for c in inner:
                c.attrib.pop("id", None)
                transform = next((t for t in c.findall("transform") if t.get("name") == "to_world"), None)
                if transform is None:
                    transform = ElementTree.SubElement(c, "transform", name="to_world")
                transform.extend(copy.deepcopy(op) for op in ops)  # applied after the shape's own
            copies.extend(inner)
        return copies

    for instance in [e for e in root.iter("shape") if e.get("type") == "instance"]:
        parent = parents[instance]
        if parent.get("type") == "shapegroup":
            continue  # expanded with its group's instances
        at = list(parent).index(instance)
        parent.remove(instance)
        for offset, shape in enumerate(expand(instance)):
            parent.insert(at + offset, shape)
    for group in groups.values():
        parents[group].remove(group)
    return True


def _render_settings(root) -> list[str]:
    """Takes the scene's integrators, its sensors' samplers and their films (all but width and
    height) out of ``root``; returns a warning naming each."""
    notes = []
    for integrator in root.findall("integrator"):
        root.remove(integrator)
        notes.append(
            f"the scene's integrator '{integrator.get('type')}' is not used (bundle settings render; "
            "references use Mitsuba's path integrator with --bounces)"
        )
    for sensor in root.iter("sensor"):
        for sampler in sensor.findall("sampler"):
            sensor.remove(sampler)
            notes.append(f"the sensor's sampler '{sampler.get('type')}' is not used (--spp sets the samples)")
        for film in sensor.findall("film"):
            kept = [c for c in film if c.tag == "integer" and c.get("name") in ("width", "height")]
            if film.get("type") != "hdrfilm" or len(kept) != len(film):
                notes.append(f"the sensor's film '{film.get('type')}' is not used but for its width and height")
            film.attrib = {"type": "hdrfilm"}
            film[:] = kept
    return notes


@contextlib.contextmanager
def _resolving_from(mi, folder: str):
    """Mitsuba's file resolver with ``folder`` first, as `mi.load_file` has it for relative paths."""
    resolver = mi.file_resolver()
    resolver.prepend(folder)
    try:
        yield
    finally:
        paths = [resolver[i] for i in range(1, len(resolver))]
        resolver.clear()
        for p in paths:
            resolver.append(p)


def load_mitsuba_dict(scene_dict: dict, name: str, source: str | None = None, variant: str | None = None) -> Scene:
    """Load a Mitsuba scene dict (as ``mi.load_dict`` takes it)."""
    source = source or name
    mi = mitsuba(variant)
    _refuse_loader_crashes_dict(source, scene_dict)
    try:
        mi_scene = mi.load_dict(scene_dict)
    except Exception as e:
        raise InputError(source, f"Mitsuba could not load it: {_last_line(e)}") from None
    return from_mitsuba_scene(mi, mi_scene, name=name, source=source)


def from_mitsuba_scene(mi, mi_scene, name: str, source: str, notes: list[str] = ()) -> Scene:
    """Read a loaded ``mi.Scene`` into a `Scene`; ``notes`` start its warnings."""
    warnings: list[str] = list(notes)
    materials: list[Material] = []
    material_index: dict[tuple, int] = {}
    meshes: list[Mesh] = []
    shapes = [(shape, _shape_geometry(mi, shape, shape.class_name(), source)) for shape in mi_scene.shapes()]
    # Mitsuba merges meshes that share a BSDF, in an order that changes from run to run, so the
    # shapes and their triangles are put in a canonical order: the content hash, primitive ids and
    # reference store must not depend on thread timing.
    shapes = [(shape, None if g is None else _canonical_order(*g)) for shape, g in shapes]
    shapes.sort(key=lambda sg: (sg[0].id(), b"" if sg[1] is None else sg[1][0][sg[1][1][:1]].tobytes()))
    for shape_no, (shape, geometry) in enumerate(shapes):
        shape_name = shape.id() or f"shape{shape_no}"
        kind = shape.class_name()
        if shape.interior_medium() is not None or shape.exterior_medium() is not None:
            warnings.append(f"shape '{shape_name}': participating media are not supported; the medium is ignored")
        if geometry is None:
            why = " (instances are flattened in XML files only)" if kind == "Instance" else ""
            raise InputError(source, f"shape '{shape_name}': plugin {kind} is not supported{why}")
        emission = _area_emission(mi, shape, shape_name, source)
        bsdf = shape.bsdf()
        key = (bsdf.ptr, emission)
        if key not in material_index:
            material_index[key] = len(materials)
            materials.append(_material(mi, bsdf, shape_name, emission, warnings, source, geometry[4]))
        positions, faces, normals, uvs, colors = geometry
        meshes.append(Mesh(shape_name, positions, faces, material_index[key], normals, uvs, colors=colors))

    lights = []
    for emitter in mi_scene.emitters():
        light = _light(mi, emitter, source)
        if light is not None:
            lights.append(light)

    camera = None
    sensors = mi_scene.sensors()
    if sensors:
        camera = _camera(mi, sensors[0], source)
    return assemble(name, source, meshes, materials, lights, camera, warnings)


# --- import helpers -------------------------------------------------------------------------------


def _last_line(e: Exception) -> str:
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return lines[-1] if lines else type(e).__name__


def _np(value) -> np.ndarray:
    return np.array(value, dtype=np.float64)


def _matrix(transform) -> np.ndarray:
    return _np(transform.matrix).reshape(4, 4)


def _shape_geometry(mi, shape, kind, source: str):
    """(positions, faces, normals or None, uvs or None, vertex colours or None) in world space, or
    None if unsupported."""
    if shape.is_mesh():
        positions = _np(shape.vertex_positions_buffer()).reshape(-1, 3)
        faces = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        normals = _np(shape.vertex_normals_buffer()).reshape(-1, 3) if shape.has_vertex_normals() else None
        uvs = _np(shape.vertex_texcoords_buffer()).reshape(-1, 2) if shape.has_vertex_texcoords() else None
        if shape.has_flipped_normals():  # Mitsuba turns the normals when it shades: the front side is the other
            faces, normals = faces[:, ::-1].copy(), None if normals is None else -normals
        return _mesh_colors(mi, shape, source, positions, faces, normals, uvs)
    tessellate = {
        "Sphere": lambda: unit_sphere(SPHERE_SEGMENTS),
        "Disk": lambda: unit_disk(DISK_SEGMENTS),
        "Cylinder": lambda: unit_cylinder(CYLINDER_SEGMENTS),
    }
    if kind in tessellate:
        pos, faces, normals, uv = tessellate[kind]()
        if shape.has_flipped_normals():  # flip_normals: the front side (and emission) faces in
            faces, normals = faces[:, ::-1], -normals
        if _color_attribute(shape.bsdf()) is not None:
            raise InputError(
                source, f"shape '{shape.id()}' ({kind}): a mesh_attribute texture needs a mesh's attributes"
            )
        return (*_transform((pos, faces, normals, uv), _matrix(mi.traverse(shape)["to_world"])), None)
    return None


# A texture read from a volume at the shaded point (Mitsuba's `volume` texture plugin; not a
# GridVolume or ConstVolume inside one, which the word boundary leaves out).
VOLUME_TEXTURE = re.compile(r"\bVolume\[")
# A diffuse BSDF's reflectance read from a mesh attribute.
MESH_ATTRIBUTE = re.compile(r'\breflectance = MeshAttribute\[\s*name = "((?:vertex|face)_\w+)",\s*scale = "([^"]+)"')


def _color_attribute(bsdf) -> tuple[str, float] | None:
    """The mesh attribute (its name and scale) that ``bsdf``'s diffuse reflectance reads, or None;
    a mesh_attribute anywhere else in it (a blend weight, a roughness) is refused by `_material`."""
    found = {(m.group(1), float(m.group(2))) for m in MESH_ATTRIBUTE.finditer(str(bsdf))}
    return found.pop() if len(found) == 1 else None


def _mesh_colors(mi, shape, source: str, positions, faces, normals, uvs):
    """The mesh with the colours its BSDF reads from a vertex or face attribute (times the
    texture's scale), as vertex colours: a face attribute gives each corner its face's colour, so
    the corners are not shared. Mitsuba reflects an attribute of 3 channels; one of 4 (a PLY's
    RGBA) it renders black, so any other count is refused."""
    found = _color_attribute(shape.bsdf())
    if found is None:
        return positions, faces, normals, uvs, None
    name, scale = found
    params = mi.traverse(shape)
    per = len(positions) if name.startswith("vertex_") else len(faces)
    values = _np(params[name]) if name in params else np.zeros(0)
    if values.size != 3 * per:
        raise InputError(
            source,
            f"shape '{shape.id()}': mesh attribute '{name}' has {values.size} values for {per} elements, not 3 "
            "(rgb) each, which Mitsuba's mesh_attribute reflects",
        )
    colors = values.reshape(per, 3) * scale
    if name.startswith("face_"):
        return face_colors_at_corners(positions, faces, normals, uvs, colors)
    return positions, faces, normals, uvs, colors


def _canonical_order(positions, faces, normals, uvs, colors):
    """The mesh with its triangles sorted by their corner positions and its vertices in order of
    first use (winding and corner order kept)."""
    key = positions[faces].reshape(len(faces), 9)
    faces = faces[np.lexsort(key.T[::-1])]
    used, first = np.unique(faces.ravel(), return_index=True)
    vertices = used[np.argsort(first)]
    remap = np.empty(len(positions), np.int64)
    remap[vertices] = np.arange(len(vertices))

    def pick(a):
        return None if a is None else a[vertices]

    return positions[vertices], remap[faces], pick(normals), pick(uvs), pick(colors)


def _transform(local, to_world: np.ndarray):
    pos, faces, normals, uv = local
    world = pos @ to_world[:3, :3].T + to_world[:3, 3]
    det = np.linalg.det(to_world[:3, :3])
    if not (np.isfinite(det) and det != 0):
        # A zero radius or scale (found by tests/fuzz_soak.py): every triangle is degenerate, and
        # `assemble` removes and counts them; there are no normals to transform.
        return world, faces, None, uv
    n = normals @ np.linalg.inv(to_world[:3, :3])  # inverse transpose, applied to row vectors
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    if det < 0:  # a mirroring transform flips the winding
        faces = faces[:, ::-1]
    return world, faces, n, uv


def _area_emission(mi, shape, shape_name: str, source: str):
    emitter = shape.emitter()
    if emitter is None:
        return (0.0, 0.0, 0.0)
    params = mi.traverse(emitter)
    if "radiance.value" not in params:
        raise InputError(
            source, f"shape '{shape_name}': textured area emission is not supported (only a uniform radiance)"
        )
    return rgb(_np(params["radiance.value"]))


def _material(mi, bsdf, shape_name: str, emission, warnings: list[str], source: str, colors) -> Material:
    params = mi.traverse(bsdf)
    kind = bsdf.class_name()
    name = bsdf.id() or f"{shape_name}.bsdf"
    if VOLUME_TEXTURE.search(str(bsdf)):
        # Read at the surface's position, which a lookup by uv cannot reproduce; Mitsuba crashes
        # evaluating one whose volume is missing.
        raise InputError(source, f"BSDF '{name}' ({kind}): a volume texture is not supported")
    attributes = str(bsdf).count("MeshAttribute[")
    if attributes and (colors is None or attributes != len(MESH_ATTRIBUTE.findall(str(bsdf)))):
        raise InputError(
            source,
            f"BSDF '{name}': a mesh_attribute texture is supported as a diffuse reflectance of a mesh's vertex or "
            "face colours only",
        )
    diffuse = kind == "SmoothDiffuse" or (kind == "TwoSidedBRDF" and _twosided_diffuse(mi, bsdf))
    gloss, approximation = (None, None) if diffuse else _gloss(bsdf, params, name, source)
    if colors is not None and not diffuse:  # Mitsuba's glossy BSDFs need their base's mean, which mesh_attribute lacks
        raise InputError(source, f"BSDF '{name}' ({kind}): vertex or face colours are supported on diffuse BSDFs only")
    if colors is not None:
        texture, albedo, off = {"vertex_colors": True}, rgb(colors.mean(axis=0)), 0.0
    elif _conductor(gloss):
        texture, albedo, off = {}, (0.0, 0.0, 0.0), 0.0
    else:
        texture, albedo, off = _reflectance(mi, bsdf, params)
    notes = [] if approximation is None else [approximation]
    if not diffuse and gloss is None:
        # A rough conductor's "diffuse reflectance" reads as 20 or more: a diffuse surface with it
        # would create energy.
        clamped = tuple(min(a, 1.0) for a in albedo)
        reflectance = "its diffuse reflectance" + ("" if clamped == albedo else f" {rounded(albedo)}, clamped to 1")
        notes.append(
            f"BSDF '{name}' ({kind}) is approximated as diffuse with albedo {rounded(clamped)} ({reflectance})"
        )
        if texture.get("texture") is not None:
            texture["texture"] = np.minimum(texture["texture"], 1.0)
        albedo = clamped
    if off > TEXTURE_TOLERANCE:
        notes.append(
            f"BSDF '{name}': its reflectance texture is baked to a {_shape(texture)} bitmap, "
            f"up to {off:.3g} off Mitsuba's at probed uvs"
        )
    for message in notes:
        if message not in warnings:  # once per BSDF, also when shared by an emitter
            warnings.append(message)
    return Material(
        name,
        albedo,
        emission=emission,
        twosided=kind == "TwoSidedBRDF",
        source_bsdf=kind,
        approximated=bool(notes),
        gloss=gloss,
        **texture,
    )


def _conductor(gloss: Gloss | None) -> bool:
    return gloss is not None and gloss.kind == "roughconductor"


def _gloss(bsdf, params, name: str, source: str) -> tuple[Gloss | None, str | None]:
    """A ``roughconductor`` or ``roughplastic`` (alone or in ``twosided``) with its parameters as
    Mitsuba holds them, a smooth ``conductor`` or ``plastic`` as the rough one of roughness
    `SMOOTH_ALPHA`, a ``principled`` as the nearest of them, or None for any other BSDF; and what the
    import approximated, or None. What the `Gloss` cannot hold is refused."""
    text = str(bsdf)
    inner = re.search(r"brdf\[0\] = (\w+)\[", text) if bsdf.class_name() == "TwoSidedBRDF" else None
    plugin = inner.group(1) if inner else bsdf.class_name()
    if plugin not in GLOSSY_PLUGINS:
        return None, None
    kind = GLOSSY_PLUGINS[plugin]
    keys = list(params.keys())  # noqa: SIM118 (SceneParameters iterate as items)
    prefix = "brdf_0." if bsdf.class_name() == "TwoSidedBRDF" else ""
    if any(k.startswith("brdf_1.") for k in keys):
        raise InputError(source, f"BSDF '{name}': a twosided BSDF with a different BSDF on each side is not supported")
    for part in ("alpha", "specular_reflectance", "eta", "k", "metallic", "roughness"):
        if any(k.startswith(prefix + part + ".") and not k.endswith(".value") for k in keys):
            raise InputError(source, f"BSDF '{name}' ({plugin}): a textured {part} is not supported")
    if kind == "principled":
        gloss, what = _principled(params, keys, prefix, name, source)
        return gloss, f"BSDF '{name}' ({plugin}) is approximated as {what}"
    approximation = None
    if plugin in SMOOTH_PLUGINS:
        approximation = (
            f"BSDF '{name}' ({plugin}) is smooth, a lobe no bundle direction reaches: rendered as a "
            f"{kind} of GGX roughness {SMOOTH_ALPHA:g}"
        )
        alpha = SMOOTH_ALPHA
    elif prefix + "alpha_u.value" in keys:
        alpha_u, alpha_v = (_scalar(params, prefix + f"alpha_{a}.value") for a in "uv")
        if alpha_u != alpha_v:
            roughness = f"alpha_u {alpha_u:g}, alpha_v {alpha_v:g}"
            raise InputError(source, f"BSDF '{name}' ({plugin}): anisotropic roughness ({roughness}) is not supported")
        alpha = alpha_u
    else:
        alpha = _scalar(params, prefix + ("alpha.value" if prefix + "alpha.value" in keys else "alpha"))
    common = {
        "distribution": "ggx" if plugin in SMOOTH_PLUGINS else re.search(r"distribution = (\w+)", text).group(1),
        "alpha": max(alpha, MIN_ALPHA),
        "specular_reflectance": rgb(_np(params[prefix + "specular_reflectance.value"]))
        if prefix + "specular_reflectance.value" in keys
        else (1.0, 1.0, 1.0),
    }
    if kind == "roughconductor":
        eta, k = (rgb(_np(params[prefix + f"{p}.value"])) for p in ("eta", "k"))
        return Gloss("roughconductor", eta=eta, k=k, **common), approximation
    eta = _scalar(params, prefix + "eta")
    nonlinear = re.search(r"nonlinear = (\w+)", text).group(1) in ("1", "true")
    transmittance, internal = rough_plastic_tables(common["distribution"], common["alpha"], eta)
    return (
        Gloss(
            "roughplastic",
            eta=(eta,) * 3,
            nonlinear=nonlinear,
            transmittance=transmittance,
            internal_reflectance=internal,
            **common,
        ),
        approximation,
    )


# The principled BSDF's lobes that no `Gloss` has: named in its warning where they are not zero.
PRINCIPLED_IGNORED = ("clearcoat", "sheen", "spec_trans", "anisotropic", "spec_tint", "flatness")


def _principled(params, keys: list[str], prefix: str, name: str, source: str) -> tuple[Gloss, str]:
    """A ``principled`` BSDF as the `Gloss` nearest it (evalkit/core/scene/gloss.py), the index of
    a dielectric from its ``specular`` as Mitsuba reads it (eta = 2 / (1 - sqrt(0.08 specular)) - 1),
    and what that leaves out."""

    def value(part: str) -> float:
        return _scalar(params, prefix + part + ".value")

    metallic, roughness = value("metallic"), value("roughness")
    if metallic >= 0.5 and prefix + "base_color.value" not in keys:
        raise InputError(source, f"BSDF '{name}' (Principled): a textured base_color on a metal is not supported")
    base = rgb(_np(params[prefix + "base_color.value"])) if prefix + "base_color.value" in keys else (0.0,) * 3
    specular = _scalar(params, prefix + "specular")
    ior = 2.0 / (1.0 - np.sqrt(0.08 * specular)) - 1.0
    gloss, what = metallic_roughness(base, metallic, roughness, float(ior))
    ignored = [f"{p} {value(p):g}" for p in PRINCIPLED_IGNORED if prefix + p + ".value" in keys and value(p) != 0.0]
    return gloss, what + ("; " + ", ".join(ignored) + " ignored" if ignored else "")


def _scalar(params, key: str) -> float:
    """A BSDF parameter that Mitsuba holds as a scalar (a float, or a one-value texture or array)."""
    return float(np.ravel(params[key])[0])


def _twosided_diffuse(mi, bsdf) -> bool:
    """Whether a twosided BSDF wraps diffuse BSDFs only: their parameters are a reflectance alone."""
    keys = mi.traverse(bsdf).keys()  # noqa: SIM118 (SceneParameters iterate as items)
    return {k.split(".")[1] for k in keys if k.startswith("brdf_")} <= {"reflectance"}


def _shape(texture: dict) -> str:
    h, w = texture["texture"].shape[:2]
    return f"{w} x {h}"


def _reflectance(mi, bsdf, params) -> tuple[dict, tuple, float]:
    """The BSDF's diffuse reflectance: (the `Material` texture fields, {} for a constant; the mean
    rgb; the largest difference from Mitsuba's own lookup at probed uvs).

    A bitmap keeps its texels (read at their centres through Mitsuba, so any encoding decodes as
    Mitsuba decodes it), its ``to_uv``, and the wrap mode and filter that reproduce Mitsuba's
    lookups; a checkerboard is the 2 x 2 bitmap it is with nearest filtering. Any other texture is
    baked on a `BAKE_RESOLUTION` grid over the unit uv square, and the probe says how far off that is.
    """
    rng = np.random.default_rng(0)
    values = _eval_reflectance(mi, bsdf, rng.random((16, 2)))
    if np.ptp(values, axis=0).max() <= 1e-7:
        return {}, rgb(values[0]), 0.0
    keys = list(params.keys())  # noqa: SIM118 (SceneParameters iterate as items)
    data_keys = sorted(k for k in keys if k.endswith(".data"))
    to_uv_keys = sorted(k for k in keys if k.endswith(".to_uv"))
    to_uv = _np(params[to_uv_keys[0]].matrix).reshape(3, 3) if to_uv_keys else None
    if to_uv is not None and np.allclose(to_uv, np.eye(3)):
        to_uv = None
    checker = [k for k in keys if k.endswith(".color0.value") or k.endswith(".color1.value")]
    if data_keys:
        h, w = np.shape(params[data_keys[0]])[:2]
        candidates = [(wrap, filt) for wrap in WRAP_MODES for filt in FILTER_TYPES]
    elif len(checker) == 2 and len(data_keys) == 0:
        h = w = 2
        candidates = [("repeat", "nearest")]
    else:
        h = w = BAKE_RESOLUTION
        to_uv = None
        candidates = [("repeat", "bilinear")]
    # Texel centres in texture space, pulled back to the mesh's uv space through to_uv, so that
    # eval(uv) lands exactly on each texel.
    tv, tu = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")
    centres = np.stack([tu.ravel(), tv.ravel()], axis=-1)
    to_mesh = np.eye(3) if to_uv is None else np.linalg.inv(to_uv)
    texels = _eval_reflectance(mi, bsdf, centres @ to_mesh[:2, :2].T + to_mesh[:2, 2]).reshape(h, w, 3)
    texels = texels.astype(np.float32)
    # The wrap mode and filter are not parameters Mitsuba exposes: the ones whose lookups match
    # Mitsuba's at uvs reaching two periods beyond the texture on each side are the texture's.
    probe = rng.uniform(-2.0, 3.0, (4096, 2)) @ to_mesh[:2, :2].T + to_mesh[:2, 2]
    truth = _eval_reflectance(mi, bsdf, probe)
    scale = max(float(np.abs(truth).max()), 1e-6)
    off, wrap, filt = min(
        (float(np.abs(sample_texture(texels, probe, to_uv, w_, f_) - truth).max()) / scale, w_, f_)
        for w_, f_ in candidates
    )
    fields = {"texture": texels, "to_uv": to_uv, "wrap_mode": wrap, "filter_type": filt}
    return fields, rgb(texels.reshape(-1, 3).mean(axis=0)), off


def _eval_reflectance(mi, bsdf, uv: np.ndarray) -> np.ndarray:
    import drjit as dr

    if mi.variant().startswith("scalar"):
        out = []
        for u, v in uv:
            si = mi.SurfaceInteraction3f()
            si.uv, si.wi = mi.Point2f(u, v), mi.Vector3f(0, 0, 1)
            out.append(_np(bsdf.eval_diffuse_reflectance(si)).reshape(3))
        return np.array(out)
    si = dr.zeros(mi.SurfaceInteraction3f, len(uv))
    si.uv = mi.Point2f(uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32))
    si.wi = mi.Vector3f(0, 0, 1)
    return _np(bsdf.eval_diffuse_reflectance(si)).reshape(3, -1).T


def _light(mi, emitter, source: str) -> Light | None:
    kind = emitter.class_name()
    if kind == "AreaLight":
        return None  # read with its shape
    p = mi.traverse(emitter)
    if kind == "PointLight":
        return Light("point", rgb(_np(p["intensity.value"])), position=_np(p["position"]).reshape(3))
    if kind == "SpotLight":
        m = _matrix(p["to_world"])
        if "texture.value" not in p or np.any(_np(p["texture.value"]) != 1.0):
            raise InputError(source, "spot light: a projected texture is not supported")
        return Light(
            "spot",
            rgb(_np(p["intensity.value"])),
            position=m[:3, 3].copy(),
            direction=_unit(m[:3, 2]),
            cutoff_angle=float(_np(p["cutoff_angle"]).ravel()[0]),
            beam_width=float(_np(p["beam_width"]).ravel()[0]),
        )
    if kind == "DirectionalEmitter":
        m = _matrix(p["to_world"])
        return Light("directional", rgb(_np(p["irradiance.value"])), direction=_unit(m[:3, 2]))
    if kind == "ConstantBackgroundEmitter":
        return Light("constant", rgb(_np(p["radiance.value"])))
    if kind == "EnvironmentMapEmitter":
        # Mitsuba pads its lat-long data with one wrapped column on each side.
        texels = _np(p["data"])[:, 1:-1, :3].astype(np.float32)
        scale = float(_np(p["scale"]).ravel()[0])
        return Light("envmap", rgb(scale), envmap=texels, to_world=_matrix(p["to_world"]))
    raise InputError(source, f"emitter plugin {kind} is not supported")


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _camera(mi, sensor, source: str) -> Camera:
    kind = sensor.class_name()
    if kind not in ("PerspectiveCamera", "OrthographicCamera"):
        raise InputError(source, f"sensor plugin {kind} is not supported (only perspective and orthographic)")
    p = mi.traverse(sensor)
    width, height = (int(x) for x in sensor.film().size())
    orthographic = kind == "OrthographicCamera"
    return Camera(
        _matrix(p["to_world"]),  # an orthographic camera's scale is how much it sees
        fov=0.0 if orthographic else float(_np(p["x_fov"]).ravel()[0]),
        fov_axis="x",  # Mitsuba stores every fov axis as x_fov once loaded
        width=width,
        height=height,
        near_clip=float(_np(p["near_clip"]).ravel()[0]),
        far_clip=float(_np(p["far_clip"]).ravel()[0]),
        kind="orthographic" if orthographic else "perspective",
    )


# --- export ---------------------------------------------------------------------------------------


def to_mitsuba_dict(scene: Scene, mi, spp: int = 64, width: int | None = None, height: int | None = None) -> dict:
    """A Mitsuba scene dict of ``scene`` (sensor, meshes, materials, emitters; no integrator).

    ``mi`` is the Mitsuba module with the variant to build for (the meshes are Mitsuba objects).
    The sensor uses a box pixel filter and a float32 film, which is what comparisons with the
    rasterizer need (docs/platform.md). Positions are in scene space (recentred).
    """
    d: dict = {"type": "scene", "sensor": sensor_dict(scene.camera, mi, spp, width, height)}
    bsdfs = [mi.load_dict(_bsdf_dict(mi, m)) for m in scene.materials]
    for i, mesh in enumerate(scene.meshes):
        mat = scene.materials[mesh.material]
        props = mi.Properties()
        props["bsdf"] = bsdfs[mesh.material]
        if mat.emissive:
            props["emitter"] = mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": list(mat.emission)}})
        m = mi.Mesh(
            mesh.name,
            len(mesh.positions),
            len(mesh.faces),
            props,
            has_vertex_normals=mesh.normals is not None,
            has_vertex_texcoords=mesh.uvs is not None,
        )
        params = mi.traverse(m)
        params["vertex_positions"] = mi.Float(mesh.positions.astype(np.float32).ravel())
        params["faces"] = mi.UInt(mesh.faces.astype(np.uint32).ravel())
        if mesh.normals is not None:
            params["vertex_normals"] = mi.Float(mesh.normals.astype(np.float32).ravel())
        if mesh.uvs is not None:
            params["vertex_texcoords"] = mi.Float(mesh.uvs.astype(np.float32).ravel())
        if mesh.colors is not None:
            m.add_attribute("vertex_color", 3, mi.Float(mesh.colors.astype(np.float32).ravel()))
        params.update()
        d[f"mesh{i:05d}"] = m
    for i, light in enumerate(scene.lights):
        d[f"light{i:03d}"] = _emitter_dict(mi, light)
    return d


def sensor_dict(camera: Camera, mi, spp: int, width: int | None, height: int | None, offset=(0.0, 0.0, 0.0)) -> dict:
    """Mitsuba's sensor of ``camera`` at ``spp`` (a box pixel filter, a float32 film), moved by
    ``offset`` (the scene's origin puts it back in the file's world space)."""
    width, height = camera.film_size(width, height)
    to_world = camera.to_world.copy()
    to_world[:3, 3] += np.asarray(offset, dtype=np.float64)
    lens = {"fov": camera.fov, "fov_axis": camera.fov_axis} if not camera.orthographic else {}
    return {
        "type": camera.kind,
        **lens,
        "near_clip": camera.near_clip,
        "far_clip": camera.far_clip,
        "to_world": mi.ScalarTransform4f(to_world.tolist()),
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {
            "type": "hdrfilm",
            "width": width,
            "height": height,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
        },
    }


def _bsdf_dict(mi, mat: Material) -> dict:
    if mat.vertex_colors:
        reflectance = {"type": "mesh_attribute", "name": "vertex_color"}
    elif mat.texture is None:
        reflectance = {"type": "rgb", "value": list(mat.albedo)}
    else:
        reflectance = {
            "type": "bitmap",
            "bitmap": mi.Bitmap(mat.texture),
            "raw": True,
            "filter_type": mat.filter_type,
            "wrap_mode": mat.wrap_mode,
        }
        if mat.to_uv is not None:
            reflectance["to_uv"] = mi.ScalarTransform3f(mat.to_uv.tolist())
    gloss = mat.gloss
    if gloss is None:
        one_side = {"type": "diffuse", "reflectance": reflectance}
    else:
        one_side = {
            "type": gloss.kind,
            "distribution": gloss.distribution,
            "alpha": gloss.alpha,
            "specular_reflectance": {"type": "rgb", "value": list(gloss.specular_reflectance)},
        }
        if gloss.kind == "roughconductor":
            one_side["eta"] = {"type": "rgb", "value": list(gloss.eta)}
            one_side["k"] = {"type": "rgb", "value": list(gloss.k)}
        else:
            one_side.update(
                int_ior=gloss.eta[0], ext_ior=1.0, nonlinear=gloss.nonlinear, diffuse_reflectance=reflectance
            )
    return {"type": "twosided", "bsdf": one_side} if mat.twosided else one_side


def _emitter_dict(mi, light: Light) -> dict:
    value = {"type": "rgb", "value": list(light.intensity)}
    if light.kind == "point":
        return {"type": "point", "position": light.position.tolist(), "intensity": value}
    if light.kind == "spot":
        frame = mi.ScalarTransform4f().look_at(
            origin=light.position.tolist(),
            target=(light.position + light.direction).tolist(),
            up=_any_perpendicular(light.direction).tolist(),
        )
        return {
            "type": "spot",
            "to_world": frame,
            "intensity": value,
            "cutoff_angle": light.cutoff_angle,
            "beam_width": light.beam_width,
        }
    if light.kind == "directional":
        return {"type": "directional", "direction": light.direction.tolist(), "irradiance": value}
    if light.kind == "constant":
        return {"type": "constant", "radiance": value}
    return {
        "type": "envmap",
        "bitmap": mi.Bitmap(light.envmap),
        "scale": light.intensity[0],
        "to_world": mi.ScalarTransform4f(light.to_world.tolist()),
    }


def _any_perpendicular(d: np.ndarray) -> np.ndarray:
    axis = np.eye(3)[int(np.argmin(np.abs(d)))]
    return np.cross(d, axis)
