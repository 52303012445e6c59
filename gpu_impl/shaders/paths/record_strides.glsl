// The strides of the records the Python side builds or sizes (gpu_impl/layout.py: RECORDS), as this
// driver lays them out: the length() of each record array over a buffer of a known size. The test
// suite runs it (tests/test_gl_context.py); RECORD_GROUP picks the includes, which together would
// exceed a compute shader's 16 storage blocks. Group 5 reads the bundle frames' uniform block,
// whose length is fixed: the last frame's d.w, which the test writes where the Python layout puts it.

#extension GL_ARB_gpu_shader_int64 : require
#include "common.glsl"

#if RECORD_GROUP == 0 || RECORD_GROUP == 5
#define NODE_REFERENCE NODE_SPLAT_POINT
#define SPLAT_SHAPES
#include "scene.glsl"
#include "bundle.glsl"
#elif RECORD_GROUP == 1
#define SHADOW_LIGHTS 1
#define LIGHT_VISIBILITY LIGHT_VISIBILITY_EXACT
#define ATLAS_TEXTURES 1  // the records are the same however many textures the atlas takes
#include "lights.glsl"
#elif RECORD_GROUP == 2
#include "paths.glsl"
#elif RECORD_GROUP == 4
#include "light_path_records.glsl"
#else
#define LINKED_LISTS
#define SLOT_LISTS
#define SPLAT_LINE_RECORDS
#include "bundle_build.glsl"
#endif

#if defined COMPUTE_SHADER

layout(local_size_x = 1) in;
layout(std430, binding = BINDING_SCAN_DATA) writeonly buffer Lengths { uint lengths[]; };

void main() {
#if RECORD_GROUP == 0
    lengths[0] = uint(materials.length());
    lengths[1] = uint(triangles.length());
    lengths[2] = uint(vertices.length());
    lengths[3] = uint(points.length());
    lengths[4] = uint(splat_shapes.length());
#elif RECORD_GROUP == 5
    lengths[0] = uint(frames[MAX_DIRECTIONS - 1].d.w);
#elif RECORD_GROUP == 1
    lengths[0] = uint(lights.length());
    lengths[1] = uint(shadow_views.length());
#elif RECORD_GROUP == 2
    lengths[0] = uint(paths.length());
    lengths[1] = uint(sums.length());
#elif RECORD_GROUP == 4
    lengths[0] = uint(starts.length());
    lengths[1] = uint(light_path_records.length());
#else
    lengths[0] = uint(nodes.length());
    lengths[1] = uint(node_next.length());
    lengths[2] = uint(list_keys.length());
    lengths[3] = uint(splat_lines.length());
#endif
}

#endif
