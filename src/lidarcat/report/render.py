"""The one report renderer: a :class:`~lidarcat.report.model.Document` as self-contained HTML or as Markdown.

HTML: one page with its style, a navigation bar of the level-2 sections, each
section a ``<section id=...>``; figures embedded as base64 PNG (the bytes of a
:class:`~lidarcat.report.model.Figure`, or its file when it exists next to the
page), so that the page opens offline with no external resource.  Table cells
``PASSED`` / ``FAILED`` / ``not applicable`` are coloured, long text cells
left-aligned.  Markdown: the same blocks, figures linking their PNG files.

Kept as a small module instead of a Markdown library: the reports use only
these constructs, and they do not earn a new runtime dependency.

>>> from lidarcat.report.model import Document, Paragraph, Table
>>> doc = Document("Run")
>>> doc.section("Tests", "tests").blocks += [Paragraph("All **passed**."), Table(["test", "verdict"], [["t", "PASSED"]])]
>>> print(to_markdown(doc))
# Run
<BLANKLINE>
## Tests
<BLANKLINE>
All **passed**.
<BLANKLINE>
| test | verdict |
|---|---|
| t | PASSED |
<BLANKLINE>
>>> '<td class="PASSED">PASSED</td>' in to_html(doc) and '<section id="tests"><h2>Tests</h2>' in to_html(doc)
True
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from .model import Bullets, Document, Figure, Paragraph, Section, Table, parse_markdown

__all__ = ["CSS", "to_html", "to_markdown", "markdown_to_html", "figure_files"]

#: the style sheet of every HTML report
CSS = """
body{font-family:-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #1f5fa8;padding-bottom:.2em}h2{margin-top:1.8em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.6em 0 1.2em;font-size:.86em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:right;vertical-align:top}
th{background:#eef2f7}td:first-child,th:first-child{text-align:left}
caption{caption-side:top;text-align:left;font-style:italic;padding:.2em 0;color:#444}
td.PASSED{background:#e3f4e1;color:#1d6b1d;font-weight:600}td.FAILED{background:#fbe3e1;color:#a02020;
font-weight:600}td.na{color:#888}td.t{text-align:left}p.na{color:#777;font-style:italic}p.note{font-size:.9em;color:#5a4a00;
background:#fff8e0;padding:.3em .6em;border-left:3px solid #e0b400}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.9em;color:#444}
nav a{margin-right:1em;font-size:.9em}
"""

_CELL_CLASS = {"PASSED": "PASSED", "FAILED": "FAILED", "not applicable": "na"}
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")


def _inline(text: str, q: str) -> str:
    """Escaped *text* with ``**bold**`` and ``[link](url)``."""
    esc = html.escape(text)
    esc = _LINK.sub(lambda m: f"<a href={q}{m.group(2)}{q}>{m.group(1)}</a>", esc)
    parts = esc.split("**")
    return "".join(f"<strong>{p}</strong>" if i % 2 else p for i, p in enumerate(parts))


def _numeric(s: str) -> bool:
    try:
        float(s.split(" ")[0].rstrip("%"))
    except ValueError:
        return False
    return True


def _attr(name: str, value: str, q: str) -> str:
    return f"{name}={q}{html.escape(value)}{q}"


def _section_ids(doc: Document) -> list[str]:
    """The anchor of every section: its id, else a slug of its title (made unique)."""
    seen: set[str] = set()
    out = []
    for s in doc.sections:
        sid = s.id or re.sub(r"[^a-z0-9]+", "-", s.title.lower()).strip("-") or "section"
        base, k = sid, 2
        while sid in seen:
            sid, k = f"{base}-{k}", k + 1
        seen.add(sid)
        out.append(sid)
    return out


def _figure_src(f: Figure, base: Path | None) -> str:
    png = f.png
    if png is None and base is not None:
        path = base / f.src
        if path.is_file() and path.suffix.lower() == ".png":
            png = path.read_bytes()
    return f.src if png is None else "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _html_block(b, q: str, base: Path | None) -> list[str]:
    if isinstance(b, Paragraph):
        return [f"<p class={q}{b.style}{q}>{_inline(b.text, q)}</p>" if b.style else f"<p>{_inline(b.text, q)}</p>"]
    if isinstance(b, Bullets):
        return ["<ul>" + "".join(f"<li>{_inline(t, q)}</li>" for t in b.items) + "</ul>"]
    if isinstance(b, Table):
        out = ["<table>"]
        if b.caption:
            out.append(f"<caption>{_inline(b.caption, q)}</caption>")
        out.append("<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in b.header) + "</tr>")
        for r in b.rows:
            cells = []
            for c in r:
                s = str(c)
                cls = _CELL_CLASS.get(s)
                if cls is None and len(s) > 14 and not _numeric(s):
                    cls = "t"
                cells.append(f"<td class={q}{cls}{q}>{_inline(s, q)}</td>" if cls else f"<td>{_inline(s, q)}</td>")
            out.append("<tr>" + "".join(cells) + "</tr>")
        out.append("</table>")
        return out
    if isinstance(b, Figure):
        alt = b.alt if b.alt is not None else b.caption
        return [f"<figure><img {_attr('alt', alt, q)} {_attr('src', _figure_src(b, base), q)}>"
                f"<figcaption>{html.escape(b.caption)}</figcaption></figure>"]
    raise TypeError(f"not a report block: {type(b).__name__}")


def to_html(doc: Document, *, base: Path | None = None, quote: str = '"') -> str:
    """*doc* as one self-contained HTML page.

    Parameters
    ----------
    doc : Document
    base : Path, optional
        Folder of the page: a figure given only by its *src* is embedded when
        that PNG file exists relative to it.
    quote : str
        The quote of the attributes (``"``; the pipeline report, whose readers
        parse it, keeps ``'``).

    Returns
    -------
    str
        The page, ending with a newline.
    """
    q = quote
    ids = _section_ids(doc)
    out = ["<!DOCTYPE html>", f"<html lang={q}en{q}><head><meta charset={q}utf-8{q}>",
           f"<title>{html.escape(doc.title)}</title>", f"<style>{CSS}</style></head><body>",
           f"<h1>{html.escape(doc.title)}</h1>", "<nav>"]
    out += [f"<a href={q}#{sid}{q}>{html.escape(s.title)}</a>"
            for sid, s in zip(ids, doc.sections) if s.title and s.level == 2]
    out.append("</nav>")
    for sid, s in zip(ids, doc.sections):
        head = f"<h{s.level}>{html.escape(s.title)}</h{s.level}>" if s.title else ""
        out.append(f"<section id={q}{sid}{q}>{head}")
        for b in s.blocks:
            out += _html_block(b, q, base)
        out.append("</section>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|")


def _md_section(s: Section, fig_dir: str) -> list[str]:
    out = [f"{'#' * s.level} {s.title}", ""] if s.title else []
    for b in s.blocks:
        if isinstance(b, Paragraph):
            out += [b.text, ""]
        elif isinstance(b, Bullets):
            out += [f"- {t}" for t in b.items] + [""]
        elif isinstance(b, Table):
            if b.caption:
                out += [f"*{b.caption}*", ""]
            out.append("| " + " | ".join(_md_cell(str(h)) for h in b.header) + " |")
            out.append("|" + "---|" * len(b.header))
            out += ["| " + " | ".join(_md_cell(str(c)) for c in r) + " |" for r in b.rows]
            out.append("")
        elif isinstance(b, Figure):
            src = f"{fig_dir}/{b.src}" if fig_dir else b.src
            out += [f"![{b.caption}]({src})", "", f"*{b.caption}*", ""]
        else:
            raise TypeError(f"not a report block: {type(b).__name__}")
    return out


def to_markdown(doc: Document, fig_dir: str = "") -> str:
    """*doc* as Markdown; figures link ``fig_dir/src`` (the PNG files written next to it:
    :func:`figure_files`)."""
    out = [f"# {doc.title}", ""]
    for s in doc.sections:
        out += _md_section(s, fig_dir)
    return "\n".join(out).rstrip() + "\n"


def figure_files(doc: Document) -> list[tuple[str, bytes]]:
    """``(src, png)`` of every figure that carries its PNG bytes, in order."""
    return [(b.src, b.png) for s in doc.sections for b in s.blocks if isinstance(b, Figure) and b.png is not None]


def markdown_to_html(md: str, title: str, base: Path | None = None) -> str:
    """Markdown of :func:`lidarcat.report.model.parse_markdown`'s subset as one HTML page
    (:func:`to_html`, attributes in ``'``); figure paths are relative to *base*.

    The first ``#`` heading of *md* is the page's title (else *title*).
    """
    return to_html(parse_markdown(md, title), base=base, quote="'")
