r"""Collinearity equations, rotation matrices and their analytic derivatives.

Convention (thesis eq. 08, Kraus 1992, Wolf 2004)
-------------------------------------------------
The rotation matrix from the object frame (E, N, h) to the image frame is

.. math::  M = R_3(\kappa)\,R_2(\varphi)\,R_1(\omega)

with

.. math::

    R_1(\omega) = \begin{bmatrix}1&0&0\\0&\cos\omega&\sin\omega\\0&-\sin\omega&\cos\omega\end{bmatrix},\;
    R_2(\varphi) = \begin{bmatrix}\cos\varphi&0&-\sin\varphi\\0&1&0\\\sin\varphi&0&\cos\varphi\end{bmatrix},\;
    R_3(\kappa) = \begin{bmatrix}\cos\kappa&\sin\kappa&0\\-\sin\kappa&\cos\kappa&0\\0&0&1\end{bmatrix}.

Image coordinates are x right, y up, in millimetres, with the origin at the
principal point.  With :math:`u = M (X - X_0)` the collinearity equations are

.. math::  x = -c\,u_1/u_3, \qquad y = -c\,u_2/u_3 .

Jacobians
---------
:math:`\partial u/\partial X = M`, :math:`\partial u/\partial X_0 = -M` and
:math:`\partial u/\partial\theta = (\partial M/\partial\theta)(X - X_0)` with
:math:`\partial M/\partial\omega = R_3 R_2 R_1'`, :math:`\partial M/\partial\varphi
= R_3 R_2' R_1`, :math:`\partial M/\partial\kappa = R_3' R_2 R_1`.  The chain rule
through :math:`\partial x/\partial u = -c\,[1/u_3,\;0,\;-u_1/u_3^2]` and
:math:`\partial y/\partial u = -c\,[0,\;1/u_3,\;-u_2/u_3^2]` gives the 2x6 block
of the exterior orientation (X0, Y0, Z0, omega, phi, kappa) and the 2x3 block of
the point (E, N, h) of every observation; everything is vectorised over the
observations.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: rays per chunk of the vectorised projection (temporaries of ~40 rows of this length stay in cache)
_CHUNK = 32768

__all__ = ["block_sum", "rotation_matrix", "rotation_and_derivatives", "project", "project_with_jacobians",
           "project_jacobian_parts"]


def _elementary(angles_rad: np.ndarray):
    a = np.asarray(angles_rad, dtype=float).reshape(-1, 3)
    n = a.shape[0]
    co, so = np.cos(a[:, 0]), np.sin(a[:, 0])
    cp, sp = np.cos(a[:, 1]), np.sin(a[:, 1])
    ck, sk = np.cos(a[:, 2]), np.sin(a[:, 2])
    z, o = np.zeros(n), np.ones(n)
    r1 = np.stack([o, z, z, z, co, so, z, -so, co], axis=1).reshape(n, 3, 3)
    r2 = np.stack([cp, z, -sp, z, o, z, sp, z, cp], axis=1).reshape(n, 3, 3)
    r3 = np.stack([ck, sk, z, -sk, ck, z, z, z, o], axis=1).reshape(n, 3, 3)
    d1 = np.stack([z, z, z, z, -so, co, z, -co, -so], axis=1).reshape(n, 3, 3)
    d2 = np.stack([-sp, z, -cp, z, z, z, cp, z, -sp], axis=1).reshape(n, 3, 3)
    d3 = np.stack([-sk, ck, z, -ck, -sk, z, z, z, z], axis=1).reshape(n, 3, 3)
    return r1, r2, r3, d1, d2, d3


def rotation_matrix(angles_rad: np.ndarray) -> np.ndarray:
    """M = R3(kappa) R2(phi) R1(omega) for (omega, phi, kappa) in radians.

    Parameters
    ----------
    angles_rad : (3,) or (n, 3) array

    Returns
    -------
    (3, 3) or (n, 3, 3) array

    >>> import numpy as np
    >>> np.round(rotation_matrix([0.0, 0.0, np.pi / 2]), 12)
    array([[ 0.,  1.,  0.],
           [-1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    a = np.asarray(angles_rad, dtype=float)
    r1, r2, r3, *_ = _elementary(a)
    m = r3 @ r2 @ r1
    return m[0] if a.ndim == 1 else m


def rotation_and_derivatives(angles_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M (n, 3, 3) and dM/d(omega, phi, kappa) (n, 3, 3, 3), last-but-two axis = angle."""
    r1, r2, r3, d1, d2, d3 = _elementary(angles_rad)
    r32 = r3 @ r2
    m = r32 @ r1
    dm = np.stack([r32 @ d1, r3 @ d2 @ r1, d3 @ r2 @ r1], axis=1)
    return m, dm


def project(eo: np.ndarray, xyz_m: np.ndarray, focal_mm: np.ndarray,
            index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Photo coordinates of points, one ray per row.

    Parameters
    ----------
    eo : (n, 6) array, or (P, 6) with *index*
        X0, Y0, Z0 (m), omega, phi, kappa (rad) of the photo of each ray.
    xyz_m : (n, 3) array
        Object coordinates of the point of each ray.
    focal_mm : (n,) array
    index : (n,) int array, optional
        Photo of each ray when *eo* holds one row per photo (rotations are then
        computed once per photo).

    Returns
    -------
    xy_mm : (n, 2) array
    u3 : (n,) array
        Third image-space component (negative for a point in front of the camera).
    """
    eo = np.asarray(eo, dtype=float).reshape(-1, 6)
    m = rotation_matrix(eo[:, 3:6])
    per_photo = np.concatenate([m.reshape(-1, 9), eo[:, :3]], axis=1).T     # (12, P), rows
    n, chunks = _ray_chunks(per_photo, xyz_m, focal_mm, index)
    xy = np.empty((n, 2))
    u3 = np.empty(n)
    for sl, rows, d, c in chunks:
        M = rows[0:9].reshape(3, 3, -1)
        u = M[:, 0] * d[0] + M[:, 1] * d[1] + M[:, 2] * d[2]
        f = -c / u[2]
        xy[sl, 0] = f * u[0]
        xy[sl, 1] = f * u[1]
        u3[sl] = u[2]
    return xy, u3


def _ray_chunks(per_photo: np.ndarray, xyz_m, focal_mm, index: np.ndarray | None):
    """The rays of :func:`project` in chunks of at most ``_CHUNK`` (temporaries stay in cache).

    *per_photo* (r, P) holds one column per photo, its last three rows X0, Y0, Z0 (m).
    Returns ``(n, iterator of (slice, rows (r, k), d (3, k) = X - X0 in m, c (k,) or (1,) mm))``;
    a single photo, point or focal length is broadcast over the rays.
    """
    xyz = np.asarray(xyz_m, dtype=float).reshape(-1, 3)
    c_all = np.broadcast_to(np.asarray(focal_mm, dtype=float), (len(xyz),))
    n = len(xyz) if index is not None or per_photo.shape[1] == 1 else max(len(xyz), per_photo.shape[1])

    def chunks():
        for a in range(0, n, _CHUNK):
            b = min(n, a + _CHUNK)
            if index is not None:
                rows = np.take(per_photo, index[a:b], axis=1)
            else:
                rows = per_photo if per_photo.shape[1] == 1 else per_photo[:, a:b]
            d = (xyz if len(xyz) == 1 else xyz[a:b]).T - rows[-3:]
            yield slice(a, b), rows, d, (c_all[a:b] if len(c_all) == n else c_all)

    return n, chunks()


def project_with_jacobians(eo: np.ndarray, xyz_m: np.ndarray, focal_mm: np.ndarray,
                           index: np.ndarray | None = None):
    """Photo coordinates and the Jacobians of every ray (arguments as :func:`project`).

    Returns
    -------
    xy_mm : (n, 2)
    a_eo : (n, 2, 6)
        d(x, y)/d(X0, Y0, Z0, omega, phi, kappa), mm per m and mm per rad.
    a_pt : (n, 2, 3)
        d(x, y)/d(E, N, h), mm per m.
    u3 : (n,)
    """
    xy, a_pt, a_ang, u3 = project_jacobian_parts(eo, xyz_m, focal_mm, index)
    return xy, np.concatenate([-a_pt, a_ang], axis=2), a_pt, u3


def project_jacobian_parts(eo: np.ndarray, xyz_m: np.ndarray, focal_mm: np.ndarray,
                            index: np.ndarray | None = None):
    r"""Photo coordinates, d(x, y)/d(point) and d(x, y)/d(angles) of every ray.

    The position part of the exterior-orientation Jacobian is ``-a_pt``
    (``du/dX0 = -M``).  Vectorised without per-ray 3 x 3 products: with
    :math:`q = c/u_3`, :math:`\xi = -u_1/u_3 = x/c`, :math:`\eta = -u_2/u_3`,

    .. math::  \partial x/\partial v = -q\,(v_1 + \xi v_3), \qquad
               \partial y/\partial v = -q\,(v_2 + \eta v_3)

    for a change ``v`` of u; ``v = M e_j`` for the point coordinate j, and for an
    angle ``v = (dM/d\theta) (X - X_0) = G u`` with ``G = (dM/d\theta) M^T``
    skew-symmetric (``M M^T = I``), i.e. a cross product ``g \times u`` with a
    3-vector per photo and angle.

    Returns ``(xy (n, 2), a_pt (n, 2, 3), a_ang (n, 2, 3), u3 (n,))``.
    """
    eo = np.asarray(eo, dtype=float)
    m, dm = rotation_and_derivatives(eo[:, 3:6])
    G = dm @ np.transpose(m, (0, 2, 1))[:, None]             # (P, 3 angles, 3, 3), skew
    g = np.stack([G[:, :, 2, 1], G[:, :, 0, 2], G[:, :, 1, 0]], axis=2)   # (P, angle, component)
    # per-photo quantities as rows (structure of arrays): every operation below runs on
    # contiguous rows of at most _CHUNK rays (temporaries stay in cache on large blocks)
    per_photo = np.concatenate([m.reshape(-1, 9), g.reshape(-1, 9), eo[:, :3]], axis=1).T   # (21, P)
    n, chunks = _ray_chunks(per_photo, xyz_m, focal_mm, index)
    xy = np.empty((n, 2))
    a_pt = np.empty((n, 2, 3))
    a_ang = np.empty((n, 2, 3))
    u3 = np.empty(n)
    for sl, rows, d, c in chunks:
        M, gv = rows[0:9].reshape(3, 3, -1), rows[9:18].reshape(3, 3, -1)
        u = M[:, 0] * d[0] + M[:, 1] * d[1] + M[:, 2] * d[2]                               # (3, k)
        inv3 = 1.0 / u[2]
        xi = -u[0] * inv3
        eta = -u[1] * inv3
        q = -c * inv3                                          # -q of the docstring
        xy[sl, 0] = c * xi
        xy[sl, 1] = c * eta
        a_pt[sl, 0] = (q * (M[0] + xi * M[2])).T
        a_pt[sl, 1] = (q * (M[1] + eta * M[2])).T
        # v = g x u for the three angles at once: (angle, k)
        v1 = gv[:, 1] * u[2] - gv[:, 2] * u[1]
        v2 = gv[:, 2] * u[0] - gv[:, 0] * u[2]
        v3 = gv[:, 0] * u[1] - gv[:, 1] * u[0]
        a_ang[sl, 0] = (q * (v1 + xi * v3)).T
        a_ang[sl, 1] = (q * (v2 + eta * v3)).T
        u3[sl] = u[2]
    return xy, a_pt, a_ang, u3


def block_sum(index: np.ndarray, blocks: np.ndarray, n: int) -> np.ndarray:
    """Sum (m, ...) blocks into (n, ...) by *index*.

    One sparse (n x m) matrix of ones times the blocks flattened to (m, k): a
    C loop over the m rows (several times ``np.bincount`` per component).

    >>> block_sum(np.array([0, 1, 0]), np.ones((3, 2, 2)), 2)[:, 0, 0]
    array([2., 1.])
    """
    blocks = np.asarray(blocks, dtype=float)
    m = blocks.shape[0]
    tail = blocks.shape[1:]
    k = int(np.prod(tail)) if tail else 1
    ones = sp.csr_matrix((np.ones(m), (np.asarray(index), np.arange(m))), shape=(n, m))
    return np.asarray(ones @ blocks.reshape(m, k)).reshape((n,) + tail)
