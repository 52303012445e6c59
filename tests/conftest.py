"""Shared fixtures: the Mitsuba module, a seeded generator, texture files written on the fly, and a
runner for the installed `evalkit` command (bad input must end in exit 2 without a traceback)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evalkit.core.exr import write_exr
from evalkit.core.mitsuba_env import mitsuba
from evalkit.core.scene import load_scene
from evalkit.core.settings import RenderSettings
from evalkit.figures import error_map_png
from evalkit.metrics.confidence import mean_ratio
from evalkit.metrics.images import relmse as metric
from gpu_impl.api import bundle_tracer, render, trace_bundles
from gpu_impl.context import default_context
from gpu_impl.registry import resolve
from gpu_impl.shader_source import unlisted_variants
from references.mitsuba import COMMITTED_STORE, load_reference, store_entry

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# Where tests that compare images keep them when they fail (as Mitsuba's render tests do).
ERROR_OUTPUT = Path(REPO) / "error_output"


@pytest.fixture(scope="session", autouse=True)
def user_cache(tmp_path_factory):
    """The user cache (imported scenes, references of other scenes) is a folder of the session's."""
    os.environ.pop("EVALKIT_REFERENCE_STORE", None)
    os.environ["EVALKIT_CACHE"] = str(tmp_path_factory.mktemp("user-cache"))


@pytest.fixture(scope="session")
def mi():
    return mitsuba()


@pytest.fixture(scope="session")
def gl():
    """The process's one GL context (making one is slow), the same the one-call API and in-process
    studies use whichever test makes it first: a second context would take the first's GL calls."""
    with default_context() as context:
        yield context


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def cornell_reference(bounces: int):
    """cornell-box and its committed Mitsuba reference at B bounces (16384 spp, 128x128, seed 0)."""
    scene = load_scene("cornell-box")
    entry = store_entry(scene.name, scene.content_hash(), bounces, 16384, 128, 128, 0, COMMITTED_STORE)
    return scene, load_reference(entry)


# The tracers' hooks, which are not settings (gpu_impl/api.py: bundle_tracer).
TRACER_HOOKS = ("count_covered", "initial_capacity", "max_atlas_size", "textures")


def _tracer_args(method: str, kw: dict) -> tuple[RenderSettings, dict]:
    """Settings and hooks from flat keywords; settings ``method`` does not have are left out, so a
    test can give both methods the same keywords."""
    hooks = {k: kw.pop(k) for k in TRACER_HOOKS if k in kw}
    return resolve(RenderSettings(method=method, **kw), inapplicable="drop").settings, hooks


def trace(gl, scene, directions, method: str = "perfect", **kw):
    """The `BundleSet` of one direction set (`gpu_impl.api.trace_bundles`), settings and hooks flat."""
    settings, hooks = _tracer_args(method, kw)
    return trace_bundles(scene, directions, settings, gl=gl, **hooks)


def make_tracer(gl, gpu_scene, method: str = "perfect", **kw):
    """A tracer of an uploaded scene (`gpu_impl.api.bundle_tracer`), settings and hooks flat."""
    settings, hooks = _tracer_args(method, kw)
    return bundle_tracer(gl, gpu_scene, settings, **hooks)


def render_with(gl, scene, **settings):
    """`gpu_impl.api.render` on the tests' GL context, the settings flat; settings the chosen units
    do not have are left out, so a test can give both methods the same keywords."""
    return render(scene, resolve(RenderSettings(**settings), inapplicable="drop").settings, gl=gl)


def mean_interval(result, ref, image: str, channels: bool = False):
    """The ratio of a render's image mean to a reference's with its 95 % interval
    (`evalkit.metrics.confidence.mean_ratio`): over all channels, or per channel."""
    r = mean_ratio(result.frame_means[image], ref.images[image], ref.variances[image])
    return r["per_channel"] if channels else r["all"]


def describe_interval(r: dict) -> str:
    return f"{r['ratio']:.4f} [{r['lo']:.4f}, {r['hi']:.4f}]"


def run_evalkit(*args: str, timeout: float = 600, env: dict | None = None) -> subprocess.CompletedProcess:
    """`evalkit ARGS` in a child process, as a user runs it (``env``: its whole environment)."""
    return subprocess.run(
        [sys.executable, "-m", "evalkit.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
        env=env,
    )


def write_texture(path, size: int = 8, seed: int = 0) -> np.ndarray:
    """An 8-bit sRGB PNG; returns its texels (H, W, 3) uint8."""
    from PIL import Image

    texels = np.random.default_rng(seed).integers(0, 256, (size, size, 3), dtype=np.uint8)
    Image.fromarray(texels).save(path)
    return texels


class ImageOutput:
    """For a test that compares images: on failure, `keep` writes the test image, the reference and
    the relMSE error map (EXR, and PNG in magma) to error_output/<test>/<name>/ and returns the
    failure message naming that folder, so the next person can look instead of guess."""

    def __init__(self, test_id: str, root: Path = ERROR_OUTPUT):
        self.folder = root / re.sub(r"[^\w.-]+", "_", test_id)

    def keep(self, name: str, test: np.ndarray, ref: np.ndarray, message: str) -> str:
        folder = self.folder / name
        folder.mkdir(parents=True, exist_ok=True)
        test, ref = np.asarray(test, dtype=np.float32), np.asarray(ref, dtype=np.float32)
        write_exr(folder / "test.exr", test, {"test": self.folder.name, "image": name})
        write_exr(folder / "reference.exr", ref, {"test": self.folder.name, "image": name})
        error = metric(test.astype(np.float64), ref.astype(np.float64)).map
        write_exr(
            folder / "relmse_map.exr", np.repeat(error[..., None], 3, axis=2).astype(np.float32), {"map": "relmse"}
        )
        vmax = error_map_png(error, folder / "relmse_map.png")
        return f"{message}; test image, reference and relMSE map (magma, 0..{vmax:.3g}) in {folder}"

    def relmse_at_most(self, name: str, test: np.ndarray, ref: np.ndarray, threshold: float) -> float:
        """relMSE of ``test`` against ``ref``, asserted at most ``threshold``."""
        value = relmse(test, ref)
        assert value <= threshold, self.keep(name, test, ref, f"{name}: relMSE {value:.4g} > {threshold:.4g}")
        return value


@pytest.fixture
def images(request) -> ImageOutput:
    return ImageOutput(request.node.nodeid)


def relmse(test: np.ndarray, ref: np.ndarray, eps: float = 0.01) -> float:
    """Mean of (x - r)^2 / (r^2 + eps), the tev form, over pixels and channels (the toolkit's own metric)."""
    return metric(np.asarray(test, dtype=np.float64), np.asarray(ref, dtype=np.float64), eps).value


CHROMIUM, DRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")


@pytest.fixture(scope="session")
def browser():
    """Headless Chromium driven by Selenium (Debian's chromium and chromium-driver, which `make
    test` installs), keeping the pages' console messages (``driver.get_log("browser")``)."""
    if not (CHROMIUM.is_file() and DRIVER.is_file()):
        pytest.fail("chromium and chromium-driver are missing: `make test` (scripts/setup.sh test) installs them")
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1280,1000"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(str(DRIVER)), options=options)
    yield driver
    driver.quit()


# Shader variants compiled by pytest-xdist's workers (make test runs two), gathered as each worker
# finishes and reported with the controller's own.
WORKER_VARIANTS: list = []


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    WORKER_VARIANTS.extend(node.workeroutput.get("unlisted_variants", []))


def pytest_sessionfinish(session, exitstatus):
    """Every shader variant the suite compiled must be one that SHADER_VARIANTS lists
    (gpu_impl/shader_source.py), so the test that compiles them all compiles what runs."""
    unlisted = unlisted_variants()
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # a worker: its controller reports
        workeroutput["unlisted_variants"] = [(name, [list(d) for d in defines]) for name, defines in unlisted]
        return
    unlisted = sorted({*unlisted, *((name, tuple(map(tuple, d))) for name, d in WORKER_VARIANTS)})
    if unlisted:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        lines = "\n".join(f"  {name} {dict(defines)}" for name, defines in unlisted)
        reporter.write_line(f"FAILED: shader variants compiled but not in SHADER_VARIANTS:\n{lines}", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


# Hypothesis: derandomized in CI (the same examples every run); `make fuzz` (HYPOTHESIS_PROFILE=fuzz)
# draws fresh examples, many more of them.
from hypothesis import HealthCheck, settings  # noqa: E402

settings.register_profile(
    "ci",
    derandomize=True,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.register_profile(
    "fuzz",
    derandomize=False,
    deadline=None,
    max_examples=5000,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
