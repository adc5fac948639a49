"""Imaging kernels: spot windows, the sparse pixel set, pixels to DN, the background's threshold crossings.

Compiled with numba, no checks; the checked API is :mod:`startracker.imaging` (``render_sparse``, ``render_frame``,
``render_expected``, ``draw_false_pixels``). Pixel ``(0, 0)`` is the centre of the top-left pixel; linear pixel
indices are ``row * n_cols + col``. Random numbers are drawn by the caller's ``numpy.random.Generator`` and passed in.

The module is over 600 lines because the sparse pixel frame is one pipeline (spots, windows, the sparse set,
DN conversion, background crossings) whose stages share the same pixel-set layout.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "normal_sf",
    "normal_isf",
    "render_spot_windows",
    "shift_intensified_spots",
    "sparse_pixel_set",
    "pixels_to_dn",
    "sparse_pixels_to_dn",
    "false_pixel_cells",
    "place_false_pixels",
    "lookup_pixels",
    "spots_from_paths",
    "frame_star_spots",
    "split_pixel_index",
    "sparse_source_table",
]

_INV_SQRT2 = 1.0 / math.sqrt(2.0)


@njit(cache=True, no_cfunc_wrapper=True)
def normal_sf(t):
    """Upper tail ``Q(t) = P(Z > t)`` of the standard normal, accurate in both tails (float)."""
    return 0.5 * math.erfc(t * _INV_SQRT2)


@njit(cache=True, no_cfunc_wrapper=True)
def normal_isf(q):
    """Inverse upper tail: ``t`` with ``Q(t) = q`` for ``0 < q < 1`` (float).

    Acklam's rational approximation refined by two Halley steps on ``Q`` (relative error ~1e-15).
    """
    a = (-3.969683028665376e01, 2.209460984245205e02, -2.759285104469687e02, 1.383577518672690e02,
         -3.066479806614716e01, 2.506628277459239e00)
    b = (-5.447609879822406e01, 1.615858368580409e02, -1.556989798598866e02, 6.680131188771972e01,
         -1.328068155288572e01)
    c = (-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e00, -2.549732539343734e00,
         4.374664141464968e00, 2.938163982698783e00)
    d = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e00, 3.754408661907416e00)
    p = q if q < 0.5 else 1.0 - q  # lower-tail probability of -|t|
    if p < 0.02425:
        s = math.sqrt(-2.0 * math.log(p))
        x = (((((c[0] * s + c[1]) * s + c[2]) * s + c[3]) * s + c[4]) * s + c[5]) / \
            ((((d[0] * s + d[1]) * s + d[2]) * s + d[3]) * s + 1.0)
    else:
        s = p - 0.5
        r = s * s
        x = (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * s / \
            (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)
    t = -x if q < 0.5 else x  # x solves Φ(x) = p, so Q(−x) = p
    for _ in range(2):
        e = normal_sf(t) - q
        u = -e * math.sqrt(2.0 * math.pi) * math.exp(0.5 * t * t)  # −e / Q'(t)
        t = t - u / (1.0 + 0.5 * t * u)
    return t


@njit(cache=True, no_cfunc_wrapper=True)
def split_pixel_index(px, n_cols, inv_cols):
    """Row and column of a linear pixel index, exactly ``divmod(px, n_cols)`` for ``px >= 0`` (int, int).

    The quotient is guessed from the product with ``inv_cols = 1.0 / n_cols`` (off by at most one) and corrected
    in integers: a hardware integer division by a run-time divisor costs several times more, once per pixel.
    """
    r = np.int64(px * inv_cols)
    c = px - r * n_cols
    if c < 0:
        r -= 1
        c += n_cols
    elif c >= n_cols:
        r += 1
        c -= n_cols
    return r, c


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _optical_pe(opt0, opt_dx, opt_dy, cx, cy, x, y):
    """The planar optical background at (x, y) px, photoelectrons, >= 0 (``BackgroundField.optical_pe``)."""
    return max(opt0 + opt_dx * (x - cx) + opt_dy * (y - cy), 0.0)


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True, inline="always")
def _hart_terms(t):
    """Numerator and denominator of Hart's rational for ``Q(t)``, ``0 <= t < 7.07`` (Horner; the denominator is
    >= 440). Inlined where it is used, so :func:`_edge_tails`' loop over them still vectorises."""
    n = 3.52624965998911e-02 * t + 0.700383064443688
    n = n * t + 6.37396220353165
    n = n * t + 33.912866078383
    n = n * t + 112.079291497871
    n = n * t + 221.213596169931
    n = n * t + 220.206867912376
    d = 8.83883476483184e-02 * t + 1.75566716318264
    d = d * t + 16.064177579207
    d = d * t + 86.7807322029461
    d = d * t + 296.564248779674
    d = d * t + 637.333633378831
    d = d * t + 793.826512519948
    d = d * t + 440.413735824752
    return n, d


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _upper_tail_hart(t):
    """``Q(t)`` for ``t >= 0`` by Hart's rational approximation (West 2005): absolute error < 2e-16 (relative
    error up to ~1e-8 in the far tail), half the cost of ``erfc``. For pixel fractions of a spot, where only the
    absolute error matters."""
    e = math.exp(-0.5 * t * t)
    if t < 7.07106781186547:
        n, d = _hart_terms(t)
        return e * n / d
    b = t + 0.65
    b = t + 4.0 / b
    b = t + 3.0 / b
    b = t + 2.0 / b
    b = t + 1.0 / b
    return e / b / 2.506628274631


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True, error_model="numpy")
def _edge_tails(t, q, m):
    """``q[i] = Q(|t[i]|)`` by :func:`_upper_tail_hart` (the same operations, so the same values) for i < m.

    In passes over all the edges of a window: the ``exp`` calls, then Hart's rational (two Horner chains and a
    division, most of its cost) in a branch-free loop that vectorises (error_model="numpy": no zero-division
    branch; its denominator is >= 440), then the rare far-tail edges (|t| >= 7.07, or NaN) redone, in a pass
    run only when there are any (a loop testing each edge costs as much as the rational).
    """
    for i in range(m):
        a = abs(t[i])
        q[i] = math.exp(-0.5 * a * a)
    far = 0
    for i in range(m):
        a = abs(t[i])
        n, d = _hart_terms(a)
        q[i] = q[i] * n / d
        far += not a < 7.07106781186547  # a count, not a branch: the loop stays vectorised
    if far > 0:
        for i in range(m):
            a = abs(t[i])
            if not a < 7.07106781186547:
                q[i] = _upper_tail_hart(a)


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _edge_fractions(t, q, i0, n, out):
    """Fraction of a unit Gaussian in each of n pixels whose edges' standardised positions are t[i0 : i0 + n + 1]
    and their upper tails ``Q(|t|)`` q[i0 : i0 + n + 1] (from :func:`_edge_tails`)."""
    for j in range(n):
        ta = t[i0 + j]
        qa = q[i0 + j]
        qb = q[i0 + j + 1]
        if ta >= 0.0:
            out[j] = qa - qb  # both edges right of the centre: Q(a) − Q(b)
        elif t[i0 + j + 1] <= 0.0:
            out[j] = qb - qa  # both left: Q(−b) − Q(−a)
        else:
            out[j] = 1.0 - qb - qa


@njit(cache=True, no_cfunc_wrapper=True)
def render_spot_windows(sub_xy, sub_w, sigma_px, half_width_px, n_cols, n_rows, min_value):
    """Pixel-integrated Gaussian sub-spots summed into one window per spot.

    Parameters
    ----------
    sub_xy : ndarray, shape (P, K, 2)
        Sub-spot centres (column, row), px.
    sub_w : ndarray, shape (P, K)
        Sub-spot signals (any unit: photoelectrons, e⁻).
    sigma_px : ndarray, shape (P,)
        Gaussian σ of each spot, px.
    half_width_px : ndarray of int64, shape (P,)
        Window half width beyond the sub-spots' extent, px.
    n_cols, n_rows : int
        Detector size, px.
    min_value : float
        Window pixels below this expected signal are dropped (0: keep all).

    Returns
    -------
    lin : ndarray of int64, shape (E,)
        Linear index of every kept in-bounds window pixel.
    value : ndarray, shape (E,)
        Expected signal there (units of ``sub_w``).
    spot : ndarray of int64, shape (E,)
        Spot index (into P) of each entry.
    """
    n_p, n_k = sub_w.shape
    c_lo = np.empty(n_p, dtype=np.int64)
    r_lo = np.empty(n_p, dtype=np.int64)
    wc = np.empty(n_p, dtype=np.int64)
    wr = np.empty(n_p, dtype=np.int64)
    ca_ = np.empty(n_p, dtype=np.int64)
    cb_ = np.empty(n_p, dtype=np.int64)
    ra_ = np.empty(n_p, dtype=np.int64)
    rb_ = np.empty(n_p, dtype=np.int64)
    cap = 0
    w_max = 0
    for p in range(n_p):
        x0 = sub_xy[p, 0, 0]
        x1 = x0
        y0 = sub_xy[p, 0, 1]
        y1 = y0
        wsum = 0.0
        for k in range(n_k):
            x0 = min(x0, sub_xy[p, k, 0])
            x1 = max(x1, sub_xy[p, k, 0])
            y0 = min(y0, sub_xy[p, k, 1])
            y1 = max(y1, sub_xy[p, k, 1])
            wsum += sub_w[p, k]
        h = half_width_px[p]
        c_lo[p] = np.int64(np.rint(x0)) - h
        r_lo[p] = np.int64(np.rint(y0)) - h
        wc[p] = np.int64(np.rint(x1)) + h - c_lo[p] + 1
        wr[p] = np.int64(np.rint(y1)) + h - r_lo[p] + 1
        ca = max(c_lo[p], 0)
        cb = min(c_lo[p] + wc[p], n_cols)
        ra = max(r_lo[p], 0)
        rb = min(r_lo[p] + wr[p], n_rows)
        if min_value > 0.0 and wsum > 0.0:
            # Trim the window to the rows and columns that can reach min_value. A pixel whose nearest edge lies
            # d beyond every sub-spot along one axis holds at most wsum c Q(d/σ), with c = min(1, 1/(σ√(2π))) the
            # largest fraction of a unit Gaussian in one pixel along the other axis, and Q(t) <= exp(−t²/2)/2
            # (Chernoff), tightened where it holds by Q(t) <= φ(t)/t (Mills). The kept pixels and their values
            # are unchanged (the edges stay integers + 0.5), only fewer of them are evaluated.
            s = sigma_px[p]
            c = min(1.0, 1.0 / (s * math.sqrt(2.0 * math.pi)))
            ratio = wsum * c / (2.0 * min_value)
            if ratio > 1.0:
                t = math.sqrt(2.0 * math.log(ratio))
                a = wsum * c / (min_value * math.sqrt(2.0 * math.pi))
                t_prev = t
                for _ in range(3):
                    q = a / t_prev
                    if q <= 1.0:
                        break
                    t_new = math.sqrt(2.0 * math.log(q))
                    t_try = max(t_new, 0.5 * (t_new + t_prev))
                    if t_try > 0.0 and a * math.exp(-0.5 * t_try * t_try) / t_try < 0.999:
                        t = min(t, t_try)
                    t_prev = t_new
                d = s * t * (1.0 + 1e-9) + 1e-9
                # keep pixel centres strictly within (x0 − d − 0.5, x1 + d + 0.5) (and likewise for rows)
                ca = max(ca, np.int64(math.floor(x0 - d - 0.5)) + 1)
                cb = min(cb, np.int64(math.ceil(x1 + d + 0.5)))
                ra = max(ra, np.int64(math.floor(y0 - d - 0.5)) + 1)
                rb = min(rb, np.int64(math.ceil(y1 + d + 0.5)))
        ca_[p] = ca
        cb_[p] = cb
        ra_[p] = ra
        rb_[p] = rb
        if cb > ca and rb > ra:
            cap += (cb - ca) * (rb - ra)
            w_max = max(w_max, cb - ca, rb - ra)
    lin = np.empty(cap, dtype=np.int64)
    val = np.empty(cap)
    spot = np.empty(cap, dtype=np.int64)
    gx = np.empty((n_k, w_max))
    gy = np.empty((n_k, w_max))
    gx_max = np.empty(n_k)
    acc = np.empty(w_max)
    t_edge = np.empty(2 * n_k * (w_max + 1))
    q_edge = np.empty(2 * n_k * (w_max + 1))
    n = 0
    for p in range(n_p):
        ca = ca_[p]
        cb = cb_[p]
        ra = ra_[p]
        rb = rb_[p]
        if cb <= ca or rb <= ra:
            continue
        nc = cb - ca
        nr = rb - ra
        inv_s = 1.0 / sigma_px[p]
        # every sub-spot's column edges, then its row edges, standardised (edge − centre) / σ; the edges are
        # half-integers, so ca − 0.5 + j is exact
        m = 0
        for k in range(n_k):
            cx = sub_xy[p, k, 0]
            for j in range(nc + 1):
                t_edge[m + j] = (ca - 0.5 + j - cx) * inv_s
            m += nc + 1
        for k in range(n_k):
            cy = sub_xy[p, k, 1]
            for i in range(nr + 1):
                t_edge[m + i] = (ra - 0.5 + i - cy) * inv_s
            m += nr + 1
        _edge_tails(t_edge, q_edge, m)  # each edge's Q once, shared by the two pixels it bounds
        for k in range(n_k):
            _edge_fractions(t_edge, q_edge, k * (nc + 1), nc, gx[k])
            _edge_fractions(t_edge, q_edge, n_k * (nc + 1) + k * (nr + 1), nr, gy[k])
            wk = sub_w[p, k]
            for i in range(rb - ra):
                gy[k, i] *= wk
        if min_value > 0.0:
            for k in range(n_k):
                m = 0.0
                for j in range(nc):
                    m = max(m, gx[k, j])
                gx_max[k] = m
        for i in range(rb - ra):
            if min_value > 0.0:
                bound = 0.0
                for k in range(n_k):
                    bound += gy[k, i] * gx_max[k]
                if bound < min_value:
                    continue
            # k outermost so the column loop vectorises; each pixel still sums its sub-spots in order k = 0, 1, …
            for j in range(nc):
                acc[j] = 0.0
            for k in range(n_k):
                g = gy[k, i]
                for j in range(nc):
                    acc[j] += g * gx[k, j]
            base = (ra + i) * n_cols + ca
            for j in range(nc):
                v = acc[j]
                if min_value > 0.0 and v < min_value:
                    continue
                lin[n] = base + j
                val[n] = v
                spot[n] = p
                n += 1
    return lin[:n], val[:n], spot[:n]


@njit(cache=True, no_cfunc_wrapper=True)
def shift_intensified_spots(sub_xy, along, length_px, n_pe, charge_e, z, excess_noise_factor, optics_sigma_px):
    """Displace each intensified spot by the scatter of its photoelectrons and give it its random charge.

    Parameters
    ----------
    sub_xy : ndarray, shape (P, K, 2)
        Sub-spot centres, px (not modified).
    along : ndarray, shape (P, 2)
        Unit vector along each spot's segment.
    length_px : ndarray, shape (P,)
        Segment lengths, px.
    n_pe : ndarray, shape (P,)
        Drawn photoelectron counts (Poisson).
    charge_e : ndarray, shape (P,)
        Drawn charge after the intensifier, e⁻.
    z : ndarray, shape (P, 2)
        Standard normal draws (along, across).
    excess_noise_factor, optics_sigma_px : float
        Intensifier excess-noise factor F and the optics' part of the PSF σ, px.

    Returns
    -------
    sub_xy : ndarray, shape (P, K, 2)
        Shifted sub-spot centres, px.
    sub_w : ndarray, shape (P, K)
        Charge per sub-spot, e⁻.
    """
    n_p, n_k, _ = sub_xy.shape
    out_xy = np.empty_like(sub_xy)
    out_w = np.empty((n_p, n_k))
    f2 = excess_noise_factor * excess_noise_factor
    so2 = optics_sigma_px * optics_sigma_px
    for p in range(n_p):
        n_eff = max(n_pe[p], 1.0)
        sd_cross = math.sqrt(f2 * so2 / n_eff)
        sd_along = math.sqrt(f2 * (so2 + length_px[p] * length_px[p] / 12.0) / n_eff)
        ax = along[p, 0]
        ay = along[p, 1]
        dx = ax * z[p, 0] * sd_along - ay * z[p, 1] * sd_cross
        dy = ay * z[p, 0] * sd_along + ax * z[p, 1] * sd_cross
        w = charge_e[p] / n_k
        for k in range(n_k):
            out_xy[p, k, 0] = sub_xy[p, k, 0] + dx
            out_xy[p, k, 1] = sub_xy[p, k, 1] + dy
            out_w[p, k] = w
    return out_xy, out_w


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _add_3x3(centres, n_cols, n_rows, src0, centre_e, lin, src, exp_e, n):
    for i in range(len(centres)):
        r0 = centres[i] // n_cols
        c0 = centres[i] - r0 * n_cols
        for dr in range(-1, 2):
            r = r0 + dr
            if r < 0 or r >= n_rows:
                continue
            for dc in range(-1, 2):
                c = c0 + dc
                if c < 0 or c >= n_cols:
                    continue
                lin[n] = r * n_cols + c
                src[n] = src0 + i
                exp_e[n] = centre_e[i] if dr == 0 and dc == 0 else 0.0
                n += 1
    return n


@njit(cache=True, no_cfunc_wrapper=True)
def sparse_pixel_set(opt_lin, opt_val, opt_src, opt_e_per_unit, dir_lin, dir_val, dir_src, hot_lin, hot_e, hot_src0,
                     false_lin, false_src0, n_cols, n_rows, buf, prnu):
    """The deduplicated pixels of a sparse frame and its entries (window pixels, 3×3 neighbourhoods), with each
    pixel's PRNU gathered.

    Entries come in this order: optical windows, cosmic-ray windows, hot pixels' 3×3, background crossings' 3×3.
    Deduplication uses ``buf`` as a sparse set: it is never cleared, ``buf[lin]`` is trusted only when it points
    back to the same pixel. On return ``buf[uniq[i]] == i``. Every entry's PRNU is read first, in one pass of
    independent loads: with ``buf`` and ``prnu`` the two columns of one interleaved (n_px, 2) array (as
    :func:`startracker.imaging.render_sparse` passes them) that pass brings in the cache lines the deduplication's
    lookups then hit, one miss per window row instead of two in separate maps.

    Parameters
    ----------
    opt_lin, opt_val, opt_src : ndarray, shape (E1,)
        Optical window entries: linear index, expected signal (units of the rendered spots), source id.
    opt_e_per_unit : float
        e⁻ per unit of ``opt_val`` (the truth charge of an entry).
    dir_lin, dir_val, dir_src : ndarray, shape (E2,)
        Directly deposited charge (cosmic rays): linear index, e⁻, source id.
    hot_lin : ndarray of int64, shape (H,)
        Hot pixels' linear indices; ``hot_e`` (H,) their expected extra dark charge, e⁻; source ids from hot_src0.
    false_lin : ndarray of int64, shape (F,)
        Distinct background threshold crossings; source ids from false_src0.
    n_cols, n_rows : int
    buf : ndarray of int32, shape (n_rows * n_cols,)
        Persistent index buffer (modified; may be a strided view).
    prnu : ndarray of float32, shape (n_rows * n_cols,) or (0,)
        The detector's PRNU map (relative gain − 1; may be a strided view), none when empty.

    Returns
    -------
    uniq : ndarray of int64, shape (U,)
        Distinct pixels, in order of first appearance.
    entry_pixel, entry_source : ndarray of int64, shape (E,)
    entry_e : ndarray, shape (E,)
        Expected charge of the entry's source in that pixel, e⁻ (1 at a crossing's centre, 0 around it; 0 for
        every entry of a crossing that falls on a window pixel).
    spot_u : ndarray, shape (U,)
        Optical signal per pixel (units of ``opt_val``).
    direct_u : ndarray, shape (U,)
        Cosmic-ray charge per pixel, e⁻.
    hot_u : ndarray of int64, shape (H,)
        Compact id of each hot pixel.
    false_u : ndarray of int64, shape (F,)
        Compact id of each crossing, −1 where it fell on a window (optical, cosmic-ray or hot) pixel.
    prnu_u : ndarray of float32, shape (U,) or (0,)
        ``prnu[uniq]`` (empty when ``prnu`` is).
    """
    n1 = len(opt_lin)
    n2 = len(dir_lin)
    cap = n1 + n2 + 9 * (len(hot_lin) + len(false_lin))
    lin = np.empty(cap, dtype=np.int64)
    src = np.empty(cap, dtype=np.int64)
    exp_e = np.empty(cap)
    for i in range(n1):
        lin[i] = opt_lin[i]
        src[i] = opt_src[i]
        exp_e[i] = opt_val[i] * opt_e_per_unit
    for i in range(n2):
        lin[n1 + i] = dir_lin[i]
        src[n1 + i] = dir_src[i]
        exp_e[n1 + i] = dir_val[i]
    n = _add_3x3(hot_lin, n_cols, n_rows, hot_src0, hot_e, lin, src, exp_e, n1 + n2)
    n_base = n
    n = _add_3x3(false_lin, n_cols, n_rows, false_src0, np.ones(len(false_lin)), lin, src, exp_e, n)
    uniq = np.empty(n, dtype=np.int64)
    inv = np.empty(n, dtype=np.int64)
    has_prnu = len(prnu) > 0
    # Every entry's PRNU first, in a loop of independent loads: in the deduplication below each load waits on the
    # previous entry's branch, so the cache misses of the window rows in the large index+PRNU array would come one
    # at a time; here they overlap, and the deduplication finds the lines cached (this kernel ~1.7x faster in the
    # pixel env). The deduplication then compacts the values in place (n_u <= e).
    prnu_all = np.empty(n if has_prnu else 0, dtype=np.float32)
    for e in range(len(prnu_all)):
        prnu_all[e] = prnu[lin[e]]
    n_u = 0
    n_u_base = 0
    for e in range(n):
        if e == n_base:
            n_u_base = n_u
        px = lin[e]
        cand = buf[px]
        if cand >= 0 and cand < n_u and uniq[cand] == px:
            inv[e] = cand
        else:
            buf[px] = n_u
            uniq[n_u] = px
            if has_prnu:
                prnu_all[n_u] = prnu_all[e]
            inv[e] = n_u
            n_u += 1
    if n == n_base:
        n_u_base = n_u
    spot_u = np.zeros(n_u)
    direct_u = np.zeros(n_u)
    for e in range(n1):
        spot_u[inv[e]] += opt_val[e]
    for e in range(n1, n1 + n2):
        direct_u[inv[e]] += dir_val[e - n1]
    hot_u = np.empty(len(hot_lin), dtype=np.int64)
    for i in range(len(hot_lin)):
        hot_u[i] = buf[hot_lin[i]]
    # pixels first seen after the window entries are exactly those outside every window
    false_u = np.empty(len(false_lin), dtype=np.int64)
    for i in range(len(false_lin)):
        u = buf[false_lin[i]]
        false_u[i] = u if u >= n_u_base else -1
    for e in range(n_base, n):
        if false_u[src[e] - false_src0] < 0:
            exp_e[e] = 0.0
    return (uniq[:n_u].copy(), inv[:n], src[:n], exp_e[:n], spot_u, direct_u, hot_u, false_u,
            prnu_all[:n_u].copy() if has_prnu else prnu_all)


@njit(cache=True, no_cfunc_wrapper=True)
def pixels_to_dn(intensified, spot_e, opt_bg_pe, prnu, lin, z, charge_e, direct_e, hot_u, hot_e, hot_z, gain,
                 enf2_c, dark_e, read_var_e2, full_well_e, gain_e_per_dn, bias_dn, adc_max_dn):
    """Random DN of pixels from their expected signals and the caller's draws.

    Parameters
    ----------
    intensified : bool
        Intensified detector: ``spot_e`` is the randomised spot charge, e⁻, and gets the pixel shape noise;
        CMOS: the star charge is ``charge_e`` (drawn Poisson × gain statistics) and ``spot_e`` is unused.
    spot_e : ndarray, shape (U,)
        Intensified spot charge per pixel, e⁻.
    opt_bg_pe : ndarray, shape (U,)
        Optical background photoelectrons (sky, stray light) per pixel.
    prnu : ndarray of float32, shape (n_rows * n_cols,) or (0,)
        The detector's photo-response non-uniformity (relative gain − 1), none when empty.
    lin : ndarray of int64, shape (U,)
        Linear indices of the pixels (into ``prnu``).
    z : ndarray, shape (U,)
        Standard normal draws (pixel noise).
    charge_e : ndarray, shape (U,)
        CMOS: star charge per pixel, e⁻ (zeros for an intensified detector).
    direct_e : ndarray, shape (U,)
        Directly deposited charge (cosmic rays), e⁻.
    hot_u : ndarray of int64, shape (H,)
        Compact ids of hot pixels; ``hot_e`` (H,) their expected extra dark charge, e⁻; ``hot_z`` (H,) normal draws.
    gain, enf2_c, dark_e, read_var_e2 : float
        Intensifier gain, its pixel variance per unit charge G F² c, dark charge e⁻, read variance e⁻².
    full_well_e, gain_e_per_dn, bias_dn, adc_max_dn : float

    Returns
    -------
    dn : ndarray, shape (U,)
    """
    u = len(z)
    out = np.empty(u)
    base_var = dark_e + read_var_e2
    has_prnu = len(prnu) > 0
    for i in range(u):
        f = 1.0 + np.float64(prnu[lin[i]]) if has_prnu else 1.0
        out[i] = _pixel_electrons(intensified, spot_e[i], gain * opt_bg_pe[i], f, z[i], charge_e[i], enf2_c, dark_e,
                                  base_var) + direct_e[i]
    for h in range(len(hot_u)):
        i = hot_u[h]
        out[i] += hot_e[h] + math.sqrt(hot_e[h]) * hot_z[h]
    inv_gain = 1.0 / gain_e_per_dn
    for i in range(u):
        out[i] = _digitise(out[i], full_well_e, inv_gain, bias_dn, adc_max_dn)
    return out


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _pixel_electrons(intensified, spot_e, b, f, z, charge_e, enf2_c, dark_e, base_var):
    """One pixel's electrons before the ADC (see :func:`pixels_to_dn`): ``b`` its optical background e⁻ (after the
    gain), ``f`` its PRNU factor, ``z`` its standard normal draw."""
    if intensified:
        q = spot_e + b
        sd = math.sqrt(enf2_c * q + base_var)
        return q * f + dark_e + sd * z
    sd = math.sqrt(enf2_c * b + base_var)
    return sd * z + b * f + dark_e + f * charge_e


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _digitise(e, full_well_e, inv_gain, bias_dn, adc_max_dn):
    """Electrons to DN: clipped at the full well, converted, rounded, clipped to the ADC's range."""
    v = np.rint(min(e, full_well_e) * inv_gain + bias_dn)
    return min(max(v, 0.0), adc_max_dn)


@njit(cache=True, no_cfunc_wrapper=True)
def sparse_pixels_to_dn(intensified, spot_e, prnu_u, lin, z, charge_e, direct_e, hot_u, hot_e, hot_z, false_u,
                        false_dn, n_cols, opt0, opt_dx, opt_dy, cx, cy, gain, enf2_c, dark_e, read_var_e2, prnu_sigma,
                        full_well_e, gain_e_per_dn, bias_dn, adc_max_dn, k_sigma):
    """The pixels of a sparse frame in one pass: their expected background (the plane of
    :class:`startracker.imaging.BackgroundField`: optical photoelectrons, level, threshold), their random DN
    (:func:`pixels_to_dn`, same arithmetic) and the background crossings' drawn DN written over theirs.

    Parameters
    ----------
    intensified, spot_e, lin, z, charge_e, direct_e, hot_u, hot_e, hot_z
        As in :func:`pixels_to_dn`, shape (U,) (``hot_*`` (H,)).
    prnu_u : ndarray of float32, shape (U,) or (0,)
        The PRNU of each pixel (``prnu[lin]``, as gathered by :func:`sparse_pixel_set`), none when empty.
    false_u : ndarray of int64, shape (F,)
        Compact id of each background crossing, −1 where it fell on a window pixel (:func:`sparse_pixel_set`).
    false_dn : ndarray, shape (F,)
        The crossings' DN (:func:`place_false_pixels`).
    n_cols, opt0, opt_dx, opt_dy, cx, cy, gain, enf2_c, dark_e, read_var_e2, prnu_sigma
        Detector width and the background: optical plane ``opt0 + opt_dx (x − cx) + opt_dy (y − cy)``
        photoelectrons (clipped at 0), intensifier gain, its pixel variance per unit charge, dark charge e⁻, read
        variance e⁻², PRNU σ.
    full_well_e, gain_e_per_dn, bias_dn, adc_max_dn, k_sigma : float

    Returns
    -------
    dn : ndarray of float32, shape (U,)
    background_dn, threshold_dn : ndarray, shape (U,)
        Expected background and the detection threshold ``background + k_sigma σ`` (shot, dark, read, PRNU and
        1/12 DN² quantisation), DN.
    """
    u = len(z)
    out = np.empty(u)
    mean = np.empty(u)
    thr = np.empty(u)
    base_var = dark_e + read_var_e2
    has_prnu = len(prnu_u) > 0
    g2 = gain_e_per_dn * gain_e_per_dn
    inv_cols = 1.0 / n_cols
    for i in range(u):
        r, c = split_pixel_index(lin[i], n_cols, inv_cols)
        o = _optical_pe(opt0, opt_dx, opt_dy, cx, cy, float(c), float(r))
        q_bg = gain * o
        mean[i] = (q_bg + dark_e) / gain_e_per_dn + bias_dn
        var = enf2_c * q_bg + dark_e + read_var_e2 + (prnu_sigma * q_bg) ** 2
        thr[i] = mean[i] + k_sigma * math.sqrt(var / g2 + 1.0 / 12.0)
        f = 1.0 + np.float64(prnu_u[i]) if has_prnu else 1.0
        out[i] = _pixel_electrons(intensified, spot_e[i], q_bg, f, z[i], charge_e[i], enf2_c, dark_e,
                                  base_var) + direct_e[i]
    for h in range(len(hot_u)):
        i = hot_u[h]
        out[i] += hot_e[h] + math.sqrt(hot_e[h]) * hot_z[h]
    inv_gain = 1.0 / gain_e_per_dn
    dn = np.empty(u, dtype=np.float32)
    for i in range(u):
        dn[i] = _digitise(out[i], full_well_e, inv_gain, bias_dn, adc_max_dn)
    for h in range(len(false_u)):
        if false_u[h] >= 0:
            dn[false_u[h]] = false_dn[h]
    return dn, mean, thr


@njit(cache=True, no_cfunc_wrapper=True)
def false_pixel_cells(col_edges, row_edges, opt0, opt_dx, opt_dy, cx, cy, gain, enf2_c, dark_e, read_var_e2,
                      prnu_sigma, gain_e_per_dn, bias_dn, saturation_dn, k_sigma):
    """Per cell of a grid: the background's crossing probability and its statistics at the cell centre.

    Parameters
    ----------
    col_edges : ndarray, shape (GX + 1,); row_edges : ndarray, shape (GY + 1,)
        Cell edges, px (pixel centres are integers).
    opt0, opt_dx, opt_dy, cx, cy : float
        Optical background plane ``opt0 + opt_dx (x − cx) + opt_dy (y − cy)``, photoelectrons (clipped at 0).
    gain, enf2_c, dark_e, read_var_e2, prnu_sigma : float
        As in :class:`startracker.imaging.BackgroundField`.
    gain_e_per_dn, bias_dn, saturation_dn, k_sigma : float

    Returns
    -------
    cum_lam : ndarray, shape (GY * GX,)
        Cumulative expected number of crossing pixels over the cells (row-major).
    p, mu_e, sd_e, z0, thr_dn : ndarray, shape (GY * GX,)
        Crossing probability of one pixel, background mean and σ (e⁻), the standardised cut, the threshold (DN).
    """
    gx = len(col_edges) - 1
    gy = len(row_edges) - 1
    m = gx * gy
    cum = np.empty(m)
    p_out = np.empty(m)
    mu_out = np.empty(m)
    sd_out = np.empty(m)
    z0_out = np.empty(m)
    thr_out = np.empty(m)
    acc = 0.0
    for j in range(gy):
        yc = 0.5 * (row_edges[j] + row_edges[j + 1])
        n_r = math.floor(row_edges[j + 1] + 0.5) - math.floor(row_edges[j] + 0.5)
        for i in range(gx):
            xc = 0.5 * (col_edges[i] + col_edges[i + 1])
            n_c = math.floor(col_edges[i + 1] + 0.5) - math.floor(col_edges[i] + 0.5)
            q = gain * _optical_pe(opt0, opt_dx, opt_dy, cx, cy, xc, yc)
            mu = q + dark_e
            var = enf2_c * q + dark_e + read_var_e2 + (prnu_sigma * q) ** 2
            sd = math.sqrt(var)
            thr = mu / gain_e_per_dn + bias_dn + k_sigma * math.sqrt(var / gain_e_per_dn**2 + 1.0 / 12.0)
            cut_e = (math.floor(thr) + 0.5 - bias_dn) * gain_e_per_dn  # DN > thr  <=>  e >= cut_e
            z0 = (cut_e - mu) / sd
            p = normal_sf(z0) if math.floor(thr) + 1 <= saturation_dn else 0.0  # a clipped pixel cannot cross
            k = j * gx + i
            acc += p * n_r * n_c
            cum[k] = acc
            p_out[k] = p
            mu_out[k] = mu
            sd_out[k] = sd
            z0_out[k] = z0
            thr_out[k] = thr
    return cum, p_out, mu_out, sd_out, z0_out, thr_out


@njit(cache=True, no_cfunc_wrapper=True)
def place_false_pixels(u_cell, u_col, u_row, u_tail, cum_lam, col_edges, row_edges, p, mu_e, sd_e, z0, thr_dn,
                       full_well_e, gain_e_per_dn, bias_dn, adc_max_dn):
    """Positions and DN of the background's threshold crossings from uniform draws.

    Parameters
    ----------
    u_cell, u_col, u_row, u_tail : ndarray, shape (T,)
        Uniform [0, 1) draws: the cell (in proportion to its expected count), the column and row within it, and the
        value in the Gaussian tail above the cut.
    cum_lam, p, mu_e, sd_e, z0, thr_dn : ndarray, shape (GY * GX,)
        From :func:`false_pixel_cells`.
    col_edges, row_edges : ndarray
        The grid's cell edges, px.
    full_well_e, gain_e_per_dn, bias_dn, adc_max_dn : float

    Returns
    -------
    lin : ndarray of int64, shape (T,)
        Linear pixel indices (may repeat).
    dn : ndarray, shape (T,)
    """
    t = len(u_cell)
    gx = len(col_edges) - 1
    n_cols = int(math.floor(col_edges[gx] + 0.5))
    m = len(cum_lam)
    total = cum_lam[m - 1]
    lin = np.empty(t, dtype=np.int64)
    dn = np.empty(t)
    for i in range(t):
        cell = min(np.searchsorted(cum_lam, u_cell[i] * total, side="right"), m - 1)
        cy = cell // gx
        cx = cell - cy * gx
        c0 = math.floor(col_edges[cx] + 0.5)
        c1 = math.floor(col_edges[cx + 1] + 0.5)
        r0 = math.floor(row_edges[cy] + 0.5)
        r1 = math.floor(row_edges[cy + 1] + 0.5)
        col = int(c0 + math.floor(u_col[i] * (c1 - c0)))
        row = int(r0 + math.floor(u_row[i] * (r1 - r0)))
        lin[i] = row * n_cols + col
        zz = max(normal_isf(max(u_tail[i] * p[cell], 1e-300)), z0[cell])  # Gaussian tail above z0
        e = min(mu_e[cell] + sd_e[cell] * zz, full_well_e)
        v = np.rint(e / gain_e_per_dn + bias_dn)
        dn[i] = min(max(v, math.floor(thr_dn[cell]) + 1.0), adc_max_dn)
    return lin, dn


@njit(cache=True, no_cfunc_wrapper=True)
def lookup_pixels(lin, buf, uniq):
    """Compact id of each pixel of ``lin`` (E,) in the sparse set ``uniq`` (U,) indexed by ``buf``, −1 if absent.

    ``buf`` must hold ``buf[uniq[i]] == i`` (as left by :func:`sparse_pixel_set`); other entries may be anything.
    """
    n_u = len(uniq)
    out = np.empty(len(lin), dtype=np.int64)
    for i in range(len(lin)):
        c = buf[lin[i]]
        out[i] = c if (c >= 0 and c < n_u and uniq[c] == lin[i]) else -1
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def spots_from_paths(paths, total, sigma_px):
    """Cut spot paths into segments no longer than 4σ and each segment into sub-spots at most σ/2 apart.

    Each path is cut into its own number of segments (the fewest no longer than 4σ of its own σ: a long debris
    streak in the frame does not cut the stars' short paths into as many), at instants evenly spaced in time; every
    segment into the same number K of sub-spots (enough for the longest segment) at the midpoints of equal time
    slices, sharing the path's signal equally.

    Parameters
    ----------
    paths : ndarray, shape (E, S, 2)
        Positions (column, row) at S ≥ 2 instants evenly spaced over each exposure, px.
    total : ndarray, shape (E,)
        Signal of each path (any unit).
    sigma_px : ndarray, shape (E,)
        Gaussian σ of each path's spot, px.

    Returns
    -------
    sub_xy : ndarray, shape (P, K, 2)
        Sub-spot centres, px (P = the paths' segments in all, path-major).
    sub_w : ndarray, shape (P, K)
    sigma : ndarray, shape (P,)
    path : ndarray of int64, shape (P,)
        Path of each segment.
    along : ndarray, shape (P, 2)
        Unit vector along each segment ((1, 0) for a still spot).
    length : ndarray, shape (P,)
        Segment lengths, px.
    """
    e_n, s, _ = paths.shape
    n_seg = np.empty(e_n, dtype=np.int64)
    first = np.empty(e_n + 1, dtype=np.int64)  # each path's first segment
    first[0] = 0
    for e in range(e_n):
        ln = 0.0
        for i in range(s - 1):
            ln += math.hypot(paths[e, i + 1, 0] - paths[e, i, 0], paths[e, i + 1, 1] - paths[e, i, 1])
        n_seg[e] = max(1, int(math.ceil(ln / (4.0 * sigma_px[e]))))
        first[e + 1] = first[e] + n_seg[e]
    n_p = first[e_n]
    knots = np.empty((n_p + e_n, 2))  # path e's knots at rows first[e] + e ... first[e + 1] + e
    for e in range(e_n):
        ns = n_seg[e]
        k0 = first[e] + e
        for j in range(ns + 1):
            f = j * (s - 1.0) / ns
            i0 = min(int(math.floor(f)), s - 2)
            w = f - i0
            for c in range(2):
                knots[k0 + j, c] = paths[e, i0, c] * (1 - w) + paths[e, i0 + 1, c] * w
    length = np.empty(n_p)
    along = np.empty((n_p, 2))
    sigma = np.empty(n_p)
    path = np.empty(n_p, dtype=np.int64)
    k_ratio = 0.0
    for e in range(e_n):
        for j in range(n_seg[e]):
            p = first[e] + j
            k = p + e
            dx = knots[k + 1, 0] - knots[k, 0]
            dy = knots[k + 1, 1] - knots[k, 1]
            ln = math.sqrt(dx * dx + dy * dy)
            length[p] = ln
            if ln > 1e-12:
                along[p, 0] = dx / ln
                along[p, 1] = dy / ln
            else:
                along[p, 0] = 1.0
                along[p, 1] = 0.0
            sigma[p] = sigma_px[e]
            path[p] = e
            k_ratio = max(k_ratio, ln / (0.5 * sigma_px[e]))
    n_k = max(1, int(math.ceil(k_ratio)))
    sub_xy = np.empty((n_p, n_k, 2))
    sub_w = np.empty((n_p, n_k))
    for e in range(e_n):
        w = total[e] / (n_seg[e] * n_k)
        for j in range(n_seg[e]):
            p = first[e] + j
            k0 = p + e
            for k in range(n_k):
                f = (k + 0.5) / n_k
                sub_xy[p, k, 0] = knots[k0, 0] + (knots[k0 + 1, 0] - knots[k0, 0]) * f
                sub_xy[p, k, 1] = knots[k0, 1] + (knots[k0 + 1, 1] - knots[k0, 1]) * f
                sub_w[p, k] = w
    return sub_xy, sub_w, sigma, path, along, length


@njit(cache=True, no_cfunc_wrapper=True)
def frame_star_spots(xy_path, pe_star, gain, x_lo, x_hi, y_lo, y_hi):
    """The stars' part of a frame's source table and the star paths that can light the detector.

    Sources are exposure-major: row ``i M + m`` is scene star m in exposure i. A path is kept when its
    bounding box over the samples reaches the window ``[x_lo, x_hi] × [y_lo, y_hi]`` (the detector widened by
    a margin, px) and its star gives light.

    Parameters
    ----------
    xy_path : ndarray, shape (N, S, M, 2)
        Star positions (column, row) at S >= 3 instants over each exposure, px.
    pe_star : ndarray, shape (M,)
        Expected photoelectrons of each star in one exposure.
    gain : float
        Charge per photoelectron (the intensifier gain; 1 without one).
    x_lo, x_hi, y_lo, y_hi : float
        The window, px.

    Returns
    -------
    star, exposure : ndarray of int64, shape (N M,)
        Scene star and exposure of each source.
    xy : ndarray, shape (N M, 2)
        Time-averaged position over the exposure (trapezoid rule over the samples, summed in sample order as
        ``Scene.xy_mean``), px.
    expected_e : ndarray, shape (N M,)
        ``pe_star · gain``, e⁻.
    paths : ndarray, shape (E, S, 2)
        The kept paths, in source order, px.
    total : ndarray, shape (E,)
        Their photoelectrons.
    source : ndarray of int64, shape (E,)
        Their source rows.
    """
    n, s, m, _ = xy_path.shape
    q = n * m
    star = np.empty(q, dtype=np.int64)
    expo = np.empty(q, dtype=np.int64)
    xy = np.empty((q, 2))
    exp_e = np.empty(q)
    keep = np.empty(q, dtype=np.bool_)
    n_keep = 0
    for i in range(n):
        for j in range(m):
            r = i * m + j
            star[r] = j
            expo[r] = i
            exp_e[r] = pe_star[j] * gain
            for c in range(2):
                acc = xy_path[i, 1, j, c]
                for k in range(2, s - 1):
                    acc += xy_path[i, k, j, c]
                xy[r, c] = (acc + 0.5 * (xy_path[i, 0, j, c] + xy_path[i, s - 1, j, c])) / (s - 1.0)
            lo_x = hi_x = xy_path[i, 0, j, 0]
            lo_y = hi_y = xy_path[i, 0, j, 1]
            for k in range(1, s):
                lo_x = min(lo_x, xy_path[i, k, j, 0])
                hi_x = max(hi_x, xy_path[i, k, j, 0])
                lo_y = min(lo_y, xy_path[i, k, j, 1])
                hi_y = max(hi_y, xy_path[i, k, j, 1])
            ok = hi_x >= x_lo and lo_x <= x_hi and hi_y >= y_lo and lo_y <= y_hi and pe_star[j] > 0
            keep[r] = ok
            if ok:
                n_keep += 1
    paths = np.empty((n_keep, s, 2))
    total = np.empty(n_keep)
    source = np.empty(n_keep, dtype=np.int64)
    e = 0
    for r in range(q):
        if keep[r]:
            i = r // m
            j = r - i * m
            for k in range(s):
                paths[e, k, 0] = xy_path[i, k, j, 0]
                paths[e, k, 1] = xy_path[i, k, j, 1]
            total[e] = pe_star[j]
            source[e] = r
            e += 1
    return star, expo, xy, exp_e, paths, total, source


@njit(cache=True, no_cfunc_wrapper=True)
def sparse_source_table(kind, star, exposure, xy, expected_e, hot_idx, hot_e, f_lin, f_dn, n_cols, kind_hot,
                        kind_noise, bias_dn, gain_e_per_dn, opt0, opt_dx, opt_dy, cx, cy, gain, dark_e):
    """A sparse frame's source table: the spots' sources, then the hot pixels, then the background crossings.

    Parameters
    ----------
    kind, star, exposure : ndarray of int64, shape (Q0,)
        The spots' sources (stars, debris, cosmic rays): kind code, scene star index, exposure index.
    xy : ndarray, shape (Q0, 2)
        Their time-averaged positions, px.
    expected_e : ndarray, shape (Q0,)
        Their expected charge, e⁻.
    hot_idx : ndarray of int64, shape (H,)
        Linear indices ``row * n_cols + col`` of the hot pixels.
    hot_e : ndarray, shape (H,)
        Their extra dark charge, e⁻.
    f_lin : ndarray of int64, shape (F,)
        Linear indices of the background's threshold crossings.
    f_dn : ndarray, shape (F,)
        Their values, DN.
    n_cols : int
        Detector width, px.
    kind_hot, kind_noise : int
        Kind codes of a hot pixel and of a crossing.
    bias_dn, gain_e_per_dn : float
        DN offset and e⁻ per DN.
    opt0, opt_dx, opt_dy, cx, cy, gain, dark_e : float
        The background field (:class:`startracker.imaging.BackgroundField`): optical photoelectrons at ``(cx, cy)``
        and their gradient per px, intensifier gain, dark charge e⁻.

    Returns
    -------
    kind, star, exposure : ndarray of int64, shape (Q0 + H + F,)
        −1 star and exposure for the hot pixels and crossings.
    xy : ndarray, shape (Q0 + H + F, 2)
        Pixel centres (column, row) of the hot pixels and crossings, px.
    expected_e : ndarray, shape (Q0 + H + F,)
        Crossings: their charge above the expected background, ``(DN − bias) g − mean_e``, e⁻.
    """
    q0 = len(kind)
    n_hot = len(hot_idx)
    n_f = len(f_lin)
    q = q0 + n_hot + n_f
    t_kind = np.empty(q, dtype=np.int64)
    t_star = np.empty(q, dtype=np.int64)
    t_exp = np.empty(q, dtype=np.int64)
    t_xy = np.empty((q, 2))
    t_e = np.empty(q)
    for i in range(q0):
        t_kind[i] = kind[i]
        t_star[i] = star[i]
        t_exp[i] = exposure[i]
        t_xy[i, 0] = xy[i, 0]
        t_xy[i, 1] = xy[i, 1]
        t_e[i] = expected_e[i]
    for h in range(n_hot):
        i = q0 + h
        t_kind[i] = kind_hot
        t_star[i] = -1
        t_exp[i] = -1
        t_xy[i, 0] = float(hot_idx[h] % n_cols)
        t_xy[i, 1] = float(hot_idx[h] // n_cols)
        t_e[i] = hot_e[h]
    for f in range(n_f):
        i = q0 + n_hot + f
        c = f_lin[f] % n_cols
        r = f_lin[f] // n_cols
        t_kind[i] = kind_noise
        t_star[i] = -1
        t_exp[i] = -1
        t_xy[i, 0] = float(c)
        t_xy[i, 1] = float(r)
        # the expected background, BackgroundField.mean_e (its flat case is the same value: the gradient terms are 0)
        t_e[i] = (f_dn[f] - bias_dn) * gain_e_per_dn - (gain * _optical_pe(opt0, opt_dx, opt_dy, cx, cy, float(c), float(r))
                                                        + dark_e)
    return t_kind, t_star, t_exp, t_xy, t_e
