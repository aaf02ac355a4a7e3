r"""Rotation conventions of the formats lidarcat reads and writes, and the conversions.

lidarcat (thesis eq. 08, :mod:`lidarcat.geometry.collinearity`)
    ``M = R3(kappa) R2(phi) R1(omega)`` rotates **object to image**; the image
    frame is x right, **y up**, z backwards (the camera looks along -z), so
    ``x = -c u1/u3`` with ``u = M (X - X0)``.  The elementary rotations are the
    *passive* ones, ``R1(w) = [[1,0,0],[0,cos w, sin w],[0,-sin w, cos w]]``.

omega-phi-kappa text (Pix4D, Metashape import, orthority, IGN Borea)
    Pix4D states ``R = Rx(omega) Ry(phi) Rz(kappa)`` with the *active*
    rotations, camera to world, camera x right, y up, z backwards.  Since
    ``Rx(w) = R1(w)^T`` that is ``R = M^T``: **the same three angles** as
    lidarcat.  IGN Borea builds ``R = Rx(pi) from_euler('xyz', -[O, P, K])``
    world to camera with y down, z forward: ``from_euler('xyz', -a) =
    Rz(-K) Ry(-P) Rx(-O) = M`` and ``Rx(pi) = diag(1, -1, -1)``, again the same
    angles.  Only the units differ (degrees in the files, radians in orthority's
    PATB-style API).

COLMAP (``images.txt``) and OpenSfM (``reconstruction.json``)
    ``x_cam = R X + t`` maps **world to camera**, camera frame x right,
    **y down, z forward**; COLMAP stores ``R`` as a Hamilton unit quaternion
    ``QW QX QY QZ`` (scalar first), OpenSfM as an angle-axis vector.  Hence
    ``R = F M`` with ``F = diag(1, -1, -1)`` and ``t = -R X0``.

Decomposition of M
------------------
Row 3 of ``R3 R2 R1`` does not depend on kappa: ``M[2] = (sin phi,
-cos phi sin omega, cos phi cos omega)``, and column 1 gives ``M[0,0] = cos phi
cos kappa``, ``M[1,0] = -cos phi sin kappa``.  So ``phi = asin M[2,0]``,
``omega = atan2(-M[2,1], M[2,2])``, ``kappa = atan2(-M[1,0], M[0,0])``
(phi in [-90, 90] degrees; for |phi| = 90 degrees omega and kappa are not separable).

>>> import numpy as np
>>> a = np.radians([[2.0, -3.0, 150.0]])
>>> np.allclose(matrix_to_opk(opk_to_matrix(a)), a, atol=1e-15)
True
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.collinearity import rotation_matrix

__all__ = [
    "FLIP",
    "opk_to_matrix",
    "matrix_to_opk",
    "opk_to_world_to_cv",
    "world_to_cv_to_opk",
    "quaternion_wxyz_to_matrix",
    "matrix_to_quaternion_wxyz",
    "ypr_to_opk",
]

#: image frame y up, z back (lidarcat) <-> y down, z forward (COLMAP, OpenSfM, OpenCV, Metashape)
FLIP = np.diag([1.0, -1.0, -1.0])


def opk_to_matrix(angles_rad) -> np.ndarray:
    """M = R3(kappa) R2(phi) R1(omega), object to image (y up), for (n, 3) or (3,) radians."""
    return rotation_matrix(np.asarray(angles_rad, dtype=float))


def matrix_to_opk(m) -> np.ndarray:
    """(omega, phi, kappa) in radians of object-to-image matrices M (n, 3, 3) or (3, 3)."""
    a = np.asarray(m, dtype=float)
    mm = a.reshape(-1, 3, 3)
    phi = np.arcsin(np.clip(mm[:, 2, 0], -1.0, 1.0))
    omega = np.arctan2(-mm[:, 2, 1], mm[:, 2, 2])
    kappa = np.arctan2(-mm[:, 1, 0], mm[:, 0, 0])
    out = np.column_stack([omega, phi, kappa])
    return out[0] if a.ndim == 2 else out


def opk_to_world_to_cv(angles_rad) -> np.ndarray:
    """World-to-camera rotation R = F M of COLMAP/OpenSfM (camera y down, z forward)."""
    return FLIP @ opk_to_matrix(angles_rad)


def world_to_cv_to_opk(r) -> np.ndarray:
    """omega, phi, kappa (rad) of a COLMAP/OpenSfM world-to-camera rotation R (M = F R)."""
    return matrix_to_opk(FLIP @ np.asarray(r, dtype=float))


def quaternion_wxyz_to_matrix(q) -> np.ndarray:
    """Rotation matrix of Hamilton quaternions (w, x, y, z), (n, 4) or (4,); normalised first."""
    a = np.asarray(q, dtype=float)
    qq = a.reshape(-1, 4)
    mat = Rotation.from_quat(qq[:, [1, 2, 3, 0]]).as_matrix()
    return mat[0] if a.ndim == 1 else mat


def matrix_to_quaternion_wxyz(m) -> np.ndarray:
    """Hamilton quaternions (w, x, y, z) with w >= 0 of rotation matrices (n, 3, 3) or (3, 3)."""
    a = np.asarray(m, dtype=float)
    q = Rotation.from_matrix(a.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    q[q[:, 0] < 0] *= -1.0
    return q[0] if a.ndim == 2 else q


def ypr_to_opk(ypr_rad) -> np.ndarray:
    r"""omega, phi, kappa (rad) of a nadir camera from yaw, pitch, roll (rad) of the aircraft.

    The conversion of the Pix4D note "Yaw, Pitch, Roll and Omega, Phi, Kappa
    angles": the body frame is x forward, y right, z down (NED when all angles
    are 0), ``C_B^N = Rz(yaw) Ry(pitch) Rx(roll)`` (active rotations), the camera
    is mounted with x = body y (right), y = body x (forward), z = -body z (up),
    ``C_C^B = [[0,1,0],[1,0,0],[0,0,-1]]``, and the world frame is ENU,
    ``C_N^E = [[0,1,0],[1,0,0],[0,0,-1]]``.  Then the camera-to-world matrix
    ``R = C_N^E C_B^N C_C^B`` equals ``M^T``.  Meridian convergence of a map
    projection and lever arms/boresight angles are **not** applied (give them
    to the adjustment as constraint sds).

    >>> import numpy as np
    >>> np.round(np.degrees(ypr_to_opk(np.radians([[90.0, 0.0, 0.0]]))), 9) + 0.0  # heading east
    array([[  0.,   0., -90.]])
    """
    a = np.asarray(ypr_rad, dtype=float)
    yaw, pitch, roll = a.reshape(-1, 3).T
    c_bn = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_matrix()
    swap = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    r = swap @ c_bn @ swap
    out = matrix_to_opk(np.transpose(r, (0, 2, 1)))
    return out[0] if a.ndim == 1 else out
