"""Processing delay in the loop: the processor model's latency, and a filter that fuses late samples exactly."""

import copy

import numpy as np
import pytest

from startracker.filter import AttitudeEKF, DelayedFusion
from startracker.onboard import StarTrackerUnit, UnitConfig
from startracker.processor import ProcessorModel
from startracker.rotations import quat_from_rotvec, quat_integrate, quat_multiply, quat_random

ARCSEC = np.radians(1 / 3600)


def setup(seed=0, g=40):
    """A filter, 40 gyro intervals of 10 ms at ~20 °/s, and one attitude sample inside them."""
    rng = np.random.default_rng(seed)
    q0 = quat_random(rng)
    ekf = AttitudeEKF(q0, arw_rad_sqrt_s=2e-5, rrw_rad_s_sqrt_s=1e-7, sigma_attitude_rad=20 * ARCSEC,
                      sigma_bias_rad_s=1e-4, gate_chi2=30.0)
    tg = 0.01 * np.arange(1, g + 1)
    wg = np.radians([0.0, 20.0, 3.0]) + rng.normal(size=(g, 3)) * 1e-4
    t_meas = 0.1234  # inside the 13th interval
    q_meas = quat_multiply(quat_integrate(q0, np.radians([0.0, 20.0, 3.0]), t_meas),
                           quat_from_rotvec(rng.normal(size=3) * 5 * ARCSEC))
    cov = np.diag([2.0, 2.0, 30.0]) ** 2 * ARCSEC**2
    return ekf, wg, tg, q_meas, t_meas, cov


def test_a_delayed_sample_gives_the_posterior_of_the_sample_on_time():
    """The sample reaches the filter 0.2 s after its exposure (20 gyro intervals later, nothing in between): the
    filter's posterior at the exposure instant, and the estimate now, equal those of the same sample fused on time
    (the plain EKF fusing gyro and sample in time order) to 1e-9."""
    ekf, wg, tg, qm, tm, cov = setup()
    on_time = copy.deepcopy(ekf)
    k = int(np.searchsorted(tg, tm))  # the interval covering the sample
    tg_cut = tg[: k + 1].copy()
    tg_cut[k] = tm
    on_time.process(wg[: k + 1], tg_cut, qm[None], [tm], cov[None])  # up to the exposure instant, then the update
    posterior = (on_time.q_body_to_icrs.copy(), on_time.bias_rad_s.copy(), on_time.P.copy())
    through = copy.deepcopy(ekf)
    through.process(wg, tg, qm[None], [tm], cov[None])  # the whole window in one in-order pass

    late = DelayedFusion(horizon_s=1.0)
    late.start(copy.deepcopy(ekf))
    late.add_gyro(wg[:33], tg[:33])  # the gyro is on time: 0.33 s have passed when the sample arrives
    assert late.fuse(qm[None], np.array([tm]), cov[None]).tolist() == [True]
    late.add_gyro(wg[33:], tg[33:])
    np.testing.assert_allclose(late.ekf.q_body_to_icrs, posterior[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(late.ekf.bias_rad_s, posterior[1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(late.ekf.P, posterior[2], rtol=1e-9, atol=1e-20)
    assert late.ekf.t_s == tm
    q, b, P, omega, t = late.current()
    assert t == tg[-1]
    np.testing.assert_allclose(q, through.q_body_to_icrs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b, through.bias_rad_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(P, through.P, rtol=1e-9, atol=1e-20)
    np.testing.assert_allclose(omega, wg[-1] - through.bias_rad_s, rtol=0, atol=1e-12)


def test_without_the_sample_the_estimate_is_the_gyro_propagation():
    ekf, wg, tg, qm, tm, cov = setup(1)
    ref = copy.deepcopy(ekf)
    ref.process(wg, tg, np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3, 3)))
    late = DelayedFusion(horizon_s=5.0)
    late.start(copy.deepcopy(ekf))
    late.add_gyro(wg, tg)
    q, b, P, _, _ = late.current()
    np.testing.assert_allclose(q, ref.q_body_to_icrs, atol=1e-12)
    np.testing.assert_allclose(P, ref.P, rtol=1e-12, atol=1e-22)
    # a fused sample moves the estimate: the delayed path really updates (not just propagates)
    late.fuse(qm[None], np.array([tm]), cov[None])
    assert np.max(np.sqrt(np.diag(late.current()[2])[:3])) < np.max(np.sqrt(np.diag(P)[:3]))


def test_stale_samples_are_rejected_and_old_gyro_is_folded_in():
    ekf, wg, tg, qm, tm, cov = setup(2)
    late = DelayedFusion(horizon_s=0.1)
    late.start(copy.deepcopy(ekf))
    late.add_gyro(wg, tg)  # 0.4 s of gyro: everything older than 0.3 s is folded into the filter
    assert late.ekf.t_s == pytest.approx(0.3)
    assert late.fuse(qm[None], np.array([tm]), cov[None]).tolist() == [False] and late.n_stale == 1
    ref = copy.deepcopy(ekf)
    ref.process(wg, tg, np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3, 3)))
    np.testing.assert_allclose(late.current()[0], ref.q_body_to_icrs, atol=1e-12)


def test_processor_model_budget():
    p = ProcessorModel()
    lat = p.frame_latency_ms(1000, 21, identified=False)
    assert lat == pytest.approx(5.0 + 1.0 + 0.005 * 1000 + 0.005 * 1000 + 0.1 * 21)
    assert p.frame_latency_ms(40, 1, identified=True) == pytest.approx(5.0 + 1.0 + 0.2 + 0.1 + 30.0)
    assert ProcessorModel.instantaneous().frame_latency_ms(500, 21, True) == 0.0
    assert ProcessorModel.fixed(20.0).frame_latency_ms(500, 21, False) == 20.0
    with pytest.raises(ValueError, match="readout_ms"):
        ProcessorModel(readout_ms=-1.0)
    with pytest.raises(TypeError, match="processor"):
        UnitConfig(processor=20.0)


def constant_rate_history(seconds=2.0, rate_hz=100.0):
    t = np.arange(int(seconds * rate_hz) + 1) / rate_hz
    return t, quat_integrate(quat_random(np.random.default_rng(9)), np.radians([0.5, -0.3, 0.2]), t)


@pytest.mark.parametrize("latency_ms", [0.0, 50.0, 150.0])
def test_samples_reach_the_filter_their_latency_after_the_frame(latency_ms):
    """In track, a frame's samples are fused once the span covering frame end + latency has been observed, not
    before (one frame per span: ceil(latency / frame period) spans later); the reported latency is the model's."""
    t, q = constant_rate_history()
    unit = StarTrackerUnit(UnitConfig(processor=ProcessorModel.fixed(latency_ms)))
    rng = np.random.default_rng(0)
    unit.reset(rng)
    frame = int(round(unit.config.frame_period_s * unit.config.gyro_rate_hz))
    produced, fused = [], []
    for f in range(len(t) // frame):
        sl = slice(f * frame, (f + 1) * frame + 1)
        n_before = None if unit.ekf is None else unit.ekf.n_updates
        unit.observe(t[sl], q[sl], rng)
        if unit.last_stats["n_attitude_samples"]:
            assert unit.last_stats["matching_latency_ms"] == latency_ms
        if n_before is not None and unit.ekf is not None:
            produced.append(unit.last_stats["n_attitude_samples"])
            fused.append(unit.ekf.n_updates - n_before)
    delay = int(np.ceil(latency_ms / 1e3 / unit.config.frame_period_s - 1e-9))
    assert sum(produced) >= 10 and produced[-1] > 0
    # what the filter took in each span is what the tracker produced `delay` spans earlier (no gate rejections)
    assert fused[delay:] == produced[: len(produced) - delay]


def test_env_takes_a_processor_and_reports_its_latency():
    """processor= as a model, a dict of its fields or a fixed latency in ms; info["matching_latency_ms"] is the
    model's figure for the frame (the same on every run); anything else is refused naming the argument."""
    import gymnasium as gym

    import envs  # noqa: F401

    for proc, expected in ((ProcessorModel.fixed(12.5), 12.5), ({"readout_ms": 12.5, "identify_ms": 0.0,
                           "overhead_ms": 0.0, "centroid_ms_per_detection": 0.0, "match_ms_per_detection": 0.0,
                           "solve_ms_per_instant": 0.0}, 12.5), (7.0, 7.0)):
        env = gym.make("startracker/AttitudeHold-v0", processor=proc).unwrapped
        env.reset(seed=0)
        info = env.step(np.zeros(env.action_space.shape, np.float32))[4]
        assert info["matching_latency_ms"] == expected
        env.close()
    with pytest.raises(TypeError, match="processor"):
        gym.make("startracker/AttitudeHold-v0", processor="fast")


@pytest.mark.parametrize("seed", range(3))
def test_fuse_timed_is_the_timing_test_then_fuse(seed):
    """The delivery's timing test and its fusion in one call equal, bit for bit, the test on prior_innovations
    (timing_statistic along the rate) followed by fuse: the statistic, the loose flag, the accepted samples, the
    filter's state, its innovations and the estimate now; when the statistic is above the threshold nothing is
    fused and the filter is left as it was. Both with the buffer reaching past the samples (one compiled call) and
    with the samples at the end of the buffer."""
    from startracker.kernels.filter import timing_statistic

    ekf, wg, tg, _, _, cov = setup(seed)
    rng = np.random.default_rng(seed)
    t_meas = np.array([0.1234, 0.1534, 0.1834, 0.2134])
    q_meas = np.array([quat_multiply(quat_integrate(ekf.q_body_to_icrs, np.radians([0.0, 20.0, 3.0]), t),
                                     quat_from_rotvec(rng.normal(size=3) * 5 * ARCSEC)) for t in t_meas])
    covs = np.repeat(cov[None], len(t_meas), axis=0)
    u = np.radians([0.0, 20.0, 3.0]) / np.linalg.norm(np.radians([0.0, 20.0, 3.0]))
    for n_gyro in (33, 22):
        a, b = DelayedFusion(horizon_s=1.0), DelayedFusion(horizon_s=1.0)
        a.start(copy.deepcopy(ekf))
        b.start(copy.deepcopy(ekf))
        a.add_gyro(wg[:n_gyro], tg[:n_gyro])
        b.add_gyro(wg[:n_gyro], tg[:n_gyro])
        if n_gyro == 22:  # the last sample at the buffer's very end
            t_meas[-1] = tg[21]
        z, s = b.prior_innovations(q_meas, t_meas, covs)
        stat_ref, loose_ref = timing_statistic(u, z, s, covs, 4.0)
        for threshold in (np.inf, stat_ref * 0.5):
            a2, b2 = copy.deepcopy(a), copy.deepcopy(b)
            stat, loose, acc = a2.fuse_timed(q_meas, t_meas, covs, u, threshold, 4.0)
            assert stat == stat_ref and loose == bool(loose_ref)
            if threshold < stat_ref:
                assert acc is None
                assert np.array_equal(a2.ekf.P, ekf.P) and np.array_equal(a2.ekf.q_body_to_icrs, ekf.q_body_to_icrs)
                continue
            ref = b2.fuse(q_meas, t_meas, covs)
            assert np.array_equal(acc, ref) and acc.any()
            for x, y in zip(a2.current(), b2.current()):
                assert np.array_equal(x, y)
            assert np.array_equal(a2.ekf.P, b2.ekf.P) and a2.ekf.t_s == b2.ekf.t_s
            assert np.array_equal(a2.last_nis, b2.last_nis)
            assert np.array_equal(a2.last_innovation_rad, b2.last_innovation_rad)
            assert np.array_equal(a2.last_innovation_cov_rad2, b2.last_innovation_cov_rad2)


@pytest.mark.parametrize("case", ["one_at_end", "one_inside", "several"])
def test_fuse_frame_timed_kernel_is_the_three_calls(case):
    """kernels.filter.fuse_frame_timed equals, bit for bit, fuse_frame on copies with a gate below every NIS,
    timing_statistic, then fuse_frame: every output and in-place array (Φ and Q of the last propagation and the
    propagation count too), with one sample at the last gyro instant (no propagation after it), one inside the
    intervals and several."""
    from startracker.kernels import filter as kf

    ekf, wg, tg, q_meas, t_meas, cov = setup(1, g=11)
    t_meas = {"one_at_end": [tg[-1]], "one_inside": [0.0734], "several": [0.0234, 0.0534, 0.0534, 0.11]}[case]
    rng = np.random.default_rng(3)
    tm = np.array(t_meas)
    qm = np.array([quat_multiply(quat_integrate(ekf.q_body_to_icrs, np.radians([0.0, 20.0, 3.0]), t),
                                 quat_from_rotvec(rng.normal(size=3) * 5 * ARCSEC)) for t in tm])
    rs = np.repeat(cov[None], len(tm), axis=0)
    rn = np.zeros((len(tg), 3))
    rn[4] = 1e-9  # one saturated interval
    u = np.radians([0.0, 20.0, 3.0]) / np.linalg.norm(np.radians([0.0, 20.0, 3.0]))
    m = len(tm)

    def state():
        return [np.array(ekf.q_body_to_icrs, float), np.array(ekf.bias_rad_s, float), np.array(ekf.P, float),
                np.zeros(m, bool), np.full((6, 6), 7.0), np.full((6, 6), 8.0), np.full(3, 9.0), np.zeros(m),
                np.zeros((m, 3)), np.zeros((m, 3, 3))]

    def call(st):
        q, b, P, acc, phi, qd, zl, nis, zo, so = st
        return q, b, P, float(ekf.t_s), wg, tg, qm, tm, rs, ekf.sigma_v, ekf.sigma_u, 30.0, acc, phi, qd, zl, rn, nis, zo, so

    ref = state()
    q, b, P = ref[0].copy(), ref[1].copy(), ref[2].copy()
    z, s = np.empty((m, 3)), np.empty((m, 3, 3))
    kf.fuse_frame(q, b, P, float(ekf.t_s), wg, tg, qm, tm, rs, ekf.sigma_v, ekf.sigma_u, -1.0, np.empty(m, bool),
                  np.empty((6, 6)), np.empty((6, 6)), np.empty(3), rn, np.empty(m), z, s)
    stat_ref, loose_ref = kf.timing_statistic(u, z, s, rs, 4.0)
    t_ref, n_acc_ref, n_prop_ref = kf.fuse_frame(*call(ref))
    got = state()
    out = kf.fuse_frame_timed(*call(got), u, np.inf, 4.0)
    assert out == (stat_ref, loose_ref, True, t_ref, n_acc_ref, n_prop_ref)
    for x, y in zip(got, ref):
        assert np.array_equal(x, y)
    held = state()  # the test fails: nothing changes
    out = kf.fuse_frame_timed(*call(held), u, stat_ref * 0.5, 4.0)
    assert out == (stat_ref, loose_ref, False, float(ekf.t_s), 0, 0)
    for x, y in zip(held, state()):
        assert np.array_equal(x, y)


def test_propagate_buffer_kernel_is_the_filters_propagation():
    """kernels.filter.propagate_buffer: the filter propagated through a buffer equals filterpy's predict interval by
    interval (AttitudeEKF.propagate) to 1e-12, and fuse_frame without samples on copies bit for bit (the estimate now
    of DelayedFusion.current before the kernel); its inputs are left unchanged."""
    from startracker.kernels import filter as kf

    ekf, wg, tg, _, _, _ = setup(2, g=12)
    rn = np.zeros((len(tg), 3))
    q0, b0, P0 = ekf.q_body_to_icrs.copy(), ekf.bias_rad_s.copy(), ekf.P.copy()
    q, b, P, omega, t = kf.propagate_buffer(ekf.q_body_to_icrs, ekf.bias_rad_s, ekf.P, float(ekf.t_s), wg, tg, rn,
                                            ekf.sigma_v, ekf.sigma_u)
    assert np.array_equal(ekf.q_body_to_icrs, q0) and np.array_equal(ekf.bias_rad_s, b0) and np.array_equal(ekf.P, P0)
    q_ref, b_ref, P_ref = q0.copy(), b0.copy(), P0.copy()
    kf.fuse_frame(q_ref, b_ref, P_ref, float(ekf.t_s), wg, tg, np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3, 3)),
                  ekf.sigma_v, ekf.sigma_u, np.inf, np.zeros(0, bool), np.empty((6, 6)), np.empty((6, 6)), np.empty(3),
                  rn, np.empty(0), np.empty((0, 3)), np.empty((0, 3, 3)))
    assert np.array_equal(q, q_ref) and np.array_equal(b, b_ref) and np.array_equal(P, P_ref)
    assert np.array_equal(omega, wg[-1] - b_ref) and t == tg[-1]
    slow = copy.deepcopy(ekf)
    t_prev = slow.t_s
    for w, t_end in zip(wg, tg):
        slow.propagate(w, t_end - t_prev)
        t_prev = t_end
    np.testing.assert_allclose(q, slow.q_body_to_icrs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(P, slow.P, rtol=1e-12, atol=1e-24)


@pytest.mark.parametrize("t_last", [0.0534, 0.06, 0.2])
def test_fuse_buffer_timed_kernel_is_the_cut_buffer_and_fuse_frame_timed(t_last):
    """kernels.filter.fuse_buffer_timed equals, bit for bit, fuse_frame_timed on copies of the filter over the buffer
    cut at the last sample (np.searchsorted's interval, its end moved to the sample), with the covering interval and
    the first interval to keep; beyond the buffer it reports that none reaches the sample."""
    from startracker.kernels import filter as kf

    ekf, wg, tg, _, _, cov = setup(4, g=11)
    rng = np.random.default_rng(5)
    tm = np.array([0.0234, 0.0434, t_last])
    qm = np.array([quat_multiply(quat_integrate(ekf.q_body_to_icrs, np.radians([0.0, 20.0, 3.0]), t),
                                 quat_from_rotvec(rng.normal(size=3) * 5 * ARCSEC)) for t in tm])
    rs = np.repeat(cov[None], len(tm), axis=0)
    rn = np.zeros((len(tg), 3))
    rn[2] = 1e-9
    u = np.radians([0.0, 20.0, 3.0]) / np.linalg.norm(np.radians([0.0, 20.0, 3.0]))
    args = (ekf.q_body_to_icrs, ekf.bias_rad_s, ekf.P, float(ekf.t_s), wg, tg, rn, qm, tm, rs, ekf.sigma_v,
            ekf.sigma_u, 30.0, u, np.inf, 4.0)
    out = kf.fuse_buffer_timed(*args)
    j = int(np.searchsorted(tg, t_last))
    if j == len(tg):
        assert out[0] is False and out[1] == j
        return
    assert out[:3] == (True, j, j if tg[j] > t_last else j + 1)
    m = len(tm)
    ref = [ekf.q_body_to_icrs.copy(), ekf.bias_rad_s.copy(), ekf.P.copy(), np.zeros(m, bool), np.empty((6, 6)),
           np.empty((6, 6)), np.empty(3), np.zeros(m), np.zeros((m, 3)), np.zeros((m, 3, 3))]
    tg_cut = tg[:j + 1].copy()
    tg_cut[j] = t_last
    q, b, P, acc, phi, qd, zl, nis, zs, ss = ref
    scalars = kf.fuse_frame_timed(q, b, P, float(ekf.t_s), wg[:j + 1], tg_cut, qm, tm, rs, ekf.sigma_v, ekf.sigma_u,
                                  30.0, acc, phi, qd, zl, rn[:j + 1], nis, zs, ss, u, np.inf, 4.0)
    assert out[3:9] == scalars and scalars[2]
    qbz, mats = out[9], out[10]
    got = [qbz[:4], qbz[4:7], mats[0], out[11], mats[1], mats[2], qbz[7:10], qbz[10:]] + list(out[12:])
    assert len(out) == 14 and qbz.shape == (10 + m,)
    for x, y in zip(got, ref):
        assert np.array_equal(x, y)


def test_reported_attitude_kernel_is_the_widened_block_and_its_nis():
    """kernels.filter.reported_attitude: the attitude block of P with its diagonal widened (or not), the NIS of the
    estimate's error (scipy's rotation vector of q̂* ⊗ q_true) on it, and its largest variance."""
    from scipy.spatial.transform import Rotation

    from startracker.kernels import filter as kf

    rng = np.random.default_rng(6)
    a = rng.normal(size=(6, 6)) * 1e-5
    P = a @ a.T + np.eye(6) * 1e-12
    q_est = quat_random(rng)
    q_true = quat_multiply(q_est, quat_from_rotvec(rng.normal(size=3) * 2e-5))
    for widen, extra in ((False, 0.0), (True, 3e-11)):
        cov, nis, max_var = kf.reported_attitude(q_true, q_est, P, widen, extra)
        cov_ref = P[:3, :3] + (np.eye(3) * extra if widen else 0.0)
        np.testing.assert_allclose(cov, cov_ref, rtol=1e-15, atol=0)
        d = (Rotation.from_quat(q_est[[1, 2, 3, 0]]).inv() * Rotation.from_quat(q_true[[1, 2, 3, 0]])).as_rotvec()
        np.testing.assert_allclose(nis, d @ np.linalg.solve(cov_ref, d), rtol=1e-9)
        assert max_var == max(cov[0, 0], cov[1, 1], cov[2, 2])
