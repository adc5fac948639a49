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


# ------------------------------------------------------------------------------------- compiled kernels
def _sparse_set(lin_all, n_px):
    """A sparse-set index over the given pixels, the way the renderer leaves it (stale entries elsewhere)."""
    buf = np.random.default_rng(0).integers(-5, len(lin_all) + 5, n_px).astype(np.int32)
    buf[lin_all] = np.arange(len(lin_all), dtype=np.int32)
    return buf


@pytest.mark.parametrize("seed", range(6))
def test_sparse_components_match_scipy_label(seed):
    """Components over a sparse pixel set == scipy.ndimage.label (8-connected) of the same pixels, numbered in
    order of first appearance; pixels outside the set never connect."""
    from scipy import ndimage

    from startracker.kernels.centroid_extraction import sparse_components

    rng = np.random.default_rng(seed)
    n_rows, n_cols = 23, 31
    mask = rng.random((n_rows, n_cols)) < 0.35
    above = rng.permutation(np.flatnonzero(mask))
    others = rng.permutation(np.flatnonzero(~mask))[: int(rng.integers(0, (~mask).sum()))]
    lin = np.concatenate([above, others])[rng.permutation(len(above) + len(others))]
    buf = _sparse_set(lin, n_rows * n_cols)
    pos = np.full(len(lin), -1, dtype=np.int64)
    where = {p: i for i, p in enumerate(lin)}
    order = np.array(sorted(above, key=lambda p: where[p]), dtype=np.int64)  # above pixels in set order
    for j, p in enumerate(order):
        pos[where[p]] = j
    labels, n = sparse_components(order, n_rows, n_cols, buf, lin, pos)
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
