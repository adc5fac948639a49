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

Two code paths, one arithmetic (the compiled kernels of :mod:`startracker.kernels.filter`):

- :meth:`AttitudeEKF.propagate` / :meth:`AttitudeEKF.update`: one call per gyro interval / attitude
  sample; Φ, Q, the innovation and the reset come from the kernels, the covariance algebra is filterpy's
  own ``predict`` and ``update``;
- :meth:`AttitudeEKF.process`: a whole frame (gyro samples and M attitude samples merged in time order) in
  one compiled call, :func:`startracker.kernels.filter.fuse_frame`: the same sequence of predictions and
  Joseph-form updates, equal to the filterpy path to rounding (1e-13). ``benchmarks/bench_filter.py``
  measures it against filterpy's loop.

A batch update (all M samples of a frame in one 3M x 3M solve) used to exist beside the sequential one;
compiled, the sequential update costs less for every M a frame carries (M <= 21), so it is the only one.

The multiplicative reset's covariance correction (second order in δθ) is neglected, as usual.

The module is over 600 lines because the sequential and the batch update are two paths of one filter
(:class:`AttitudeEKF`) that must agree, and are kept side by side.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from startracker.kernels import filter as kf
from startracker.validation import as_float_array, check_positive

__all__ = ["AttitudeEKF", "DelayedFusion", "ARW_FLOOR_RAD_SQRT_S", "BIAS_SIGMA_FLOOR_RAD_S"]

_H = np.hstack([np.eye(3), np.zeros((3, 3))])
# DelayedFusion's innovations when it has none (shared, empty: nothing to write into)
_NO_INNOVATIONS = np.zeros((0, 3))
_NO_INNOVATION_COVS = np.zeros((0, 3, 3))
_NO_RATE_NOISE = np.zeros((0, 3))  # add_gyro without rate noise (kernels.filter.append_intervals appends zeros)
_METHODS = ("auto", "sequential")


# Floors of :meth:`AttitudeEKF.from_gyro_spec`
ARW_FLOOR_RAD_SQRT_S = 1e-7
BIAS_SIGMA_FLOOR_RAD_S = 1e-7


def _hjacobian(_x):
    return _H


def _hx(x):
    return x[:3]


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
    last_nis : ndarray, shape (M,)
        Normalised innovation squared of each sample of the last :meth:`process` call against the filter just
        before it (3 dof), accepted or not.
    last_innovation_rad, last_innovation_cov_rad2 : ndarray, shape (M, 3) and (M, 3, 3)
        Those samples' innovations and their covariances ``S``.
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
        self.last_nis = np.zeros(0)
        self.last_innovation_rad = np.zeros((0, 3))
        self.last_innovation_cov_rad2 = np.zeros((0, 3, 3))

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
        w_hat = w - self.bias_rad_s
        self.omega_body = w_hat
        if dt == 0.0:
            return
        phi, qd = kf.transition(w_hat, dt, self.sigma_v, self.sigma_u)
        self.q_body_to_icrs = kf.quat_advance(np.asarray(self.q_body_to_icrs, dtype=float), w_hat * dt)
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
        z = kf.attitude_residual(np.asarray(self.q_body_to_icrs, dtype=float), qm)
        if self.gate_chi2 is not None:
            s = self.ekf.P[:3, :3] + r
            if float(z @ np.linalg.solve(s, z)) > self.gate_chi2:
                self.n_rejected += 1
                return False
        self.ekf.update(z.reshape(-1, 1), _hjacobian, _hx, R=r)
        self.ekf.R = r
        self._reset(self.ekf.x[:, 0])
        self.ekf.x = np.zeros((6, 1))
        self.n_updates += 1
        return True

    def _reset(self, dx):
        self.q_body_to_icrs = kf.quat_advance(np.asarray(self.q_body_to_icrs, dtype=float), dx[:3].copy())
        self.bias_rad_s = self.bias_rad_s + dx[3:]
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

    # ------------------------------------------------------------------ frame path
    def process(
        self, omega_gyro, t_gyro_s, q_meas_body_to_icrs, t_meas_s, covariance_rad2, method: str = "auto", *,
        rate_noise_rad2_s=None, validate: bool = True,
    ) -> np.ndarray:
        """Fuse a frame's gyro samples and attitude samples in time order, in one compiled call.

        Gyro sample ``g`` is the rate over ``(t_gyro_s[g-1], t_gyro_s[g]]`` (the first one from the
        estimate's time). Each attitude sample is applied at its exposure time, propagated to with the
        gyro sample covering that instant; the filter ends at ``t_gyro_s[-1]``. The result equals the
        sequence of :meth:`propagate` and :meth:`update` calls to rounding.

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
        method : {"auto", "sequential"}
            Both run the sequential update. ``"batch"`` (a one-solve update of all M samples) was removed: the
            compiled sequential update is cheaper for every M a frame carries; passing it raises ValueError.
        rate_noise_rad2_s : array_like, shape (G, 3), optional
            Extra angle-random-walk variance density of each gyro interval per body axis, rad²/s (>= 0), added to
            the attitude process noise as ``rate_noise · dt``: the square of the rate uncertainty of an axis whose
            reading is saturated. Default zero.
        validate : bool
            False skips the checks, for a caller passing C-contiguous float64 arrays that meet them:
            ``omega_gyro`` (G, 3),
            ``t_gyro_s`` (G,), unit ``q_meas_body_to_icrs`` (M, 4), ``t_meas_s`` (M,), symmetric positive definite
            ``covariance_rad2`` (M, 3, 3), times ordered as above.

        Returns
        -------
        ndarray of bool, shape (M,)
            Which samples were accepted (all True without ``gate_chi2``).
        """
        if method not in _METHODS:
            if method == "batch":
                raise ValueError(
                    "method='batch' was removed: the compiled sequential update is cheaper for the M <= 21 samples"
                    " of a frame (benchmarks/bench_filter.py); use method='sequential' or 'auto'"
                )
            raise ValueError(f"method must be 'sequential' or 'auto', got {method!r}")
        if not validate:
            return self._fuse(omega_gyro, t_gyro_s, q_meas_body_to_icrs, t_meas_s, covariance_rad2, rate_noise_rad2_s)
        wg = as_float_array(omega_gyro, "omega_gyro", last_dim=3).reshape(-1, 3)
        if rate_noise_rad2_s is not None:
            rate_noise_rad2_s = as_float_array(rate_noise_rad2_s, "rate_noise_rad2_s", last_dim=3).reshape(-1, 3)
            if len(rate_noise_rad2_s) != len(wg) or np.any(~(rate_noise_rad2_s >= 0.0)):
                raise ValueError(f"rate_noise_rad2_s must have shape ({len(wg)}, 3) and be >= 0")
            rate_noise_rad2_s = np.ascontiguousarray(rate_noise_rad2_s)
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
        # one memory layout for the kernel (broadcast or strided inputs would each compile a variant)
        return self._fuse(*(np.ascontiguousarray(a) for a in (wg, tg, qm, tm, rs)), rate_noise_rad2_s)

    def _fuse(self, wg, tg, qm, tm, rs, rate_noise=None, timing=None):
        """The work of :meth:`process` on checked inputs: one :func:`~startracker.kernels.filter.fuse_frame` call.

        With ``timing`` (``u`` (3,), threshold, loose ratio; M >= 1): behind the delivery's timing test, one
        :func:`~startracker.kernels.filter.fuse_frame_timed` call; returns ``(statistic, loose, accepted)``, with
        ``accepted`` None and the filter unchanged when the test failed."""
        m = len(qm)
        # the kernel works in place on fresh float64 copies (no caller's array changes behind its back)
        q = np.array(self.q_body_to_icrs, dtype=np.float64)
        b = np.array(self.bias_rad_s, dtype=np.float64)
        P = np.array(self.ekf.P, dtype=np.float64)
        accepted = np.empty(m, dtype=np.bool_)
        nis = np.empty(m)
        zs = np.empty((m, 3))
        ss = np.empty((m, 3, 3))
        phi = np.empty((6, 6))
        qd = np.empty((6, 6))
        z = np.empty(3)
        if timing is None:
            t, n_acc, n_prop = kf.fuse_frame(
                q, b, P, float(self.t_s), wg, tg, qm, tm, rs, self.sigma_v, self.sigma_u,
                math.inf if self.gate_chi2 is None else self.gate_chi2, accepted, phi, qd, z,
                np.zeros((len(tg), 3)) if rate_noise is None else rate_noise, nis, zs, ss,
            )
        else:
            stat, loose, fused, t, n_acc, n_prop = kf.fuse_frame_timed(
                q, b, P, float(self.t_s), wg, tg, qm, tm, rs, self.sigma_v, self.sigma_u,
                math.inf if self.gate_chi2 is None else self.gate_chi2, accepted, phi, qd, z,
                np.zeros((len(tg), 3)) if rate_noise is None else rate_noise, nis, zs, ss, *timing,
            )
            if not fused:
                return stat, loose, None
        self._take(q, b, P, t, n_acc, n_prop, wg[-1], rs[-1] if m else None, phi, qd, z, nis, zs, ss)
        return accepted if timing is None else (stat, loose, accepted)

    def _take(self, q, b, P, t, n_acc, n_prop, w_last, rs_last, phi, qd, z, nis, zs, ss):
        """The filter after a :func:`~startracker.kernels.filter.fuse_frame` call on its copies: its new state
        (``w_last`` (3,): the last interval's gyro rate; ``rs_last``: the last sample's covariance, None without
        samples) and the call's outputs."""
        m = len(nis)
        self.last_nis, self.last_innovation_rad, self.last_innovation_cov_rad2 = nis, zs, ss
        self.n_updates += n_acc
        self.n_rejected += m - n_acc
        self.q_body_to_icrs = q
        self.bias_rad_s = b
        self.t_s = t
        self._omega_gyro_last = w_last.copy()
        self.omega_body = self._omega_gyro_last - b
        self.ekf.P = P
        self.ekf.x = np.zeros((6, 1))
        if n_prop:
            self.ekf.F, self.ekf.Q = phi, qd
        if m:
            self.ekf.y, self.ekf.R = z.reshape(-1, 1), rs_last

    def __repr__(self) -> str:
        sig = np.degrees(self.attitude_sigma_rad) * 3600.0
        return f"AttitudeEKF(t_s={self.t_s:.3f}, sigma_arcsec={np.round(sig, 2).tolist()}, updates={self.n_updates})"


class DelayedFusion:
    """An :class:`AttitudeEKF` that takes attitude samples late: processing delay without approximation.

    A star tracker's sample reaches the filter some time after its exposure instant (the processor's latency),
    while the gyro streams in on time. The method is *filter recalculation*, the exact one (Larsen et al.,
    "Incorporation of time delayed measurements in a discrete-time Kalman filter", CDC 1998): the filter
    :attr:`ekf` is held at the time of its last attitude sample, the gyro intervals since then are buffered, and

    - a sample that arrives late is fused at its exposure instant: :attr:`ekf` is propagated through the buffered
      intervals up to that instant (the interval covering it split there), updated, and the intervals before it
      leave the buffer;
    - the estimate *now* (:meth:`current`) is :attr:`ekf` propagated through the buffer, recomputed when it is asked
      for after a change.

    With samples arriving in time order (a tracker's output port delivers frames in order), this is the same
    sequence of operations as fusing each sample at its instant with no delay, so the posterior is the same
    (to rounding) whatever the delay, and the cost is one propagation of the buffer per query. A state-history
    rollback would serve samples out of order too; a tracker does not produce those. Samples older than
    :attr:`ekf`'s time are stale and rejected. Intervals older than ``horizon_s`` are folded into :attr:`ekf`
    (no sample can be that late).

    Parameters
    ----------
    horizon_s : float
        Longest delay a sample may have, s (> 0): gyro intervals older than this are folded into the filter.

    Attributes
    ----------
    ekf : AttitudeEKF or None
        The filter at the time of its last sample (or of the last folded interval); None before :meth:`start`.
    t_s : float
        End of the last gyro interval, s (the time of :meth:`current`).
    n_stale : int
        Samples rejected because they arrived after a later one had been fused.
    last_nis : ndarray, shape (M,)
        Normalised innovation squared of each sample of the last :meth:`fuse` (NaN for stale ones).
    last_innovation_rad, last_innovation_cov_rad2 : ndarray, shape (F, 3) and (F, 3, 3)
        Innovations and their covariances of the fresh samples of the last :meth:`fuse`.
    """

    def __init__(self, horizon_s: float):
        self.horizon_s = check_positive(horizon_s, "horizon_s")
        self.ekf: AttitudeEKF | None = None
        self.t_s = -math.inf
        self.n_stale = 0
        self.last_nis = np.zeros(0)
        self.last_innovation_rad = np.zeros((0, 3))
        self.last_innovation_cov_rad2 = np.zeros((0, 3, 3))
        self._tg = np.zeros(0)
        self._wg = np.zeros((0, 3))
        self._rn = np.zeros((0, 3))
        self._now = None

    def start(self, ekf: AttitudeEKF) -> None:
        """Use ``ekf`` (a new filter at its own time) from now on; the buffered intervals after its time are kept."""
        if not isinstance(ekf, AttitudeEKF):
            raise TypeError(f"ekf must be an AttitudeEKF, got {type(ekf).__name__}")
        self.ekf = ekf
        self._drop_before(ekf.t_s)
        self._now = None

    def add_gyro(self, omega_gyro, t_gyro_s, rate_noise_rad2_s=None) -> None:
        """Append gyro intervals ``(t_gyro_s[g-1], t_gyro_s[g]]`` (float64, C-contiguous, after :attr:`t_s`).

        Parameters
        ----------
        omega_gyro : ndarray, shape (G, 3)
            Measured rates, rad/s.
        t_gyro_s : ndarray, shape (G,)
            End of each interval, s, strictly increasing.
        rate_noise_rad2_s : ndarray, shape (G, 3), optional
            Extra angle-random-walk variance density per interval and axis, rad²/s (see
            :meth:`AttitudeEKF.process`). Default zero.
        """
        g = len(t_gyro_s)
        if g == 0:
            return
        self._tg, wr = kf.append_intervals(self._tg, self._wg, self._rn, t_gyro_s, omega_gyro,
                                           _NO_RATE_NOISE if rate_noise_rad2_s is None else rate_noise_rad2_s)
        self._wg, self._rn = wr[0], wr[1]  # rows of one array (one boxed array)
        self.t_s = float(self._tg[-1])
        self._now = None
        old = self.t_s - self.horizon_s
        if self._tg[0] > old:  # nothing older than the horizon (the usual case): no search
            return
        n_old = int(self._tg.searchsorted(old, side="right"))  # the method: np.searchsorted without its dispatch
        if self.ekf is not None and self._tg[n_old - 1] > self.ekf.t_s:
            k = n_old
            empty = np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3, 3))
            self.ekf.process(self._wg[:k], self._tg[:k], *empty, rate_noise_rad2_s=self._rn[:k], validate=False)
        self._keep_from(n_old)

    def correct_gyro(self, delta_rad_s, t_from_s: float) -> None:
        """Subtract ``delta_rad_s`` (3,) from the buffered gyro intervals that end after ``t_from_s`` (a gyro step
        found late: the readings from the step on, not yet in the filter, are corrected; what the filter already
        integrated is the caller's to account for)."""
        later = self._tg > t_from_s
        if later.any():
            self._wg = self._wg.copy()
            self._wg[later] -= np.asarray(delta_rad_s, dtype=np.float64)
            self._now = None

    def fuse(self, q_meas_body_to_icrs, t_meas_s, covariance_rad2) -> np.ndarray:
        """Fuse attitude samples (time order, unit quaternions, SPD covariances, float64) at their exposure instants.

        Parameters
        ----------
        q_meas_body_to_icrs : ndarray, shape (M, 4)
        t_meas_s : ndarray, shape (M,)
            Exposure instants, s, non-decreasing, at most :attr:`t_s`.
        covariance_rad2 : ndarray, shape (M, 3, 3)

        Returns
        -------
        ndarray of bool, shape (M,)
            Which samples the filter accepted (stale ones and those its innovation gate rejected are False).
        """
        m = len(t_meas_s)
        self.last_innovation_rad = _NO_INNOVATIONS
        self.last_innovation_cov_rad2 = _NO_INNOVATION_COVS
        if m == 0 or self.ekf is None or t_meas_s[0] < self.ekf.t_s:
            # the unusual cases: NaN for the samples the filter does not test
            self.last_nis = np.full(m, np.nan)
            accepted = np.zeros(m, dtype=bool)
            if m == 0:
                return accepted
            if self.ekf is None:
                raise RuntimeError("start(ekf) before fuse()")
            fresh = t_meas_s >= self.ekf.t_s
            n_fresh = int(np.count_nonzero(fresh))
        else:  # in time order: all fresh (the usual case); the filter's own arrays are the results
            fresh = slice(None)
            n_fresh = m
            accepted = None
        self.n_stale += m - n_fresh
        if n_fresh == 0:
            return accepted
        if n_fresh < m:
            q_meas_body_to_icrs, t_meas_s, covariance_rad2 = (
                q_meas_body_to_icrs[fresh], t_meas_s[fresh], covariance_rad2[fresh])
        t_last = float(t_meas_s[-1])
        wg, tg, rn, j = self._intervals_to(t_last)
        if wg is None:
            if t_last > self.ekf.t_s:
                self.last_nis = np.full(m, np.nan)
                raise ValueError(f"t_meas_s must not be later than the last gyro interval ({self.t_s}), got {t_last}")
            # all samples at the filter's own instant and nothing buffered: an update without propagation
            acc = self.ekf.process(self._held_rate(), np.array([t_last]), q_meas_body_to_icrs, t_meas_s,
                                   covariance_rad2, validate=False)
            if accepted is None:
                accepted, self.last_nis = acc, self.ekf.last_nis
            else:
                accepted[fresh] = acc
                self.last_nis[fresh] = self.ekf.last_nis
            self.last_innovation_rad = self.ekf.last_innovation_rad
            self.last_innovation_cov_rad2 = self.ekf.last_innovation_cov_rad2
            self._now = None
            return accepted
        acc = self.ekf.process(wg, tg, q_meas_body_to_icrs, t_meas_s, covariance_rad2, rate_noise_rad2_s=rn,
                               validate=False)
        if n_fresh == m:  # the usual case: the filter's own arrays, no masking
            accepted = acc
            self.last_nis = self.ekf.last_nis
        else:
            accepted[fresh] = acc
            self.last_nis[fresh] = self.ekf.last_nis
        self.last_innovation_rad = self.ekf.last_innovation_rad
        self.last_innovation_cov_rad2 = self.ekf.last_innovation_cov_rad2
        self._keep_from(j if self._tg[j] > t_last else j + 1)
        self._now = None
        return accepted

    def fuse_timed(self, q_meas_body_to_icrs, t_meas_s, covariance_rad2, rate_axis, timing_chi2_max: float,
                   loose_ratio: float):
        """A delivery's timing test against the prediction, then, when it passes, its :meth:`fuse`: the test of
        :func:`startracker.kernels.filter.timing_statistic` on :meth:`prior_innovations` along the body rate, and the
        fusion, in one compiled call when the buffer reaches the samples (:func:`~startracker.kernels.filter.fuse_frame_timed`).

        Parameters
        ----------
        q_meas_body_to_icrs, t_meas_s, covariance_rad2 :
            As :meth:`fuse` (M >= 1), none before the filter's time.
        rate_axis : ndarray, shape (3,)
            Unit vector of the body rate (body frame).
        timing_chi2_max : float
            Above this statistic the samples are not fused.
        loose_ratio : float
            The prediction is loose beyond this many times the smallest sample variance along the rate
            (:func:`~startracker.kernels.filter.timing_statistic`).

        Returns
        -------
        statistic : float
            The timing statistic, χ²(1) without a timing error.
        loose : bool
        accepted : ndarray of bool, shape (M,), or None
            As :meth:`fuse`; None when the test failed (the filter is unchanged).
        """
        ekf = self.ekf
        if ekf is not None and len(t_meas_s) and t_meas_s[0] >= ekf.t_s:
            # the usual case: one compiled call (the buffer's cut, the copies, the test and the fusion), then fuse's
            # bookkeeping
            # (the filter's arrays come packed: q, b, z and the NIS slices of one, P, phi and qd rows of another)
            (reached, j, keep_from, stat, loose, fused, t, n_acc, n_prop, qbz, mats, acc, zs,
             ss) = kf.fuse_buffer_timed(
                ekf.q_body_to_icrs, ekf.bias_rad_s, ekf.P, float(ekf.t_s), self._wg, self._tg, self._rn,
                q_meas_body_to_icrs, t_meas_s, covariance_rad2, ekf.sigma_v, ekf.sigma_u,
                math.inf if ekf.gate_chi2 is None else ekf.gate_chi2, rate_axis, timing_chi2_max, loose_ratio)
            if reached:
                if not fused:
                    return stat, loose, None
                nis = qbz[10:]
                ekf._take(qbz[:4], qbz[4:7], mats[0], t, n_acc, n_prop, self._wg[j], covariance_rad2[-1], mats[1],
                          mats[2], qbz[7:10], nis, zs, ss)
                self.last_nis = nis
                self.last_innovation_rad = zs
                self.last_innovation_cov_rad2 = ss
                self._keep_from(keep_from)
                self._now = None
                return stat, loose, acc
        # the others: the test, then the fusion, apart
        z, s = self.prior_innovations(q_meas_body_to_icrs, t_meas_s, covariance_rad2)
        stat, loose = kf.timing_statistic(rate_axis, z, s, covariance_rad2, loose_ratio)
        if stat > timing_chi2_max:
            return stat, bool(loose), None
        return stat, bool(loose), self.fuse(q_meas_body_to_icrs, t_meas_s, covariance_rad2)

    def prior_innovations(self, q_meas_body_to_icrs, t_meas_s, covariance_rad2):
        """Each sample's innovation against the filter's prediction at its instant, with no update in between (the
        filter does not change): what the samples say against the gyro-propagated estimate, before any of them
        moves it.

        Parameters as :meth:`fuse` (time order, unit quaternions, SPD covariances, float64, not before the
        filter's time, not after :attr:`t_s`).

        Returns
        -------
        z : ndarray, shape (M, 3)
            Innovation ``log(q̂(t_i)* ⊗ q_i)``, rad, body frame.
        s : ndarray, shape (M, 3, 3)
            Its covariance ``P_θθ(t_i) + R_i``, rad² (the prediction's errors are shared by the samples).
        """
        ekf = self.ekf
        m = len(t_meas_s)
        z = np.empty((m, 3))
        s = np.empty((m, 3, 3))
        if m == 0:
            return z, s
        t_last = float(t_meas_s[-1])
        wg, tg, rn, _ = self._intervals_to(t_last)
        if wg is None:  # nothing buffered after the filter's time: the held rate
            wg, tg, rn = self._held_rate(), np.array([max(t_last, ekf.t_s)]), np.zeros((1, 3))
        q = np.array(ekf.q_body_to_icrs, dtype=np.float64)
        b = np.array(ekf.bias_rad_s, dtype=np.float64)
        P = np.array(ekf.P, dtype=np.float64)
        # a gate below every NIS: each sample is tested against the prediction and none is applied
        kf.fuse_frame(q, b, P, float(ekf.t_s), wg, tg, q_meas_body_to_icrs, t_meas_s, covariance_rad2, ekf.sigma_v,
                      ekf.sigma_u, -1.0, np.empty(m, dtype=np.bool_), np.empty((6, 6)), np.empty((6, 6)),
                      np.empty(3), rn, np.empty(m), z, s)
        return z, s

    def _intervals_to(self, t_last: float):
        """The buffered gyro intervals up to ``t_last``, the one covering it split at its instant: ``(wg, tg, rn, j)``
        with ``j`` the covering interval's index; ``(None, None, None, len)`` when no buffered interval reaches it."""
        j = int(self._tg.searchsorted(t_last, side="left"))
        if j == len(self._tg):
            return None, None, None, j
        tg = self._tg[: j + 1].copy()
        tg[j] = t_last
        return self._wg[: j + 1], tg, self._rn[: j + 1], j

    def _held_rate(self) -> np.ndarray:
        """The filter's last gyro rate (bias included), (1, 3): what propagates when nothing is buffered."""
        return (np.asarray(self.ekf.omega_body, dtype=np.float64) + self.ekf.bias_rad_s).reshape(1, 3)

    def current(self):
        """The estimate at :attr:`t_s`: :attr:`ekf` propagated through the buffered intervals.

        Returns
        -------
        q_body_to_icrs : ndarray, shape (4,)
        bias_rad_s : ndarray, shape (3,)
        P : ndarray, shape (6, 6)
        omega_body : ndarray, shape (3,)
            Bias-corrected rate of the last interval, rad/s.
        t_s : float

        The arrays are the object's own: copy before changing them.
        """
        if self.ekf is None:
            raise RuntimeError("start(ekf) before current()")
        if self._now is None:
            ekf = self.ekf
            if len(self._tg):  # one compiled call: the copies, the propagation and the rate
                self._now = kf.propagate_buffer(ekf.q_body_to_icrs, ekf.bias_rad_s, ekf.P, float(ekf.t_s), self._wg,
                                                self._tg, self._rn, ekf.sigma_v, ekf.sigma_u)
            else:
                self._now = (np.array(ekf.q_body_to_icrs, dtype=np.float64), np.array(ekf.bias_rad_s, dtype=np.float64),
                             np.array(ekf.P, dtype=np.float64), np.asarray(ekf.omega_body, dtype=np.float64).copy(),
                             float(ekf.t_s))
        return self._now

    def _keep_from(self, k: int) -> None:
        self._tg, self._wg, self._rn = self._tg[k:], self._wg[k:], self._rn[k:]

    def _drop_before(self, t: float) -> None:
        self._keep_from(int(self._tg.searchsorted(t, side="right")))
