// The direct and indirect images: each pixel averages the sums of its s x s G-buffer samples and
// their paths over the frames so far (a box filter, as the Mitsuba references use). The frames are
// independent estimates, so their spread is the images' noise: per pixel, Welford's running sum of
// squared deviations of the frames' values (IMAGE_M2; the variance of the mean is M2 / (F (F - 1))),
// and per workgroup this frame's summed pixel values (FRAME_SUMS), whose spread over the frames
// gives the noise of the image mean (gpu_impl/renderer.py: RenderResult).

#include "common.glsl"
#include "paths.glsl"

#if defined COMPUTE_SHADER

layout(local_size_x = LOCAL_SIZE) in;

uniform uint invocations;       // W H pixels
uniform ivec2 image_size;       // W x H
uniform int supersampling;      // s
uniform uint paths_per_sample;
uniform float sample_weight;    // 1 / (s^2 paths_per_sample frames)
uniform uint frame;             // f: the frames so far are 0 .. f
// The running means: direct, then indirect.
layout(std430, binding = BINDING_IMAGES) buffer Images { vec4 images[]; };
// Per pixel: M2 of direct, of indirect, of total.
layout(std430, binding = BINDING_IMAGE_M2) buffer ImageM2 { vec4 image_m2[]; };
// Per workgroup: this frame's pixel values summed, direct then indirect.
layout(std430, binding = BINDING_FRAME_SUMS) writeonly buffer FrameSums { vec4 frame_sums[]; };

shared vec3 partial_direct[LOCAL_SIZE];
shared vec3 partial_indirect[LOCAL_SIZE];

// Frame f's value of a pixel from the running means before and after it: exact up to float32
// round-off of f times the mean, far below a frame's noise.
void welford(uint slot, vec3 before, vec3 after, vec3 value) {
    vec3 m2 = frame == 0u ? vec3(0.0) : image_m2[slot].rgb + (value - before) * (value - after);
    image_m2[slot] = vec4(m2, 0.0);
}

void main() {
    uint id = linear_id();
    vec3 value_direct = vec3(0.0), value_indirect = vec3(0.0);
    if (id < invocations) {
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
        vec3 mean_direct = direct * sample_weight, mean_indirect = indirect * sample_weight;
        vec3 before_direct = frame == 0u ? vec3(0.0) : images[id].rgb;
        vec3 before_indirect = frame == 0u ? vec3(0.0) : images[invocations + id].rgb;
        float f = float(frame);
        value_direct = (f + 1.0) * mean_direct - f * before_direct;
        value_indirect = (f + 1.0) * mean_indirect - f * before_indirect;
        welford(id, before_direct, mean_direct, value_direct);
        welford(invocations + id, before_indirect, mean_indirect, value_indirect);
        welford(2u * invocations + id, before_direct + before_indirect, mean_direct + mean_indirect,
                value_direct + value_indirect);
        images[id] = vec4(mean_direct, 1.0);
        images[invocations + id] = vec4(mean_indirect, 1.0);
    }
    // This workgroup's sum of the frame's values (every invocation takes part in the barriers).
    uint i = gl_LocalInvocationID.x;
    partial_direct[i] = value_direct;
    partial_indirect[i] = value_indirect;
    for (uint stride = uint(LOCAL_SIZE) / 2u; stride > 0u; stride >>= 1u) {
        barrier();
        if (i < stride) {
            partial_direct[i] += partial_direct[i + stride];
            partial_indirect[i] += partial_indirect[i + stride];
        }
    }
    if (i == 0u) {
        uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
        frame_sums[2u * group] = vec4(partial_direct[0], 0.0);
        frame_sums[2u * group + 1u] = vec4(partial_indirect[0], 0.0);
    }
}

#endif
