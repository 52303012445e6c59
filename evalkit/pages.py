"""The HTML pages the toolkit writes (study reports, tune reports): one page writer with one style,
and the tables in them."""

from __future__ import annotations

import html
import math

STYLE = (
    "body{font-family:sans-serif;max-width:1400px;margin:2em auto}table{border-collapse:collapse;font-size:12px}"
    "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}figure{display:inline-block;margin:4px}"
    "figure img{width:192px;image-rendering:pixelated}figcaption{font-size:11px}"
)


def page(title: str, parts: list[str]) -> str:
    """A whole HTML page: ``title`` and the body ``parts`` (HTML) in order."""
    head = f"<meta charset='utf-8'><title>{html.escape(title)}</title><style>{STYLE}</style>"
    return f"<!doctype html><html><head>{head}</head><body>{''.join(parts)}</body></html>\n"


def is_number(v) -> bool:
    """A finite int or float (not a bool): a value a table or plot can use."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def format_value(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if value == 0 or math.isnan(value):
            return f"{value:g}"
        return f"{value:.4g}" if 1e-3 <= abs(value) < 1e5 else f"{value:.3e}"
    return str(value)


def table_html(rows: list[dict], columns: list[str]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    cells = (
        "<tr>" + "".join(f"<td>{html.escape(format_value(r.get(c)))}</td>" for c in columns) + "</tr>" for r in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(cells)}</tbody></table>"
