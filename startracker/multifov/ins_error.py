"""INS attitude error driven by a gyro (paper 001 §4.2), and an honest bound of its covariance.

The gyro error model is :mod:`startracker.imu` (paper 001's conditions are
``gyro_preset("paper001-cond1" | "paper001-cond2" | "paper001-cond3")``: 0.004, 1 and 5 °/h of random
constant and of first-order Markov drift with τ = 3600 s, plus white noise). This module turns a drift history
into the error of the INS attitude and gives the per-axis 1σ bound the part catalog's error radius uses.

Attitude error. The INS's body-to-inertial attitude ``q̂`` differs from the truth by a small rotation ``μ``
in ICRS axes, ``q̂ = exp(μ) ⊗ q`` (so ``v̂_icrs = R(μ) v_icrs``). Paper 001 writes the error of the
navigation-frame attitude (platform error angle ``φ``, ENU) and of the position (``δθ``: latitude and
longitude errors as a rotation of the computed navigation frame), eqs. 8-9; the LoS in inertial axes goes
through both, and to first order they combine into ``μ = φ − δθ`` (the "psi angle"), whose rate is the gyro
drift seen in inertial axes::

    dμ/dt = −R(q_body_to_icrs) ε_body(t),        ε = ω_measured − ω_true

(accelerometer errors move ``φ`` and ``δθ`` together and cancel in ``μ``). That is what
:func:`propagate_attitude_error` integrates.
"""

from __future__ import annotations

import numpy as np

from startracker.imu import GyroSpec
from startracker.rotations import quat_to_matrix
from startracker.validation import as_float_array

__all__ = ["propagate_attitude_error", "attitude_sigma_bound_rad"]


def propagate_attitude_error(t_s, q_body_to_icrs, drift_body_rad_s, mu0_icrs=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Integrate the INS attitude error ``dμ/dt = −R(q) ε`` (rectangle rule, drift held over each step).

    Parameters
    ----------
    t_s : array_like, shape (T,)
        Strictly increasing times, s.
    q_body_to_icrs : array_like, shape (T, 4)
        True attitude at those times.
    drift_body_rad_s : array_like, shape (T, 3)
        Gyro error (measured minus true rate, the sample's average over the following step), body axes, rad/s.
    mu0_icrs : array_like, shape (3,)
        Error at ``t_s[0]``, rad.

    Returns
    -------
    ndarray, shape (T, 3)
        ``μ`` in ICRS axes, rad, with ``q_ins = exp(μ) ⊗ q_true``.
    """
    t = as_float_array(t_s, "t_s", ndim=1)
    q = as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4, ndim=2)
    e = as_float_array(drift_body_rad_s, "drift_body_rad_s", last_dim=3, ndim=2)
    if not (len(t) == len(q) == len(e)) or len(t) == 0:
        raise ValueError("t_s, q_body_to_icrs and drift_body_rad_s must have the same non-zero length")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t_s must be strictly increasing")
    mu0 = as_float_array(mu0_icrs, "mu0_icrs", last_dim=3, ndim=1)
    rate = -np.einsum("tij,tj->ti", quat_to_matrix(q), e)
    mu = np.empty((len(t), 3))
    mu[0] = mu0
    mu[1:] = mu0 + np.cumsum(rate[:-1] * np.diff(t)[:, None], axis=0)
    return mu


def attitude_sigma_bound_rad(spec: GyroSpec, elapsed_s, initial_sigma_rad: float = 0.0, max_rate_rad_s: float = 0.0):
    """Upper bound of the per-axis 1σ of ``μ`` after ``elapsed_s`` of free (unaided) INS.

    For any body motion each component of ``μ(t) = −∫ R ε ds`` has variance at most::

        σ0² + σ_b² t² + 2 σ_m² τ² (t/τ − 1 + e^{−t/τ}) + N² t + K² t³ / 3 + 3 (σ_sf ω_max t)²

    (random constant σ_b, Markov σ_m and τ, angle random walk N, rate random walk K, scale factor σ_sf at a
    body rate up to ω_max). The bound is reached when the body does not rotate: rotation only averages the
    drift down, because every term's autocovariance is non-negative. It is the honest INS covariance ``σ² I``
    that :func:`startracker.multifov.local_catalog.predict_scopes` turns into error radii.

    Parameters
    ----------
    spec : GyroSpec
    elapsed_s : float or array_like, shape (T,)
        Time since the last star fix, s (>= 0).
    initial_sigma_rad : float
        1σ attitude error at the last fix, rad.
    max_rate_rad_s : float
        Largest body rate during the interval, rad/s (for the scale-factor term).

    Returns
    -------
    ndarray, shape like ``elapsed_s``
        rad.
    """
    if not isinstance(spec, GyroSpec):
        raise TypeError(f"spec must be a GyroSpec, got {type(spec).__name__}")
    t = as_float_array(elapsed_s, "elapsed_s")
    if np.any(t < 0):
        raise ValueError("elapsed_s must be >= 0")
    for name, v in (("initial_sigma_rad", initial_sigma_rad), ("max_rate_rad_s", max_rate_rad_s)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be a finite number >= 0, got {v}")
    tau = spec.gm_tau_s
    var = (
        initial_sigma_rad**2
        + (spec.bias_sigma_rad_s * t) ** 2
        + 2 * spec.gm_sigma_rad_s**2 * tau**2 * (t / tau - 1 + np.exp(-t / tau))
        + spec.arw_rad_sqrt_s**2 * t
        + spec.rrw_rad_s_sqrt_s**2 * t**3 / 3
        + 3 * (spec.scale_factor_sigma_ppm * 1e-6 * max_rate_rad_s * t) ** 2
    )
    return np.sqrt(var)
