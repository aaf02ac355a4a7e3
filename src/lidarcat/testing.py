"""Assertions for tests of code built on lidarcat (like :mod:`numpy.testing`)."""

from __future__ import annotations

import numpy as np

__all__ = ["assert_poses_close"]


def _rows(poses) -> tuple[np.ndarray, list[str] | None]:
    """(n, 6) X0, Y0, Z0, omega, phi, kappa of *poses*, and their photo ids (None for arrays)."""
    if hasattr(poses, "position_m"):
        poses = [poses]
    if isinstance(poses, np.ndarray) or not len(poses) or not hasattr(poses[0], "position_m"):
        return np.asarray(poses, dtype=float).reshape(-1, 6), None
    params = np.array([np.concatenate([p.position_m, p.angles_rad]) for p in poses])
    return params, [getattr(p, "photo", "") or str(i) for i, p in enumerate(poses)]


def assert_poses_close(actual, desired, atol_m: float, atol_rad: float, err_msg: str = "") -> None:
    """Assert that exterior orientations agree within *atol_m* and *atol_rad*.

    Parameters
    ----------
    actual, desired : ExteriorOrientation, sequence of them, or (n, 6) arrays
        (X0, Y0, Z0 in m; omega, phi, kappa in rad).  Angle differences are
        wrapped to (-pi, pi], so kappa = pi and -pi agree.
    atol_m, atol_rad : float
        Absolute tolerances of the position (each coordinate) and the angles.

    Raises
    ------
    AssertionError
        Naming the worst photo (index or id) and parameter.

    >>> import numpy as np
    >>> a = np.array([[100.0, 200.0, 1000.0, 0.01, -0.02, np.pi]])
    >>> b = np.array([[100.05, 200.0, 1000.0, 0.01, -0.02, -np.pi]])
    >>> assert_poses_close(a, b, atol_m=0.1, atol_rad=1e-9)
    """
    (a, ids), (d, _) = _rows(actual), _rows(desired)
    if a.shape != d.shape:
        raise AssertionError(f"{err_msg} shape mismatch: {a.shape} vs {d.shape}".strip())
    diff = a - d
    diff[:, 3:] = (diff[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    names = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
    tol = np.array([atol_m] * 3 + [atol_rad] * 3)
    excess = np.abs(diff) / tol
    if not np.all(np.isfinite(diff)) or np.any(excess > 1):
        excess = np.where(np.isfinite(excess), excess, np.inf)
        i, k = np.unravel_index(int(np.argmax(excess)), excess.shape)
        who = ids[i] if ids else str(i)
        unit = "m" if k < 3 else "rad"
        n_bad = int((excess > 1).sum())
        raise AssertionError(
            f"{err_msg} poses differ: {n_bad} value(s) beyond tolerance; worst photo {who} {names[k]}: "
            f"actual {a[i, k]!r}, desired {d[i, k]!r}, |diff| {abs(diff[i, k]):.6g} {unit} > "
            f"{tol[k]:g} {unit}".strip())
