"""The page rendered: HTML (inline CSS, no script) beside its images and table files, the same
page as one portable file (images and tables inline as data URIs), and Markdown."""
from __future__ import annotations

import base64
import csv
import html
import io
import re
from pathlib import Path

from deapull.workflows.report.document import Report


_INLINE = re.compile(r"`([^`]+)`|\[([^\]]+)\]\(([^)\s]+)\)|\*\*([^*]+)\*\*")


def inline_html(text: str) -> str:
    """Escape ``text`` and turn its `code`, [link](href) and **bold** into HTML."""
    out, pos = [], 0
    for m in _INLINE.finditer(text):
        out.append(html.escape(text[pos:m.start()]))
        if m.group(1) is not None:
            out.append(f"<code>{html.escape(m.group(1))}</code>")
        elif m.group(2) is not None:
            out.append(f'<a href="{html.escape(m.group(3), quote=True)}">{inline_html(m.group(2))}</a>')
        else:
            out.append(f"<strong>{html.escape(m.group(4))}</strong>")
        pos = m.end()
    out.append(html.escape(text[pos:]))
    return "".join(out)


def _md_cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


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


def render_html(report: Report, title: str, lead: list[str], standalone: bool = False) -> str:
    """The page as HTML. ``standalone``: one portable file, every image and table file inline as a
    data URI (opens from anywhere, with no file beside it); otherwise they are files beside it
    (``img/``, ``tables/``)."""
    files = table_files(report)
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>"]
    parts += [f"<p>{inline_html(t)}</p>" for t in lead]
    parts.append("<nav><ol>" + "".join(f'<li><a href="#{s.id}">{html.escape(s.title)}</a></li>'
                                       for s in report.sections) + "</ol></nav>")
    for s in report.sections:
        parts.append(f'<section id="{s.id}"><h2>{html.escape(s.title)}</h2>')
        for block in s.blocks:
            kind = block[0]
            if kind == "p":
                parts.append(f"<p>{inline_html(block[1])}</p>")
            elif kind == "ul":
                parts.append("<ul>" + "".join(f"<li>{inline_html(i)}</li>" for i in block[1]) + "</ul>")
            elif kind == "img":
                src = block[1]
                if standalone:
                    path = report.out / src
                    src = _data_uri(path.read_bytes(), MIME.get(path.suffix.lower(), "application/octet-stream"))
                src, alt = html.escape(src, quote=True), html.escape(block[2], quote=True)
                parts.append(f'<figure><img src="{src}" alt="{alt}">'
                             f"<figcaption>{inline_html(block[2])}</figcaption></figure>")
            elif kind == "data":
                _, name, text, label = block
                href = _data_uri(text.encode(), "text/csv") if standalone else f"tables/{name}"
                parts.append(f'<p class="data"><a href="{html.escape(href, quote=True)}" download="{name}">'
                             f"{inline_html(label)}</a></p>")
            elif kind == "missing":
                _, what, step = block
                make, command = step.hint(report.inputs)
                parts.append(f'<div class="missing"><strong>Missing:</strong> {inline_html(what)}. Make it with '
                             f"<code>{html.escape(make)}</code> (runs <code>{html.escape(command)}</code>)."
                             "</div>")
            elif kind == "table":
                t = block[1]
                cap = f"<caption>{inline_html(t.caption)}</caption>" if t.caption else ""
                head = "".join(f"<th>{inline_html(str(h))}</th>" for h in t.headers)
                rows = []
                for i, row in enumerate(t.rows):
                    rid = t.anchors[i] if t.anchors else None
                    attr = f' id="{rid}"' if rid else ""
                    rows.append(f"<tr{attr}>" + "".join(f"<td>{inline_html(str(c))}</td>" for c in row) + "</tr>")
                cls = ' class="wrap"' if t.wrap else ""
                parts.append(f"<table{cls}>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>")
                name = files[id(t)]
                href = _data_uri(table_csv(t).encode(), "text/csv") if standalone else f"tables/{name}"
                parts.append(f'<p class="data"><a href="{html.escape(href, quote=True)}" download="{name}">'
                             f"CSV of this table</a></p>")
        if s.sources:
            links = ", ".join(f'<a href="#{report.sources[Path(p).resolve()]["anchor"]}"><code>{html.escape(str(p))}'
                              "</code></a>" for p in s.sources)
            parts.append(f"<p><small>Sources: {links}</small></p>")
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def render_markdown(report: Report, title: str, lead: list[str]) -> str:
    lines = [f"# {title}", ""]
    for t in lead:
        lines += [t, ""]
    lines += [f"{i + 1}. [{s.title}](#{s.id})" for i, s in enumerate(report.sections)] + [""]
    for s in report.sections:
        lines += [f'<a id="{s.id}"></a>', "", f"## {s.title}", ""]
        for block in s.blocks:
            kind = block[0]
            if kind == "p":
                lines += [block[1], ""]
            elif kind == "ul":
                lines += [f"* {i}" for i in block[1]] + [""]
            elif kind == "img":
                lines += [f"![{block[2]}]({block[1]})", "", f"*{block[2]}*", ""]
            elif kind == "data":
                lines += [f"[{block[3]}](tables/{block[1]})", ""]
            elif kind == "missing":
                _, what, step = block
                make, command = step.hint(report.inputs)
                lines += [f"> **Missing:** {what}. Make it with `{make}` (runs `{command}`).", ""]
            elif kind == "table":
                t = block[1]
                if t.caption:
                    lines += [f"**{t.caption}**", ""]
                lines.append("| " + " | ".join(_md_cell(h) for h in t.headers) + " |")
                lines.append("|" + "---|" * len(t.headers))
                for i, row in enumerate(t.rows):
                    rid = t.anchors[i] if t.anchors else None
                    cells = [_md_cell(c) for c in row]
                    if rid:
                        cells[0] = f'<a id="{rid}"></a>{cells[0]}'
                    lines.append("| " + " | ".join(cells) + " |")
                lines.append("")
        if s.sources:
            lines += ["<small>Sources: " + ", ".join(f"[`{p}`](#{report.sources[Path(p).resolve()]['anchor']})"
                                                    for p in s.sources) + "</small>", ""]
    return "\n".join(lines)

