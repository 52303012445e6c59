"""The one table of what the shaders and the Python side share: storage-buffer bindings, bit
flags, enumerations, and the records they exchange.

`GLContext` writes every entry of `BINDINGS` (as ``BINDING_<name>``) and `SHADER_CONSTANTS` as a
``#define`` at the top of every shader, so a value is written down once, here. Records that Python
builds are numpy structured dtypes laid out as std430 lays out the GLSL struct of the same name;
tests/test_gl_context.py checks each stride against the shaders' own (``array.length()`` of a
buffer of known size).
"""

from __future__ import annotations

import numpy as np

# Storage-buffer binding points.
BINDINGS = {
    "MATERIALS": 0, "TEXELS": 1, "TRIANGLES": 2, "POSITIONS": 3, "NORMALS": 4, "UVS": 5, "INDICES": 6,
    "AREA_CDF": 7, "FRAMES": 8, "COUNTERS": 9, "HEADS": 10, "NEXT": 11, "NODE_DEPTH": 12, "NODE_PRIM": 13,
    "NODE_NORMAL": 14, "NODE_ALBEDO": 15, "OFFSETS": 16, "SORTED_NODE": 17, "SORTED_DEPTH": 18, "POINTS": 19,
    "SCAN_DATA": 20, "SCAN_SUMS": 21, "NODE_RADIANCE": 22, "PATHS": 23, "PATH_SUMS": 24, "IMAGES": 25, "LIGHTS": 26,
    "SHADOW_VIEWS": 27, "ENVMAP": 28, "ALIVE_PATHS": 29,
}

# Bits and enumerations. np.uint32 values are written as GLSL uint literals (1u), Python ints as
# int literals (usable in #if), floats as float literals.
SPLAT_BIT = np.uint32(0x80000000)  # node prim: a splat of triangle prim & ~SPLAT_BIT
MATERIAL_TEXTURED = np.uint32(1)  # Material.texture.w flags
MATERIAL_TWOSIDED = np.uint32(2)
TRIANGLE_SMOOTH = np.uint32(0x80000000)  # Triangle.material_flags: interpolate vertex normals
TRIANGLE_MATERIAL = np.uint32(0x7FFFFFFF)  # Triangle.material_flags: the material index
LIGHT_KINDS = {"point": 0.0, "spot": 1.0, "directional": 2.0}  # Light.position.w
ENVIRONMENT_KINDS = {None: 0, "constant": 1, "envmap": 2}  # the ENVIRONMENT define
# The build counters (bundle.glsl): nodes appended (including any past the capacity), redundant
# nodes, the longest list.
COUNTERS = {"NODES": 0, "REDUNDANT": 1, "MAX_LENGTH": 2}

SHADER_CONSTANTS = {
    "SPLAT_BIT": SPLAT_BIT, "MATERIAL_TEXTURED": MATERIAL_TEXTURED, "MATERIAL_TWOSIDED": MATERIAL_TWOSIDED,
    "TRIANGLE_SMOOTH": TRIANGLE_SMOOTH, "TRIANGLE_MATERIAL": TRIANGLE_MATERIAL,
    **{f"LIGHT_{kind.upper()}": value for kind, value in LIGHT_KINDS.items()},
    **{f"ENVIRONMENT_{'NONE' if kind is None else ('MAP' if kind == 'envmap' else kind.upper())}": value
       for kind, value in ENVIRONMENT_KINDS.items()},
    **{f"COUNTER_{name}": value for name, value in COUNTERS.items()},
}

# Records, as the shaders declare them (std430).
MATERIAL = np.dtype([("albedo", "<f4", 4), ("emission", "<f4", 4), ("texture", "<u4", 4)])  # scene.glsl: Material
TRIANGLE = np.dtype([("normal", "<f4", 3), ("material_flags", "<u4")])  # scene.glsl: Triangle
BUNDLE_FRAME = np.dtype([("u", "<f4", 4), ("v", "<f4", 4), ("d", "<f4", 4)])  # bundle.glsl: BundleFrame
LIGHT = np.dtype([("position", "<f4", 4), ("direction", "<f4", 4), ("intensity", "<f4", 4), ("shape", "<f4", 4)])  # lights.glsl: Light
SHADOW_VIEW = np.dtype([("to_clip", "<f4", (4, 4)), ("tile", "<f4", 4), ("origin", "<f4", 4), ("axis", "<f4", 4)])  # lights.glsl
PATH = np.dtype([("position", "<f4", 3), ("normal", "<u4"), ("throughput", "<f4", 3), ("alive", "<u4"),
                 ("albedo", "<f4", 3), ("geometric", "<u4")])  # paths.glsl: Path
PATH_SUMS = np.dtype([("direct", "<f4", 4), ("indirect", "<f4", 4)])  # paths.glsl: PathSums

# Record name -> (dtype, the binding of its array): what tests/test_gl_context.py checks.
RECORDS = {"Material": (MATERIAL, "MATERIALS"), "Triangle": (TRIANGLE, "TRIANGLES"), "BundleFrame": (BUNDLE_FRAME, "FRAMES"),
           "Light": (LIGHT, "LIGHTS"), "ShadowView": (SHADOW_VIEW, "SHADOW_VIEWS"),
           "Path": (PATH, "PATHS"), "PathSums": (PATH_SUMS, "PATH_SUMS")}


def glsl_literal(value) -> str:
    """A value of the table as GLSL source."""
    if isinstance(value, np.unsignedinteger):
        return f"{int(value)}u"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (bool, int, np.integer)):
        return str(int(value))
    raise TypeError(f"no GLSL literal for {value!r}")
