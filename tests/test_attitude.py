"""Wahba's problem: recovery of a known rotation and a covariance that matches the Monte Carlo scatter."""

import numpy as np
import pytest
from scipy import stats

from startracker.attitude import solve_wahba, solve_wahba_batch
from startracker.rotations import quat_multiply, quat_conjugate, quat_random, quat_to_matrix, quat_to_rotvec, quat_angle_between


def noisy_unit(v, sigma, rng):
    """Perturb each unit vector by isotropic small-angle noise of 1-sigma `sigma` per axis."""
    n = rng.normal(size=v.shape) * sigma
    n -= np.sum(n * v, axis=1, keepdims=True) * v  # tangent plane
    out = v + n
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def random_fov_vectors(rng, k, half_angle=np.radians(10)):
    v = np.column_stack([rng.uniform(-1, 1, (k, 2)) * np.tan(half_angle), np.ones(k)])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_recovers_random_rotation_noise_free():
    rng = np.random.default_rng(10)
    q = quat_random(rng)
    b = random_fov_vectors(rng, 8)
    r = b @ quat_to_matrix(q).T
    sol = solve_wahba(b, r)
    assert sol.success
    assert quat_angle_between(sol.q_meas_to_ref, q) < 1e-12


def test_two_vectors_are_enough_and_one_is_refused():
    rng = np.random.default_rng(11)
    q = quat_random(rng)
    b = random_fov_vectors(rng, 2)
    r = b @ quat_to_matrix(q).T
    assert solve_wahba(b, r).success
    one = solve_wahba(b[:1], r[:1])
    assert not one.success and "fewer" in one.status
    par = solve_wahba(np.array([[0, 0, 1.0], [0, 0, 2.0]]), np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    assert not par.success


def test_covariance_is_consistent_chi_square_monte_carlo():
    rng = np.random.default_rng(12)
    sigma = np.radians(5 / 3600)
    q = quat_random(rng)
    b_true = random_fov_vectors(rng, 10)
    r = b_true @ quat_to_matrix(q).T
    nees = []
    errs = []
    for _ in range(500):
        b = noisy_unit(b_true, sigma, rng)
        sol = solve_wahba(b, r, sigma_rad=sigma)
        # error rotation in the measurement frame: q_true = q_est ⊗ dq
        dtheta = quat_to_rotvec(quat_multiply(quat_conjugate(sol.q_meas_to_ref), q))
        nees.append(dtheta @ np.linalg.solve(sol.covariance_rad2, dtheta))
        errs.append(dtheta)
    nees = np.array(nees)
    # mean NEES of 3-dof errors over 500 runs: 95% interval of chi2(1500)/500
    lo, hi = stats.chi2.ppf([0.005, 0.995], 3 * 500) / 500
    assert lo < nees.mean() < hi
    # cross-boresight error is much smaller than roll error for a narrow field
    errs = np.array(errs)
    assert errs[:, 2].std() > 3 * errs[:, 0].std()


def test_batch_solves_each_problem_independently_and_masks_padding():
    rng = np.random.default_rng(13)
    qs = quat_random(rng, 5)
    b = np.stack([random_fov_vectors(rng, 6) for _ in range(5)])
    r = np.einsum("bij,bkj->bki", quat_to_matrix(qs), b)
    mask = np.ones((5, 6), bool)
    mask[0, 1:] = False  # one vector only: fails
    r[2, 5] = -r[2, 5]  # garbage in a padded slot must not matter
    mask[2, 5] = False
    q, cov, rms, ok = solve_wahba_batch(b, r, 1e-5, mask)
    assert ok.tolist() == [False, True, True, True, True]
    assert np.all(quat_angle_between(q[1:], qs[1:]) < 1e-10)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="v_meas"):
        solve_wahba(np.zeros((3, 3)), np.eye(3))
    with pytest.raises(ValueError, match="same length"):
        solve_wahba(np.eye(3), np.eye(3)[:2])
    with pytest.raises(ValueError, match="NaN"):
        solve_wahba(np.full((3, 3), np.nan), np.eye(3))
    with pytest.raises(ValueError, match="sigma_rad"):
        solve_wahba(np.eye(3), np.eye(3), sigma_rad=-1.0)


from hypothesis import given, settings
from hypothesis import strategies as st


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(2, 12))
def test_wahba_is_invariant_to_the_order_of_the_vectors(seed, k):
    rng = np.random.default_rng(seed)
    q = quat_random(rng)
    b = noisy_unit(random_fov_vectors(rng, k), 1e-5, rng)
    r = random_fov_vectors(rng, k) @ quat_to_matrix(q).T  # any pairs, even inconsistent ones
    sig = rng.uniform(1e-6, 1e-4, k)
    perm = rng.permutation(k)
    s1 = solve_wahba(b, r, sig)
    s2 = solve_wahba(b[perm], r[perm], sig[perm])
    assert s1.success == s2.success
    if s1.success:
        assert quat_angle_between(s1.q_meas_to_ref, s2.q_meas_to_ref) < 1e-9
        np.testing.assert_allclose(s1.covariance_rad2, s2.covariance_rad2, rtol=1e-8, atol=1e-20)


@pytest.mark.parametrize("angle", [np.pi, np.pi - 1e-9, np.pi / 2, 1e-12, 0.0])
def test_any_rotation_angle_even_a_half_turn_equals_scipy(angle):
    # Davenport's eigenvector from the adjugate has no singular attitude (QUEST's Gibbs vector does at π).
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(31)
    for _ in range(20):
        axis = rng.normal(size=3)
        truth = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle)
        b = random_fov_vectors(rng, 12)
        r = noisy_unit(truth.apply(b), 1e-6, rng)
        sol = solve_wahba(b, r, 1e-6)
        ref, _ = Rotation.align_vectors(r, b)
        assert sol.success
        err = quat_angle_between(sol.q_meas_to_ref, ref.as_quat()[[3, 0, 1, 2]])
        assert err < 1e-11
