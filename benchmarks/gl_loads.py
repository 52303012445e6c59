"""What one load costs in a compute shader, side by side in one run: a vec4 from a storage buffer
(and a float), from a uniform block, and by texelFetch from an RGBA32F texture, against the same
loop without loads. On llvmpipe a storage buffer is read lane by lane, each component on its own,
which is why the bundle frames are a uniform block (shaders/include/bundle.glsl).

    python benchmarks/gl_loads.py [--invocations 1048576] [--loads 16] [--records 4096] [--repeats 5]
                                  [--record JSON]

Each invocation reads ``--loads`` records at hashed indices (benchmarks/gl_loads.glsl). 4096
records (64 KiB, a uniform block's most) stay in cache; the uniform block is left out past 4096.
Times are medians over the repeats after a warm-up, host time around glFinish; ns per load is
less the loop without loads. Prints a table; the last line is one JSON object with every figure,
which ``--record`` also saves with the command and versions (the documentation's results page
"Loads by memory kind" is made from it).
"""

from __future__ import annotations

import argparse
import json
from functools import partial
from pathlib import Path

import numpy as np

from evalkit.records import write_record
from gpu_impl.context import GLContext
from gpu_impl.timing import median_ms

SOURCES = ("STORAGE_VEC4", "STORAGE_FLOAT", "UNIFORM_VEC4", "TEXTURE_VEC4", "NONE")
UNIFORM_BLOCK_RECORDS = 4096  # 64 KiB of vec4


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--invocations", type=int, default=1 << 20)
    parser.add_argument("--loads", type=int, default=16)
    parser.add_argument("--records", type=int, default=4096, help="a power of two, at least 1024")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--record", metavar="JSON", help="also save the report with its command and versions there")
    args = parser.parse_args()
    if args.records < 1024 or args.records & (args.records - 1):
        parser.error(f"--records must be a power of two of at least 1024, got {args.records}")
    gl = GLContext()
    ctx = gl.ctx
    values = np.random.default_rng(0).random(4 * args.records, dtype=np.float32)
    records = ctx.buffer(values.tobytes())
    texture = ctx.texture((1024, args.records // 1024), 4, values.tobytes(), dtype="f4")
    sums = ctx.buffer(reserve=4 * args.invocations)
    source = Path(__file__).with_suffix(".glsl").read_text()
    groups = args.invocations // 256
    defines = "".join(f"#define SOURCE_{s} {i}\n" for i, s in enumerate(SOURCES))
    defines += f"#define LOADS {args.loads}u\n#define RECORDS {args.records}u\n"
    rows = {}
    for name in SOURCES:
        if name == "UNIFORM_VEC4" and args.records > UNIFORM_BLOCK_RECORDS:
            continue
        program = ctx.compute_shader(f"#version 450\n{defines}#define SOURCE SOURCE_{name}\n{source}")
        records.bind_to_storage_buffer(0)
        if name == "UNIFORM_VEC4":
            records.bind_to_uniform_block(0)
        texture.use(0)
        sums.bind_to_storage_buffer(1)
        rows[name] = median_ms(gl, partial(program.run, groups), args.repeats)
        program.release()
    loads = args.invocations * args.loads
    per_load = {name: (ms - rows["NONE"]) * 1e6 / loads for name, ms in rows.items() if name != "NONE"}
    print(f"loads on {gl.info['renderer']}: {args.invocations:,} invocations x {args.loads} loads of "
          f"{args.records:,} records, median of {args.repeats}")  # fmt: skip
    print(f"{'source':16}{'ms':>10}{'ns a load':>12}{'/ uniform':>11}{'/ texture':>11}")
    for name, ms in rows.items():
        ns = per_load.get(name)
        ratio = {
            r: ns / per_load[r] if ns is not None and r in per_load else None for r in ("UNIFORM_VEC4", "TEXTURE_VEC4")
        }
        cells = [f"{ms:10.1f}", f"{ns:12.2f}" if ns is not None else f"{'':12}"]
        cells += [f"{v:11.2f}" if v is not None else f"{'':11}" for v in ratio.values()]
        print(f"{name.lower():16}" + "".join(cells))
    device = gl.info
    report = {
        "benchmark": "gl_loads", "device": device["renderer"], "gl_version": device["version"],
        "timing": "host time around glFinish", "invocations": args.invocations, "loads": args.loads,
        "records": args.records, "repeats": args.repeats, "median_ms": rows, "ns_per_load": per_load,
    }  # fmt: skip
    if args.record:
        write_record(args.record, report)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
