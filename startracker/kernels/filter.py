"""MEKF kernels: the arithmetic of :class:`startracker.filter.AttitudeEKF` on float64 arrays, compiled, no checks.

The model (see :mod:`startracker.filter`): a 6-element error state ``x = [δθ (rad), δb (rad/s)]`` with
``q_true = q̂ ⊗ exp(δθ)`` (body frame), gyro ``ω_gyro = ω + b + n_v``, bias ``ḃ = n_u``; the measurement is the
rotation vector ``z = log(q̂* ⊗ q_meas)`` of an attitude sample, ``H = [I₃, 0]``. Quaternions are (w, x, y, z).

- :func:`transition`: the state transition Φ and the process noise Q of one gyro interval;
- :func:`ekf_predict` / :func:`ekf_update`: filterpy's ``ExtendedKalmanFilter.predict`` / ``update`` (Joseph
  form) for this ``H``, on any error state ``x``;
- :func:`attitude_residual`: the innovation ``z`` of an attitude sample; :func:`quat_advance`: ``q ⊗ exp(r)``;
- :func:`fuse_frame`: a whole frame (gyro intervals and attitude samples in time order, sequential updates
  with the innovation gate and the multiplicative reset after each one), the per-frame path of
  :meth:`startracker.filter.AttitudeEKF.process` (its extra ``rate_noise`` is the process noise of saturated gyro
  axes; it also returns each sample's innovation, its covariance and NIS);
- :func:`saturated_rate_noise`: which gyro readings are saturated, and the process noise they get;
- :func:`innovation_window`: the innovation monitor's statistics (spread and mean of the innovations over the
  window, the newest delivery's mean and its largest NIS);
- :func:`timing_statistic`: the timing test of a delivery along the body rate, before it is fused, and
  :func:`fuse_frame_timed`: the test against the prediction, then the fusion when it passes, in one call
  (:func:`fuse_buffer_timed`: the same on the delayed fusion's buffer, with its copies and outputs);
- :func:`gyro_jump_statistic`: the gyro jump monitor's test for a step in the readings (a bias that jumped), and
  :func:`gyro_jump_looks`: its two looks of a span (its own window, then the previous span's again) in one call;
- :func:`append_intervals`: the delayed fusion's gyro buffer with a span's intervals appended, and
  :func:`propagate_buffer`: the estimate at the buffer's end (the estimate *now*);
- :func:`reported_attitude`: the estimate's reported covariance, its verdict's NIS against the truth and its largest
  variance, in one call;
- :func:`delivery_rows` / :func:`delivery_counts`: a delivery's samples made unit (and whether they are in time
  order), and its tallies after fusion (the last accepted sample, wrong and confidently wrong samples).

The module is over 600 lines because it is one room: what the onboard filter computes, the fusion of a frame and
the statistics of the monitors that judge its inputs (innovations, saturated readings, gyro steps), compiled
together; the innovation window reuses the frame's 3 × 3 solve.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.sensor import consistency_nis

__all__ = ["transition", "ekf_predict", "ekf_update", "attitude_residual", "quat_advance", "fuse_frame",
           "innovation_window", "timing_statistic", "fuse_frame_timed", "saturated_rate_noise", "gyro_jump_statistic",
           "gyro_jump_looks", "delivery_rows", "delivery_counts", "delivery_tallies", "append_intervals", "propagate_buffer",
           "reported_attitude", "fuse_buffer_timed"]


@njit(cache=True, no_cfunc_wrapper=True)
def _transition_into(wx, wy, wz, dt, sigma_v, sigma_u, phi, qd):
    w2 = wx * wx + wy * wy + wz * wz
    th2 = w2 * dt * dt
    if th2 < 1e-8:  # Taylor series, error < th^4 relative
        c1 = dt * (1.0 - th2 / 6.0)  # sin(w dt)/w
        c2 = dt * dt * (0.5 - th2 / 24.0)  # (1 - cos(w dt))/w²
        c3 = dt**3 * (1.0 / 6.0 - th2 / 120.0)  # (w dt - sin(w dt))/w³
    else:
        w = math.sqrt(w2)
        th = w * dt
        s = math.sin(th)
        c1 = s / w
        c2 = (1.0 - math.cos(th)) / w2
        c3 = (th - s) / (w2 * w)
    # [ω×]² = ω ωᵀ - |ω|² I
    xx, yy, zz = wx * wx - w2, wy * wy - w2, wz * wz - w2
    xy, xz, yz = wx * wy, wx * wz, wy * wz
    # Φ11 = I - c1 [ω×] + c2 [ω×]²;  Φ12 = -dt I + c2 [ω×] - c3 [ω×]²;  Φ21 = 0;  Φ22 = I
    for i in range(3, 6):  # element stores, not a slice assignment (its generic loop is slower)
        for j in range(3):
            phi[i, j] = 0.0
            phi[i, j + 3] = 0.0
    phi[0, 0] = 1.0 + c2 * xx
    phi[0, 1] = c1 * wz + c2 * xy
    phi[0, 2] = -c1 * wy + c2 * xz
    phi[1, 0] = -c1 * wz + c2 * xy
    phi[1, 1] = 1.0 + c2 * yy
    phi[1, 2] = c1 * wx + c2 * yz
    phi[2, 0] = c1 * wy + c2 * xz
    phi[2, 1] = -c1 * wx + c2 * yz
    phi[2, 2] = 1.0 + c2 * zz
    phi[0, 3] = -dt - c3 * xx
    phi[0, 4] = -c2 * wz - c3 * xy
    phi[0, 5] = c2 * wy - c3 * xz
    phi[1, 3] = c2 * wz - c3 * xy
    phi[1, 4] = -dt - c3 * yy
    phi[1, 5] = -c2 * wx - c3 * yz
    phi[2, 3] = -c2 * wy - c3 * xz
    phi[2, 4] = c2 * wx - c3 * yz
    phi[2, 5] = -dt - c3 * zz
    phi[3, 3] = phi[4, 4] = phi[5, 5] = 1.0
    sv2, su2 = sigma_v * sigma_v, sigma_u * sigma_u
    q11 = sv2 * dt + su2 * dt * dt * dt / 3.0
    q12 = -0.5 * su2 * dt * dt
    q22 = su2 * dt
    for i in range(6):
        for j in range(6):
            qd[i, j] = 0.0
    for i in range(3):
        qd[i, i] = q11
        qd[i, i + 3] = q12
        qd[i + 3, i] = q12
        qd[i + 3, i + 3] = q22


@njit(cache=True, no_cfunc_wrapper=True)
def transition(w_hat, dt, sigma_v, sigma_u):
    """State transition and process noise of the error state over one gyro interval.

    Parameters
    ----------
    w_hat : ndarray, shape (3,)
        Bias-corrected body rate ``ω_gyro - b̂``, rad/s, held constant over the interval.
    dt : float
        Interval, s (>= 0).
    sigma_v : float
        Angle random walk σ_v, rad/√s.
    sigma_u : float
        Bias random walk σ_u, rad/s/√s.

    Returns
    -------
    phi : ndarray, shape (6, 6)
        ``[[exp(-[ω̂×] dt), -∫₀^dt exp(-[ω̂×] s) ds], [0, I]]`` (closed form; series below ``|ω̂| dt = 1e-4``).
    qd : ndarray, shape (6, 6)
        ``[[σ_v² dt + σ_u² dt³/3, -σ_u² dt²/2], [-σ_u² dt²/2, σ_u² dt]] ⊗ I₃``.
    """
    phi = np.empty((6, 6))
    qd = np.empty((6, 6))
    _transition_into(w_hat[0], w_hat[1], w_hat[2], dt, sigma_v, sigma_u, phi, qd)
    return phi, qd


@njit(cache=True, no_cfunc_wrapper=True)
def _predict_cov_into(P, phi, qd, tmp, out):
    """out = Φ P Φᵀ + Q (out may be P)."""
    for i in range(6):
        for j in range(6):
            s = 0.0
            for k in range(6):
                s += phi[i, k] * P[k, j]
            tmp[i, j] = s
    for i in range(6):
        for j in range(6):
            s = 0.0
            for k in range(6):
                s += tmp[i, k] * phi[j, k]
            out[i, j] = s + qd[i, j]


@njit(cache=True, no_cfunc_wrapper=True)
def ekf_predict(x, P, F, Q):
    """filterpy's ``ExtendedKalmanFilter.predict`` (no control input): ``x ← F x``, ``P ← F P Fᵀ + Q``.

    Parameters
    ----------
    x : ndarray, shape (6,)
        Error state (δθ rad, δb rad/s).
    P : ndarray, shape (6, 6)
        Its covariance.
    F, Q : ndarray, shape (6, 6)
        State transition and process noise (:func:`transition`).

    Returns
    -------
    x_new : ndarray, shape (6,)
    P_new : ndarray, shape (6, 6)
    """
    x_new = np.empty(6)
    for i in range(6):
        s = 0.0
        for k in range(6):
            s += F[i, k] * x[k]
        x_new[i] = s
    P_new = np.empty((6, 6))
    _predict_cov_into(P, F, Q, np.empty((6, 6)), P_new)
    return x_new, P_new


@njit(cache=True, no_cfunc_wrapper=True)
def _inv3_sym_into(s, out):
    """Inverse of a symmetric positive-definite (3, 3) matrix by the adjugate (upper triangle read)."""
    a, b, c = s[0, 0], s[0, 1], s[0, 2]
    d, e, f = s[1, 1], s[1, 2], s[2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    out[0, 0] = c00 / det
    out[0, 1] = out[1, 0] = c01 / det
    out[0, 2] = out[2, 0] = c02 / det
    out[1, 1] = c11 / det
    out[1, 2] = out[2, 1] = c12 / det
    out[2, 2] = c22 / det


@njit(cache=True, no_cfunc_wrapper=True)
def _update_into(x, P, y0, y1, y2, R, s_inv, k, kr, tmp, x_out, P_out):
    """Kalman update with H = [I 0] for the residual y (given S⁻¹): x_out = x + K y, Joseph-form P_out (may be P).

    ``(I - K H) P (I - K H)ᵀ + K R Kᵀ`` with ``I - K H = I - [K 0]``, evaluated on its upper triangle and mirrored
    (the result is symmetric; P is read only through ``tmp`` once ``tmp`` is formed).
    """
    for i in range(6):
        for j in range(3):
            k[i, j] = P[i, 0] * s_inv[0, j] + P[i, 1] * s_inv[1, j] + P[i, 2] * s_inv[2, j]
        for j in range(3):
            kr[i, j] = k[i, 0] * R[0, j] + k[i, 1] * R[1, j] + k[i, 2] * R[2, j]
    for i in range(6):
        x_out[i] = x[i] + (k[i, 0] * y0 + k[i, 1] * y1 + k[i, 2] * y2)
    for i in range(6):
        for j in range(6):
            tmp[i, j] = P[i, j] - (k[i, 0] * P[0, j] + k[i, 1] * P[1, j] + k[i, 2] * P[2, j])
    for i in range(6):
        for j in range(i, 6):
            a = tmp[i, j] - (tmp[i, 0] * k[j, 0] + tmp[i, 1] * k[j, 1] + tmp[i, 2] * k[j, 2])
            v = a + (kr[i, 0] * k[j, 0] + kr[i, 1] * k[j, 1] + kr[i, 2] * k[j, 2])
            P_out[i, j] = v
            P_out[j, i] = v


@njit(cache=True, no_cfunc_wrapper=True)
def _predict_model_cov_into(P, phi, qd, m1, m2):
    """P ← Φ P Φᵀ + Q in place for the model's Φ = [[A, B], [0, I]] and a symmetric P.

    With P = [[Paa, Pab], [Pabᵀ, Pbb]]: M2 = A Pab + B Pbb is the new cross block, M1 = A Paa + B Pabᵀ, and the new
    attitude block is M1 Aᵀ + M2 Bᵀ; Pbb is unchanged (plus Q). A third of the products of the dense form.
    """
    for i in range(3):
        for j in range(3):
            s1 = 0.0
            s2 = 0.0
            for k in range(3):
                s1 += phi[i, k] * P[k, j] + phi[i, k + 3] * P[k + 3, j]
                s2 += phi[i, k] * P[k, j + 3] + phi[i, k + 3] * P[k + 3, j + 3]
            m1[i, j] = s1
            m2[i, j] = s2
    for i in range(3):
        for j in range(i, 3):
            s = 0.0
            for k in range(3):
                s += m1[i, k] * phi[j, k] + m2[i, k] * phi[j, k + 3]
            v = s + qd[i, j]
            P[i, j] = v
            P[j, i] = v
    for i in range(3):
        for j in range(3):
            v = m2[i, j] + qd[i, j + 3]
            P[i, j + 3] = v
            P[j + 3, i] = v
    for i in range(3):
        for j in range(3):
            P[i + 3, j + 3] += qd[i + 3, j + 3]


@njit(cache=True, no_cfunc_wrapper=True)
def ekf_update(x, P, z, R):
    """filterpy's ``ExtendedKalmanFilter.update`` for ``H = [I₃, 0]``, ``h(x) = x[:3]`` (Joseph form).

    ``y = z - x[:3]``, ``S = P[:3, :3] + R``, ``K = P Hᵀ S⁻¹``, ``x ← x + K y``,
    ``P ← (I - K H) P (I - K H)ᵀ + K R Kᵀ``.

    Parameters
    ----------
    x : ndarray, shape (6,)
        Prior error state.
    P : ndarray, shape (6, 6)
        Prior covariance.
    z : ndarray, shape (3,)
        Measurement (rotation vector, rad).
    R : ndarray, shape (3, 3)
        Measurement covariance, rad², symmetric positive definite.

    Returns
    -------
    x_new : ndarray, shape (6,)
    P_new : ndarray, shape (6, 6)
    """
    s = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            s[i, j] = P[i, j] + R[i, j]
    s_inv = np.empty((3, 3))
    _inv3_sym_into(s, s_inv)
    x_new = np.empty(6)
    P_new = np.empty((6, 6))
    _update_into(x, P, z[0] - x[0], z[1] - x[1], z[2] - x[2], R, s_inv, np.empty((6, 3)), np.empty((6, 3)),
                 np.empty((6, 6)), x_new, P_new)
    return x_new, P_new


@njit(cache=True, no_cfunc_wrapper=True)
def _residual(qw, qx, qy, qz, mw, mx, my, mz):
    """Rotation vector of q̂* ⊗ q_meas, sign-invariant (the shorter rotation)."""
    w = qw * mw + qx * mx + qy * my + qz * mz
    x = qw * mx - qx * mw - qy * mz + qz * my
    y = qw * my + qx * mz - qy * mw - qz * mx
    z = qw * mz - qx * my + qy * mx - qz * mw
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    vn = math.sqrt(x * x + y * y + z * z)
    if vn < 1e-15:
        return 2.0 * x, 2.0 * y, 2.0 * z
    k = 2.0 * math.atan2(vn, w) / vn
    return k * x, k * y, k * z


@njit(cache=True, no_cfunc_wrapper=True)
def attitude_residual(q_est, q_meas):
    """Innovation of an attitude sample: the rotation vector of ``q_est* ⊗ q_meas`` (body frame).

    Parameters
    ----------
    q_est, q_meas : ndarray, shape (4,)
        Unit quaternions (w, x, y, z), body -> ICRS; the sign of ``q_meas`` does not matter.

    Returns
    -------
    ndarray, shape (3,)
        Rotation vector, rad, of norm <= π.
    """
    out = np.empty(3)
    out[0], out[1], out[2] = _residual(q_est[0], q_est[1], q_est[2], q_est[3],
                                       q_meas[0], q_meas[1], q_meas[2], q_meas[3])
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def _rotate_by(q, rx, ry, rz):
    """q ← normalise(q ⊗ exp(r)) in place, r a body-frame rotation vector (rad)."""
    th2 = rx * rx + ry * ry + rz * rz
    if th2 < 1e-16:
        s = 0.5 - th2 / 48.0
        dw = 1.0 - th2 / 8.0
    else:
        th = math.sqrt(th2)
        s = math.sin(0.5 * th) / th
        dw = math.cos(0.5 * th)
    dx, dy, dz = s * rx, s * ry, s * rz
    aw, ax, ay, az = q[0], q[1], q[2], q[3]
    w = aw * dw - ax * dx - ay * dy - az * dz
    x = aw * dx + ax * dw + ay * dz - az * dy
    y = aw * dy - ax * dz + ay * dw + az * dx
    z = aw * dz + ax * dy - ay * dx + az * dw
    n = math.sqrt(w * w + x * x + y * y + z * z)
    q[0], q[1], q[2], q[3] = w / n, x / n, y / n, z / n


@njit(cache=True, no_cfunc_wrapper=True)
def _propagate(q, b, P, w_gyro, rate_noise, dt, sigma_v, sigma_u, phi, qd, m1, m2):
    wx, wy, wz = w_gyro[0] - b[0], w_gyro[1] - b[1], w_gyro[2] - b[2]
    _transition_into(wx, wy, wz, dt, sigma_v, sigma_u, phi, qd)
    # extra angle random walk on the axes whose reading is unreliable (a saturated gyro)
    qd[0, 0] += rate_noise[0] * dt
    qd[1, 1] += rate_noise[1] * dt
    qd[2, 2] += rate_noise[2] * dt
    _rotate_by(q, wx * dt, wy * dt, wz * dt)
    _predict_model_cov_into(P, phi, qd, m1, m2)


@njit(cache=True, no_cfunc_wrapper=True)
def fuse_frame(q, b, P, t_s, wg, tg, qm, tm, rs, sigma_v, sigma_u, gate_chi2, accepted, phi, qd, z_last, rate_noise,
               nis_out, z_out, s_out):
    """One frame of the MEKF: gyro intervals and attitude samples in time order, sequential updates.

    Gyro sample ``g`` is the rate over ``(tg[g-1], tg[g]]`` (the first from ``t_s``). Each attitude sample is
    applied at its time ``tm[i]``, reached with the gyro sample covering it; samples at one instant are applied
    one after the other. After each accepted update the error state is folded into ``q`` and ``b`` (multiplicative
    reset, x back to zero). The filter ends at ``tg[-1]``.

    Parameters
    ----------
    q : ndarray, shape (4,)
        Attitude estimate (w, x, y, z), unit, body -> ICRS; updated in place.
    b : ndarray, shape (3,)
        Gyro bias estimate, rad/s; updated in place.
    P : ndarray, shape (6, 6)
        Error covariance (rad², (rad/s)²); updated in place.
    t_s : float
        Time of the estimate, s.
    wg : ndarray, shape (G, 3)
        Measured gyro rates, rad/s (G >= 1).
    tg : ndarray, shape (G,)
        End time of each gyro interval, s, strictly increasing, > ``t_s``.
    qm : ndarray, shape (M, 4)
        Unit attitude samples (w, x, y, z), any sign.
    tm : ndarray, shape (M,)
        Their times, s, non-decreasing, in ``[t_s, tg[-1]]``.
    rs : ndarray, shape (M, 3, 3)
        Body-frame covariance of each sample, rad², symmetric positive definite.
    sigma_v, sigma_u : float
        Angle random walk (rad/√s) and bias random walk (rad/s/√s) of the process noise.
    gate_chi2 : float
        Reject a sample whose normalised innovation squared ``zᵀ S⁻¹ z`` exceeds this (``inf``: accept all).
    accepted : ndarray of bool, shape (M,)
        Output: which samples were applied.
    phi, qd : ndarray, shape (6, 6)
        Output: Φ and Q of the last propagation (unchanged when there was none).
    z_last : ndarray, shape (3,)
        Output: innovation of the last sample (unchanged when M = 0).
    rate_noise : ndarray, shape (G, 3)
        Extra angle-random-walk variance density of each gyro interval per body axis, rad²/s, added to the attitude
        block of Q as ``rate_noise · dt``: zero for a healthy reading, the square of the rate uncertainty for an
        axis whose reading is saturated (its true rate is unknown beyond the reading).
    nis_out : ndarray, shape (M,)
        Output: normalised innovation squared ``zᵀ S⁻¹ z`` of each sample against the filter just before it (3 dof:
        χ²(3) for a consistent filter), whether or not the gate accepted it.
    z_out : ndarray, shape (M, 3)
        Output: each sample's innovation ``z`` (rotation vector, rad).
    s_out : ndarray, shape (M, 3, 3)
        Output: its covariance ``S = P_θθ + R`` (rad²).

    Returns
    -------
    t_end : float
        Time of the estimate at the end, s (``tg[-1]``, or a later sample time within rounding).
    n_accepted : int
        Number of accepted samples.
    n_propagations : int
        Number of propagation steps (intervals of non-zero length).
    """
    n_g = tg.shape[0]
    m = qm.shape[0]
    tmp = np.empty((6, 6))
    k = np.empty((6, 3))
    kr = np.empty((6, 3))
    m1 = np.empty((3, 3))
    m2 = np.empty((3, 3))
    s = np.empty((3, 3))
    s_inv = np.empty((3, 3))
    dx = np.zeros(6)
    x0 = np.zeros(6)
    t = t_s
    g = 0
    n_acc = 0
    n_prop = 0
    w_gyro = wg[0]
    for i in range(m + 1):
        last = i == m
        t_next = tg[n_g - 1] if last else tm[i]
        # whole gyro intervals that end before the next event
        while g < n_g and (last or tg[g] < t_next):
            w_gyro = wg[g]
            dt = tg[g] - t
            if dt > 0.0:
                _propagate(q, b, P, w_gyro, rate_noise[g], dt, sigma_v, sigma_u, phi, qd, m1, m2)
                n_prop += 1
                t = tg[g]
            g += 1
        if last:
            break
        gi = g if g < n_g else n_g - 1
        w_gyro = wg[gi]
        dt = t_next - t
        if dt > 0.0:
            _propagate(q, b, P, w_gyro, rate_noise[gi], dt, sigma_v, sigma_u, phi, qd, m1, m2)
            n_prop += 1
            t = t_next
        z0, z1, z2 = _residual(q[0], q[1], q[2], q[3], qm[i, 0], qm[i, 1], qm[i, 2], qm[i, 3])
        z_last[0], z_last[1], z_last[2] = z0, z1, z2
        r = rs[i]
        for a in range(3):
            for c in range(3):
                s[a, c] = P[a, c] + r[a, c]
        _inv3_sym_into(s, s_inv)
        nis = (
            (z0 * s_inv[0, 0] + z1 * s_inv[1, 0] + z2 * s_inv[2, 0]) * z0
            + (z0 * s_inv[0, 1] + z1 * s_inv[1, 1] + z2 * s_inv[2, 1]) * z1
            + (z0 * s_inv[0, 2] + z1 * s_inv[1, 2] + z2 * s_inv[2, 2]) * z2
        )
        nis_out[i] = nis
        z_out[i, 0], z_out[i, 1], z_out[i, 2] = z0, z1, z2
        for a in range(3):
            for c in range(3):
                s_out[i, a, c] = s[a, c]
        if nis > gate_chi2:
            accepted[i] = False
            continue
        accepted[i] = True
        _update_into(x0, P, z0, z1, z2, r, s_inv, k, kr, tmp, dx, P)
        _rotate_by(q, dx[0], dx[1], dx[2])
        b[0] += dx[3]
        b[1] += dx[4]
        b[2] += dx[5]
        n_acc += 1
    return t, n_acc, n_prop


@njit(cache=True, no_cfunc_wrapper=True)
def quat_advance(q, rotvec):
    """``normalise(q ⊗ exp(rotvec))``: an attitude turned by a body-frame rotation vector.

    Used for the propagation (``rotvec = ω̂ dt``) and for the multiplicative reset (``rotvec = δθ``).

    Parameters
    ----------
    q : ndarray, shape (4,)
        Unit quaternion (w, x, y, z).
    rotvec : ndarray, shape (3,)
        Rotation vector, rad, in the frame ``q`` maps from (body).

    Returns
    -------
    ndarray, shape (4,)
        Unit quaternion.
    """
    out = q.copy()
    _rotate_by(out, rotvec[0], rotvec[1], rotvec[2])
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def innovation_window(nis, z, s, ring_nis, ring_n, ring_z, ring_s, slot):
    """Store one delivery's innovation sums in a ring and return the window's and the delivery's statistics.

    Parameters
    ----------
    nis : ndarray, shape (M,)
        Normalised innovation squared of each sample of the delivery (NaN: not fused; skipped).
    z : ndarray, shape (F, 3)
        Innovations of the fused samples, rad.
    s : ndarray, shape (F, 3, 3)
        Their covariances ``S``, rad².
    ring_nis, ring_n : ndarray, shape (K,)
        Per-delivery sums of NIS and sample counts (0 marks an empty slot); slot ``slot`` is overwritten.
    ring_z : ndarray, shape (K, 3)
        Per-delivery sums of innovations.
    ring_s : ndarray, shape (K, 3, 3)
        Per-delivery sums of their covariances.
    slot : int
        Slot to write, in [0, K).

    Returns
    -------
    nis_total : float
        Σ NIS over the window: χ²(3 n) for a consistent filter.
    n : float
        Samples in the window.
    mean_chi2 : float
        ``(Σ z)ᵀ (Σ S)⁻¹ (Σ z)`` over the window: χ²(3) for a white innovation sequence (0 for an empty window).
    delivery_chi2 : float
        The same over this delivery's ``z`` and ``s`` alone (0 when it has none).
    max_nis : float
        The delivery's largest NIS (NaN skipped; 0 when none).
    n_nis : float
        How many of its NIS are not NaN.
    """
    total = 0.0
    count = 0.0
    max_nis = 0.0
    for i in range(nis.shape[0]):
        if nis[i] == nis[i]:
            total += nis[i]
            count += 1.0
            if nis[i] > max_nis:
                max_nis = nis[i]
    ring_nis[slot] = total
    ring_n[slot] = count
    for a in range(3):
        acc = 0.0
        for i in range(z.shape[0]):
            acc += z[i, a]
        ring_z[slot, a] = acc
        for c in range(3):
            acc = 0.0
            for i in range(s.shape[0]):
                acc += s[i, a, c]
            ring_s[slot, a, c] = acc
    s_inv = np.empty((3, 3))
    delivery_chi2 = 0.0
    if z.shape[0] > 0:
        _inv3_sym_into(ring_s[slot], s_inv)
        for a in range(3):
            for c in range(3):
                delivery_chi2 += ring_z[slot, a] * s_inv[a, c] * ring_z[slot, c]
    nis_total = 0.0
    n = 0.0
    zs = np.zeros(3)
    ss = np.zeros((3, 3))
    for k in range(ring_n.shape[0]):
        if ring_n[k] > 0.0:
            nis_total += ring_nis[k]
            n += ring_n[k]
            for a in range(3):
                zs[a] += ring_z[k, a]
                for c in range(3):
                    ss[a, c] += ring_s[k, a, c]
    if n == 0.0:
        return nis_total, n, 0.0, delivery_chi2, max_nis, count
    _inv3_sym_into(ss, s_inv)
    mean_chi2 = 0.0
    for a in range(3):
        for c in range(3):
            mean_chi2 += zs[a] * s_inv[a, c] * zs[c]
    return nis_total, n, mean_chi2, delivery_chi2, max_nis, count


@njit(cache=True, no_cfunc_wrapper=True)
def timing_statistic(u, z, s, r_cov, loose_ratio):
    """The timing test of a delivery against the gyro-propagated prediction, along the body rate.

    A timestamp error δt shared by the samples moves each by ``ω δt`` along ``u``. With ``r_i = uᵀ R_i u`` and ``p``
    the prediction's variance along ``u`` (``uᵀ S_i u − r_i``, the largest over the samples), the weighted mean
    innovation along ``u``, ``c = Σ (uᵀ z_i / r_i) / Σ 1 / r_i``, has variance ``p + 1 / Σ 1 / r_i`` without one.

    Parameters
    ----------
    u : ndarray, shape (3,)
        Unit vector of the body rate (body frame).
    z : ndarray, shape (M, 3)
        Each sample's innovation against the prediction, rad (M ≥ 1).
    s : ndarray, shape (M, 3, 3)
        Its covariance, prediction's plus the sample's, rad².
    r_cov : ndarray, shape (M, 3, 3)
        The samples' own covariances ``R_i``, rad².
    loose_ratio : float
        ``p`` beyond this many times the smallest ``r_i`` makes the prediction loose.

    Returns
    -------
    statistic : float
        ``c² / (p + 1 / Σ 1 / r_i)``: χ²(1) without a timing error.
    loose : bool
        Whether ``p > loose_ratio · min r_i``: the test cannot vouch for the frame.
    """
    p = -math.inf
    r_min = math.inf
    sum_inv = 0.0
    sum_c = 0.0
    for i in range(z.shape[0]):
        r = 0.0
        si = 0.0
        for a in range(3):
            for c in range(3):
                r += u[a] * r_cov[i, a, c] * u[c]
                si += u[a] * s[i, a, c] * u[c]
        if si - r > p:
            p = si - r
        if r < r_min:
            r_min = r
        sum_inv += 1.0 / r
        sum_c += (u[0] * z[i, 0] + u[1] * z[i, 1] + u[2] * z[i, 2]) / r
    if p < 0.0:
        p = 0.0
    v = 1.0 / sum_inv
    c = sum_c * v
    return c * c / (p + v), p > loose_ratio * r_min


@njit(cache=True, no_cfunc_wrapper=True)
def saturated_rate_noise(omega, omega_prev, limit_rad_s, check_repeat, noise_rad2_s, out):
    """Extra process noise of the gyro axes whose reading is saturated.

    An axis of sample ``g`` is saturated when ``|ω| >= limit_rad_s``, or, with ``check_repeat``, when it equals the
    previous sample's reading bit for bit (a clip below the range; a noisy gyro never repeats a value).

    Parameters
    ----------
    omega : ndarray, shape (G, 3)
        Gyro readings, rad/s.
    omega_prev : ndarray, shape (3,)
        The reading before ``omega[0]``, rad/s.
    limit_rad_s : float
        The gyro's range, rad/s.
    check_repeat : bool
        Flag repeated readings too.
    noise_rad2_s : float
        Angle-random-walk variance density given to a saturated axis, rad²/s.
    out : ndarray, shape (G, 3)
        Output: ``noise_rad2_s`` on saturated axes, 0 elsewhere.

    Returns
    -------
    int
        Index of the last sample with a saturated axis, -1 when none is.
    """
    last = -1
    for g in range(omega.shape[0]):
        for a in range(3):
            w = omega[g, a]
            prev = omega_prev[a] if g == 0 else omega[g - 1, a]
            if abs(w) >= limit_rad_s or (check_repeat and w == prev):
                out[g, a] = noise_rad2_s
                last = g
            else:
                out[g, a] = 0.0
    return last


@njit(cache=True, no_cfunc_wrapper=True)
def gyro_jump_statistic(y, m, den, first, sigma2, delta_out):
    """Generalised likelihood ratio test for a step in a window of gyro readings (a bias that jumped).

    Under the null hypothesis the readings are a smooth rate (the columns of the design behind ``m``: offset, slope,
    and a slope change at the previous span's end, where a new torque command may act) plus white noise of variance
    ``sigma2`` per axis. The alternative adds a step ``δ`` (3,) from sample ``j`` on. With ``r = m y`` the residual of
    the null fit, the step's estimate is ``δ̂_j = Σ_{g≥j} r_g / den_j`` and its statistic
    ``T_j = |Σ_{g≥j} r_g|² / (den_j σ²)``, χ²(3) for each ``j`` when no step occurred.

    Parameters
    ----------
    y : ndarray, shape (n, 3)
        Gyro readings of the window, rad/s, in time order.
    m : ndarray, shape (n, n)
        Residual projector ``I - X (XᵀX)⁻¹ Xᵀ`` of the null design ``X``.
    den : ndarray, shape (n,)
        ``s_jᵀ m s_j`` with ``s_j`` the step from sample ``j`` (0 where ``j`` is not a candidate).
    first : int
        First candidate sample; candidates are ``first .. n-1`` with ``den_j > 0``.
    sigma2 : float
        Per-axis variance of one reading's noise, (rad/s)².
    delta_out : ndarray, shape (3,)
        Output: ``δ̂`` of the largest statistic, rad/s.

    Returns
    -------
    t_max : float
        The largest ``T_j``.
    j_max : int
        Its sample index (-1 when there is no candidate).
    """
    n = y.shape[0]
    r = np.zeros((n, 3))
    for g in range(n):
        for h in range(n):
            mgh = m[g, h]
            r[g, 0] += mgh * y[h, 0]
            r[g, 1] += mgh * y[h, 1]
            r[g, 2] += mgh * y[h, 2]
    t_max = -1.0
    j_max = -1
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for j in range(n - 1, first - 1, -1):
        s0 += r[j, 0]
        s1 += r[j, 1]
        s2 += r[j, 2]
        d = den[j]
        if d <= 0.0:
            continue
        t = (s0 * s0 + s1 * s1 + s2 * s2) / (d * sigma2)
        if t > t_max:
            t_max = t
            j_max = j
            delta_out[0] = s0 / d
            delta_out[1] = s1 / d
            delta_out[2] = s2 / d
    return t_max, j_max


@njit(cache=True, no_cfunc_wrapper=True)
def delivery_rows(qm, tm):
    """A delivery's attitudes made unit, and whether its instants are in time order.

    Each row is divided by its norm ``√(((q₀² + q₁²) + q₂²) + q₃²)``, numpy's ``q / norm(q, axis=1)[:, None]``
    arithmetic (the same operations in the same order), so the rows are its own bit for bit.

    Parameters
    ----------
    qm : ndarray, shape (M, 4)
        Attitude samples (w, x, y, z), non-zero.
    tm : ndarray, shape (M,)
        Their instants, s.

    Returns
    -------
    q_unit : ndarray, shape (M, 4)
        ``qm`` row by row over its norm (a new array).
    in_order : bool
        Whether ``tm`` is non-decreasing.
    """
    m = qm.shape[0]
    out = np.empty((m, 4))
    for i in range(m):
        s = qm[i, 0] * qm[i, 0] + qm[i, 1] * qm[i, 1]
        s = s + qm[i, 2] * qm[i, 2]
        s = s + qm[i, 3] * qm[i, 3]
        n = math.sqrt(s)
        for c in range(4):
            out[i, c] = qm[i, c] / n
    in_order = True
    for i in range(1, tm.shape[0]):
        if tm[i] < tm[i - 1]:
            in_order = False
            break
    return out, in_order


@njit(cache=True, no_cfunc_wrapper=True)
def delivery_counts(accepted, wrong):
    """A fused delivery's tallies: its last accepted sample, its wrong and its confidently wrong samples.

    Parameters
    ----------
    accepted : ndarray of bool, shape (M,)
        Which samples the filter accepted.
    wrong : ndarray of bool, shape (M,)
        Which samples the verdict found wrong.

    Returns
    -------
    last_accepted : int
        Index of the last accepted sample (-1 when none was).
    n_wrong : int
        Wrong samples.
    n_confidently_wrong : int
        Wrong samples the filter accepted.
    """
    last = -1
    n_wrong = 0
    n_confident = 0
    for i in range(accepted.shape[0]):
        if accepted[i]:
            last = i
        if wrong[i]:
            n_wrong += 1
            if accepted[i]:
                n_confident += 1
    return last, n_wrong, n_confident


@njit(cache=True, no_cfunc_wrapper=True)
def delivery_tallies(accepted, wrong, nis, z, s, ring_nis, ring_n, ring_z, ring_s, slot):
    """A fused delivery's :func:`delivery_counts` and, when it has innovations, its :func:`innovation_window`, in one
    call (the same operations as the two calls one after the other).

    Parameters
    ----------
    accepted, wrong : ndarray of bool, shape (M,)
        As :func:`delivery_counts`.
    nis, z, s, ring_nis, ring_n, ring_z, ring_s, slot :
        As :func:`innovation_window`; with no innovation (``z`` of shape (0, 3)) the ring is left as it is.

    Returns
    -------
    last_accepted, n_wrong, n_confidently_wrong : int
        :func:`delivery_counts`' results.
    windowed : bool
        Whether the delivery had innovations (the window was updated).
    window : tuple of 6 float
        :func:`innovation_window`'s results (zeros when not ``windowed``).
    """
    last, n_wrong, n_confident = delivery_counts(accepted, wrong)
    if z.shape[0] == 0:
        return last, n_wrong, n_confident, False, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return last, n_wrong, n_confident, True, innovation_window(nis, z, s, ring_nis, ring_n, ring_z, ring_s, slot)


@njit(cache=True, no_cfunc_wrapper=True)
def gyro_jump_looks(prev2, prev, cur, m1, den1, first1, m2, den2, first2, sigma2, chi2_max, delta_out):
    """The gyro jump monitor's two looks of a span, in one call: :func:`gyro_jump_statistic` over the previous and
    this span's readings; when it finds no step beyond ``chi2_max``, over the span before, the previous and this one
    (the second look at the previous span), unless ``m2`` is empty.

    Parameters
    ----------
    prev2, prev, cur : ndarray, shape (n2, 3), (n1, 3), (n0, 3)
        Readings of the span before the previous one, the previous one and this one, rad/s.
    m1, den1, first1 : ndarray (n1 + n0, n1 + n0), ndarray (n1 + n0,), int
        The first look's design (see :func:`gyro_jump_statistic`).
    m2, den2, first2 : ndarray (n2 + n1 + n0, n2 + n1 + n0), ndarray (n2 + n1 + n0,), int
        The second look's design; ``m2`` of shape (0, 0): no second look.
    sigma2 : float
        Per-axis variance of one reading's noise, (rad/s)².
    chi2_max : float
        A look finds a step when its largest statistic is not below or at this (NaN finds one).
    delta_out : ndarray, shape (3,)
        Output: the step's estimate of the look that found it, rad/s.

    Returns
    -------
    look : int
        1: the first look found a step, 2: the second, 0: none.
    j : int
        The step's reading in that look's window (the last look's best candidate when none found one, -1 for none).
    """
    n2, n1, n0 = prev2.shape[0], prev.shape[0], cur.shape[0]
    y = np.empty((n1 + n0, 3))
    for g in range(n1):
        for a in range(3):
            y[g, a] = prev[g, a]
    for g in range(n0):
        for a in range(3):
            y[n1 + g, a] = cur[g, a]
    t_max, j = gyro_jump_statistic(y, m1, den1, first1, sigma2, delta_out)
    if j >= 0 and not t_max <= chi2_max:
        return 1, j
    if m2.shape[0] == 0:
        return 0, j
    y2 = np.empty((n2 + n1 + n0, 3))
    for g in range(n2):
        for a in range(3):
            y2[g, a] = prev2[g, a]
    for g in range(n1 + n0):
        for a in range(3):
            y2[n2 + g, a] = y[g, a]
    d2 = np.zeros(3)
    t_max, j = gyro_jump_statistic(y2, m2, den2, first2, sigma2, d2)
    if j >= 0 and not t_max <= chi2_max:
        delta_out[0], delta_out[1], delta_out[2] = d2[0], d2[1], d2[2]
        return 2, j
    return 0, j


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _copy_state_into(q, b, P, q_out, b_out, P_out):
    """The filter's state (q (4,), b (3,), P (6, 6)) copied into the output arrays, element by element (a slice
    assignment compiles numba's shape check and its error message, ~3 s)."""
    for i in range(4):
        q_out[i] = q[i]
    for i in range(3):
        b_out[i] = b[i]
    for i in range(6):
        for j in range(6):
            P_out[i, j] = P[i, j]


@njit(cache=True, no_cfunc_wrapper=True)
def fuse_frame_timed(q, b, P, t_s, wg, tg, qm, tm, rs, sigma_v, sigma_u, gate_chi2, accepted, phi, qd, z_last,
                     rate_noise, nis_out, z_out, s_out, u, timing_chi2_max, loose_ratio):
    """A delivery's timing test, then its fusion when the test passes: one call for the two.

    First each sample's innovation against the prediction with no update in between (:func:`fuse_frame` on copies
    of ``q``, ``b``, ``P`` with a gate below every NIS) and their :func:`timing_statistic` along ``u``; then, unless
    the statistic is above ``timing_chi2_max``, :func:`fuse_frame` of the samples on ``q``, ``b``, ``P`` in place.
    The same operations as the three calls one after the other.

    Parameters
    ----------
    q, b, P, t_s, wg, tg, qm, tm, rs, sigma_v, sigma_u, gate_chi2, accepted, phi, qd, z_last, rate_noise, nis_out, z_out, s_out :
        As :func:`fuse_frame` (M >= 1); left unchanged when the test fails.
    u : ndarray, shape (3,)
        Unit vector of the body rate (body frame).
    timing_chi2_max : float
        The timing test's threshold: above it the delivery is not fused.
    loose_ratio : float
        As :func:`timing_statistic`.

    Returns
    -------
    statistic : float
        The timing statistic (χ²(1) without a timing error).
    loose : bool
        Whether the prediction was too loose for the test to vouch for the delivery.
    fused : bool
        Whether the samples were fused (the statistic was not above ``timing_chi2_max``).
    t_end : float
        As :func:`fuse_frame` (``t_s`` when not fused).
    n_accepted, n_propagations : int
        As :func:`fuse_frame` (0 when not fused).
    """
    m = qm.shape[0]
    z = np.empty((m, 3))
    s = np.empty((m, 3, 3))
    # the two passes are one up to the first sample (a still frame's ~9 of its ~10 intervals): that stretch is
    # propagated once, as fuse_frame's first loop would, and both passes go on from it (fuse_frame skips the
    # intervals that end before its start: their dt <= 0)
    q0, b0, P0 = q.copy(), b.copy(), P.copy()
    phi0 = np.empty((6, 6))
    qd0 = np.empty((6, 6))
    m1 = np.empty((3, 3))
    m2 = np.empty((3, 3))
    t0 = t_s
    g = 0
    n_pre = 0
    while g < tg.shape[0] and tg[g] < tm[0]:
        dt = tg[g] - t0
        if dt > 0.0:
            _propagate(q0, b0, P0, wg[g], rate_noise[g], dt, sigma_v, sigma_u, phi0, qd0, m1, m2)
            n_pre += 1
            t0 = tg[g]
        g += 1
    fuse_frame(q0.copy(), b0.copy(), P0.copy(), t0, wg, tg, qm, tm, rs, sigma_v, sigma_u, -1.0,
               np.empty(m, dtype=np.bool_), np.empty((6, 6)), np.empty((6, 6)), np.empty(3), rate_noise, np.empty(m),
               z, s)
    stat, loose = timing_statistic(u, z, s, rs, loose_ratio)
    if stat > timing_chi2_max:
        return stat, loose, False, t_s, 0, 0
    # Φ and Q: the second pass propagates at least once more (to tm[0] > t0, or to tg[-1] > t_s), so it sets them
    # element by element: a slice assignment `q[:] = q0` compiles numba's shape check and its error message (~3 s)
    _copy_state_into(q0, b0, P0, q, b, P)
    t, n_acc, n_prop = fuse_frame(q, b, P, t0, wg, tg, qm, tm, rs, sigma_v, sigma_u, gate_chi2, accepted, phi, qd,
                                  z_last, rate_noise, nis_out, z_out, s_out)
    return stat, loose, True, t, n_acc, n_pre + n_prop


@njit(cache=True, no_cfunc_wrapper=True)
def append_intervals(tg, wg, rn, t_new, w_new, rn_new):
    """The gyro buffer of :class:`startracker.filter.DelayedFusion` with G intervals appended (new arrays: the
    ``np.concatenate`` of each pair, values copied as they are).

    Parameters
    ----------
    tg : ndarray, shape (n,)
        Buffered interval ends, s.
    wg : ndarray, shape (n, 3)
        Their rates, rad/s.
    rn : ndarray, shape (n, 3)
        Their extra rate noise, rad²/s.
    t_new : ndarray, shape (G,)
        Ends of the new intervals, s.
    w_new : ndarray, shape (G, 3)
        Their rates, rad/s.
    rn_new : ndarray, shape (G, 3) or (0, 3)
        Their extra rate noise, rad²/s; (0, 3): zero.

    Returns
    -------
    tg : ndarray, shape (n + G,)
    wr : ndarray, shape (2, n + G, 3)
        ``wr[0]``: the rates ``wg``; ``wr[1]``: the rate noise ``rn`` (one array: every array handed back to Python
        costs a boxing of its own).
    """
    n = tg.shape[0]
    g = t_new.shape[0]
    tg2 = np.empty(n + g)
    wr = np.empty((2, n + g, 3))
    wg2 = wr[0]
    rn2 = wr[1]
    for i in range(n):
        tg2[i] = tg[i]
        for a in range(3):
            wg2[i, a] = wg[i, a]
            rn2[i, a] = rn[i, a]
    zero_noise = rn_new.shape[0] == 0
    for i in range(g):
        tg2[n + i] = t_new[i]
        for a in range(3):
            wg2[n + i, a] = w_new[i, a]
            rn2[n + i, a] = 0.0 if zero_noise else rn_new[i, a]
    return tg2, wr


@njit(cache=True, no_cfunc_wrapper=True)
def propagate_buffer(q, b, P, t_s, wg, tg, rate_noise, sigma_v, sigma_u):
    """The estimate at the end of a gyro buffer: :func:`fuse_frame` without samples on copies of ``q``, ``b``, ``P``.

    Parameters
    ----------
    q : ndarray, shape (4,)
        Attitude estimate (w, x, y, z), unit, at ``t_s`` (not changed).
    b : ndarray, shape (3,)
        Gyro bias estimate, rad/s (not changed).
    P : ndarray, shape (6, 6)
        Error covariance, rad² and (rad/s)² (not changed).
    t_s : float
        Time of the estimate, s.
    wg : ndarray, shape (G, 3)
        Measured gyro rates of the buffered intervals, rad/s (G >= 1).
    tg : ndarray, shape (G,)
        End of each interval, s, strictly increasing.
    rate_noise : ndarray, shape (G, 3)
        Extra angle-random-walk variance density of each interval, rad²/s (see :func:`fuse_frame`).
    sigma_v, sigma_u : float
        Angle random walk (rad/√s) and bias random walk (rad/s/√s).

    Returns
    -------
    q_now : ndarray, shape (4,)
        Attitude at ``tg[-1]``.
    b_now : ndarray, shape (3,)
        Bias, rad/s.
    P_now : ndarray, shape (6, 6)
        Error covariance.
    omega : ndarray, shape (3,)
        Bias-corrected rate of the last interval ``wg[-1] - b_now``, rad/s.
    t_now : float
        ``tg[-1]``, s.
    """
    q2 = np.empty(4)
    b2 = np.empty(3)
    P2 = np.empty((6, 6))
    _copy_state_into(q, b, P, q2, b2, P2)
    fuse_frame(q2, b2, P2, t_s, wg, tg, np.empty((0, 4)), np.empty(0), np.empty((0, 3, 3)), sigma_v, sigma_u, math.inf,
               np.empty(0, dtype=np.bool_), np.empty((6, 6)), np.empty((6, 6)), np.empty(3), rate_noise, np.empty(0),
               np.empty((0, 3)), np.empty((0, 3, 3)))
    n = tg.shape[0]
    omega = np.empty(3)
    for a in range(3):
        omega[a] = wg[n - 1, a] - b2[a]
    return q2, b2, P2, omega, tg[n - 1]


@njit(cache=True, no_cfunc_wrapper=True)
def reported_attitude(q_true, q, P, widen, extra_rad2):
    """The reported attitude covariance of an estimate, its verdict's NIS against the truth and its largest variance.

    The covariance is the attitude block of ``P``, its diagonal widened by ``extra_rad2`` when ``widen`` (a drift the
    monitors may have missed); the NIS is :func:`startracker.kernels.sensor.consistency_nis` of ``q`` on it.

    Parameters
    ----------
    q_true : ndarray, shape (4,)
        True attitude (w, x, y, z), unit.
    q : ndarray, shape (4,)
        Estimated attitude, unit.
    P : ndarray, shape (6, 6) (or at least (3, 3))
        Error covariance; its upper-left (3, 3) block, rad², is the attitude's.
    widen : bool
        Whether ``extra_rad2`` is added to the diagonal.
    extra_rad2 : float
        Variance added to each axis, rad².

    Returns
    -------
    cov : ndarray, shape (3, 3)
        Reported attitude covariance, rad² (a new array).
    nis : float
        ``δθᵀ cov⁻¹ δθ`` with ``δθ = log(q* ⊗ q_true)`` (χ²(3) when the covariance tells the truth).
    max_var : float
        The largest diagonal element of ``cov`` (the first of equals; Python's ``max`` of the three), rad².
    """
    cov = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            cov[i, j] = P[i, j]
    if widen:
        cov[0, 0] += extra_rad2
        cov[1, 1] += extra_rad2
        cov[2, 2] += extra_rad2
    qt = np.empty((1, 4))
    qe = np.empty((1, 4))
    for i in range(4):
        qt[0, i] = q_true[i]
        qe[0, i] = q[i]
    c3 = np.empty((1, 3, 3))
    for i in range(3):
        for j in range(3):
            c3[0, i, j] = cov[i, j]
    nis = consistency_nis(qt, qe, c3)[0]
    max_var = cov[0, 0]
    if cov[1, 1] > max_var:
        max_var = cov[1, 1]
    if cov[2, 2] > max_var:
        max_var = cov[2, 2]
    return cov, nis, max_var


@njit(cache=True, no_cfunc_wrapper=True)
def fuse_buffer_timed(q, b, P, t_s, wg_buf, tg_buf, rn_buf, qm, tm, rs, sigma_v, sigma_u, gate_chi2, u, timing_chi2_max,
                      loose_ratio):
    """:func:`fuse_frame_timed` of a delivery on the delayed fusion's gyro buffer, on fresh copies of the filter.

    The buffered intervals up to the last sample's instant ``tm[-1]`` are taken, the one covering it (the first that
    ends at or after it) cut there, and :func:`fuse_frame_timed` runs on copies of ``q``, ``b``, ``P`` with fresh
    output arrays: the arithmetic of :meth:`startracker.filter.DelayedFusion.fuse_timed`'s usual case in one call.

    Parameters
    ----------
    q, b, P, t_s :
        The filter (as :func:`fuse_frame`; not changed).
    wg_buf, tg_buf, rn_buf : ndarray, shape (n, 3), (n,), (n, 3)
        The buffer's rates (rad/s), interval ends (s, strictly increasing) and extra rate noise (rad²/s).
    qm, tm, rs :
        The samples (M >= 1, time order, ``tm[0] >= t_s``), as :func:`fuse_frame`.
    sigma_v, sigma_u, gate_chi2 :
        As :func:`fuse_frame`.
    u, timing_chi2_max, loose_ratio :
        As :func:`fuse_frame_timed`.

    Returns
    -------
    reached : bool
        Whether a buffered interval reaches ``tm[-1]``; when not, nothing else is computed (the arrays are empty and
        the scalars zero).
    j : int
        The buffered interval covering ``tm[-1]`` (``np.searchsorted(tg_buf, tm[-1])``; ``n`` when none reaches it).
    keep_from : int
        The first buffered interval that ends after ``tm[-1]`` (the buffer to keep after a fusion).
    statistic, loose, fused, t_end, n_accepted, n_propagations :
        As :func:`fuse_frame_timed`.
    qbz : ndarray, shape (10 + M,)
        ``qbz[:4]``, ``qbz[4:7]``: ``q_new``, ``b_new``, the filter after the fusion (the copies, unchanged when not
        fused); ``qbz[7:10]``: ``z_last``; ``qbz[10:]``: ``nis``.
    mats : ndarray, shape (3, 6, 6)
        ``mats[0]``: ``P_new`` (as ``q_new``); ``mats[1]``, ``mats[2]``: ``phi``, ``qd``.
    accepted, z, s : ndarray, shape (M,), (M, 3), (M, 3, 3)
        The outputs of :func:`fuse_frame` (``phi``, ``qd`` and ``z_last`` as allocated, uninitialised, when there was
        no propagation or sample).

    Notes
    -----
    The outputs of one shape class share one array (``q_new``, ``b_new``, ``z_last``, ``nis`` its contiguous slices,
    the matrices its rows), written through those views: every array handed back to Python costs a boxing of its own.
    """
    m = qm.shape[0]
    n = tg_buf.shape[0]
    t_last = tm[m - 1]
    j = 0  # np.searchsorted(tg_buf, t_last, side="left")
    while j < n and tg_buf[j] < t_last:
        j += 1
    qbz = np.empty(10 + m)
    q2 = qbz[0:4]
    b2 = qbz[4:7]
    z_last = qbz[7:10]
    nis = qbz[10:]
    mats = np.empty((3, 6, 6))
    P2 = mats[0]
    phi = mats[1]
    qd = mats[2]
    accepted = np.empty(m, dtype=np.bool_)
    zs = np.empty((m, 3))
    ss = np.empty((m, 3, 3))
    if j == n:
        return (False, j, j, 0.0, False, False, 0.0, 0, 0, qbz, mats, accepted, zs, ss)
    _copy_state_into(q, b, P, q2, b2, P2)
    tg = np.empty(j + 1)
    wg = np.empty((j + 1, 3))
    rn = np.empty((j + 1, 3))
    for i in range(j + 1):
        tg[i] = tg_buf[i]
        for a in range(3):
            wg[i, a] = wg_buf[i, a]
            rn[i, a] = rn_buf[i, a]
    tg[j] = t_last
    stat, loose, fused, t, n_acc, n_prop = fuse_frame_timed(q2, b2, P2, t_s, wg, tg, qm, tm, rs, sigma_v, sigma_u,
                                                            gate_chi2, accepted, phi, qd, z_last, rn, nis, zs, ss, u,
                                                            timing_chi2_max, loose_ratio)
    keep_from = j if tg_buf[j] > t_last else j + 1
    return (True, j, keep_from, stat, loose, fused, t, n_acc, n_prop, qbz, mats, accepted, zs, ss)
