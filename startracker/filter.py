"""Attitude estimation: a multiplicative EKF (MEKF) fusing a gyro with star-tracker attitudes.

The filter is built on :class:`filterpy.kalman.ExtendedKalmanFilter`. Its 6-element error state is

    x = [δθ (3), δb (3)],   q_true = q̂ ⊗ exp(δθ)  (body-frame attitude error, rad),   b_true = b̂ + δb (rad/s)

and the full attitude ``q̂`` (``q_body_to_icrs``, w x y z) and bias ``b̂`` live outside it (Markley 2003;
Crassidis & Markley, *Fundamentals of Spacecraft Attitude Determination and Control*, §6.2). After every
measurement update the error is folded into ``q̂`` and ``b̂`` and ``x`` is reset to zero.

Gyro model (consistent with :mod:`startracker.imu`): ``ω_gyro = ω + b + n_v``, ``ḃ = n_u``, with
``n_v`` the angle random walk (density σ_v, rad/√s) and ``n_u`` the bias random walk (σ_u, rad/s/√s).
Propagation over ``dt`` with ``ω̂ = ω_gyro - b̂`` (held constant over ``dt``):

    q̂ ← q̂ ⊗ exp(ω̂ dt)
    Φ = [[exp(-[ω̂×] dt), -∫₀^dt exp(-[ω̂×] s) ds], [0, I]]          (closed forms below)
    Q = [[σ_v² dt + σ_u² dt³/3, -σ_u² dt²/2], [-σ_u² dt²/2, σ_u² dt]] ⊗ I₃
    P ← Φ P Φᵀ + Q

Measurement: a star-tracker attitude ``q_meas = q_true ⊗ exp(v)``, ``v ~ N(0, R)`` with ``R`` the (3, 3)
body-frame covariance (rad²) of the sample; residual ``z = log(q̂* ⊗ q_meas)`` (rotation vector),
``H = [I₃, 0]``. filterpy's update is called with ``z.reshape(-1, 1)`` (its ``x`` is a column vector and
a 1-D ``z`` would broadcast to (3, 3)).

Three code paths:

- :meth:`AttitudeEKF.propagate` / :meth:`AttitudeEKF.update`: one call per gyro interval / attitude
  sample through filterpy's ``predict`` and ``update`` (about 25 + 60 µs per sample on the dev machine);
- :meth:`AttitudeEKF.process` with ``method="sequential"``: a whole frame (gyro samples and N attitude
  samples merged in time order) with the same algebra on plain arrays; equal to the filterpy path to
  rounding (1e-13), about 3x cheaper per sample;
- :meth:`AttitudeEKF.process` with ``method="batch"``: the frame-end state conditioned on all N samples
  in one 3N x 3N solve, with the exact cross-covariances that process noise creates between samples
  taken at different instants. It is the same linear-Gaussian estimate linearised once, about the
  frame's prior trajectory, instead of after every sample: it agrees with the sequential path to second
  order in the attitude error (< 1e-4 σ while tracking) and its cost barely grows with N.

Numerical note: the batch path calls LAPACK on 3N x 3N matrices; with a multi-threaded OpenBLAS on a
busy machine, set ``OPENBLAS_NUM_THREADS=1`` (thread hand-off costs more than these small solves).

The multiplicative reset's covariance correction (second order in δθ) is neglected, as usual.

The module is over 600 lines because the sequential and the batch update are two paths of one filter
(:class:`AttitudeEKF`) that must agree, and are kept side by side.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.linalg.lapack import dposv

from startracker.validation import as_float_array, check_positive

__all__ = ["AttitudeEKF", "ARW_FLOOR_RAD_SQRT_S", "BIAS_SIGMA_FLOOR_RAD_S"]

_I6 = np.eye(6)
_AUTO_BATCH_MIN_SAMPLES = 8  # measured break-even of the batch path's fixed cost
_H = np.hstack([np.eye(3), np.zeros((3, 3))])


# Floors of :meth:`AttitudeEKF.from_gyro_spec`
ARW_FLOOR_RAD_SQRT_S = 1e-7
BIAS_SIGMA_FLOOR_RAD_S = 1e-7


def _hjacobian(_x):
    return _H


def _hx(x):
    return x[:3]


def _qmul(a, b):
    """Hamilton product of two quaternions given as sequences of 4 floats, returns a list."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]


def _qexp(rx, ry, rz):
    """Quaternion of a rotation vector (rad), as a list."""
    th2 = rx * rx + ry * ry + rz * rz
    if th2 < 1e-16:
        s = 0.5 - th2 / 48.0
        return [1.0 - th2 / 8.0, s * rx, s * ry, s * rz]
    th = math.sqrt(th2)
    s = math.sin(0.5 * th) / th
    return [math.cos(0.5 * th), s * rx, s * ry, s * rz]


def _qlog_residual(q_est, q_meas):
    """Rotation vector of ``q_est* ⊗ q_meas`` (body frame), sign-invariant, as a list."""
    ew, ex, ey, ez = q_est
    dq = _qmul((ew, -ex, -ey, -ez), q_meas)
    w, x, y, z = dq
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    vn = math.sqrt(x * x + y * y + z * z)
    if vn < 1e-15:
        return [2.0 * x, 2.0 * y, 2.0 * z]
    k = 2.0 * math.atan2(vn, w) / vn
    return [k * x, k * y, k * z]


def _normalized(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [q[0] / n, q[1] / n, q[2] / n, q[3] / n]


def _inv3_sym(s):
    """Inverse of a symmetric positive-definite (3, 3) array by the adjugate (floats, no LAPACK call)."""
    (a, b, c), (_, d, e), (_, _, f) = s.tolist()
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    return np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]) / det


# Left-multiplication matrix of a quaternion: q ⊗ p = L(q) p with L(q)[r, c] = sign[r, c] * q[index[r, c]]
_L_INDEX = np.array([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_L_SIGN = np.array([[1.0, -1.0, -1.0, -1.0], [1.0, 1.0, -1.0, 1.0], [1.0, 1.0, 1.0, -1.0], [1.0, -1.0, 1.0, 1.0]])
# skew(w).ravel() = w @ _SKEW
_SKEW = np.array(
    [
        [0, 0, 0, 0, 0, -1, 0, 1, 0],
        [0, 0, 1, 0, 0, 0, -1, 0, 0],
        [0, -1, 0, 1, 0, 0, 0, 0, 0],
    ],
    dtype=float,
)
_Q_BASIS = np.zeros((3, 6, 6))  # Q = q11 E11 + q12 E12 + q22 E22
_Q_BASIS[0, :3, :3] = _Q_BASIS[1, :3, 3:] = _Q_BASIS[1, 3:, :3] = _Q_BASIS[2, 3:, 3:] = np.eye(3)
_Q_BASIS = _Q_BASIS.reshape(3, 36)
_I3 = np.eye(3)
_I9 = np.eye(3).ravel()


def _qmul_v(a, b):
    """Hamilton product of (k, 4) quaternion arrays."""
    return ((a[:, _L_INDEX] * _L_SIGN) @ b[:, :, None])[:, :, 0]


def _qexp_v(rv):
    """Quaternions (k, 4) of rotation vectors (k, 3), rad."""
    th = np.sqrt((rv * rv).sum(axis=1))
    half = 0.5 * th
    tiny = th < 1e-6
    s = np.where(tiny, 0.5 - th * th / 48.0, np.sin(half) / np.where(tiny, 1.0, th))  # sin(θ/2)/θ
    out = np.empty((len(rv), 4))
    out[:, 0] = np.cos(half)
    out[:, 1:] = s[:, None] * rv
    return out


_MASKS: dict[int, np.ndarray] = {}


def _block_lower_mask(k):
    """(3k, 3k) bool mask of the 3x3 blocks on and below the block diagonal (cached)."""
    m = _MASKS.get(k)
    if m is None:
        blk = np.repeat(np.arange(k), 3)
        m = _MASKS[k] = blk[:, None] >= blk[None, :]
    return m


def _qlog_residual_v(q_est, q_meas):
    """Rotation vectors (k, 3) of ``q_est* ⊗ q_meas``, sign-invariant."""
    dq = _qmul_v(q_est * np.array([1.0, -1.0, -1.0, -1.0]), q_meas)
    w = dq[:, 0]
    sgn = np.where(w < 0.0, -1.0, 1.0)
    v = dq[:, 1:] * sgn[:, None]
    w = np.abs(w)
    vn = np.sqrt(np.einsum("ki,ki->k", v, v))
    tiny = vn < 1e-15
    k = np.where(tiny, 2.0, 2.0 * np.arctan2(vn, w) / np.where(tiny, 1.0, vn))
    return k[:, None] * v


def _transition_batch(w_hat, dt, sigma_v, sigma_u):
    """Vectorised :meth:`AttitudeEKF._transition`: Φ and Q, shape (M, 6, 6), for rates (M, 3) over dt (M,)."""
    m = len(dt)
    w2 = (w_hat * w_hat).sum(axis=1)
    th2 = w2 * dt * dt
    small = th2 < 1e-4
    # sin θ / w, (1 - cos θ)/w², (θ - sin θ)/w³, with their series below θ = 0.01
    if small.any():
        series = (
            dt * (1.0 - th2 / 6.0 + th2 * th2 / 120.0),
            dt * dt * (0.5 - th2 / 24.0 + th2 * th2 / 720.0),
            dt**3 * (1.0 / 6.0 - th2 / 120.0 + th2 * th2 / 5040.0),
        )
    if not small.all():
        th = np.sqrt(np.where(small, 1.0, th2))
        w = th / np.where(small, 1.0, dt)
        s, c = np.sin(th), np.cos(th)
        w2s = w * w
        exact = (s / w, (1.0 - c) / w2s, (th - s) / (w2s * w))
    if not small.any():
        coef = exact
    elif small.all():
        coef = series
    else:
        coef = tuple(np.where(small, a, b) for a, b in zip(series, exact))
    wx = w_hat @ _SKEW  # (m, 9) rows of [ω×]
    wx2 = (wx.reshape(m, 3, 3) @ wx.reshape(m, 3, 3)).reshape(m, 9)
    phi = np.zeros((m, 6, 6))
    phi[:, :3, :3] = (_I9 - coef[0][:, None] * wx + coef[1][:, None] * wx2).reshape(m, 3, 3)
    phi[:, :3, 3:] = (coef[1][:, None] * wx - coef[2][:, None] * wx2 - dt[:, None] * _I9).reshape(m, 3, 3)
    phi[:, 3:, 3:] = _I3
    sv2, su2 = sigma_v * sigma_v, sigma_u * sigma_u
    q = (np.stack([sv2 * dt + su2 * dt**3 / 3.0, -0.5 * su2 * dt * dt, su2 * dt], axis=1) @ _Q_BASIS).reshape(m, 6, 6)
    return phi, q


class AttitudeEKF:
    """Multiplicative EKF on filterpy: attitude (outside the filter) + gyro bias.

    Parameters
    ----------
    q_body_to_icrs : array_like, shape (4,)
        Initial attitude estimate (w, x, y, z), body -> world (ICRS).
    arw_rad_sqrt_s : float
        Gyro angle random walk σ_v, rad/√s (> 0).
    rrw_rad_s_sqrt_s : float
        Bias random walk σ_u, rad/s/√s (>= 0); for a Gauss-Markov bias use ``sqrt(K² + 2σ²/τ)``
        (:attr:`startracker.imu.GyroSpec.bias_rw_equivalent_rad_s_sqrt_s`).
    sigma_attitude_rad : float or array_like (3,)
        Initial 1σ attitude error per body axis, rad (> 0).
    sigma_bias_rad_s : float or array_like (3,)
        Initial 1σ bias error per axis, rad/s (> 0).
    bias_rad_s : array_like, shape (3,)
        Initial bias estimate, rad/s. Default zero.
    t_s : float
        Time of the initial estimate, s.
    gate_chi2 : float, optional
        Reject an attitude sample whose normalised innovation squared (3 dof) exceeds this value
        (e.g. 16.27 for p = 0.999). Default: accept every sample.

    Attributes
    ----------
    q_body_to_icrs : ndarray, shape (4,)
        Attitude estimate (w, x, y, z), unit norm, ``w >= 0`` not enforced.
    bias_rad_s : ndarray, shape (3,)
        Gyro bias estimate, rad/s.
    t_s : float
        Time of the estimate, s.
    omega_body : ndarray, shape (3,)
        Bias-corrected rate of the last propagation, rad/s (body frame).
    ekf : filterpy.kalman.ExtendedKalmanFilter
        The underlying filter: ``ekf.x`` (6, 1) error state (zero between calls), ``ekf.P`` (6, 6),
        ``ekf.Q`` (last process noise), ``ekf.R`` (last measurement covariance), ``ekf.y`` (last residual).
    n_updates, n_rejected : int
        Accepted and gated-out attitude samples.
    """

    def __init__(
        self,
        q_body_to_icrs,
        *,
        arw_rad_sqrt_s: float,
        rrw_rad_s_sqrt_s: float = 0.0,
        sigma_attitude_rad=math.radians(1.0),
        sigma_bias_rad_s=math.radians(10.0) / 3600.0,
        bias_rad_s=(0.0, 0.0, 0.0),
        t_s: float = 0.0,
        gate_chi2: float | None = None,
    ):
        q = as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4, ndim=1)
        nq = float(np.linalg.norm(q))
        if nq < 1e-12:
            raise ValueError("q_body_to_icrs must be a non-zero quaternion")
        self.sigma_v = check_positive(arw_rad_sqrt_s, "arw_rad_sqrt_s")
        self.sigma_u = float(as_float_array(rrw_rad_s_sqrt_s, "rrw_rad_s_sqrt_s"))
        if self.sigma_u < 0.0:
            raise ValueError(f"rrw_rad_s_sqrt_s must be >= 0, got {rrw_rad_s_sqrt_s}")
        sa = np.broadcast_to(as_float_array(sigma_attitude_rad, "sigma_attitude_rad"), (3,))
        sb = np.broadcast_to(as_float_array(sigma_bias_rad_s, "sigma_bias_rad_s"), (3,))
        if np.any(sa <= 0.0):
            raise ValueError(f"sigma_attitude_rad must be > 0, got {sigma_attitude_rad}")
        if np.any(sb <= 0.0):
            raise ValueError(f"sigma_bias_rad_s must be > 0, got {sigma_bias_rad_s}")
        b = as_float_array(bias_rad_s, "bias_rad_s", last_dim=3, ndim=1)
        if gate_chi2 is not None:
            gate_chi2 = check_positive(gate_chi2, "gate_chi2")
        self.gate_chi2 = gate_chi2

        self.q_body_to_icrs = q / nq
        self.bias_rad_s = b.copy()
        self.t_s = float(as_float_array(t_s, "t_s"))
        self.omega_body = np.zeros(3)
        self._omega_gyro_last = np.zeros(3)
        self.n_updates = 0
        self.n_rejected = 0

        self.ekf = ExtendedKalmanFilter(dim_x=6, dim_z=3)
        self.ekf.x = np.zeros((6, 1))
        self.ekf.P = np.diag(np.concatenate([sa**2, sb**2]))
        self.ekf.Q = np.zeros((6, 6))

    @classmethod
    def from_gyro_spec(
        cls,
        spec,
        q_body_to_icrs,
        *,
        arw_floor_rad_sqrt_s: float = ARW_FLOOR_RAD_SQRT_S,
        bias_sigma_floor_rad_s: float = BIAS_SIGMA_FLOOR_RAD_S,
        **kwargs,
    ) -> "AttitudeEKF":
        """Filter tuned to a :class:`startracker.imu.GyroSpec`: the one way to build the filter for a gyro.

        Derived values: ``arw_rad_sqrt_s = max(spec.arw_rad_sqrt_s, arw_floor_rad_sqrt_s)``;
        ``rrw_rad_s_sqrt_s = spec.bias_rw_equivalent_rad_s_sqrt_s``; ``sigma_bias_rad_s = max(spec.bias_sigma_rad_s
        + spec.gm_sigma_rad_s, bias_sigma_floor_rad_s)`` (the sum of the turn-on and Gauss-Markov σ: an initial σ
        too large only slows convergence, one too small makes the filter ignore the gyro's real bias).

        Parameters
        ----------
        spec : startracker.imu.GyroSpec
        q_body_to_icrs : array_like, shape (4,)
            Initial attitude estimate.
        arw_floor_rad_sqrt_s : float
            Smallest angle random walk the filter assumes, rad/√s (default 1e-7: an ideal gyro still leaves the
            filter some process noise, so it keeps listening to the star tracker).
        bias_sigma_floor_rad_s : float
            Smallest initial bias 1σ, rad/s (default 1e-7).
        **kwargs
            Any argument of :class:`AttitudeEKF` (``sigma_attitude_rad``, ``t_s``, ``gate_chi2``, ``bias_rad_s``,
            ...); ``arw_rad_sqrt_s``, ``rrw_rad_s_sqrt_s`` and ``sigma_bias_rad_s`` override the derived values.

        Returns
        -------
        AttitudeEKF
        """
        arw_floor = check_positive(arw_floor_rad_sqrt_s, "arw_floor_rad_sqrt_s")
        bias_floor = check_positive(bias_sigma_floor_rad_s, "bias_sigma_floor_rad_s")
        kw = dict(
            arw_rad_sqrt_s=max(spec.arw_rad_sqrt_s, arw_floor),
            rrw_rad_s_sqrt_s=spec.bias_rw_equivalent_rad_s_sqrt_s,
            sigma_bias_rad_s=max(spec.bias_sigma_rad_s + spec.gm_sigma_rad_s, bias_floor),
        )
        kw.update(kwargs)
        return cls(q_body_to_icrs, **kw)

    def set_bias_covariance(self, covariance_rad2_s2) -> None:
        """Replace the bias block of the error covariance (e.g. to let the filter relearn a bias that jumped).

        The attitude block is kept; the attitude-bias cross-covariance is kept too (zero right after
        construction).

        Parameters
        ----------
        covariance_rad2_s2 : array_like, shape (3, 3)
            New bias covariance, (rad/s)², symmetric positive definite.
        """
        self.ekf.P[3:, 3:] = self._check_cov(covariance_rad2_s2, "covariance_rad2_s2")

    # ------------------------------------------------------------------ views
    @property
    def P(self) -> np.ndarray:
        """Error covariance (6, 6): attitude (rad², body frame) then bias ((rad/s)²)."""
        return self.ekf.P

    @property
    def attitude_sigma_rad(self) -> np.ndarray:
        """1σ attitude uncertainty about each body axis, shape (3,), rad."""
        return np.sqrt(np.diag(self.ekf.P)[:3])

    @property
    def bias_sigma_rad_s(self) -> np.ndarray:
        """1σ bias uncertainty per axis, shape (3,), rad/s."""
        return np.sqrt(np.diag(self.ekf.P)[3:])

    # ------------------------------------------------------------------ algebra shared by both paths
    def _transition(self, w_hat, dt):
        """Φ (6, 6) and Q (6, 6) for a constant bias-corrected rate ``w_hat`` (3 floats) over ``dt``."""
        wx, wy, wz = w_hat
        w2 = wx * wx + wy * wy + wz * wz
        th2 = w2 * dt * dt
        if th2 < 1e-8:  # Taylor series, error < th^4 relative
            c1 = dt * (1.0 - th2 / 6.0)  # sin(w dt)/w
            c2 = dt * dt * (0.5 - th2 / 24.0)  # (1 - cos(w dt))/w²
            c3 = dt**3 * (1.0 / 6.0 - th2 / 120.0)  # (w dt - sin(w dt))/w³
        else:
            w = math.sqrt(w2)
            th = w * dt
            s, c = math.sin(th), math.cos(th)
            c1 = s / w
            c2 = (1.0 - c) / w2
            c3 = (th - s) / (w2 * w)
        # [ω×]² = ω ωᵀ - |ω|² I, written out in floats (one array construction per matrix)
        xx, yy, zz, xy, xz, yz = wx * wx - w2, wy * wy - w2, wz * wz - w2, wx * wy, wx * wz, wy * wz
        # Φ11 = I - c1 [ω×] + c2 [ω×]²;  Φ12 = -dt I + c2 [ω×] - c3 [ω×]²
        a, d = c1, c2
        e, f = c2, c3
        phi = np.array(
            [
                [1.0 + d * xx, a * wz + d * xy, -a * wy + d * xz, -dt - f * xx, -e * wz - f * xy, e * wy - f * xz],
                [-a * wz + d * xy, 1.0 + d * yy, a * wx + d * yz, e * wz - f * xy, -dt - f * yy, -e * wx - f * yz],
                [a * wy + d * xz, -a * wx + d * yz, 1.0 + d * zz, -e * wy - f * xz, e * wx - f * yz, -dt - f * zz],
                [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            ]
        )
        sv2, su2 = self.sigma_v * self.sigma_v, self.sigma_u * self.sigma_u
        q11 = sv2 * dt + su2 * dt * dt * dt / 3.0
        q12 = -0.5 * su2 * dt * dt
        q22 = su2 * dt
        qd = np.array(
            [
                [q11, 0.0, 0.0, q12, 0.0, 0.0],
                [0.0, q11, 0.0, 0.0, q12, 0.0],
                [0.0, 0.0, q11, 0.0, 0.0, q12],
                [q12, 0.0, 0.0, q22, 0.0, 0.0],
                [0.0, q12, 0.0, 0.0, q22, 0.0],
                [0.0, 0.0, q12, 0.0, 0.0, q22],
            ]
        )
        return phi, qd

    def _advance_quaternion(self, w_hat, dt):
        dq = _qexp(w_hat[0] * dt, w_hat[1] * dt, w_hat[2] * dt)
        return _normalized(_qmul(self.q_body_to_icrs.tolist(), dq))

    # ------------------------------------------------------------------ filterpy path
    def propagate(self, omega_gyro, dt: float) -> None:
        """Propagate the estimate and covariance with one gyro rate over ``dt``.

        Parameters
        ----------
        omega_gyro : array_like, shape (3,)
            Measured body rate (bias included), rad/s, held over the interval.
        dt : float
            Interval, s (>= 0; 0 is a no-op).
        """
        w = as_float_array(omega_gyro, "omega_gyro", last_dim=3, ndim=1)
        dt = float(as_float_array(dt, "dt"))
        if dt < 0.0:
            raise ValueError(f"dt must be >= 0, got {dt}")
        self._omega_gyro_last = w.copy()
        w_hat = (w - self.bias_rad_s).tolist()
        self.omega_body = np.array(w_hat)
        if dt == 0.0:
            return
        phi, qd = self._transition(w_hat, dt)
        self.q_body_to_icrs = np.array(self._advance_quaternion(w_hat, dt))
        self.ekf.F = phi
        self.ekf.Q = qd
        self.ekf.predict()
        self.t_s += dt

    def update(self, q_meas_body_to_icrs, covariance_rad2, t: float | None = None, omega_gyro=None) -> bool:
        """Fuse one star-tracker attitude sample taken at time ``t``.

        If ``t`` is later than the estimate, the filter first propagates to ``t`` with ``omega_gyro``
        (or the last gyro rate). Samples must arrive in time order.

        Parameters
        ----------
        q_meas_body_to_icrs : array_like, shape (4,)
            Measured attitude (w, x, y, z), any sign.
        covariance_rad2 : array_like, shape (3, 3)
            Body-frame covariance of the sample's attitude error, rad², symmetric positive definite.
        t : float, optional
            Exposure time of the sample, s, >= the estimate's time. Default: the estimate's time.
        omega_gyro : array_like, shape (3,), optional
            Gyro rate for the propagation to ``t``, rad/s.

        Returns
        -------
        bool
            False when the sample was rejected by the innovation gate.
        """
        qm = self._unit(as_float_array(q_meas_body_to_icrs, "q_meas_body_to_icrs", last_dim=4, ndim=1))
        r = self._check_cov(covariance_rad2, "covariance_rad2")
        if t is not None:
            t = float(as_float_array(t, "t"))
            if t < self.t_s - 1e-9:
                raise ValueError(f"t={t} is earlier than the estimate's time {self.t_s}: samples must be in order")
            if t > self.t_s:
                self.propagate(self._omega_gyro_last if omega_gyro is None else omega_gyro, t - self.t_s)
                self.t_s = t
        z = np.array(_qlog_residual(self.q_body_to_icrs.tolist(), qm.tolist()))
        if self.gate_chi2 is not None:
            s = self.ekf.P[:3, :3] + r
            if float(z @ _inv3_sym(s) @ z) > self.gate_chi2:
                self.n_rejected += 1
                return False
        self.ekf.update(z.reshape(-1, 1), _hjacobian, _hx, R=r)
        self.ekf.R = r
        self._reset(self.ekf.x[:, 0])
        self.ekf.x = np.zeros((6, 1))
        self.n_updates += 1
        return True

    def _reset(self, dx):
        dx = dx.tolist()
        dq = _qexp(dx[0], dx[1], dx[2])
        self.q_body_to_icrs = np.array(_normalized(_qmul(self.q_body_to_icrs.tolist(), dq)))
        self.bias_rad_s = self.bias_rad_s + np.array(dx[3:])
        self.omega_body = self._omega_gyro_last - self.bias_rad_s

    @staticmethod
    def _unit(q):
        n = float(np.linalg.norm(q))
        if n < 1e-12:
            raise ValueError("q_meas_body_to_icrs must be a non-zero quaternion")
        return q / n

    @staticmethod
    def _check_cov(c, name, batch=False):
        r = as_float_array(c, name)
        shape_ok = (r.ndim == 3 and r.shape[1:] == (3, 3)) if batch else r.shape == (3, 3)
        if not shape_ok:
            raise ValueError(f"{name} must have shape {'(M, 3, 3)' if batch else '(3, 3)'}, got {r.shape}")
        if np.abs(r - np.swapaxes(r, -1, -2)).max() > 1e-9 * np.abs(r).max():
            raise ValueError(f"{name} must be symmetric")
        # Sylvester's criterion: leading principal minors positive
        m1 = r[..., 0, 0]
        m2 = r[..., 0, 0] * r[..., 1, 1] - r[..., 0, 1] * r[..., 1, 0]
        if np.any(m1 <= 0.0) or np.any(m2 <= 0.0) or np.any(np.linalg.det(r) <= 0.0):
            raise ValueError(f"{name} must be positive definite")
        return r

    # ------------------------------------------------------------------ lean path
    def process(
        self, omega_gyro, t_gyro_s, q_meas_body_to_icrs, t_meas_s, covariance_rad2, method: str = "auto", *,
        validate: bool = True,
    ) -> np.ndarray:
        """Fuse a frame's gyro samples and attitude samples in time order (lean paths).

        Gyro sample ``g`` is the rate over ``(t_gyro_s[g-1], t_gyro_s[g]]`` (the first one from the
        estimate's time). Each attitude sample is applied at its exposure time, propagated to with the
        gyro sample covering that instant; the filter ends at ``t_gyro_s[-1]``.

        ``method="sequential"`` equals the sequence of :meth:`propagate` and :meth:`update` calls (to
        rounding) at a third of the cost per sample. ``method="batch"`` conditions the frame-end state
        on all M samples at once (one 3M x 3M Cholesky solve), with the exact cross-covariances the
        process noise creates between samples: it is the same linear-Gaussian estimate, linearised
        once about the frame's prior trajectory instead of after every sample, so it agrees with the
        sequential result to second order in the attitude error (1e-9 rad when tracking) and is the
        fast choice for many samples per frame. ``"auto"`` picks batch for M >= 8. The innovation
        gate of a batch is applied to each sample's innovation against the prior trajectory.

        Parameters
        ----------
        omega_gyro : array_like, shape (G, 3) or (3,)
            Measured rates, rad/s.
        t_gyro_s : array_like, shape (G,) or scalar
            End time of each gyro interval, s, strictly increasing, after the estimate's time.
        q_meas_body_to_icrs : array_like, shape (M, 4)
            Attitude samples (w, x, y, z); M may be 0.
        t_meas_s : array_like, shape (M,)
            Exposure times, s, non-decreasing, in ``[t_s, t_gyro_s[-1]]``.
        covariance_rad2 : array_like, shape (M, 3, 3)
            Body-frame covariance of each sample, rad².

        method : {"auto", "sequential", "batch"}
            Default ``"auto"``: batch for M >= 8 samples (the measured break-even), sequential otherwise.
        validate : bool
            False skips the checks, for a caller passing float64 arrays that meet them: ``omega_gyro`` (G, 3),
            ``t_gyro_s`` (G,), unit ``q_meas_body_to_icrs`` (M, 4), ``t_meas_s`` (M,), symmetric positive definite
            ``covariance_rad2`` (M, 3, 3), times ordered as above.

        Returns
        -------
        ndarray of bool, shape (M,)
            Which samples were accepted (all True without ``gate_chi2``).
        """
        if not validate:
            return self._fuse(omega_gyro, t_gyro_s, q_meas_body_to_icrs, t_meas_s, covariance_rad2, method)
        if method not in ("sequential", "batch", "auto"):
            raise ValueError(f"method must be 'sequential', 'batch' or 'auto', got {method!r}")
        wg = as_float_array(omega_gyro, "omega_gyro", last_dim=3).reshape(-1, 3)
        tg = as_float_array(t_gyro_s, "t_gyro_s").reshape(-1)
        if len(tg) != len(wg) or len(tg) == 0:
            raise ValueError(f"t_gyro_s must have one time per omega_gyro row ({len(wg)}), got {len(tg)}")
        if tg[0] <= self.t_s - 1e-9 or np.any(np.diff(tg) <= 0.0):
            raise ValueError(f"t_gyro_s must be strictly increasing and after the estimate's time {self.t_s}")
        qm = as_float_array(q_meas_body_to_icrs, "q_meas_body_to_icrs").reshape(-1, 4)
        tm = as_float_array(t_meas_s, "t_meas_s").reshape(-1)
        m = len(qm)
        if len(tm) != m:
            raise ValueError(f"t_meas_s must have one time per q_meas_body_to_icrs row ({m}), got {len(tm)}")
        rs = self._check_cov(covariance_rad2, "covariance_rad2", batch=True) if m else np.zeros((0, 3, 3))
        if len(rs) != m:
            raise ValueError(f"covariance_rad2 must have shape ({m}, 3, 3), got {rs.shape}")
        if m and (np.any(np.diff(tm) < 0.0) or tm[0] < self.t_s - 1e-9 or tm[-1] > tg[-1] + 1e-9):
            raise ValueError(f"t_meas_s must be non-decreasing and lie in [{self.t_s}, {tg[-1]}]")
        norms = np.linalg.norm(qm, axis=1)
        if np.any(norms < 1e-12):
            raise ValueError("q_meas_body_to_icrs contains a zero quaternion")
        qm = qm / norms[:, None]
        return self._fuse(wg, tg, qm, tm, rs, method)

    def _fuse(self, wg, tg, qm, tm, rs, method: str = "auto") -> np.ndarray:
        """The work of :meth:`process` on checked inputs."""
        m = len(qm)
        if method == "batch" or (method == "auto" and m >= _AUTO_BATCH_MIN_SAMPLES):
            return self._process_batch(wg, tg, qm, tm, rs)
        qm_l = qm.tolist()
        accepted = np.ones(m, dtype=bool)

        P = self.ekf.P
        q = self.q_body_to_icrs.tolist()
        b = self.bias_rad_s.tolist()
        t = self.t_s
        gate = self.gate_chi2
        wg_l = wg.tolist()
        tg_l = tg.tolist()
        tm_l = tm.tolist()
        phi = qd = None
        z = r = None
        g = 0
        w_gyro = wg_l[0]

        def prop(w_gyro, dt, q, P):
            w_hat = [w_gyro[0] - b[0], w_gyro[1] - b[1], w_gyro[2] - b[2]]
            phi, qd = self._transition(w_hat, dt)
            dq = _qexp(w_hat[0] * dt, w_hat[1] * dt, w_hat[2] * dt)
            return _normalized(_qmul(q, dq)), phi @ P @ phi.T + qd, phi, qd

        for i in range(m + 1):
            t_next = tm_l[i] if i < m else tg_l[-1]
            # whole gyro intervals that end before the next event
            while g < len(tg_l) and (tg_l[g] < t_next if i < m else True):
                w_gyro = wg_l[g]
                dt = tg_l[g] - t
                if dt > 0.0:
                    q, P, phi, qd = prop(w_gyro, dt, q, P)
                    t = tg_l[g]
                g += 1
            if i == m:
                break
            if g < len(tg_l):
                w_gyro = wg_l[g]
            dt = t_next - t
            if dt > 0.0:
                q, P, phi, qd = prop(w_gyro, dt, q, P)
                t = t_next
            # measurement update (H = [I 0]), Joseph form as filterpy
            z = np.array(_qlog_residual(q, qm_l[i]))
            r = rs[i]
            s_inv = _inv3_sym(P[:3, :3] + r)
            if gate is not None and float(z @ s_inv @ z) > gate:
                accepted[i] = False
                self.n_rejected += 1
                continue
            k = P[:, :3] @ s_inv
            dx = (k @ z).tolist()
            i_kh = _I6.copy()
            i_kh[:, :3] -= k
            P = i_kh @ P @ i_kh.T + k @ r @ k.T
            q = _normalized(_qmul(q, _qexp(dx[0], dx[1], dx[2])))
            b = [b[0] + dx[3], b[1] + dx[4], b[2] + dx[5]]
            self.n_updates += 1

        self.q_body_to_icrs = np.array(q)
        self.bias_rad_s = np.array(b)
        self.t_s = t
        self._omega_gyro_last = np.array(w_gyro)
        self.omega_body = self._omega_gyro_last - self.bias_rad_s
        self.ekf.P = P
        self.ekf.x = np.zeros((6, 1))
        if phi is not None:
            self.ekf.F, self.ekf.Q = phi, qd
        if z is not None:
            self.ekf.y, self.ekf.R = z.reshape(-1, 1), r
        return accepted

    def _process_batch(self, wg, tg, qm, tm, rs) -> np.ndarray:
        """Batch path of :meth:`process` (inputs already validated, quaternions unit)."""
        m, n_g = len(qm), len(tg)
        b0 = self.bias_rad_s
        w_hat = wg - b0  # (G, 3) bias-corrected rates, fixed over the frame
        starts = np.concatenate([[self.t_s], tg[:-1]])
        # prior trajectory at the gyro boundaries: quaternion, covariance and Φ(start_g, t0)
        q_start = np.empty((n_g, 4))
        p_start = np.empty((n_g, 6, 6))
        phi_start = np.empty((n_g, 6, 6))
        q = self.q_body_to_icrs.tolist()
        P = self.ekf.P
        phi_acc = _I6
        phi = qd = None
        for g in range(n_g):
            q_start[g], p_start[g], phi_start[g] = q, P, phi_acc
            dt = float(tg[g] - starts[g])
            if dt > 0.0:
                wl = w_hat[g].tolist()
                phi, qd = self._transition(wl, dt)
                P = phi @ P @ phi.T + qd
                phi_acc = phi @ phi_acc
                q = _normalized(_qmul(q, _qexp(wl[0] * dt, wl[1] * dt, wl[2] * dt)))
        accepted = np.ones(m, dtype=bool)
        if m:
            # each sample inside its gyro interval
            gi = np.minimum(np.searchsorted(tg, tm, side="left"), n_g - 1)
            dts = np.maximum(tm - starts[gi], 0.0)
            wi = w_hat[gi]
            phi_s, q_s = _transition_batch(wi, dts, self.sigma_v, self.sigma_u)
            p_i = phi_s @ p_start[gi] @ np.swapaxes(phi_s, 1, 2) + q_s  # prior covariance at t_i
            phi_i = phi_s @ phi_start[gi]  # Φ(t_i, t0)
            q_prior = _qmul_v(q_start[gi], _qexp_v(wi * dts[:, None]))
            z = _qlog_residual_v(q_prior, qm)  # (M, 3)
            s_ii = p_i[:, :3, :3] + rs
            if self.gate_chi2 is not None:
                nis = np.einsum("ki,ki->k", z, np.linalg.solve(s_ii, z[..., None])[..., 0])
                accepted = nis <= self.gate_chi2
                self.n_rejected += int(m - accepted.sum())
        if m and accepted.any():
            sel = np.flatnonzero(accepted)
            k = len(sel)
            phi_i, p_i, z, rs_k = phi_i[sel], p_i[sel], z[sel], rs[sel]
            # Φ(t_i, t0)⁻¹ = [[Aᵀ, -Aᵀ B], [0, I]] (A a rotation); Y_i = Φ_i⁻¹ P_i Hᵀ
            a_t = np.swapaxes(phi_i[:, :3, :3], 1, 2)
            inv = np.zeros((k, 6, 6))
            inv[:, :3, :3] = a_t
            inv[:, :3, 3:] = -a_t @ phi_i[:, :3, 3:]
            inv[:, 3:, 3:] = np.eye(3)
            y = inv @ p_i[:, :, :3]  # (k, 6, 3)
            # Cov(z_j, z_i) = H Φ(t_j, t_i) P_i Hᵀ = H Φ_j Y_i for t_i <= t_j: one (3k, 6) @ (6, 3k) product
            y_cols = y.transpose(1, 0, 2).reshape(6, 3 * k)
            full = phi_i[:, :3, :].reshape(3 * k, 6) @ y_cols
            s_big = np.where(_block_lower_mask(k), full, full.T)
            s_big = 0.5 * (s_big + s_big.T)
            diag = np.arange(k)
            s_big.reshape(k, 3, k, 3)[diag, :, diag, :] += rs_k
            c = phi_acc @ y_cols  # Cov(x_end, Z), (6, 3k)
            _, kt, info = dposv(s_big, c.T, lower=1)  # S⁻¹ Cᵀ by Cholesky (raw LAPACK: no wrapper overhead)
            if info != 0:
                kt = np.linalg.solve(s_big, c.T)
            dx = (kt.T @ z.reshape(-1)).tolist()
            P = P - c @ kt
            P = 0.5 * (P + P.T)
            q = _normalized(_qmul(q, _qexp(dx[0], dx[1], dx[2])))
            self.bias_rad_s = b0 + np.array(dx[3:])
            self.n_updates += k
            self.ekf.y, self.ekf.R = z[-1].reshape(-1, 1), rs_k[-1]
        self.q_body_to_icrs = np.array(q)
        self.t_s = float(tg[-1])
        self._omega_gyro_last = wg[-1].copy()
        self.omega_body = self._omega_gyro_last - self.bias_rad_s
        self.ekf.P = P
        self.ekf.x = np.zeros((6, 1))
        if phi is not None:
            self.ekf.F, self.ekf.Q = phi, qd
        return accepted

    def __repr__(self) -> str:
        sig = np.degrees(self.attitude_sigma_rad) * 3600.0
        return f"AttitudeEKF(t_s={self.t_s:.3f}, sigma_arcsec={np.round(sig, 2).tolist()}, updates={self.n_updates})"
