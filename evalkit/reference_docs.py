"""The documentation site's reference pages, generated from the code itself so they cannot drift:
the command line from `evalkit.cli.build_parser`, and every declared setting and registered unit
from `RenderSettings` and `gpu_impl.registry` (docs/hooks.py puts them in the site)."""

from __future__ import annotations

import argparse
import dataclasses

from evalkit.cli import build_parser
from evalkit.core.scene.builtin import BUILTIN_SCENES
from evalkit.core.settings import RenderSettings, declared
from gpu_impl.registry import KINDS


def commands(
    parser: argparse.ArgumentParser | None = None, prefix: str = "evalkit"
) -> list[tuple[str, argparse.ArgumentParser]]:
    """Every command (``evalkit scene info`` ...) with its parser, depth first."""
    parser = parser or build_parser()
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                subcommands = commands(sub, f"{prefix} {name}")
                found += subcommands or [(f"{prefix} {name}", sub)]
    return found


def _helps(parser: argparse.ArgumentParser) -> dict[str, str]:
    """The one-line help of each subcommand of ``parser``, by name."""
    helps = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps.update({a.dest: a.help or "" for a in action._choices_actions})
    return helps


def cli_markdown() -> str:
    """The command line reference: per command, what it does, its usage and every argument."""
    root = build_parser()
    lines = [
        "# Command line",
        "",
        "Generated from the parser (`evalkit.cli.build_parser`). Bad input prints one line naming the "
        "file and the problem and exits 2; `--json` ends the output with one JSON object.",
        "",
        "`SCENE` is a built-in scene, "
        + ", ".join(f"`{name}`" for name in BUILTIN_SCENES)
        + " (`evalkit/core/scene/builtin.py` says what each is for), or a path to a Mitsuba XML, OBJ, PLY, "
        "glTF or GLB file ([scenes and importers](scenes.md)).",
        "",
    ]
    for name, parser in commands(root):
        words = name.split()
        help_text = _helps(_parser_at(root, words[1:-1])).get(words[-1], "")
        lines += [f"## `{name}`", "", help_text, "", "```", parser.format_usage().strip(), "```", ""]
        rows = []
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            flag = ", ".join(f"`{o}`" for o in action.option_strings) or f"`{action.dest}`"
            default = "" if action.default in (None, argparse.SUPPRESS, False) else f"`{action.default}`"
            rows.append(f"| {flag} | {default} | {_cell(action.help or '')} |")
        if rows:
            lines += ["| argument | default | meaning |", "|---|---|---|", *rows, ""]
    return "\n".join(lines)


def _parser_at(root: argparse.ArgumentParser, words: list[str]) -> argparse.ArgumentParser:
    parser = root
    for word in words:
        parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[word]
    return parser


def settings_markdown() -> str:
    """Every declared setting: `RenderSettings`' own, then each registered unit's, with its default,
    range and meaning."""
    lines = [
        "# Settings and units",
        "",
        "Generated from the declarations (`evalkit.core.settings.setting`) and the registries "
        "(`gpu_impl.registry`). A unit's settings are flags of `evalkit render` and parameters of "
        "study files; a setting given to a unit the render does not use is a warning.",
        "",
        "## Render settings (`RenderSettings`)",
        "",
        *_settings_table(RenderSettings),
    ]
    for kind, registry in KINDS.items():
        lines += [f"## {registry.kind.capitalize()}s (`{kind}`)", ""]
        for unit in registry:
            lines += [f"### `{unit.name}`", "", unit.summary, ""]
            lines += _settings_table(unit.settings) if declared(unit.settings) else ["No settings of its own.", ""]
    return "\n".join(lines)


def _settings_table(settings_type) -> list[str]:
    rows = ["| setting | default | range | meaning |", "|---|---|---|---|"]
    for f in declared(settings_type):
        m = f.metadata
        default = f.default if f.default is not dataclasses.MISSING else None
        if m["choices"]:
            allowed = " / ".join(f"`{c}`" for c in m["choices"])
        elif m["positive"]:
            allowed = "> 0"
        elif m["minimum"] is not None:
            allowed = f">= {m['minimum']:g}"
        else:
            allowed = ""
        unit = f" {m['unit']}" if m["unit"] else ""
        rows.append(f"| `{f.name}` | `{default}`{unit} | {allowed} | {_cell(m['help'])} |")
    return [*rows, ""]


def _cell(text: str) -> str:
    return text.replace("%%", "%").replace("|", "\\|").replace("\n", " ")
