"""The avionics chain inside every env step: star tracker frames, gyro samples and the attitude EKF.

Timeline of one control period ``[t0, t1]``:

1. The spacecraft is integrated in MuJoCo substeps; the true attitude at every substep is kept (truth
   history), and each substep yields one gyro sample (the average true rate over the substep, from the
   quaternion increment, plus the gyro's errors).
2. Each camera frame ``[tf, tf + T]`` inside the period is imaged from the truth history: an exposure plan
   (single while the tracker is lost, multi-exposure with N chosen from the *gyro* rate while tracking),
   the scene, detections (centroid or pixel fidelity), then the ``StarTracker`` state machine, which
   returns up to N attitude samples stamped with their exposure instants.
3. The EKF replays the period: gyro samples and attitude samples in time order (``AttitudeEKF.process``).
   The frame's result is thus used as soon as the frame ends; processing delay is not simulated (the
   measured matching latency is reported, never fed back into the dynamics).

Everything random draws from the env's ``np_random``; wall-clock latencies are reported only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from startracker.catalog import load_catalog
from startracker.filter import AttitudeEKF
from startracker.imu import Gyro, gyro_preset, GYRO_GRADES
from startracker.rotations import quat_conjugate, quat_integrate, quat_interpolate, quat_rotate
from startracker.scene import BrightBody, ExposurePlan, choose_n_exposures

from startracker.multifov import MultiFovSensor

from envs.camera_head import HEAD_CAMERAS, make_head
from envs.faults import FaultSchedule
from startracker.sensor import StarTracker
from startracker.kernels import rotations as rk

__all__ = ["Avionics", "AvionicsConfig", "Estimate", "TRACKER_MODES"]

TRACKER_MODES = ("lost", "acquire", "track")
IDENTIFY_METHODS = ("pyramid", "voting", "brightness", "string")
MATCHERS = ("dkvlut", "brute", "kdtree")


@dataclass(frozen=True)
class AvionicsConfig:
    """Star tracker, gyro and filter settings (the env's keyword arguments, validated here)."""

    camera: str = "paper000"
    frame_period_s: float = 0.1
    control_period_s: float = 0.1
    exposure_mode: str = "multi"
    n_exposures: int | str = "adaptive"
    exposure_s: float | None = None  # default: the head's (1 ms intensified, 10 ms plain CMOS)
    single_exposure_s: float = 0.02
    max_exposures: int = 21
    identify_method: str = "pyramid"
    matcher: str = "dkvlut"
    fidelity: str = "centroid"
    gyro_grade: str = "tactical"
    gyro_rate_hz: float = 100.0
    mag_limit: float = 6.0
    n_heads: int = 1
    head_separation_deg: float = 45.0
    keep_images: bool = False

    def __post_init__(self):
        if self.camera not in HEAD_CAMERAS:
            raise ValueError(f"camera must be one of {HEAD_CAMERAS}, got {self.camera!r}")
        if self.n_heads not in (1, 2) or isinstance(self.n_heads, bool):
            raise ValueError(f"n_heads must be 1 or 2, got {self.n_heads!r}")
        if self.n_heads == 2 and self.camera == "paper004_3cmos":
            raise ValueError("n_heads=2 is available for the monochrome cameras only, not camera='paper004_3cmos'")
        if not (np.isfinite(self.head_separation_deg) and 10.0 <= self.head_separation_deg <= 170.0):
            raise ValueError(f"head_separation_deg must be in [10, 170] (heads must not overlap or point the same way), "
                             f"got {self.head_separation_deg!r}")
        if self.exposure_mode not in ("single", "multi"):
            raise ValueError(f"exposure_mode must be 'single' or 'multi', got {self.exposure_mode!r}")
        n = self.n_exposures
        if not (n == "adaptive" or (isinstance(n, (int, np.integer)) and not isinstance(n, bool) and 1 <= n <= self.max_exposures)):
            raise ValueError(f"n_exposures must be 'adaptive' or an int in [1, {self.max_exposures}], got {n!r}")
        if self.identify_method not in IDENTIFY_METHODS:
            raise ValueError(f"identify_method must be one of {IDENTIFY_METHODS}, got {self.identify_method!r}")
        if self.matcher not in MATCHERS:
            raise ValueError(f"matcher must be one of {MATCHERS}, got {self.matcher!r}")
        if self.fidelity not in ("centroid", "pixel"):
            raise ValueError(f"fidelity must be 'centroid' or 'pixel', got {self.fidelity!r}")
        if self.gyro_grade not in GYRO_GRADES:
            raise ValueError(f"gyro_grade must be one of {sorted(GYRO_GRADES)}, got {self.gyro_grade!r}")
        ratio = self.control_period_s / self.frame_period_s
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(
                "frame_rate_hz * control_period_s must be a positive integer (whole frames per control period), "
                f"got {ratio:.6g}"
            )
        steps = self.frame_period_s * self.gyro_rate_hz
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ValueError("the frame period must be a whole number of gyro samples (gyro_rate_hz * frame period)")


@dataclass
class Estimate:
    """What the controller may know: the filter's output."""

    q_body_to_icrs: np.ndarray
    omega_body: np.ndarray
    attitude_sigma_rad: float
    valid: bool
    attitude_cov_rad2: np.ndarray | None = None  # (3, 3) body frame, None before the first fix


class Avionics:
    """Star tracker + gyro + MEKF run against the spacecraft's truth.

    Parameters
    ----------
    config : AvionicsConfig
    """

    def __init__(self, config: AvionicsConfig):
        if not isinstance(config, AvionicsConfig):
            raise TypeError("config must be an AvionicsConfig")
        self.config = config
        if config.n_heads == 1:
            self.heads = [make_head(config.camera)]
        else:
            # paper 001's layout: two heads symmetric about body +z, boresights head_separation_deg apart
            base = make_head(config.camera)
            mounted = MultiFovSensor.two_heads(base.camera, config.head_separation_deg).heads
            self.heads = [make_head(config.camera, q_cam_to_body=c.q_cam_to_body) for c in mounted]
        self.head = self.heads[0]
        self.camera = self.head.camera
        self.exposure_s = config.exposure_s if config.exposure_s is not None else self.head.exposure_s
        self.catalog = load_catalog(mag_limit=config.mag_limit)
        self.gyro_spec = gyro_preset(config.gyro_grade, rate_hz=config.gyro_rate_hz)
        self.trackers = [
            StarTracker(h.camera, self.catalog, identify_method=config.identify_method, matcher=config.matcher)
            for h in self.heads
        ]
        self.tracker = self.trackers[0]
        self.head_modes = ["lost"] * len(self.heads)
        self.gyro_max_rate_rad_s = float(min(self.gyro_spec.max_rate_rad_s, 2 * np.pi))
        self._gyro_dt = 1.0 / config.gyro_rate_hz
        self.gyro: Gyro | None = None
        self.ekf: AttitudeEKF | None = None
        self.tracker_mode = "lost"
        self.last_stats = self._empty_stats()
        self._last_frame = None
        self._lost_events = 0

    # ------------------------------------------------------------------ lifecycle
    @staticmethod
    def _empty_stats() -> dict:
        return dict(
            update_rate_hz=0.0,
            matching_latency_ms=0.0,
            n_stars=0,
            exposures_per_frame=0,
            n_attitude_samples=0,
            lost_lock_events=0,
            n_wrong_samples=0,
            filter_restarts=0,
            faults_active=[],
        )

    def reset(self, spacecraft, rng: np.random.Generator, faults: FaultSchedule | None = None) -> None:
        """New episode: fresh gyro errors, lost tracker, no estimate; then one single-exposure frame."""
        self.faults = faults if faults is not None else FaultSchedule()
        self._n_wrong = 0
        self._rejected_frames = 0
        self._filter_resets = 0
        self._t_lock_lost = None
        self._reacquisition_s: list[float] = []
        self.gyro = Gyro(self.gyro_spec, rng)
        for tr in self.trackers:
            tr.reset()
        self.head_modes = ["lost"] * len(self.heads)
        self.tracker_mode = "lost"
        self.ekf = None
        self._omega_gyro = np.zeros(3)
        self._lost_events = 0
        self.last_stats = self._empty_stats()
        t = spacecraft.time_s
        # The first frame is exposed while the spacecraft sits at its initial attitude (at rest or drifting slowly):
        # the truth over it comes from integrating the initial rate, without stepping the episode's clock.
        w = spacecraft.omega_body
        t_pre = np.linspace(t - self.config.frame_period_s, t, 11)
        q_pre = quat_integrate(spacecraft.q_body_to_icrs, w, t_pre - t)
        samples = self._run_frame(t_pre[0], (t_pre, q_pre), rng)
        if samples:
            last = samples[-1]
            self._init_ekf(last, t)

    def _init_ekf(self, sample, t_now: float) -> None:
        sig = float(np.sqrt(np.max(np.linalg.eigvalsh(sample.covariance_rad2))))
        self.ekf = AttitudeEKF(
            sample.q_body_to_icrs,
            arw_rad_sqrt_s=max(self.gyro_spec.arw_rad_sqrt_s, 1e-7),
            rrw_rad_s_sqrt_s=self.gyro_spec.bias_rw_equivalent_rad_s_sqrt_s,
            sigma_attitude_rad=max(3 * sig, 1e-5),
            sigma_bias_rad_s=max(self.gyro_spec.bias_sigma_rad_s + self.gyro_spec.gm_sigma_rad_s, 1e-7),
            t_s=sample.t_s,
            gate_chi2=30.0,
        )
        if t_now > sample.t_s:
            self.ekf.propagate(self._omega_gyro, t_now - sample.t_s)

    # ------------------------------------------------------------------ one control period
    def advance(self, spacecraft, duration_s: float, rng: np.random.Generator) -> None:
        """Integrate the spacecraft over ``duration_s`` and run frames, gyro and filter over it."""
        n_sub = int(round(duration_s / self._gyro_dt))
        t0 = spacecraft.time_s
        times = np.empty(n_sub + 1)
        quats = np.empty((n_sub + 1, 4))
        times[0] = t0
        quats[0] = spacecraft.q_body_to_icrs
        if hasattr(spacecraft, "_step_recording"):
            spacecraft._step_recording(self._gyro_dt, n_sub, times[1:], quats[1:])
        else:
            for k in range(n_sub):
                spacecraft.step(self._gyro_dt)
                times[k + 1] = spacecraft.time_s
                quats[k + 1] = spacecraft.q_body_to_icrs
        # average true rate over each gyro interval, from the quaternion increment (body frame)
        dq = rk.quat_multiply(quat_conjugate(quats[:-1]), quats[1:])
        omega_avg = rk.quat_to_rotvec(dq) / np.diff(times)[:, None]
        omega_meas = self.gyro.measure(omega_avg, rng)
        if self.faults:
            omega_meas = self.faults.modify_gyro(omega_meas, times[1:], rng)
        self._omega_gyro = omega_meas[-1].copy()

        samples = []
        n_frames = int(round(duration_s / self.config.frame_period_s))
        stats = self._empty_stats()
        lat = []
        offsets = []
        for f in range(n_frames):
            tf = t0 + f * self.config.frame_period_s
            # the gyro reading at the frame's start: the tracker propagates its prediction from frame_time
            k = min(int(round((tf - t0) / self._gyro_dt)), len(omega_meas) - 1)
            new = self._run_frame(tf, (times, quats), rng, omega_hint=omega_meas[k])
            samples.extend(new)
            offsets.extend([self._last_time_error_s] * len(new))
            lat.append(self.last_stats["matching_latency_ms"])
            stats["n_stars"] = self.last_stats["n_stars"]
            stats["exposures_per_frame"] = self.last_stats["exposures_per_frame"]
        stats["matching_latency_ms"] = float(np.mean(lat)) if lat else 0.0
        stats["filter_restarts"] = self._filter_resets
        stats["n_attitude_samples"] = len(samples)
        stats["update_rate_hz"] = len(samples) / duration_s
        stats["lost_lock_events"] = self._lost_events
        stats["n_wrong_samples"] = self._count_wrong(samples, np.array(offsets), times, quats)
        stats["faults_active"] = self.faults.active_kinds(t0, times[-1]) if self.faults else []

        if self.ekf is None:
            if samples:
                first = samples[0]
                self._init_ekf(first, first.t_s)
                rest = [s for s in samples[1:]]
                self._ekf_process(times, omega_meas, rest, start_index=int(np.searchsorted(times, first.t_s, side="right")))
        else:
            self._ekf_process(times, omega_meas, samples)
        self.last_stats = stats

    def _ekf_process(self, times, omega_meas, samples, start_index: int = 1) -> None:
        """Replay gyro intervals ``(times[k-1], times[k]]`` and the attitude samples in time order."""
        tg = times[start_index:]
        wg = omega_meas[start_index - 1 :]
        if len(tg) == 0:
            return
        if samples:
            samples = sorted(samples, key=lambda s: s.t_s)
            qm = np.array([s.q_body_to_icrs for s in samples])
            tm = np.array([s.t_s for s in samples])
            cm = np.array([s.covariance_rad2 for s in samples])
            keep = tm >= self.ekf.t_s - 1e-12
            qm, tm, cm = qm[keep], np.maximum(tm[keep], self.ekf.t_s), cm[keep]
        else:
            qm, tm, cm = np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3, 3))
        if tg[0] > self.ekf.t_s - 1e-9 and (len(tm) == 0 or tm[-1] <= tg[-1] + 1e-9):
            # what ekf.process checks holds by construction (sorted, finite, unit, SPD from Wahba): skip the checks
            accepted = self.ekf.process(wg, tg, qm / np.linalg.norm(qm, axis=1)[:, None], tm, cm, validate=False)
        else:
            accepted = self.ekf.process(wg, tg, qm, tm, cm)
        # Persistent innovation: the tracker keeps reporting attitudes the filter gates out (a gyro bias jump the
        # filter does not believe). After three such frames in a row, restart from the tracker, keep the bias
        # estimate, and open its covariance so the filter can learn the new bias.
        if len(accepted) and self.tracker_mode == "track":
            self._rejected_frames = 0 if accepted.any() else self._rejected_frames + 1
            if self._rejected_frames >= 3:
                bias = self.ekf.bias_rad_s.copy()
                t_end = self.ekf.t_s
                last = samples[-1]
                self._init_ekf(last, last.t_s)
                self.ekf.bias_rad_s = bias
                self.ekf.ekf.P[3:, 3:] = np.eye(3) * max(np.radians(1.0) ** 2, float(np.max(np.diag(self.ekf.ekf.P[3:, 3:]))))
                if t_end > self.ekf.t_s:
                    self.ekf.propagate(self._omega_gyro, t_end - self.ekf.t_s)
                self._rejected_frames = 0
                self._filter_resets += 1

    def _count_wrong(self, samples, time_errors_s, times, quats) -> int:
        """Attitude samples reported valid whose true error exceeds max(5σ, 20″): confident wrong answers.

        Each sample is judged against the truth at its true exposure instant: an injected timestamp error
        (``time_jitter``) makes the time tag wrong, not the attitude, and shows in the filter's error instead.
        """
        if not samples:
            return 0
        t = np.array([s.t_s for s in samples]) - time_errors_s
        inside = (t >= times[0]) & (t <= times[-1])
        if not inside.any():
            return 0
        q_true = rk.quat_interpolate(times, quats, t[inside])  # quat_interpolate on the own truth history
        q_meas = np.array([s.q_body_to_icrs for s in samples])[inside]
        err = rk.quat_angle_between(q_true, q_meas)
        cov = np.array([s.covariance_rad2 for s in samples])[inside]
        floor = np.radians(20 / 3600)
        # σ² = λ_max lies in [trace/3, trace]: most samples are decided by these bounds without an eigensolver
        tr = np.trace(cov, axis1=1, axis2=2)
        sure_wrong = err > np.maximum(5 * np.sqrt(tr * (1 + 1e-9)), floor)
        sure_right = err <= np.maximum(5 * np.sqrt(tr / 3 * (1 - 1e-9)), floor)
        undecided = np.flatnonzero(~(sure_wrong | sure_right))
        if len(undecided):
            sig = np.sqrt(np.max(np.linalg.eigvalsh(cov[undecided]), axis=-1))
            sure_wrong[undecided] = err[undecided] > np.maximum(5 * sig, floor)
        wrong = int(np.sum(sure_wrong))
        self._n_wrong += wrong
        return wrong

    @property
    def n_wrong_samples_total(self) -> int:
        return self._n_wrong

    @property
    def reacquisition_times_s(self) -> list[float]:
        return list(self._reacquisition_s)

    def _plan_for(self, tracker, camera, omega_hint) -> ExposurePlan:
        cfg = self.config
        requested = tracker.requested_n_exposures  # a computed property: evaluate it once
        if cfg.exposure_mode == "single" or requested == 1:
            # lost-in-space needs one sharp spot per star: a single exposure centred in the frame
            return ExposurePlan(n_exposures=1, exposure_s=cfg.single_exposure_s, frame_period_s=cfg.frame_period_s,
                                start_offset_s=0.5 * (cfg.frame_period_s - cfg.single_exposure_s))
        if cfg.n_exposures == "adaptive":
            # N is what the tracker can separate given its prediction (requested_n_exposures) and what the detector
            # can separate given the smear (the no-overlap rule of the exposure plan): the smaller of the two
            rate = np.zeros(3) if omega_hint is None else omega_hint
            n_img = choose_n_exposures(rate, camera, cfg.frame_period_s, self.exposure_s, n_max=cfg.max_exposures)
            n = max(1, min(n_img, requested))
        else:
            n = int(cfg.n_exposures)
        return ExposurePlan(n_exposures=n, exposure_s=self.exposure_s, frame_period_s=cfg.frame_period_s)

    def _inertial_prior(self, tracker, t_frame: float):
        """The EKF attitude propagated to the frame, offered to a tracker that is not tracking (inertial aiding),
        when the filter is confident enough for the tracker's prior check."""
        if self.ekf is None:
            return None
        if float(np.max(self.ekf.attitude_sigma_rad)) > tracker.prior_sigma_rad / 3.0:
            return None
        return quat_integrate(self.ekf.q_body_to_icrs, self.ekf.omega_body, t_frame - self.ekf.t_s)

    def _run_frame(self, t_frame: float, truth, rng, omega_hint=None) -> list:
        """Image, detect and process one frame starting at ``t_frame`` on every head; returns the attitude samples."""
        cfg = self.config
        t_mid = t_frame + 0.5 * cfg.frame_period_s
        self._last_time_error_s = 0.0
        if self.faults and self.faults.frame_dropped(t_mid):
            self.last_stats = dict(self._empty_stats(), exposures_per_frame=0)
            return []
        sun = None
        blinded = set()
        if self.faults:
            t_s, q_s = truth
            q_mid = quat_interpolate(t_s, q_s, np.clip(t_mid, t_s[0], t_s[-1]))
            bore = quat_rotate(q_mid, self.camera.boresight_body())
            sun = self.faults.sun_direction_world(t_mid, bore, rng)
            blinded = self.faults.blinded_heads(t_mid)
            self._last_time_error_s = self.faults.timestamp_error_s(t_mid, rng)
        prev_mode = self.tracker_mode
        samples, n_matched, latency, n_exp, frames = [], 0, 0.0, 0, []
        for k, (head, tracker) in enumerate(zip(self.heads, self.trackers)):
            plan = self._plan_for(tracker, head.camera, omega_hint)
            bodies = (BrightBody("sun", tuple(sun)),) if sun is not None and k == 0 else ()
            det, _, scene = head.detections(self.catalog, truth, plan, t_frame, rng, cfg.fidelity, bodies)
            if len(det) and np.any(det.intensity <= 0):
                det = det.subset(np.flatnonzero(det.intensity > 0))  # background-dominated blobs carry no star
            if self.faults:
                det = self.faults.modify_detections(det, t_mid, rng, head.camera.resolution)
            if k in blinded:
                det = det.subset(np.zeros(0, dtype=np.int64))
            t_exp = plan.exposure_mid_times(t_frame) + self._last_time_error_s
            prior = self._inertial_prior(tracker, t_frame) if self.head_modes[k] != "track" else None
            if self.faults or len(det) == 0 or det.xy.dtype != np.float64 or det.intensity.dtype != np.float64:
                res = tracker.process_frame(det.xy, det.intensity, t_exp, t_frame, omega_body=omega_hint, q_body_prior=prior)
            else:  # detections and times built here to process_frame's contract: skip its input checks
                res = tracker.process_frame(
                    det.xy, det.intensity, t_exp, float(t_frame), omega_hint,
                    None if prior is None else rk.quat_normalize(prior), validate=False)
            self.head_modes[k] = res.mode
            samples.extend(res.samples)
            n_matched += int(res.n_matched)
            latency += float(res.matching_latency_ms)
            n_exp = max(n_exp, int(plan.n_exposures))
            frames.append((scene, det))
        # the sensor tracks while any head tracks
        self.tracker_mode = next((m for m in ("track", "acquire") if m in self.head_modes), "lost")
        if prev_mode == "track" and self.tracker_mode != "track":
            self._lost_events += 1
            self._t_lock_lost = t_frame
        if self.tracker_mode == "track" and prev_mode != "track" and self._t_lock_lost is not None:
            self._reacquisition_s.append(t_frame + cfg.frame_period_s - self._t_lock_lost)
            self._t_lock_lost = None
        if cfg.keep_images:
            self._last_frame = frames[0]
        self.last_stats = dict(
            self._empty_stats(),
            matching_latency_ms=latency,
            n_stars=n_matched,
            exposures_per_frame=n_exp,
            n_attitude_samples=len(samples),
        )
        return samples

    # ------------------------------------------------------------------ outputs
    def estimate(self) -> Estimate:
        if self.ekf is None:
            return Estimate(np.array([1.0, 0.0, 0.0, 0.0]), self._omega_gyro.copy(), np.pi, False)
        sig = float(np.max(self.ekf.attitude_sigma_rad))
        return Estimate(self.ekf.q_body_to_icrs.copy(), np.asarray(self.ekf.omega_body, float).copy(), sig, True,
                        np.array(self.ekf.P[:3, :3], dtype=float))

    def render_last_frame(self) -> np.ndarray | None:
        """RGB uint8 image (rows, cols, 3) of the last frame (full render), detections boxed; None before a frame."""
        if self._last_frame is None:
            return None
        scene, det = self._last_frame
        return self.head.render(scene, det)
