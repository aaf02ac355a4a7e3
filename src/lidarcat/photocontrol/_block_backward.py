"""The backward step of the block test over the roof edges: a rejected edge put back, or exchanged.

Private to :mod:`lidarcat.photocontrol` (:func:`~lidarcat.photocontrol.blockcheck.check_block` uses it after its
worst-first rounds; its module docstring, "The backward step over the edges", says why).  As in the engine's data
snooping (:func:`lidarcat.bundle.reliability.snoop`): an edge rejected is put back when every test passes with
it (:func:`all_pass`: no vertex measurement's test over its critical value, no edge's 2-D test
:math:`T = w^2` over :math:`\\chi^2_{1-\\alpha_2}(2)`); else the edge of its line whose rejection instead lowers
:math:`v^T P v` most is rejected in its place, when every test passes then.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import DatumError

__all__ = ["block_tests", "all_pass", "edge_backward_step"]


def block_tests(res: Any, level: float, power: float) -> tuple[Any, Any]:
    """The w-tests of the block's image observations (:func:`~lidarcat.bundle.redundancy.reliability`) and of its
    edges (:func:`~lidarcat.bundle.line_tests.line_tests`; None without edges)."""
    from ..bundle.line_tests import line_tests
    from ..bundle.redundancy import reliability

    rel = reliability(res, level=level, power=power) if len(res.problem.photo_index) else None
    lt = line_tests(res, level=level, power=power) if res.problem.lines is not None else None
    return rel, lt


def all_pass(res: Any, n_ties: int, level: float, power: float) -> tuple[bool, Any]:
    """Whether no vertex measurement (the rows after the *n_ties* tie observations) and no edge of *res* is
    rejected (its test over its critical value); and the edge tests."""
    try:
        rel, lt = block_tests(res, level, power)
    except DatumError:
        return False, None
    rows = np.arange(n_ties, len(res.problem.photo_index))
    worst = -np.inf
    if rel is not None and len(rows):
        worst = float(np.where(rel.testable[rows], np.nan_to_num(rel.ratio[rows], nan=-np.inf), -np.inf).max())
    if lt is not None and len(lt.w):
        worst = max(worst, float(np.nan_to_num((lt.w / lt.critical_w) ** 2, nan=-np.inf).max()))
    return worst <= 1.0, lt


def edge_backward_step(edges: Sequence[Any], e_in: np.ndarray, rejected: list[int], res: Any,
                        rebuild: Any, n_ties: int, level: float, power: float
                        ) -> tuple[np.ndarray, Any, list[tuple[int, int | None, float, float]], int]:
    """The backward step over the rejected edges (indices *rejected* into *edges*, in the order found).

    For each: adjust with it put back (``rebuild(e_in) -> result`` or None); when every test passes it was a
    false rejection and it stays in.  Otherwise try rejecting instead each other edge of its line that is in
    (the tests of the edges of one line are correlated: the largest w can sit on a good one); the exchange that
    lowers v'Pv most (the same number of observations out: the likelihood decides) is kept when every test
    passes then.  One change at a time, until none (each put-back shortens the list, each exchange lowers
    v'Pv).  Returns the edges in, the final result, the changes ``(edge, edge rejected instead or None, its w
    in the block with both in, its critical value)`` and the number of adjustments.
    """
    e_in = e_in.copy()
    rejected = list(rejected)
    changes: list[tuple[int, int | None, float, float]] = []
    n_adj = 0
    changed = True
    while changed:
        changed = False
        for a in rejected:
            trial = e_in.copy()
            trial[a] = True
            r = rebuild(trial)
            n_adj += 1
            if r is None:
                continue
            ok, lt = all_pass(r, n_ties, level, power)
            if ok:
                e_in, res = trial, r
                rejected.remove(a)
                changes.append((a, None, math.nan, math.nan))
                changed = True
                break
            best = None
            for h in np.flatnonzero(e_in & np.array([e.line == edges[a].line for e in edges])):
                swap = trial.copy()
                swap[h] = False
                r2 = rebuild(swap)
                n_adj += 1
                if r2 is not None and r2.vtpv < res.vtpv - 1e-9 * max(1.0, res.vtpv) and \
                        (best is None or r2.vtpv < best[2].vtpv) and all_pass(r2, n_ties, level, power)[0]:
                    best = (int(h), swap, r2)
            if best is not None:
                h, e_in, res = best
                w_h = float(lt.w[int(np.flatnonzero(np.flatnonzero(trial) == h)[0])]) if lt is not None else math.nan
                rejected[rejected.index(a)] = h
                changes.append((a, h, w_h, float(lt.critical_w) if lt is not None else math.nan))
                changed = True
                break
    return e_in, res, changes, n_adj
