r"""The vertex from the roof near it: the local extraction (``ExtractionParams.fit_radius_m``).

**Why.**  A face of the clip is fitted from all its points in the clip, so its plane -- and the
vertex -- depends on the clip radius whenever the face is not exactly a plane over the whole clip.
Real roofs are not: on the AHN3 tiles the outer part of many faces (eaves, verges; sagging or
bell-cast roofs) lies off the plane of the part near the corner by centimetres, and the radius sweep
of issue 29 (docs/extraction.md, "Radius sweep", item 5) found this the largest single class of
vertices that move with the radius by more than their covariance explains (15 of 36).  The others
are the segmentation's: points near a break line assigned to one face or the other, bands of the
break-line buffer left in or out (its pooled test is over the clip's bands), faces merged or split --
all decided on the whole clip.  The clip radius is a parameter of the *search* (how much roof the
segmentation sees to find the faces); the corner is a property of the roof near it.

**What.**  The vertex :math:`x_0` found in the clip (its faces are the clip's, its choice
:func:`~lidarcat.control.vertices.select_vertex`'s) is extracted again from the clip of the fixed radius
:math:`R` (``fit_radius_m``, default 5 m: the thesis's clip) *centred on it*: the whole chain --
height filter, segmentation, break-line buffer, plane fits, intersection -- on those points alone.
The vertex :math:`x_1` of that clip is again the centre of the next, until the centre moves by less
than ``CENTRE_TOL_M`` (1 mm):

.. math:: x_{k+1} = V\big(\{p : \lVert p_{EN} - x_{k,EN} \rVert \le R\}\big),

:math:`V` the extraction of one clip.  In practice one or two rounds: the first centre is already
within centimetres of the corner, and a move of :math:`\delta` changes the clip by the points of a
ring of width :math:`\delta` on its rim (a few points per centimetre at AHN3 densities), far from the
corner and left out of its faces' fits by the outer-edge rule anyway.

**Independent of the clip.**  Every search clip, of whatever radius, that finds the same corner
(within :math:`\max(0.5\,m, 4\,sd_{plan})`) ends at the same fixed point up to the tolerance: the
same points, the same segmentation, the same vertex.  The radius sweep's move becomes the difference
of two fixed points (sub-millimetre) instead of a random vector whose size the covariance explains.
What the sweep can still find is a search clip that finds *another* corner, or none; the
radius-stability check (:mod:`lidarcat.control.stability`) still tests every accepted vertex for
that.

**The cost.**  Fewer points per plane than an 8 m clip: the vertex sd grows by about
:math:`\sqrt{n_8 / n_5}` for independent errors (up to 1.6 on faces larger than both clips), less
where the cell components dominate (they average over cells, not points).  On exact planes that is a
loss of precision for nothing; on real roofs it is the price of a vertex that is the corner's and not
the clip's.  Measured: docs/extraction.md, "Local extraction".

**When it fails.**  The clip of radius :math:`R` finds no vertex, or another corner (farther than
:math:`\max(0.5\,m, 4\,sd_{plan})` from :math:`x_0`; e.g. a corner whose faces are cut too small by
the clip's rim, or whose clip is dominated by another roof's faces): the clips of 1.3 and 1.6
:math:`R` (``LADDER``; 6.5 and 8 m) are tried in turn, each centred on the vertex, so the choice
still does not depend on the search clip.  When none finds the corner, the search clip's vertex is
kept and its reason says so (it is then the radius-dependent vertex, which the stability check tests;
on the AHN3 sweep 12 of 178 candidates needed a larger clip than 5 m, docs/extraction.md).
``fit_radius_m=None``: the search clip's vertex (the thesis: one clip of 5 m about the position).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

import numpy as np

__all__ = ["extract_locally", "CENTRE_TOL_M", "MAX_ROUNDS", "LADDER"]

#: the fixed point is reached when the centre moves by less than this (m)
CENTRE_TOL_M = 0.001
#: rounds of "clip about the vertex -> vertex" at most
MAX_ROUNDS = 4
#: the local clip radii tried in turn, as multiples of ``fit_radius_m`` (5, 6.5, 8 m at the default), while
#: the smaller finds no vertex or another corner: each is centred on the vertex, so the choice is still
#: independent of the search clip
LADDER = (1.0, 1.3, 1.6)


def extract_locally(cp: Any, radius_m: float, extract: Callable[[np.ndarray, float], Any], apart_m: float) -> Any:
    """*cp* extracted again from the clip of *radius_m* centred on it, to the fixed point (module docstring).

    Parameters
    ----------
    cp : ControlPoint
        The vertex of the search clip (``ok`` or ``imprecise``).
    radius_m : float
        ``fit_radius_m``: the radius of the local clip (m); when it finds no vertex or another corner,
        the clips of ``LADDER`` x *radius_m* are tried in turn.
    extract : callable
        ``extract(centre_en, radius_m) -> ControlPoint``: one clip of ``radius_m`` about ``centre_en`` (E, N;
        m), no retries, no stability check.
    apart_m : float
        Plan distance (m) beyond which a vertex of the local clip is another corner than *cp*.

    Returns
    -------
    ControlPoint
        The local clip's vertex (status ``ok`` or ``imprecise``, with *cp*'s ``approx_en`` and, when ``ok``,
        its reason); *cp* with a reason appended when no local clip finds a vertex of the same corner.
    """
    first = ""
    for f in LADDER:
        r = f * radius_m
        got, why = _fixed_point(cp, r, lambda c: extract(c, r), apart_m)
        if got is not None:
            return got
        first = first or why
    return replace(cp, reason=_why(cp, f"{first}; so do the clips of {LADDER[1] * radius_m:g}-"
                                       f"{LADDER[-1] * radius_m:g} m: the vertex of the search clip is kept"))


def _fixed_point(cp: Any, radius_m: float, extract: Callable[[np.ndarray], Any], apart_m: float
                 ) -> tuple[Any, str]:
    """(the local vertex, "") of the clips of *radius_m*, or (None, why not)."""
    x0 = np.asarray(cp.enh_m, dtype=np.float64)
    centre = x0[:2]
    new = None
    for _ in range(MAX_ROUNDS):
        got = extract(centre)
        if got.status not in ("ok", "imprecise"):
            return None, f"the clip of {radius_m:g} m about the vertex gives {got.status} ({got.reason})"
        moved = float(np.hypot(*(got.enh_m[:2] - x0[:2])))
        if moved > apart_m:
            return None, f"the clip of {radius_m:g} m about the vertex finds another corner {moved:.2f} m away"
        new = got
        step = float(np.hypot(*(got.enh_m[:2] - centre)))
        centre = np.asarray(got.enh_m[:2], dtype=np.float64)
        if step < CENTRE_TOL_M:
            break
    status = new.status
    reason = (cp.reason if cp.status == "ok" else "") if status == "ok" else new.reason
    return replace(new, point_id=cp.point_id, approx_en=cp.approx_en, status=status, reason=reason), ""


def _why(cp: Any, note: str) -> str:
    return f"{cp.reason}; {note}" if cp.reason else note
