"""Centroid-extraction kernels: connected components of sparse pixels, centre of mass, Gaussian interpolation.

Compiled with numba, no checks; the checked API is :mod:`startracker.centroid` (``extract_centroids``,
``detections_from_sparse``). Conventions: pixel ``(0, 0)`` is the centre of the top-left pixel, linear indices are
``row * n_cols + col``, spots are 8-connected, ``signal`` is DN above the background (paper 002 §3).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.imaging import split_pixel_index
from startracker.kernels.kvector import stable_argsort_into

__all__ = [
    "sparse_components",
    "measure_components",
    "gaussian_axis_offset",
    "sigma_from_three",
    "gaussian_refine",
    "rank_components",
    "detect_sparse",
    "truth_labels",
]

_INV_SQRT2 = 1.0 / math.sqrt(2.0)


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, no_cfunc_wrapper=True)
def sparse_components(above_lin, n_rows, n_cols):
    """8-connected components of a set of pixels on a detector.

    The pixels are sorted by linear index (LSD radix sort, 11-bit digits) and cut into horizontal runs; runs in
    consecutive rows that touch (diagonals included) are joined by a monotone scan of the sorted runs. No lookup in
    a detector-sized map, whose rows lie far apart in memory.

    Parameters
    ----------
    above_lin : ndarray of int64, shape (A,)
        Linear indices of the pixels (distinct, in [0, n_rows · n_cols)).
    n_rows, n_cols : int
        Detector size, px.

    Returns
    -------
    labels : ndarray of int64, shape (A,)
        Component of each pixel, numbered in order of first appearance in ``above_lin``.
    n_comp : int
    """
    a = len(above_lin)
    key = above_lin.copy()
    idx = np.arange(a)  # sorted position -> index in above_lin
    key2 = np.empty(a, dtype=np.int64)
    idx2 = np.empty(a, dtype=np.int64)
    count = np.empty(2048, dtype=np.int64)
    top = n_rows * n_cols - 1
    shift = 0
    while (top >> shift) > 0:
        count[:] = 0
        for i in range(a):
            count[(key[i] >> shift) & 2047] += 1
        acc = 0
        for d in range(2048):
            m = count[d]
            count[d] = acc
            acc += m
        for i in range(a):  # stable, so the earlier digits' order holds among equal digits
            d = (key[i] >> shift) & 2047
            t = count[d]
            key2[t] = key[i]
            idx2[t] = idx[i]
            count[d] = t + 1
        key, key2 = key2, key
        idx, idx2 = idx2, idx
        shift += 11
    # horizontal runs: first and last pixel, end of their row (linear, exclusive); the spare sort arrays hold them
    run_lo = key2
    run_row_end = idx2
    run_hi = np.empty(a, dtype=np.int64)
    run_of = np.empty(a, dtype=np.int64)  # run of each pixel, indexed as above_lin
    inv_cols = 1.0 / n_cols
    n_run = -1
    row_end = 0
    prev = -2
    for i in range(a):
        px = key[i]
        if px >= row_end:
            r, _ = split_pixel_index(px, n_cols, inv_cols)
            row_end = (r + 1) * n_cols
            prev = -2
        if px != prev + 1:
            n_run += 1
            run_lo[n_run] = px
            run_row_end[n_run] = row_end
        run_hi[n_run] = px
        run_of[idx[i]] = n_run
        prev = px
    n_run += 1
    # union-find over runs: a run joins the runs of the next row overlapping its columns widened by one
    parent = np.arange(n_run)
    j = 0
    for r in range(n_run):
        lo = max(run_lo[r] + n_cols - 1, run_row_end[r])
        hi = min(run_hi[r] + n_cols + 1, run_row_end[r] + n_cols - 1)
        while j < n_run and run_hi[j] < lo:
            j += 1
        k = j
        while k < n_run and run_lo[k] <= hi:
            rr = _find(parent, r)
            rk = _find(parent, k)
            if rr < rk:
                parent[rk] = rr
            elif rk < rr:
                parent[rr] = rk
            k += 1
    for r in range(n_run):
        parent[r] = parent[parent[r]]  # a root is the smallest run of its tree, so this pass in order flattens all
    labels = np.empty(a, dtype=np.int64)
    comp_of_root = np.full(n_run, -1, dtype=np.int64)
    n_comp = 0
    for i in range(a):
        root = parent[run_of[i]]
        if comp_of_root[root] < 0:
            comp_of_root[root] = n_comp
            n_comp += 1
        labels[i] = comp_of_root[root]
    return labels, n_comp


@njit(cache=True, no_cfunc_wrapper=True)
def measure_components(labels, n_comp, rows, cols, signal, saturated_px, noise_px):
    """Centre of mass and photometry of every component (paper 002 §3.1, eqs. 1–3).

    Parameters
    ----------
    labels : ndarray of int64, shape (A,)
        Component of each pixel, in [0, n_comp).
    rows, cols : ndarray, shape (A,)
        Pixel coordinates, px.
    signal : ndarray, shape (A,)
        DN above the background.
    saturated_px : ndarray of bool, shape (A,)
    noise_px : ndarray, shape (A,)
        Background σ at each pixel, DN.

    Returns
    -------
    x, y : ndarray, shape (n_comp,)
        Signal-weighted centre of mass, px (0 where the intensity is not positive).
    intensity : ndarray, shape (n_comp,)
        Σ signal, DN.
    area : ndarray of int64, shape (n_comp,)
    saturated : ndarray of bool, shape (n_comp,)
    noise : ndarray, shape (n_comp,)
        Mean background σ over the component, DN.
    peak : ndarray, shape (n_comp,)
        Largest signal, DN.
    peak_pixel : ndarray of int64, shape (n_comp,)
        Index (into A) of the brightest pixel (the last one on ties).
    """
    area = np.zeros(n_comp, dtype=np.int64)
    inten = np.zeros(n_comp)
    sx = np.zeros(n_comp)
    sy = np.zeros(n_comp)
    sat = np.zeros(n_comp, dtype=np.bool_)
    noise = np.zeros(n_comp)
    peak = np.full(n_comp, -np.inf)
    peak_pixel = np.full(n_comp, -1, dtype=np.int64)
    n = len(labels)
    i = 0
    while i < n:
        # a run of pixels of one component keeps its sums in registers (added in the same order): summing into
        # the arrays pixel by pixel waits on the previous pixel's store each time
        k = labels[i]
        ar = area[k]
        it = inten[k]
        x = sx[k]
        y = sy[k]
        st = sat[k]
        ns = noise[k]
        pk = peak[k]
        pp = peak_pixel[k]
        while i < n and labels[i] == k:
            s = signal[i]
            ar += 1
            it += s
            x += s * cols[i]
            y += s * rows[i]
            st |= saturated_px[i]
            ns += noise_px[i]
            take = s >= pk
            pk = s if take else pk
            pp = i if take else pp
            i += 1
        area[k] = ar
        inten[k] = it
        sx[k] = x
        sy[k] = y
        sat[k] = st
        noise[k] = ns
        peak[k] = pk
        peak_pixel[k] = pp
    for k in range(n_comp):
        d = inten[k] if inten[k] > 0 else 1.0
        sx[k] /= d
        sy[k] /= d
        noise[k] /= max(area[k], 1)
    return sx, sy, inten, area, sat, noise, peak, peak_pixel


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _pixel_fraction(u, a, b, inv_sigma):
    """Fraction of a unit Gaussian centred at u falling in [a, b] (paper 002 eq. 5)."""
    return 0.5 * (math.erfc((a - u) * inv_sigma * _INV_SQRT2) - math.erfc((b - u) * inv_sigma * _INV_SQRT2))


@njit(cache=True, no_cfunc_wrapper=True)
def gaussian_axis_offset(i_minus, i_0, i_plus, sigma_px):
    """Sub-pixel offset along one axis from the brightest pixel and its two neighbours (paper 002 §3.2).

    The ratio of the brighter neighbour to the centre equals the ratio of the Gaussian integrated over the two
    pixels (eq. 5); it is inverted exactly by 26 bisection steps (monotone in the offset).

    Parameters
    ----------
    i_minus, i_0, i_plus : float
        Background-subtracted DN of the pixels at −1, 0, +1 (NaN: unknown, taken as 0).
    sigma_px : float
        Gaussian σ, px.

    Returns
    -------
    float
        Offset in [−0.5, 0.5] px, NaN when ``i_0 <= 0``.
    """
    if not i_0 > 0:
        return np.nan
    im = i_minus if math.isfinite(i_minus) else 0.0
    ip = i_plus if math.isfinite(i_plus) else 0.0
    side = 1.0 if ip >= im else -1.0
    rho = min(max(max(ip, im) / i_0, 0.0), 1.0)
    inv_s = 1.0 / sigma_px
    lo = 0.0
    hi = 0.5
    for _ in range(26):
        mid = 0.5 * (lo + hi)
        f = _pixel_fraction(mid, 0.5, 1.5, inv_s) - rho * _pixel_fraction(mid, -0.5, 0.5, inv_s)
        if f > 0:
            hi = mid
        else:
            lo = mid
    return side * 0.5 * (lo + hi)


@njit(cache=True, no_cfunc_wrapper=True)
def sigma_from_three(i_minus, i_0, i_plus, default_px):
    """PSF σ from the log-parabola through three pixels, minus the pixel integration (1/12 px²), px.

    ``default_px`` where the three values do not give a σ² > 0.05 px² (non-positive or unknown pixels).
    """
    if not (i_minus > 0 and i_0 > 0 and i_plus > 0):
        return default_px
    curv = -(math.log(i_minus) - 2.0 * math.log(i_0) + math.log(i_plus))
    if curv == 0.0:
        return default_px
    s2 = 1.0 / curv - 1.0 / 12.0
    if not (math.isfinite(s2) and s2 > 0.05):
        return default_px
    return math.sqrt(min(s2, 25.0))


@njit(cache=True, no_cfunc_wrapper=True)
def gaussian_refine(x, y, peak_row, peak_col, i_0, i_left, i_right, i_up, i_down, saturated, psf_sigma_px):
    """Replace the centre of mass by the Gaussian interpolation where it can be formed (in place).

    Parameters
    ----------
    x, y : ndarray, shape (C,)
        Centres of mass, px (modified).
    peak_row, peak_col : ndarray, shape (C,)
        Brightest pixel of each component.
    i_0, i_left, i_right, i_up, i_down : ndarray, shape (C,)
        Background-subtracted DN at the brightest pixel and at its neighbours (col −1, col +1, row −1, row +1;
        NaN where unknown).
    saturated : ndarray of bool, shape (C,)
        Saturated components keep the centre of mass.
    psf_sigma_px : float
        Gaussian σ, px; NaN: estimated per spot and axis by :func:`sigma_from_three` (default 1 px).
    """
    for k in range(len(x)):
        if saturated[k]:
            continue
        if math.isnan(psf_sigma_px):
            sxg = sigma_from_three(i_left[k], i_0[k], i_right[k], 1.0)
            syg = sigma_from_three(i_up[k], i_0[k], i_down[k], 1.0)
        else:
            sxg = psf_sigma_px
            syg = psf_sigma_px
        dx = gaussian_axis_offset(i_left[k], i_0[k], i_right[k], sxg)
        dy = gaussian_axis_offset(i_up[k], i_0[k], i_down[k], syg)
        if math.isfinite(dx):
            x[k] = peak_col[k] + dx
        if math.isfinite(dy):
            y[k] = peak_row[k] + dy


@njit(cache=True, no_cfunc_wrapper=True)
def rank_components(intensity, area, noise, min_area_px):
    """Components kept (area ≥ min_area_px, positive intensity), brightest first, and their rough SNR.

    Returns
    -------
    keep : ndarray of int64, shape (K,)
        Component ids, by decreasing intensity (ties in id order).
    snr : ndarray, shape (K,)
        ``intensity / (σ √area)``.
    """
    n = 0
    sel = np.empty(len(intensity), dtype=np.int64)
    for k in range(len(intensity)):
        if area[k] >= min_area_px and intensity[k] > 0:
            sel[n] = k
            n += 1
    # stable order of the negated intensities: np.argsort(-intensity[sel], kind="mergesort"), by the project's
    # stable sort (the same permutation; numba's argsort compiles for seconds)
    neg = np.empty(n)
    for i in range(n):
        neg[i] = -intensity[sel[i]]
    order = np.empty(n, dtype=np.int64)
    stable_argsort_into(neg, order)
    keep = np.empty(n, dtype=np.int64)
    snr = np.empty(n)
    for i in range(n):
        keep[i] = sel[order[i]]
        k = keep[i]
        snr[i] = intensity[k] / (max(noise[k], 1e-9) * math.sqrt(area[k]))
    return keep, snr


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _sparse_value(r, c, n_rows, n_cols, buf, uniq, dn, background_dn):
    if r < 0 or r >= n_rows or c < 0 or c >= n_cols:
        return np.nan
    q = r * n_cols + c
    k = buf[q]
    if k < 0 or k >= len(uniq) or uniq[k] != q:
        return np.nan
    return dn[k] - background_dn[k]


@njit(cache=True, no_cfunc_wrapper=True)
def detect_sparse(lin, dn, background_dn, threshold_dn, saturation_dn, k_sigma, n_rows, n_cols, buf, gaussian,
                  psf_sigma_px, min_area_px, entry_pixel, entry_source, entry_e):
    """Components, centroids and truth owners of a sparse frame.

    Parameters
    ----------
    lin : ndarray of int64, shape (U,)
        The frame's pixels (``buf[lin[i]] == i``).
    dn, background_dn, threshold_dn : ndarray, shape (U,)
        Pixel values (float32 as rendered, or float64), expected background, detection threshold, DN (a pixel is
        detected when ``dn > threshold``).
    saturation_dn, k_sigma : float
    n_rows, n_cols : int
    buf : ndarray of int32, shape (n_rows * n_cols,)
    gaussian : bool
        Gaussian interpolation (paper 002 §3.2) instead of the centre of mass.
    psf_sigma_px : float
        σ of the interpolation, px; NaN: estimated per spot.
    min_area_px : int
    entry_pixel, entry_source : ndarray of int64, shape (E,); entry_e : ndarray, shape (E,)
        Rendered entries (compact pixel, source, expected charge e⁻); the owner of a component is the source with
        the largest expected charge in any one of its pixels (the last such entry on ties), −1 if none.

    Returns
    -------
    xy : ndarray, shape (K, 2)
    intensity, peak, snr : ndarray, shape (K,)
    area : ndarray of int64, shape (K,)
    saturated : ndarray of bool, shape (K,)
    owner : ndarray of int64, shape (K,)
        Brightest first.
    """
    n_u = len(lin)
    pos = np.empty(n_u, dtype=np.int64)
    at = np.empty(n_u, dtype=np.int64)  # compact id of each detected pixel
    a = 0
    for i in range(n_u):  # branch-free: whether a pixel is detected is unpredictable
        hit = dn[i] > threshold_dn[i]
        pos[i] = a if hit else -1
        at[a] = i
        a += hit
    above = np.empty(a, dtype=np.int64)
    rows = np.empty(a)
    cols = np.empty(a)
    signal = np.empty(a)
    sat_px = np.empty(a, dtype=np.bool_)
    noise_px = np.empty(a)
    inv_cols = 1.0 / n_cols
    for j in range(a):
        i = at[j]
        above[j] = lin[i]
        r, c = split_pixel_index(lin[i], n_cols, inv_cols)
        rows[j] = r
        cols[j] = c
        signal[j] = dn[i] - background_dn[i]
        sat_px[j] = dn[i] >= saturation_dn
        noise_px[j] = (threshold_dn[i] - background_dn[i]) / k_sigma
    labels, n_comp = sparse_components(above, n_rows, n_cols)
    x, y, inten, area, sat, noise, peak, peak_pixel = measure_components(labels, n_comp, rows, cols, signal, sat_px,
                                                                         noise_px)
    if gaussian and n_comp > 0:
        pr = np.empty(n_comp)
        pc = np.empty(n_comp)
        i0 = np.empty(n_comp)
        il = np.empty(n_comp)
        ir = np.empty(n_comp)
        iu = np.empty(n_comp)
        idn = np.empty(n_comp)
        for k in range(n_comp):
            j = peak_pixel[k]
            r = int(rows[j])
            c = int(cols[j])
            pr[k] = r
            pc[k] = c
            i0[k] = signal[j]
            il[k] = _sparse_value(r, c - 1, n_rows, n_cols, buf, lin, dn, background_dn)
            ir[k] = _sparse_value(r, c + 1, n_rows, n_cols, buf, lin, dn, background_dn)
            iu[k] = _sparse_value(r - 1, c, n_rows, n_cols, buf, lin, dn, background_dn)
            idn[k] = _sparse_value(r + 1, c, n_rows, n_cols, buf, lin, dn, background_dn)
        gaussian_refine(x, y, pr, pc, i0, il, ir, iu, idn, sat, psf_sigma_px)
    best = np.full(n_comp, -np.inf)
    owner = np.full(n_comp, -1, dtype=np.int64)
    for e in range(len(entry_pixel)):
        j = pos[entry_pixel[e]]
        if j < 0:
            continue
        k = labels[j]
        if entry_e[e] >= best[k]:
            best[k] = entry_e[e]
            owner[k] = entry_source[e]
    keep, snr = rank_components(inten, area, noise, min_area_px)
    n = len(keep)
    xy = np.empty((n, 2))
    for i in range(n):
        xy[i, 0] = x[keep[i]]
        xy[i, 1] = y[keep[i]]
    return xy, inten[keep], area[keep], sat[keep], peak[keep], snr, owner[keep]


@njit(cache=True, no_cfunc_wrapper=True)
def truth_labels(owner, kind, star, exposure, xy, kind_none):
    """The source-table rows of detections' owners: their truth labels.

    Parameters
    ----------
    owner : ndarray of int64, shape (K,)
        Source id of each detection (:func:`detect_sparse`), −1 for none.
    kind, star, exposure : ndarray of int64, shape (Q,)
        The source table's kind code, scene star index and exposure index.
    xy : ndarray, shape (Q, 2)
        The sources' time-averaged positions, px.
    kind_none : int
        Kind code of a detection without an owner (``startracker.imaging.KIND_NOISE``).

    Returns
    -------
    t_kind, t_star, t_exposure : ndarray of int64, shape (K,)
        The owner's columns; ``kind_none``, −1, −1 without an owner.
    t_xy : ndarray, shape (K, 2)
        The owner's position, px; NaN without an owner.
    """
    n = len(owner)
    t_kind = np.empty(n, dtype=np.int64)
    t_star = np.empty(n, dtype=np.int64)
    t_exp = np.empty(n, dtype=np.int64)
    t_xy = np.empty((n, 2))
    for i in range(n):
        o = owner[i]
        if o >= 0:
            t_kind[i] = kind[o]
            t_star[i] = star[o]
            t_exp[i] = exposure[o]
            t_xy[i, 0] = xy[o, 0]
            t_xy[i, 1] = xy[o, 1]
        else:
            t_kind[i] = kind_none
            t_star[i] = -1
            t_exp[i] = -1
            t_xy[i, 0] = np.nan
            t_xy[i, 1] = np.nan
    return t_kind, t_star, t_exp, t_xy
