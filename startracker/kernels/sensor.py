"""Star-tracker bookkeeping kernels: the lock's innovation test and the consistency verdict, no checks.

The callers are :class:`startracker.sensor.StarTracker` (the innovation χ² of a tracked frame) and the verdicts of
:mod:`startracker.onboard` (:func:`~startracker.onboard.judge_samples`, :func:`~startracker.onboard.judge_estimate`:
an attitude against the truth on its own covariance); both hand over float64 arrays they built themselves. Quaternions are (w, x, y, z), covariances body-frame rad².
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["innovation_chi2_mean", "consistency_nis"]


@njit(cache=True)
def innovation_chi2_mean(q_pred, q_sol, cov_sol, tau_s, cov_theta, cov_omega, cov_alpha):
    """Mean over instants of the innovation χ² ``δᵀ S⁻¹ δ`` of solved against predicted attitudes.

    ``δ`` is the rotation vector of ``conj(q_pred) ⊗ q_sol`` (angle in [0, π]) and
    ``S = P_θ + P_ω τ² + P_α τ⁴ / 4 + C_sol``: the prediction's covariance after ``τ`` plus the solution's.

    Parameters
    ----------
    q_pred, q_sol : ndarray, shape (n, 4)
        Predicted and solved attitudes at each instant (non-zero; normalised here).
    cov_sol : ndarray, shape (n, 3, 3)
        Covariance of each solved attitude, rad².
    tau_s : ndarray, shape (n,)
        Time from the motion state's reference instant to each instant, s.
    cov_theta : ndarray, shape (3, 3)
        Attitude covariance of the motion state, rad².
    cov_omega : ndarray, shape (3, 3)
        Rate covariance, (rad/s)².
    cov_alpha : ndarray, shape (3, 3)
        Acceleration covariance, (rad/s²)².

    Returns
    -------
    float
        Mean χ² (3 degrees of freedom per instant); 0.0 for n = 0.
    """
    n = q_pred.shape[0]
    if n == 0:
        return 0.0
    total = 0.0
    s = np.empty((3, 3))
    for k in range(n):
        sa = math.sqrt(q_pred[k, 0] ** 2 + q_pred[k, 1] ** 2 + q_pred[k, 2] ** 2 + q_pred[k, 3] ** 2)
        sb = math.sqrt(q_sol[k, 0] ** 2 + q_sol[k, 1] ** 2 + q_sol[k, 2] ** 2 + q_sol[k, 3] ** 2)
        w1, x1, y1, z1 = q_pred[k, 0] / sa, -q_pred[k, 1] / sa, -q_pred[k, 2] / sa, -q_pred[k, 3] / sa
        w2, x2, y2, z2 = q_sol[k, 0] / sb, q_sol[k, 1] / sb, q_sol[k, 2] / sb, q_sol[k, 3] / sb
        w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
        x = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
        y = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
        z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
        if w < 0.0:  # the shorter of the two rotations
            w, x, y, z = -w, -x, -y, -z
        v = math.sqrt(x * x + y * y + z * z)
        angle = 2.0 * math.atan2(v, w)
        if angle <= 1e-3:
            a2 = angle * angle
            scale = 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0
        else:
            scale = angle / math.sin(0.5 * angle)
        d0, d1, d2 = scale * x, scale * y, scale * z
        t2 = tau_s[k] * tau_s[k]
        t4 = t2 * t2 / 4.0
        for i in range(3):
            for j in range(3):
                s[i, j] = cov_theta[i, j] + cov_omega[i, j] * t2 + cov_alpha[i, j] * t4 + cov_sol[k, i, j]
        # S is symmetric positive definite: Cholesky S = L Lᵀ, then δᵀ S⁻¹ δ = |L⁻¹ δ|²
        l00 = math.sqrt(s[0, 0])
        l10 = s[1, 0] / l00
        l20 = s[2, 0] / l00
        l11 = math.sqrt(s[1, 1] - l10 * l10)
        l21 = (s[2, 1] - l20 * l10) / l11
        l22 = math.sqrt(s[2, 2] - l20 * l20 - l21 * l21)
        u0 = d0 / l00
        u1 = (d1 - l10 * u0) / l11
        u2 = (d2 - l20 * u0 - l21 * u1) / l22
        total += u0 * u0 + u1 * u1 + u2 * u2
    return total / n


@njit(cache=True)
def consistency_nis(q_true, q_est, cov):
    """Normalised error squared of each attitude against the truth, on its own covariance (3 dof).

    The error is the body-frame rotation vector ``δθ = log(q_est* ⊗ q_true)`` (``q_true = q_est ⊗ exp(δθ)``, the
    convention of the tracker's and the filter's covariances; angle in [0, π]) and the result ``δθᵀ C⁻¹ δθ``:
    χ²(3)-distributed when the covariance tells the truth. A covariance that is not positive definite gives ``inf``
    (an attitude that claims no uncertainty is consistent with no error at all).

    Parameters
    ----------
    q_true, q_est : ndarray, shape (n, 4)
        True and reported attitudes (w, x, y, z), unit, body -> ICRS; signs do not matter.
    cov : ndarray, shape (n, 3, 3)
        Reported covariance of each attitude's error, body frame, rad², symmetric.

    Returns
    -------
    ndarray, shape (n,)
        ``δθᵀ C⁻¹ δθ`` of each attitude (dimensionless).
    """
    n = q_true.shape[0]
    out = np.empty(n)
    for k in range(n):
        w1, x1, y1, z1 = q_est[k, 0], -q_est[k, 1], -q_est[k, 2], -q_est[k, 3]
        w2, x2, y2, z2 = q_true[k, 0], q_true[k, 1], q_true[k, 2], q_true[k, 3]
        w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
        x = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
        y = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
        z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
        if w < 0.0:  # the shorter of the two rotations
            w, x, y, z = -w, -x, -y, -z
        v = math.sqrt(x * x + y * y + z * z)
        scale = 2.0 if v < 1e-15 else 2.0 * math.atan2(v, w) / v
        d0, d1, d2 = scale * x, scale * y, scale * z
        c = cov[k]
        # Cholesky C = L Lᵀ, then δᵀ C⁻¹ δ = |L⁻¹ δ|²
        a00 = c[0, 0]
        if not a00 > 0.0:
            out[k] = math.inf
            continue
        l00 = math.sqrt(a00)
        l10 = c[1, 0] / l00
        l20 = c[2, 0] / l00
        a11 = c[1, 1] - l10 * l10
        if not a11 > 0.0:
            out[k] = math.inf
            continue
        l11 = math.sqrt(a11)
        l21 = (c[2, 1] - l20 * l10) / l11
        a22 = c[2, 2] - l20 * l20 - l21 * l21
        if not a22 > 0.0:
            out[k] = math.inf
            continue
        l22 = math.sqrt(a22)
        u0 = d0 / l00
        u1 = (d1 - l10 * u0) / l11
        u2 = (d2 - l20 * u0 - l21 * u1) / l22
        out[k] = u0 * u0 + u1 * u1 + u2 * u2
    return out
