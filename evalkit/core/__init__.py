"""The lower layer of evalkit: what every other part of the project builds on, and nothing else.

- `evalkit.core.scene`: the scene model (`Scene`) and its importers (built-ins, Mitsuba XML and
  dicts, OBJ/PLY/glTF/GLB) and the export to Mitsuba;
- `evalkit.core.bundleset`: `DirectionSet` and `BundleSet`, the one type every bundle builder makes;
- `evalkit.core.exr`: float32 EXR files with provenance;
- `evalkit.core.errors`: `InputError`, the one-line error users see;
- `evalkit.core.mitsuba_env`: loading Mitsuba with an LLVM that works.

`gpu_impl` and `references` import only this layer; the upper modules of evalkit (metrics, study,
report, check, cli, demo) import downward. tests/test_layers.py enforces the direction.
"""

# The toolkit's version, pyproject.toml's (`evalkit.__version__`): read here, not from the installed
# metadata, so a checkout run without installing it records it too.
VERSION = "0.1.0"
