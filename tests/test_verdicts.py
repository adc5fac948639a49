"""Verdicts by consistency: a sample or an estimate is wrong when its true error fails the χ²(3) test on its own
covariance, confidently wrong when it is also flagged valid; the estimate monitors a saturated gyro."""

import gymnasium as gym
import numpy as np
import pytest
from scipy.stats import chi2

import envs  # noqa: F401
from startracker import onboard
from startracker.onboard import Estimate, chi2_3_threshold, judge_estimate, judge_samples
from startracker.rotations import quat_from_rotvec, quat_integrate, quat_interpolate, quat_multiply, quat_random
from startracker.sensor import AttitudeSample

ARCSEC = np.radians(1 / 3600)


@pytest.mark.parametrize("p", [1e-3, 1e-6, 1e-9, 1e-12])
def test_chi2_threshold_is_scipys_quantile(p):
    assert chi2_3_threshold(p) == pytest.approx(chi2.isf(p, 3), rel=1e-10)


def test_the_verdict_level_is_the_stated_one():
    assert onboard.VERDICT_CHI2_3 == pytest.approx(chi2.isf(onboard.VERDICT_FALSE_ALARM_P, 3), rel=1e-10)
    with pytest.raises(ValueError, match="false_alarm_p"):
        chi2_3_threshold(0.0)


def tracker_like_covariance(rng):
    """A star tracker's covariance: 2″ about two cross-boresight axes, 30″ in roll, the boresight anywhere."""
    a, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    sig = np.array([2.0, 2.0, 30.0]) * ARCSEC
    return a @ np.diag(sig**2) @ a.T, a, sig


def truth_history(rng):
    times = np.linspace(0.0, 0.1, 11)
    return times, quat_integrate(quat_random(rng), np.radians([3.0, -20.0, 5.0]), times)


@pytest.mark.parametrize("k", [1.0, 3.0, 6.0, 6.6, 6.75, 7.0, 12.0, 30.0])
def test_error_of_k_sigma_along_either_axis_is_judged_as_the_chi2_says(k):
    """A sample k σ off along its least-certain (roll) or most-certain (cross-boresight) axis has NEES k²: wrong
    exactly when k² exceeds the χ²(3) quantile computed here with scipy, whichever axis it is."""
    rng = np.random.default_rng(int(k * 100))
    times, quats = truth_history(rng)
    cov, axes, sig = tracker_like_covariance(rng)
    limit = chi2.isf(onboard.VERDICT_FALSE_ALARM_P, 3)
    for axis in (0, 2):  # most certain, least certain
        t = 0.043
        q_true = quat_interpolate(times, quats, t)
        # q_true = q_meas ⊗ exp(δθ): the sample is the truth turned by -δθ
        q_meas = quat_multiply(q_true, quat_from_rotvec(-k * sig[axis] * axes[:, axis]))
        n_wrong, n_conf = judge_samples([AttitudeSample(t, q_meas, cov, 20)], np.zeros(1), times, quats)
        assert n_wrong == int(k * k > limit) and n_conf == n_wrong


def test_thirty_sigma_cross_boresight_is_wrong_now():
    """The old rule (wrong beyond max(5 √λ_max, 20″) = 150″ here) called a 60″ = 30σ cross-boresight error right."""
    rng = np.random.default_rng(3)
    times, quats = truth_history(rng)
    cov, axes, sig = tracker_like_covariance(rng)
    q_true = quat_interpolate(times, quats, 0.05)
    q_meas = quat_multiply(q_true, quat_from_rotvec(30 * sig[0] * axes[:, 0]))
    assert 30 * sig[0] < max(5 * sig[2], 20 * ARCSEC)
    assert judge_samples([AttitudeSample(0.05, q_meas, cov, 20)], np.zeros(1), times, quats) == (1, 1)


def test_confidently_wrong_needs_the_valid_flag():
    rng = np.random.default_rng(4)
    times, quats = truth_history(rng)
    cov, axes, sig = tracker_like_covariance(rng)
    samples = []
    for t, k in ((0.01, 50.0), (0.02, 50.0), (0.03, 1.0), (0.04, 50.0)):
        q_true = quat_interpolate(times, quats, t)
        samples.append(AttitudeSample(t, quat_multiply(q_true, quat_from_rotvec(k * sig[0] * axes[:, 0])), cov, 20))
    assert judge_samples(samples, np.zeros(4), times, quats, valid=[True, False, True, False]) == (3, 1)
    assert judge_samples(samples, np.zeros(4), times, quats) == (3, 3)


def test_estimate_verdict():
    q_true = quat_random(np.random.default_rng(5))
    cov = np.diag([4.0, 9.0, 16.0]) * ARCSEC**2
    limit = chi2.isf(onboard.VERDICT_FALSE_ALARM_P, 3)
    for k in (5.0, 7.0):
        off = quat_multiply(q_true, quat_from_rotvec([0.0, 0.0, -4.0 * k * ARCSEC]))  # k σ about z
        wrong = k * k > limit
        assert judge_estimate(Estimate(off, np.zeros(3), 4 * ARCSEC, True, cov), q_true) == (wrong, wrong)
        assert judge_estimate(Estimate(off, np.zeros(3), 4 * ARCSEC, False, cov), q_true) == (wrong, False)
    # before a fix the estimate claims nothing
    assert judge_estimate(Estimate(np.array([1.0, 0, 0, 0]), np.zeros(3), np.pi, False), q_true) == (False, False)


def run_slew(faults, seed=0, **kwargs):
    from policies import EigenaxisSlewPolicy

    env = gym.make("startracker/AgileSlew-v0", faults=faults, max_episode_s=10.0, **kwargs)
    obs, info = env.reset(seed=seed, options={"slew_angle_deg": 60.0})
    pol = EigenaxisSlewPolicy.from_env(env)
    infos = [info]
    done = False
    while not done:
        obs, r, te, tr, info = env.step(pol.act(obs))
        infos.append(info)
        done = te or tr
    env.close()
    return infos


@pytest.mark.parametrize("extra", [[], [dict(kind="blank", t_start_s=3.5, duration_s=1.0)]],
                         ids=["saturation", "saturation+blank"])
def test_gyro_saturation_during_a_slew_gives_no_confidently_wrong_estimate(extra):
    """The gyro clips at 1 °/s for 3 s of a 20 °/s slew (blank frames in the same window too): the estimate
    drifts by degrees, but its covariance grows with it and it flags itself invalid; it is never confidently
    wrong, and valid again with an arc-second error once the fault clears."""
    faults = [dict(kind="gyro_saturation", t_start_s=3.0, duration_s=3.0, severity=1.0)] + extra
    infos = run_slew(faults)
    during = [i for i in infos if 3.2 <= i["time_s"] <= 6.0]
    assert max(i["attitude_error_arcsec"] for i in during) > 3600.0  # the fault bites: degrees of true error
    assert not any(i["estimate_valid"] for i in during)
    assert infos[-1]["n_confidently_wrong_estimates_total"] == 0
    assert not any(i["estimate_confidently_wrong"] for i in infos)
    assert infos[-1]["n_confidently_wrong_samples_total"] == 0
    late = [i for i in infos if i["time_s"] >= 8.0]
    assert all(i["estimate_valid"] for i in late) and max(i["attitude_error_arcsec"] for i in late) < 60.0


def test_fault_free_slew_is_consistent():
    """No fault: the estimate is valid and never wrong; the samples' verdicts are counted in the info."""
    infos = run_slew([])
    assert all(i["estimate_valid"] for i in infos[5:])
    assert infos[-1]["n_wrong_estimates_total"] == 0 and infos[-1]["n_confidently_wrong_samples_total"] == 0
    assert sum(i["n_attitude_samples"] for i in infos) > 100
