"""Wahba kernels: attitude problems by the SVD method with the QUEST covariance, compiled, float64 arrays, no checks.

The checked API and the method's description are in :mod:`startracker.attitude`. One problem is
:func:`solve_wahba_one`: the Wahba optimum by Davenport's q-method (the 4×4 eigenproblem equivalent to the SVD
solution of the attitude profile matrix ``B = Σ w r bᵀ``: Newton on its characteristic polynomial, the
eigenvector from the adjugate), the Fisher information ``Σ w (I - b bᵀ)`` and its closed-form inverse (no LAPACK
call: a few hundred flops per problem);
:func:`solve_wahba_batch` loops it over many problems and the tracker's grouping kernel
(:mod:`startracker.kernels.track`) calls it once per exposure instant.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.algebra import det3_entries, quat_normalize_canonical, quat_to_rotation

__all__ = ["davenport_quaternion", "symmetric_min_eigenvalue", "solve_wahba_one", "solve_wahba_batch", "RAD_TO_ARCSEC"]

RAD_TO_ARCSEC = 180.0 / np.pi * 3600.0


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _cofactor4(m, i, j):
    """Cofactor (i, j) of a 4×4 matrix: (-1)^(i+j) times the minor without row i and column j."""
    r0, r1, r2 = (1, 2, 3) if i == 0 else ((0, 2, 3) if i == 1 else ((0, 1, 3) if i == 2 else (0, 1, 2)))
    c0, c1, c2 = (1, 2, 3) if j == 0 else ((0, 2, 3) if j == 1 else ((0, 1, 3) if j == 2 else (0, 1, 2)))
    d = det3_entries(m[r0, c0], m[r0, c1], m[r0, c2], m[r1, c0], m[r1, c1], m[r1, c2], m[r2, c0], m[r2, c1], m[r2, c2])
    return -d if (i + j) % 2 else d


@njit(cache=True, no_cfunc_wrapper=True)
def davenport_quaternion(s, q):
    """Davenport's q-method: the quaternion maximising ``Σ w r · (A(q) b)`` from ``S = Σ w b rᵀ`` (normalised by Σ w).

    The largest eigenvalue λ of Horn's traceless symmetric 4×4 matrix N(S) by Newton's method on
    ``det(λI − N) = λ⁴ + c₂λ² − c₃λ + c₄`` from λ = 1 (an upper bound for weights summing to 1: the iteration
    decreases monotonically onto the largest root), then the eigenvector as the largest column of
    ``adj(N − λI)`` (of rank one, ∝ q qᵀ), which has no singular attitude, refined by one inverse-iteration step
    ``adj(N − ρI) q`` at its Rayleigh quotient ρ.

    Parameters
    ----------
    s : ndarray, shape (3, 3)
        ``S[a, c] = Σ w b_a r_c / Σ w`` (source b: measured, target r: reference).
    q : ndarray, shape (4,)
        Output: unit canonical ``q_meas_to_ref`` (w, x, y, z).
    """
    n = np.empty((4, 4))
    n[0, 0] = s[0, 0] + s[1, 1] + s[2, 2]
    n[1, 1] = s[0, 0] - s[1, 1] - s[2, 2]
    n[2, 2] = -s[0, 0] + s[1, 1] - s[2, 2]
    n[3, 3] = -s[0, 0] - s[1, 1] + s[2, 2]
    n[0, 1] = n[1, 0] = s[1, 2] - s[2, 1]
    n[0, 2] = n[2, 0] = s[2, 0] - s[0, 2]
    n[0, 3] = n[3, 0] = s[0, 1] - s[1, 0]
    n[1, 2] = n[2, 1] = s[0, 1] + s[1, 0]
    n[1, 3] = n[3, 1] = s[2, 0] + s[0, 2]
    n[2, 3] = n[3, 2] = s[1, 2] + s[2, 1]
    c2 = 0.0  # sum of the principal 2×2 minors
    for i in range(4):
        for j in range(i + 1, 4):
            c2 += n[i, i] * n[j, j] - n[i, j] * n[i, j]
    c3 = 0.0  # sum of the principal 3×3 minors = trace of the adjugate
    for i in range(4):
        c3 += _cofactor4(n, i, i)
    c4 = 0.0  # det N, along the first row
    row0 = np.int64(0)  # an int64, not a literal 0: the callee compiles once, not once per literal
    for j in range(4):
        c4 += n[0, j] * _cofactor4(n, row0, j)
    lam = 1.0
    for _ in range(50):
        l2 = lam * lam
        p = (l2 + c2) * l2 - c3 * lam + c4
        dp = (4.0 * l2 + 2.0 * c2) * lam - c3
        if dp <= 0.0:
            break
        step = p / dp
        lam -= step
        if abs(step) <= 1e-16 * abs(lam):
            break
    m = n.copy()
    for i in range(4):
        m[i, i] -= lam
    best, best_v = row0, -1.0
    for i in range(4):
        d = abs(_cofactor4(m, i, i))
        if d > best_v:
            best, best_v = i, d
    q0 = np.empty(4)
    for i in range(4):
        q0[i] = _cofactor4(m, i, best)
    # The polynomial's root is only good to ~eps/gap: one inverse-iteration step at the Rayleigh quotient
    # (good to ~eps) brings the eigenvector to the ~eps/gap of a backward-stable eigensolver.
    nq = math.sqrt(q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] + q0[3] * q0[3])
    for i in range(4):
        q0[i] /= nq
    rq = 0.0
    for i in range(4):
        for j in range(4):
            rq += q0[i] * n[i, j] * q0[j]
    for i in range(4):
        for j in range(4):
            m[i, j] = n[i, j] - (rq if i == j else 0.0)
    for i in range(4):
        acc = 0.0
        for j in range(4):
            acc += _cofactor4(m, j, i) * q0[j]  # adj(M) = cofactor matrix transposed
        q[i] = acc
    if not q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] > 0.0:
        for i in range(4):  # M exactly singular at the Rayleigh quotient: q0 is already the eigenvector
            q[i] = q0[i]
    quat_normalize_canonical(q)


@njit(cache=True, no_cfunc_wrapper=True)
def symmetric_min_eigenvalue(a):
    """Smallest eigenvalue of a symmetric 3×3 matrix (closed form, Smith 1961), shape (3, 3) -> float."""
    p1 = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
    qm = (a[0, 0] + a[1, 1] + a[2, 2]) / 3.0
    d0, d1, d2 = a[0, 0] - qm, a[1, 1] - qm, a[2, 2] - qm
    p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1
    if p2 == 0.0:
        return qm
    p = math.sqrt(p2 / 6.0)
    rdet = det3_entries(d0 / p, a[0, 1] / p, a[0, 2] / p, a[1, 0] / p, d1 / p, a[1, 2] / p, a[2, 0] / p, a[2, 1] / p,
                 d2 / p) / 2.0
    rdet = min(1.0, max(-1.0, rdet))
    phi = math.acos(rdet) / 3.0
    return qm + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)


@njit(cache=True, no_cfunc_wrapper=True)
def solve_wahba_one(b, r, w, m, q, cov, ang):
    """One Wahba problem: optimal attitude, QUEST covariance and RMS residual.

    The attitude maximises ``Σ w r · (A b)``, the optimum the SVD method gives (``A = U diag(1, 1, det U det V)
    Vᵀ`` of ``B = Σ w r bᵀ``), found here by Davenport's q-method (:func:`davenport_quaternion`). The covariance
    is the inverse of the Fisher information ``Σ w (I - b bᵀ)`` (adjugate over determinant); the problem fails
    when the information's smallest eigenvalue is below 1e-10 of ``Σ w`` (parallel or fewer than two vectors).

    Parameters
    ----------
    b : ndarray, shape (K, 3)
        Unit measured directions (camera/body frame).
    r : ndarray, shape (K, 3)
        Unit reference (ICRS) directions.
    w : ndarray, shape (K,)
        Weights ``σ⁻²`` of the pairs, rad⁻².
    m : ndarray of bool, shape (K,)
        Which pairs take part.
    q : ndarray, shape (4,)
        Output: ``q_meas_to_ref`` (identity if the problem fails), canonical.
    cov : ndarray, shape (3, 3)
        Output: attitude error covariance in the measurement frame, rad² (infinite diagonal if it fails).
    ang : ndarray, shape (K,)
        Output: residual angle of each used pair, ``atan2(|A b × r|, A b · r)``, rad (-1 for unused pairs).

    Returns
    -------
    residual_rms_arcsec : float
        RMS angle between the rotated measured and the reference directions of the used pairs.
    ok : bool
        At least two used, non-parallel directions.
    """
    k = b.shape[0]
    s = np.zeros((3, 3))  # S[a, c] = Σ w b_a r_c (source b, target r)
    bb = np.zeros((3, 3))
    wsum = 0.0
    n_used = 0
    for j in range(k):
        if m[j]:
            wj = w[j]
            wsum += wj
            n_used += 1
            for a in range(3):
                wb = wj * b[j, a]
                for c in range(3):
                    s[a, c] += wb * r[j, c]
                    bb[a, c] += wb * b[j, c]
    info = np.empty((3, 3))
    for a in range(3):
        for c in range(3):
            info[a, c] = (wsum if a == c else 0.0) - bb[a, c]
    ok = n_used >= 2 and symmetric_min_eigenvalue(info) > 1e-10 * max(wsum, 1e-300)
    rot = np.empty((3, 3))
    if ok:
        det = det3_entries(info[0, 0], info[0, 1], info[0, 2], info[1, 0], info[1, 1], info[1, 2], info[2, 0], info[2, 1],
                    info[2, 2])
        cov[0, 0] = (info[1, 1] * info[2, 2] - info[1, 2] * info[2, 1]) / det
        cov[0, 1] = (info[0, 2] * info[2, 1] - info[0, 1] * info[2, 2]) / det
        cov[0, 2] = (info[0, 1] * info[1, 2] - info[0, 2] * info[1, 1]) / det
        cov[1, 0] = (info[1, 2] * info[2, 0] - info[1, 0] * info[2, 2]) / det
        cov[1, 1] = (info[0, 0] * info[2, 2] - info[0, 2] * info[2, 0]) / det
        cov[1, 2] = (info[0, 2] * info[1, 0] - info[0, 0] * info[1, 2]) / det
        cov[2, 0] = (info[1, 0] * info[2, 1] - info[1, 1] * info[2, 0]) / det
        cov[2, 1] = (info[0, 1] * info[2, 0] - info[0, 0] * info[2, 1]) / det
        cov[2, 2] = (info[0, 0] * info[1, 1] - info[0, 1] * info[1, 0]) / det
        for a in range(3):
            for c in range(3):
                s[a, c] /= wsum
        davenport_quaternion(s, q)
        quat_to_rotation(q, rot)
    else:
        cov[:, :] = 0.0
        for a in range(3):
            cov[a, a] = np.inf
            for c in range(3):
                rot[a, c] = 1.0 if a == c else 0.0
        q[0], q[1], q[2], q[3] = 1.0, 0.0, 0.0, 0.0
    ss = 0.0
    for j in range(k):
        if m[j]:
            a = residual_angle_rad(rot, b[j], r[j])
            ang[j] = a
            ss += a * a
        else:
            ang[j] = -1.0
    return math.sqrt(ss / max(n_used, 1)) * RAD_TO_ARCSEC, ok


@njit(cache=True, no_cfunc_wrapper=True)
def residual_angle_rad(rot, b, r):
    """Angle between ``rot @ b`` and ``r``, rad: ``atan2(|rot b × r|, rot b · r)``; b, r shape (3,), rot (3, 3)."""
    x = rot[0, 0] * b[0] + rot[0, 1] * b[1] + rot[0, 2] * b[2]
    y = rot[1, 0] * b[0] + rot[1, 1] * b[1] + rot[1, 2] * b[2]
    z = rot[2, 0] * b[0] + rot[2, 1] * b[1] + rot[2, 2] * b[2]
    cx = y * r[2] - z * r[1]
    cy = z * r[0] - x * r[2]
    cz = x * r[1] - y * r[0]
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), x * r[0] + y * r[1] + z * r[2])


@njit(cache=True, no_cfunc_wrapper=True)
def solve_wahba_batch(b, r, sigma, m):
    """B independent Wahba problems (:func:`solve_wahba_one` each).

    Parameters
    ----------
    b : ndarray, shape (B, K, 3)
        Unit measured directions (camera/body frame), float64.
    r : ndarray, shape (B, K, 3)
        Unit reference (ICRS) directions.
    sigma : ndarray, shape (B, K)
        Angular noise of each measured direction, rad, > 0.
    m : ndarray of bool, shape (B, K)
        Which pairs take part.

    Returns
    -------
    q : ndarray, shape (B, 4)
        ``q_meas_to_ref`` (identity where a problem failed).
    covariance_rad2 : ndarray, shape (B, 3, 3)
        Infinite diagonal where a problem failed.
    residual_rms_arcsec : ndarray, shape (B,)
    ok : ndarray of bool, shape (B,)
        At least two used, non-parallel vectors.
    """
    nb, k = b.shape[0], b.shape[1]
    q = np.empty((nb, 4))
    cov = np.empty((nb, 3, 3))
    rms = np.empty(nb)
    ok = np.empty(nb, dtype=np.bool_)
    w = np.empty(k)
    ang = np.empty(k)
    for i in range(nb):
        for j in range(k):
            w[j] = 1.0 / (sigma[i, j] * sigma[i, j])
        rms[i], ok[i] = solve_wahba_one(b[i], r[i], w, m[i], q[i], cov[i], ang)
    return q, cov, rms, ok
