"""Reports: the per-run accuracy report and the pipeline report as HTML and Markdown.

============  ============================================================
``document``  Accuracy report: one self-contained HTML file, plus Markdown and JSON.
``html``      The Markdown subset of the pipeline report as self-contained HTML.
============  ============================================================
"""

from __future__ import annotations

from .document import (  # noqa: F401
    SECTIONS,
    load_adjustment,
    footprints,
    write_report,
)
from .html import (  # noqa: F401
    markdown_to_html,
)

__all__ = [
    'SECTIONS',
    'load_adjustment',
    'footprints',
    'write_report',
    'markdown_to_html',
]
