"""The shaders as source: the program files (one program per file with ``#if defined
VERTEX_SHADER`` stage guards, shared code through ``#include``), the header every stage gets (the
shared table of gpu_impl/layout.py and the variant's defines), and the variants the code compiles.

gpu_impl/shaders/ holds the programs by the part of a frame they make, and apart from them the code
they share:

    bundles/   the bundles: perfect lists, splat points and lists, the resolve, its prefix sum, and
               the nodes expanded for the host
    lights/    shadow maps (exact and imperfect, their second surfaces and pull-push) and the
               light that splat points precompute
    paths/     the camera's G-buffer and first hits, eye and light paths, their connections, and
               the images they resolve into
    include/   what programs ``#include`` by name (``#include "common.glsl"``): never a program

A program is named by its file's stem (``gl.program("eye_paths")``), so stems are unique across
the folders.

`SHADER_VARIANTS` lists, per program, every set of defines the code can compile it with: a list
of flag sets, or the axes of the scene features and settings it is compiled over (every product of
them, less the combinations `REQUIRES` rules out). `GLContext.program` records what it compiles
(`COMPILED`); the test suite compiles every listed variant and fails on a compiled one that is not
listed (tests/conftest.py), so the list cannot drift from what runs.
"""

from __future__ import annotations

import functools
import itertools
import re
from pathlib import Path

from gpu_impl.layout import (
    BINDINGS,
    ENVIRONMENT_KINDS,
    LIGHT_VISIBILITY_EXACT,
    LIGHT_VISIBILITY_IMPERFECT,
    MAX_ATLAS_TEXTURES,
    NODE_SPLAT_POINT,
    NODE_TRIANGLE,
    SAMPLERS,
    SHADER_CONSTANTS,
    glsl_literal,
)

SHADER_DIR = Path(__file__).parent / "shaders"
INCLUDE_DIR = SHADER_DIR / "include"
STAGES = {"VERTEX_SHADER": "vertex_shader", "FRAGMENT_SHADER": "fragment_shader", "COMPUTE_SHADER": "compute_shader"}

NODE_REFERENCES = (NODE_TRIANGLE, NODE_SPLAT_POINT)
LIGHT_VISIBILITIES = (LIGHT_VISIBILITY_EXACT, LIGHT_VISIBILITY_IMPERFECT)
ENVIRONMENTS = tuple(ENVIRONMENT_KINDS.values())
ENVMAP = ENVIRONMENT_KINDS["envmap"]
# A define that is 1 only where another one is (lazy light and light vertices need shadow-mapped lights).
# Bidirectional paths light every hit where it lands (their connections depend on the path).
REQUIRES = {
    "LAZY_LIGHTING": "SHADOW_LIGHTS",
    "EMITTER_SAMPLES": "SHADOW_LIGHTS",
    "ENVIRONMENT_SAMPLES": "SHADOW_LIGHTS",
    "BIDIRECTIONAL": "LAZY_LIGHTING",
}
# The shadow atlas read through one sampler, or through an array where it takes more textures,
# which only light paths' vertices make (gpu_impl/lights.py: ShadowLights.atlas_textures).
ATLAS_TEXTURES = (1, MAX_ATLAS_TEXTURES)


def atlas_possible(d: dict) -> bool:
    return d["ATLAS_TEXTURES"] == 1 or (d["SHADOW_LIGHTS"] and d["BIDIRECTIONAL"])


# Per program: flag sets (a list), or axes (a dict of define -> the values the code sets it to),
# with a rule that leaves out combinations no code makes (a (dict, predicate) pair).
VARIANTS = {
    "perfect_bundles": [{}, {"NULL_FRAGMENT": True}],
    "imperfect_bundles": [{}, {"NULL_FRAGMENT": True}],
    "splat_points": [{"SAMPLER": s, **queue} for s in SAMPLERS.values() for queue in ({}, {"QUEUE_SPLATS": True})],
    "splat_lists": [
        {"COUNT_SPLATS": True, **count, **run}
        for count in ({}, {"COUNT_COVERED": True})
        for run in ({}, {"PLAIN_SPLATS": True})
    ]
    + [
        {"SCATTER_SPLATS": True},
        {"SCATTER_SPLATS": True, "FIND_AGAIN": True},
    ],
    "resolve_lists": [
        {"COUNT_LISTS": True},
        *(
            {**sort, **long}
            for sort in ({"SORT_LISTS": True}, {"MERGE_LISTS": True}, {"MERGE_LISTS": True, "FROM_LINKED_LISTS": True})
            for long in ({"QUEUE_GROUPS": True}, {}, {"MEDIUM_LISTS": True}, {"LONG_LISTS": True})
        ),
    ],
    "prefix_sum": [{"SCAN_BLOCKS": True}, {"ADD_BLOCK_OFFSETS": True}],
    "expand_nodes": {"TEXTURES": (0, 1), "NODE_REFERENCE": NODE_REFERENCES},
    "gbuffer": [{}],
    "shadow_maps": {"SECOND_SURFACES": (0, 1)},
    "shadow_second_surface": [{}],
    "imperfect_shadow_maps": [{}],
    "ism_pull_push": [{}],
    "connection_visibility": {"LIGHT_VISIBILITY": LIGHT_VISIBILITIES, "ATLAS_TEXTURES": (1,)},
    "irradiance": {
        "SHADOW_LIGHTS": (1,),
        "NODE_SIDES": (1, 2),
        "TEXTURES": (0, 1),
        "LIGHT_VISIBILITY": LIGHT_VISIBILITIES,
        "ATLAS_TEXTURES": (1,),
    },
    "primary": (
        {
            "SHADOW_LIGHTS": (0, 1),
            "ENVIRONMENT": ENVIRONMENTS,
            "TEXTURES": (0, 1),
            "LIGHT_VISIBILITY": LIGHT_VISIBILITIES,
            "BIDIRECTIONAL": (0, 1),
            "ATLAS_TEXTURES": ATLAS_TEXTURES,
            "GLOSSY": (0, 1),
        },
        lambda d: (d["SHADOW_LIGHTS"] or not d["BIDIRECTIONAL"]) and atlas_possible(d),
    ),
    "eye_paths": (
        {
            "SHADOW_LIGHTS": (0, 1),
            "LAZY_LIGHTING": (0, 1),
            "EMITTER_SAMPLES": (0, 1),
            "ENVIRONMENT": ENVIRONMENTS,
            "ENVIRONMENT_SAMPLES": (0, 1),
            "NODE_SIDES": (1, 2),
            "TEXTURES": (0, 1),
            "NODE_REFERENCE": NODE_REFERENCES,
            "LIGHT_VISIBILITY": LIGHT_VISIBILITIES,
            "BIDIRECTIONAL": (0, 1),
            "ATLAS_TEXTURES": ATLAS_TEXTURES,
            "GLOSSY": (0, 1),
        },
        # Precomputed light (shadow-mapped lights, not lazy) is splat points' only; environment
        # samples are drawn from a map, for eye paths only.
        lambda d: (
            (not d["SHADOW_LIGHTS"] or d["LAZY_LIGHTING"] or d["NODE_REFERENCE"] == NODE_SPLAT_POINT)
            and (not d["ENVIRONMENT_SAMPLES"] or (d["ENVIRONMENT"] == ENVMAP and not d["BIDIRECTIONAL"]))
            and atlas_possible(d)
            # Glossy materials are lit where each path lands: irradiance holds no direction.
            and (not d["GLOSSY"] or not d["SHADOW_LIGHTS"] or d["LAZY_LIGHTING"])
        ),
    ),
    "light_paths": {
        "BIDIRECTIONAL": (1,),
        "TEXTURES": (0, 1),
        "NODE_SIDES": (1, 2),
        "NODE_REFERENCE": NODE_REFERENCES,
        "LIGHT_VISIBILITY": LIGHT_VISIBILITIES,
        "ENVIRONMENT": ENVIRONMENTS,
        "ATLAS_TEXTURES": ATLAS_TEXTURES,
        "GLOSSY": (0, 1),
    },
    "resolve_images": [{}],
    "record_strides": {"RECORD_GROUP": (0, 1, 2, 3, 4, 5)},
}


def _expand(spec) -> list[dict]:
    if isinstance(spec, list):
        return spec
    axes, possible = spec if isinstance(spec, tuple) else (spec, lambda d: True)
    combos = [dict(zip(axes, values)) for values in itertools.product(*axes.values())]
    return [c for c in combos if all(not c.get(a) or c.get(b, 1) for a, b in REQUIRES.items()) and possible(c)]


# Program name -> every set of defines the code compiles it with.
SHADER_VARIANTS = {name: _expand(spec) for name, spec in VARIANTS.items()}
# (program, defines) of every program compiled in this process.
COMPILED: set[tuple[str, tuple]] = set()


def variant_key(name: str, defines: dict) -> tuple[str, tuple]:
    return name, tuple(sorted((k, int(v) if isinstance(v, bool) else v) for k, v in defines.items()))


def unlisted_variants() -> list[tuple[str, tuple]]:
    """Variants this process compiled that `SHADER_VARIANTS` does not list."""
    listed = {variant_key(name, d) for name, variants in SHADER_VARIANTS.items() for d in variants}
    return sorted(COMPILED - listed)


def is_program(text: str) -> bool:
    """Program files define main(); the others are includes (``#include "common.glsl"``)."""
    return re.search(r"^\s*void\s+main\s*\(", text, re.M) is not None


def shader_stages(text: str) -> list[str]:
    """The stages a .glsl file defines, from its ``#if defined X_SHADER`` guards."""
    return [s for s in STAGES if re.search(rf"^\s*#\s*(el)?if\s+defined\s*\(?\s*{s}\b", text, re.M)]


INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$', re.M)


def expand_includes(text: str, within: tuple[str, ...] = ()) -> str:
    """``text`` with every ``#include "file.glsl"`` line replaced by that file's text, its own
    includes expanded too (the preprocessor then keeps or drops it with the ``#if`` around it)."""

    def include(match) -> str:
        name = match.group(1)
        if name in within:
            raise ValueError(f"shaders/{name} includes itself through {' -> '.join(within)}")
        path = INCLUDE_DIR / name
        if not path.is_file():
            raise ValueError(f"shaders/{within[-1] if within else '?'}: no include file shaders/include/{name}")
        return expand_includes(path.read_text(), (*within, name))

    return INCLUDE.sub(include, text)


@functools.cache
def program_files() -> dict[str, Path]:
    """Every program file, by name (its stem), from the folders beside include/ (found once: the
    files do not move while the process runs)."""
    files: dict[str, Path] = {}
    for path in sorted(SHADER_DIR.glob("*/*.glsl")):
        if path.parent != INCLUDE_DIR:
            if path.stem in files:
                raise ValueError(f"{path}: a second program named {path.stem} (the first: {files[path.stem]})")
            files[path.stem] = path
    return files


def program_path(name: str) -> Path:
    """The file of program ``name``."""
    path = program_files().get(name)
    if path is None:
        hint = " (an include file, not a program)" if (INCLUDE_DIR / f"{name}.glsl").is_file() else ""
        raise ValueError(f"no shader program {name} in {SHADER_DIR}/*/{hint}")
    return path


def program_sources(name: str, defines: dict) -> dict[str, str]:
    """The stages of program ``name`` (moderngl's keyword per stage), each with its header and its
    includes expanded."""
    path = program_path(name)
    text = path.read_text()
    stages = shader_stages(text)  # the program's own guards: its includes have theirs
    if not is_program(text) or not stages:
        raise ValueError(f"{path}: no main() under a stage guard; programs have one, include files none")
    text = expand_includes(text, (f"{name}.glsl",))
    return {STAGES[s]: with_header(text, s, defines) for s in stages}


def with_header(text: str, stage: str, defines: dict) -> str:
    lines = ["#version 450 core", f"#define {stage}"]
    lines += [f"#define BINDING_{name} {index}" for name, index in BINDINGS.items()]
    lines += [f"#define {name} {glsl_literal(value)}" for name, value in SHADER_CONSTANTS.items()]
    lines += [f"#define {k} {int(v) if isinstance(v, bool) else v}" for k, v in sorted(defines.items())]
    return "\n".join(lines) + "\n#line 1\n" + text
