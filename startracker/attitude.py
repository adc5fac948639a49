"""Wahba's problem: the attitude that best maps measured directions onto catalog directions.

The optimal attitude of the SVD method (Markley 1988), batched over many independent problems (one per exposure
instant of a multi-exposure frame) in a compiled kernel (:mod:`startracker.kernels.attitude`: Davenport's
q-method, the same optimum; :func:`solve_wahba_single` keeps numpy's SVD). Covariance by Shuster's QUEST
measurement model: each unit vector measured with isotropic angular noise σ_i gives

    P = [ Σ σ_i⁻² (I − b_i b_iᵀ) ]⁻¹          (rad², in the measurement frame)

the covariance of the small rotation vector δθ with ``q_true = q_est ⊗ δq(δθ)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np


from startracker.validation import as_float_array
from startracker.kernels import attitude as wahba_kernels

__all__ = ["WahbaSolution", "solve_wahba", "solve_wahba_batch", "solve_wahba_single", "RAD_TO_ARCSEC"]

RAD_TO_ARCSEC = wahba_kernels.RAD_TO_ARCSEC


@dataclass(frozen=True)
class WahbaSolution:
    """Result of one Wahba solve.

    Attributes
    ----------
    success : bool
        False when fewer than two non-parallel vectors were given.
    q_meas_to_ref : ndarray, shape (4,)
        (w, x, y, z) rotation from the measurement frame (camera or body) to the reference frame
        (ICRS): ``v_ref ≈ R(q) @ v_meas``. Identity when not successful.
    residual_rms_arcsec : float
        RMS angle between each reference vector and its rotated measurement.
    covariance_rad2 : ndarray, shape (3, 3)
        Covariance of the attitude error rotation vector in the measurement frame. Infinite diagonal
        when not successful.
    n_vectors : int
    status : str
        "ok", or why it failed.
    """

    success: bool
    q_meas_to_ref: np.ndarray
    residual_rms_arcsec: float
    covariance_rad2: np.ndarray
    n_vectors: int
    status: str = "ok"


def _check_pairs(v_meas, v_ref, name_meas="v_meas", name_ref="v_ref"):
    b = as_float_array(v_meas, name_meas, last_dim=3)
    r = as_float_array(v_ref, name_ref, last_dim=3)
    if b.shape != r.shape:
        raise ValueError(f"{name_meas} and {name_ref} must have the same shape, got {b.shape} and {r.shape}")
    nb = np.linalg.norm(b, axis=-1, keepdims=True)
    nr = np.linalg.norm(r, axis=-1, keepdims=True)
    if np.any(nb == 0) or np.any(nr == 0):
        raise ValueError(f"{name_meas} and {name_ref} must not contain zero vectors")
    return b / nb, r / nr


def solve_wahba_batch(v_meas, v_ref, sigma_rad, mask=None):
    """Solve many Wahba problems at once.

    Parameters
    ----------
    v_meas : array_like, shape (B, K, 3)
        Measured directions (camera/body frame), any norm > 0.
    v_ref : array_like, shape (B, K, 3)
        Matching reference (ICRS) directions.
    sigma_rad : float or array_like, broadcastable to (B, K)
        Angular noise (1σ, rad) of each measured direction; weights are σ⁻².
    mask : array_like of bool, shape (B, K), optional
        Which pairs take part (padding for problems with fewer vectors).

    Returns
    -------
    q : ndarray, shape (B, 4)
        ``q_meas_to_ref`` per problem (identity where it failed).
    covariance_rad2 : ndarray, shape (B, 3, 3)
    residual_rms_arcsec : ndarray, shape (B,)
    ok : ndarray of bool, shape (B,)
        At least two used vectors that are not parallel.
    """
    b, r = _check_pairs(v_meas, v_ref)
    if b.ndim != 3:
        raise ValueError(f"v_meas must have shape (B, K, 3), got {b.shape}")
    sigma = np.ascontiguousarray(np.broadcast_to(np.asarray(sigma_rad, dtype=np.float64), b.shape[:2]))
    if not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError("sigma_rad must be positive and finite")
    if mask is None:
        m = np.ones(b.shape[:2], dtype=bool)
    else:
        m = np.ascontiguousarray(np.broadcast_to(np.asarray(mask, dtype=bool), b.shape[:2]))
    return wahba_kernels.solve_wahba_batch(np.ascontiguousarray(b), np.ascontiguousarray(r), sigma, m)


def solve_wahba(v_meas, v_ref, sigma_rad=1e-5) -> WahbaSolution:
    """Attitude from matched measured and reference unit vectors.

    Parameters
    ----------
    v_meas : array_like, shape (K, 3)
        Measured directions in the camera or body frame.
    v_ref : array_like, shape (K, 3)
        The same stars' catalog directions in ICRS.
    sigma_rad : float or array_like, shape (K,)
        1σ angular noise of each measured direction in rad (default 1e-5 rad ≈ 2″).

    Returns
    -------
    WahbaSolution
        ``success=False`` with a status for fewer than 2 vectors or parallel vectors.
    """
    b = as_float_array(v_meas, "v_meas", last_dim=3, ndim=2)
    r = as_float_array(v_ref, "v_ref", last_dim=3, ndim=2)
    if len(b) != len(r):
        raise ValueError(f"v_meas and v_ref must have the same length, got {len(b)} and {len(r)}")
    if len(b) < 2:
        return WahbaSolution(False, np.array([1.0, 0, 0, 0]), np.inf, np.diag([np.inf] * 3), len(b), "fewer than 2 vectors")
    sig = np.broadcast_to(np.asarray(sigma_rad, dtype=np.float64), (len(b),))
    q, cov, rms, ok = solve_wahba_batch(b[None], r[None], sig[None])
    if not ok[0]:
        return WahbaSolution(False, q[0], np.inf, cov[0], len(b), "vectors are parallel: attitude not observable")
    return WahbaSolution(True, q[0], float(rms[0]), cov[0], len(b))


def _quat_from_rotation(m: np.ndarray) -> np.ndarray:
    """(w, x, y, z) with w >= 0 from one proper rotation matrix (Shepperd's method, plain floats)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m.tolist()
    tr = m00 + m11 + m22
    big = max(tr, m00, m11, m22)
    if big == tr:
        s = 2.0 * (1.0 + tr) ** 0.5
        q = [0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s]
    elif big == m00:
        s = 2.0 * (1.0 + m00 - m11 - m22) ** 0.5
        q = [(m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s]
    elif big == m11:
        s = 2.0 * (1.0 + m11 - m00 - m22) ** 0.5
        q = [(m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s]
    else:
        s = 2.0 * (1.0 + m22 - m00 - m11) ** 0.5
        q = [(m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s]
    q = np.array(q)
    q /= np.sqrt(q @ q)
    first = q[np.argmax(q != 0.0)]
    return -q if first < 0 else q


def solve_wahba_single(v_meas, v_ref, sigma_rad=1e-5) -> WahbaSolution:
    """:func:`solve_wahba` for one problem, without the batch machinery (for hot paths).

    Same method and results as :func:`solve_wahba` (SVD solution, QUEST covariance, RMS residual, the
    same failure statuses) at a fraction of the overhead: star identification calls it once per frame.

    Parameters
    ----------
    v_meas : array_like, shape (K, 3)
        Measured directions in the camera or body frame (non-zero).
    v_ref : array_like, shape (K, 3)
        The same stars' catalog directions in ICRS.
    sigma_rad : float or array_like, shape (K,)
        1σ angular noise of each measured direction in rad.

    Returns
    -------
    WahbaSolution
    """
    b = as_float_array(v_meas, "v_meas", last_dim=3, ndim=2)
    r = as_float_array(v_ref, "v_ref", last_dim=3, ndim=2)
    if len(b) != len(r):
        raise ValueError(f"v_meas and v_ref must have the same length, got {len(b)} and {len(r)}")
    if len(b) < 2:
        return WahbaSolution(False, np.array([1.0, 0, 0, 0]), np.inf, np.diag([np.inf] * 3), len(b), "fewer than 2 vectors")
    nb = np.sqrt(np.einsum("ij,ij->i", b, b))
    nr = np.sqrt(np.einsum("ij,ij->i", r, r))
    if not (nb.min() > 0 and nr.min() > 0):
        raise ValueError("v_meas and v_ref must not contain zero vectors")
    b = b / nb[:, None]
    r = r / nr[:, None]
    if np.ndim(sigma_rad) == 0:  # one noise for all: scalar weights
        s = float(sigma_rad)
        if not (math.isfinite(s) and s > 0):
            raise ValueError("sigma_rad must be positive and finite")
        w1 = s**-2
        wb = b * w1
        wsum = w1 * len(b)
    else:
        sig = np.broadcast_to(np.asarray(sigma_rad, dtype=np.float64), (len(b),))
        if not np.all(np.isfinite(sig)) or np.any(sig <= 0):
            raise ValueError("sigma_rad must be positive and finite")
        w = sig**-2
        wb = b * w[:, None]
        wsum = float(w.sum())
    u, _, vt = np.linalg.svd(r.T @ wb)
    rot = u @ vt
    (a, b_, c), (d, e, f), (g, h, i) = rot.tolist()
    if a * (e * i - f * h) - b_ * (d * i - f * g) + c * (d * h - e * g) < 0:  # det(U) det(V) = -1
        u[:, 2] = -u[:, 2]
        rot = u @ vt
    info = wsum * np.eye(3) - wb.T @ b
    if np.linalg.eigvalsh(info)[0] <= 1e-10 * max(wsum, 1e-300):
        return WahbaSolution(False, np.array([1.0, 0, 0, 0]), np.inf, np.diag([np.inf] * 3), len(b), "vectors are parallel: attitude not observable")
    rb = b @ rot.T
    cx = rb[:, 1] * r[:, 2] - rb[:, 2] * r[:, 1]
    cy = rb[:, 2] * r[:, 0] - rb[:, 0] * r[:, 2]
    cz = rb[:, 0] * r[:, 1] - rb[:, 1] * r[:, 0]
    ang = np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz), np.einsum("ij,ij->i", rb, r))
    rms = float(np.sqrt(np.mean(ang * ang))) * RAD_TO_ARCSEC
    return WahbaSolution(True, _quat_from_rotation(rot), rms, np.linalg.inv(info), len(b))
