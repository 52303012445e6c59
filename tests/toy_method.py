"""A toy bundle method that follows docs/ARCHITECTURE.md's recipe for a new unit: this module and
its line in gpu_impl/registry.py, nothing else. Its bundles are perfect bundles; its one setting
shows in its tracer's description. tests/test_units.py registers it and checks that the command
line, the render's provenance, the generated reference and the unit contract all know it."""

from __future__ import annotations

from dataclasses import dataclass

from evalkit.core.settings import setting
from gpu_impl.methods.perfect import PerfectTracer
from gpu_impl.units import BundleMethod


@dataclass(frozen=True)
class ToySettings:
    toy_tag: int = setting(1, "a number the toy's tracer names in its description", minimum=1, symbol="T")


class ToyTracer(PerfectTracer):
    def __init__(self, gl, gpu_scene, settings, **hooks):
        self.tag = METHOD.settings_of(settings).toy_tag
        super().__init__(gl, gpu_scene, settings, **hooks)

    def describe(self) -> str:
        return f"toy bundles {self.tag} (K={self.K}, R={self.R})"


METHOD = BundleMethod(name="toy", summary="perfect bundles under a test's name", settings=ToySettings, tracer=ToyTracer)
