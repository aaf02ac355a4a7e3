"""Shared helpers of every stage: files (atomic output, located input), tables (CSV/TOML/JSON), frozen value types.

=================  =========================================================
``files``          atomic writes, the output-folder boundary (safe names, no links), lock, located reads, SHA-256, provenance
``tables``         CSV with the header first, TOML line numbers, JSON (sorted keys, NaN -> null)
``frozen``         frozen value types holding read-only arrays
``formatting``     the one number formatter (``format_number``) of reports, CLI and standards
``values``         sane ranges of input values (coordinates, heights, angles, pixels), ASCII number parsing
=================  =========================================================
"""

from __future__ import annotations

from .files import *  # noqa: F401,F403
from .files import __all__ as _files_all
from .tables import *  # noqa: F401,F403
from .tables import __all__ as _tables_all

__all__ = [*_files_all, *_tables_all]
