"""The GL context, its shader loader, and the driver facts the bundle code relies on."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

from evalkit.core.errors import InputError
from gpu_impl.context import GLContext, default_context, gl_integer, system_free_memory
from gpu_impl.layout import BINDINGS, BUNDLE_FRAME, MAX_DIRECTIONS, RECORDS, SHADER_CONSTANTS, glsl_literal
from gpu_impl.shader_source import INCLUDE_DIR, SHADER_DIR, SHADER_VARIANTS, is_program, program_files

# Compiles every other listed variant (from argv[1] on, in steps of argv[2]) in a GL context of
# its own; prints how many.
COMPILE_SHARE = """
import sys
from gpu_impl.context import default_context
from gpu_impl.shader_source import SHADER_VARIANTS
start, step = int(sys.argv[1]), int(sys.argv[2])
work = [(name, d) for name, variants in SHADER_VARIANTS.items() for d in variants][start::step]
with default_context() as gl:
    for name, defines in work:
        gl.program(name, **defines)
print(len(work))
"""


@pytest.mark.long
def test_every_shader_compiles(gl):
    programs = set(program_files())
    assert programs == set(SHADER_VARIANTS), "every program file needs its variants listed in SHADER_VARIANTS"
    name, defines = next(iter(SHADER_VARIANTS.items()))
    assert gl.program(name, **defines[0]) is gl.program(name, **defines[0])  # compiled once, cached
    # Compiling is single-threaded per context: two processes share the variants, one per core.
    children = [
        subprocess.Popen([sys.executable, "-c", COMPILE_SHARE, str(i), "2"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
        for i in range(2)
    ]  # fmt: skip
    done = [child.communicate(timeout=900) for child in children]
    for child, (_, err) in zip(children, done):
        assert child.returncode == 0, err[-3000:]
    assert sum(int(out.split()[-1]) for out, _ in done) == sum(len(v) for v in SHADER_VARIANTS.values())


# The records of gpu_impl/layout.py by RECORD_GROUP of shaders/paths/record_strides.glsl, in its order.
RECORD_GROUPS = {
    0: ["Material", "Triangle", "Vertex", "SplatPoint", "SplatShapeWord"],
    1: ["Light", "ShadowView"],
    2: ["Path", "PathSums"],
    3: ["Node", "NodeNext", "NodeKey", "SplatLines"],
    4: ["LightPathStart", "LightPathVertex"],
}


def test_python_records_have_the_shaders_strides(gl):
    # Each record array bound with room for exactly n records of the Python layout must have
    # length n in the shader: a stride that differs by even one byte changes the length.
    assert sorted(sum(RECORD_GROUPS.values(), [])) == sorted(RECORDS)
    n = 1000
    for group, names in RECORD_GROUPS.items():
        buffers = [gl.buffer(reserve=n * RECORDS[name][0].itemsize) for name in names]
        for name, buffer in zip(names, buffers):
            buffer.bind_to_storage_buffer(BINDINGS[RECORDS[name][1]])
        lengths = gl.buffer(reserve=4 * len(names))
        lengths.bind_to_storage_buffer(BINDINGS["SCAN_DATA"])
        gl.run_groups(gl.program("record_strides", RECORD_GROUP=group), 1)
        found = np.frombuffer(lengths.read(), dtype=np.uint32)
        assert dict(zip(names, found.tolist())) == dict.fromkeys(names, n)
        for buffer in [*buffers, lengths]:
            buffer.release()


def test_bundle_frames_have_the_python_layout_in_their_uniform_block(gl):
    # std140 fixes the block's length, so the last frame's d.w is written where the Python layout
    # puts it, and must be what the shader reads there.
    frames = np.zeros(MAX_DIRECTIONS, dtype=BUNDLE_FRAME)
    frames["d"][:, 3] = np.arange(MAX_DIRECTIONS)
    block, read = gl.buffer(frames.tobytes()), gl.buffer(reserve=4)
    block.bind_to_uniform_block(BINDINGS["FRAMES"])
    read.bind_to_storage_buffer(BINDINGS["SCAN_DATA"])
    gl.run_groups(gl.program("record_strides", RECORD_GROUP=5), 1)
    assert np.frombuffer(read.read(), dtype=np.uint32)[0] == MAX_DIRECTIONS - 1
    assert BUNDLE_FRAME.itemsize * MAX_DIRECTIONS <= int(gl.limit("GL_MAX_UNIFORM_BLOCK_SIZE"))
    for buffer in (block, read):
        buffer.release()


def test_shared_constants_are_written_as_glsl_literals_of_their_type():
    # Unsigned flags as uint literals (bit tests against uint fields), enumerations usable in #if,
    # light kinds as floats (compared with a vec4 component); every program's compile checks the rest.
    assert glsl_literal(SHADER_CONSTANTS["SPLAT_BIT"]) == "2147483648u"
    assert glsl_literal(SHADER_CONSTANTS["ENVIRONMENT_MAP"]) == "2"
    assert glsl_literal(SHADER_CONSTANTS["LIGHT_DIRECTIONAL"]) == "2.0"
    assert {glsl_literal(v)[-1] for k, v in SHADER_CONSTANTS.items() if k.startswith(("MATERIAL_", "TRIANGLE_"))} == {
        "u"
    }


def test_programs_and_include_files_sit_apart(gl):
    # Every .glsl file is in a folder of its role: include/ holds code without main(), the others
    # programs with one; nothing lies loose beside them.
    assert not list(SHADER_DIR.glob("*.glsl"))
    includes = list(INCLUDE_DIR.glob("*.glsl"))
    assert {"common.glsl", "scene.glsl", "bundle.glsl"} <= {p.name for p in includes}
    assert not any(is_program(p.read_text()) for p in includes)
    assert all(is_program(p.read_text()) for p in program_files().values())
    with pytest.raises(ValueError, match="include"):
        gl.program("common")


def test_llvmpipe_indexes_storage_past_its_reported_limit(gl):
    # llvmpipe reports GL_MAX_SHADER_STORAGE_BLOCK_SIZE = 128 MiB; GLContext.max_storage_bytes
    # relies on it indexing further than that. Write past 128 MiB and read it back.
    if not gl.is_llvmpipe:
        pytest.skip("a llvmpipe fact")
    reported = int(gl.limit("GL_MAX_SHADER_STORAGE_BLOCK_SIZE"))
    words = reported // 4 + 1024
    buffer = gl.buffer(reserve=4 * words)
    shader = gl.ctx.compute_shader("""#version 450
        layout(local_size_x = 64) in;
        layout(std430, binding = 0) buffer B { uint v[]; };
        uniform uint base;
        void main() { v[base + gl_GlobalInvocationID.x] = base + gl_GlobalInvocationID.x; }""")
    buffer.bind_to_storage_buffer(0)
    shader["base"] = words - 1024
    shader.run(1024 // 64)
    tail = np.frombuffer(buffer.read(4 * 1024, offset=4 * (words - 1024)), dtype=np.uint32)
    assert np.array_equal(tail, np.arange(words - 1024, words, dtype=np.uint32))
    buffer.release()


def test_bad_device_index_is_one_clear_error():
    with pytest.raises(InputError, match="EGL device 97"):
        GLContext(device_index=97)


def test_a_shader_the_driver_cannot_compile_is_one_line_naming_its_file(gl, monkeypatch):
    broken = "#version 450\nlayout(local_size_x = 1) in;\nvoid main() { undeclared_name += 1.0; }\n"
    monkeypatch.setattr("gpu_impl.context.program_sources", lambda name, defines: {"compute_shader": broken})
    with pytest.raises(InputError) as caught:
        gl.program("prefix_sum", SOME_FLAG=1)  # a program's file, its source broken
    message = str(caught.value)
    assert message.startswith("gpu_impl/shaders/bundles/prefix_sum.glsl: the GL driver (")
    assert "SOME_FLAG=1" in message and "undeclared_name" in message and "\n" not in message


def test_free_memory_is_what_the_system_says(gl):
    # llvmpipe's buffers are system memory; an NVIDIA GPU's free video memory is the driver's figure,
    # unrelated to the host's (held to the host's, this test could not pass on a GPU).
    free, source = gl.free_memory()
    if gl.is_llvmpipe:
        with open("/proc/meminfo") as f:
            available = next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
        assert 0 < free <= available * 1.05 and ("MemAvailable" in source or "cgroup" in source)
    else:
        assert free > 0 and source == "GL_NVX_gpu_memory_info"
    assert gl_integer(0x0D33) == gl.limit("GL_MAX_TEXTURE_SIZE")  # the query path GL_NVX_gpu_memory_info takes


@pytest.mark.parametrize(
    "cgroup, files, expected",
    [
        ("0::/job\n", {"job/memory.max": "3221225472", "job/memory.current": "1073741824"}, 2 << 30),
        ("0::/job\n", {"job/memory.max": "max", "job/memory.current": "1073741824"}, 16 << 30),
        ("0::/outside\n", {"memory.max": "2147483648", "memory.current": "0"}, 2 << 30),  # a namespace's root
        (
            "4:memory:/job\n0::/\n",
            {"memory/job/memory.limit_in_bytes": "1073741824", "memory/job/memory.usage_in_bytes": "0"},
            1 << 30,
        ),  # fmt: skip
        (
            "4:memory:/\n",
            {"memory/memory.limit_in_bytes": "9223372036854771712", "memory/memory.usage_in_bytes": "5"},
            16 << 30,
        ),  # fmt: skip
    ],
)
def test_free_memory_is_capped_by_the_memory_cgroup(tmp_path, cgroup, files, expected):
    # A container or batch job's limit kills the process long before MemAvailable runs out.
    (tmp_path / "proc" / "self").mkdir(parents=True)
    (tmp_path / "proc" / "meminfo").write_text("MemTotal: 33554432 kB\nMemAvailable: 16777216 kB\n")
    (tmp_path / "proc" / "self" / "cgroup").write_text(cgroup)
    for name, text in files.items():
        (tmp_path / "cg" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "cg" / name).write_text(text + "\n")
    free, source = system_free_memory(str(tmp_path / "proc"), str(tmp_path / "cg"))
    assert free == expected
    assert ("cgroup" in source) == (expected < 16 << 30), source


def test_the_one_call_api_uses_the_processs_first_context(gl):
    # A second context would be made current and take the GL calls of objects made on this one
    # (buffers that could not be mapped, a hung pass, when a notebook test rendered in-process).
    assert default_context() is gl


def test_buffers_are_filled_and_read_by_the_gl_without_mapping_them(gl):
    # fill sets every word (what the list heads' 0xFFFFFFFF and the counters' 0 need), and read
    # returns a range of records through the staging buffer, also past the staging buffer's first size.
    words = 3000
    buffer = gl.buffer(reserve=4 * words)
    try:
        gl.fill(buffer, 0xFFFFFFFF)
        assert (np.frombuffer(buffer.read(), dtype=np.uint32) == 0xFFFFFFFF).all()
        buffer.write(np.arange(words, dtype=np.uint32).tobytes())
        got = gl.read(buffer, np.uint32, 10, first=2990)
        np.testing.assert_array_equal(got, np.arange(2990, 3000))
        gl.fill(buffer)
        assert not gl.read(buffer).any()
        # A read longer than the staging buffer goes in pieces, starting at any record.
        buffer.write(np.arange(words, dtype=np.uint32).tobytes())
        with mock.patch("gpu_impl.context.STAGING_BYTES", 4096), mock.patch.object(gl, "_staging", None):
            records = gl.read(buffer, np.dtype([("a", "<u4"), ("b", "<u4"), ("c", "<u4")]), 999, first=1)
            assert gl._staging.size == 4096  # a piece's size, not the read's
            gl._staging.release()
        np.testing.assert_array_equal(records["c"], np.arange(5, words, 3))
    finally:
        buffer.release()
    odd = gl.buffer(reserve=6)
    try:
        with pytest.raises(ValueError, match="not whole 32-bit words"):
            gl.fill(odd)
    finally:
        odd.release()


def test_allocate_returns_nothing_and_releases_what_the_driver_could_not_hold(gl):
    """`GLContext.allocate`: objects past the memory the driver has free (every layer the GL allows
    of the largest side, 16 bytes a texel: terabytes) are None, and never asked for, as the NVIDIA
    driver makes them without an error; on llvmpipe, a texture within the free memory but past the
    bytes one of its textures holds (3 layers of 8192 x 8192 RG32F, 1.5 GiB) is None, not an empty
    texture; one that fits is made; an error of an earlier call is not taken for it."""
    side, layers = gl.limit("GL_MAX_TEXTURE_SIZE"), gl.limit("GL_MAX_ARRAY_TEXTURE_LAYERS")
    asked = []

    def huge():
        asked.append(gl.texture_array((side, side), layers, 4, "f4"))
        return asked[-1:]

    assert gl.allocate(huge, side * side * layers * 16) is None and not asked
    if gl.is_llvmpipe and gl.free_memory()[0] > 2 * 2**30:
        made = []

        def over_one_texture():
            made.append(gl.texture_array((8192, 8192), 3, 2, "f4"))
            return made[-1:]

        assert gl.allocate(over_one_texture, 8192 * 8192 * 3 * 8) is None and len(made) == 1
    gl.ctx.texture((side + 1, 1), 1)  # refused: GL_INVALID_VALUE, left pending
    small = gl.allocate(lambda: [gl.texture_array((8, 8), 2, 2, "f4")], 8 * 8 * 2 * 8)
    assert small is not None and small[0].size == (8, 8, 2)
    small[0].release()


def test_the_branch_benchmark_reports_every_case_against_its_block(tmp_path):
    # benchmarks/gl_branches.py (docs/platform.md cites it): a small run prints its table and, last,
    # one JSON object with every case's time and its share of the block's, and records it.
    record = tmp_path / "gl_branches.json"
    benchmark = Path(__file__).parents[1] / "benchmarks" / "gl_branches.py"
    script = [str(benchmark), "--invocations", "4096", "--repeats", "1", "--record", str(record)]
    r = subprocess.run([sys.executable, *script], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout.strip().splitlines()[-1])
    cases = ["no block", "block", "if, taken by every lane", "if, taken by none"]
    iterations = ("one iteration", "three iterations", "no iteration")
    loops = [f"{loop}, {n}" for loop in ("loop", "do-while") for n in iterations]
    assert list(report["median_ms"]) == [*cases, *loops]
    assert report["of_block"]["block"] == 1.0 and set(report["of_block"]) == set(report["median_ms"]) - {"no block"}
    assert all(np.isfinite(list(report["of_block"].values())))
    assert json.loads(record.read_text())["record"]["command"].endswith("--record " + str(record))
