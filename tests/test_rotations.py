"""Quaternion algebra against independent constructions (axis-angle by hand, scipy)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from startracker import rotations as rot


def axis_angle_matrix(axis, angle):
    """Rodrigues' formula, written independently of the module under test."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_rotation_about_z_by_90_deg_maps_x_to_y():
    q = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(rot.quat_rotate(q, [1, 0, 0]), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_matrix(q), axis_angle_matrix([0, 0, 1], np.pi / 2), atol=1e-15)


def test_product_composes_rotations_in_order():
    rng = np.random.default_rng(1)
    qa, qb = rot.quat_random(rng, 2)
    # v_c = R(qb) R(qa) v  <=>  q_a_to_c = qb ⊗ qa
    np.testing.assert_allclose(
        rot.quat_to_matrix(rot.quat_multiply(qb, qa)), rot.quat_to_matrix(qb) @ rot.quat_to_matrix(qa), atol=1e-14
    )


def test_matrix_matches_rodrigues_for_random_axes():
    rng = np.random.default_rng(2)
    for _ in range(20):
        axis = rng.normal(size=3)
        angle = rng.uniform(0, np.pi)
        q = rot.quat_from_rotvec(axis / np.linalg.norm(axis) * angle)
        np.testing.assert_allclose(rot.quat_to_matrix(q), axis_angle_matrix(axis, angle), atol=1e-13)


def test_scipy_roundtrip_keeps_scalar_first_convention():
    q = np.array([0.5, 0.5, 0.5, 0.5])
    np.testing.assert_allclose(rot.to_scipy(q).as_matrix(), rot.quat_to_matrix(q), atol=1e-15)
    np.testing.assert_allclose(rot.from_scipy(rot.to_scipy(q)), q, atol=1e-15)


def test_angle_between_small_rotation_is_accurate():
    q1 = np.array([1.0, 0, 0, 0])
    q2 = rot.quat_from_rotvec([1e-9, 0, 0])
    assert rot.quat_angle_between(q1, q2) == pytest.approx(1e-9, rel=1e-6)
    # sign invariance: q and -q are the same attitude
    assert rot.quat_angle_between(q2, -q2) == pytest.approx(0.0, abs=1e-15)


def test_integrate_constant_rate_is_exact_rotation():
    q0 = np.array([1.0, 0, 0, 0])
    w = np.radians([0.0, 0.0, 20.0])
    q1 = rot.quat_integrate(q0, w, 0.5)
    assert rot.quat_angle_between(q0, q1) == pytest.approx(np.radians(10.0), rel=1e-12)


def test_bad_input_names_argument():
    with pytest.raises(ValueError, match="q"):
        rot.quat_normalize([0, 0, 0, 0])
    with pytest.raises(ValueError, match="NaN"):
        rot.quat_normalize([np.nan, 0, 0, 1])
    with pytest.raises(ValueError, match="rotvec"):
        rot.quat_from_rotvec([1.0, 2.0])


unit_quats = arrays(np.float64, 4, elements=st.floats(-1, 1, allow_nan=False)).filter(lambda q: np.linalg.norm(q) > 0.1)


@settings(max_examples=200, deadline=None)
@given(unit_quats)
def test_roundtrips_property(q):
    q = rot.quat_normalize(q)
    back_m = rot.quat_from_matrix(rot.quat_to_matrix(q))
    # q and -q are one rotation; near w = 0 rounding may pick either sign
    assert min(np.abs(back_m - q).max(), np.abs(back_m + q).max()) < 1e-12
    assert back_m[0] >= 0
    back = rot.quat_from_rotvec(rot.quat_to_rotvec(q))
    assert rot.quat_angle_between(back, q) < 1e-12
    np.testing.assert_allclose(rot.quat_multiply(q, rot.quat_conjugate(q)), [1, 0, 0, 0], atol=1e-14)


def test_quaternion_algebra_checks_its_arguments_once():
    with pytest.raises(ValueError, match="q1"):
        rot.quat_multiply([np.nan, 0, 0, 1], [1, 0, 0, 0])
    with pytest.raises(ValueError, match="q2"):
        rot.quat_multiply([1, 0, 0, 0], [1, 0, 0])
    with pytest.raises(ValueError, match="q1 .* q2 .* broadcast"):
        rot.quat_multiply(np.ones((3, 4)), np.ones((2, 4)))
    with pytest.raises(ValueError, match="q"):
        rot.quat_conjugate([1, 0, np.inf, 0])
    with pytest.raises(TypeError, match="q"):
        rot.quat_conjugate("1 0 0 0")


def test_product_broadcasts_like_scipy_composition():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    qa = rot.quat_random(rng, 5)  # (5, 4)
    qb = rot.quat_random(rng)  # (4,)
    xyzw = [1, 2, 3, 0]
    for left, right in ((qb, qa), (qa, qb), (qa, qa[::-1])):
        # scipy: (A * B) applies B first, as q_left ⊗ q_right does
        truth = (Rotation.from_quat(np.atleast_2d(left)[:, xyzw]) * Rotation.from_quat(np.atleast_2d(right)[:, xyzw])).as_matrix()
        np.testing.assert_allclose(rot.quat_to_matrix(rot.quat_multiply(left, right)), truth, atol=1e-14)
    # the conjugate inverts: q ⊗ q* is the identity, row by row
    np.testing.assert_allclose(rot.quat_multiply(qa, rot.quat_conjugate(qa)), np.tile([1.0, 0, 0, 0], (5, 1)), atol=1e-15)
    # the normalised quaternion is the same rotation, unit norm, w >= 0
    raw = -3.0 * qa
    unit = rot.quat_normalize(raw)
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0, atol=1e-15)
    assert np.all(unit[:, 0] >= 0)
    np.testing.assert_allclose(rot.quat_to_matrix(unit), Rotation.from_quat(raw[:, xyzw]).as_matrix(), atol=1e-14)


def test_pointing_errors_kernel_matches_scipy_rotations():
    """The env step's attitude figures (startracker.kernels.rotations.pointing_errors) against scipy's Rotation:
    the angles of q_true⁻¹ q_target and q_true⁻¹ q_est, the rotation vectors of q_est⁻¹ q_target and q_est⁻¹ q_true."""
    from scipy.spatial.transform import Rotation as R
    from startracker.kernels.rotations import pointing_errors

    rng = np.random.default_rng(7)

    def scipy_rot(q):  # (w, x, y, z) -> scipy's (x, y, z, w)
        return R.from_quat([q[1], q[2], q[3], q[0]])

    for _ in range(50):
        q_true, q_est, q_target = (rng.normal(size=4) for _ in range(3))
        q_est = q_true + 1e-3 * rng.normal(size=4)  # an estimate near the truth, a target anywhere
        out = pointing_errors(q_true, q_est, q_target)
        rt, re, rg = scipy_rot(q_true), scipy_rot(q_est), scipy_rot(q_target)
        assert out.shape == (8,)
        assert out[0] == pytest.approx((rt.inv() * rg).magnitude(), abs=1e-12)
        assert out[1] == pytest.approx((rt.inv() * re).magnitude(), abs=1e-12)
        assert np.allclose(out[2:5], (re.inv() * rg).as_rotvec(), atol=1e-12)
        assert np.allclose(out[5:8], (re.inv() * rt).as_rotvec(), atol=1e-12)
