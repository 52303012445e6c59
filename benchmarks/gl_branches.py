"""What a branch that no lane takes costs in a compute shader, side by side in one run: a block of
straight-line arithmetic run unconditionally, behind an `if` that every lane or no lane takes, and
in a loop that runs once, three times or not at all, tested at its top (for) or at its end
(do-while), against the same shader without the block. A GPU skips a branch that no lane of a warp
takes; llvmpipe, which runs 8 lanes of a SIMD batch under a mask, runs its code all the same, and a
loop tested at its top once more after its last lane leaves, which is why the toolkit takes rarely
needed work out of loops and passes and tests its tightest loops at their end (docs/platform.md).

    python benchmarks/gl_branches.py [--invocations 1048576] [--repeats 5] [--record JSON]

Each invocation runs a block of 256 dependent sines (benchmarks/gl_branches.glsl). Times are
medians over the repeats after a warm-up dispatch, host time around glFinish; "/ block" is each
case's time less the shader without the block, over the block's own. Prints a table; the last line
is one JSON object with every figure, which ``--record`` also saves with the command and versions
(the documentation's results page "Branches no lane takes" is made from it).
"""

from __future__ import annotations

import argparse
import json
from functools import partial
from pathlib import Path

from evalkit.records import write_record
from gpu_impl.context import GLContext
from gpu_impl.timing import median_ms

SHAPES = ("NONE", "BLOCK", "IF", "LOOP", "DO_WHILE")
# (case, shader shape, gate, iterations): gate 0 lets every lane into the branch (the loop runs
# `iterations` times), 1 none.
CASES = (
    ("no block", "NONE", 0, 1),
    ("block", "BLOCK", 0, 1),
    ("if, taken by every lane", "IF", 0, 1),
    ("if, taken by none", "IF", 1, 1),
    ("loop, one iteration", "LOOP", 0, 1),
    ("loop, three iterations", "LOOP", 0, 3),
    ("loop, no iteration", "LOOP", 1, 1),
    ("do-while, one iteration", "DO_WHILE", 0, 1),
    ("do-while, three iterations", "DO_WHILE", 0, 3),
    ("do-while, no iteration", "DO_WHILE", 1, 1),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--invocations", type=int, default=1 << 20, help="a multiple of 256")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--record", metavar="JSON", help="also save the report with its command and versions there")
    args = parser.parse_args()
    if args.invocations < 256 or args.invocations % 256:
        parser.error(f"--invocations must be a positive multiple of 256, got {args.invocations}")
    gl = GLContext()
    ctx = gl.ctx
    results = ctx.buffer(reserve=4 * args.invocations)
    source = Path(__file__).with_suffix(".glsl").read_text()
    defines = "".join(f"#define SHAPE_{s} {i}\n" for i, s in enumerate(SHAPES))
    programs = {s: ctx.compute_shader(f"#version 450\n{defines}#define SHAPE SHAPE_{s}\n{source}") for s in SHAPES}
    rows = {}
    for case, shape, gate, iterations in CASES:
        program = programs[shape]
        for name, value in (("gate", gate), ("iterations", iterations)):
            if name in program:
                program[name] = value
        results.bind_to_storage_buffer(0)
        rows[case] = median_ms(gl, partial(program.run, args.invocations // 256), args.repeats)
    base, block = rows["no block"], rows["block"] - rows["no block"]
    of_block = {case: (ms - base) / block for case, ms in rows.items() if case != "no block"}
    print(f"branches on {gl.info['renderer']}: {args.invocations:,} invocations, a block of 256 sines, "
          f"median of {args.repeats}")  # fmt: skip
    print(f"{'case':28}{'ms':>10}{'/ block':>10}")
    for case, ms in rows.items():
        ratio = of_block.get(case)
        print(f"{case:28}{ms:10.1f}" + (f"{ratio:10.2f}" if ratio is not None else ""))
    device = gl.info
    report = {
        "benchmark": "gl_branches", "device": device["renderer"], "gl_version": device["version"],
        "timing": "host time around glFinish", "invocations": args.invocations, "block_sines": 256,
        "repeats": args.repeats, "median_ms": rows, "of_block": of_block,
    }  # fmt: skip
    if args.record:
        write_record(args.record, report)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
