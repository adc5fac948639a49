"""The StarTracker state machine on simulated slews: acquisition, N attitudes per frame, loss and recovery,
the 20 °/s closed loop of paper 000 (≥ 200 Hz with N = 21), and no confident wrong attitude from false objects."""

import dataclasses

import numpy as np
import pytest

from startracker.catalog import load_catalog, select_navigation_stars
from startracker.optics import camera_preset
from startracker.rotations import (
    quat_conjugate,
    quat_from_rotvec,
    quat_integrate,
    quat_multiply,
    quat_random,
    quat_to_rotvec,
)
from startracker.sensor import AttitudeSample, FrameResult, MotionState, StarTracker
from startracker.simulation import simulate_tracking_frame

FRAME_S = 0.1
SIGMA_PX = 0.3


class Slew:
    """Truth: q(t) = q0 ⊗ exp(ω0 t + α t²/2) about a fixed body axis (exact for a fixed axis)."""

    def __init__(self, rng, rate_deg_s, alpha_rad_s2=0.0, axis=(0.6, 0.8, 0.0)):
        self.q0 = quat_random(rng)
        ax = np.asarray(axis, float) / np.linalg.norm(axis)
        self.w0 = np.radians(rate_deg_s) * ax
        self.alpha = alpha_rad_s2 * ax

    def q(self, t):
        return quat_integrate(self.q0, self.w0, t, self.alpha)

    def rate(self, t):
        return self.w0 + self.alpha * t


def frame(cam, nav, slew, k, n, rng, n_false=10, p_detect=0.95, frame_s=FRAME_S, stamp="end"):
    """Frame k (from k·T to (k+1)·T) with n exposures spread over it, mid-exposure stamps; the frame time
    (and gyro reading) at its end or its start."""
    times = k * frame_s + (np.arange(n) + 0.5) * frame_s / n
    fr = simulate_tracking_frame(cam, nav, slew.q0, slew.w0, times, rng, alpha_body=slew.alpha, sigma_px=SIGMA_PX,
                         n_false=n_false, p_detect=p_detect)
    return fr, times, (k + 1) * frame_s if stamp == "end" else k * frame_s


def nees(sample: AttitudeSample, q_true):
    e = quat_to_rotvec(quat_multiply(quat_conjugate(sample.q_body_to_icrs), q_true))
    return float(e @ np.linalg.solve(sample.covariance_rad2, e))


def run(st, cam, nav, slew, frames, rng, gyro=False, overrides=None, stamp="end"):
    """Drive the tracker; ``overrides[k]`` replaces frame k's detections (xy, intensity)."""
    log = []
    for k in frames:
        n = st.requested_n_exposures
        fr, times, t_frame = frame(cam, nav, slew, k, n, rng, stamp=stamp)
        xy, inten = fr.xy, fr.intensity
        if overrides and k in overrides:
            xy, inten = overrides[k](fr)
        w = slew.rate(t_frame) + rng.normal(0, 1e-4, 3) if gyro else None
        res = st.process_frame(xy, inten, times, t_frame, omega_body=w)
        log.append((k, n, times, res))
    return log


def stray_light(rng):
    def make(fr):
        xy = rng.uniform(0, 2048, (400, 2))
        return xy, rng.uniform(1.0, 50.0, 400)

    return make


def test_state_machine_lost_acquire_track_forced_loss_lost_track(cam, nav):
    rng = np.random.default_rng(21)
    slew = Slew(rng, 20.0)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    assert st.mode == "lost" and st.requested_n_exposures == 1
    log = run(st, cam, nav, slew, range(8), rng, overrides={5: stray_light(rng)})
    modes = [r.mode for *_, r in log]
    assert modes == ["acquire", "track", "track", "track", "track", "lost", "track", "track"]
    # No sample before confirmation; none from the stray-light frame.
    assert log[0][3].samples == [] and log[5][3].samples == []
    assert "lock lost" in log[5][3].status
    assert "recovered" in log[6][3].status
    # Single exposures while lost / acquiring / estimating the acceleration, then the plan's N, which is
    # capped by the prediction uncertainty (one-exposure spacing >= 8 σ_pred) before it reaches 21.
    ns = [n for _, n, _, _ in log]
    assert ns[:3] == [1, 1, 1] and 10 <= ns[3] <= 21 and ns[4] == 21 and ns[6] == 1 and ns[7] > 1
    assert len(log[4][3].samples) == 21
    for k, n, times, res in log:
        for s in res.samples:
            assert nees(s, slew.q(s.t_s)) < 25.0  # χ²(3): 99.998 %
    # After a long outage (2.2 s, beyond coast_max_s) the multi-exposure frame cannot be predicted: lock
    # lost, then a single exposure is identified again: lost -> acquire -> track.
    log2 = run(st, cam, nav, slew, [30, 31, 32, 33], rng)
    assert [r.mode for *_, r in log2] == ["lost", "acquire", "track", "track"]
    assert [n for _, n, _, _ in log2][1:3] == [1, 1] and log2[0][1] > 1 and log2[1][3].samples == []
    st.reset()
    assert st.mode == "lost" and st.state is None and st.requested_n_exposures == 1


@pytest.mark.parametrize("stamp", ["end", "start"])
def test_closed_loop_20deg_per_s_10hz_never_drops_lock_and_reaches_210hz(cam, nav, stamp):
    rng = np.random.default_rng(22)
    slew = Slew(rng, 20.0)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX, matcher="dkvlut")
    log = run(st, cam, nav, slew, range(40), rng, stamp=stamp)
    modes = [r.mode for *_, r in log]
    assert modes[0] == "acquire" and all(m == "track" for m in modes[1:])
    full = [(n, times, r) for _, n, times, r in log if n == 21]
    assert len(full) >= 35
    all_nees = []
    n_samples = 0
    for n, times, r in full:
        assert isinstance(r, FrameResult)
        # the instants' smoothness test drops a right instant with probability 1e-3 (instant_gate 16)
        assert len(r.samples) >= 20 and r.update_rate_hz == pytest.approx(10.0 * len(r.samples))
        assert set(s.t_s for s in r.samples) <= set(times.tolist())  # each sample carries its exposure instant
        assert r.n_matched > 0.8 * r.n_predicted and r.matching_latency_ms > 0.0 and r.n_exposures == 21
        all_nees += [nees(s, slew.q(s.t_s)) for s in r.samples]
        n_samples += len(r.samples)
    assert n_samples >= 0.99 * 21 * len(full)
    all_nees = np.array(all_nees)
    # Covariances consistent with the truth: χ²(3) has mean 3.
    assert 2.4 < all_nees.mean() < 3.6
    assert np.mean(all_nees < 7.81) > 0.9


def test_gyro_aided_acquisition_and_accelerating_slew(cam, nav):
    rng = np.random.default_rng(23)
    slew = Slew(rng, 5.0, alpha_rad_s2=0.1)  # 5 °/s -> 22 °/s over 3 s
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    log = run(st, cam, nav, slew, range(30), rng, gyro=True)
    modes = [r.mode for *_, r in log]
    assert modes[0] == "acquire" and all(m == "track" for m in modes[1:])
    assert "confirmed by tracking" in log[1][3].status
    ns = [n for _, n, _, _ in log]
    assert ns[3] < ns[15] < ns[-1] == 21  # the plan follows the rate
    vals = [nees(s, slew.q(s.t_s)) for *_, r in log for s in r.samples]
    assert len(vals) > 300 and np.mean(vals) < 3.6 and max(vals) < 30.0


def test_frames_of_false_objects_never_give_an_attitude(cam, nav):
    rng = np.random.default_rng(24)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    for k in range(12):
        n = int(rng.integers(20, 400))
        res = st.process_frame(rng.uniform(0, 2048, (n, 2)), rng.uniform(1, 100, n), [k * 0.1 + 0.05], k * 0.1 + 0.1)
        assert res.samples == [] and res.mode in ("lost", "acquire")
    # Empty frames as well.
    res = st.process_frame(np.empty((0, 2)), np.empty(0), [2.05], 2.1)
    assert res.mode == "lost" and res.samples == [] and res.n_detections == 0


def test_heavy_false_objects_while_tracking_stay_consistent(cam, nav):
    rng = np.random.default_rng(25)
    slew = Slew(rng, 15.0)

    def clutter(fr):
        xy = np.concatenate([fr.xy, rng.uniform(0, 2048, (3000, 2))])
        return xy, np.concatenate([fr.intensity, rng.uniform(0.1, 5.0, 3000)])

    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    log = run(st, cam, nav, slew, range(10), rng, overrides={k: clutter for k in range(4, 10)})
    assert all(r.mode == "track" for *_, r in log[1:])
    vals = [nees(s, slew.q(s.t_s)) for *_, r in log[4:] for s in r.samples]
    assert len(vals) > 60 and np.mean(vals) < 4.0 and max(vals) < 30.0


def test_state_off_by_one_exposure_is_refused(cam, nav):
    # A motion state lagging by exactly one exposure interval agrees with its own prediction (every spot
    # of instant n-1 taken for instant n): the empty first instant gives it away, never a wrong attitude.
    rng = np.random.default_rng(26)
    slew = Slew(rng, 20.0)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    log = run(st, cam, nav, slew, range(5), rng)
    assert log[-1][3].mode == "track" and st.requested_n_exposures == 21
    s = st.state
    lag = FRAME_S / 21
    st._state = MotionState(
        s.t_s, slew.q(s.t_s - lag), s.cov_theta_rad2, s.omega_body, s.cov_omega, s.alpha_body, s.cov_alpha,
        s.rate_meas, s.alpha_known,
    )
    fr, times, t_frame = frame(cam, nav, slew, 5, 21, rng)
    res = st.process_frame(fr.xy, fr.intensity, times, t_frame)
    assert res.mode == "lost" and res.samples == []
    assert "one exposure off" in res.status


def test_recovery_from_an_attitude_prior(cam, nav):
    rng = np.random.default_rng(27)
    slew = Slew(rng, 10.0)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX, prior_sigma_rad=np.radians(20 / 3600))
    fr, times, t_frame = frame(cam, nav, slew, 3, 11, rng)
    q_prior = quat_multiply(slew.q(t_frame), quat_from_rotvec(np.radians([10, -15, 20]) / 3600))
    res = st.process_frame(fr.xy, fr.intensity, times, t_frame, omega_body=slew.rate(t_frame), q_body_prior=q_prior)
    assert res.mode == "track" and len(res.samples) == 11 and "prior" in res.status
    assert max(nees(s, slew.q(s.t_s)) for s in res.samples) < 25.0


@pytest.mark.parametrize("rate_deg_s,expected_n", [(0.2, 1), (5.0, 6), (12.0, 13), (20.0, 21), (28.0, 21)])
def test_exposure_plan_follows_the_rate(cam, nav, rate_deg_s, expected_n):
    rng = np.random.default_rng(28)
    slew = Slew(rng, rate_deg_s)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    run(st, cam, nav, slew, range(6), rng)
    assert st.mode == "track" and st.requested_n_exposures == expected_n


@pytest.mark.parametrize("matcher", ["brute", "kdtree"])
def test_other_matchers_track_the_same(cam, nav, matcher):
    rng_a, rng_b = np.random.default_rng(29), np.random.default_rng(29)
    slew = Slew(np.random.default_rng(30), 12.0)
    a = run(StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX), cam, nav, slew, range(5), rng_a)
    b = run(StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX, matcher=matcher), cam, nav, slew, range(5), rng_b)
    for (_, _, _, ra), (_, _, _, rb) in zip(a, b):
        assert ra.mode == rb.mode and ra.n_matched == rb.n_matched
        for sa, sb in zip(ra.samples, rb.samples):
            np.testing.assert_allclose(sa.q_body_to_icrs, sb.q_body_to_icrs, atol=1e-12)


def test_bad_input(cam, nav):
    st = StarTracker(cam, nav)
    with pytest.raises(ValueError, match="xy"):
        st.process_frame([[np.nan, 1.0]], None, [0.0], 0.1)
    with pytest.raises(ValueError, match="intensity"):
        st.process_frame([[1.0, 1.0]], [1.0, 2.0], [0.0], 0.1)
    with pytest.raises(ValueError, match="exposure_times"):
        st.process_frame([[1.0, 1.0]], None, [0.1, 0.05], 0.1)
    with pytest.raises(ValueError, match="omega_body"):
        st.process_frame([[1.0, 1.0]], None, [0.0], 0.1, omega_body=[1.0, 2.0])
    with pytest.raises(ValueError, match="matcher"):
        StarTracker(cam, nav, matcher="grid")
    with pytest.raises(ValueError, match="identify_method"):
        StarTracker(cam, nav, identify_method="magic")
    with pytest.raises(ValueError, match="centroid_sigma_px"):
        StarTracker(cam, nav, centroid_sigma_px=-1.0)
    with pytest.raises(TypeError, match="camera"):
        StarTracker("paper000", nav)


def test_multi_exposure_frame_without_a_usable_rate_is_refused(cam, nav):
    # A prior attitude without a gyro says nothing about the rate: the N spots of a star cannot be told
    # apart, so the frame must not be tracked (it would pile every spot onto one instant).
    rng = np.random.default_rng(31)
    slew = Slew(rng, 15.0)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    fr, times, t_frame = frame(cam, nav, slew, 2, 16, rng)
    res = st.process_frame(fr.xy, fr.intensity, times, t_frame, q_body_prior=slew.q(t_frame))
    assert res.mode == "lost" and res.samples == [] and "too uncertain" in res.status


def test_innovation_chi2_matches_a_scipy_and_linalg_reference():
    """The compiled innovation test: mean of δᵀ S⁻¹ δ with δ the rotation from predicted to solved attitude and
    S = P_θ + P_ω τ² + P_α τ⁴/4 + C, against scipy's rotation vectors and numpy's solver."""
    from scipy.spatial.transform import Rotation

    from startracker.kernels.sensor import innovation_chi2_mean

    rng = np.random.default_rng(3)

    def spd(scale):
        a = rng.normal(size=(3, 3)) * scale
        return a @ a.T + scale**2 * np.eye(3)

    n = 7
    q_pred = quat_random(rng, n)
    delta_true = rng.normal(size=(n, 3)) * 1e-4
    delta_true[0] *= 1e4  # one large rotation (~1 rad): the series branch and the sin branch
    q_sol = quat_multiply(q_pred, quat_from_rotvec(delta_true)) * rng.choice([-1.0, 1.0], size=(n, 1))
    cov_sol = np.array([spd(1e-5) for _ in range(n)])
    tau = rng.uniform(-0.05, 0.1, n)
    p_th, p_w, p_a = spd(1e-5), spd(1e-4), spd(1e-2)
    got = innovation_chi2_mean(q_pred, q_sol, cov_sol, tau, p_th, p_w, p_a)

    # reference: scipy rotations (scalar-last), the shorter rotation, numpy's LU solve
    r_pred = Rotation.from_quat(q_pred[:, [1, 2, 3, 0]])
    r_sol = Rotation.from_quat(q_sol[:, [1, 2, 3, 0]])
    delta = (r_pred.inv() * r_sol).as_rotvec()
    np.testing.assert_allclose(delta, delta_true, rtol=1e-9, atol=1e-12)
    s = p_th + p_w * tau[:, None, None] ** 2 + p_a * tau[:, None, None] ** 4 / 4 + cov_sol
    want = np.mean([d @ np.linalg.solve(si, d) for d, si in zip(delta, s)])
    assert got == pytest.approx(want, rel=1e-10)
    assert innovation_chi2_mean(q_pred[:0], q_sol[:0], cov_sol[:0], tau[:0], p_th, p_w, p_a) == 0.0


def test_samples_do_not_share_memory_with_the_tracker_state(cam, nav):
    """A caller editing a returned sample in place must not move the tracker's motion state."""
    rng = np.random.default_rng(8)
    slew = Slew(rng, 5.0)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    log = run(st, cam, nav, slew, range(4), rng)
    res = log[-1][3]
    assert res.mode == "track" and res.samples
    q_state = st.state.q_body_to_icrs.copy()
    cov_state = st.state.cov_theta_rad2.copy()
    last = res.samples[-1]
    assert last.t_s == st.state.t_s  # the state is the last solved instant ...
    np.testing.assert_array_equal(last.q_body_to_icrs, q_state)
    last.q_body_to_icrs[:] = 0.0  # ... but not the same memory
    last.covariance_rad2[:] = 0.0
    np.testing.assert_array_equal(st.state.q_body_to_icrs, q_state)
    np.testing.assert_array_equal(st.state.cov_theta_rad2, cov_state)
    if len(res.samples) > 1:
        assert np.all(res.samples[-2].q_body_to_icrs != 0.0)


def test_residuals_beyond_the_centroid_model_widen_the_sample_covariance(cam, nav):
    """Centroids twice as noisy as the tracker's model (0.6 px against 0.3 px, e.g. streaks in stray light): each
    instant's covariance grows by its a-posteriori variance factor, so the samples' NEES against the truth stays
    near its 3 dof; without the scaling the same frames' samples claim half the error they have (NEES ~4×)."""
    def run_noisy(scale):
        rng = np.random.default_rng(31)
        slew = Slew(rng, 10.0)
        st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX, scale_by_residuals=scale)
        vals = []
        for k in range(14):
            n = st.requested_n_exposures
            times = k * FRAME_S + (np.arange(n) + 0.5) * FRAME_S / n
            fr = simulate_tracking_frame(cam, nav, slew.q0, slew.w0, times, rng, sigma_px=2 * SIGMA_PX, n_false=5)
            res = st.process_frame(fr.xy, fr.intensity, times, (k + 1) * FRAME_S, omega_body=slew.rate(0.0))
            vals += [nees(s, slew.q(s.t_s)) for s in res.samples] if k >= 2 else []
        return np.array(vals)

    scaled, raw = run_noisy(True), run_noisy(False)
    assert len(scaled) > 30 and len(raw) > 30
    assert np.mean(scaled) < 4.5
    assert np.mean(raw) > 2.5 * np.mean(scaled)


def _field_names_and_values_hold(obj):
    """``obj`` holds exactly its dataclass's fields, in declaration order, as its own ``__init__`` would set them."""
    names = [f.name for f in dataclasses.fields(obj)]
    assert list(vars(obj)) == names
    rebuilt = dataclasses.replace(obj)  # the generated __init__ with every field read back from obj
    for name in names:
        a, b = getattr(obj, name), getattr(rebuilt, name)
        assert a is b or a == b, name


def test_frame_results_samples_and_states_are_complete_dataclasses(cam, nav):
    """The per-frame results are built with their fields set at once: every field is there, in order."""
    rng = np.random.default_rng(8)
    slew = Slew(rng, 5.0)
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX)
    res = run(st, cam, nav, slew, range(5), rng)[-1][3]
    assert res.mode == "track" and res.samples
    _field_names_and_values_hold(res)
    _field_names_and_values_hold(res.attitude_samples)
    for s in res.samples:
        assert isinstance(s, AttitudeSample)
        _field_names_and_values_hold(s)
    assert isinstance(st.state, MotionState)
    _field_names_and_values_hold(st.state)
