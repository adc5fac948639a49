"""Star colour (B−V -> T -> channel electrons) and the 3CMOS channel optics (paper 004 eqs. 1-3, 21-23)."""

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from startracker.color import (
    BANDS_NM,
    ChannelResponse,
    ColorCamera,
    RegistrationParams,
    bv_to_teff,
    planck_photon_radiance,
)
from startracker.optics import Camera, camera_preset

# --------------------------------------------------------------------------------------- colour


def test_ballesteros_sun():
    """Ballesteros (2012) gives the Sun's 5778 K for its B−V = 0.65, and T falls with B−V."""
    assert bv_to_teff(0.65) == pytest.approx(5778, rel=2e-3)
    t = bv_to_teff(np.linspace(-0.4, 5.4, 100))
    assert np.all(np.diff(t) < 0)
    assert bv_to_teff(0.0) == pytest.approx(4600 * (1 / 1.7 + 1 / 0.62))


def test_planck_photon_peak_follows_wien():
    """Photon spectrum per wavelength peaks at λT = hc / (x k), x = 4 (1 - e^-x) (x ≈ 3.9207)."""
    x = brentq(lambda x: x - 4 * (1 - np.exp(-x)), 1, 10)
    lam = np.linspace(100, 3000, 290001)
    for t in (3000.0, 5778.0, 12000.0):
        spec = planck_photon_radiance(lam, t)
        assert lam[np.argmax(spec)] == pytest.approx(6.62607015e-34 * 299792458 / 1.380649e-23 / x / t * 1e9, abs=0.02)


def test_ratio_ordering_hot_and_cool_stars():
    r = ChannelResponse()
    e = r.electrons([-0.3, 0.0, 0.65, 1.6])  # B-type, A0 (Vega), Sun, M giant
    red, green, blue = e.T
    assert blue[0] > green[0] > red[0]  # hot star: blue-rich
    assert red[3] > green[3] > blue[3]  # cool star: red-rich
    assert red[2] > blue[2]  # the Sun is already redder than blue in these bands
    ratio = r.color_ratio(np.linspace(-0.4, 5.4, 60))
    assert np.all(np.diff(ratio) > 0)
    np.testing.assert_allclose(r.fractions([0.3, 1.0]).sum(axis=1), 1.0)


def test_channel_integral_matches_quadrature_for_flat_qe():
    """With QE = 1, each channel is the band integral of the Planck photon spectrum (scipy quad)."""
    r = ChannelResponse(qe_wavelength_nm=(300, 800), qe=(1.0, 1.0), step_nm=0.5)
    for bv in (-0.2, 0.65, 1.5):
        t = float(bv_to_teff(bv))
        ref = np.array([quad(lambda lam: planck_photon_radiance([lam], t)[0], *BANDS_NM[c])[0]
                        for c in ("red", "green", "blue")])
        e = r.electrons([bv])[0]
        np.testing.assert_allclose(e / e[1], ref / ref[1], rtol=2e-5)


def test_equal_v_normalisation():
    """A B−V = 0 star gives a channel sum of 1; equal-V stars collect comparable total signal."""
    r = ChannelResponse()
    assert r.electrons([0.0]).sum() == pytest.approx(1.0, abs=1e-12)
    tot = r.electrons([-0.3, 0.65, 1.5]).sum(axis=1)
    assert np.all((tot > 0.8) & (tot < 1.5))
    # the V band sits in the green channel: green electrons of equal-V stars vary far less than red or blue
    e = r.electrons(np.linspace(-0.3, 1.8, 30))
    spread = e.max(axis=0) / e.min(axis=0)
    assert spread[1] < spread[0] and spread[1] < spread[2]


def test_colour_bad_input():
    with pytest.raises(ValueError, match="bv"):
        bv_to_teff([0.1, np.nan])
    with pytest.raises(ValueError, match="bv"):
        bv_to_teff(-0.8)
    with pytest.raises(ValueError, match="teff_k"):
        planck_photon_radiance([500.0], -10.0)
    with pytest.raises(ValueError, match="bands_nm"):
        ChannelResponse(bands_nm={"red": (580, 680), "green": (490, 590)})
    with pytest.raises(ValueError, match="bands_nm"):
        ChannelResponse(bands_nm={"red": (680, 580), "green": (490, 590), "blue": (400, 500)})
    with pytest.raises(ValueError, match="qe"):
        ChannelResponse(qe_wavelength_nm=(400, 500), qe=(0.5, 1.5))


# ------------------------------------------------------------------------------------- channels


def test_paper004_preset_matches_table1_and_green_camera():
    cc = ColorCamera.paper004()
    assert [c.focal_length_mm for c in cc.cameras] == [25.0601, 25.0, 24.95]
    assert [c.principal_point for c in cc.cameras] == [(1033.9, 774.3), (1032.0, 772.0), (1030.6, 770.4)]
    assert [c.distortion_k1_per_mm2 for c in cc.cameras] == [5.7e-5, 4.9e-5, 3.6e-5]
    assert np.degrees(cc.rotation_rad) == pytest.approx([0.07, 0.0, -0.05])
    fov = cc.green.fov_deg
    assert fov[0] == pytest.approx(16.1, abs=0.2) and fov[1] == pytest.approx(12.1, abs=0.2)
    v = np.random.default_rng(0).normal([0, 0, 8], 1, (100, 3))
    np.testing.assert_allclose(cc.project_channel("green", v)[0], camera_preset("paper004").project(v)[0])


def test_channel_projection_follows_eq22():
    """Red channel written out from eq. 22: rotate (F_r v/v_z + δ_r) by [[c, s], [-s, c]], add x0_r."""
    cc = ColorCamera.paper004()
    rng = np.random.default_rng(1)
    v = np.column_stack([rng.uniform(-0.12, 0.12, 50), rng.uniform(-0.09, 0.09, 50), np.ones(50)])
    for i, name in ((0, "red"), (2, "blue")):
        cam = cc.cameras[i]
        f_mm, m, p_mm = cam.focal_length_mm, cam.distortion_k1_per_mm2, cam.pixel_size_um * 1e-3
        xp, yp = f_mm * v[:, 0] / v[:, 2], f_mm * v[:, 1] / v[:, 2]
        r2 = xp**2 + yp**2
        ux, uy = (xp + xp * m * r2) / p_mm, (yp + yp * m * r2) / p_mm
        th = cc.rotation_rad[i]
        want = np.column_stack([np.cos(th) * ux + np.sin(th) * uy + cam.principal_point[0],
                                -np.sin(th) * ux + np.cos(th) * uy + cam.principal_point[1]])
        xy, inside = cc.project_channel(name, v)
        np.testing.assert_allclose(xy, want, atol=1e-9)
        assert inside.all()
        np.testing.assert_allclose(cc.unproject_channel(name, xy), v / np.linalg.norm(v, axis=1, keepdims=True),
                                   atol=1e-12)
    xy3, in3 = cc.project(v)
    assert xy3.shape == (3, 50, 2) and in3.shape == (3, 50)


def test_color_camera_bad_input():
    kw = dict(resolution=(2064, 1544), pixel_size_um=3.45, focal_length_mm=25.0)
    g = Camera(**kw)
    with pytest.raises(ValueError, match="resolution"):
        ColorCamera(red=Camera(**{**kw, "resolution": (2048, 1544)}), green=g, blue=g)
    with pytest.raises(ValueError, match="pixel_size_um"):
        ColorCamera(red=Camera(**{**kw, "pixel_size_um": 3.5}), green=g, blue=g)
    with pytest.raises(ValueError, match="q_cam_to_body"):
        ColorCamera(red=Camera(**kw, q_cam_to_body=(0.0, 1.0, 0.0, 0.0)), green=g, blue=g)
    with pytest.raises(ValueError, match="rotation_rad"):
        ColorCamera(red=g, green=g, blue=g, rotation_rad=(0.0, 0.01, 0.0))
    with pytest.raises(TypeError, match="blue"):
        ColorCamera(red=g, green=g, blue="camera")
    with pytest.raises(ValueError, match="channel"):
        ColorCamera(red=g, green=g, blue=g).project_channel("yellow", [0, 0, 1])
    with pytest.raises(ValueError, match="translation"):
        ColorCamera.paper004(translation="table3")


# ------------------------------------------------------------------------------ imaging and fusion
from dataclasses import replace  # noqa: E402

from scipy.spatial import cKDTree  # noqa: E402
from scipy.stats import spearmanr  # noqa: E402

from startracker.catalog import StarCatalog, load_catalog  # noqa: E402
from startracker.centroid import extract_centroids  # noqa: E402
from startracker.color import (  # noqa: E402
    ColorRegistration,
    aperture_photometry,
    channel_scenes,
    color_ratio_from_fluxes,
    fuse_channel_centroids,
    fuse_channel_images,
    generate_rotary_table_data,
    paper004_sensor_model,
    render_color_frame,
)
from startracker.imaging import render_expected  # noqa: E402
from startracker.rotations import quat_multiply, quat_random  # noqa: E402
from startracker.scene import ExposurePlan  # noqa: E402


def _static(q):
    return lambda t: np.tile(q, (len(t), 1))


def test_channel_magnitudes_follow_each_cameras_response():
    """A channel's magnitude is V − 2.5 log10 e_c(B−V) of that camera's own response: the per-catalog table is shared
    by equal responses (each env builds its own camera) and never by different ones."""
    v = np.array([[0.05, -0.03, 1.0], [-0.08, 0.06, 1.0]])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    cat = StarCatalog(hip=np.array([1, 2]), vectors=v, vmag=np.array([4.0, 4.5]), bv=np.array([-0.2, 1.4]))
    plan = ExposurePlan(1, 0.05, frame_period_s=0.1)
    narrow = ChannelResponse(bands_nm={"red": (620.0, 680.0), "green": (500.0, 560.0), "blue": (400.0, 440.0)})
    for response in (ChannelResponse(), narrow, ChannelResponse(), narrow):
        cc = ColorCamera.paper004(response=response)  # a new camera each time, as a new env makes
        scenes = channel_scenes(cc, cat, _static(np.array([1.0, 0, 0, 0])), plan)
        e = response.electrons(cat.bv)
        for i, sc in enumerate(scenes):
            order = np.argsort(sc.hip)
            np.testing.assert_allclose(sc.vmag[order], cat.vmag - 2.5 * np.log10(e[:, i]), rtol=0, atol=1e-12)


def test_channel_scenes_geometry_and_light_share():
    """Each channel's scene puts a star where that channel's optics do, with its colour's share of light."""
    cc = ColorCamera.paper004()
    v = np.array([[0.05, -0.03, 1.0], [-0.08, 0.06, 1.0]])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    cat = StarCatalog(hip=np.array([1, 2]), vectors=v, vmag=np.array([4.0, 4.5]), bv=np.array([-0.2, 1.4]))
    plan = ExposurePlan(1, 0.05, frame_period_s=0.1)
    scenes = channel_scenes(cc, cat, _static(np.array([1.0, 0, 0, 0])), plan)
    model = paper004_sensor_model(prnu_sigma=0.0)
    charge = []
    for i, sc in enumerate(scenes):
        order = np.argsort(sc.hip)
        np.testing.assert_allclose(sc.xy[0][order], cc.project_channel(i, v)[0], atol=1e-9)
        img = render_expected(sc, model, include_background=False)
        cols = np.arange(img.shape[1])[None, :]
        rows = np.arange(img.shape[0])[:, None]
        per_star = []
        for xy in sc.xy[0][order]:
            near = (np.abs(cols - xy[0]) < 12) & (np.abs(rows - xy[1]) < 12)
            per_star.append(img[near].sum())
        charge.append(per_star)
    charge = np.array(charge).T  # (2 stars, 3 channels)
    share = cc.response.electrons(cat.bv)
    pe_v0 = model.star_pe(cat.vmag, np.zeros(2), 0.05)
    np.testing.assert_allclose(charge, pe_v0[:, None] * share, rtol=1e-6)
    assert charge[0, 2] > charge[0, 0] and charge[1, 0] > charge[1, 2]  # hot star blue, cool star red


def _assign(xy, truth, radius=2.0):
    """Detections -> nearest true star within radius: dict star -> error vector."""
    d, j = cKDTree(truth).query(xy, distance_upper_bound=radius)
    out = {}
    for k in np.flatnonzero(np.isfinite(d)):
        out.setdefault(int(j[k]), xy[k] - truth[j[k]])
    return out, int(np.sum(~np.isfinite(d)))


@pytest.fixture(scope="module")
def color_frames():
    cc = ColorCamera.paper004()
    cat = load_catalog(7.5)
    rng = np.random.default_rng(2024)
    reg = ColorRegistration.calibrate(generate_rotary_table_data(cc, rng), rng)
    model = paper004_sensor_model()
    plan = ExposurePlan(1, 0.02, frame_period_s=0.1)
    frames = []
    for _ in range(3):
        scenes = channel_scenes(cc, cat, _static(quat_random(rng)), plan)
        frames.append((scenes, render_color_frame(scenes, model, rng)))
    return cc, reg, model, frames


def test_fused_centroids_beat_single_channel(color_frames):
    cc, reg, model, frames = color_frames
    err = {"green": [], "centroid-fusion": [], "image-fusion": []}
    false = {"green": 0, "centroid-fusion": 0, "image-fusion": 0}
    for scenes, images in frames:
        cents = [extract_centroids(im) for im in images]
        fused_c = fuse_channel_centroids(cents, reg, gain_e_per_dn=model.gain_e_per_dn)
        fused_i = extract_centroids(fuse_channel_images(images, reg))
        g = scenes[1]
        truth = g.xy_mean[0][g.visible[0]]
        res = {}
        for name, xy in (("green", cents[1].xy), ("centroid-fusion", fused_c.xy), ("image-fusion", fused_i.xy)):
            res[name], n_false = _assign(xy, truth)
            false[name] += n_false
        common = set(res["green"]) & set(res["centroid-fusion"]) & set(res["image-fusion"])
        for name in err:
            err[name] += [res[name][s] for s in common]
    rms = {k: float(np.sqrt(np.mean(np.sum(np.array(v) ** 2, axis=1)))) for k, v in err.items()}
    assert len(err["green"]) >= 40
    assert rms["centroid-fusion"] < 0.85 * rms["green"]
    assert rms["image-fusion"] < 0.85 * rms["green"]
    # a cosmic ray or hot pixel hits one detector: requiring two channels removes what only one sees
    assert false["centroid-fusion"] < 0.2 * max(false["green"], 1)


def test_measured_colour_ratio_tracks_bv(color_frames):
    cc, reg, model, frames = color_frames
    meas, expect, bv = [], [], []
    for scenes, images in frames:
        fused = fuse_channel_centroids([extract_centroids(im) for im in images], reg,
                                       gain_e_per_dn=model.gain_e_per_dn)
        g = scenes[1]
        vis = np.flatnonzero(g.visible[0])
        d, j = cKDTree(g.xy_mean[0][vis]).query(fused.xy, distance_upper_bound=2.0)
        ok = np.isfinite(d)
        ratio, valid = color_ratio_from_fluxes(aperture_photometry(images, fused.xy[ok], reg))
        star_bv = g.bv[vis[j[ok]]]
        meas += list(ratio[valid])
        bv += list(star_bv[valid])
        expect += list(cc.response.color_ratio(star_bv[valid]))
    meas, expect, bv = map(np.array, (meas, expect, bv))
    assert len(meas) >= 40
    assert spearmanr(meas, bv).statistic > 0.85
    assert np.median(np.abs(meas - expect)) < 0.15  # ln-ratio: ~15 % on the flux ratio
    assert np.median(meas[bv < 0.2]) < np.median(meas[bv > 1.0]) - 0.8


def test_fusion_bad_input():
    reg = ColorRegistration(
        red=RegistrationParams(k=1.0, theta_rad=0.0, dx_px=0.0, dy_px=0.0, principal_point=(10, 10)),
        blue=RegistrationParams(k=1.0, theta_rad=0.0, dx_px=0.0, dy_px=0.0, principal_point=(10, 10)))
    ims = np.zeros((3, 20, 30), np.float32)
    with pytest.raises(ValueError, match="one shape"):
        fuse_channel_images([ims[0], ims[1], np.zeros((20, 31))], reg)
    bad = ims.copy()
    bad[2, 3, 4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fuse_channel_images(bad, reg)
    with pytest.raises(ValueError, match="3 channel"):
        fuse_channel_centroids([None, None], reg)
    with pytest.raises(ValueError, match="match_radius_px"):
        fuse_channel_centroids([None] * 3, reg, match_radius_px=0.0)
    with pytest.raises(ValueError, match="registration failed"):
        ColorRegistration(red=replace(reg.red, success=False, status="collinear"), blue=reg.blue)
    with pytest.raises(ValueError, match="xy_green"):
        aperture_photometry(ims, [[np.nan, 3.0]], reg)
    with pytest.raises(ValueError, match="color_term_per_bv"):
        cc = ColorCamera.paper004()
        cat = StarCatalog(hip=np.array([1]), vectors=np.array([[0, 0, 1.0]]), vmag=np.array([4.0]), bv=np.array([0.5]))
        scenes = channel_scenes(cc, cat, _static(np.array([1.0, 0, 0, 0])), ExposurePlan(1, 0.01))
        m = paper004_sensor_model()
        render_color_frame(scenes, replace(m, photometry=replace(m.photometry, color_term_per_bv=0.1)),
                           np.random.default_rng(0))


# ------------------------------------------------------------------------ colour-aided identification
from startracker.color import build_color_database, identify_color  # noqa: E402
from startracker.identify import identify  # noqa: E402
from startracker.simulation import simulate_identification_frame  # noqa: E402


def test_color_identification_at_least_as_accurate_as_monochrome():
    """Same frames, same database: colour pruning never loses a correct identification, never mislabels,
    keeps a minority of the geometric pair candidates, and rescues frames with few stars."""
    cc = ColorCamera.paper004()
    cam = cc.channel_camera("green")
    cat = load_catalog(6.0)
    cdb = build_color_database(cat, cam)
    ratio_of = dict(zip(cdb.db.nav.hip.tolist(), cdb.star_ratio.tolist()))
    rng = np.random.default_rng(7)
    counts = {"mono": {"correct": 0, "mislabel": 0}, "color": {"correct": 0, "mislabel": 0}}
    kept = []
    for scen in (dict(sigma_px=0.5, n_false=2), dict(sigma_px=1.0, max_stars=5)):
        for _ in range(25):
            f = simulate_identification_frame(cat, cam, quat_random(rng), rng, **scen)
            cr = np.array([ratio_of.get(h, np.nan) if h >= 0 else rng.choice(cdb.star_ratio) for h in f.hip])
            cr = cr + rng.normal(0, 0.1, len(cr))
            mono = identify(f.xy, cam, cat, "pyramid", f.intensities, database=cdb.db, sigma_px=scen["sigma_px"])
            col, pr = identify_color(f.xy, cam, cat, cr, 0.1, f.intensities, database=cdb,
                                     sigma_px=scen["sigma_px"], return_pruning=True)
            kept.append(pr.kept_fraction)
            for name, r in (("mono", mono), ("color", col)):
                true = f.hip >= 0
                if r.success:
                    bad = np.any((r.star_ids[true] != -1) & (r.star_ids[true] != f.hip[true]))
                    counts[name]["mislabel"] += int(bad)
                    counts[name]["correct"] += int(not bad and r.n_matched >= 3)
    assert counts["color"]["correct"] >= counts["mono"]["correct"]
    assert counts["color"]["mislabel"] <= counts["mono"]["mislabel"] == 0
    assert counts["color"]["correct"] > counts["mono"]["correct"]  # the 5-star frames
    assert np.median(kept) < 0.5


def test_color_identification_end_to_end_from_pixels(color_frames):
    """Fused detections and aperture colours of rendered 3CMOS frames identify with the right HIPs."""
    cc, reg, model, frames = color_frames
    cam = cc.channel_camera("green")
    cat = load_catalog(6.0)  # the frames hold stars to V 7.5: the fainter ones stay unlabelled
    n_ok = 0
    for scenes, images in frames:
        fused = fuse_channel_centroids([extract_centroids(im) for im in images], reg,
                                       gain_e_per_dn=model.gain_e_per_dn)
        ratio, valid = color_ratio_from_fluxes(aperture_photometry(images, fused.xy, reg))
        r = identify_color(fused.xy, cam, cat, np.where(valid, ratio, np.nan), 0.15,
                           fused.total_intensity, sigma_px=0.5)
        assert r.success, r.status
        g = scenes[1]
        d, j = cKDTree(g.xy_mean[0]).query(fused.xy)
        labelled = r.star_ids >= 0
        assert np.all(r.star_ids[labelled] == g.hip[j[labelled]])
        n_ok += int(labelled.sum() >= 5)
    assert n_ok == len(frames)


def test_color_identification_bad_input():
    cam = ColorCamera.paper004().channel_camera("green")
    cat = load_catalog(6.0)
    xy = np.array([[100.0, 200.0], [300.0, 400.0], [500.0, 600.0]])
    with pytest.raises(ValueError, match="color_ratio"):
        identify_color(xy, cam, cat, [0.1, 0.2])
    with pytest.raises(ValueError, match="color_ratio"):
        identify_color(xy, cam, cat, [0.1, np.inf, 0.2])
    with pytest.raises(ValueError, match="color_sigma"):
        identify_color(xy, cam, cat, [0.1, 0.2, 0.3], color_sigma=-1.0)
    r = identify_color(xy[:2], cam, cat, [0.1, 0.2])
    assert not r.success and "fewer than 3" in r.status


def _mutual_nearest_reference(a, b, radius):
    """Mutual nearest neighbours within ``radius`` by two k-d trees (the independent truth)."""
    da, ja = cKDTree(b).query(a, k=1, distance_upper_bound=radius)
    _, ib = cKDTree(a).query(b, k=1, distance_upper_bound=radius)
    i = np.flatnonzero(np.isfinite(da))
    keep = ib[ja[i]] == i
    return i[keep], ja[i][keep]


def test_mutual_nearest_kernel_matches_kdtrees():
    """The compiled pairing of two channels' centroids finds the same mutual-nearest pairs as two k-d trees."""
    from startracker.kernels.color import mutual_nearest

    rng = np.random.default_rng(7)
    for k, m in ((0, 5), (5, 0), (1, 1), (40, 35), (200, 180)):
        a = rng.uniform(0, 60, (k, 2))
        b = np.concatenate([a[: min(k, m)] + rng.normal(0, 0.7, (min(k, m), 2)), rng.uniform(0, 60, (m - min(k, m), 2))])
        i, j = mutual_nearest(a, b, 2.0)
        if k and m:
            ri, rj = _mutual_nearest_reference(a, b, 2.0)
        else:
            ri = rj = np.zeros(0, dtype=np.int64)
        np.testing.assert_array_equal(i, ri)
        np.testing.assert_array_equal(j, rj)
        assert np.all(np.hypot(*(a[i] - b[j]).T) < 2.0)


def test_fusion_without_validation_is_the_same(color_frames):
    """The per-frame call (``validate=False``) fuses exactly as the checked call does."""
    cc, reg, model, frames = color_frames
    scenes, images = frames[0]
    cents = [extract_centroids(im) for im in images]
    a = fuse_channel_centroids(cents, reg, gain_e_per_dn=model.gain_e_per_dn)
    b = fuse_channel_centroids(cents, reg, gain_e_per_dn=model.gain_e_per_dn, validate=False)
    assert len(a) > 5
    for name in ("xy", "intensity", "channel_index", "n_channels", "has_color"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(np.isnan(a.color_ratio), np.isnan(b.color_ratio))


def _fusion_reference(cs, reg, radius, min_channels, gain):
    """The fusion rule written out with numpy and k-d trees (the independent truth of the compiled fusion)."""
    xy = [reg.to_green(i, c.xy) if len(c.xy) else c.xy for i, c in enumerate(cs)]
    var = [(np.maximum(c.intensity, 1e-9) / gain + c.area * c.noise_dn ** 2) / np.maximum(c.intensity, 1e-9) ** 2
           for c in cs]
    rows = [[r, g, b] for g, (r, b) in enumerate(zip([-1] * len(xy[1]), [-1] * len(xy[1])))]
    for ch in (0, 2):
        if len(xy[1]) and len(xy[ch]):
            for g, j in zip(*_mutual_nearest_reference(xy[1], xy[ch], radius)):
                rows[g][ch] = j
    free = [np.setdiff1d(np.arange(len(xy[ch])), [r[ch] for r in rows]) for ch in (0, 1, 2)]
    ri, bi = (_mutual_nearest_reference(xy[0][free[0]], xy[2][free[2]], radius) if len(free[0]) and len(free[2])
              else (np.zeros(0, int), np.zeros(0, int)))
    rows += [[free[0][i], -1, free[2][j]] for i, j in zip(ri, bi)]
    if min_channels == 1:
        rows += [[i, -1, -1] for i in np.setdiff1d(free[0], free[0][ri])]
        rows += [[-1, -1, j] for j in np.setdiff1d(free[2], free[2][bi])]
    rows = [r for r in rows if sum(v >= 0 for v in r) >= min_channels]
    out = []
    for r in rows:
        w = np.array([1.0 / var[ch][r[ch]] if r[ch] >= 0 else 0.0 for ch in range(3)])
        p = np.array([xy[ch][r[ch]] if r[ch] >= 0 else [0.0, 0.0] for ch in range(3)])
        it = np.array([cs[ch].intensity[r[ch]] if r[ch] >= 0 else 0.0 for ch in range(3)])
        out.append((w @ p / w.sum(), it, r))
    out.sort(key=lambda o: -o[1].sum())  # stable: ties keep their order
    return out


def test_compiled_fusion_follows_the_fusion_rule(color_frames):
    """The compiled centroid-level fusion against the rule written out here: pairs, lone spots per min_channels,
    inverse-variance positions, brightest first, colour ratio where red and blue both see the star."""
    from types import SimpleNamespace

    cc, reg, model, _ = color_frames
    rng = np.random.default_rng(11)
    truth = rng.uniform(40, 2000, (60, 2))
    cs = []
    for ch in range(3):
        seen = rng.random(len(truth)) < 0.8
        p = reg.from_green(ch, truth[seen]) + rng.normal(0, 0.2, (seen.sum(), 2))
        p = np.concatenate([p, rng.uniform(0, 2048, (5, 2))])  # lone spots (cosmic rays, hot pixels)
        cs.append(SimpleNamespace(xy=p, intensity=rng.uniform(50, 5000, len(p)),
                                  area=rng.integers(1, 30, len(p)).astype(np.int64), noise_dn=1.5 + ch))
    for min_channels in (1, 2, 3):
        got = fuse_channel_centroids(cs, reg, min_channels=min_channels, gain_e_per_dn=0.5)
        want = _fusion_reference(cs, reg, 2.0, min_channels, 0.5)
        assert len(got) == len(want) > 30
        np.testing.assert_allclose(got.xy, [o[0] for o in want], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(got.intensity, [o[1] for o in want])
        np.testing.assert_array_equal(got.channel_index, [o[2] for o in want])
        np.testing.assert_array_equal(got.n_channels, [sum(v >= 0 for v in o[2]) for o in want])
        both = np.array([o[2][0] >= 0 and o[2][2] >= 0 for o in want])
        np.testing.assert_array_equal(got.has_color, both)
        np.testing.assert_allclose(got.color_ratio[both], [np.log(o[1][0] / o[1][2]) for o, b in zip(want, both) if b],
                                   rtol=1e-14)
        assert np.all(np.isnan(got.color_ratio[~both]))
    # a channel whose noise is unknown (NaN) is weighted as noiseless: photon noise alone
    unknown = [SimpleNamespace(**{**vars(c), "noise_dn": np.nan if ch == 1 else c.noise_dn}) for ch, c in enumerate(cs)]
    noiseless = [SimpleNamespace(**{**vars(c), "noise_dn": 0.0 if ch == 1 else c.noise_dn}) for ch, c in enumerate(cs)]
    got = fuse_channel_centroids(unknown, reg, min_channels=2, gain_e_per_dn=0.5)
    want = _fusion_reference(noiseless, reg, 2.0, 2, 0.5)
    np.testing.assert_allclose(got.xy, [o[0] for o in want], rtol=0, atol=1e-9)


def test_fused_simulation_is_the_channels_simulated_then_fused(color_frames):
    """The 3CMOS per-frame path (three channels' centroid-fidelity detections and their fusion in one compiled call)
    gives exactly the fusion of the three channels simulated one by one, and leaves the generator where they do."""
    from startracker.centroid import simulate_detections
    from startracker.color import simulate_fused_detections

    cc, reg, model, _ = color_frames
    cat = load_catalog(7.0)
    # a brighter sky and busy false objects, so that every kind of detection and both noise terms take part
    busy = replace(model, cosmic_ray_rate_per_cm2_s=20.0, debris_rate_per_frame=2.0, hot_pixel_fraction=2e-5)
    rng = np.random.default_rng(5)
    n_fused = 0
    for frame in range(6):
        q = quat_random(rng)
        omega = np.radians([0.0, 6.0 * frame, 2.0])  # still to smeared frames
        plan = ExposurePlan(1, 0.02, frame_period_s=0.1)
        t = np.linspace(0.0, 0.1, 11)
        half = 0.5 * np.outer(t, omega)
        ang = np.linalg.norm(half, axis=1, keepdims=True)
        dq = np.hstack([np.cos(ang), np.where(ang > 0, np.sin(ang) / np.maximum(ang, 1e-300), 1.0) * half])
        truth = (t, quat_multiply(np.tile(q, (len(t), 1)), dq))
        scenes = channel_scenes(cc, cat, truth, plan)
        for md, min_channels in ((model, 2), (busy, 1), (busy, 3)):
            seed = int(rng.integers(1 << 31))
            r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
            want = fuse_channel_centroids([simulate_detections(sc, md, r1) for sc in scenes], reg,
                                          min_channels=min_channels, gain_e_per_dn=md.gain_e_per_dn)
            got = simulate_fused_detections(scenes, md, r2, reg, min_channels=min_channels)
            for name in ("xy", "intensity", "channel_index", "n_channels", "has_color", "color_ratio"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
            assert r1.bit_generator.state == r2.bit_generator.state
            n_fused += len(got)
    assert n_fused > 100
    with pytest.raises(TypeError, match="scenes"):
        simulate_fused_detections(scenes[:2], model, rng, reg)
    with pytest.raises(TypeError, match="registration"):
        simulate_fused_detections(scenes, model, rng, None)
    with pytest.raises(ValueError, match="min_channels"):
        simulate_fused_detections(scenes, model, rng, reg, min_channels=0)
    with pytest.raises(ValueError, match="match_radius_px"):
        simulate_fused_detections(scenes, model, rng, reg, match_radius_px=-1.0)
