"""Tracking mode: paper 000's DKVLUT (Appendix A), matcher equivalence, prediction geometry, N attitudes per frame."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from startracker.catalog import StarCatalog, load_catalog, select_navigation_stars
from startracker.optics import Camera, camera_preset
from startracker.rotations import (
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_random,
    quat_to_rotvec,
)
from startracker.simulation import simulate_tracking_frame
from startracker.track import (
    DKVLUT,
    MATCH_METHODS,
    attitudes_per_instant,
    match_stars,
    predict_star_positions,
    prediction_radius_px,
    prediction_sigma_px,
)

# Paper 000, Appendix A.
APPENDIX_PRED = np.array(
    [(506.4, 45.6), (23.2, 347.9), (105.8, 78.5), (1023.2, 732.6), (243.1, 381.5), (132.7, 176.3)]
)
APPENDIX_OBS = np.array([[246.7, 378.5]])


def reference_match(pred, obs, r):
    """Independent definition: nearest predicted point with d² <= r², ties to the lowest index, pure Python."""
    out = []
    for ox, oy in obs.tolist():
        best, best_d2 = -1, math.inf
        for j, (px, py) in enumerate(pred.tolist()):
            d2 = (ox - px) ** 2 + (oy - py) ** 2
            if d2 <= r * r and d2 < best_d2:
                best, best_d2 = j, d2
        out.append(best)
    return out


# ----------------------------------------------------------------------------------- Appendix A
def test_appendix_a_tables_candidates_and_result():
    t = DKVLUT(APPENDIX_PRED)
    assert t.kx.k.tolist() == [0, 3, 4, 5, 5, 6]  # K_x of Table A1
    assert t.ky.k.tolist() == [0, 2, 3, 5, 5, 6]  # K_y of Table A1
    assert (t.kx.order + 1).tolist() == [2, 3, 6, 5, 1, 4]  # R_x
    assert (t.ky.order + 1).tolist() == [1, 3, 6, 2, 5, 4]  # R_y
    assert t.kx.a1 == pytest.approx(240.0) and t.kx.b1 == pytest.approx(-316.8)  # eq. A2
    (sx, ex), (sy, ey) = t.candidate_ranges(APPENDIX_OBS, 5.0)
    # u_x in [3, 4] and u_y in [3, 5] (1-based rows), eq. A4 and step (3).
    assert (sx[0] + 1, ex[0]) == (3, 4) and (sy[0] + 1, ey[0]) == (3, 5)
    assert (t.kx.order[sx[0] : ex[0]] + 1).tolist() == [6, 5]  # R_x(u_x) = {6, 5}
    assert (t.ky.order[sy[0] : ey[0]] + 1).tolist() == [6, 2, 5]  # R_y(u_y) = {6, 2, 5}
    _, inter = t.candidates(APPENDIX_OBS, 5.0)
    assert sorted((inter + 1).tolist()) == [5, 6]  # R_P = {6, 5}
    for method in MATCH_METHODS:
        assert match_stars(APPENDIX_PRED, APPENDIX_OBS, 5.0, method=method).tolist() == [4]  # star 5


# ------------------------------------------------------------------------------- equivalence
coord = st.one_of(st.integers(-5, 60).map(float), st.floats(-50.0, 2100.0, allow_nan=False))


@settings(max_examples=400, deadline=None)
@given(
    st.lists(st.tuples(coord, coord), min_size=0, max_size=40),
    st.lists(st.tuples(coord, coord), min_size=0, max_size=40),
    st.one_of(st.sampled_from([0.0, 1.0, 2.0, 5.0]), st.floats(0.0, 300.0)),
)
def test_all_matchers_identical_and_equal_to_definition(pred, obs, r):
    pred = np.array(pred, dtype=float).reshape(-1, 2)
    obs = np.array(obs, dtype=float).reshape(-1, 2)
    ref = reference_match(pred, obs, r)
    for method in MATCH_METHODS:
        assert match_stars(pred, obs, r, method=method).tolist() == ref, method


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(coord, coord), min_size=1, max_size=40),
    st.lists(st.tuples(coord, coord), min_size=1, max_size=20),
    st.floats(0.0, 100.0),
)
def test_dkvlut_candidates_hold_every_point_of_the_square(pred, obs, r):
    pred, obs = np.array(pred), np.array(obs)
    qi, e = DKVLUT(pred).candidates(obs, r)
    got = set(zip(qi.tolist(), e.tolist()))
    inside = {
        (q, j)
        for q in range(len(obs))
        for j in range(len(pred))
        if abs(obs[q, 0] - pred[j, 0]) <= r and abs(obs[q, 1] - pred[j, 1]) <= r
    }
    assert inside <= got
    # Candidates beyond the square come only from the paper's inclusive u_a = K(i_a) and the bin widths.
    assert len(got) <= len(inside) + 4 * len(obs) * max(1, len(pred))


def test_dense_random_scene_all_methods_equal():
    rng = np.random.default_rng(3)
    pred = rng.uniform(0, 2048, (3000, 2))
    obs = np.concatenate([pred[:2000] + rng.normal(0, 2.0, (2000, 2)), rng.uniform(0, 2048, (500, 2))])
    results = [match_stars(pred, obs, 8.0, method=m) for m in MATCH_METHODS]
    assert all(np.array_equal(results[0], r) for r in results[1:])
    assert np.mean(results[0][:2000] == np.arange(2000)) > 0.98


def test_bad_input():
    p = np.array([[1.0, 2.0], [3.0, 4.0]])
    for method in MATCH_METHODS:
        assert match_stars(np.empty((0, 2)), p, 3.0, method).tolist() == [-1, -1]
        assert match_stars(p, np.empty((0, 2)), 3.0, method).shape == (0,)
        assert match_stars([], [], 3.0, method).shape == (0,)
        # Far off the detector: no crash, no match.
        assert match_stars(p * 1e12, p, 3.0, method).tolist() == [-1, -1]
    with pytest.raises(ValueError, match="radius_px"):
        match_stars(p, p, -1.0)
    with pytest.raises(ValueError, match="radius_px"):
        match_stars(p, p, float("nan"))
    with pytest.raises(ValueError, match="observed_xy"):
        match_stars(p, [[np.nan, 1.0]], 1.0)
    with pytest.raises(ValueError, match="predicted_xy"):
        match_stars([[1.0, 2.0, 3.0]], p, 1.0)
    with pytest.raises(ValueError, match="method"):
        match_stars(p, p, 1.0, method="grid")
    with pytest.raises(TypeError, match="radius_px"):
        match_stars(p, p, "3")


# -------------------------------------------------------------------------------- prediction
def one_star_catalog(v):
    v = np.asarray(v, float)
    return StarCatalog(hip=np.array([1]), vectors=(v / np.linalg.norm(v))[None], vmag=np.array([3.0]), bv=np.array([0.5]))


def test_prediction_of_a_boresight_star_under_rotation_about_camera_y():
    # Body = camera; a star on the boresight at t=0; rotation about +y by θ(t) = ω t + α t²/2 moves it to
    # v_cam = (-sin θ, 0, cos θ), i.e. column cx - f_px tan θ (exact pinhole geometry, fixed axis).
    cam = camera_preset("paper000")
    cat = one_star_catalog([0, 0, 1])
    w, a = 0.3, 0.5
    t = np.linspace(0.0, 0.1, 11)
    pred = predict_star_positions(cam, cat, [1, 0, 0, 0], t, 0.0, [0, w, 0], [0, a, 0])
    theta = w * t + 0.5 * a * t**2
    np.testing.assert_allclose(pred.xy[:, 0], cam.principal_point[0] - cam.focal_length_px * np.tan(theta), atol=1e-6)
    np.testing.assert_allclose(pred.xy[:, 1], cam.principal_point[1], atol=1e-6)
    assert pred.instant.tolist() == list(range(11))
    # The spot leaves the 20° field at θ = 10°: no prediction beyond, unless within the margin.
    t_late = np.array([np.radians(10.5) / w])
    assert len(predict_star_positions(cam, cat, [1, 0, 0, 0], t_late, 0.0, [0, w, 0])) == 0
    p = predict_star_positions(cam, cat, [1, 0, 0, 0], t_late, 0.0, [0, w, 0], margin_px=200.0)
    assert len(p) == 1 and not p.on_detector[0]


def test_prediction_applies_the_camera_mounting():
    # Camera boresight along body +x: q_cam_to_body rotates camera z onto body x (90° about body y).
    q_mount = quat_from_rotvec([0, np.pi / 2, 0])
    cam = Camera(q_cam_to_body=q_mount)
    cat = one_star_catalog([1, 0, 0])  # body = ICRS: the star sits on body +x, the boresight
    pred = predict_star_positions(cam, cat, [1, 0, 0, 0], [0.0])
    np.testing.assert_allclose(pred.xy[0], cam.principal_point, atol=1e-9)


def test_radius_rule():
    assert prediction_radius_px(1.0) == pytest.approx(6.0)
    assert prediction_radius_px(0.3, 0.4) == pytest.approx(3.0)
    assert prediction_radius_px(0.1, 0.0, r_min_px=2.0) == 2.0
    cam = camera_preset("paper000")
    # 10 arcsec cross-boresight attitude error, exact rate: f_px * 4.85e-5 rad ≈ 0.28 px.
    s = np.radians(10 / 3600)
    cov = np.diag([s**2, s**2, 0.0])
    assert prediction_sigma_px(cam, cov, 0.1) == pytest.approx(cam.focal_length_px * s, rel=1e-12)
    # Rate uncertainty grows linearly with the propagation time, acceleration quadratically.
    g1 = prediction_sigma_px(cam, np.zeros((3, 3)), 0.05, np.diag([1e-6, 1e-6, 0.0]))
    g2 = prediction_sigma_px(cam, np.zeros((3, 3)), [0.01, -0.10], np.diag([1e-6, 1e-6, 0.0]))
    assert g2 == pytest.approx(2 * g1) and g1 == pytest.approx(cam.focal_length_px * 1e-3 * 0.05)
    a1 = prediction_sigma_px(cam, np.zeros((3, 3)), 0.05, 0.0, 0.1**2)
    a2 = prediction_sigma_px(cam, np.zeros((3, 3)), 0.10, 0.0, 0.1**2)
    assert a2 == pytest.approx(4 * a1)
    # Roll error: the spot in the far corner moves by ρ σ.
    roll = prediction_sigma_px(cam, np.diag([0.0, 0.0, s**2]))
    assert roll == pytest.approx(np.hypot(2048, 2048) / 2 * s)


# ----------------------------------------------------------------- a multi-exposure frame end to end
@pytest.fixture(scope="module")
def catalog():
    return load_catalog(6.0)


def slew_axis(rng):
    ax = np.array([*rng.normal(size=2), 0.1 * rng.normal()])
    return ax / np.linalg.norm(ax)


def test_matching_accuracy_100_percent_at_sigma_1px(catalog):
    # Paper 000 §4 setting: N = 15 at 14 °/s (spots of one star 9.5 px apart), σ = 1 px, predicted = true
    # spots, r = 6σ by the rule. A spot whose nearest other predicted spot is D away is mis-assigned only if
    # its noise along that direction exceeds D/2: for D > 1.5 r = 9σ that is Φ(-4.5) = 3e-6 per spot, so all
    # of those must be right. Close doubles and crossing trails (another star's spot within a few px) are
    # geometrically ambiguous and excluded from the 100 % claim.
    cam = camera_preset("paper000")
    rng = np.random.default_rng(5)
    r = prediction_radius_px(1.0)
    n_total = n_ok = n_res = n_res_ok = 0
    for _ in range(10):
        q = quat_random(rng)
        w = slew_axis(rng) * np.radians(14.0)
        times = np.arange(15) * 0.1 / 15
        fr = simulate_tracking_frame(cam, catalog, q, w, times, rng, sigma_px=1.0)
        pred = predict_star_positions(cam, catalog, q, times, 0.0, w)
        key = {(s, i): j for j, (s, i) in enumerate(zip(pred.star_index.tolist(), pred.instant.tolist()))}
        truth = np.array([key[(s, i)] for s, i in zip(fr.star_index.tolist(), fr.instant.tolist())])
        results = [match_stars(pred.xy, fr.xy, r, method=m) for m in MATCH_METHODS]
        assert all(np.array_equal(results[0], x) for x in results[1:])
        d = np.linalg.norm(pred.xy[:, None] - pred.xy[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        resolvable = d.min(axis=1)[truth] > 1.5 * r
        n_total += len(truth)
        n_ok += int(np.sum(results[0] == truth))
        n_res += int(resolvable.sum())
        n_res_ok += int(np.sum(results[0][resolvable] == truth[resolvable]))
    assert n_res > 0.9 * n_total > 2000
    assert n_res_ok == n_res
    assert n_ok > 0.99 * n_total


def attitude_errors_body(q_est, q_true):
    """Rotation vector δθ with q_true = q_est ⊗ δq(δθ): the error in the body frame."""
    return quat_to_rotvec(quat_multiply(quat_conjugate(q_est), q_true))


def test_n_attitudes_per_frame_timestamps_and_covariance_consistent_with_truth(catalog):
    cam = camera_preset("paper000", q_cam_to_body=quat_from_rotvec([0.3, -0.2, 0.1]))
    rng = np.random.default_rng(7)
    sigma_px = 0.3
    nav = select_navigation_stars(catalog, min_separation_rad=np.radians(0.1))  # no blended doubles
    nees, n_used, n_wrong = [], 0, 0
    for k in range(15):
        q = quat_random(rng)
        w = slew_axis(rng) * np.radians(10.0)
        times = 100.0 + k * 0.1 + np.arange(11) * 0.1 / 11
        fr = simulate_tracking_frame(cam, nav, q, w, times, rng, t_ref_s=times[0], sigma_px=sigma_px, n_false=200)
        # Prediction from a slightly wrong prior (20 arcsec, 0.1 %/s rate error), as in tracking.
        q_prior = quat_multiply(q, quat_from_rotvec(rng.normal(0, np.radians(20 / 3600), 3)))
        pred = predict_star_positions(cam, nav, q_prior, times, times[0], w * 1.001, margin_px=6.0)
        r = prediction_radius_px(sigma_px, 2.0)
        idx = match_stars(pred.xy, fr.xy, r)
        res = attitudes_per_instant(fr.xy, idx, pred, cam, nav, sigma_px)
        assert res.ok.all() and res.times_s.tolist() == times.tolist()
        assert np.all(res.n_stars >= 10)
        err = attitude_errors_body(res.q_body_to_icrs, fr.q_body_to_icrs)  # (N, 3)
        nees.extend(np.einsum("ni,nij,nj->n", err, np.linalg.inv(res.covariance_rad2), err))
        # Hardly any false object is used: only one lying closer to a predicted spot than its true spot.
        used = res.assignment >= 0
        n_used += int(used.sum())
        wrong = (fr.star_index[used] != pred.star_index[res.assignment[used]]) | (
            fr.instant[used] != pred.instant[res.assignment[used]]
        )
        n_wrong += int(wrong.sum())
        assert np.all(fr.star_index[used][wrong] == -1)
    nees = np.array(nees)
    # χ² with 3 degrees of freedom: mean 3; 165 samples give a standard error of 0.19.
    assert 2.3 < nees.mean() < 3.7
    assert np.mean(nees < 7.81) > 0.9  # 95 % quantile of χ²(3)
    assert n_wrong <= 1e-3 * n_used


def test_instants_with_too_few_stars_are_skipped(catalog):
    cam = camera_preset("paper000")
    rng = np.random.default_rng(8)
    q = quat_random(rng)
    w = slew_axis(rng) * np.radians(5.0)
    times = np.arange(6) * 0.1 / 6
    fr = simulate_tracking_frame(cam, catalog, q, w, times, rng, sigma_px=0.2)
    # Instant 2 keeps only two stars, instant 4 none.
    drop = ((fr.instant == 2) & (np.cumsum(fr.instant == 2) > 2)) | (fr.instant == 4)
    xy = fr.xy[~drop]
    pred = predict_star_positions(cam, catalog, q, times, 0.0, w)
    res = attitudes_per_instant(xy, match_stars(pred.xy, xy, 2.0), pred, cam, catalog, 0.2)
    assert res.skipped.tolist() == [2, 4]
    assert res.n_stars[2] == 2 and res.n_stars[4] == 0
    assert np.all(np.isinf(res.covariance_rad2[[2, 4]]))


def test_outlier_on_a_predicted_spot_is_rejected(catalog):
    cam = camera_preset("paper000")
    rng = np.random.default_rng(9)
    q = quat_random(rng)
    times = np.array([0.0])
    fr = simulate_tracking_frame(cam, catalog, q, np.zeros(3), times, rng, sigma_px=0.1)
    pred = predict_star_positions(cam, catalog, q, times)
    xy = fr.xy.copy()
    xy[0] += [2.5, -1.5]  # one spot displaced 2.9 px: matched (r = 4), but 29 σ off in the Wahba residual
    idx = match_stars(pred.xy, xy, 4.0)
    assert idx[0] >= 0
    res = attitudes_per_instant(xy, idx, pred, cam, catalog, 0.1)
    assert res.n_outliers == 1 and res.assignment[0] == -1
    err = attitude_errors_body(res.q_body_to_icrs[0], fr.q_body_to_icrs[0])
    assert err @ np.linalg.inv(res.covariance_rad2[0]) @ err < 16.3  # χ²(3) 99.9 %: consistent again
    kept = attitudes_per_instant(xy, idx, pred, cam, catalog, 0.1, outlier_k_sigma=1e9)
    err_kept = attitude_errors_body(kept.q_body_to_icrs[0], fr.q_body_to_icrs[0])
    assert kept.n_outliers == 0 and err_kept @ np.linalg.inv(kept.covariance_rad2[0]) @ err_kept > 16.3


# ------------------------------------------------------------------ compiled path against references
def _reference_prediction(cam, cat, q0, times, t_ref, w, a, margin):
    """Prediction by the checked rotation functions, an explicit cone of dot products and ``Camera.project``."""
    from startracker.rotations import quat_integrate, quat_to_matrix

    q_body = quat_integrate(np.asarray(q0, float), np.asarray(w, float), np.asarray(times) - t_ref, np.asarray(a, float))
    rows = []
    for i, q in enumerate(np.atleast_2d(q_body)):
        r_c2i = quat_to_matrix(quat_multiply(q, np.array(cam.q_cam_to_body)))
        v_cam = cat.vectors @ r_c2i
        xy, _, front = cam.project(v_cam, return_in_front=True)
        # Stars far outside the field can fold onto the detector through the distortion polynomial: only those
        # within the field's half-diagonal (plus the margin) are real spots.
        front &= v_cam[:, 2] >= np.cos(cam.half_diagonal_fov_rad + margin / cam.focal_length_px + 0.01)
        wdt, hgt = cam.resolution
        keep = front & (xy[:, 0] >= -0.5 - margin) & (xy[:, 0] <= wdt - 0.5 + margin) & (xy[:, 1] >= -0.5 - margin) & (xy[:, 1] <= hgt - 0.5 + margin)
        for j in np.flatnonzero(keep):
            rows.append((i, j, xy[j, 0], xy[j, 1]))
    return np.atleast_2d(q_body), rows


@pytest.mark.parametrize("kind", ["plain", "distorted", "channel"])
def test_compiled_prediction_equals_a_reference_over_the_whole_catalog(catalog, kind):
    from startracker.color import ChannelCamera

    base = camera_preset("paper000", q_cam_to_body=quat_from_rotvec([0.1, 0.4, -0.2]))
    if kind == "distorted":
        base = Camera(resolution=(1024, 768), pixel_size_um=5.5, focal_length_mm=20.0, distortion_k1_per_mm2=-2e-4,
                      q_cam_to_body=base.q_cam_to_body)
    cam = ChannelCamera.from_camera(base, np.radians(1.7)) if kind == "channel" else base
    rng = np.random.default_rng(21)
    for _ in range(5):
        q = quat_random(rng)
        times = np.sort(rng.uniform(0, 0.1, 7))
        w, a = rng.normal(0, 0.2, 3), rng.normal(0, 0.5, 3)
        pred = predict_star_positions(cam, catalog, q, times, 0.03, w, a, margin_px=5.0)
        q_ref, rows = _reference_prediction(cam, catalog, q, times, 0.03, w, a, 5.0)
        np.testing.assert_allclose(pred.q_body_to_icrs, q_ref, atol=1e-15)
        got = sorted(zip(pred.instant.tolist(), pred.star_index.tolist()))
        assert got == sorted((i, j) for i, j, _, _ in rows)
        ref_xy = {(i, j): (x, y) for i, j, x, y in rows}
        np.testing.assert_allclose(pred.xy, [ref_xy[k] for k in zip(pred.instant.tolist(), pred.star_index.tolist())],
                                   atol=1e-7)
        assert np.all(np.diff(pred.instant) >= 0)
        wdt, hgt = cam.resolution
        on = (pred.xy[:, 0] >= -0.5) & (pred.xy[:, 0] <= wdt - 0.5) & (pred.xy[:, 1] >= -0.5) & (pred.xy[:, 1] <= hgt - 0.5)
        assert np.array_equal(pred.on_detector, on)


class _MirroredCamera(Camera):
    """A camera with a projection model of its own (columns mirrored): must go through its methods."""

    def project(self, v_cam, return_in_front=False, *, validate=True):
        xy, in_frame, front = super().project(v_cam, return_in_front=True, validate=validate)
        xy = np.array(xy, copy=True)
        xy[..., 0] = self.resolution[0] - 1 - xy[..., 0]
        return (xy, in_frame, front) if return_in_front else (xy, in_frame)

    def unproject(self, xy):
        xy = np.array(xy, dtype=float, copy=True)
        xy[..., 0] = self.resolution[0] - 1 - xy[..., 0]
        return super().unproject(xy)


def test_a_camera_with_its_own_projection_is_used_through_its_methods(catalog):
    cam = _MirroredCamera(resolution=(2048, 2048), pixel_size_um=5.5, focal_length_mm=31.94)
    plain = camera_preset("paper000")
    rng = np.random.default_rng(22)
    q = quat_random(rng)
    times = np.linspace(0, 0.1, 4)
    p_m = predict_star_positions(cam, catalog, q, times, 0.0, [0.0, 0.05, 0.0])
    p_p = predict_star_positions(plain, catalog, q, times, 0.0, [0.0, 0.05, 0.0])
    assert p_m.star_index.tolist() == p_p.star_index.tolist()
    np.testing.assert_allclose(p_m.xy[:, 0], 2047 - p_p.xy[:, 0], atol=1e-9)
    res = attitudes_per_instant(p_m.xy, np.arange(len(p_m)), p_m, cam, catalog, 0.1)
    err = quat_to_rotvec(quat_multiply(quat_conjugate(res.q_body_to_icrs), p_m.q_body_to_icrs))
    assert res.ok.all() and np.abs(err).max() < 1e-9


def _reference_attitudes(obs, idx, pred, cam, cat, sigma_px, k_sigma):
    """Unique assignment and per-instant outlier loop in plain numpy, Wahba by scipy's align_vectors."""
    from scipy.spatial.transform import Rotation

    assign = np.full(len(obs), -1)
    for p in np.unique(idx[idx >= 0]):
        q = np.flatnonzero(idx == p)
        d2 = np.sum((obs[q] - pred.xy[p]) ** 2, axis=1)
        assign[q[np.argmin(d2)]] = p  # first minimum: the lowest observed index on ties
    v_body = cam.unproject(obs) @ cam.r_cam_to_body.T
    thr = k_sigma * sigma_px / cam.focal_length_px
    out = []
    for i in range(len(pred.times_s)):
        q_i = [q for q in range(len(obs)) if assign[q] >= 0 and pred.instant[assign[q]] == i]
        while True:
            b = v_body[q_i]
            r = cat.vectors[pred.star_index[assign[q_i]]]
            rot, _ = Rotation.align_vectors(r, b)
            ab = rot.apply(b)
            ang = np.arctan2(np.linalg.norm(np.cross(ab, r), axis=1), np.sum(ab * r, axis=1))
            if len(q_i) > 2 and ang.max() > thr:
                q_i.pop(int(np.argmax(ang)))
                continue
            break
        out.append((rot, q_i))
    return out


def test_grouping_and_wahba_equal_an_independent_reference(catalog):
    cam = camera_preset("paper000", q_cam_to_body=quat_from_rotvec([0.3, -0.2, 0.1]))
    rng = np.random.default_rng(23)
    n_out = n_doubles = 0
    for _ in range(4):
        q = quat_random(rng)
        w = slew_axis(rng) * np.radians(6.0)
        times = np.arange(7) * 0.1 / 7
        pred = predict_star_positions(cam, catalog, q, times, 0.0, w)
        obs = pred.xy + rng.normal(0, 0.3, pred.xy.shape)
        extra = pred.xy[rng.choice(len(pred), 25)] + rng.normal(0, 1.0, (25, 2))  # doubles on predicted spots
        obs = np.concatenate([obs, extra])
        obs[rng.choice(len(pred), 5)] += rng.uniform(2.0, 3.0, (5, 2))  # outliers within the radius
        idx = match_stars(pred.xy, obs, 4.5)
        res = attitudes_per_instant(obs, idx, pred, cam, catalog, 0.3)
        ref = _reference_attitudes(obs, idx, pred, cam, catalog, 0.3, 5.0)
        for i, (rot, q_i) in enumerate(ref):
            assert res.n_stars[i] == len(q_i)
            assert sorted(np.flatnonzero(res.assignment >= 0)[pred.instant[res.assignment[res.assignment >= 0]] == i].tolist()) == sorted(q_i)
            q_ref = rot.as_quat()[[3, 0, 1, 2]]
            assert np.linalg.norm(quat_to_rotvec(quat_multiply(quat_conjugate(res.q_body_to_icrs[i]), q_ref))) < 1e-11
        # every predicted spot matched keeps exactly one detection unless that one was rejected as an outlier
        assert res.n_outliers == len(np.unique(idx[idx >= 0])) - np.sum(res.assignment >= 0)
        n_out += res.n_outliers
        n_doubles += int(np.sum(idx >= 0) - len(np.unique(idx[idx >= 0])))
    assert n_out > 0 and n_doubles > 0  # both rules were exercised
