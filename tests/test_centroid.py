"""Centroids: COM and Gaussian interpolation (paper 002 §3), noise against linearised theory, fidelities."""

import dataclasses

import numpy as np
import pytest
from scipy.special import ndtr

from startracker.catalog import load_catalog
from startracker.centroid import (
    CentroidErrorModel,
    Centroids,
    calibrate_error_model,
    extract_centroids,
    simulate_detections,
)
from startracker.imaging import KIND_STAR, SensorModel, background_field, render_expected, render_frame
from startracker.optics import Camera, camera_preset
from startracker.photometry import Photometry
from startracker.rotations import quat_integrate, quat_random
from startracker.scene import ExposurePlan, compute_scene, scene_from_tracks

TINY = Camera(resolution=(64, 64))


def quiet(model, **kw):
    base = dict(hot_pixel_fraction=0.0, cosmic_ray_rate_per_cm2_s=0.0, debris_rate_per_frame=0.0, prnu_sigma=0.0)
    base.update(kw)
    return dataclasses.replace(model, **base)


def gaussian_image(shape, x0, y0, sigma, total, background=100.0):
    """Independent pixel-integrated Gaussian spot (paper 002 eq. 4-5)."""
    cols = np.arange(shape[1])
    rows = np.arange(shape[0])
    gx = ndtr((cols + 0.5 - x0) / sigma) - ndtr((cols - 0.5 - x0) / sigma)
    gy = ndtr((rows + 0.5 - y0) / sigma) - ndtr((rows - 0.5 - y0) / sigma)
    return background + total * np.outer(gy, gx)


# ------------------------------------------------------------------------------------- exact cases
def test_noiseless_spot_com_and_gaussian_interpolation_are_exact():
    rng = np.random.default_rng(0)
    for _ in range(20):
        x0, y0 = rng.uniform(20, 44, 2)
        img = gaussian_image((64, 64), x0, y0, 1.3, 5.0e4)
        com = extract_centroids(img, k_sigma=3.0, background="global")
        assert len(com) == 1
        np.testing.assert_allclose(com.xy[0], [x0, y0], atol=2e-3)
        gau = extract_centroids(img, k_sigma=3.0, method="gaussian", psf_sigma_px=1.3, background="global")
        np.testing.assert_allclose(gau.xy[0], [x0, y0], atol=1e-6)  # exact inversion of eq. 6
        est = extract_centroids(img, k_sigma=3.0, method="gaussian", background="global")  # σ from the log-parabola
        np.testing.assert_allclose(est.xy[0], [x0, y0], atol=0.03)


def test_high_snr_centroid_error_below_0_05_px():
    rng = np.random.default_rng(1)
    cases = [
        (quiet(SensorModel.preset("paper000_cmos")), ExposurePlan(1, 0.02), 3.0),
        (quiet(SensorModel.preset("paper000")), ExposurePlan(1, 1e-3), 1.0),
    ]
    for model, plan, vmag in cases:
        err = []
        for _ in range(60):
            xy = rng.uniform(24, 40, (1, 2))
            sc = scene_from_tracks(TINY, plan, xy, [vmag])
            c = extract_centroids(render_frame(sc, model, rng), saturation_dn=model.saturation_dn)
            assert not c.saturated[0]
            err.append(c.xy[0] - xy[0])
        rms = np.sqrt(np.mean(np.square(err)))
        assert rms < 0.05, (model.name, rms)


def linearised_com_variance(expected_e, x0, y0, var_e, thr_e):
    """Variance (px², per axis) of a thresholded centre of mass with Gaussian pixel noise.

    Each pixel contributes Y = 1{X > T} X with X ~ N(s, v): E[Y] = s Q + σ φ,
    E[Y²] = (s² + v) Q + σ (s + T) φ with z = (T − s)/σ. Linearising x̂ = Σ x Y / Σ Y about the means.
    """
    s = expected_e
    sd = np.sqrt(var_e)
    z = (thr_e - s) / sd
    q = ndtr(-z)
    phi = np.exp(-0.5 * z**2) / np.sqrt(2 * np.pi)
    ey = s * q + sd * phi
    ey2 = (s**2 + var_e) * q + sd * (s + thr_e) * phi
    var_y = ey2 - ey**2
    rows, cols = np.indices(s.shape)
    tot = ey.sum()
    return (np.sum((cols - x0) ** 2 * var_y) / tot**2, np.sum((rows - y0) ** 2 * var_y) / tot**2)


@pytest.mark.parametrize("read_noise_e", [2.0, 8.0, 25.0])
def test_centroid_noise_follows_linearised_theory(read_noise_e):
    """Monte Carlo RMS of the COM matches the linearised theory of a thresholded COM within 15 %."""
    model = quiet(SensorModel.preset("paper000_cmos"), read_noise_e=read_noise_e, dark_current_e_per_s=0.0,
                  sky_mag_per_arcsec2=30.0, gain_e_per_dn=1.0)
    plan = ExposurePlan(1, 0.02)
    rng = np.random.default_rng(int(read_noise_e))
    x0, y0 = 31.7, 32.2
    sc = scene_from_tracks(TINY, plan, [[x0, y0]], [4.5])
    expected = render_expected(sc, model, include_background=False)
    bg = background_field(sc, model)
    var_b = bg.var_e(0, 0) + model.gain_e_per_dn**2 / 12
    k = 5.0
    var_x, var_y = linearised_com_variance(expected, x0, y0, expected + var_b, k * np.sqrt(var_b))
    errs = []
    for _ in range(400):
        c = extract_centroids(render_frame(sc, model, rng), k_sigma=k, background="global")
        errs.append(c.xy[0] - [x0, y0])
    errs = np.array(errs)
    rms = np.sqrt(np.mean(errs**2, axis=0))
    np.testing.assert_allclose(rms, np.sqrt([var_x, var_y]), rtol=0.15)


def test_centroid_error_grows_with_noise_and_shrinks_with_signal():
    """Photon-limited: error ∝ S^-1/2; background-limited: error grows with the read noise."""
    rng = np.random.default_rng(7)
    plan = ExposurePlan(1, 0.02)

    def rms(model, vmag, n=200):
        e = []
        for _ in range(n):
            xy = rng.uniform(28, 36, (1, 2))
            c = extract_centroids(render_frame(scene_from_tracks(TINY, plan, xy, [vmag]), model, rng), background="global")
            e.append(c.xy[0] - xy[0])
        return np.sqrt(np.mean(np.square(e)))

    photon = quiet(SensorModel.preset("paper000_cmos"), read_noise_e=0.5, dark_current_e_per_s=0.0,
                   sky_mag_per_arcsec2=30.0, gain_e_per_dn=0.5, full_well_e=1e7, adc_bits=24)
    r = np.array([rms(photon, v) for v in (3.0, 5.5)])  # signal ratio 10: error ratio √10
    assert r[0] / r[1] == pytest.approx(10 ** -0.5, rel=0.2)
    s = photon.star_pe([5.5], [0.0], 0.02)[0]
    assert r[1] == pytest.approx(np.sqrt((photon.sigma_px**2 + 1 / 12) / s), rel=0.2)
    noisy = [rms(dataclasses.replace(photon, read_noise_e=rn), 4.5) for rn in (2.0, 10.0, 30.0)]
    assert noisy[0] < noisy[1] < noisy[2]


def test_gaussian_interpolation_is_noisier_than_com():
    """Paper 002 §3.3: COM is smoother than Gaussian interpolation (which uses two pixels per axis)."""
    model = quiet(SensorModel.preset("paper000"))
    plan = ExposurePlan(1, 1e-3)
    rng = np.random.default_rng(3)
    ec, eg = [], []
    for _ in range(150):
        xy = rng.uniform(28, 36, (1, 2))
        img = render_frame(scene_from_tracks(TINY, plan, xy, [3.5]), model, rng)
        ec.append(extract_centroids(img).xy[0] - xy[0])
        eg.append(extract_centroids(img, method="gaussian").xy[0] - xy[0])
    assert np.sqrt(np.mean(np.square(eg))) > 1.3 * np.sqrt(np.mean(np.square(ec)))


# ------------------------------------------------------------------------------------- behaviour
def test_multi_exposure_frame_gives_one_detection_per_spot_brightest_first():
    cam = Camera(resolution=(256, 256))
    model = quiet(SensorModel())
    plan = ExposurePlan(6, 1e-3, frame_period_s=0.1)
    sc = scene_from_tracks(cam, plan, [[60.0, 128.0], [128.0, 60.0], [180.0, 200.0]], [2.0, 3.0, 3.5],
                           np.tile([1000.0, 200.0], (3, 1)))
    img = render_frame(sc, model, np.random.default_rng(0))
    c = extract_centroids(img, saturation_dn=model.saturation_dn)
    assert len(c) == 18
    assert np.all(np.diff(c.intensity) <= 0)
    truth = sc.xy_mean.reshape(-1, 2)
    d = np.linalg.norm(c.xy[:, None] - truth[None], axis=-1).min(axis=1)
    assert d.max() < 0.6
    assert np.all(c.area >= 1) and c.area.dtype.kind == "i"
    assert np.all(c.snr > 5)
    # the six spots of the brightest star are the six brightest detections
    bright = np.argsort(np.linalg.norm(c.xy[:6, None] - truth[None, :6], axis=-1).min(axis=1))
    assert len(bright) == 6


def test_empty_and_saturated_frames():
    flat = np.full((64, 64), 100.0, dtype=np.float32)
    c = extract_centroids(flat)
    assert isinstance(c, Centroids) and len(c) == 0
    noise = 100 + np.random.default_rng(0).normal(0, 3, (128, 128))
    assert len(extract_centroids(noise, k_sigma=8.0)) == 0
    sat = np.full((64, 64), 4095.0)
    assert len(extract_centroids(sat, saturation_dn=4095.0)) == 0
    blob = flat.copy()
    blob[30:34, 30:34] = 4095.0
    c = extract_centroids(blob, saturation_dn=4095.0)
    assert len(c) == 1 and c.saturated[0] and c.area[0] == 16
    np.testing.assert_allclose(c.xy[0], [31.5, 31.5])
    assert extract_centroids(np.zeros((16, 16), dtype=np.uint16)).xy.shape == (0, 2)


@pytest.mark.parametrize(
    "image,kw",
    [
        (np.zeros((8, 8, 3)), {}),
        (np.zeros(64), {}),
        (np.full((16, 16), np.nan), {}),
        (np.zeros((16, 16)), dict(k_sigma=0.0)),
        (np.zeros((16, 16)), dict(k_sigma=float("nan"))),
        (np.zeros((16, 16)), dict(method="peak")),
        (np.zeros((16, 16)), dict(min_area_px=0)),
        (np.zeros((16, 16)), dict(background="median")),
        (np.zeros((2, 2)), {}),
    ],
)
def test_bad_images_raise_value_error(image, kw):
    with pytest.raises(ValueError):
        extract_centroids(image, **kw)


def test_bad_simulate_arguments():
    sc = scene_from_tracks(TINY, ExposurePlan(1, 1e-3), [[30.0, 30.0]], [4.0])
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError):
        simulate_detections(sc, SensorModel(), rng, fidelity="photons")
    with pytest.raises(TypeError):
        simulate_detections(sc, SensorModel(), None)
    with pytest.raises(ValueError):
        simulate_detections(sc, SensorModel(), rng, method="gaussian", error_model=CentroidErrorModel(method="com"))
    with pytest.raises(ValueError):
        CentroidErrorModel(peak_factor=-1.0)


def test_centroid_fidelity_merges_coincident_spots_like_pixels_do():
    """A still camera with N exposures stacks every star's spots: one detection per star in both fidelities."""
    cam = Camera(resolution=(256, 256))
    model = quiet(SensorModel())
    plan = ExposurePlan(8, 1e-3, frame_period_s=0.1)
    sc = scene_from_tracks(cam, plan, [[60.0, 128.0], [128.0, 60.0], [200.0, 190.0]], [4.0, 4.5, 5.0])
    for fidelity in ("pixel", "centroid"):
        det = simulate_detections(sc, model, np.random.default_rng(1), fidelity)
        assert len(det) == 3, fidelity
        assert sorted(det.truth_star) == [0, 1, 2]


# ------------------------------------------------------------------------------------- fidelities agree
class BinStats:
    """Per magnitude bin: visible spots, spots found, radial errors of the finds (px)."""

    def __init__(self, bins):
        self.bins = bins
        self.visible = np.zeros(len(bins))
        self.found = np.zeros(len(bins))
        self.errors = [[] for _ in bins]
        self.false = []

    def add(self, det, sc):
        n, m = sc.n_exposures, sc.n_stars
        st = np.flatnonzero(det.truth_kind == KIND_STAR)
        key = det.truth_exposure[st] * m + det.truth_star[st]
        _, first = np.unique(key, return_index=True)
        found = np.zeros(n * m, dtype=bool)
        found[key[first]] = True
        err = np.full(n * m, np.nan)
        err[key[first]] = np.linalg.norm(det.xy[st[first]] - det.truth_xy[st[first]], axis=1)
        vis = sc.visible.reshape(-1)
        vm = np.tile(sc.vmag, n)
        for j, (lo, hi) in enumerate(self.bins):
            s = vis & (vm >= lo) & (vm < hi)
            self.visible[j] += s.sum()
            self.found[j] += found[s].sum()
            self.errors[j].extend(err[s & found])
        self.false.append(int(np.sum(det.truth_kind != KIND_STAR)))
        return self

    @property
    def p_det(self):
        return self.found / self.visible

    def quantile(self, q):
        return np.array([np.quantile(e, q) if len(e) else np.nan for e in self.errors])

    def blended(self, px=2.0):
        """Fraction of finds farther than ``px`` from their truth (merged with another spot)."""
        return np.array([np.mean(np.asarray(e) > px) if len(e) else np.nan for e in self.errors])


@pytest.mark.parametrize("preset", ["paper000", "paper000_cmos"])
def test_centroid_fidelity_reproduces_the_pixel_path(preset):
    """Per magnitude bin: detection rate within 0.08, median and 90th-percentile centroid error within 25 %,
    blend fraction within 0.05; false detections per frame within 35 %."""
    cam = camera_preset("paper000")
    cat = load_catalog(7.0 if preset == "paper000" else 7.9)
    model = SensorModel.preset(preset)
    if preset == "paper000":
        rate = np.radians(14.0)
        bins = [(-2.0, 5.0), (5.0, 6.0), (6.0, 6.6), (6.6, 7.0)]
    else:
        rate = np.radians(0.3)
        bins = [(-2.0, 6.0), (6.0, 7.0), (7.0, 7.6), (7.6, 7.9)]
    rng = np.random.default_rng(2024)
    acc = {"pixel": BinStats(bins), "centroid": BinStats(bins)}
    for _ in range(6):
        q0 = quat_random(rng)
        phi = rng.uniform(0, 2 * np.pi)
        omega = rate * np.array([np.cos(phi), np.sin(phi), rng.uniform(-0.1, 0.1)])
        plan = ExposurePlan.for_rate(omega, cam) if preset == "paper000" else ExposurePlan(1, 0.02)
        sc = compute_scene(cam, cat, lambda t: quat_integrate(np.broadcast_to(q0, (len(t), 4)), omega, t), plan, 0.0)
        for fid in acc:
            for _ in range(3):
                acc[fid].add(simulate_detections(sc, model, rng, fid), sc)
    p, c = acc["pixel"], acc["centroid"]
    assert np.all(p.visible > 30)
    np.testing.assert_allclose(c.p_det, p.p_det, atol=0.08)
    # centroid error distribution: median and 90th percentile of the radial error within 25 %
    np.testing.assert_allclose(c.quantile(0.5), p.quantile(0.5), rtol=0.25)
    np.testing.assert_allclose(c.quantile(0.9), p.quantile(0.9), rtol=0.25)
    np.testing.assert_allclose(c.blended(), p.blended(), atol=0.05)
    assert np.mean(c.false) == pytest.approx(np.mean(p.false), rel=0.35, abs=1.0)


def test_calibration_fits_a_new_detector():
    """calibrate_error_model against the pixel path makes the centroid fidelity match for a custom detector."""
    model = quiet(SensorModel.preset("paper000_cmos"), psf_sigma_px=1.6, read_noise_e=8.0, name="custom",
                  photometry=Photometry(aperture_diameter_mm=40.0))
    em = calibrate_error_model(model, np.random.default_rng(0), n_frames=3, smear_px=(0.0, 3.0))
    assert 0.8 < em.peak_factor < 2.0
    cam = camera_preset("paper000")
    plan = ExposurePlan(1, 0.02)
    rng = np.random.default_rng(1)
    from startracker.centroid.fidelity import grid_scene

    acc = {}
    bins = [(6.0, 7.5), (7.5, 8.5), (8.5, 9.5)]
    for fid in ("pixel", "centroid"):
        acc[fid] = BinStats(bins)
        for i in range(3):
            sc = grid_scene(cam, plan, 6.0, 9.5, 100.0, 64.0, np.random.default_rng(100 + i))
            acc[fid].add(simulate_detections(sc, model, rng, fid, error_model=em), sc)
    p, c = acc["pixel"], acc["centroid"]
    np.testing.assert_allclose(c.p_det, p.p_det, atol=0.08)
    ok = p.found > 20
    np.testing.assert_allclose(c.quantile(0.5)[ok], p.quantile(0.5)[ok], rtol=0.3)


# ------------------------------------------------------------------------------------- compiled kernel vs theory
def reference_spot_theory(s_units, gain, f2, sigma, sigma_o, c_splash, length, var_b, thr_e, err, intensified):
    """The closed-form statistics of a thresholded centre of mass, written out in numpy (the independent
    reference of startracker.kernels.centroid.spot_theory; the model is in its docstring)."""
    from scipy.special import erf

    se2 = sigma**2 + 1.0 / 12.0
    se = np.sqrt(se2)
    lpos = np.maximum(length, 1e-9)
    phi = np.where(length > 1e-6, (np.sqrt(2 * np.pi) * se / lpos) * erf(lpos / (2 * np.sqrt(2) * se)), 1.0)
    total_e = gain * s_units
    peak = total_e * phi / (2 * np.pi * se2)
    s_safe = np.maximum(s_units, 1e-12)
    if intensified:
        var_peak = peak**2 * f2 / s_safe + gain * f2 * c_splash * peak + var_b
    else:
        var_peak = gain * f2 * peak + var_b
    cp = peak * (1.0 + (err.peak_factor - 1.0) * (var_peak - var_b) / var_peak)
    p_det = ndtr((cp - thr_e) / np.sqrt(var_peak))
    a = np.maximum(np.log(np.maximum(cp / np.maximum(thr_e, 1e-12), 1e-300)), err.min_log_ratio)
    r2 = 2.0 * se2 * a
    r = np.sqrt(r2)
    frac = np.maximum(1.0 - np.exp(-a), 1e-6)
    m2 = se2 * (1.0 - a * np.exp(-a) / frac)
    l2 = length**2 / 12.0
    if intensified:
        ph_cross = f2 * (sigma_o**2 + c_splash * m2 / frac) / s_safe
        ph_along = f2 * (sigma_o**2 + l2 + c_splash * (m2 + l2) / frac) / s_safe
    else:
        ph_cross = f2 * m2 / (s_safe * frac)
        ph_along = f2 * (m2 + l2) / (s_safe * frac)
    cap = total_e * frac
    cap2 = np.maximum(cap, 1e-12) ** 2
    disc = np.pi * r2**2 / 4
    bg_cross = var_b * (disc + (2 * r) ** 3 * length / 12) / cap2
    bg_along = var_b * (disc + 2 * r * length**3 / 12 + np.pi * r2 * length**2 / 4) / cap2
    edge_k = thr_e * np.sqrt(var_b) * se2 / np.maximum(r, 1e-6) / cap2 / np.sqrt(np.pi)
    bg_cross = bg_cross + edge_k * (2 * length * r2 + np.pi * r2 * r)
    bg_along = bg_along + edge_k * (length**3 / 6 + np.pi * r * length**2 / 2 + np.pi * r2 * r + 2 * length * r2)
    lock_cross = (1.0 - m2 / se2) ** 2 / 12.0
    lock_along = (1.0 - (m2 + l2) / (se2 + l2)) ** 2 / 12.0
    area = np.maximum(np.pi * r2 + 2 * r * length, 1.0)
    return dict(
        p_det=p_det, ph_along=ph_along, ph_cross=ph_cross, bg_along=bg_along, bg_cross=bg_cross,
        lock_along=lock_along, lock_cross=lock_cross,
        var_cross=err.photon_factor * ph_cross + err.background_factor * bg_cross + err.locking_factor * lock_cross,
        var_along=err.photon_factor * ph_along + err.background_factor * bg_along + err.locking_factor * lock_along,
        cap=cap, var_cap=gain * gain * f2 * s_units * frac + var_b * area, area=area, peak=peak)


@pytest.mark.parametrize("intensified", [True, False])
def test_spot_theory_kernel_matches_the_reference_formulas(intensified):
    from startracker.centroid.fidelity import default_error_model
    from startracker.kernels.centroid import THEORY_COLUMNS, spot_theory

    model = SensorModel.preset("paper000" if intensified else "paper000_cmos")
    err = default_error_model(model)
    rng = np.random.default_rng(4)
    p = 500
    s_units = 10 ** rng.uniform(0, 6, p)
    length = np.where(rng.random(p) < 0.2, 0.0, rng.uniform(0, 30, p))
    var_b = rng.uniform(5, 500, p)
    thr = 5.0 * np.sqrt(var_b)
    args = (model.intensifier_gain, model.excess_noise_factor**2, model.sigma_px, model.optics_sigma_px,
            model.splash_energy)
    got = spot_theory(s_units, *args, length, var_b, thr,
                      np.array([err.peak_factor, err.photon_factor, err.background_factor, err.locking_factor,
                                err.min_log_ratio]), intensified)
    ref = reference_spot_theory(s_units, *args, length, var_b, thr, err, intensified)
    for j, name in enumerate(THEORY_COLUMNS):
        np.testing.assert_allclose(got[:, j], ref[name], rtol=1e-12, atol=1e-300, err_msg=name)
    assert 0.05 < np.mean(got[:, 0]) < 0.95  # the magnitudes span rare to certain detection


def test_detection_statistics_follow_the_analytic_formulas():
    """Isolated moving spots over many frames: detection frequency = p_det (binomial), centroid errors along and
    across the motion and the charge are Gaussian with the theory's variances (normalised errors of unit variance)."""
    from startracker.centroid.fidelity import default_error_model

    cam = Camera(resolution=(1024, 1024))
    model = quiet(SensorModel.preset("paper000"))
    err = default_error_model(model)
    plan = ExposurePlan(1, 1e-3, frame_period_s=0.1)
    rng = np.random.default_rng(12)
    g = np.arange(40.0, 1000.0, 80.0)
    xy = np.column_stack([a.ravel() for a in np.meshgrid(g, g)])
    m = len(xy)
    ang = rng.uniform(0, 2 * np.pi, m)
    vel = 2500.0 * np.column_stack([np.cos(ang), np.sin(ang)])  # 2.5 px streaks
    vmag = np.linspace(3.0, 8.5, m)
    sc = scene_from_tracks(cam, plan, xy, vmag, vel)
    bg = background_field(sc, model)
    var_b = bg.var_e(xy[:, 0], xy[:, 1]) + model.gain_e_per_dn**2 / 12
    th = reference_spot_theory(model.star_pe(vmag, np.zeros(m), 1e-3), model.intensifier_gain,
                               model.excess_noise_factor**2, model.sigma_px, model.optics_sigma_px, model.splash_energy,
                               sc.smear_px[0], var_b, 5.0 * np.sqrt(var_b), err, True)
    n_frames = 150
    found = np.zeros(m)
    z_al, z_cr, z_q = [], [], []
    along = vel / np.linalg.norm(vel, axis=1, keepdims=True)
    for _ in range(n_frames):
        det = simulate_detections(sc, model, rng, "centroid", include_false=False)
        assert np.all(det.truth_kind == KIND_STAR) and len(np.unique(det.truth_star)) == len(det)
        s = det.truth_star
        found[s] += 1
        e = det.xy - xy[s]
        z_al.append((e * along[s]).sum(1) / np.sqrt(th["var_along"][s]))
        z_cr.append((-e[:, 0] * along[s, 1] + e[:, 1] * along[s, 0]) / np.sqrt(th["var_cross"][s]))
        bright = th["cap"][s] > 4 * np.sqrt(th["var_cap"][s])  # the charge is floored at 1e-3 e⁻: Gaussian well above
        z_q.append(((det.intensity * model.gain_e_per_dn - th["cap"][s]) / np.sqrt(th["var_cap"][s]))[bright])
        np.testing.assert_allclose(det.truth_xy, xy[s], atol=1e-9)
    p = th["p_det"]
    assert p.min() < 0.2 and p.max() > 0.99  # from rare to certain detection
    # binomial: each star's count within 4.5 σ, and the total within 4 σ
    sd = np.sqrt(n_frames * p * (1 - p)) + 0.5
    assert np.all(np.abs(found - n_frames * p) < 4.5 * sd)
    assert abs(found.sum() - n_frames * p.sum()) < 4 * np.sqrt(np.sum(n_frames * p * (1 - p)))
    for z in (np.concatenate(z_al), np.concatenate(z_cr), np.concatenate(z_q)):
        n = len(z)
        assert abs(z.mean()) < 4.0 / np.sqrt(n)
        assert abs(z.var() - 1.0) < 4.0 * np.sqrt(2.0 / n)


def test_spots_closer_than_their_reach_merge_into_the_brightest():
    """Two still spots: closer than the sum of their expected threshold radii they are one detection at the
    charge-weighted centroid with the brighter one's labels; just beyond it still one (where the two threshold
    regions meet, the summed profile is twice the threshold: connected pixels join them, as the pixel path does,
    tests/test_overlap_fidelity.py); far beyond, two detections."""
    from startracker.centroid.fidelity import default_error_model

    cam = Camera(resolution=(256, 256))
    model = quiet(SensorModel.preset("paper000"))
    plan = ExposurePlan(1, 1e-3, frame_period_s=0.1)
    vmag = np.array([4.0, 4.6])
    bg = background_field(scene_from_tracks(cam, plan, [[128.0, 128.0]], [5.0]), model)
    var_b = float(bg.var_e(128.0, 128.0)) + model.gain_e_per_dn**2 / 12
    th = reference_spot_theory(model.star_pe(vmag, np.zeros(2), 1e-3), model.intensifier_gain,
                               model.excess_noise_factor**2, model.sigma_px, model.optics_sigma_px, model.splash_energy,
                               np.zeros(2), np.full(2, var_b), np.full(2, 5 * np.sqrt(var_b)),
                               default_error_model(model), True)
    se2 = model.sigma_px**2 + 1 / 12
    reach = np.sqrt(2 * se2 * np.log(th["peak"] / (5 * np.sqrt(var_b)))).sum()
    for gap, n_expected in ((0.98 * reach, 1), (1.02 * reach, 1), (1.6 * reach, 2)):
        xy = np.array([[100.0, 128.0], [100.0 + gap, 128.0]])
        det = simulate_detections(scene_from_tracks(cam, plan, xy, vmag), model, np.random.default_rng(2), "centroid",
                                  include_false=False)
        assert len(det) == n_expected
        if n_expected == 1:
            assert det.truth_star[0] == 0
            np.testing.assert_allclose(det.truth_xy[0], xy[0])
            assert xy[0, 0] < det.xy[0, 0] < xy[0, 0] + 0.5 * gap  # pulled toward the fainter spot, less than halfway


def test_saturation_flag_is_peak_plus_background_at_the_adc_limit():
    from startracker.centroid.fidelity import default_error_model

    cam = Camera(resolution=(512, 512))
    model = quiet(SensorModel.preset("paper000_cmos"))
    plan = ExposurePlan(1, 0.02)
    vmag = np.linspace(-1.0, 4.0, 16)
    xy = np.column_stack([np.linspace(30, 480, 16), np.full(16, 256.0)])
    sc = scene_from_tracks(cam, plan, xy, vmag)
    det = simulate_detections(sc, model, np.random.default_rng(0), "centroid", include_false=False)
    assert len(det) == 16
    bg = background_field(sc, model)
    s = det.truth_star
    var_b = bg.var_e(xy[s, 0], xy[s, 1]) + model.gain_e_per_dn**2 / 12
    th = reference_spot_theory(model.star_pe(vmag[s], np.zeros(16), 0.02), 1.0, 1.0, model.sigma_px, model.sigma_px,
                               1.0, np.zeros(16), var_b, 5 * np.sqrt(var_b), default_error_model(model), False)
    expect = (th["peak"] + bg.mean_e(xy[s, 0], xy[s, 1])) / model.gain_e_per_dn + model.bias_dn >= model.saturation_dn
    assert 0 < expect.sum() < 16
    np.testing.assert_array_equal(det.saturated, expect)
    np.testing.assert_allclose(det.peak, np.minimum(th["peak"] / model.gain_e_per_dn, model.saturation_dn - model.bias_dn))


def test_draws_are_fixed_by_the_inputs_not_by_the_outcomes():
    """Same geometry, different brightness (different detections): the generator ends in the same state."""
    cam = Camera(resolution=(256, 256))
    model = SensorModel.preset("paper000")
    plan = ExposurePlan(3, 1e-3, frame_period_s=0.1)
    xy = [[60.0, 60.0], [128.0, 180.0], [200.0, 90.0]]
    states = []
    for vmag in ([3.0, 4.0, 5.0], [9.0, 9.5, 10.0]):
        rng = np.random.default_rng(7)
        det = simulate_detections(scene_from_tracks(cam, plan, xy, vmag, np.full((3, 2), 300.0)), model, rng, "centroid")
        states.append((np.count_nonzero(det.truth_kind == KIND_STAR), rng.random()))
    assert states[0][0] == 9 and states[1][0] == 0
    assert states[0][1] == states[1][1]


def test_validate_false_gives_the_same_detections():
    cam = camera_preset("paper000")
    q0 = quat_random(np.random.default_rng(9))
    sc = compute_scene(cam, load_catalog(6.0), lambda t: quat_integrate(np.broadcast_to(q0, (len(t), 4)),
                                                                        np.radians([5.0, 3.0, 0.0]), t),
                       ExposurePlan(10, 1e-3), 0.0)
    model = SensorModel.preset("paper000")
    a = simulate_detections(sc, model, np.random.default_rng(1))
    b = simulate_detections(sc, model, np.random.default_rng(1), validate=False)
    for f in ("xy", "intensity", "area", "saturated", "peak", "snr", "truth_star", "truth_exposure", "truth_kind"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert np.all(np.diff(a.intensity) <= 0)


_DETERMINISM_SCRIPT = """
import hashlib, numpy as np
from startracker.catalog import load_catalog
from startracker.centroid import simulate_detections
from startracker.imaging import SensorModel
from startracker.optics import camera_preset
from startracker.rotations import quat_integrate, quat_random
from startracker.scene import ExposurePlan, compute_scene
rng = np.random.default_rng(31)
q0 = quat_random(rng)
t = np.linspace(0.0, 0.1, 11)
truth = (t, quat_integrate(np.broadcast_to(q0, (11, 4)), np.radians([9.0, -6.0, 1.0]), t))
sc = compute_scene(camera_preset("paper000"), load_catalog(6.0), truth, ExposurePlan(12, 1e-3), 0.0)
model = SensorModel.preset("paper000")
h = hashlib.sha256()
for _ in range(3):
    d = simulate_detections(sc, model, rng)
    for a in (sc.xy_path, d.xy, d.intensity, d.area, d.saturated, d.peak, d.snr, d.truth_star, d.truth_kind, d.truth_xy):
        h.update(np.ascontiguousarray(a).tobytes())
print(h.hexdigest())
"""


def test_same_seed_same_detections_across_processes_on_a_fresh_compile_cache(tmp_path):
    """Two interpreters, each compiling the kernels into its own empty numba cache: bit-identical scenes and
    detections, equal to this process's."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    procs = []
    for k in range(2):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / f"cache{k}"), PYTHONPATH=str(root))
        procs.append(subprocess.Popen([sys.executable, "-c", _DETERMINISM_SCRIPT], cwd=root, env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    outs = []
    for p in procs:
        out, errs = p.communicate(timeout=600)
        assert p.returncode == 0, errs
        outs.append(out.strip())
    assert any((tmp_path / "cache0").rglob("*.nbi"))  # the kernels were compiled into the fresh cache
    import io
    from contextlib import redirect_stdout

    buf = io.StringIO()
    with redirect_stdout(buf):
        exec(_DETERMINISM_SCRIPT, {})
    assert outs[0] == outs[1] == buf.getvalue().strip()


# ------------------------------------------------------------------------------------- compiled kernels
def _sparse_set(lin_all, n_px):
    """A sparse-set index over the given pixels, the way the renderer leaves it (stale entries elsewhere)."""
    buf = np.random.default_rng(0).integers(-5, len(lin_all) + 5, n_px).astype(np.int32)
    buf[lin_all] = np.arange(len(lin_all), dtype=np.int32)
    return buf


@pytest.mark.parametrize("seed", range(6))
def test_sparse_components_match_scipy_label(seed):
    """Components of a set of pixels given in any order == scipy.ndimage.label (8-connected) of the same pixels,
    numbered in order of first appearance; on small detectors and on one of over 2^22 pixels (three radix
    passes), with components across row ends (the last column is not next to the next row's first)."""
    from scipy import ndimage

    from startracker.kernels.centroid_extraction import sparse_components

    rng = np.random.default_rng(seed)
    n_rows, n_cols = [(23, 31), (61, 47), (2053, 2049)][seed % 3]
    density = 0.35 if n_rows * n_cols < 10_000 else 0.001
    mask = rng.random((n_rows, n_cols)) < density
    mask[n_rows // 2: n_rows // 2 + 9] |= rng.random((9, n_cols)) < 0.4  # a dense band, wrapping row ends
    order = rng.permutation(np.flatnonzero(mask))
    labels, n = sparse_components(order, n_rows, n_cols)
    ref, n_ref = ndimage.label(mask, structure=np.ones((3, 3)))
    assert n == n_ref
    ref_lab = ref.ravel()[order]
    pairs = set(zip(labels.tolist(), ref_lab.tolist()))
    assert len(pairs) == n  # a bijection between the two labellings
    first = [labels.tolist().index(k) for k in range(n)]
    assert first == sorted(first)


def test_sparse_detections_match_explicit_centre_of_mass():
    """detect_sparse on a frame given as sparse pixels: area, intensity, centre of mass (eqs. 1–3), peak and the
    brightest-first order equal an explicit numpy computation over scipy's components; the owner is the source
    with the largest charge in one of the component's pixels."""
    from scipy import ndimage

    from startracker.kernels.centroid_extraction import detect_sparse

    rng = np.random.default_rng(3)
    n_rows, n_cols = 40, 50
    img = 100.0 + rng.normal(0, 1.0, (n_rows, n_cols))
    for x0, y0, tot in [(10.3, 12.8, 900.0), (30.7, 8.1, 400.0), (40.2, 30.6, 2500.0), (11.5, 33.4, 150.0)]:
        img += gaussian_image((n_rows, n_cols), x0, y0, 1.1, tot, 0.0)
    img = np.rint(img)
    lin = rng.permutation(n_rows * n_cols).astype(np.int64)
    buf = _sparse_set(lin, n_rows * n_cols)
    dn = img.ravel()[lin]
    bgd = np.full(len(lin), 100.0)
    thr = np.full(len(lin), 104.0)
    # entries: every pixel owned by a random one of 7 sources with random charge
    ent_px = np.arange(len(lin), dtype=np.int64)
    ent_src = rng.integers(0, 7, len(lin)).astype(np.int64)
    ent_e = rng.random(len(lin))
    xy, inten, area, sat, peak, snr, owner = detect_sparse(lin, dn, bgd, thr, 110.0, 4.0, n_rows, n_cols, buf, False,
                                                           np.nan, 1, ent_px, ent_src, ent_e)
    mask = img > 104.0
    lab, n = ndimage.label(mask, structure=np.ones((3, 3)))
    sig = img - 100.0
    ids = np.arange(1, n + 1)
    ref_i = ndimage.sum(sig, lab, ids)
    ref_com = np.array(ndimage.center_of_mass(np.where(mask, sig, 0.0), lab, ids))[:, ::-1]
    ref_a = ndimage.sum(mask, lab, ids)
    ref_pk = ndimage.maximum(sig, lab, ids)
    o = np.argsort(-ref_i, kind="stable")
    assert len(xy) == n
    np.testing.assert_allclose(inten, ref_i[o], rtol=1e-12)
    np.testing.assert_allclose(xy, ref_com[o], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(area, ref_a[o])
    np.testing.assert_allclose(peak, ref_pk[o])
    np.testing.assert_array_equal(sat, ndimage.maximum(img, lab, ids)[o] >= 110.0)
    np.testing.assert_allclose(snr, ref_i[o] / (1.0 * np.sqrt(ref_a[o])))
    e_img = np.zeros(n_rows * n_cols)
    e_img[lin] = ent_e
    s_img = np.zeros(n_rows * n_cols, dtype=np.int64)
    s_img[lin] = ent_src
    for k, comp in enumerate(ids[o]):
        px = np.flatnonzero(lab.ravel() == comp)
        assert owner[k] == s_img[px[np.argmax(e_img[px])]]


def test_sparse_gaussian_interpolation_matches_the_full_frame_path():
    """The compiled sparse path and extract_centroids (shared measuring kernels, scipy components) give the same
    Gaussian-interpolated centroids on the same noiseless frame; both recover the spot centres."""
    from startracker.kernels.centroid_extraction import detect_sparse

    n_rows, n_cols = 64, 64
    centres = [(20.3, 22.8), (44.7, 15.1), (40.2, 47.6)]
    img = sum(gaussian_image((n_rows, n_cols), x0, y0, 1.2, 3000.0, 0.0) for x0, y0 in centres) + 100.0
    full = extract_centroids(img, 5.0, "gaussian", psf_sigma_px=1.2, background="global")
    lin = np.arange(n_rows * n_cols, dtype=np.int64)
    buf = _sparse_set(lin, n_rows * n_cols)
    lvl = full.background_dn
    thr = lvl + 5.0 * full.noise_dn
    xy, *_ = detect_sparse(lin, img.ravel(), np.full(lin.size, lvl), np.full(lin.size, thr), 1e9, 5.0, n_rows, n_cols,
                           buf, True, 1.2, 1, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))
    np.testing.assert_allclose(xy, full.xy, atol=1e-12)
    truth = np.array(centres)
    for p in xy:
        assert np.min(np.hypot(*(truth - p).T)) < 1e-3


def test_truth_labels_gather_the_owners_rows():
    """truth_labels equals a plain per-detection lookup of the owner's row (no owner: noise kind, −1, −1, NaN)."""
    from startracker.kernels.centroid_extraction import truth_labels

    rng = np.random.default_rng(11)
    q = 30
    kind = rng.integers(0, 5, q).astype(np.int64)
    star = rng.integers(-1, 100, q).astype(np.int64)
    expo = rng.integers(-1, 4, q).astype(np.int64)
    xy = rng.uniform(0, 1000, (q, 2))
    owner = rng.integers(-1, q, 50).astype(np.int64)
    owner[:3] = -1
    t_kind, t_star, t_exp, t_xy = truth_labels(owner, kind, star, expo, xy, 1)
    for i, o in enumerate(owner):
        if o < 0:
            assert (t_kind[i], t_star[i], t_exp[i]) == (1, -1, -1)
            assert np.isnan(t_xy[i]).all()
        else:
            assert (t_kind[i], t_star[i], t_exp[i]) == (kind[o], star[o], expo[o])
            assert t_xy[i, 0] == xy[o, 0] and t_xy[i, 1] == xy[o, 1]
    assert t_kind.dtype == t_star.dtype == t_exp.dtype == np.int64
    empty = truth_labels(np.zeros(0, dtype=np.int64), kind, star, expo, xy, 1)
    assert [len(a) for a in empty] == [0, 0, 0, 0] and empty[3].shape == (0, 2)
