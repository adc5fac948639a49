"""AgileSlew-v1: the agile-slew task shaped for off-the-shelf learners (body-torque action, scaled observation,
a reward that does not vanish near the target, early termination on divergence, an optional ideal sensor)."""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from envs.agile_slew import INFO_KEYS, AgileSlewEnv
from envs.avionics import Estimate, TRACKER_MODES
from envs.faults import Fault
from startracker.kernels import rotations as rk
from startracker.rotations import quat_from_rotvec, quat_multiply, quat_normalize, quat_random

__all__ = ["AgileSlewV1Env", "BodyTorqueAllocator", "ACTION_MODES", "ACTION_CURVES", "command_from_action",
           "action_from_command", "SENSORS", "episode_seconds_for"]

ACTION_MODES = ("body_torque", "wheel")
# action value -> command: "linear" (the default) or "cubic" (command = a³: fine resolution near zero for a
# tanh-squashed policy, full authority at |a| = 1)
ACTION_CURVES = ("linear", "cubic")
SENSORS = ("tracker", "ideal")
ARCSEC = math.pi / (180.0 * 3600.0)
# scales of the observation's near-target entries: tanh(x / scale) resolves the settle window (the angle's scale is
# the default of ``fine_error_deg``)
FINE_ANGLE_RAD = math.radians(1.0)
FINE_RATE_RAD_S = math.radians(0.2)
# log-scaled attitude σ: 0.2″ maps to -1, π (lost) to +1
SIGMA_FLOOR_RAD = 1e-6


def episode_seconds_for(max_slew_deg: float, max_rate_deg_s: float, accel_deg_s2: float, settle_hold_s: float) -> float:
    """Episode length (s) that fits a slew of ``max_slew_deg``: twice a rate-limited bang-coast-bang slew at
    acceleration ``accel_deg_s2``, plus the settle hold and 5 s of capture."""
    t_ramp = max_rate_deg_s / accel_deg_s2
    t_slew = max_slew_deg / max_rate_deg_s + t_ramp if max_slew_deg > max_rate_deg_s * t_ramp \
        else 2.0 * math.sqrt(max_slew_deg / accel_deg_s2)
    return 2.0 * t_slew + settle_hold_s + 5.0


class BodyTorqueAllocator:
    """Body torque to wheel commands, with null-space momentum management.

    The body feels ``-A τ_w`` from wheel motor torques ``τ_w`` (``A`` the (3, n) matrix of spin axes). The body
    part is the least-norm solution ``τ_w = -A⁺ τ_body`` (it has no null-space component), scaled down with its
    direction kept so that no wheel exceeds ``1 - null_budget`` of its limit. With four wheels a null-space torque
    ``-(nᵀ h_w / T) n`` (``n`` the unit null vector of ``A``, ``h_w`` the wheel momenta, ``T`` the management time
    constant) bleeds the internal momentum that produces no body torque, limited to ``null_budget`` of the limit:
    the wheels never hold momentum that the body cannot feel, so rest with torque zero means rest at zero momentum.

    Parameters
    ----------
    wheel_axes_body : ndarray, shape (n_wheels, 3)
    wheel_max_torque_Nm : float
    null_time_s : float
        Time constant ``T`` of null-space momentum management, s.
    null_budget : float
        Fraction of each wheel's torque reserved for null-space management (0 with three wheels).
    """

    def __init__(self, wheel_axes_body, wheel_max_torque_Nm: float, null_time_s: float = 10.0, null_budget: float = 0.05):
        axes = np.asarray(wheel_axes_body, dtype=np.float64).T  # (3, n)
        self.axes = axes
        self.pinv = np.linalg.pinv(axes)  # (n, 3)
        self.max_torque_Nm = float(wheel_max_torque_Nm)
        self.null_time_s = float(null_time_s)
        n = axes.shape[1]
        if n > 3:
            _, _, vt = np.linalg.svd(axes)
            self.null = vt[-1] / np.linalg.norm(vt[-1])  # (n,)
            self.null_budget = float(null_budget)
        else:
            self.null = np.zeros(n)
            self.null_budget = 0.0

    def wheel_torques(self, torque_body_Nm, wheel_momentum_Nms) -> tuple[np.ndarray, np.ndarray]:
        """(body part, null part) of the wheel motor torques, each shape (n_wheels,), N m.

        ``torque_body_Nm`` (3,) is the requested body torque, ``wheel_momentum_Nms`` (n_wheels,) each wheel's
        momentum about its axis.
        """
        tau_b = -self.pinv @ np.asarray(torque_body_Nm, dtype=np.float64)
        limit = (1.0 - self.null_budget) * self.max_torque_Nm
        peak = float(np.max(np.abs(tau_b)))
        if peak > limit:
            tau_b = tau_b * (limit / peak)
        if self.null_budget == 0.0:
            return tau_b, np.zeros_like(tau_b)
        m = float(self.null @ np.asarray(wheel_momentum_Nms, dtype=np.float64))
        s = -m / self.null_time_s
        s_max = self.null_budget * self.max_torque_Nm / float(np.max(np.abs(self.null)))
        s = min(max(s, -s_max), s_max)
        return tau_b, s * self.null


def command_from_action(action, curve: str = "linear") -> np.ndarray:
    """The command (fraction of the torque limit) of an action in [-1, 1]: ``a`` (``"linear"``) or ``a³``
    (``"cubic"``); same shape as ``action``."""
    a = np.asarray(action, dtype=np.float64)
    return a * a * a if curve == "cubic" else a


def action_from_command(command, curve: str = "linear") -> np.ndarray:
    """Inverse of :func:`command_from_action` (the action that gives ``command``)."""
    c = np.asarray(command, dtype=np.float64)
    return np.cbrt(c) if curve == "cubic" else c


def log_scale(x: float, unit: float, x_max: float) -> float:
    """``log(1 + x/unit) / log(1 + x_max/unit)``, clipped to [0, 1]: 0 at x = 0, 1 at ``x_max``, the same change per
    decade above ``unit``."""
    return min(math.log1p(x / unit) / math.log1p(x_max / unit), 1.0)


class AgileSlewV1Env(AgileSlewEnv):
    r"""## Description

    The slew task of ``startracker/AgileSlew-v0`` (same spacecraft, avionics and settle criterion; see
    :class:`envs.agile_slew.AgileSlewEnv`) shaped for learners (id ``startracker/AgileSlew-v1``): a 3-axis
    body-torque action allocated to the wheels, an observation scaled to about [-1, 1] that includes the settle
    timer, a reward whose per-step scale does not vanish near the target, a bonus on settling, and early termination
    on divergence. ``sensor="ideal"`` replaces the star tracker, gyro and filter by the truth plus a stated noise:
    the baseline against which a tracker's cost to a controller is measured, and a cheap pre-training stage.

    ## Action Space

    ``action_mode="body_torque"`` (default): ``Box(-1, 1, (3,), float32)``, the body torque in units of
    ``wheel_max_torque_Nm`` per axis, allocated to the wheels by :class:`BodyTorqueAllocator` (least norm, scaled
    down with its direction kept if a wheel saturates; with four wheels 5 % of each wheel's torque is reserved for
    null-space momentum management, time constant ``null_momentum_time_s``). ``action_mode="wheel"``: the v0 action
    (``Box(-1, 1, (n_wheels,))`` wheel torque commands). Values outside [-1, 1] are clipped; NaN or inf raises
    ``ValueError``.

    | Num | Action (body_torque)               | Min | Max | Unit                         |
    |-----|------------------------------------|-----|-----|------------------------------|
    | 0-2 | body torque about body x, y, z      | -1  | 1   | fraction of wheel max torque |

    ``action_curve="cubic"`` commands ``a³`` instead of ``a`` (in either action mode): a torque of 1 % of the limit
    is the action 0.22 instead of 0.01, so a tanh-squashed policy reaches the small torques that hold the settle
    window (one step of full torque changes the rate by ~0.57°/s, eleven times the 0.05°/s tolerance). The default
    ``"linear"`` is the action the shipped v1 checkpoints before the cubic one were trained with.

    ## Observation Space

    ``Box(float32)``; from the estimate (``sensor="tracker"``) or the noisy truth (``sensor="ideal"``), never the
    bare truth. The error is the rotation vector of the shortest rotation from the estimated attitude to the
    target (angle in [0, π]), so it is continuous everywhere below 180°:

    | Num     | Observation                                              | Min | Max | Unit |
    |---------|----------------------------------------------------------|-----|-----|------|
    | 0-2     | attitude error rotation vector / π (body)                | -1  | 1   | -    |
    | 3-5     | tanh(attitude error rotation vector / ``fine_error_deg``) | -1  | 1   | -    |
    | 6-8     | body rate / ``max_rate_deg_s``, clipped                  | -f  | f   | -    |
    | 9-11    | tanh(body rate / 0.2°/s)                                 | -1  | 1   | -    |
    | 12-15   | wheel momentum / capacity                                | -1  | 1   | -    |
    | 16-18   | tracker mode one-hot: lost, acquire, track               | 0   | 1   | -    |
    | 19      | attitude 1σ, log scale: 2·log(σ/1e-6 rad)/log(π/1e-6) − 1 | -1  | 1   | -    |
    | 20      | settle timer / ``settle_hold_s``                         | 0   | 1   | -    |

    ``f`` is ``diverge_rate_factor`` (rates beyond it end the episode). ``fine_error_deg`` is 1° by default; at
    0.2° the settle tolerance (0.05°) reads 0.245 in entries 3-5, as the rate tolerance does in entries 9-11. ``observation_layout`` names the slices.

    ## Rewards

    ``reward = reward_pointing + reward_rate + reward_effort + reward_settle + reward_diverge``; every term is in
    ``info["reward_*"]``. θ is the true pointing error, ω the true rate, ``dt`` the control period, and
    ``L(x, u, x_max) = log(1 + x/u) / log(1 + x_max/u)`` in [0, 1] (the same change per decade above ``u``):

    | Term | Value | Why |
    |---|---|---|
    | ``reward_pointing`` | ``-w_pointing · L(θ, settle_tolerance, π) · dt`` | log scale: 3° → 0.5·dt, 0.05° → 0.08·dt, so the per-step signal stays large down to the tolerance |
    | ``reward_rate`` | ``-w_rate · L(ω, settle_rate, max_rate) · dt`` | damps the approach; zero only at rest |
    | ``reward_effort`` | ``-w_effort · mean(wheel command²) · dt`` | as v0 (the same control-effort figure) |
    | ``reward_settle`` | ``+settle_bonus`` on the step that settles (terminates) | the goal, seen once |
    | ``reward_diverge`` | ``-(w_pointing + w_rate + w_effort) · dt · remaining steps`` on divergence | at least what the rest of the episode could cost: diverging never pays |

    Every per-step term is ≤ 0, so settling never ends a positive stream.

    ## Episode End

    Terminated when settled (true error within ``settle_tolerance_deg`` and true rate within ``settle_rate_deg_s``
    for ``settle_hold_s``; ``info["settled"]``) or diverged (true rate above ``diverge_rate_factor · max_rate`` or
    error above the initial error plus ``diverge_error_margin_deg``; ``info["diverged"]``). Truncated after
    ``max_episode_s``; ``"auto"`` (default) fits the slew range (:func:`episode_seconds_for`: twice a
    bang-coast-bang slew at the wheels' weakest-axis acceleration, plus the hold and 5 s).

    ## Arguments

    Every argument of ``AgileSlew-v0`` (except ``task``, always ``"slew"``, and ``w_settle``), plus:

    | Argument | Default | Meaning |
    |---|---|---|
    | ``action_mode`` | ``"body_torque"`` | ``"body_torque"`` or ``"wheel"`` |
    | ``fine_error_deg`` | 1 | scale of the observation's tanh error entries, ° |
    | ``action_curve`` | ``"linear"`` | ``"linear"`` (command = a) or ``"cubic"`` (command = a³) |
    | ``sensor`` | ``"tracker"`` | ``"tracker"`` (star tracker, gyro, EKF) or ``"ideal"`` (truth plus noise) |
    | ``ideal_attitude_noise_arcsec`` | 5 | ideal sensor: white attitude noise, 1σ per axis, ″ (observed as σ); a (low, high) pair draws one level per episode, log-uniform |
    | ``ideal_rate_noise_deg_s`` | 0.001 | ideal sensor: white rate noise, 1σ per axis, °/s (a navigation-to-tactical gyro averaged over 0.1 s) |
    | ``slew_angle_deg_range`` | (5, 180) | target slew angle range, ° |
    | ``max_episode_s`` | ``"auto"`` | time limit, s, or ``"auto"`` |
    | ``w_pointing``, ``w_rate``, ``w_effort`` | 1, 0.5, 0.01 | per-step weights |
    | ``settle_bonus`` | 10 | reward on settling |
    | ``diverge_rate_factor`` | 2 | divergence rate, multiple of ``max_rate_deg_s`` |
    | ``diverge_error_margin_deg`` | 45 | divergence: error above the initial error plus this, ° |
    | ``null_momentum_time_s`` | 10 | null-space momentum management time constant, s |

    ## Version History

    * v1: body-torque action, scaled observation with the settle timer, log-scaled reward with settle bonus,
      divergence termination, episode length from the slew range, ideal sensor. Later, opt-in (the default
      behaviour unchanged): ``action_curve="cubic"``, ``fine_error_deg``, a (low, high) range of ideal-sensor
      noise, and v0's ``info_keys`` (which may also name the keys below).
    """

    # v0's info keys and the ones this task adds (step_info)
    available_info_keys = INFO_KEYS + ("reward_rate", "reward_diverge", "settled", "diverged", "sensor")

    def __init__(
        self,
        *,
        action_mode: str = "body_torque",
        action_curve: str = "linear",
        fine_error_deg: float = 1.0,
        sensor: str = "tracker",
        ideal_attitude_noise_arcsec: float = 5.0,
        ideal_rate_noise_deg_s: float = 0.001,
        slew_angle_deg_range: tuple[float, float] = (5.0, 180.0),
        max_episode_s: float | str = "auto",
        w_pointing: float = 1.0,
        w_rate: float = 0.5,
        w_effort: float = 0.01,
        settle_bonus: float = 10.0,
        diverge_rate_factor: float = 2.0,
        diverge_error_margin_deg: float = 45.0,
        null_momentum_time_s: float = 10.0,
        **kwargs,
    ):
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
        if action_curve not in ACTION_CURVES:
            raise ValueError(f"action_curve must be one of {ACTION_CURVES}, got {action_curve!r}")
        if not isinstance(fine_error_deg, (int, float)) or not np.isfinite(fine_error_deg) or fine_error_deg <= 0:
            raise ValueError(f"fine_error_deg must be a finite number > 0, got {fine_error_deg!r}")
        if sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {SENSORS}, got {sensor!r}")
        for key in ("task", "w_settle"):
            if key in kwargs:
                raise ValueError(f"AgileSlew-v1 has no argument {key!r}")
        noise_range = (ideal_attitude_noise_arcsec,) * 2 if np.ndim(ideal_attitude_noise_arcsec) == 0 \
            else tuple(float(v) for v in ideal_attitude_noise_arcsec)
        if len(noise_range) != 2 or not 0 < noise_range[0] <= noise_range[1] or not np.isfinite(noise_range[1]):
            raise ValueError("ideal_attitude_noise_arcsec must be a positive number or a (low, high) pair, "
                             f"got {ideal_attitude_noise_arcsec!r}")
        for name, value in (("ideal_rate_noise_deg_s", ideal_rate_noise_deg_s), ("w_rate", w_rate),
                            ("settle_bonus", settle_bonus), ("diverge_error_margin_deg", diverge_error_margin_deg)):
            if not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not np.isfinite(diverge_rate_factor) or diverge_rate_factor <= 1:
            raise ValueError(f"diverge_rate_factor must be > 1, got {diverge_rate_factor!r}")
        if not np.isfinite(null_momentum_time_s) or null_momentum_time_s <= 0:
            raise ValueError(f"null_momentum_time_s must be > 0, got {null_momentum_time_s!r}")
        auto = isinstance(max_episode_s, str)
        if auto and max_episode_s != "auto":
            raise ValueError(f"max_episode_s must be a number of seconds or 'auto', got {max_episode_s!r}")
        super().__init__(task="slew", slew_angle_deg_range=slew_angle_deg_range,
                         max_episode_s=120.0 if auto else max_episode_s, w_pointing=w_pointing, w_effort=w_effort,
                         w_settle=settle_bonus, **kwargs)
        spec = self.controller_spec()
        if auto:
            j_max = float(np.max(np.linalg.eigvalsh(spec["inertia_kg_m2"])))
            accel_deg_s2 = math.degrees(spec["wheel_max_torque_Nm"] / j_max)
            t = episode_seconds_for(self.slew_angle_deg_range[1], math.degrees(self.max_rate_rad_s), accel_deg_s2,
                                    self.settle_hold_s)
            self.max_episode_s = math.ceil(t / self.control_period_s) * self.control_period_s
        self.action_mode = action_mode
        self.action_curve = action_curve
        self.fine_error_rad = math.radians(float(fine_error_deg))
        self.sensor = sensor
        self.ideal_noise_range_rad = (noise_range[0] * ARCSEC, noise_range[1] * ARCSEC)
        self.ideal_attitude_noise_rad = self.ideal_noise_range_rad[0]
        self.ideal_rate_noise_rad_s = math.radians(float(ideal_rate_noise_deg_s))
        self.w_rate = float(w_rate)
        self.settle_bonus = float(settle_bonus)
        self.diverge_rate_factor = float(diverge_rate_factor)
        self.diverge_error_margin_rad = math.radians(float(diverge_error_margin_deg))
        self.allocator = BodyTorqueAllocator(spec["wheel_axes_body"].T, spec["wheel_max_torque_Nm"],
                                             null_time_s=null_momentum_time_s)
        nw = self.spacecraft.n_wheels
        self.observation_layout = {
            "attitude_error_scaled": slice(0, 3),
            "attitude_error_fine": slice(3, 6),
            "omega_scaled": slice(6, 9),
            "omega_fine": slice(9, 12),
            "wheel_momentum_fraction": slice(12, 12 + nw),
            "tracker_mode": slice(12 + nw, 15 + nw),
            "attitude_sigma_log": slice(15 + nw, 16 + nw),
            "settle_timer": slice(16 + nw, 17 + nw),
        }
        f = self.diverge_rate_factor
        low = np.concatenate([[-1.0] * 6, [-f] * 3, [-1.0] * 3, [-1.0] * nw, [0.0] * 3, [-1.0], [0.0]])
        high = np.concatenate([[1.0] * 6, [f] * 3, [1.0] * 3, [1.0] * nw, [1.0] * 3, [1.0], [1.0]])
        self.observation_space = spaces.Box(low=low.astype(np.float32), high=high.astype(np.float32), dtype=np.float32)
        n_act = 3 if action_mode == "body_torque" else nw
        self.action_space = spaces.Box(-1.0, 1.0, (n_act,), dtype=np.float32)
        self._initial_error_rad = 0.0
        self._ideal = None  # (q_meas, omega_meas) of the ideal sensor at the last step

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if self.sensor == "tracker":
            super().reset(seed=seed, options=options)
        else:
            self.reset_ideal(seed=seed, options=options)
        self._initial_error_rad = float(rk.quat_angle_between(self.spacecraft.q_body_to_icrs, self._q_target))
        est = self.current_estimate()
        info = self.step_info((0.0, 0.0, 0.0, 0.0, 0.0), est, False, False)
        return self.scaled_observation(est), info

    def reset_ideal(self, *, seed=None, options=None):
        """The v0 reset's draws (attitude, target, disturbance) without the tracker's first frame."""
        super(AgileSlewEnv, self).reset(seed=seed)
        rng = self.np_random
        options = dict(options or {})
        q0 = quat_random(rng)
        lo, hi = self.slew_angle_deg_range
        angle = np.radians(options.get("slew_angle_deg", rng.uniform(lo, hi)))
        axis = rng.normal(size=3)
        if "slew_axis_body" in options:
            axis = np.asarray(options["slew_axis_body"], dtype=np.float64)
            if axis.shape != (3,) or not np.all(np.isfinite(axis)) or np.linalg.norm(axis) == 0:
                raise ValueError(f"options['slew_axis_body'] must be a non-zero 3-vector, got {options['slew_axis_body']!r}")
        axis /= np.linalg.norm(axis)
        self._q_target = quat_normalize(quat_multiply(q0, quat_from_rotvec(axis * angle)))
        if "q_target" in options:
            self._q_target = quat_normalize(options["q_target"])
        if "faults" in options:  # checked as in v0; the ideal sensor has nothing to fail
            [Fault.from_dict(f) for f in options["faults"]]
        # reset, not set_state: MuJoCo's warm start and wheel angles from the last episode would change the last bits
        self.spacecraft.reset(q0, np.zeros(3), np.zeros(self.spacecraft.n_wheels), time_s=0.0)
        if self.disturbance_torque_Nm > 0:
            d = rng.normal(size=3)
            self._disturbance_world = d / np.linalg.norm(d) * self.disturbance_torque_Nm
        else:
            self._disturbance_world = np.zeros(3)
        self.spacecraft.set_external_torque_world(self._disturbance_world)
        self._settled_s = 0.0
        lo, hi = self.ideal_noise_range_rad
        if hi > lo:  # a range: one noise level per episode, log-uniform (the tracker's σ varies by scene and rate)
            self.ideal_attitude_noise_rad = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        self._ideal = self.ideal_measurement(rng)

    def step(self, action):
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("action contains NaN or inf")
        a = command_from_action(np.minimum(np.maximum(a, -1.0), 1.0), self.action_curve)
        sc = self.spacecraft
        if self.action_mode == "body_torque":
            h_w = sc.wheel_speeds_rad_s * sc.wheel_inertia_kg_m2
            tau_b, tau_n = self.allocator.wheel_torques(a * self.allocator.max_torque_Nm, h_w)
            tau_w = tau_b + tau_n
        else:
            tau_w = a * sc.wheel_max_torque_Nm
        sc.apply_wheel_torque(tau_w)
        cmd = tau_w / sc.wheel_max_torque_Nm
        if self.sensor == "tracker":
            dt_gyro = self.avionics.gyro_period_s
            t_obs, q_obs = sc.step_recording(dt_gyro, int(round(self.control_period_s / dt_gyro)), include_start=True)
            self.avionics.observe(t_obs, q_obs, self.np_random)
        else:
            # the physics substeps of the gyro period, with no recording consumer
            dt_gyro = self.avionics.gyro_period_s
            sc.step_recording(dt_gyro, int(round(self.control_period_s / dt_gyro)))
            self._ideal = self.ideal_measurement(self.np_random)

        dt = self.control_period_s
        err = float(rk.quat_angle_between(sc.q_body_to_icrs, self._q_target))
        rate = float(np.linalg.norm(sc.omega_body))
        settled_now = err <= self.settle_tolerance_rad and rate <= self.settle_rate_rad_s
        self._settled_s = self._settled_s + dt if settled_now else 0.0
        settled = self._settled_s >= self.settle_hold_s - 1e-9
        diverged = (rate > self.diverge_rate_factor * self.max_rate_rad_s
                    or err > self._initial_error_rad + self.diverge_error_margin_rad)
        diverged = diverged and not settled
        r_point = -self.w_pointing * log_scale(err, self.settle_tolerance_rad, math.pi) * dt
        r_rate = -self.w_rate * log_scale(rate, self.settle_rate_rad_s, self.max_rate_rad_s) * dt
        r_effort = -self.w_effort * float(np.mean(cmd * cmd)) * dt
        r_settle = self.settle_bonus if settled else 0.0
        truncated = sc.time_s >= self.max_episode_s - 1e-9
        r_diverge = 0.0
        if diverged:
            remaining = max(round((self.max_episode_s - sc.time_s) / dt), 0)
            r_diverge = -(self.w_pointing + self.w_rate + self.w_effort) * dt * remaining
        reward = r_point + r_rate + r_effort + r_settle + r_diverge
        est = self.current_estimate()
        obs = self.scaled_observation(est)
        info = self.step_info((r_point, r_rate, r_effort, r_settle, r_diverge), est, settled, diverged, err)
        return obs, float(reward), bool(settled or diverged), bool(truncated), info

    # ------------------------------------------------------------------ the ideal sensor and the observation
    def ideal_measurement(self, rng) -> tuple[np.ndarray, np.ndarray]:
        """Truth plus white noise: (attitude (4,), body rate (3,) rad/s)."""
        sc = self.spacecraft
        dq = rk.quat_from_rotvec(rng.normal(size=3) * self.ideal_attitude_noise_rad)
        q = rk.quat_multiply(sc.q_body_to_icrs, dq)
        w = sc.omega_body + rng.normal(size=3) * self.ideal_rate_noise_rad_s
        return q, w

    def current_estimate(self) -> Estimate:
        """What the controller knows: the EKF estimate, or the ideal sensor's noisy truth."""
        if self.sensor == "tracker":
            return self.avionics.estimate()
        q, w = self._ideal
        s = self.ideal_attitude_noise_rad
        return Estimate(q_body_to_icrs=q, omega_body=w, attitude_sigma_rad=s, valid=True,
                        attitude_cov_rad2=np.eye(3) * s * s)

    def current_tracker_mode(self) -> str:
        return self.avionics.tracker_mode if self.sensor == "tracker" else "track"

    def scaled_observation(self, est: Estimate) -> np.ndarray:
        nw = self.spacecraft.n_wheels
        obs = np.empty(17 + nw, dtype=np.float32)
        q_err = rk.quat_multiply(rk.quat_conjugate(est.q_body_to_icrs), self._q_target)
        e = rk.quat_to_rotvec(q_err)  # shortest rotation: angle in [0, π]
        obs[0:3] = e / math.pi
        obs[3:6] = np.tanh(e / self.fine_error_rad)
        f = self.diverge_rate_factor
        w = np.asarray(est.omega_body, dtype=np.float64)
        obs[6:9] = np.clip(w / self.max_rate_rad_s, -f, f)
        obs[9:12] = np.tanh(w / FINE_RATE_RAD_S)
        obs[12:12 + nw] = np.clip(self.spacecraft.wheel_momentum_fraction, -1.0, 1.0)
        obs[12 + nw:15 + nw] = 0.0
        obs[12 + nw + TRACKER_MODES.index(self.current_tracker_mode())] = 1.0
        sigma = min(max(float(est.attitude_sigma_rad), SIGMA_FLOOR_RAD), math.pi)
        obs[15 + nw] = 2.0 * math.log(sigma / SIGMA_FLOOR_RAD) / math.log(math.pi / SIGMA_FLOOR_RAD) - 1.0
        obs[16 + nw] = min(self._settled_s / self.settle_hold_s, 1.0) if self.settle_hold_s > 0 else 0.0
        return obs

    def step_info(self, terms, est, settled: bool, diverged: bool, pointing_error_rad=None) -> dict:
        r_point, r_rate, r_effort, r_settle, r_diverge = terms
        info = self._info((r_point, r_effort, r_settle), est, self.spacecraft.q_body_to_icrs, pointing_error_rad)
        info.update(reward_rate=r_rate, reward_diverge=r_diverge, settled=bool(settled), diverged=bool(diverged),
                    sensor=self.sensor)
        if self.sensor == "ideal":
            info.update(tracker_mode="track", update_rate_hz=1.0 / self.control_period_s, matching_latency_ms=0.0,
                        n_attitude_samples=1)
        return self.select_info(info)
