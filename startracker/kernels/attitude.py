"""Wahba kernel: many attitude problems at once (SVD method, QUEST covariance), float64 arrays, no checks.

The checked API and the method's description are in :mod:`startracker.attitude`.
"""

from __future__ import annotations

import numpy as np

from startracker.kernels import rotations as rk

__all__ = ["solve_wahba_batch", "RAD_TO_ARCSEC"]

RAD_TO_ARCSEC = 180.0 / np.pi * 3600.0


def solve_wahba_batch(b: np.ndarray, r: np.ndarray, sigma, m: np.ndarray):
    """B independent Wahba problems by the SVD method, with the QUEST covariance.

    Parameters
    ----------
    b : ndarray, shape (B, K, 3)
        Unit measured directions (camera/body frame), float64.
    r : ndarray, shape (B, K, 3)
        Unit reference (ICRS) directions.
    sigma : ndarray or float, broadcastable to (B, K)
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
    w = np.where(m, sigma**-2, 0.0)
    attitude_profile = np.einsum("bk,bki,bkj->bij", w, r, b)
    u, _, vt = np.linalg.svd(attitude_profile)
    d = np.linalg.det(u) * np.linalg.det(vt)
    u[:, :, 2] *= d[:, None]
    rot = u @ vt
    # Fisher information of the rotation error in the measurement frame.
    eye = np.eye(3)
    info = np.einsum("bk,ij->bij", w, eye) - np.einsum("bk,bki,bkj->bij", w, b, b)
    n_used = m.sum(axis=1)
    # Two or more non-parallel directions make the information matrix full rank.
    eig_min = np.linalg.eigvalsh(info)[:, 0]
    scale = np.maximum(w.sum(axis=1), 1e-300)
    ok = (n_used >= 2) & (eig_min > 1e-10 * scale)
    if ok.all():  # the usual case: no masked assignments (inv works matrix by matrix, so the same values)
        cov = np.linalg.inv(info)
    else:
        cov = np.full((len(b), 3, 3), 0.0)
        cov[ok] = np.linalg.inv(info[ok])
        cov[~ok] = np.diag([np.inf, np.inf, np.inf])
        rot[~ok] = eye
    q = rk.quat_from_matrix(rot)  # quat_from_matrix, bit for bit
    rb = np.einsum("bij,bkj->bki", rot, b)
    ang = np.arctan2(rk.vector_norm(rk.cross(rb, r)), np.add.reduce(rb * r, axis=-1))
    rms = np.sqrt(np.add.reduce(np.where(m, ang**2, 0.0), axis=1) / np.maximum(n_used, 1)) * RAD_TO_ARCSEC
    return q, cov, rms, ok
