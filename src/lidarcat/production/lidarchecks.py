"""LiDAR system checks (LACTEC report 7.1): vertical and planimetric accuracy against surveyed points.

Arrays in and out (no files):


1. **Vertical accuracy against surveyed check points** (the report's 900
   runway points, 7.1.1).  The LiDAR height at each check point is read from
   the points given (ground or last returns) either by the TIN (linear
   interpolation in the Delaunay triangle holding the point) or by a local
   plane ``z = a + b dx + c dy`` fitted by least squares to the points within
   a radius.  The discrepancy is ``dz = z_lidar - H_check``.  Reported as
   ASPRS 2023 NVA (``RMSE_z`` on non-vegetated points, ``1.96 RMSE_z`` the
   95 % figure of the 2014 edition and NSSDA), VVA (``RMSE_z`` of the
   vegetated points, which Edition 2 reports; and the 95th percentile of
   ``|dz|`` of the 2014 edition, linear interpolation between order
   statistics, ``numpy.percentile`` default), the ASPRS 2023 class
   (:func:`lidarcat.accuracy.standards.classify_asprs2023`) and the Brazilian
   PEC altimetric class (:func:`~lidarcat.accuracy.standards.classify_pec`).

2. **Systematic parameters** (7.1.2): roll and pitch misalignment between the
   scanner and the INS (boresight), the scan-angle scale factor and the
   elevation bias, by least squares from (a) LiDAR points over a surveyed
   control surface (vertical) and (b) the differences between overlapping
   strips.
   The calibration is :mod:`lidarcat.production.lidarcalib` (the geolocation equation and the
   least-squares estimate) and :mod:`lidarcat.production.lidarcalib_tiles` (tile by tile on the tile
   engine); their names are importable from here as well.

Planimetric check against surveyed building outlines (7.1.1, Figure 5)
----------------------------------------------------------------------
The report surveys the corners of a building and compares them with the
building in the LiDAR.  Here each edge ``P_i -> P_i+1`` of a surveyed outline
(made counter-clockwise, outward normal ``n = (u_y, -u_x)`` for the edge
direction ``u``) is found in the points: roof points and low (ground) points
within ``band_m`` of the edge, away from the corners (the middle 80 % of
it), are binned every ``bin_m`` along the edge; in each bin the roof ends at
the outermost roof point (offset ``o_r`` along ``n``) and the ground starts
at the innermost low point beyond it (``o_g``), so the edge is at
``(o_r + o_g) / 2``.  With no low point the edge is ``o_r + ln 2 / (rho w)``:
for roof points of density ``rho`` (counted in the band inside the edge) the
gap between the outermost point of a bin ``w`` wide and the edge is
exponential (randomly spread points) with median ``ln 2 / (rho w)``.  The LiDAR edge is the line parallel to the surveyed one
at the median offset of the bins (robust to the gaps' long tail): a free direction would turn short edges (an 8 m wing at 0.5 m
spacing) by degrees, and the check is of a shift, not of the building's
shape; each LiDAR corner is the intersection of its two edges, and its discrepancy ``(dE, dN) =
corner_lidar - corner_surveyed``.  An edge with fewer than ``min_bins`` bins
leaves its two corners out (NaN).  Reported as ASPRS 2023 horizontal
accuracy (``RMSE_x``, ``RMSE_y``, ``RMSE_r = sqrt(RMSE_x^2 + RMSE_y^2)``)
and the PEC planimetric class at a scale (:func:`planimetric_accuracy`).

>>> round(vertical_accuracy(np.array([0.1, -0.1, 0.2, -0.2])).nva_rmse_m, 4)
0.1581
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..accuracy.standards import StandardResult, classify_asprs2023, classify_pec
from ..errors import ProductError
from .lidarcalib import (PARAMETER_NAMES, CalibrationResult, PulseRecords, SystemParameters, estimate_system_parameters,
                         geolocation_partials, georeference, pulses_from_points)
from .lidarcalib_tiles import (CalibrationObservations, bounds_tile, calibration_tile, estimate_from_observations,
                               merge_observations, point_keys, select_observations)

__all__ = [
    "PARAMETER_NAMES",
    "PulseRecords",
    "SystemParameters",
    "VerticalAccuracy",
    "CalibrationResult",
    "georeference",
    "geolocation_partials",
    "pulses_from_points",
    "lidar_heights_at",
    "vertical_accuracy",
    "estimate_system_parameters",
    "CalibrationObservations",
    "point_keys",
    "select_observations",
    "merge_observations",
    "estimate_from_observations",
    "calibration_tile",
    "bounds_tile",
    "OutlineEdges",
    "lidar_outline_corners",
    "planimetric_accuracy",
]


@dataclass(frozen=True, eq=False)
class VerticalAccuracy:
    """Vertical accuracy of a LiDAR surface against check points.

    Attributes
    ----------
    n_nonveg, n_veg : int
    nva_rmse_m : float
        RMSE_z of the non-vegetated discrepancies (ASPRS 2023 NVA).
    nva_95_m : float
        ``1.96 nva_rmse_m`` (ASPRS 2014 / NSSDA 95 % figure).
    mean_nonveg_m : float
    vva_rmse_m, vva_95th_percentile_m : float
        Vegetated: RMSE_z (Edition 2 reports it) and the 95th percentile of
        ``|dz|`` (Edition 1); NaN without vegetated points.
    asprs2023 : StandardResult
    pec : StandardResult or None
        PEC altimetric class when a scale and contour interval were given.
    """

    n_nonveg: int
    n_veg: int
    nva_rmse_m: float
    nva_95_m: float
    mean_nonveg_m: float
    vva_rmse_m: float
    vva_95th_percentile_m: float
    asprs2023: StandardResult
    pec: StandardResult | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"n_nonveg": self.n_nonveg, "n_veg": self.n_veg, "nva_rmse_m": self.nva_rmse_m,
                "nva_95_m": self.nva_95_m, "mean_nonveg_m": self.mean_nonveg_m,
                "vva_rmse_m": None if math.isnan(self.vva_rmse_m) else self.vva_rmse_m,
                "vva_95th_percentile_m": None if math.isnan(self.vva_95th_percentile_m)
                else self.vva_95th_percentile_m,
                "asprs2023": self.asprs2023.to_dict(), "pec": None if self.pec is None else self.pec.to_dict()}



# ----------------------------------------------------------------------------- vertical accuracy


def lidar_heights_at(points_m: np.ndarray, check_en_m: np.ndarray, *, method: str = "tin",
                     radius_m: float = 1.0, ids: Sequence[str] | None = None) -> np.ndarray:
    """LiDAR height at plan positions, by the TIN of the points or a local plane.

    Parameters
    ----------
    points_m : (N, 3) float
        Ground or last-return points (m).
    check_en_m : (M, 2) float
        Plan positions of the check points (m).
    method : {"tin", "plane"}
    radius_m : float
        Plane method: the points within this plan distance (at least 3).
    ids : sequence of str, optional
        Check-point ids for the error messages (default: row numbers from 1).

    Returns
    -------
    (M,) float, the heights (m).

    Raises
    ------
    ProductError
        Fewer than 3 points; a check point outside the triangulation (TIN) or
        with fewer than 3 points within the radius (plane), naming the point.
    """
    from scipy.spatial import Delaunay, cKDTree

    from ..geometry.tin import TinLocator

    pts = np.asarray(points_m, dtype=float)
    q = np.asarray(check_en_m, dtype=float).reshape(-1, 2)
    names = list(ids) if ids is not None else [str(i + 1) for i in range(q.shape[0])]
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise ProductError(f"LiDAR heights need at least 3 points as an (N, 3) array; got shape {pts.shape}")
    origin = pts[:, :2].mean(axis=0)
    xy = pts[:, :2] - origin
    ql = q - origin
    if method == "tin":
        loc = TinLocator(Delaunay(xy))
        simplex, w = loc.locate(ql)
        bad = np.flatnonzero(simplex < 0)
        if bad.size:
            i = int(bad[0])
            raise ProductError(f"check point {names[i]} ({q[i, 0]:.3f}, {q[i, 1]:.3f}) is outside the LiDAR "
                               f"triangulation ({bad.size} of {q.shape[0]} check points outside)")
        verts = loc.triangulation.simplices[simplex]
        return np.einsum("mk,mk->m", w, pts[verts, 2])
    if method == "plane":
        tree = cKDTree(xy)
        nbrs = tree.query_ball_point(ql, radius_m)
        out = np.empty(q.shape[0])
        for i, nb in enumerate(nbrs):  # one small fit per check point (hundreds, not millions)
            if len(nb) < 3:
                raise ProductError(f"check point {names[i]} ({q[i, 0]:.3f}, {q[i, 1]:.3f}) has {len(nb)} LiDAR "
                                   f"points within {radius_m:g} m; a plane needs at least 3")
            d = xy[nb] - ql[i]
            a = np.column_stack([np.ones(len(nb)), d])
            coef, *_ = np.linalg.lstsq(a, pts[nb, 2], rcond=None)
            out[i] = coef[0]
        return out
    raise ProductError(f"method must be 'tin' or 'plane', got {method!r}")


def vertical_accuracy(dz_nonveg_m: np.ndarray, dz_veg_m: np.ndarray | None = None, *,
                      checkpoint_sd_m: float | None = None, scale: float | None = None,
                      contour_interval_m: float | None = None) -> VerticalAccuracy:
    """ASPRS 2023 NVA / VVA and the PEC class from height discrepancies ``z_lidar - H_check``.

    Parameters
    ----------
    dz_nonveg_m : (N,) float
        Discrepancies on non-vegetated (hard, open) check points (m), N >= 1.
    dz_veg_m : (M,) float, optional
        Discrepancies on vegetated check points (m).
    checkpoint_sd_m : float, optional
        Vertical sd of the check-point survey (ASPRS 2023 product accuracy).
    scale, contour_interval_m : float, optional
        Map scale denominator and contour interval for the PEC altimetric class.

    Raises
    ------
    AssessmentError
        No non-vegetated discrepancy, or NaN among them.
    """
    dz = np.asarray(dz_nonveg_m, dtype=float).ravel()
    dv = np.asarray(dz_veg_m if dz_veg_m is not None else [], dtype=float).ravel()
    d = np.column_stack([np.zeros_like(dz), np.zeros_like(dz), dz])
    sd = None if checkpoint_sd_m is None else np.array([0.0, 0.0, checkpoint_sd_m])
    asprs = classify_asprs2023(d, checkpoint_sd_m=sd)
    rmse = float(np.sqrt(np.mean(dz * dz)))
    pec = None
    if scale is not None and contour_interval_m is not None:
        pec = classify_pec(d, scale, contour_interval_m)
    vva_rmse = float(np.sqrt(np.mean(dv * dv))) if dv.size else math.nan
    vva95 = float(np.percentile(np.abs(dv), 95)) if dv.size else math.nan
    return VerticalAccuracy(int(dz.size), int(dv.size), rmse, 1.96 * rmse, float(np.mean(dz)), vva_rmse, vva95,
                            asprs, pec)



# ----------------------------------------------------------------------------- planimetric check


@dataclass(frozen=True, eq=False)
class OutlineEdges:
    """The LiDAR corners of one surveyed outline (module docstring, "Planimetric check").

    Attributes
    ----------
    surveyed_m : (K, 2) float
        The outline's corners as given (without a closing repeat).
    lidar_m : (K, 2) float
        The corners from the LiDAR edges (NaN where an edge was not found).
    edge_offset_m : (K,) float
        Mean offset of the LiDAR edge from the surveyed edge ``i -> i+1`` along its outward normal (m).
    edge_bins : (K,) int
        Bins that fixed each edge.
    """

    surveyed_m: np.ndarray
    lidar_m: np.ndarray
    edge_offset_m: np.ndarray
    edge_bins: np.ndarray

    @property
    def discrepancies_m(self) -> np.ndarray:
        """(K, 2) ``lidar - surveyed`` (NaN rows where a corner was not found)."""
        return self.lidar_m - self.surveyed_m


def _spacing_m(xy: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    if len(xy) < 2:
        return math.nan
    d, _ = cKDTree(xy).query(xy, k=2)
    return float(np.median(d[:, 1]))


def lidar_outline_corners(outline_m: np.ndarray, roof_xyz: np.ndarray, low_xyz: np.ndarray | None = None, *,
                          band_m: float = 2.0, bin_m: float = 1.0, min_bins: int = 3,
                          spacing_m: float | None = None) -> OutlineEdges:
    """The corners of a surveyed building outline as the LiDAR sees them (module docstring).

    Parameters
    ----------
    outline_m : (K, 2) float
        Surveyed corners (E, N), K >= 3, in order (either way round; a closing repeat is dropped).
    roof_xyz : (N, 3) float
        Points on the roof (building class, or points well above the ground).
    low_xyz : (L, 3) float, optional
        Ground (low) points around the building: they bound the edge from outside.
    band_m, bin_m, min_bins
        Points within ``band_m`` of an edge, binned every ``bin_m`` along it; an edge needs ``min_bins``.
    spacing_m : float, optional
        Largest gap between the outermost roof point and the innermost low point that still brackets the
        edge (default: the median nearest-neighbour distance of the roof points); 3 x this.

    Raises
    ------
    ProductError
        Fewer than 3 distinct corners.
    """
    q = np.asarray(outline_m, dtype=float)[:, :2]
    if len(q) > 1 and np.allclose(q[0], q[-1]):
        q = q[:-1]
    if len(q) < 3:
        raise ProductError(f"a building outline needs at least 3 corners, got {len(q)}")
    xs, ys = q[:, 0], q[:, 1]
    ccw = (np.dot(xs, np.roll(ys, -1)) - np.dot(np.roll(xs, -1), ys)) > 0
    order = np.arange(len(q)) if ccw else np.arange(len(q))[::-1]
    qq = q[order]
    roof = np.asarray(roof_xyz, dtype=float)[:, :2]
    low = np.zeros((0, 2)) if low_xyz is None else np.asarray(low_xyz, dtype=float)[:, :2]
    s = spacing_m if spacing_m is not None else _spacing_m(roof)
    k = len(qq)
    lines = []
    offs = np.full(k, np.nan)
    nbins = np.zeros(k, dtype=int)
    for i in range(k):
        a, b = qq[i], qq[(i + 1) % k]
        length = float(np.hypot(*(b - a)))
        u = (b - a) / length
        n = np.array([u[1], -u[0]])
        nb = max(1, int(0.8 * length // bin_m))

        def local(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            r = xy - a
            return r @ u, r @ n

        tr, orr = local(roof)
        sel = (tr >= 0.1 * length) & (tr <= 0.9 * length) & (np.abs(orr) <= band_m)
        tr, orr = tr[sel], orr[sel]
        br = np.minimum(((tr - 0.1 * length) / (0.8 * length) * nb).astype(int), nb - 1)
        o_r = np.full(nb, -np.inf)
        np.maximum.at(o_r, br, orr)
        tl, ol = local(low)
        sel = (tl >= 0.1 * length) & (tl <= 0.9 * length) & (np.abs(ol) <= band_m)
        tl, ol = tl[sel], ol[sel]
        bl = np.minimum(((tl - 0.1 * length) / (0.8 * length) * nb).astype(int), nb - 1)
        beyond = ol > o_r[bl]
        o_g = np.full(nb, np.inf)
        np.minimum.at(o_g, bl[beyond], ol[beyond])
        have = np.isfinite(o_r)
        inner = np.count_nonzero((orr <= -0.5) & (orr >= -band_m))
        rho = inner / max(0.8 * length * (band_m - 0.5), 1e-9)
        gap = math.log(2.0) / max(rho * (0.8 * length / nb), 1e-9) if rho > 0 else 0.5 * s
        o_r, o_g = o_r[have], o_g[have]
        bracket = np.isfinite(o_g) & (o_g - o_r <= 3 * s)
        e_ok = np.where(bracket, 0.5 * (o_r + np.where(bracket, o_g, 0.0)), o_r + gap)
        if e_ok.size < min_bins:
            lines.append(None)
            continue
        offs[i] = float(np.median(e_ok))        # the edge parallel to the surveyed one
        lines.append((a + offs[i] * n, u))
        nbins[i] = int(e_ok.size)
    corners = np.full((k, 2), np.nan)
    for i in range(k):
        l1, l2 = lines[i - 1], lines[i]           # edges into and out of corner i
        if l1 is None or l2 is None:
            continue
        m = np.column_stack([l1[1], -l2[1]])
        if abs(np.linalg.det(m)) < 1e-6:
            continue
        t = np.linalg.solve(m, l2[0] - l1[0])
        corners[i] = l1[0] + t[0] * l1[1]
    back = np.argsort(order)
    # edge i of the given order runs from corner i to i+1: in reversed order it is edge (k - 2 - i) mod k
    edge_map = np.arange(k) if ccw else (k - 2 - np.arange(k)) % k
    return OutlineEdges(q, corners[back], offs[edge_map], nbins[edge_map])


def planimetric_accuracy(d_en_m: np.ndarray, *, checkpoint_sd_m: float | None = None,
                         scale: float | None = None) -> dict[str, Any]:
    """ASPRS 2023 horizontal accuracy and the PEC planimetric class of corner discrepancies (M, 2), m.

    Rows with NaN (corners not found) are left out and counted.

    Raises
    ------
    AssessmentError
        No finite discrepancy.
    """
    from ..errors import AssessmentError

    d = np.asarray(d_en_m, dtype=float).reshape(-1, 2)
    ok = np.all(np.isfinite(d), axis=1)
    if not ok.any():
        raise AssessmentError("planimetric check: no building corner was found in the LiDAR points")
    dd = np.column_stack([d[ok], np.zeros(int(ok.sum()))])
    sd = None if checkpoint_sd_m is None else np.array([checkpoint_sd_m, checkpoint_sd_m, 0.0])
    asprs = classify_asprs2023(dd, checkpoint_sd_m=sd)
    rx, ry = (float(np.sqrt(np.mean(dd[:, j] ** 2))) for j in (0, 1))
    # the heights are not compared: only the planimetric classes are kept
    a = asprs.to_dict()
    a["class"] = {"planimetric": a["class"]["planimetric"]}
    out = {"n_corners": int(ok.sum()), "n_missing": int((~ok).sum()), "rmse_x_m": rx, "rmse_y_m": ry,
           "rmse_r_m": math.hypot(rx, ry), "mean_dE_m": float(np.mean(dd[:, 0])),
           "mean_dN_m": float(np.mean(dd[:, 1])), "asprs2023": a, "pec": None}
    if scale is not None:
        p = classify_pec(dd, scale).to_dict()
        p["class"] = {"planimetric": p["class"]["planimetric"]}
        out["pec"] = p
    return out
