"""The checks :mod:`lidarcat.interop.block` makes before it writes a survey folder: every value in
its sane range (:data:`lidarcat._util.values.VALUE_RANGES`), every standard deviation within the
survey's :data:`~lidarcat.survey.schema.SD_BOUNDS`, and a survey's ``source_cameras.json`` read with
its values checked -- so that what ``lidarcat import`` writes, ``Survey.load`` and ``adjust`` accept;
and the small helpers :mod:`lidarcat.interop.block` and :mod:`lidarcat.interop.merge` share.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .._util import read_text
from ..errors import FormatError
from ._text import format_error
from .cameras import SOURCE_KINDS, check_source_model

__all__ = ["check_values", "check_crs", "check_block", "read_source_models", "frozen_rows", "photo_eo", "toml_string",
           "PHOTO_COLUMNS_EO", "EO_KINDS", "ENH_KINDS"]


def check_values(where: str, what: str, ids: Any, values: np.ndarray, kinds: tuple[str, ...],
                 names: tuple[str, ...], lines: Any = None) -> None:
    """Refuse a value outside the sane range of its kind (:data:`lidarcat._util.values.VALUE_RANGES`;
    ``sd_m``/``sd_deg``: a standard deviation by the survey's :data:`~lidarcat.survey.schema.SD_BOUNDS`)
    before it is written: what ``import`` writes, ``adjust`` reads.  NaN is an absent value.

    Raises
    ------
    FormatError
        ``WHERE[:LINE]: field 'NAME': WHAT 'ID': the problem`` for the first bad value.
    """
    from .._util.values import value_problem
    from ._text import sd_problem

    vals = np.asarray(values, dtype=float).reshape(len(values), len(kinds))
    for j, (kind, name) in enumerate(zip(kinds, names)):
        col = vals[:, j]
        for i in np.flatnonzero(~np.isnan(col)):
            v = float(col[i])
            problem = (sd_problem(v, kind[3:]) if kind.startswith("sd_") else value_problem(v, kind))
            if problem:
                line = int(lines[i]) if lines is not None and int(lines[i]) > 0 else None
                raise format_error(where, line, name, f"{what} {str(np.asarray(ids)[i])!r}: {problem}")


def check_crs(crs: str | None, *, option: str = "--crs", local: bool = False) -> str | None:
    """*crs* unchanged when pyproj knows it (or, with *local*, when it declares a local frame
    ``local: <description>``); None stays None.

    >>> check_crs("EPSG:31982")
    'EPSG:31982'
    >>> check_crs("not a crs")
    Traceback (most recent call last):
    ...
    lidarcat.errors.FormatError: --crs 'not a crs' is not a CRS pyproj knows: give EPSG:nnnn (e.g. EPSG:31982), a WKT or a PROJ string

    Raises
    ------
    FormatError
        Names the option, the value and what to give instead.
    """
    from ..errors import CRSError
    from ..lidar.crs import resolve_crs
    from ..survey.folder import is_local_crs

    if crs is None or (local and is_local_crs(crs)):
        return crs
    try:
        if resolve_crs(crs) is not None:
            return crs
    except CRSError:
        pass
    raise FormatError(f"{option} {crs!r} is not a CRS pyproj knows: give EPSG:nnnn (e.g. EPSG:31982), a WKT or "
                      f"a PROJ string" + (", or 'local: <description>' for a frame that is not georeferenced"
                                          if local else ""))


def check_area(where: str, what: str, crs: str, ids: Any, en: np.ndarray, lines: Any = None) -> None:
    """Refuse E, N outside the area of use of the survey CRS *crs* (as :meth:`lidarcat.Survey.load`
    does), before they are written; a local frame or an unknown CRS is left to the survey's own check.

    Raises
    ------
    FormatError
        ``WHERE[:LINE]: WHAT 'ID': ... outside the area of use of CRS``.
    """
    from ..errors import CRSError
    from ..lidar.crs import check_area_of_use, resolve_crs
    from ..survey.folder import is_local_crs

    if not crs or crs in ("", "unspecified") or is_local_crs(crs):
        return
    en = np.asarray(en, dtype=float).reshape(-1, 2)
    ok = np.isfinite(en).all(axis=1)
    if not ok.any():
        return
    try:
        c = resolve_crs(crs)
    except CRSError:
        return
    ids = np.asarray(ids)
    try:
        check_area_of_use(c, en[ok], ids=[str(x) for x in ids[ok]])
    except CRSError as ex:
        line = None
        if lines is not None:
            bad = [i for i in np.flatnonzero(ok) if str(ids[i]) in str(ex)]
            line = int(np.asarray(lines)[bad[0]]) if bad and int(np.asarray(lines)[bad[0]]) > 0 else None
        raise format_error(where, line, None, f"{what}: {ex}") from None


def check_block(block: Any) -> None:
    """:func:`check_values` over a whole block (before :func:`write_survey` writes it)."""
    w = block.name
    eo = np.column_stack([block.eo[:, :3], np.degrees(block.eo[:, 3:])])
    check_values(w, "photo", block.photo_ids, eo, EO_KINDS, PHOTO_COLUMNS_EO)
    if block.eo_sd is not None:
        sd = np.column_stack([block.eo_sd[:, :3], np.degrees(block.eo_sd[:, 3:])])
        check_values(w, "photo", block.photo_ids, sd, ("sd_m",) * 3 + ("sd_deg",) * 3,
                     tuple(f"sd_{n}" for n in PHOTO_COLUMNS_EO))
    obs = np.column_stack([block.obs_px, block.obs_mm])
    check_values(w, "measurement of point", block.obs_point, obs, ("pixel_px",) * 2 + ("photo_mm",) * 2,
                 ("col_px", "row_px", "x_mm", "y_mm"))
    if block.obs_sd_mm is not None:
        check_values(w, "measurement of point", block.obs_point, block.obs_sd_mm, ("sd_mm",) * 2,
                     ("sd_x_mm", "sd_y_mm"))
    check_values(w, "point", block.ground_ids, block.ground_m, ENH_KINDS, ("E", "N", "h"))
    check_values(w, "point", block.ground_ids, block.ground_sd_m, ("sd_m",) * 3, ("sd_E", "sd_N", "sd_h"))
    check_area(w, "photo", block.crs, block.photo_ids, block.eo[:, :2])
    check_area(w, "point", block.crs, block.ground_ids, block.ground_m[:, :2])


#: the columns of photos.csv an orientation fills, and their sane ranges (degrees for the angles)
PHOTO_COLUMNS_EO = ("X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg")
EO_KINDS = ("coordinate_m", "coordinate_m", "height_m", "angle_deg", "angle_deg", "angle_deg")
ENH_KINDS = ("coordinate_m", "coordinate_m", "height_m")


def read_source_models(path: Path, cameras: Any) -> dict[str, dict]:
    """``source_cameras.json`` of a survey folder: camera id -> source model (:func:`pinhole_camera`),
    for the cameras of the survey; every value checked (FormatError located at the camera)."""
    import json

    from .._util.values import value_problem

    text = read_text(path, FormatError)
    if text.count("[") + text.count("{") > 10 * max(len(cameras), 1) + 1000:  # a few levels per camera
        raise FormatError(f"{path}: too many nested arrays/objects for a camera file")
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as ex:
        raise FormatError(f"{path}: invalid JSON: {str(ex)[:120]}") from None
    if not isinstance(doc, dict):
        raise FormatError(f"{path}: expected an object camera id -> model")
    out = {}
    for cid, m in doc.items():
        if cid not in cameras:
            continue
        bad = None
        if not isinstance(m, dict) or not isinstance(m.get("dist", {}), dict):
            bad = "not an object with fx, fy, cx, cy, w, h, dist"
        else:
            for k, kind in (("fx", "pixel_px"), ("fy", "pixel_px"), ("cx", "pixel_px"), ("cy", "pixel_px"),
                            ("w", "image_px"), ("h", "image_px"), ("skew", None)):
                v = m.get(k, 0.0 if k == "skew" else None)
                if isinstance(v, bool) or not isinstance(v, (int, float)) or \
                        (isinstance(v, int) and abs(v) > 10 ** 18):
                    bad = f"{k}: expected a number"
                elif value_problem(float(v), kind) if kind else not np.isfinite(v):
                    bad = f"{k}: {value_problem(float(v), kind) if kind else 'not finite'}"
                if bad:
                    break
            for k, v in m.get("dist", {}).items():
                if not bad and (isinstance(v, bool) or not isinstance(v, (int, float)) or
                                (isinstance(v, int) and abs(v) > 10 ** 18) or not np.isfinite(v)):
                    bad = f"dist {k}: expected a finite number"
        if not bad and m.get("kind", "brown") not in SOURCE_KINDS:
            bad = f"kind: {str(m.get('kind'))[:40]!r} is not a camera model kind ({', '.join(SOURCE_KINDS)})"
        if bad:
            raise FormatError(f"{path}: camera {cid!r}: {bad}")
        m = {**m, "kind": m.get("kind", "brown")}
        check_source_model(cid, m, str(path))
        out[cid] = m
    return out


def frozen_rows(a: Any, shape_tail: tuple[int, ...], dtype: Any = float) -> np.ndarray:
    """*a* as a read-only array of rows of shape *shape_tail* (``()``: a vector)."""
    from .._util.frozen import frozen_array

    out = frozen_array(a, dtype=dtype)
    return out.reshape((-1, *shape_tail)) if shape_tail else out.reshape(-1)


def photo_eo(photos: Any) -> tuple[np.ndarray, np.ndarray]:
    """(P, 6) orientations and sds (m, rad; NaN where absent) of survey photos."""
    eo = np.full((len(photos), 6), np.nan)
    esd = np.full((len(photos), 6), np.nan)
    for k, ph in enumerate(photos):
        for arr, pos, att in ((eo, ph.position_m, ph.attitude_deg), (esd, ph.sd_position_m, ph.sd_attitude_deg)):
            if pos is not None:
                arr[k, :3] = pos
            if att is not None:
                arr[k, 3:] = np.radians(att)
    return eo, esd


def toml_string(s: str) -> str:
    """*s* as a TOML basic string (JSON's escapes are TOML's)."""
    import json

    return json.dumps(s, ensure_ascii=False)
