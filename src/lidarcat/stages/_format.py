"""The number format of the stage reports (index.md, the mapping section)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["num"]


def num(v: Any, nd: int) -> str:
    """*v* with *nd* decimals; ``-`` for None, NaN and infinities."""
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{nd}f}"
