"""3CMOS kernels: pairing the centroids of two colour channels, the centroid-level fusion of three, and a frame's
three channels' centroid-fidelity detections fused in one call.

The checked API and the fusion it serves are in :mod:`startracker.color.fusion`. Coordinates are pixels of one
frame (the green channel's, after registration).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.centroid import centroid_detections
from startracker.kernels.kvector import stable_argsort

__all__ = ["mutual_nearest", "register_to_green", "fuse_channels", "fused_centroid_detections"]


@njit(cache=True, no_cfunc_wrapper=True)
def mutual_nearest(a, b, radius_px):
    """Index pairs (i into ``a``, j into ``b``) that are each other's nearest neighbour closer than ``radius_px``.

    Brute force over all pairs (a frame's channels hold tens of centroids); a tie goes to the lower index.

    Parameters
    ----------
    a : ndarray, shape (K, 2)
        Points, px.
    b : ndarray, shape (L, 2)
        Points, px.
    radius_px : float
        Pairs at this distance or farther are not neighbours, px.

    Returns
    -------
    i : ndarray of int64, shape (P,)
        Increasing indices into ``a``.
    j : ndarray of int64, shape (P,)
        Their partners in ``b``.
    """
    k = a.shape[0]
    m = b.shape[0]
    r2 = radius_px * radius_px
    best_a = np.full(k, -1, dtype=np.int64)
    best_a_d = np.full(k, np.inf)
    best_b = np.full(m, -1, dtype=np.int64)
    best_b_d = np.full(m, np.inf)
    for i in range(k):
        for j in range(m):
            dx = a[i, 0] - b[j, 0]
            dy = a[i, 1] - b[j, 1]
            d2 = dx * dx + dy * dy
            if d2 < r2:
                if d2 < best_a_d[i]:
                    best_a_d[i] = d2
                    best_a[i] = j
                if d2 < best_b_d[j]:
                    best_b_d[j] = d2
                    best_b[j] = i
    n = 0
    for i in range(k):
        j = best_a[i]
        if j >= 0 and best_b[j] == i:
            n += 1
    out_i = np.empty(n, dtype=np.int64)
    out_j = np.empty(n, dtype=np.int64)
    n = 0
    for i in range(k):
        j = best_a[i]
        if j >= 0 and best_b[j] == i:
            out_i[n] = i
            out_j[n] = j
            n += 1
    return out_i, out_j


@njit(cache=True, no_cfunc_wrapper=True)
def register_to_green(xy, affine, x0, q_per_px2):
    """A channel's pixel coordinates in the green frame (paper 004 eqs. 17-18, :meth:`ChannelRegistration.apply`).

    ``x' = x0 + d (1 + q |d|²)`` with ``d = x - x0`` (skipped for ``q = 0``), then ``x_g = A x' + b``.

    Parameters
    ----------
    xy : ndarray, shape (K, 2)
        Channel pixel coordinates, px.
    affine : ndarray, shape (2, 3)
        ``[A | b]``.
    x0 : ndarray, shape (2,)
        Centre of the radial term, px.
    q_per_px2 : float
        Radial term, 1/px².

    Returns
    -------
    ndarray, shape (K, 2)
    """
    n = xy.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        x, y = xy[i, 0], xy[i, 1]
        if q_per_px2 != 0.0:
            dx, dy = x - x0[0], y - x0[1]
            f = 1.0 + q_per_px2 * (dx * dx + dy * dy)
            x, y = x0[0] + dx * f, x0[1] + dy * f
        out[i, 0] = affine[0, 0] * x + affine[0, 1] * y + affine[0, 2]
        out[i, 1] = affine[1, 0] * x + affine[1, 1] * y + affine[1, 2]
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def _free(n, paired):
    """Increasing indices in ``range(n)`` that ``paired`` (−1: none) does not hold."""
    used = np.zeros(n, dtype=np.bool_)
    for p in paired:
        if p >= 0:
            used[p] = True
    out = np.empty(n - used.sum(), dtype=np.int64)
    m = 0
    for i in range(n):
        if not used[i]:
            out[m] = i
            m += 1
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def fuse_channels(xy_r, xy_g, xy_b, inten_r, inten_g, inten_b, area_r, area_g, area_b, noise_dn, affine_r, x0_r, q_r,
                  affine_b, x0_b, q_b, radius_px, min_channels, gain_e_per_dn):
    """Centroid-level fusion of the red, green and blue detections of a frame (:func:`startracker.color.fusion.
    fuse_channel_centroids`): red and blue registered to green (:func:`register_to_green`); green's detections are the
    anchors, paired with red and with blue by :func:`mutual_nearest`; the red and blue left over paired with each
    other; with ``min_channels`` 1 the lone red and blue kept too; spots seen by fewer than ``min_channels`` channels
    dropped. The position is the inverse-variance mean, each channel's variance ``(I/g + A σ²) / I²`` (``I`` the
    intensity floored at 1e-9 DN, ``A`` the area, ``σ`` the channel's noise); brightest (summed intensity) first.

    Parameters
    ----------
    xy_r, xy_g, xy_b : ndarray, shape (K_c, 2)
        Each channel's centroids on its own detector, px.
    inten_r, inten_g, inten_b : ndarray, shape (K_c,)
        Intensities, DN.
    area_r, area_g, area_b : ndarray, shape (K_c,)
        Areas, px.
    noise_dn : ndarray, shape (3,)
        Background noise of each channel, DN (a non-finite value: unknown, taken as 0).
    affine_r, affine_b : ndarray, shape (2, 3)
        Registrations ``[A | b]`` of red and blue onto green.
    x0_r, x0_b : ndarray, shape (2,)
        Centres of their radial terms, px.
    q_r, q_b : float
        Their radial terms, 1/px².
    radius_px : float
        Pairing radius, px.
    min_channels : int
        1, 2 or 3.
    gain_e_per_dn : float
        Conversion gain, e⁻/DN.

    Returns
    -------
    xy : ndarray, shape (F, 2)
        Fused centroids, green frame, px.
    intensity : ndarray, shape (F, 3)
        Per channel (red, green, blue), DN; 0 where absent.
    channel_index : ndarray of int64, shape (F, 3)
        Row of the detection in each channel's input, −1 where absent.
    n_channels : ndarray of int64, shape (F,)
    color_ratio : ndarray, shape (F,)
        ``ln(I_red / I_blue)``, NaN without both.
    has_color : ndarray of bool, shape (F,)
    """
    reg_r = register_to_green(xy_r, affine_r, x0_r, q_r) if xy_r.shape[0] else xy_r
    reg_b = register_to_green(xy_b, affine_b, x0_b, q_b) if xy_b.shape[0] else xy_b
    n_r, n_g, n_b = xy_r.shape[0], xy_g.shape[0], xy_b.shape[0]
    pair_r = np.full(n_g, -1, dtype=np.int64)
    pair_b = np.full(n_g, -1, dtype=np.int64)
    if n_g and n_r:
        gi, ri = mutual_nearest(xy_g, reg_r, radius_px)
        for t in range(gi.shape[0]):
            pair_r[gi[t]] = ri[t]
    if n_g and n_b:
        gi, bi = mutual_nearest(xy_g, reg_b, radius_px)
        for t in range(gi.shape[0]):
            pair_b[gi[t]] = bi[t]
    free_r = _free(n_r, pair_r)
    free_b = _free(n_b, pair_b)
    if free_r.shape[0] and free_b.shape[0]:
        fr = np.empty((free_r.shape[0], 2))
        fb = np.empty((free_b.shape[0], 2))
        # element copies: a row assignment compiles numba's shape check and its error message
        for t in range(free_r.shape[0]):
            fr[t, 0] = reg_r[free_r[t], 0]
            fr[t, 1] = reg_r[free_r[t], 1]
        for t in range(free_b.shape[0]):
            fb[t, 0] = reg_b[free_b[t], 0]
            fb[t, 1] = reg_b[free_b[t], 1]
        ri, bi = mutual_nearest(fr, fb, radius_px)
    else:
        ri = np.zeros(0, dtype=np.int64)
        bi = np.zeros(0, dtype=np.int64)
    n_rb = ri.shape[0]
    lone_r = np.zeros(0, dtype=np.int64)
    lone_b = np.zeros(0, dtype=np.int64)
    if min_channels == 1:
        took = np.full(free_r.shape[0], -1, dtype=np.int64)
        for t in range(n_rb):
            took[ri[t]] = ri[t]
        lone_r = free_r[_free(free_r.shape[0], took)]
        took = np.full(free_b.shape[0], -1, dtype=np.int64)
        for t in range(n_rb):
            took[bi[t]] = bi[t]
        lone_b = free_b[_free(free_b.shape[0], took)]
    n_all = n_g + n_rb + lone_r.shape[0] + lone_b.shape[0]
    idx = np.full((n_all, 3), -1, dtype=np.int64)
    for i in range(n_g):
        idx[i, 0] = pair_r[i]
        idx[i, 1] = i
        idx[i, 2] = pair_b[i]
    for t in range(n_rb):
        idx[n_g + t, 0] = free_r[ri[t]]
        idx[n_g + t, 2] = free_b[bi[t]]
    o = n_g + n_rb
    for t in range(lone_r.shape[0]):
        idx[o + t, 0] = lone_r[t]
    o += lone_r.shape[0]
    for t in range(lone_b.shape[0]):
        idx[o + t, 2] = lone_b[t]
    keep = np.empty(n_all, dtype=np.int64)
    k = 0
    for i in range(n_all):
        c = 0
        for ch in range(3):
            if idx[i, ch] >= 0:
                c += 1
        if c >= min_channels:
            keep[k] = i
            k += 1
    noise = np.empty(3)
    for ch in range(3):
        noise[ch] = noise_dn[ch] if math.isfinite(noise_dn[ch]) else 0.0
    xy = np.zeros((k, 2))
    it = np.zeros((k, 3))
    ch_idx = np.empty((k, 3), dtype=np.int64)
    n_ch = np.empty(k, dtype=np.int64)
    key = np.empty(k)
    for a in range(k):
        i = keep[a]
        wsum = 0.0
        sx = 0.0
        sy = 0.0
        c = 0
        for ch in range(3):
            j = idx[i, ch]
            ch_idx[a, ch] = j
            if j < 0:
                continue
            c += 1
            if ch == 0:
                inten, area, px, py = inten_r[j], area_r[j], reg_r[j, 0], reg_r[j, 1]
            elif ch == 1:
                inten, area, px, py = inten_g[j], area_g[j], xy_g[j, 0], xy_g[j, 1]
            else:
                inten, area, px, py = inten_b[j], area_b[j], reg_b[j, 0], reg_b[j, 1]
            it_pos = max(inten, 1e-9)
            w = 1.0 / ((it_pos / gain_e_per_dn + area * noise[ch] ** 2) / (it_pos * it_pos))
            wsum += w
            sx += w * px
            sy += w * py
            it[a, ch] = inten
        n_ch[a] = c
        d = max(wsum, 1e-300)
        xy[a, 0] = sx / d
        xy[a, 1] = sy / d
        key[a] = -(it[a, 0] + it[a, 1] + it[a, 2])
    order = stable_argsort(key)  # the project's stable sort (numba's argsort compiles for seconds per caller)
    out_xy = np.empty((k, 2))
    out_it = np.empty((k, 3))
    out_idx = np.empty((k, 3), dtype=np.int64)
    out_n = np.empty(k, dtype=np.int64)
    ratio = np.full(k, np.nan)
    has = np.zeros(k, dtype=np.bool_)
    for t in range(k):
        a = order[t]
        out_xy[t, 0] = xy[a, 0]  # element copies: a row assignment compiles numba's shape check (seconds)
        out_xy[t, 1] = xy[a, 1]
        for ch in range(3):
            out_it[t, ch] = it[a, ch]
            out_idx[t, ch] = ch_idx[a, ch]
        out_n[t] = n_ch[a]
        if ch_idx[a, 0] >= 0 and ch_idx[a, 2] >= 0 and it[a, 0] > 0.0 and it[a, 2] > 0.0:
            has[t] = True
            ratio[t] = np.log(it[a, 0] / it[a, 2])
    return out_xy, out_it, out_idx, out_n, ratio, has


@njit(cache=True, no_cfunc_wrapper=True)
def fused_centroid_detections(inputs_r, inputs_g, inputs_b, affine_r, x0_r, q_r, affine_b, x0_b, q_b, radius_px,
                              min_channels, gain_e_per_dn):
    """A 3CMOS frame's detections in the centroid fidelity, fused (:func:`startracker.color.simulate_fused_detections`):
    each channel's :func:`startracker.kernels.centroid.centroid_detections`, then :func:`fuse_channels` on their
    centroids, intensities, areas and noise σ, in one call.

    Parameters
    ----------
    inputs_r, inputs_g, inputs_b : tuple
        Each channel's 25 arguments of ``centroid_detections`` (its scene and draws:
        :func:`startracker.centroid.fidelity.draw_centroid_inputs`).
    affine_r, x0_r, q_r, affine_b, x0_b, q_b, radius_px, min_channels, gain_e_per_dn
        As :func:`fuse_channels`.

    Returns
    -------
    xy, intensity, channel_index, n_channels, color_ratio, has_color
        As :func:`fuse_channels`.
    """
    det_r = centroid_detections(*inputs_r)
    det_g = centroid_detections(*inputs_g)
    det_b = centroid_detections(*inputs_b)
    noise = np.empty(3)
    noise[0] = det_r[5]
    noise[1] = det_g[5]
    noise[2] = det_b[5]
    return fuse_channels(det_r[0][0], det_g[0][0], det_b[0][0], det_r[1][0], det_g[1][0], det_b[1][0],
                         det_r[2][0].astype(np.float64), det_g[2][0].astype(np.float64), det_b[2][0].astype(np.float64),
                         noise, affine_r, x0_r, q_r, affine_b, x0_b, q_b, radius_px, min_channels, gain_e_per_dn)
