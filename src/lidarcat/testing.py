"""Assertions for tests of code built on lidarcat (like :mod:`numpy.testing`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["assert_poses_close"]


def _params(poses) -> np.ndarray:
    if isinstance(poses, np.ndarray) or (isinstance(poses, Sequence) and len(poses)
                                         and not hasattr(poses[0], "position_m")):
        arr = np.asarray(poses, dtype=float)
        return arr.reshape(-1, 6)
    if hasattr(poses, "position_m"):
        poses = [poses]
    return np.array([np.concatenate([p.position_m, p.angles_rad]) for p in poses]).reshape(-1, 6)


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
    a, d = _params(actual), _params(desired)
    if a.shape != d.shape:
        raise AssertionError(f"{err_msg} shape mismatch: {a.shape} vs {d.shape}".strip())
    diff = a - d
    diff[:, 3:] = (diff[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    ids = None
    if not isinstance(actual, np.ndarray):
        seq = [actual] if hasattr(actual, "position_m") else list(actual)
        ids = [getattr(p, "photo", str(i)) or str(i) for i, p in enumerate(seq)] if hasattr(
            seq[0] if seq else None, "photo") else None
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
