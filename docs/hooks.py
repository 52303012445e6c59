"""MkDocs hooks (mkdocs.yml): the reference pages generated from the code (evalkit/reference_docs.py),
the results pages generated from the committed data files in docs/results/data/
(evalkit/results_docs.py), with the design decisions and their measurements
(docs/results/decisions.toml) and the tutorials, notebooks run at build time (evalkit/notebooks.py),
are added to the site at build time, never written into the checkout."""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File

from evalkit.notebooks import notebook_markdown
from evalkit.reference_docs import cli_markdown, outputs_markdown, settings_markdown
from evalkit.results_docs import decisions_markdown, read_decisions, results_pages

GENERATED = {"reference/cli.md": cli_markdown, "reference/settings.md": settings_markdown}
TUTORIALS = {  # page: notebook in docs/
    "tutorials/quick_start.md": "quick_start.ipynb",
    "tutorials/bundles.md": "bundles_tutorial.ipynb",
    "tutorials/poster_question.md": "poster_question.ipynb",
    "tutorials/ci.md": "ci_tutorial.ipynb",
}


def on_files(files, config):
    for path, make in GENERATED.items():
        files.append(File.generated(config, path, content=make()))
    docs = Path(config["docs_dir"])
    data = docs / "results" / "data"
    files.append(File.generated(config, "reference/outputs.md", content=outputs_markdown(data)))
    for page, notebook in TUTORIALS.items():
        files.append(File.generated(config, page, content=notebook_markdown(docs / notebook, docs.parent)))
    for path, content in results_pages(data, docs).items():
        files.append(File.generated(config, path, content=content))
    decisions = docs / "results" / "decisions.toml"
    page = decisions_markdown(read_decisions(decisions), decisions.relative_to(docs.parent).as_posix())
    files.append(File.generated(config, "results/decisions.md", content=page))
    return files
