"""Stage ``compare-A-B``: run A minus run B (thesis section 4.4).

Exterior orientations of the photos of both runs (``eop_differences.csv``,
metres and degrees) and the points free (not control) in both runs
(``point_differences.csv``, metres), with mean, RMSE and max |.| per
component in ``comparison.json``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._util import write_json_atomic
from .context import StageContext as Context

__all__ = ["run", "EOP", "EOP_DIFF", "read_photo_rows"]


def _stats(d: np.ndarray) -> dict[str, float]:
    """mean, sample sd, RMSE and max |.| of the columns E, N, h (and planimetric resultant)."""
    out: dict[str, float] = {"n": int(len(d))}
    if not len(d):
        return out
    cols = {"E": d[:, 0], "N": d[:, 1], "h": d[:, 2], "planimetric": np.hypot(d[:, 0], d[:, 1])}
    for k, v in cols.items():
        out[f"mean_{k}_m"] = float(v.mean())
        out[f"std_{k}_m"] = float(v.std(ddof=1)) if len(v) > 1 else float("nan")
        out[f"rmse_{k}_m"] = float(np.sqrt(np.mean(v ** 2)))
        out[f"max_abs_{k}_m"] = float(np.abs(v).max())
    return out


EOP = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
EOP_DIFF = ("dX0", "dY0", "dZ0", "domega", "dphi", "dkappa")


def read_photo_rows(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    """``{photo: values of the columns *names*}`` of a per-photo CSV (eop.csv, eop_differences.csv)."""
    from .._util import read_csv_table

    t = read_csv_table(path, required=("photo", *names), allow_extra=True)
    cols = np.column_stack([t.floats(c) for c in names])
    return {p: cols[i] for i, p in enumerate(t.column("photo"))}


def run(ctx: Context, tmp: Path) -> dict:
    """Differences between two runs (thesis section 4.4): first minus second."""
    from .._util import write_csv_atomic
    from ..accuracy.checkpoints import read_points

    par = ctx.params
    a, b = par["first"], par["second"]
    fa, fb = ctx.folder(f"adjust-{a}"), ctx.folder(f"adjust-{b}")
    ea, eb = read_photo_rows(fa / "eop.csv", EOP), read_photo_rows(fb / "eop.csv", EOP)
    photos = [p for p in ea if p in eb]
    d_eo = np.array([ea[p] - eb[p] for p in photos]).reshape(-1, 6)
    eo_names = list(EOP_DIFF)
    write_csv_atomic(tmp / "eop_differences.csv", ["photo"] + eo_names,
                     [[p, *d] for p, d in zip(photos, d_eo)],
                     comments=[f"Exterior orientation of run {a} minus run {b}: metres and degrees."])
    pa, pb = read_points(fa / "points.csv"), read_points(fb / "points.csv")
    ra = dict(zip(pa.ids, pa.roles or [""] * len(pa.ids)))
    rb = dict(zip(pb.ids, pb.roles or [""] * len(pb.ids)))
    ia, ib = pa.index(), pb.index()
    free = [q for q in pa.ids if q in ib and ra[q] != "control" and rb[q] != "control"]
    d_pt = np.array([pa.xyz[ia[q]] - pb.xyz[ib[q]] for q in free]).reshape(-1, 3)
    write_csv_atomic(tmp / "point_differences.csv",
                     ["point", f"role_{a}", f"role_{b}", "dE", "dN", "dh", "dP"],
                     [[q, ra[q], rb[q], *d, float(np.hypot(d[0], d[1]))]
                      for q, d in zip(free, d_pt)],
                     comments=[f"Points free (not control) in both runs: run {a} minus run {b}, metres."])
    eo_stats = {}
    for k, nm in enumerate(eo_names):
        v = d_eo[:, k]
        if len(v):
            eo_stats[nm] = {"mean": float(v.mean()), "rmse": float(np.sqrt(np.mean(v ** 2))),
                            "max_abs": float(np.abs(v).max())}
    result = {"first": a, "second": b, "sign": f"{a} minus {b}", "n_photos": len(photos),
              "eop": eo_stats, "points": _stats(d_pt), "n_points": len(free)}
    write_json_atomic(tmp / "comparison.json", result)
    return result
