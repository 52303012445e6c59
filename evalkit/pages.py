"""The HTML pages the toolkit writes (study reports, tune reports): one page writer with one style,
and the tables in them."""

from __future__ import annotations

import html
import math

from evalkit import viewer

STYLE = (
    "body{font-family:sans-serif;max-width:1400px;margin:2em auto}table{border-collapse:collapse;font-size:12px}"
    "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}figure{display:inline-block;margin:4px}"
    "figure img{width:192px;image-rendering:pixelated}figcaption{font-size:11px}"
)


def page(title: str, parts: list[str]) -> str:
    """A whole HTML page: ``title`` and the body ``parts`` (HTML) in order; with the image viewer's
    style and script (evalkit/viewer) when a part has a viewer."""
    head = f"<meta charset='utf-8'><title>{html.escape(title)}</title><style>{STYLE}</style>"
    if any("class='ek-viewer'" in part for part in parts):
        head += viewer.head()
    if any("class='ek-table" in part for part in parts):
        head += f"<script>{(viewer.ASSETS / 'table.js').read_text()}</script>"
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


def results_table_html(rows: list[dict], groups: dict[str, list[str]], collapsed: tuple[str, ...] = ()) -> str:
    """A results table whose columns come in named groups (``groups``: name -> columns, in order):
    sortable by a click on a column's name, each group hidden or shown by a click on its name
    (evalkit/viewer/table.js), the groups in ``collapsed`` hidden at first. A value a row does not
    have (a setting that does not apply to its method) is left empty."""
    groups = {name: cols for name, cols in groups.items() if cols}
    classes = " ".join(f"ek-hide-{i}" for i, name in enumerate(groups) if name in collapsed)
    styles = "".join(
        f"table.ek-hide-{i} .ek-g{i}{{display:none}}table.ek-hide-{i} .ek-p{i}{{display:table-cell}}"
        for i in range(len(groups))
    )
    top, names, cells = [], [], [[] for _ in rows]
    for i, (name, cols) in enumerate(groups.items()):
        span = 1 if name in collapsed else len(cols)
        top.append(f"<th data-group='{i}' data-span='{len(cols)}' colspan='{span}'>{html.escape(name)}</th>")
        names += [f"<th class='ek-g{i}'>{html.escape(c)}</th>" for c in cols] + [f"<th class='ek-p{i}'>...</th>"]
        for row, out in zip(rows, cells):
            out += [
                f"<td class='ek-g{i}'>{'' if c not in row else html.escape(format_value(row[c]))}</td>" for c in cols
            ]
            out.append(f"<td class='ek-p{i}'></td>")
    body = "".join(f"<tr>{''.join(c)}</tr>" for c in cells)
    return (
        f"<style>.ek-wrap{{max-height:80vh;overflow:auto}}.ek-table th{{cursor:pointer;position:sticky}}"
        f".ek-groups th{{top:0;background:#dde}}.ek-columns th{{top:1.5em;background:#eef}}"
        f"[class^=ek-p]{{display:none}}{styles}</style>"
        f"<div class='ek-wrap'><table class='ek-table {classes}'><thead><tr class='ek-groups'>{''.join(top)}</tr>"
        f"<tr class='ek-columns'>{''.join(names)}</tr></thead><tbody>{body}</tbody></table></div>"
    )
