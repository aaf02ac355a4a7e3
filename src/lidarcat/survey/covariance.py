"""``eop_covariance.csv``: the full 6 x 6 covariance of every adjusted exterior orientation.

``eop.csv`` carries the standard deviations of X0, Y0, Z0, omega, phi, kappa;
what a product computed from one photo needs is their whole covariance
``Sigma_EO`` (6 x 6), because the parameters of a photo are strongly
correlated: a shift of the projection centre along X is nearly compensated by
a rotation phi (both move the image in x), so ``sd(X0)`` and ``sd(phi)`` can each
be large while the ground point a ray meets moves little.  Propagating
``J Sigma_EO J^T`` with the diagonal alone counts each of them in full and
overstates the plan sd of a monoplotted point many times (issue 25: 8-18x on
the synthetic demo).

The file holds one row per photo with the 21 terms of the upper triangle
(``i <= j``, row-major) of ``Sigma_EO`` from the adjustment (its variance factor
applied), each column named ``c_<a>_<b>_<unit>`` with the parameters
``X0 Y0 Z0`` in metres and ``omega phi kappa`` in **radians**::

    c_X0_X0_m2, c_X0_Y0_m2, ..., c_X0_omega_m_rad, ..., c_omega_omega_rad2, ...

so ``c_X0_phi_m_rad = Cov(X0, phi)`` in m*rad.  The symmetric matrix is
rebuilt by mirroring.  :func:`write_eop_covariance` writes it (atomically,
header first, the notes in the CSV sidecar), :func:`read_eop_covariance`
reads it back (a located :class:`~lidarcat.errors.SurveyError` for a missing
column, a non-number, a photo given twice).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SurveyError

__all__ = ["EO_PARAMETERS", "EOP_COVARIANCE_COLUMNS", "EOP_COVARIANCE_FILE", "write_eop_covariance",
           "read_eop_covariance", "write_result_eop_covariance"]

#: the exterior orientation parameters, in the order of the matrix
EO_PARAMETERS = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
#: file name beside ``eop.csv``
EOP_COVARIANCE_FILE = "eop_covariance.csv"

_UNIT = {"X0": "m", "Y0": "m", "Z0": "m", "omega": "rad", "phi": "rad", "kappa": "rad"}
_IU = np.triu_indices(6)


def _column(a: str, b: str) -> str:
    ua, ub = _UNIT[a], _UNIT[b]
    unit = f"{ua}2" if ua == ub else f"{ua}_{ub}"
    return f"c_{a}_{b}_{unit}"


#: ``photo`` and the 21 upper-triangle terms (m^2, m*rad, rad^2)
EOP_COVARIANCE_COLUMNS = ("photo",) + tuple(_column(EO_PARAMETERS[i], EO_PARAMETERS[j]) for i, j in zip(*_IU))


def write_eop_covariance(path: str | os.PathLike, photo_ids: Sequence[Any], eo_cov: Any, *,
                         variance_factor: str = "a posteriori",
                         provenance: Mapping[str, Any] | None = None) -> Path:
    """Write the (P, 6, 6) covariances *eo_cov* (m, rad) of the photos *photo_ids*.

    >>> import tempfile
    >>> cov = np.diag([1e-4, 1e-4, 4e-4, 1e-8, 1e-8, 4e-8])
    >>> cov[0, 4] = cov[4, 0] = -9e-7            # X0 and phi correlated
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = write_eop_covariance(Path(d) / "eop_covariance.csv", ["7"], cov[None])
    ...     back = read_eop_covariance(p)["7"]
    ...     header = p.read_text().splitlines()[0].split(",")
    >>> bool(np.allclose(back, cov, rtol=1e-12)), header[1], header[5]
    (True, 'c_X0_X0_m2', 'c_X0_phi_m_rad')
    """
    from .._util import write_csv_atomic

    cov = np.asarray(eo_cov, dtype=np.float64).reshape(-1, 6, 6)
    if len(cov) != len(photo_ids):
        raise SurveyError(f"{path}: {len(photo_ids)} photos but {len(cov)} covariance matrices")
    rows = [[str(pid), *c[_IU]] for pid, c in zip(photo_ids, cov)]
    return write_csv_atomic(path, EOP_COVARIANCE_COLUMNS, rows, provenance=provenance, comments=[
        "full covariance of each photo's exterior orientation: the 21 terms c_a_b = Cov(a, b) of the "
        "upper triangle (row-major); X0, Y0, Z0 in m, omega, phi, kappa in rad (units in each column "
        f"name: m2, m_rad, rad2); {variance_factor} variance factor; eop.csv has the same photos"])


def write_result_eop_covariance(result: Any, folder: str | os.PathLike,
                                provenance: Mapping[str, Any] | None = None) -> Path | None:
    """``<folder>/eop_covariance.csv`` of a :class:`~lidarcat.bundle.BundleResult` (``write_adjustment``).

    Written when the adjustment computed the photos' covariance blocks
    (``precision`` ``"all"`` or ``"photos"``); None otherwise.
    """
    if getattr(result, "precision", "all") == "none" or not np.isfinite(result.eo_cov).any():
        return None
    kind = str(getattr(result, "variance_factor_kind", "a_posteriori")).replace("_", " ")
    return write_eop_covariance(Path(folder) / EOP_COVARIANCE_FILE, result.photo_ids, result.eo_cov,
                                variance_factor=kind, provenance=provenance)


def read_eop_covariance(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The symmetric (6, 6) covariance of each photo of an ``eop_covariance.csv``, by photo id (m, rad).

    Raises
    ------
    SurveyError
        Missing file or column, a non-numeric value, a photo given twice (file, line, field).
    """
    from .._util import read_csv_table
    from ..errors import location

    path = Path(path)
    if not path.is_file():
        raise SurveyError(f"{path}: no such covariance file (eop_covariance.csv of `lidarcat adjust`)")
    t = read_csv_table(path, required=EOP_COVARIANCE_COLUMNS, allow_extra=True)
    terms = np.column_stack([t.floats(k) for k in EOP_COVARIANCE_COLUMNS[1:]])
    out: dict[str, np.ndarray] = {}
    for i, pid in enumerate(t.column("photo")):
        if pid in out:
            raise SurveyError(f"{location(path, t.lines[i], 'photo')}: photo {pid!r} is given twice")
        c = np.zeros((6, 6))
        c[_IU] = terms[i]
        out[pid] = c + np.triu(c, 1).T
    return out
