r"""Ellipsoidal and orthometric heights: declared per source, converted with a user geoid grid.

LiDAR and GNSS heights are usually **ellipsoidal** (h, above the ellipsoid),
levelled control and map heights **orthometric** (H, above the geoid); they
differ by the geoid undulation N (tens of metres):

.. math::  H = h - N(\varphi, \lambda)

A survey declares, in ``survey.toml``, what each source's heights are, and the
geoid model as a grid file (GTX, GeoTIFF, ... anything PROJ's ``vgridshift``
reads; lidarcat ships none and downloads none)::

    [survey]
    height_system = "orthometric"        # the heights the adjustment works in
    [heights]
    sources = { gps = "orthometric", lidar = "ellipsoidal", photos = "ellipsoidal" }
    geoid_grid = "geoid/hBR_MAPGEO2015.tif"   # relative to the survey folder

``sources`` keys are the words of ``ground_points.csv`` column ``source`` plus
``photos`` (positions in photos.csv); an undeclared source takes the survey's
height system.  :func:`harmonise_ground_points` converts every ground point to
the survey system; when a conversion is needed and no grid is declared it stops
with a :class:`HeightError` naming the source and what to add, instead of
silently mixing h and H.

A compound CRS (e.g. ``EPSG:7415`` Amersfoort / RD New + NAP height) or a 3D
geographic CRS (``EPSG:4979``) already says what its heights are
(:func:`height_system_of_crs`); a declaration that contradicts it is an error.
A 2D CRS such as SIRGAS 2000 / UTM zone 22S (``EPSG:31982``) says nothing, so the
declaration decides.  N is evaluated with PROJ: the grid is sampled at the
geographic position of each point (horizontal CRS -> its geographic CRS ->
``vgridshift``, bilinear interpolation).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidarcatError, location

__all__ = ["HEIGHT_SYSTEMS", "HeightError", "HeightDeclarations", "height_system_of_crs",
           "read_height_declarations", "geoid_undulation", "convert_heights", "harmonise_ground_points",
           "write_harmonised_survey", "json_report"]

log = logging.getLogger(__name__)

HEIGHT_SYSTEMS = ("ellipsoidal", "orthometric")


class HeightError(LidarcatError, ValueError):
    """Heights of different systems would be mixed, or a declaration is invalid (names file and key)."""


def height_system_of_crs(crs: str) -> str | None:
    """``orthometric``/``ellipsoidal`` when the CRS itself fixes the heights, else None.

    >>> height_system_of_crs("EPSG:7415")      # Amersfoort / RD New + NAP height
    'orthometric'
    >>> height_system_of_crs("EPSG:4979")      # WGS 84 3D: ellipsoidal heights
    'ellipsoidal'
    >>> height_system_of_crs("EPSG:31982") is None   # SIRGAS 2000 / UTM 22S: 2D
    True
    """
    from pyproj import CRS

    c = CRS.from_user_input(crs)
    if c.is_compound:
        return "orthometric" if any(s.is_vertical for s in c.sub_crs_list) else None
    if len(c.axis_info) == 3 and (c.is_geographic or c.is_projected):
        return "ellipsoidal"
    return None


@dataclass(frozen=True)
class HeightDeclarations:
    """What each source's heights are, and the geoid grid (from survey.toml).

    Attributes
    ----------
    survey_system : str
        ``[survey] height_system``.
    sources : dict[str, str]
        Source word -> ``ellipsoidal`` | ``orthometric``.
    geoid_grid : Path or None
    """

    survey_system: str
    sources: dict[str, str] = field(default_factory=dict)
    geoid_grid: Path | None = None

    def of(self, source: str) -> str:
        return self.sources.get(source, self.survey_system)


def read_height_declarations(survey: Any) -> HeightDeclarations:
    """The ``[heights]`` table of a survey, checked.

    Raises
    ------
    HeightError
        A value that is not ellipsoidal/orthometric, a missing grid file, or a
        declaration that contradicts the survey CRS (``survey.toml:LINE: field``).
    """
    from ..survey.folder import Survey

    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    cfg = survey.config   # survey.toml as Survey.load parsed and type-checked it
    where = lambda key: location(survey.toml_path, cfg.line("heights", key), key)  # noqa: E731
    sources = dict(cfg.heights.sources or {})
    for k, v in sources.items():
        if v not in HEIGHT_SYSTEMS:
            raise HeightError(f"{where('sources')}: source {k!r}: {v!r} is not one of {', '.join(HEIGHT_SYSTEMS)}")
    grid = None
    if cfg.heights.geoid_grid is not None:
        g = Path(cfg.heights.geoid_grid)
        grid = g if g.is_absolute() else survey.root / g
        if not grid.is_file():
            raise HeightError(f"{where('geoid_grid')}: geoid grid {cfg.heights.geoid_grid!r} not found ({grid})")
    system = survey.height_system
    implied = height_system_of_crs(survey.crs)
    if implied is not None and system in HEIGHT_SYSTEMS and system != implied:
        raise HeightError(f"{location(survey.toml_path, cfg.line('survey', 'height_system'), 'height_system')}: "
                          f"{system!r} contradicts the CRS {survey.crs}, whose heights are {implied}")
    if system not in HEIGHT_SYSTEMS:
        system = implied or system
    return HeightDeclarations(system, dict(sources), grid)


def geoid_undulation(e: Any, n: Any, crs: str, geoid_grid: str | Path) -> np.ndarray:
    """Geoid undulation N (m) of a grid file at points (E, N) of *crs* (its horizontal part).

    Raises
    ------
    HeightError
        The grid cannot be read by PROJ or does not cover a point (names the grid).
    """
    from pyproj import CRS, Transformer
    from pyproj.exceptions import ProjError

    grid = Path(geoid_grid)
    if not grid.is_file():
        raise HeightError(f"{grid}: geoid grid not found")
    c = CRS.from_user_input(crs)
    horiz = c.sub_crs_list[0] if c.is_compound else c
    to_geo = Transformer.from_crs(horiz, horiz.geodetic_crs, always_xy=True)
    lon, lat = to_geo.transform(np.asarray(e, float), np.asarray(n, float))
    pipe = (f"+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
            f"+step +proj=vgridshift +grids={grid.resolve()} +multiplier=1")
    try:
        tr = Transformer.from_pipeline(pipe)
        _, _, z = tr.transform(np.atleast_1d(lon), np.atleast_1d(lat), np.zeros(np.size(lon)), errcheck=True)
    except ProjError as ex:
        raise HeightError(f"{grid}: PROJ cannot use this geoid grid here ({ex})") from ex
    z = np.asarray(z, float)
    if not np.isfinite(z).all():
        raise HeightError(f"{grid}: the grid does not cover every point")
    return z


def convert_heights(e: Any, n: Any, h: Any, crs: str, from_system: str, to_system: str,
                    geoid_grid: str | Path | None) -> np.ndarray:
    """Heights converted between ``ellipsoidal`` (h) and ``orthometric`` (H = h - N).

    Raises
    ------
    HeightError
        Unknown system, or a conversion is needed and *geoid_grid* is None.
    """
    for s in (from_system, to_system):
        if s not in HEIGHT_SYSTEMS:
            raise HeightError(f"height system {s!r} is not one of {', '.join(HEIGHT_SYSTEMS)}")
    h = np.asarray(h, float)
    if from_system == to_system:
        return h.copy()
    if geoid_grid is None:
        raise HeightError(f"{from_system} -> {to_system} heights need a geoid model: give a grid file "
                          f"([heights] geoid_grid in survey.toml, or --geoid FILE)")
    nn = geoid_undulation(e, n, crs, geoid_grid)
    return h - nn if to_system == "orthometric" else h + nn


def harmonise_ground_points(survey: Any, to_system: str | None = None, geoid_grid: str | Path | None = None):
    """The survey's ground points with every height in one system.

    Parameters
    ----------
    survey : Survey or path
    to_system : str, optional
        Target system (default: the survey's ``height_system``).
    geoid_grid : path, optional
        Overrides ``[heights] geoid_grid``.

    Returns
    -------
    (GroundPoints, dict)
        The converted points and a report ``{source: {"from", "to", "n", "mean_N_m"}}``.

    Raises
    ------
    HeightError
        The target is not ellipsoidal/orthometric, or a source needs converting
        and no grid is available (names the source, the count and what to add).
    """
    from ..survey.folder import GroundPoints, Survey

    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    decl = read_height_declarations(survey)
    target = to_system or decl.survey_system
    if target not in HEIGHT_SYSTEMS:
        raise HeightError(f"{survey.toml_path}: field 'height_system': {target!r} is not ellipsoidal or "
                          f"orthometric; declare it (or give the target) before converting")
    grid = Path(geoid_grid) if geoid_grid is not None else decl.geoid_grid
    gp = survey.ground_points
    enh = np.array(gp.enh_m, dtype=float)
    report = {}
    for src in sorted(set(gp.source.tolist())):
        rows = gp.source == src
        frm = decl.of(src)
        if frm not in HEIGHT_SYSTEMS:
            raise HeightError(f"{survey.toml_path}: heights of source {src!r} are {frm!r}; declare them in "
                              f"[heights] sources (ellipsoidal or orthometric)")
        if frm == target:
            report[src] = {"from": frm, "to": target, "n": int(rows.sum()), "mean_N_m": 0.0}
            continue
        if grid is None:
            raise HeightError(f"{survey.toml_path}: {int(rows.sum())} ground point(s) of source {src!r} have "
                              f"{frm} heights, the survey works in {target} heights, and no geoid model is "
                              f"given: add [heights] geoid_grid = \"FILE\" (or --geoid FILE); lidarcat does "
                              f"not mix the two")
        new = convert_heights(enh[rows, 0], enh[rows, 1], enh[rows, 2], survey.crs, frm, target, grid)
        report[src] = {"from": frm, "to": target, "n": int(rows.sum()),
                       "mean_N_m": float(np.mean(np.abs(new - enh[rows, 2])))}
        enh[rows, 2] = new
    out = GroundPoints(gp.point, enh, gp.sd_m, gp.source, gp.line, gp.path)
    return out, report


def write_harmonised_survey(survey: Any, folder: str | Path, *, to_system: str | None = None,
                            geoid_grid: str | Path | None = None, overwrite: bool = False) -> tuple[Path, dict]:
    """Copy a survey to *folder* with every ground-point height in one system, atomically.

    ``ground_points.csv`` gets the converted heights (its JSON sidecar says from
    what), ``[survey] height_system`` the target and ``[heights] sources`` is
    emptied (every source is now in the survey system).

    Returns
    -------
    (folder, report) as :func:`harmonise_ground_points`.

    Raises
    ------
    HeightError
        As :func:`harmonise_ground_points`; *folder* holds a survey and not *overwrite*.
    """
    import re

    from .._util import atomic_dir, write_csv_atomic, write_text_atomic
    from ..survey.folder import Survey
    from .merge import copy_survey_files

    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    folder = Path(folder)
    if (folder / "survey.toml").exists() and not overwrite:
        raise HeightError(f"{folder}: already holds a survey.toml; choose another folder or pass overwrite (--force)")
    gp, report = harmonise_ground_points(survey, to_system, geoid_grid)
    target = to_system or read_height_declarations(survey).survey_system
    rel = survey.files["ground_points"].relative_to(survey.root)
    text = survey.toml_path.read_text(encoding="utf-8")
    text = re.sub(r"(?m)^(\s*sources\s*=).*$", r"\1 {}", text)
    if re.search(r"(?m)^\s*height_system\s*=", text):
        text = re.sub(r"(?m)^(\s*height_system\s*=)[^#\n]*", rf'\1 "{target}"  ', text)
    else:
        text = re.sub(r"(?m)^\[survey\]\s*$", f'[survey]\nheight_system = "{target}"', text, count=1)
    with atomic_dir(folder) as tmp:
        copy_survey_files(survey, tmp, skip={rel, Path("survey.toml")})
        write_csv_atomic(tmp / rel, ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"],
                         [[p, *x, *s, src] for p, x, s, src in zip(gp.point.tolist(), gp.enh_m, gp.sd_m,
                                                                   gp.source.tolist())],
                         comments=[f"heights converted to {target}: " + json_report(report)])
        write_text_atomic(tmp / "survey.toml", text)
    return folder, report


def json_report(report: dict) -> str:
    """One line per source: ``source: from -> to (n points, mean |N| m)``."""
    return "; ".join(f"{k}: {v['from']} -> {v['to']} ({v['n']} points, mean |N| {v['mean_N_m']:.3f} m)"
                     for k, v in report.items())
