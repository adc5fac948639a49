"""Wahba kernels: attitude problems by the SVD method with the QUEST covariance, compiled, float64 arrays, no checks.

The checked API and the method's description are in :mod:`startracker.attitude`. One problem is
:func:`solve_wahba_one` (a 3×3 SVD of the attitude profile matrix ``B = Σ w r bᵀ``, the sign fix ``det(U) det(V)``,
the Fisher information ``Σ w (I - b bᵀ)`` and its inverse); :func:`solve_wahba_batch` loops it over many problems
and the tracker's grouping kernel (:mod:`startracker.kernels.track`) calls it once per exposure instant.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["solve_wahba_one", "solve_wahba_batch", "quat_from_rotation", "RAD_TO_ARCSEC"]

RAD_TO_ARCSEC = 180.0 / np.pi * 3600.0


@njit(cache=True)
def quat_from_rotation(m, q):
    """Shepperd's method: a proper rotation matrix to the canonical unit quaternion (w, x, y, z).

    Parameters
    ----------
    m : ndarray, shape (3, 3)
        Rotation matrix (``v_ref = m @ v_meas``).
    q : ndarray, shape (4,)
        Output, written in place: first non-zero component positive.
    """
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    big = max(tr, m[0, 0], m[1, 1], m[2, 2])
    if big == tr:
        s = 2.0 * math.sqrt(1.0 + tr)
        q[0], q[1], q[2], q[3] = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif big == m[0, 0]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q[0], q[1], q[2], q[3] = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif big == m[1, 1]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q[0], q[1], q[2], q[3] = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q[0], q[1], q[2], q[3] = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = 1.0
    for i in range(4):
        if q[i] != 0.0:
            sign = 1.0 if q[i] > 0.0 else -1.0
            break
    for i in range(4):
        q[i] = sign * q[i] / n


@njit(cache=True)
def solve_wahba_one(b, r, w, m, q, cov):
    """One Wahba problem: SVD attitude, QUEST covariance and RMS residual.

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
        Output: ``q_meas_to_ref`` (identity if the problem fails).
    cov : ndarray, shape (3, 3)
        Output: attitude error covariance in the measurement frame, rad² (infinite diagonal if it fails).

    Returns
    -------
    residual_rms_arcsec : float
        RMS angle between the rotated measured and the reference directions of the used pairs.
    ok : bool
        At least two used, non-parallel directions.
    """
    k = b.shape[0]
    prof = np.zeros((3, 3))
    info = np.zeros((3, 3))
    wsum = 0.0
    n_used = 0
    for j in range(k):
        if m[j]:
            wj = w[j]
            wsum += wj
            n_used += 1
            for a in range(3):
                for c in range(3):
                    prof[a, c] += wj * r[j, a] * b[j, c]
                    info[a, c] -= wj * b[j, a] * b[j, c]
    for a in range(3):
        info[a, a] += wsum
    u, _, vt = np.linalg.svd(prof)
    d = np.linalg.det(u) * np.linalg.det(vt)
    for a in range(3):
        u[a, 2] *= d
    rot = u @ vt
    eig_min = np.linalg.eigvalsh(info)[0]
    ok = n_used >= 2 and eig_min > 1e-10 * max(wsum, 1e-300)
    if ok:
        cov[:, :] = np.linalg.inv(info)
        quat_from_rotation(rot, q)
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
            ss += residual_angle_rad(rot, b[j], r[j]) ** 2
    return math.sqrt(ss / max(n_used, 1)) * RAD_TO_ARCSEC, ok


@njit(cache=True)
def residual_angle_rad(rot, b, r):
    """Angle between ``rot @ b`` and ``r``, rad: ``atan2(|rot b × r|, rot b · r)``; b, r shape (3,), rot (3, 3)."""
    x = rot[0, 0] * b[0] + rot[0, 1] * b[1] + rot[0, 2] * b[2]
    y = rot[1, 0] * b[0] + rot[1, 1] * b[1] + rot[1, 2] * b[2]
    z = rot[2, 0] * b[0] + rot[2, 1] * b[1] + rot[2, 2] * b[2]
    cx = y * r[2] - z * r[1]
    cy = z * r[0] - x * r[2]
    cz = x * r[1] - y * r[0]
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), x * r[0] + y * r[1] + z * r[2])


@njit(cache=True)
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
    for i in range(nb):
        for j in range(k):
            w[j] = 1.0 / (sigma[i, j] * sigma[i, j])
        rms[i], ok[i] = solve_wahba_one(b[i], r[i], w, m[i], q[i], cov[i])
    return q, cov, rms, ok
