"""Loading Mitsuba 3 with an LLVM that works.

Dr.Jit's LLVM backend loads libLLVM at the first use of an ``llvm_*`` variant. With mitsuba 3.9.1 and
drjit 1.5.0, LLVM 14 is refused and LLVM 15 and 16 abort the whole process (``Cannot select ...
fminimum``), so auto-detection must not be left to pick one of those. This module points
``DRJIT_LIBLLVM_PATH`` at LLVM 19 (or a newer one) before Mitsuba is imported, unless the user set it.
"""

from __future__ import annotations

import glob
import os
import re

# Checked to work (docs/platform.md); newer ones are tried after it, older ones are known to fail.
MIN_LLVM_MAJOR = 17
PREFERRED_LLVM_MAJOR = 19

_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
)


def llvm_major(path: str) -> int | None:
    """The LLVM major version in a libLLVM file name (libLLVM.so.19.1, libLLVM-19.so, llvm-19/...)."""
    m = re.search(r"libLLVM(?:[-.]|\.so\.)(\d+)", os.path.basename(path)) or re.search(r"llvm-(\d+)/", path)
    return int(m.group(1)) if m else None


def find_libllvm(patterns: tuple[str, ...] = _LLVM_GLOBS) -> str | None:
    """The libLLVM to give Dr.Jit: version 19 if present, else the newest at or above 17."""
    candidates = {}
    for pattern in patterns:
        for path in sorted(glob.glob(pattern)):
            major = llvm_major(path)
            if major is not None and major >= MIN_LLVM_MAJOR and os.path.isfile(path):
                candidates.setdefault(major, path)
    if not candidates:
        return None
    if PREFERRED_LLVM_MAJOR in candidates:
        return candidates[PREFERRED_LLVM_MAJOR]
    return candidates[max(candidates)]


def configure_llvm() -> str | None:
    """Set DRJIT_LIBLLVM_PATH (unless the user did) and return the path Dr.Jit will load, if any."""
    user = os.environ.get("DRJIT_LIBLLVM_PATH")
    if user:
        return user
    path = find_libllvm()
    if path:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def llvm_usable() -> bool:
    """Whether an LLVM that Dr.Jit can use without aborting is configured."""
    path = configure_llvm()
    if not path or not os.path.exists(path):
        return False
    major = llvm_major(path)
    return major is None or major >= MIN_LLVM_MAJOR


def cuda_usable() -> bool:
    """Whether an NVIDIA driver with CUDA is there (Dr.Jit's CUDA backend needs libcuda)."""
    import ctypes

    try:
        ctypes.CDLL("libcuda.so.1")
    except OSError:
        return False
    return True


def default_variant() -> str:
    """``cuda_ad_rgb`` where a GPU driver is there, else ``llvm_ad_rgb`` when a working LLVM is
    there, else ``scalar_rgb`` (no LLVM, about half the speed). With the independent sampler the
    same seed gives the same image on llvm and scalar (docs/platform.md).

    ``EVALKIT_MITSUBA_VARIANT`` overrides the choice.
    """
    forced = os.environ.get("EVALKIT_MITSUBA_VARIANT")
    if forced:
        return forced
    if cuda_usable():
        return "cuda_ad_rgb"
    return "llvm_ad_rgb" if llvm_usable() else "scalar_rgb"


def mitsuba(variant: str | None = None):
    """Import Mitsuba with a safe LLVM and select ``variant`` (default: `default_variant`)."""
    configure_llvm()
    import mitsuba as mi

    mi.set_variant(variant or default_variant())
    return mi
