// The direct and indirect images: each pixel averages the sums of its s x s G-buffer samples and
// their paths over the frames so far (a box filter, as the Mitsuba references use).

#include "common.glsl"
#include "paths.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;       // W H pixels
uniform ivec2 image_size;       // W x H
uniform int supersampling;      // s
uniform uint paths_per_sample;
uniform float sample_weight;    // 1 / (s^2 paths_per_sample frames)
layout(std430, binding = BINDING_IMAGES) writeonly buffer Images { vec4 images[]; };  // direct, then indirect

void main() {
    uint id = linear_id();
    if (id >= invocations) return;
    ivec2 xy = ivec2(id % uint(image_size.x), id / uint(image_size.x));
    int width = image_size.x * supersampling;
    vec3 direct = vec3(0.0), indirect = vec3(0.0);
    for (int sy = 0; sy < supersampling; sy++) {
        for (int sx = 0; sx < supersampling; sx++) {
            uint s = uint((xy.y * supersampling + sy) * width + xy.x * supersampling + sx);
            for (uint q = 0u; q < paths_per_sample; q++) {
                direct += sums[s * paths_per_sample + q].direct.rgb;
                indirect += sums[s * paths_per_sample + q].indirect.rgb;
            }
        }
    }
    images[id] = vec4(direct * sample_weight, 1.0);
    images[invocations + id] = vec4(indirect * sample_weight, 1.0);
}

#endif
