"""The cartographic conventions of the LACTEC sheets (report 13.1, Figure 27): one level per map element.

The report's production drew every element of a sheet on its own MicroStation
level, with the colour number, line style and weight of Figure 27:

=====  =======================  =======  =========================
level  name (layer)             colour   drawn on the chart as
=====  =======================  =======  =========================
0      Default                  0        --
1      Limite de Restituição    3        red outline of the mapped area
2      Curvas Mestras           6        orange-brown line, 0.5 mm
3      Pontos Cotados           0        black cross
4      Cotas                    0        black numbers (spot heights, master-curve labels)
5      Curvas Intermediárias    32       light brown line, 0.2 mm
6      Malha UTM                0        black thin line, labelled on the frame
7      Prancha                  0        black frame of the sheet
=====  =======================  =======  =========================

The colour numbers are the report's (MicroStation's default table: 0 white,
drawn black on paper; 3 red; 6 orange); the RGB colours below are what the
chart draws and what the DXF layers carry as true colour, with the nearest
AutoCAD colour index (ACI) for programs that read only that.  The layer names
are the report's, accents included (DXF R2013 is UTF-8).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Convention", "CONVENTIONS", "convention"]


@dataclass(frozen=True)
class Convention:
    """One element of Figure 27.

    Attributes
    ----------
    key : str
        Short name used in code (``master``, ``intermediate``, ``spot``, ...).
    level : int
        The report's level number.
    layer : str
        The report's level name, used as the layer name of DXF and Shapefile output.
    colour_number : int
        The report's colour number (MicroStation table).
    rgb : str
        ``#rrggbb`` drawn on the chart and written as the DXF layer's true colour.
    aci : int
        Nearest AutoCAD colour index (7: black on white paper).
    width_mm : float
        Printed line width, mm.
    """

    key: str
    level: int
    layer: str
    colour_number: int
    rgb: str
    aci: int
    width_mm: float


#: Figure 27 of the report, in level order
CONVENTIONS: tuple[Convention, ...] = (
    Convention("default", 0, "Default", 0, "#000000", 7, 0.13),
    Convention("boundary", 1, "Limite de Restituição", 3, "#e00000", 1, 0.35),
    Convention("master", 2, "Curvas Mestras", 6, "#c86400", 30, 0.5),
    Convention("spot", 3, "Pontos Cotados", 0, "#000000", 7, 0.25),
    Convention("label", 4, "Cotas", 0, "#000000", 7, 0.13),
    Convention("intermediate", 5, "Curvas Intermediárias", 32, "#d2a05a", 32, 0.2),
    Convention("grid", 6, "Malha UTM", 0, "#000000", 7, 0.13),
    Convention("sheet", 7, "Prancha", 0, "#000000", 7, 0.35),
)


def convention(key: str) -> Convention:
    """The convention of element *key*.

    Examples
    --------
    >>> convention("master").layer, convention("master").colour_number
    ('Curvas Mestras', 6)
    """
    for c in CONVENTIONS:
        if c.key == key:
            return c
    from ..errors import ProductError

    raise ProductError(f"no convention {key!r}; known: {', '.join(c.key for c in CONVENTIONS)}")
