"""Fitting a few scalar constants with Dr.Jit's automatic differentiation: the hole model
(`evalkit.metrics.hole_model`) and the tuner's time and error models (`evalkit.tune`)."""

from __future__ import annotations

import math

from evalkit.core.mitsuba_env import configure_llvm


def drjit():
    """Dr.Jit and its LLVM AD float type (Dr.Jit's LLVM found first, `configure_llvm`)."""
    configure_llvm()
    import drjit as dr
    from drjit.llvm.ad import Float

    return dr, Float


def gradient_descent(loss, x0: list[float], steps: int = 400, rate: float = 0.05) -> list[float]:
    """Adam on a Dr.Jit AD loss ``loss(dr, *params)`` of a few scalar parameters; returns them."""
    dr, Float = drjit()
    x = [float(v) for v in x0]
    m, v = [0.0] * len(x), [0.0] * len(x)
    for t in range(1, steps + 1):
        params = [dr.opaque(Float, value) for value in x]  # opaque: one compiled kernel for every step
        for p in params:
            dr.enable_grad(p)
        value = loss(dr, *params)
        dr.backward(value)
        grads = [dr.grad(p) for p in params]
        dr.eval(*grads)  # one evaluation for all: reading each on its own took twice as long
        grads = [float(g[0]) for g in grads]
        for i, g in enumerate(grads):
            m[i] = 0.9 * m[i] + 0.1 * g
            v[i] = 0.999 * v[i] + 0.001 * g * g
            x[i] -= rate * (m[i] / (1 - 0.9**t)) / (math.sqrt(v[i] / (1 - 0.999**t)) + 1e-12)
    return x
