"""Centroid-fidelity kernels: detections of a frame drawn from its scene truth, without pixels.

The checked API, the model and its calibration are in :mod:`startracker.centroid.fidelity`. Here, arrays are
float64 (int64 / bool where said), C-contiguous, nothing is checked, and every random number comes in as an array
drawn by the caller's ``numpy.random.Generator`` (sizes fixed by the inputs: one uniform and three normals per
candidate spot, one normal per hot pixel), so the same draws give the same detections, bit for bit.

Parameter vectors
-----------------
``background`` (13,): the planar expected background of :class:`startracker.imaging.BackgroundField`,
``(opt0, opt_dx, opt_dy, cx, cy, dark_e, gain, enf2_c, read_var_e2, prnu_sigma, gain_e_per_dn, bias_dn,
integration_s)``; optical photoelectrons at ``(x, y)`` are ``max(opt0 + opt_dx (x − cx) + opt_dy (y − cy), 0)``.

``sensor`` (12,): ``(intensifier_gain, excess_noise_factor², sigma_px, optics_sigma_px, splash_energy,
intensified (1.0 / 0.0), saturation_dn, bias_dn, full_well_e, adc_max_dn, gain_e_per_dn, cosmic_sigma_px)``.

``factors`` (5,): the calibration ``(peak_factor, photon_factor, background_factor, locking_factor,
min_log_ratio)`` of :class:`startracker.centroid.CentroidErrorModel`.

``kinds`` (5,) int64: the codes of a star, debris, a cosmic ray, a hot pixel and noise (``startracker.imaging.KIND_*``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["THEORY_COLUMNS", "spot_theory", "candidate_pairs", "centroid_detections"]

THEORY_COLUMNS = ("p_det", "ph_along", "ph_cross", "bg_along", "bg_cross", "lock_along", "lock_cross",
                  "var_along", "var_cross", "cap", "var_cap", "area", "peak")
"""Columns of :func:`spot_theory`'s result, in order."""

_SQRT_2PI = math.sqrt(2.0 * math.pi)
_INV_SQRT_PI = 1.0 / math.sqrt(math.pi)


@njit(cache=True)
def _ndtr(x):
    """Standard normal CDF."""
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


@njit(cache=True)
def _theory(s_units, gain, f2, sigma, sigma_o, c_splash, length, var_b, thr_e, peak_f, photon_f, bg_f, lock_f,
            min_log_ratio, intensified):
    """One spot of :func:`spot_theory`: the 13 values of ``THEORY_COLUMNS``."""
    se2 = sigma * sigma + 1.0 / 12.0
    se = math.sqrt(se2)
    if length > 1e-6:
        lpos = max(length, 1e-9)
        phi = (_SQRT_2PI * se / lpos) * math.erf(lpos / (2.0 * math.sqrt(2.0) * se))
    else:
        phi = 1.0
    total_e = gain * s_units
    peak = total_e * phi / (2.0 * math.pi * se2)
    s_safe = max(s_units, 1e-12)
    if intensified:
        var_peak = peak * peak * f2 / s_safe + gain * f2 * c_splash * peak + var_b
    else:
        var_peak = gain * f2 * peak + var_b
    cp = peak_f * peak
    p_det = _ndtr((cp - thr_e) / math.sqrt(var_peak))
    # a barely detected spot is an upward fluctuation that keeps its few brightest pixels: floor on a
    a = max(math.log(max(cp / max(thr_e, 1e-12), 1e-300)), min_log_ratio)
    r2 = 2.0 * se2 * a
    r = math.sqrt(r2)
    exp_a = math.exp(-a)
    frac = max(1.0 - exp_a, 1e-6)
    m2 = se2 * (1.0 - a * exp_a / frac)
    len2 = length * length
    len3 = len2 * length
    l2 = len2 / 12.0
    if intensified:
        ph_cross = f2 * (sigma_o * sigma_o + c_splash * m2 / frac) / s_safe
        ph_along = f2 * (sigma_o * sigma_o + l2 + c_splash * (m2 + l2) / frac) / s_safe
    else:
        ph_cross = f2 * m2 / (s_safe * frac)
        ph_along = f2 * (m2 + l2) / (s_safe * frac)
    cap = total_e * frac
    disc = math.pi * r2 * r2 / 4.0
    cap2 = max(cap, 1e-12) ** 2
    a_cross = disc + (2.0 * r) ** 3 * length / 12.0
    a_along = disc + 2.0 * r * len3 / 12.0 + math.pi * r2 * len2 / 4.0
    # support noise: pixels near the threshold join or leave the component at random, each carrying about T
    edge_k = _INV_SQRT_PI * thr_e * math.sqrt(var_b) * se2 / max(r, 1e-6) / cap2
    side = 2.0 * length * r2
    ring = math.pi * r2 * r
    bg_cross = var_b * a_cross / cap2 + edge_k * (side + ring)
    bg_along = var_b * a_along / cap2 + edge_k * (len3 / 6.0 + math.pi * r * len2 / 2.0 + ring + side)
    lock_cross = (1.0 - m2 / se2) ** 2 / 12.0
    lock_along = (1.0 - (m2 + l2) / (se2 + l2)) ** 2 / 12.0
    var_cross = photon_f * ph_cross + bg_f * bg_cross + lock_f * lock_cross
    var_along = photon_f * ph_along + bg_f * bg_along + lock_f * lock_along
    area = max(math.pi * r2 + 2.0 * r * length, 1.0)
    var_cap = gain * gain * f2 * s_units * frac + var_b * area
    return (p_det, ph_along, ph_cross, bg_along, bg_cross, lock_along, lock_cross, var_along, var_cross, cap, var_cap,
            area, peak)


@njit(cache=True)
def spot_theory(s_units, gain, f2, sigma, sigma_o, c_splash, length, var_b, thr_e, factors, intensified):
    """Closed-form statistics of a thresholded centre of mass, spot by spot.

    The model (σ_e² = σ² + 1/12 for pixel integration; L the smear length; G the gain; F² the excess noise):

    * peak pixel ``P = G S φ(L) / (2π σ_e²)``, ``φ(L) = (√(2π) σ_e / L) erf(L / (2√2 σ_e))`` (1 for a still spot),
      the peak of a uniform streak convolved with the PSF; detection probability ``Φ((c_peak P − T) / sd(P))``;
    * threshold region: ``a = max(ln(c_peak P / T), min_log_ratio)``, radius ``R = σ_e √(2a)``, captured fraction
      ``f = 1 − e^{−a}``, truncated second moment ``m2 = σ_e² (1 − a e^{−a} / f)``;
    * centroid variance per axis = photon term (``F² m2 / (S f)``, plus ``L²/12`` along; with an intensifier the
      photoelectron scatter ``F² σ_o² / S`` plus the splash shape noise) + background term (``σ_b² Σ_Ω x² / (G S
      f)²`` over a stadium of radius R and length L, plus the support noise of the pixels at the threshold,
      ``(1/√π) T σ_b σ_e² / R ∮ x² dl / (G S f)²``) + pixel locking (the COM over a fixed set of pixels lags the
      true shift by ``1 − m2/σ_e²``, uniform over a pixel: that squared / 12), each scaled by its factor;
    * captured charge ``G S f`` with variance ``G² F² S f + σ_b² area``, area ``max(π R² + 2 R L, 1)``.

    Parameters
    ----------
    s_units : ndarray, shape (P,)
        Expected photoelectrons of each spot (e⁻ for direct charge, with ``gain = 1``).
    gain, f2 : float
        Electrons per photoelectron G, excess-noise factor squared F².
    sigma, sigma_o : float
        Total PSF σ and its part before the intensifier, px.
    c_splash : float
        Σ K² of the pixel-integrated splash kernel (1 without intensifier).
    length : ndarray, shape (P,)
        Smear length, px.
    var_b : ndarray, shape (P,)
        Background variance at the spot, e⁻² (quantisation included).
    thr_e : ndarray, shape (P,)
        Threshold above the background mean, e⁻.
    factors : ndarray, shape (5,)
        Calibration factors (module docstring).
    intensified : bool

    Returns
    -------
    ndarray, shape (P, 13)
        Columns ``THEORY_COLUMNS``: detection probability; photon, background and locking variance terms along
        and across the motion (px², unscaled); total variances along and across (px²); captured charge (e⁻) and
        its variance (e⁻²); area (px); expected peak pixel (e⁻).
    """
    n = s_units.shape[0]
    out = np.empty((n, 13))
    pf, hf, bf, lf, ml = factors[0], factors[1], factors[2], factors[3], factors[4]
    for i in range(n):
        v = _theory(s_units[i], gain, f2, sigma, sigma_o, c_splash, length[i], var_b[i], thr_e[i], pf, hf, bf, lf, ml,
                    intensified)
        for j in range(13):
            out[i, j] = v[j]
    return out


@njit(cache=True)
def candidate_pairs(xy, r):
    """Pairs ``(i, j)``, ``i < j``, of points closer than ``r`` along both x and y (a superset of the pairs
    within ``r``), by a sort and sweep over x.

    Parameters
    ----------
    xy : ndarray, shape (K, 2)
    r : float
        Distance, same units as ``xy``.

    Returns
    -------
    ndarray of int64, shape (Q, 2)
    """
    n = xy.shape[0]
    order = np.argsort(xy[:, 0], kind="mergesort")
    cap = 16
    out = np.empty((cap, 2), dtype=np.int64)
    q = 0
    for a in range(n):
        i = order[a]
        for b in range(a + 1, n):
            j = order[b]
            if xy[j, 0] - xy[i, 0] > r:
                break
            if abs(xy[j, 1] - xy[i, 1]) <= r:
                if q == cap:
                    cap *= 2
                    grown = np.empty((cap, 2), dtype=np.int64)
                    grown[:q] = out[:q]
                    out = grown
                out[q, 0] = min(i, j)
                out[q, 1] = max(i, j)
                q += 1
    return out[:q].copy()


@njit(cache=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


@njit(cache=True)
def _optical_pe(bg, x, y):
    return max(bg[0] + bg[1] * (x - bg[3]) + bg[2] * (y - bg[4]), 0.0)


@njit(cache=True)
def _var_e(bg, x, y):
    """Background pixel variance at (x, y), e⁻² (shot, dark, read, PRNU)."""
    q = bg[6] * _optical_pe(bg, x, y)
    return bg[7] * q + bg[5] + bg[8] + (bg[9] * q) ** 2


@njit(cache=True)
def _mean_e(bg, x, y):
    return bg[6] * _optical_pe(bg, x, y) + bg[5]


@njit(cache=True)
def centroid_detections(xy_path, visible, star_pe, debris_xy0, debris_velocity_px_s, debris_pe, t_start_rel_s,
                        t_end_rel_s, cosmic_start_xy, cosmic_end_xy, cosmic_e, hot_index, hot_dark_e_per_s,
                        noise_index, noise_dn, u_detect, z_spot, z_hot, background, sensor, factors, k_sigma, n_cols,
                        n_rows, kinds):
    """The detections of one frame in the centroid fidelity, brightest first.

    Candidate spots, in this order (the index of a candidate picks its draws): star m in exposure i (row
    ``i M + m``; its light centred at the trapezoid time-average of its path, its streak the polyline length,
    its motion from the first to the last path point), debris d in exposure i (row ``N M + i D + d``; a straight
    dash from ``xy0 + v t_start`` to ``xy0 + v t_end``), cosmic ray c (row ``N (M + D) + c``; a track of direct
    charge with σ = ``cosmic_sigma_px``). A candidate on the detector with a positive signal is detected when
    ``u_detect < p_det`` (:func:`spot_theory` at its background); its centroid is the truth plus
    ``z0 √var_along`` along and ``z1 √var_cross`` across the motion, its charge ``max(cap + z2 √var_cap, 1e-3)``.
    Detected spots whose expected threshold regions touch (distance < sum of ``R + L/2``, R without the peak
    factor) merge into one, as connected pixels do: intensity-weighted centroid, summed charge, area and peak,
    the labels of the brightest member. A hot pixel (dark charge over the integration window on top of the
    background, drawn with ``z_hot``) is detected when its DN exceeds ``mean + k σ``; the background's threshold
    crossings come in drawn (``noise_index``, ``noise_dn``). Saturation: expected peak plus background at or
    above ``saturation_dn``.

    Parameters
    ----------
    xy_path : ndarray, shape (N, S, M, 2)
        Star paths, px.
    visible : ndarray of bool, shape (N, M)
    star_pe : ndarray, shape (M,)
        Expected photoelectrons of each star in one exposure.
    debris_xy0, debris_velocity_px_s : ndarray, shape (D, 2)
        Debris position at the middle of the frame (px) and image velocity (px/s).
    debris_pe : ndarray, shape (D,)
        Photoelectrons per exposure.
    t_start_rel_s, t_end_rel_s : ndarray, shape (N,)
        Exposure start and end relative to the middle of the frame, s.
    cosmic_start_xy, cosmic_end_xy : ndarray, shape (C, 2)
        Cosmic-ray track ends, px.
    cosmic_e : ndarray, shape (C,)
        Deposited charge, e⁻.
    hot_index : ndarray of int64, shape (H,)
        Row-major linear pixel indices of the hot pixels.
    hot_dark_e_per_s : ndarray, shape (H,)
        Their extra dark current, e⁻/s.
    noise_index : ndarray of int64, shape (F,)
        Linear indices of background pixels drawn above the threshold.
    noise_dn : ndarray, shape (F,)
        Their DN.
    u_detect : ndarray, shape (N M + N D + C,)
        Uniform draws in [0, 1).
    z_spot : ndarray, shape (N M + N D + C, 3)
        Standard normal draws (along, across, charge).
    z_hot : ndarray, shape (H,)
        Standard normal draws.
    background, sensor, factors : ndarray
        Parameter vectors (module docstring).
    k_sigma : float
        Threshold, background σ.
    n_cols, n_rows : int
        Detector size, px.
    kinds : ndarray of int64, shape (5,)
        Kind codes (module docstring).

    Returns
    -------
    xy : ndarray, shape (K, 2)
        Centroids, px.
    intensity : ndarray, shape (K,)
        DN above the background.
    area : ndarray of int64, shape (K,)
    saturated : ndarray of bool, shape (K,)
    peak : ndarray, shape (K,)
        Peak above the background, DN (clipped at saturation).
    snr : ndarray, shape (K,)
    star : ndarray of int64, shape (K,)
        Scene star index, −1 otherwise.
    exposure : ndarray of int64, shape (K,)
        Exposure index (stars and debris), −1 otherwise.
    kind : ndarray of int64, shape (K,)
    truth_xy : ndarray, shape (K, 2)
        Where the source's light is centred, px.
    background_dn, noise_dn : float
        Background level and σ at the principal point, DN.
    """
    n, s, m = xy_path.shape[0], xy_path.shape[1], xy_path.shape[2]
    nd = debris_xy0.shape[0]
    nc = cosmic_e.shape[0]
    n_cand = n * m + n * nd + nc
    gain, f2, sigma, sigma_o, c_splash = sensor[0], sensor[1], sensor[2], sensor[3], sensor[4]
    intensified = sensor[5] > 0.5
    saturation_dn, bias_dn, full_well_e, adc_max_dn, g_dn = sensor[6], sensor[7], sensor[8], sensor[9], sensor[10]
    cosmic_sigma = sensor[11]
    kind_star, kind_debris, kind_cosmic, kind_hot, kind_noise = kinds[0], kinds[1], kinds[2], kinds[3], kinds[4]
    x_lo, x_hi, y_lo, y_hi = -0.5, n_cols - 0.5, -0.5, n_rows - 0.5

    # candidates on the detector with a signal: geometry first (stars, debris, cosmic rays), then one loop of theory
    c_id = np.empty(n_cand, dtype=np.int64)
    c_g = np.empty((n_cand, 6))  # x, y, dx, dy, length, signal
    c_lab = np.empty((n_cand, 3), dtype=np.int64)  # kind, star, exposure
    n_in = 0
    inv_s1 = 1.0 / (s - 1)
    for e in range(n):
        for j in range(m):
            if not visible[e, j] or not star_pe[j] > 0.0:
                continue
            sx = 0.5 * (xy_path[e, 0, j, 0] + xy_path[e, s - 1, j, 0])
            sy = 0.5 * (xy_path[e, 0, j, 1] + xy_path[e, s - 1, j, 1])
            ln = 0.0
            for t in range(1, s):
                if t < s - 1:
                    sx += xy_path[e, t, j, 0]
                    sy += xy_path[e, t, j, 1]
                ddx = xy_path[e, t, j, 0] - xy_path[e, t - 1, j, 0]
                ddy = xy_path[e, t, j, 1] - xy_path[e, t - 1, j, 1]
                ln += math.sqrt(ddx * ddx + ddy * ddy)
            c_id[n_in] = e * m + j
            c_g[n_in, 0], c_g[n_in, 1] = sx * inv_s1, sy * inv_s1
            c_g[n_in, 2] = xy_path[e, s - 1, j, 0] - xy_path[e, 0, j, 0]
            c_g[n_in, 3] = xy_path[e, s - 1, j, 1] - xy_path[e, 0, j, 1]
            c_g[n_in, 4], c_g[n_in, 5] = ln, star_pe[j]
            c_lab[n_in, 0], c_lab[n_in, 1], c_lab[n_in, 2] = kind_star, j, e
            n_in += 1
    for e in range(n):
        for j in range(nd):
            p0x = debris_xy0[j, 0] + debris_velocity_px_s[j, 0] * t_start_rel_s[e]
            p0y = debris_xy0[j, 1] + debris_velocity_px_s[j, 1] * t_start_rel_s[e]
            p1x = debris_xy0[j, 0] + debris_velocity_px_s[j, 0] * t_end_rel_s[e]
            p1y = debris_xy0[j, 1] + debris_velocity_px_s[j, 1] * t_end_rel_s[e]
            x, y = 0.5 * (p0x + p1x), 0.5 * (p0y + p1y)
            if not (x >= x_lo and x <= x_hi and y >= y_lo and y <= y_hi) or not debris_pe[j] > 0.0:
                continue
            dx, dy = p1x - p0x, p1y - p0y
            c_id[n_in] = n * m + e * nd + j
            c_g[n_in, 0], c_g[n_in, 1], c_g[n_in, 2], c_g[n_in, 3] = x, y, dx, dy
            c_g[n_in, 4], c_g[n_in, 5] = math.sqrt(dx * dx + dy * dy), debris_pe[j]
            c_lab[n_in, 0], c_lab[n_in, 1], c_lab[n_in, 2] = kind_debris, -1, e
            n_in += 1
    n_optical = n_in
    for j in range(nc):
        x = 0.5 * (cosmic_start_xy[j, 0] + cosmic_end_xy[j, 0])
        y = 0.5 * (cosmic_start_xy[j, 1] + cosmic_end_xy[j, 1])
        if not (x >= x_lo and x <= x_hi and y >= y_lo and y <= y_hi):
            continue
        dx = cosmic_end_xy[j, 0] - cosmic_start_xy[j, 0]
        dy = cosmic_end_xy[j, 1] - cosmic_start_xy[j, 1]
        c_id[n_in] = n * m + n * nd + j
        c_g[n_in, 0], c_g[n_in, 1], c_g[n_in, 2], c_g[n_in, 3] = x, y, dx, dy
        c_g[n_in, 4], c_g[n_in, 5] = math.sqrt(dx * dx + dy * dy), cosmic_e[j]
        c_lab[n_in, 0], c_lab[n_in, 1], c_lab[n_in, 2] = kind_cosmic, -1, -1
        n_in += 1

    # detected spots
    pf, hf, bf, lf, ml = factors[0], factors[1], factors[2], factors[3], factors[4]
    bg_opt0, bg_dx, bg_dy, bg_cx, bg_cy = background[0], background[1], background[2], background[3], background[4]
    bg_dark, bg_gain, bg_enf2c, bg_read, bg_prnu = background[5], background[6], background[7], background[8], background[9]
    se2_optical = sigma * sigma + 1.0 / 12.0
    se2_cosmic = cosmic_sigma * cosmic_sigma + 1.0 / 12.0
    g_dn2 = g_dn * g_dn
    t_xy = np.empty((n_in, 2))
    o_xy = np.empty((n_in, 2))
    inten = np.empty(n_in)
    peak = np.empty(n_in)
    area = np.empty(n_in)
    var_bd = np.empty(n_in)
    reach = np.empty(n_in)
    star = np.empty(n_in, dtype=np.int64)
    expo = np.empty(n_in, dtype=np.int64)
    kind = np.empty(n_in, dtype=np.int64)
    nk = 0
    for i in range(n_in):
        x, y, dx, dy, ln, su = c_g[i, 0], c_g[i, 1], c_g[i, 2], c_g[i, 3], c_g[i, 4], c_g[i, 5]
        qe = bg_gain * max(bg_opt0 + bg_dx * (x - bg_cx) + bg_dy * (y - bg_cy), 0.0)
        var_b = ((bg_enf2c * qe + bg_dark + bg_read + (bg_prnu * qe) ** 2) / g_dn2 + 1.0 / 12.0) * g_dn2
        thr_e = k_sigma * math.sqrt(var_b)
        if i < n_optical:
            th = _theory(su, gain, f2, sigma, sigma_o, c_splash, ln, var_b, thr_e, pf, hf, bf, lf, ml, intensified)
            se2 = se2_optical
        else:
            th = _theory(su, 1.0, 1.0, cosmic_sigma, cosmic_sigma, 1.0, ln, var_b, thr_e, pf, hf, bf, lf, ml, False)
            se2 = se2_cosmic
        c = c_id[i]
        if not u_detect[c] < th[0]:
            continue
        if ln > 1e-9:
            ax, ay = dx / max(ln, 1e-12), dy / max(ln, 1e-12)
        else:
            ax, ay = 1.0, 0.0
        e_al = z_spot[c, 0] * math.sqrt(th[7])
        e_cr = z_spot[c, 1] * math.sqrt(th[8])
        t_xy[nk, 0], t_xy[nk, 1] = x, y
        o_xy[nk, 0] = x + (ax * e_al + (-ay) * e_cr)
        o_xy[nk, 1] = y + (ay * e_al + ax * e_cr)
        inten[nk] = max(th[9] + z_spot[c, 2] * math.sqrt(th[10]), 1e-3)
        peak[nk] = th[12]
        area[nk] = th[11]
        var_bd[nk] = var_b
        # expected threshold radius (without the detection calibration factor) plus half the streak
        reach[nk] = math.sqrt(2.0 * se2 * math.log(max(th[12] / thr_e, 1.0))) + 0.5 * ln
        star[nk], expo[nk], kind[nk] = c_lab[i, 1], c_lab[i, 2], c_lab[i, 0]
        nk += 1

    # spots whose threshold regions touch are one component in the pixel path: merge them
    parent = np.arange(nk)
    merged = np.zeros(nk, dtype=np.bool_)
    if nk > 1:
        reach_max = reach[:nk].max()
        order = np.argsort(t_xy[:nk, 0], kind="mergesort")
        for a in range(nk):
            i = order[a]
            for b in range(a + 1, nk):
                j = order[b]
                if t_xy[j, 0] - t_xy[i, 0] > reach[i] + reach_max:
                    break
                ddx = t_xy[i, 0] - t_xy[j, 0]
                ddy = t_xy[i, 1] - t_xy[j, 1]
                if ddx * ddx + ddy * ddy < (reach[i] + reach[j]) ** 2:
                    merged[i] = True
                    merged[j] = True
                    ri, rj = _find(parent, i), _find(parent, j)
                    if ri != rj:
                        parent[max(ri, rj)] = min(ri, rj)
    # roots are the smallest member: the kept spots in order, then the merged groups by their smallest member
    n_h = hot_index.shape[0]
    n_f = noise_index.shape[0]
    cap = nk + n_h + n_f
    r_xy = np.empty((cap, 2))
    r_tr = np.empty((cap, 2))
    r_in = np.empty(cap)
    r_area = np.empty(cap, dtype=np.int64)
    r_sat = np.empty(cap, dtype=np.bool_)
    r_peak = np.empty(cap)
    r_snr = np.empty(cap)
    r_star = np.empty(cap, dtype=np.int64)
    r_expo = np.empty(cap, dtype=np.int64)
    r_kind = np.empty(cap, dtype=np.int64)
    r_varb = np.empty(cap)
    r_pk = np.empty(cap)
    r_ar = np.empty(cap)
    q = 0
    for i in range(nk):
        if not merged[i]:
            r_xy[q, 0], r_xy[q, 1] = o_xy[i, 0], o_xy[i, 1]
            r_tr[q, 0], r_tr[q, 1] = t_xy[i, 0], t_xy[i, 1]
            r_in[q], r_pk[q], r_ar[q], r_varb[q] = inten[i], peak[i], area[i], var_bd[i]
            r_star[q], r_expo[q], r_kind[q] = star[i], expo[i], kind[i]
            q += 1
    n_single = q
    slot = np.full(nk, -1, dtype=np.int64)
    lead_w = np.empty(nk)
    for i in range(nk):
        if merged[i]:
            root = _find(parent, i)
            if slot[root] < 0:
                slot[root] = q
                r_in[q] = 0.0
                r_xy[q, 0] = 0.0
                r_xy[q, 1] = 0.0
                r_pk[q] = 0.0
                r_ar[q] = 0.0
                lead_w[root] = -1.0
                q += 1
            g = slot[root]
            w = inten[i]
            r_in[g] += w
            r_xy[g, 0] += w * o_xy[i, 0]
            r_xy[g, 1] += w * o_xy[i, 1]
            r_pk[g] += peak[i]
            r_ar[g] += area[i]
            if w >= lead_w[root]:  # the brightest member labels the merged detection (the last of equals)
                lead_w[root] = w
                r_tr[g, 0], r_tr[g, 1] = t_xy[i, 0], t_xy[i, 1]
                r_varb[g] = var_bd[i]
                r_star[g], r_expo[g], r_kind[g] = star[i], expo[i], kind[i]
    # finish the optical and charge spots
    n_spots = q
    for g in range(n_single, n_spots):
        r_xy[g, 0] /= r_in[g]
        r_xy[g, 1] /= r_in[g]
    for g in range(n_spots):
        bg_e = _mean_e(background, r_tr[g, 0], r_tr[g, 1])
        r_sat[g] = (r_pk[g] + bg_e) / g_dn + bias_dn >= saturation_dn
        sigma_dn = math.sqrt(r_varb[g]) / g_dn
        ar = max(np.rint(r_ar[g]), 1.0)
        r_area[g] = np.int64(ar)
        r_peak[g] = min(r_pk[g] / g_dn, saturation_dn - bias_dn)
        r_snr[g] = r_in[g] / g_dn / (sigma_dn * math.sqrt(ar))
        r_in[g] = r_in[g] / g_dn
    # hot pixels: background + their own dark charge, detected when the drawn DN crosses the threshold
    integration_s = background[12]
    for h in range(n_h):
        hr, hc = hot_index[h] // n_cols, hot_index[h] % n_cols
        qe = background[6] * _optical_pe(background, float(hc), float(hr))
        hot_e = hot_dark_e_per_s[h] * integration_s
        var0 = background[7] * qe + background[5] + background[8]
        mean_dn0 = (qe + background[5]) / g_dn + bias_dn
        sd_dn0 = math.sqrt((var0 + (background[9] * qe) ** 2) / g_dn ** 2 + 1.0 / 12.0)
        e_h = qe + background[5] + hot_e + math.sqrt(var0 + hot_e) * z_hot[h]
        dn = min(max(np.rint(min(e_h, full_well_e) / g_dn + bias_dn), 0.0), adc_max_dn)
        if dn > mean_dn0 + k_sigma * sd_dn0:
            sig = dn - mean_dn0
            r_xy[q, 0], r_xy[q, 1] = float(hc), float(hr)
            r_tr[q, 0], r_tr[q, 1] = float(hc), float(hr)
            r_in[q], r_peak[q], r_area[q], r_sat[q] = sig, sig, 1, dn >= saturation_dn
            r_snr[q] = sig / max(sd_dn0, 1e-9)
            r_star[q], r_expo[q], r_kind[q] = -1, -1, kind_hot
            q += 1
    # background threshold crossings
    for f in range(n_f):
        fr, fc = noise_index[f] // n_cols, noise_index[f] % n_cols
        x, y = float(fc), float(fr)
        sig = noise_dn[f] - (_mean_e(background, x, y) / g_dn + bias_dn)
        sd = math.sqrt(_var_e(background, x, y) / g_dn ** 2 + 1.0 / 12.0)
        r_xy[q, 0], r_xy[q, 1] = x, y
        r_tr[q, 0], r_tr[q, 1] = x, y
        r_in[q], r_peak[q], r_area[q], r_sat[q] = sig, sig, 1, noise_dn[f] >= saturation_dn
        r_snr[q] = sig / max(sd, 1e-9)
        r_star[q], r_expo[q], r_kind[q] = -1, -1, kind_noise
        q += 1
    order = np.argsort(-r_in[:q], kind="mergesort")
    cx, cy = background[3], background[4]
    bg_dn = _mean_e(background, cx, cy) / g_dn + bias_dn
    noise_dn_c = math.sqrt(_var_e(background, cx, cy) / g_dn ** 2 + 1.0 / 12.0)
    return (r_xy[order], r_in[order], r_area[order], r_sat[order], r_peak[order], r_snr[order], r_star[order],
            r_expo[order], r_kind[order], r_tr[order], bg_dn, noise_dn_c)
