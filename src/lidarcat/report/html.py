"""The Markdown subset of the pipeline report as self-contained HTML.

Headings, tables, paragraphs, list items, ``[links](url)``, ``**bold**`` and
figure lines ``![caption](path.png)``; a figure whose file exists (relative to
*base*) is embedded as a base64 PNG, so ``index.html`` shows the figures of
every run without external files.  Kept as a small module instead of a Markdown
library: the report uses only these constructs, and they do not earn a new
runtime dependency (the per-run reports use :mod:`lidarcat.report.document`'s own
renderer).
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

__all__ = ["markdown_to_html"]


_FIGURE = re.compile(r"^!\[([^\]]*)\]\(([^)]+)\)$")


def markdown_to_html(md: str, title: str, base: Path | None = None) -> str:
    """*md* (the subset above) as one HTML page; figure paths are relative to *base*."""
    def inline(text: str) -> str:
        text = re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r"<a href='\2'>\1</a>", html.escape(text, quote=False))
        return re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)

    def figure(caption: str, src: str) -> str:
        path = base / src if base is not None else None
        if path is not None and path.is_file() and path.suffix.lower() == ".png":
            src = "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")
        return (f"<figure><img style='max-width:100%' alt='{html.escape(caption)}' src='{html.escape(src)}'>"
                f"<figcaption>{html.escape(caption)}</figcaption></figure>")

    out = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           "<style>body{font-family:sans-serif;max-width:60em;margin:2em auto}"
           "table{border-collapse:collapse}td,th{border:1px solid #999;padding:2px 8px}</style>",
           "</head><body>"]
    in_table = False
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-"):
                continue
            if not in_table:
                out.append("<table>")
                in_table = True
                out.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in cells) + "</tr>")
            else:
                out.append("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in cells) + "</tr>")
            continue
        if in_table:
            out.append("</table>")
            in_table = False
        if line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            out.append(f"<h{level}>{html.escape(line[level:].strip())}</h{level}>")
        elif _FIGURE.match(line):
            out.append(figure(*_FIGURE.match(line).groups()))
        elif line.startswith("- "):
            out.append(f"<ul><li>{inline(line[2:])}</li></ul>")
        elif line.strip():
            out.append(f"<p>{inline(line)}</p>")
    if in_table:
        out.append("</table>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"
