r"""Orthophoto charts (ortofotocartas, report 12.4 and 13.3): one printable sheet per sheet of the index.

A chart is the orthomosaic of one sheet with the contours over it (master
curves labelled with their height), the spot heights, the UTM grid labelled on
the frame, and beside the map a panel with the title block (project, sheet,
scale, datum and projection, magnetic declination, contour interval, date),
the legend of the cartographic conventions (:mod:`lidarcat.production.conventions`,
the report's Figure 27) and an index map of the sheet in the block.

True scale
----------
The map is drawn at the chart's scale :math:`1:S` on the page: a sheet
:math:`W \times H` metres wide takes :math:`W/S \times H/S` metres of paper
(a 1,000 m sheet at 1:5,000 is 20 cm), and the page is that plus fixed margins
and the side panel.  Printed at 100 % the PDF is at scale; the PNG is the
same page at ``dpi`` pixels per inch.

UTM grid
--------
The grid interval is the "nice" number (1, 2 or 5 x 10^k m) giving 4 to 10
lines across the sheet's width (100 m or 200 m on a 1,000 m sheet); each line is
labelled with its easting or northing in metres on the frame, eastings below
and above, northings left and right.

Master-curve labels
-------------------
Each master curve with at least ``label_min_m`` of its length inside the sheet
gets its height once, at the vertex nearest to the middle of its length inside
the sheet, turned along the line (and kept upright), on a white box (a box, not a
stroked halo: a halo would turn the text into paths in the PDF).

Magnetic declination
--------------------
It is not computed: a geomagnetic model (IGRF/WMM) would need its coefficient
files.  It is a parameter (``declination_deg``, east positive, with the date
of the value), printed as degrees and minutes E/W; without it the title
block says "not given".

In parallel
-----------
:func:`render_charts` draws the sheets on the project's tile runner
(:func:`lidarcat.lidar.jobs.run_tasks`: serially in this process by default, or
on a Dask ``LocalCluster`` of ``workers`` single-threaded processes, or on a
running scheduler, as the tile commands run their tiles; matplotlib is not
thread-safe, and one chart is a few seconds of pure-Python drawing, so threads
would not help either).  Each task carries only what its sheet needs: the
mosaic cells meeting the sheet (with their own transform, so
:func:`crop_image` gives the same cells), the contours whose bounding box meets
it and the spot heights inside, with the index map's sheets and the title
block; at most two tasks per worker are in flight, so the crops held are a few
sheets' worth.  A chart is the same bytes drawn serially or on a worker (the
tests compare them).

Nothing half-written: the PDF and PNG are written through
:func:`lidarcat._util.atomic_write`.  The PDF embeds its fonts as TrueType
(``pdf.fonttype 42``), so its text stays text (searchable, and selectable in a
viewer).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ProductError
from ..lidar.geotiff import GeoTransform
from .conventions import convention

__all__ = ["TitleBlock", "ChartFiles", "sheet_extent", "grid_interval", "crop_image", "draw_chart",
           "write_chart", "format_declination", "render_charts"]

_MM = 1.0 / 25.4   # inches per millimetre
_PANEL_IN = 3.4     # width of the side panel, in
_MARGIN_IN = 0.9    # margin around the map for the grid labels, in


@dataclass(frozen=True)
class TitleBlock:
    """The title block of a chart.

    Attributes
    ----------
    project : str
    scale : int
        Scale denominator (5000: 1:5,000).
    datum_projection : str
        The CRS's name, e.g. ``SIRGAS 2000 / UTM zone 23S (EPSG:31983)``.
    declination_deg : float or None
        Magnetic declination, degrees, east positive (None: not given).
    declination_date : str
        Date (epoch) of the declination value.
    date : str
        Date of the chart.
    contour_interval_m : float
    master_every : int
    """

    project: str
    scale: int
    datum_projection: str
    declination_deg: float | None
    declination_date: str
    date: str
    contour_interval_m: float
    master_every: int


@dataclass(frozen=True)
class ChartFiles:
    """The files of one chart: the sheet's name, the PDF and the PNG."""

    sheet: str
    pdf: Path
    png: Path


def format_declination(deg: float | None, date: str = "") -> str:
    """The declination as degrees and minutes east/west.

    Examples
    --------
    >>> format_declination(-21.5, "2009-06-01")
    "21°30' W (2009-06-01)"
    >>> format_declination(None)
    'not given'
    """
    if deg is None:
        return "not given"
    m = round(abs(deg) * 60.0)
    text = f"{m // 60}°{m % 60:02d}' {'E' if deg >= 0 else 'W'}"
    return f"{text} ({date})" if date else text


def sheet_extent(sheet: Any, crs: Any = None) -> tuple[tuple[float, float, float, float], np.ndarray]:
    """Plan box (xmin, ymin, xmax, ymax) of a sheet in the projected CRS and its outline ring (N, 2)."""
    from .mapindex import MapSheet, sheet_outline

    if isinstance(sheet, MapSheet):
        if crs is None:
            raise ProductError(f"sheet {sheet.name}: a chart of a geographic sheet needs the CRS of the products")
        ring = np.asarray(sheet_outline(sheet, crs), dtype=np.float64)
        return (float(ring[:, 0].min()), float(ring[:, 1].min()), float(ring[:, 0].max()),
                float(ring[:, 1].max())), ring
    ring = np.array([[sheet.xmin, sheet.ymin], [sheet.xmax, sheet.ymin], [sheet.xmax, sheet.ymax],
                     [sheet.xmin, sheet.ymax], [sheet.xmin, sheet.ymin]])
    return (sheet.xmin, sheet.ymin, sheet.xmax, sheet.ymax), ring


def grid_interval(width_m: float) -> float:
    """The UTM grid interval: 1, 2 or 5 x 10^k m giving 4 to 10 lines over *width_m*.

    Examples
    --------
    >>> grid_interval(1000.0), grid_interval(600.0), grid_interval(3500.0)
    (200.0, 100.0, 500.0)
    """
    if not width_m > 0:
        raise ProductError(f"the sheet's width must be positive, got {width_m!r} m")
    k = 10.0 ** math.floor(math.log10(width_m / 10.0))
    for step in (1.0, 2.0, 5.0, 10.0, 20.0):
        if width_m / (step * k) < 10.0:
            return step * k
    return 50.0 * k   # pragma: no cover  (10^k <= width/10 < 10^(k+1): 20 x 10^k always does)



def _cell_window(shape: tuple[int, ...], transform: GeoTransform,
                 box: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
    """Rows ``r0:r1`` and columns ``c0:c1`` of a grid of *shape* (north-up *transform*) meeting *box*
    (E0, N0, E1, N1); empty (``r1 <= r0`` or ``c1 <= c0``) when they do not meet."""
    rows, cols = shape[:2]
    c = transform.cell_m
    return (max(0, int(math.floor((transform.y0 - box[3]) / c))), min(rows, int(math.ceil((transform.y0 - box[1]) / c))),
            max(0, int(math.floor((box[0] - transform.x0) / c))), min(cols, int(math.ceil((box[2] - transform.x0) / c))))


def crop_image(image: np.ndarray, transform: GeoTransform,
               box: tuple[float, float, float, float]) -> tuple[np.ndarray, tuple[float, float, float, float]] | None:
    """The cells of *image* (rows, cols[, bands]) meeting *box*, as RGBA in 0..1 and their extent.

    Floats above 1 are taken as 8-bit values (0..255), NaN cells are transparent.
    None when the image does not meet the box.
    """
    r0, r1, c0, c1 = _cell_window(image.shape, transform, box)
    if c1 <= c0 or r1 <= r0:
        return None
    sub = np.asarray(image[r0:r1, c0:c1], dtype=np.float64)
    if sub.ndim == 2:
        sub = sub[..., None]
    valid = np.isfinite(sub).all(axis=2)
    if not valid.any():
        return None
    scale = 255.0 if (image.dtype == np.uint8 or np.nanmax(sub) > 1.0) else 1.0
    if image.dtype == np.uint16:
        scale = 65535.0
    rgb = np.clip(np.nan_to_num(sub[..., :3] / scale), 0.0, 1.0)
    if rgb.shape[2] == 1:
        rgb = np.repeat(rgb, 3, axis=2)
    elif rgb.shape[2] == 2:
        rgb = np.repeat(rgb[..., :1], 3, axis=2)
    rgba = np.concatenate([rgb, valid[..., None].astype(np.float64)], axis=2)
    c = transform.cell_m
    ext = (transform.x0 + c0 * c, transform.x0 + c1 * c, transform.y0 - r1 * c, transform.y0 - r0 * c)
    return rgba, ext


def _lines(features: Sequence[dict[str, Any]], kind: str) -> list[np.ndarray]:
    return [np.asarray(f["geometry"]["coordinates"], dtype=np.float64) for f in features
            if (f.get("properties") or {}).get("type", "intermediate") == kind]


def _meets(xy: np.ndarray, box: tuple[float, float, float, float]) -> bool:
    """True when the bounding box of the line *xy* (N, 2) meets *box*."""
    return bool(len(xy) and xy[:, 0].min() <= box[2] and xy[:, 0].max() >= box[0] and xy[:, 1].min() <= box[3]
                and xy[:, 1].max() >= box[1])


def _label_master(ax: Any, xy: np.ndarray, level: float, box: tuple[float, float, float, float],
                  min_len_m: float) -> bool:
    """Put the height of a master curve at the middle of its run inside *box* (module docstring)."""
    inside = (xy[:, 0] >= box[0]) & (xy[:, 0] <= box[2]) & (xy[:, 1] >= box[1]) & (xy[:, 1] <= box[3])
    if inside.sum() < 2:
        return False
    seg = np.hypot(*np.diff(xy, axis=0).T)
    seg_in = seg * (inside[1:] & inside[:-1])
    total = float(seg_in.sum())
    if total < min_len_m:
        return False
    s = np.concatenate([[0.0], np.cumsum(seg_in)])
    k = int(np.argmin(np.abs(s - total / 2) + np.where(inside, 0.0, np.inf)))
    a, b = xy[max(k - 1, 0)], xy[min(k + 1, len(xy) - 1)]
    ang = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
    if ang > 90:
        ang -= 180
    elif ang < -90:
        ang += 180
    lab = convention("label")
    ax.text(xy[k, 0], xy[k, 1], f"{level:g}", rotation=ang, rotation_mode="anchor", ha="center",
            va="center", fontsize=6, color=lab.rgb, zorder=6,
            bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8})
    return True


def draw_chart(sheet: Any, title: TitleBlock, *, image: np.ndarray | None, image_transform: GeoTransform | None,
               contours: Sequence[dict[str, Any]], spots: np.ndarray | None = None,
               sheets: Sequence[Any] = (), area: tuple[float, float, float, float] | None = None,
               crs: Any = None, label_min_m: float = 50.0) -> Any:
    """The chart of one sheet as a matplotlib Figure (module docstring).

    Parameters
    ----------
    sheet : Sheet or MapSheet
        The sheet (:mod:`lidarcat.production.sheets`, :mod:`lidarcat.production.mapindex`).
    title : TitleBlock
    image, image_transform : (rows, cols[, bands]) array and GeoTransform
        The orthomosaic (uint8, uint16 or float with NaN for nodata).
    contours : sequence of GeoJSON LineString features
        With properties ``level_m`` and ``type`` (``master``/``intermediate``),
        as :func:`lidarcat.production.contours.contour_features` makes them.
    spots : (M, 3+) array, optional
        Spot heights E, N, h (m).
    sheets : sequence of sheets
        Every sheet of the block, for the index map (default: this one).
    area : (xmin, ymin, xmax, ymax), optional
        The mapped area, drawn as the restitution limit.
    crs : CRS-like, optional
        Needed for a geographic (Brazilian index) sheet.
    label_min_m : float
        Master curves shorter than this inside the sheet are not labelled, m.

    Raises
    ------
    ProductError
        No orthomosaic, no contour line, or a sheet that meets neither the
        orthomosaic nor any contour (a sheet outside the data).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    if image is None or image_transform is None:
        raise ProductError(f"chart of sheet {sheet.name}: no orthomosaic given; an orthophoto chart is the "
                           "mosaic with the contours over it")
    if not contours:
        raise ProductError(f"chart of sheet {sheet.name}: no contour lines given")
    if not (isinstance(title.scale, (int, np.integer)) and title.scale > 0):
        raise ProductError(f"chart scale must be a positive whole denominator, got {title.scale!r}")
    box, ring = sheet_extent(sheet, crs)
    crop = crop_image(image, image_transform, box)
    contours = [f for f in contours if _meets(np.asarray(f["geometry"]["coordinates"], dtype=np.float64), box)]
    lines = {k: _lines(contours, k) for k in ("master", "intermediate")}
    meets = bool(contours)
    if crop is None and not meets:
        raise ProductError(f"chart of sheet {sheet.name}: the sheet (E {box[0]:.0f}..{box[2]:.0f}, "
                           f"N {box[1]:.0f}..{box[3]:.0f}) holds neither orthomosaic cells nor contours: "
                           "outside the data")
    w_m, h_m = box[2] - box[0], box[3] - box[1]
    map_w, map_h = w_m / title.scale / 0.0254, h_m / title.scale / 0.0254     # inches at scale
    fig_w = _MARGIN_IN + map_w + _MARGIN_IN + _PANEL_IN + 0.3
    fig_h = max(map_h + 2 * _MARGIN_IN, 7.5)
    fig = Figure(figsize=(fig_w, fig_h))
    ax = fig.add_axes((_MARGIN_IN / fig_w, (fig_h - map_h) / 2 / fig_h, map_w / fig_w, map_h / fig_h))
    if crop is not None:
        ax.imshow(crop[0], extent=crop[1], interpolation="nearest", zorder=0)
    lw = 72.0 * _MM   # points per mm
    for kind in ("intermediate", "master"):
        cv = convention(kind)
        ax.add_collection(LineCollection(lines[kind], colors=cv.rgb, linewidths=cv.width_mm * lw, zorder=3))
    for f, xy in zip([f for f in contours if (f.get("properties") or {}).get("type") == "master"], lines["master"]):
        _label_master(ax, xy, float(f["properties"].get("level_m", float("nan"))), box, label_min_m)
    if spots is not None and len(spots):
        sp = np.asarray(spots, dtype=np.float64)
        sp = sp[(sp[:, 0] >= box[0]) & (sp[:, 0] <= box[2]) & (sp[:, 1] >= box[1]) & (sp[:, 1] <= box[3])]
        cv = convention("spot")
        ax.plot(sp[:, 0], sp[:, 1], "+", color=cv.rgb, markersize=4, mew=cv.width_mm * lw, zorder=5)
        for e, n, h in sp[:, :3]:
            ax.annotate(f"{h:.1f}", (e, n), xytext=(2, 2), textcoords="offset points", fontsize=5,
                        color=convention("label").rgb, zorder=6)
    if area is not None:
        cv = convention("boundary")
        ax.plot([area[0], area[2], area[2], area[0], area[0]], [area[1], area[1], area[3], area[3], area[1]],
                color=cv.rgb, lw=cv.width_mm * lw, zorder=4)
    cv = convention("sheet")
    ax.plot(ring[:, 0], ring[:, 1], color=cv.rgb, lw=cv.width_mm * lw, zorder=4)
    step = grid_interval(w_m)
    ge = np.arange(math.ceil(box[0] / step), math.floor(box[2] / step) + 1) * step
    gn = np.arange(math.ceil(box[1] / step), math.floor(box[3] / step) + 1) * step
    ge = ge[(ge > box[0] + 0.02 * w_m) & (ge < box[2] - 0.02 * w_m)]   # not on the frame: the corners stay clear
    gn = gn[(gn > box[1] + 0.02 * h_m) & (gn < box[3] - 0.02 * h_m)]
    g = convention("grid")
    ax.set_xticks(ge, [f"{e:.0f}" for e in ge])
    ax.set_yticks(gn, [f"{n:.0f}" for n in gn])
    ax.tick_params(labeltop=True, labelright=True, top=True, right=True, labelsize=6, direction="in")
    ax.tick_params(axis="y", labelrotation=90)
    for lab in ax.get_yticklabels():
        lab.set_verticalalignment("center")
    ax.grid(True, color=g.rgb, linewidth=g.width_mm * lw, alpha=0.8, zorder=2)
    ax.set_xlim(box[0], box[2])
    ax.set_ylim(box[1], box[3])
    ax.set_aspect("equal")
    _panel(fig, fig_w, fig_h, sheet, title, list(sheets) or [sheet], crs, Line2D)
    return fig


def _panel(fig: Any, fig_w: float, fig_h: float, sheet: Any, t: TitleBlock, sheets: list[Any], crs: Any,
           Line2D: Any) -> None:
    """Title block, legend of the conventions and index map in the right-hand panel."""
    x0 = (fig_w - _PANEL_IN - 0.3) / fig_w
    w = _PANEL_IN / fig_w
    top = 1.0 - 0.5 / fig_h
    tb = fig.add_axes((x0, top - 3.0 / fig_h, w, 3.0 / fig_h))
    tb.set_xticks([])
    tb.set_yticks([])
    rows = [("ORTHOPHOTO CHART (ortofotocarta)", 9, "bold"), (t.project, 8, "bold"),
            (f"Sheet: {sheet.name}", 7, "normal"), (f"Scale 1:{t.scale:,}", 8, "bold"),
            (f"Datum and projection: {t.datum_projection}", 6, "normal"),
            (f"Magnetic declination: {format_declination(t.declination_deg, t.declination_date)}", 6, "normal"),
            (f"Contours every {t.contour_interval_m:g} m, master curves every "
             f"{t.contour_interval_m * t.master_every:g} m", 6, "normal"),
            ("Grid: UTM coordinates, metres", 6, "normal"), (f"Date: {t.date}", 6, "normal")]
    y = 0.93
    for text, size, weight in rows:
        tb.text(0.04, y, text, fontsize=size, fontweight=weight, va="top", wrap=True)
        y -= 0.105
    lg = fig.add_axes((x0, top - 5.3 / fig_h, w, 2.1 / fig_h))
    lg.set_axis_off()
    lw = 72.0 * _MM
    handles = []
    for key, label in (("master", "master curve"), ("intermediate", "intermediate curve"),
                       ("spot", "spot height"), ("grid", "UTM grid"), ("boundary", "limit of the mapped area"),
                       ("sheet", "sheet frame")):
        cv = convention(key)
        if key == "spot":
            h = Line2D([], [], color=cv.rgb, marker="+", ls="none", markersize=6)
        else:
            h = Line2D([], [], color=cv.rgb, lw=max(cv.width_mm * lw, 0.5))
        handles.append((h, f"{label} ({cv.layer}, colour {cv.colour_number})"))
    lg.legend([h for h, _ in handles], [s for _, s in handles], loc="upper left", fontsize=6,
              title="Conventions", title_fontsize=7, frameon=True)
    im = fig.add_axes((x0 + 0.1 * w, 0.5 / fig_h, 0.8 * w, 1.9 / fig_h))
    im.set_title("Index map", fontsize=7)
    im.set_xticks([])
    im.set_yticks([])
    for s in sheets:
        _, ring = sheet_extent(s, crs)
        this = s.name == sheet.name
        im.fill(ring[:, 0], ring[:, 1], color="#9a9a9a" if this else "white", ec="black", lw=0.5)
        if len(sheets) <= 30:
            im.text(ring[:-1, 0].mean(), ring[:-1, 1].mean(), s.name, fontsize=3.5, ha="center", va="center")
    im.set_aspect("equal")


def write_chart(fig: Any, pdf_path: str | os.PathLike, png_path: str | os.PathLike | None = None, *,
                dpi: int = 150) -> tuple[Path, Path | None]:
    """Write the figure as PDF (TrueType fonts, no creation date: the same chart gives the same bytes)
    and PNG at *dpi*, atomically."""
    import matplotlib

    from .._util import atomic_write

    pdf_path = Path(pdf_path)
    with matplotlib.rc_context({"pdf.fonttype": 42}), atomic_write(pdf_path, "wb") as fh:
        fig.savefig(fh, format="pdf", metadata={"CreationDate": None})
    if png_path is not None:
        png_path = Path(png_path)
        with atomic_write(png_path, "wb") as fh:
            fig.savefig(fh, format="png", dpi=dpi, metadata={"Software": None})
    return pdf_path, png_path


# ----------------------------------------------------------------------------- in parallel


def _draw_one(task: dict[str, Any]) -> list[str]:
    """Draw and write one chart (on a runner's worker or in-process); the file names written."""
    c = task["common"]
    fig = draw_chart(task["sheet"], c["title"], image=task["image"], image_transform=task["transform"],
                     contours=task["contours"], spots=task["spots"], sheets=c["sheets"], area=c["area"],
                     crs=c["crs"])
    folder, name = Path(c["folder"]), task["name"]
    write_chart(fig, folder / f"{name}.pdf", folder / f"{name}.png", dpi=c["dpi"])
    return [f"{name}.pdf", f"{name}.png"]


def _task(sheet: Any, name: str, image: np.ndarray, transform: GeoTransform,
          contours: Sequence[dict[str, Any]], boxes: np.ndarray, spots: np.ndarray | None, crs: Any,
          common: dict[str, Any]) -> dict[str, Any]:
    """What one sheet's chart needs (module docstring, "In parallel")."""
    box = sheet_extent(sheet, crs)[0]
    r0, r1, c0, c1 = _cell_window(image.shape, transform, box)
    c = transform.cell_m
    if c1 > c0 and r1 > r0:
        sub = np.ascontiguousarray(image[r0:r1, c0:c1])
        sub_t = GeoTransform(transform.x0 + c0 * c, transform.y0 - r0 * c, c)
    else:
        sub, sub_t = image[0:0, 0:0], transform
    meet = np.flatnonzero((boxes[:, 0] <= box[2]) & (boxes[:, 2] >= box[0]) & (boxes[:, 1] <= box[3])
                          & (boxes[:, 3] >= box[1]))
    sp = None
    if spots is not None and len(spots):
        a = np.asarray(spots, dtype=np.float64)
        sp = a[(a[:, 0] >= box[0]) & (a[:, 0] <= box[2]) & (a[:, 1] >= box[1]) & (a[:, 1] <= box[3])]
    # none meeting the sheet: one that does not, so that draw_chart says "outside the data" as it would
    feats = [contours[i] for i in meet] if meet.size else list(contours[:1])
    return {"sheet": sheet, "name": name, "image": sub, "transform": sub_t, "contours": feats, "spots": sp,
            "common": common}


def render_charts(todo: Sequence[Any], names: Sequence[str], title: TitleBlock, folder: str | os.PathLike, *,
                  image: np.ndarray, image_transform: GeoTransform, contours: Sequence[dict[str, Any]],
                  spots: np.ndarray | None = None, sheets: Sequence[Any] = (),
                  area: tuple[float, float, float, float] | None = None, crs: Any = None, dpi: int = 150,
                  workers: int | None = None, scheduler: str | None = None,
                  progress: Callable[[int, int], Any] | None = None) -> list[str]:
    """Draw and write the chart of every sheet of *todo* as ``<name>.pdf`` and ``.png`` in *folder*.

    Parameters
    ----------
    todo : sequence of sheets
    names : sequence of str
        File name of each sheet's chart (safe path components), same length.
    title, image, image_transform, contours, spots, sheets, area, crs
        As :func:`draw_chart`.
    dpi : int
        PNG resolution.
    workers, scheduler : optional
        As the tile runner (:func:`lidarcat.lidar.jobs.run_tasks`): default serially in this process;
        *workers* processes of a local Dask cluster; or the running Dask scheduler at *scheduler*
        (its workers must see *folder*).
    progress : callable, optional
        ``progress(done, total)`` after each chart, in the calling process.

    Returns
    -------
    list of str
        The files written, relative to *folder*, in the order of *todo*.

    Raises
    ------
    ProductError
        As :func:`draw_chart` (the first failing sheet's error, re-raised here).
    """
    from ..lidar.jobs import run_tasks

    if len(names) != len(todo):
        raise ProductError(f"render_charts: {len(todo)} sheets and {len(names)} names")
    boxes = np.array([[*np.min(np.asarray(f["geometry"]["coordinates"], dtype=float)[:, :2], axis=0),
                       *np.max(np.asarray(f["geometry"]["coordinates"], dtype=float)[:, :2], axis=0)]
                      for f in contours]).reshape(-1, 4)
    common = {"title": title, "sheets": list(sheets), "area": area, "crs": crs, "dpi": dpi, "folder": str(folder)}
    n = len(todo)
    done = 0

    def tick(k: int) -> None:
        nonlocal done
        done += k
        if progress is not None:
            progress(done, n)

    tasks = (_task(s, name, image, image_transform, contours, boxes, spots, crs, common)
             for s, name in zip(todo, names))
    if workers is not None:
        workers = max(1, min(int(workers), n))
    results = run_tasks(_draw_one, tasks, workers=workers, scheduler=scheduler, progress=tick)
    return [f for r in results for f in r]
