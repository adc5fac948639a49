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
from startracker.rotations import quat_random

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


def test_quiet_sky_background_is_the_sky_every_frame_and_a_bright_body_still_counts():
    """The background of frames without bright bodies (computed once per camera, plan and model) is the sky's
    surface brightness over the open time at every attitude and time; a sun in between raises that frame's
    background only, and the next quiet frame is back to the sky."""
    cam = camera_preset("paper000")
    cat = load_catalog(5.0)
    model = SensorModel()
    plan = ExposurePlan(7, 1e-3)
    sky_pe = model.photometry.surface_pe_rate_per_px(model.sky_mag_per_arcsec2, cam.pixel_size_um,
                                                     cam.focal_length_mm) * 7 * 1e-3
    a = np.radians(40.0)
    sun = BrightBody("sun", (np.sin(a), 0.0, np.cos(a)))
    rng = np.random.default_rng(4)
    for k in range(4):
        q = quat_random(rng)
        sc = compute_scene(cam, cat, lambda t: np.tile(q, (len(t), 1)), plan, 0.3 * k)
        bg = background_field(sc, model)
        assert bg.flat and not bg.blinded
        assert bg.opt0 == pytest.approx(sky_pe, rel=1e-12)
        assert bg.dark_e == pytest.approx(model.dark_current_e_per_s * plan.integration_window_s, rel=1e-12)
        lit = background_field(compute_scene(cam, cat, lambda t: np.tile([1.0, 0, 0, 0], (len(t), 1)), plan, 0.3 * k,
                                             bright_bodies=[sun]), model)
        assert lit.opt0 > 2 * sky_pe and not lit.flat
    other = dataclasses.replace(model, sky_mag_per_arcsec2=model.sky_mag_per_arcsec2 - 2.5)  # 10× brighter sky
    assert background_field(sc, other).opt0 == pytest.approx(10 * sky_pe, rel=1e-9)



def test_background_at_the_principal_point_and_star_electrons_as_the_formulas_give():
    """The field's cached values at the principal point follow the noise model written out (shot through the
    intensifier, dark, read, PRNU; DN with bias and 1/12 DN² quantisation), for a field with a gradient (a sun
    in view); a frame's star electrons, unchecked (the per-frame path), are the photometry formula
    ``rate0 · 10^(−0.4 (V + c (B−V))) · τ``, as the checked call gives them."""
    cam = camera_preset("paper000")
    cat = load_catalog(5.0)
    model = SensorModel()
    plan = ExposurePlan(7, 1e-3)
    a = np.radians(40.0)
    sc = compute_scene(cam, cat, lambda t: np.tile([1.0, 0, 0, 0], (len(t), 1)), plan, 0.0,
                       bright_bodies=[BrightBody("sun", (np.sin(a), 0.0, np.cos(a)))])
    bg = background_field(sc, model)
    assert not bg.flat
    q = bg.gain * bg.opt0  # at (cx, cy) the plane is opt0
    var = bg.enf2_c * q + bg.dark_e + bg.read_var_e2 + (bg.prnu_sigma * q) ** 2
    assert bg.var_e_centre == pytest.approx(var, rel=1e-12)
    assert bg.mean_dn_centre == pytest.approx((q + bg.dark_e) / bg.gain_e_per_dn + bg.bias_dn, rel=1e-12)
    assert bg.sigma_dn_centre == pytest.approx(np.sqrt(var / bg.gain_e_per_dn**2 + 1 / 12), rel=1e-12)
    quiet = compute_scene(cam, cat, lambda t: np.tile([1.0, 0, 0, 0], (len(t), 1)), plan, 0.0)
    ph = model.photometry
    expected = ph.pe_per_s_at_v0 * 10.0 ** (-0.4 * (quiet.vmag + ph.color_term_per_bv * quiet.bv)) * 2e-3
    for validate in (True, False):
        np.testing.assert_allclose(model.star_pe(quiet.vmag, quiet.bv, 2e-3, validate=validate), expected, rtol=1e-14)
    with pytest.raises(ValueError, match="vmag"):
        model.star_pe(np.array([np.nan]), np.zeros(1), 2e-3)

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


# ------------------------------------------------------------------------------------- compiled kernels
def _reference_windows(sub_xy, sub_w, sigma, n_cols, n_rows):
    """Independent truth: every sub-spot integrated over every pixel of the detector with scipy's ndtr."""
    from scipy.special import ndtr

    img = np.zeros((n_rows, n_cols))
    e_c = np.arange(n_cols + 1) - 0.5
    e_r = np.arange(n_rows + 1) - 0.5
    for p in range(sub_xy.shape[0]):
        for k in range(sub_xy.shape[1]):
            gx = np.diff(ndtr((e_c - sub_xy[p, k, 0]) / sigma[p]))
            gy = np.diff(ndtr((e_r - sub_xy[p, k, 1]) / sigma[p]))
            img += sub_w[p, k] * np.outer(gy, gx)
    return img


def test_each_path_is_cut_into_its_own_segments():
    """spots_from_paths: every path gets the fewest segments no longer than 4σ of its own σ, whatever the frame's
    other paths (a long debris streak does not multiply a star's spots); its sub-spots stay <= σ/2 apart, and it
    keeps its signal and its time-mean position (the midpoint of a path swept at a constant speed)."""
    from startracker.kernels.imaging import spots_from_paths

    t = np.linspace(0.0, 1.0, 5)[:, None]
    star = np.array([10.0, 20.0]) + t * np.array([1.5, 0.5])  # 1.58 px
    debris = np.array([5.0, 60.0]) + t * np.array([300.0, -40.0])  # 302.7 px
    still = np.array([50.0, 50.0]) + 0.0 * t
    paths = np.stack([star, debris, still])
    total = np.array([100.0, 50.0, 7.0])
    sigma = np.array([1.2, 1.2, 0.8])
    sub, w, sig, path, along, length = spots_from_paths(paths, total, sigma)
    lengths = np.hypot(*(paths[:, -1] - paths[:, 0]).T)
    expected = [max(1, int(np.ceil(n / (4.0 * s)))) for n, s in zip(lengths, sigma)]
    assert expected == [1, 64, 1]
    assert [int(np.count_nonzero(path == e)) for e in range(3)] == expected
    assert np.all(length <= 4.0 * sig * (1 + 1e-12))
    assert np.all(length / sub.shape[1] <= 0.5 * sig * (1 + 1e-12))  # sub-spot spacing
    for e in range(3):
        m = path == e
        assert w[m].sum() == pytest.approx(total[e], rel=1e-12)
        mean_xy = (sub[m] * w[m][..., None]).sum(axis=(0, 1)) / w[m].sum()
        np.testing.assert_allclose(mean_xy, 0.5 * (paths[e, 0] + paths[e, -1]), atol=1e-9)
        np.testing.assert_allclose(np.sort(sig[m]), sigma[e])


def test_window_kernel_integrates_the_gaussian_over_pixels():
    """render_spot_windows == the pixel-integrated Gaussians summed over sub-spots, spots across the edges included."""
    from startracker.kernels.imaging import render_spot_windows

    rng = np.random.default_rng(5)
    n_cols, n_rows = 40, 30
    sub_xy = np.stack([rng.uniform(-3, n_cols + 2, (12, 3)), rng.uniform(-3, n_rows + 2, (12, 3))], axis=2)
    sub_w = rng.uniform(10, 1000, (12, 3))
    sigma = rng.uniform(0.5, 2.0, 12)
    hw = np.full(12, 12, dtype=np.int64)  # windows reaching 12 px beyond the spots: the tails are < 1e-9
    lin, val, spot = render_spot_windows(sub_xy, sub_w, sigma, hw, n_cols, n_rows, 0.0)
    assert np.all((lin >= 0) & (lin < n_cols * n_rows))
    img = np.bincount(lin, val, minlength=n_cols * n_rows).reshape(n_rows, n_cols)
    ref = _reference_windows(sub_xy, sub_w, sigma, n_cols, n_rows)
    np.testing.assert_allclose(img, ref, rtol=1e-9, atol=1e-6)
    # per spot: every pixel at most once, the spot's own light only
    for p in range(12):
        assert len(np.unique(lin[spot == p])) == np.count_nonzero(spot == p)
    # min_value drops exactly the pixels below it, and the trimmed windows (rows and columns that cannot reach it
    # are not evaluated) keep the others bit for bit, in the same order; sharp spots (σ < 0.4 px, where one pixel
    # holds most of the light) and floors near a spot's peak included
    sharp = sigma.copy()
    sharp[::3] = 0.3
    for sig in (sigma, sharp):
        lin, val, spot = render_spot_windows(sub_xy, sub_w, sig, hw, n_cols, n_rows, 0.0)
        for floor in (0.5, 5.0, 50.0, 150.0, 400.0):
            lin2, val2, spot2 = render_spot_windows(sub_xy, sub_w, sig, hw, n_cols, n_rows, floor)
            keep = val >= floor
            assert np.all(val2 >= floor)
            np.testing.assert_array_equal(lin2, lin[keep])
            np.testing.assert_array_equal(val2, val[keep])
            np.testing.assert_array_equal(spot2, spot[keep])


def test_sparse_windows_carry_the_expected_charge_of_the_full_frame():
    """The sparse frame's star entries, summed per pixel, equal render_expected on the same pixels (smeared,
    multi-exposure spots on a CMOS detector, where the spots are not randomised)."""
    model = quiet(SensorModel.preset("paper000_cmos"))
    plan = ExposurePlan(3, 2e-3, frame_period_s=0.1)
    sc = scene_from_tracks(SMALL, plan, [[40.3, 50.7], [90.2, 80.9], [2.0, 120.4]], [4.0, 5.5, 6.0],
                           [[0.0, 0.0], [600.0, 200.0], [-300.0, 100.0]])
    sf = render_sparse(sc, model, np.random.default_rng(1), false_objects=FalseObjects.none(), draw_crossings=False)
    star = sf.sources.kind[sf.entry_source] == KIND_STAR
    per_px = np.bincount(sf.entry_pixel[star], sf.entry_e[star], minlength=len(sf.lin))
    expected = render_expected(sc, model, include_background=False).ravel()[sf.lin]
    np.testing.assert_allclose(per_px, expected, rtol=1e-9, atol=1e-9)
    # one still spot per star: every pixel left out holds less light than 0.3 σ of the background noise
    sc = scene_from_tracks(SMALL, ExposurePlan(1, 2e-3), [[40.3, 50.7], [90.2, 80.9]], [4.0, 5.5])
    sf = render_sparse(sc, model, np.random.default_rng(1), false_objects=FalseObjects.none(), draw_crossings=False)
    full = render_expected(sc, model, include_background=False).ravel()
    bg = background_field(sc, model)
    out = np.ones(full.size, dtype=bool)
    out[sf.lin] = False
    assert 0 < full[out].max() < 0.3 * np.sqrt(float(bg.var_e(bg.cx, bg.cy)))


def test_normal_tail_inverse_matches_scipy():
    from scipy.special import ndtri

    from startracker.kernels.imaging import normal_isf, normal_sf

    for q in [1e-300, 1e-200, 1e-30, 2.9e-7, 1e-3, 0.02, 0.3, 0.5, 0.7, 0.99]:
        t = normal_isf(q)
        assert t == pytest.approx(-ndtri(q), rel=1e-12, abs=1e-12)
        assert normal_sf(t) == pytest.approx(q, rel=1e-12)


def test_false_pixel_values_follow_the_gaussian_tail():
    """Drawn background crossings: all above the threshold, their mean count and their DN distribution those of
    Gaussian pixels (flat background), from the kernels' cells and tail sampling."""
    from scipy.special import ndtr

    cam = Camera(resolution=(512, 512))
    model = quiet(SensorModel.preset("paper000_cmos"), read_noise_e=20.0)
    sc = scene_from_tracks(cam, ExposurePlan(1, 0.02), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)))
    bg = background_field(sc, model)
    from startracker.imaging import draw_false_pixels

    k = 3.0  # low threshold: many crossings to test
    rng = np.random.default_rng(2)
    draws = [draw_false_pixels(bg, k, 512, 512, model, rng) for _ in range(20)]
    dn = np.concatenate([d[1] for d in draws])
    thr = float(bg.threshold_dn(bg.cx, bg.cy, k))
    assert np.all(dn > thr)
    mu = float(bg.mean_e(bg.cx, bg.cy)) / model.gain_e_per_dn + model.bias_dn
    sd = np.sqrt(float(bg.var_e(bg.cx, bg.cy))) / model.gain_e_per_dn
    levels = np.arange(np.floor(thr) + 1, np.floor(thr) + 6)
    p_level = ndtr(-(levels - 0.5 - mu) / sd) - ndtr(-(levels + 0.5 - mu) / sd)  # P(DN = level)
    n_px = 20 * 512 * 512
    counts = np.array([np.count_nonzero(dn == v) for v in levels])
    assert np.all(np.abs(counts - n_px * p_level) < 4 * np.sqrt(n_px * p_level) + 1), (counts, n_px * p_level)
    p_cross = ndtr(-(np.floor(thr) + 0.5 - mu) / sd)
    assert len(dn) == pytest.approx(n_px * p_cross, abs=4 * np.sqrt(n_px * p_cross))
    assert all(np.all((d[0] >= 0) & (d[0] < 512 * 512)) for d in draws)


def test_pixel_path_is_deterministic_across_processes_on_a_fresh_numba_cache(tmp_path):
    """Same seed, same detections, bit for bit, in two processes that each compile the kernels afresh."""
    import os
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from startracker.imaging import SensorModel, render_sparse\n"
        "from startracker.centroid import detections_from_sparse\n"
        "from startracker.optics import camera_preset\n"
        "from startracker.scene import ExposurePlan, scene_from_tracks\n"
        "cam = camera_preset('paper000')\n"
        "r = np.random.default_rng(4)\n"
        "xy = r.uniform(50, 2000, (25, 2)); v = r.uniform(3, 7, 25); vel = r.uniform(-800, 800, (25, 2))\n"
        "sc = scene_from_tracks(cam, ExposurePlan(5, 1e-3, frame_period_s=0.1), xy, v, vel)\n"
        "out = []\n"
        "for method in ('com', 'gaussian'):\n"
        "    d = detections_from_sparse(render_sparse(sc, SensorModel.preset('paper000'), np.random.default_rng(0)),"
        " method)\n"
        "    out.append(np.concatenate([d.xy.ravel(), d.intensity, d.area, d.truth_star, d.truth_kind]))\n"
        "print(np.concatenate(out).tobytes().hex())\n"
    )
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    outs = []
    for i in range(2):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / f"cache{i}"), PYTHONPATH=root)
        res = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True,
                             timeout=600)
        assert res.returncode == 0, res.stderr
        outs.append(res.stdout.strip())
    assert len(outs[0]) > 1000 and outs[0] == outs[1]


def test_sparse_pixel_kernel_gives_the_background_and_the_noisy_dn_of_each_pixel():
    """sparse_pixels_to_dn in one pass: the background plane's level and threshold (mean + k σ with shot, dark,
    read, PRNU and 1/12 DN² quantisation), the DN of the pixel-noise model (intensified and CMOS), hot pixels'
    extra charge, the full well, the ADC range, and the drawn DN of the background crossings written over theirs;
    each against the formulas evaluated here with numpy."""
    from startracker.kernels.imaging import sparse_pixels_to_dn

    rng = np.random.default_rng(11)
    n_cols, n_rows = 50, 40
    u = 300
    lin = rng.choice(n_cols * n_rows, u, replace=False).astype(np.int64)
    rows, cols = np.divmod(lin, n_cols)
    prnu = (0.02 * rng.standard_normal(n_cols * n_rows)).astype(np.float32)
    spot = rng.uniform(0, 3000, u) * (rng.random(u) < 0.7)
    spot[:3] = 1e7  # beyond the full well
    z = rng.standard_normal(u)
    charge = rng.uniform(0, 2000, u)
    direct = np.where(rng.random(u) < 0.1, rng.uniform(0, 500, u), 0.0)
    hot_u = np.array([5, 17, 40], dtype=np.int64)
    hot_e = np.array([200.0, 50.0, 900.0])
    hot_z = rng.standard_normal(3)
    false_u = np.array([7, -1, 60], dtype=np.int64)
    false_dn = np.array([151.0, 999.0, 163.0])
    opt0, opt_dx, opt_dy, cx, cy = 40.0, 0.9, -2.5, 25.0, 20.0  # clipped at 0 in part of the frame
    gain, enf2_c, dark_e, read_var, prnu_sigma = 3.0, 4.5, 2.0, 9.0, 0.02
    full_well, g_dn, bias, adc_max, k = 60000.0, 16.0, 100.0, 4095.0, 5.0
    o = np.maximum(opt0 + opt_dx * (cols - cx) + opt_dy * (rows - cy), 0.0)
    assert np.any(o == 0.0) and np.any(o > 0.0)
    q_bg = gain * o
    mean_ref = (q_bg + dark_e) / g_dn + bias
    thr_ref = mean_ref + k * np.sqrt((enf2_c * q_bg + dark_e + read_var + (prnu_sigma * q_bg) ** 2) / g_dn**2 + 1 / 12)
    f = 1.0 + prnu[lin].astype(np.float64)
    for intensified in (True, False):
        dn, mean, thr = sparse_pixels_to_dn(intensified, spot, prnu[lin], lin, z, charge, direct, hot_u, hot_e, hot_z,
                                            false_u, false_dn, n_cols, opt0, opt_dx, opt_dy, cx, cy, gain, enf2_c,
                                            dark_e, read_var, prnu_sigma, full_well, g_dn, bias, adc_max, k)
        assert dn.dtype == np.float32
        np.testing.assert_allclose(mean, mean_ref, rtol=1e-12)
        np.testing.assert_allclose(thr, thr_ref, rtol=1e-12)
        if intensified:
            q = spot + q_bg
            e = q * f + dark_e + np.sqrt(enf2_c * q + dark_e + read_var) * z
        else:
            e = np.sqrt(enf2_c * q_bg + dark_e + read_var) * z + q_bg * f + dark_e + f * charge
        e = e + direct
        e[hot_u] += hot_e + np.sqrt(hot_e) * hot_z
        x = np.minimum(e, full_well) / g_dn + bias
        ref = np.clip(np.rint(x), 0.0, adc_max)
        ref[false_u[false_u >= 0]] = false_dn[false_u >= 0]
        off = dn != ref
        # equal except where rounding order could tip a value sitting on a half DN
        assert np.all(np.abs(np.abs(x[off] - np.floor(x[off])) - 0.5) < 1e-9)
        if intensified:
            assert np.all(dn[:3] == full_well / g_dn + bias)  # clipped at the full well
        assert dn[7] == 151.0 and dn[60] == 163.0


def test_sparse_pixel_set_deduplicates_and_gathers_each_pixels_prnu():
    """sparse_pixel_set: the distinct pixels in order of first appearance (as numpy's unique gives them), the index
    buffer pointing back at them, the entries' compact ids, and each pixel's PRNU gathered from the map, whether the
    buffer and the map are separate arrays or the two columns of one interleaved array (as render_sparse passes)."""
    from startracker.kernels.imaging import sparse_pixel_set

    rng = np.random.default_rng(5)
    n_cols, n_rows = 60, 45
    n_px = n_cols * n_rows
    opt_lin = rng.integers(0, n_px, 700)  # with repeats: overlapping windows
    opt_val = rng.uniform(0, 50, 700)
    opt_src = rng.integers(0, 30, 700)
    prnu = (0.03 * rng.standard_normal(n_px)).astype(np.float32)
    _, first = np.unique(opt_lin, return_index=True)
    ref_uniq = opt_lin[np.sort(first)]
    empty_i, empty_f = np.zeros(0, dtype=np.int64), np.zeros(0)
    pair = np.zeros((n_px, 2), dtype=np.int32)
    pair.view(np.float32)[:, 1] = prnu
    for buf, pmap in ((np.full(n_px, 7, dtype=np.int32), prnu), (pair[:, 0], pair.view(np.float32)[:, 1])):
        out = sparse_pixel_set(opt_lin, opt_val, opt_src, 2.0, empty_i, empty_f, empty_i, empty_i, empty_f, 30,
                               empty_i, 30, n_cols, n_rows, buf, pmap)
        uniq, inv, prnu_u = out[0], out[1], out[8]
        np.testing.assert_array_equal(uniq, ref_uniq)
        np.testing.assert_array_equal(uniq[inv], opt_lin)
        np.testing.assert_array_equal(buf[uniq], np.arange(len(uniq)))
        assert prnu_u.dtype == np.float32
        np.testing.assert_array_equal(prnu_u, prnu[uniq])
    out = sparse_pixel_set(opt_lin, opt_val, opt_src, 2.0, empty_i, empty_f, empty_i, empty_i, empty_f, 30,
                           empty_i, 30, n_cols, n_rows, np.zeros(n_px, dtype=np.int32), np.zeros(0, dtype=np.float32))
    assert len(out[8]) == 0


def test_split_pixel_index_is_divmod():
    """split_pixel_index equals divmod(px, n_cols) for every pixel of several detectors, including the multiples of
    n_cols where the floating-point guess of the quotient falls one short (e.g. 49 · (1/49) < 1)."""
    from numba import njit

    from startracker.kernels.imaging import split_pixel_index

    @njit
    def split_all(px, n_cols):
        out = np.empty((len(px), 2), dtype=np.int64)
        for i in range(len(px)):
            out[i, 0], out[i, 1] = split_pixel_index(px[i], n_cols, 1.0 / n_cols)
        return out

    rng = np.random.default_rng(2)
    assert 49 * (1.0 / 49) < 1.0  # the guess alone would be wrong here
    for n_cols, n_rows in ((49, 37), (1, 10), (7, 1000), (2048, 2048), (4095, 3000), (5000, 5000)):
        n_px = n_cols * n_rows
        px = np.concatenate([np.arange(min(n_px, 20000)), np.arange(n_rows) * n_cols,
                             np.arange(1, n_rows + 1) * n_cols - 1, rng.integers(0, n_px, 20000)]).astype(np.int64)
        np.testing.assert_array_equal(split_all(px, n_cols), np.stack(np.divmod(px, n_cols), 1))


@pytest.mark.parametrize("n_samples", [3, 5, 12])
def test_frame_star_spots_equal_the_numpy_formulation(n_samples):
    from startracker.kernels.imaging import frame_star_spots

    rng = np.random.default_rng(n_samples)
    n, m = 4, 9
    xy_path = rng.uniform(-40.0, 140.0, (n, n_samples, m, 2))  # some paths off the 100 x 80 window, some across it
    pe = rng.uniform(1.0, 100.0, m)
    pe[3] = 0.0  # a star without light keeps its source row but no path
    gain, x_lo, x_hi, y_lo, y_hi = 2.5, -3.5, 102.5, -3.5, 82.5
    star, expo, xy, exp_e, paths, total, source = frame_star_spots(xy_path, pe, gain, x_lo, x_hi, y_lo, y_hi)
    # the source table, exposure-major, and the trapezoid mean as Scene.xy_mean computes it
    assert np.array_equal(star, np.tile(np.arange(m), n)) and np.array_equal(expo, np.repeat(np.arange(n), m))
    mean = (xy_path[:, 1:-1].sum(axis=1) + 0.5 * (xy_path[:, 0] + xy_path[:, -1])) / (n_samples - 1)
    assert np.array_equal(xy, mean.reshape(-1, 2))
    assert np.array_equal(exp_e, np.tile(pe * gain, n))
    # kept: the path's bounding box meets the window and the star gives light
    p = np.moveaxis(xy_path, 1, 2).reshape(n * m, n_samples, 2)
    lo, hi = p.min(axis=1), p.max(axis=1)
    inside = (hi[:, 0] >= x_lo) & (lo[:, 0] <= x_hi) & (hi[:, 1] >= y_lo) & (lo[:, 1] <= y_hi) & (np.tile(pe, n) > 0)
    assert 0 < inside.sum() < n * m
    assert np.array_equal(source, np.flatnonzero(inside))
    assert np.array_equal(paths, p[inside]) and np.array_equal(total, np.tile(pe, n)[inside])


@pytest.mark.parametrize("gradient", [(0.0, 0.0), (0.004, -0.003)])
def test_sparse_source_table_appends_hot_pixels_and_crossings(gradient):
    """sparse_source_table: the spots' rows unchanged, then one row per hot pixel and per crossing at its pixel
    centre, the crossing's charge its DN in e⁻ less BackgroundField.mean_e there (flat and sloped sky)."""
    from startracker.imaging import BackgroundField
    from startracker.kernels.imaging import sparse_source_table

    rng = np.random.default_rng(4)
    n_cols, n_rows = 640, 480
    q0 = 12
    kind = rng.integers(0, 5, q0).astype(np.int64)
    star = rng.integers(-1, 50, q0).astype(np.int64)
    expo = rng.integers(-1, 3, q0).astype(np.int64)
    xy = rng.uniform(0, 400, (q0, 2))
    exp_e = rng.uniform(0, 1e4, q0)
    hot = np.sort(rng.choice(n_cols * n_rows, 5, replace=False)).astype(np.int64)
    hot_e = rng.uniform(10, 100, 5)
    f_lin = rng.choice(n_cols * n_rows, 7, replace=False).astype(np.int64)
    f_dn = rng.uniform(120, 200, 7)
    bg = BackgroundField(opt0=40.0, opt_dx=gradient[0], opt_dy=gradient[1], cx=319.5, cy=239.5, dark_e=3.0,
                         integration_s=0.1, gain=2.5, enf2_c=3.0, read_var_e2=4.0, prnu_sigma=0.01, gain_e_per_dn=1.7,
                         bias_dn=100.0, blinded=False)
    k, s, e, t_xy, t_e = sparse_source_table(kind, star, expo, xy, exp_e, hot, hot_e, f_lin, f_dn, n_cols, 2, 1, 100.0,
                                             1.7, bg.opt0, bg.opt_dx, bg.opt_dy, bg.cx, bg.cy, bg.gain, bg.dark_e)
    n = q0 + 5 + 7
    assert len(k) == len(s) == len(e) == len(t_e) == n and t_xy.shape == (n, 2)
    np.testing.assert_array_equal(k, np.r_[kind, [2] * 5, [1] * 7])
    np.testing.assert_array_equal(s, np.r_[star, [-1] * 12])
    np.testing.assert_array_equal(e, np.r_[expo, [-1] * 12])
    cols = np.r_[hot % n_cols, f_lin % n_cols]
    rows = np.r_[hot // n_cols, f_lin // n_cols]
    np.testing.assert_array_equal(t_xy, np.r_[xy, np.column_stack([cols, rows]).astype(float)])
    fc, fr = f_lin % n_cols, f_lin // n_cols
    np.testing.assert_array_equal(t_e, np.r_[exp_e, hot_e, (f_dn - 100.0) * 1.7 - bg.mean_e(fc, fr)])
