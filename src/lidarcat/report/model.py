"""The document model of every report: a title and sections of paragraphs, lists, tables and figures.

The per-run accuracy report (:mod:`lidarcat.report.document`) builds a
:class:`Document` directly; the pipeline report (``index.md``, written by the
``report`` stage) is Markdown, read into the same model by
:func:`parse_markdown`.  :mod:`lidarcat.report.render` writes a document as
self-contained HTML and as Markdown.

Inline text is Markdown's small subset: ``**bold**`` and ``[link](url)``.

>>> doc = parse_markdown("# Run\\n\\nSome **text**.\\n\\n## Points\\n\\n| a | b |\\n|---|---|\\n| 1 | 2 |\\n")
>>> doc.title, [s.title for s in doc.sections], doc.sections[1].blocks[0].rows
('Run', ['', 'Points'], [['1', '2']])
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

__all__ = ["Paragraph", "Bullets", "Table", "Figure", "Block", "Section", "Document", "parse_markdown"]


@dataclass
class Paragraph:
    """A paragraph of inline text; *style* ``na`` (not available / applicable) or ``note`` marks it."""

    text: str
    style: str = ""


@dataclass
class Bullets:
    """A bulleted list of inline texts."""

    items: list[str] = field(default_factory=list)


@dataclass
class Table:
    """A table: *header* cells, body *rows* (any values, written with ``str``), an optional *caption*."""

    header: list[str]
    rows: list[list]
    caption: str = ""


@dataclass
class Figure:
    """A figure: *caption*, and either the PNG bytes (*png*, written as *src* next to the Markdown)
    or only *src*, a path relative to the document's folder.  *alt* defaults to the caption."""

    caption: str
    src: str
    png: bytes | None = None
    alt: str | None = None


Block = Paragraph | Bullets | Table | Figure


@dataclass
class Section:
    """A heading (*title*, *level* 2 or deeper; an empty title: no heading) and its blocks.

    *id* is the HTML anchor (made from the title when empty).
    """

    title: str
    blocks: list[Block] = field(default_factory=list)
    id: str = ""
    level: int = 2


@dataclass
class Document:
    """A title and its sections, in order."""

    title: str
    sections: list[Section] = field(default_factory=list)

    def section(self, title: str, id: str = "", level: int = 2) -> Section:
        """Append a new section and return it."""
        s = Section(title, [], id, level)
        self.sections.append(s)
        return s


_FIGURE = re.compile(r"^!\[([^\]]*)\]\(([^)]+)\)$")


def parse_markdown(md: str, title: str = "") -> Document:
    """A :class:`Document` of Markdown's subset: ``#`` headings, ``|`` tables, ``- `` items,
    ``![caption](path)`` figure lines and paragraphs (one per line).

    The first level-1 heading is the title (else *title*); text before the
    first level-2 heading is a section without a heading.  A table's first row
    is its header; ``|---|`` rows are skipped.
    """
    doc = Document(title)
    titled = False
    cur = Section("")
    doc.sections.append(cur)
    table: Table | None = None
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-"):
                continue
            if table is None:
                table = Table(cells, [])
                cur.blocks.append(table)
            else:
                table.rows.append(cells)
            continue
        table = None
        if line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            text = line[level:].strip()
            if level == 1 and not titled:
                doc.title, titled = text, True
            else:
                cur = doc.section(text, level=max(level, 2))
        elif _FIGURE.match(line):
            cap, src = _FIGURE.match(line).groups()
            cur.blocks.append(Figure(cap, src))
        elif line.startswith("- "):
            if cur.blocks and isinstance(cur.blocks[-1], Bullets):
                cur.blocks[-1].items.append(line[2:])
            else:
                cur.blocks.append(Bullets([line[2:]]))
        elif line.strip():
            cur.blocks.append(Paragraph(line))
    if not doc.sections[0].blocks:
        doc.sections.pop(0)
    return doc
