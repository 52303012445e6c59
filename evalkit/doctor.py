"""`evalkit doctor`: is every backend usable, and if not, what fixes it.

Each backend is probed in a child process, because the failures that matter most do not raise:
an LLVM that Dr.Jit cannot use aborts the whole process, and a broken GL driver can crash it. The
parent reads one JSON line from each probe and never dies with it.
"""

from __future__ import annotations

import json
import subprocess
import sys

from evalkit.core.mitsuba_env import configure_llvm, default_variant, mitsuba
from gpu_impl.context import GL_REQUIRED, GLContext

PROBE_TIMEOUT_S = 180
SETUP_FIX = "run `make setup` in the checkout (installs the Debian packages and .venv)"


def probe_gl() -> dict:
    with GLContext() as gl:
        info = gl.info
    info["ok"] = info["version_code"] >= GL_REQUIRED
    if not info["ok"]:
        info["problem"] = f"OpenGL {info['version_code']} < {GL_REQUIRED} required"
    return info


def probe_mitsuba() -> dict:
    """Import Mitsuba the way the toolkit does and render 16x16 pixels, which compiles real
    kernels: the step at which an unusable LLVM aborts."""
    import numpy as np

    llvm_path = configure_llvm()
    variant = default_variant()
    mi = mitsuba(variant)
    import drjit as dr

    scene = mi.cornell_box()
    scene["sensor"]["film"].update(width=16, height=16)
    image = mi.render(mi.load_dict(scene), spp=1)
    info = {
        "mitsuba": mi.__version__,
        "drjit": dr.__version__,
        "variant": variant,
        "llvm_path": llvm_path,
        "llvm_version": ".".join(map(str, dr.detail.llvm_version())) if variant.startswith("llvm") else None,
    }
    mean = float(np.mean(np.array(image)))
    info["ok"] = variant.startswith(("llvm", "cuda")) and np.isfinite(mean) and mean > 0
    if not np.isfinite(mean) or mean <= 0:
        info["problem"] = f"a 16x16 test render of the Cornell box came out with mean {mean}"
    elif not info["ok"]:
        info["problem"] = "no usable libLLVM (17 or newer): Mitsuba falls back to scalar_rgb, about half the speed"
        info["fix"] = "apt-get install -y libllvm19 (or set DRJIT_LIBLLVM_PATH to a libLLVM 19)"
    return info


def probe_embree() -> dict:
    import importlib.metadata

    import numpy as np
    from embreex import rtcore, rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=np.float32))
    hit = scene.run(np.array([[0.2, 0.2, 1.0]], np.float32), np.array([[0, 0, -1.0]], np.float32))
    version = str(rtcore.EmbreeDevice()).split(":")[-1].strip()
    ok = int(hit[0]) == 0
    info = {"embree": version, "embreex": importlib.metadata.version("embreex"), "ok": ok}
    if not ok:
        info["problem"] = "a ray through a triangle missed it"
    return info


PROBES = {"gl": probe_gl, "mitsuba": probe_mitsuba, "embree": probe_embree}
FIXES = {
    "gl": "apt-get install -y libegl1 libgl1 libgl1-mesa-dri (Mesa's EGL and llvmpipe), or " + SETUP_FIX,
    "mitsuba": "apt-get install -y libllvm19, then " + SETUP_FIX,
    "embree": "pip install embreex==4.4.0.post1 into .venv, or " + SETUP_FIX,
}


def run_probe(name: str) -> dict:
    """Run one probe in a child process; a crash, an abort or a hang becomes a problem report."""
    try:
        done = subprocess.run(
            [sys.executable, "-m", "evalkit.doctor", name], capture_output=True, text=True, timeout=PROBE_TIMEOUT_S
        )
    except subprocess.TimeoutExpired:
        return {"ok": False, "problem": f"the probe hung for {PROBE_TIMEOUT_S} s", "fix": FIXES[name]}
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode == 0 and lines:
        result = json.loads(lines[-1])
    else:
        tail = [line.strip() for line in (done.stderr or "").splitlines() if line.strip()]
        how = f"exited with {done.returncode}" if done.returncode > 0 else f"was killed by signal {-done.returncode}"
        result = {"ok": False, "problem": f"the probe {how}: {tail[-1] if tail else 'no message'}"}
    if not result["ok"]:
        result.setdefault("fix", FIXES[name])
    return result


def diagnose() -> dict:
    return {name: run_probe(name) for name in PROBES}


def report_lines(results: dict) -> list[str]:
    lines = []
    gl, mi, em = results["gl"], results["mitsuba"], results["embree"]
    if "renderer" in gl:
        lines.append(f"GL       {gl['vendor']} | {gl['renderer']} | {gl['version']} (EGL device {gl['device_index']})")
    if "mitsuba" in mi:
        lines.append(
            f"Mitsuba  {mi['mitsuba']} (drjit {mi['drjit']}), variant {mi['variant']}, "
            f"LLVM {mi['llvm_version'] or '-'} from {mi['llvm_path'] or '-'}"
        )
    if "embree" in em:
        lines.append(f"Embree   {em['embree']} (embreex {em['embreex']})")
    for name, r in results.items():
        if not r["ok"]:
            lines.append(f"problem: {name}: {r['problem']}. Fix: {r['fix']}")
    return lines


if __name__ == "__main__":
    print(json.dumps(PROBES[sys.argv[1]]()))
