"""Clipping LiDAR points around a roof for plane extraction (thesis section 3.2.3).

The thesis cuts the points within 2.5-5.0 m of the approximate plan position
of a roof vertex, then drops every point whose height differs by more than
2.0 m from the mean height of the clip ("pre-filtering", to remove ground
points).  :func:`clip` does this (``height_filter="thesis"``) and offers better
options, applied in this order:

1. plan radius around ``center_en`` (edge included);
2. ``first_returns_only``: keep first (or only) returns, which hit the roof
   skin rather than vegetation or walls underneath;
3. ``classes``: keep only these LAS classes (e.g. ``[6]`` buildings);
4. ``height_filter``:

   ``"thesis"``
       keep ``|h - mean(h)| <= height_window_m``.  With much ground in the clip
       the mean falls between ground and roof and the window cuts both.
   ``"robust"``
       keep ``|h - h_roof| <= height_window_m`` where ``h_roof`` is the median
       of the points at or above the clip's median height.  The roof is the
       upper surface of a clip centred on it, so while ground (and other low
       points) make up less than about three quarters of the clip, ``h_roof`` is
       a roof height.  Tall roofs (steep gables whose ridge and eaves differ
       by more than twice the window) need a larger ``height_window_m``.
   ``None``
       no height filter.

5. at least ``min_points`` must remain (the thesis needs 6 per roof face),
   otherwise :class:`~lidarcat.errors.ClipError` names the position, the
   radius and how many points were found.
"""

from __future__ import annotations

import logging
import os
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ..errors import ClipError, CRSError, LidarFormatError
from .cloud import PointCloud
from .crs import crs_compatible, crs_label, require_metres, resolve_crs, transform_points
from .membership import in_radius
from .tileindex import TileIndex
from .tiles import expand_paths

__all__ = ["clip", "height_window_mask", "HEIGHT_FILTERS"]

log = logging.getLogger(__name__)

HEIGHT_FILTERS = ("thesis", "robust", None)


def height_window_mask(h: np.ndarray, method: str | None = "thesis", window_m: float = 2.0) -> np.ndarray:
    """Mask of heights kept by a height pre-filter (see the module docstring).

    Parameters
    ----------
    h : ndarray, shape (N,)
        Heights, metres.
    method : {"thesis", "robust", None}
    window_m : float
        Half-width of the kept window, metres (thesis: 2.0).

    Examples
    --------
    >>> h = np.array([0.1, 0.0, 0.2, 0.1, 8.0, 8.2, 8.4, 8.1, 8.3, 8.2])
    >>> int(height_window_mask(h, "thesis").sum())   # mean 4.96: neither ground nor roof
    0
    >>> height_window_mask(h, "robust").nonzero()[0].tolist()
    [4, 5, 6, 7, 8, 9]
    """
    h = np.asarray(h, dtype=np.float64)
    if method is None or len(h) == 0:
        return np.ones(len(h), dtype=bool)
    if not window_m > 0:
        raise ValueError(f"height_window_m must be positive, got {window_m}")
    if method == "thesis":
        ref = float(h.mean())
    elif method == "robust":
        upper = h[h >= np.median(h)]
        ref = float(np.median(upper))
    else:
        raise ValueError(f"unknown height_filter {method!r}; use 'thesis', 'robust' or None")
    return np.abs(h - ref) <= window_m


_INDEXES: OrderedDict[tuple, TileIndex] = OrderedDict()


def _index_for(source: Any, crs: Any) -> TileIndex:
    """A TileIndex for *source* paths, reused across calls while the files are unchanged.

    Many clips in one file (the thesis's 18 roofs in one ASCII strip) then parse
    it once: the index keeps recently read tiles in memory.
    """
    paths = expand_paths(source)
    stats = tuple((str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in paths)
    crs_obj = resolve_crs(crs)
    key = (stats, None if crs_obj is None else crs_obj.to_wkt())
    index = _INDEXES.get(key)
    if index is None:
        index = TileIndex.build(paths, crs=crs_obj)
        _INDEXES[key] = index
        while len(_INDEXES) > 4:
            _INDEXES.popitem(last=False)
    else:
        _INDEXES.move_to_end(key)
    return index


def _describe_position(center: np.ndarray, crs: Any) -> str:
    where = f"E={center[0]:.3f} N={center[1]:.3f}"
    return where if crs is None else f"{where} ({crs_label(crs)})"


def clip(source: PointCloud | TileIndex | str | os.PathLike | Iterable[str | os.PathLike],
         center_en: Sequence[float], radius_m: float, *, height_filter: str | None = "thesis",
         height_window_m: float = 2.0, first_returns_only: bool = False,
         classes: Iterable[int] | None = None, min_points: int = 10, crs: Any = None,
         lidar_crs: Any = None) -> PointCloud:
    """Points around a roof position, pre-filtered for plane extraction.

    Parameters
    ----------
    source : PointCloud, TileIndex, path or list of paths/globs
        Where the points come from; paths are indexed on the fly (only tiles
        near the position are read) and the index is kept for the next call
        on the same unchanged files, so that many clips read each tile once.
    center_en : (E, N)
        Approximate plan position of the roof vertex, metres.
    radius_m : float
        Clip radius, metres (thesis: 2.5-5.0).
    height_filter : {"thesis", "robust", None}
        See the module docstring.
    height_window_m : float
        Half-width of the height window, metres (thesis: 2.0).
    first_returns_only : bool
        Keep only first (or only) returns.
    classes : iterable of int, optional
        Keep only these LAS classes (e.g. ``[6]``, buildings).
    min_points : int
        Fewest points accepted after filtering.
    crs : CRS-like, optional
        CRS of *center_en*.  When *source* is given as paths whose files carry
        no CRS and *lidar_crs* is not given, the files are taken to be in
        *crs* too.
    lidar_crs : CRS-like, optional
        CRS of files that carry none (paths only).

    Returns
    -------
    PointCloud
        The kept points, in the CRS of the LiDAR data.

    Raises
    ------
    ClipError
        Fewer than *min_points* points remain (the message names the position,
        the radius, and the count at each step); a position that is not two
        finite numbers; a radius that is not positive.
    CRSError
        The position's CRS cannot be related to the data's.
    LidarFormatError
        ``first_returns_only`` or ``classes`` asked of data without return
        numbers or classes.
    """
    if height_filter not in HEIGHT_FILTERS:
        raise ValueError(f"unknown height_filter {height_filter!r}; use 'thesis', 'robust' or None")
    if not radius_m > 0:
        raise ClipError(f"clip radius must be positive, got {radius_m} m")
    center = np.asarray(center_en, dtype=np.float64).ravel()[:2]
    if len(center) != 2 or not np.isfinite(center).all():
        raise ClipError(f"clip position must be two finite numbers (E, N) in metres, got {center_en!r}")
    q_crs = resolve_crs(crs)
    if isinstance(source, PointCloud):
        data_crs = source.crs
        require_metres(data_crs, f"a clip radius of {radius_m:g} m")
        c = center
        if q_crs is not None and not crs_compatible(q_crs, data_crs):
            if data_crs is None:
                raise CRSError(f"the clip position is in {crs_label(q_crs)} but the points have no CRS")
            c = transform_points(center, q_crs, data_crs)
        found = source.select(in_radius(source.xyz, c, radius_m))
        coverage = source.bounds
    else:
        index = source if isinstance(source, TileIndex) else \
            _index_for(source, lidar_crs if lidar_crs is not None else q_crs)
        data_crs = index.crs
        found = index.query_radius(center, radius_m, crs=q_crs)
        coverage = index.bounds
    where = _describe_position(center, q_crs if q_crs is not None else data_crs)
    steps = [f"{len(found)} within {radius_m:g} m"]
    if len(found) == 0:
        raise ClipError(f"no LiDAR points within {radius_m:g} m of {where}; the data cover "
                        f"E {coverage.xmin:.1f}..{coverage.xmax:.1f}, N {coverage.ymin:.1f}..{coverage.ymax:.1f}")
    keep = np.ones(len(found), dtype=bool)
    if first_returns_only:
        if not found.has("return_number"):
            raise LidarFormatError(f"first_returns_only: the points at {where} carry no return numbers")
        keep &= found.first_returns()
        steps.append(f"{int(keep.sum())} first returns")
    if classes is not None:
        wanted = sorted({int(c) for c in classes})
        if not found.has("classification"):
            raise LidarFormatError(f"classes={wanted}: the points at {where} carry no classification")
        keep &= np.isin(found.attributes["classification"], wanted)
        steps.append(f"{int(keep.sum())} in class {','.join(map(str, wanted))}")
    if height_filter is not None and keep.any():
        idx = np.flatnonzero(keep)
        keep[idx] = height_window_mask(found.xyz[idx, 2], height_filter, height_window_m)
        steps.append(f"{int(keep.sum())} after the {height_filter} height filter "
                     f"(+-{height_window_m:g} m)")
    n = int(keep.sum())
    if n < min_points:
        raise ClipError(f"only {n} LiDAR points kept around {where} (radius {radius_m:g} m: "
                        f"{'; '.join(steps)}); at least {min_points} are needed: enlarge the radius "
                        "or relax the filters")
    log.debug("clip at %s: %s", where, "; ".join(steps))
    return found.select(keep)
