"""Gyroscope and accelerometer error models (three orthogonal axes, body frame).

Each axis of a sensor sampled every ``Δ = 1 / rate_hz`` seconds outputs

    y_k = sat( (1 + s) u_k + b_c + b_gm,k + b_rw,k + n_k )

- ``u_k``: the true input (body rate in rad/s, or specific force in m/s²), held over the sample;
- ``s``: scale-factor error, drawn once per :meth:`reset` from N(0, scale_factor_sigma_ppm² 1e-12);
- ``b_c``: turn-on ("random constant") bias, drawn once per reset from N(0, bias_sigma²);
- ``b_gm``: first-order Gauss-Markov bias, ``db = -b/τ dt + σ sqrt(2/τ) dW``, discretised exactly:
  ``b_k = φ b_(k-1) + σ sqrt(1 - φ²) ξ_k`` with ``φ = exp(-Δ/τ)``; started from its stationary N(0, σ²);
- ``b_rw``: rate random walk (gyro) / acceleration random walk, ``b_k = b_(k-1) + K sqrt(Δ) ξ_k``, from 0;
- ``n_k``: white noise of the sample average, N(0, N²/Δ), with N the angle (velocity) random walk
  coefficient: the Allan deviation is ``N / sqrt(τ)`` at short τ and ``K sqrt(τ/3)`` at long τ;
- ``sat``: saturation at ± the measurement range.

Paper 001 (inertial-aided matching, §4.2) models the gyro drift as a random constant plus a first-order
Markov process (correlation time 3600 s) plus white noise, the same on all axes, and the accelerometer
drift as a first-order Markov process (correlation time 1800 s), with three gyro conditions 0.004, 1 and
5 °/h. The extracted text lost Table 2 and the accelerometer value; :func:`gyro_preset` reconstructs the
conditions as "each component has the condition's magnitude" (constant σ = d, Markov σ = d, angle random
walk d °/√h, which for d = 0.004 is the SIGI/GG1320 ring-laser gyro the paper cites: 0.0035 °/h bias,
0.0035 °/√h random walk), and :func:`accelerometer_preset` assumes a 100 µg (1e-4 g) Markov bias.

Every stochastic method takes an ``rng: numpy.random.Generator``: :meth:`Gyro.measure` draws its normal variates
from it (Gauss-Markov drive, random-walk steps, white noise) and hands them to the compiled kernel
:func:`startracker.kernels.imu.sensor_samples`, which forms the samples in numpy's operation order (bit for bit the
``lfilter``/``cumsum`` formulation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from startracker.kernels import imu as kimu
from startracker.validation import as_float_array, check_rng

__all__ = [
    "GyroSpec",
    "AccelerometerSpec",
    "Gyro",
    "Accelerometer",
    "gyro_preset",
    "accelerometer_preset",
    "GYRO_GRADES",
    "DEG_PER_H",
    "DEG_PER_SQRT_H",
    "DEG_PER_H_PER_SQRT_H",
    "MICRO_G",
    "M_S_PER_SQRT_H",
]

#: 1 °/h in rad/s.
DEG_PER_H = math.pi / 180.0 / 3600.0
#: 1 °/√h (angle random walk) in rad/√s.
DEG_PER_SQRT_H = math.pi / 180.0 / 60.0
#: 1 °/h/√h (rate random walk) in rad/s/√s.
DEG_PER_H_PER_SQRT_H = math.pi / 180.0 / 3600.0 / 60.0
#: 1 µg in m/s² (standard gravity 9.80665 m/s²).
MICRO_G = 9.80665e-6
#: 1 m/s/√h (velocity random walk) in m/s/√s.
M_S_PER_SQRT_H = 1.0 / 60.0


_NO_DRAWS = np.zeros((1, 0, 3))  # the draws of a sensor whose terms are all off (the kernel reads none)


def _check_nonneg(obj, names) -> None:
    for name in names:
        v = getattr(obj, name)
        if not isinstance(v, (int, float, np.floating, np.integer)) or isinstance(v, bool):
            raise TypeError(f"{name} must be a real number, got {type(v).__name__}")
        if math.isnan(v) or v < 0.0:
            raise ValueError(f"{name} must be >= 0, got {v}")


@dataclass(frozen=True)
class GyroSpec:
    """Parameters of a three-axis gyro, SI units (same on every axis).

    Attributes
    ----------
    rate_hz : float
        Output rate, Hz (> 0). Each sample is the average rate over ``1 / rate_hz``.
    bias_sigma_rad_s : float
        1σ of the turn-on (random constant) bias, rad/s.
    gm_sigma_rad_s : float
        Stationary 1σ of the first-order Gauss-Markov bias, rad/s.
    gm_tau_s : float
        Correlation time of the Gauss-Markov bias, s (> 0).
    arw_rad_sqrt_s : float
        Angle random walk coefficient N, rad/√s.
    rrw_rad_s_sqrt_s : float
        Rate random walk coefficient K, rad/s/√s.
    scale_factor_sigma_ppm : float
        1σ of the scale-factor error, ppm.
    max_rate_rad_s : float
        Measurement range (saturation), rad/s (> 0; ``inf`` for none).
    """

    rate_hz: float = 100.0
    bias_sigma_rad_s: float = 0.0
    gm_sigma_rad_s: float = 0.0
    gm_tau_s: float = 3600.0
    arw_rad_sqrt_s: float = 0.0
    rrw_rad_s_sqrt_s: float = 0.0
    scale_factor_sigma_ppm: float = 0.0
    max_rate_rad_s: float = math.inf

    def __post_init__(self):
        _check_nonneg(self, [f.name for f in fields(self)])
        for name in ("rate_hz", "gm_tau_s", "max_rate_rad_s"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not math.isfinite(self.rate_hz) or not math.isfinite(self.gm_tau_s):
            raise ValueError("rate_hz and gm_tau_s must be finite")

    @classmethod
    def from_datasheet(
        cls,
        *,
        rate_hz: float = 100.0,
        bias_deg_h: float = 0.0,
        gm_sigma_deg_h: float = 0.0,
        gm_tau_s: float = 3600.0,
        arw_deg_sqrt_h: float = 0.0,
        rrw_deg_h_sqrt_h: float = 0.0,
        scale_factor_ppm: float = 0.0,
        max_rate_deg_s: float = math.inf,
    ) -> "GyroSpec":
        """Build from datasheet units: °/h, °/√h, °/h/√h, ppm, °/s (same meaning as the attributes)."""
        return cls(
            rate_hz=float(rate_hz),
            bias_sigma_rad_s=float(bias_deg_h) * DEG_PER_H,
            gm_sigma_rad_s=float(gm_sigma_deg_h) * DEG_PER_H,
            gm_tau_s=float(gm_tau_s),
            arw_rad_sqrt_s=float(arw_deg_sqrt_h) * DEG_PER_SQRT_H,
            rrw_rad_s_sqrt_s=float(rrw_deg_h_sqrt_h) * DEG_PER_H_PER_SQRT_H,
            scale_factor_sigma_ppm=float(scale_factor_ppm),
            max_rate_rad_s=math.radians(float(max_rate_deg_s)),
        )

    @property
    def bias_rw_equivalent_rad_s_sqrt_s(self) -> float:
        """Random-walk density a filter can use for the slowly varying bias, rad/s/√s.

        ``sqrt(K² + 2 σ_gm² / τ)``: the rate random walk plus the Gauss-Markov driving noise.
        """
        return math.sqrt(self.rrw_rad_s_sqrt_s**2 + 2.0 * self.gm_sigma_rad_s**2 / self.gm_tau_s)


@dataclass(frozen=True)
class AccelerometerSpec:
    """Parameters of a three-axis accelerometer, SI units (same on every axis).

    Attributes
    ----------
    rate_hz : float
        Output rate, Hz (> 0).
    bias_sigma_m_s2 : float
        1σ of the turn-on bias, m/s².
    gm_sigma_m_s2 : float
        Stationary 1σ of the first-order Gauss-Markov bias, m/s².
    gm_tau_s : float
        Correlation time of the Gauss-Markov bias, s (> 0).
    vrw_m_s_sqrt_s : float
        Velocity random walk coefficient, m/s/√s.
    arw_m_s2_sqrt_s : float
        Acceleration (bias) random walk coefficient, m/s²/√s.
    scale_factor_sigma_ppm : float
        1σ of the scale-factor error, ppm.
    max_accel_m_s2 : float
        Measurement range (saturation), m/s² (> 0; ``inf`` for none).
    """

    rate_hz: float = 100.0
    bias_sigma_m_s2: float = 0.0
    gm_sigma_m_s2: float = 0.0
    gm_tau_s: float = 1800.0
    vrw_m_s_sqrt_s: float = 0.0
    arw_m_s2_sqrt_s: float = 0.0
    scale_factor_sigma_ppm: float = 0.0
    max_accel_m_s2: float = math.inf

    def __post_init__(self):
        _check_nonneg(self, [f.name for f in fields(self)])
        for name in ("rate_hz", "gm_tau_s", "max_accel_m_s2"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not math.isfinite(self.rate_hz) or not math.isfinite(self.gm_tau_s):
            raise ValueError("rate_hz and gm_tau_s must be finite")

    @classmethod
    def from_datasheet(
        cls,
        *,
        rate_hz: float = 100.0,
        bias_ug: float = 0.0,
        gm_sigma_ug: float = 0.0,
        gm_tau_s: float = 1800.0,
        vrw_m_s_sqrt_h: float = 0.0,
        scale_factor_ppm: float = 0.0,
        max_accel_g: float = math.inf,
    ) -> "AccelerometerSpec":
        """Build from datasheet units: µg, m/s/√h, ppm, g."""
        return cls(
            rate_hz=float(rate_hz),
            bias_sigma_m_s2=float(bias_ug) * MICRO_G,
            gm_sigma_m_s2=float(gm_sigma_ug) * MICRO_G,
            gm_tau_s=float(gm_tau_s),
            vrw_m_s_sqrt_s=float(vrw_m_s_sqrt_h) * M_S_PER_SQRT_H,
            scale_factor_sigma_ppm=float(scale_factor_ppm),
            max_accel_m_s2=float(max_accel_g) * MICRO_G * 1e6,
        )


class _ThreeAxisSensor:
    """Shared error-state machinery of :class:`Gyro` and :class:`Accelerometer`."""

    _input_name = "u"

    def _configure(self, rate_hz, bias_sigma, gm_sigma, gm_tau, white, rw, sf_sigma_ppm, limit, rng):
        self._dt = 1.0 / rate_hz
        self._bias_sigma = bias_sigma
        self._gm_sigma = gm_sigma
        self._phi = math.exp(-self._dt / gm_tau)
        self._gm_drive = gm_sigma * math.sqrt(-math.expm1(-2.0 * self._dt / gm_tau))
        self._white_sigma = white / math.sqrt(self._dt)
        self._rw_step = rw * math.sqrt(self._dt)
        self._sf_sigma = sf_sigma_ppm * 1e-6
        self._limit = limit
        # index of each term's draws in a call's (n_on, K, 3) block (0 when off: not read), and n_on
        flags = [self._gm_drive > 0.0, self._rw_step > 0.0, self._white_sigma > 0.0]
        index = np.cumsum(flags) - 1
        self._terms_on = (int(max(index[0], 0)), int(max(index[1], 0)), int(max(index[2], 0)), int(sum(flags)))
        self.reset(rng)

    def reset(self, rng: np.random.Generator) -> None:
        """Draw a new turn-on bias, scale factor and stationary Gauss-Markov state; zero the random walk.

        Parameters
        ----------
        rng : numpy.random.Generator
        """
        check_rng(rng)
        self._b_const = self._bias_sigma * rng.standard_normal(3)
        self._b_gm = self._gm_sigma * rng.standard_normal(3)
        self._b_rw = np.zeros(3)
        self._sf = 1.0 + self._sf_sigma * rng.standard_normal(3)
        self._n_samples = 0

    @property
    def sample_period_s(self) -> float:
        """Time between samples, s."""
        return self._dt

    @property
    def n_samples(self) -> int:
        """Samples produced since the last reset."""
        return self._n_samples

    @property
    def scale_factor(self) -> np.ndarray:
        """Current multiplicative scale factor ``1 + s`` per axis, shape (3,)."""
        return self._sf.copy()

    def _bias(self) -> np.ndarray:
        return self._b_const + self._b_gm + self._b_rw

    def sample_times(self, t_start_s: float, t_end_s: float) -> np.ndarray:
        """Sample instants ``k Δ`` of this sensor's clock in ``(t_start_s, t_end_s]``, shape (K,), s."""
        t0 = float(as_float_array(t_start_s, "t_start_s"))
        t1 = float(as_float_array(t_end_s, "t_end_s"))
        if t1 < t0:
            raise ValueError(f"t_end_s ({t1}) must be >= t_start_s ({t0})")
        eps = 1e-9
        k0 = math.floor(t0 / self._dt + eps) + 1
        k1 = math.floor(t1 / self._dt + eps)
        return np.arange(k0, k1 + 1) * self._dt

    def _measure(self, u, rng, validate: bool = True) -> np.ndarray:
        if validate:
            check_rng(rng)
            u = as_float_array(u, self._input_name)
            if u.ndim not in (1, 2) or u.shape[-1] != 3:
                raise ValueError(f"{self._input_name} must have shape (3,) or (K, 3), got {u.shape}")
        single = u.ndim == 1
        # a (K, 3) C-contiguous array (the unit's own interval rates) as it is: no view, no copy
        u2 = u if not single and u.flags.c_contiguous else np.ascontiguousarray(u.reshape(-1, 3))
        k = u2.shape[0]
        if k == 0:
            return np.empty((0, 3))
        x_gm, x_rw, x_white = self._draw_terms(k, rng)
        y = kimu.sensor_samples(
            u2, self._sf, self._b_const, self._b_gm, self._b_rw, self._phi,
            self._gm_drive, x_gm, self._rw_step, x_rw, self._white_sigma, x_white, self._limit,
        )
        self._n_samples += k
        return y[0] if single else y

    def _draw_terms(self, k: int, rng):
        """The draws of K samples, in this order and amount: Gauss-Markov drive, random-walk steps, white noise,
        (K, 3) each for the terms that are on. One call draws them all: the generator's stream is the same as with
        one call each. Returns the three terms' (K, 3) normals (a term that is off gets an unused view)."""
        on = self._terms_on
        xi = rng.standard_normal((on[3], k, 3)) if on[3] else _NO_DRAWS
        return xi[on[0]], xi[on[1]], xi[on[2]]

    def _measure_history(self, t, q, rng) -> np.ndarray:
        # the mean rate of each interval and its samples in one compiled call; the draws as in _measure
        k = t.shape[0] - 1
        if k <= 0:
            return np.empty((0, 3))
        x_gm, x_rw, x_white = self._draw_terms(k, rng)
        y = kimu.gyro_samples_of_history(
            t, q, self._sf, self._b_const, self._b_gm, self._b_rw, self._phi,
            self._gm_drive, x_gm, self._rw_step, x_rw, self._white_sigma, x_white, self._limit,
        )
        self._n_samples += k
        return y


class Gyro(_ThreeAxisSensor):
    """Three-axis rate gyro with the error model of the module docstring.

    Parameters
    ----------
    spec : GyroSpec
        Error parameters (see :func:`gyro_preset`).
    rng : numpy.random.Generator
        Draws the turn-on bias, scale factor and initial Gauss-Markov state.

    Examples
    --------
    >>> g = Gyro(gyro_preset("tactical", rate_hz=10.0), rng=np.random.default_rng(0))
    >>> y = g.measure(np.zeros((10, 3)), rng=np.random.default_rng(1))   # one second of samples
    """

    _input_name = "omega_true_body"

    def __init__(self, spec: GyroSpec, rng: np.random.Generator):
        if not isinstance(spec, GyroSpec):
            raise TypeError(f"spec must be a GyroSpec, got {type(spec).__name__}")
        self.spec = spec
        self._configure(
            spec.rate_hz,
            spec.bias_sigma_rad_s,
            spec.gm_sigma_rad_s,
            spec.gm_tau_s,
            spec.arw_rad_sqrt_s,
            spec.rrw_rad_s_sqrt_s,
            spec.scale_factor_sigma_ppm,
            spec.max_rate_rad_s,
            rng,
        )

    @property
    def bias_rad_s(self) -> np.ndarray:
        """Current additive bias (constant + Gauss-Markov + random walk) per axis, shape (3,), rad/s (truth)."""
        return self._bias()

    def measure(self, omega_true_body, rng: np.random.Generator, *, validate: bool = True) -> np.ndarray:
        """Produce consecutive samples, one per row, ``1 / rate_hz`` apart.

        Parameters
        ----------
        omega_true_body : array_like, shape (3,) or (K, 3)
            True body rate over each sample interval, rad/s.
        rng : numpy.random.Generator
        validate : bool
            False skips the checks, for a caller passing a finite float64 array of shape (3,) or (K, 3) and a
            ``numpy.random.Generator``.

        Returns
        -------
        ndarray, shape (3,) or (K, 3)
            Measured rates, rad/s, within ``±max_rate_rad_s``.
        """
        return self._measure(omega_true_body, rng, validate)

    def measure_history(self, times_s, q_body_to_icrs, rng: np.random.Generator, *,
                        validate: bool = True) -> np.ndarray:
        """Samples over each interval of a true attitude history: :meth:`measure` of its mean body rates (the
        rotation vector of ``conj(q[k]) ⊗ q[k + 1]`` over ``t[k + 1] - t[k]``), in one compiled call.

        Parameters
        ----------
        times_s : ndarray, shape (K + 1,)
            Instants, s, increasing (float64, C-contiguous).
        q_body_to_icrs : ndarray, shape (K + 1, 4)
            True attitudes at ``times_s`` (non-zero, float64, C-contiguous).
        rng : numpy.random.Generator
            Draws as :meth:`measure` of the K rates does (the same stream).
        validate : bool
            False skips the checks, for a caller passing float64 C-contiguous arrays of these shapes (the unit's own
            truth history) and a ``numpy.random.Generator``.

        Returns
        -------
        ndarray, shape (K, 3)
            Measured rates over ``(times_s[k], times_s[k + 1]]``, rad/s, within ``±max_rate_rad_s``.
        """
        if validate:
            check_rng(rng)
            times_s = np.ascontiguousarray(as_float_array(times_s, "times_s", ndim=1))
            q_body_to_icrs = np.ascontiguousarray(as_float_array(q_body_to_icrs, "q_body_to_icrs", ndim=2,
                                                                 last_dim=4))
            if len(q_body_to_icrs) != len(times_s):
                raise ValueError(f"q_body_to_icrs must have one row per instant of times_s ({len(times_s)}), "
                                 f"got {len(q_body_to_icrs)}")
            if np.any(np.diff(times_s) <= 0.0):
                raise ValueError("times_s must be increasing")
            if np.any(np.linalg.norm(q_body_to_icrs, axis=1) == 0.0):
                raise ValueError("q_body_to_icrs must have non-zero rows")
        return self._measure_history(times_s, q_body_to_icrs, rng)


class Accelerometer(_ThreeAxisSensor):
    """Three-axis accelerometer (specific force) with the error model of the module docstring.

    Parameters
    ----------
    spec : AccelerometerSpec
    rng : numpy.random.Generator
    """

    _input_name = "specific_force_body"

    def __init__(self, spec: AccelerometerSpec, rng: np.random.Generator):
        if not isinstance(spec, AccelerometerSpec):
            raise TypeError(f"spec must be an AccelerometerSpec, got {type(spec).__name__}")
        self.spec = spec
        self._configure(
            spec.rate_hz,
            spec.bias_sigma_m_s2,
            spec.gm_sigma_m_s2,
            spec.gm_tau_s,
            spec.vrw_m_s_sqrt_s,
            spec.arw_m_s2_sqrt_s,
            spec.scale_factor_sigma_ppm,
            spec.max_accel_m_s2,
            rng,
        )

    @property
    def bias_m_s2(self) -> np.ndarray:
        """Current additive bias per axis, shape (3,), m/s² (truth)."""
        return self._bias()

    def measure(self, specific_force_body, rng: np.random.Generator, *, validate: bool = True) -> np.ndarray:
        """Produce consecutive samples, one per row, ``1 / rate_hz`` apart.

        Parameters
        ----------
        specific_force_body : array_like, shape (3,) or (K, 3)
            True specific force (non-gravitational acceleration) in the body frame, m/s².
        rng : numpy.random.Generator
        validate : bool
            False skips the checks (a finite float64 array of shape (3,) or (K, 3), a Generator).

        Returns
        -------
        ndarray, shape (3,) or (K, 3)
            Measured specific force, m/s².
        """
        return self._measure(specific_force_body, rng, validate)


# Datasheet-unit parameters of each grade: representative values of the class, not one product.
# navigation ~ ring-laser / fibre-optic INS gyros (e.g. the GG1320 class: 0.0035 °/h, 0.0035 °/√h);
# tactical ~ small FOG / RLG IMUs (~1 °/h, ~0.1 °/√h); industrial/mems ~ good MEMS IMUs (~5-20 °/h, 0.3 °/√h).
_GYRO_GRADES = {
    "ideal": dict(),
    "navigation": dict(
        bias_deg_h=0.003, gm_sigma_deg_h=0.003, gm_tau_s=3600.0, arw_deg_sqrt_h=0.002,
        scale_factor_ppm=5.0, max_rate_deg_s=400.0,
    ),
    "tactical": dict(
        bias_deg_h=1.0, gm_sigma_deg_h=0.5, gm_tau_s=1000.0, arw_deg_sqrt_h=0.125,
        scale_factor_ppm=150.0, max_rate_deg_s=1000.0,
    ),
    "industrial": dict(
        bias_deg_h=20.0, gm_sigma_deg_h=5.0, gm_tau_s=300.0, arw_deg_sqrt_h=0.3, rrw_deg_h_sqrt_h=1.0,
        scale_factor_ppm=1000.0, max_rate_deg_s=450.0,
    ),
}
_GYRO_GRADES["mems"] = _GYRO_GRADES["industrial"]
for _i, _d in enumerate((0.004, 1.0, 5.0), start=1):
    _GYRO_GRADES[f"paper001-cond{_i}"] = dict(
        bias_deg_h=_d, gm_sigma_deg_h=_d, gm_tau_s=3600.0, arw_deg_sqrt_h=_d
    )

_ACCEL_GRADES = {
    "ideal": dict(),
    "navigation": dict(bias_ug=25.0, gm_sigma_ug=10.0, gm_tau_s=1800.0, vrw_m_s_sqrt_h=0.003, scale_factor_ppm=50.0, max_accel_g=30.0),
    "tactical": dict(bias_ug=1000.0, gm_sigma_ug=100.0, gm_tau_s=1800.0, vrw_m_s_sqrt_h=0.03, scale_factor_ppm=300.0, max_accel_g=50.0),
    "industrial": dict(bias_ug=10000.0, gm_sigma_ug=500.0, gm_tau_s=600.0, vrw_m_s_sqrt_h=0.1, scale_factor_ppm=1000.0, max_accel_g=16.0),
}
_ACCEL_GRADES["mems"] = _ACCEL_GRADES["industrial"]
for _i in (1, 2, 3):  # paper 001: accelerometer drift is one Markov process, tau 1800 s; value lost -> 1e-4 g
    _ACCEL_GRADES[f"paper001-cond{_i}"] = dict(gm_sigma_ug=100.0, gm_tau_s=1800.0)

#: Names accepted by :func:`gyro_preset` and :func:`accelerometer_preset`.
GYRO_GRADES = tuple(_GYRO_GRADES)


def gyro_preset(grade: str, rate_hz: float = 100.0) -> GyroSpec:
    """Gyro parameters of a grade.

    Parameters
    ----------
    grade : str
        ``"ideal"`` (no error), ``"navigation"``, ``"tactical"``, ``"industrial"`` (alias ``"mems"``),
        or paper 001's gyro conditions ``"paper001-cond1"`` (0.004 °/h), ``"paper001-cond2"`` (1 °/h),
        ``"paper001-cond3"`` (5 °/h): random constant σ = d, Markov σ = d with τ = 3600 s, ARW d °/√h.
    rate_hz : float
        Output rate, Hz.

    Returns
    -------
    GyroSpec
    """
    if grade not in _GYRO_GRADES:
        raise ValueError(f"grade must be one of {sorted(_GYRO_GRADES)}, got {grade!r}")
    return GyroSpec.from_datasheet(rate_hz=rate_hz, **_GYRO_GRADES[grade])


def accelerometer_preset(grade: str, rate_hz: float = 100.0) -> AccelerometerSpec:
    """Accelerometer parameters of a grade (same names as :func:`gyro_preset`).

    The ``paper001-cond*`` presets are paper 001's model: a first-order Markov bias only, τ = 1800 s,
    σ = 100 µg (assumed: the value was lost in the paper's text extraction).

    Returns
    -------
    AccelerometerSpec
    """
    if grade not in _ACCEL_GRADES:
        raise ValueError(f"grade must be one of {sorted(_ACCEL_GRADES)}, got {grade!r}")
    return AccelerometerSpec.from_datasheet(rate_hz=rate_hz, **_ACCEL_GRADES[grade])
