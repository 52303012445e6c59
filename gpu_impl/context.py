"""The one object that owns the headless OpenGL 4.5 context.

Creating an EGL context is slow (shader caches, llvmpipe thread pools, driver start-up), so one
`GLContext` is made and reused for every bundle build and render.

Device selection: on a machine with several EGL devices (a GPU machine), the device is picked by
index, from the ``device_index`` argument or the ``EVALKIT_GL_DEVICE`` variable (glcontext's own
``GLCONTEXT_DEVICE_INDEX`` works too). ``CUDA_VISIBLE_DEVICES`` does not renumber EGL devices.
"""

from __future__ import annotations

import json
import os

GL_REQUIRED = 450  # SSBOs, image atomics, compute shaders


def _default_raster_threads() -> int:
    # llvmpipe sizes its thread pool from the host's CPU count, which containers may overstate.
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


class GLContext:
    """A headless EGL OpenGL 4.5 core context (moderngl), made once and reused.

    Parameters: ``device_index``: the EGL device (default: ``EVALKIT_GL_DEVICE``, else 0).
    Raises RuntimeError with the driver's message when no such context can be made.
    """

    def __init__(self, device_index: int | None = None):
        import moderngl

        os.environ.setdefault("LP_NUM_THREADS", str(_default_raster_threads()))
        if device_index is None:
            env = os.environ.get("EVALKIT_GL_DEVICE", os.environ.get("GLCONTEXT_DEVICE_INDEX", "0"))
            device_index = int(env)
        self.device_index = device_index
        self.ctx = moderngl.create_context(standalone=True, backend="egl", require=GL_REQUIRED, device_index=device_index)

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

    def __enter__(self) -> "GLContext":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


if __name__ == "__main__":  # the probe `evalkit doctor` runs in a child process
    with GLContext() as gl:
        print(json.dumps(gl.info))
