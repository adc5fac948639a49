"""Gymnasium environments: agile slews and attitude hold of a MuJoCo spacecraft closed-loop with a star tracker."""

from __future__ import annotations

import math

import numpy as np
import gymnasium as gym
from gymnasium import spaces

from envs import WALL_CLOCK_INFO_KEYS
from envs.avionics import Avionics, AvionicsConfig, TRACKER_MODES
from envs.faults import Fault, FaultSchedule, random_fault_schedule
from envs.spacecraft import Spacecraft
from startracker.onboard import ProcessorModel, UnitConfig
from startracker.rotations import quat_from_rotvec, quat_integrate, quat_multiply, quat_normalize, quat_random
from startracker.kernels import rotations as rk

__all__ = ["AgileSlewEnv", "INFO_KEYS"]

# every key of the raw environment's info, in order (the wrapper adds envs.WALL_CLOCK_INFO_KEYS)
INFO_KEYS = (
    "time_s", "q_true", "q_est", "omega_est_body", "estimate_valid", "q_target", "omega_true_body",
    "attitude_error_arcsec", "pointing_error_deg", "update_rate_hz", "update_rate_hz_per_head", "matching_latency_ms",
    "matching_latency_ms_per_head", "tracker_mode", "n_stars", "exposures_per_frame", "n_attitude_samples",
    "lost_lock_events", "faults_active", "n_wrong_samples", "filter_restarts", "n_wrong_samples_total",
    "n_confidently_wrong_samples", "n_confidently_wrong_samples_total", "estimate_wrong", "estimate_confidently_wrong",
    "n_wrong_estimates_total", "n_confidently_wrong_estimates_total", "reacquisition_times_s", "attitude_sigma_arcsec",
    "ekf_nees", "reward_pointing", "reward_effort", "reward_settle", "settled_s",
)


class AgileSlewEnv(gym.Env):
    r"""## Description

    A free-floating spacecraft (MuJoCo, RK4) with four reaction wheels must slew from a random attitude to a random
    target attitude, as fast as its wheels allow (rates up to about 20°/s), and settle there. The controller never
    sees the truth: its observation comes from the avionics chain that runs inside every step,

    * a star tracker that renders each camera frame from the true attitude history (multi-exposure: N exposures per
      frame give N attitudes per frame, N chosen from the angular rate), detects and centroids the stars
      (``fidelity="centroid"``: detections drawn from the scene truth with the pixel path's error model;
      ``fidelity="pixel"``: sparse rendering and centroiding), identifies them with no prior when lost, then tracks
      them with the double k-vector lookup table;
    * a gyro (bias, Gauss-Markov drift, angle and rate random walk, scale factor, saturation);
    * a multiplicative EKF (filterpy) that fuses every attitude sample at its exposure timestamp with the gyro.

    ``info`` reports what the star tracker achieved: the attitude update rate (``update_rate_hz``: distinct attitude
    instants per second, two heads exposed at once count once; ``update_rate_hz_per_head``), the processing latency
    (``matching_latency_ms``, from the tracker's processor model: deterministic; ``matching_latency_ms_per_head``),
    the true and estimated attitudes, and the verdicts on the tracker's samples and the filter's estimate (wrong: the
    error fails a χ²(3) test on its own covariance; confidently wrong: and flagged valid). ``gymnasium.make``'s
    ``WallClockLatency`` wrapper adds this machine's wall clock of one frame's prediction, matching, grouping by
    instant, N Wahba solutions and lock tests (``matching_wall_clock_ms``, ``matching_wall_clock_ms_per_head``,
    ``wall_clock_breakdown_ms``).

    The task ``"hold"`` (id ``startracker/AttitudeHold-v0``) keeps an inertial target under a disturbance torque.

    ## Action Space

    ``Box(-1, 1, (n_wheels,), float32)``: wheel motor torque commands, scaled by ``wheel_max_torque_Nm``. Values
    outside [-1, 1] are clipped; NaN or inf raises ``ValueError`` without touching the state.

    | Num | Action                        | Min | Max | Unit                      |
    |-----|-------------------------------|-----|-----|---------------------------|
    | 0-3 | torque command of wheel i     | -1  | 1   | fraction of max torque    |

    ## Observation Space

    ``Box(float32)`` with finite bounds, nothing from truth:

    | Num     | Observation                                                  | Min  | Max | Unit         |
    |---------|--------------------------------------------------------------|------|-----|--------------|
    | 0-2     | estimated attitude error to the target, rotation vector, body | -π   | π   | rad          |
    | 3-5     | estimated body rate (gyro minus estimated bias)              | -max | max | rad/s        |
    | 6-9     | wheel momentum / wheel momentum capacity (tachometers)       | -1   | 1   | -            |
    | 10-12   | tracker mode one-hot: lost, acquire, track                   | 0    | 1   | -            |
    | 13      | EKF attitude 1σ (largest axis), clipped                      | 0    | π   | rad          |

    ``env.unwrapped.observation_layout`` names these slices. ``max`` is the gyro's measurement range.

    ## Rewards

    ``reward = reward_pointing + reward_effort + reward_settle`` with, from the true attitude error θ (rad),
    ``reward_pointing = -w_pointing · θ · dt``, ``reward_effort = -w_effort · mean(a²) · dt`` and
    ``reward_settle = +w_settle · dt`` while θ is within ``settle_tolerance_deg``. Each term is also in
    ``info["reward_*"]``.

    ## Starting State

    Attitude uniformly random; target at a random angle in ``slew_angle_deg_range`` about a random axis; reset
    ``options`` may fix ``slew_angle_deg``, ``slew_axis_body`` (3,) or ``q_target`` (4,), and ``faults``; body at
    rest with wheels at rest (``slew``), or a small random rate (``hold``). The star tracker starts lost and the
    first frame is taken at reset, so the first observation already carries an estimate if identification works.

    ## Episode End

    Terminated when the true pointing error has stayed within ``settle_tolerance_deg`` and the true rate within
    ``settle_rate_deg_s`` for ``settle_hold_s`` (``slew`` only); truncated after ``max_episode_s``.

    ## Arguments

    | Argument | Default | Meaning |
    |---|---|---|
    | ``task`` | ``"slew"`` | ``"slew"`` or ``"hold"`` |
    | ``control_period_s`` | 0.1 or one frame | time between actions, s (a whole number of frames; default 0.1 s, or one frame period when the camera's frames are longer) |
    | ``camera`` | ``"paper000"`` | the star tracker: a preset (``paper000``, ``zy3``, ``paper003``, ``paper004`` monochrome, each with its paper's detector and exposure; ``paper004_3cmos``, paper 004's 3CMOS colour head: three registered detectors fused at centroid level, ``render()`` shows the registered colour image), a ``startracker.spec.StarTrackerSpec`` or its dict (``StarTrackerSpec.from_dict``), or a list of them, one per head with its own mounting |
    | ``frame_rate_hz`` | the camera's | camera frame rate (paper000: 10 Hz, ZY-3: 4 Hz); ``control_period_s`` must be a whole number of frames |
    | ``exposure_mode`` | the camera's | ``"single"`` or ``"multi"`` |
    | ``n_exposures`` | the camera's (``"adaptive"``) | N per multi-exposure frame: ``"adaptive"`` (from the rate) or an int 1..max_exposures |
    | ``identify_method`` | the camera's (``"pyramid"``) | lost-in-space method: ``pyramid``, ``voting``, ``brightness``, ``string`` |
    | ``matcher`` | the camera's (``"dkvlut"``) | tracking matcher: ``dkvlut``, ``brute``, ``kdtree`` |
    | ``fidelity`` | ``"centroid"`` | ``"centroid"`` (fast) or ``"pixel"`` (rendered windows, centroiding) |
    | ``gyro_grade`` | ``"tactical"`` | ``ideal``, ``navigation``, ``tactical``, ``industrial`` |
    | ``mag_limit`` | the camera's (6.0; ZY-3 5.5) | catalog limit, V |
    | ``n_heads`` | 1, or the list's length | optical heads: 2 with one camera mounts two copies symmetric about body +z (paper 001); each runs its own state machine, the EKF fuses all, a lost head is re-acquired with the EKF attitude as an inertial prior |
    | ``head_separation_deg`` | 45 | angle between the two boresights, ° |
    | ``inertia_kg_m2`` | (5, 6, 4) | spacecraft inertia, diagonal or 3×3, kg m² |
    | ``n_wheels`` | 4 | 3 (orthogonal) or 4 (pyramid) |
    | ``wheel_max_torque_Nm`` | 0.5 | wheel torque limit, N m |
    | ``wheel_max_speed_rad_s`` | 600 | wheel speed limit, rad/s |
    | ``max_rate_deg_s`` | 20 | rate limit given to controllers (``controller_spec``), °/s |
    | ``slew_angle_deg_range`` | (30, 180) | target slew angle range, ° |
    | ``settle_tolerance_deg`` | 0.05 | pointing tolerance for settling, ° |
    | ``settle_rate_deg_s`` | 0.05 | rate tolerance for settling, °/s |
    | ``settle_hold_s`` | 2.0 | time within tolerance that ends the episode, s |
    | ``max_episode_s`` | 120 | time limit, s |
    | ``disturbance_torque_Nm`` | 0 (slew), 1e-3 (hold) | constant inertial disturbance torque magnitude, N m |
    | ``w_pointing``, ``w_effort``, ``w_settle`` | 1, 0.01, 1 | reward weights |
    | ``faults`` | () | fault schedule: ``envs.faults.Fault`` objects or dicts ``{kind, t_start_s, duration_s, severity}`` |
    | ``random_faults_per_min`` | 0 | random faults (Poisson) drawn at each reset, for soak runs |
    | ``processor`` | ``ProcessorModel()`` | the tracker's processing budget (``startracker.processor.ProcessorModel``, a dict of its fields, or a fixed latency in ms): each frame's samples reach the filter that long after the frame ends; ``info["matching_latency_ms"]`` is this modelled latency |
    | ``info_keys`` | None (every key) | the ``info`` keys to return (``envs.agile_slew.INFO_KEYS``, the wrapper's ``envs.WALL_CLOCK_INFO_KEYS``), e.g. ``("reward_pointing", "settled_s")``: a vector env pickles and merges every key of every step, so an RL run that reads a few keys steps faster with just those; the episode is the same |
    | ``render_mode`` | None | ``"rgb_array"``: the last star image with detections marked |

    ## Version History

    * v0: first release.
    * v0, sensor revision (task unchanged: observation, action, reward, episode ends, info keys): the paper000
      camera takes paper 000's N rule (21 exposures, 210 Hz at 20°/s); near-overlapping spots join in both
      fidelities; the tracker drops joined spots and instants off a smooth motion (docs/environment.md).
    * v0, ``info_keys`` argument (default: every key, as before).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    available_info_keys = INFO_KEYS  # what ``info_keys`` may name, with envs.WALL_CLOCK_INFO_KEYS

    def __init__(
        self,
        *,
        task: str = "slew",
        control_period_s: float | None = None,
        camera="paper000",
        frame_rate_hz: float | None = None,
        exposure_mode: str | None = None,
        n_exposures: int | str | None = None,
        identify_method: str | None = None,
        matcher: str | None = None,
        fidelity: str = "centroid",
        gyro_grade: str = "tactical",
        mag_limit: float | None = None,
        n_heads: int | None = None,
        head_separation_deg: float = 45.0,
        inertia_kg_m2=(5.0, 6.0, 4.0),
        n_wheels: int = 4,
        wheel_max_torque_Nm: float = 0.5,
        wheel_max_speed_rad_s: float = 600.0,
        max_rate_deg_s: float = 20.0,
        slew_angle_deg_range: tuple[float, float] = (30.0, 180.0),
        settle_tolerance_deg: float = 0.05,
        settle_rate_deg_s: float = 0.05,
        settle_hold_s: float = 2.0,
        max_episode_s: float = 120.0,
        disturbance_torque_Nm: float | None = None,
        w_pointing: float = 1.0,
        w_effort: float = 0.01,
        w_settle: float = 1.0,
        faults=None,
        random_faults_per_min: float = 0.0,
        processor=None,
        info_keys=None,
        render_mode: str | None = None,
    ):
        if task not in ("slew", "hold"):
            raise ValueError(f"task must be 'slew' or 'hold', got {task!r}")
        for name, value in (
            ("control_period_s", 0.1 if control_period_s is None else control_period_s),
            ("frame_rate_hz", 10.0 if frame_rate_hz is None else frame_rate_hz),
            ("max_rate_deg_s", max_rate_deg_s),
            ("settle_tolerance_deg", settle_tolerance_deg),
            ("settle_rate_deg_s", settle_rate_deg_s),
            ("max_episode_s", max_episode_s),
        ):
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        if not np.isfinite(settle_hold_s) or settle_hold_s < 0:
            raise ValueError(f"settle_hold_s must be >= 0, got {settle_hold_s!r}")
        lo, hi = (float(v) for v in slew_angle_deg_range)
        if not (0.0 <= lo <= hi <= 180.0):
            raise ValueError(f"slew_angle_deg_range must satisfy 0 <= lo <= hi <= 180, got {slew_angle_deg_range!r}")
        for name, value in (("w_pointing", w_pointing), ("w_effort", w_effort), ("w_settle", w_settle)):
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be >= 0, got {value!r}")
        self.fault_list = tuple(Fault.from_dict(f) for f in (faults or ()))
        if not np.isfinite(random_faults_per_min) or random_faults_per_min < 0:
            raise ValueError(f"random_faults_per_min must be >= 0, got {random_faults_per_min!r}")
        self.random_faults_per_min = float(random_faults_per_min)
        if processor is None:
            processor = ProcessorModel()
        elif isinstance(processor, dict):
            processor = ProcessorModel(**processor)
        elif isinstance(processor, (int, float)) and not isinstance(processor, bool):
            processor = ProcessorModel.fixed(float(processor))
        if not isinstance(processor, ProcessorModel):
            raise TypeError(f"processor must be a ProcessorModel, a dict of its fields, a latency in ms or None, "
                            f"got {type(processor).__name__}")
        self.info_keys = self.check_info_keys(info_keys)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        if disturbance_torque_Nm is None:
            disturbance_torque_Nm = 1e-3 if task == "hold" else 0.0
        if not np.isfinite(disturbance_torque_Nm) or disturbance_torque_Nm < 0:
            raise ValueError(f"disturbance_torque_Nm must be >= 0, got {disturbance_torque_Nm!r}")

        self.task = task
        if control_period_s is None:
            # 0.1 s, or one frame when the camera's own frames are longer (ZY-3: 4 Hz)
            control_period_s = 0.1 if frame_rate_hz is not None else max(0.1, UnitConfig(camera=camera).frame_period_s)
        self.control_period_s = float(control_period_s)
        self.slew_angle_deg_range = (lo, hi)
        self.settle_tolerance_rad = np.radians(settle_tolerance_deg)
        self.settle_rate_rad_s = np.radians(settle_rate_deg_s)
        self.settle_hold_s = float(settle_hold_s)
        self.max_episode_s = float(max_episode_s)
        self.max_rate_rad_s = np.radians(max_rate_deg_s)
        self.disturbance_torque_Nm = float(disturbance_torque_Nm)
        self.w_pointing, self.w_effort, self.w_settle = float(w_pointing), float(w_effort), float(w_settle)
        self.render_mode = render_mode

        self.spacecraft = Spacecraft(
            inertia_kg_m2=inertia_kg_m2,
            n_wheels=n_wheels,
            wheel_max_torque_Nm=wheel_max_torque_Nm,
            wheel_max_speed_rad_s=wheel_max_speed_rad_s,
        )
        self.avionics = Avionics(
            AvionicsConfig(
                camera=camera,
                frame_period_s=None if frame_rate_hz is None else 1.0 / float(frame_rate_hz),
                control_period_s=self.control_period_s,
                exposure_mode=exposure_mode,
                n_exposures=n_exposures,
                identify_method=identify_method,
                matcher=matcher,
                fidelity=fidelity,
                gyro_grade=gyro_grade,
                mag_limit=mag_limit,
                n_heads=n_heads,
                head_separation_deg=head_separation_deg,
                keep_images=render_mode == "rgb_array",
                processor=processor,
            )
        )
        # the values in use of the arguments the camera spec decides (None above: the spec's), for provenance
        cfg = self.avionics.config
        self.frame_rate_hz = 1.0 / cfg.frame_period_s
        self.exposure_mode, self.n_exposures = cfg.exposure_mode, cfg.n_exposures
        self.identify_method, self.matcher, self.mag_limit = cfg.identify_method, cfg.matcher, cfg.mag_limit
        self.n_heads = cfg.n_heads
        nw = self.spacecraft.n_wheels
        self.observation_layout = {
            "attitude_error_rotvec": slice(0, 3),
            "omega_body": slice(3, 6),
            "wheel_momentum_fraction": slice(6, 6 + nw),
            "tracker_mode": slice(6 + nw, 9 + nw),
            "attitude_sigma": slice(9 + nw, 10 + nw),
        }
        w_max = self.avionics.gyro_max_rate_rad_s
        low = np.concatenate([[-np.pi] * 3, [-w_max] * 3, [-1.0] * nw, [0.0] * 3, [0.0]]).astype(np.float32)
        high = np.concatenate([[np.pi] * 3, [w_max] * 3, [1.0] * nw, [1.0] * 3, [np.pi]]).astype(np.float32)
        self.observation_space = spaces.Box(low=low, high=high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (nw,), dtype=np.float32)
        self._action_shape = self.action_space.shape
        self._wheel_max_torque_Nm = self.spacecraft.wheel_max_torque_Nm  # a copy, fixed for the env's life
        self._q_target = np.array([1.0, 0.0, 0.0, 0.0])
        self._disturbance_world = np.zeros(3)
        self._settled_s = 0.0
        self._last_info: dict = {}

    @classmethod
    def check_info_keys(cls, info_keys) -> tuple[str, ...] | None:
        """``info_keys`` checked: None (every key), or a tuple of distinct known key names in the caller's order.

        Raises ``TypeError`` for a string or a non-string entry, ``ValueError`` naming any unknown key.
        """
        if info_keys is None:
            return None
        if isinstance(info_keys, (str, bytes)):
            raise TypeError(f"info_keys must be a sequence of key names or None, not a single string: {info_keys!r}")
        try:
            keys = tuple(info_keys)
        except TypeError:
            raise TypeError(f"info_keys must be a sequence of key names or None, got {type(info_keys).__name__}") from None
        known = cls.available_info_keys + WALL_CLOCK_INFO_KEYS
        for k in keys:
            if not isinstance(k, str):
                raise TypeError(f"info_keys must hold strings, got {k!r}")
        unknown = [k for k in keys if k not in known]
        if unknown:
            raise ValueError(f"info_keys names unknown keys {unknown}; the keys are {list(known)}")
        return tuple(dict.fromkeys(keys))

    def select_info(self, info: dict) -> dict:
        """The entries of ``info`` that ``info_keys`` asks for (all when it is None), in its order."""
        keys = self.info_keys
        if keys is None:
            return info
        return {k: info[k] for k in keys if k in info}

    # ------------------------------------------------------------------ design (not state) for controllers
    def controller_spec(self) -> dict:
        """Design parameters a controller may use (``policies.ControllerSpec(**spec)``): no state, no truth."""
        return dict(
            inertia_kg_m2=self.spacecraft.inertia_kg_m2.copy(),
            wheel_axes_body=self.spacecraft.wheel_axes_body.T.copy(),
            wheel_max_torque_Nm=float(np.min(self.spacecraft.wheel_max_torque_Nm)),
            max_rate_rad_s=float(self.max_rate_rad_s),
            control_period_s=self.control_period_s,
            observation_layout=dict(self.observation_layout),
        )

    @property
    def q_target_body_to_icrs(self) -> np.ndarray:
        return self._q_target.copy()

    @property
    def matching_wall_clock_ms(self) -> float:
        """This machine's wall clock of the last step's prediction and matching, ms: a measurement of the computer,
        kept out of ``info`` (the ``envs.wrappers.WallClockLatency`` wrapper reports it)."""
        return float(self.avionics.last_stats["matching_wall_clock_ms"])

    @property
    def wall_clock_info(self) -> dict:
        """The last step's wall-clock figures (``envs.WALL_CLOCK_INFO_KEYS``), ms: the total, per head, and by stage
        (``predict_match``, ``group_solve_test``, ``identify``)."""
        st = self.avionics.last_stats
        return {"matching_wall_clock_ms": float(st["matching_wall_clock_ms"]),
                "matching_wall_clock_ms_per_head": list(st["matching_wall_clock_ms_per_head"]),
                "wall_clock_breakdown_ms": dict(st["wall_clock_breakdown_ms"])}

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        options = dict(options or {})
        q0 = quat_random(rng)
        if self.task == "slew":
            lo, hi = self.slew_angle_deg_range
            angle = np.radians(options.get("slew_angle_deg", rng.uniform(lo, hi)))
            axis = rng.normal(size=3)
            if "slew_axis_body" in options:  # e.g. (1, 0, 0): cross-boresight for a camera on +z
                axis = np.asarray(options["slew_axis_body"], dtype=np.float64)
                if axis.shape != (3,) or not np.all(np.isfinite(axis)) or np.linalg.norm(axis) == 0:
                    raise ValueError(f"options['slew_axis_body'] must be a non-zero 3-vector, got {options['slew_axis_body']!r}")
            axis /= np.linalg.norm(axis)
            self._q_target = quat_normalize(quat_multiply(q0, quat_from_rotvec(axis * angle)))
            w0 = np.zeros(3)
        else:
            self._q_target = q0.copy()
            w0 = rng.normal(size=3) * np.radians(0.05)
        if "q_target" in options:
            self._q_target = quat_normalize(options["q_target"])
        self.spacecraft.reset(q0, w0, np.zeros(self.spacecraft.n_wheels), time_s=0.0)
        if self.disturbance_torque_Nm > 0:
            d = rng.normal(size=3)
            self._disturbance_world = d / np.linalg.norm(d) * self.disturbance_torque_Nm
        else:
            self._disturbance_world = np.zeros(3)
        self.spacecraft.set_external_torque_world(self._disturbance_world)
        self._settled_s = 0.0
        faults = list(self.fault_list)
        if "faults" in options:
            faults = [Fault.from_dict(f) for f in options["faults"]]
        if self.random_faults_per_min > 0:
            faults += list(random_fault_schedule(rng, self.max_episode_s, self.random_faults_per_min).faults)
        # The first frame is exposed while the spacecraft sits at its initial attitude (at rest or drifting slowly):
        # the truth over it comes from integrating the initial rate, without stepping the episode's clock.
        t = self.spacecraft.time_s
        t_pre = np.linspace(t - self.avionics.config.frame_period_s, t, 11)
        q_pre = quat_integrate(self.spacecraft.q_body_to_icrs, self.spacecraft.omega_body, t_pre - t)
        self.avionics.reset(rng, FaultSchedule(faults), first_frame_truth=(t_pre, q_pre))
        obs = self._observation()
        info = self._info(reward_terms=(0.0, 0.0, 0.0))
        return obs, self.select_info(info)

    def step(self, action):
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self._action_shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        a_list = a.tolist()  # a few floats: Python's scalar arithmetic beats numpy's dispatch on them
        if not all(map(math.isfinite, a_list)):
            raise ValueError("action contains NaN or inf")
        a_list = [min(max(v, -1.0), 1.0) for v in a_list]  # finite: np.clip's values
        sc = self.spacecraft
        sc.apply_wheel_torque(np.array(a_list) * self._wheel_max_torque_Nm, validate=False)  # a is checked
        # the env steps the physics and records the truth (with its starting instant); the avionics observe it
        dt_gyro = self.avionics.gyro_period_s
        t_obs, q_obs = sc.step_recording(dt_gyro, int(round(self.control_period_s / dt_gyro)), include_start=True)
        self.avionics.observe(t_obs, q_obs, self.np_random)

        q_true = sc.q_body_to_icrs
        est = self.avionics.estimate()  # one fresh estimate for the observation and the info
        # the step's attitude errors in one compiled call (pointing, estimation, the observed error, the NEES's)
        figures = rk.pointing_errors(q_true, est.q_body_to_icrs, self._q_target).tolist()
        err = figures[0]
        w0, w1, w2 = sc.omega_body.tolist()
        rate = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        dt = self.control_period_s
        settled_now = err <= self.settle_tolerance_rad and rate <= self.settle_rate_rad_s
        self._settled_s = self._settled_s + dt if settled_now else 0.0
        r_point = -self.w_pointing * err * dt
        # mean of the squared commands, summed left to right as numpy does for a few elements
        r_effort = -self.w_effort * (sum(x * x for x in a_list) / len(a_list)) * dt
        r_settle = self.w_settle * dt if settled_now else 0.0
        reward = r_point + r_effort + r_settle
        terminated = self.task == "slew" and self._settled_s >= self.settle_hold_s - 1e-9
        truncated = sc.time_s >= self.max_episode_s - 1e-9
        obs = self._observation(est, figures)
        info = self._info((r_point, r_effort, r_settle), est, q_true, err, figures)
        return obs, float(reward), bool(terminated), bool(truncated), self.select_info(info)

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self.avionics.render_last_frame()

    # ------------------------------------------------------------------ internals
    def _observation(self, est=None, figures=None) -> np.ndarray:
        """The observation of ``est`` (a fresh estimate when None); ``figures``: :func:`rk.pointing_errors` of the
        step as a list, when the step has it."""
        if est is None:
            est = self.avionics.estimate()
        if figures is None:
            figures = rk.pointing_errors(self.spacecraft.q_body_to_icrs, est.q_body_to_icrs, self._q_target).tolist()
        # error rotation vector (3), rate (3), wheel momentum fractions (W), tracker mode one-hot (3), σ (1): Python
        # floats clipped as np.clip does (max then min), each rounded to float32 once by the array
        w_max = self.avionics.gyro_max_rate_rad_s
        wheels = self.spacecraft.wheel_momentum_fraction.tolist()
        vals = (figures[2:5] + [min(max(w, -w_max), w_max) for w in est.omega_body.tolist()]
                + [min(max(h, -1.0), 1.0) for h in wheels] + [0.0, 0.0, 0.0] + [min(est.attitude_sigma_rad, np.pi)])
        vals[6 + len(wheels) + TRACKER_MODES.index(self.avionics.tracker_mode)] = 1.0
        return np.array(vals, dtype=np.float32)

    @staticmethod
    def _nees(est, d_rad) -> float | None:
        """Normalised estimation error squared of the EKF attitude (3 dof; mean 3 when consistent), None before a fix;
        ``d_rad``: the estimate's error rotation vector (3 floats, rad; :func:`rk.pointing_errors`' ``[5:8]``)."""
        p = est.attitude_cov_rad2
        if p is None:
            return None
        d0, d1, d2 = d_rad
        (a, b, c), (_, e, f), (_, _, i) = p.tolist()  # symmetric: d' P⁻¹ d by the adjugate, on scalars
        c00, c01, c02 = e * i - f * f, c * f - b * i, b * f - c * e
        c11, c12, c22 = a * i - c * c, b * c - a * f, a * e - b * b
        det = a * c00 + b * c01 + c * c02
        q = (d0 * (c00 * d0 + c01 * d1 + c02 * d2) + d1 * (c01 * d0 + c11 * d1 + c12 * d2)
             + d2 * (c02 * d0 + c12 * d1 + c22 * d2))
        return float(q / det)

    def _info(self, reward_terms, est=None, q_true=None, pointing_error_rad=None, figures=None) -> dict:
        """The step's info; ``est`` (a fresh estimate), ``q_true`` (a copy of the true attitude), the pointing
        error (rad) and ``figures`` (:func:`rk.pointing_errors` as a list) when the step has them already."""
        if q_true is None:
            q_true = self.spacecraft.q_body_to_icrs
        if est is None:
            est = self.avionics.estimate()
        if figures is None:
            figures = rk.pointing_errors(q_true, est.q_body_to_icrs, self._q_target).tolist()
        if pointing_error_rad is None:
            pointing_error_rad = figures[0]
        stats = self.avionics.last_stats
        info = {
            "time_s": float(self.spacecraft.time_s),
            "q_true": q_true,
            "q_est": est.q_body_to_icrs.copy(),
            "omega_est_body": est.omega_body.copy(),
            "estimate_valid": bool(est.valid),
            "q_target": self._q_target.copy(),
            "omega_true_body": self.spacecraft.omega_body,
            "attitude_error_arcsec": math.degrees(figures[1]) * 3600.0,
            "pointing_error_deg": math.degrees(pointing_error_rad),
            "update_rate_hz": stats["update_rate_hz"],
            "update_rate_hz_per_head": list(stats["update_rate_hz_per_head"]),
            "matching_latency_ms": stats["matching_latency_ms"],
            "matching_latency_ms_per_head": list(stats["matching_latency_ms_per_head"]),
            "tracker_mode": self.avionics.tracker_mode,
            "n_stars": stats["n_stars"],
            "exposures_per_frame": stats["exposures_per_frame"],
            "n_attitude_samples": stats["n_attitude_samples"],
            "lost_lock_events": stats["lost_lock_events"],
            "faults_active": list(stats["faults_active"]),
            "n_wrong_samples": stats["n_wrong_samples"],
            "filter_restarts": stats["filter_restarts"],
            "n_wrong_samples_total": self.avionics.n_wrong_samples_total,
            "n_confidently_wrong_samples": stats["n_confidently_wrong_samples"],
            "n_confidently_wrong_samples_total": self.avionics.n_confidently_wrong_samples_total,
            "estimate_wrong": stats["estimate_wrong"],
            "estimate_confidently_wrong": stats["estimate_confidently_wrong"],
            "n_wrong_estimates_total": self.avionics.n_wrong_estimates_total,
            "n_confidently_wrong_estimates_total": self.avionics.n_confidently_wrong_estimates_total,
            "reacquisition_times_s": self.avionics.reacquisition_times_s,
            "attitude_sigma_arcsec": math.degrees(min(float(est.attitude_sigma_rad), math.pi)) * 3600.0,
            "ekf_nees": self._nees(est, figures[5:8]),
            "reward_pointing": reward_terms[0],
            "reward_effort": reward_terms[1],
            "reward_settle": reward_terms[2],
            "settled_s": self._settled_s,
        }
        return info
