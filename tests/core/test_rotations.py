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
_UNIT = _DIRS / np.linalg.norm(_DIRS, axis=1, keepdims=True)
ROTVECS = np.vstack([_UNIT[:24] * RNG.uniform(1e-10, np.pi - 1e-3, (24, 1)),  # the general case
                     _UNIT[24:27] * 1e-9,  # the series branch of Rodrigues
                     _UNIT[27:] * (np.pi - 1e-9)])  # next to pi, where the rotation vector is still unique


@pytest.mark.parametrize("rv", list(ROTVECS))
def test_rotation_vector_against_scipy_and_round_trip(rv):
    """Rodrigues (rotvec_to_dcm) against scipy, and back through dcm_to_rotvec, for angles up to pi."""
    ref = Rotation.from_rotvec(rv).as_matrix()
    c = R.rotvec_to_dcm(rv)
    assert np.allclose(c, ref, atol=1e-14)
    assert np.allclose(c @ c.T, np.eye(3), atol=1e-14) and np.isclose(np.linalg.det(c), 1.0)
    assert np.allclose(R.dcm_to_rotvec(c), rv, rtol=0, atol=1e-12)


def test_rotation_vector_of_elementary_rotations_and_batches():
    # closed forms: rot_x(a) is the rotation vector (a, 0, 0), and so on, for any |a| < pi
    for k, rot in enumerate((R.rot_x, R.rot_y, R.rot_z)):
        for a in (-3.0, -0.5, 1e-7, 0.25, 3.1):
            assert np.allclose(R.dcm_to_rotvec(rot(a)), np.eye(3)[k] * a, rtol=0, atol=1e-14)
    assert np.allclose(R.dcm_to_rotvec(np.eye(3)), 0.0, atol=0)
    batch = np.array([R.rot_x(0.1), R.rot_y(-0.2), R.rot_z(0.3)])
    assert np.allclose(R.dcm_to_rotvec(batch), np.diag([0.1, -0.2, 0.3]), atol=1e-15)


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


def test_quaternion_and_euler_of_closed_form_rotations():
    a = 0.7
    # a turn a about z: q = (cos a/2, 0, 0, sin a/2); about x: (cos a/2, sin a/2, 0, 0)
    assert np.allclose(R.dcm_to_quat(R.rot_z(a)), [np.cos(a / 2), 0, 0, np.sin(a / 2)], atol=1e-15)
    assert np.allclose(R.dcm_to_quat(R.rot_x(a)), [np.cos(a / 2), np.sin(a / 2), 0, 0], atol=1e-15)
    assert np.allclose(R.quat_to_dcm([np.cos(a / 2), 0, np.sin(a / 2), 0]), R.rot_y(a), atol=1e-15)
    # a half turn about x has q0 = 0 (the trace <= 0 branch): q = (0, 1, 0, 0)
    assert np.allclose(R.dcm_to_quat(np.diag([1.0, -1.0, -1.0])), [0, 1, 0, 0], atol=1e-15)
    # quat_to_dcm normalises: any positive multiple of q is the same rotation
    q = np.array([0.9, -0.1, 0.3, 0.2])
    assert np.allclose(R.quat_to_dcm(3.0 * q), R.quat_to_dcm(q), atol=1e-15)
    c = R.quat_to_dcm(q)
    assert np.allclose(c @ c.T, np.eye(3), atol=1e-15) and np.isclose(np.linalg.det(c), 1.0)
    # pitch alone is a rotation about East (x), roll alone about the body y axis, yaw alone about Up (z)
    assert np.allclose(R.dcm_to_euler(R.rot_x(0.3)), (0.3, 0.0, 0.0), atol=1e-15)
    assert np.allclose(R.dcm_to_euler(R.rot_y(-0.4)), (0.0, -0.4, 0.0), atol=1e-15)
    assert np.allclose(R.dcm_to_euler(R.rot_z(2.5)), (0.0, 0.0, 2.5), atol=1e-15)


@pytest.mark.parametrize("pitch,roll,yaw", ANGLES[:20])
def test_round_trip_euler_dcm_quaternion_rotation_vector(pitch, roll, yaw):
    """Euler -> DCM -> quaternion -> DCM -> rotation vector -> DCM -> Euler returns the angles."""
    c = R.euler_to_dcm(pitch, roll, yaw)
    c2 = R.quat_to_dcm(R.dcm_to_quat(c))
    c3 = R.rotvec_to_dcm(R.dcm_to_rotvec(c2))
    for m in (c2, c3):
        assert np.allclose(m, c, atol=1e-13)
    assert np.allclose(R.dcm_to_euler(c3), (pitch, roll, yaw), atol=1e-12)
