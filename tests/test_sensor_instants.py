"""The smoothness test of a tracked frame's instants: an instant matched one exposure off (its spots taken for the
neighbouring exposure's, when the prediction lags by about half the spots' spacing at the end of a frame after a
torque step) is not reported; the leave-one-out χ² kernel against a brute-force fit."""

import numpy as np
import pytest

from startracker.catalog import load_catalog, select_navigation_stars
from startracker.kernels.sensor import instant_deleted_chi2
from startracker.optics import camera_preset
from startracker.rotations import quat_conjugate, quat_from_rotvec, quat_integrate, quat_multiply, quat_random, quat_to_rotvec
from startracker.sensor import StarTracker
from startracker.simulation import simulate_tracking_frame

FRAME_S = 0.1
SIGMA_PX = 0.3
VERDICT_CHI2 = 44.8  # χ²(3) at 1e-9: the verdict of docs/reliability.md


def nees(sample, q_true):
    e = quat_to_rotvec(quat_multiply(quat_conjugate(sample.q_body_to_icrs), q_true))
    return float(e @ np.linalg.solve(sample.covariance_rad2, e))


def shifted_instant_run(cam, nav, gate, shift_px, seed, n=21, rate_deg_s=19.0):
    """Five frames at a constant rate with ``n`` exposures; in frames 3 and 4 every spot of the middle exposure is
    displaced by ``shift_px`` along the motion (the coherent pull of spots joined across exposures, or part of an
    exposure's spots taken for the neighbour's). Returns the samples of frames 3-4 over the verdict's χ² threshold,
    and the number of samples at the shifted instant that were reported."""
    rng = np.random.default_rng(seed)
    q0 = quat_random(rng)
    w0 = np.radians(rate_deg_s) * np.array([0.6, 0.8, 0.0])
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX, instant_gate=gate)
    n_wrong = n_mid = 0
    for k in range(5):
        nk = st.requested_n_exposures if k < 3 else n
        times = k * FRAME_S + (np.arange(nk) + 0.5) * FRAME_S / nk
        fr = simulate_tracking_frame(cam, nav, q0, w0, times, rng, sigma_px=SIGMA_PX, p_detect=0.95)
        xy = fr.xy.copy()
        if k >= 3:
            mid = fr.instant == nk // 2
            # the image motion of the middle exposure's spots: their displacement to the next exposure's
            step = np.array([np.median(np.diff(fr.xy_true[(fr.star_index == s) & (fr.instant >= 0)][np.argsort(
                fr.instant[(fr.star_index == s) & (fr.instant >= 0)])], axis=0), axis=0)
                for s in np.unique(fr.star_index[mid])]).mean(axis=0)
            xy[mid] += shift_px * step / np.linalg.norm(step)
        res = st.process_frame(xy, fr.intensity, times, k * FRAME_S, omega_body=w0)
        if k >= 3:
            n_wrong += sum(nees(s, quat_integrate(q0, w0, s.t_s)) > VERDICT_CHI2 for s in res.samples)
            n_mid += sum(abs(s.t_s - times[nk // 2]) < 1e-9 for s in res.samples)
    return n_wrong, n_mid


def test_an_instant_off_the_smooth_motion_is_not_reported(cam, nav):
    """One instant pulled along the motion by a fraction of the spots' spacing: with the smoothness test it is not
    reported and no wrong sample leaves the tracker; without it (gate ∞) wrong samples do."""
    on = [shifted_instant_run(cam, nav, 16.0, d, seed) for seed, d in enumerate((0.6, 0.9, 1.2, 1.6))]
    off = [shifted_instant_run(cam, nav, np.inf, d, seed) for seed, d in enumerate((0.6, 0.9, 1.2, 1.6))]
    assert sum(w for w, _ in on) == 0
    assert sum(w for w, _ in off) > 0
    # where the pulled instant left the tracker without the test, the test removed exactly it
    assert all(m_on == 0 for (_, m_on), (w_off, _) in zip(on, off) if w_off)


def test_instant_deleted_chi2_against_brute_force_leave_one_out():
    rng = np.random.default_rng(4)
    n = 9
    tau = np.sort(rng.uniform(0.0, 0.1, n))
    q_ref = quat_random(rng)
    w, a = rng.normal(0, 0.2, 3), rng.normal(0, 0.5, 3)
    theta = w * tau[:, None] + 0.5 * a * tau[:, None] ** 2
    covs = np.array([np.diag(rng.uniform(1, 3, 3)) * 1e-10 for _ in range(n)])
    theta += np.array([rng.multivariate_normal(np.zeros(3), c) for c in covs])
    theta[4] += np.array([3e-4, 0.0, 0.0])  # one instant off its trajectory
    q = quat_multiply(q_ref, quat_from_rotvec(theta))
    got = instant_deleted_chi2(np.broadcast_to(q[n // 2], (n, 4)).copy(), q, covs, tau, 2)
    # brute force: fit the other instants (numpy.polyfit per axis, rotation vectors about the middle instant)
    ref = q[n // 2]
    th = quat_to_rotvec(quat_multiply(quat_conjugate(np.broadcast_to(ref, (n, 4))), q))
    for k in range(n):
        others = np.delete(np.arange(n), k)
        pred = np.array([np.polyval(np.polyfit(tau[others], th[others, ax], 2), tau[k]) for ax in range(3)])
        # the fit's own variance at tau_k with the others' mean covariance (equal weights)
        x = np.vander(tau[others] - tau.mean(), 3)
        xk = np.vander(np.array([tau[k] - tau.mean()]), 3)[0]
        h = xk @ np.linalg.inv(x.T @ x) @ xk
        s = covs[k] + covs[others].mean(axis=0) * h
        d = th[k] - pred
        assert got[k] == pytest.approx(d @ np.linalg.solve(s, d), rel=1e-6, abs=1e-6)
    # the instant off its trajectory stands out (its neighbours' fits are pulled by it, less)
    assert np.argmax(got) == 4 and got[4] > 100.0 and got[4] > 4.0 * np.sort(got)[-2]


def blended_run(cam, nav, star_flux, seed, n=21, rate_deg_s=19.0, sigma_px=0.5):
    """Five frames at a constant rate; in frames 3 and 4 a third of the stars have the spots of exposures 9-12 joined
    into one blob (light 1, 1, 1, 0.3: its centroid 0.18 of a spacing past exposure 10's spot, intensity 3.3 times one
    exposure's), as a bright star's near-overlapping spots are. The smoothness test is off, to see the photometric
    test alone. Returns the samples of frames 3-4 over the verdict's χ² threshold."""
    rng = np.random.default_rng(seed)
    q0 = quat_random(rng)
    w0 = np.radians(rate_deg_s) * np.array([0.6, 0.8, 0.0])
    st = StarTracker(cam, nav, centroid_sigma_px=sigma_px, instant_gate=np.inf, star_flux=star_flux)
    n_wrong = 0
    for k in range(5):
        nk = st.requested_n_exposures if k < 3 else n
        times = k * FRAME_S + (np.arange(nk) + 0.5) * FRAME_S / nk
        fr = simulate_tracking_frame(cam, nav, q0, w0, times, rng, sigma_px=SIGMA_PX, p_detect=1.0)
        xy, inten = fr.xy.copy(), fr.intensity.copy()
        if k >= 3:
            keep = np.ones(len(xy), dtype=bool)
            blobs, blob_i = [], []
            for s in np.unique(fr.star_index[fr.star_index >= 0])[::3]:
                rows = [np.flatnonzero((fr.star_index == s) & (fr.instant == e)) for e in (9, 10, 11, 12)]
                if any(len(r) != 1 for r in rows):
                    continue
                rows = [r[0] for r in rows]
                wgt = np.array([1.0, 1.0, 1.0, 0.3])
                blobs.append((wgt[:, None] * fr.xy_true[rows]).sum(axis=0) / wgt.sum() + rng.normal(0, SIGMA_PX, 2))
                blob_i.append((wgt * fr.intensity[rows]).sum())
                keep[rows] = False
            xy = np.vstack([xy[keep], blobs])
            inten = np.concatenate([inten[keep], blob_i])
        res = st.process_frame(xy, inten, times, k * FRAME_S, omega_body=w0)
        if k >= 3:
            n_wrong += sum(nees(s, quat_integrate(q0, w0, s.t_s)) > VERDICT_CHI2 for s in res.samples)
    return n_wrong


def test_spots_joined_across_exposures_are_not_used(cam, nav):
    """Blobs of a star's joined exposures sit inside the outlier threshold and pull their instant along the motion;
    the photometric blend test (each star's expected signal, the frame's own flux scale) leaves them out."""
    flux = 10.0 ** (-0.4 * nav.vmag)
    with_test = sum(blended_run(cam, nav, flux, seed) for seed in range(3))
    without = sum(blended_run(cam, nav, None, seed) for seed in range(3))
    assert with_test == 0
    assert without > 0
    with pytest.raises(ValueError, match="star_flux"):
        StarTracker(cam, nav, star_flux=np.ones(3))
    with pytest.raises(ValueError, match="blend_flux_ratio"):
        StarTracker(cam, nav, star_flux=flux, blend_flux_ratio=1.0)


def torque_step_modes(cam, nav, use_alpha, d_alpha=0.6, seed=5, n=10, rate_deg_s=9.0):
    """Six frames at a constant rate with a gyro, then the angular acceleration steps by ``d_alpha`` (rad/s²) at the
    start of frame 6. The gyro rate at each frame's start is given; ``use_alpha``: also the gyro's mean acceleration
    over the frame. Returns the modes after frames 6-8 and the largest NEES of their samples."""
    rng = np.random.default_rng(seed)
    q0 = quat_random(rng)
    axis = np.array([0.6, 0.8, 0.0])
    w0 = np.radians(rate_deg_s) * axis
    t1 = 6 * FRAME_S
    q1 = quat_integrate(q0, w0, t1)
    a1 = d_alpha * axis
    st = StarTracker(cam, nav, centroid_sigma_px=SIGMA_PX, gyro_sigma_rad_s=1e-5)
    modes, worst = [], 0.0
    for k in range(9):
        nk = st.requested_n_exposures if k < 6 else n
        times = k * FRAME_S + (np.arange(nk) + 0.5) * FRAME_S / nk
        if k < 6:
            fr = simulate_tracking_frame(cam, nav, q0, w0, times, rng, sigma_px=SIGMA_PX, p_detect=0.95)
            w_start, alpha = w0, np.zeros(3)
        else:
            fr = simulate_tracking_frame(cam, nav, q1, w0, times, rng, t_ref_s=t1, alpha_body=a1, sigma_px=SIGMA_PX,
                                         p_detect=0.95)
            w_start, alpha = w0 + a1 * (k * FRAME_S - t1), a1
        res = st.process_frame(fr.xy, fr.intensity, times, k * FRAME_S, omega_body=w_start,
                               alpha_body=alpha if use_alpha else None)
        if k >= 6:
            modes.append(res.mode)
            for s in res.samples:
                q_true = quat_integrate(q0, w0, s.t_s) if s.t_s <= t1 else quat_integrate(q1, w0, s.t_s - t1, a1)
                worst = max(worst, nees(s, q_true))
    return modes, worst


def test_gyro_acceleration_over_the_frame_follows_a_torque_step(cam, nav):
    """A torque step at a frame's start: the acceleration of the previous frames is stale, and the prediction lags
    several spot spacings by the frame's end (lock lost); with the gyro's acceleration over the frame it does not."""
    modes_on, worst_on = torque_step_modes(cam, nav, True)
    modes_off, _ = torque_step_modes(cam, nav, False)
    assert modes_on == ["track", "track", "track"] and worst_on < VERDICT_CHI2
    assert modes_off[0] == "lost"
