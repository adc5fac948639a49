"""The onboard unit on a trajectory of one's own: truth in, estimate history out, no env."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from envs.avionics import Avionics
from startracker.onboard import CONFIRM_DELIVERIES, StarTrackerUnit, UnitConfig, run_star_tracker

ARCSEC = np.radians(1 / 3600)


def constant_rate_trajectory(duration_s=5.0, rate_hz=100.0, w_deg_s=(0.5, -0.3, 1.0)):
    """q_body_to_icrs(t) = q0 ⊗ exp(ω t), ω in the body frame (scipy: r0 * exp), sampled at rate_hz."""
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    w = np.radians(w_deg_s)
    r = Rotation.from_euler("zyx", [40, -20, 10], degrees=True) * Rotation.from_rotvec(np.outer(t, w))
    return t, r, w


def errors_arcsec(r_true, t, hist):
    """Angle between the estimate and the truth at each frame end, arcsec."""
    truth = r_true[np.searchsorted(t, hist.t_s - 1e-9)]
    assert np.allclose(t[np.searchsorted(t, hist.t_s - 1e-9)], hist.t_s)
    d = truth.inv() * Rotation.from_quat(hist.q_body_to_icrs, scalar_first=True)
    return np.linalg.norm(d.as_rotvec(), axis=1) / ARCSEC


def test_readme_example_tracks_a_constant_rate_rotation():
    t, r, _ = constant_rate_trajectory()
    q = r.as_quat(scalar_first=True)  # (T, 4) w, x, y, z
    hist = run_star_tracker(t, q, camera="paper000", rng=np.random.default_rng(0))
    assert len(hist.t_s) == 50 and hist.q_body_to_icrs.shape == (50, 4)
    # lost -> acquire -> track within the first frames, then tracking to the end
    assert hist.mode[0] in ("acquire", "track") and hist.mode.index("track") <= 2
    assert all(m == "track" for m in hist.mode[3:])
    # the first fix, at 1.2 °/s, waits for CONFIRM_DELIVERIES frames that check its timestamp before it is valid
    assert not hist.valid[:2 + CONFIRM_DELIVERIES].any() and hist.valid[2 + CONFIRM_DELIVERIES:].all()
    assert np.all(hist.n_attitude_samples[3:] >= 1)
    err = errors_arcsec(r, t, hist)
    late = slice(20, None)
    # the estimate follows the truth to the tracker's accuracy, inside the filter's own 3σ
    assert err[late].max() < 30.0
    assert np.all(err[late] <= 3 * hist.attitude_sigma_rad[late] / ARCSEC + 2.0)
    # and it is an estimate of this trajectory: the truth 0.1 s earlier is thousands of arcsec away
    d = (r[np.searchsorted(t, hist.t_s[late] - 0.1 - 1e-9)].inv()
         * Rotation.from_quat(hist.q_body_to_icrs[late], scalar_first=True)).magnitude() / ARCSEC
    assert d.min() > 300.0


def test_own_gyro_rates_are_used():
    """A perfect gyro given by the user (the true rate) is what the filter's rate follows (the simulated tactical
    gyro's white noise alone is ~4e-4 rad/s per sample); a biased one is learned as a bias."""
    t, r, w = constant_rate_trajectory(duration_s=4.0)
    q = r.as_quat(scalar_first=True)
    good = run_star_tracker(t, q, omega_gyro=np.tile(w, (len(t) - 1, 1)), rng=np.random.default_rng(1))
    err = errors_arcsec(r, t, good)
    assert good.mode[-1] == "track" and err[15:].max() < 15.0
    assert np.allclose(good.omega_body[-1], w, atol=1e-5)  # the filter's rate is the gyro's minus a tiny bias
    bad = run_star_tracker(t, q, omega_gyro=np.tile(w + np.radians([0.0, 0.0, 0.2]), (len(t) - 1, 1)),
                           rng=np.random.default_rng(1))
    assert bad.mode[-1] == "track" and np.allclose(bad.omega_body[-1], w, atol=1e-4)
    assert errors_arcsec(r, t, bad)[25:].max() < 30.0
    simulated = run_star_tracker(t, q, rng=np.random.default_rng(1))
    assert not np.allclose(simulated.omega_body[-1], w, atol=1e-5)


def test_run_star_tracker_rejects_bad_input():
    t, r, _ = constant_rate_trajectory(duration_s=1.0)
    q = r.as_quat(scalar_first=True)
    with pytest.raises(ValueError, match="t_s"):
        run_star_tracker(t[::-1], q)
    with pytest.raises(ValueError, match="q_body_to_icrs"):
        run_star_tracker(t, q[:-1])
    with pytest.raises(ValueError, match="at least one frame"):
        run_star_tracker(t[:5], q[:5])
    with pytest.raises(ValueError, match="omega_gyro"):
        run_star_tracker(t, q, omega_gyro=np.zeros((3, 3)))
    with pytest.raises(TypeError, match="rng"):
        run_star_tracker(t, q, rng=0)


def test_state_exists_after_init():
    """Before any reset, the avionics answer with an invalid estimate instead of failing."""
    for unit in (Avionics(), StarTrackerUnit(UnitConfig(gyro_grade="ideal"))):
        est = unit.estimate()
        assert est.valid is False and est.attitude_sigma_rad == np.pi and est.attitude_cov_rad2 is None
        assert np.array_equal(est.q_body_to_icrs, [1.0, 0.0, 0.0, 0.0]) and np.array_equal(est.omega_body, np.zeros(3))
        assert unit.tracker_mode == "lost" and unit.last_stats["n_attitude_samples"] == 0
        assert unit.n_wrong_samples_total == 0 and unit.reacquisition_times_s == []
        assert unit.render_last_frame() is None and unit.ekf is None
        with pytest.raises(RuntimeError, match="reset"):
            unit.observe(np.array([0.0, 0.01]), np.array([[1.0, 0, 0, 0]] * 2), np.random.default_rng(0))


def test_count_wrong_samples_judges_only_samples_inside_the_truth_history():
    """Samples stamped outside the history are not judged; those inside are, against the slerped truth at their
    true instant (stamp minus its timestamp error)."""
    from startracker.onboard import count_wrong_samples
    from startracker.rotations import quat_from_rotvec, quat_integrate, quat_interpolate, quat_multiply
    from startracker.sensor import AttitudeSample

    times = np.linspace(1.0, 1.1, 11)
    quats = quat_integrate(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.1, 0.2, -0.3]), times - 1.0)
    cov = (np.radians(1 / 3600) ** 2) * np.eye(3)  # 1″: wrong beyond max(5″, 20″) = 20″
    off = quat_from_rotvec(np.radians([0.0, 0.0, 60 / 3600]))  # 60″ off: wrong wherever it is judged
    bad = [AttitudeSample(t, quat_multiply(quat_interpolate(times, quats, min(max(t, 1.0), 1.1)), off), cov, 5)
           for t in (0.95, 1.02, 1.05, 1.2)]
    good = AttitudeSample(1.07, quat_interpolate(times, quats, 1.07), cov, 5)
    assert count_wrong_samples(bad + [good], np.zeros(5), times, quats) == 2  # 0.95 and 1.2 s are outside
    assert count_wrong_samples([bad[0], bad[3]], np.zeros(2), times, quats) == 0
    assert count_wrong_samples([], np.zeros(0), times, quats) == 0
    # a timestamp error moves the judged instant: the sample stamped 1.2 s was taken at 1.08 s (inside, and
    # 60″ off the truth at 1.1 s which is not its truth at 1.08 s either)
    assert count_wrong_samples([bad[3]], np.array([0.12]), times, quats) == 1
    # the good sample, stamped 0.03 s late, is judged against the truth at 1.04 s: 0.03 s × 0.37 rad/s ≈ 2300″ off
    assert count_wrong_samples([good], np.array([0.03]), times, quats) == 1
    assert count_wrong_samples([good], np.array([0.0]), times, quats) == 0
