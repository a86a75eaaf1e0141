"""The page rendered by Jinja2 templates (``templates/``), its inline Markdown by markdown-it-py: HTML
(inline CSS, no script) beside its images and table files, the same page as one portable file
(images and tables inline as data URIs), and Markdown."""
from __future__ import annotations

import base64
import csv
import io
from pathlib import Path

from jinja2 import Environment, PackageLoader
from markdown_it import MarkdownIt
from markupsafe import Markup

from deapull.workflows.report.document import Report


_MD = MarkdownIt("commonmark", {"html": False})


def inline_html(text) -> Markup:
    """``text`` as inline Markdown (`code`, [link](href), **bold**) rendered to HTML, raw HTML escaped."""
    return Markup(_MD.renderInline(str(text)))


def _md_cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


_ENV = {autoescape: Environment(loader=PackageLoader("deapull.workflows.report", "templates"),
                                autoescape=autoescape, keep_trailing_newline=True)
        for autoescape in (True, False)}
_ENV[True].filters["md"] = inline_html
_ENV[False].filters["cell"] = _md_cell


CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;max-width:1200px;margin:0 auto;
padding:0 1.2em 3em;
color:#1d1d1f;line-height:1.45}
h1{margin-top:.6em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0 1.2em;font-size:.86em;display:block;overflow-x:auto}
th,td{border:1px solid #ccc;padding:.25em .5em;text-align:right;white-space:nowrap}
th{background:#f2f2f5}td:first-child,th:first-child{text-align:left}
tr:target{background:#fff3b0}caption{caption-side:top;text-align:left;font-weight:600;padding:.3em 0}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}figcaption{font-size:.88em;color:#444}
.missing{background:#fff4f0;border-left:4px solid #d9534f;padding:.5em .8em;margin:.8em 0}
code{background:#f4f4f6;padding:0 .25em;border-radius:3px}nav ol{columns:2}
table.wrap td,table.wrap th{white-space:normal;text-align:left}
.data{font-size:.8em;margin:-.9em 0 1.2em}
p,li,figcaption,.missing{overflow-wrap:anywhere}
@media (max-width:600px){body{padding:0 .6em 2em}nav ol{columns:1}table{font-size:.8em}}
"""

MIME = {".png": "image/png", ".gif": "image/gif", ".svg": "image/svg+xml", ".jpg": "image/jpeg"}


def table_csv(table) -> str:
    """A table's headers and rows as CSV text (the cells as shown)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([str(h) for h in table.headers])
    writer.writerows([[str(c) for c in row] for row in table.rows])
    return buf.getvalue()


def table_files(report: Report) -> dict:
    """{id(table): file name under ``tables/``} for every table of the page: section id and position."""
    names = {}
    for s in report.sections:
        tables = [b[1] for b in s.blocks if b[0] == "table"]
        for k, t in enumerate(tables, 1):
            names[id(t)] = f"{s.id}-{k}.csv"
    return names


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode()}"


def _view(report: Report, standalone: bool) -> list[dict]:
    """The sections as the templates read them: every block a dict, every link resolved."""
    files = table_files(report)
    sections = []
    for s in report.sections:
        blocks = []
        for block in s.blocks:
            kind = block[0]
            if kind == "p":
                blocks.append({"kind": kind, "text": block[1]})
            elif kind == "ul":
                blocks.append({"kind": kind, "entries": block[1]})
            elif kind == "img":
                src = block[1]
                if standalone:
                    path = report.out / src
                    src = _data_uri(path.read_bytes(), MIME.get(path.suffix.lower(), "application/octet-stream"))
                blocks.append({"kind": kind, "src": src, "caption": block[2]})
            elif kind == "data":
                _, name, text, label = block
                href = _data_uri(text.encode(), "text/csv") if standalone else f"tables/{name}"
                blocks.append({"kind": kind, "name": name, "href": href, "label": label})
            elif kind == "missing":
                _, what, step = block
                make, command = step.hint(report.inputs)
                blocks.append({"kind": kind, "what": what, "make": make, "command": command})
            elif kind == "table":
                t, name = block[1], files[id(block[1])]
                rows = [{"id": t.anchors[i] if t.anchors else None, "cells": row} for i, row in enumerate(t.rows)]
                href = _data_uri(table_csv(t).encode(), "text/csv") if standalone else f"tables/{name}"
                blocks.append({"kind": kind, "table": t, "rows": rows, "name": name, "href": href})
        sources = [{"path": str(p), "anchor": report.sources[Path(p).resolve()]["anchor"]} for p in s.sources]
        sections.append({"id": s.id, "title": s.title, "blocks": blocks, "sources": sources})
    return sections


def render_html(report: Report, title: str, lead: list[str], standalone: bool = False) -> str:
    """The page as HTML (templates/page.html.j2). ``standalone``: one portable file, every image and
    table file inline as a data URI (opens from anywhere, with no file beside it); otherwise they are
    files beside it (``img/``, ``tables/``)."""
    return _ENV[True].get_template("page.html.j2").render(
        title=title, lead=lead, css=Markup(CSS), sections=_view(report, standalone))


def render_markdown(report: Report, title: str, lead: list[str]) -> str:
    """The page as Markdown (templates/page.md.j2), its images and tables as files beside it."""
    return _ENV[False].get_template("page.md.j2").render(title=title, lead=lead,
                                                          sections=_view(report, standalone=False))
