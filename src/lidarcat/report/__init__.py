"""Reports: the per-run accuracy report and the pipeline report, one document model rendered as HTML and Markdown.

===================  ============================================================
``model``            The document model of every report: a title and sections of paragraphs, lists, tables and figures.
``render``           The one report renderer: a document as self-contained HTML or as Markdown.
``figures``          The figures of the accuracy report, as PNG bytes (matplotlib, no display needed).
``document``         Accuracy report: one self-contained HTML file, plus Markdown and JSON.
``quality``          The quality report of a run: verdict, residuals, precision, overlap, control, camera, standards, tie points, density, thumbnails.
``quality_figures``  The figures of the quality report, as PNG bytes (matplotlib, no display needed).
===================  ============================================================

Numbers are written by :func:`lidarcat._util.formatting.format_number`.
"""

from __future__ import annotations

from .model import (  # noqa: F401
    Document,
    Section,
    Paragraph,
    Bullets,
    Table,
    Figure,
    parse_markdown,
)
from .render import (  # noqa: F401
    to_html,
    to_markdown,
    markdown_to_html,
)
from .document import (  # noqa: F401
    SECTIONS,
    load_adjustment,
    footprints,
    write_report,
)

__all__ = [
    'Document',
    'Section',
    'Paragraph',
    'Bullets',
    'Table',
    'Figure',
    'parse_markdown',
    'to_html',
    'to_markdown',
    'markdown_to_html',
    'SECTIONS',
    'load_adjustment',
    'footprints',
    'write_report',
]
