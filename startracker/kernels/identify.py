"""Compiled core of lost-in-space identification: sky grid, matching, verification, the pyramid loop.

Plain numba functions on float64 / int64 arrays, no input checks (the callers in
:mod:`startracker.identify` validate once). Deterministic: no randomness anywhere.

Sky grid. The navigation stars are binned in a uniform ``g × g × g`` grid over the cube ``[-1, 1]³``
that holds the unit sphere (``cell_start[c] : cell_start[c + 1]`` indexes ``cell_stars``, the stars of
cell ``c`` in ascending order). A two-nearest-neighbour query within a chord radius visits only the
cells that the query ball touches (eight at most when the radius is below half a cell): the compiled
stand-in for a k-d tree query, with the same answer.

Pyramid. :func:`pyramid_search` is the whole hypothesis loop of
:func:`startracker.identify.pyramid.identify_pyramid`: Mortari's smart triad order, the three pair
windows looked up on the k-vector, the catalog triangles joined on the apex star, the handedness test,
the fourth star, the verification with the false-alarm rule and the misfit test, and the ambiguity rule
between verified attitudes of one triad (documented in :mod:`startracker.identify.verification`).
The candidate source is data: each detection ``p`` may only stand for the catalog stars whose
``star_key`` lies in ``[key_lo[p], key_hi[p]]`` (all stars when the interval is infinite), so a method
with one more per-star feature (colour) reuses the same loop. Window sizes (which triads are cheapest,
which side is the widest) come from a coarse cumulative count of the pair angles
(:func:`pair_count_table`, a few tens of kB that stay in cache) rather than from the large k-vector.

One call per frame. :func:`identify_pyramid_detections` takes the raw detections to labels and attitude:
:func:`prepare_detections` (order, detector bounds, unit vectors, duplicates, angle tables), the
:func:`smart_triads` of the pool, :func:`pyramid_search` and :func:`solve_identified` (final least
squares and labels), so :func:`startracker.identify.identify` spends one call (four compiled ones) on a
pyramid frame.

The module is over 600 lines because it holds the compiled core of every identification method: the
pyramid loop, the shared verification and least squares, the vote table and the frame tables call the same
inner helpers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.algebra import det3, inv_transpose3, quat_from_rotation
from startracker.kernels.kvector import stable_argsort_into
from startracker.kernels.optics import unproject_pinhole

__all__ = [
    "rotate_all",
    "triple_product",
    "admissible",
    "window_count",
    "cast_votes",
    "prepare_detections",
    "GRID_CELLS",
    "build_sky_grid",
    "grid_cell",
    "nearest_two",
    "select_matches",
    "rotation_svd",
    "solve_attitude",
    "solve_identified",
    "binom_tail",
    "poisson_tail",
    "required_matches",
    "triangle_false_rate",
    "kvector_range",
    "refine_matches",
    "verify_hypothesis",
    "pyramid_search",
    "smart_triads",
    "identify_pyramid_detections",
    "pair_count_table",
    "window_estimate",
    "cdf_at",
]

GRID_CELLS = 64  # cells per axis of the sky grid: 0.031 rad (1.8°) per cell

STATUS_OK = 0
STATUS_AMBIGUOUS = 1
STATUS_NONE = 2


def build_sky_grid(vectors: np.ndarray, g: int = GRID_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """Bin unit vectors into the sky grid (numpy, once per database).

    Parameters
    ----------
    vectors : ndarray, shape (N, 3)
        Unit vectors (ICRS).
    g : int
        Cells per axis.

    Returns
    -------
    cell_start : ndarray of int32, shape (g³ + 1,)
    cell_stars : ndarray of int32, shape (N,)
        Star indices sorted by cell (ascending within a cell). int32 halves the memory the random
        look-ups of a frame touch.
    """
    v = np.asarray(vectors, dtype=np.float64).reshape(-1, 3)
    ijk = np.clip(((v + 1.0) * (0.5 * g)).astype(np.int64), 0, g - 1)
    cell = (ijk[:, 0] * g + ijk[:, 1]) * g + ijk[:, 2]
    cell_stars = np.argsort(cell, kind="stable").astype(np.int32)
    cell_start = np.zeros(g**3 + 1, dtype=np.int32)
    np.cumsum(np.bincount(cell, minlength=g**3), out=cell_start[1:])
    return cell_start, cell_stars


@njit(cache=True, no_cfunc_wrapper=True)
def grid_cell(x: float, g: int) -> int:
    """Cell index along one axis of a coordinate in [-1, 1]."""
    c = int((x + 1.0) * (0.5 * g))
    if c < 0:
        return 0
    if c > g - 1:
        return g - 1
    return c


@njit(cache=True, no_cfunc_wrapper=True)
def nearest_two(w, nav, cell_start, cell_stars, g, max_chord, dist, idx):
    """Two nearest navigation stars of each direction within a chord radius (k-d tree semantics).

    Parameters
    ----------
    w : ndarray, shape (n, 3)
        Directions (ICRS, unit).
    nav : ndarray, shape (N, 3)
        Navigation star unit vectors.
    cell_start, cell_stars : ndarray of int32
        Sky grid of ``nav`` (:func:`build_sky_grid`).
    g : int
        Cells per axis.
    max_chord : float
        Search radius as a chord (a distance on the unit sphere's embedding).
    dist : ndarray, shape (n, 2)
        Output chord distances, ascending; ``inf`` where fewer stars lie closer than ``max_chord``.
    idx : ndarray of int64, shape (n, 2)
        Output star indices; ``N`` where ``dist`` is ``inf``.
    """
    n_nav = nav.shape[0]
    r2max = max_chord * max_chord
    for q in range(w.shape[0]):
        x, y, z = w[q, 0], w[q, 1], w[q, 2]
        d0 = np.inf
        d1 = np.inf
        i0 = n_nav
        i1 = n_nav
        ax0, ax1 = grid_cell(x - max_chord, g), grid_cell(x + max_chord, g)
        ay0, ay1 = grid_cell(y - max_chord, g), grid_cell(y + max_chord, g)
        az0, az1 = grid_cell(z - max_chord, g), grid_cell(z + max_chord, g)
        for cx in range(ax0, ax1 + 1):
            for cy in range(ay0, ay1 + 1):
                base = (cx * g + cy) * g
                for t in range(cell_start[base + az0], cell_start[base + az1 + 1]):
                    s = cell_stars[t]
                    dx = nav[s, 0] - x
                    dy = nav[s, 1] - y
                    dz = nav[s, 2] - z
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 >= r2max:
                        continue
                    if d2 < d0 or (d2 == d0 and s < i0):
                        d1, i1 = d0, i0
                        d0, i0 = d2, s
                    elif d2 < d1 or (d2 == d1 and s < i1):
                        d1, i1 = d2, s
        dist[q, 0] = math.sqrt(d0) if i0 < n_nav else np.inf
        dist[q, 1] = math.sqrt(d1) if i1 < n_nav else np.inf
        idx[q, 0] = i0
        idx[q, 1] = i1


@njit(cache=True, no_cfunc_wrapper=True)
def select_matches(dist, idx, chord):
    """Unambiguous one-to-one matches from a two-nearest-neighbour query.

    A detection matches its nearest star when that star is within ``chord`` and the second-nearest is
    at least ``chord`` farther; a star claimed by several detections keeps the nearest (the lower
    detection index on a tie).

    Parameters
    ----------
    dist : ndarray, shape (n, 2)
    idx : ndarray of int64, shape (n, 2)
    chord : float

    Returns
    -------
    det, nav : ndarray of int64, shape (m,)
        Matched detections (ascending) and their stars.
    d : ndarray, shape (m,)
        Chord distances.
    """
    n = dist.shape[0]
    cand = np.empty(n, dtype=np.int64)
    m = 0
    for q in range(n):
        if dist[q, 0] <= chord and dist[q, 1] > dist[q, 0] + chord:
            cand[m] = q
            m += 1
    keep = np.ones(m, dtype=np.bool_)
    for a in range(m):
        qa = cand[a]
        for b in range(m):
            if a == b:
                continue
            qb = cand[b]
            if idx[qb, 0] == idx[qa, 0]:
                if dist[qb, 0] < dist[qa, 0] or (dist[qb, 0] == dist[qa, 0] and qb < qa):
                    keep[a] = False
                    break
    cnt = 0
    for a in range(m):
        if keep[a]:
            cnt += 1
    det = np.empty(cnt, dtype=np.int64)
    nav = np.empty(cnt, dtype=np.int64)
    d = np.empty(cnt)
    t = 0
    for a in range(m):
        if keep[a]:
            det[t] = cand[a]
            nav[t] = idx[cand[a], 0]
            d[t] = dist[cand[a], 0]
            t += 1
    return det, nav, d


@njit(cache=True, no_cfunc_wrapper=True)
def rotation_svd(b, r):
    """Unweighted Wahba rotation ``R`` with ``r ≈ R b`` (SVD, proper).

    Parameters
    ----------
    b : ndarray, shape (m, 3)
        Measured unit vectors (camera frame).
    r : ndarray, shape (m, 3)
        Reference unit vectors (ICRS).

    Returns
    -------
    ndarray, shape (3, 3)
        Camera -> ICRS rotation matrix.
    """
    att = np.zeros((3, 3))
    for t in range(b.shape[0]):
        for i in range(3):
            for j in range(3):
                att[i, j] += r[t, i] * b[t, j]
    # The orthogonal polar factor of att is U Vᵀ; scaled Newton (Higham) reaches it in a few 3×3
    # inversions, far cheaper than a LAPACK SVD. A reflection (det < 0) or a singular matrix takes the SVD.
    x = att.copy()
    det0 = det3(x)
    if det0 > 0.0:
        for _ in range(30):
            d = det3(x)
            if not d > 0.0:
                break
            xi = inv_transpose3(x, d)  # X⁻ᵀ
            # Scaling by |det|^(-1/3) speeds up the first steps on ill-conditioned (narrow-field) matrices.
            gam = (abs(d) ** (-1.0 / 3.0)) if d != 0 else 1.0
            delta = 0.0
            for i in range(3):
                for j in range(3):
                    xn = 0.5 * (gam * x[i, j] + xi[i, j] / gam)
                    delta = max(delta, abs(xn - x[i, j]))
                    x[i, j] = xn
            if delta < 1e-15:
                return x
    u, _, vt = np.linalg.svd(att)
    rot = u @ vt
    det = (rot[0, 0] * (rot[1, 1] * rot[2, 2] - rot[1, 2] * rot[2, 1])
           - rot[0, 1] * (rot[1, 0] * rot[2, 2] - rot[1, 2] * rot[2, 0])
           + rot[0, 2] * (rot[1, 0] * rot[2, 1] - rot[1, 1] * rot[2, 0]))
    if det < 0:
        for i in range(3):
            u[i, 2] = -u[i, 2]
        rot = u @ vt
    return rot


@njit(cache=True, no_cfunc_wrapper=True)
def solve_attitude(b, r, sigma_rad):
    """Final least squares: Wahba by SVD with equal weights, QUEST covariance, RMS residual.

    The same solution as :func:`startracker.attitude.solve_wahba_single` with a scalar ``sigma_rad``.

    Parameters
    ----------
    b : ndarray, shape (m, 3)
        Measured unit vectors (camera frame), m >= 2.
    r : ndarray, shape (m, 3)
        Catalog unit vectors (ICRS).
    sigma_rad : float
        1σ angular noise of a measured direction, rad.

    Returns
    -------
    ok : bool
        False when the vectors are parallel (attitude not observable).
    q : ndarray, shape (4,)
        Camera -> ICRS quaternion (w, x, y, z).
    rms_rad : float
        RMS angle between the rotated measurements and the catalog.
    cov : ndarray, shape (3, 3)
        Attitude error covariance, rad² (camera frame).
    """
    rot = rotation_svd(b, r)
    m = b.shape[0]
    w1 = 1.0 / (sigma_rad * sigma_rad)
    info = np.zeros((3, 3))
    for t in range(m):
        for i in range(3):
            for j in range(3):
                info[i, j] -= w1 * b[t, i] * b[t, j]
    for i in range(3):
        info[i, i] += w1 * m
    ev = np.linalg.eigvalsh(info)
    if ev[0] <= 1e-10 * max(w1 * m, 1e-300):
        q_none = np.zeros(4)
        q_none[0] = 1.0
        cov_none = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                cov_none[i, j] = np.inf
        return False, q_none, np.inf, cov_none
    acc = 0.0
    for t in range(m):
        rb0 = rot[0, 0] * b[t, 0] + rot[0, 1] * b[t, 1] + rot[0, 2] * b[t, 2]
        rb1 = rot[1, 0] * b[t, 0] + rot[1, 1] * b[t, 1] + rot[1, 2] * b[t, 2]
        rb2 = rot[2, 0] * b[t, 0] + rot[2, 1] * b[t, 1] + rot[2, 2] * b[t, 2]
        cx = rb1 * r[t, 2] - rb2 * r[t, 1]
        cy = rb2 * r[t, 0] - rb0 * r[t, 2]
        cz = rb0 * r[t, 1] - rb1 * r[t, 0]
        a = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), rb0 * r[t, 0] + rb1 * r[t, 1] + rb2 * r[t, 2])
        acc += a * a
    return True, quat_from_rotation(rot), math.sqrt(acc / m), np.linalg.inv(info)


@njit(cache=True, no_cfunc_wrapper=True)
def solve_identified(v, nav, nav_hip, index, det, nav_idx, n_input, sigma_rad):
    """Final least squares on a verified match set, and the HIP label of every input detection.

    Parameters
    ----------
    v : ndarray, shape (n, 3)
        Usable detections (camera frame).
    nav : ndarray, shape (N, 3)
        Navigation stars (ICRS).
    nav_hip : ndarray of int64, shape (N,)
        Their HIP numbers.
    index : ndarray of int64, shape (n,)
        Input row of each usable detection.
    det, nav_idx : ndarray of int64, shape (m,)
        Detection ``det[t]`` is navigation star ``nav_idx[t]``.
    n_input : int
        Input detections.
    sigma_rad : float
        1σ angular noise of a measured direction, rad.

    Returns
    -------
    ok, q, rms_rad, cov
        As :func:`solve_attitude` on the matched pairs.
    star_ids : ndarray of int64, shape (n_input,)
        HIP number of each input detection, −1 for the unmatched.
    """
    m = det.shape[0]
    b = np.empty((m, 3))
    r = np.empty((m, 3))
    star_ids = np.empty(n_input, dtype=np.int64)
    for t in range(n_input):
        star_ids[t] = -1
    for t in range(m):
        for ax in range(3):
            b[t, ax] = v[det[t], ax]
            r[t, ax] = nav[nav_idx[t], ax]
        star_ids[index[det[t]]] = nav_hip[nav_idx[t]]
    ok, q, rms, cov = solve_attitude(b, r, sigma_rad)
    return ok, q, rms, cov, star_ids


@njit(cache=True, no_cfunc_wrapper=True)
def binom_tail(n, p, e):
    """P(Binomial(n, p) >= e), summed from the tail term upwards (accurate for tiny p)."""
    if e <= 0:
        return 1.0
    if e > n:
        return 0.0
    if p >= 1.0:
        return 1.0
    if p <= 0.0:
        return 0.0
    q = 1.0 - p
    term = math.exp(math.lgamma(n + 1) - math.lgamma(e + 1) - math.lgamma(n - e + 1) + e * math.log(p)
                    + (n - e) * math.log(q))
    total = term
    ratio = p / q
    x = e
    while x < n and term > 1e-6 * total:
        term *= (n - x) / (x + 1) * ratio
        total += term
        x += 1
    return min(total, 1.0)


@njit(cache=True, no_cfunc_wrapper=True)
def poisson_tail(mu, k):
    """P(Poisson(mu) >= k)."""
    if k <= 0:
        return 1.0
    term = math.exp(-mu)
    cdf = 0.0
    for x in range(k):
        cdf += term
        term *= mu / (x + 1)
    return max(0.0, 1.0 - cdf)


@njit(cache=True, no_cfunc_wrapper=True)
def required_matches(lam, n_det, p, false_alarm):
    """Smallest ``3 + e`` matched detections with ``λ · P(Binomial(n_det − 3, p) >= e) <= false_alarm``.

    ``e >= 1`` whenever a fourth detection exists; ``n_det + 1`` when no count is convincing.
    """
    n_other = n_det - 3
    e = 1 if n_other >= 1 else 0
    while e <= n_other:
        if lam * binom_tail(n_other, p, e) <= false_alarm:
            return 3 + e
        e += 1
    return n_det + 1


@njit(cache=True, no_cfunc_wrapper=True)
def triangle_false_rate(ang, tol, i, j, k, n_stars, clumping):
    """Expected number of wrong catalog triangles matching detections (i, j, k) (``λ``).

    Parameters
    ----------
    ang, tol : ndarray, shape (m, m)
        Inter-star angles and their window half-widths, rad.
    i, j, k : int
    n_stars : float
        Navigation stars.
    clumping : float
        ``⟨ρ³⟩ / ⟨ρ⟩³`` of the catalog.
    """
    a, b, c = ang[i, j], ang[i, k], ang[j, k]
    eps = (tol[i, j] * tol[i, k] * tol[j, k]) ** (1.0 / 3.0)
    s = 0.5 * (a + b + c)
    area2 = max(s * (s - a) * (s - b) * (s - c), 0.0)
    area = math.sqrt(area2)
    radius = a * b * c / (4.0 * area) if area > 0 else np.inf
    radius = min(radius, 10.0)
    return 2.0 * n_stars**3 * eps**3 * radius / math.pi * clumping


@njit(cache=True, no_cfunc_wrapper=True)
def kvector_range(s, kk, a1, b1, lo, hi):
    """Exact index range of the ascending values ``s`` inside ``[lo, hi]`` (k-vector look-up, paper 000).

    Parameters
    ----------
    s : ndarray, shape (M,)
        Sorted values.
    kk : ndarray of int64, shape (M,)
        The k-vector ``K`` (``kk[i - 1]`` is the paper's ``K(i)``).
    a1, b1 : float
        The line ``h(i) = a1 i + b1``.

    Returns
    -------
    start, stop : int
    """
    n = s.shape[0]
    ia = min(max(int(math.floor((lo - b1) / a1)), 1), n)
    ib = min(max(int(math.ceil((hi - b1) / a1)), 1), n)
    start = kk[ia - 1]
    stop = kk[ib - 1]
    while start > 0 and s[start - 1] >= lo:
        start -= 1
    while start < n and s[start] < lo:
        start += 1
    while stop < n and s[stop] <= hi:
        stop += 1
    while stop > 0 and s[stop - 1] > hi:
        stop -= 1
    return start, max(stop, start)


@njit(cache=True, no_cfunc_wrapper=True)
def rotate_all(rot, v):
    """``v @ rot.T``: rows of ``v`` (n, 3) rotated by ``rot`` (3, 3)."""
    out = np.empty_like(v)
    for t in range(v.shape[0]):
        for i in range(3):
            out[t, i] = rot[i, 0] * v[t, 0] + rot[i, 1] * v[t, 1] + rot[i, 2] * v[t, 2]
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def refine_matches(v, nav, cell_start, cell_stars, g, det, navm, chord, n_req, max_rounds, stable_fit, dist, idx):
    """Refit the attitude on every match and match again until the matches stop changing.

    Returns
    -------
    ok : bool
        False when the matches fall below ``n_req`` or never settle.
    rot : ndarray, shape (3, 3)
    det, navm, dm : ndarray
        Final matches and their chord distances; ``dist`` / ``idx`` hold the last query.
    """
    rot = np.zeros((3, 3))
    for i in range(3):
        rot[i, i] = 1.0
    dm = np.empty(0)
    converged = False
    for _ in range(max_rounds):
        b = np.empty((len(det), 3))
        r = np.empty((len(det), 3))
        for t in range(len(det)):
            for a in range(3):  # element copies: a row assignment compiles numba's shape-check machinery
                b[t, a] = v[det[t], a]
                r[t, a] = nav[navm[t], a]
        rot = rotation_svd(b, r)
        nearest_two(rotate_all(rot, v), nav, cell_start, cell_stars, g, 3.0 * chord, dist, idx)
        det2, nav2, dm = select_matches(dist, idx, chord)
        if len(det2) < n_req:
            return False, rot, det2, nav2, dm
        same = len(det2) == len(det)
        if same:
            for t in range(len(det)):
                if det2[t] != det[t] or nav2[t] != navm[t]:
                    same = False
                    break
        if same:
            converged = True
            break
        grown = False
        if len(det) >= stable_fit and len(det2) - len(det) <= max(2, len(det) // 10):
            # every old match kept with the same star, only new ones added
            grown = True
            t2 = 0
            for t in range(len(det)):
                while t2 < len(det2) and det2[t2] < det[t]:
                    t2 += 1
                if t2 >= len(det2) or det2[t2] != det[t] or nav2[t2] != navm[t]:
                    grown = False
                    break
        det, navm = det2, nav2
        if grown:
            converged = True
            break
    return converged, rot, det, navm, dm


@njit(cache=True, no_cfunc_wrapper=True)
def verify_hypothesis(v, nav, cell_start, cell_stars, g, det0, nav0, rot0, have_rot, lam, false_alarm,
                      match_tol_rad, dens_eff_per_sr, max_rounds, stable_fit, misfit_p):
    """Verification of one hypothesis (see :mod:`startracker.identify.verification`).

    Parameters
    ----------
    v : ndarray, shape (n, 3)
        Detections, camera frame.
    nav, cell_start, cell_stars, g
        Navigation stars and their sky grid.
    det0, nav0 : ndarray of int64, shape (h,)
        The hypothesis: detection ``det0[t]`` is star ``nav0[t]``.
    rot0 : ndarray, shape (3, 3)
        Hypothesis attitude when ``have_rot``.
    have_rot : bool
    lam : float
        Expected number of wrong hypotheses of this kind.
    false_alarm : float
    match_tol_rad : float
        Verification radius.
    dens_eff_per_sr : float
        Star density a wrong attitude meets.
    max_rounds, stable_fit : int
        Refinement rounds; matches above which an attitude that only adds matches is final.
    misfit_p : float
        Near misses less likely than this under a correct attitude reject it.

    Returns
    -------
    ok : bool
    rot : ndarray, shape (3, 3)
    det, nav_out : ndarray of int64
    n_req : int
    rms_rad : float
    """
    n = v.shape[0]
    tol = match_tol_rad
    p_tol = min(1.0, dens_eff_per_sr * math.pi * tol * tol)
    empty = np.empty(0, dtype=np.int64)
    n_req = required_matches(lam, n, p_tol, false_alarm)
    if n_req > n:
        return False, rot0, empty, empty, n_req, np.inf
    chord = 2.0 * math.sin(tol / 2.0)
    if have_rot:
        rot = rot0
    else:
        b = np.empty((len(det0), 3))
        r = np.empty((len(det0), 3))
        for t in range(len(det0)):
            for a in range(3):  # element copies: a row assignment compiles numba's shape-check machinery
                b[t, a] = v[det0[t], a]
                r[t, a] = nav[nav0[t], a]
        rot = rotation_svd(b, r)
    dist = np.empty((n, 2))
    idx = np.empty((n, 2), dtype=np.int64)
    nearest_two(rotate_all(rot, v), nav, cell_start, cell_stars, g, 3.0 * chord, dist, idx)
    det, navm, dm = select_matches(dist, idx, chord)
    if len(det) < n_req:
        return False, rot, empty, empty, n_req, np.inf
    ok, rot, det, navm, dm = refine_matches(v, nav, cell_start, cell_stars, g, det, navm, chord, n_req, max_rounds,
                                            stable_fit, dist, idx)
    if not ok:
        return False, rot, empty, empty, n_req, np.inf
    if len(det) < n:
        # Growth: an attitude fitted on a tight group of stars can miss the far ones by several radii
        # (a poorly observed roll). Match once with a radius four times wider, refit, and refine again
        # with the normal radius; keep the result only if it holds more matches.
        wide = 4.0 * chord
        dist_w = np.empty((n, 2))
        idx_w = np.empty((n, 2), dtype=np.int64)
        nearest_two(rotate_all(rot, v), nav, cell_start, cell_stars, g, 3.0 * wide, dist_w, idx_w)
        det_w, nav_w, _ = select_matches(dist_w, idx_w, wide)
        if len(det_w) > len(det):
            dist_g = np.empty((n, 2))
            idx_g = np.empty((n, 2), dtype=np.int64)
            ok_g, rot_g, det_g, nav_g, dm_g = refine_matches(v, nav, cell_start, cell_stars, g, det_w, nav_w, chord,
                                                             n_req, max_rounds, stable_fit, dist_g, idx_g)
            if ok_g and len(det_g) > len(det):
                rot, det, navm, dm = rot_g, det_g, nav_g, dm_g
                for q in range(n):
                    for c in range(2):
                        dist[q, c] = dist_g[q, c]
                        idx[q, c] = idx_g[q, c]
    near = 0
    for q in range(n):
        if dist[q, 0] > chord and dist[q, 0] <= 3.0 * chord:
            near += 1
    if near >= 2:
        p3 = min(1.0, dens_eff_per_sr * math.pi * 9.0 * tol * tol)
        expected = (n - len(det)) * (p3 - p_tol)
        # np.int64: typing first sees the loop's literal 0 and would compile the callee for it too
        if poisson_tail(expected, np.int64(near)) < misfit_p:
            return False, rot, empty, empty, n_req, np.inf
    acc = 0.0
    for t in range(len(dm)):
        acc += dm[t] * dm[t]
    rms = math.sqrt(acc / len(dm))
    return True, rot, det, navm, n_req, rms


@njit(cache=True, no_cfunc_wrapper=True)
def triple_product(a, b, c):
    """a · (b × c) of three 3-vectors."""
    return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))


@njit(cache=True, no_cfunc_wrapper=True)
def admissible(star_key, key_lo, key_hi, p, s):
    """Whether star ``s`` may stand for detection ``p`` under the candidate filter."""
    k = star_key[s]
    return k >= key_lo[p] and k <= key_hi[p]


@njit(cache=True, no_cfunc_wrapper=True)
def window_count(s_ang, kk, a1, b1, first, second, star_key, key_lo, key_hi, filtered, ang, tol, p, q):
    """Catalog pair candidates (both orientations) in the window of detections (p, q), and those kept."""
    start, stop = kvector_range(s_ang, kk, a1, b1, ang[p, q] - tol[p, q], ang[p, q] + tol[p, q])
    if not filtered:
        return 2 * (stop - start), 2 * (stop - start)
    kept = 0
    for t in range(start, stop):
        a = first[t]
        b = second[t]
        if admissible(star_key, key_lo, key_hi, p, a) and admissible(star_key, key_lo, key_hi, q, b):
            kept += 1
        if admissible(star_key, key_lo, key_hi, p, b) and admissible(star_key, key_lo, key_hi, q, a):
            kept += 1
    return 2 * (stop - start), kept


def pair_count_table(sorted_angles: np.ndarray, n_bins: int = 8192) -> tuple[np.ndarray, float]:
    """Coarse cumulative count of sorted pair angles, for window-size estimates that stay in cache.

    Parameters
    ----------
    sorted_angles : ndarray, shape (M,)
        Ascending pair angles, rad.
    n_bins : int
        Bins over ``[0, max angle]``.

    Returns
    -------
    cdf : ndarray, shape (n_bins + 1,)
        ``cdf[b]`` = number of angles below ``b · bin_rad`` (float64).
    bin_rad : float
        Bin width, rad.
    """
    top = float(sorted_angles[-1]) if len(sorted_angles) else 1.0
    bin_rad = max(top, 1e-12) * (1.0 + 1e-9) / n_bins
    cdf = np.searchsorted(sorted_angles, np.arange(n_bins + 1) * bin_rad, side="left").astype(np.float64)
    return cdf, bin_rad


@njit(cache=True, no_cfunc_wrapper=True)
def cdf_at(cdf, bin_rad, x):
    """The count table of :func:`pair_count_table` at angle ``x`` (linear inside a bin)."""
    nb = cdf.shape[0] - 1
    u = x / bin_rad
    if u <= 0.0:
        return 0.0
    if u >= nb:
        return cdf[nb]
    b = int(u)
    return cdf[b] + (u - b) * (cdf[b + 1] - cdf[b])


@njit(cache=True, no_cfunc_wrapper=True)
def window_estimate(cdf, bin_rad, lo, hi):
    """Estimated catalog pair candidates (both orientations) with angles in ``[lo, hi]``, from
    :func:`pair_count_table`."""
    return 2.0 * (cdf_at(cdf, bin_rad, hi) - cdf_at(cdf, bin_rad, lo))


@njit(cache=True, no_cfunc_wrapper=True)
def pyramid_search(v, ang, tol, triads, cheap_first, pool, nav, s_ang, kk, a1, b1, first, second, cell_start, cell_stars,
                   g, count_cdf, count_bin_rad, star_key, key_lo, key_hi, filtered, rate, clumping, dens_eff_per_sr, match_tol_rad,
                   false_alarm, max_rounds, stable_fit, misfit_p):
    """The pyramid hypothesis loop (see the module docstring), up to the first triad that verifies.

    Parameters
    ----------
    v : ndarray, shape (n, 3)
        Detections (camera frame, brightest first).
    ang, tol : ndarray, shape (m, m)
        Inter-star angles of the first ``m >= pool`` detections and their window half-widths, rad.
    triads : ndarray of int64, shape (T, 3)
        Detection triads in the order to try (Mortari's smart order).
    cheap_first : int
        Block size within which triads are tried cheapest first (0: the given order).
    pool : int
        Size of the hypothesis pool (fourth stars are looked for among detections ``0 .. max(pool, 4)-1``).
    nav : ndarray, shape (N, 3)
        Navigation stars.
    s_ang, kk, a1, b1
        Star-pair catalog: sorted angles (rad) and their k-vector.
    first, second : ndarray of int64, shape (M,)
        Brighter and dimmer star of each pair.
    cell_start, cell_stars, g
        Sky grid of ``nav``.
    count_cdf, count_bin_rad
        Coarse cumulative count of the pair angles (:func:`pair_count_table`): the window sizes that order
        the triads and pick the apex, read without touching the large pair arrays.
    star_key : ndarray, shape (N,)
        Per-star value of the candidate filter.
    key_lo, key_hi : ndarray, shape (n,)
        Admissible interval of each detection.
    filtered : bool
        False: every star is admissible (the filter arrays are not read).
    rate : ndarray, shape (n,)
        Factor on ``λ`` per detection (the filter's pass rate; ones without a filter).
    clumping, dens_eff_per_sr : float
        Database statistics of the false-alarm rule.
    match_tol_rad, false_alarm : float
    max_rounds, stable_fit, misfit_p
        Verification constants.

    Returns
    -------
    status : int
        0 verified, 1 ambiguous (two attitudes of one triad verified), 2 nothing verified.
    det, nav_idx : ndarray of int64
        The matches of the verified attitude.
    n_req : int
    n_hyp : int
        Hypotheses verified.
    rot : ndarray, shape (3, 3)
    rms_rad : float
    counts : ndarray of int64, shape (2,)
        Catalog pair candidates (both orientations) in the windows looked up, and those the filter kept.
    """
    n = v.shape[0]
    n_nav = nav.shape[0]
    empty = np.empty(0, dtype=np.int64)
    ambiguous = False
    n_hyp = 0
    counts = np.zeros(2, dtype=np.int64)
    # Allocations spelt np.empty / np.zeros with the element types other kernels use: each other spelling
    # (np.full, a bool matrix of zeros, np.array of a list) compiles one more numba function.
    seen = np.zeros((ang.shape[0], ang.shape[0]), dtype=np.int64)
    # int32 work arrays: the join's random accesses then stay in the first-level caches.
    stamp = np.empty(n_nav, dtype=np.int32)
    for s in range(n_nav):
        stamp[s] = -1
    head = np.empty(n_nav, dtype=np.int32)
    chord = 2.0 * math.sin(match_tol_rad / 2.0)
    n4 = min(max(pool, 4), n)
    dist = np.empty((n, 2))
    idx = np.empty((n, 2), dtype=np.int64)
    b3 = np.empty((3, 3))
    r3 = np.empty((3, 3))
    w1 = np.empty((1, 3))
    d1 = np.empty((1, 2))
    i1 = np.empty((1, 2), dtype=np.int64)
    order = np.empty(triads.shape[0], dtype=np.int64)
    for t in range(triads.shape[0]):
        order[t] = t
    # Window sizes (both orientations) from the coarse count table: a look-up in the large k-vector costs a
    # cache miss or two per window, and most windows of the pool are never joined.
    m_ang = ang.shape[0]
    cnt = np.zeros((m_ang, m_ang))
    for p in range(min(pool, m_ang)):
        for q in range(p + 1, min(pool, m_ang)):
            c = window_estimate(count_cdf, count_bin_rad, ang[p, q] - tol[p, q], ang[p, q] + tol[p, q])
            cnt[p, q] = c
            cnt[q, p] = c
    if cheap_first > 0:
        # Cheapest triads first: the cost of a triad is the size of its two shortest windows (the join
        # runs on them). Within blocks of ``cheap_first`` triads of the smart order, so a false star still
        # cannot spoil a long run.
        cost = np.empty(triads.shape[0])
        for t in range(triads.shape[0]):
            x, y, z = cnt[triads[t, 0], triads[t, 1]], cnt[triads[t, 0], triads[t, 2]], cnt[triads[t, 1], triads[t, 2]]
            cost[t] = x + y + z - max(x, max(y, z))
        block = np.empty(cheap_first)
        sub = np.empty(cheap_first, dtype=np.int64)
        for b0 in range(0, triads.shape[0], cheap_first):
            nb = min(b0 + cheap_first, triads.shape[0]) - b0
            for u in range(nb):
                block[u] = cost[b0 + u]
            stable_argsort_into(block[:nb], sub[:nb])
            for u in range(nb):
                order[b0 + u] = b0 + sub[u]
    for tt in range(triads.shape[0]):
        t = order[tt]
        i, j, k = triads[t, 0], triads[t, 1], triads[t, 2]
        # Apex opposite the widest window: the join then runs on the two shortest lists.
        if filtered:
            c_ij, n_ij = window_count(s_ang, kk, a1, b1, first, second, star_key, key_lo, key_hi, filtered, ang,
                                      tol, i, j)
            c_ik, n_ik = window_count(s_ang, kk, a1, b1, first, second, star_key, key_lo, key_hi, filtered, ang,
                                      tol, i, k)
            c_jk, n_jk = window_count(s_ang, kk, a1, b1, first, second, star_key, key_lo, key_hi, filtered, ang,
                                      tol, j, k)
            if seen[i, j] == 0:
                seen[i, j] = 1
                counts[0] += c_ij
                counts[1] += n_ij
            if seen[i, k] == 0:
                seen[i, k] = 1
                counts[0] += c_ik
                counts[1] += n_ik
            if seen[j, k] == 0:
                seen[j, k] = 1
                counts[0] += c_jk
                counts[1] += n_jk
            kij, kik, kjk = float(n_ij), float(n_ik), float(n_jk)
        else:
            kij, kik, kjk = cnt[i, j], cnt[i, k], cnt[j, k]
        if kij >= kik and kij >= kjk:
            i, j, k = k, i, j
        elif kik >= kjk:
            i, j, k = j, i, k
        # Adjacency of window (i, j): stars a that may be s_i, each with its partners b (s_j).
        st, sp = kvector_range(s_ang, kk, a1, b1, ang[i, j] - tol[i, j], ang[i, j] + tol[i, j])
        m_ij = 2 * (sp - st)
        nxt = np.empty(m_ij, dtype=np.int32)
        partner = np.empty(m_ij, dtype=np.int32)
        e = 0
        for u in range(st, sp):
            for o in range(2):
                a = first[u] if o == 0 else second[u]
                b = second[u] if o == 0 else first[u]
                if filtered and not (admissible(star_key, key_lo, key_hi, i, a)
                                     and admissible(star_key, key_lo, key_hi, j, b)):
                    continue
                if stamp[a] != t:
                    stamp[a] = t
                    head[a] = -1
                partner[e] = b
                nxt[e] = head[a]
                head[a] = e
                e += 1
        if e == 0:
            continue
        th, tw = ang[j, k], tol[j, k]
        cos_hi = math.cos(max(th - tw, 0.0))
        cos_lo = math.cos(min(th + tw, math.pi))
        s_meas = triple_product(v[i], v[j], v[k])
        # Window (i, k): a (s_i) with c (s_k); join on a, check (b, c) and handedness.
        st2, sp2 = kvector_range(s_ang, kk, a1, b1, ang[i, k] - tol[i, k], ang[i, k] + tol[i, k])
        hyp = np.empty((16, 3), dtype=np.int64)
        h = 0
        for u in range(st2, sp2):
            for o in range(2):
                a = first[u] if o == 0 else second[u]
                c = second[u] if o == 0 else first[u]
                if stamp[a] != t:
                    continue
                if filtered and not (admissible(star_key, key_lo, key_hi, i, a)
                                     and admissible(star_key, key_lo, key_hi, k, c)):
                    continue
                x = head[a]
                while x >= 0:
                    b = partner[x]
                    x = nxt[x]
                    cbc = nav[b, 0] * nav[c, 0] + nav[b, 1] * nav[c, 1] + nav[b, 2] * nav[c, 2]
                    if cbc > cos_hi or cbc < cos_lo:
                        continue
                    s_cat = triple_product(nav[a], nav[b], nav[c])
                    if (s_cat > 0) != (s_meas > 0):
                        continue
                    if h == hyp.shape[0]:
                        grown = np.empty((2 * h, 3), dtype=np.int64)
                        for row in range(h):
                            for col in range(3):
                                grown[row, col] = hyp[row, col]
                        hyp = grown
                    hyp[h, 0], hyp[h, 1], hyp[h, 2] = a, b, c
                    h += 1
        if h == 0:
            continue
        lam = triangle_false_rate(ang, tol, i, j, k, float(n_nav), clumping) * rate[i] * rate[j] * rate[k]
        for ax in range(3):  # element copies: row assignments compile numba's shape-check machinery
            b3[0, ax], b3[1, ax], b3[2, ax] = v[i, ax], v[j, ax], v[k, ax]
        n_ver = 0
        ver_n = np.empty(h, dtype=np.int64)
        ver_rms = np.empty(h)
        ver_rot = np.empty((h, 3, 3))
        ver_det = np.empty((h, n), dtype=np.int64)
        ver_nav = np.empty((h, n), dtype=np.int64)
        ver_req = np.empty(h, dtype=np.int64)
        for hh in range(h):
            a, b, c = hyp[hh, 0], hyp[hh, 1], hyp[hh, 2]
            for ax in range(3):
                r3[0, ax], r3[1, ax], r3[2, ax] = nav[a, ax], nav[b, ax], nav[c, ax]
            rot = rotation_svd(b3, r3)
            if n > 3:
                # The pyramid: a fourth detection of the pool pointing at a catalog star.
                found = False
                for rr in range(n4):
                    if rr == i or rr == j or rr == k:
                        continue
                    for ax in range(3):
                        w1[0, ax] = rot[ax, 0] * v[rr, 0] + rot[ax, 1] * v[rr, 1] + rot[ax, 2] * v[rr, 2]
                    nearest_two(w1, nav, cell_start, cell_stars, g, 3.0 * chord, d1, i1)
                    if d1[0, 0] <= chord:
                        found = True
                        break
                if not found:
                    continue
            n_hyp += 1
            det3 = np.empty(3, dtype=np.int64)
            nav3 = np.empty(3, dtype=np.int64)
            det3[0], det3[1], det3[2] = i, j, k
            nav3[0], nav3[1], nav3[2] = a, b, c
            ok, rot_v, det_v, nav_v, req_v, rms_v = verify_hypothesis(
                v, nav, cell_start, cell_stars, g, det3, nav3, rot, True, lam, false_alarm, match_tol_rad,
                dens_eff_per_sr, max_rounds, stable_fit, misfit_p)
            if ok:
                ver_n[n_ver] = len(det_v)
                ver_rms[n_ver] = rms_v
                for ax in range(3):
                    for ay in range(3):
                        ver_rot[n_ver, ax, ay] = rot_v[ax, ay]
                ver_req[n_ver] = req_v
                for col in range(len(det_v)):
                    ver_det[n_ver, col] = det_v[col]
                    ver_nav[n_ver, col] = nav_v[col]
                n_ver += 1
        if n_ver == 0:
            continue
        # best_of: most matches, then smallest residual; refuse two different attitudes.
        bi = 0
        for x in range(1, n_ver):
            if ver_n[x] > ver_n[bi] or (ver_n[x] == ver_n[bi] and ver_rms[x] < ver_rms[bi]):
                bi = x
        amb = False
        for x in range(n_ver):
            if x == bi:
                continue
            tr = 0.0
            for ax in range(3):
                for ay in range(3):
                    tr += ver_rot[bi, ay, ax] * ver_rot[x, ay, ax]
            cang = max(-1.0, min(1.0, (tr - 1.0) / 2.0))
            if math.acos(cang) > match_tol_rad:
                if ver_n[bi] - 3 < 2 * (ver_n[x] - 3) + 2:
                    amb = True
                    break
        if amb:
            ambiguous = True
            continue
        nb = ver_n[bi]
        return (STATUS_OK, ver_det[bi, :nb].copy(), ver_nav[bi, :nb].copy(), ver_req[bi], n_hyp,
                ver_rot[bi].copy(), ver_rms[bi], counts)
    status = STATUS_AMBIGUOUS if ambiguous else STATUS_NONE
    rot_none = np.zeros((3, 3))
    for ax in range(3):
        rot_none[ax, ax] = 1.0
    return status, empty, empty, 0, n_hyp, rot_none, np.inf, counts


@njit(cache=True, no_cfunc_wrapper=True)
def smart_triads(n, max_triads):
    """The first ``max_triads`` triads of Mortari's "smart" order over ``n`` stars.

    ``for dj in 1 .. n-2: for dk in 1 .. n-dj-1: for i in 0 .. n-dj-dk-1: (i, i+dj, i+dj+dk)``.

    Returns
    -------
    ndarray of int64, shape (T, 3)
    """
    total = n * (n - 1) * (n - 2) // 6 if n >= 3 else 0
    m = min(total, max_triads)
    out = np.empty((m, 3), dtype=np.int64)
    t = 0
    for dj in range(1, n - 1):
        for dk in range(1, n - dj):
            for i in range(0, n - dj - dk):
                if t == m:
                    return out
                out[t, 0], out[t, 1], out[t, 2] = i, i + dj, i + dj + dk
                t += 1
    return out


STATUS_FEW = 3
STATUS_PARALLEL = 4
STATUS_RESIDUAL = 5


def identify_pyramid_detections(xy, intensities, have_intensities, mag_zero_point, width, height, focal_length_mm,
                                k1_per_mm2, pixel_size_mm, ppx, ppy, n_angles, dup_cos, pair_sigma_rad, floor_rad,
                                aberration_scale, max_stars, max_triads, cheap_first, nav, s_ang, kk, a1, b1, first,
                                second, cell_start, cell_stars, g, count_cdf, count_bin_rad, nav_hip, clumping,
                                dens_eff_per_sr, sigma_rad, match_tol_rad, false_alarm, max_rounds, stable_fit,
                                misfit_p):
    """Pyramid lost-in-space on one frame of detections: :func:`prepare_detections`, the :func:`smart_triads` of
    the pool, :func:`pyramid_search` (no candidate filter) and :func:`solve_identified`.

    Plain Python over four compiled calls (a few microseconds more than one): compiled as one function it would
    carry the whole tree of compiled code below it once more, about 4 s of the first compilation.

    Parameters
    ----------
    xy ... aberration_scale
        As :func:`prepare_detections`.
    max_stars : int
        Largest hypothesis pool (the pool is the ``min(n, max_stars, n_angles)`` brightest usable detections).
    max_triads, cheap_first : int
        Triads tried, and the block size of the cheapest-first order (:func:`pyramid_search`).
    nav ... dens_eff_per_sr
        The database, as :func:`pyramid_search` takes it; ``nav_hip`` (N,) int64: HIP numbers.
    sigma_rad, match_tol_rad, false_alarm : float
        Centroid noise as an angle, verification radius, false-alarm limit.
    max_rounds, stable_fit, misfit_p
        Verification constants.

    Returns
    -------
    code : int
        0 identified, 1 ambiguous, 2 nothing verified, 3 fewer than 3 usable detections, 4 final attitude
        not observable (parallel vectors), 5 final residual above the verification radius.
    star_ids : ndarray of int64, shape (K,)
        HIP number of each input detection, −1 when unidentified (all −1 unless code 0).
    q : ndarray, shape (4,)
        Camera -> ICRS quaternion (w, x, y, z) of the final least squares (identity unless code 0).
    cov : ndarray, shape (3, 3)
        Its covariance, rad² (inf unless code 0).
    n_matched, n_req, n_hyp, n_usable : int
        Matches, matches the false-alarm rule asked for, hypotheses verified, usable detections.
    rms_rad : float
        RMS residual of the matches (inf unless code 0).
    """
    k = xy.shape[0]
    index, v, mag, ang, tol = prepare_detections(xy, intensities, have_intensities, mag_zero_point, width, height,
                                                 focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy, n_angles,
                                                 dup_cos, pair_sigma_rad, floor_rad, aberration_scale)
    n = int(index.shape[0])
    none_ids = np.full(k, -1, dtype=np.int64)
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    cov0 = np.full((3, 3), np.inf)
    if n < 3:
        return STATUS_FEW, none_ids, q0, cov0, 0, 0, 0, n, np.inf
    pool = min(n, max_stars, int(ang.shape[0]))
    triads = smart_triads(pool, max_triads)
    no_key = np.zeros(1)
    status, det, nav_idx, n_req, n_hyp, rot, rms, counts = pyramid_search(
        v, ang, tol, triads, cheap_first, pool, nav, s_ang, kk, a1, b1, first, second, cell_start, cell_stars, g,
        count_cdf, count_bin_rad, no_key, no_key, no_key, False, np.ones(n), clumping, dens_eff_per_sr,
        match_tol_rad, false_alarm, max_rounds, stable_fit, misfit_p)
    if status != STATUS_OK:
        return status, none_ids, q0, cov0, 0, 0, n_hyp, n, np.inf
    ok, q, rms_f, cov, star_ids = solve_identified(v, nav, nav_hip, index, det, nav_idx, k, sigma_rad)
    if not ok:
        return STATUS_PARALLEL, none_ids, q0, cov0, 0, n_req, n_hyp, n, np.inf
    if rms_f > match_tol_rad:
        return STATUS_RESIDUAL, none_ids, q0, cov0, 0, n_req, n_hyp, n, np.inf
    return STATUS_OK, star_ids, q, cov, int(det.shape[0]), n_req, n_hyp, n, rms_f


@njit(cache=True, no_cfunc_wrapper=True)
def cast_votes(ang, tol, pool, s_ang, kk, a1, b1, first, second, first_mag, second_mag, mag, mag_tol, use_mag,
               n_nav):
    """Geometric-voting table (see :mod:`startracker.identify.voting`).

    Parameters
    ----------
    ang, tol : ndarray, shape (m, m)
        Inter-star angles and window half-widths of the first ``m >= pool`` detections, rad.
    pool : int
    s_ang, kk, a1, b1
        Star-pair catalog angles (sorted, rad) and their k-vector.
    first, second : ndarray of int, shape (M,)
    first_mag, second_mag : ndarray of float32, shape (M,)
        V magnitudes of the pair stars.
    mag : ndarray, shape (n,)
        Measured magnitudes (read only when ``use_mag``).
    mag_tol : float
        Magnitude-difference tolerance of the brightness-ordered votes.
    use_mag : bool
    n_nav : int

    Returns
    -------
    ndarray of int64, shape (pool, n_nav)
    """
    votes = np.zeros((pool, n_nav), dtype=np.int64)
    for p in range(pool):
        for q in range(p + 1, pool):
            start, stop = kvector_range(s_ang, kk, a1, b1, ang[p, q] - tol[p, q], ang[p, q] + tol[p, q])
            if use_mag:
                dm = mag[p] - mag[q]
                for u in range(start, stop):
                    a = first[u]
                    b = second[u]
                    dv = float(first_mag[u]) - float(second_mag[u])
                    if abs(dm - dv) <= mag_tol:
                        votes[p, a] += 1
                        votes[q, b] += 1
                    if abs(dm + dv) <= mag_tol:
                        votes[p, b] += 1
                        votes[q, a] += 1
            else:
                for u in range(start, stop):
                    a = first[u]
                    b = second[u]
                    votes[p, a] += 1
                    votes[p, b] += 1
                    votes[q, a] += 1
                    votes[q, b] += 1
    return votes


@njit(cache=True, no_cfunc_wrapper=True)
def prepare_detections(xy, intensities, have_intensities, mag_zero_point, width, height, focal_length_mm,
                       k1_per_mm2, pixel_size_mm, ppx, ppy, n_angles, dup_cos, pair_sigma_rad, floor_rad,
                       aberration_scale):
    """A frame's detections ready for identification: order, usable points, unit vectors, angle tables.

    Detections are ordered brightest first (stable) when intensities are given, points off the detector
    (beyond the outer pixel edges) dropped, the rest turned into camera-frame unit vectors
    (:func:`startracker.kernels.optics.unproject_pinhole`), a detection closer than the duplicate radius
    to a brighter one dropped, and the inter-star angles and pair windows of the first ``n_angles``
    kept detections tabulated.

    Parameters
    ----------
    xy : ndarray, shape (K, 2)
        Detections (column, row), px.
    intensities : ndarray, shape (K,)
        Positive intensities (read only when ``have_intensities``).
    have_intensities : bool
    mag_zero_point : float
        Measured magnitude ``mag_zero_point − 2.5 log10(intensity)``.
    width, height : int
        Detector size, px.
    focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy : float
        Camera model (see :func:`startracker.kernels.optics.unproject_pinhole`).
    n_angles : int
        Tabulate the first ``m = min(n, n_angles)`` kept detections.
    dup_cos : float
        Cosine of the duplicate radius.
    pair_sigma_rad : float
        ``pair_sigmas · √2 · σ`` of an inter-star angle, rad.
    floor_rad : float
        Added in quadrature to the window half-width, rad.
    aberration_scale : float
        Relative widening of a window with its angle.

    Returns
    -------
    index : ndarray of int64, shape (n,)
        Row in ``xy`` of each kept detection, brightest first.
    v : ndarray, shape (n, 3)
        Camera-frame unit vectors.
    mag : ndarray, shape (n,)
        Measured magnitudes (zeros without intensities).
    ang : ndarray, shape (m, m)
        Angles between kept detections, rad.
    tol : ndarray, shape (m, m)
        Window half-widths, rad.
    """
    k = xy.shape[0]
    order = np.empty(k, dtype=np.int64)
    if have_intensities:
        neg = np.empty(k)
        for t in range(k):
            neg[t] = -intensities[t]
        stable_argsort_into(neg, order)
    else:
        for t in range(k):
            order[t] = t
    on = np.empty(k, dtype=np.int64)
    n_on = 0
    for t in range(k):
        r = order[t]
        x, y = xy[r, 0], xy[r, 1]
        if x >= -0.5 and x <= width - 0.5 and y >= -0.5 and y <= height - 0.5:
            on[n_on] = r
            n_on += 1
    pts = np.empty((n_on, 2))
    for t in range(n_on):
        pts[t, 0] = xy[on[t], 0]
        pts[t, 1] = xy[on[t], 1]
    u = unproject_pinhole(pts, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy)
    keep = np.ones(n_on, dtype=np.bool_)
    n = n_on
    for j in range(1, n_on):
        for i in range(j):
            if u[i, 0] * u[j, 0] + u[i, 1] * u[j, 1] + u[i, 2] * u[j, 2] > dup_cos:
                keep[j] = False
                n -= 1
                break
    index = np.empty(n, dtype=np.int64)
    v = np.empty((n, 3))
    mag = np.zeros(n)
    c = 0
    for t in range(n_on):
        if keep[t]:
            index[c] = on[t]
            v[c, 0], v[c, 1], v[c, 2] = u[t, 0], u[t, 1], u[t, 2]
            if have_intensities:
                mag[c] = mag_zero_point - 2.5 * math.log10(intensities[on[t]])
            c += 1
    m = min(n, n_angles)
    ang = np.zeros((m, m))
    tol = np.empty((m, m))
    base = math.sqrt(pair_sigma_rad * pair_sigma_rad + floor_rad * floor_rad)
    for a in range(m):
        tol[a, a] = base
        for b in range(a + 1, m):
            # atan2 of |p × q| and p · q: accurate at small angles too
            cx = v[a, 1] * v[b, 2] - v[a, 2] * v[b, 1]
            cy = v[a, 2] * v[b, 0] - v[a, 0] * v[b, 2]
            cz = v[a, 0] * v[b, 1] - v[a, 1] * v[b, 0]
            dot = v[a, 0] * v[b, 0] + v[a, 1] * v[b, 1] + v[a, 2] * v[b, 2]
            th = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), dot)
            ang[a, b] = th
            ang[b, a] = th
            w = base + aberration_scale * th
            tol[a, b] = w
            tol[b, a] = w
    return index, v, mag, ang, tol
