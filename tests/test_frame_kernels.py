"""The per-frame folds of the sensor path: one compiled call where the stages were called one by one.

``kernels.scene.scene_frame`` and ``kernels.track.track_frame_from_state`` must give the stepwise stages' results bit
for bit (the same episode for the same seed); ``kernels.sensor.smooth_instants`` and ``accept_instants`` the
smoothness test's verdicts and the a-posteriori covariance scaling, checked against fits and factors computed here.
"""

import numpy as np
import pytest

from startracker.kernels import sensor as sk
from startracker.kernels import track as tk
from startracker.kernels.rotations import normalize_rows
from startracker.rotations import quat_from_rotvec, quat_integrate, quat_multiply, quat_random
from startracker.scene import BrightBody, ExposurePlan, compute_scene
from startracker.simulation import simulate_tracking_frame
from startracker.track import camera_projection_model


def test_scene_frame_is_the_stepwise_scene(cam, nav):
    """The compiled scene (validate=False, sampled history) against the checked stepwise path (validate=True)."""
    rng = np.random.default_rng(7)
    plan = ExposurePlan(n_exposures=12, exposure_s=1e-3, spacing_s=0.1 / 12, frame_period_s=0.1)
    t_s = np.linspace(0.0, 0.2, 21)
    w = np.radians(15.0) * np.array([0.3, 0.9, 0.1])
    q_s = np.ascontiguousarray(quat_integrate(quat_random(rng), w, t_s))
    fast = compute_scene(cam, nav, (t_s, q_s), plan, 0.05, validate=False)
    slow = compute_scene(cam, nav, (t_s, q_s), plan, 0.05)
    assert len(fast.star_index) > 20
    for name in ("star_index", "hip", "vmag", "bv", "xy_path", "visible", "q_body_to_icrs", "q_cam_to_icrs", "times",
                 "path_times"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    # with a bright body the compiled call also fills the rotations its view needs
    sun = BrightBody("sun", (0.3, -0.5, 0.8))
    fast = compute_scene(cam, nav, (t_s, q_s), plan, 0.05, bright_bodies=(sun,), validate=False)
    slow = compute_scene(cam, nav, (t_s, q_s), plan, 0.05, bright_bodies=(sun,))
    np.testing.assert_array_equal(fast.bright_bodies[0].angle_rad, slow.bright_bodies[0].angle_rad)
    np.testing.assert_array_equal(fast.bright_bodies[0].direction_cam, slow.bright_bodies[0].direction_cam)
    np.testing.assert_array_equal(fast.xy_path, slow.xy_path)


def test_track_frame_from_state_is_propagation_cone_and_frame(cam, nav):
    rng = np.random.default_rng(3)
    q0 = quat_random(rng)
    w = np.radians(8.0) * np.array([0.6, 0.8, 0.0])
    alpha = np.array([0.01, -0.02, 0.005])
    times = (np.arange(9) + 0.5) * 0.1 / 9
    fr = simulate_tracking_frame(cam, nav, q0, w, times, rng, sigma_px=0.3)
    # a slightly wrong motion state, as the tracker's is
    q_state = quat_multiply(q0, quat_from_rotvec([2e-5, -1e-5, 3e-5]))
    w_state, t_ref = w + 1e-4, -0.01
    q_state = quat_integrate(q_state, w_state, np.array([t_ref]))[0]
    cov_t, cov_w, cov_a = 1e-10 * np.eye(3), 1e-8 * np.eye(3), 1e-4 * np.eye(3)
    model = (*camera_projection_model(cam), *map(int, cam.resolution))
    q_cb = np.array(cam.q_cam_to_body, dtype=np.float64)
    sigma = 0.3 / cam.focal_length_px
    tail = (fr.xy, 6.0, False, cam.r_cam_to_body, sigma, 3, 5 * sigma)
    photometry = (np.zeros(len(fr.xy)), np.zeros(0), 1.6)
    # the state's attitude as the kernel may get it: any norm and sign (it normalises it first)
    q_raw = -1.7 * q_state * np.sign(q_state[0])
    accept = (16.0, 0.5, True)  # a residual scale the frame exceeds: the covariances grow
    got = tk.track_frame_from_state(q_raw, w_state, alpha, times, t_ref, q_cb, float(cam.half_diagonal_fov_rad),
                                    float(cam.focal_length_px), *nav.z_index, nav.vectors, *model, *tail,
                                    cov_t, cov_w, cov_a, *photometry, *accept)
    q0 = normalize_rows(q_raw[None])[0]
    q_pred, r_c2i, mid, spread = tk.propagate_attitudes(q0, w_state, alpha, times - t_ref, q_cb)
    cone = min(np.pi, cam.half_diagonal_fov_rad + spread + 6.0 / cam.focal_length_px + 0.02)
    cand = nav.cone_search(mid, cone)
    n_pred, n_matched, q, cov, rms, n_used, ok, nis = tk.track_frame(
        q_pred, r_c2i, cand, nav.vectors, *model, *tail, times, t_ref, cov_t, cov_w, cov_a, *photometry)
    assert n_matched > 100 and np.all(ok)  # matched, every instant solved
    want = (n_pred, n_matched, rms, n_used, ok, nis) + sk.accept_instants(np.flatnonzero(ok), times, q_pred, q, cov,
                                                                         rms, n_used, *accept)
    assert not np.array_equal(want[10], cov[ok])  # the scaling ran
    n_pred, n_matched, nis, n_off, values, counts, q_got, cov_got = got
    m = len(want[7])
    assert set(counts[3].tolist()) <= {0, 1}
    got = (n_pred, n_matched, values[0], counts[0], counts[3] == 1, nis, n_off, counts[1, :m], values[1, :m], q_got,
           cov_got, counts[2, :m])
    assert len(got) == len(want) and values.shape == (2, len(times)) and counts.dtype == np.int64
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def _instants(rng, n, off=None, shift_rad=3e-4):
    """n instants of a smooth prediction error (quadratic in time) with 1e-5 rad noise; ``off`` displaced."""
    tau = np.sort(rng.uniform(0.0, 0.1, n))
    q_pred = np.ascontiguousarray(quat_random(rng, n))
    theta = np.array([2e-4, -1e-4, 5e-5]) * tau[:, None] + np.array([1e-3, 0.0, -2e-3]) * tau[:, None] ** 2
    theta += rng.normal(0.0, 1e-5, (n, 3))
    if off is not None:
        theta[off] += np.array([shift_rad, 0.0, 0.0])
    q_sol = np.ascontiguousarray(quat_multiply(q_pred, quat_from_rotvec(theta)))
    covs = np.array([1e-10 * np.eye(3)] * n)
    return q_pred, q_sol, covs, tau


@pytest.mark.parametrize("n, off", [(9, 4), (5, 0), (8, 7)])
def test_smooth_instants_drops_exactly_the_instant_off_the_motion(n, off):
    rng = np.random.default_rng(n)
    q_pred, q_sol, covs, tau = _instants(rng, n)
    np.testing.assert_array_equal(sk.smooth_instants(q_pred, q_sol, covs, tau, 16.0), np.arange(n))
    q_pred, q_sol, covs, tau = _instants(rng, n, off)
    np.testing.assert_array_equal(sk.smooth_instants(q_pred, q_sol, covs, tau, 16.0), np.delete(np.arange(n), off))
    # the gate off: nothing is tested
    np.testing.assert_array_equal(sk.smooth_instants(q_pred, q_sol, covs, tau, np.inf), np.arange(n))


def test_three_instants_off_a_line_keep_none_and_two_cannot_be_tested():
    rng = np.random.default_rng(1)
    q_pred, q_sol, covs, tau = _instants(rng, 3, 1)
    assert len(sk.smooth_instants(q_pred, q_sol, covs, tau, 16.0)) == 0
    q_pred, q_sol, covs, tau = _instants(rng, 2, 1)
    np.testing.assert_array_equal(sk.smooth_instants(q_pred, q_sol, covs, tau, 16.0), [0, 1])


def test_accept_instants_scales_covariances_by_the_residual_variance_factor():
    rng = np.random.default_rng(5)
    n = 6
    q_pred, q_sol, covs, tau = _instants(rng, n)
    t_exp = tau
    rms = np.array([1.0, 3.0, 1.5, 2.5, 0.5, 2.0])  # arcsec
    n_stars = np.array([10, 4, 20, 8, 30, 3])
    sel = np.array([0, 1, 2, 3, 5])  # instant 4 not solved
    n_off, kept, t_s, q, cov, n_used = sk.accept_instants(sel, t_exp, q_pred, q_sol, covs, rms, n_stars, 16.0, 2.0, True)
    assert n_off == 0
    np.testing.assert_array_equal(kept, sel)
    np.testing.assert_array_equal(t_s, t_exp[sel])
    np.testing.assert_array_equal(q, q_sol[sel])
    np.testing.assert_array_equal(n_used, n_stars[sel])
    for k, j in enumerate(sel):
        # (rms / expected)² over the share of 2n - 3 degrees of freedom in 2n, never below 1
        factor = max((rms[j] / 2.0) ** 2 / max(1.0 - 1.5 / n_stars[j], 0.25), 1.0)
        np.testing.assert_allclose(cov[k], covs[j] * factor, rtol=1e-15)
    assert cov[1, 0, 0] > 2.0 * covs[1, 0, 0] and cov[0, 0, 0] == covs[0, 0, 0]
    unscaled = sk.accept_instants(sel, t_exp, q_pred, q_sol, covs, rms, n_stars, 16.0, 2.0, False)[4]
    np.testing.assert_array_equal(unscaled, covs[sel])
