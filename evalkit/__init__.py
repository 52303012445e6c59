"""evalkit: the toolkit users call for ray-bundle global illumination.

Scene model and importers (`evalkit.core.scene`), Mitsuba set-up (`evalkit.core.mitsuba_env`), diagnostics
(`evalkit.doctor`) and the command line (`evalkit.cli`). Importing this package is cheap: Mitsuba,
trimesh and OpenGL are loaded only by the functions that need them.
"""

__version__ = "0.1.0"
