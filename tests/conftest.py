"""Shared fixtures: the Mitsuba module, a seeded generator, texture files written on the fly, and a
runner for the installed `evalkit` command (bad input must end in exit 2 without a traceback)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="session")
def mi():
    from evalkit.mitsuba_env import mitsuba

    return mitsuba()


@pytest.fixture(scope="session")
def gl():
    """One headless GL context for the whole session: making one is slow."""
    from gpu_impl.context import GLContext

    with GLContext() as context:
        yield context


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def run_evalkit(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """`evalkit ARGS` in a child process, as a user runs it."""
    return subprocess.run([sys.executable, "-m", "evalkit.cli", *args], capture_output=True, text=True, timeout=timeout, cwd=REPO)


def write_texture(path, size: int = 8, seed: int = 0) -> np.ndarray:
    """An 8-bit sRGB PNG; returns its texels (H, W, 3) uint8."""
    from PIL import Image

    texels = np.random.default_rng(seed).integers(0, 256, (size, size, 3), dtype=np.uint8)
    Image.fromarray(texels).save(path)
    return texels


def relmse(test: np.ndarray, ref: np.ndarray, eps: float = 0.01) -> float:
    """Mean of (x - r)^2 / (r^2 + eps), the tev form, over pixels and channels (the toolkit's own metric)."""
    from evalkit.metrics.images import relmse as metric

    return metric(np.asarray(test, dtype=np.float64), np.asarray(ref, dtype=np.float64), eps).value


# Hypothesis: derandomized in CI (the same examples every run); `make fuzz` (HYPOTHESIS_PROFILE=fuzz)
# draws fresh examples, many more of them.
from hypothesis import HealthCheck, settings  # noqa: E402

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("fuzz", derandomize=False, deadline=None, max_examples=5000, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
