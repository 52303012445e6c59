// The strides of the records the Python side builds or sizes (gpu_impl/layout.py: RECORDS), as this
// driver lays them out: the length() of each record array over a buffer of a known size. The test
// suite runs it (tests/test_gl_context.py); RECORD_GROUP picks the includes, which together would
// exceed a compute shader's 16 storage blocks.

#include "common.glsl"

#if RECORD_GROUP == 0
#define BUNDLE_METHOD METHOD_IMPERFECT
#include "scene.glsl"
#include "bundle.glsl"
#elif RECORD_GROUP == 1
#define SHADOW_LIGHTS 1
#include "lights.glsl"
#else
#include "paths.glsl"
#endif

#if defined COMPUTE_SHADER

layout(local_size_x = 1) in;
layout(std430, binding = BINDING_SCAN_DATA) writeonly buffer Lengths { uint lengths[]; };

void main() {
#if RECORD_GROUP == 0
    lengths[0] = uint(materials.length());
    lengths[1] = uint(triangles.length());
    lengths[2] = uint(vertices.length());
    lengths[3] = uint(frames.length());
    lengths[4] = uint(points.length());
#elif RECORD_GROUP == 1
    lengths[0] = uint(lights.length());
    lengths[1] = uint(shadow_views.length());
#else
    lengths[0] = uint(paths.length());
    lengths[1] = uint(sums.length());
#endif
}

#endif
