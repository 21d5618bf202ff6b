"""Rotations: direction cosine matrices, rotation vectors, quaternions, Euler angles.

Conventions
-----------
* ``C_b^n`` (``cbn``) maps body-frame vectors to the ENU navigation frame: ``v_n = C_b^n v_b``.
* Quaternions are scalar-first ``(q0, q1, q2, q3)`` and represent the same rotation as ``C_b^n``.
* Euler angles follow the ENU convention common in Chinese SINS literature (He 2019): yaw ``psi``
  about Up (positive counter-clockwise seen from above, i.e. *from North towards West*), then pitch
  ``theta`` about the once-rotated East (x) axis, then roll ``gamma`` about the body y axis:
  ``C_b^n = R_z(psi) R_x(theta) R_y(gamma)``. Heading (clockwise from North) is ``-psi``.
* Small attitude errors ``phi`` (the misalignment of He 2019 eq. 4) are defined by
  ``C_b^n_computed = (I - [phi x]) C_b^n_true``.

Numerics
--------
The conversions the simulator and the navigation use are the closed forms written here: their last bits
enter the simulated sessions (table angles, nominal attitudes) and the navigation products, and
``scipy.spatial.transform.Rotation`` rounds differently (it agrees to ~1e-15 relative and is slower per
call). scipy's ``Rotation`` is the independent reference of the tests, and it serves :func:`dcm_to_rotvec`
(used for checking), where its quaternion route stays accurate up to an angle of pi.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def skew(v):
    """Cross-product matrix [v x]."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def axis_angle(axis, angle):
    """DCM of a right-handed rotation by ``angle`` [rad] about unit ``axis`` (active form)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    k = skew(axis)
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def rotvec_to_dcm(rv):
    """Rodrigues formula: DCM of rotation vector ``rv`` [rad]; exact for all magnitudes."""
    rv = np.asarray(rv, dtype=float)
    a = np.linalg.norm(rv)
    k = skew(rv)
    if a < 1e-8:
        return np.eye(3) + k + 0.5 * (k @ k)
    return np.eye(3) + np.sin(a) / a * k + (1.0 - np.cos(a)) / a**2 * (k @ k)


def dcm_to_rotvec(c):
    """Rotation vector [rad] of a DCM, angle in [0, pi] (inverse of :func:`rotvec_to_dcm`); (N, 3, 3) gives
    (N, 3). Through scipy's unit quaternion, accurate for every angle up to pi (at exactly pi the sign of
    the vector is a convention)."""
    return Rotation.from_matrix(np.asarray(c, dtype=float)).as_rotvec()


def euler_to_dcm(pitch, roll, yaw):
    """C_b^n from pitch, roll, yaw [rad] in the ENU convention of this module."""
    return rot_z(yaw) @ rot_x(pitch) @ rot_y(roll)


def dcm_to_euler(c):
    """(pitch, roll, yaw) [rad] of C_b^n; inverse of :func:`euler_to_dcm` (|pitch| < 90 deg)."""
    c = np.asarray(c)
    pitch = np.arcsin(np.clip(c[..., 2, 1], -1.0, 1.0))
    roll = np.arctan2(-c[..., 2, 0], c[..., 2, 2])
    yaw = np.arctan2(-c[..., 0, 1], c[..., 1, 1])
    return pitch, roll, yaw


def dcm_to_quat(c):
    """Scalar-first unit quaternion of a DCM (Shepperd's method)."""
    c = np.asarray(c, dtype=float)
    tr = np.trace(c)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2.0
        q = [0.25 * s, (c[2, 1] - c[1, 2]) / s, (c[0, 2] - c[2, 0]) / s, (c[1, 0] - c[0, 1]) / s]
    elif c[0, 0] > c[1, 1] and c[0, 0] > c[2, 2]:
        s = np.sqrt(1.0 + c[0, 0] - c[1, 1] - c[2, 2]) * 2.0
        q = [(c[2, 1] - c[1, 2]) / s, 0.25 * s, (c[0, 1] + c[1, 0]) / s, (c[0, 2] + c[2, 0]) / s]
    elif c[1, 1] > c[2, 2]:
        s = np.sqrt(1.0 + c[1, 1] - c[0, 0] - c[2, 2]) * 2.0
        q = [(c[0, 2] - c[2, 0]) / s, (c[0, 1] + c[1, 0]) / s, 0.25 * s, (c[1, 2] + c[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + c[2, 2] - c[0, 0] - c[1, 1]) * 2.0
        q = [(c[1, 0] - c[0, 1]) / s, (c[0, 2] + c[2, 0]) / s, (c[1, 2] + c[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q / np.linalg.norm(q) * (1.0 if q[0] >= 0 else -1.0)


def quat_to_dcm(q):
    """DCM of a scalar-first quaternion."""
    q0, q1, q2, q3 = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
            [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
            [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
        ]
    )
