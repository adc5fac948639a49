"""Scene kernels: attitudes at the path instants of a frame, and every candidate star projected at every instant.

The checked API and the meaning of a scene are in :mod:`startracker.scene`. Conventions: quaternions
``(w, x, y, z)``, Hamilton product; ``v_icrs = R(q_body_to_icrs) R_cam_to_body v_cam``; camera +z is the boresight;
pixel ``(0, 0)`` the centre of the top-left pixel; the pinhole with first-order radial distortion of
:mod:`startracker.optics` (paper 004 eqs. 1-3). Arrays are float64 (int64 / bool where said), C-contiguous; nothing
is checked. A frame has N exposures of S path instants each: the ``P = N S`` instants are exposure-major.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.catalog import cone_search_angle
from startracker.kernels.kvector import search_sorted

__all__ = [
    "interpolate_attitudes",
    "camera_frames",
    "rotate_to_camera",
    "select_near_detector",
    "project_scene",
    "scene_frame",
    "min_image_speed",
    "no_overlap_exposures",
]


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _canonical(q):
    """q and -q are one rotation: the one whose first non-zero component is positive (in place)."""
    for i in range(4):
        if q[i] != 0.0:
            if q[i] < 0.0:
                for j in range(4):
                    q[j] = -q[j]
            return


@njit(cache=True, no_cfunc_wrapper=True)
def interpolate_attitudes(t_samples, q_samples, t_query):
    """Spherical-linear interpolation of an attitude history (scipy ``Slerp``'s rule).

    For ``t`` in ``[t_k, t_{k+1}]`` (``k`` from a left-sided search, the first interval at ``t_0``), with
    ``p, r`` the unit quaternions at ``t_k, t_{k+1}``: ``δ = rotvec(p⁻¹ r)`` on the short arc and
    ``q(t) = p ⊗ exp(α δ)``, ``α = (t − t_k) / (t_{k+1} − t_k)``, normalised, canonical sign.

    Parameters
    ----------
    t_samples : ndarray, shape (S,)
        Strictly increasing sample times, s (S >= 2).
    q_samples : ndarray, shape (S, 4)
        Non-zero attitudes at those times (any norm).
    t_query : ndarray, shape (Q,)
        Query times, s; clipped to ``[t_samples[0], t_samples[-1]]``.

    Returns
    -------
    q : ndarray, shape (Q, 4)
        Unit quaternions.
    """
    n_s = t_samples.shape[0]
    n_q = t_query.shape[0]
    out = np.empty((n_q, 4))
    p = np.empty(4)
    r = np.empty(4)
    k_prev = -1
    dw = dx = dy = dz = vn = arc = 0.0
    for i in range(n_q):
        t = min(max(t_query[i], t_samples[0]), t_samples[n_s - 1])
        k = search_sorted(t_samples, t, np.bool_(False)) - 1  # side="left"; a bool, not a literal: one signature
        if k < 0:
            k = 0
        if k > n_s - 2:
            k = n_s - 2
        alpha = (t - t_samples[k]) / (t_samples[k + 1] - t_samples[k])
        if k != k_prev:  # the interval's own terms, shared by the queries in it (a frame's ~60 fall in ~11)
            k_prev = k
            np_ = 0.0
            nr = 0.0
            for j in range(4):
                np_ += q_samples[k, j] * q_samples[k, j]
                nr += q_samples[k + 1, j] * q_samples[k + 1, j]
            np_ = math.sqrt(np_)
            nr = math.sqrt(nr)
            for j in range(4):
                p[j] = q_samples[k, j] / np_
                r[j] = q_samples[k + 1, j] / nr
            # d = conj(p) ⊗ r
            dw = p[0] * r[0] + p[1] * r[1] + p[2] * r[2] + p[3] * r[3]
            dx = p[0] * r[1] - p[1] * r[0] - p[2] * r[3] + p[3] * r[2]
            dy = p[0] * r[2] + p[1] * r[3] - p[2] * r[0] - p[3] * r[1]
            dz = p[0] * r[3] - p[1] * r[2] + p[2] * r[1] - p[3] * r[0]
            if dw < 0.0:  # the short arc
                dw, dx, dy, dz = -dw, -dx, -dy, -dz
            vn = math.sqrt(dx * dx + dy * dy + dz * dz)
            arc = 2.0 * math.atan2(vn, dw)
        angle = arc * alpha  # rotation angle of exp(α δ)
        if vn > 0.0:
            s = math.sin(0.5 * angle) / vn
        else:
            s = 0.0
        ew = math.cos(0.5 * angle)
        ex, ey, ez = s * dx, s * dy, s * dz
        qw = p[0] * ew - p[1] * ex - p[2] * ey - p[3] * ez
        qx = p[0] * ex + p[1] * ew + p[2] * ez - p[3] * ey
        qy = p[0] * ey - p[1] * ez + p[2] * ew + p[3] * ex
        qz = p[0] * ez + p[1] * ey - p[2] * ex + p[3] * ew
        nq = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        out[i, 0] = qw / nq
        out[i, 1] = qx / nq
        out[i, 2] = qy / nq
        out[i, 3] = qz / nq
        _canonical(out[i])
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def camera_frames(q_body_to_icrs, q_cam_to_body, r_cam_to_body, n_path_samples):
    """Camera-to-ICRS rotations at the path instants, the camera attitudes at the mid instants, the cone axis.

    Parameters
    ----------
    q_body_to_icrs : ndarray, shape (P, 4)
        Unit body attitudes at the ``P = N S`` path instants (exposure-major).
    q_cam_to_body : ndarray, shape (4,)
        Unit mounting quaternion.
    r_cam_to_body : ndarray, shape (3, 3)
        Its rotation matrix.
    n_path_samples : int
        S (odd); the mid instant of exposure i is row ``i S + S // 2``.

    Returns
    -------
    r_cam_to_icrs : ndarray, shape (P, 3, 3)
        ``R(q_body_to_icrs) R_cam_to_body`` (``v_icrs = R v_cam``).
    q_cam_to_icrs_mid : ndarray, shape (N, 4)
        ``q_body_to_icrs ⊗ q_cam_to_body`` at the mid instants, unit, canonical sign.
    centre : ndarray, shape (3,)
        Unit mean boresight over the instants (ICRS).
    drift_rad : float
        Largest angle between a boresight and ``centre``, rad.
    """
    n_p = q_body_to_icrs.shape[0]
    r = np.empty((n_p, 3, 3))
    m = np.empty((3, 3))
    centre = np.zeros(3)
    for i in range(n_p):
        w, x, y, z = q_body_to_icrs[i, 0], q_body_to_icrs[i, 1], q_body_to_icrs[i, 2], q_body_to_icrs[i, 3]
        m[0, 0] = 1.0 - 2.0 * (y * y + z * z)
        m[0, 1] = 2.0 * (x * y - w * z)
        m[0, 2] = 2.0 * (x * z + w * y)
        m[1, 0] = 2.0 * (x * y + w * z)
        m[1, 1] = 1.0 - 2.0 * (x * x + z * z)
        m[1, 2] = 2.0 * (y * z - w * x)
        m[2, 0] = 2.0 * (x * z - w * y)
        m[2, 1] = 2.0 * (y * z + w * x)
        m[2, 2] = 1.0 - 2.0 * (x * x + y * y)
        for a in range(3):
            for b in range(3):
                r[i, a, b] = m[a, 0] * r_cam_to_body[0, b] + m[a, 1] * r_cam_to_body[1, b] + m[a, 2] * r_cam_to_body[2, b]
            centre[a] += r[i, a, 2]
    nc = math.sqrt(centre[0] ** 2 + centre[1] ** 2 + centre[2] ** 2)
    for a in range(3):
        centre[a] /= nc
    cos_min = 1.0
    for i in range(n_p):
        c = r[i, 0, 2] * centre[0] + r[i, 1, 2] * centre[1] + r[i, 2, 2] * centre[2]
        cos_min = min(cos_min, c)
    drift = math.acos(max(min(cos_min, 1.0), -1.0))
    s = n_path_samples
    n = n_p // s
    qc = np.empty((n, 4))
    b0, b1, b2, b3 = q_cam_to_body[0], q_cam_to_body[1], q_cam_to_body[2], q_cam_to_body[3]
    for e in range(n):
        i = e * s + s // 2
        a0, a1, a2, a3 = q_body_to_icrs[i, 0], q_body_to_icrs[i, 1], q_body_to_icrs[i, 2], q_body_to_icrs[i, 3]
        w = a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3
        x = a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2
        y = a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1
        z = a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0
        nq = math.sqrt(w * w + x * x + y * y + z * z)
        qc[e, 0] = w / nq
        qc[e, 1] = x / nq
        qc[e, 2] = y / nq
        qc[e, 3] = z / nq
        _canonical(qc[e])
    return r, qc, centre, drift


@njit(cache=True, no_cfunc_wrapper=True)
def rotate_to_camera(r_cam_to_icrs, vectors, index):
    """Catalog directions in the camera frame at every instant: ``Rᵀ v``.

    Parameters
    ----------
    r_cam_to_icrs : ndarray, shape (P, 3, 3)
    vectors : ndarray, shape (n_catalog, 3)
        Unit ICRS directions of the catalog.
    index : ndarray of int64, shape (K,)
        Rows of ``vectors`` to rotate.

    Returns
    -------
    v_cam : ndarray, shape (P, K, 3)
    """
    n_p = r_cam_to_icrs.shape[0]
    k_n = index.shape[0]
    out = np.empty((n_p, k_n, 3))
    for i in range(n_p):
        for k in range(k_n):
            v0, v1, v2 = vectors[index[k], 0], vectors[index[k], 1], vectors[index[k], 2]
            for a in range(3):
                out[i, k, a] = r_cam_to_icrs[i, 0, a] * v0 + r_cam_to_icrs[i, 1, a] * v1 + r_cam_to_icrs[i, 2, a] * v2
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def select_near_detector(xy, in_front, n_path_samples, n_cols, n_rows, margin_px):
    """Keep the stars whose path comes within ``margin_px`` of the detector; their paths and visibility.

    Parameters
    ----------
    xy : ndarray, shape (P, K, 2)
        Pixel positions (column, row) of K candidates at the ``P = N S`` instants, px.
    in_front : ndarray of bool, shape (P, K)
        Z > 0 at each instant.
    n_path_samples : int
        S.
    n_cols, n_rows : int
        Detector size, px.
    margin_px : float
        Edge margin, px (>= 0).

    Returns
    -------
    keep : ndarray of int64, shape (M,)
        Columns of ``xy`` kept, increasing: a star is kept when it is in front and inside the detector grown by
        the margin at one instant at least.
    xy_path : ndarray, shape (N, S, M, 2)
    visible : ndarray of bool, shape (N, M)
        In front over the whole exposure and, at the mid instant, on the detector (outer pixel edges).
    """
    n_p, k_n = in_front.shape
    xs = np.empty((n_p, k_n))
    ys = np.empty((n_p, k_n))
    for i in range(n_p):
        for k in range(k_n):
            xs[i, k] = xy[i, k, 0]
            ys[i, k] = xy[i, k, 1]
    return _select_planar(xs, ys, in_front, n_path_samples, n_cols, n_rows, margin_px)


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _select_planar(xs, ys, in_front, n_path_samples, n_cols, n_rows, margin_px):
    """:func:`select_near_detector` on the columns ``xs`` and rows ``ys`` (P, K) held apart."""
    n_p, k_n = in_front.shape
    s = n_path_samples
    n = n_p // s
    lo_x, hi_x = -0.5 - margin_px, n_cols - 0.5 + margin_px
    lo_y, hi_y = -0.5 - margin_px, n_rows - 0.5 + margin_px
    keep = np.empty(k_n, dtype=np.int64)
    m = 0
    for k in range(k_n):
        for i in range(n_p):
            x, y = xs[i, k], ys[i, k]
            if in_front[i, k] and x >= lo_x and x <= hi_x and y >= lo_y and y <= hi_y:
                keep[m] = k
                m += 1
                break
    keep = keep[:m].copy()
    xy_path = np.empty((n, s, m, 2))
    visible = np.empty((n, m), dtype=np.bool_)
    for e in range(n):
        for t in range(s):  # row by row: contiguous stores
            i = e * s + t
            for j in range(m):
                k = keep[j]
                xy_path[e, t, j, 0] = xs[i, k]
                xy_path[e, t, j, 1] = ys[i, k]
        for j in range(m):
            k = keep[j]
            front = True
            for t in range(s):
                front = front and in_front[e * s + t, k]
            x, y = xy_path[e, s // 2, j, 0], xy_path[e, s // 2, j, 1]
            visible[e, j] = front and x >= -0.5 and x <= n_cols - 0.5 and y >= -0.5 and y <= n_rows - 0.5
    return keep, xy_path, visible


@njit(cache=True, no_cfunc_wrapper=True, error_model="numpy")
def project_scene(r_cam_to_icrs, vectors, index, focal_length_mm, k1_per_mm2, pixel_size_mm, cx_px, cy_px,
                  n_path_samples, n_cols, n_rows, margin_px, cos_rot=1.0, sin_rot=0.0):
    """Every candidate star at every instant through the pinhole with radial distortion, then
    :func:`select_near_detector`.

    Pinhole (:mod:`startracker.optics`): ``x' = f X/Z, y' = f Y/Z`` (mm), ``δ = k1 (x'² + y'²)``,
    ``col = cx + x' (1 + δ) / p, row = cy + y' (1 + δ) / p``; in front when ``Z > 1e-12 |v|``. A detector rotated in
    its plane by θ about the principal point (a 3CMOS channel, :class:`startracker.color.ChannelCamera`) then has
    ``(col, row) = pp + (d_col cos θ + d_row sin θ, −d_col sin θ + d_row cos θ)`` with ``d`` the offsets from ``pp``
    (``cos_rot = 1``, ``sin_rot = 0``: no rotation, skipped).

    Parameters
    ----------
    r_cam_to_icrs : ndarray, shape (P, 3, 3)
    vectors : ndarray, shape (n_catalog, 3)
        Unit ICRS directions.
    index : ndarray of int64, shape (K,)
        Candidate rows of ``vectors``.
    focal_length_mm, k1_per_mm2, pixel_size_mm : float
        Focal length (mm), radial distortion (1/mm²), pixel pitch (mm).
    cx_px, cy_px : float
        Principal point (column, row), px.
    n_path_samples, n_cols, n_rows, margin_px
        As :func:`select_near_detector`.
    cos_rot, sin_rot : float
        The detector's in-plane rotation θ.

    Returns
    -------
    keep, xy_path, visible
        As :func:`select_near_detector` (``keep`` indexes ``index``).
    """
    n_p = r_cam_to_icrs.shape[0]
    k_n = index.shape[0]
    vx = np.empty(k_n)
    vy = np.empty(k_n)
    vz = np.empty(k_n)
    for k in range(k_n):
        vx[k], vy[k], vz[k] = vectors[index[k], 0], vectors[index[k], 1], vectors[index[k], 2]
    # columns and rows in separate planes and error_model="numpy" (no zero-division branch: Z is never 0 here, the
    # same IEEE operations, so the same bits): the loop over the stars then runs in vector registers
    xs = np.empty((n_p, k_n))
    ys = np.empty((n_p, k_n))
    in_front = np.empty((n_p, k_n), dtype=np.bool_)
    f_px = focal_length_mm / pixel_size_mm
    k1_px = k1_per_mm2 * focal_length_mm * focal_length_mm  # δ = k1 f² (X² + Y²) / Z²
    rotate = cos_rot != 1.0 or sin_rot != 0.0
    for i in range(n_p):
        r00, r10, r20 = r_cam_to_icrs[i, 0, 0], r_cam_to_icrs[i, 1, 0], r_cam_to_icrs[i, 2, 0]
        r01, r11, r21 = r_cam_to_icrs[i, 0, 1], r_cam_to_icrs[i, 1, 1], r_cam_to_icrs[i, 2, 1]
        r02, r12, r22 = r_cam_to_icrs[i, 0, 2], r_cam_to_icrs[i, 1, 2], r_cam_to_icrs[i, 2, 2]
        xr = xs[i]
        yr = ys[i]
        fr = in_front[i]
        for k in range(k_n):
            x = r00 * vx[k] + r10 * vy[k] + r20 * vz[k]
            y = r01 * vx[k] + r11 * vy[k] + r21 * vz[k]
            z = r02 * vx[k] + r12 * vy[k] + r22 * vz[k]
            front = (z > 0.0) & (z * z > 1e-24 * (x * x + y * y + z * z))  # Z > 1e-12 |v|
            fr[k] = front
            inv_z = 1.0 / (z if front else 1.0)
            u = x * inv_z
            w = y * inv_z
            g = f_px * (1.0 + k1_px * (u * u + w * w))
            xr[k] = u * g
            yr[k] = w * g
        if rotate:
            for k in range(k_n):
                dx = xr[k]
                dy = yr[k]
                xr[k] = cx_px + (dx * cos_rot + dy * sin_rot)
                yr[k] = cy_px + (-dx * sin_rot + dy * cos_rot)
        else:
            for k in range(k_n):
                xr[k] = xr[k] + cx_px
                yr[k] = yr[k] + cy_px
    return _select_planar(xs, ys, in_front, n_path_samples, n_cols, n_rows, margin_px)


@njit(cache=True, no_cfunc_wrapper=True)
def scene_frame(t_samples, q_samples, t_first, start_steps, path_steps, instants, q_cam_to_body, r_cam_to_body,
                n_path_samples, vectors_by_z, z_sorted,
                z_order, vectors, hip, vmag, bv, half_diag_rad, focal_length_px, focal_length_mm, k1_per_mm2,
                pixel_size_mm, cx_px, cy_px, n_cols, n_rows, margin_px, cos_rot, sin_rot, r_cam_to_icrs):
    """A pinhole camera's frame from a sampled attitude history, in one call: the path instants, then
    :func:`interpolate_attitudes` at them, :func:`camera_frames`, the cone search of the catalog around the mean
    boresight, then :func:`project_scene` and the catalog fields of the kept stars.

    The cone's half-angle is ``min(half_diag_rad + drift + (margin_px + 2) / focal_length_px + 1e-6, π)`` (the
    detector's corners, the boresight's motion over the frame and the margin), the chord test widened by 1e-12
    relative as :meth:`startracker.catalog.StarCatalog.cone_search` does.

    Parameters
    ----------
    t_samples : ndarray, shape (T,)
        Strictly increasing sample times of the attitude history, s (T >= 2).
    q_samples : ndarray, shape (T, 4)
        Its non-zero body-to-ICRS attitudes.
    t_first : float
        Start of the first exposure, s.
    start_steps : ndarray, shape (N,)
        Exposure starts after ``t_first``, s.
    path_steps : ndarray, shape (S,)
        Path instants after an exposure's start, s: path instant ``(i, j)`` is ``(t_first + start_steps[i]) +
        path_steps[j]`` (numpy's ``np.add.outer(t_first + start_steps, path_steps)``, the same sums).
    instants : ndarray, shape (N S + N,)
        Output: the ``P = N S`` path instants, exposure-major, then the N mid instants (``j = S // 2``), s.
    q_cam_to_body : ndarray, shape (4,)
    r_cam_to_body : ndarray, shape (3, 3)
    n_path_samples : int
        S (odd).
    vectors_by_z, z_sorted, z_order : ndarray, shapes (C, 3), (C,), (C,) int64
        The catalog's z index (:attr:`startracker.catalog.StarCatalog.z_index`).
    vectors : ndarray, shape (C, 3)
        Unit ICRS directions (catalog order).
    hip : ndarray of int64, shape (C,)
    vmag, bv : ndarray, shape (C,)
    half_diag_rad : float
        Angle from the boresight to the farthest detector corner, rad.
    focal_length_px : float
    focal_length_mm, k1_per_mm2, pixel_size_mm, cx_px, cy_px, n_cols, n_rows, margin_px, cos_rot, sin_rot
        As :func:`project_scene`.
    r_cam_to_icrs : ndarray, shape (P, 3, 3) or (0, 3, 3)
        Output: the camera-to-ICRS rotations at the path instants (:func:`camera_frames`), written when it has ``P``
        rows (a caller that needs them passes the room; one without, an empty array).

    Returns
    -------
    q_mid : ndarray, shape (2, N, 4)
        ``q_mid[0]``: body-to-ICRS attitudes at the mid instants; ``q_mid[1]``: camera-to-ICRS ones.
    rows : ndarray of int64, shape (2, M)
        ``rows[0]``: catalog rows of the kept stars, increasing; ``rows[1]``: their HIP numbers.
    mags : ndarray, shape (2, M)
        ``mags[0]``: their vmag; ``mags[1]``: their B−V.
    xy_path : ndarray, shape (N, S, M, 2)
    visible : ndarray of bool, shape (N, M)

    Notes
    -----
    The outputs of one kind share one array (each row a C-contiguous view for the caller's fields): every array
    handed back to Python costs a boxing of its own.
    """
    n_exp = start_steps.shape[0]
    p = n_exp * n_path_samples
    for i in range(n_exp):
        start = t_first + start_steps[i]
        for j in range(n_path_samples):
            instants[i * n_path_samples + j] = start + path_steps[j]
        instants[p + i] = instants[i * n_path_samples + n_path_samples // 2]
    q_bw = interpolate_attitudes(t_samples, q_samples, instants[:p])
    r_cw, q_cam_mid, centre, drift = camera_frames(q_bw, q_cam_to_body, r_cam_to_body, n_path_samples)
    radius = half_diag_rad + drift + (margin_px + 2.0) / focal_length_px + 1e-6
    if math.pi < radius:  # min(radius, π) as Python's min has it
        radius = math.pi
    idx = cone_search_angle(vectors_by_z, z_sorted, z_order, centre, radius)
    keep, xy_path, visible = project_scene(r_cw, vectors, idx, focal_length_mm, k1_per_mm2, pixel_size_mm, cx_px,
                                           cy_px, n_path_samples, n_cols, n_rows, margin_px, cos_rot, sin_rot)
    m = keep.shape[0]
    rows = np.empty((2, m), dtype=np.int64)
    mags = np.empty((2, m))
    for j in range(m):
        c = idx[keep[j]]
        rows[0, j] = c
        rows[1, j] = hip[c]
        mags[0, j] = vmag[c]
        mags[1, j] = bv[c]
    s = n_path_samples
    n = q_bw.shape[0] // s
    q_mid = np.empty((2, n, 4))
    for e in range(n):
        for a in range(4):
            q_mid[0, e, a] = q_bw[e * s + s // 2, a]
            q_mid[1, e, a] = q_cam_mid[e, a]
    if r_cam_to_icrs.shape[0] == r_cw.shape[0]:  # element by element: a slice assignment compiles a shape check
        for k in range(r_cw.shape[0]):
            for i in range(3):
                for j in range(3):
                    r_cam_to_icrs[k, i, j] = r_cw[k, i, j]
    return q_mid, rows, mags, xy_path, visible


@njit(cache=True, no_cfunc_wrapper=True)
def min_image_speed(flow, r_cam_to_body, omega_body):
    """Slowest star-image speed over a grid of detector points, px/s: ``min_i |J_i R_cam_to_bodyᵀ ω|``.

    Parameters
    ----------
    flow : ndarray, shape (P, 2, 3)
        Pinhole motion-field matrices at the grid points (:func:`startracker.scene.image_flow_matrices`):
        ``xy_dot = J ω_cam``, px per rad.
    r_cam_to_body : ndarray, shape (3, 3)
        Camera mounting.
    omega_body : ndarray, shape (3,)
        Body-frame angular velocity, rad/s (finite).

    Returns
    -------
    float
        The least speed, px/s (inf for P = 0).
    """
    w0, w1, w2 = omega_body[0], omega_body[1], omega_body[2]
    c0 = r_cam_to_body[0, 0] * w0 + r_cam_to_body[1, 0] * w1 + r_cam_to_body[2, 0] * w2
    c1 = r_cam_to_body[0, 1] * w0 + r_cam_to_body[1, 1] * w1 + r_cam_to_body[2, 1] * w2
    c2 = r_cam_to_body[0, 2] * w0 + r_cam_to_body[1, 2] * w1 + r_cam_to_body[2, 2] * w2
    best = np.inf
    for i in range(flow.shape[0]):
        x = flow[i, 0, 0] * c0 + flow[i, 0, 1] * c1 + flow[i, 0, 2] * c2
        y = flow[i, 1, 0] * c0 + flow[i, 1, 1] * c1 + flow[i, 1, 2] * c2
        v = math.sqrt(x * x + y * y)
        if v < best:
            best = v
    return best


@njit(cache=True, no_cfunc_wrapper=True)
def no_overlap_exposures(speed_px_s, frame_period_s, exposure_s, psf_sigma_px, min_gap_sigma, n_max):
    """Exposures per frame by the no-overlap rule: ``clip(floor(v T / (v τ + k σ)), 1, n_max)`` (the largest N whose
    evenly spread exposures leave ``k σ`` px between the end of one streak of a star and the start of the next;
    a relative 1e-12 upwards so that an exact quotient is not floored one below).

    Parameters
    ----------
    speed_px_s : float
        Image speed v, px/s (>= 0; :func:`min_image_speed`).
    frame_period_s, exposure_s : float
        T and τ, s (0 < τ <= T).
    psf_sigma_px : float
        σ, px (> 0).
    min_gap_sigma : float
        k (> 0).
    n_max : int
        Upper bound (>= 1).

    Returns
    -------
    int
    """
    n = math.floor(speed_px_s * frame_period_s / (speed_px_s * exposure_s + min_gap_sigma * psf_sigma_px)
                   * (1 + 1e-12))
    return min(max(n, 1), n_max)
