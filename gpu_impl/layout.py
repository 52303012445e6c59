"""The one table of what the shaders and the Python side share: storage-buffer bindings, bit
flags, enumerations, block sizes, and the records they exchange or size.

`GLContext` writes every entry of `BINDINGS` (as ``BINDING_<name>``) and `SHADER_CONSTANTS` as a
``#define`` at the top of every shader, so a value is written down once, here. Records that Python
builds or sizes buffers by are numpy dtypes laid out as std430 lays out the GLSL type of the same
buffer; tests/test_gl_context.py checks each stride against the shaders' own (``array.length()``
of a buffer of known size).
"""

from __future__ import annotations

import numpy as np

from evalkit.core.scene.edges import MAX_SPLAT_CUTS, OWN_SPLAT_COS

# The workgroup size of every 1-D compute pass, and the most workgroups along one dispatch axis.
LOCAL_SIZE = 256
MAX_GROUPS = 65535
# Values each invocation of the prefix sum scans (shaders/bundles/prefix_sum.glsl).
SCAN_PER_THREAD = np.uint32(16)
# The resolve's first pass sorts lists of up to SHORT_LIST nodes by a sorting network of that many
# keys and queues the longer ones: those of up to MEDIUM_LIST nodes for a pass with a network of
# that many, the rest for one whose network sorts up to SORT_NETWORK (shaders/bundles/resolve_lists.glsl).
# A network reads that many slots of a list, past the list's end, so the node buffer keeps
# SORT_NETWORK slots beyond the last list.
SHORT_LIST = 8
MEDIUM_LIST = 16
SORT_NETWORK = 32
# The resolve's first pass runs over the groups of LIST_GROUP consecutive lists that hold a node,
# queued by a pass before it (shaders/bundles/resolve_lists.glsl: QUEUE_GROUPS): llvmpipe runs a
# SIMD batch of 8 lanes through every branch of a program's code, so a batch of empty lists cost
# what a batch of full ones did, and over half of atrium's lists are empty.
LIST_GROUP = 8

# Storage-buffer binding points (FRAMES: a uniform-block binding point).
BINDINGS = {
    # the scene (scene_buffers.py)
    "MATERIALS": 0,
    "TEXELS": 1,
    "TRIANGLES": 2,
    "VERTICES": 3,
    "INDICES": 4,
    "AREA_CDF": 5,
    "CDF_GUIDE": 30,
    # the lines that cut each triangle's splats (scene_buffers.py: splat_facts)
    "SPLAT_SHAPES": 12,
    # the imperfect bundles' own point CDF and its guide (scene_buffers.py: surface_area_cdf)
    "SPLAT_CDF": 18,
    "SPLAT_CDF_GUIDE": 19,
    # bundles: frames, splat points, build counters (bundles.py)
    "FRAMES": 6,
    "POINTS": 7,
    "COUNTERS": 8,
    # linked lists, appended to by the raster passes
    "HEADS": 9,
    "NEXT": 10,
    "LIST_KEYS": 11,
    # the lists in exact-size slot ranges: where each starts, its nodes (keys), and its length
    # (the build's counts, then the resolved lists the eye paths read)
    "LIST_OFFSETS": 13,
    "NODES": 14,
    "LIST_COUNTS": 15,
    # the lines each splat covers, from the compute splatter's count pass to its scatter pass
    "SPLAT_LINES": 16,
    "SPLATS_FOUND_AGAIN": 33,
    # the splats, those no line cuts first (splat_points.glsl: queue_splat), for the count pass
    "SPLAT_QUEUE": 41,
    # the lists longer than SHORT_LIST, queued by the resolve's first pass for the others
    "LONG_LISTS": 17,
    # the groups of LIST_GROUP lists that hold a node, queued for the resolve's first pass
    "LIST_GROUPS": 40,
    # prefix sums, and node attributes for the host (read-back only)
    "SCAN_DATA": 20,
    "SCAN_SUMS": 21,
    "NODE_ATTRIBUTES": 22,
    # the renderer (renderer.py, lights.py)
    "IRRADIANCE": 23,
    "PATHS": 24,
    "PATH_SUMS": 25,
    "IMAGES": 26,
    "LIGHTS": 27,
    "SHADOW_VIEWS": 28,
    "ALIVE_PATHS": 29,
    # the frames' spread (resolve_images.glsl): per pixel, and per workgroup this frame
    "IMAGE_M2": 31,
    "FRAME_SUMS": 32,
    # bidirectional paths (strategies/bidirectional.py): each eye path's MIS state, the light paths'
    # starts and the vertices they leave
    "PATH_MIS": 33,
    "LIGHT_PATH_STARTS": 34,
    "LIGHT_PATH_VERTICES": 35,
    # light visibility measured (evalkit/metrics/light_visibility.py): receiver points, and what each pair sees
    "RECEIVERS": 36,
    "VISIBLE": 37,
    # imperfect shadow maps' pull-push pyramids (visibility/imperfect.py)
    "ISM_PYRAMID": 38,
    # the environment map's sampling density per cell (lights.py: EnvironmentSamples; environment.glsl)
    "ENVIRONMENT_PDF": 39,
}

# Bits and enumerations. np.uint32 values are written as GLSL uint literals (1u), Python ints as
# int literals (usable in #if), floats as float literals.
SPLAT_BIT = np.uint32(0x80000000)  # node prim: a splat of triangle prim & ~SPLAT_BIT
MATERIAL_TEXTURED = np.uint32(1)  # Material.texture.w flags
MATERIAL_TWOSIDED = np.uint32(2)
MATERIAL_NEAREST = np.uint32(4)  # nearest texel, else bilinear
MATERIAL_WRAP_MIRROR = np.uint32(8)  # mirrored repeat; with neither wrap bit, repeat
MATERIAL_WRAP_CLAMP = np.uint32(16)
MATERIAL_VERTEX_COLORS = np.uint32(32)  # the diffuse reflectance is the vertices' colours
# Material.gloss.x: the BSDF (bsdf.glsl); .y: the microfacet distribution
BSDF_DIFFUSE = np.uint32(0)
BSDF_ROUGH_CONDUCTOR = np.uint32(1)
BSDF_ROUGH_PLASTIC = np.uint32(2)
MICROFACET_BECKMANN = np.uint32(0)
MICROFACET_GGX = np.uint32(1)
TRIANGLE_SMOOTH = np.uint32(0x80000000)  # Triangle.material_flags: interpolate vertex normals
# Triangle.material_flags: the triangle bounds a solid (scene_buffers.py: solid_triangles)
TRIANGLE_SOLID = np.uint32(0x40000000)
# Triangle.material_flags: lines cut the triangle's splats (scene.glsl: SplatShape), its sharp edges
# or its flat neighbours' (evalkit/core/scene/edges.py: splat_cuts)
TRIANGLE_CUT = np.uint32(0x08000000)
TRIANGLE_MATERIAL = np.uint32(0x07FFFFFF)  # Triangle.material_flags: the material index
# The top bit of a triangle's word for the triangle across an edge (scene_buffers.py: splat_facts):
# the triangle across runs the edge the same way, so its normal is turned.
TRIANGLE_TURNED = np.uint32(0x80000000)
# Light.position.w; "emitter_sample" is a point drawn on an emissive triangle for next-event
# estimation (lights.py: EmitterSamples), a point light whose intensity falls as the cosine to its
# normal; "light_path_vertex" is a vertex a light path left on a surface (strategies/bidirectional.py),
# lighting the same way, and reached by connections.
LIGHT_KINDS = {
    "point": 0.0,
    "spot": 1.0,
    "directional": 2.0,
    "emitter_sample": 3.0,
    "light_path_vertex": 4.0,
    "environment_sample": 5.0,
}
ENVIRONMENT_KINDS = {None: 0, "constant": 1, "envmap": 2}  # the ENVIRONMENT define
# How a node's reference is read (bundle.glsl, NODE_REFERENCE): a triangle or a splat point. Each
# bundle method's tracer says which of them its nodes hold.
NODE_TRIANGLE, NODE_SPLAT_POINT = 0, 1
# How light vertices' shadow maps are looked up (LIGHT_VISIBILITY, shaders/include/lights.glsl): each light
# visibility unit's value.
LIGHT_VISIBILITY_EXACT, LIGHT_VISIBILITY_IMPERFECT = 0, 1
# How imperfect bundles' points are drawn (splat_points.glsl).
SAMPLERS = {"random": 0, "stratified": 1}
# The build counters (bundle_build.glsl): nodes appended to linked lists (including any past the
# capacity), perfect bundles' coincident duplicates (all kept; imperfect bundles' redundant nodes
# are the written less the kept), the longest list, count/scatter mismatches (always 0), the lines
# splats cover (the nodes there would be without merging), the nodes the merge kept, the long
# and the medium lists the resolve's first pass queued for the others, the splats whose lines the compute
# splatter's scatter finds again, and the groups of lists that hold a node, queued for the resolve.
COUNTERS = {
    "NODES": 0,
    "REDUNDANT": 1,
    "MAX_LENGTH": 2,
    "MISMATCH": 3,
    "COVERED": 4,
    "KEPT": 5,
    "LONG_LISTS": 6,
    "MEDIUM_LISTS": 7,
    "FOUND_AGAIN": 8,
    "LIST_GROUPS": 9,
    "PLAIN_SPLATS": 10,
    "CUT_SPLATS": 11,
}
# KEPT and MAX_LENGTH, which the resolve adds to and raises for every list, are COUNTER_STRIPES
# stripes a cache line (STRIPE_WORDS) apart after the others, word STRIPED_COUNTERS.index(name) of
# each: workgroup g takes stripe g % COUNTER_STRIPES, and the host sums and takes the largest
# (bundles.py: read_counters). On llvmpipe the CPU threads took turns at the one address's cache
# line, and at MAX_LENGTH's, read for every list, while the other thread queued lists on the same
# line (docs/results/decisions.toml: plain-splats).
STRIPED_COUNTERS = ("KEPT", "MAX_LENGTH")
COUNTER_STRIPES = 64
STRIPE_WORDS = 16
COUNTER_WORDS = STRIPE_WORDS * (1 + COUNTER_STRIPES)
assert len(COUNTERS) <= STRIPE_WORDS and len(STRIPED_COUNTERS) <= STRIPE_WORDS
# A raw splat node's reference carries in its top bit which way its surface faces along the line.
FACING_BIT = np.uint32(0x80000000)
# The image units of the two R32UI images in which the shadow maps' raster pass keeps each texel's
# two nearest surfaces that face the light (shadow_maps.glsl).
FACING_IMAGE_UNITS = (1, 2)
# Path.bundle (paths.glsl) past the bundle indices: the path has ended, or is at its camera vertex.
PATH_ENDED = np.uint32(0xFFFFFFFF)
PATH_FROM_CAMERA = np.uint32(0xFFFFFFFE)
PATH_BACK = np.uint32(0x80000000)  # Path.triangle: the path is on the triangle's back
# A vertex on no triangle of the scene's (a light path's start on a light or the frame's disk).
NO_TRIANGLE = np.uint32(0xFFFFFFFF)
# The most directions a frame may have: the frames (bundle.glsl: BundleFrame, 48 bytes) are one
# uniform block, and llvmpipe and NVIDIA's driver allow 64 KiB of one (GL_MAX_UNIFORM_BLOCK_SIZE).
UNIFORM_BLOCK_BYTES = 65536
MAX_DIRECTIONS = UNIFORM_BLOCK_BYTES // 48

# Records read as texels by the splat builders and the lookups, which read them by the million
# (common.glsl: TRIANGLE_TEXELS, SPLAT_TEXELS): textures TEXEL_ROW texels wide, a splat point a texel
# (SPLAT_POINT's four words), a triangle TEXELS_PER_TRIANGLE (its corners, each with its vertex
# index, its normal, then the triangles across its edges and its smooth surface:
# scene_buffers.py: GpuScene.triangle_texels), bound at these texture units.
TEXEL_ROW = 4096
TEXELS_PER_TRIANGLE = 5
TEXEL_UNITS = {"point_texels": 9, "triangle_texels": 10}

# The most texture arrays the shadow atlas' pages take (gpu_impl/lights.py: AtlasTextures): a
# driver caps one texture's bytes below its size limits (llvmpipe at about 1.3 GiB:
# docs/platform.md). An atlas in one texture is read through one sampler (shaders compiled with
# ATLAS_TEXTURES 1); one past it, through an array of this many, which only bidirectional paths
# compile (their light vertices are what outgrows a texture): on llvmpipe, lookups through an
# array of 4 samplers made cornell-box's bidirectional G-buffer and bounce passes 1.7 times as slow
# (a loop picks the sampler, since an array of samplers is indexed only by a dynamically uniform
# expression), a cost paid only where one texture cannot hold the atlas.
MAX_ATLAS_TEXTURES = 4
SHADER_CONSTANTS = {
    "SPLAT_BIT": SPLAT_BIT,
    "MATERIAL_TEXTURED": MATERIAL_TEXTURED,
    "MATERIAL_TWOSIDED": MATERIAL_TWOSIDED,
    "MATERIAL_NEAREST": MATERIAL_NEAREST,
    "MATERIAL_WRAP_MIRROR": MATERIAL_WRAP_MIRROR,
    "MATERIAL_WRAP_CLAMP": MATERIAL_WRAP_CLAMP,
    "MATERIAL_VERTEX_COLORS": MATERIAL_VERTEX_COLORS,
    "BSDF_DIFFUSE": BSDF_DIFFUSE,
    "BSDF_ROUGH_CONDUCTOR": BSDF_ROUGH_CONDUCTOR,
    "BSDF_ROUGH_PLASTIC": BSDF_ROUGH_PLASTIC,
    "MICROFACET_BECKMANN": MICROFACET_BECKMANN,
    "MICROFACET_GGX": MICROFACET_GGX,
    "TRIANGLE_SMOOTH": TRIANGLE_SMOOTH,
    "TRIANGLE_MATERIAL": TRIANGLE_MATERIAL,
    "TRIANGLE_CUT": TRIANGLE_CUT,
    "MAX_SPLAT_CUTS": MAX_SPLAT_CUTS,
    "OWN_SPLAT_COS": OWN_SPLAT_COS,
    "TRIANGLE_SOLID": TRIANGLE_SOLID,
    "FACING_BIT": FACING_BIT,
    "FACING_IMAGE_NEAREST": FACING_IMAGE_UNITS[0],
    "FACING_IMAGE_NEXT": FACING_IMAGE_UNITS[1],
    "PATH_ENDED": PATH_ENDED,
    "PATH_FROM_CAMERA": PATH_FROM_CAMERA,
    "PATH_BACK": PATH_BACK,
    "NO_TRIANGLE": NO_TRIANGLE,
    "TRIANGLE_TURNED": TRIANGLE_TURNED,
    **{f"LIGHT_{kind.upper()}": value for kind, value in LIGHT_KINDS.items()},
    **{
        f"ENVIRONMENT_{'NONE' if kind is None else ('MAP' if kind == 'envmap' else kind.upper())}": value
        for kind, value in ENVIRONMENT_KINDS.items()
    },
    "NODE_TRIANGLE": NODE_TRIANGLE,
    "NODE_SPLAT_POINT": NODE_SPLAT_POINT,
    "LIGHT_VISIBILITY_EXACT": LIGHT_VISIBILITY_EXACT,
    "LIGHT_VISIBILITY_IMPERFECT": LIGHT_VISIBILITY_IMPERFECT,
    "LOCAL_SIZE": LOCAL_SIZE,
    "SCAN_PER_THREAD": SCAN_PER_THREAD,
    "SHORT_LIST": SHORT_LIST,
    "MEDIUM_LIST": MEDIUM_LIST,
    "SORT_NETWORK": SORT_NETWORK,
    "LIST_GROUP": LIST_GROUP,
    "COUNTER_STRIPES": COUNTER_STRIPES,
    "STRIPE_WORDS": STRIPE_WORDS,
    "MAX_DIRECTIONS": MAX_DIRECTIONS,
    "TEXEL_ROW": TEXEL_ROW,
    "TEXELS_PER_TRIANGLE": TEXELS_PER_TRIANGLE,
    **{f"SAMPLER_{name.upper()}": value for name, value in SAMPLERS.items()},
    **{f"COUNTER_{name}": value for name, value in COUNTERS.items()},
    **{f"STRIPE_{name}": word for word, name in enumerate(STRIPED_COUNTERS)},
}

# Records, as the shaders declare them (std430).
# scene.glsl: Material
MATERIAL = np.dtype(
    [
        ("albedo", "<f4", 4),
        ("emission", "<f4", 4),
        ("texture", "<u4", 4),
        ("to_uv_u", "<f4", 4),
        ("to_uv_v", "<f4", 4),
        ("gloss", "<u4", 4),
        ("specular", "<f4", 4),
        ("eta", "<f4", 4),
        ("k", "<f4", 4),
    ]
)
TRIANGLE = np.dtype([("normal", "<f4", 3), ("material_flags", "<u4")])  # scene.glsl: Triangle
# scene.glsl: Vertex
VERTEX = np.dtype([("position", "<f4", 3), ("normal", "<f4", 3), ("uv", "<f4", 2), ("color", "<f4", 3)])
# bundle.glsl: SplatPoint
SPLAT_POINT = np.dtype([("triangle", "<u4"), ("barycentrics", "<u4"), ("radius", "<f4"), ("cut_lines", "<u4")])
# scene.glsl: splat_shapes, a triangle's first cut line's word, its surface, or a third of a line
SPLAT_SHAPE_WORD = np.dtype("<u4")
# bundle.glsl: BundleFrame, in a uniform block: three vec4, so std140 lays it out as std430 would.
BUNDLE_FRAME = np.dtype([("u", "<f4", 4), ("v", "<f4", 4), ("d", "<f4", 4)])
LIGHT = np.dtype(
    [
        ("position", "<f4", 4),
        ("direction", "<f4", 4),
        ("intensity", "<f4", 4),
        ("shape", "<f4", 4),
        ("paths", "<f4", 4),
        ("surface", "<f4", 4),
        ("incoming", "<f4", 4),
    ]
)  # lights.glsl: Light
# Where a light path starts and what its first vertex leaves (light_paths.glsl).
LIGHT_PATH_START = np.dtype(
    [
        ("position", "<f4", 4),
        ("normal", "<f4", 4),
        ("radiance", "<f4", 4),
        ("geometric", "<f4", 4),
        ("square_point", "<f4", 2),
        ("triangle", "<u4"),
        ("unused", "<u4"),
    ]
)  # light_paths.glsl: LightPathStart
LIGHT_PATH_VERTEX = np.dtype(
    [
        ("position", "<f4", 4),
        ("normal", "<f4", 4),
        ("intensity", "<f4", 4),
        ("surface", "<f4", 4),
        ("incoming", "<f4", 4),
    ]
)  # light_paths.glsl: LightPathVertex
SHADOW_VIEW = np.dtype(
    [("to_clip", "<f4", (4, 4)), ("tile", "<f4", 4), ("origin", "<f4", 4), ("axis", "<f4", 4)]
)  # lights.glsl
PATH = np.dtype(
    [
        ("position", "<f4", 3),
        ("normal", "<u4"),
        ("throughput", "<f4", 3),
        ("bundle", "<u4"),
        ("albedo", "<f4", 3),
        ("triangle", "<u4"),
        ("incoming", "<f4", 4),
    ]
)  # paths.glsl: Path
PATH_SUMS = np.dtype([("direct", "<f4", 4), ("indirect", "<f4", 4)])  # paths.glsl: PathSums
# A resolved node: one 64-bit key, depth and reference (bundle_build.glsl: nodes).
NODE = np.dtype("<u8")
# A node while linked lists are built: its link and its key, one array each (bundle_build.glsl).
LINKED_NODE = {
    "NodeNext": (np.dtype("<u4"), "NEXT"),
    "NodeKey": (NODE, "LIST_KEYS"),
}
LINKED_NODE_BYTES = sum(dtype.itemsize for dtype, _ in LINKED_NODE.values())
# The compute splatter's record of the lines a splat covers (bundle_build.glsl: splat_lines).
SPLAT_LINES = np.dtype([("box", "<u4"), ("mask", "<u4", 2), ("depth_plane", "<f4", 3)])
# The largest R the compute splatter's record holds: the box's first row in 15 bits, beside the
# splat's FACING_BIT.
SPLAT_LINES_MAX_RESOLUTION = 2**15

# Record name -> (dtype, the binding of its array): what tests/test_gl_context.py checks.
RECORDS = {
    "Material": (MATERIAL, "MATERIALS"),
    "Triangle": (TRIANGLE, "TRIANGLES"),
    "Vertex": (VERTEX, "VERTICES"),
    "SplatPoint": (SPLAT_POINT, "POINTS"),
    "SplatShapeWord": (SPLAT_SHAPE_WORD, "SPLAT_SHAPES"),
    "Light": (LIGHT, "LIGHTS"),
    "LightPathStart": (LIGHT_PATH_START, "LIGHT_PATH_STARTS"),
    "LightPathVertex": (LIGHT_PATH_VERTEX, "LIGHT_PATH_VERTICES"),
    "ShadowView": (SHADOW_VIEW, "SHADOW_VIEWS"),
    "Path": (PATH, "PATHS"),
    "PathSums": (PATH_SUMS, "PATH_SUMS"),
    "Node": (NODE, "NODES"),
    **LINKED_NODE,
    "SplatLines": (SPLAT_LINES, "SPLAT_LINES"),
}


def glsl_literal(value) -> str:
    """A value of the table as GLSL source."""
    if isinstance(value, np.unsignedinteger):
        return f"{int(value)}u"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (bool, int, np.integer)):
        return str(int(value))
    raise TypeError(f"no GLSL literal for {value!r}")
