// Multi-bounce eye paths over ray bundles (Tokuyoshi and Ogaki): every bounce picks one of the
// frame's K bundles at random and follows its line to the next surface, so no ray is ever traced.
// The passes of one frame (gpu_impl/renderer.py), each its own program:
//
//   irradiance.glsl      the shadow-mapped light reaching every node or splat point, when that is
//                        cheaper than lighting each path's hits where it lands (eye_paths.glsl);
//   primary.glsl         the G-buffer samples: exact camera-ray hits, emission seen directly and
//                        direct light, and the first path vertex;
//   eye_paths.glsl       one bounce of every path (run once per bounce);
//   resolve_images.glsl  the per-path sums averaged into the direct and indirect images.
//
// Bounces are counted as Mitsuba's path integrator counts them (max_depth), so the images compare
// with its references: at path vertex j (the G-buffer sample is vertex 0), shadow-mapped light
// counts as bounce j, and emission or the environment reached at vertex j as bounce j - 1. Bounce
// 0 is the direct image; bounces 1..B are the indirect image.

#define INV_PI 0.3183098861837907

// One path per G-buffer sample and path index, advanced in place bounce by bounce.
struct Path {
    vec3 position;    // the current vertex, relative to the bundle centre
    uint normal;      // its shading normal (encode_normal), turned to the side the path is on
    vec3 throughput;
    uint bundle;      // the bundle it arrived along; PATH_FROM_CAMERA at vertex 0, PATH_ENDED once it has ended
    vec3 albedo;      // of the current vertex
    uint triangle;    // its triangle, PATH_BACK set where the path is on the side its geometric normal points away from
    vec4 incoming;    // xyz: the unit direction back along the last segment (to the camera or the
                      // vertex before), which a glossy BSDF needs (bsdf.glsl); w: unused
};
// Per path, the radiance summed over frames: bounce 0, and bounces 1..B.
struct PathSums {
    vec4 direct;
    vec4 indirect;
};

layout(std430, binding = BINDING_PATHS) buffer Paths { Path paths[]; };
layout(std430, binding = BINDING_PATH_SUMS) buffer Sums { PathSums sums[]; };
#if BIDIRECTIONAL
// Per path, the eye side's share of its MIS sum at its current vertex j (E_j, lights.glsl): 0 at
// the G-buffer sample, then E_j = (1 + b^2 E_{j-1}) / a^2 with a the eye side's density of vertex j
// and b the light side's density of vertex j - 1 (strategies/bidirectional.py).
layout(std430, binding = BINDING_PATH_MIS) buffer PathMis { float path_mis[]; };
#endif
// The paths alive after the primary pass (the renderer's lighting choice weighs them), and after a
// bounce pass not 0 where any is: when none is, the passes left are skipped.
layout(std430, binding = BINDING_ALIVE_PATHS) buffer AlivePaths { uint alive_paths; };

#if defined PRECOMPUTED_IRRADIANCE
// The irradiance (rgb) reaching each node (perfect bundles, CSR order) or each splat point
// (imperfect bundles), from the shadow-mapped lights, on its front and, with NODE_SIDES 2 (a
// two-sided material), its back: irradiance.glsl writes it, the eye paths read it.
layout(std430, binding = BINDING_IRRADIANCE) buffer Irradiance { float irradiance[]; };

uint irradiance_index(uint item, uint side) {
    return 3u * (item * uint(NODE_SIDES) + side);
}
#endif
