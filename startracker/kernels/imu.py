"""Inertial-sensor kernels: the sample model of :mod:`startracker.imu` on float64 arrays, compiled, no checks.

The caller (:meth:`startracker.imu.Gyro.measure`) draws the standard normal variates from its
``numpy.random.Generator`` (the Gauss-Markov drive, then the random-walk steps, then the white noise, each
(K, 3), each only when its coefficient is non-zero) and passes them in; the kernel keeps numpy's operation
order, so its samples are bit for bit those of the vectorised numpy formulation (``lfilter``, ``cumsum``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from startracker.kernels.rotations import interval_rates_rows

__all__ = ["sensor_samples", "gyro_samples_of_history"]


@njit(cache=True, no_cfunc_wrapper=True)
def sensor_samples(u, scale, b_const, b_gm, b_rw, phi, gm_drive, xi_gm, rw_step, xi_rw, white_sigma, xi_white,
                   limit):
    """Samples of a three-axis sensor: ``sat((1 + s) u + b_c + b_gm + b_rw + n)``, advancing its bias states.

    Per sample k and axis: ``b_gm ← φ b_gm + gm_drive ξ_gm`` (if ``gm_drive > 0``), ``b_rw ← b_rw + rw_step ξ_rw``
    (if ``rw_step > 0``, accumulated from the call's starting value), ``y = scale u + (b_c + b_gm + b_rw)``,
    ``y += white_sigma ξ_white`` (if ``white_sigma > 0``), clipped to ``±limit``.

    Parameters
    ----------
    u : ndarray, shape (K, 3)
        True input per sample (rad/s for a gyro, m/s² for an accelerometer).
    scale : ndarray, shape (3,)
        Scale factor ``1 + s`` per axis.
    b_const : ndarray, shape (3,)
        Turn-on bias, input units.
    b_gm : ndarray, shape (3,)
        Gauss-Markov bias before the first sample; set in place to its value at the last sample.
    b_rw : ndarray, shape (3,)
        Random-walk bias before the first sample; set in place to its value at the last sample.
    phi : float
        Gauss-Markov decay per sample, ``exp(-Δ/τ)``.
    gm_drive : float
        Gauss-Markov driving 1σ per sample, input units (0: the state stays constant).
    xi_gm : ndarray, shape (K, 3)
        Standard normal draws of the Gauss-Markov drive (not read when ``gm_drive == 0``).
    rw_step : float
        Random-walk 1σ step per sample, input units (0: none).
    xi_rw : ndarray, shape (K, 3)
        Standard normal draws of the random walk (not read when ``rw_step == 0``).
    white_sigma : float
        1σ of the white noise of a sample, input units (0: none).
    xi_white : ndarray, shape (K, 3)
        Standard normal draws of the white noise (not read when ``white_sigma == 0``).
    limit : float
        Saturation, input units (``inf``: none).

    Returns
    -------
    ndarray, shape (K, 3)
        The samples.
    """
    k = u.shape[0]
    y = np.empty((k, 3))
    for a in range(3):
        gm = b_gm[a]
        rw0 = b_rw[a]
        acc = 0.0  # the running sum of the steps, added to the starting value as numpy's cumsum does
        rw = rw0
        for i in range(k):
            if gm_drive > 0.0:
                gm = gm_drive * xi_gm[i, a] + phi * gm
            if rw_step > 0.0:
                acc = acc + rw_step * xi_rw[i, a]
                rw = rw0 + acc
            v = scale[a] * u[i, a] + ((b_const[a] + gm) + rw)
            if white_sigma > 0.0:
                v = v + white_sigma * xi_white[i, a]
            if v > limit:
                v = limit
            elif v < -limit:
                v = -limit
            y[i, a] = v
        b_gm[a] = gm
        b_rw[a] = rw
    return y


@njit(cache=True, no_cfunc_wrapper=True)
def gyro_samples_of_history(t, q, scale, b_const, b_gm, b_rw, phi, gm_drive, xi_gm, rw_step, xi_rw, white_sigma,
                            xi_white, limit):
    """A gyro's samples over the intervals of an attitude history, in one call: :func:`sensor_samples` of the mean
    body rates :func:`startracker.kernels.rotations.interval_rates_rows` (the same operations as the two calls).

    Parameters
    ----------
    t : ndarray, shape (K + 1,)
        Instants of the history, s (increasing).
    q : ndarray, shape (K + 1, 4)
        Attitudes at ``t`` (body to inertial, non-zero quaternions).
    scale, b_const, b_gm, b_rw, phi, gm_drive, xi_gm, rw_step, xi_rw, white_sigma, xi_white, limit :
        As :func:`sensor_samples` (K rows of draws); ``b_gm`` and ``b_rw`` are advanced in place.

    Returns
    -------
    ndarray, shape (K, 3)
        The samples, rad/s: sample k over ``(t[k], t[k + 1]]``.
    """
    u = interval_rates_rows(t, q)
    return sensor_samples(u, scale, b_const, b_gm, b_rw, phi, gm_drive, xi_gm, rw_step, xi_rw, white_sigma, xi_white,
                          limit)
