r"""Accuracy of mapped features as Cavassim (2005) judges it.

:func:`assess_features` -- per feature class (``building``, ``road``): the
mean and sd of dE, dN and of the resultant (Tables 06-08), K-S of the
generalized squared distances (eq. 03,
:func:`lidarcat.accuracy.statistics.ks_mahalanobis_test`), Hotelling's T^2 of a zero
mean (eq. 04, :func:`lidarcat.accuracy.statistics.hotelling_t2_test`), the radius holding
90 % of the points (Table 09, :func:`lidarcat.accuracy.statistics.ce90`, empirical) and
the planimetric PEC class (:func:`lidarcat.accuracy.standards.classify_pec`; the paper
uses 1:2000).  Discrepancies are reference minus measured.

The paper's experiment on a synthetic town is :func:`lidarcat.synthetic.cavassim.cavassim_experiment`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..accuracy.statistics import ce90, hotelling_t2_test, ks_mahalanobis_test
from ..errors import AssessmentError
from ..accuracy.standards import classify_pec

__all__ = ["assess_features", "assess_monoplot", "read_reference", "REFERENCE_CSV_COLUMNS"]

#: columns of a reference file (map coordinates of the features' vertices; ``h`` optional)
REFERENCE_CSV_COLUMNS = ("feature", "vertex", "E", "N")


def assess_features(den_m: Any, classes: Sequence[str], *, scale: float = 2000.0,
                    alpha: float = 0.05) -> dict[str, dict[str, Any]]:
    """Per-class statistics of planimetric discrepancies (module docstring).

    Parameters
    ----------
    den_m : (N, 2) array
        dE, dN = reference - measured, m.
    classes : sequence of N str
    scale : float
        Map scale denominator of the PEC classification.
    alpha : float
        Level of K-S and Hotelling's T^2 (the paper: 0.05).

    Returns
    -------
    dict
        ``{class: {"n", "mean_E", "sd_E", "mean_N", "sd_N", "mean_resultant",
        "sd_resultant", "ks", "hotelling", "r90_m", "pec_class"}}``; tests as
        :meth:`lidarcat.accuracy.statistics.TestResult.to_dict`.

    Raises
    ------
    AssessmentError
        Shapes disagree.
    """
    d = np.asarray(den_m, dtype=np.float64)
    cls = np.asarray(list(classes), dtype=str)
    if d.ndim != 2 or d.shape[1] != 2 or len(d) != len(cls):
        raise AssessmentError(f"discrepancies must be (N, 2) with one class each; got {d.shape} and "
                              f"{len(cls)} classes")
    out: dict[str, dict[str, Any]] = {}
    for c in dict.fromkeys(cls.tolist()):
        x = d[cls == c]
        x = x[np.isfinite(x).all(axis=1)]
        r = np.hypot(x[:, 0], x[:, 1])
        sd = (lambda v: float(v.std(ddof=1)) if len(v) > 1 else math.nan)   # noqa: E731  (one point: no sd)
        pec = classify_pec(np.column_stack([x, np.zeros(len(x))]), scale)
        out[c] = {
            "n": int(len(x)),
            "mean_E": float(x[:, 0].mean()), "sd_E": sd(x[:, 0]),
            "mean_N": float(x[:, 1].mean()), "sd_N": sd(x[:, 1]),
            "mean_resultant": float(r.mean()), "sd_resultant": sd(r),
            "ks": ks_mahalanobis_test(x, alpha).to_dict(),
            "hotelling": hotelling_t2_test(x, alpha).to_dict(),
            "r90_m": float(ce90(x, "empirical").statistic),
            "pec_class": pec.classes["planimetric"],
        }
    return out


def read_reference(path: Any) -> dict[tuple[str, int], np.ndarray]:
    """Reference (truth) positions of feature vertices: a CSV ``feature,vertex,E,N[,h]``.

    ``feature`` is the id of the feature in the file digitised on the photo,
    ``vertex`` its vertex number from 0 (the order of the feature's
    coordinates), E and N in m in the survey CRS (e.g. from a map of a larger
    scale, the paper's 1:2000 stereo-plotted base, or the truth of a synthetic
    scene).

    Returns
    -------
    dict
        ``{(feature, vertex): array([E, N])}``.

    Raises
    ------
    SurveyError
        Unreadable file, missing column, a non-numeric cell or a repeated
        (feature, vertex) pair (file, line and field).
    """
    from .._util import read_csv_table
    from ..errors import SurveyError, location

    t = read_csv_table(path, required=REFERENCE_CSV_COLUMNS, optional=("h", "class"))
    e, n = t.floats("E"), t.floats("N")
    out: dict[tuple[str, int], np.ndarray] = {}
    for k, (fid, v) in enumerate(zip(t.column("feature"), t.column("vertex"))):
        try:
            vi = int(v)
        except ValueError:
            vi = -1
        if vi < 0:
            raise SurveyError(f"{location(t.path, t.lines[k], 'vertex')}: {v!r} is not a vertex number (0, 1, ...)")
        if (fid, vi) in out:
            raise SurveyError(f"{location(t.path, t.lines[k], 'feature')}: feature {fid!r} vertex {vi} is given twice")
        out[(fid, vi)] = np.array([e[k], n[k]])
    return out


def assess_monoplot(features: Sequence[Any], enh_m: Any, status: Sequence[str],
                    reference: dict[tuple[str, int], np.ndarray], *, scale: float = 2000.0,
                    alpha: float = 0.05) -> dict[str, Any]:
    """Monorestituted vertices against their reference, per feature class (:func:`assess_features`).

    Parameters
    ----------
    features : sequence of :class:`lidarcat.mapping.features.ImageFeature`
        The digitised features, in the order of *enh_m*.
    enh_m : (V, 3) array
        Monorestituted E, N, h of every vertex, m.
    status : sequence of V str
        Monoplot status per vertex; only ``ok`` vertices are assessed.
    reference : dict
        :func:`read_reference`.
    scale, alpha : float
        As :func:`assess_features`.

    Returns
    -------
    dict
        ``classes`` (:func:`assess_features`), ``n_vertices``, ``n_assessed``,
        ``n_not_ok`` (a status other than ``ok``), ``n_no_reference`` (vertices
        the reference does not list).
    """
    enh = np.asarray(enh_m, dtype=np.float64)
    d, cls = [], []
    n_bad = n_noref = k = 0
    for f in features:
        for v in range(len(f.colrow_px)):
            ref = reference.get((f.id, v))
            if ref is None:
                n_noref += 1
            elif status[k] != "ok":
                n_bad += 1
            else:
                d.append(ref - enh[k, :2])
                cls.append(f.cls or "unclassified")
            k += 1
    if k != len(enh):
        raise AssessmentError(f"{k} feature vertices but {len(enh)} monorestituted positions")
    classes = assess_features(np.reshape(d, (-1, 2)), cls, scale=scale, alpha=alpha) if d else {}
    return {"classes": classes, "n_vertices": k, "n_assessed": len(d), "n_not_ok": n_bad,
            "n_no_reference": n_noref}
