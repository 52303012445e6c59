"""The one object that owns the headless OpenGL 4.5 context.

Creating an EGL context is slow (shader caches, llvmpipe thread pools, driver start-up), so one
`GLContext` is made and reused for every bundle build and render.

Device selection: on a machine with several EGL devices (a GPU machine), the device is picked by
index, from the ``device_index`` argument or the ``EVALKIT_GL_DEVICE`` variable (glcontext's own
``GLCONTEXT_DEVICE_INDEX`` works too). ``CUDA_VISIBLE_DEVICES`` does not renumber EGL devices.
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
from pathlib import Path

import moderngl
import numpy as np

from evalkit.core.errors import InputError, LimitError
from gpu_impl.layout import LOCAL_SIZE, MAX_GROUPS, TEXEL_ROW
from gpu_impl.shader_source import COMPILED, program_path, program_sources, variant_key

GL_REQUIRED = 450  # SSBOs, image atomics, compute shaders
GPU_MEMORY_INFO_CURRENT_AVAILABLE_VIDMEM_NVX = 0x9049  # in KiB
GL_CLIP_DISTANCE0 = 0x3000
GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT = 0x8236, 0x8D94, 0x1405
# The share of the free memory a build or a shadow atlas may take: the rest is for the process and
# the driver. On llvmpipe the raster pass of atrium-dense (2.4 M triangles, K=256, R=1024) took
# 1.4 GiB beyond its buffers, and with 80 % the memory cgroup killed it
# (docs/results/decisions.toml: llvmpipe-memory-headroom).
MEMORY_HEADROOM = 0.5
# The most `GLContext.read` copies through its staging buffer at a time.
STAGING_BYTES = 16 << 20
GL_RED, GL_RG, GL_FLOAT, GL_DEPTH_COMPONENT, GL_DEPTH_COMPONENT24 = 0x1903, 0x8227, 0x1406, 0x1902, 0x81A6
GL_TEXTURE_2D_ARRAY, GL_COLOR_ATTACHMENT0, GL_DEPTH_ATTACHMENT = 0x8C1A, 0x8CE0, 0x8D00


def _default_raster_threads() -> int:
    # llvmpipe sizes its thread pool from the host's CPU count, which containers may overstate.
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


_DEFAULT = None  # the process's GLContext (default_context)


class GLContext:
    """A headless EGL OpenGL 4.5 core context (moderngl), made once and reused.

    Parameters: ``device_index``: the EGL device (default: ``EVALKIT_GL_DEVICE``, else 0).
    Raises `InputError` with the driver's message when no such context can be made.
    """

    def __init__(self, device_index: int | None = None):
        os.environ.setdefault("LP_NUM_THREADS", str(_default_raster_threads()))
        if device_index is None:
            env = os.environ.get("EVALKIT_GL_DEVICE", os.environ.get("GLCONTEXT_DEVICE_INDEX", "0"))
            if not env.strip().isdigit():
                raise InputError("EVALKIT_GL_DEVICE", f"'{env}' is not an EGL device index (0, 1, ...)")
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
        self._staging = None  # the buffer `read` copies through, at most STAGING_BYTES
        # GL calls go to the context current on the thread, and making a context makes it current:
        # a second one would take the GL calls of objects made on the first (seen as buffers that
        # cannot be mapped, and a hung pass). So the process's first context is the one the
        # one-call API uses too (`default_context`).
        global _DEFAULT
        if _DEFAULT is None:
            _DEFAULT = self

    @property
    def is_llvmpipe(self) -> bool:
        return "llvmpipe" in self.ctx.info["GL_RENDERER"]

    @property
    def max_storage_bytes(self) -> int:
        """The largest storage buffer a shader may index. llvmpipe reports 128 MiB but indexes any
        buffer it can allocate (tests/test_gl_context.py checks this), so there the limit is the
        32-bit byte offset."""
        return 2**32 - 1 if self.is_llvmpipe else int(self.ctx.info["GL_MAX_SHADER_STORAGE_BLOCK_SIZE"])

    def free_memory(self) -> tuple[int, str] | None:
        """(bytes, where the figure comes from) that new buffers can take now, or None where the
        driver does not say. llvmpipe's buffers are system memory (`system_free_memory`); the
        NVIDIA driver reports its free video memory through GL_NVX_gpu_memory_info."""
        if self.is_llvmpipe:
            return system_free_memory()
        if "GL_NVX_gpu_memory_info" in self.ctx.extensions:
            kib = gl_integer(GPU_MEMORY_INFO_CURRENT_AVAILABLE_VIDMEM_NVX)
            if kib:
                return 1024 * kib, "GL_NVX_gpu_memory_info"
        return None

    def program(self, name: str, **defines):
        """Program ``name`` (gpu_impl/shaders/*/<name>.glsl, its stages selected by ``#if defined
        VERTEX_SHADER`` guards), compiled once per set of ``defines`` and cached."""
        key = variant_key(name, defines)
        if key not in self._programs:
            sources = program_sources(name, defines)
            try:
                if "compute_shader" in sources:
                    self._programs[key] = self.ctx.compute_shader(sources["compute_shader"])
                else:
                    self._programs[key] = self.ctx.program(**sources)
            except moderngl.Error as e:
                # A driver that cannot compile a shader (one without an extension it needs, or a
                # shader being edited): the file, the variant and the driver's first complaint.
                lines = [line.strip() for line in str(e).splitlines() if line.strip()]
                errors = [line for line in lines if "error" in line.lower() and ":" in line]
                complaint = (errors or lines[-1:] or ["no log"])[0]
                variant = ", ".join(f"{k}={v}" for k, v in sorted(defines.items())) or "no defines"
                raise InputError(
                    str(program_path(name).relative_to(Path(__file__).parent.parent)),
                    f"the GL driver ({self.ctx.info['GL_RENDERER']}) cannot compile it ({variant}): {complaint}",
                ) from e
            COMPILED.add(key)
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

    def draw(
        self, vertex_array, mode: int, framebuffer, depth_test: bool, commands=None, clip_distances: int = 0, **kw
    ) -> None:
        """Draw ``vertex_array`` into ``framebuffer`` (no face culling, no blending; the depth test
        only when asked), then a barrier: what its shaders wrote to storage is visible after it.
        ``commands``: (buffer, count, first) to draw ``count`` indirect commands of ``buffer`` from
        its ``first``, instead of the whole array. ``clip_distances``: how many gl_ClipDistance the
        vertex shader writes (enabled for this draw only)."""
        framebuffer.use()
        self.ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        (self.ctx.enable if depth_test else self.ctx.disable)(moderngl.DEPTH_TEST)
        for i in range(clip_distances):
            self.ctx.enable_direct(GL_CLIP_DISTANCE0 + i)
        if mode == moderngl.POINTS:  # splats size themselves (gl_PointSize)
            self.ctx.enable(moderngl.PROGRAM_POINT_SIZE)
        if commands is None:
            vertex_array.render(mode, **kw)
        else:
            buffer, count, first = commands
            vertex_array.render_indirect(buffer, mode, count=int(count), first=int(first))
        for i in range(clip_distances):
            self.ctx.disable_direct(GL_CLIP_DISTANCE0 + i)
        self.ctx.disable(moderngl.DEPTH_TEST)
        self.ctx.memory_barrier()

    # The GL objects the toolkit makes, each released by the one object that made it.
    def buffer(self, data: bytes | None = None, reserve: int = 0):
        return self.ctx.buffer(data, reserve=reserve)

    def texture(self, size: tuple[int, int], components: int, dtype: str):
        texture = self.ctx.texture(size, components, dtype=dtype)
        texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return texture

    def record_texture(self, records: int, components: int, dtype: str, what: str, settings: tuple[str, ...] = ()):
        """A texture of ``records`` texels, `TEXEL_ROW` a row (the last row padded), that shaders read
        records from by texel fetch (shaders/include/bundle.glsl: record_texel); ``what`` names them, and
        ``settings`` the settings that make them as many, in the refusal when the driver makes no
        such texture."""
        rows = max(1, -(-records // TEXEL_ROW))
        made = None
        if rows <= self.limit("GL_MAX_TEXTURE_SIZE"):
            nbytes = TEXEL_ROW * rows * components * np.dtype(dtype).itemsize
            made = self.allocate(lambda: [self.texture((TEXEL_ROW, rows), components, dtype)], nbytes)
        if made is None:
            raise LimitError(
                f"{records:,} {what} as texels need a texture of {TEXEL_ROW} x {rows}, which the GL driver refused",
                settings,
            )
        return made[0]

    def texture_array(self, size: tuple[int, int], layers: int, components: int, dtype: str):
        texture = self.ctx.texture_array((*size, layers), components, dtype=dtype)
        texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return texture

    def layer_targets(self, color: list) -> LayerTargets:
        """A framebuffer per layer of the texture arrays ``color`` (all of one size), with a depth
        array of its own; the caller owns the arrays and the targets."""
        return LayerTargets(self, color)

    def allocate(self, make, nbytes: int):
        """The GL objects ``make()`` returns (a list), or None, with nothing or them released, where
        the driver cannot hold their ``nbytes``: more than the memory it has free (the NVIDIA
        driver makes a texture of terabytes without an error, docs/platform.md), or an
        out-of-memory error making them (llvmpipe caps one texture's bytes below what its size
        limits say, at about 1.3 GiB, and leaves a texture past it empty, not refused)."""
        room = self.free_memory()
        if room is not None and nbytes > room[0]:
            return None
        while self.ctx.error != "GL_NO_ERROR":  # errors of earlier calls are not this one's
            pass
        made = make()
        if self.ctx.error != "GL_OUT_OF_MEMORY":
            return made
        for thing in made:
            thing.release()
        return None

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

    # Buffers that shaders use are filled and read on the GPU's side of the bus. moderngl's
    # Buffer.clear maps the buffer and fills it on the CPU, and Buffer.read maps it: on a GPU each
    # map waits for the passes before it, and a buffer the CPU keeps touching may be moved to
    # system memory, where every atomic of the next pass crosses the bus (on an H100 a perfect
    # frame of parts at K=64, R=512 took 1.7 s with maps and 0.04 s without,
    # docs/platform.md). llvmpipe's buffers are system memory either way.
    def fill(self, buffer, value: int = 0) -> None:
        """Every 32-bit word of ``buffer`` set to ``value``, by the GL (glClearNamedBufferData)."""
        if buffer.size % 4:
            raise ValueError(f"a buffer of {buffer.size} bytes is not whole 32-bit words")
        clear = _required_gl_function(
            "glClearNamedBufferData", ctypes.c_uint, ctypes.c_uint, ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p
        )
        word = ctypes.c_uint32(value & 0xFFFFFFFF)
        clear(buffer.glo, GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, ctypes.byref(word))

    def fill_texture(self, texture, value: int) -> None:
        """Every texel of an R32UI ``texture`` set to ``value``, by the GL (glClearTexImage), as
        `fill` does for buffers."""
        clear = _required_gl_function(
            "glClearTexImage", ctypes.c_uint, ctypes.c_int, ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p
        )
        word = ctypes.c_uint32(value & 0xFFFFFFFF)
        clear(texture.glo, 0, GL_RED_INTEGER, GL_UNSIGNED_INT, ctypes.byref(word))

    def read(self, buffer, dtype=np.uint32, count: int | None = None, first: int = 0) -> np.ndarray:
        """``count`` records of ``dtype`` from record ``first`` of ``buffer`` (default: to its end),
        copied by the GL into a staging buffer and read from there, so that the buffer itself (a
        counter the passes update) is never mapped."""
        dtype = np.dtype(dtype)
        count = buffer.size // dtype.itemsize - first if count is None else count
        size, offset = dtype.itemsize * count, dtype.itemsize * first
        # In pieces of at most STAGING_BYTES: a read of a whole node buffer (gigabytes at high R)
        # neither holds a staging buffer its size afterwards nor needs one beside it.
        if self._staging is None or self._staging.size < min(size, STAGING_BYTES):
            if self._staging is not None:
                self._staging.release()
            self._staging = self.ctx.buffer(reserve=max(min(size, STAGING_BYTES), 4096))
        out = np.empty(size, dtype=np.uint8)
        for start in range(0, size, STAGING_BYTES):
            piece = min(STAGING_BYTES, size - start)
            self.ctx.copy_buffer(self._staging, buffer, piece, read_offset=offset + start)
            self._staging.read_into(memoryview(out)[start : start + piece], piece)
        return out.view(dtype)

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
        global _DEFAULT
        if _DEFAULT is self:
            _DEFAULT = None
        if self._staging is not None:
            self._staging.release()
            self._staging = None
        self.ctx.release()
        self._programs.clear()

    def __enter__(self) -> GLContext:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


class LayerTargets:
    """Draw targets for texture arrays drawn a layer at a time: ``framebuffers[i]`` draws into
    layer i of every array of ``color`` and of a 24-bit depth array made here (as moderngl's depth
    renderbuffers are). moderngl attaches only whole 2-D textures, so the framebuffers and the
    depth array are made through the GL and wrapped (`moderngl.Context.detect_framebuffer`)."""

    def __init__(self, gl: GLContext, color: list):
        self.color = list(color)
        width, height, layers = self.color[0].size
        make_textures = _required_gl_function(
            "glCreateTextures", ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_uint)
        )
        storage = _required_gl_function(
            "glTextureStorage3D", ctypes.c_uint, ctypes.c_int, ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int
        )
        make_framebuffers = _required_gl_function("glCreateFramebuffers", ctypes.c_int, ctypes.POINTER(ctypes.c_uint))
        attach = _required_gl_function(
            "glNamedFramebufferTextureLayer", ctypes.c_uint, ctypes.c_uint, ctypes.c_uint, ctypes.c_int, ctypes.c_int
        )
        draw_buffers = _required_gl_function(
            "glNamedFramebufferDrawBuffers", ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_uint)
        )
        depth = ctypes.c_uint(0)
        make_textures(GL_TEXTURE_2D_ARRAY, 1, ctypes.byref(depth))
        storage(depth.value, 1, GL_DEPTH_COMPONENT24, width, height, layers)
        self.depth = depth.value
        names = (ctypes.c_uint * layers)()
        make_framebuffers(layers, names)
        self.names = list(names)
        outputs = (ctypes.c_uint * len(self.color))(*(GL_COLOR_ATTACHMENT0 + i for i in range(len(self.color))))
        self.framebuffers = []
        for layer, name in enumerate(self.names):
            for i, texture in enumerate(self.color):
                attach(name, GL_COLOR_ATTACHMENT0 + i, texture.glo, 0, layer)
            attach(name, GL_DEPTH_ATTACHMENT, self.depth, 0, layer)
            draw_buffers(name, len(self.color), outputs)
            framebuffer = gl.ctx.detect_framebuffer(name)
            framebuffer.viewport = (0, 0, width, height)
            self.framebuffers.append(framebuffer)

    def clear(self, layer: int, viewport: tuple[int, int, int, int], color: list) -> None:
        """Set ``viewport`` (x, y, width, height) of ``layer``: each colour array to its value of
        ``color`` (floats for a float array, an integer for an integer one), the depth to 1."""
        clear = _required_gl_function(
            "glClearTexSubImage",
            ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int,
            ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p,
        )  # fmt: skip
        x, y, w, h = viewport
        if w <= 0 or h <= 0:
            return
        for texture, value in zip(self.color, color):
            if texture.dtype.startswith("u"):
                data, fmt, kind = (ctypes.c_uint32 * 1)(int(value) & 0xFFFFFFFF), GL_RED_INTEGER, GL_UNSIGNED_INT
            else:
                values = np.atleast_1d(np.asarray(value, dtype=np.float32))
                data, fmt, kind = (ctypes.c_float * len(values))(*values), (GL_RED, GL_RG)[len(values) - 1], GL_FLOAT
            clear(texture.glo, 0, x, y, layer, w, h, 1, fmt, kind, data)
        clear(self.depth, 0, x, y, layer, w, h, 1, GL_DEPTH_COMPONENT, GL_FLOAT, (ctypes.c_float * 1)(1.0))

    def release(self) -> None:
        delete_framebuffers = _required_gl_function("glDeleteFramebuffers", ctypes.c_int, ctypes.POINTER(ctypes.c_uint))
        delete_textures = _required_gl_function("glDeleteTextures", ctypes.c_int, ctypes.POINTER(ctypes.c_uint))
        delete_framebuffers(len(self.names), (ctypes.c_uint * len(self.names))(*self.names))
        delete_textures(1, (ctypes.c_uint * 1)(self.depth))
        self.names, self.framebuffers = [], []


def system_free_memory(proc: str = "/proc", cgroups: str = "/sys/fs/cgroup") -> tuple[int, str] | None:
    """MemAvailable of /proc/meminfo, or less where this process's memory cgroup (a container, a
    batch job; cgroup v2 ``memory.max`` or v1 ``memory.limit_in_bytes``) leaves less below its
    limit: what can be allocated before the kernel kills the process. None where neither is
    readable."""
    try:
        with open(f"{proc}/meminfo") as f:
            fields = dict(line.split(":", 1) for line in f if ":" in line)
        free, source = int(fields["MemAvailable"].split()[0]) * 1024, "MemAvailable"
    except (OSError, KeyError, ValueError):
        return None
    for limit, usage in _cgroup_memory_files(proc, cgroups):
        try:
            with open(limit) as f:
                cap = f.read().strip()
            with open(usage) as f:
                used = int(f.read())
        except (OSError, ValueError):
            continue
        if cap.isdigit() and int(cap) < 2**60 and int(cap) - used < free:  # v1 says "no limit" as ~2^63
            free, source = max(0, int(cap) - used), f"the memory cgroup's {os.path.basename(limit)}"
        break
    return free, source


def _cgroup_memory_files(proc: str, cgroups: str):
    """(limit file, usage file) of this process's memory cgroup, its own folder first, then the
    mount's root (where a cgroup namespace puts a container's own)."""
    try:
        with open(f"{proc}/self/cgroup") as f:
            lines = f.read().splitlines()
    except OSError:
        return
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controllers == "":  # v2: one unified hierarchy
            names, folders = ("memory.max", "memory.current"), (f"{cgroups}{path}", cgroups)
        elif "memory" in controllers.split(","):
            names, folders = (
                ("memory.limit_in_bytes", "memory.usage_in_bytes"),
                (f"{cgroups}/memory{path}", f"{cgroups}/memory"),
            )
        else:
            continue
        for folder in folders:
            if os.path.isfile(os.path.join(folder, names[0])):
                yield os.path.join(folder, names[0]), os.path.join(folder, names[1])
                break


def gl_integer(pname: int) -> int | None:
    """glGetIntegerv(pname) in the current context, for the queries moderngl does not expose;
    None when the entry point cannot be found."""
    get = _gl_function("glGetIntegerv", ctypes.c_uint, ctypes.POINTER(ctypes.c_int))
    if get is None:
        return None
    value = ctypes.c_int(0)
    get(pname, ctypes.byref(value))
    return value.value


@functools.cache
def _gl_function(name: str, *argtypes):
    """A GL entry point moderngl does not expose, through EGL's loader, looked up once (None where
    there is no libEGL or no such function)."""
    try:
        egl = ctypes.CDLL("libEGL.so.1")
    except OSError:
        return None
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    address = egl.eglGetProcAddress(name.encode())
    return ctypes.CFUNCTYPE(None, *argtypes)(address) if address else None


def _required_gl_function(name: str, *argtypes):
    """`_gl_function`, for the entry points an OpenGL 4.5 context has: only a missing libEGL makes
    one None, and that is an error."""
    function = _gl_function(name, *argtypes)
    if function is None:
        raise RuntimeError(f"{name} not found through libEGL.so.1")
    return function


def default_context() -> GLContext:
    """The process's context: the first `GLContext` made and not released, else one made now
    (making one is slow) and kept. What the one-call API (`gpu_impl.api`) and studies render with
    when given none. A process should hold one context: see `GLContext.__init__`."""
    return _DEFAULT if _DEFAULT is not None else GLContext()


def set_uniforms(program, values: dict) -> None:
    """Set each uniform ``program`` has; those a shader variant compiled away are skipped."""
    for name, value in values.items():
        if name in program:
            program[name] = value


def format_bytes(n: int) -> str:
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.2f} {unit}"
    return f"{n} B"
