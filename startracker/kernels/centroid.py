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

The module is over 600 lines because the centroid-fidelity frame is one kernel built from small compiled
stages (candidates, theory, detection, merging, assembly, ordering) that only it calls.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["THEORY_COLUMNS", "spot_theory", "candidate_pairs", "profile_terms", "profile_at", "saddle_search",
           "centroid_detections"]

THEORY_COLUMNS = ("p_det", "ph_along", "ph_cross", "bg_along", "bg_cross", "lock_along", "lock_cross",
                  "var_along", "var_cross", "cap", "var_cap", "area", "peak")
"""Columns of :func:`spot_theory`'s result, in order."""

_SQRT_2PI = math.sqrt(2.0 * math.pi)
_INV_SQRT_PI = 1.0 / math.sqrt(math.pi)


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _ndtr(x):
    """Standard normal CDF."""
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


@njit(cache=True, no_cfunc_wrapper=True, error_model="numpy")
def spot_theory(s_units, gain, f2, sigma, sigma_o, c_splash, length, var_b, thr_e, factors, intensified):
    """Closed-form statistics of a thresholded centre of mass, spot by spot.

    The model (σ_e² = σ² + 1/12 for pixel integration; L the smear length; G the gain; F² the excess noise):

    * peak pixel ``P = G S φ(L) / (2π σ_e²)``, ``φ(L) = (√(2π) σ_e / L) erf(L / (2√2 σ_e))`` (1 for a still spot),
      the peak of a uniform streak convolved with the PSF; effective peak ``P' = P (1 + (c_peak − 1) w)`` with w
      the photon share of the peak's variance ``sd(P)²`` (the brightest of the central pixels beats the mean by
      photon clumping, which a background-dominated noise dilutes); detection probability ``Φ((P' − T) / sd(P))``;
    * threshold region: ``a = max(ln(P' / T), min_log_ratio)``, radius ``R = σ_e √(2a)``, captured fraction
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
    peak_f, photon_f, bg_f, lock_f, min_log_ratio = factors[0], factors[1], factors[2], factors[3], factors[4]
    se2 = sigma * sigma + 1.0 / 12.0
    se = math.sqrt(se2)
    # In stages over all spots: the arithmetic between the library calls (erf, erfc, log, exp) then runs as vector
    # loops (error_model="numpy": no zero-division branch; the same IEEE operations, so the same bits). The log and
    # exp share the erfc's loop, which keeps them scalar libm calls even where numba has a vector math library.
    phi = np.empty(n)
    for i in range(n):
        if length[i] > 1e-6:
            lpos = max(length[i], 1e-9)
            phi[i] = (_SQRT_2PI * se / lpos) * math.erf(lpos / (2.0 * math.sqrt(2.0) * se))
        else:
            phi[i] = 1.0
    z = np.empty(n)
    a_ln = np.empty(n)  # cp / T, then a
    for i in range(n):
        total_e = gain * s_units[i]
        peak = total_e * phi[i] / (2.0 * math.pi * se2)
        s_safe = max(s_units[i], 1e-12)
        var_b_i = var_b[i]
        if intensified:
            var_peak = peak * peak * f2 / s_safe + gain * f2 * c_splash * peak + var_b_i
        else:
            var_peak = gain * f2 * peak + var_b_i
        # the brightest pixel near the centre beats the mean peak by photon clumping: the boost fades as the
        # background's share of the peak's variance grows (stray light)
        cp = peak * (1.0 + (peak_f - 1.0) * (var_peak - var_b_i) / var_peak)
        z[i] = (cp - thr_e[i]) / math.sqrt(var_peak)
        a_ln[i] = max(cp / max(thr_e[i], 1e-12), 1e-300)
        out[i, 12] = peak
    exp_a = np.empty(n)
    for i in range(n):
        out[i, 0] = _ndtr(z[i])
        # a barely detected spot is an upward fluctuation that keeps its few brightest pixels: floor on a
        a = max(math.log(a_ln[i]), min_log_ratio)
        a_ln[i] = a
        exp_a[i] = math.exp(-a)
    for i in range(n):
        a = a_ln[i]
        length_i = length[i]
        var_b_i = var_b[i]
        r2 = 2.0 * se2 * a
        r = math.sqrt(r2)
        frac = max(1.0 - exp_a[i], 1e-6)
        m2 = se2 * (1.0 - a * exp_a[i] / frac)
        len2 = length_i * length_i
        len3 = len2 * length_i
        l2 = len2 / 12.0
        s_safe = max(s_units[i], 1e-12)
        if intensified:
            ph_cross = f2 * (sigma_o * sigma_o + c_splash * m2 / frac) / s_safe
            ph_along = f2 * (sigma_o * sigma_o + l2 + c_splash * (m2 + l2) / frac) / s_safe
        else:
            ph_cross = f2 * m2 / (s_safe * frac)
            ph_along = f2 * (m2 + l2) / (s_safe * frac)
        cap = gain * s_units[i] * frac
        disc = math.pi * r2 * r2 / 4.0
        cap2 = max(cap, 1e-12) ** 2
        a_cross = disc + (2.0 * r) ** 3 * length_i / 12.0
        a_along = disc + 2.0 * r * len3 / 12.0 + math.pi * r2 * len2 / 4.0
        # support noise: pixels near the threshold join or leave the component at random, each carrying about T
        edge_k = _INV_SQRT_PI * thr_e[i] * math.sqrt(var_b_i) * se2 / max(r, 1e-6) / cap2
        side = 2.0 * length_i * r2
        ring = math.pi * r2 * r
        bg_cross = var_b_i * a_cross / cap2 + edge_k * (side + ring)
        bg_along = var_b_i * a_along / cap2 + edge_k * (len3 / 6.0 + math.pi * r * len2 / 2.0 + ring + side)
        lock_cross = (1.0 - m2 / se2) ** 2 / 12.0
        lock_along = (1.0 - (m2 + l2) / (se2 + l2)) ** 2 / 12.0
        area = max(math.pi * r2 + 2.0 * r * length_i, 1.0)
        out[i, 1] = ph_along
        out[i, 2] = ph_cross
        out[i, 3] = bg_along
        out[i, 4] = bg_cross
        out[i, 5] = lock_along
        out[i, 6] = lock_cross
        out[i, 7] = photon_f * ph_along + bg_f * bg_along + lock_f * lock_along
        out[i, 8] = photon_f * ph_cross + bg_f * bg_cross + lock_f * lock_cross
        out[i, 9] = cap
        out[i, 10] = gain * gain * f2 * s_units[i] * frac + var_b_i * area
        out[i, 11] = area
    return out


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _columns(x, width):
    """Counting sort of the points into columns at least ``width`` wide (at most about one per point): the
    column of each point (K,), the points by column then index (K,), and where each column starts (n_col + 2,),
    so that ``order[start[c]:start[c + 2]]`` are the points of columns c and c + 1."""
    n = x.shape[0]
    x0 = x[0]
    x1 = x[0]
    for i in range(n):
        x0 = min(x0, x[i])
        x1 = max(x1, x[i])
    w = max(width, (x1 - x0) / n)
    if not w > 0.0:
        w = 1.0
    col = np.empty(n, dtype=np.int64)
    n_col = 0
    for i in range(n):
        col[i] = int((x[i] - x0) / w)
        n_col = max(n_col, col[i] + 1)
    start = np.zeros(n_col + 2, dtype=np.int64)
    for i in range(n):
        start[col[i] + 1] += 1
    for c in range(n_col + 1):
        start[c + 1] += start[c]
    fill = np.empty(n_col + 2, dtype=np.int64)
    for c in range(n_col + 2):
        fill[c] = start[c]
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[col[i]]] = i
        fill[col[i]] += 1
    return col, order, start


@njit(cache=True, no_cfunc_wrapper=True)
def candidate_pairs(xy, r):
    """Pairs ``(i, j)``, ``i < j``, of points closer than ``r`` along both x and y (a superset of the pairs
    within ``r``): points sorted into columns at least ``r`` wide, each compared with those after it in its
    column and in the next.

    Parameters
    ----------
    xy : ndarray, shape (K, 2)
    r : float
        Distance, same units as ``xy`` (>= 0).

    Returns
    -------
    ndarray of int64, shape (Q, 2)
    """
    n = xy.shape[0]
    cap = 16
    out = np.empty((cap, 2), dtype=np.int64)
    if n < 2:
        return np.empty((0, 2), dtype=np.int64)
    x = np.empty(n)
    for i in range(n):
        x[i] = xy[i, 0]
    col, order, start = _columns(x, r)
    q = 0
    for a in range(n):
        i = order[a]
        for b in range(a + 1, start[col[i] + 2]):
            j = order[b]
            if abs(xy[j, 0] - xy[i, 0]) <= r and abs(xy[j, 1] - xy[i, 1]) <= r:
                if q == cap:
                    cap *= 2
                    grown = np.empty((cap, 2), dtype=np.int64)
                    grown[:q] = out[:q]
                    out = grown
                out[q, 0] = min(i, j)
                out[q, 1] = max(i, j)
                q += 1
    res = np.empty((q, 2), dtype=np.int64)
    for i in range(q):
        res[i, 0] = out[i, 0]
        res[i, 1] = out[i, 1]
    return res


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _candidates(xy_path, visible, star_pe, debris_xy0, debris_velocity_px_s, debris_pe, t_start_rel_s, t_end_rel_s,
                cosmic_start_xy, cosmic_end_xy, cosmic_e, n_cols, n_rows):
    """The candidate spots on the detector with a signal: draw row (K,), geometry (K, 6) = x, y, dx, dy, length,
    signal; source (K, 2) = star (-1), exposure (-1); the number of optical ones (stars, then debris), the number
    of those that are stars."""
    n, s, m = xy_path.shape[0], xy_path.shape[1], xy_path.shape[2]
    nd = debris_xy0.shape[0]
    nc = cosmic_e.shape[0]
    n_cand = n * m + n * nd + nc
    x_hi, y_hi = n_cols - 0.5, n_rows - 0.5
    c_id = np.empty(n_cand, dtype=np.int64)
    c_g = np.empty((n_cand, 6))
    c_src = np.empty((n_cand, 2), dtype=np.int64)
    k = 0
    inv_s1 = 1.0 / (s - 1)
    for e in range(n):
        for j in range(m):
            if not visible[e, j] or not star_pe[j] > 0.0:
                continue
            # trapezoid time-average of the path, polyline length
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
            c_id[k] = e * m + j
            c_g[k, 0] = sx * inv_s1
            c_g[k, 1] = sy * inv_s1
            c_g[k, 2] = xy_path[e, s - 1, j, 0] - xy_path[e, 0, j, 0]
            c_g[k, 3] = xy_path[e, s - 1, j, 1] - xy_path[e, 0, j, 1]
            c_g[k, 4] = ln
            c_g[k, 5] = star_pe[j]
            c_src[k, 0] = j
            c_src[k, 1] = e
            k += 1
    n_star = k
    for e in range(n):
        for j in range(nd):
            p0x = debris_xy0[j, 0] + debris_velocity_px_s[j, 0] * t_start_rel_s[e]
            p0y = debris_xy0[j, 1] + debris_velocity_px_s[j, 1] * t_start_rel_s[e]
            p1x = debris_xy0[j, 0] + debris_velocity_px_s[j, 0] * t_end_rel_s[e]
            p1y = debris_xy0[j, 1] + debris_velocity_px_s[j, 1] * t_end_rel_s[e]
            x = 0.5 * (p0x + p1x)
            y = 0.5 * (p0y + p1y)
            if x < -0.5 or x > x_hi or y < -0.5 or y > y_hi or not debris_pe[j] > 0.0:
                continue
            c_id[k] = n * m + e * nd + j
            c_g[k, 0] = x
            c_g[k, 1] = y
            c_g[k, 2] = p1x - p0x
            c_g[k, 3] = p1y - p0y
            c_g[k, 4] = math.sqrt(c_g[k, 2] ** 2 + c_g[k, 3] ** 2)
            c_g[k, 5] = debris_pe[j]
            c_src[k, 0] = -1
            c_src[k, 1] = e
            k += 1
    n_optical = k
    for j in range(nc):
        x = 0.5 * (cosmic_start_xy[j, 0] + cosmic_end_xy[j, 0])
        y = 0.5 * (cosmic_start_xy[j, 1] + cosmic_end_xy[j, 1])
        if x < -0.5 or x > x_hi or y < -0.5 or y > y_hi:
            continue
        c_id[k] = n * m + n * nd + j
        c_g[k, 0] = x
        c_g[k, 1] = y
        c_g[k, 2] = cosmic_end_xy[j, 0] - cosmic_start_xy[j, 0]
        c_g[k, 3] = cosmic_end_xy[j, 1] - cosmic_start_xy[j, 1]
        c_g[k, 4] = math.sqrt(c_g[k, 2] ** 2 + c_g[k, 3] ** 2)
        c_g[k, 5] = cosmic_e[j]
        c_src[k, 0] = -1
        c_src[k, 1] = -1
        k += 1
    return c_id[:k], c_g[:k], c_src[:k], n_optical, n_star


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _detect(c_id, c_g, n_optical, u_detect, z_spot, background, sensor, factors, k_sigma):
    """Theory, detection and measurement of the candidates: the detected rows (D,), and per detection (D, 8) =
    truth x, y, measured x, y, charge (e⁻), expected peak (e⁻), area (px), background variance (e⁻²), the
    reach (D,) (px: where the expected profile falls to a sixth of the threshold, plus half the streak; two spots
    farther apart than the sum of theirs never join), and what the
    near-overlap model of :func:`_touching` needs (D, 8): PSF variance (px²), half streak (px), signal units,
    intensifier gain (0: not intensified), splash energy, the detection draw scaled to U(0, 1), and the streak's
    unit direction (x, y)."""
    gain, f2, sigma, sigma_o, c_splash = sensor[0], sensor[1], sensor[2], sensor[3], sensor[4]
    intensified = sensor[5] > 0.5
    g_dn = sensor[10]
    cosmic_sigma = sensor[11]
    saturation_dn, bias_dn = sensor[6], sensor[7]
    opt0, gx, gy, cx, cy = background[0], background[1], background[2], background[3], background[4]
    dark, gain_bg, enf2c, read_var, prnu = background[5], background[6], background[7], background[8], background[9]
    se2_optical = sigma * sigma + 1.0 / 12.0
    se2_cosmic = cosmic_sigma * cosmic_sigma + 1.0 / 12.0
    g_dn2 = g_dn * g_dn
    n_in = c_id.shape[0]
    # the candidates that can be detected at their background: row, signal, length, background variance, threshold
    kept = np.empty(n_in, dtype=np.int64)
    su_k = np.empty(n_in)
    ln_k = np.empty(n_in)
    var_k = np.empty(n_in)
    thr_k = np.empty(n_in)
    # a flat background (no gradient: no bright body) has one level, threshold and verdict for every spot
    flat = gx == 0.0 and gy == 0.0
    q = var_b = thr_e = 0.0
    washed_out = False
    if flat:
        q = gain_bg * max(opt0 + gx * (cx - cx) + gy * (cy - cy), 0.0)
        var_b = ((enf2c * q + dark + read_var + (prnu * q) ** 2) / g_dn2 + 1.0 / 12.0) * g_dn2
        thr_e = k_sigma * math.sqrt(var_b)
        washed_out = math.floor((q + dark + thr_e) / g_dn + bias_dn) + 1.0 > saturation_dn
    m = 0
    m_opt = 0
    for i in range(n_in):
        if flat:
            if washed_out:
                break
        else:
            q = gain_bg * max(opt0 + gx * (c_g[i, 0] - cx) + gy * (c_g[i, 1] - cy), 0.0)
            var_b = ((enf2c * q + dark + read_var + (prnu * q) ** 2) / g_dn2 + 1.0 / 12.0) * g_dn2
            thr_e = k_sigma * math.sqrt(var_b)
            # a pixel is detected when its DN exceeds the threshold, and no pixel reads above saturation: where the
            # background's threshold is at or above it (stray light washing the detector out) nothing is detected
            if math.floor((q + dark + thr_e) / g_dn + bias_dn) + 1.0 > saturation_dn:
                continue
        kept[m] = i
        su_k[m] = c_g[i, 5]
        ln_k[m] = c_g[i, 4]
        var_k[m] = var_b
        thr_k[m] = thr_e
        m += 1
        m_opt += 1 if i < n_optical else 0
    th_opt = spot_theory(su_k[:m_opt], gain, f2, sigma, sigma_o, c_splash, ln_k[:m_opt], var_k[:m_opt], thr_k[:m_opt],
                         factors, intensified)
    th_cos = spot_theory(su_k[m_opt:m], 1.0, 1.0, cosmic_sigma, cosmic_sigma, 1.0, ln_k[m_opt:m], var_k[m_opt:m],
                         thr_k[m_opt:m], factors, np.bool_(False))
    rows = np.empty(m, dtype=np.int64)
    out = np.empty((m, 8))
    reach = np.empty(m)
    # se2, half streak, signal units, gain, splash, the detection draw scaled to U(0, 1), streak direction x, y
    pair = np.empty((m, 8))
    nk = 0
    for part in range(2):  # the optical candidates, then the cosmic rays (one theory table each)
        th = th_opt if part == 0 else th_cos
        opt = part == 0
        for r in range(th.shape[0]):
            t = r if opt else m_opt + r
            i = kept[t]
            c = c_id[i]
            if not u_detect[c] < th[r, 0]:
                continue
            x, y, dx, dy, ln, su = c_g[i, 0], c_g[i, 1], c_g[i, 2], c_g[i, 3], c_g[i, 4], c_g[i, 5]
            var_b = var_k[t]
            if ln > 1e-9:
                ax = dx / max(ln, 1e-12)
                ay = dy / max(ln, 1e-12)
            else:
                ax = 1.0
                ay = 0.0
            e_al = z_spot[c, 0] * math.sqrt(th[r, 7])
            e_cr = z_spot[c, 1] * math.sqrt(th[r, 8])
            rows[nk] = i
            out[nk, 0] = x
            out[nk, 1] = y
            out[nk, 2] = x + (ax * e_al + (-ay) * e_cr)
            out[nk, 3] = y + (ay * e_al + ax * e_cr)
            out[nk, 4] = max(th[r, 9] + z_spot[c, 2] * math.sqrt(th[r, 10]), 1e-3)
            out[nk, 5] = th[r, 12]
            out[nk, 6] = th[r, 11]
            out[nk, 7] = var_b
            se2 = se2_optical if opt else se2_cosmic
            reach[nk] = math.sqrt(2.0 * se2 * math.log(max(6.0 * th[r, 12] / thr_k[t], 1.0))) + 0.5 * ln
            pair[nk, 0] = se2
            pair[nk, 1] = 0.5 * ln
            pair[nk, 2] = max(su, 1e-12)
            pair[nk, 3] = gain if (opt and intensified) else 0.0
            pair[nk, 4] = c_splash if opt else 1.0
            # given detection, u / p_det is uniform on [0, 1) and independent of the spot's other draws
            pair[nk, 5] = u_detect[c] / max(th[r, 0], 1e-300)
            pair[nk, 6] = ax
            pair[nk, 7] = ay
            nk += 1
    return rows[:nk], out[:nk], reach[:nk], pair[:nk]


@njit(cache=True, no_cfunc_wrapper=True)
def profile_terms(se2, half):
    """The constants of one spot's expected profile along the line to a neighbour (:func:`profile_at`): a Gaussian
    of variance ``se2`` px² smeared over a streak of half length ``half`` px along that line (its projection).

    Returns
    -------
    tuple (still, k, den)
        ``still`` when ``half < 10⁻³ σ_e`` (then ``k = 2 se2``, ``den = 1``), else ``k = 1 / (√2 σ_e)`` and
        ``den = 2 erf(half k)``.
    """
    se = math.sqrt(se2)
    if half < 1e-3 * se:
        return True, 2.0 * se2, 1.0
    k = 1.0 / (math.sqrt(2.0) * se)
    return False, k, 2.0 * math.erf(half * k)


@njit(cache=True, no_cfunc_wrapper=True)
def profile_at(s, peak, half, terms):
    """Expected signal (e⁻) of a spot at distance ``s`` px (>= 0) from its centre along the line to a neighbour,
    ``peak`` e⁻ at the centre: ``peak exp(−s² / (2 se2))`` when still, else
    ``peak (erf((s + half) k) − erf((s − half) k)) / den`` (``terms`` from :func:`profile_terms`). It falls
    with ``s``."""
    if terms[0]:
        return peak * math.exp(-s * s / terms[1])
    k = terms[1]
    return peak * (math.erf((s + half) * k) - math.erf((s - half) * k)) / terms[2]


@njit(cache=True, no_cfunc_wrapper=True)
def saddle_search(d, peak_i, half_i, terms_i, peak_j, half_j, terms_j, a, b, lows):
    """The saddle of two spots' summed profiles: the least of ``a[k] + b[k]`` over the 33 points ``s = d k / 32``
    of the segment between their centres, the first of equals, with ``a[k] = profile_at(s, peak_i, …)`` and
    ``b[k] = profile_at(d − s, peak_j, …)``.

    Found by bisection with bounds rather than by evaluating every point: spot i's profile falls and spot j's
    rises along the segment, so between two evaluated points the sum is at least i's value at the right one plus
    j's at the left one. A span whose bound exceeds the least value found by a margin (10⁻⁹ of the summed peaks,
    far above the profiles' rounding: erf to an ulp over ``den >= 2 erf(10⁻³ / √2)``) holds neither a smaller
    value nor an equal one, so the index is the exhaustive search's, bit for bit, at about half the evaluations.
    The caller evaluates the ends and the midpoint (k = 0, 16, 32) first: its own bounds on the saddle may
    settle the question without the search (:func:`_touching`).

    Parameters
    ----------
    d : float
        Distance between the centres, px.
    peak_i, peak_j : float
        Expected peaks, e⁻.
    half_i, half_j : float
        Streak half lengths projected on the segment, px.
    terms_i, terms_j : tuple
        :func:`profile_terms` of the two spots.
    a, b : ndarray, shape (33,)
        On entry ``a[k]``, ``b[k]`` for k = 0, 16, 32 hold the profiles there, the rest is scratch; on return
        they hold the two profiles at the index found (and at the other evaluated points).
    lows : ndarray of int64, shape (24,)
        Scratch: the spans' left ends.

    Returns
    -------
    int
        The index k in [0, 32].
    """
    best_k = 0
    best = a[0] + b[0]
    for k in (16, 32):
        v = a[k] + b[k]
        if v < best:
            best = v
            best_k = k
    margin = 1e-9 * (peak_i + peak_j)
    lows[0] = 0
    lows[1] = 16
    n_iv = 2
    w = 16
    while w > 1:
        h = w // 2
        m = n_iv  # the children are written after the parents, then moved down
        for t in range(n_iv):
            lo = lows[t]
            if a[lo + w] + b[lo] > best + margin:
                continue
            k = lo + h
            s = d * k / 32.0
            a[k] = profile_at(s, peak_i, half_i, terms_i)
            b[k] = profile_at(d - s, peak_j, half_j, terms_j)
            v = a[k] + b[k]
            if v < best or (v == best and k < best_k):
                best = v
                best_k = k
            if h > 1:  # spans of one step have no point inside
                lows[m] = lo
                lows[m + 1] = k
                m += 2
        for t in range(n_iv, m):
            lows[t - n_iv] = lows[t]
        n_iv = m - n_iv
        w = h
    return best_k


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _signal_variance(p, pr, f2):
    """Variance (e⁻²) of a pixel's signal ``p`` e⁻ from one spot: intensified photon clumping and splash, or shot
    noise (the terms of :func:`spot_theory`'s peak variance)."""
    if pr[3] > 0.0:
        return p * p * f2 / pr[2] + pr[3] * f2 * pr[4] * p
    return f2 * p


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _merge_probability(d, peak_i, peak_j, pair_i, pair_j, half_i, half_j, var_b, thr_e, f2, terms_i, terms_j, a, b,
                       lows):
    """Probability that two spots ``d`` px apart join into one 8-connected component above the threshold.

    The summed expected profile of the two spots is lowest at the saddle between them (:func:`saddle_search`);
    a pixel there joins the components when its value S, with the noise of that signal (the variance model of
    :func:`spot_theory`'s peak: intensified photon clumping and splash, or shot noise, plus the background),
    exceeds the threshold T. The saddle falls between pixel centres, so the two pixels straddling it give two
    about independent chances: ``1 − (1 − Φ((S − T) / σ_S))²``, near 1 where each spot alone reaches past the
    saddle, 0 far beyond.

    Parameters
    ----------
    d : float
        Distance between the spots' centres, px.
    peak_i, peak_j : float
        Expected peaks, e⁻.
    pair_i, pair_j : ndarray, shape (8,)
        The spots' columns of :func:`_detect`'s near-overlap block.
    half_i, half_j : float
        Their streaks' half lengths projected on the line between them, px.
    var_b : float
        Background variance, e⁻² (the pair's mean).
    thr_e : float
        Threshold above the background, e⁻.
    f2 : float
        Excess noise factor squared.
    terms_i, terms_j, a, b, lows
        :func:`profile_terms` of the two spots and :func:`saddle_search`'s arrays (``a``, ``b`` with the profiles
        at k = 0, 16, 32).
    """
    k = saddle_search(d, peak_i, half_i, terms_i, peak_j, half_j, terms_j, a, b, lows)
    best = a[k] + b[k]
    var = var_b + _signal_variance(a[k], pair_i, f2) + _signal_variance(b[k], pair_j, f2)
    # the saddle falls between pixel centres: an 8-connected path can cross it through either of the two pixels
    # that straddle it, two about independent chances
    miss = 1.0 - _ndtr((best - thr_e) / math.sqrt(var))
    return 1.0 - miss * miss


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _touching(det, far, pair, k_sigma, f2):
    """Union-find labels (K,) (the smallest member of each group) of the spots that join into one component, and
    whether each touches another. Two spots join with :func:`_merge_probability` (the saddle of their summed
    profiles above the threshold), decided by the pair's draw ``frac(u_i + u_j)`` (uniform, and independent of each
    spot's own draws and of the pair's other pairs), and never farther apart than the sum of their reaches
    ``far`` (D,) (:func:`_detect`). Each spot is compared with those near it in y in its column
    and the next (columns as wide as the largest distance at which a pair can join), the pair oriented as its
    column order has it (the lower column first, then the smaller index): the labels do not depend on the order
    in which pairs join (a group's root is always its smallest member)."""
    n = far.shape[0]
    parent = np.empty(n, dtype=np.int64)
    touched = np.zeros(n, dtype=np.bool_)
    x = np.empty(n)
    far_max = 0.0
    for i in range(n):
        parent[i] = i
        x[i] = det[i, 0]
        far_max = max(far_max, far[i])
    if n < 2:
        return parent, touched
    col, order, start = _columns(x, 2.0 * far_max)
    # each column by increasing y (insertion sort: a column holds a few spots), so that a spot meets only the
    # spots within the joining distance in y, plus a margin far above the rounding of the distance test
    n_col = start.shape[0] - 2
    for c in range(n_col):
        for a in range(start[c] + 1, start[c + 1]):
            i = order[a]
            b = a
            while b > start[c] and det[order[b - 1], 1] > det[i, 1]:
                order[b] = order[b - 1]
                b -= 1
            order[b] = i
    a_s = np.empty(33)  # scratch of the saddle search
    b_s = np.empty(33)
    lows = np.empty(24, dtype=np.int64)
    dy_max = 2.0 * far_max + 1e-6
    for c in range(n_col):
        lo = start[c + 1]  # the first spot of the next column not far below the current spot
        for a in range(start[c], start[c + 1]):
            ii = order[a]
            y_i = det[ii, 1]
            dy_i = far[ii] + far_max + 1e-6
            while lo < start[c + 2] and det[order[lo], 1] < y_i - dy_max:
                lo += 1
            for side in range(2):  # the spots after it in its column, then those of the next column
                for b in range(a + 1 if side == 0 else lo, start[c + 1 + side]):
                    jj = order[b]
                    if det[jj, 1] - y_i >= dy_i:
                        break
                    i = min(ii, jj) if side == 0 else ii
                    j = max(ii, jj) if side == 0 else jj
                    ddx = det[j, 0] - det[i, 0]
                    ddy = det[j, 1] - det[i, 1]
                    d2 = ddx * ddx + ddy * ddy
                    if not d2 < (far[i] + far[j]) ** 2:
                        continue
                    d = math.sqrt(d2)
                    if d > 1e-9:
                        ux, uy = ddx / d, ddy / d
                    else:
                        ux, uy = 1.0, 0.0
                    half_i = pair[i, 1] * abs(pair[i, 6] * ux + pair[i, 7] * uy)
                    half_j = pair[j, 1] * abs(pair[j, 6] * ux + pair[j, 7] * uy)
                    var_b = 0.5 * (det[i, 7] + det[j, 7])
                    thr_e = k_sigma * math.sqrt(var_b)
                    u = pair[i, 5] + pair[j, 5]
                    u = u - math.floor(u)
                    # Exact shortcut for the many pairs that cannot join: the saddle S is at most the summed
                    # profile at the midpoint (one of saddle_search's 33 points); below the threshold, its z-score
                    # is at most that value's with the largest signal variance there (the two profiles at the
                    # saddle are >= 0 and sum to S, so neither exceeds the midpoint's sum), and the join
                    # probability at most the one of that bound. A draw above the bound (by a margin far above its
                    # rounding) decides "apart" without the search.
                    p_i, p_j = det[i, 5], det[j, 5]
                    ti = profile_terms(pair[i, 0], half_i)
                    tj = profile_terms(pair[j, 0], half_j)
                    a_s[16] = profile_at(0.5 * d, p_i, half_i, ti)  # saddle_search's k = 16: s = d - s = d / 2
                    b_s[16] = profile_at(0.5 * d, p_j, half_j, tj)
                    s_mid = a_s[16] + b_s[16]
                    if s_mid < thr_e:
                        var_max = (var_b + _signal_variance(s_mid, pair[i], f2)
                                   + _signal_variance(s_mid, pair[j], f2))
                        miss = 1.0 - _ndtr((s_mid - thr_e) / math.sqrt(var_max))
                        if u >= 1.0 - miss * miss + 1e-12:
                            continue
                    a_s[0] = profile_at(0.0, p_i, half_i, ti)
                    b_s[0] = profile_at(d, p_j, half_j, tj)
                    a_s[32] = profile_at(d, p_i, half_i, ti)
                    b_s[32] = profile_at(0.0, p_j, half_j, tj)
                    # Exact shortcut for the pairs that surely join: i's profile falls and j's rises along the
                    # segment, so the saddle is at least the least of the two halves' bounds (saddle_search's, with
                    # its margin); the join probability is at least the one of that bound, with the signal
                    # variance at its largest above the threshold (the peaks') or its least below (none).
                    s_low = min(a_s[16] + b_s[0], a_s[32] + b_s[16]) - 1e-9 * (p_i + p_j)
                    var_s = var_b
                    if s_low >= thr_e:
                        var_s = var_b + _signal_variance(p_i, pair[i], f2) + _signal_variance(p_j, pair[j], f2)
                    miss = 1.0 - _ndtr((s_low - thr_e) / math.sqrt(var_s))
                    if u < 1.0 - miss * miss - 1e-12:
                        p = 1.0
                    else:
                        p = _merge_probability(d, p_i, p_j, pair[i], pair[j], half_i, half_j, var_b, thr_e, f2, ti,
                                               tj, a_s, b_s, lows)
                    if u < p:
                        touched[i] = True
                        touched[j] = True
                        ri = _find(parent, i)
                        rj = _find(parent, j)
                        if ri != rj:
                            parent[max(ri, rj)] = min(ri, rj)
    for i in range(n):
        parent[i] = _find(parent, i)
    return parent, touched


@njit(cache=True, no_cfunc_wrapper=True)
def order_decreasing(key):
    """Stable order of decreasing ``key`` (K,) (float64, C-contiguous, no NaN): a least-significant-digit radix
    sort on the upper 32 bits, then an insertion sort on the lower 32 within each run of equal upper halves
    (rare and short: keys that close are equal or a few ulps apart); up to 64 keys, an insertion sort.

    Returns
    -------
    ndarray of int64, shape (K,)
        ``numpy.argsort(-key, kind="stable")``.
    """
    n = key.shape[0]
    bits = key.view(np.uint64)
    sign = np.uint64(1) << np.uint64(63)
    ukey = np.empty(n, dtype=np.uint64)
    for i in range(n):
        b = bits[i]
        # increasing ukey = decreasing key: non-negative keys in reverse order first, then negative ones
        ukey[i] = b if b & sign else ~b & ~sign
    idx = np.empty(n, dtype=np.int64)
    for i in range(n):
        idx[i] = i
    if n <= 64:  # a few keys (a still frame's): an insertion sort beats the radix passes' fixed cost
        _insertion(idx, ukey, np.uint64(0))
        return idx
    hist = np.zeros((4, 256), dtype=np.int64)
    for i in range(n):
        u = ukey[i] >> np.uint64(32)
        for p in range(4):
            hist[p, (u >> np.uint64(8 * p)) & np.uint64(255)] += 1
    tmp = np.empty(n, dtype=np.int64)
    pos = np.empty(256, dtype=np.int64)
    for p in range(4):
        same = False
        for d in range(256):
            same = same or hist[p, d] == n
        if same:  # one digit value for every key: nothing to reorder
            continue
        acc = 0
        for d in range(256):
            pos[d] = acc
            acc += hist[p, d]
        shift = np.uint64(32 + 8 * p)
        for t in range(n):
            i = idx[t]
            d = (ukey[i] >> shift) & np.uint64(255)
            tmp[pos[d]] = i
            pos[d] += 1
        idx, tmp = tmp, idx
    _insertion(idx, ukey, ~np.uint64(0xFFFFFFFF))
    return idx


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _insertion(idx, ukey, upper):
    """Stable insertion sort of ``idx`` by increasing ``ukey[idx]`` within its runs of equal ``ukey & upper``
    (``upper = 0``: the whole array); only a strictly larger key moves past, so equal keys keep their order."""
    for t in range(1, idx.shape[0]):
        i = idx[t]
        u = ukey[i]
        s = t
        while s > 0 and ukey[idx[s - 1]] & upper == u & upper and ukey[idx[s - 1]] > u:
            idx[s] = idx[s - 1]
            s -= 1
        idx[s] = i


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _assemble(det, far, pair, src, rows, n_star, n_optical, kinds, sensor, background, k_sigma, n_extra):
    """Merge the touching detections and finish them (DN, area, saturation, SNR): the columns of the result,
    with room for ``n_extra`` single-pixel detections after them; returns the arrays and the count."""
    g_dn, bias_dn, saturation_dn = sensor[10], sensor[7], sensor[6]
    parent, touched = _touching(det, far, pair, k_sigma, sensor[1])
    nk = far.shape[0]
    cap = nk + n_extra
    f = np.empty((cap, 8))  # xy, truth xy, intensity, peak, snr, background variance / area scratch
    lab = np.empty((cap, 3), dtype=np.int64)  # star, exposure, kind
    area = np.empty(cap, dtype=np.int64)
    sat = np.empty(cap, dtype=np.bool_)
    area_f = np.empty(cap)
    q = 0
    slot = np.empty(nk, dtype=np.int64)
    lead_w = np.empty(nk)
    n_single = 0
    for i in range(nk):
        slot[i] = -1
        n_single += 0 if touched[i] else 1
    for pass_ in range(2):  # the spots that touch none in order, then the groups by their smallest member
        for i in range(nk):
            if touched[i] != (pass_ == 1):
                continue
            r = rows[i]
            if pass_ == 0:
                g = q
                q += 1
                f[g, 0] = det[i, 2]
                f[g, 1] = det[i, 3]
                f[g, 4] = det[i, 4]
                f[g, 5] = det[i, 5]
                area_f[g] = det[i, 6]
            else:
                root = parent[i]
                if slot[root] < 0:
                    slot[root] = q
                    f[q, 0] = 0.0
                    f[q, 1] = 0.0
                    f[q, 4] = 0.0
                    f[q, 5] = 0.0
                    area_f[q] = 0.0
                    lead_w[root] = -1.0
                    q += 1
                g = slot[root]
                w = det[i, 4]
                f[g, 0] += w * det[i, 2]
                f[g, 1] += w * det[i, 3]
                f[g, 4] += w
                f[g, 5] += det[i, 5]
                area_f[g] += det[i, 6]
                if w < lead_w[root]:  # the brightest member labels the merged detection (the last of equals)
                    continue
                lead_w[root] = w
            f[g, 2] = det[i, 0]
            f[g, 3] = det[i, 1]
            f[g, 7] = det[i, 7]
            lab[g, 0] = src[r, 0]
            lab[g, 1] = src[r, 1]
            lab[g, 2] = kinds[0] if r < n_star else (kinds[1] if r < n_optical else kinds[2])
    for g in range(n_single, q):
        f[g, 0] /= f[g, 4]
        f[g, 1] /= f[g, 4]
    opt0, gx, gy, cx, cy = background[0], background[1], background[2], background[3], background[4]
    for g in range(q):
        inten = f[g, 4]
        bg_e = background[6] * max(opt0 + gx * (f[g, 2] - cx) + gy * (f[g, 3] - cy), 0.0) + background[5]
        sat[g] = (f[g, 5] + bg_e) / g_dn + bias_dn >= saturation_dn
        sigma_dn = math.sqrt(f[g, 7]) / g_dn
        a = max(np.rint(area_f[g]), 1.0)
        area[g] = np.int64(a)
        f[g, 5] = min(f[g, 5] / g_dn, saturation_dn - bias_dn)
        f[g, 6] = inten / g_dn / (sigma_dn * math.sqrt(a))
        f[g, 4] = inten / g_dn
    return f, lab, area, sat, q


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _single_pixels(f, lab, area, sat, q, hot_index, hot_dark_e_per_s, z_hot, noise_index, noise_dn, background, sensor,
                   k_sigma, n_cols, kinds):
    """Append the hot pixels that cross the threshold and the background's crossings from row ``q``; returns the
    new count."""
    g_dn, bias_dn, saturation_dn, full_well_e, adc_max_dn = sensor[10], sensor[7], sensor[6], sensor[8], sensor[9]
    opt0, gx, gy, cx, cy = background[0], background[1], background[2], background[3], background[4]
    dark, gain_bg, enf2c, read_var, prnu = background[5], background[6], background[7], background[8], background[9]
    integration_s = background[12]
    for h in range(hot_index.shape[0]):
        # background + the pixel's own dark charge, detected when the drawn DN crosses the threshold
        hr = hot_index[h] // n_cols
        hc = hot_index[h] - hr * n_cols
        qe = gain_bg * max(opt0 + gx * (hc - cx) + gy * (hr - cy), 0.0)
        hot_e = hot_dark_e_per_s[h] * integration_s
        var0 = enf2c * qe + dark + read_var
        mean_dn0 = (qe + dark) / g_dn + bias_dn
        sd_dn0 = math.sqrt((var0 + (prnu * qe) ** 2) / g_dn ** 2 + 1.0 / 12.0)
        e_h = qe + dark + hot_e + math.sqrt(var0 + hot_e) * z_hot[h]
        dn = min(max(np.rint(min(e_h, full_well_e) / g_dn + bias_dn), 0.0), adc_max_dn)
        if dn > mean_dn0 + k_sigma * sd_dn0:
            _put_pixel(f, lab, area, sat, q, hc, hr, dn - mean_dn0, dn >= saturation_dn, sd_dn0, kinds[3])
            q += 1
    for i in range(noise_index.shape[0]):
        fr = noise_index[i] // n_cols
        fc = noise_index[i] - fr * n_cols
        qe = gain_bg * max(opt0 + gx * (fc - cx) + gy * (fr - cy), 0.0)
        mean_dn = (qe + dark) / g_dn + bias_dn
        sd = math.sqrt((enf2c * qe + dark + read_var + (prnu * qe) ** 2) / g_dn ** 2 + 1.0 / 12.0)
        _put_pixel(f, lab, area, sat, q, fc, fr, noise_dn[i] - mean_dn, noise_dn[i] >= saturation_dn, sd, kinds[4])
        q += 1
    return q


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _put_pixel(f, lab, area, sat, q, col, row, signal_dn, saturated, sigma_dn, kind):
    f[q, 0] = col
    f[q, 1] = row
    f[q, 2] = col
    f[q, 3] = row
    f[q, 4] = signal_dn
    f[q, 5] = signal_dn
    f[q, 6] = signal_dn / max(sigma_dn, 1e-9)
    lab[q, 0] = -1
    lab[q, 1] = -1
    lab[q, 2] = kind
    area[q] = 1
    sat[q] = saturated


@njit(cache=True, no_cfunc_wrapper=True)
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
    ``u_detect < p_det`` (:func:`spot_theory` at its background) and a pixel there can still exceed the threshold
    (``floor(background + kσ) + 1 <= saturation_dn``, in DN); its centroid is the truth plus
    ``z0 √var_along`` along and ``z1 √var_cross`` across the motion, its charge ``max(cap + z2 √var_cap, 1e-3)``.
    Detected spots near each other merge into one, as connected pixels do, with the probability that the saddle of
    their summed expected profiles (each a Gaussian smeared over its streak's projection on the line between them)
    is above the threshold given the noise there (``_merge_probability``; the pair's draw is ``frac(u_i + u_j)`` of
    the two spots' detection draws scaled to U(0, 1)): intensity-weighted centroid, summed charge, area and peak,
    the labels of the brightest member. Near-overlapping spots of paper 000's high-N frames thus give the pixel
    path's joined detections, at the same rate versus separation (tests/test_overlap_fidelity.py). A hot pixel (dark charge over the integration window on top of the
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
    xy : ndarray, shape (2, K, 2)
        ``xy[0]``: the centroids, px; ``xy[1]``: where each source's light is centred, px.
    values : ndarray, shape (3, K)
        Rows: intensity (DN above the background), peak (above the background, DN, clipped at saturation) and snr.
    labels : ndarray of int64, shape (4, K)
        Rows: area (px), scene star index (−1 otherwise), exposure index (stars and debris, −1 otherwise) and kind.
    saturated : ndarray of bool, shape (K,)
    background_dn, noise_dn : float
        Background level and σ at the principal point, DN.

    Notes
    -----
    The outputs of one kind share one array (each row a C-contiguous view for the caller's fields): every array
    handed back to Python costs a boxing of its own.
    """
    c_id, c_g, c_src, n_optical, n_star = _candidates(
        xy_path, visible, star_pe, debris_xy0, debris_velocity_px_s, debris_pe, t_start_rel_s, t_end_rel_s,
        cosmic_start_xy, cosmic_end_xy, cosmic_e, n_cols, n_rows)
    rows, det, far, pair = _detect(c_id, c_g, n_optical, u_detect, z_spot, background, sensor, factors, k_sigma)
    f, lab, area, sat, q = _assemble(det, far, pair, c_src, rows, n_star, n_optical, kinds, sensor, background,
                                     k_sigma,
                                     hot_index.shape[0] + noise_index.shape[0])
    q = _single_pixels(f, lab, area, sat, q, hot_index, hot_dark_e_per_s, z_hot, noise_index, noise_dn, background,
                       sensor, k_sigma, n_cols, kinds)
    key = np.empty(q)
    for i in range(q):
        key[i] = f[i, 4]
    order = order_decreasing(key)
    cx, cy = background[3], background[4]
    q_c = background[6] * max(background[0], 0.0)
    g_dn = sensor[10]
    bg_dn = (q_c + background[5]) / g_dn + sensor[7]
    noise_dn_c = math.sqrt((background[7] * q_c + background[5] + background[8] + (background[9] * q_c) ** 2) / g_dn ** 2
                           + 1.0 / 12.0)
    xy = np.empty((2, q, 2))
    vals = np.empty((3, q))
    labels = np.empty((4, q), dtype=np.int64)
    sat_o = np.empty(q, dtype=np.bool_)
    for t in range(q):
        i = order[t]
        xy[0, t, 0] = f[i, 0]
        xy[0, t, 1] = f[i, 1]
        xy[1, t, 0] = f[i, 2]
        xy[1, t, 1] = f[i, 3]
        vals[0, t] = f[i, 4]
        vals[1, t] = f[i, 5]
        vals[2, t] = f[i, 6]
        labels[0, t] = area[i]
        sat_o[t] = sat[i]
        labels[1, t] = lab[i, 0]
        labels[2, t] = lab[i, 1]
        labels[3, t] = lab[i, 2]
    return xy, vals, labels, sat_o, bg_dn, noise_dn_c
