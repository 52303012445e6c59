"""The one object that owns the headless OpenGL 4.5 context.

Creating an EGL context is slow (shader caches, llvmpipe thread pools, driver start-up), so one
`GLContext` is made and reused for every bundle build and render.

Device selection: on a machine with several EGL devices (a GPU machine), the device is picked by
index, from the ``device_index`` argument or the ``EVALKIT_GL_DEVICE`` variable (glcontext's own
``GLCONTEXT_DEVICE_INDEX`` works too). ``CUDA_VISIBLE_DEVICES`` does not renumber EGL devices.
"""

from __future__ import annotations

import json
import math
import os
import re
import time
from contextlib import contextmanager
from pathlib import Path

import moderngl

from evalkit.core.errors import InputError
from gpu_impl.layout import BINDINGS, METHODS, SAMPLERS, SHADER_CONSTANTS, glsl_literal

GL_REQUIRED = 450  # SSBOs, image atomics, compute shaders
SHADER_DIR = Path(__file__).parent / "shaders"
STAGES = {"VERTEX_SHADER": "vertex_shader", "FRAGMENT_SHADER": "fragment_shader", "COMPUTE_SHADER": "compute_shader"}

# Every program in shaders/ with each set of defines the code compiles it with (tests compile them all).
SHADER_VARIANTS = {
    "perfect_bundles": [{}, {"NULL_FRAGMENT": True}],
    "imperfect_bundles": [{}, {"NULL_FRAGMENT": True}],
    "splat_points": [{"SAMPLER": sampler} for sampler in SAMPLERS.values()],
    "splat_lists": [{"COUNT_SPLATS": True}, {"COUNT_SPLATS": True, "COUNT_COVERED": True}, {"SCATTER_SPLATS": True}],
    "resolve_lists": [
        {"COUNT_LISTS": True},
        {"SORT_LISTS": True},
        {"MERGE_LISTS": True},
        {"MERGE_LISTS": True, "FROM_LINKED_LISTS": True},
    ],
    "prefix_sum": [{"SCAN_BLOCKS": True}, {"ADD_BLOCK_OFFSETS": True}],
    "expand_nodes": [{"BUNDLE_METHOD": method, "TEXTURES": method} for method in METHODS.values()],
    "gbuffer": [{}],
    "shadow_maps": [{}],
    "irradiance": [
        {"SHADOW_LIGHTS": 1, "NODE_SIDES": sides, "TEXTURES": sides - 1, "BUNDLE_METHOD": method}
        for sides in (1, 2)
        for method in METHODS.values()
    ],
    "primary": [
        {"SHADOW_LIGHTS": lights, "ENVIRONMENT": env, "TEXTURES": t}
        for lights, env, t in ((0, 0, 0), (1, 1, 1), (0, 2, 1))
    ],
    "eye_paths": [
        {
            "SHADOW_LIGHTS": lights,
            "LAZY_LIGHTING": lazy,
            "ENVIRONMENT": env,
            "NODE_SIDES": sides,
            "TEXTURES": t,
            "BUNDLE_METHOD": method,
        }
        for lights, lazy, env, sides, t, method in (
            (0, 0, 0, 1, 0, 0),
            (1, 0, 1, 2, 1, 1),
            (1, 1, 2, 1, 1, 0),
            (1, 1, 2, 2, 1, 1),
        )
    ],
    "resolve_images": [{}],
    "record_strides": [{"RECORD_GROUP": group} for group in (0, 1, 2)],
}
# The workgroup size of every 1-D compute pass, and the most workgroups along one dispatch axis.
LOCAL_SIZE = 256
MAX_GROUPS = 65535


def _default_raster_threads() -> int:
    # llvmpipe sizes its thread pool from the host's CPU count, which containers may overstate.
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


class GLContext:
    """A headless EGL OpenGL 4.5 core context (moderngl), made once and reused.

    Parameters: ``device_index``: the EGL device (default: ``EVALKIT_GL_DEVICE``, else 0).
    Raises `InputError` with the driver's message when no such context can be made.
    """

    def __init__(self, device_index: int | None = None):
        os.environ.setdefault("LP_NUM_THREADS", str(_default_raster_threads()))
        if device_index is None:
            env = os.environ.get("EVALKIT_GL_DEVICE", os.environ.get("GLCONTEXT_DEVICE_INDEX", "0"))
            device_index = int(env)
        self.device_index = device_index
        try:
            self.ctx = moderngl.create_context(
                standalone=True, backend="egl", require=GL_REQUIRED, device_index=device_index
            )
        except Exception as e:  # glcontext and moderngl raise plain Exceptions with the driver's words
            raise InputError(
                f"EGL device {device_index}", f"no OpenGL 4.5 context ({e}); `evalkit doctor` says what to install"
            ) from None
        self._programs: dict = {}
        for path in SHADER_DIR.glob("*.glsl"):
            text = path.read_text()
            if not is_program(text):
                self.ctx.includes[path.name] = text

    @property
    def is_llvmpipe(self) -> bool:
        return "llvmpipe" in self.ctx.info["GL_RENDERER"]

    @property
    def max_storage_bytes(self) -> int:
        """The largest storage buffer a shader may index. llvmpipe reports 128 MiB but indexes any
        buffer it can allocate (tests/test_gl_context.py checks this), so there the limit is the
        32-bit byte offset."""
        return 2**32 - 1 if self.is_llvmpipe else int(self.ctx.info["GL_MAX_SHADER_STORAGE_BLOCK_SIZE"])

    def program(self, name: str, **defines):
        """The program in ``shaders/<name>.glsl`` (its stages selected by ``#if defined
        VERTEX_SHADER`` guards), compiled once per set of ``defines`` and cached."""
        key = (name, tuple(sorted(defines.items())))
        if key not in self._programs:
            text = (SHADER_DIR / f"{name}.glsl").read_text()
            stages = shader_stages(text)
            if not is_program(text) or not stages:
                raise ValueError(f"shaders/{name}.glsl has no main() under a stage guard; it is an include")
            sources = {STAGES[s]: _with_header(text, s, defines) for s in stages}
            if "compute_shader" in sources:
                self._programs[key] = self.ctx.compute_shader(sources["compute_shader"])
            else:
                self._programs[key] = self.ctx.program(**sources)
        return self._programs[key]

    def dispatch(self, shader, invocations: int) -> None:
        """Run a compute shader over ``invocations`` 1-D work items (``linear_id()`` in the shader;
        items past ``invocations`` must return early), then a barrier: what it wrote is visible
        to every pass after it."""
        if "invocations" in shader:
            shader["invocations"] = invocations
        self.run_groups(shader, math.ceil(invocations / LOCAL_SIZE))

    def run_groups(self, shader, groups: int) -> None:
        """Run ``groups`` workgroups, spread over y past the per-axis limit, then a barrier."""
        gx = min(max(1, groups), MAX_GROUPS)
        shader.run(gx, math.ceil(max(1, groups) / gx))
        self.ctx.memory_barrier()

    def draw(self, vertex_array, mode: int, framebuffer, depth_test: bool, **kw) -> None:
        """Draw ``vertex_array`` into ``framebuffer`` (no face culling, no blending; the depth test
        only when asked), then a barrier: what its shaders wrote to storage is visible after it."""
        framebuffer.use()
        self.ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        (self.ctx.enable if depth_test else self.ctx.disable)(moderngl.DEPTH_TEST)
        vertex_array.render(mode, **kw)
        self.ctx.disable(moderngl.DEPTH_TEST)
        self.ctx.memory_barrier()

    # The GL objects the toolkit makes, each released by the one object that made it.
    def buffer(self, data: bytes | None = None, reserve: int = 0):
        return self.ctx.buffer(data, reserve=reserve)

    def texture(self, size: tuple[int, int], components: int, dtype: str):
        texture = self.ctx.texture(size, components, dtype=dtype)
        texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return texture

    def depth_renderbuffer(self, size: tuple[int, int]):
        return self.ctx.depth_renderbuffer(size)

    def framebuffer(self, color: list, depth=None):
        """A framebuffer on ``color`` textures (and a depth renderbuffer); the caller owns them all."""
        return self.ctx.framebuffer(color, depth)

    def empty_framebuffer(self, size: tuple[int, int]):
        """A framebuffer without attachments: the raster passes write only to storage buffers."""
        return self.ctx.empty_framebuffer(size)

    def copy_buffer(self, dst, src, size: int, read_offset: int = 0, write_offset: int = 0) -> None:
        """Copy ``size`` bytes of ``src`` (from ``read_offset``) into ``dst`` (at ``write_offset``), on the GPU."""
        self.ctx.copy_buffer(dst, src, size, read_offset=read_offset, write_offset=write_offset)

    def vertex_array(self, program, content: list, **kw):
        return self.ctx.vertex_array(program, content, **kw)

    def finish(self) -> None:
        self.ctx.finish()

    def limit(self, name: str):
        """A GL implementation limit, e.g. GL_MAX_VIEWPORT_DIMS."""
        return self.ctx.info[name]

    @property
    def info(self) -> dict:
        i = self.ctx.info
        return {
            "vendor": i["GL_VENDOR"],
            "renderer": i["GL_RENDERER"],
            "version": i["GL_VERSION"],
            "version_code": self.ctx.version_code,
            "device_index": self.device_index,
            "llvmpipe_threads": os.environ.get("LP_NUM_THREADS") if "llvmpipe" in i["GL_RENDERER"] else None,
        }

    def release(self) -> None:
        self.ctx.release()
        self._programs.clear()

    def __enter__(self) -> GLContext:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def set_uniforms(program, values: dict) -> None:
    """Set each uniform ``program`` has; those a shader variant compiled away are skipped."""
    for name, value in values.items():
        if name in program:
            program[name] = value


def is_program(text: str) -> bool:
    """Program files define main(); the others are includes (``#include "common.glsl"``)."""
    return re.search(r"^\s*void\s+main\s*\(", text, re.M) is not None


def shader_stages(text: str) -> list[str]:
    """The stages a .glsl file defines, from its ``#if defined X_SHADER`` guards."""
    return [s for s in STAGES if re.search(rf"^\s*#\s*(el)?if\s+defined\s*\(?\s*{s}\b", text, re.M)]


def _with_header(text: str, stage: str, defines: dict) -> str:
    lines = ["#version 450 core", f"#define {stage}", f"#define LOCAL_SIZE {LOCAL_SIZE}"]
    lines += [f"#define BINDING_{name} {index}" for name, index in BINDINGS.items()]
    lines += [f"#define {name} {glsl_literal(value)}" for name, value in SHADER_CONSTANTS.items()]
    lines += [f"#define {k} {int(v) if isinstance(v, bool) else v}" for k, v in sorted(defines.items())]
    return "\n".join(lines) + "\n#line 1\n" + text


INVALID_QUERY = 2**32 - 1  # moderngl reads 32-bit results: a failed or saturated time query


class PassTimer:
    """GPU time per named pass, read once at the end so timing adds no round-trip between passes.

    On a GPU it uses GL timer queries. llvmpipe's timer queries do not cover compute dispatches (a
    13 s dispatch measured 1 ns), so there each pass ends in glFinish and is timed on the host:
    on a CPU rasterizer that is the rasterizer's own time.
    """

    def __init__(self, gl: GLContext):
        self.ctx = gl.ctx
        self.host_timing = gl.is_llvmpipe
        self.queries: list[tuple[str, object]] = []

    @contextmanager
    def measure(self, name: str):
        if self.host_timing:
            self.ctx.finish()
            start = time.perf_counter()
            yield
            self.ctx.finish()
            self.queries.append((name, (time.perf_counter() - start) * 1e9))
            return
        query = self.ctx.query(time=True)
        with query:
            yield
        self.queries.append((name, query))

    def milliseconds(self) -> dict[str, float | None]:
        """Per pass name, the summed time; None where the driver gave no valid time."""
        out: dict[str, float | None] = {}
        for name, query in self.queries:
            ns = query if isinstance(query, float) else query.elapsed
            valid = ns != INVALID_QUERY and out.get(name, 0.0) is not None
            out[name] = out.get(name, 0.0) + ns / 1e6 if valid else None
        return out

    @property
    def method(self) -> str:
        return "host time around glFinish (llvmpipe)" if self.host_timing else "GL timer queries"


if __name__ == "__main__":  # the probe `evalkit doctor` runs in a child process
    with GLContext() as gl:
        print(json.dumps(gl.info))
