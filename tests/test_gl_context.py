"""The GL context, its shader loader, and the driver facts the bundle code relies on."""

from __future__ import annotations

import numpy as np
import pytest

from gpu_impl.context import SHADER_DIR, SHADER_VARIANTS, GLContext, is_program


def test_every_shader_compiles(gl):
    programs = {p.stem for p in SHADER_DIR.glob("*.glsl") if is_program(p.read_text())}
    assert programs == set(SHADER_VARIANTS), "every program file needs its variants listed in SHADER_VARIANTS"
    for name, variants in SHADER_VARIANTS.items():
        for defines in variants:
            assert gl.program(name, **defines) is gl.program(name, **defines)  # compiled once, cached


def test_include_files_are_not_programs(gl):
    includes = {p.name for p in SHADER_DIR.glob("*.glsl") if not is_program(p.read_text())}
    assert {"common.glsl", "scene.glsl", "bundle.glsl"} <= includes
    with pytest.raises(ValueError, match="include"):
        gl.program("common")


def test_llvmpipe_indexes_storage_past_its_reported_limit(gl):
    # llvmpipe reports GL_MAX_SHADER_STORAGE_BLOCK_SIZE = 128 MiB; GLContext.max_storage_bytes
    # relies on it indexing further than that. Write past 128 MiB and read it back.
    if not gl.is_llvmpipe:
        pytest.skip("a llvmpipe fact")
    reported = int(gl.ctx.info["GL_MAX_SHADER_STORAGE_BLOCK_SIZE"])
    words = reported // 4 + 1024
    buffer = gl.ctx.buffer(reserve=4 * words)
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
    from evalkit.errors import InputError

    with pytest.raises(InputError, match="EGL device 97"):
        GLContext(device_index=97)
