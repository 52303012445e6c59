"""MkDocs hooks (mkdocs.yml): the reference pages generated from the code (evalkit/reference_docs.py)
are added to the site at build time, never written into the checkout."""

from __future__ import annotations

from mkdocs.structure.files import File

from evalkit.reference_docs import cli_markdown, settings_markdown

GENERATED = {"reference/cli.md": cli_markdown, "reference/settings.md": settings_markdown}


def on_files(files, config):
    for path, make in GENERATED.items():
        files.append(File.generated(config, path, content=make()))
    return files
