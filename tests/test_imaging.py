"""Pixels: photometry, PSF and smear, detector noise, stray light, false objects, sparse vs full frame."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree

from startracker.centroid import detections_from_sparse, extract_centroids, simulate_detections
from startracker.imaging import (
    KIND_DEBRIS,
    KIND_STAR,
    FalseObjects,
    SensorModel,
    background_field,
    draw_false_objects,
    fixed_pattern,
    render_expected,
    render_frame,
    render_sparse,
)
from startracker.optics import Camera, camera_preset
from startracker.photometry import Photometry
from startracker.scene import BrightBody, ExposurePlan, compute_scene, scene_from_tracks
from startracker.catalog import load_catalog

SMALL = Camera(resolution=(128, 128))


def quiet(model, **kw):
    """No false objects, no fixed pattern: only the physics under test."""
    base = dict(hot_pixel_fraction=0.0, cosmic_ray_rate_per_cm2_s=0.0, debris_rate_per_frame=0.0, prnu_sigma=0.0)
    base.update(kw)
    return dataclasses.replace(model, **base)


# ------------------------------------------------------------------------------------- photometry
def test_photometry_zero_point_and_pogson():
    ph = Photometry(aperture_diameter_mm=20.0, bandwidth_nm=300.0, transmission=0.8, quantum_efficiency=0.5)
    area_cm2 = np.pi * 1.0**2
    assert ph.pe_per_s_at_v0 == pytest.approx(1.0e4 * 300.0 * area_cm2 * 0.8 * 0.5)
    r = ph.pe_rate([0.0, 5.0, 2.5])
    assert r[0] / r[1] == pytest.approx(100.0)
    assert r[0] / r[2] == pytest.approx(10.0)
    assert ph.magnitude_of_rate(r)[1] == pytest.approx(5.0)
    # a 1 arcsec² pixel sees a surface of m mag/arcsec² like a star of magnitude m
    f_mm = 5.5e-3 * 180 * 3600 / np.pi  # focal length giving 1 arcsec pixels of 5.5 µm
    assert ph.surface_pe_rate_per_px(20.0, 5.5, f_mm) == pytest.approx(ph.pe_rate([20.0])[0])
    with pytest.raises(ValueError):
        Photometry(quantum_efficiency=1.5)


@pytest.mark.parametrize("preset", ["paper000", "paper000_cmos"])
def test_total_signal_matches_photometry(preset):
    """Summed expected charge of a spot (still, smeared, multi-exposure) = G · rate(V) · τ."""
    model = quiet(SensorModel.preset(preset))
    plan = ExposurePlan(3, 2e-3, frame_period_s=0.1)
    sc = scene_from_tracks(SMALL, plan, [[40.3, 50.7], [90.2, 80.9]], [4.0, 5.5], [[0.0, 0.0], [600.0, 200.0]])
    img = render_expected(sc, model, include_background=False)
    rate = model.photometry.pe_rate([4.0, 5.5])
    expected_total = model.intensifier_gain * rate.sum() * 2e-3 * 3
    assert img.sum() == pytest.approx(expected_total, rel=1e-6)
    # the still star alone (a 25 px box around it)
    assert img[38:63, 28:53].sum() == pytest.approx(model.intensifier_gain * rate[0] * 2e-3 * 3, rel=1e-6)


def test_mean_of_noisy_frames_matches_expected_charge():
    """The noise model is unbiased: E[(DN − bias) · gain] = expected charge (no clipping in play)."""
    rng = np.random.default_rng(0)
    for model in (quiet(SensorModel.preset("paper000")), quiet(SensorModel.preset("paper000_cmos"))):
        plan = ExposurePlan(2, 2e-3, frame_period_s=0.1)
        sc = scene_from_tracks(SMALL, plan, [[64.2, 63.6]], [5.0], [[500.0, 0.0]])
        expected = render_expected(sc, model)[50:78, 50:78].sum()
        sums = [((render_frame(sc, model, rng)[50:78, 50:78] - model.bias_dn) * model.gain_e_per_dn).sum()
                for _ in range(300)]
        se = np.std(sums) / np.sqrt(len(sums))
        assert abs(np.mean(sums) - expected) < 4 * se + 0.002 * expected


@pytest.mark.parametrize("preset", ["paper000", "paper000_cmos"])
def test_dark_frame_level_and_noise(preset):
    model = quiet(SensorModel.preset(preset), dark_current_e_per_s=200.0)
    plan = ExposurePlan(5, 1e-3, frame_period_s=0.1)
    sc = scene_from_tracks(Camera(resolution=(512, 512)), plan, np.zeros((0, 2)), np.zeros(0))
    bg = background_field(sc, model)
    img = render_frame(sc, model, np.random.default_rng(1))
    g = model.gain_e_per_dn
    assert img.mean() == pytest.approx(bg.mean_dn(0, 0), abs=0.02)
    assert img.std() == pytest.approx(bg.sigma_dn(0, 0), rel=0.01)
    # the variance budget by hand: shot (gain G F² c for light through an intensifier) + dark + read
    q = bg.gain * bg.optical_pe(0, 0)
    var_e = model.intensifier_gain * model.excess_noise_factor**2 * model.splash_energy * q + 200.0 * plan.integration_window_s + model.read_noise_e**2
    assert bg.sigma_dn(0, 0) == pytest.approx(np.sqrt(var_e / g**2 + 1 / 12), rel=1e-9)
    assert np.all(img == np.rint(img))


def test_smear_profile_second_moments():
    """A streak of length L has along-track variance σ² + 1/12 + L²/12 and cross-track σ² + 1/12."""
    model = quiet(SensorModel.preset("paper000_cmos"), psf_sigma_px=1.2)
    cam = Camera(resolution=(256, 256))
    plan = ExposurePlan(1, 0.01, frame_period_s=0.1)
    sc = scene_from_tracks(cam, plan, [[128.3, 127.6]], [3.0], [[600.0, 800.0]])  # L = 10 px
    img = render_expected(sc, model, include_background=False)
    rows, cols = np.indices(img.shape)
    w = img / img.sum()
    mx, my = (w * cols).sum(), (w * rows).sum()
    assert mx == pytest.approx(128.3, abs=1e-6) and my == pytest.approx(127.6, abs=1e-6)
    u = np.array([0.6, 0.8])
    d_al = (cols - mx) * u[0] + (rows - my) * u[1]
    d_cr = -(cols - mx) * u[1] + (rows - my) * u[0]
    # sub-spots σ/2 apart stand in for the continuous streak: along-track variance short by at most σ²/48
    assert (w * d_al**2).sum() == pytest.approx(1.44 + 1 / 12 + 100 / 12, abs=1.44 / 48)
    assert (w * d_cr**2).sum() == pytest.approx(1.44 + 1 / 12, rel=2e-3)


def test_saturation_and_adc_range():
    model = quiet(SensorModel.preset("paper000"))
    sc = scene_from_tracks(SMALL, ExposurePlan(1, 5e-3), [[64.0, 64.0]], [-1.0])
    img = render_frame(sc, model, np.random.default_rng(2))
    assert img.max() == model.saturation_dn == 4095.0
    assert img.min() >= 0 and np.all(img == np.rint(img))
    c = extract_centroids(img, saturation_dn=model.saturation_dn)
    assert c.saturated[0] and np.allclose(c.xy[0], [64.0, 64.0], atol=0.1)
    m8 = dataclasses.replace(model, adc_bits=8, bias_dn=10.0)
    assert render_frame(sc, m8, np.random.default_rng(2)).max() == 255.0


def test_fixed_pattern_is_a_property_of_the_detector():
    model = SensorModel(hot_pixel_fraction=1e-3, cosmic_ray_rate_per_cm2_s=0.0, debris_rate_per_frame=0.0)
    cam = Camera(resolution=(200, 100))
    p1, hot1, rate1 = fixed_pattern(model, cam.resolution)
    p2, hot2, _ = fixed_pattern(dataclasses.replace(model), cam.resolution)
    np.testing.assert_array_equal(hot1, hot2)
    np.testing.assert_array_equal(p1, p2)
    assert np.std(p1) == pytest.approx(0.01, rel=0.05)
    assert 5 <= len(hot1) <= 40
    plan = ExposurePlan(1, 0.05, frame_period_s=0.1)
    sc = scene_from_tracks(cam, plan, np.zeros((0, 2)), np.zeros(0))
    frames = np.stack([render_frame(sc, model, np.random.default_rng(s)) for s in range(20)])
    bg = background_field(sc, model)
    level = frames.reshape(20, -1)[:, hot1].mean(axis=0)
    np.testing.assert_allclose(level, bg.mean_dn(0, 0) + np.minimum(rate1 * 0.05, 15000) / model.gain_e_per_dn, rtol=0.05, atol=2.0)


def test_same_seed_same_frame():
    model = SensorModel()
    sc = scene_from_tracks(SMALL, ExposurePlan(3, 1e-3), [[30.0, 40.0]], [4.0], [[2000.0, 0.0]])
    a = render_frame(sc, model, np.random.default_rng(9))
    b = render_frame(sc, model, np.random.default_rng(9))
    np.testing.assert_array_equal(a, b)
    sa = simulate_detections(sc, model, np.random.default_rng(9), "pixel")
    sb = simulate_detections(sc, model, np.random.default_rng(9), "pixel")
    np.testing.assert_array_equal(sa.xy, sb.xy)


# ------------------------------------------------------------------------------------- stray light
def test_stray_light_raises_a_gradient_toward_the_sun_and_blinds_inside_exclusion():
    cam = camera_preset("paper000")
    cat = load_catalog(5.0)
    model = SensorModel()
    att = lambda t: np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))  # noqa: E731
    plan = ExposurePlan(15, 1e-3)
    no_sun = background_field(compute_scene(cam, cat, att, plan, 0.0), model)
    a = np.radians(40.0)
    sun = BrightBody("sun", (np.sin(a), 0.0, np.cos(a)))  # toward +x, i.e. increasing column
    sc = compute_scene(cam, cat, att, plan, 0.0, bright_bodies=[sun])
    bg = background_field(sc, model)
    assert not bg.blinded
    assert bg.mean_dn(1023.5, 1023.5) > no_sun.mean_dn(1023.5, 1023.5) + 5
    assert bg.mean_dn(2047, 1023.5) > bg.mean_dn(0, 1023.5)
    assert bg.mean_dn(1023.5, 0) == pytest.approx(bg.mean_dn(1023.5, 2047))
    img = render_frame(sc, model, np.random.default_rng(0))
    assert img[:, 1900:].mean() > img[:, :150].mean()
    # the sun 3° off the boresight: deep inside the 30° exclusion cone, the frame washes out
    a = np.radians(3.0)
    sc = compute_scene(cam, cat, att, plan, 0.0, bright_bodies=[BrightBody("sun", (np.sin(a), 0.0, np.cos(a)))])
    assert background_field(sc, model).blinded
    img = render_frame(sc, model, np.random.default_rng(0))
    assert np.all(img == model.saturation_dn)
    assert len(extract_centroids(img, saturation_dn=model.saturation_dn)) == 0
    for fidelity in ("pixel", "centroid"):
        assert len(simulate_detections(sc, model, np.random.default_rng(0), fidelity)) == 0
    with pytest.raises(ValueError):
        background_field(compute_scene(cam, cat, att, plan, 0.0, bright_bodies=[BrightBody("jupiter", (1, 0, 0))]), model)


# ------------------------------------------------------------------------------------- false objects
def test_cosmic_ray_rate():
    model = SensorModel(cosmic_ray_rate_per_cm2_s=50.0)
    cam = camera_preset("paper000")
    sc = scene_from_tracks(cam, ExposurePlan(10, 1e-3), np.zeros((0, 2)), np.zeros(0))
    rng = np.random.default_rng(0)
    counts = [len(draw_false_objects(sc, model, rng).cosmic_e) for _ in range(400)]
    area_cm2 = (2048 * 5.5e-4) ** 2
    expected = 50.0 * area_cm2 * sc.plan.integration_window_s
    assert np.mean(counts) == pytest.approx(expected, abs=4 * np.sqrt(expected / 400))


def test_debris_leaves_one_dash_per_exposure():
    model = quiet(SensorModel())
    cam = Camera(resolution=(512, 512))
    plan = ExposurePlan(5, 1e-3, frame_period_s=0.1)
    sc = scene_from_tracks(cam, plan, np.zeros((0, 2)), np.zeros(0))
    fo = FalseObjects(np.array([[256.0, 256.0]]), np.array([[1500.0, -500.0]]), np.array([3.0]),
                      np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    det = detections_from_sparse(render_sparse(sc, model, np.random.default_rng(0), false_objects=fo, draw_crossings=False))
    deb = det.subset(det.truth_kind == KIND_DEBRIS)
    assert len(deb) == 5
    order = np.argsort(deb.truth_exposure)
    steps = np.diff(deb.xy[order], axis=0)
    np.testing.assert_allclose(steps, np.tile([1500.0 * 0.02, -500.0 * 0.02], (4, 1)), atol=0.5)


# ------------------------------------------------------------------------------------- sparse vs full frame
def test_sparse_and_full_frame_detection_statistics_agree():
    """Same scene, same model: detections per frame (stars, false) and centroid errors agree within MC error.

    The threshold is put half-way between two DN levels: on quantised data only its integer part matters,
    and the full-frame path estimates it from the image while the sparse path knows it.
    """
    cam = Camera(resolution=(512, 512))
    # no debris here (a rare bright streak makes the per-frame counts heavy-tailed; debris has its own test)
    model = dataclasses.replace(SensorModel(), hot_pixel_fraction=2e-5, cosmic_ray_rate_per_cm2_s=20.0,
                                debris_rate_per_frame=0.0)
    plan = ExposurePlan(5, 1e-3, frame_period_s=0.1)
    rng = np.random.default_rng(11)
    xy = rng.uniform(30, 480, (12, 2))
    vmag = rng.uniform(5.0, 7.3, 12)
    sc = scene_from_tracks(cam, plan, xy, vmag, np.tile([1500.0, 600.0], (12, 1)))
    bg = background_field(sc, model)
    k = (np.floor(bg.threshold_dn(0, 0, 5.0)) + 0.5 - bg.mean_dn(0, 0)) / bg.sigma_dn(0, 0)
    truth = sc.xy_mean.reshape(-1, 2)
    faint = np.tile(vmag, plan.n_exposures) > 6.5
    stats = {"full": [], "sparse": []}
    for _ in range(70):
        img = render_frame(sc, model, rng)
        full = extract_centroids(img, k_sigma=k, saturation_dn=model.saturation_dn)
        sparse = simulate_detections(sc, model, rng, "pixel", k_sigma=k)
        for name, c in (("full", full), ("sparse", sparse)):
            d, i = cKDTree(truth).query(c.xy, distance_upper_bound=2.0)
            ok = np.isfinite(d)
            found = np.zeros(len(truth), dtype=bool)
            found[i[ok]] = True
            stats[name].append((found.sum(), found[faint].sum(), len(c) - ok.sum(), np.sum(d[ok] ** 2), ok.sum()))
    f = np.array(stats["full"], dtype=float)
    s = np.array(stats["sparse"], dtype=float)
    for j in range(3):  # stars found, faint stars found, false detections per frame
        se = np.hypot(f[:, j].std(), s[:, j].std()) / np.sqrt(len(f))
        assert abs(f[:, j].mean() - s[:, j].mean()) < 3.5 * se + 0.02, (j, f[:, j].mean(), s[:, j].mean())
    rms_f = np.sqrt(f[:, 3].sum() / f[:, 4].sum())
    rms_s = np.sqrt(s[:, 3].sum() / s[:, 4].sum())
    assert rms_s == pytest.approx(rms_f, rel=0.08)


def test_sparse_frame_truth_labels_point_at_the_right_spots():
    cam = Camera(resolution=(512, 512))
    model = SensorModel()
    plan = ExposurePlan(4, 1e-3, frame_period_s=0.1)
    rng = np.random.default_rng(5)
    sc = scene_from_tracks(cam, plan, rng.uniform(30, 480, (10, 2)), rng.uniform(3, 5, 10), np.tile([2000.0, 0.0], (10, 1)))
    det = simulate_detections(sc, model, rng, "pixel")
    st = det.truth_kind == KIND_STAR
    assert st.sum() >= 0.95 * sc.visible.sum()
    err = det.xy[st] - sc.xy_mean[det.truth_exposure[st], det.truth_star[st]]
    assert np.max(np.linalg.norm(err, axis=1)) < 2.0
    np.testing.assert_allclose(det.truth_xy[st], sc.xy_mean[det.truth_exposure[st], det.truth_star[st]])


# ------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kw",
    [
        dict(psf_sigma_px=0.0),
        dict(psf_sigma_px=float("nan")),
        dict(read_noise_e=-1.0),
        dict(excess_noise_factor=0.5),
        dict(adc_bits=40),
        dict(adc_bits=12.5),
        dict(gain_e_per_dn=0.0),
        dict(prnu_sigma=0.9),
        dict(intensifier_splash_sigma_px=3.0),
        dict(debris_vmag_range=(7.0, 3.0)),
    ],
)
def test_bad_sensor_models(kw):
    with pytest.raises((ValueError, TypeError)):
        SensorModel(**kw)


def test_bad_render_arguments():
    sc = scene_from_tracks(SMALL, ExposurePlan(1, 1e-3), [[10.0, 10.0]], [5.0])
    with pytest.raises(TypeError):
        render_frame(sc, SensorModel(), 42)
    with pytest.raises(TypeError):
        render_frame("scene", SensorModel(), np.random.default_rng(0))
    with pytest.raises(ValueError):
        render_sparse(sc, SensorModel(), np.random.default_rng(0), k_sigma=-1.0)
    with pytest.raises(ValueError):
        SensorModel.preset("hubble")
