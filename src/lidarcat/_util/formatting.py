"""The one number formatter of the reports, the CLI and the standards' class labels.

:func:`format_number` writes a number with a fixed count of decimals (or in
its shortest form), a missing or non-finite value as a placeholder, a truth
value as ``yes`` / ``no`` and an integer as it is.

>>> format_number(0.12345), format_number(2.5, 1), format_number(None), format_number(float("nan"))
('0.123', '2.5', '-', '-')
>>> format_number(7), format_number(True), format_number(None, missing="—"), format_number("A")
('7', 'yes', '—', 'A')
>>> format_number(0.05, None), format_number(2000.0, None), format_number(1.5, 2, unit=" m")
('0.05', '2000', '1.50 m')
"""

from __future__ import annotations

import math
import numbers
from typing import Any

__all__ = ["format_number", "MISSING"]

#: the placeholder of a missing (None) or non-finite number
MISSING = "-"


def format_number(value: Any, digits: int | None = 3, *, missing: str = MISSING, unit: str = "") -> str:
    """*value* as text: a real number with *digits* decimals, ``None``/NaN/inf as *missing*.

    Parameters
    ----------
    value : any
        A real number (Python or numpy), an integer, a bool, None, or anything
        else (written with ``str``).
    digits : int or None
        Decimals of a real number (fixed point); None: its shortest form
        (``format(value, "g")``).
    missing : str
        Text of None and of a non-finite real number (the tables' ``-``; the
        HTML report uses an em dash).
    unit : str
        Appended to a written number (not to *missing*, not to other text).

    Returns
    -------
    str
        ``yes``/``no`` for a bool, the digits of an integer unchanged, the real
        number rounded as :func:`format` rounds.
    """
    if value is None:
        return missing
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return "yes" if value else "no"
    if isinstance(value, numbers.Integral):
        return f"{int(value)}{unit}"
    if isinstance(value, numbers.Real):
        x = float(value)
        if not math.isfinite(x):
            return missing
        return (f"{x:g}" if digits is None else f"{x:.{digits}f}") + unit
    return str(value)
