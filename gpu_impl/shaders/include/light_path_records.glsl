// The light paths' records (gpu_impl/layout.py: LIGHT_PATH_START, LIGHT_PATH_VERTEX): where each
// starts, from the host, and the vertices it leaves, for the host (light_paths.glsl).

struct LightPathStart {
    vec4 position;   // xyz relative to the bundle centre (an emitter point); w: -1 an emitter, -2 the environment, else the light's index
    vec4 normal;     // xyz the emitter's shading normal; w: b_n, the light paths' density of the start (V q p_A, or the environment's V q p(omega) p(disk point))
    vec4 radiance;   // rgb the emitter's radiance; w: e_n, next-event estimation's density of the point (M p_A; 0 for a light)
    vec4 geometric;  // xyz the emitter triangle's geometric normal
    vec2 square_point;  // the point of the unit square a fixed light's or the environment's start is drawn from
    uint triangle;      // an emitter point's triangle among the scene's (Scene.arrays order); NO_TRIANGLE for the others
    uint unused;
};
struct LightPathVertex {
    vec4 position;   // xyz relative to the bundle centre; w: depth (0: no vertex)
    vec4 normal;     // xyz shading normal, on the side the path arrived at; w: L_i
    vec4 intensity;  // rgb alpha albedo / pi; with glossy materials (GLOSSY), alpha
    vec4 surface;    // with glossy materials: rgb the diffuse reflectance, w the material's index
    vec4 incoming;   // with glossy materials: xyz the unit direction back along the path
};

layout(std430, binding = BINDING_LIGHT_PATH_STARTS) readonly buffer LightPathStarts { LightPathStart starts[]; };
layout(std430, binding = BINDING_LIGHT_PATH_VERTICES) writeonly buffer LightPathVertices { LightPathVertex light_path_records[]; };
