"""Tracking kernels: prediction, DKVLUT and brute-force matching, grouping into N Wahba solutions; compiled, no checks.

The checked API and the methods' descriptions are in :mod:`startracker.track` (paper 000). Arrays are float64
(int64 for indices, bool for masks), pixel coordinates (column, row) in px, directions unit vectors, quaternions
(w, x, y, z) unit and canonical (first non-zero component positive).

The module is over 600 lines because prediction, the two matchers and the grouping with its Wahba solutions
are the compiled steps of one tracking frame and share their projection and bookkeeping helpers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.algebra import quat_multiply_into, quat_normalize_canonical, quat_to_rotation
from startracker.kernels.attitude import solve_wahba_one
from startracker.kernels.catalog import cone_search_angle
from startracker.kernels.kvector import kvector_fill, median_value, partition_values
from startracker.kernels.rotations import normalize_rows
from startracker.kernels.sensor import accept_instants, gather_instants, innovation_chi2_mean, true_indices

__all__ = [
    "propagate_attitudes",
    "project_frame",
    "dkvlut_build",
    "dkvlut_ranges",
    "dkvlut_candidates",
    "dkvlut_match",
    "dkvlut_build_match",
    "match_brute",
    "unproject_to_body",
    "solve_instants",
    "track_frame",
    "track_frame_from_state",
    "prediction_sigma_px",
]


# ------------------------------------------------------------------------------------------- prediction
@njit(cache=True, no_cfunc_wrapper=True)
def propagate_attitudes(q0, omega, alpha, dt, q_cam_to_body):
    """Second-order attitude propagation to N instants and the camera's attitude there.

    ``q(dt) = q0 ⊗ exp(ω dt + α dt²/2)`` (body-frame rotation vector, as
    :func:`startracker.rotations.quat_integrate`), then ``q_cam = q(dt) ⊗ q_cam_to_body``.

    Parameters
    ----------
    q0 : ndarray, shape (4,)
        Unit body-to-ICRS quaternion at the reference time.
    omega : ndarray, shape (3,)
        Body rate, rad/s.
    alpha : ndarray, shape (3,)
        Body angular acceleration, rad/s².
    dt : ndarray, shape (N,)
        Instants minus the reference time, s.
    q_cam_to_body : ndarray, shape (4,)
        Camera mounting.

    Returns
    -------
    q_body_to_icrs : ndarray, shape (N, 4)
        Canonical unit quaternions.
    r_cam_to_icrs : ndarray, shape (N, 3, 3)
        ``v_icrs = R @ v_cam`` per instant.
    boresight_mid : ndarray, shape (3,)
        Unit mean of the N boresights (camera +z in ICRS).
    spread_rad : float
        Largest angle between a boresight and ``boresight_mid``.
    """
    n = dt.shape[0]
    q_body = np.empty((n, 4))
    r = np.empty((n, 3, 3))
    dq = np.empty(4)
    qc = np.empty(4)
    qm = np.empty(4)  # a writable copy of the (read-only) mounting: quat_multiply_into compiles once, not twice
    for k in range(4):
        qm[k] = q_cam_to_body[k]
    mid = np.zeros(3)
    for i in range(n):
        t = dt[i]
        rx = omega[0] * t + 0.5 * alpha[0] * t * t
        ry = omega[1] * t + 0.5 * alpha[1] * t * t
        rz = omega[2] * t + 0.5 * alpha[2] * t * t
        angle = math.sqrt(rx * rx + ry * ry + rz * rz)
        if angle <= 1e-3:
            a2 = angle * angle
            scale = 0.5 - a2 / 48 + a2 * a2 / 3840
        else:
            scale = math.sin(angle / 2) / angle
        dq[0] = math.cos(angle / 2)
        dq[1] = scale * rx
        dq[2] = scale * ry
        dq[3] = scale * rz
        quat_multiply_into(q0, dq, q_body[i])
        quat_normalize_canonical(q_body[i])
        quat_multiply_into(q_body[i], qm, qc)
        quat_to_rotation(qc, r[i])
        for k in range(3):
            mid[k] += r[i, k, 2]
    nm = math.sqrt(mid[0] * mid[0] + mid[1] * mid[1] + mid[2] * mid[2])
    for k in range(3):
        mid[k] /= nm
    spread = 0.0
    for i in range(n):
        c = r[i, 0, 2] * mid[0] + r[i, 1, 2] * mid[1] + r[i, 2, 2] * mid[2]
        spread = max(spread, math.acos(min(1.0, max(-1.0, c))))
    return q_body, r, mid, spread


@njit(cache=True, no_cfunc_wrapper=True)
def project_frame(v_icrs, star, r_cam_to_icrs, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, cos_rot,
                  sin_rot, width, height, margin_px):
    """Project S catalog stars at N instants; keep the spots on the detector or within the margin around it.

    Pinhole with first-order radial distortion (:func:`startracker.kernels.optics.project_pinhole`), then the
    in-plane rotation of a 3CMOS channel's detector about the principal point, ``xy' = pp + (xy - pp) R(θ)``
    in row-vector form (identity for θ = 0: ``cos_rot = 1``, ``sin_rot = 0`` skip it).

    Parameters
    ----------
    v_icrs : ndarray, shape (S, 3)
        Unit ICRS directions of the candidate stars.
    star : ndarray of int64, shape (S,)
        Their catalog rows.
    r_cam_to_icrs : ndarray, shape (N, 3, 3)
    focal_length_mm, k1_per_mm2, pixel_size_mm : float
        Focal length (mm), radial distortion (1/mm²), pixel pitch (mm).
    ppx, ppy : float
        Principal point (column, row), px.
    cos_rot, sin_rot : float
        Detector in-plane rotation θ.
    width, height : int
        Detector size, px.
    margin_px : float
        Keep spots up to this far outside the detector's outer pixel edges, px.

    Returns
    -------
    xy : ndarray, shape (W, 2)
        Kept spots, instant-major (all stars of instant 0, then instant 1, ...), px.
    star_index : ndarray of int64, shape (W,)
    instant : ndarray of int64, shape (W,)
    on_detector : ndarray of bool, shape (W,)
    """
    n_t, n_s = r_cam_to_icrs.shape[0], v_icrs.shape[0]
    cap = n_t * n_s
    xy = np.empty((cap, 2))
    st = np.empty(cap, dtype=np.int64)
    inst = np.empty(cap, dtype=np.int64)
    on = np.empty(cap, dtype=np.bool_)
    rotate = cos_rot != 1.0 or sin_rot != 0.0
    x_lo, x_hi = -0.5 - margin_px, width - 0.5 + margin_px
    y_lo, y_hi = -0.5 - margin_px, height - 0.5 + margin_px
    w = 0
    for i in range(n_t):
        m = r_cam_to_icrs[i]
        for s in range(n_s):
            a, b, c = v_icrs[s, 0], v_icrs[s, 1], v_icrs[s, 2]
            vx = a * m[0, 0] + b * m[1, 0] + c * m[2, 0]
            vy = a * m[0, 1] + b * m[1, 1] + c * m[2, 1]
            vz = a * m[0, 2] + b * m[1, 2] + c * m[2, 2]
            # in front of the camera: the sum of magnitudes bounds the norm, so the first test accepts without the
            # square root wherever the second would
            if not (vz > 2e-12 * (abs(vx) + abs(vy) + abs(vz)) or vz > 1e-12 * math.sqrt(vx * vx + vy * vy + vz * vz)):
                continue
            x = focal_length_mm * vx / vz
            y = focal_length_mm * vy / vz
            if k1_per_mm2 != 0.0:
                f = 1.0 + k1_per_mm2 * (x * x + y * y)
                x = x * f
                y = y * f
            x = x / pixel_size_mm + ppx
            y = y / pixel_size_mm + ppy
            if rotate:
                dx, dy = x - ppx, y - ppy
                x = ppx + (dx * cos_rot + dy * sin_rot)
                y = ppy + (-dx * sin_rot + dy * cos_rot)
            # written always, kept when within the margin: no branch on a test that fails for much of the cone
            xy[w, 0] = x
            xy[w, 1] = y
            st[w] = star[s]
            inst[w] = i
            on[w] = (x >= -0.5) & (x <= width - 0.5) & (y >= -0.5) & (y <= height - 0.5)
            w += (x >= x_lo) & (x <= x_hi) & (y >= y_lo) & (y <= y_hi)
    return xy[:w].copy(), st[:w].copy(), inst[:w].copy(), on[:w].copy()


# --------------------------------------------------------------------------------------------- matching
@njit(cache=True, no_cfunc_wrapper=True)
def dkvlut_build(pred):
    """Paper 000 §3.1: both k-vector tables over the predicted points, and the rows linking them.

    Parameters
    ----------
    pred : ndarray, shape (W, 2)
        Predicted points (column, row), px, W >= 1.

    Returns
    -------
    order : ndarray of int64, shape (2, W)
        ``R_x``, ``R_y`` (0-based predicted indices in ascending x, y).
    k : ndarray of int64, shape (2, W)
        ``K_x``, ``K_y`` (``k[a, i - 1]`` is the paper's ``K(i)``).
    line : ndarray, shape (2, 6)
        Per axis ``(1/a1, b1, tol, S(1), S(l_s), a1)``: ``1/a1 = 0`` marks an axis whose coordinates are (nearly)
        all equal, where the line means nothing in floating point; ``tol`` = 1e-9 of the coordinate scale widens
        every range so that floor/ceil rounding never drops a point.
    cross : ndarray of int64, shape (2, W)
        ``cross[a, u]``: the row, in the other axis' table, of the point at row u of axis a's table.
    """
    n = pred.shape[0]
    order = np.empty((2, n), dtype=np.int64)
    k = np.empty((2, n), dtype=np.int64)
    cross = np.empty((2, n), dtype=np.int64)
    line = np.empty((2, 6))
    col = np.empty(n)
    srt = np.empty(n)
    for a in range(2):
        for j in range(n):
            col[j] = pred[j, a]
        a1, b1 = kvector_fill(col, order[a], srt, k[a])
        s0, s1 = srt[0], srt[n - 1]
        degenerate = not (a1 > 1e-9 * max(1.0, abs(s0), abs(s1)))
        line[a, 0] = 0.0 if degenerate else 1.0 / a1
        line[a, 1] = b1
        line[a, 2] = 1e-9 * (abs(s0) + abs(s1) + a1)
        line[a, 3] = s0
        line[a, 4] = s1
        line[a, 5] = a1
    cross = np.empty((2, n), dtype=np.int64)
    rank = np.empty(n, dtype=np.int64)
    for a in range(2):
        for j in range(n):
            rank[order[1 - a, j]] = j
        for j in range(n):
            cross[a, j] = rank[order[a, j]]
    return order, k, line, cross


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _axis_line(line, r):
    """One axis' constants of eqs. 4-5 for radius r, computed once per call rather than per observed point:
    ``(1/a1, i_a offset, i_b offset, r, tol, S(1), S(l_s))`` (``i = o / a1 + offset``)."""
    inv, b1, tol = line[0], line[1], line[2]
    return inv, (-r - tol - b1) * inv, (r + tol - b1) * inv, r, tol, line[3], line[4]


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _axis_range(k, c, n, o):
    """Eqs. 4-5 on one axis (``c`` from :func:`_axis_line`): 0-based half-open rows ``[K(i_a) - 1, K(i_b))`` (the
    paper's ``[K(i_a), K(i_b)]``)."""
    inv, off_a, off_b, r, tol, s0, s1 = c
    if inv == 0.0:
        # tol also here: d² may underflow to <= r² for |o - s| a hair beyond r
        if o + r + tol >= s0 and o - r - tol <= s1:
            return 0, n
        return 0, 0
    ha = o * inv + off_a
    hb = o * inv + off_b
    if not ha >= 1.0:  # NaN too
        ha = 1.0
    elif ha > n:
        ha = float(n)
    if not hb <= n:
        hb = float(n)
    elif hb < 1.0:
        hb = 1.0
    ia = int(ha)  # floor: ha >= 1
    ib = int(math.ceil(hb))
    return max(k[ia - 1] - 1, 0), k[ib - 1]


@njit(cache=True, no_cfunc_wrapper=True)
def dkvlut_ranges(order, k, line, obs, radius_px):
    """Candidate rows of every observed point on both axes (eqs. 4-5).

    Parameters
    ----------
    order, k, line : ndarray
        From :func:`dkvlut_build`.
    obs : ndarray, shape (Q, 2)
        Observed points, px.
    radius_px : float
        Star-neighbourhood radius r >= 0, px.

    Returns
    -------
    ndarray of int64, shape (Q, 4)
        ``(start_x, stop_x, start_y, stop_y)``: ``order[0, start_x:stop_x]`` is R_x(u_x), the same for y.
    """
    n = order.shape[1]
    q_n = obs.shape[0]
    out = np.empty((q_n, 4), dtype=np.int64)
    cx, cy = _axis_line(line[0], radius_px), _axis_line(line[1], radius_px)
    for q in range(q_n):
        for a in range(2):
            lo, hi = _axis_range(k[a], cx if a == 0 else cy, n, obs[q, a])
            out[q, 2 * a] = lo
            out[q, 2 * a + 1] = hi
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def dkvlut_candidates(order, k, line, cross, obs, radius_px):
    """The intersection set R_P of eq. 6 of every observed point, as (query, predicted) pairs.

    The intersection is taken without sets: walking the shorter of the two candidate lists, a candidate is in
    the other axis' set when its row there (``cross``) lies inside that axis' range, an O(1) test.

    Parameters
    ----------
    order, k, line, cross : ndarray
        From :func:`dkvlut_build`.
    obs : ndarray, shape (Q, 2)
    radius_px : float

    Returns
    -------
    query_index, predicted_index : ndarray of int64, shape (P,)
        Grouped by query (ascending).
    """
    rng = dkvlut_ranges(order, k, line, obs, radius_px)
    q_n = obs.shape[0]
    total = 0
    for q in range(q_n):
        total += min(rng[q, 1] - rng[q, 0], rng[q, 3] - rng[q, 2])
    qi = np.empty(total, dtype=np.int64)
    ei = np.empty(total, dtype=np.int64)
    p = 0
    for q in range(q_n):
        a = 0 if rng[q, 1] - rng[q, 0] <= rng[q, 3] - rng[q, 2] else 1
        olo, ohi = rng[q, 2 - 2 * a], rng[q, 3 - 2 * a]
        for u in range(rng[q, 2 * a], rng[q, 2 * a + 1]):
            ro = cross[a, u]
            if ro >= olo and ro < ohi:
                qi[p] = q
                ei[p] = order[a, u]
                p += 1
    return qi[:p].copy(), ei[:p].copy()


@njit(cache=True, no_cfunc_wrapper=True)
def dkvlut_match(pred, order, k, line, cross, obs, radius_px):
    """Paper 000 §3.2 for every observed point: the nearest point of R_P within the radius.

    Parameters
    ----------
    pred : ndarray, shape (W, 2)
        Predicted points, px (the ones :func:`dkvlut_build` tabulated).
    order, k, line, cross : ndarray
        From :func:`dkvlut_build`.
    obs : ndarray, shape (Q, 2)
        Observed points, px.
    radius_px : float
        r >= 0, px.

    Returns
    -------
    ndarray of int64, shape (Q,)
        Predicted index minimising ``d² = (x_q - x_p)² + (y_q - y_p)²`` among ``d² <= r²`` (ties to the lowest
        index), -1 when none.
    """
    n = order.shape[1]
    q_n = obs.shape[0]
    r2 = radius_px * radius_px
    out = np.empty(q_n, dtype=np.int64)
    kx, ky = k[0], k[1]
    cx, cy = _axis_line(line[0], radius_px), _axis_line(line[1], radius_px)
    for q in range(q_n):
        xq, yq = obs[q, 0], obs[q, 1]
        x0, x1 = _axis_range(kx, cx, n, xq)
        y0, y1 = _axis_range(ky, cy, n, yq)
        if x1 - x0 <= y1 - y0:
            a, lo, hi, olo, ohi = 0, x0, x1, y0, y1
        else:
            a, lo, hi, olo, ohi = 1, y0, y1, x0, x1
        best = -1
        bd = np.inf
        for u in range(lo, hi):
            ro = cross[a, u]
            if ro >= olo and ro < ohi:  # R_x(u_x) ∩ R_y(u_y), eq. 6
                e = order[a, u]
                dx = xq - pred[e, 0]
                dy = yq - pred[e, 1]
                d2 = dx * dx + dy * dy
                if d2 <= r2 and (d2 < bd or (d2 == bd and e < best)):
                    best = e
                    bd = d2
        out[q] = best
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def dkvlut_build_match(pred, obs, radius_px):
    """:func:`dkvlut_build` then :func:`dkvlut_match`, in one call (the tracker's per-frame use).

    Parameters
    ----------
    pred : ndarray, shape (W, 2)
        Predicted points, px, W >= 1.
    obs : ndarray, shape (Q, 2)
        Observed points, px.
    radius_px : float
        r >= 0, px.

    Returns
    -------
    ndarray of int64, shape (Q,)
        As :func:`dkvlut_match`.
    """
    order, k, line, cross = dkvlut_build(pred)
    return dkvlut_match(pred, order, k, line, cross, obs, radius_px)


@njit(cache=True, no_cfunc_wrapper=True)
def match_brute(pred, obs, radius_px):
    """Paper 000 §2's "existing method": every observed point against every predicted point.

    Parameters and result as :func:`dkvlut_match` (without the tables).
    """
    q_n, n = obs.shape[0], pred.shape[0]
    r2 = radius_px * radius_px
    out = np.empty(q_n, dtype=np.int64)
    for q in range(q_n):
        xq, yq = obs[q, 0], obs[q, 1]
        best = -1
        bd = np.inf
        for e in range(n):
            dx = xq - pred[e, 0]
            dy = yq - pred[e, 1]
            d2 = dx * dx + dy * dy
            if d2 < bd:  # strict: ties keep the lowest index
                bd = d2
                best = e
        out[q] = best if bd <= r2 else -1
    return out


# ------------------------------------------------------------------------ grouping into N attitudes
@njit(cache=True, no_cfunc_wrapper=True)
def unproject_to_body(xy, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, cos_rot, sin_rot, r_cam_to_body):
    """Pixel coordinates to unit body-frame directions (inverse of :func:`project_frame`'s camera model).

    The in-plane detector rotation is undone, the radial distortion ``r_d = r (1 + k1 r²)`` inverted per point by
    Newton's method (to 1e-15 relative), then ``v_body = R_cam_to_body @ (x_mm, y_mm, f_mm) / |·|``.

    Parameters
    ----------
    xy : ndarray, shape (K, 2)
        Pixel coordinates (column, row), distorted as measured.
    focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, cos_rot, sin_rot : float
        As :func:`project_frame`.
    r_cam_to_body : ndarray, shape (3, 3)

    Returns
    -------
    ndarray, shape (K, 3)
    """
    n = xy.shape[0]
    out = np.empty((n, 3))
    rotate = cos_rot != 1.0 or sin_rot != 0.0
    for j in range(n):
        x, y = xy[j, 0], xy[j, 1]
        if rotate:
            dx, dy = x - ppx, y - ppy
            x = ppx + (dx * cos_rot - dy * sin_rot)
            y = ppy + (dx * sin_rot + dy * cos_rot)
        dx = (x - ppx) * pixel_size_mm
        dy = (y - ppy) * pixel_size_mm
        if k1_per_mm2 != 0.0:
            rd = math.sqrt(dx * dx + dy * dy)
            rr = rd
            for _ in range(20):
                f = rr * (1 + k1_per_mm2 * rr * rr) - rd
                step = f / (1 + 3 * k1_per_mm2 * rr * rr)
                rr = rr - step
                if abs(step) <= 1e-15 * max(rd, 1e-30):
                    break
            if rd > 0:
                dx = dx * (rr / rd)
                dy = dy * (rr / rd)
        nv = math.sqrt(dx * dx + dy * dy + focal_length_mm * focal_length_mm)
        cx, cy, cz = dx / nv, dy / nv, focal_length_mm / nv
        for i in range(3):
            out[j, i] = r_cam_to_body[i, 0] * cx + r_cam_to_body[i, 1] * cy + r_cam_to_body[i, 2] * cz
    return out


ROBUST_MIN_STARS = 8
"""Instants with at least this many stars also test outliers against their own robust residual scale."""


@njit(cache=True, no_cfunc_wrapper=True)
def solve_instants(obs, v_body, idx, pred_xy, pred_instant, pred_star, catalog_vectors, n_instants, sigma_rad,
                   min_stars, outlier_threshold_rad, obs_intensity, star_flux, flux_ratio_max):
    """Unique assignment, grouping by exposure instant and one Wahba solution per instant with outlier rejection.

    Several observed points on one predicted point: the nearest keeps it (ties: the lowest observed index).
    Per instant, the stars in observed-index order are solved (:func:`~startracker.kernels.attitude.solve_wahba_one`,
    weights σ⁻²); while more than two remain and the largest residual exceeds the threshold, that star is dropped
    and the instant solved again. With at least :data:`ROBUST_MIN_STARS` stars the threshold is also at most 5 times
    the instant's robust residual scale (median residual / 1.1774), not below 0.4 of ``outlier_threshold_rad``: spots
    joined across two exposures (half a spacing off, all along the motion) pull the fit toward them together and
    would otherwise stay under a threshold set by the claimed σ.

    Parameters
    ----------
    obs : ndarray, shape (K, 2)
        Detections, px.
    v_body : ndarray, shape (K, 3)
        Their unit body-frame directions (:func:`unproject_to_body`).
    idx : ndarray of int64, shape (K,)
        Match of each detection into the prediction, or -1.
    pred_xy : ndarray, shape (W, 2)
    pred_instant, pred_star : ndarray of int64, shape (W,)
        Exposure instant and catalog row of each predicted spot.
    catalog_vectors : ndarray, shape (C, 3)
        Unit ICRS star directions.
    n_instants : int
        N.
    sigma_rad : float
        Angular noise of a detection, rad.
    min_stars : int
        Instants with fewer stars are not ``ok``.
    outlier_threshold_rad : float
        Residual above which a star is an outlier.
    obs_intensity : ndarray, shape (K,)
        Intensity of each detection (any unit); unused when ``star_flux`` is empty.
    star_flux : ndarray, shape (C,) or (0,)
        Expected single-exposure signal of each catalog star (relative, e.g. ``SensorModel.star_pe`` per second);
        empty: no photometric test.
    flux_ratio_max : float
        Photometric blend test: with :data:`ROBUST_MIN_STARS` or more matches, a detection whose intensity over its
        star's expected signal exceeds this times the lower quartile of that ratio over the frame's matches (one
        exposure's light, as long as a quarter of the matches are single spots) is not used:
        it holds the light of more than one exposure (spots joined across exposures, whose centroid lies between
        them).

    Returns
    -------
    q : ndarray, shape (N, 4)
        ``q_body_to_icrs`` per instant (identity where Wahba failed).
    covariance_rad2 : ndarray, shape (N, 3, 3)
        Body frame; all entries infinite where not ``ok``.
    residual_rms_arcsec : ndarray, shape (N,)
        Infinite where not ``ok``.
    n_stars : ndarray of int64, shape (N,)
    ok : ndarray of bool, shape (N,)
    assignment : ndarray of int64, shape (K,)
        Predicted index each detection was finally used for, or -1.
    n_outliers : int
    """
    k_n, w_n = obs.shape[0], pred_xy.shape[0]
    best_q = np.full(w_n, -1, dtype=np.int64)
    best_d = np.empty(w_n)
    for q in range(k_n):
        p = idx[q]
        if p >= 0:
            dx = obs[q, 0] - pred_xy[p, 0]
            dy = obs[q, 1] - pred_xy[p, 1]
            d2 = dx * dx + dy * dy
            if best_q[p] < 0 or d2 < best_d[p]:
                best_q[p] = q
                best_d[p] = d2
    assign = np.full(k_n, -1, dtype=np.int64)
    n_assigned = 0
    for p in range(w_n):
        if best_q[p] >= 0:
            assign[best_q[p]] = p
            n_assigned += 1
    if star_flux.shape[0] and n_assigned >= ROBUST_MIN_STARS:
        ratio = np.empty(n_assigned)
        j = 0
        for q in range(k_n):
            if assign[q] >= 0:
                ratio[j] = obs_intensity[q] / max(star_flux[pred_star[assign[q]]], 1e-300)
                j += 1
        # the scale of one exposure's light: the lower quartile (at low rates joined spots can be most matches)
        cap = flux_ratio_max * partition_values(ratio, n_assigned // 4)[n_assigned // 4]
        j = 0
        for q in range(k_n):
            if assign[q] >= 0:
                if ratio[j] > cap:  # the ratio computed above, in the same detection order
                    assign[q] = -1
                j += 1
    counts = np.zeros(n_instants, dtype=np.int64)
    for q in range(k_n):
        if assign[q] >= 0:
            counts[pred_instant[assign[q]]] += 1
    kmax = 2
    for i in range(n_instants):
        kmax = max(kmax, counts[i])
    b = np.zeros((n_instants, kmax, 3))
    r = np.zeros((n_instants, kmax, 3))
    m = np.zeros((n_instants, kmax), dtype=np.bool_)
    slot_q = np.empty((n_instants, kmax), dtype=np.int64)  # -1 (empty slot); not np.full: one compile less
    for i in range(n_instants):
        for s in range(kmax):
            slot_q[i, s] = -1
    fill = np.zeros(n_instants, dtype=np.int64)
    for q in range(k_n):
        p = assign[q]
        if p >= 0:
            i = pred_instant[p]
            s = fill[i]
            fill[i] += 1
            nb = math.sqrt(v_body[q, 0] ** 2 + v_body[q, 1] ** 2 + v_body[q, 2] ** 2)
            c = catalog_vectors[pred_star[p]]
            nr = math.sqrt(c[0] ** 2 + c[1] ** 2 + c[2] ** 2)
            for a in range(3):
                b[i, s, a] = v_body[q, a] / nb
                r[i, s, a] = c[a] / nr
            m[i, s] = True
            slot_q[i, s] = q
    wgt = np.full(kmax, 1.0 / (sigma_rad * sigma_rad))
    q_out = np.empty((n_instants, 4))
    cov = np.empty((n_instants, 3, 3))
    rms = np.empty(n_instants)
    n_used = np.empty(n_instants, dtype=np.int64)
    ok = np.empty(n_instants, dtype=np.bool_)
    ang = np.empty(kmax)
    n_out = 0
    used = np.empty(kmax)
    for i in range(n_instants):
        rms_i, ok_i = 0.0, False
        for _ in range(kmax):  # one outlier per pass
            rms_i, ok_i = solve_wahba_one(b[i], r[i], wgt, m[i], q_out[i], cov[i], ang)
            worst = 0
            cnt = 0
            for s in range(kmax):
                if m[i, s]:
                    used[cnt] = ang[s]
                    cnt += 1
                if ang[s] > ang[worst]:  # unused pairs hold -1
                    worst = s
            threshold = outlier_threshold_rad
            lower = 0.4 * outlier_threshold_rad
            if cnt >= ROBUST_MIN_STARS and ang[worst] > lower and not ang[worst] > threshold:
                # Several outliers pulling one way (spots joined across exposures, all displaced along the motion)
                # drag the fit toward them and hide from a threshold on the claimed σ: also test against the
                # instant's own robust scale (median residual norm / 1.1774 is σ for Gaussian errors), never below
                # 0.4 of the threshold (2σ of the claimed σ at the default 5σ). The median only decides a worst
                # residual between those two bounds: outside them it is not computed.
                med = median_value(used[:cnt]) / 1.1774
                threshold = min(threshold, max(5.0 * med, lower))
            if cnt > 2 and ang[worst] > threshold:
                m[i, worst] = False
                n_out += 1
            else:
                break
        cnt = 0
        for s in range(kmax):
            if m[i, s]:
                cnt += 1
        n_used[i] = cnt
        ok[i] = ok_i and cnt >= min_stars
        rms[i] = rms_i if ok[i] else np.inf
        if not ok[i]:
            cov[i, :, :] = np.inf
        for s in range(kmax):
            if slot_q[i, s] >= 0 and not m[i, s]:
                assign[slot_q[i, s]] = -1
    return q_out, cov, rms, n_used, ok, assign, n_out


@njit(cache=True, no_cfunc_wrapper=True)
def track_frame(q_body, r_cam_to_icrs, cand, catalog_vectors, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy,
                cos_rot, sin_rot, width, height, obs, radius_px, brute, r_cam_to_body, sigma_rad, min_stars,
                outlier_threshold_rad, t_exp, t_ref, cov_theta, cov_omega, cov_alpha, obs_intensity, star_flux,
                flux_ratio_max):
    """One tracking frame after the prediction's attitudes: projection, matching, N Wahba solutions, innovation.

    :func:`project_frame` of the candidate stars (margin = the radius), :func:`dkvlut_build_match` (or
    :func:`match_brute`), :func:`unproject_to_body`, :func:`solve_instants`, then
    :func:`~startracker.kernels.sensor.innovation_chi2_mean` over the solved instants: the tracker's frame in
    one call, with the lock tests' inputs as scalars.

    Parameters
    ----------
    q_body : ndarray, shape (N, 4)
        Predicted body attitudes at the instants (:func:`propagate_attitudes`).
    r_cam_to_icrs : ndarray, shape (N, 3, 3)
        Predicted camera attitudes.
    cand : ndarray of int64, shape (S,)
        Catalog rows of the candidate stars (cone search).
    catalog_vectors : ndarray, shape (C, 3)
    focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, cos_rot, sin_rot : float
        Camera model, as :func:`project_frame`.
    width, height : int
        Detector size, px.
    obs : ndarray, shape (K, 2)
        Detections, px.
    radius_px : float
        Star-neighbourhood radius (and the prediction's margin outside the detector), px.
    brute : bool
        Match by :func:`match_brute` instead of the DKVLUT (same answer).
    r_cam_to_body : ndarray, shape (3, 3)
    sigma_rad, min_stars, outlier_threshold_rad
        As :func:`solve_instants`.
    t_exp : ndarray, shape (N,)
        Exposure instants, s.
    t_ref : float
        Time of the motion state the prediction starts from, s.
    cov_theta, cov_omega, cov_alpha : ndarray, shape (3, 3)
        The prediction's covariances, as :func:`~startracker.kernels.sensor.innovation_chi2_mean`.
    obs_intensity, star_flux, flux_ratio_max
        The photometric blend test, as :func:`solve_instants` (``star_flux`` empty: none).

    Returns
    -------
    n_predicted : int
        Predicted spots on the detector.
    n_matched : int
        Detections used by the solutions.
    q, covariance_rad2, residual_rms_arcsec, n_stars, ok
        Per instant, as :func:`solve_instants`.
    nis : float
        Mean innovation χ² of the solved instants (0.0 when none).
    """
    n_inst = t_exp.shape[0]
    n_c = cand.shape[0]
    v = np.empty((n_c, 3))
    for j in range(n_c):
        for a in range(3):
            v[j, a] = catalog_vectors[cand[j], a]
    xy, star, inst, on_det = project_frame(v, cand, r_cam_to_icrs, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx,
                                           ppy, cos_rot, sin_rot, width, height, radius_px)
    n_pred = 0
    for j in range(on_det.shape[0]):
        if on_det[j]:
            n_pred += 1
    k_n = obs.shape[0]
    if xy.shape[0] == 0 or k_n == 0:
        idx = np.full(k_n, -1, dtype=np.int64)
    elif brute:
        idx = match_brute(xy, obs, radius_px)
    else:
        idx = dkvlut_build_match(xy, obs, radius_px)
    v_body = unproject_to_body(obs, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, cos_rot, sin_rot,
                               r_cam_to_body)
    q, cov, rms, n_used, ok, assign, _ = solve_instants(obs, v_body, idx, xy, inst, star, catalog_vectors, n_inst,
                                                        sigma_rad, min_stars, outlier_threshold_rad, obs_intensity,
                                                        star_flux, flux_ratio_max)
    n_matched = 0
    for j in range(k_n):
        if assign[j] >= 0:
            n_matched += 1
    sel = true_indices(ok)
    nis = 0.0
    if sel.shape[0]:
        t_s, q_body_s, q_s, cov_s = gather_instants(sel, t_exp, q_body, q, cov)
        for i in range(t_s.shape[0]):
            t_s[i] -= t_ref
        nis = innovation_chi2_mean(q_body_s, q_s, cov_s, t_s, cov_theta, cov_omega, cov_alpha)
    return n_pred, n_matched, q, cov, rms, n_used, ok, nis


@njit(cache=True, no_cfunc_wrapper=True)
def track_frame_from_state(q_state, omega, alpha, t_exp, t_ref, q_cam_to_body, half_diag_fov_rad, focal_length_px,
                           vectors_by_z, z_sorted, z_order, catalog_vectors, focal_length_mm, k1_per_mm2, pixel_size_mm,
                           ppx, ppy, cos_rot, sin_rot, width, height, obs, radius_px, brute, r_cam_to_body, sigma_rad,
                           min_stars, outlier_threshold_rad, cov_theta, cov_omega, cov_alpha, obs_intensity, star_flux,
                           flux_ratio_max, instant_gate, residual_expected_arcsec, scale_by_residuals):
    """The tracker's whole frame from its motion state: the state's attitude normalised
    (:func:`~startracker.kernels.rotations.normalize_rows`), :func:`propagate_attitudes` to the instants, the cone
    search of the catalog around them, :func:`track_frame`, then the solved instants' smoothness test and covariance
    scaling (:func:`~startracker.kernels.sensor.accept_instants`), in one call.

    The cone (:func:`~startracker.kernels.catalog.cone_search_angle`) is centred on the mean predicted boresight,
    its half-angle ``min(π, half_diag_fov_rad + spread + radius_px / focal_length_px + 0.02)`` (the detector's
    corners, the boresights' spread over the frame, the neighbourhood radius and a margin), the chord test widened
    by 1e-12 relative as :meth:`startracker.catalog.StarCatalog.cone_search` does.

    Parameters
    ----------
    q_state : ndarray, shape (4,)
        Body-to-ICRS attitude of the motion state (non-zero).
    omega, alpha : ndarray, shape (3,)
        Body rate (rad/s) and angular acceleration (rad/s²) of the propagation.
    t_exp : ndarray, shape (N,)
        Exposure instants, s.
    t_ref : float
        Time of the motion state, s.
    q_cam_to_body : ndarray, shape (4,)
        Camera mounting.
    half_diag_fov_rad : float
        Angle from the boresight to the farthest detector corner, rad.
    focal_length_px : float
        Focal length, px.
    vectors_by_z, z_sorted, z_order : ndarray, shapes (C, 3), (C,), (C,) int64
        The catalog's z index (:attr:`startracker.catalog.StarCatalog.z_index`).
    catalog_vectors : ndarray, shape (C, 3)
        Unit ICRS star directions (catalog order).
    focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, cos_rot, sin_rot, width, height, obs, radius_px, brute,
    r_cam_to_body, sigma_rad, min_stars, outlier_threshold_rad, cov_theta, cov_omega, cov_alpha, obs_intensity,
    star_flux, flux_ratio_max
        As :func:`track_frame`.
    instant_gate, residual_expected_arcsec, scale_by_residuals
        As ``gate``, ``residual_expected_arcsec`` and ``scale`` of
        :func:`~startracker.kernels.sensor.accept_instants`.

    Returns
    -------
    n_predicted, n_matched
        As :func:`track_frame`.
    nis : float
        As :func:`track_frame`.
    n_off : int
        The solved instants (``ok``) through :func:`~startracker.kernels.sensor.accept_instants`: instants off a smooth
        motion.
    values : ndarray, shape (2, N)
        ``values[0]``: residual_rms_arcsec per instant, as :func:`track_frame`; ``values[1, :m]``: the m kept
        instants' times, s (the rest uninitialised).
    counts : ndarray of int64, shape (4, N)
        ``counts[0]``: n_stars per instant, as :func:`track_frame`; ``counts[1, :m]``, ``counts[2, :m]``: the kept
        instants (ascending) and their stars (the rest uninitialised); ``counts[3]``: 1 where :func:`track_frame`'s
        ``ok`` (solved), else 0.
    q, covariance_rad2 : ndarray, shapes (m, 4), (m, 3, 3)
        The kept instants' attitudes and scaled covariances (rad²), fresh arrays.

    Notes
    -----
    The outputs of one kind share one array (the caller's arrays its rows and row slices): every array handed back
    to Python costs a boxing of its own.
    """
    n = t_exp.shape[0]
    dt = np.empty(n)
    for i in range(n):
        dt[i] = t_exp[i] - t_ref
    q_row = np.empty((1, 4))
    for i in range(4):
        q_row[0, i] = q_state[i]
    q0 = normalize_rows(q_row)[0]
    q_pred, r_c2i, mid, spread = propagate_attitudes(q0, omega, alpha, dt, q_cam_to_body)
    cone = half_diag_fov_rad + spread + radius_px / focal_length_px + 0.02
    if not cone < math.pi:  # min(π, cone), NaN to π as Python's min has it
        cone = math.pi
    cand = cone_search_angle(vectors_by_z, z_sorted, z_order, mid, cone)
    n_pred, n_matched, q, cov, rms, n_used, ok, nis = track_frame(
        q_pred, r_c2i, cand, catalog_vectors, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, cos_rot, sin_rot,
        width, height, obs, radius_px, brute, r_cam_to_body, sigma_rad, min_stars, outlier_threshold_rad, t_exp, t_ref,
        cov_theta, cov_omega, cov_alpha, obs_intensity, star_flux, flux_ratio_max)
    n_off, kept, t_s, q_k, cov_k, n_k = accept_instants(true_indices(ok), t_exp, q_pred, q, cov, rms, n_used,
                                                        instant_gate, residual_expected_arcsec, scale_by_residuals)
    values = np.empty((2, n))
    counts = np.empty((4, n), dtype=np.int64)
    for i in range(n):
        values[0, i] = rms[i]
        counts[0, i] = n_used[i]
        counts[3, i] = 1 if ok[i] else 0
    for k in range(kept.shape[0]):
        values[1, k] = t_s[k]
        counts[1, k] = kept[k]
        counts[2, k] = n_k[k]
    return n_pred, n_matched, nis, n_off, values, counts, q_k, cov_k


@njit(cache=True, no_cfunc_wrapper=True)
def prediction_sigma_px(r_cam_to_body, cov_theta, cov_omega, cov_alpha, dt_s, focal_length_px, rho_px):
    """1σ per-axis spot prediction error, px: ``sqrt(f² max(P_xx, P_yy) + ρ² P_zz)`` of ``Rᵀ P(dt) R``.

    Parameters
    ----------
    r_cam_to_body : ndarray, shape (3, 3)
    cov_theta, cov_omega, cov_alpha : ndarray, shape (3, 3)
        Attitude (rad²), rate ((rad/s)²) and acceleration ((rad/s²)²) error covariances, body frame.
    dt_s : float
        Propagation time, s; ``P(dt) = P_θ + P_ω dt² + P_α dt⁴ / 4``.
    focal_length_px, rho_px : float
        Focal length and the distance from the detector centre to a corner, px.

    Returns
    -------
    float, px
    """
    dt2 = dt_s * dt_s
    dt4 = dt2 * dt2 / 4.0
    d = np.zeros(3)
    for c in range(3):  # diagonal of R^T P R
        acc = 0.0
        for i in range(3):
            for j in range(3):
                p = cov_theta[i, j] + cov_omega[i, j] * dt2 + cov_alpha[i, j] * dt4
                acc += r_cam_to_body[i, c] * p * r_cam_to_body[j, c]
        d[c] = acc
    return math.sqrt(focal_length_px * focal_length_px * max(d[0], d[1], 0.0) + rho_px * rho_px * max(d[2], 0.0))
