"""Rotations of calib.core.rotations against closed forms and against scipy.spatial.transform.Rotation (an
independent implementation): round trips, orthonormality, the ENU Euler convention of the module docstring."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.core import rotations as R

RNG = np.random.default_rng(20261125)
ANGLES = RNG.uniform(-np.pi, np.pi, (50, 3)) * np.array([0.49, 1.0, 1.0])  # |pitch| < 90 deg


def test_elementary_rotations_are_right_handed():
    # a quarter turn about z takes x to y, about x takes y to z, about y takes z to x (active, right-handed)
    assert np.allclose(R.rot_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(R.rot_x(np.pi / 2) @ [0, 1, 0], [0, 0, 1])
    assert np.allclose(R.rot_y(np.pi / 2) @ [0, 0, 1], [1, 0, 0])


@pytest.mark.parametrize("pitch,roll,yaw", ANGLES[:20])
def test_euler_convention_is_z_x_y_as_documented(pitch, roll, yaw):
    # C_b^n = R_z(yaw) R_x(pitch) R_y(roll): intrinsic z, x', y'' (scipy's upper-case = intrinsic)
    ref = Rotation.from_euler("ZXY", [yaw, pitch, roll]).as_matrix()
    assert np.allclose(R.euler_to_dcm(pitch, roll, yaw), ref, atol=1e-14)


@pytest.mark.parametrize("pitch,roll,yaw", ANGLES)
def test_euler_round_trip_and_orthonormality(pitch, roll, yaw):
    c = R.euler_to_dcm(pitch, roll, yaw)
    assert np.allclose(c @ c.T, np.eye(3), atol=1e-14) and np.isclose(np.linalg.det(c), 1.0)
    assert np.allclose(R.dcm_to_euler(c), (pitch, roll, yaw), atol=1e-12)


def test_yaw_is_counter_clockwise_from_north_towards_west():
    # the body y axis (front) points North at yaw 0 and West at yaw +90 deg (heading = -yaw)
    assert np.allclose(R.euler_to_dcm(0, 0, np.pi / 2) @ [0, 1, 0], [-1, 0, 0])


_DIRS = RNG.normal(size=(30, 3))
ROTVECS = _DIRS / np.linalg.norm(_DIRS, axis=1, keepdims=True) * RNG.uniform(1e-10, np.pi - 1e-3, (30, 1))


@pytest.mark.parametrize("rv", list(ROTVECS))
def test_rotation_vector_against_scipy_and_round_trip(rv):
    """Angles below pi, where the rotation vector is unique (the documented range of dcm_to_rotvec)."""
    ref = Rotation.from_rotvec(rv).as_matrix()
    assert np.allclose(R.rotvec_to_dcm(rv), ref, atol=1e-14)
    assert np.allclose(R.dcm_to_rotvec(ref), rv, atol=1e-9 * max(1.0, np.linalg.norm(rv)))


def test_axis_angle_is_rodrigues():
    axis = np.array([1.0, -2.0, 0.5])
    for a in (0.0, 0.3, -2.0, np.pi):
        ref = Rotation.from_rotvec(axis / np.linalg.norm(axis) * a).as_matrix()
        assert np.allclose(R.axis_angle(axis, a), ref, atol=1e-14)


@pytest.mark.parametrize("k", range(40))
def test_quaternion_against_scipy_all_branches(k):
    # random rotations plus rotations near pi about each axis (the trace <= 0 branches of Shepperd's method)
    rot = Rotation.random(random_state=k) if k < 30 else Rotation.from_rotvec(np.eye(3)[k % 3] * (np.pi - 1e-3 * k))
    c = rot.as_matrix()
    q = R.dcm_to_quat(c)
    x, y, z, w = rot.as_quat()  # scipy: scalar-last
    ref = np.array([w, x, y, z]) * (1 if w >= 0 else -1)
    assert np.isclose(np.linalg.norm(q), 1.0) and q[0] >= 0
    assert np.allclose(q, ref, atol=1e-12)
    assert np.allclose(R.quat_to_dcm(q), c, atol=1e-13)


def test_skew_is_the_cross_product():
    a, b = RNG.normal(size=3), RNG.normal(size=3)
    assert np.allclose(R.skew(a) @ b, np.cross(a, b))
    assert np.allclose(R.skew(a), -R.skew(a).T)


def test_small_misalignment_convention():
    # C_computed = (I - [phi x]) C_true: a small phi about Up rotates the computed frame clockwise
    phi = np.array([0.0, 0.0, 1e-6])
    c_true = R.euler_to_dcm(0.1, -0.2, 0.3)
    c_comp = (np.eye(3) - R.skew(phi)) @ c_true
    assert np.allclose(R.dcm_to_rotvec(c_comp @ c_true.T), -phi, atol=1e-12)
