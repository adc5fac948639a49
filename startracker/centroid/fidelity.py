"""The centroid-fidelity model: detections drawn from scene truth without pixels.

Fidelities of :func:`simulate_detections`
-----------------------------------------
* ``"pixel"``: :func:`startracker.imaging.render_sparse` then the same components and measurements on
  the sparse pixels (connectivity by a neighbour graph, ``scipy.sparse.csgraph``), with the threshold
  at the known background.
* ``"centroid"``: no pixels. Each spot's detection probability, centroid noise (along and across the
  smear) and intensity follow the linearised theory of a thresholded centre of mass on the same
  detector model, with three factors calibrated against the pixel path (:class:`CentroidErrorModel`,
  :func:`calibrate_error_model`); hot pixels, cosmic rays, debris and the background's threshold
  crossings are drawn from the same statistics as in the pixel path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import erf, ndtr

from startracker.centroid.extraction import (
    Centroids,
    check_k_sigma,
    check_method,
    check_min_area,
    check_psf_sigma,
    detections_from_sparse,
)
from startracker.imaging import (
    COSMIC_SIGMA_PX,
    KIND_COSMIC_RAY,
    KIND_DEBRIS,
    KIND_HOT_PIXEL,
    KIND_NOISE,
    KIND_STAR,
    FalseObjects,
    SensorModel,
    background_field,
    draw_false_objects,
    draw_false_pixels,
    fixed_pattern,
    render_sparse,
)
from startracker.scene import Scene

__all__ = [
    "CentroidErrorModel",
    "DEFAULT_ERROR_MODELS",
    "default_error_model",
    "simulate_detections",
    "calibrate_error_model",
    "candidate_pairs",
    "grid_scene",
]


# ------------------------------------------------------------------------------------------ centroid fidelity
@dataclass(frozen=True)
class CentroidErrorModel:
    """Calibration factors of the centroid-fidelity theory (module docstring).

    Attributes
    ----------
    peak_factor : float
        Multiplies the spot's expected peak pixel in the detection probability and the threshold radius
        (the brightest of several pixels near the centre beats the mean peak).
    photon_factor : float
        Multiplies the photon (shot and gain) term of the centroid variance.
    background_factor : float
        Multiplies the background-noise term of the centroid variance.
    locking_factor : float
        Multiplies the pixel-locking term.
    min_log_ratio : float
        Floor of ``ln(peak / threshold)`` (the threshold region of a barely detected spot is about a
        ``sqrt(2 · min_log_ratio)`` σ disk).
    method : {"com", "gaussian"}
        Centroiding method these factors were calibrated for.
    """

    peak_factor: float = 1.0
    photon_factor: float = 1.0
    background_factor: float = 1.0
    locking_factor: float = 1.0
    min_log_ratio: float = 0.5
    method: str = "com"

    def __post_init__(self):
        check_method(self.method)
        for name in ("peak_factor", "photon_factor", "background_factor", "locking_factor", "min_log_ratio"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be finite and > 0, got {v}")


# calibrate_error_model(SensorModel.preset(name), np.random.default_rng(2025), n_frames=16, method=method);
# tests/test_centroid.py checks that they still reproduce the pixel path.
DEFAULT_ERROR_MODELS = {
    ("paper000", "com"): CentroidErrorModel(1.425, 0.758, 1.011, 2.886, 0.5, "com"),
    ("paper000", "gaussian"): CentroidErrorModel(1.425, 3.417, 0.001, 0.001, 0.5, "gaussian"),
    ("paper000_cmos", "com"): CentroidErrorModel(1.200, 0.542, 1.494, 0.182, 0.5, "com"),
    ("paper000_cmos", "gaussian"): CentroidErrorModel(1.200, 12.367, 0.583, 0.345, 0.5, "gaussian"),
}


def default_error_model(model: SensorModel, method: str = "com") -> CentroidErrorModel:
    """The stored calibration for a preset (by ``model.name``); other models get the one of their
    detector kind (intensified or not). Run :func:`calibrate_error_model` for a model far from both."""
    check_method(method)
    key = (model.name, method)
    if key not in DEFAULT_ERROR_MODELS:
        key = ("paper000" if model.intensified else "paper000_cmos", method)
    return DEFAULT_ERROR_MODELS[key]


def _spot_theory(s_units, gain, f2, sigma, sigma_o, c_splash, length, var_b, thr_e, err: CentroidErrorModel, intensified):
    """Closed-form statistics of a thresholded centre of mass for spots (all arrays (P,)).

    s_units : expected photoelectrons (or e⁻ for direct charge with gain 1); var_b : background variance
    (e⁻², incl. quantisation); thr_e : threshold above the background mean, e⁻.

    Model (σ_e² = σ² + 1/12 for pixel integration; L the smear length):

    * peak pixel ``P = G S φ(L) / (2π σ_e²)`` with ``φ`` the peak of a uniform streak convolved with the
      PSF; detection probability ``Φ((c_peak P − T) / sd(P))``;
    * threshold region: ``a = ln(c_peak P / T)`` (floored), radius ``R = σ_e √(2a)``, captured fraction
      ``f = 1 − e^{−a}``, truncated second moment ``m2 = σ_e² (1 − a e^{−a} / f)``;
    * centroid variance per axis = photon term (``F² m2 / (S f)``, plus ``L²/12`` along; for an intensifier
      the photoelectron scatter ``F² σ_o² / S`` plus the splash shape noise) + background term
      (``σ_b² Σ_Ω x² / (G S f)²`` over a stadium of radius R, length L, plus the support noise of the
      pixels at the threshold, ``(1/√π) T σ_b σ_e² / R ∮ x² dl / (G S f)²``) + pixel locking (the COM over a
      fixed set of pixels lags the true shift by ``1 − m2/σ_e²``, uniform over a pixel: that squared / 12).

    Returns a dict of arrays: p_det, ph/bg/lock for along and cross, var_along, var_cross, cap (captured
    e⁻), var_cap, area, peak (e⁻).
    """
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
    cp = err.peak_factor * peak
    p_det = ndtr((cp - thr_e) / np.sqrt(var_peak))
    # a barely detected spot is an upward fluctuation that keeps its few brightest pixels: floor on a
    a = np.maximum(np.log(np.maximum(cp / np.maximum(thr_e, 1e-12), 1e-300)), err.min_log_ratio)
    r2 = 2.0 * se2 * a
    r = np.sqrt(r2)
    exp_a = np.exp(-a)
    frac = np.maximum(1.0 - exp_a, 1e-6)
    m2 = se2 * (1.0 - a * exp_a / frac)
    len2, len3 = length**2, length**3
    l2 = len2 / 12.0
    if intensified:
        ph_cross = f2 * (sigma_o**2 + c_splash * m2 / frac) / s_safe
        ph_along = f2 * (sigma_o**2 + l2 + c_splash * (m2 + l2) / frac) / s_safe
    else:
        ph_cross = f2 * m2 / (s_safe * frac)
        ph_along = f2 * (m2 + l2) / (s_safe * frac)
    cap = total_e * frac
    # (repeated subexpressions computed once: the same operations, so the same values)
    disc = np.pi * r2**2 / 4
    cap2 = np.maximum(cap, 1e-12) ** 2
    a_cross = disc + (2 * r) ** 3 * length / 12
    a_along = disc + 2 * r * len3 / 12 + np.pi * r2 * len2 / 4
    bg_cross = var_b * a_cross / cap2
    bg_along = var_b * a_along / cap2
    # support noise: pixels near the threshold join or leave the component at random, each carrying about T;
    # Σ p(1−p) T² x² over the edge ≈ (1/√π) T σ_b σ_e² / R · ∮ x² dl  (ring width σ_b / |∇s|, |∇s| = T R / σ_e²)
    edge_k = (1.0 / np.sqrt(np.pi)) * thr_e * np.sqrt(var_b) * se2 / np.maximum(r, 1e-6) / cap2
    side, ring = 2 * length * r2, np.pi * r2 * r
    bg_cross = bg_cross + edge_k * (side + ring)
    bg_along = bg_along + edge_k * (len3 / 6 + np.pi * r * len2 / 2 + ring + side)
    lock_cross = (1.0 - m2 / se2) ** 2 / 12.0
    lock_along = (1.0 - (m2 + l2) / (se2 + l2)) ** 2 / 12.0
    var_cross = err.photon_factor * ph_cross + err.background_factor * bg_cross + err.locking_factor * lock_cross
    var_along = err.photon_factor * ph_along + err.background_factor * bg_along + err.locking_factor * lock_along
    area = np.maximum(np.pi * r2 + 2 * r * length, 1.0)
    var_cap = gain * gain * f2 * s_units * frac + var_b * area
    return dict(p_det=p_det, ph_along=ph_along, ph_cross=ph_cross, bg_along=bg_along, bg_cross=bg_cross,
                lock_along=lock_along, lock_cross=lock_cross, var_along=var_along, var_cross=var_cross,
                cap=cap, var_cap=var_cap, area=area, peak=peak)


_THEORY_KEYS = ("p_det", "var_along", "var_cross", "cap", "var_cap", "area", "peak")


def _centroid_fidelity(scene: Scene, model: SensorModel, rng, k_sigma, err: CentroidErrorModel, include_false: bool) -> Centroids:
    cam = scene.camera
    n_cols, n_rows = cam.resolution
    bg = background_field(scene, model)
    g_dn = model.gain_e_per_dn
    n, m = scene.n_exposures, scene.n_stars
    tau = scene.plan.exposure_s
    fo = draw_false_objects(scene, model, rng) if include_false else None

    # optical spots: stars (exposure-major) then debris
    xy = scene.xy_mean.reshape(-1, 2)
    vis = scene.visible.reshape(-1)
    length = scene.smear_px.reshape(-1)
    d = (scene.xy_end - scene.xy_start).reshape(-1, 2)
    s_pe = np.tile(model.star_pe(scene.vmag, scene.bv, tau), n)
    kind = np.full(n * m, KIND_STAR)
    star = np.tile(np.arange(m), n)
    expo = np.repeat(np.arange(n), m)
    if include_false and len(fo.debris_vmag):
        nd = len(fo.debris_vmag)
        t_mid = scene.t_frame_start + 0.5 * scene.plan.frame_period_s
        t0 = scene.path_times[:, 0] - t_mid
        t1 = scene.path_times[:, -1] - t_mid
        p0 = fo.debris_xy0[None] + fo.debris_velocity_px_s[None] * t0[:, None, None]
        p1 = fo.debris_xy0[None] + fo.debris_velocity_px_s[None] * t1[:, None, None]
        dxy = 0.5 * (p0 + p1).reshape(-1, 2)
        inside = (dxy[:, 0] >= -0.5) & (dxy[:, 0] <= n_cols - 0.5) & (dxy[:, 1] >= -0.5) & (dxy[:, 1] <= n_rows - 0.5)
        xy = np.concatenate([xy, dxy])
        vis = np.concatenate([vis, inside])
        dd = (p1 - p0).reshape(-1, 2)
        d = np.concatenate([d, dd])
        length = np.concatenate([length, np.linalg.norm(dd, axis=1)])
        s_pe = np.concatenate([s_pe, np.tile(model.star_pe(fo.debris_vmag, np.zeros(nd), tau), n)])
        kind = np.concatenate([kind, np.full(n * nd, KIND_DEBRIS)])
        star = np.concatenate([star, np.full(n * nd, -1)])
        expo = np.concatenate([expo, np.repeat(np.arange(n), nd)])
    sel = np.flatnonzero(vis & (s_pe > 0))
    xy, d, length, s_pe = xy[sel], d[sel], length[sel], s_pe[sel]
    kind, star, expo = kind[sel], star[sel], expo[sel]
    var_b_dn2 = bg.var_e(xy[:, 0], xy[:, 1]) / g_dn**2 + 1.0 / 12.0
    var_b = var_b_dn2 * g_dn**2
    thr_e = k_sigma * np.sqrt(var_b)
    f2 = model.excess_noise_factor**2
    th = _spot_theory(
        s_pe, model.intensifier_gain, f2, model.sigma_px, model.optics_sigma_px, model.splash_energy, length,
        var_b, thr_e, err, model.intensified)
    p_det, v_al, v_cr, cap, v_cap, area, peak = (th[k] for k in _THEORY_KEYS)
    # direct charge: cosmic rays
    if include_false and len(fo.cosmic_e):
        cxy = 0.5 * (fo.cosmic_start_xy + fo.cosmic_end_xy)
        cd = fo.cosmic_end_xy - fo.cosmic_start_xy
        clen = np.linalg.norm(cd, axis=1)
        inside = (cxy[:, 0] >= -0.5) & (cxy[:, 0] <= n_cols - 0.5) & (cxy[:, 1] >= -0.5) & (cxy[:, 1] <= n_rows - 0.5)
        cxy, cd, clen, ce = cxy[inside], cd[inside], clen[inside], fo.cosmic_e[inside]
        cvb = (bg.var_e(cxy[:, 0], cxy[:, 1]) / g_dn**2 + 1.0 / 12.0) * g_dn**2
        cres = _spot_theory(ce, 1.0, 1.0, np.full(len(ce), COSMIC_SIGMA_PX), np.full(len(ce), COSMIC_SIGMA_PX), 1.0,
                            clen, cvb, k_sigma * np.sqrt(cvb), err, False)
        xy = np.concatenate([xy, cxy])
        d = np.concatenate([d, cd])
        length = np.concatenate([length, clen])
        var_b = np.concatenate([var_b, cvb])
        p_det, v_al, v_cr, cap, v_cap, area, peak = (np.concatenate([u, cres[k]]) for u, k in zip(
            (p_det, v_al, v_cr, cap, v_cap, area, peak), _THEORY_KEYS))
        kind = np.concatenate([kind, np.full(len(ce), KIND_COSMIC_RAY)])
        star = np.concatenate([star, np.full(len(ce), -1)])
        expo = np.concatenate([expo, np.full(len(ce), -1)])
    det = rng.random(len(p_det)) < p_det
    idx = np.flatnonzero(det)
    ln = np.maximum(length[idx], 1e-12)
    along = np.where(length[idx, None] > 1e-9, d[idx] / ln[:, None], np.array([1.0, 0.0]))
    z = rng.standard_normal((len(idx), 3))
    err_xy = along * (z[:, :1] * np.sqrt(v_al[idx])[:, None]) + np.stack([-along[:, 1], along[:, 0]], 1) * (z[:, 1:2] * np.sqrt(v_cr[idx])[:, None])
    truth_xy = xy[idx]
    out_xy = truth_xy + err_xy
    inten_e = np.maximum(cap[idx] + z[:, 2] * np.sqrt(v_cap[idx]), 1e-3)
    peak_e = peak[idx]
    det_area = area[idx]
    star, expo, kind = star[idx], expo[idx], kind[idx]
    var_bd = var_b[idx]
    # spots whose threshold regions touch are one component in the pixel path: merge them
    if len(idx) > 1:
        # expected threshold radius (without the detection calibration factor) plus half the streak
        se2 = np.where(kind == KIND_COSMIC_RAY, COSMIC_SIGMA_PX**2, model.sigma_px**2) + 1.0 / 12.0
        r_exp = np.sqrt(2.0 * se2 * np.log(np.maximum(peak_e / (k_sigma * np.sqrt(var_bd)), 1.0)))
        reach = r_exp + 0.5 * length[idx]
        pairs = candidate_pairs(truth_xy, 2.0 * float(reach.max()) + 1e-9)
        if len(pairs):
            dxy = truth_xy[pairs[:, 0]] - truth_xy[pairs[:, 1]]
            pairs = pairs[dxy[:, 0] ** 2 + dxy[:, 1] ** 2 < (reach[pairs[:, 0]] + reach[pairs[:, 1]]) ** 2]
        if len(pairs):
            inv = np.unique(pairs)  # only the spots that merge are regrouped
            n_grp, grp = _pair_groups(len(inv), np.searchsorted(inv, pairs))
            w = inten_e[inv]
            wsum = np.bincount(grp, w, n_grp)
            mxy = np.column_stack([np.bincount(grp, w * out_xy[inv, 0], n_grp),
                                   np.bincount(grp, w * out_xy[inv, 1], n_grp)]) / wsum[:, None]
            lead = np.empty(n_grp, dtype=np.int64)
            order_w = np.argsort(w, kind="stable")
            lead[grp[order_w]] = inv[order_w]  # the brightest member labels the merged detection
            keep = np.ones(len(idx), dtype=bool)
            keep[inv] = False
            out_xy = np.concatenate([out_xy[keep], mxy])
            inten_e = np.concatenate([inten_e[keep], wsum])
            det_area = np.concatenate([det_area[keep], np.bincount(grp, det_area[inv], n_grp)])
            peak_e = np.concatenate([peak_e[keep], np.bincount(grp, peak_e[inv], n_grp)])
            star, expo, kind, var_bd, truth_xy = (np.concatenate([a[keep], a[lead]]) for a in (star, expo, kind, var_bd, truth_xy))
    bg_e = bg.mean_e(truth_xy[:, 0], truth_xy[:, 1])
    sat = (peak_e + bg_e) / g_dn + model.bias_dn >= model.saturation_dn
    sigma_dn = np.sqrt(var_bd) / g_dn
    det_area = np.maximum(np.rint(det_area), 1).astype(np.int64)
    parts = dict(
        xy=[out_xy], intensity=[inten_e / g_dn], area=[det_area], saturated=[sat],
        peak=[np.minimum(peak_e / g_dn, model.saturation_dn - model.bias_dn)],
        snr=[inten_e / g_dn / (sigma_dn * np.sqrt(det_area))], star=[star], exposure=[expo],
        kind=[kind], truth_xy=[truth_xy],
    )
    if include_false:
        # hot pixels: background + their own dark charge, detected when the drawn DN crosses the threshold
        _, hot_idx, hot_rate = fixed_pattern(model, cam.resolution)
        if len(hot_idx):
            hr, hc = np.divmod(hot_idx, n_cols)
            q = bg.gain * bg.optical_pe(hc, hr)
            hot_e = hot_rate * scene.plan.integration_window_s
            var0 = bg.enf2_c * q + bg.dark_e + bg.read_var_e2
            mean_dn0 = (q + bg.dark_e) / g_dn + model.bias_dn
            sd_dn0 = np.sqrt((var0 + (bg.prnu_sigma * q) ** 2) / g_dn**2 + 1.0 / 12.0)
            e = q + bg.dark_e + hot_e + np.sqrt(var0 + hot_e) * rng.standard_normal(len(hot_idx))
            dn = np.clip(np.rint(np.minimum(e, model.full_well_e) / g_dn + model.bias_dn), 0, model.adc_max_dn)
            hit = np.flatnonzero(dn > mean_dn0 + k_sigma * sd_dn0)
            if len(hit):
                hxy = np.column_stack([hc[hit], hr[hit]]).astype(float)
                _append_singletons(parts, hxy, dn[hit] - mean_dn0[hit] if np.ndim(mean_dn0) else dn[hit] - mean_dn0,
                                   dn[hit] >= model.saturation_dn, sd_dn0[hit] if np.ndim(sd_dn0) else sd_dn0, KIND_HOT_PIXEL)
        f_lin, f_dn = draw_false_pixels(bg, k_sigma, n_cols, n_rows, model, rng)
        if len(f_lin):
            fr, fc = np.divmod(f_lin, n_cols)
            fxy = np.stack([fc, fr], 1).astype(float)
            _append_singletons(parts, fxy, f_dn - bg.mean_dn(fc, fr), f_dn >= model.saturation_dn, bg.sigma_dn(fc, fr), KIND_NOISE)
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    order = np.argsort(-cat["intensity"], kind="stable")
    return Centroids(
        cat["xy"][order], cat["intensity"][order], cat["area"][order], cat["saturated"][order], cat["peak"][order],
        cat["snr"][order], float(bg.mean_dn(bg.cx, bg.cy)), float(bg.sigma_dn(bg.cx, bg.cy)),
        cat["star"][order].astype(np.int64), cat["exposure"][order].astype(np.int64),
        cat["kind"][order].astype(np.int64), cat["truth_xy"][order],
    )


_SWEEP_MAX_PAIRS = 200_000


def candidate_pairs(xy: np.ndarray, r: float) -> np.ndarray:
    """Pairs (i, j), i < j, of points closer than ``r`` along x (a superset of the pairs within ``r``), by a sort
    and sweep over x. The caller's exact distance test then leaves the same set as a k-d tree's
    ``query_pairs(r)`` would (every pair it keeps is closer than ``r``), in another order; only the set is used.
    Falls back to the k-d tree when the x-window holds too many candidates."""
    n = len(xy)
    o = np.argsort(xy[:, 0], kind="stable")
    xs = xy[o, 0]
    cnt = np.searchsorted(xs, xs + r, side="right") - np.arange(1, n + 1)
    tot = int(cnt.sum())
    if tot > _SWEEP_MAX_PAIRS:
        tree = cKDTree(xy, leafsize=32, balanced_tree=False, compact_nodes=False)
        return tree.query_pairs(r, output_type="ndarray")
    first = np.repeat(np.arange(n), cnt)
    second = np.arange(tot) - np.repeat(np.cumsum(cnt) - cnt, cnt) + first + 1
    a, b = o[first], o[second]
    near = np.abs(xy[a, 1] - xy[b, 1]) <= r
    a, b = a[near], b[near]
    return np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)


def _pair_groups(n: int, pairs: np.ndarray):
    """Connected groups of n items linked by pairs (P, 2): min-label propagation (few short chains)."""
    lab = np.arange(n)
    i, j = pairs[:, 0], pairs[:, 1]
    while True:
        m = np.minimum(lab[i], lab[j])
        new = lab.copy()
        np.minimum.at(new, i, m)
        np.minimum.at(new, j, m)
        new = new[new]  # pointer jumping
        if np.array_equal(new, lab):
            break
        lab = new
    uniq, grp = np.unique(lab, return_inverse=True)
    return len(uniq), grp


def _append_singletons(parts, xy, signal_dn, sat, sigma_dn, kind):
    k = len(xy)
    parts["xy"].append(xy)
    parts["intensity"].append(signal_dn)
    parts["area"].append(np.ones(k, dtype=np.int64))
    parts["saturated"].append(np.asarray(sat, dtype=bool))
    parts["peak"].append(signal_dn)
    parts["snr"].append(signal_dn / np.maximum(sigma_dn, 1e-9))
    parts["star"].append(np.full(k, -1))
    parts["exposure"].append(np.full(k, -1))
    parts["kind"].append(np.full(k, kind))
    parts["truth_xy"].append(xy)


def simulate_detections(
    scene: Scene,
    model: SensorModel,
    rng: np.random.Generator,
    fidelity: str = "centroid",
    *,
    k_sigma: float = 5.0,
    method: str = "com",
    min_area_px: int = 1,
    psf_sigma_px: float | None = None,
    error_model: CentroidErrorModel | None = None,
    include_false: bool = True,
) -> Centroids:
    """Detections of one frame with truth labels, without drawing the full frame.

    Parameters
    ----------
    scene : Scene
    model : SensorModel
    rng : numpy.random.Generator
    fidelity : {"centroid", "pixel"}
        "pixel": sparse rendering and centroiding; "centroid": drawn from the calibrated error model.
    k_sigma, method, min_area_px, psf_sigma_px
        As in :func:`extract_centroids`.
    error_model : CentroidErrorModel, optional
        Centroid fidelity only; default :func:`default_error_model` for ``model`` and ``method``.
    include_false : bool
        Draw hot pixels, cosmic rays, debris and background threshold crossings.

    Returns
    -------
    Centroids
        Brightest first, with ``truth_star``, ``truth_exposure``, ``truth_kind``, ``truth_xy``.
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
    if not isinstance(model, SensorModel):
        raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    k = check_k_sigma(k_sigma)
    check_method(method)
    min_area_px = check_min_area(min_area_px)
    psf_sigma_px = check_psf_sigma(psf_sigma_px)
    if fidelity == "pixel":
        if include_false:
            sf = render_sparse(scene, model, rng, k)
        else:
            sf = render_sparse(scene, replace(model, hot_pixel_fraction=0.0), rng, k,
                               false_objects=FalseObjects.none(), draw_crossings=False)
        return detections_from_sparse(sf, method, min_area_px=min_area_px, psf_sigma_px=psf_sigma_px)
    if fidelity == "centroid":
        err = default_error_model(model, method) if error_model is None else error_model
        if not isinstance(err, CentroidErrorModel):
            raise TypeError("error_model must be a CentroidErrorModel")
        if err.method != method:
            raise ValueError(f"error_model was calibrated for method {err.method!r}, not {method!r}")
        c = _centroid_fidelity(scene, model, rng, k, err, include_false)
        if min_area_px > 1:
            c = c.subset(c.area >= min_area_px)
        return c
    raise ValueError(f"fidelity must be 'centroid' or 'pixel', got {fidelity!r}")


def grid_scene(camera, plan, vmag_lo, vmag_hi, speed_px_s, spacing_px, rng):
    """Stars on a jittered grid, random magnitudes and motion directions (calibration scenes)."""
    from startracker.scene import scene_from_tracks

    w, h = camera.resolution
    gx = np.arange(spacing_px / 2, w - spacing_px / 2 + 1e-9, spacing_px)
    gy = np.arange(spacing_px / 2, h - spacing_px / 2 + 1e-9, spacing_px)
    X, Y = np.meshgrid(gx, gy)
    xy = np.column_stack([X.ravel(), Y.ravel()]) + rng.uniform(-0.5, 0.5, (X.size, 2))
    vm = rng.uniform(vmag_lo, vmag_hi, len(xy))
    ang = rng.uniform(0, 2 * np.pi, len(xy))
    vel = speed_px_s * np.column_stack([np.cos(ang), np.sin(ang)])
    return scene_from_tracks(camera, plan, xy, vm, vel)


def _star_errors(det: Centroids, scene: Scene):
    """First detection of each scene star: detected (N*M,), error along/cross the motion (N*M, 2)."""
    n, m = scene.n_exposures, scene.n_stars
    found = np.zeros(n * m, dtype=bool)
    err = np.full((n * m, 2), np.nan)
    st = np.flatnonzero(det.truth_kind == KIND_STAR)
    key = det.truth_exposure[st] * m + det.truth_star[st]
    u, first = np.unique(key, return_index=True)
    found[u] = True
    e = det.xy[st[first]] - det.truth_xy[st[first]]
    d = (scene.xy_end - scene.xy_start).reshape(-1, 2)[u]
    ln = np.linalg.norm(d, axis=1)
    al = np.where(ln[:, None] > 1e-9, d / np.maximum(ln, 1e-12)[:, None], np.array([1.0, 0.0]))
    err[u, 0] = (e * al).sum(axis=1)
    err[u, 1] = -e[:, 0] * al[:, 1] + e[:, 1] * al[:, 0]
    return found, err


def _theory_for_scene(scene: Scene, model: SensorModel, k_sigma: float, err: CentroidErrorModel):
    bg = background_field(scene, model)
    xy = scene.xy_mean.reshape(-1, 2)
    var_b = (bg.var_e(xy[:, 0], xy[:, 1]) / model.gain_e_per_dn**2 + 1.0 / 12.0) * model.gain_e_per_dn**2
    s_pe = np.tile(model.star_pe(scene.vmag, scene.bv, scene.plan.exposure_s), scene.n_exposures)
    return _spot_theory(s_pe, model.intensifier_gain, model.excess_noise_factor**2, model.sigma_px,
                        model.optics_sigma_px, model.splash_energy, scene.smear_px.reshape(-1), var_b,
                        k_sigma * np.sqrt(var_b), err, model.intensified)


def calibrate_error_model(
    model: SensorModel,
    rng: np.random.Generator,
    *,
    camera=None,
    exposure_s: float | None = None,
    smear_px=(0.0, 2.0),
    n_frames: int = 4,
    k_sigma: float = 5.0,
    method: str = "com",
    min_log_ratio: float = 0.5,
) -> CentroidErrorModel:
    """Fit the centroid-fidelity factors to the pixel path (sparse rendering + centroiding).

    Stars on a 60-px grid, magnitudes spanning certain to rare detection, one exposure per frame at each
    streak length; no false objects. ``peak_factor`` maximises the Bernoulli likelihood of the pixel path's
    detections; the photon, background and pixel-locking factors are a non-negative weighted least-squares
    fit of the squared centroid errors (along and across the motion) on the three variance terms.

    Parameters
    ----------
    model : SensorModel
    rng : numpy.random.Generator
    camera : Camera, optional
        Default paper 000's.
    exposure_s : float, optional
        Default 1 ms with an intensifier, 20 ms without.
    smear_px : sequence of float
        Streak lengths to calibrate on (image speed = smear / exposure).
    n_frames : int
        Frames per speed.
    k_sigma : float
    method : {"com", "gaussian"}
    min_log_ratio : float

    Returns
    -------
    CentroidErrorModel
    """
    from scipy.optimize import nnls

    from startracker.optics import camera_preset
    from startracker.scene import ExposurePlan

    if not isinstance(model, SensorModel):
        raise TypeError("model must be a SensorModel")
    cam = camera_preset("paper000") if camera is None else camera
    tau = (1e-3 if model.intensified else 0.02) if exposure_s is None else float(exposure_s)
    plan = ExposurePlan(1, tau, frame_period_s=max(0.1, tau))
    k = check_k_sigma(k_sigma)
    quiet = replace(model, hot_pixel_fraction=0.0, cosmic_ray_rate_per_cm2_s=0.0, debris_rate_per_frame=0.0)
    # magnitude where a still spot's peak equals the threshold
    probe = grid_scene(cam, plan, 0.0, 0.0, 0.0, cam.resolution[0] / 2, rng)
    th0 = _theory_for_scene(probe, quiet, k, CentroidErrorModel(min_log_ratio=min_log_ratio, method=method))
    thr_e = k * math.sqrt(float(background_field(probe, quiet).var_e(0, 0)) + model.gain_e_per_dn**2 / 12)
    v_thr = float(2.5 * np.log10(np.median(th0["peak"]) / thr_e))
    rows = []
    for smear in smear_px:
        speed = float(smear) / tau
        for _ in range(int(n_frames)):
            sc = grid_scene(cam, plan, v_thr - 4.0, v_thr + 0.8, float(speed), 60.0, rng)
            det = simulate_detections(sc, quiet, rng, "pixel", k_sigma=k, method=method, include_false=False)
            found, e = _star_errors(det, sc)
            rows.append((sc, found, e))
    base = CentroidErrorModel(min_log_ratio=min_log_ratio, method=method)

    def loglik(pf):
        ll = 0.0
        for sc, found, _ in rows:
            p = np.clip(_theory_for_scene(sc, quiet, k, replace(base, peak_factor=pf))["p_det"], 1e-9, 1 - 1e-9)
            vis = sc.visible.reshape(-1)
            ll += np.sum(np.where(found, np.log(p), np.log1p(-p))[vis])
        return ll

    grid = np.linspace(0.6, 3.0, 49)
    pf = float(grid[np.argmax([loglik(g) for g in grid])])
    fine = np.linspace(pf - 0.05, pf + 0.05, 21)
    pf = float(fine[np.argmax([loglik(g) for g in fine])])
    X, y = [], []
    for sc, found, e in rows:
        th = _theory_for_scene(sc, quiet, k, replace(base, peak_factor=pf))
        ok = found & np.all(np.abs(e) < 3.0, axis=1)
        for j, ax in enumerate(("along", "cross")):
            X.append(np.column_stack([th["ph_" + ax][ok], th["bg_" + ax][ok], th["lock_" + ax][ok]]))
            y.append(e[ok, j] ** 2)
    X = np.concatenate(X)
    y = np.concatenate(y)
    coef = np.ones(3)
    for _ in range(3):  # weights 1/predicted variance: the squared error of a Gaussian has sd ∝ its variance
        w = 1.0 / np.maximum(X @ coef, 1e-8)
        coef, _ = nnls(X * w[:, None], y * w)
        coef = np.maximum(coef, 1e-3)
    return CentroidErrorModel(pf, float(coef[0]), float(coef[1]), float(coef[2]), min_log_ratio, method)
