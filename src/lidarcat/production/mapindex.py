r"""The Brazilian systematic map index (Cartografia Sistemática Brasileira) down to 1:5,000 and 1:2,000.

The Brazilian topographic series cuts the country along the International
Map of the World (IMW, *Carta Internacional do Mundo ao Milionésimo*) and
subdivides each 1:1,000,000 sheet step by step; a sheet is named by the chain
of symbols of its ancestors.  In geographic coordinates (degrees of the
map's own datum, SIRGAS 2000 today) each level is a regular subdivision of
its parent into ``ncols x nrows`` equal cells, whose symbols run row by row
from the north-west corner (west to east, then north to south):

=============  ==========================  ===========  ==================  ================
scale          symbols                     cols x rows  sheet (lon x lat)   example
=============  ==========================  ===========  ==================  ================
1:1,000,000    hemisphere N/S, band A-V,   --           6 deg x 4 deg       SF-23
               zone 1-60
1:500,000      V X / Y Z                   2 x 2        3 deg x 2 deg       SF-23-X
1:250,000      A B / C D                   2 x 2        1 deg 30' x 1 deg   SF-23-X-D
1:100,000      I II III / IV V VI          3 x 2        30' x 30'           SF-23-X-D-VI
1:50,000       1 2 / 3 4                   2 x 2        15' x 15'           SF-23-X-D-VI-1
1:25,000       NO NE / SO SE               2 x 2        7'30" x 7'30"       ...-VI-1-NE
1:10,000       A B / C D / E F             2 x 3        3'45" x 2'30"       ...-NE-C
1:5,000        I II / III IV               2 x 2        1'52.5" x 1'15"     ...-NE-C-III
1:2,000        1 2 3 / 4 5 6               3 x 2        37.5" x 37.5"       ...-III-4
=============  ==========================  ===========  ==================  ================

The 1:1,000,000 sheet of a point at longitude :math:`\lambda` and latitude
:math:`\varphi` (degrees) is the UTM zone :math:`z = \lfloor(\lambda + 180)/6\rfloor + 1`
(west edge :math:`6z - 186`) and the 4-degree band counted from the equator,
:math:`b = \lfloor |\varphi| / 4 \rfloor` (letter ``"ABCDEFGHIJKLMNOPQRSTUV"[b]``),
prefixed N or S: SF-23 spans 48-42 deg W, 20-24 deg S.  Below it, a sheet
of size :math:`(w, h)` split into ``ncols x nrows`` gives, for a point at
offset :math:`(\Delta\lambda, \Delta\varphi)` from the sheet's north-west
corner, column :math:`\lfloor \Delta\lambda\, ncols / w \rfloor` and row
:math:`\lfloor -\Delta\varphi\, nrows / h \rfloor`; the symbol is number
``row * ncols + col`` of the level's list.  The arithmetic is done in exact
integer units of 1/8 arc-second (every sheet edge down to 1:2,000 is a whole
number of them), so sheet edges are exact: a sheet holds its west and south
edges, a point on a meridian belongs to the sheet east of it and a point on a
parallel to the sheet north of it.

**Sources and certainty.**  The levels down to 1:25,000 (V-Z, A-D, I-VI, 1-4,
NO/NE/SO/SE and their sizes) are those of the IBGE's *Noções Básicas de
Cartografia* (Manual Técnico, 1999, "Índice de nomenclatura") and the DSG's
technical norms, used on the printed IBGE/DSG sheets (by this definition the
1:250,000 sheet holding Juiz de Fora is SF-23-X-D).  The large-scale extension
(1:10,000 A-F in 2 columns x 3 rows of 3'45" x 2'30"; 1:5,000 I-IV; 1:2,000
1-6 in 3 columns x 2 rows) is the one municipal and utility mapping in
Brazil commonly uses; it was reconstructed here without a normative text at
hand, so **the 1:10,000, 1:5,000 and 1:2,000 levels are to be checked
against the contracting agency's articulation before delivery** (the levels
are data in :data:`LEVELS`; a different convention is a one-line change).
The tests check the definition itself (children tile their parent exactly,
names and corners round-trip) and sheets whose names follow by hand from it.

**Surveys in a projected CRS.**  :func:`sheets_covering` transforms the
survey area (SIRGAS 2000 / UTM, or any projected CRS) to the geographic CRS
of its own datum with pyproj, lists the sheets of the geographic bounding
box and keeps those whose outline meets the area.  A sheet is a geographic
rectangle; in the projected CRS its outline is a polygon whose edges are
densified (:func:`sheet_outline`, 16 points per edge by default: the
meridians converge and the parallels are curves under UTM).  Products are
cut in the geographic frame (:func:`cut_raster_geo`: cells whose centre lies
in the sheet; :func:`cut_contours_geo`: contour lines clipped to the sheet's
geographic rectangle and transformed back), so that neighbouring sheets
share their edges exactly.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CRSError, ProductError
from ._clip import Box, clip_lines, cut_grid

#: Largest number of sheets an index may make (316 km x 316 km in sheets of 1 km): counted first,
#: so that one vertex far from the others is an error, not an hour of empty sheets.
MAX_SHEETS = 100_000

__all__ = ["MapSheet", "Level", "LEVELS", "SCALES", "sheet_at", "sheet_names", "sheet_from_name",
           "sheets_covering", "sheet_outline", "cut_raster_geo", "cut_contours_geo", "geographic_crs_of",
           "MAX_SHEETS"]

#: units per degree: 1/8 arc-second
_U = 3600 * 8
_BANDS = "ABCDEFGHIJKLMNOPQRSTUV"


@dataclass(frozen=True)
class Level:
    """One subdivision level: scale denominator, symbols (row by row from the north-west), columns."""

    scale: int
    symbols: tuple[str, ...]
    ncols: int

    @property
    def nrows(self) -> int:
        return len(self.symbols) // self.ncols


#: the levels below 1:1,000,000, in order
LEVELS: tuple[Level, ...] = (
    Level(500_000, ("V", "X", "Y", "Z"), 2),
    Level(250_000, ("A", "B", "C", "D"), 2),
    Level(100_000, ("I", "II", "III", "IV", "V", "VI"), 3),
    Level(50_000, ("1", "2", "3", "4"), 2),
    Level(25_000, ("NO", "NE", "SO", "SE"), 2),
    Level(10_000, ("A", "B", "C", "D", "E", "F"), 2),
    Level(5_000, ("I", "II", "III", "IV"), 2),
    Level(2_000, ("1", "2", "3", "4", "5", "6"), 3),
)
#: scale denominators with an index, largest sheet first
SCALES: tuple[int, ...] = (1_000_000,) + tuple(lv.scale for lv in LEVELS)


def _sizes() -> dict[int, tuple[int, int]]:
    """Sheet width and height (units of 1/8 arc-second) per scale."""
    w, h = 6 * _U, 4 * _U
    out = {1_000_000: (w, h)}
    for lv in LEVELS:
        assert w % lv.ncols == 0 and h % lv.nrows == 0, lv
        w, h = w // lv.ncols, h // lv.nrows
        out[lv.scale] = (w, h)
    return out


_SIZE = _sizes()


@dataclass(frozen=True)
class MapSheet:
    """One sheet of the systematic index.

    Attributes
    ----------
    name : str
        e.g. ``"SF-23-X-D-VI-1-NE-C-III"``.
    scale : int
        Scale denominator (5000 for 1:5,000).
    west, south, east, north : float
        Geographic bounds, degrees (longitude east-positive, latitude north-positive).
    geographic_crs : str
        The geographic CRS of the bounds (e.g. ``"EPSG:4674"``, SIRGAS 2000).
    """

    name: str
    scale: int
    west: float
    south: float
    east: float
    north: float
    geographic_crs: str = "EPSG:4674"

    # the rectangle protocol of lidarcat.production.sheets (clipping works in this frame: x longitude,
    # y latitude, degrees)
    xmin = property(lambda self: self.west, doc="West bound (degrees).")
    ymin = property(lambda self: self.south, doc="South bound (degrees).")
    xmax = property(lambda self: self.east, doc="East bound (degrees).")
    ymax = property(lambda self: self.north, doc="North bound (degrees).")

def _check_scale(scale: int) -> None:
    if scale not in _SIZE:
        raise ValueError(f"no Brazilian index sheet at 1:{scale}; use one of "
                         f"{', '.join(f'1:{s}' for s in SCALES)}")


def _units(lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Longitude from 180 deg W and latitude from 90 deg S, in integer 1/8 arc-seconds (floor)."""
    # round first to 1e-6 unit so that a corner computed in floating point lands on its edge
    u = np.floor(np.round((np.asarray(lon, np.float64) + 180.0) * _U, 6)).astype(np.int64)
    v = np.floor(np.round((np.asarray(lat, np.float64) + 90.0) * _U, 6)).astype(np.int64)
    return u, v


def sheet_names(lon: Any, lat: Any, scale: int) -> np.ndarray:
    """Names of the sheets at 1:*scale* holding the points (vectorised).

    Parameters
    ----------
    lon, lat : array_like, shape (N,)
        Geographic coordinates, degrees.
    scale : int
        Scale denominator, one of :data:`SCALES`.

    Returns
    -------
    ndarray of str, shape (N,)

    Examples
    --------
    >>> sheet_names([-42.1, -43.35], [-21.7, -21.76], 250_000).tolist()
    ['SF-23-X-D', 'SF-23-X-D']
    """
    _check_scale(scale)
    lon_a, lat_a = np.atleast_1d(np.asarray(lon, np.float64)), np.atleast_1d(np.asarray(lat, np.float64))
    if lon_a.shape != lat_a.shape:
        raise ValueError(f"lon and lat differ in shape: {lon_a.shape} and {lat_a.shape}")
    bad = ~(np.isfinite(lon_a) & np.isfinite(lat_a) & (np.abs(lat_a) < 88) & (np.abs(lon_a) <= 180))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ProductError(f"point {i}: longitude {float(lon_a[i])!r}, latitude {float(lat_a[i])!r} deg is outside the "
                         f"index (|lat| < 88, |lon| <= 180)")
    u, v = _units(lon_a, lat_a)
    u = np.minimum(u, 360 * _U - 1)
    w, h = _SIZE[1_000_000]
    zone = u // w
    south = lat_a < 0
    band = np.where(south, (90 * _U - 1 - v) // h, (v - 90 * _U) // h)
    names = np.char.add(np.char.add(np.where(south, "S", "N"), np.array(list(_BANDS))[band]),
                        np.char.add("-", (zone + 1).astype(str)))
    # north-west corner of the 1:1,000,000 sheet, units
    west = zone * w
    north = np.where(south, 90 * _U - band * h, 90 * _U + (band + 1) * h)
    for lv in LEVELS[:SCALES.index(scale)]:
        cw, ch = _SIZE[lv.scale]
        col = (u - west) // cw
        row = (north - 1 - v) // ch
        names = np.char.add(np.char.add(names, "-"), np.array(lv.symbols)[row * lv.ncols + col])
        west = west + col * cw
        north = north - row * ch
    return names


def sheet_at(lon: float, lat: float, scale: int, geographic_crs: str = "EPSG:4674") -> MapSheet:
    """The sheet at 1:*scale* holding the point (*lon*, *lat*) in degrees.

    Examples
    --------
    >>> s = sheet_at(-42.1, -21.7, 1_000_000)
    >>> s.name, (s.west, s.south, s.east, s.north)
    ('SF-23', (-48.0, -24.0, -42.0, -20.0))
    """
    return sheet_from_name(str(sheet_names([lon], [lat], scale)[0]), geographic_crs)


_MILLION = re.compile(r"^([NS])([A-V])-([1-9]|[1-5][0-9]|60)$")


def sheet_from_name(name: str, geographic_crs: str = "EPSG:4674") -> MapSheet:
    """The sheet named *name* (any level), with its geographic bounds.

    Raises
    ------
    ValueError
        A name that is not a sheet of the index; the message names the faulty part.

    Examples
    --------
    >>> s = sheet_from_name("SF-23-X-D-VI-1")
    >>> s.scale, (s.west, s.south, s.east, s.north)
    (50000, (-42.5, -21.75, -42.25, -21.5))
    """
    parts = str(name).strip().upper().split("-")
    m = _MILLION.match("-".join(parts[:2]))
    if m is None:
        raise ValueError(f"sheet name {name!r}: it must start with a 1:1,000,000 sheet such as 'SF-23' "
                         f"(N/S, band A-V, zone 1-60)")
    if len(parts) - 2 > len(LEVELS):
        raise ValueError(f"sheet name {name!r}: more parts than the index has levels (down to 1:2,000)")
    w, h = _SIZE[1_000_000]
    zone, band = int(m.group(3)), _BANDS.index(m.group(2))
    west = (zone - 1) * w
    north = 90 * _U - band * h if m.group(1) == "S" else 90 * _U + (band + 1) * h
    scale = 1_000_000
    for lv, sym in zip(LEVELS, parts[2:]):
        if sym not in lv.symbols:
            raise ValueError(f"sheet name {name!r}: {sym!r} is not a 1:{lv.scale:,} symbol "
                             f"({' '.join(lv.symbols)})")
        k = lv.symbols.index(sym)
        cw, ch = _SIZE[lv.scale]
        west += (k % lv.ncols) * cw
        north -= (k // lv.ncols) * ch
        scale = lv.scale
    w, h = _SIZE[scale]
    canonical = "-".join(parts)
    return MapSheet(canonical, scale, west / _U - 180.0, (north - h) / _U - 90.0, (west + w) / _U - 180.0,
                    north / _U - 90.0, geographic_crs)


def geographic_crs_of(crs: Any) -> Any:
    """The geographic CRS of the datum of *crs* (SIRGAS 2000 for SIRGAS 2000 / UTM zone 23S)."""
    from ..errors import CRSError
    from ..lidar.crs import resolve_crs

    c = resolve_crs(crs)
    if c is None:
        raise CRSError("the Brazilian map index needs the CRS of the survey (e.g. EPSG:31983)")
    g = c.geodetic_crs
    if g is None:
        raise CRSError(f"CRS {c.name!r} has no geodetic datum; the map index is geographic")
    return g


@functools.lru_cache(maxsize=16)
def _transformer(src: Any, dst: Any) -> Any:
    """A lon/lat-ordered pyproj transformer (cached: building one costs milliseconds, a survey has
    thousands of sheets)."""
    from pyproj import Transformer

    return Transformer.from_crs(src, dst, always_xy=True)


def sheet_outline(sheet: MapSheet, crs: Any, per_edge: int = 16) -> np.ndarray:
    """The sheet's outline in the projected *crs*: a closed counter-clockwise ring, shape (4 per_edge + 1, 2).

    Each geographic edge is divided into *per_edge* equal steps of longitude
    or latitude before the transformation, so the projected polygon follows
    the curved parallels and converging meridians.
    """
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)
    w, s, e, n = sheet.west, sheet.south, sheet.east, sheet.north
    lon = np.concatenate([w + (e - w) * t, np.full(per_edge, e), e - (e - w) * t, np.full(per_edge, w), [w]])
    lat = np.concatenate([np.full(per_edge, s), s + (n - s) * t, np.full(per_edge, n), n - (n - s) * t, [s]])
    x, y = _transformer(sheet.geographic_crs, crs).transform(lon, lat)
    return np.column_stack([x, y])


def sheets_covering(bounds: tuple[float, float, float, float], crs: Any, scale: int, *,
                    geographic_crs: Any = None, per_edge: int = 16) -> list[MapSheet]:
    """The sheets at 1:*scale* whose outline meets the plan box *bounds* of a projected *crs*.

    Parameters
    ----------
    bounds : (xmin, ymin, xmax, ymax)
        Survey area, metres, in *crs*.
    crs : CRS-like
        Projected CRS of *bounds* (e.g. ``"EPSG:31983"``, SIRGAS 2000 / UTM zone 23S).
    scale : int
        One of :data:`SCALES` (5000, 2000...).
    geographic_crs : CRS-like, optional
        Frame of the index; default the geographic CRS of *crs*'s own datum.
    per_edge : int
        Densification of the sheet outlines (see :func:`sheet_outline`).

    Returns
    -------
    list of MapSheet
        North to south, west to east.
    """
    from ..lidar.crs import resolve_crs
    from ..lidar.membership import in_polygon

    _check_scale(scale)
    geo = resolve_crs(geographic_crs, what="geographic CRS") if geographic_crs is not None else geographic_crs_of(crs)
    if not geo.is_geographic:
        raise CRSError(f"the sheets of the Brazilian index are geographic rectangles; {geo.name!r} is not a "
                       f"geographic CRS (give e.g. EPSG:4674, SIRGAS 2000)")
    src = resolve_crs(crs)
    xmin, ymin, xmax, ymax = map(float, bounds)
    if not (xmax >= xmin and ymax >= ymin):
        raise ProductError(f"empty area: E {xmin}..{xmax}, N {ymin}..{ymax}")
    # the area's outline, densified, in degrees: its bounding box bounds the candidate sheets
    k = np.linspace(0.0, 1.0, 33)
    ex = np.concatenate([xmin + (xmax - xmin) * k, np.full(33, xmax), xmax - (xmax - xmin) * k, np.full(33, xmin)])
    ny = np.concatenate([np.full(33, ymin), ymin + (ymax - ymin) * k, np.full(33, ymax), ymax - (ymax - ymin) * k])
    lon, lat = _transformer(src, geo).transform(ex, ny)
    if not (np.isfinite(lon).all() and np.isfinite(lat).all()):
        raise CRSError(f"the area E {xmin}..{xmax}, N {ymin}..{ymax} does not transform to geographic "
                         f"coordinates in {geo.name}; is the CRS right?")
    w, h = _SIZE[scale]
    u0, v0 = _units(lon.min(), lat.min())
    u1, v1 = _units(lon.max(), lat.max())
    q0, q1 = int(v0) - 90 * _U, int(v1) - 90 * _U   # latitude units from the equator: sheet edges at k h
    n = ((int(u1) - int(u0)) // w + 2) * ((q1 - q0) // h + 2)   # candidates, counted before any is made
    inside = bool((np.abs(lat) < 88).all() and (np.abs(lon) <= 180).all())  # else sheet_at names the point
    if n > MAX_SHEETS and inside:
        raise ProductError(f"the area E {xmin:.6g}..{xmax:.6g} N {ymin:.6g}..{ymax:.6g} meets about {n:,} "
                           f"sheets of the 1:{scale:,} index, more than {MAX_SHEETS:,}; a point far from the "
                           "others, or a smaller scale?")
    geo_name = geo.to_string()
    area = Box(xmin, ymin, xmax, ymax)
    corner = np.array([[xmin, ymin]])
    out = []
    for q in range(q1 // h * h, q0 // h * h - 1, -h):          # rows of sheets, north first
        for u in range(int(u0) // w * w, int(u1) // w * w + 1, w):
            sheet = sheet_at((u + w / 2) / _U - 180.0, (q + h / 2) / _U, scale, geo_name)
            ring = sheet_outline(sheet, src, per_edge)
            # the outline crosses or lies in the area, or the area lies inside the outline
            if _ring_meets_box(ring, area) or in_polygon(corner, ring[:-1])[0]:
                out.append(sheet)
    return out


def _ring_meets_box(ring: np.ndarray, box: Any) -> bool:
    """True when a segment of the polyline *ring* meets the rectangle *box* (Liang-Barsky, vectorised)."""
    a, d = ring[:-1], np.diff(ring, axis=0)
    t0, t1 = np.zeros(len(a)), np.ones(len(a))
    ok = np.ones(len(a), bool)
    for p, q in ((-d[:, 0], a[:, 0] - box.xmin), (d[:, 0], box.xmax - a[:, 0]),
                 (-d[:, 1], a[:, 1] - box.ymin), (d[:, 1], box.ymax - a[:, 1])):
        zero = p == 0
        ok &= ~(zero & (q < 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(zero, 0.0, q / np.where(zero, 1.0, p))
        t0 = np.where(p < 0, np.maximum(t0, t), t0)
        t1 = np.where(p > 0, np.minimum(t1, t), t1)
    return bool(np.any(ok & (t0 <= t1)))


def cut_raster_geo(grid: np.ndarray, transform: Any, sheet: MapSheet, crs: Any) -> tuple[np.ndarray, Any] | None:
    """The cells of *grid* (in the projected *crs*) whose centre lies in the geographic *sheet*.

    Returns the sub-grid of the bounding box of those cells (cells outside the
    sheet set to NaN, or 0 for integer grids) and its transform; ``None`` when
    no cell centre lies in the sheet.
    """
    from ..lidar.raster import GeoTransform

    ring = sheet_outline(sheet, crs)
    box = Box(float(ring[:, 0].min()), float(ring[:, 1].min()), float(ring[:, 0].max()), float(ring[:, 1].max()))
    cut = cut_grid(grid, transform, box)
    if cut is None:
        return None
    sub, t = cut
    c = t.cell_m
    rows, cols = sub.shape[:2]
    xc = t.x0 + (np.arange(cols) + 0.5) * c
    yc = t.y0 - (np.arange(rows) + 0.5) * c
    xx, yy = np.meshgrid(xc, yc)
    lon, lat = _transformer(crs, sheet.geographic_crs).transform(xx.ravel(), yy.ravel())
    u, v = _units(lon, lat)
    w0, s0 = _units(sheet.west, sheet.south)
    e0, n0 = _units(sheet.east, sheet.north)
    inside = ((u >= w0) & (u < e0) & (v >= s0) & (v < n0)).reshape(rows, cols)
    if not inside.any():
        return None
    r = np.flatnonzero(inside.any(axis=1))
    k = np.flatnonzero(inside.any(axis=0))
    sub = np.array(sub[r[0]:r[-1] + 1, k[0]:k[-1] + 1], copy=True)
    inside = inside[r[0]:r[-1] + 1, k[0]:k[-1] + 1]
    fill = np.nan if np.issubdtype(sub.dtype, np.floating) else 0
    sub[~inside] = fill
    return sub, GeoTransform(t.x0 + k[0] * c, t.y0 - r[0] * c, c)


def cut_contours_geo(features: list[dict[str, Any]], sheet: MapSheet, crs: Any) -> list[dict[str, Any]]:
    """Contour LineStrings (in the projected *crs*) clipped to the geographic rectangle of *sheet*.

    The lines are transformed to the sheet's geographic CRS, clipped there
    (Liang-Barsky, as :func:`lidarcat.production.sheets.cut_contours`) and
    transformed back; vertices move by the pyproj round trip only (well
    under a micrometre).
    """
    if not features:
        return []
    fwd, back = _transformer(crs, sheet.geographic_crs), _transformer(sheet.geographic_crs, crs)
    xy = [np.asarray(f["geometry"]["coordinates"], dtype=np.float64).reshape(-1, 2) for f in features]
    lens = np.cumsum([0] + [len(a) for a in xy])
    allxy = np.vstack(xy)
    lon, lat = fwd.transform(allxy[:, 0], allxy[:, 1])
    geo_feats = [{"type": "Feature", "properties": f["properties"],
                  "geometry": {"type": "LineString",
                               "coordinates": np.column_stack([lon[a:b], lat[a:b]])}}
                 for f, a, b in zip(features, lens[:-1], lens[1:])]
    out = clip_lines(geo_feats, sheet)
    for f in out:
        ll = np.asarray(f["geometry"]["coordinates"], dtype=np.float64)
        x, y = back.transform(ll[:, 0], ll[:, 1])
        f["geometry"]["coordinates"] = np.round(np.column_stack([x, y]), 3).tolist()
    return out
