// benchmarks/gl_branches.py: each invocation runs a block of 256 dependent sines (straight-line
// code, no loop) unconditionally, behind an `if` on a uniform, or in a loop on uniforms, tested at
// its top (for) or at its end (do-while), and writes the result so that nothing is compiled away.
// `gate` 0: every lane takes the branch and the loop runs `iterations` times; 1: no lane does (the
// loop runs no iteration).

layout(local_size_x = 256) in;
layout(std430, binding = 0) writeonly buffer Results { float results[]; };
uniform uint gate;
uniform uint iterations;

#define STEP s = s * 1.0001 + sin(s);
#define STEPS_16 STEP STEP STEP STEP STEP STEP STEP STEP STEP STEP STEP STEP STEP STEP STEP STEP
#define BLOCK { STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 \
                STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 STEPS_16 }

void main() {
    uint id = gl_GlobalInvocationID.x;
    float s = float(id);
#if SHAPE == SHAPE_BLOCK
    BLOCK
#elif SHAPE == SHAPE_IF
    if (gate == 0u) BLOCK
#elif SHAPE == SHAPE_LOOP
    for (uint i = 0u; i < iterations * (1u - min(gate, 1u)); i++) BLOCK
#elif SHAPE == SHAPE_DO_WHILE
    uint i = 0u, n = iterations * (1u - min(gate, 1u));
    if (i < n) do BLOCK while (++i < n);
#endif
    results[id] = s;
}
