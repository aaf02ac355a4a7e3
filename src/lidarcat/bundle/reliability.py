r"""Data snooping and robust re-weighting: the blunders of an adjustment found and removed.

The tests they use -- redundancy numbers, the multi-dimensional group test (w-test) of
Baarda's B-method, its levels, minimal detectable bias and external reliability -- are
:mod:`lidarcat.bundle.redundancy` (Baarda 1968; Teunissen, *Testing theory*, 2006); their
names stay importable from here.

Data snooping and robust re-weighting
-------------------------------------
:func:`snoop` adjusts, tests, removes the single group with the largest test
ratio ``T_a / chi2_{1-alpha_q}(q)`` when it exceeds 1, re-adjusts from the
previous solution, and repeats (Baarda: one rejection per iteration, because
one blunder raises the w of its neighbours).  On large blocks a round also
removes every other rejected group that is *separate* from those already picked
(:func:`lidarcat.bundle._rounds.round_picks`: no photo that sees its point is, or shares a point with,
such a photo of a picked group), because a blunder raises the tests of the
groups that share its photo, its point or a neighbouring photo, not of groups
far away; on the thesis block no two groups are separate, so it is the classic
one per round.  Only image observations go together: a control point, a GNSS/INS group
or an observation of line control carries the datum (an error in it moves the whole
block), so a round whose largest ratio is one removes it alone.  The observations of
line control are groups of the same loop (2-D tests, :mod:`lidarcat.bundle.redundancy`,
"Line observations"), of the robust start and of the re-weighting below, so a wrong
roof edge is named before it pulls a correct vertex or a photo's GNSS/INS out of the
adjustment.  A backward step then puts back a
rejected observation when every test passes with it, or exchanges it for
another ray of its point when that lowers v'Pv (the tests of the rays of one
point are correlated), and snooping resumes.  ``robust="danish"`` or
``"huber"`` first runs iteratively re-weighted least squares: the weight of
group a is multiplied by ``f(w_a / c_a)`` with ``c_a`` its critical value,
``f(u) = 1`` for ``u <= 1`` and ``exp(1 - u^2)`` (Danish type) or ``1 / u``
(Huber) beyond; groups whose factor falls below 0.1 are removed together and
snooping cleans what is left, so the final result and its covariance come from
the original weights.  The rays that leave with a cut ray of their point (the other
ray of a two-ray point, :data:`HALF_RAYS_RULE`) are listed as blunders of their own,
as snooping lists them.  All tests use the a priori variance factor (sigma0 = 1:
the sigmas are trusted, which the global chi-square test checks).

Two rules for automatic tie points and a GNSS/INS datum
-------------------------------------------------------
* A free point that lost as many rays as it has left loses the rest too
  (:data:`HALF_RAYS_RULE`; a two-ray point is the old case): a track that joined two
  ground points splits 2 against 2 without a majority, and the pair that stays is
  consistent with itself -- an error along an epipolar line passes every test.
* When the weighted GNSS/INS orientations are the only datum (no control point,
  :func:`eo_is_datum`), a photo's GNSS/INS group whose test rejects is named but
  never removed (:data:`EO_DATUM_NOTE`): without it the photo's position and
  attitude rest on its tie points alone, which hardly separate a shift from a tilt
  of a narrow-angle camera.  On the four NGI frames the tie points, fitted with a
  camera that lacks the principal point and distortion of the real one, rejected
  the published orientation of photo 0182 (w 8-9.5); removing it let the photo
  drift 14-16 m and 0.14-0.16 deg along that correlation.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import DatumError
from .problem import BundleProblem
# the tests' names stay importable from here (defined here before the split, issue 23)
from .redundancy import (  # noqa: F401
    COMPONENTS, FAMILY_LEVEL, MIN_REDUNDANCY, RELIABILITY_COLUMNS, Blunder, Reliability,
    check_level, critical_values, family_alpha, noncentrality, reliability)
from .result import BundleResult
from ._rounds import OBS_PER_REJECTION, Neighbours as _Neighbours, round_picks as _round_picks  # noqa: F401
from .robust import (START_MODES, line_normalised, line_start_blunders, put_back, put_back_lines, robust_start,
                     start_blunders, with_line_weights)
from .solve import adjust

__all__ = ["Blunder", "Reliability", "SnoopingResult", "SNOOPING_MODES", "ROBUST_METHODS",
           "FAMILY_LEVEL", "noncentrality", "critical_values", "family_alpha", "reliability", "snoop"]

log = logging.getLogger(__name__)

#: values of the ``snooping`` switch
SNOOPING_MODES = ("off", "report", "remove")
#: values of the ``robust`` switch
ROBUST_METHODS = ("none", "danish", "huber")
#: IRLS: groups whose weight factor ends below this are removed before snooping
ROBUST_CUT = 0.1
#: snooping stops (blunders remain) after this share of the tested groups is rejected, or 100
MAX_REJECTED_SHARE = 0.05
#: IRLS: stop when the set of groups below ROBUST_CUT is the same after this many re-weightings
ROBUST_STABLE = 2
#: the backward step re-adjusts once per rejection up to this many rejections; beyond, the
#: rejected image observations are put back together when their predicted residual passes
REFINE_MAX = 20
#: a free tie point that lost as many rays as it has left (to snooping or the robust start) loses the rest
#: too: the 2-vs-2 split of a four-ray track that joined two ground points 3.7 px apart along an epipolar
#: line has no majority, and the pair that stays is consistent with itself (w 1.7) -- a mismatch along the
#: epipolar line is invisible to any test (the 24-photo block, seed 8)
HALF_RAYS_RULE = True
#: why a GNSS/INS group is named but not removed when the weighted orientations are the only datum
EO_DATUM_NOTE = ("not removed: the weighted GNSS/INS orientations are the block's only datum (no control point); "
                 "without its own, the photo's position and attitude rest on the tie points alone and trade "
                 "along their correlation (the four NGI frames: 14-16 m against 0.14-0.16 deg). The tie points "
                 "disagree with it: a model error of the camera (principal point, distortion) or a GNSS/INS blunder")
#: IRLS: smallest weight factor (sigma x 100: a point keeps a regular normal-equation block)
ROBUST_FLOOR = 1e-4


@dataclasses.dataclass(frozen=True, eq=False)
class SnoopingResult:
    """Outcome of :func:`snoop`.

    Attributes
    ----------
    result : BundleResult
        The final adjustment: all observations (``report``, ``off``) or
        without the removed ones (``remove``).
    reliability : Reliability or None
        Tests of *result* (None for ``off`` or when it did not converge).
    blunders : tuple of Blunder
        In the order found.
    mode, robust : str
    more_remain : bool
        Snooping stopped (rejection limit, datum, non-convergence) with a
        rejected test left.
    n_adjustments : int
    """

    result: BundleResult
    reliability: Reliability | None
    blunders: tuple[Blunder, ...]
    mode: str
    robust: str
    more_remain: bool
    n_adjustments: int
    start: str = "plain"

    @property
    def blunders_remain(self) -> bool:
        """Blunders are left in the final result (reported only, or not removable)."""
        return self.more_remain or any(not b.removed for b in self.blunders)

    def summary(self) -> dict[str, Any]:
        """``snooping`` and ``blunders`` of ``summary.json``."""
        rel = self.reliability
        snoop_info: dict[str, Any] = {"mode": self.mode, "robust": self.robust, "start": self.start,
                                      "n_found_by": {k: sum(b.found_by == k for b in self.blunders)
                                                     for k in sorted({b.found_by for b in self.blunders})},
                                      "n_adjustments": self.n_adjustments,
                                      "n_blunders": len(self.blunders),
                                      "n_removed": sum(b.removed for b in self.blunders),
                                      "blunders_remain": self.blunders_remain}
        if rel is not None:
            snoop_info.update({
                "level": rel.alpha, "power": rel.power, "noncentrality": rel.lam0,
                "family_level": None if math.isnan(rel.family_level) else rel.family_level,
                "n_tests": int(np.sum(rel.testable)),
                "family_tests": rel.family_tests or None,
                "critical_w": {str(q): math.sqrt(critical_values(rel.alpha, rel.power, q)[1])
                               for q in sorted(set(int(v) for v in rel.q if v > 0))},
                "test": "multi-dimensional chi-square per observation group (B-method), a priori "
                        "variance factor",
                "n_untestable": int(np.sum(~rel.testable)),
                "sum_redundancy": float(np.nansum(rel.redundancy)),
                "min_redundancy_image": float(np.nanmin(rel.redundancy[rel.kind == "image"]))
                if np.any(rel.kind == "image") else math.nan,
                "max_mdb_image_mm": float(np.nanmax(rel.mdb[rel.kind == "image"]))
                if np.any(rel.kind == "image") else math.nan,
                "max_bnr": float(np.nanmax(rel.bnr)) if np.isfinite(rel.bnr).any() else math.nan,
            })
        return {"snooping": snoop_info, "blunders": [b.to_dict() for b in self.blunders]}


# ---------------------------------------------------------------------------
# removing observation groups
# ---------------------------------------------------------------------------


@dataclasses.dataclass
class _Subset:
    """Which observation groups of the original problem are still in."""

    obs: np.ndarray       # (n,) bool
    con: np.ndarray       # (k,) bool
    eo: np.ndarray        # (e,) bool
    lines: np.ndarray | None = None     # (m,) bool: observations of line control (None: the problem has none)

    @classmethod
    def every(cls, p: BundleProblem) -> _Subset:
        """Every group of *p*."""
        m = None if getattr(p, "lines", None) is None else np.ones(len(p.lines.line_index), bool)
        return cls(np.ones(len(p.photo_index), bool), np.ones(len(p.constraint_point_index), bool),
                   np.ones(0 if p.eo_constraint_photo_index is None else len(p.eo_constraint_photo_index), bool),
                   m)

    def copy(self) -> _Subset:
        return _Subset(self.obs.copy(), self.con.copy(), self.eo.copy(),
                       None if self.lines is None else self.lines.copy())

    def restore(self, other: _Subset) -> None:
        """Take the groups of *other* (in place)."""
        self.obs[:], self.con[:], self.eo[:] = other.obs, other.con, other.eo
        if self.lines is not None:
            self.lines[:] = other.lines

    def problem(self, p: BundleProblem) -> tuple[BundleProblem, np.ndarray, np.ndarray]:
        """The reduced problem, its photo and point positions in *p* (points with no ray dropped)."""
        keep_pt = np.zeros(p.n_points, dtype=bool)
        keep_pt[p.point_index[self.obs]] = True
        pt_new = np.cumsum(keep_pt) - 1
        ci = p.constraint_point_index
        con = self.con & keep_pt[ci]
        eo_kw: dict[str, Any] = {}
        if p.eo_constraint_photo_index is not None and self.eo.any():
            eo_kw = dict(eo_constraint_photo_index=p.eo_constraint_photo_index[self.eo],
                         eo_constraint_params=p.eo_constraint_params[self.eo],
                         eo_constraint_sd=p.eo_constraint_sd[self.eo])
        sub = BundleProblem(
            photo_ids=p.photo_ids, point_ids=p.point_ids[keep_pt], focal_length_mm=p.focal_length_mm,
            photo_index=p.photo_index[self.obs], point_index=pt_new[p.point_index[self.obs]],
            xy_mm=p.xy_mm[self.obs], sd_mm=p.sd_mm[self.obs],
            constraint_point_index=pt_new[ci[con]], constraint_enh_m=p.constraint_enh_m[con],
            constraint_sd_m=p.constraint_sd_m[con], initial_eo=p.initial_eo,
            point_role=p.point_role[keep_pt], info=p.info, lines=self.kept_lines(p), **eo_kw,
            rays=None if p.rays is None else p.rays.select(self.obs))
        return sub, np.arange(p.n_photos), np.flatnonzero(keep_pt)

    def kept_lines(self, p: BundleProblem) -> Any:
        """The line control of *p* with the observations still in (None when none is left)."""
        if self.lines is None or p.lines is None or not self.lines.any():
            return None
        return p.lines if self.lines.all() else p.lines.select(self.lines)

    def remove(self, p: BundleProblem, kind: str, photo: str | None, point: str | None) -> list[str]:
        """Remove one group.  A free point left with no more rays than it lost loses the rest too
        (:data:`HALF_RAYS_RULE`): the two rays of a point seen on two photos cannot be told apart by
        any test, and a track that lost half of its rays may have joined two ground points.  Returns
        the photos of the rays removed with it."""
        partners = []
        if kind == "image":
            hit = self.obs & (p.photo_ids[p.photo_index] == photo) & (p.point_ids[p.point_index] == point)
            self.obs &= ~hit
            j = int(np.flatnonzero(p.point_ids == point)[0])
            rays = self.obs & (p.point_index == j)
            con_j = self.con & (p.constraint_point_index == j)
            full = bool(con_j.any() and np.isfinite(p.constraint_sd_m[con_j][0]).all())
            left, lost = int(rays.sum()), int(np.sum((p.point_index == j) & ~self.obs))
            if left and not full and (left == 1 or (HALF_RAYS_RULE and left <= lost)):
                self.obs &= ~rays
                partners += [str(x) for x in p.photo_ids[p.photo_index[rays]]]
        elif kind == "control":
            self.con &= p.point_ids[p.constraint_point_index] != point
            j = int(np.flatnonzero(p.point_ids == point)[0])
            rays = self.obs & (p.point_index == j)
            if rays.sum() == 1:              # a control point on one photo: nothing left to fix it
                self.obs &= ~rays
                partners.append(str(p.photo_ids[p.photo_index[rays]][0]))
        elif kind == "line":
            L = p.lines
            self.lines &= ~((L.line_ids[L.line_index] == point) & (p.photo_ids[L.photo_index] == photo))
        else:
            self.eo &= p.photo_ids[p.eo_constraint_photo_index] != photo
        return partners


# ---------------------------------------------------------------------------
# data snooping
# ---------------------------------------------------------------------------


def snoop(
    problem: BundleProblem,
    *,
    mode: str = "remove",
    level: float | None = None,
    power: float = 0.80,
    family_level: float = FAMILY_LEVEL,
    robust: str = "none",
    start: str = "robust",
    loss: str = "auto",
    max_rejections: int | None = None,
    backward: bool = True,
    multiple: bool = True,
    on_rejection: Callable[[Blunder], None] | None = None,
    **adjust_kwargs: Any,
) -> SnoopingResult:
    """Adjust *problem* with blunder detection (Baarda's data snooping).

    Parameters
    ----------
    problem : BundleProblem
    mode : {"off", "report", "remove"}
        ``off``: adjust only.  ``report``: find the blunders as ``remove`` does
        but return the adjustment of all observations, the blunders listed with
        ``removed=False``.  ``remove``: return the adjustment without them.
    level : float, optional
        alpha of the one-dimensional w-test (B-method, see the module docstring);
        e.g. 0.001 gives critical w 3.29 (q = 1), 3.42 (q = 2), 3.55 (q = 3), 3.92
        (q = 6).  Default: :func:`family_alpha` of the tests of the first adjustment
        at *family_level*, kept for every re-adjustment (the family is the block's
        tests); on the thesis block (159 tests) alpha_1 = 1.04e-4, critical w 4.00
        for q = 2.
    power : float
        Power of the tests (0.80).
    family_level : float
        Probability that a block without blunders has any test rejecting, when *level*
        is None (0.05).
    robust : {"none", "danish", "huber"}
        Run iteratively re-weighted least squares first and remove the groups
        it weights down below :data:`ROBUST_CUT` in one go (large blocks with
        many blunders); snooping then tests the rest.
    start : {"robust", "plain"}
        ``robust`` (with ``report`` and ``remove``): screen the tie points by their intersection
        geometry and re-weight with *loss* before any least-squares step
        (:func:`lidarcat.bundle.robust.robust_start`); the observations it rejects are listed
        as blunders (``found_by`` ``screening`` or the loss), and put back when their residual
        at the solution of the rest passes the test.  ``plain``: least squares from the start.
    loss : {"auto", "cauchy", "huber", "tukey", "none"}
        Loss of the robust start's re-weighting (``auto``: Cauchy, when least squares on the
        screened observations does not converge).
    max_rejections : int, optional
        Stop after this many rejections (``more_remain`` tells).  Default: 100, or
        :data:`MAX_REJECTED_SHARE` of the groups tested in the first adjustment when that is
        more (a large block with several rejections per round).
    multiple : bool
        Remove in one round, besides the group with the largest test ratio, every other
        rejected group that is *separate* from those already picked in that round: no
        photo that sees its point is, or shares a point with, such a photo of a picked
        group (:func:`lidarcat.bundle._rounds.round_picks`).  On a block whose photos all share points (the thesis
        block) this is the classic one rejection per round.
    backward : bool
        After snooping stops, put back a rejected image observation when every test passes
        with it, or exchange it for another ray of its point when that lowers v'Pv
        (:func:`_refine`), and snoop again; costs up to (rays + 1) adjustments per rejection.
    on_rejection : callable(Blunder), optional
        Called after every rejection.
    **adjust_kwargs
        Passed to every :func:`lidarcat.bundle.adjust` (``variance_factor``,
        ``chi2_level``, ``max_iter``, ``progress``, ``precision`` -- the
        intermediate adjustments skip the covariances).

    Returns
    -------
    SnoopingResult

    Raises
    ------
    ValueError
        An unknown *mode* or *robust*, a bad *level* or *power*.
    DatumError
        From the first adjustment.
    """
    if mode not in SNOOPING_MODES:
        raise ValueError(f"`snooping` must be one of {', '.join(SNOOPING_MODES)}, got {mode!r}")
    if robust not in ROBUST_METHODS:
        raise ValueError(f"`robust` must be one of {', '.join(ROBUST_METHODS)}, got {robust!r}")
    if level is not None:
        check_level(level, power)
    check_level(family_level, power)
    if start not in START_MODES:
        raise ValueError(f"`start` must be one of {', '.join(START_MODES)}, got {start!r}")
    final_precision = adjust_kwargs.pop("precision", "all")
    p = problem
    sub = _Subset.every(p)
    rs = None
    if mode != "off" and start == "robust":
        if "initial" in adjust_kwargs:
            adjust_kwargs = dict(adjust_kwargs)
            init = adjust_kwargs.pop("initial")
            rs = robust_start(p, initial=init, loss=loss, **_tolerances(adjust_kwargs))
        else:
            rs = robust_start(p, loss=loss, **_tolerances(adjust_kwargs))
    if rs is None or rs.n_rejected == 0:
        kw = adjust_kwargs if rs is None else {**adjust_kwargs, "initial": (np.asarray(rs.eo), None)}
        first = adjust(problem, precision=final_precision, **kw)
        res, cur = first, p
        rs = None
    else:   # the least squares start without the rejected observations, from the robust estimate
        sub.obs[:] = rs.keep
        if sub.lines is not None and rs.keep_lines is not None:
            sub.lines[:] = rs.keep_lines
        cur, _, kept = sub.problem(p)
        first = None
        res = adjust(cur, initial=(np.asarray(rs.eo), np.asarray(rs.points_m)[kept]), precision="none",
                     **{k: v for k, v in adjust_kwargs.items() if k != "initial"})
    if mode == "off":
        return SnoopingResult(first, None, (), mode, robust, False, 1, "plain")
    n_adj = 1
    blunders: list[Blunder] = []
    rel_first = reliability(res, level=level, power=power, family_level=family_level) if res.success else None
    if rel_first is not None:
        level = rel_first.alpha          # the family is the first adjustment's tests
    if max_rejections is None:
        n_groups = 0 if rel_first is None else int(np.sum(rel_first.testable))
        max_rejections = max(100, math.ceil(MAX_REJECTED_SHARE * n_groups))
    rel = rel_first
    more = False
    hold_eo = eo_is_datum(p)       # no control point: a photo's GNSS/INS group is named, never removed
    if robust != "none" and res.success:
        res, cur, rel, found, k = _robust(p, sub, res, rel, robust, level, power, adjust_kwargs, base=cur,
                                          hold_eo=hold_eo)
        blunders += found
        n_adj += k
    iteration = n_rej = 0
    tried = np.zeros(len(p.photo_index), dtype=bool)      # robust-start rejections tested for putting back
    tried_lines = np.zeros(0 if sub.lines is None else len(sub.lines), dtype=bool)
    tried_snoop = np.zeros(len(p.photo_index), dtype=bool)  # snooping rejections tested (large blocks)
    near = _Neighbours(p) if multiple else None
    single = False                 # after a failed multiple round: one group at a time
    for _round in range(20):
        while rel is not None:
            pick = _pickable(rel, hold_eo)
            g = pick.worst()
            if g is None or pick.ratio[g] <= 1:
                break
            if n_rej >= max_rejections:
                more = True
                log.warning("data snooping stopped after %d rejections; tests still reject", n_rej)
                break
            picks = [g] if near is None or single else _round_picks(pick, near, max_rejections - n_rej)
            iteration += 1
            saved = sub.copy()
            found: list[Blunder] = []
            for gg in picks:
                found += _remove_group(p, sub, rel, gg, iteration)
            try:
                nxt, _, _ = sub.problem(p)
                warm = (np.asarray(res.eo_params), _warm_points(res, nxt))
                res_new = _readjust(nxt, warm, adjust_kwargs)
                n_adj += 1
                if not res_new.success:
                    raise DatumError(f"the adjustment without it did not converge ({res_new.status})")
                rel_new = reliability(res_new, level=level, power=power)
            except (DatumError, ValueError) as ex:
                sub = saved
                if len(picks) > 1:          # try again with the largest ratio alone
                    iteration -= 1
                    single = True
                    continue
                blunders.append(dataclasses.replace(found[0], removed=False, note=f"not removed: {ex}"))
                more = True
                log.warning("data snooping: %s not removed: %s", found[0].label(), ex)
                break
            single = False
            blunders += found
            n_rej += len(picks)
            for bl in found:
                log.info("data snooping: rejected %s (w %.2f > %.2f)", bl.label(), bl.w, bl.w_critical)
                if on_rejection is not None:
                    on_rejection(bl)
            res, cur, rel = res_new, nxt, rel_new
        if more or rel is None or not backward:
            break
        if rs is not None:   # put back what the robust start rejected at a worse orientation
            w2 = math.sqrt(critical_values(level, power, 2)[1])
            back = put_back(p, ~rs.keep & ~tried & ~sub.obs, np.asarray(res.eo_params), res.point_ids,
                            np.asarray(res.points_m), w2)
            tried |= ~rs.keep
            back_l = np.zeros(0, dtype=bool)
            if sub.lines is not None and rs.keep_lines is not None:
                back_l = put_back_lines(p, ~rs.keep_lines & ~tried_lines & ~sub.lines, np.asarray(res.eo_params), w2)
                tried_lines |= ~rs.keep_lines
            if back.any() or back_l.any():
                trial = sub.copy()
                trial.obs |= back
                if back_l.any():
                    trial.lines |= back_l
                try:
                    prob, _, _ = trial.problem(p)
                    r = _readjust(prob, (np.asarray(res.eo_params), _warm_points_or_new(res, prob, p)),
                                  adjust_kwargs)
                    n_adj += 1
                    if r.success:
                        log.info("robust start: %d observation(s) put back", int(back.sum() + back_l.sum()))
                        sub, res, cur = trial, r, prob
                        rel = reliability(r, level=level, power=power)
                        continue
                except (DatumError, ValueError):
                    pass
        snooped = [b for b in blunders if b.found_by == "snooping" and b.removed and b.kind == "image"]
        if len(snooped) > REFINE_MAX:   # a large block: put back together what passes at the solution
            changed, sub, res, cur, rel, blunders, k = _put_back_many(p, sub, blunders, res, cur, rel, level,
                                                                      power, adjust_kwargs, tried_snoop)
            n_adj += k
            if changed:
                continue
            break
        # backward step: re-insert or exchange a rejected observation when the data prefer it
        changed, sub, res, cur, rel, blunders, k = _refine(p, sub, blunders, res, cur, rel, level, power,
                                                            adjust_kwargs, hold_eo)
        n_adj += k
        if not changed:
            break
    blunders += _held_blunders(rel, hold_eo, iteration + 1)
    adjust_kwargs = {k: v for k, v in adjust_kwargs.items() if k != "initial"}
    if rs is not None:          # the robust start's rejections still out of the adjustment
        rej = dataclasses.replace(rs, keep=rs.keep | sub.obs, keep_lines=None if sub.lines is None or rs.keep_lines
                                  is None else rs.keep_lines | sub.lines)
        w_crit = math.sqrt(critical_values(level, power, 2)[1]) if level is not None else math.nan
        blunders = (start_blunders(p, rej, np.asarray(res.eo_params), res.point_ids, np.asarray(res.points_m),
                                   w_crit) + line_start_blunders(p, rej, np.asarray(res.eo_params), w_crit)
                    + blunders)
        if mode == "report":    # the adjustment of every observation, when it converges
            from .approx import intersect_points

            eo_r = np.asarray(res.eo_params)
            first = adjust(p, initial=(eo_r, intersect_points(p, eo_r)), precision=final_precision,
                           **adjust_kwargs)
            n_adj += 1
            if first.success:
                rel_first = reliability(first, level=level, power=power, family_level=family_level)
            else:
                note = (f"removed: the adjustment with every observation does not converge ({first.status}) "
                        "in report mode")
                blunders = [dataclasses.replace(b, note="; ".join(x for x in (b.note, note) if x))
                            if b.found_by != "snooping" else b for b in blunders]
                first = None
    if mode == "report" and first is not None:
        final, final_rel = first, rel_first
        blunders = [dataclasses.replace(b, removed=False) for b in blunders]
    elif res is first:
        final, final_rel = first, rel_first
    else:  # the intermediate adjustments skipped the covariances: once more with them
        final = adjust(cur, initial=(np.asarray(res.eo_params), np.asarray(res.points_m)),
                       precision=final_precision, **adjust_kwargs)
        final_rel = rel
        n_adj += 1
    if final_rel is not None and rel_first is not None:
        final_rel = dataclasses.replace(final_rel, family_level=rel_first.family_level,
                                        family_tests=rel_first.family_tests)
    return SnoopingResult(final, final_rel, tuple(blunders), mode, robust, more, n_adj, start)


def eo_is_datum(p: BundleProblem) -> bool:
    """The weighted GNSS/INS orientations are the only datum: no control point with a finite sd."""
    has_eo = p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index) > 0
    return has_eo and not bool(np.isfinite(np.asarray(p.constraint_sd_m, float)).any())


def _pickable(rel: Reliability | None, hold_eo: bool) -> Reliability | None:
    """*rel* with the GNSS/INS groups untestable when they are held (:func:`eo_is_datum`): snooping names
    them (:data:`EO_DATUM_NOTE`) but never removes one."""
    if rel is None or not hold_eo:
        return rel
    return dataclasses.replace(rel, w=np.where(rel.kind == "eo", np.nan, rel.w))


def _held_blunders(rel: Reliability | None, hold_eo: bool, iteration: int) -> list[Blunder]:
    """The held GNSS/INS groups whose test rejects in *rel*, named with :data:`EO_DATUM_NOTE`."""
    if rel is None or not hold_eo:
        return []
    bad = np.flatnonzero((rel.kind == "eo") & (np.nan_to_num(rel.ratio) > 1))
    return [rel.blunder(int(g), removed=False, iteration=iteration, note=EO_DATUM_NOTE) for g in bad]


def _remove_group(p: BundleProblem, sub: _Subset, rel: Reliability, g: int, iteration: int) -> list[Blunder]:
    """Remove group *g* of *rel* from *sub*; its :class:`Blunder` records (two for a two-ray point)."""
    bl = rel.blunder(g, removed=True, iteration=iteration)
    partners = sub.remove(p, bl.kind, bl.photo, bl.point)
    out = [bl]
    for ph in partners if bl.kind == "control" else ():
        out[0] = dataclasses.replace(bl, note=f"its only ray (photo {ph}) removed with it")
    if bl.kind == "image" and partners:
        n_rays = int(np.sum(p.point_ids[p.point_index] == bl.point))
        if n_rays == 2:      # a two-ray point: the rays are not separable
            note = (f"point {bl.point} is on two photos only: its rays on photos {bl.photo} and {partners[0]} "
                    "cannot be told apart; both removed")
        else:
            note = (f"point {bl.point} lost {n_rays - len(partners)} of its {n_rays} rays: a track that may join "
                    f"two ground points (a mismatch along an epipolar line passes every test); its rays on "
                    f"photo(s) {', '.join(partners)} removed with it")
        out[0] = dataclasses.replace(bl, note=note)
        for ph in partners:
            other = np.flatnonzero((rel.kind == "image") & (rel.photo == ph) & (rel.point == bl.point))
            if len(other):
                out.append(rel.blunder(int(other[0]), removed=True, iteration=iteration, note=note))
    return out


def _refine(p, sub, blunders, res, cur, rel, level, power, adjust_kwargs, hold_eo=False):
    """One backward step after snooping stopped; returns ``(changed, sub, res, cur, rel, blunders, n_adj)``.

    For each image observation removed by snooping (not a two-ray point): adjust with it put back;
    when every test then passes it was a false rejection (its w was raised by a blunder removed
    later) and it is re-inserted.  Otherwise try removing, instead of it, each other ray of its
    point: the w-tests of the rays of one point are correlated and the largest w can sit on a good
    ray; the exchange is kept when it lowers v'Pv (the same number of observations removed, so
    the likelihood decides).  At most one change per call.
    """
    n_adj = 0
    pid, qid = p.photo_ids[p.photo_index], p.point_ids[p.point_index]
    for k, b in enumerate(blunders):
        if b.kind != "image" or b.found_by != "snooping" or not b.removed or b.note:
            continue
        a = int(np.flatnonzero((pid == b.photo) & (qid == b.point))[0])
        others = np.flatnonzero(sub.obs & (p.point_index == p.point_index[a]))
        if not len(others):      # its point's other rays went with a later rejection (HALF_RAYS_RULE)
            continue
        best = back = None
        for h in [None, *(int(o) for o in others)]:
            trial = sub.copy()
            trial.obs[a] = True
            if h is not None:
                trial.obs[h] = False
            try:
                prob, _, _ = trial.problem(p)
                r = _readjust(prob, (np.asarray(res.eo_params), _warm_points(res, prob)), adjust_kwargs)
                n_adj += 1
                if not r.success:
                    continue
                if h is None:
                    relt = back = reliability(r, level=level, power=power)
                    pick = _pickable(relt, hold_eo)
                    g = pick.worst()
                    if g is None or pick.ratio[g] <= 1:
                        best = (None, trial, r, prob, relt)
                        break
                elif r.vtpv < res.vtpv - 1e-9 * max(1.0, res.vtpv) and (best is None or r.vtpv < best[2].vtpv):
                    best = (h, trial, r, prob, None)
            except (DatumError, ValueError, KeyError):
                continue
        if best is None:
            continue
        h, trial, r, prob, relt = best
        relt = relt if relt is not None else reliability(r, level=level, power=power)
        out = list(blunders)
        if h is None:
            log.info("data snooping: %s put back (every test passes with it)", b.label())
            del out[k]
        else:
            # its test in the adjustment with both rays in (where the choice was made)
            src = back if back is not None else rel
            g = int(np.flatnonzero((src.kind == "image") & (src.photo == pid[h]) & (src.point == qid[h]))[0])
            out[k] = src.blunder(g, removed=True, iteration=b.iteration,
                                 note=f"exchanged for photo {b.photo} (same point): lower v'Pv")
            log.info("data snooping: %s exchanged for photo %s (lower v'Pv)", b.label(), pid[h])
        return True, trial, r, prob, relt, out, n_adj
    return False, sub, res, cur, rel, blunders, n_adj


def _put_back_many(p, sub, blunders, res, cur, rel, level, power, adjust_kwargs, tried):
    """The backward step of a large block: every image observation rejected by snooping (not yet
    tried) whose predicted residual at the current solution passes the test of a good observation
    (:func:`lidarcat.bundle.robust.put_back`) goes back in one re-adjustment.  Returns
    ``(changed, sub, res, cur, rel, blunders, n_adj)``; *tried* (n,) bool is updated."""
    pid, qid = p.photo_ids[p.photo_index], p.point_ids[p.point_index]
    key = {(str(a), str(b)): i for i, (a, b) in enumerate(zip(pid, qid))}
    rej = np.zeros(len(p.photo_index), dtype=bool)
    for b in blunders:
        if b.found_by == "snooping" and b.removed and b.kind == "image" and not b.note:
            rej[key[(b.photo, b.point)]] = True
    rej &= ~tried & ~sub.obs
    tried |= rej
    back = put_back(p, rej, np.asarray(res.eo_params), res.point_ids, np.asarray(res.points_m),
                    math.sqrt(critical_values(level, power, 2)[1]))
    if not back.any():
        return False, sub, res, cur, rel, blunders, 0
    trial = sub.copy()
    trial.obs |= back
    try:
        prob, _, _ = trial.problem(p)
        r = _readjust(prob, (np.asarray(res.eo_params), _warm_points_or_new(res, prob, p)), adjust_kwargs)
    except (DatumError, ValueError):
        return False, sub, res, cur, rel, blunders, 0
    if not r.success:
        return False, sub, res, cur, rel, blunders, 1
    keys = {(str(pid[i]), str(qid[i])) for i in np.flatnonzero(back)}
    out = [b for b in blunders if not (b.found_by == "snooping" and b.kind == "image" and (b.photo, b.point) in keys)]
    log.info("data snooping: %d rejected observation(s) put back (they pass at the solution)", int(back.sum()))
    return True, trial, r, prob, reliability(r, level=level, power=power), out, 1


def _readjust(problem: BundleProblem, initial: tuple[np.ndarray, np.ndarray], adjust_kwargs: dict) -> BundleResult:
    """Re-adjustment from a nearby solution, without covariances: plain Gauss-Newton first (it
    converges in a few steps from there; the damped path took about twice as many), the damped
    one when that fails or when the caller chose ``damping``."""
    if "damping" not in adjust_kwargs:
        r = adjust(problem, initial=initial, precision="none", damping=False, **adjust_kwargs)
        if r.success:
            return r
    return adjust(problem, initial=initial, precision="none", **adjust_kwargs)


def _tolerances(adjust_kwargs: dict) -> dict:
    """The keys of *adjust_kwargs* the robust start's re-weighted adjustments take."""
    return {k: v for k, v in adjust_kwargs.items() if k in ("tol_m", "tol_rad", "tol_vtpv", "solver")}


def _warm_points_or_new(res: BundleResult, nxt: BundleProblem, p: BundleProblem) -> np.ndarray:
    """Adjusted coordinates of *res* for the points of *nxt*; a point new to *nxt* intersected from its
    rays at the orientations of *res*."""
    from .screening import intersect_rays

    pos = {str(q): i for i, q in enumerate(res.point_ids)}
    out = np.full((nxt.n_points, 3), np.nan)
    have = np.array([str(q) in pos for q in nxt.point_ids], dtype=bool)
    out[have] = np.asarray(res.points_m)[[pos[str(q)] for q in nxt.point_ids[have]]]
    if not have.all():
        out[~have] = intersect_rays(nxt, np.asarray(res.eo_params))[~have]
    return out


def _warm_points(res: BundleResult, nxt: BundleProblem) -> np.ndarray:
    """Adjusted coordinates of *res* for the points of *nxt* (by id)."""
    pos = {str(q): i for i, q in enumerate(res.point_ids)}
    return np.asarray(res.points_m)[[pos[str(q)] for q in nxt.point_ids]]


def _robust(p, sub, res, rel, method, level, power, adjust_kwargs, max_iter: int = 20, base=None,
            hold_eo: bool = False):
    """IRLS with the Danish or Huber weight function on the group tests; returns the state after
    removing the groups weighted below :data:`ROBUST_CUT`.  *base*: the problem *res* adjusted (the
    groups of *sub* of *p*; default *p*).  *hold_eo* (:func:`eo_is_datum`): the GNSS/INS groups keep
    their weight -- weighted down, the datum of their photo would go with them; snooping names the
    rejected ones (:data:`EO_DATUM_NOTE`)."""
    base = p if base is None else base
    n_img = len(base.photo_index)
    k_con = len(base.constraint_point_index)
    factor = np.ones(len(rel.kind))
    cur = base
    saved = sub.copy()
    n_adj = 0
    r_cur, rel_cur = res, rel
    crit = {q: critical_values(level, power, q)[1] for q in (1, 2, 3, 6)}
    kq = np.array([crit[{"image": 2, "control": 3, "eo": 6, "line": 2}[str(k)]] for k in rel.kind])
    same_cut = 0
    for _ in range(max_iter):
        # normalised residuals with the original sigmas (not the re-weighted ones: a group weighted
        # down must keep its large residual, or it would get its weight back the next time)
        u = np.sqrt(_normalised_sq(base, r_cur) / kq)
        new = np.ones_like(u)
        big = u > 1
        new[big] = np.maximum(np.exp(1 - u[big] ** 2) if method == "danish" else 1.0 / u[big], ROBUST_FLOOR)
        if hold_eo:
            new[rel.kind == "eo"] = 1.0
        if np.allclose(new, factor, rtol=1e-3, atol=1e-6):
            break
        # only the groups cut below ROBUST_CUT leave the re-weighting (snooping with the original weights
        # tests the rest): stop when that set has not changed in ROBUST_STABLE re-weightings
        same_cut = same_cut + 1 if np.array_equal(new < ROBUST_CUT, factor < ROBUST_CUT) else 0
        if same_cut >= ROBUST_STABLE:
            factor = new
            break
        factor = new
        cur = _reweighted(base, factor, n_img, k_con)
        prev = r_cur
        r_cur = _readjust(cur, (np.asarray(r_cur.eo_params), np.asarray(r_cur.points_m)), adjust_kwargs)
        n_adj += 1
        if not r_cur.success:
            r_cur = prev
            log.warning("robust %s: the re-weighted adjustment did not converge; stopped", method)
            break
    try:
        rel_cur = reliability(r_cur, level=level, power=power)
    except DatumError:
        rel_cur = rel
    # remove the groups weighted down (tests of the original weights follow in snooping)
    found: list[Blunder] = []
    cut = np.flatnonzero(factor < ROBUST_CUT)
    listed: set[tuple[str, str, str]] = set()
    image_row: dict[tuple[str, str], int] | None = None
    for g in cut[np.argsort(factor[cut], kind="stable")]:        # the lowest weight first
        kind = str(rel_cur.kind[g])
        photo = str(rel_cur.photo[g]) if kind != "control" else None
        point = str(rel_cur.point[g]) if kind != "eo" else None
        if (kind, str(photo), str(point)) in listed:             # gone with a ray cut before it
            continue
        b = rel_cur.blunder(int(g), removed=True, iteration=0, found_by=method)
        # w and the estimated error of the original weights: e / sd relative to the critical value
        partners = sub.remove(p, kind, photo, point)
        found.append(dataclasses.replace(b, w=float(math.sqrt(u[g] ** 2 * kq[g])),
                                         note="; ".join([f"weight factor {factor[g]:.1e}",
                                                         *(f"the other ray (photo {ph}) removed with it"
                                                           for ph in partners)])))
        listed.add((kind, str(photo), str(point)))
        # every ray removed with it is a blunder of its own (as snooping lists them): blunders.csv names
        # every observation that left the adjustment (before, the Danish start left 2 of the matched
        # block's 17 gross matches in a note only)
        for ph in partners if kind == "image" else ():
            if image_row is None:       # (photo, point) -> row of rel_cur, built once
                n_i = int(np.sum(rel_cur.kind == "image"))
                image_row = {(str(a), str(q)): i for i, (a, q) in enumerate(zip(rel_cur.photo[:n_i],
                                                                                 rel_cur.point[:n_i]))}
            h0 = image_row.get((ph, str(point)))
            if h0 is None or ("image", ph, str(point)) in listed:
                continue
            found.append(dataclasses.replace(
                rel_cur.blunder(h0, removed=True, iteration=0, found_by=method),
                w=float(math.sqrt(u[h0] ** 2 * kq[h0])),
                note=f"weight factor {factor[h0]:.1e}; removed with the ray of photo {photo} (point {point} "
                     f"lost {1 + len(partners)} of its rays: " + ("its two rays cannot be told apart)"
                                                                  if len(partners) == 1 else "a track that may "
                                                                  "join two ground points)")))
            listed.add(("image", ph, str(point)))
    if not found:
        return res, base, rel, [], n_adj
    try:
        nxt, _, _ = sub.problem(p)
        r2 = _readjust(nxt, (np.asarray(r_cur.eo_params), _warm_points(r_cur, nxt)), adjust_kwargs)
    except (DatumError, ValueError) as ex:
        log.warning("robust %s: removing the %d down-weighted group(s) leaves %s; snooping alone", method,
                    len(found), ex)
        sub.restore(saved)
        return res, base, rel, [], n_adj
    n_adj += 1
    rel2 = reliability(r2, level=level, power=power) if r2.success else None
    log.info("robust %s: %d group(s) removed", method, len(found))
    return r2, nxt, rel2, found, n_adj


def _normalised_sq(p: BundleProblem, res: BundleResult) -> np.ndarray:
    """Sum of (residual / original sigma)^2 of every group, in the order of :class:`Reliability` (a line
    observation: ``r^T P r``, its residual pair whitened, :func:`lidarcat.bundle.robust.line_normalised`)."""
    parts = [np.sum((np.asarray(res.residuals_mm) / p.sd_mm) ** 2, axis=1)]
    if len(p.constraint_point_index):
        w = np.where(np.isfinite(p.constraint_sd_m), 1.0 / p.constraint_sd_m, 0.0)
        parts.append(np.sum((np.asarray(res.constraint_residuals_m) * w) ** 2, axis=1))
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        w = np.where(np.isfinite(p.eo_constraint_sd), 1.0 / p.eo_constraint_sd, 0.0)
        parts.append(np.sum((np.asarray(res.eo_constraint_residuals) * w) ** 2, axis=1))
    if getattr(p, "lines", None) is not None and len(p.lines.line_index):
        q = line_normalised(p.lines, np.asarray(res.eo_params), p.focal_length_mm)
        parts.append(np.where(np.isfinite(q), q, np.inf))
    return np.concatenate(parts)


def _reweighted(p: BundleProblem, factor: np.ndarray, n_img: int, k_con: int) -> BundleProblem:
    """*p* with the sigmas of every group divided by sqrt(factor) (a line observation: its weight
    matrix times the factor)."""
    s = 1.0 / np.sqrt(factor)
    kw: dict[str, Any] = {}
    n_eo = 0 if p.eo_constraint_photo_index is None else len(p.eo_constraint_photo_index)
    if n_eo:
        kw = dict(eo_constraint_sd=p.eo_constraint_sd * s[n_img + k_con:n_img + k_con + n_eo, None])
    if getattr(p, "lines", None) is not None and len(p.lines.line_index):
        kw["lines"] = with_line_weights(p.lines, factor[n_img + k_con + n_eo:])
    return dataclasses.replace(p, sd_mm=p.sd_mm * s[:n_img, None],
                               constraint_sd_m=p.constraint_sd_m * s[n_img:n_img + k_con, None], **kw)
