"""The text of a PDF written by matplotlib with TrueType fonts (``pdf.fonttype 42``), without a PDF library.

matplotlib writes each text item as one ``Tj`` string or one ``TJ`` array of strings (kerning numbers
between them), UTF-16BE encoded (Identity-H), in zlib-compressed content streams: each stream is
inflated, each item's strings unescaped (PDF string escapes) and decoded.
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

__all__ = ["pdf_text", "pdf_page_size_pt"]

_ESC = {b"n": b"\n", b"r": b"\r", b"t": b"\t", b"b": b"\b", b"f": b"\f", b"(": b"(", b")": b")", b"\\": b"\\"}


def _unescape(s: bytes) -> bytes:
    def rep(m: re.Match) -> bytes:
        e = m.group(1)
        return bytes([int(e, 8) & 0xFF]) if e[:1].isdigit() else _ESC.get(e, e)

    return re.sub(rb"\\([0-7]{1,3}|.)", rep, s, flags=re.S)


def pdf_text(path: str | Path) -> list[str]:
    """Every text item (a label, a line of the title block) of the PDF, in drawing order."""
    data = Path(path).read_bytes()
    items: list[str] = []
    string = re.compile(rb"\((?:\\.|[^\\)])*\)", re.S)
    for m in re.finditer(rb"stream\r?\n(.*?)\r?\nendstream", data, re.S):
        try:
            raw = zlib.decompress(m.group(1))
        except zlib.error:
            continue
        if b"BT" not in raw:
            continue   # an image or a font, no text object
        for block in re.findall(rb"\bBT\b(.*?)\bET\b", raw, re.S):
            # one text item per Tj / TJ operator: its strings, up to the operator
            for op in re.split(rb"T[Jj]\b", block)[:-1]:
                parts = string.findall(op)
                if parts:
                    text = b"".join(_unescape(p[1:-1]) for p in parts)
                    items.append(text.decode("utf-16-be", errors="replace"))
    return items


def pdf_page_size_pt(path: str | Path) -> tuple[float, float]:
    """Width and height of the first page's MediaBox, points (1/72 in)."""
    m = re.search(rb"/MediaBox\s*\[\s*([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s*\]", Path(path).read_bytes())
    assert m, f"{path}: no MediaBox"
    x0, y0, x1, y1 = map(float, m.groups())
    return x1 - x0, y1 - y0
