"""MEKF: convergence, NEES consistency, bias estimation, coasting covariance, lean path = filterpy path."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from startracker.filter import AttitudeEKF
from startracker.imu import Gyro, GyroSpec
from startracker.rotations import (
    quat_from_rotvec,
    quat_multiply,
    quat_conjugate,
    quat_random,
    quat_to_matrix,
    quat_to_rotvec,
)

ARCSEC = math.pi / 180.0 / 3600.0
DEG = math.pi / 180.0


def star_tracker_cov(rng=None):
    """Body-frame covariance of a tracker with 5" cross-boresight and 40" roll noise, tilted mounting."""
    q_cam_to_body = quat_from_rotvec([0.3, -0.2, 0.1])
    c = quat_to_matrix(q_cam_to_body)
    return c @ np.diag([(5 * ARCSEC) ** 2, (5 * ARCSEC) ** 2, (40 * ARCSEC) ** 2]) @ c.T


def attitude_error(q_est, q_true):
    """Body-frame rotation vector δθ with q_true = q_est ⊗ exp(δθ)."""
    return quat_to_rotvec(quat_multiply(quat_conjugate(q_est), q_true))


class Truth:
    """Piecewise-constant true rate per frame (exact attitude at any instant) and a gyro."""

    def __init__(self, rng, gyro_spec, frame_s=0.1, q0=None):
        self.rng = rng
        self.frame_s = frame_s
        self.q = quat_random(rng) if q0 is None else np.asarray(q0, float)
        self.t = 0.0
        self.k = 0
        self.gyro = Gyro(gyro_spec, rng)

    def rate(self, t):
        return np.array([0.1 * math.sin(0.3 * t), 0.05 * math.cos(0.2 * t), 20 * DEG * math.sin(0.05 * t + 1.0)])

    def frame(self, n_samples, cov):
        """Advance one frame: gyro sample over it, n attitude samples at random instants inside."""
        w = self.rate(self.t)
        y = self.gyro.measure(w, self.rng)
        t_meas = np.sort(self.t + self.frame_s * self.rng.uniform(0.0, 1.0, n_samples))
        q_true_at = quat_multiply(self.q, quat_from_rotvec(np.outer(t_meas - self.t, w)))
        noise = self.rng.standard_normal((n_samples, 3)) @ np.linalg.cholesky(cov).T
        q_meas = quat_multiply(q_true_at, quat_from_rotvec(noise))
        self.q = quat_multiply(self.q, quat_from_rotvec(w * self.frame_s))
        self.k += 1
        self.t = self.k * self.frame_s
        return y, self.t, q_meas, t_meas


@pytest.mark.parametrize("path", ["filterpy", "sequential"])
def test_converges_from_5_deg_initial_error(path):
    rng = np.random.default_rng(0)
    spec = GyroSpec(rate_hz=10.0, arw_rad_sqrt_s=1e-5, bias_sigma_rad_s=1 * math.pi / 180 / 3600)
    truth = Truth(rng, spec)
    q0 = quat_multiply(truth.q, quat_from_rotvec(5 * DEG * np.array([0.6, -0.48, 0.64])))
    f = AttitudeEKF.from_gyro_spec(spec, q0, sigma_attitude_rad=5 * DEG)
    assert np.degrees(np.linalg.norm(attitude_error(f.q_body_to_icrs, truth.q))) > 4.9
    cov = star_tracker_cov()
    errs = []
    for _ in range(30):
        y, t_end, qm, tm = truth.frame(3, cov)
        if path == "filterpy":
            for q, t in zip(qm, tm):
                f.update(q, cov, t, omega_gyro=y)
            f.propagate(y, t_end - f.t_s)
        else:
            f.process(y, t_end, qm, tm, np.broadcast_to(cov, (3, 3, 3)), method=path)
        errs.append(attitude_error(f.q_body_to_icrs, truth.q))
    errs = np.array(errs)
    # after one frame the 5° error is gone; after 3 s the error is at the tracker-noise level
    assert np.linalg.norm(errs[0]) < 100 * ARCSEC
    assert np.all(np.abs(errs[-1]) < 4 * f.attitude_sigma_rad)
    assert f.attitude_sigma_rad.max() < 30 * ARCSEC
    assert f.ekf.x.shape == (6, 1) and np.all(f.ekf.x == 0.0)  # filterpy's column vector, reset to zero


def test_nees_consistent_over_monte_carlo(method="sequential"):
    """Average NEES over 40 runs lies in the two-sided 95% χ² band at most instants (6 dof)."""
    runs, frames, n_s, frame_s = 40, 200, 3, 0.1
    spec = GyroSpec(rate_hz=10.0, arw_rad_sqrt_s=2e-5, rrw_rad_s_sqrt_s=1e-7, bias_sigma_rad_s=5e-5)
    cov = star_tracker_cov()
    chol = np.linalg.cholesky(cov)
    covs = np.broadcast_to(cov, (n_s, 3, 3))
    t_frame = frame_s * np.arange(frames)
    # the same smooth 20 deg/s-class rate profile in every run, piecewise constant per frame
    w = np.stack([0.1 * np.sin(0.3 * t_frame), 0.05 * np.cos(0.2 * t_frame), 20 * DEG * np.sin(0.05 * t_frame + 1)], 1)
    dq_frame = quat_from_rotvec(w * frame_s)
    nees = np.zeros((runs, frames))
    for r in range(runs):
        rng = np.random.default_rng(100 + r)
        gyro = Gyro(spec, rng)
        q_true = np.empty((frames + 1, 4))
        q_true[0] = quat_random(rng)
        for k in range(frames):
            q_true[k + 1] = quat_multiply(q_true[k], dq_frame[k])
        dt_s = np.sort(frame_s * rng.uniform(0, 1, (frames, n_s)), axis=1)
        q_at = quat_multiply(q_true[:-1, None, :], quat_from_rotvec(w[:, None, :] * dt_s[..., None]))
        q_meas = quat_multiply(q_at, quat_from_rotvec(rng.standard_normal((frames, n_s, 3)) @ chol.T))
        p0_att = 1 * DEG
        q0 = quat_multiply(q_true[0], quat_from_rotvec(rng.normal(0.0, p0_att, 3)))
        f = AttitudeEKF(
            q0, arw_rad_sqrt_s=spec.arw_rad_sqrt_s, rrw_rad_s_sqrt_s=spec.rrw_rad_s_sqrt_s,
            sigma_attitude_rad=p0_att, sigma_bias_rad_s=spec.bias_sigma_rad_s,
        )
        q_est, err_b, p_all = np.empty((frames, 4)), np.empty((frames, 3)), np.empty((frames, 6, 6))
        for k in range(frames):
            y = gyro.measure(w[k], rng)
            f.process(y, t_frame[k] + frame_s, q_meas[k], t_frame[k] + dt_s[k], covs, method=method)
            q_est[k], err_b[k], p_all[k] = f.q_body_to_icrs, gyro.bias_rad_s - f.bias_rad_s, f.P
        e = np.concatenate([attitude_error(q_est, q_true[1:]), err_b], axis=1)
        nees[r] = np.einsum("ki,ki->k", e, np.linalg.solve(p_all, e[..., None])[..., 0])
    mean_nees = nees.mean(axis=0)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    inside = np.mean((mean_nees > lo) & (mean_nees < hi))
    assert inside > 0.85, (inside, mean_nees.mean())
    assert 5.6 < nees.mean() < 6.4


def test_gyro_bias_estimated_during_slew():
    rng = np.random.default_rng(3)
    b_true = np.array([10.0, -5.0, 8.0]) * DEG / 3600.0  # °/h
    spec = GyroSpec(rate_hz=10.0, arw_rad_sqrt_s=1e-6)
    truth = Truth(rng, spec)
    truth.gyro._b_const = b_true.copy()  # a known constant bias (tests the estimate, not the draw)
    f = AttitudeEKF(truth.q, arw_rad_sqrt_s=1e-6, rrw_rad_s_sqrt_s=1e-9, sigma_attitude_rad=10 * ARCSEC,
                    sigma_bias_rad_s=50 * DEG / 3600)
    cov = star_tracker_cov()
    for _ in range(600):  # 60 s
        y, t_end, qm, tm = truth.frame(3, cov)
        f.process(y, t_end, qm, tm, np.broadcast_to(cov, (3, 3, 3)), method="sequential")
    err = f.bias_rad_s - b_true
    assert np.all(np.abs(err) < 3 * f.bias_sigma_rad_s)
    assert np.linalg.norm(err) < 0.02 * np.linalg.norm(b_true)
    assert np.all(f.bias_sigma_rad_s < 0.1 * DEG / 3600)


def test_covariance_grows_when_coasting_as_closed_form():
    """At ω̂ = 0: P_θθ(t) = P_θθ(0) + P_bb(0) t² + σ_v² t + σ_u² t³/3, P_θb(t) = -P_bb(0) t - σ_u² t²/2."""
    sv, su, pa, pb = 3e-5, 2e-7, (10 * ARCSEC) ** 2, (0.5 * DEG / 3600) ** 2
    f = AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=sv, rrw_rad_s_sqrt_s=su,
                    sigma_attitude_rad=math.sqrt(pa), sigma_bias_rad_s=math.sqrt(pb))
    var = [f.P[0, 0]]
    for _ in range(1000):  # 100 s, gyro reads exactly the bias estimate (0)
        f.propagate(np.zeros(3), 0.1)
        var.append(f.P[0, 0])
    t = 100.0
    np.testing.assert_allclose(np.diag(f.P)[:3], pa + pb * t**2 + sv**2 * t + su**2 * t**3 / 3, rtol=1e-9)
    np.testing.assert_allclose(np.diag(f.P[:3, 3:]), -pb * t - su**2 * t**2 / 2, rtol=1e-9)
    np.testing.assert_allclose(np.diag(f.P)[3:], pb + su**2 * t, rtol=1e-12)
    assert np.all(np.diff(var) > 0)
    # while rotating, the uncertainty still grows monotonically
    g = AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=sv, rrw_rad_s_sqrt_s=su)
    tr = [np.trace(g.P[:3, :3])]
    for _ in range(200):
        g.propagate([0.2, -0.3, 0.35], 0.05)
        tr.append(np.trace(g.P[:3, :3]))
    assert np.all(np.diff(tr) > 0)


@pytest.mark.parametrize("gate", [None, 16.27])
def test_lean_process_equals_filterpy_sequence(gate):
    rng = np.random.default_rng(4)
    cov0 = star_tracker_cov()
    kw = dict(arw_rad_sqrt_s=2e-5, rrw_rad_s_sqrt_s=1e-7, sigma_attitude_rad=0.5 * DEG, gate_chi2=gate)
    q0 = quat_random(rng)
    a = AttitudeEKF(q0, **kw)  # filterpy path
    b = AttitudeEKF(q0, **kw)  # lean path
    q_true = q0
    t = 0.0
    for frame in range(40):
        g = 4  # gyro samples per frame
        t_g = t + 0.025 * np.arange(1, g + 1)
        w_g = rng.normal(0.0, 0.3, (g, 3))  # gyro = truth (zero bias and noise)
        m = int(rng.integers(0, 8))
        t_m = np.sort(t + 0.1 * rng.uniform(0, 1, m))
        if m >= 2:
            t_m[1] = t_m[0]  # two exposures at one instant
        if m >= 3:
            t_m[2] = t_g[1]  # a sample exactly at a gyro boundary
            t_m = np.sort(t_m)
        # truth: the gyro rates are exact (piecewise constant); attitude at each exposure instant
        edges = np.concatenate([[t], t_g])

        def q_at(tq):
            q = q_true
            for j in range(g):
                dt = min(tq, edges[j + 1]) - edges[j]
                if dt <= 0:
                    break
                q = quat_multiply(q, quat_from_rotvec(w_g[j] * dt))
            return q

        q_m = np.array([quat_multiply(q_at(tq), quat_from_rotvec(rng.normal(0, 5 * ARCSEC, 3))) for tq in t_m])
        q_m = q_m.reshape(m, 4)
        if m and frame == 30:
            q_m[0] = quat_multiply(q_m[0], quat_from_rotvec([0.05, 0, 0]))  # outlier for the gate
        covs = np.array([cov0 * rng.uniform(0.5, 2.0) for _ in range(m)])
        accepted = b.process(w_g, t_g, q_m, t_m, covs, method="sequential")
        acc_a = []
        gi = 0
        tt = t
        for i in range(m):
            while t_g[gi] < t_m[i]:
                a.propagate(w_g[gi], t_g[gi] - tt)
                tt = t_g[gi]
                gi += 1
            acc_a.append(a.update(q_m[i], covs[i], t_m[i], omega_gyro=w_g[gi]))
            tt = t_m[i]
        while gi < g:
            a.propagate(w_g[gi], t_g[gi] - tt)
            tt = t_g[gi]
            gi += 1
        np.testing.assert_array_equal(accepted, acc_a)
        t = t_g[-1]
        q_true = q_at(t)
        np.testing.assert_allclose(a.q_body_to_icrs, b.q_body_to_icrs, rtol=0, atol=1e-13)
        np.testing.assert_allclose(a.bias_rad_s, b.bias_rad_s, rtol=0, atol=1e-13)
        np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-14 * np.abs(a.P).max())
        np.testing.assert_allclose(a.t_s, b.t_s, atol=1e-12)
    assert a.n_updates == b.n_updates > 100
    if gate is not None:
        assert a.n_rejected == b.n_rejected >= 1


def test_tracks_truth_with_up_to_21_samples_per_frame():
    """Frames of 0 to 21 samples, several gyro samples per frame: the estimate stays within its σ of the truth and
    the gate rejects exactly the one outlier."""
    rng = np.random.default_rng(7)
    cov = star_tracker_cov()
    chol = np.linalg.cholesky(cov)
    kw = dict(arw_rad_sqrt_s=2e-5, rrw_rad_s_sqrt_s=1e-7, sigma_attitude_rad=20 * ARCSEC, gate_chi2=25.0)
    q_true = quat_random(rng)
    f = AttitudeEKF(q_true, **kw)
    t = 0.0
    for frame in range(60):
        g = 3
        t_g = t + 0.1 / g * np.arange(1, g + 1)
        w_g = rng.normal(0.0, 0.2, (g, 3))
        m = int(rng.integers(0, 22))
        t_m = np.sort(t + 0.1 * rng.uniform(0, 1, m))
        edges = np.concatenate([[t], t_g])

        def q_at(tq):
            q = q_true
            for j in range(g):
                dt = min(tq, edges[j + 1]) - edges[j]
                if dt <= 0:
                    break
                q = quat_multiply(q, quat_from_rotvec(w_g[j] * dt))
            return q

        q_m = np.array([quat_multiply(q_at(x), quat_from_rotvec(chol @ rng.standard_normal(3))) for x in t_m])
        q_m = q_m.reshape(m, 4)
        outlier = frame == 40 and m > 0
        if outlier:
            q_m[-1] = quat_multiply(q_m[-1], quat_from_rotvec([0.0, 0.01, 0.0]))
        acc = f.process(w_g, t_g, q_m, t_m, np.broadcast_to(cov, (m, 3, 3)))
        assert acc.sum() == m - outlier and (not outlier or not acc[-1])
        t = t_g[-1]
        q_true = q_at(t)
        assert f.t_s == t
        assert np.linalg.norm(attitude_error(f.q_body_to_icrs, q_true)) < 5 * np.linalg.norm(f.attitude_sigma_rad)
    assert f.n_rejected == 1 and f.n_updates > 300


def test_batch_method_is_gone_with_a_clear_error():
    f = AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=1e-5)
    for validate in (True, False):
        with pytest.raises(ValueError, match="batch.*sequential"):
            f.process(np.zeros((1, 3)), [0.1], np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3, 3)), method="batch",
                      validate=validate)
    with pytest.raises(ValueError, match="method"):
        f.process(np.zeros((1, 3)), [0.1], np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3, 3)), method="fast")
    assert f.t_s == 0.0


def test_gate_rejects_outlier():
    cov = star_tracker_cov()
    rng = np.random.default_rng(5)
    q_true = quat_random(rng)
    f = AttitudeEKF(q_true, arw_rad_sqrt_s=1e-5, sigma_attitude_rad=20 * ARCSEC, gate_chi2=16.27)
    bad = quat_multiply(q_true, quat_from_rotvec([0.0, 1 * DEG, 0.0]))
    assert f.update(bad, cov) is False
    assert np.linalg.norm(attitude_error(f.q_body_to_icrs, q_true)) < 1e-12
    good = quat_multiply(q_true, quat_from_rotvec([5 * ARCSEC, 0, 0]))
    assert f.update(good, cov) is True
    assert f.n_rejected == 1 and f.n_updates == 1


def test_measurement_sign_does_not_matter():
    q = quat_random(np.random.default_rng(6))
    meas = quat_multiply(q, quat_from_rotvec([1e-4, -2e-4, 3e-4]))
    a = AttitudeEKF(q, arw_rad_sqrt_s=1e-5)
    b = AttitudeEKF(q, arw_rad_sqrt_s=1e-5)
    a.update(meas, star_tracker_cov())
    b.update(-meas, star_tracker_cov())
    np.testing.assert_allclose(a.q_body_to_icrs, b.q_body_to_icrs, atol=1e-15)


def test_bad_input():
    f = AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=1e-5)
    cov = star_tracker_cov()
    with pytest.raises(ValueError, match="arw_rad_sqrt_s"):
        AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=0.0)
    with pytest.raises(ValueError, match="q_body_to_icrs"):
        AttitudeEKF([0, 0, 0, 0], arw_rad_sqrt_s=1e-5)
    with pytest.raises(ValueError, match="sigma_attitude_rad"):
        AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=1e-5, sigma_attitude_rad=-1.0)
    with pytest.raises(ValueError, match="omega_gyro"):
        f.propagate([np.nan, 0, 0], 0.1)
    with pytest.raises(ValueError, match="dt"):
        f.propagate([0, 0, 0], -0.1)
    with pytest.raises(ValueError, match="covariance_rad2"):
        f.update([1, 0, 0, 0], -cov)
    with pytest.raises(ValueError, match="covariance_rad2"):
        f.update([1, 0, 0, 0], np.ones((3, 3)))
    with pytest.raises(ValueError, match="covariance_rad2"):
        f.update([1, 0, 0, 0], np.eye(2))
    with pytest.raises(ValueError, match="q_meas_body_to_icrs"):
        f.update([0, 0, 0, 0], cov)
    f.propagate([0, 0, 0], 1.0)
    with pytest.raises(ValueError, match="q_meas_body_to_icrs"):
        f.update([0, 0, 0, 0], cov, t=1.5, omega_gyro=[0.1, 0, 0])  # rejected before propagating
    with pytest.raises(ValueError, match="t="):
        f.update([1, 0, 0, 0], cov, t=0.5)
    with pytest.raises(ValueError, match="t_gyro_s"):
        f.process(np.zeros((2, 3)), [0.5, 1.1], np.zeros((0, 4)), [], np.zeros((0, 3, 3)))
    with pytest.raises(ValueError, match="t_meas_s"):
        f.process(np.zeros(3), 1.1, [[1, 0, 0, 0]], [1.2], cov[None])
    with pytest.raises(ValueError, match="covariance_rad2"):
        f.process(np.zeros(3), 1.1, [[1, 0, 0, 0]], [1.05], cov)
    # nothing was changed by the rejected calls
    assert f.t_s == 1.0 and f.n_updates == 0
    np.testing.assert_array_equal(f.q_body_to_icrs, [1, 0, 0, 0])


def test_from_gyro_spec_derives_the_tuning_with_its_floors():
    """The one constructor for a gyro: ARW and bias σ from the spec, floored so an ideal gyro still leaves the
    filter process noise and an initial bias uncertainty."""
    from startracker.filter import ARW_FLOOR_RAD_SQRT_S, BIAS_SIGMA_FLOOR_RAD_S
    from startracker.imu import gyro_preset

    tact = gyro_preset("tactical", rate_hz=100.0)
    f = AttitudeEKF.from_gyro_spec(tact, [1, 0, 0, 0], sigma_attitude_rad=1e-4)
    assert f.sigma_v == tact.arw_rad_sqrt_s and f.sigma_u == tact.bias_rw_equivalent_rad_s_sqrt_s
    assert np.allclose(f.bias_sigma_rad_s, tact.bias_sigma_rad_s + tact.gm_sigma_rad_s, rtol=1e-15)
    assert np.allclose(f.attitude_sigma_rad, 1e-4, rtol=1e-15)
    ideal = AttitudeEKF.from_gyro_spec(gyro_preset("ideal", rate_hz=100.0), [1, 0, 0, 0])
    assert ideal.sigma_v == ARW_FLOOR_RAD_SQRT_S == 1e-7
    assert np.allclose(ideal.bias_sigma_rad_s, BIAS_SIGMA_FLOOR_RAD_S, rtol=1e-15)
    # an explicit value overrides the derived one; bad floors are refused
    assert AttitudeEKF.from_gyro_spec(tact, [1, 0, 0, 0], arw_rad_sqrt_s=3e-6).sigma_v == 3e-6
    with pytest.raises(ValueError, match="arw_floor_rad_sqrt_s"):
        AttitudeEKF.from_gyro_spec(tact, [1, 0, 0, 0], arw_floor_rad_sqrt_s=0.0)


def test_set_bias_covariance_replaces_the_bias_block_only():
    f = AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=1e-5, sigma_attitude_rad=1e-4, sigma_bias_rad_s=1e-6)
    f.propagate([0.01, 0.0, 0.0], 1.0)  # builds attitude-bias cross-covariance
    before = f.P.copy()
    p_bb = np.diag([1e-8, 2e-8, 3e-8])
    f.set_bias_covariance(p_bb)
    assert np.array_equal(f.P[3:, 3:], p_bb)
    assert np.array_equal(f.P[:3, :], before[:3, :]) and np.array_equal(f.P[3:, :3], before[3:, :3])
    assert np.allclose(f.bias_sigma_rad_s, np.sqrt([1e-8, 2e-8, 3e-8]))
    # the filter uses it: coasting dt at zero rate adds P_bb dt² to the attitude block (Φ12 = -dt I), so two
    # filters differing only in P_bb differ by exactly that
    g = AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=1e-5, sigma_attitude_rad=1e-4, sigma_bias_rad_s=1e-6)
    g.propagate([0.01, 0.0, 0.0], 1.0)
    g_bb = g.P[3:, 3:].copy()
    f.propagate(f.bias_rad_s, 2.0)
    g.propagate(g.bias_rad_s, 2.0)
    assert np.allclose(f.P[:3, :3] - g.P[:3, :3], (p_bb - g_bb) * 4.0, rtol=1e-9, atol=1e-20)
    for bad in (-np.eye(3), np.ones((3, 3)), np.eye(2)):
        with pytest.raises(ValueError, match="covariance_rad2_s2"):
            f.set_bias_covariance(bad)


def _random_spd(rng, n, scales):
    a = rng.standard_normal((n, n)) * scales[:, None]
    return a @ a.T + np.diag(scales**2) * 0.1


@pytest.mark.parametrize("seed", range(20))
def test_kernels_equal_filterpy_predict_and_update(seed):
    """kernels.filter.ekf_predict / ekf_update = filterpy's ExtendedKalmanFilter.predict / update (Joseph form,
    H = [I 0]) on random error states, covariances, transitions and measurements, to 1e-12."""
    from filterpy.kalman import ExtendedKalmanFilter

    from startracker.kernels import filter as kf

    rng = np.random.default_rng(seed)
    scales = np.array([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6]) * rng.uniform(0.1, 10.0, 6)  # rad, rad/s
    x = rng.standard_normal(6) * scales
    P = _random_spd(rng, 6, scales)
    w_hat = rng.normal(0.0, 0.3, 3)
    dt = rng.uniform(0.001, 0.2)
    F, Q = kf.transition(w_hat, dt, 2e-5, 1e-7)
    F = F + 1e-3 * rng.standard_normal((6, 6))  # any transition, not only the model's
    R = _random_spd(rng, 3, np.full(3, 5 * ARCSEC))
    z = rng.standard_normal(3) * 1e-4

    ref = ExtendedKalmanFilter(dim_x=6, dim_z=3)
    ref.x, ref.P, ref.F, ref.Q = x.reshape(6, 1).copy(), P.copy(), F, Q
    ref.predict()
    x1, P1 = kf.ekf_predict(x, P, F, Q)
    np.testing.assert_allclose(x1, ref.x[:, 0], rtol=0, atol=1e-12 * np.abs(ref.x).max())
    np.testing.assert_allclose(P1, ref.P, rtol=0, atol=1e-12 * np.abs(ref.P).max())

    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    ref.update(z.reshape(3, 1), lambda _x: H, lambda xx: xx[:3], R=R)
    x2, P2 = kf.ekf_update(x1, P1, z, R)
    np.testing.assert_allclose(x2, ref.x[:, 0], rtol=0, atol=1e-12 * np.abs(ref.x).max())
    np.testing.assert_allclose(P2, ref.P, rtol=0, atol=1e-12 * np.abs(ref.P).max())


@pytest.mark.parametrize("w_hat", [(0.0, 0.0, 0.0), (1e-6, -2e-6, 5e-7), (0.3, -0.2, 0.5), (2.0, 1.0, -3.0)])
def test_transition_is_the_matrix_exponential(w_hat):
    """Φ = expm(A dt) for the error dynamics δθ' = -[ω̂×] δθ - δb, δb' = 0; at ω̂ = 0, Q is Van Loan's exact
    discretisation of the noise (δθ' gets -n_v, δb' gets n_u)."""
    from scipy.linalg import expm

    from startracker.kernels import filter as kf

    w = np.array(w_hat)
    dt, sv, su = 0.1, 3e-5, 2e-6
    wx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    a = np.zeros((6, 6))
    a[:3, :3], a[:3, 3:] = -wx, -np.eye(3)
    phi, qd = kf.transition(w, dt, sv, su)
    np.testing.assert_allclose(phi, expm(a * dt), rtol=0, atol=1e-14)
    if not w.any():
        g_qc_g = np.diag([sv**2] * 3 + [su**2] * 3)
        vl = expm(np.block([[-a, g_qc_g], [np.zeros((6, 6)), a.T]]) * dt)
        q_ref = vl[6:, 6:].T @ vl[:6, 6:]
        np.testing.assert_allclose(qd, q_ref, rtol=1e-12, atol=1e-30)


def test_attitude_residual_and_advance_are_rotation_vectors():
    from startracker.kernels import filter as kf

    rng = np.random.default_rng(11)
    for _ in range(50):
        q = quat_random(rng)
        r = rng.normal(0.0, 0.8, 3)
        q2 = kf.quat_advance(q, r)
        np.testing.assert_allclose(q2, quat_multiply(q, quat_from_rotvec(r)), atol=1e-15)
        np.testing.assert_allclose(kf.attitude_residual(q, q2), r, atol=1e-12)
        np.testing.assert_allclose(kf.attitude_residual(q, -q2), r, atol=1e-12)  # either sign
        np.testing.assert_allclose(kf.attitude_residual(q, q2), attitude_error(q, q2), atol=1e-12)


_EPISODE = r"""
import hashlib, math, numpy as np
from startracker.filter import AttitudeEKF
from startracker.imu import Gyro, gyro_preset
from startracker.rotations import quat_from_rotvec, quat_multiply
rng = np.random.default_rng(2024)
gyro = Gyro(gyro_preset("industrial", rate_hz=100.0), rng)
f = AttitudeEKF.from_gyro_spec(gyro.spec, [1.0, 0.0, 0.0, 0.0], gate_chi2=30.0)
h = hashlib.sha256()
q = np.array([1.0, 0.0, 0.0, 0.0])
w = np.array([0.02, -0.05, 0.1])
for k in range(50):
    t0 = 0.1 * k
    y = gyro.measure(np.tile(w, (10, 1)), rng)
    tm = np.sort(t0 + 0.1 * rng.uniform(0, 1, 5))
    qm = quat_multiply(quat_multiply(q, quat_from_rotvec(np.outer(tm - t0, w))), quat_from_rotvec(rng.normal(0, 2e-5, (5, 3))))
    f.process(y, t0 + 0.01 * np.arange(1, 11), qm, tm, np.broadcast_to(np.eye(3) * 4e-10, (5, 3, 3)))
    q = quat_multiply(q, quat_from_rotvec(0.1 * w))
    for a in (y, f.q_body_to_icrs, f.bias_rad_s, f.P):
        h.update(np.ascontiguousarray(a).tobytes())
print(h.hexdigest())
"""


def test_same_seed_same_episode_bit_for_bit_on_a_fresh_numba_cache(tmp_path):
    """Gyro samples and filter states of a seeded episode hash the same in two processes, each compiling the kernels
    into its own empty numba cache."""
    import os
    import subprocess
    import sys

    digests = []
    for i in range(2):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / f"cache{i}"))
        out = subprocess.run([sys.executable, "-c", _EPISODE], env=env, capture_output=True, text=True, check=True,
                             cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        digests.append(out.stdout.strip())
    assert len(digests[0]) == 64 and digests[0] == digests[1]
