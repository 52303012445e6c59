"""GPU time per pass: GL timer queries on a GPU, host time around glFinish on llvmpipe."""

from __future__ import annotations

import statistics
import time
from contextlib import contextmanager

INVALID_QUERY = 2**32 - 1  # moderngl reads 32-bit results: a failed or saturated time query


class PassTimer:
    """GPU time per named pass, read once at the end so timing adds no round-trip between passes.

    On a GPU it uses GL timer queries. llvmpipe's timer queries do not cover compute dispatches (a
    13 s dispatch measured 1 ns), so there each pass ends in glFinish and is timed on the host:
    on a CPU rasterizer that is the rasterizer's own time.
    """

    def __init__(self, gl):
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


def median_ms(gl, work, repeats: int) -> float:
    """The median host time of ``work`` (ms, around glFinish) over ``repeats`` runs after a warm-up
    (the first run also compiles: llvmpipe JIT-compiles a program at its first dispatch)."""
    times = []
    for _ in range(repeats + 1):
        gl.finish()
        start = time.perf_counter()
        work()
        gl.finish()
        times.append(1e3 * (time.perf_counter() - start))
    return statistics.median(times[1:])
