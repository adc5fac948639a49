"""Distributed multiple FoVs with inertial aiding (paper 001): geometry, INS prediction, part catalog, matching."""

from dataclasses import fields

import numpy as np
import pytest

from startracker.catalog import load_catalog, select_navigation_stars
from startracker.identify.result import IdentificationResult
from startracker.imu import GyroSpec, gyro_preset
from startracker.multifov.ins_error import attitude_sigma_bound_rad, propagate_attitude_error
from startracker.multifov.local_catalog import LocalCatalog, ObservedScope, los_bias_angles, predict_scopes
from startracker.multifov import MultiFovSensor, installation_quaternions, paper001_head
from startracker.multifov.matcher import InertialAidedMatcher, MultiFovResult
from startracker.optics import Camera
from startracker.rotations import (
    quat_angle_between,
    quat_from_rotvec,
    quat_multiply,
    quat_random,
    quat_to_matrix,
)

SIGMA_PX = 0.2


@pytest.fixture(scope="module")
def matcher45(sensor45, cat):
    return InertialAidedMatcher(sensor45, cat, sigma_px=SIGMA_PX)


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def three_head_sensor():
    """Three 5° heads, 40° off body +z at azimuths 0°, 120°, 240°."""
    mats = np.stack([rot_z(np.radians(az)) @ rot_x(np.radians(40)) for az in (0, 120, 240)])
    return MultiFovSensor.from_installation_matrices(paper001_head(), mats)


def ins_attitude(rng, q_true, sigma_rad):
    mu = rng.normal(0.0, sigma_rad, 3)
    return quat_multiply(quat_from_rotvec(mu), q_true), mu


def truth_hips(cat, idx):
    return np.concatenate([cat.hip[i] for i in idx])


# ----------------------------------------------------------------------------------------- geometry
def test_two_heads_installation_angle_and_transfer_matrix():
    s = MultiFovSensor.two_heads(paper001_head(), 60.0)
    assert np.degrees(s.installation_angles_rad[0, 1]) == pytest.approx(60.0, abs=1e-9)
    c = s.transfer_matrix(1)
    # Eq. 3: C_am = C_mᵀ C_a is a rotation taking the aux boresight to a main-frame direction 60° off axis.
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(c) == pytest.approx(1.0)
    assert np.degrees(np.arccos((c @ [0, 0, 1])[2])) == pytest.approx(60.0, abs=1e-9)
    np.testing.assert_allclose(s.transfer_matrix(0), np.eye(3), atol=1e-12)


def test_fusion_matches_direct_projection_on_extended_main_plane():
    """Eqs. 2-5 against projecting the star's body direction straight through the main head's pinhole."""
    cam = Camera(resolution=(1024, 1024), pixel_size_um=5.5, focal_length_mm=64.5, distortion_k1_per_mm2=2e-4)
    aux_cam = Camera(resolution=(800, 600), pixel_size_um=4.0, focal_length_mm=50.0, distortion_k1_per_mm2=-1e-4)
    q_main = quat_from_rotvec([0.1, -0.2, 0.05])
    q_aux = quat_from_rotvec([0.3, 0.6, -0.4])
    s = MultiFovSensor((cam.with_mounting(q_main), aux_cam.with_mounting(q_aux)))
    assert s.fusable.all()
    rng = np.random.default_rng(0)
    # Random directions inside each head's detector, measured (distorted) pixel coordinates.
    xy = []
    v_body_truth = []
    for h in s.heads:
        n = 25
        px = rng.uniform([0, 0], np.array(h.resolution) - 1, (n, 2))
        v_cam = h.unproject(px)
        xy.append(px)
        v_body_truth.append(v_cam @ h.r_cam_to_body.T)
    fused = s.fuse(xy)
    v_body_truth = np.concatenate(v_body_truth)
    v_main = v_body_truth @ s.heads[0].r_cam_to_body  # C_mᵀ v_body
    f_m = s.heads[0].focal_length_mm
    direct_mm = f_m * v_main[:, :2] / v_main[:, 2:3]
    np.testing.assert_allclose(fused.xy_mm, direct_mm, atol=1e-9)
    np.testing.assert_allclose(fused.v_main, v_main, atol=1e-12)
    np.testing.assert_array_equal(fused.head, np.repeat([0, 1], 25))
    # Main-head stars land at their own undistorted position; pixel units continue the main grid.
    np.testing.assert_allclose(fused.xy_px[:25], direct_mm[:25] / 5.5e-3 + 511.5, atol=1e-6)
    # Aux stars fall outside the main detector.
    assert np.all(np.abs(fused.xy_px[25:] - 511.5).max(axis=1) > 512)
    # body_vectors rebuilds the same directions.
    v_b, head = s.body_vectors(xy)
    np.testing.assert_allclose(v_b, v_body_truth, atol=1e-12)


def test_fuse_rejects_head_beyond_the_main_horizon():
    s = MultiFovSensor.two_heads(paper001_head(), 100.0)
    assert list(s.fusable) == [True, False]
    with pytest.raises(ValueError, match=r"heads\[1\] cannot be fused"):
        s.fuse([np.array([[500.0, 500.0]]), np.array([[10.0, 10.0]])])
    # The body directions (what the matcher uses) still work.
    v, h = s.body_vectors([np.array([[500.0, 500.0]]), np.array([[10.0, 10.0]])])
    assert v.shape == (2, 3) and list(h) == [0, 1]


def test_visible_counts_against_brute_force_projection(sensor45, cat):
    rng = np.random.default_rng(1)
    q = quat_random(rng, 40)
    counts = sensor45.count_visible(q, cat, [5.0, 6.0])
    for n in range(len(q)):
        r_b2i = quat_to_matrix(q[n])
        view = sensor45.view(q[n], cat)
        for k, cam in enumerate(sensor45.heads):
            # Independent truth: every catalog star, through the camera model, no cone search.
            v_cam = cat.vectors @ (r_b2i @ cam.r_cam_to_body)
            xy, inf = cam.project(v_cam)
            expected = np.flatnonzero(inf)
            assert sorted(view.star_index[k]) == sorted(expected)
            np.testing.assert_allclose(view.xy[k], xy[view.star_index[k]], atol=1e-9)
            assert counts[n, 1, k] == len(expected)
            assert counts[n, 0, k] == np.sum(cat.vmag[expected] <= 5.0)
        assert view.n_fused == view.counts.sum()


# ----------------------------------------------------------------------------------------- bad input
def test_bad_sensors():
    cam = paper001_head()
    with pytest.raises(ValueError, match="point the same way"):
        MultiFovSensor((cam, cam.with_mounting(cam.q_cam_to_body)))
    with pytest.raises(ValueError, match="overlap"):
        MultiFovSensor.two_heads(cam, 6.0)  # 5°×5° heads: half-diagonals 3.54° + 3.54° > 6°
    assert MultiFovSensor.two_heads(cam, 6.0, allow_overlap=True).n_heads == 2
    with pytest.raises(TypeError):
        MultiFovSensor(cam)
    with pytest.raises(TypeError):
        MultiFovSensor((cam, "head"))
    with pytest.raises(ValueError, match="installation_angle_deg"):
        MultiFovSensor.two_heads(cam, 0.0)


def test_bad_installation_matrices():
    good = np.eye(3)
    singular = np.diag([1.0, 1.0, 0.0])
    with pytest.raises(ValueError, match=r"installation_matrices\[1\] is singular"):
        installation_quaternions([good, singular])
    with pytest.raises(ValueError, match=r"installation_matrices\[0\] is a reflection"):
        installation_quaternions([np.diag([1.0, 1.0, -1.0])])
    with pytest.raises(ValueError, match="not orthonormal"):
        installation_quaternions([good * 1.1])
    with pytest.raises(ValueError, match=r"shape \(K, 3, 3\)"):
        installation_quaternions(np.eye(3))
    with pytest.raises(ValueError, match="singular"):
        MultiFovSensor.from_installation_matrices(paper001_head(), [good, singular])


def test_bad_matcher_inputs(matcher45, sensor45):
    with pytest.raises(ValueError, match="xy_per_head"):
        matcher45.identify([np.zeros((3, 2))])  # one array for two heads
    with pytest.raises(ValueError, match="both"):
        matcher45.identify([np.zeros((0, 2)), np.zeros((0, 2))], q_ins_body_to_icrs=[1, 0, 0, 0])
    with pytest.raises(ValueError, match="positive semi-definite"):
        matcher45.identify([np.zeros((0, 2))] * 2, [1, 0, 0, 0], -np.eye(3))
    with pytest.raises(ValueError, match="NaN"):
        matcher45.identify([np.array([[np.nan, 1.0]]), np.zeros((0, 2))])
    with pytest.raises(ValueError, match="sigma_px"):
        InertialAidedMatcher(sensor45, matcher45.catalog, sigma_px=0.0)
    with pytest.raises(ValueError, match="n_sigma"):
        predict_scopes(sensor45, [1, 0, 0, 0], 1e-6, n_sigma=0.0)
    # Too few stars is a status, not an exception.
    r = matcher45.identify([np.array([[100.0, 100.0]]), np.array([[200.0, 300.0]])], [1, 0, 0, 0], 1e-6)
    assert not r.success and "fewer than 3" in r.status and list(r.star_ids) == [-1, -1]


# ----------------------------------------------------------------------------------------- INS prediction
def test_bias_angle_exact_and_linear_bound(sensor45):
    rng = np.random.default_rng(2)
    q = quat_random(rng, 200)
    mu = rng.normal(0, 0.3, (200, 3))
    alpha = los_bias_angles(sensor45, mu, q)
    los = np.einsum("nij,kj->nki", quat_to_matrix(q), sensor45.boresights_body)
    los_ins = np.einsum("nij,nkj->nki", quat_to_matrix(quat_from_rotvec(mu)), los)
    direct = np.arccos(np.clip(np.sum(los * los_ins, axis=-1), -1, 1))
    np.testing.assert_allclose(alpha, direct, atol=1e-7)
    linear = np.linalg.norm(np.cross(mu[:, None, :], los), axis=-1)
    assert np.all(alpha <= linear + 1e-12)  # eq. 12's linear value bounds the exact angle
    small = los_bias_angles(sensor45, mu * 1e-4, q)
    np.testing.assert_allclose(small, linear * 1e-4, rtol=1e-6)


def test_error_radius_is_cross_los_sigma(sensor45):
    q = quat_from_rotvec([0.2, -0.1, 0.3])
    sig = np.radians(0.5)
    scopes = predict_scopes(sensor45, q, sig**2, n_sigma=5.0)
    for s in scopes:
        assert s.error_radius_rad == pytest.approx(5 * sig, rel=1e-12)
        assert s.catalog_radius_rad == pytest.approx(s.fov_radius_rad + 5 * sig)  # eq. 14
    # An error only about head 0's LoS (a roll of that head) moves no LoS of head 0: zero error radius.
    l0 = scopes[0].los_icrs
    scopes = predict_scopes(sensor45, q, np.outer(l0, l0) * sig**2)
    assert scopes[0].error_radius_rad < 1e-6 * sig  # sqrt of a rounding-level eigenvalue
    assert scopes[1].error_radius_rad == pytest.approx(5 * sig * np.sin(np.radians(45)), rel=1e-9)


def test_part_catalog_holds_every_visible_star_when_error_radius_is_honest(sensor45, cat):
    """Eq. 15 with an honest covariance: truly visible stars are always in their head's part catalog."""
    rng = np.random.default_rng(3)
    missed_without_radius = 0
    for trial in range(240):
        sig = np.radians([0.01, 0.3, 2.0, 8.0][trial % 4])
        q = quat_random(rng)
        q_ins, mu = ins_attitude(rng, q, sig)
        view = sensor45.view(q, cat)
        local = LocalCatalog.build(cat, sensor45, predict_scopes(sensor45, q_ins, sig**2, n_sigma=5.0))
        for k in range(2):
            assert np.all(np.isin(view.star_index[k], local.star_sets[k])), (trial, k)
        # Control: with no error radius (the paper's small-bias assumption) stars are lost once the bias grows.
        bare = LocalCatalog.build(cat, sensor45, predict_scopes(sensor45, q_ins, 0.0))
        missed_without_radius += sum(int(np.sum(~np.isin(view.star_index[k], bare.star_sets[k]))) for k in range(2))
    assert missed_without_radius > 50


def test_pair_tables_equal_brute_force(sensor45, cat):
    rng = np.random.default_rng(4)
    q = quat_random(rng)
    local = LocalCatalog.build(cat, sensor45, predict_scopes(sensor45, q, np.radians(1.5) ** 2), margin_rad=1e-4)
    v = cat.vectors
    hd = sensor45.half_diagonal_fov_rad
    theta = sensor45.installation_angles_rad[0, 1]
    for (k, l), table in local.tables.items():
        a, b = np.meshgrid(local.star_sets[k], local.star_sets[l], indexing="ij")
        a, b = a.ravel(), b.ravel()
        ang = np.arccos(np.clip(np.sum(v[a] * v[b], axis=1), -1, 1))
        if k == l:
            keep = (a != b) & (ang <= 2 * hd[k] + 1e-4)
        else:
            keep = (ang >= theta - hd[k] - hd[l] - 1e-4) & (ang <= theta + hd[k] + hd[l] + 1e-4)
        assert set(zip(table.first.tolist(), table.second.tolist())) == set(zip(a[keep].tolist(), b[keep].tolist()))
        assert np.all(np.diff(table.angle_rad) >= 0)
        # k-vector range search = brute-force range search.
        d = float(np.median(table.angle_rad))
        _, rows = table.query_many(d - 1e-3, d + 1e-3)
        assert sorted(rows.tolist()) == np.flatnonzero(np.abs(table.angle_rad - d) <= 1e-3).tolist()
        _, rows_scan = table.query_many(d - 1e-3, d + 1e-3, search="scan")
        assert sorted(rows_scan.tolist()) == sorted(rows.tolist())
    assert local.n_stars < 0.05 * len(cat)


# ----------------------------------------------------------------------------------------- INS error model
def test_attitude_error_of_a_constant_drift():
    t = np.arange(0.0, 101.0)
    q = np.tile(quat_from_rotvec([0.3, 0.2, -0.1]), (len(t), 1))
    eps = np.tile([1e-5, -2e-5, 3e-5], (len(t), 1))
    mu = propagate_attitude_error(t, q, eps)
    np.testing.assert_allclose(mu[-1], -quat_to_matrix(q[0]) @ eps[0] * 100.0, rtol=1e-12)


def test_attitude_sigma_bound_matches_and_bounds_monte_carlo():
    from startracker.imu import Gyro

    spec = gyro_preset("paper001-cond2", rate_hz=1.0)
    t = np.arange(0.0, 2001.0)
    rng = np.random.default_rng(5)
    still = np.tile([1.0, 0, 0, 0], (len(t), 1))
    spin = quat_from_rotvec(np.outer(t * 1e-3, [0.0, 0.6, 0.8]))  # 0.06 °/s about a fixed axis
    ends = {"still": [], "spin": []}
    for _ in range(300):
        g = Gyro(spec, rng)
        drift = g.measure(np.zeros((len(t), 3)), rng)
        for name, q in (("still", still), ("spin", spin)):
            ends[name].append(propagate_attitude_error(t, q, drift)[-1])
    bound = attitude_sigma_bound_rad(spec, t[-1])
    sd_still = np.std(np.array(ends["still"]), axis=0)
    sd_spin = np.std(np.array(ends["spin"]), axis=0)
    np.testing.assert_allclose(sd_still, bound, rtol=0.15)  # reached without rotation
    assert np.all(sd_spin <= bound * 1.12)
    with pytest.raises(TypeError):
        attitude_sigma_bound_rad("paper001-cond2", 10.0)
    assert attitude_sigma_bound_rad(GyroSpec(), 100.0, initial_sigma_rad=1e-5) == pytest.approx(1e-5)


# ----------------------------------------------------------------------------------------- matching
def test_result_has_the_identification_result_fields(matcher45):
    assert issubclass(MultiFovResult, IdentificationResult)
    names = [f.name for f in fields(MultiFovResult)]
    assert names[:8] == ["success", "star_ids", "q_cam_to_icrs", "n_matched", "residual_arcsec", "latency_ms",
                         "status", "method"]
    for extra in ("star_ids_per_head", "q_body_to_icrs", "fallback_all_sky"):
        assert extra in names


def test_matcher_identifies_random_scenes_and_is_never_wrong(sensor45, matcher45, cat):
    rng = np.random.default_rng(6)
    n_ok = n_3plus = 0
    for trial in range(120):
        q = quat_random(rng)
        xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX)
        sig = np.radians([0.01, 0.5, 3.0][trial % 3])
        q_ins, _ = ins_attitude(rng, q, sig)
        r = matcher45.identify(xy, q_ins, sig**2)
        truth = truth_hips(cat, idx)
        n_3plus += len(truth) >= 3
        if r.success:
            assert np.all(r.star_ids == truth), (trial, r.status)
            assert r.method == "multifov-local" and not r.fallback_all_sky
            err = np.degrees(quat_angle_between(r.q_body_to_icrs, q)) * 3600
            assert err < max(10.0, 6 * np.degrees(np.sqrt(np.linalg.eigvalsh(r.covariance_rad2)[-1])) * 3600)
            # q_cam_to_icrs is the main head's attitude.
            q_cam = quat_multiply(q, np.asarray(sensor45.heads[0].q_cam_to_body))
            assert np.degrees(quat_angle_between(r.q_cam_to_icrs, q_cam)) * 3600 == pytest.approx(err, abs=1e-3)
            n_ok += 1
    assert n_ok >= 0.97 * n_3plus and n_3plus > 90


def test_cross_fov_patterns_no_head_alone_could_match(sensor45, matcher45, cat):
    """Scenes with 2 + 1 stars: no head has a triangle, the fused FoV does (paper 001 Fig. 18c-d)."""
    rng = np.random.default_rng(7)
    main_only = InertialAidedMatcher(MultiFovSensor((sensor45.heads[0],)), cat, sigma_px=SIGMA_PX)
    found = 0
    while found < 8:
        q = quat_random(rng)
        counts = sensor45.view(q, cat).counts
        if sorted(counts.tolist()) != [1, 2]:
            continue
        found += 1
        xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX)
        q_ins, _ = ins_attitude(rng, q, np.radians(0.2))
        r = matcher45.identify(xy, q_ins, np.radians(0.2) ** 2)
        assert r.success, r.status
        assert np.all(r.star_ids == truth_hips(cat, idx)) and r.n_matched == 3
        assert [len(s) for s in r.star_ids_per_head] == counts.tolist()
        single = main_only.identify([xy[0]], q_ins, np.radians(0.2) ** 2)
        assert not single.success


def test_three_heads_one_star_each():
    """A triangle made only of cross-FoV distances: one star in each of three heads."""
    cat = select_navigation_stars(load_catalog(6.0), min_separation_rad=np.radians(60 / 3600))
    s = three_head_sensor()
    m = InertialAidedMatcher(s, cat, sigma_px=SIGMA_PX)
    rng = np.random.default_rng(8)
    found = 0
    while found < 5:
        q = quat_random(rng)
        if s.view(q, cat).counts.tolist() != [1, 1, 1]:
            continue
        found += 1
        xy, idx = s.observe(q, cat, rng, SIGMA_PX)
        q_ins, _ = ins_attitude(rng, q, np.radians(0.1))
        r = m.identify(xy, q_ins, np.radians(0.1) ** 2)
        assert r.success, r.status
        assert np.all(r.star_ids == truth_hips(cat, idx))
        assert set(r.scopes[0].__dict__) >= {"los_icrs", "error_radius_rad", "catalog_radius_rad"}


def test_false_stars_and_dishonest_ins_never_give_a_wrong_success(sensor45, matcher45, cat):
    rng = np.random.default_rng(9)
    n_ok = 0
    for trial in range(90):
        q = quat_random(rng)
        xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX)
        truth = [cat.hip[i] for i in idx]
        for k in range(2):  # up to two false stars per head
            nf = int(rng.integers(0, 3))
            xy[k] = np.vstack([xy[k], rng.uniform(0, 1023, (nf, 2))])
            truth[k] = np.concatenate([truth[k], -np.ones(nf, np.int64)])
        truth = np.concatenate(truth)
        claimed = np.radians(0.1)
        true_sig = np.radians(0.1 if trial % 2 else 4.0)  # every other frame the INS is far off its claim
        q_ins, _ = ins_attitude(rng, q, true_sig)
        for r in (matcher45.identify(xy, q_ins, claimed**2), matcher45.identify(xy)):
            if r.success:
                assert np.all((r.star_ids == truth) | (r.star_ids == -1)), (trial, r.status)
                assert np.all(r.star_ids[truth < 0] == -1)
                n_ok += 1
    assert n_ok > 60


def test_fallbacks_are_reported(sensor45, cat):
    rng = np.random.default_rng(10)
    m = InertialAidedMatcher(sensor45, cat, sigma_px=SIGMA_PX, max_error_radius_deg=20.0, retry_all_sky=True)
    while True:
        q = quat_random(rng)
        if sensor45.view(q, cat).n_fused >= 6:
            break
    xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX)
    truth = truth_hips(cat, idx)
    # INS error radius beyond the limit: all-sky, said so.
    r = m.identify(xy, q, np.radians(5.0) ** 2)
    assert r.fallback_all_sky and r.method == "multifov-allsky"
    assert "all-sky fallback: INS error radius" in r.status and "ins error exceeds fov" in r.status
    assert r.success and np.all(r.star_ids == truth)
    # INS wrong by 10° while claiming 0.05°: the part catalog misses, the all-sky retry finds it.
    q_bad = quat_multiply(quat_from_rotvec(np.radians([10.0, 0.0, 0.0])), q)
    r = m.identify(xy, q_bad, np.radians(0.05) ** 2)
    assert r.fallback_all_sky and "part catalog failed" in r.status
    assert r.success and np.all(r.star_ids == truth)
    # Without the retry the same frame fails (never a wrong attitude).
    r = InertialAidedMatcher(sensor45, cat, sigma_px=SIGMA_PX).identify(xy, q_bad, np.radians(0.05) ** 2)
    assert not r.success and r.method == "multifov-local"
    # Error radius larger than the FoV but under the limit: widened part catalog, flagged.
    r = m.identify(xy, q, np.radians(1.5) ** 2)
    assert r.method == "multifov-local" and "ins error exceeds fov" in r.status and r.success


def test_part_catalog_is_much_smaller_than_all_sky(matcher45, sensor45, cat):
    rng = np.random.default_rng(11)
    q = quat_random(rng)
    local = matcher45.local_catalog(matcher45.predict_scopes(q, np.radians(0.05) ** 2))
    allsky = matcher45.all_sky_catalog
    assert allsky.n_stars == len(cat)
    assert local.n_stars * 100 < allsky.n_stars and local.n_pairs * 1000 < allsky.n_pairs
    assert isinstance(local.scopes[0], ObservedScope) and allsky.scopes is None
