"""Self-contained HTML pages: inline CSS, inline SVG, no script and no external address."""

from __future__ import annotations

import html
import math
import re
from collections.abc import Iterable, Sequence
from datetime import datetime
from pathlib import Path

from catenary.text import printable

__all__ = [
    "Cell",
    "contents",
    "escape",
    "facts",
    "heading",
    "note",
    "number",
    "page",
    "section",
    "stamp",
    "table",
    "tag",
    "write_text",
]


def escape(text: str) -> str:
    """``text`` for HTML: its control characters escaped as on the terminal
    (``catenary.text.printable``: a name stored before they were refused), then ``&``, ``<``,
    ``>`` and quotes."""
    return html.escape(printable(text))


CSS = """
:root { --ink: #1d2430; --muted: #5b6675; --line: #d5dae1; --band: #f4f6f9; }
* { box-sizing: border-box; }
body { margin: 0; font: 14px/1.45 "DejaVu Sans", "Liberation Sans", Arial, sans-serif;
       color: var(--ink); background: #fff; }
header { background: #1f3a5f; color: #fff; padding: 18px 28px 14px; }
header h1 { margin: 0 0 4px; font-size: 22px; font-weight: 600; }
header p { margin: 0; color: #c9d6e8; }
main { padding: 8px 24px 40px; max-width: 1320px; }
h2 { font-size: 17px; margin: 26px 0 8px; padding-bottom: 4px; border-bottom: 2px solid #1f3a5f; }
h3 { font-size: 15px; margin: 18px 0 6px; }
p.note, figcaption { color: var(--muted); font-size: 12.5px; margin: 4px 0 10px; }
table { border-collapse: collapse; margin: 4px 0 12px; font-size: 12.5px; }
th, td { border: 1px solid var(--line); padding: 3px 6px; vertical-align: top; }
td.k { white-space: nowrap; }
td.w { min-width: 16em; }
th { background: var(--band); text-align: left; font-weight: 600; white-space: nowrap; }
td.n { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
table.facts th { width: 13em; }
tr.plan td { background: #fff7d6; }
tr.urgent td { background: #ffe3c4; }
tr.critical td { background: #ffd0cc; }
span.tag { display: inline-block; padding: 0 6px; border-radius: 3px; font-size: 11.5px;
           font-weight: 600; color: #fff; background: #5b6675; }
span.tag.plan { background: #a07c00; } span.tag.urgent { background: #c2570c; }
span.tag.critical { background: #b3261e; }
figure { margin: 8px 0 18px; }
figure svg { width: 100%; height: auto; max-width: 1240px; display: block; }
figure.narrow svg { max-width: 800px; }
ul.counts { list-style: none; padding: 0; display: flex; gap: 12px; margin: 8px 0; }
ul.counts li { border: 1px solid var(--line); border-radius: 4px; padding: 6px 14px;
               background: var(--band); }
ul.counts b { font-size: 18px; display: block; }
ul.counts li.plan { background: #fff7d6; } ul.counts li.urgent { background: #ffe3c4; }
ul.counts li.critical { background: #ffd0cc; }
nav.contents { margin: 14px 0 4px; font-size: 13px; }
nav.contents h2 { border: none; margin: 0 0 4px; }
nav.contents ol { margin: 0; padding-left: 22px; } nav.contents ol ol { columns: 2; }
@page { margin: 14mm 12mm; }
@media print {
  nav.contents { display: none; }
  header { background: none; color: var(--ink); padding: 0 0 6px; }
  header p { color: var(--muted); }
  main { padding: 0; max-width: none; }
  main > section + section { break-before: page; }
  h2, h3 { break-after: avoid; }
  figure, table.facts, tr { break-inside: avoid; }
  thead { display: table-header-group; }
  tr.plan td, tr.urgent td, tr.critical td, span.tag { print-color-adjust: exact; }
}
"""
"""On screen a page; in print (``@media print``) each section after the first starts a new
page, a figure or a table row is never split across pages, a table's header repeats on each
page and the table of contents (a screen's navigation) is left out."""


class Cell:
    """A table cell: text (escaped), right-aligned and on one line when ``numeric``, on one
    line when ``keep`` (codes, dates), at least 16 em wide when ``wide`` (long text);
    ``markup`` is trusted HTML instead of text."""

    def __init__(
        self,
        text: str = "",
        *,
        numeric: bool = False,
        keep: bool = False,
        wide: bool = False,
        markup: str | None = None,
    ):
        self.html = markup if markup is not None else escape(text)
        self.css = "n" if numeric else "k" if keep else "w" if wide else ""


def number(value: float | None, decimals: int = 2) -> Cell:
    """A numeric cell; an empty one for None or NaN."""
    if value is None or not math.isfinite(value):
        return Cell("", numeric=True)
    return Cell(f"{value:.{decimals}f}", numeric=True)


def stamp(moment: datetime | None) -> str:
    """A UTC time as ``YYYY-MM-DD HH:MM UTC`` (empty for None)."""
    return "" if moment is None else moment.strftime("%Y-%m-%d %H:%M UTC")


def tag(level: str) -> str:
    """A coloured badge for an alert level."""
    return f'<span class="tag {escape(level)}">{escape(level)}</span>'


def table(
    headers: Sequence[str],
    rows: Iterable[Sequence[Cell | str]],
    *,
    row_classes: Iterable[str] | None = None,
    table_id: str | None = None,
    empty: str = "none",
) -> str:
    """A table of ``rows`` (cells or plain text) under ``headers``; ``empty`` without rows."""
    classes = iter(row_classes) if row_classes is not None else None
    body = []
    for row in rows:
        css = next(classes, "") if classes is not None else ""
        cells = []
        for cell in row:
            c = cell if isinstance(cell, Cell) else Cell(cell)
            cells.append(f'<td class="{c.css}">{c.html}</td>' if c.css else f"<td>{c.html}</td>")
        attribute = f' class="{escape(css)}"' if css else ""
        body.append(f"<tr{attribute}>{''.join(cells)}</tr>")
    if not body:
        return f'<p class="note">{escape(empty)}</p>'
    ident = f' id="{escape(table_id)}"' if table_id else ""
    head = "".join(f"<th>{escape(h)}</th>" for h in headers)
    return f"<table{ident}><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def facts(pairs: Iterable[tuple[str, str]], table_id: str = "facts") -> str:
    """A two-column table of labelled facts (plain text)."""
    rows = "".join(f"<tr><th>{escape(k)}</th><td>{escape(v)}</td></tr>" for k, v in pairs)
    return f'<table class="facts" id="{escape(table_id)}"><tbody>{rows}</tbody></table>'


def section(title: str, *parts: str, section_id: str | None = None) -> str:
    """A titled section of already-built HTML parts."""
    ident = f' id="{escape(section_id)}"' if section_id else ""
    return f"<section{ident}><h2>{escape(title)}</h2>{''.join(parts)}</section>"


_HEADING = re.compile(r'<section id="([^"]+)"><h2>(.*?)</h2>|<h3 id="([^"]+)">(.*?)</h3>')
"""A section's id and title, or a heading's within it, as ``section`` and ``heading`` write
them (already escaped)."""


def heading(title: str, heading_id: str) -> str:
    """A heading within a section, listed under it in the table of contents."""
    return f'<h3 id="{escape(heading_id)}">{escape(title)}</h3>'


def contents(sections: Iterable[str]) -> str:
    """The table of contents of ``sections`` (built by ``section``, with an id): a link to
    each, and under it to each of its ``heading``s."""
    items: list[str] = []
    for part in sections:
        entries = _HEADING.findall(part)
        links = [f'<a href="#{i or j}">{t or u}</a>' for i, t, j, u in entries]
        if not links or not entries[0][0]:
            continue
        below = "".join(f"<li>{link}</li>" for link in links[1:])
        items.append(f"<li>{links[0]}{f'<ol>{below}</ol>' if below else ''}</li>")
    return f'<nav class="contents" id="contents"><h2>Contents</h2><ol>{"".join(items)}</ol></nav>'


def note(text: str) -> str:
    return f'<p class="note">{escape(text)}</p>'


def page(title: str, subtitle: str, sections: Iterable[str], *, toc: bool = False) -> str:
    """The whole document; ``toc``: a table of contents before the sections."""
    sections = list(sections)
    nav = contents(sections) if toc else ""
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{escape(title)}</title><style>{CSS}</style></head>"
        f"<body><header><h1>{escape(title)}</h1><p>{escape(subtitle)}</p></header>"
        f"<main>{nav}{''.join(sections)}</main></body></html>\n"
    )


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file beside it, renamed at the end."""
    partial = path.with_name(f".{path.name}.partial")
    try:
        partial.write_text(text, encoding="utf-8")
        partial.replace(path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return path
