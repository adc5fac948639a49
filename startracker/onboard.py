"""The onboard unit: camera heads, star trackers, a gyro and the attitude EKF observing a truth history.

:class:`StarTrackerUnit` is everything a spacecraft carries to know its attitude. It is handed the *true*
attitude history (``t_s (G+1,)``, ``q_body_to_icrs (G+1, 4)``) of a span of time and observes it; it never
integrates physics, so the history may come from a simulator (the env's MuJoCo spacecraft) or from a user's
own trajectory (:func:`run_star_tracker`).

Timeline of one observed span ``[t0, t1]`` (:meth:`StarTrackerUnit.observe`):

1. Each interval of the history yields one gyro sample: the average true rate over the interval (from the
   quaternion increment) plus the gyro's errors. The history's instants are the gyro's sample instants.
2. Each camera frame ``[tf, tf + T]`` inside the span is imaged from the history by every head
   (:meth:`StarTrackerUnit.process_frame`): an exposure plan (single while the tracker is lost, multi-exposure
   with N chosen from the *gyro* rate while tracking), the scene, detections (centroid or pixel fidelity), then
   the :class:`startracker.sensor.StarTracker` state machine, which returns up to N attitude samples stamped with
   their exposure instants.
3. The frame's samples leave the tracker when its processor is done with them: the frame's end plus the
   latency of the processor model (:class:`startracker.processor.ProcessorModel`, deterministic; frames in
   order). The gyro streams on time; the filter fuses each delivered sample at its exposure instant
   (:class:`startracker.filter.DelayedFusion`: the EKF held at its last sample, the gyro since then buffered).
4. Verdicts against the truth: each delivered sample and the estimate at the span's end are *wrong* when their
   error fails the χ²(3) test on their own covariance, *confidently wrong* when they are also flagged valid
   (:func:`judge_samples`, :func:`judge_estimate`). The estimate monitors itself: a saturated gyro reading
   inflates its process noise and voids its validity until a later sample is accepted; a step in the gyro readings
   (a bias jump) is taken out of them and voids it likewise; innovations inconsistent over the last deliveries
   void it; samples rejected frame after frame void it and then restart the filter from the tracker. Its reported
   covariance allows for a bias change the jump monitor could miss.

Fault hooks: ``faults`` (e.g. ``envs.faults.FaultSchedule``) is any object, true when it holds faults, with
``frame_dropped(t)``, ``sun_direction_world(t, boresight_icrs, rng)`` (unit vector or None),
``blinded_heads(t)`` (set of head indices), ``timestamp_error_s(t, rng)``, ``modify_detections(det, t, rng,
resolution)``, ``modify_gyro(omega (G, 3), times (G,), rng)`` and ``active_kinds(t0, t1)``.

Everything random draws from the caller's generator; this machine's wall-clock matching time is reported
(``last_stats["matching_wall_clock_ms"]``), never fed back.

The module is over 600 lines because the unit (heads, trackers, gyro, filter and their bookkeeping over a
span of truth) is one object, and :func:`run_star_tracker` is its thin driver.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, fields, replace
from statistics import NormalDist

import numpy as np

from startracker.catalog import StarCatalog, load_catalog
from startracker.filter import AttitudeEKF, DelayedFusion
from startracker.head import HEAD_CAMERAS, make_head
from startracker.imu import GYRO_GRADES, Gyro, gyro_preset
from startracker.kernels import filter as filter_kernels
from startracker.kernels import rotations as rk
from startracker.kernels import scene as scene_kernels
from startracker.kernels import sensor as sensor_kernels
from startracker.multifov import MultiFovSensor
from startracker.processor import ProcessorModel
from startracker.rotations import quat_interpolate
from startracker.scene import BrightBody, ExposurePlan, image_flow_matrices
from startracker.sensor import MODES, NO_SAMPLES, AttitudeSample, AttitudeSamples, StarTracker
from startracker.spec import IDENTIFY_METHODS, MATCHERS, StarTrackerSpec, as_spec
from startracker.validation import as_float_array, check_real, check_rng

__all__ = [
    "StarTrackerUnit",
    "UnitConfig",
    "Estimate",
    "EstimateHistory",
    "count_wrong_samples",
    "judge_samples",
    "judge_estimate",
    "chi2_3_threshold",
    "ProcessorModel",
    "run_star_tracker",
    "IDENTIFY_METHODS",
    "MATCHERS",
    "GYRO_GRADES",
    "HEAD_CAMERAS",
    "MODES",
    "StarTrackerSpec",
    "gyro_rate_sigma_rad_s",
]

RESTART_AFTER_REJECTED_FRAMES = 3
# no second look at the gyro jump test (StarTrackerUnit._monitor_gyro_jump): an empty design
_NO_JUMP_DESIGN = (np.zeros((0, 0)), np.zeros(0), 0)
RESTART_BIAS_SIGMA_RAD_S = float(np.radians(1.0))


def chi2_3_threshold(false_alarm_p: float) -> float:
    """The χ²(3) quantile exceeded with probability ``false_alarm_p``: ``Q(x) = erfc(√(x/2)) + √(2x/π) e^(-x/2)``.

    Parameters
    ----------
    false_alarm_p : float
        Tail probability, in (0, 1).

    Returns
    -------
    float
        ``x`` with ``P(χ²₃ > x) = false_alarm_p`` (to 1e-12 relative, by bisection on the closed form).
    """
    p = float(false_alarm_p)
    if not 0.0 < p < 1.0:
        raise ValueError(f"false_alarm_p must be in (0, 1), got {false_alarm_p!r}")

    def tail(x):
        return math.erfc(math.sqrt(x / 2.0)) + math.sqrt(2.0 * x / math.pi) * math.exp(-x / 2.0)

    lo, hi = 0.0, 1.0
    while tail(hi) > p:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if tail(mid) > p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    return 0.5 * (lo + hi)


# The verdict's level. A right attitude is called wrong with this probability when its covariance tells the truth;
# at 1e-9 the 10^6-step soak (~2·10^7 tracker samples) expects 0.02 such false verdicts, so a wrong verdict there is
# a fact about the sensor and not the test's own noise. Its threshold (44.8) is a 6.7σ error on a single axis.
VERDICT_FALSE_ALARM_P = 1e-9
VERDICT_CHI2_3 = chi2_3_threshold(VERDICT_FALSE_ALARM_P)
# Rate uncertainty of a gyro axis whose reading is saturated (at the range limit, or flat-lined at a clip level):
# the true rate is unknown beyond the reading, up to the agility of the vehicles the unit serves (20 °/s slews,
# margin included); the filter adds its square, as an angle random walk (rad²/s), to the attitude process noise.
SATURATED_RATE_SIGMA_RAD_S = float(np.radians(30.0))
_SATURATED_RATE_VAR_RAD2_S2 = SATURATED_RATE_SIGMA_RAD_S**2
# The estimate is flagged valid only while its largest 1σ is within this: beyond it, it is no attitude to steer by.
ESTIMATE_VALID_SIGMA_RAD = float(np.radians(1.0))
# Longest a sample may take to reach the filter (processing delay); gyro intervals older than this are folded in.
FUSION_HORIZON_S = 1.0
# Innovation monitor: the filter's normalised innovations over its last deliveries (at most this many) are summed and
# tested against χ²(3 n) at this false-alarm probability; a failure voids the estimate's validity and opens the bias
# covariance (a gyro bias that moved, a time-tag error), as a restart would, without giving up the attitude.
MONITOR_DELIVERIES = 10
MONITOR_RECOVERY_DELIVERIES = 5  # after an alarm, the estimate is valid again once this many deliveries pass
MONITOR_FALSE_ALARM_P = 1e-4
_MONITOR_Z = 3.7190164854556804  # the standard normal quantile at 1 - MONITOR_FALSE_ALARM_P
MONITOR_MEAN_CHI2_3 = chi2_3_threshold(MONITOR_FALSE_ALARM_P)
MONITOR_DELIVERY_MEAN = True  # also test the newest delivery's own mean innovation (see _monitor_innovations)
# Timing test: a frame's timestamp error δt moves all its samples by ω δt, along the body rate. The innovations'
# component along ω, weighted and summed over a delivery, is χ²(1) without it
# (:meth:`StarTrackerUnit._timing_statistic`); summed over the monitor's window, χ²(n). Below this rate, s⁻¹ (0.1 °/s) a timestamp error moves nothing.
TIMING_MIN_RATE_RAD_S = float(np.radians(0.1))
MONITOR_TIMING_CHI2_1 = NormalDist().inv_cdf(1.0 - MONITOR_FALSE_ALARM_P / 2.0) ** 2  # χ²(1) quantile, z² two-sided
# After a timing alarm, valid again only once the window's timing sum is below χ²(n) at this standard-normal quantile
# (0: the median, evidence of no timing error rather than too little to alarm).
TIMING_RECOVERY_Z = 0.0
# An unconfirmed fix: a delivery fused over a prediction this many times looser along ω (in variance) than the frame's
# most precise sample sets the estimate along ω from that frame, whose timestamp the timing test could not check: it
# passes a timing error of √(χ²·(p + v)), most of which the fused estimate takes (a re-acquisition after a gap, a
# first fix, a restart). In tracking, the prediction, built on many frames, is as precise as a sample: p / r stayed
# ≤ 2.1 over 3,000 fault-free deliveries in random slews; a re-acquisition after seconds without frames gives 10-1000.
TIMING_LOOSE_PRIOR_RATIO = 4.0
# ... and the estimate is invalid until this many later deliveries passed the timing test with a tight prediction.
CONFIRM_DELIVERIES = 2
# Each sample's own innovation, tested at MONITOR_FALSE_ALARM_P per delivery (χ²(3) at p / M for M samples): a drift
# that starts within a frame shows in its last samples before it moves the delivery's mean.
MONITOR_SAMPLE_NIS = True
# Gyro jump monitor: a rigid body's rate is continuous (finite torques) and, within one observed span (one command
# held), smooth; a step in the readings is a gyro that changed (a bias jump), found by a GLR test over the previous
# and the current span (:func:`startracker.kernels.filter.gyro_jump_statistic`) at this false-alarm probability per
# span. The readings' noise is the gyro's white noise plus this floor for what a line does not follow (the
# gyroscopic torque's slow change of the acceleration; an ideal gyro would otherwise see every curvature as a jump).
GYRO_JUMP_FALSE_ALARM_P = 1e-7
GYRO_JUMP_CHI2_3 = chi2_3_threshold(GYRO_JUMP_FALSE_ALARM_P)
GYRO_JUMP_MODEL_SIGMA_RAD_S = 1e-5
# The second look: a span's readings are tested again one span later, with that span's readings after them.
GYRO_JUMP_SECOND_LOOK = True
# The non-centrality λ at which the jump monitor's χ²(3) statistic passes its threshold with probability 0.99 (a step
# of √λ σ_δ is found 99 % of the time; scipy.stats.ncx2, tested).
GYRO_JUMP_NONCENTRALITY_99 = 66.14439045439
# The bias change the reported covariance allows for, per σ_δ (see StarTrackerUnit._bias_allowance): a step the monitor
# finds 99 % of the time, unseen, leaves an error at the verdict's own χ² bound; smaller steps stay inside it.
BIAS_ALLOWANCE_FACTOR = math.sqrt(GYRO_JUMP_NONCENTRALITY_99 / VERDICT_CHI2_3)


@functools.lru_cache(maxsize=256)
def sample_nis_threshold(n_samples: int) -> float:
    """The per-sample innovation test's threshold for a delivery of ``n_samples``: χ²(3) at
    :data:`MONITOR_FALSE_ALARM_P` / ``n_samples`` (the delivery's false-alarm probability stays ≈ that p)."""
    return chi2_3_threshold(MONITOR_FALSE_ALARM_P / n_samples)


@functools.lru_cache(maxsize=1024)
def _chi2_quantile_wilson_hilferty(dof: float, z: float) -> float:
    """χ²(dof) quantile at the standard-normal quantile ``z`` (Wilson-Hilferty; within 1 % for dof >= 3 here); the
    monitors ask for a few dof (whole numbers of samples) over and over: kept."""
    c = 2.0 / (9.0 * dof)
    return dof * (1.0 - c + z * math.sqrt(c)) ** 3


@dataclass(frozen=True)
class UnitConfig:
    """Heads, tracker, gyro and filter settings (validated here).

    The heads are :class:`startracker.spec.StarTrackerSpec` descriptions (a preset name, a spec or its dict, or
    a list of them, one per head with its own mounting). The fields that a spec also holds (frame period,
    exposure, catalog limit, identification method, matcher) default to None, "the spec's"; a value given here
    overrides every head's spec. After construction they hold the values in use.

    Attributes
    ----------
    camera : str, StarTrackerSpec, dict, or list of them
        One head (:data:`HEAD_CAMERAS`, a spec or its dict) or one per head.
    frame_period_s : float or None
        Camera frame period, s (a whole number of gyro samples); default the spec's frame rate.
    exposure_mode : {"single", "multi"} or None
    n_exposures : int, "adaptive" or None
        N per multi-exposure frame (1 .. ``max_exposures``), or chosen from the gyro rate.
    exposure_s : float or None
        Exposure time of each exposure of a multi-exposure frame, s.
    single_exposure_s : float or None
        Exposure time of a single-exposure (lost-in-space) frame, s.
    max_exposures : int or None
    identify_method : str or None
        One of :data:`IDENTIFY_METHODS`.
    matcher : str or None
        One of :data:`MATCHERS`.
    fidelity : {"centroid", "pixel"}
    gyro_grade : str
        A key of :data:`startracker.imu.GYRO_GRADES`; also sets the tracker's gyro σ (:func:`gyro_rate_sigma_rad_s`).
    gyro_rate_hz : float
        Gyro sample rate, Hz: the truth history handed to :meth:`StarTrackerUnit.observe` is sampled at it.
    mag_limit : float or None
        Catalog limit, V.
    n_heads : int or None
        Heads: the length of a ``camera`` list; with one spec, 2 mounts two copies symmetric about body +z
        (paper 001's layout); default 1.
    head_separation_deg : float
        Angle between the two boresights of ``n_heads=2`` with one spec, ° (10 .. 170).
    keep_images : bool
        Keep the last frame's scene and detections for :meth:`StarTrackerUnit.render_last_frame`.
    heads : tuple of StarTrackerSpec
        (Derived) the spec of every head, mounted, with the overrides above applied.
    processor : ProcessorModel
        The tracker's processing budget: each frame's samples reach the filter its modelled latency after the
        frame ends (:class:`startracker.processor.ProcessorModel`; ``ProcessorModel.instantaneous()`` for none).
    """

    camera: object = "paper000"
    frame_period_s: float | None = None
    exposure_mode: str | None = None
    n_exposures: int | str | None = None
    exposure_s: float | None = None
    single_exposure_s: float | None = None
    max_exposures: int | None = None
    identify_method: str | None = None
    matcher: str | None = None
    fidelity: str = "centroid"
    gyro_grade: str = "tactical"
    gyro_rate_hz: float = 100.0
    mag_limit: float | None = None
    n_heads: int | None = None
    head_separation_deg: float = 45.0
    keep_images: bool = False
    processor: ProcessorModel = field(default_factory=ProcessorModel)
    heads: tuple = field(default=(), init=False, compare=False, repr=False)

    def __post_init__(self):
        if not isinstance(self.processor, ProcessorModel):
            raise TypeError(f"processor must be a ProcessorModel, got {type(self.processor).__name__}")
        cams = self.camera
        if isinstance(cams, (list, tuple)):
            if not 1 <= len(cams) <= 8:
                raise ValueError(f"camera: a list of 1 to 8 heads, got {len(cams)}")
            if self.n_heads is not None and self.n_heads != len(cams):
                raise ValueError(f"n_heads ({self.n_heads}) must be the number of cameras in the list ({len(cams)})")
            specs = [as_spec(c) for c in cams]
        else:
            specs = [as_spec(cams)]
            n = 1 if self.n_heads is None else self.n_heads
            if n not in (1, 2) or isinstance(n, bool):
                raise ValueError(f"n_heads must be 1 or 2 with one camera (give a list for more), got {self.n_heads!r}")
            if not (np.isfinite(self.head_separation_deg) and 10.0 <= self.head_separation_deg <= 170.0):
                raise ValueError(f"head_separation_deg must be in [10, 170] (heads must not overlap or point the same "
                                 f"way), got {self.head_separation_deg!r}")
            if n == 2:
                if specs[0].color:
                    raise ValueError("n_heads=2 is available for the monochrome cameras only, not a colour (3CMOS) camera")
                # paper 001's layout: two heads symmetric about body +z, boresights head_separation_deg apart
                mounted = MultiFovSensor.two_heads(specs[0].camera, self.head_separation_deg).heads
                specs = [specs[0].with_mounting(c.q_cam_to_body) for c in mounted]
        if sum(s.color for s in specs) and len(specs) > 1:
            raise ValueError("a colour (3CMOS) camera runs alone (one head)")
        # overrides of the specs' own values, applied to every head
        exp_over = {k: v for k, v in (("mode", self.exposure_mode), ("n_exposures", self.n_exposures),
                                      ("exposure_s", self.exposure_s), ("single_exposure_s", self.single_exposure_s),
                                      ("max_exposures", self.max_exposures)) if v is not None}
        if self.frame_period_s is not None:
            check_real(self.frame_period_s, "frame_period_s", 0.0, 10.0, lo_open=True)
            exp_over["frame_rate_hz"] = 1.0 / float(self.frame_period_s)
        top_over = {k: v for k, v in (("identify_method", self.identify_method), ("matcher", self.matcher),
                                      ("mag_limit", self.mag_limit)) if v is not None}
        if exp_over.get("mode") not in (None, "single", "multi"):
            raise ValueError(f"exposure_mode must be 'single' or 'multi', got {self.exposure_mode!r}")
        out = []
        for s in specs:
            e = s.exposure
            if exp_over:
                kw = dict(exp_over)
                period = 1.0 / kw.get("frame_rate_hz", e.frame_rate_hz)
                tau = kw.get("exposure_s", e.exposure_s)
                if "max_exposures" not in kw:  # keep what fits in the new frame
                    kw["max_exposures"] = max(1, min(e.max_exposures, math.floor(period / tau * (1 + 1e-9))))
                if "single_exposure_s" not in kw and e.single_exposure_s > period:
                    kw["single_exposure_s"] = tau
                n = kw.get("n_exposures", e.n_exposures)
                if n != "adaptive" and "max_exposures" not in exp_over and isinstance(n, (int, np.integer)) \
                        and not isinstance(n, bool) and n > kw["max_exposures"]:
                    kw["max_exposures"] = int(n)
                try:
                    e = replace(e, **kw)
                except (TypeError, ValueError) as exc:
                    raise type(exc)(f"exposure of camera {s.name!r}: {exc}") from None
            out.append(replace(s, exposure=e, **top_over))
        specs = out
        periods = {s.exposure.frame_rate_hz for s in specs}
        if len(periods) > 1:
            raise ValueError(f"all heads must have the same frame rate, got {sorted(periods)} Hz")
        first = specs[0]
        resolved = dict(frame_period_s=first.exposure.frame_period_s, exposure_mode=first.exposure.mode,
                        n_exposures=first.exposure.n_exposures, exposure_s=first.exposure.exposure_s,
                        single_exposure_s=first.exposure.single_exposure_s, max_exposures=first.exposure.max_exposures,
                        identify_method=first.identify_method, matcher=first.matcher, mag_limit=first.mag_limit,
                        n_heads=len(specs), heads=tuple(specs))
        for k, v in resolved.items():
            object.__setattr__(self, k, v)
        if self.fidelity not in ("centroid", "pixel"):
            raise ValueError(f"fidelity must be 'centroid' or 'pixel', got {self.fidelity!r}")
        if self.gyro_grade not in GYRO_GRADES:
            raise ValueError(f"gyro_grade must be one of {sorted(GYRO_GRADES)}, got {self.gyro_grade!r}")
        check_real(self.gyro_rate_hz, "gyro_rate_hz", 1.0, 10000.0)
        steps = self.frame_period_s * self.gyro_rate_hz
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ValueError("the frame period must be a whole number of gyro samples (gyro_rate_hz * frame period)")

    def __reduce__(self):
        # heads is derived: rebuild from the init fields (their resolved values reproduce the same heads)
        init = {f.name: getattr(self, f.name) for f in fields(self) if f.init}
        init["camera"] = [h.to_dict() for h in self.heads]
        init["n_heads"] = None
        return (_rebuild_config, (type(self), init))


def _rebuild_config(cls, init):
    return cls(**init)


def gyro_rate_sigma_rad_s(spec) -> float:
    """1σ per-axis error of one gyro rate sample, rad/s: the angle random walk over a sample period
    (``N √rate_hz``, white noise of the averaged rate), the turn-on bias and the Gauss-Markov bias in quadrature
    (the tracker takes one sample as the rate at the frame's start)."""
    return float(math.sqrt(spec.arw_rad_sqrt_s**2 * spec.rate_hz + spec.bias_sigma_rad_s**2 + spec.gm_sigma_rad_s**2))


@dataclass
class Estimate:
    """What the controller may know: the filter's output.

    Attributes
    ----------
    q_body_to_icrs : ndarray, shape (4,)
        Estimated attitude (identity before the first fix).
    omega_body : ndarray, shape (3,)
        Estimated body rate, rad/s (the raw gyro rate before the first fix).
    attitude_sigma_rad : float
        Largest 1σ attitude uncertainty of ``attitude_cov_rad2``, rad (π before the first fix).
    valid : bool
        The filter vouches for the estimate: it has a fix, its largest 1σ is within 1°, no saturated gyro reading
        and no gyro step came after its last accepted sample, the star tracker's samples are not being rejected, and
        the innovation monitor is quiet.
    attitude_cov_rad2 : ndarray, shape (3, 3), or None
        Body-frame attitude covariance, rad², as reported: the filter's, plus the allowance for a gyro bias change
        the jump monitor could miss since the last accepted sample (:attr:`StarTrackerUnit.bias_allowance_rad_s`);
        None before the first fix.
    """

    q_body_to_icrs: np.ndarray
    omega_body: np.ndarray
    attitude_sigma_rad: float
    valid: bool
    attitude_cov_rad2: np.ndarray | None = None


def count_wrong_samples(samples, time_errors_s, times_s, q_body_to_icrs) -> int:
    """Attitude samples that are wrong: their true error fails the χ²(3) test on their own covariance.

    Shorthand for ``judge_samples(...)[0]`` (every sample counted as flagged valid).

    Parameters
    ----------
    samples, time_errors_s, times_s, q_body_to_icrs :
        As :func:`judge_samples`.

    Returns
    -------
    int
    """
    return judge_samples(samples, time_errors_s, times_s, q_body_to_icrs)[0]


def judge_samples(samples, time_errors_s, times_s, q_body_to_icrs, valid=None) -> tuple[int, int]:
    """Wrong and confidently wrong star-tracker samples, by consistency with their own covariance.

    A sample is *wrong* when its error against the truth, the body-frame rotation vector ``δθ`` with
    ``q_true = q ⊗ exp(δθ)``, fails the χ²(3) test on its reported covariance: ``δθᵀ C⁻¹ δθ >``
    :data:`VERDICT_CHI2_3` (false-alarm probability :data:`VERDICT_FALSE_ALARM_P` for a sample whose covariance tells
    the truth). It is *confidently wrong* when, in addition, it is flagged valid (the unit used it: the filter's
    innovation gate let it in). Each sample is judged against the truth at its true exposure instant: an injected
    timestamp error makes the time tag wrong, not the attitude. Samples outside the truth history are not judged.

    Parameters
    ----------
    samples : sequence of startracker.sensor.AttitudeSample
    time_errors_s : array_like, shape (len(samples),)
        Timestamp error of each sample (reported minus true exposure instant), s.
    times_s : ndarray, shape (S,)
        Truth history instants, s, increasing.
    q_body_to_icrs : ndarray, shape (S, 4)
        True attitudes at ``times_s`` (unit, float64).
    valid : array_like of bool, shape (len(samples),), optional
        Which samples are flagged valid. Default: all.

    Returns
    -------
    n_wrong, n_confidently_wrong : int
    """
    if not samples:
        return 0, 0
    t, q, cov = _sample_arrays(samples)
    wrong = _wrong_samples(t - np.asarray(time_errors_s, dtype=np.float64), q, cov, times_s, q_body_to_icrs)
    flagged = np.ones(len(samples), dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    return int(np.count_nonzero(wrong)), int(np.count_nonzero(wrong & flagged))


def judge_estimate(estimate: "Estimate", q_true_body_to_icrs) -> tuple[bool, bool]:
    """Whether the filter's estimate is wrong, and confidently wrong, against the true attitude at its time.

    Wrong: its attitude error fails the χ²(3) test on its own attitude covariance (the NEES exceeds
    :data:`VERDICT_CHI2_3`); confidently wrong: wrong and flagged valid. An estimate without a covariance (before
    the first fix) claims nothing and is neither.

    Parameters
    ----------
    estimate : Estimate
    q_true_body_to_icrs : array_like, shape (4,)
        True attitude at the estimate's time (unit).

    Returns
    -------
    wrong, confidently_wrong : bool
    """
    if estimate.attitude_cov_rad2 is None:
        return False, False
    q_true = as_float_array(q_true_body_to_icrs, "q_true_body_to_icrs", last_dim=4, ndim=1)
    nis = sensor_kernels.consistency_nis(q_true.reshape(1, 4), np.asarray(estimate.q_body_to_icrs, float).reshape(1, 4),
                                         np.asarray(estimate.attitude_cov_rad2, float).reshape(1, 3, 3))
    wrong = bool(nis[0] > VERDICT_CHI2_3)
    return wrong, wrong and bool(estimate.valid)


def _sample_arrays(samples):
    """Times (n,), attitudes (n, 4) and covariances (n, 3, 3) of a non-empty list of samples."""
    # the (4,) rows joined flat, then shaped: the same values as np.array of the rows, with less shape discovery
    return (np.array([s.t_s for s in samples]),
            np.concatenate([s.q_body_to_icrs for s in samples]).reshape(-1, 4),
            np.array([s.covariance_rad2 for s in samples]))


def _wrong_samples(t_true, q_meas, cov, times_s, q_body_to_icrs) -> np.ndarray:
    """Wrong flags (n,) of samples at true instants ``t_true``; those outside the truth history are not wrong
    (:func:`startracker.kernels.sensor.wrong_sample_flags`, on float64 C-contiguous copies where needed)."""
    def rows(a):
        return np.ascontiguousarray(a, dtype=np.float64)
    return sensor_kernels.wrong_sample_flags(rows(t_true), rows(q_meas), rows(cov), rows(times_s),
                                             rows(q_body_to_icrs).reshape(-1, 4), VERDICT_CHI2_3)


def _empty_stats(n_heads: int = 1, *, matching_latency_ms=0.0, matching_latency_ms_per_head=None,
                 matching_wall_clock_ms=0.0, matching_wall_clock_ms_per_head=None, wall_clock_breakdown_ms=None,
                 n_stars=0, exposures_per_frame=0, n_attitude_samples=0, update_rate_hz=0.0,
                 update_rate_hz_per_head=None, lost_lock_events=0, faults_active=None) -> dict:
    """The figures of a span or frame (:attr:`StarTrackerUnit.last_stats`): zero, or a frame's or a span's (its
    arguments; a per-head list left None is zeros), in one dict literal, built once per frame and span."""
    zeros = [0.0] * n_heads
    return dict(
        update_rate_hz=update_rate_hz,
        update_rate_hz_per_head=zeros if update_rate_hz_per_head is None else update_rate_hz_per_head,
        matching_latency_ms=matching_latency_ms,
        matching_latency_ms_per_head=(list(zeros) if matching_latency_ms_per_head is None
                                      else matching_latency_ms_per_head),
        n_stars=n_stars,
        exposures_per_frame=exposures_per_frame,
        n_attitude_samples=n_attitude_samples,
        lost_lock_events=lost_lock_events,
        matching_wall_clock_ms=matching_wall_clock_ms,
        matching_wall_clock_ms_per_head=(list(zeros) if matching_wall_clock_ms_per_head is None
                                         else matching_wall_clock_ms_per_head),
        wall_clock_breakdown_ms=(dict(predict_match=0.0, group_solve_test=0.0, identify=0.0)
                                 if wall_clock_breakdown_ms is None else wall_clock_breakdown_ms),
        n_wrong_samples=0,
        n_confidently_wrong_samples=0,
        estimate_wrong=False,
        estimate_confidently_wrong=False,
        filter_restarts=0,
        faults_active=[] if faults_active is None else faults_active,
    )


class StarTrackerUnit:
    """Camera heads + star trackers + gyro + MEKF observing a true attitude history.

    Parameters
    ----------
    config : UnitConfig, optional
        Default ``UnitConfig()``.
    catalog : startracker.catalog.StarCatalog, optional
        Every head's catalog; default ``load_catalog(mag_limit=...)`` at each head's spec's limit.

    Attributes
    ----------
    heads : list of MonoHead or ColorHead
    trackers : list of startracker.sensor.StarTracker
        One state machine per head.
    gyro : startracker.imu.Gyro or None
        Drawn at :meth:`reset` (its turn-on errors come from the run's generator).
    ekf : startracker.filter.AttitudeEKF or None
        None until the first attitude sample.
    tracker_mode : str
        "track" while any head tracks, else "acquire" if any acquires, else "lost".
    last_stats : dict
        Figures of the last frame (:meth:`process_frame`) or span (:meth:`observe`): ``update_rate_hz`` (distinct
        attitude instants per second over the span: two heads exposed at the same instant count once),
        ``update_rate_hz_per_head`` (each head's samples per second), ``matching_latency_ms`` (the modelled processing
        latency of one frame, :class:`ProcessorModel`, summed over the heads; mean over the span's frames),
        ``matching_latency_ms_per_head``, ``matching_wall_clock_ms`` (this machine's wall clock of the trackers'
        work on one frame, summed over the heads, lost-in-space identification excluded: prediction, matching,
        grouping by instant, the N Wahba solutions and the lock tests), ``matching_wall_clock_ms_per_head``,
        ``wall_clock_breakdown_ms`` (``predict_match``, ``group_solve_test`` and, apart, ``identify``, per frame
        summed over the heads), ``n_stars``, ``exposures_per_frame``,
        ``n_attitude_samples``, ``lost_lock_events``, ``n_wrong_samples``, ``filter_restarts``, ``faults_active``.
    last_time_error_s : float
        Timestamp error injected into the last frame (fault hooks), s.
    last_samples : list of startracker.sensor.AttitudeSample
        The star tracker's samples over the last :meth:`observe` span (built on first access from
        ``last_attitude_samples``, the same samples as arrays: :class:`startracker.sensor.AttitudeSamples`).
    bias_allowance_rad_s : float
        The gyro bias change the reported covariance allows for, rad/s (:meth:`estimate`): a step the gyro jump
        monitor finds 99 % of the time, unseen, stays within the verdict's χ² bound.
    """

    def __init__(self, config: UnitConfig | None = None, catalog: StarCatalog | None = None):
        config = UnitConfig() if config is None else config
        if not isinstance(config, UnitConfig):
            raise TypeError(f"config must be a UnitConfig, got {type(config).__name__}")
        if catalog is not None and not isinstance(catalog, StarCatalog):
            raise TypeError(f"catalog must be a startracker.catalog.StarCatalog, got {type(catalog).__name__}")
        self.config = config
        self.heads = [make_head(spec) for spec in config.heads]
        self.head = self.heads[0]
        self.camera = self.head.camera
        self.exposure_s = config.exposure_s
        # one catalog per catalog limit among the heads (the first head's is ``catalog``)
        by_limit = {}
        for spec in config.heads:
            if spec.mag_limit not in by_limit:
                by_limit[spec.mag_limit] = load_catalog(mag_limit=spec.mag_limit) if catalog is None else catalog
        self.catalogs = [by_limit[spec.mag_limit] for spec in config.heads]
        self.catalog = self.catalogs[0]
        self.gyro_spec = gyro_preset(config.gyro_grade, rate_hz=config.gyro_rate_hz)
        # what the spacecraft really has: the centroid σ of each head's detector, the gyro grade's rate noise
        gyro_sigma = max(gyro_rate_sigma_rad_s(self.gyro_spec), 1e-7)
        self.trackers = [
            StarTracker(h.camera, cat, identify_method=spec.identify_method, matcher=spec.matcher,
                        centroid_sigma_px=spec.centroid_sigma_px(), frame_period_s=spec.frame_period_s,
                        max_exposures=spec.exposure.max_exposures, gyro_sigma_rad_s=gyro_sigma,
                        rate_per_exposure_deg_s=spec.exposure.rate_per_exposure_deg_s,
                        star_flux=h.sensor_model.star_pe(cat.vmag, cat.bv, 1.0),
                        **spec.tracker.tracker_kwargs())
            for h, spec, cat in zip(self.heads, config.heads, self.catalogs)
        ]
        self.tracker = self.trackers[0]
        self.gyro_max_rate_rad_s = float(min(self.gyro_spec.max_rate_rad_s, 2 * np.pi))
        self.gyro_period_s = 1.0 / config.gyro_rate_hz
        # the saturation monitor's per-configuration arguments: the gyro's range, whether its readings are noisy
        self._saturation_args = (float(self.gyro_spec.max_rate_rad_s), self.gyro_spec.arw_rad_sqrt_s > 0.0)
        self._plans: dict[tuple, ExposurePlan] = {}
        # the no-overlap rule's constants per head (N from the rate, startracker.scene.choose_n_exposures' checks
        # held by the spec): its kernels run every frame
        self._no_overlap = [
            (image_flow_matrices(h.camera), h.camera.r_cam_to_body, float(spec.exposure.frame_period_s),
             float(spec.exposure.exposure_s), float(h.sensor_model.sigma_px), float(spec.exposure.min_gap_sigma),
             int(spec.exposure.max_exposures))
            for h, spec in zip(self.heads, config.heads)]
        # gyro jump monitor: the noise of one reading (the white noise of the sample average, plus the model floor)
        self._jump_sigma_rad_s = math.hypot(self.gyro_spec.arw_rad_sqrt_s * math.sqrt(config.gyro_rate_hz),
                                            GYRO_JUMP_MODEL_SIGMA_RAD_S)
        self._jump_designs: dict[tuple, tuple] = {}
        self._jump_sigma2 = self._jump_sigma_rad_s**2
        g = int(round(config.frame_period_s * config.gyro_rate_hz))
        self._allowance_span = g
        self.bias_allowance_rad_s = self._bias_allowance(g)
        self.gyro: Gyro | None = None
        self.faults = None
        self._clear()

    def _clear(self) -> None:
        """The state of a unit that has seen nothing: lost, no estimate, no counts."""
        self.fusion = DelayedFusion(FUSION_HORIZON_S)
        self.head_modes = ["lost"] * len(self.heads)
        self.tracker_mode = "lost"
        self.last_stats = _empty_stats(len(self.heads))
        self.last_time_error_s = 0.0
        self._span = NO_SAMPLES  # the last span's samples: the trackers' own arrays, which the filter reads later
        self._last_samples_list: list[AttitudeSample] | None = None
        self._omega_gyro = np.zeros(3)
        self._frame_head_samples = [0] * len(self.heads)
        self._last_frame = None
        self._lost_events = 0
        self._n_wrong = 0
        self._n_confidently_wrong = 0
        self._n_wrong_estimates = 0
        self._n_confidently_wrong_estimates = 0
        self._rejected_frames = 0
        self._filter_resets = 0
        # ring of the last deliveries: Σ NIS, samples, Σ innovation, Σ its covariance
        self._monitor = (np.zeros(MONITOR_DELIVERIES), np.zeros(MONITOR_DELIVERIES), np.zeros((MONITOR_DELIVERIES, 3)),
                         np.zeros((MONITOR_DELIVERIES, 3, 3)))
        self._monitor_slot = 0
        self._monitor_filled = 0
        self._timing = np.zeros(MONITOR_DELIVERIES)  # each delivery's timing statistic (χ²(1) each, 0: none)
        self._timing_n = [0.0] * MONITOR_DELIVERIES  # 1.0 where a delivery had one (a list: its sum is a count)
        self._timing_last = (0.0, 0.0)  # the last delivery's timing statistic (see _timing_statistic)
        self._inconsistent = False
        self._timing_suspect = False
        self._unconfirmed = 0  # later deliveries a fix the timing test could not vouch for still waits for
        self._timing_alarms = 0
        self._monitor_alarms = 0
        self._t_lock_lost = None
        self._reacquisition_s: list[float] = []
        self._pending: list[tuple] = []  # (t_delivery_s, times, quats, covs, wrong flags) per frame, in order
        self._t_last_delivery = -np.inf
        self._t_saturated = -np.inf  # end of the last gyro interval with a saturated reading
        self._t_accepted = -np.inf  # exposure instant of the last sample the filter accepted
        self._t_gyro_jump = -np.inf  # start of the last gyro interval where the jump monitor saw a step
        self._gyro_jumps = 0
        self._gyro_prev = np.zeros((0, 3))  # the previous span's readings (the jump test's left side)
        self._gyro_prev_saturated = False
        self._gyro_prev_times = np.zeros(0)  # their interval starts and end (G + 1,)
        self._gyro_prev2 = np.zeros((0, 3))  # the span before (the second look's left side)
        self._gyro_prev2_saturated = False
        self._gyro_correction = np.zeros(3)  # sum of the steps the jump monitor found, rad/s
        self._correction_before_jump = None  # the correction before a step found in the last span
        self._frame_latency_ms = 0.0
        self._frame_wall_ms = 0.0
        self._reported = None  # the last reported covariance and its key (_protected_cov)

    @property
    def last_samples(self) -> list[AttitudeSample]:
        """The star tracker's samples over the last :meth:`observe` span, as objects (see the class docstring)."""
        if self._last_samples_list is None:
            self._last_samples_list = self._span.to_list()
        return self._last_samples_list

    @property
    def last_attitude_samples(self) -> AttitudeSamples:
        """The star tracker's samples over the last :meth:`observe` span, as arrays (read-only views: the filter
        fuses these rows when the processor is done with them)."""
        span = self._span
        if not len(span):
            return NO_SAMPLES

        def view(a):
            v = a.view()
            v.setflags(write=False)
            return v

        return AttitudeSamples(view(span.t_s), view(span.q_body_to_icrs), view(span.covariance_rad2),
                               view(span.n_stars))

    @property
    def ekf(self) -> AttitudeEKF | None:
        """The filter at the time of its last attitude sample (:class:`startracker.filter.DelayedFusion`); None until
        the first sample. The estimate now is :meth:`estimate`."""
        return self.fusion.ekf

    # ------------------------------------------------------------------ lifecycle
    def reset(self, rng: np.random.Generator, faults=None, first_frame_truth=None) -> None:
        """New run: fresh gyro errors, lost trackers, no estimate; optionally one first frame.

        Parameters
        ----------
        rng : numpy.random.Generator
        faults : fault hooks, optional
            See the module docstring.
        first_frame_truth : tuple (t_s (S,), q_body_to_icrs (S, 4)), optional
            Truth over a first single-exposure frame taken before the first gyro sample: the frame starts at
            ``t_s[0]``, and the filter (if it gets a fix) is propagated to ``t_s[-1]`` with zero rate (the frame's
            processing is over by the start of the run).
        """
        self.faults = faults
        self.gyro = Gyro(self.gyro_spec, rng)
        for tr in self.trackers:
            tr.reset()
        self._clear()
        if first_frame_truth is None:
            return
        t_pre, q_pre = first_frame_truth
        samples = self.process_frame((t_pre, q_pre), t_pre[0], rng)
        if samples:
            last = samples[-1]
            ekf = self._new_filter(last.q_body_to_icrs, last.covariance_rad2, last.t_s)
            if t_pre[-1] > last.t_s:
                ekf.propagate(self._omega_gyro, t_pre[-1] - last.t_s)
            self.fusion.start(ekf)
            self._t_accepted = last.t_s

    def _new_filter(self, q_body_to_icrs, covariance_rad2, t_s: float) -> AttitudeEKF:
        """A new filter at a sample: its attitude, 3σ of its covariance, at its time."""
        sig = float(np.sqrt(np.max(np.linalg.eigvalsh(covariance_rad2))))
        return AttitudeEKF.from_gyro_spec(
            self.gyro_spec, q_body_to_icrs, sigma_attitude_rad=max(3 * sig, 1e-5), t_s=t_s, gate_chi2=30.0,
        )

    def _jump_design(self, n_prev: int, n_cur: int, n_next: int = 0):
        """The jump test's null fit over ``n_prev`` readings of the previous span and ``n_cur`` of this one: its
        residual projector (n, n), each candidate step's ``den`` (n,) (0: not a candidate) and the first candidate.

        The null hypothesis is a smooth rate: an offset, a slope, and a change of slope where this span starts (a new
        command); the readings are evenly spaced, so the design depends on the counts only and is built once. With
        ``n_next`` > 0 (the second look, :meth:`_second_look`) the window runs on through ``n_next`` readings of the
        span after, with a slope change where it starts too, and the candidates stay those of the middle span."""
        key = (n_prev, n_cur, n_next)
        design = self._jump_designs.get(key)
        if design is None:
            n = n_prev + n_cur + n_next
            tau = np.arange(n, dtype=np.float64) - n_prev + 0.5  # reading mid-times, in readings, from the span start
            cols = [np.ones(n), tau] + ([np.maximum(tau, 0.0)] if n_prev >= 2 else [])
            if n_next:
                cols.append(np.maximum(tau - n_cur, 0.0))
            x = np.column_stack(cols)
            m = np.eye(n) - x @ np.linalg.pinv(x)
            steps = np.tril(np.ones((n, n)))  # column j: the step from reading j on
            den = np.einsum("gj,gh,hj->j", steps, m, steps)
            den[den < 1e-9] = 0.0  # a step the smooth rate can follow: no test there
            first = n_prev if n_prev >= 2 else 0
            den[:first] = 0.0
            den[n_prev + n_cur:] = 0.0
            design = self._jump_designs[key] = (np.ascontiguousarray(m), den, first)
        return design

    def _bias_allowance(self, n_span: int) -> float:
        """The bias change the reported covariance allows for, rad/s: the largest step the jump monitor may miss.

        A step δ is found when its statistic (non-central χ²(3), ``λ = |δ|² / σ_δ²``) passes :data:`GYRO_JUMP_CHI2_3`:
        the monitor finds 99 % of the steps of ``D₉₉ = √GYRO_JUMP_NONCENTRALITY_99 · σ_δ`` (σ_δ of the least favourable
        reading of a span of ``n_span``) and more of larger ones. The estimate's covariance grows by ``(b Δt)²`` with
        ``b = D₉₉ / √VERDICT_CHI2_3`` over the time Δt since its last accepted sample, so that an unseen step up to
        ``D₉₉`` keeps the true error within the verdict's own χ² bound (a protection level in covariance form)."""
        _, den, _ = self._jump_design(n_span, n_span)
        den = den[den > 0]
        # with too few readings per span to test, the difference of two readings is the best a monitor could do
        sigma_delta = self._jump_sigma_rad_s * (1.0 / math.sqrt(float(np.min(den))) if den.size else math.sqrt(2.0))
        return BIAS_ALLOWANCE_FACTOR * sigma_delta

    def _monitor_gyro_jump(self, omega_meas: np.ndarray, times: np.ndarray, saturated: bool) -> np.ndarray:
        """This span's readings (G, 3), rad/s, with the steps the gyro jump monitor has found taken out.

        The readings, less the correction of the steps found so far, are tested for a step
        (:func:`startracker.kernels.filter.gyro_jump_statistic`). On a step ``δ̂`` from reading ``g``: the readings from
        ``g`` on, and all later ones, are corrected by ``δ̂`` (the step's own estimate, σ_δ); the bias covariance
        opens by ``(|δ̂| + 3 σ_δ)²`` per axis for the correction's error; the estimate is flagged invalid until a
        sample exposed after the step is accepted. The fault's end, a step back, is found and undone the same way."""
        self._correction_before_jump = None
        c = self._gyro_correction
        if c[0] or c[1] or c[2]:  # ndarray.any() of three floats (NaN counts), without its dispatch
            omega_meas = omega_meas - c
        if len(omega_meas) != self._allowance_span:  # spans as long as the env's control period
            self._allowance_span = len(omega_meas)
            self.bias_allowance_rad_s = self._bias_allowance(self._allowance_span)
        prev, prev_saturated = self._gyro_prev, self._gyro_prev_saturated
        prev2, prev2_saturated, prev_times = self._gyro_prev2, self._gyro_prev2_saturated, self._gyro_prev_times
        self._gyro_prev2, self._gyro_prev2_saturated = prev, prev_saturated
        self._gyro_prev, self._gyro_prev_saturated, self._gyro_prev_times = omega_meas, saturated, times
        if saturated or prev_saturated or (len(prev) == 0 and len(omega_meas) < 3):
            return omega_meas  # a clipped reading is the saturation monitor's; too few readings for a line and a step
        n_prev, n_cur = len(prev), len(omega_meas)
        # the second look (this span's readings after the previous span's) when the first finds nothing: one call
        m, den, first = self._jump_design(n_prev, n_cur)
        if GYRO_JUMP_SECOND_LOOK and len(prev2) >= 2 and n_prev >= 2 and not prev2_saturated:
            m2, den2, first2 = self._jump_design(len(prev2), n_prev, n_cur)
        else:
            m2, den2, first2 = _NO_JUMP_DESIGN
        delta = np.zeros(3)
        sigma2 = self._jump_sigma2
        look, j = filter_kernels.gyro_jump_looks(
            np.ascontiguousarray(prev2, dtype=np.float64), np.ascontiguousarray(prev, dtype=np.float64),
            np.ascontiguousarray(omega_meas, dtype=np.float64), m, den, first, m2, den2, first2, sigma2,
            GYRO_JUMP_CHI2_3, delta)
        if look == 0:
            return omega_meas
        if look == 2:
            return self._second_look(prev2, prev, prev_times, omega_meas, j, delta, den2)
        g = j - n_prev
        self._gyro_jumps += 1
        self._t_gyro_jump = float(times[g])  # reading g covers (times[g], times[g + 1]]
        self._correction_before_jump = self._gyro_correction
        self._gyro_correction = self._gyro_correction + delta
        omega_meas = omega_meas.copy()
        omega_meas[g:] -= delta
        self._gyro_prev = omega_meas
        ekf = self.fusion.ekf
        if ekf is not None:
            # the correction's error is σ_δ for a true step, δ̂ itself for a false alarm: cover both
            reach = np.abs(delta) + 3.0 * math.sqrt(sigma2 / den[j])
            p_bb = ekf.P[3:, 3:] + np.diag(reach**2)
            ekf.set_bias_covariance(p_bb)
            self.fusion.start(ekf)  # its state changed: the estimate now is recomputed
        return omega_meas

    def _second_look(self, prev2, prev, prev_times, omega_meas, j: int, delta: np.ndarray,
                     den: np.ndarray) -> np.ndarray:
        """A step the jump test found in the previous span's readings tested again, now with this span's readings
        after them (:func:`startracker.kernels.filter.gyro_jump_looks`: reading ``j`` of the three spans' window, its
        estimate ``delta`` (3,) rad/s and the window's ``den``); this span's readings corrected.

        A step tested in its own span has few readings after it when it falls late there (σ_δ up to 1.3 σ of one
        reading); one span later it has a whole span more, and the test over the three spans (offset, slope and a
        slope change at each span start as the null; :meth:`_jump_design`) sees a step ~2× smaller. Found: this
        span's readings and the buffered ones from the step on are corrected by δ̂ (the filter's own intervals
        before that it has integrated: its attitude covariance opens by that drift), the bias covariance opens as
        for a step found at once, and the estimate is invalid until a sample fused after now is accepted."""
        n2 = len(prev2)
        sigma2 = self._jump_sigma2
        g = j - n2  # reading g of the previous span covers (prev_times[g], prev_times[g + 1]]
        t_step = float(prev_times[g])
        self._gyro_jumps += 1
        self._gyro_correction = self._gyro_correction + delta
        omega_meas = omega_meas - delta
        corrected = prev.copy()
        corrected[g:] -= delta
        self._gyro_prev2, self._gyro_prev = corrected, omega_meas
        reach = np.abs(delta) + 3.0 * math.sqrt(sigma2 / den[j])
        fusion = self.fusion
        ekf = fusion.ekf
        if ekf is not None:
            fusion.correct_gyro(delta, t_step)
            self._t_gyro_jump = max(t_step, float(ekf.t_s))
            p = ekf.P.copy()
            drift_s = max(float(ekf.t_s) - t_step, 0.0)
            p[:3, :3] += np.diag((reach * drift_s) ** 2)
            p[3:, 3:] += np.diag(reach**2)
            ekf.ekf.P = p
            fusion.start(ekf)  # its state changed: the estimate now is recomputed
        else:
            self._t_gyro_jump = t_step
        return omega_meas

    def _undo_clip_onset_step(self, saturated: bool, was_saturated: bool) -> None:
        """A step the jump monitor found in the span just before the first saturated one is the clip's onset (its
        first clipped reading does not repeat yet, so the saturation monitor flags the span after), not a bias: its
        correction is undone."""
        if saturated and not was_saturated and self._correction_before_jump is not None:
            self._gyro_correction = self._correction_before_jump

    def _rate_noise(self, omega_meas: np.ndarray, own_gyro: bool):
        """Extra process noise (G, 3), rad²/s, on the gyro axes whose reading is saturated, and the index of the last
        saturated sample; (None, -1) when none is.

        A reading is saturated at the gyro's range, or, from the unit's own gyro when it has noise, when it repeats
        the previous reading bit for bit (a clip below the range: noise never repeats a float64 value; rates a
        user hands in may well repeat). Its true rate is unknown beyond the reading:
        :data:`SATURATED_RATE_SIGMA_RAD_S`, squared, enters the attitude process noise."""
        out = np.empty((len(omega_meas), 3))
        limit, noisy = self._saturation_args
        last = filter_kernels.saturated_rate_noise(
            np.ascontiguousarray(omega_meas, dtype=np.float64), self._omega_gyro, limit, own_gyro and noisy,
            _SATURATED_RATE_VAR_RAD2_S2, out)
        return (None, -1) if last < 0 else (out, last)

    # ------------------------------------------------------------------ one span of truth
    def observe(self, times_s, q_body_to_icrs, rng: np.random.Generator, omega_gyro=None) -> None:
        """Observe a span of the true attitude history: gyro samples, camera frames and the filter over it.

        Each frame's samples reach the filter when the processor is done with the frame (its modelled latency
        after the frame's end, in frame order); the filter fuses them at their exposure instants
        (:class:`startracker.filter.DelayedFusion`). The samples delivered in the span and the estimate at its
        end are judged against the truth (:func:`judge_samples`, :func:`judge_estimate`).

        Parameters
        ----------
        times_s : ndarray, shape (G+1,)
            Instants of the history, s, one gyro period apart: ``times_s[0]`` is the end of the previous span.
            The span must hold a whole number of frames.
        q_body_to_icrs : ndarray, shape (G+1, 4)
            True attitudes at ``times_s`` (unit, float64).
        rng : numpy.random.Generator
        omega_gyro : ndarray, shape (G, 3), optional
            Measured gyro rates over the intervals ``(times_s[k-1], times_s[k]]``, rad/s, bias included: used
            instead of the unit's simulated gyro (and its gyro faults).
        """
        if self.gyro is None:
            raise RuntimeError("call reset(rng) before observe()")
        times, quats = times_s, q_body_to_icrs
        t0 = float(times[0])  # frame times as Python floats: the per-frame callees' fast path takes them unchecked
        t_end = float(times[-1])
        cfg = self.config
        frame_period_s = cfg.frame_period_s
        gyro_period_s = self.gyro_period_s
        n_heads = len(self.heads)
        n_frames = int(round((t_end - t0) / frame_period_s))
        duration_s = n_frames * frame_period_s
        faults = self.faults
        # the env's own history (float64, C-contiguous): the compiled calls take it as it is
        own_history = (quats.dtype == np.float64 and quats.flags.c_contiguous and times.dtype == np.float64
                       and times.flags.c_contiguous and quats.ndim == 2)
        if omega_gyro is None:
            # average true rate over each gyro interval, from the quaternion increment (body frame)
            if own_history:  # the rates and their samples in one compiled call
                omega_meas = self.gyro.measure_history(times, quats, rng, validate=False)  # (G, 3) float64, built here
            else:
                omega_avg = rk.quat_relative_rotvec(quats[:-1], quats[1:]) / (times[1:] - times[:-1])[:, None]
                omega_meas = self.gyro.measure(omega_avg, rng, validate=False)  # (G, 3) float64, built here
            if faults:
                omega_meas = faults.modify_gyro(omega_meas, times[1:], rng)
        else:
            omega_meas = omega_gyro
        rate_noise, last_saturated = self._rate_noise(omega_meas, omega_gyro is None)
        raw_last = omega_meas[-1].copy()
        self._undo_clip_onset_step(rate_noise is not None, self._gyro_prev_saturated)
        omega_meas = self._monitor_gyro_jump(omega_meas, times, rate_noise is not None)

        batches = []  # the frames' samples (AttitudeSamples), when they have any
        n_samples = 0
        # per-frame figures summed in Python floats (the same additions as numpy's on float64)
        lat_sum = wall_sum = 0.0
        per_head_n = [0.0] * n_heads
        per_head_lat = [0.0] * n_heads
        per_head_wall = [0.0] * n_heads
        bd_pm = bd_gst = bd_id = 0.0
        n_stars = exposures_per_frame = 0
        offsets = [] if faults else None  # timestamp errors only come from faults
        frame_ends = []
        n_omega = len(omega_meas)
        for f in range(n_frames):
            tf = t0 + f * frame_period_s
            # the gyro reading at the frame's start: the tracker propagates its prediction from frame_time
            k = min(int(round((tf - t0) / gyro_period_s)), n_omega - 1)
            # and the last reading of the frame: the gyro's mean acceleration over it
            k_end = min(int(round((tf + frame_period_s - t0) / gyro_period_s)) - 1, n_omega - 1)
            alpha = None
            # a clipped reading's change is the clip, not the body's acceleration: then the rate is held instead
            if k_end > k and (rate_noise is None or not rate_noise[k:k_end + 1].any()):
                alpha = (omega_meas[k_end] - omega_meas[k]) / ((k_end - k) * gyro_period_s)
            new = self._frame_samples((times, quats), tf, rng, omega_gyro=omega_meas[k], alpha_gyro=alpha)
            n_new = len(new)
            if n_new:
                batches.append(new)
                n_samples += n_new
            if offsets is not None:
                offsets.extend([self.last_time_error_s] * n_new)
            frame_ends.append((n_samples, tf + frame_period_s + 1e-3 * self._frame_latency_ms))
            lat_sum += self._frame_latency_ms
            wall_sum += self._frame_wall_ms
            head_latency, head_wall, f_pm, f_gst, f_id, n_stars, exposures_per_frame, _ = self._frame_figures
            head_samples = self._frame_head_samples
            for h in range(n_heads):
                per_head_n[h] += head_samples[h]
                per_head_lat[h] += head_latency[h]
                per_head_wall[h] += head_wall[h]
            bd_pm += f_pm
            bd_gst += f_gst
            bd_id += f_id
        span = AttitudeSamples.concatenate(batches)
        # distinct attitude instants: heads exposed at the same instant add samples, not updates (round half to
        # even, as np.round); one head's samples are distinct exposure instants already
        n_instants = n_samples if n_heads == 1 else len({round(t * 1e6) for t in span.t_s.tolist()})
        means = {}  # the frames' mean figures (none without frames: _empty_stats' zeros)
        if n_frames:
            means = dict(matching_latency_ms=lat_sum / n_frames,
                         matching_latency_ms_per_head=[v / n_frames for v in per_head_lat],
                         matching_wall_clock_ms=wall_sum / n_frames,
                         matching_wall_clock_ms_per_head=[v / n_frames for v in per_head_wall],
                         wall_clock_breakdown_ms=dict(predict_match=bd_pm / n_frames,
                                                      group_solve_test=bd_gst / n_frames, identify=bd_id / n_frames))
        stats = _empty_stats(n_heads, **means, n_stars=n_stars, exposures_per_frame=exposures_per_frame,
                             n_attitude_samples=n_samples, update_rate_hz=n_instants / duration_s,
                             update_rate_hz_per_head=[v / duration_s for v in per_head_n],
                             lost_lock_events=self._lost_events,
                             faults_active=faults.active_kinds(t0, times[-1]) if faults else [])
        self._span = span
        self._last_samples_list = None
        if n_samples:  # judged against this span's truth now, counted when the filter has seen them
            # the trackers' own float64 arrays (or their concatenation): the filter reads them, nothing writes them
            t_arr, q_arr, c_arr = span.t_s, span.q_body_to_icrs, span.covariance_rad2
            t_true = t_arr - np.array(offsets) if offsets is not None else t_arr
            if own_history:
                wrong = sensor_kernels.wrong_sample_flags(t_true, q_arr, c_arr, times, quats, VERDICT_CHI2_3)
            else:
                wrong = _wrong_samples(t_true, q_arr, c_arr, times, quats)
            start = 0
            for end, t_done in frame_ends:
                if end > start:
                    t_done = max(t_done, self._t_last_delivery)  # the output port delivers frames in order
                    self._t_last_delivery = t_done
                    self._pending.append((t_done, t_arr[start:end], q_arr[start:end], c_arr[start:end],
                                          wrong[start:end]))
                start = end

        # the gyro stream is on time; then whatever the processor has finished by the span's end
        self._omega_gyro = raw_last
        self.fusion.add_gyro(omega_meas, times[1:], rate_noise)
        if rate_noise is not None:
            self._t_saturated = float(times[1 + last_saturated])
        self._deliver(float(times[-1]), stats)
        stats["filter_restarts"] = self._filter_resets
        wrong_est, confident_est = self._judge_estimate_now(quats[-1])
        stats["estimate_wrong"], stats["estimate_confidently_wrong"] = wrong_est, confident_est
        self._n_wrong_estimates += wrong_est
        self._n_confidently_wrong_estimates += confident_est
        self.last_stats = stats

    def _judge_estimate_now(self, q_true) -> tuple[bool, bool]:
        """:func:`judge_estimate` of :meth:`estimate`, on the filter's own arrays (no copies)."""
        if self.fusion.ekf is None:
            return False, False
        now = self.fusion.current()
        cov, nis, max_var = self._protected_cov(now, q_true)
        wrong = bool(nis > VERDICT_CHI2_3)
        return wrong, wrong and self._estimate_valid(max_var)

    def _protected_cov(self, now, q_true=None):
        """The estimate's reported attitude covariance (3, 3), rad²: the filter's, plus the drift of a gyro bias change
        the jump monitor could miss since the last accepted sample, ``(b Δt)² I`` (:meth:`_bias_allowance`); with its
        largest variance and, given the true attitude ``q_true`` (4,), its verdict's NIS (one compiled call,
        :func:`startracker.kernels.filter.reported_attitude`).

        ``now`` is :meth:`startracker.filter.DelayedFusion.current`'s tuple; returns ``(cov, nis, max_var)`` (``nis``
        NaN without ``q_true``). The last result is kept for :meth:`estimate` while ``now``, the last accepted instant
        and the allowance stay the same: the caller must not change ``cov`` (estimate copies it)."""
        key = (now, self._t_accepted, self.bias_allowance_rad_s)
        kept = self._reported
        if q_true is None and kept is not None and kept[0][0] is now and kept[0][1:] == key[1:]:
            return kept[1]
        q, P, t_s = now[0], now[2], now[4]
        dt = t_s - self._t_accepted
        widen = dt > 0.0
        extra = (self.bias_allowance_rad_s * dt) ** 2 if widen else 0.0
        out = filter_kernels.reported_attitude(q if q_true is None else q_true, q, P, widen, extra)
        if q_true is None:  # the NIS of the estimate against itself is no verdict
            out = (out[0], math.nan, out[2])
        self._reported = (key, out)
        return out

    def _estimate_valid(self, max_var: float) -> bool:
        """The estimate's validity flag (see :class:`Estimate`); ``max_var``: the largest variance of its reported
        covariance, rad²."""
        sig = math.sqrt(max_var)
        return (sig <= ESTIMATE_VALID_SIGMA_RAD and self._rejected_frames == 0 and not self._inconsistent
                and not self._timing_suspect and self._unconfirmed == 0
                and self._t_saturated < self._t_accepted
                and self._t_gyro_jump < self._t_accepted)

    def _deliver(self, t_now: float, stats: dict) -> None:
        """Fuse the frames whose processing is over by ``t_now``, and count their verdicts into ``stats``."""
        n_due = 0
        while n_due < len(self._pending) and self._pending[n_due][0] <= t_now + 1e-9:
            n_due += 1
        if n_due == 0:
            return
        due, self._pending = self._pending[:n_due], self._pending[n_due:]
        if n_due == 1:
            _, tm, qm, cm, wrong = due[0]
        else:
            tm, qm, cm, wrong = (np.concatenate([d[i] for d in due]) for i in range(1, 5))
        # unit rows (np.linalg.norm(qm, axis=1)'s arithmetic) and the order test in one compiled call
        qm, in_order = filter_kernels.delivery_rows(qm, tm)
        if not in_order:  # several heads: merge into time order (stable)
            order = np.argsort(tm, kind="stable")
            tm, qm, cm, wrong = tm[order], qm[order], cm[order], wrong[order]
        first = 0
        if self.fusion.ekf is None:  # the first fix starts the filter
            self.fusion.start(self._new_filter(qm[0], cm[0], float(tm[0])))
            first = 1
        # what the filter's checks demand holds by construction (sorted, finite, unit, SPD from Wahba)
        self._timing_last = (0.0, 0.0)
        # a fix the timing test cannot vouch for: the filter's first, or one over a loose prediction (a gap)
        loose = first == 1 and self._rate_matters()
        t_filter = self.fusion.ekf.t_s
        fused = None
        if first == 0 and float(tm[-1]) >= t_filter:  # tm is in time order: some samples are fresh
            if float(tm[0]) >= t_filter:  # all (the usual case): no masked copies
                u = self._rate_axis()
                if u is None:  # too slow a rate for a timestamp to matter: no test
                    stat, has, loose = 0.0, 0.0, False
                else:  # the test and, when it passes, the fusion, in one call
                    stat, loose, fused = self.fusion.fuse_timed(qm, tm, cm, u, MONITOR_TIMING_CHI2_1,
                                                                TIMING_LOOSE_PRIOR_RATIO)
                    has = 1.0
            else:
                fresh = tm >= t_filter
                stat, has, loose = self._timing_statistic(qm[fresh], tm[fresh], cm[fresh])
            self._timing_last = (stat, has)
        if self._timing_last[0] > MONITOR_TIMING_CHI2_1:
            # the frame's timestamps disagree with the gyro along the rate: fused, it would drag the estimate
            # (and the bias) by ω δt; it is refused and the estimate is invalid until the timing is quiet again
            self._timing_suspect = True
            self._timing[:] = 0.0
            self._timing_n = [0.0] * MONITOR_DELIVERIES
            self._monitor_filled = 0
            self._timing_alarms += 1
            self.fusion.last_innovation_rad = np.zeros((0, 3))
            accepted = np.zeros(len(tm), dtype=bool)
        elif fused is not None:
            accepted = fused
        else:
            accepted = np.zeros(len(tm), dtype=bool)
            accepted[:first] = True  # the first fix started the filter
            accepted[first:] = self.fusion.fuse(qm[first:], tm[first:], cm[first:])
        fusion = self.fusion
        # the delivery's tallies and, when it has innovations, the monitor's window: one compiled call
        last_accepted, n_wrong, n_confident, windowed, window = filter_kernels.delivery_tallies(
            accepted, wrong, fusion.last_nis, fusion.last_innovation_rad, fusion.last_innovation_cov_rad2,
            *self._monitor, self._monitor_slot)
        any_accepted = last_accepted >= 0
        if any_accepted:
            self._t_accepted = max(self._t_accepted, float(tm[last_accepted]))
            # a loose fix waits for CONFIRM_DELIVERIES later frames the timing test could check
            self._unconfirmed = CONFIRM_DELIVERIES if loose else max(self._unconfirmed - 1, 0)
        self._n_wrong += n_wrong
        self._n_confidently_wrong += n_confident
        stats["n_wrong_samples"] += n_wrong
        stats["n_confidently_wrong_samples"] += n_confident
        if windowed:
            self._monitor_innovations(window)
        # Persistent innovation: the tracker keeps reporting attitudes the filter gates out (a gyro bias jump the
        # filter does not believe). After three such deliveries in a row, restart from the tracker's last sample,
        # keep the bias estimate, and open its covariance so the filter can learn the new bias.
        if self.tracker_mode == "track":
            self._rejected_frames = 0 if any_accepted else self._rejected_frames + 1
            if self._rejected_frames >= RESTART_AFTER_REJECTED_FRAMES:
                old = self.fusion.ekf
                ekf = self._new_filter(qm[-1], cm[-1], float(tm[-1]))
                ekf.bias_rad_s = old.bias_rad_s.copy()
                p_bias = float(np.max(np.diag(old.P[3:, 3:])))
                ekf.set_bias_covariance(np.eye(3) * max(RESTART_BIAS_SIGMA_RAD_S**2, p_bias))
                self.fusion.start(ekf)
                self._t_accepted = float(tm[-1])
                self._rejected_frames = 0
                self._filter_resets += 1
                if self._rate_matters():
                    self._unconfirmed = CONFIRM_DELIVERIES

    def _monitor_innovations(self, window: tuple) -> None:
        """Innovation tests over the last deliveries: on failure, void the estimate's validity and open the bias
        covariance so that the filter relearns the bias; valid again once :data:`MONITOR_RECOVERY_DELIVERIES`
        deliveries since have passed.

        Statistics of the window (:func:`startracker.kernels.filter.innovation_window`): the spread, Σ NIS
        against χ²(3 n), and the mean, (Σz)ᵀ (ΣS)⁻¹ (Σz) against χ²(3): a bias drags the innovations one way, and
        the mean sees a steady offset √n times sooner than the spread; the same mean over the newest delivery alone
        (:data:`MONITOR_DELIVERY_MEAN`), where a drift that has just begun is not diluted by the window; each of its
        samples' own NIS (:data:`MONITOR_SAMPLE_NIS`); and the timing test of each delivery before it was fused
        (:meth:`_timing_statistic`), summed against χ²(n): a frame whose timestamp is off moves all its samples along
        ω, a frame's worth of shared error the filter would otherwise average as if independent (a single delivery
        beyond χ²(1) is refused before fusion, in :meth:`_deliver`).

        ``window``: the statistics of the window with the newest delivery's innovations in it (their ring slot
        written), as :func:`startracker.kernels.filter.delivery_tallies` returns them for a delivery with innovations
        (the only ones the monitor looks at)."""
        fusion = self.fusion
        ring = self._monitor
        total, n, mean_chi2, delivery_chi2, max_nis, n_nis = window
        t_frame, n_frame = self._timing_last
        self._timing[self._monitor_slot], self._timing_n[self._monitor_slot] = t_frame, n_frame
        n_timing = sum(self._timing_n)  # of 0.0 and 1.0: exact in any order
        timing_sum = float(self._timing.sum()) if n_timing > 0 else None
        timing_alarm = n_timing > 0 and timing_sum > _chi2_quantile_wilson_hilferty(n_timing, _MONITOR_Z)
        # the delivery's own mean (a drift that starts now is diluted tenfold in the window's mean, not here) and
        # its samples' own NIS
        sample_alarm = MONITOR_SAMPLE_NIS and n_nis > 0 and max_nis > sample_nis_threshold(int(n_nis))
        self._monitor_slot = (self._monitor_slot + 1) % MONITOR_DELIVERIES
        self._monitor_filled += 1
        if (total > _chi2_quantile_wilson_hilferty(3.0 * n, _MONITOR_Z) or mean_chi2 > MONITOR_MEAN_CHI2_3
                or (MONITOR_DELIVERY_MEAN and delivery_chi2 > MONITOR_MEAN_CHI2_3) or timing_alarm or sample_alarm):
            ekf = fusion.ekf
            p_bb = np.diag(ekf.P[3:, 3:])
            ekf.set_bias_covariance(np.diag(np.maximum(p_bb, RESTART_BIAS_SIGMA_RAD_S**2)))
            fusion.start(ekf)  # its state changed: the estimate now is recomputed
            for a in ring:
                a[:] = 0.0
            self._timing[:] = 0.0
            self._timing_n = [0.0] * MONITOR_DELIVERIES
            self._monitor_filled = 0
            self._inconsistent = True
            self._timing_suspect = self._timing_suspect or timing_alarm
            self._monitor_alarms += 1
            return
        if self._inconsistent and self._monitor_filled >= MONITOR_RECOVERY_DELIVERIES:
            self._inconsistent = False
        # A timestamp fault lasts: after a timing alarm the estimate stays invalid until the window shows no sign of
        # one (its timing sum below χ²(n)'s median), not merely none strong enough to alarm again.
        if self._timing_suspect and self._monitor_filled >= MONITOR_RECOVERY_DELIVERIES and (
                n_timing == 0 or timing_sum <= _chi2_quantile_wilson_hilferty(n_timing, TIMING_RECOVERY_Z)):
            self._timing_suspect = False

    def _rate_matters(self) -> bool:
        """Whether the body turns fast enough (:data:`TIMING_MIN_RATE_RAD_S`, from the last gyro reading) for a
        timestamp error to move an attitude."""
        w = self._omega_gyro
        return math.sqrt(float(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])) >= TIMING_MIN_RATE_RAD_S

    def _timing_statistic(self, qm, tm, cm) -> tuple[float, float, bool]:
        """The timing test of a delivery's samples (M, 4), (M,), (M, 3, 3), before they are fused; returns the
        statistic, whether there is one (1.0) or not (0.0: too slow a rate for a timestamp to matter), and whether the
        prediction was too loose for the test to vouch for the frame (:data:`TIMING_LOOSE_PRIOR_RATIO`).

        A timestamp error δt shared by the samples moves each by ``ω δt``, along the body rate (direction ``u``).
        Against the filter's prediction (:meth:`startracker.filter.DelayedFusion.prior_innovations`), the samples'
        weighted mean innovation along ``u``, ``c = Σ (uᵀz_i / r_i) / Σ 1 / r_i`` with ``r_i = uᵀ R_i u``, has
        variance ``p + 1 / Σ 1 / r_i`` without one, ``p`` the prediction's variance along ``u`` (its error is shared by
        the samples; the largest over the frame). ``c² / var`` is χ²(1). With ``p`` more than
        :data:`TIMING_LOOSE_PRIOR_RATIO` times the smallest ``r_i``, the test can pass a timing error of
        ``√(χ² (p + 1 / Σ 1 / r_i))``, most of which the fused estimate would take: the fix must be confirmed by later
        frames (:data:`CONFIRM_DELIVERIES`)."""
        u = self._rate_axis()
        if u is None or len(tm) == 0:
            return 0.0, 0.0, False
        z, s = self.fusion.prior_innovations(qm, tm, cm)
        stat, loose = filter_kernels.timing_statistic(u, z, s, cm, TIMING_LOOSE_PRIOR_RATIO)
        return stat, 1.0, bool(loose)

    def _rate_axis(self):
        """The filter's body-rate direction (3,), for the timing test; None below :data:`TIMING_MIN_RATE_RAD_S`."""
        w0, w1, w2 = self.fusion.ekf.omega_body.tolist()  # Python floats: numpy's products, sum and quotients
        w_norm = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        if w_norm < TIMING_MIN_RATE_RAD_S:
            return None
        return np.array([w0 / w_norm, w1 / w_norm, w2 / w_norm])

    @property
    def n_wrong_samples_total(self) -> int:
        """Wrong samples (:func:`judge_samples`) delivered to the filter since :meth:`reset`."""
        return self._n_wrong

    @property
    def n_confidently_wrong_samples_total(self) -> int:
        """Wrong samples the filter accepted (flagged valid) since :meth:`reset`."""
        return self._n_confidently_wrong

    @property
    def n_wrong_estimates_total(self) -> int:
        """Spans since :meth:`reset` that ended with a wrong estimate (:func:`judge_estimate`)."""
        return self._n_wrong_estimates

    @property
    def n_confidently_wrong_estimates_total(self) -> int:
        """Spans since :meth:`reset` that ended with a wrong estimate flagged valid."""
        return self._n_confidently_wrong_estimates

    @property
    def timing_alarms_total(self) -> int:
        """Deliveries refused since :meth:`reset` because their samples disagreed with the gyro along the rate (the
        timing test: a frame whose timestamp is off)."""
        return self._timing_alarms

    @property
    def gyro_jumps_total(self) -> int:
        """Steps in the gyro readings the jump monitor found since :meth:`reset`."""
        return self._gyro_jumps

    @property
    def gyro_correction_rad_s(self) -> np.ndarray:
        """The sum of the steps found since :meth:`reset`, (3,) rad/s: taken out of every reading after them."""
        return self._gyro_correction.copy()

    @property
    def reacquisition_times_s(self) -> list[float]:
        """Time from each loss of lock to the next lock, s."""
        return list(self._reacquisition_s)

    def _plan_for(self, k: int, omega_hint) -> ExposurePlan:
        """Head k's exposure plan for the next frame (its spec's exposure, its tracker's request)."""
        exp = self.config.heads[k].exposure
        tracker = self.trackers[k]
        requested = tracker.requested_n_exposures  # a computed property: evaluate it once
        if exp.mode == "single" or requested == 1:
            # lost-in-space needs one sharp spot per star: a single exposure centred in the frame
            key = (1, exp.single_exposure_s, True)
            plan = self._plans.get(key)
            if plan is None:
                plan = self._plans[key] = ExposurePlan(
                    n_exposures=1, exposure_s=exp.single_exposure_s, frame_period_s=exp.frame_period_s,
                    start_offset_s=0.5 * (exp.frame_period_s - exp.single_exposure_s))
            return plan
        if exp.n_exposures == "adaptive" and exp.n_rule == "paper000":
            # paper 000's rule: one more exposure per rate_per_exposure_deg_s of body rate (1 -> 21 over 0 -> 20°/s);
            # spots that come near each other are left to the centroiding (both fidelities merge touching spots).
            # Only a prediction too uncertain for the frame step's own spacing test (one star's spots 1.5
            # shift_k_sigma prediction σ apart, or the frame is refused) lowers it.
            w = np.zeros(3) if omega_hint is None else omega_hint
            rate_deg_s = math.degrees(math.sqrt(float(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])))
            n = min(max(1 + math.floor(rate_deg_s / exp.rate_per_exposure_deg_s + 0.5), 1), exp.max_exposures)
            n = max(1, min(n, tracker.separable_n_exposures(1.5 * tracker.shift_k_sigma)))
        elif exp.n_exposures == "adaptive":
            # N is what the tracker can separate given its prediction (requested_n_exposures) and what the detector
            # can separate given the smear (the no-overlap rule of the exposure plan): the smaller of the two
            rate = np.zeros(3) if omega_hint is None else omega_hint
            flow, r_cam_to_body, period_s, exposure_s, sigma_px, gap_sigma, n_max = self._no_overlap[k]
            n_img = scene_kernels.no_overlap_exposures(scene_kernels.min_image_speed(flow, r_cam_to_body, rate),
                                                       period_s, exposure_s, sigma_px, gap_sigma, n_max)
            n = max(1, min(n_img, requested))
        else:
            n = int(exp.n_exposures)
        key = (n, exp.exposure_s, False)
        plan = self._plans.get(key)
        if plan is None:  # plans are frozen: each N is built and validated once
            plan = self._plans[key] = ExposurePlan(n_exposures=n, exposure_s=exp.exposure_s,
                                                   frame_period_s=exp.frame_period_s)
        return plan

    def _inertial_prior(self, tracker, t_frame: float):
        """The EKF attitude propagated to the frame, offered to a tracker that is not tracking (inertial aiding),
        when the filter is confident enough for the tracker's prior check."""
        if self.fusion.ekf is None:
            return None
        q, _, P, omega, t_s = self.fusion.current()
        if math.sqrt(max(P[0, 0], P[1, 1], P[2, 2])) > tracker.prior_sigma_rad / 3.0:
            return None
        # the kernel layer's q ⊗ exp(ω dt) on the filter's own float64 arrays (the checked API goes through scipy's
        # Rotation, ~40 µs, every frame the tracker is not tracking)
        return rk.quat_integrate(q, omega, t_frame - t_s)

    # ------------------------------------------------------------------ one frame
    def process_frame(self, truth, t_frame: float, rng: np.random.Generator, omega_gyro=None,
                      alpha_gyro=None) -> list[AttitudeSample]:
        """Image, detect and process one frame on every head, from the truth history; the attitude samples.

        Parameters
        ----------
        truth : tuple (t_s (S,), q_body_to_icrs (S, 4))
            True attitude history covering ``[t_frame, t_frame + frame_period_s]`` (s; unit, float64).
        t_frame : float
            Frame start, s.
        rng : numpy.random.Generator
        omega_gyro : ndarray, shape (3,), optional
            Gyro rate at the frame's start, rad/s (chooses N, seeds the tracker's prediction).
        alpha_gyro : ndarray, shape (3,), optional
            With ``omega_gyro``: the gyro's mean angular acceleration over the frame, rad/s² (the tracker processes
            the frame after its readout, when the gyro has measured it; its prediction then follows a torque change
            at the frame's start).

        Returns
        -------
        list of startracker.sensor.AttitudeSample
            Samples of all heads, stamped with their exposure instants (plus any injected timestamp error).
        """
        return self._frame_samples(truth, t_frame, rng, omega_gyro, alpha_gyro).to_list()

    def _frame_samples(self, truth, t_frame: float, rng: np.random.Generator, omega_gyro=None,
                       alpha_gyro=None) -> AttitudeSamples:
        """:meth:`process_frame`'s work; its samples as arrays (the heads' rows in head order)."""
        cfg = self.config
        omega_hint = omega_gyro
        t_mid = t_frame + 0.5 * cfg.frame_period_s
        self.last_time_error_s = 0.0
        faults = self.faults
        n_heads = len(self.heads)
        self._frame_head_samples = [0] * n_heads
        self._frame_latency_ms = self._frame_wall_ms = 0.0
        if faults and faults.frame_dropped(t_mid):
            self._frame_figures = ([0.0] * n_heads, [0.0] * n_heads, 0.0, 0.0, 0.0, 0, 0, 0)
            self._stats = None  # the frame's figures, built when asked for (last_stats)
            return NO_SAMPLES
        sun = None
        blinded = ()  # no head blinded without faults
        if faults:
            t_s, q_s = truth
            # the kernel layer on the env's checked float64 history (the same floats as the checked API, ~10x cheaper)
            q_mid = rk.quat_interpolate(t_s, q_s, min(max(t_mid, t_s[0]), t_s[-1]))  # np.clip of one float
            bore = rk.quat_rotate(q_mid, self.camera.boresight_body())
            sun = faults.sun_direction_world(t_mid, bore, rng)
            blinded = faults.blinded_heads(t_mid)
            self.last_time_error_s = faults.timestamp_error_s(t_mid, rng)
        prev_mode = self.tracker_mode
        batches, n_samples, n_matched, n_exp, frames = [], 0, 0, 0, []
        head_latency = [0.0] * n_heads
        head_wall = [0.0] * n_heads
        bd_pm = bd_gst = bd_id = 0.0
        for k, (head, tracker) in enumerate(zip(self.heads, self.trackers)):
            plan = self._plan_for(k, omega_hint)
            bodies = (BrightBody("sun", tuple(sun)),) if sun is not None and k == 0 else ()
            det, scene = head.detections(self.catalogs[k], truth, plan, t_frame, rng, cfg.fidelity, bodies)
            if len(det) and sensor_kernels.any_nonpositive(det.intensity):
                det = det.subset(np.flatnonzero(det.intensity > 0))  # background-dominated blobs carry no star
            if faults:
                det = faults.modify_detections(det, t_mid, rng, head.camera.resolution)
            if k in blinded:
                det = det.subset(np.zeros(0, dtype=np.int64))
            t_exp = plan.exposure_mid_times(t_frame)  # a fresh array
            if self.last_time_error_s != 0.0:
                t_exp = t_exp + self.last_time_error_s
            prior = self._inertial_prior(tracker, t_frame) if self.head_modes[k] != "track" else None
            t_proc = time.perf_counter()
            if faults or len(det) == 0 or det.xy.dtype != np.float64 or det.intensity.dtype != np.float64:
                res = tracker.process_frame(det.xy, det.intensity, t_exp, t_frame, omega_body=omega_hint, q_body_prior=prior,
                                            alpha_body=alpha_gyro)
            else:  # detections and times built here to process_frame's contract: skip its input checks
                res = tracker.process_frame(
                    det.xy, det.intensity, t_exp, float(t_frame), omega_hint,
                    None if prior is None else rk.quat_normalize(prior), alpha_body=alpha_gyro, validate=False)
            # wall clock of the tracker's whole frame but lost-in-space identification: prediction and matching
            # (timed by the tracker), grouping by instant, the N Wahba solutions and the lock tests (the rest)
            identify_ms = float(res.identify_latency_ms)
            tracker_ms = (time.perf_counter() - t_proc) * 1e3 - identify_ms
            predict_match_ms = float(res.matching_latency_ms)
            head_wall[k] = wall_k = max(tracker_ms, predict_match_ms)
            bd_pm += predict_match_ms
            bd_gst += wall_k - predict_match_ms
            bd_id += identify_ms
            n_det, res_samples = len(det), res.attitude_samples
            n_res = len(res_samples)
            self._frame_head_samples[k] = n_res
            # the modelled latency; one processor serves the heads in turn: their budgets add up
            head_latency[k] = cfg.processor.frame_latency_ms(n_det, n_res, self.head_modes[k] != "track" and n_det > 0)
            self.head_modes[k] = res.mode
            if n_res:
                batches.append(res_samples)
                n_samples += n_res
            n_matched += int(res.n_matched)
            n_exp = max(n_exp, int(plan.n_exposures))
            frames.append((scene, det))
        # the sensor tracks while any head tracks
        modes = self.head_modes
        self.tracker_mode = "track" if "track" in modes else ("acquire" if "acquire" in modes else "lost")
        if prev_mode == "track" and self.tracker_mode != "track":
            self._lost_events += 1
            self._t_lock_lost = t_frame
        if self.tracker_mode == "track" and prev_mode != "track" and self._t_lock_lost is not None:
            self._reacquisition_s.append(t_frame + cfg.frame_period_s - self._t_lock_lost)
            self._t_lock_lost = None
        if cfg.keep_images:
            self._last_frame = frames[0]
        self._frame_latency_ms = sum(head_latency)
        self._frame_wall_ms = sum(head_wall)
        self._frame_figures = (head_latency, head_wall, bd_pm, bd_gst, bd_id, n_matched, n_exp, n_samples)
        self._stats = None  # the frame's figures, built when asked for (last_stats): observe reads them as they are
        return AttitudeSamples.concatenate(batches)

    @property
    def last_stats(self) -> dict:
        """Figures of the last frame (:meth:`process_frame`) or span (:meth:`observe`); see the class docstring."""
        if self._stats is None:
            head_latency, head_wall, bd_pm, bd_gst, bd_id, n_matched, n_exp, n_samples = self._frame_figures
            self._stats = _empty_stats(
                len(head_latency), matching_latency_ms=self._frame_latency_ms,
                matching_latency_ms_per_head=head_latency, matching_wall_clock_ms=self._frame_wall_ms,
                matching_wall_clock_ms_per_head=head_wall,
                wall_clock_breakdown_ms=dict(predict_match=bd_pm, group_solve_test=bd_gst, identify=bd_id),
                n_stars=n_matched, exposures_per_frame=n_exp, n_attitude_samples=n_samples)
        return self._stats

    @last_stats.setter
    def last_stats(self, value: dict) -> None:
        self._stats = value

    # ------------------------------------------------------------------ outputs
    def estimate(self) -> Estimate:
        """The filter's estimate; before the first fix an invalid one (identity, raw gyro rate, σ = π)."""
        if self.fusion.ekf is None:
            return Estimate(np.array([1.0, 0.0, 0.0, 0.0]), self._omega_gyro.copy(), np.pi, False)
        now = self.fusion.current()
        cov, _, max_var = self._protected_cov(now)
        return Estimate(now[0].copy(), now[3].copy(), math.sqrt(max_var), self._estimate_valid(max_var), cov.copy())

    def render_last_frame(self) -> np.ndarray | None:
        """RGB uint8 image (rows, cols, 3) of the last frame of the first head, detections boxed; None before a
        frame or without ``keep_images``."""
        if self._last_frame is None:
            return None
        scene, det = self._last_frame
        return self.head.render(scene, det)


@dataclass(frozen=True)
class EstimateHistory:
    """What :func:`run_star_tracker` returns: the filter's estimate at the end of every frame.

    Attributes
    ----------
    t_s : ndarray, shape (F,)
        End of each frame, s.
    q_body_to_icrs : ndarray, shape (F, 4)
        Estimated attitude (identity while ``valid`` is False).
    attitude_sigma_rad : ndarray, shape (F,)
        Largest 1σ attitude uncertainty, rad (π while invalid).
    omega_body : ndarray, shape (F, 3)
        Estimated body rate, rad/s.
    valid : ndarray of bool, shape (F,)
    mode : tuple of str, length F
        Tracker mode after each frame ("lost", "acquire", "track").
    n_attitude_samples : ndarray of int, shape (F,)
        Attitude samples the star tracker produced in each frame.
    samples : list of startracker.sensor.AttitudeSample
        Every star-tracker sample, in time order of the frames.
    """

    t_s: np.ndarray
    q_body_to_icrs: np.ndarray
    attitude_sigma_rad: np.ndarray
    omega_body: np.ndarray
    valid: np.ndarray
    mode: tuple
    n_attitude_samples: np.ndarray
    samples: list


def run_star_tracker(t_s, q_body_to_icrs, *, omega_gyro=None, camera="paper000", rng=None,
                     catalog: StarCatalog | None = None, **options) -> EstimateHistory:
    """Run the star tracker and the filter over a trajectory of one's own: truth in, estimate history out.

    Every frame is imaged from the trajectory (slerp between its samples), detected, identified or tracked,
    and fused with the gyro by the EKF; the unit starts lost.

    Parameters
    ----------
    t_s : array_like, shape (T,)
        Trajectory instants, s, strictly increasing, spanning at least one frame.
    q_body_to_icrs : array_like, shape (T, 4)
        True attitude at ``t_s`` (w, x, y, z; normalised here).
    omega_gyro : array_like, shape (T-1, 3), optional
        Measured gyro rates over ``(t_s[k-1], t_s[k]]``, rad/s, for uniformly spaced ``t_s`` (the gyro rate is
        ``1 / (t_s[1] - t_s[0])``). Default: the unit's gyro (``gyro_grade``, ``gyro_rate_hz``) samples the
        trajectory, resampled at the gyro's instants.
    camera : str, StarTrackerSpec, dict or list of them
        Head camera(s): one of :data:`HEAD_CAMERAS`, a :class:`startracker.spec.StarTrackerSpec` or its dict.
    rng : numpy.random.Generator, optional
        Every noise draw (default ``numpy.random.default_rng(0)``).
    catalog : startracker.catalog.StarCatalog, optional
        Default ``load_catalog(mag_limit)``.
    **options
        Any other field of :class:`UnitConfig` (``frame_period_s``, ``fidelity``, ``gyro_grade``, ``n_heads``,
        ``identify_method``, ...).

    Returns
    -------
    EstimateHistory
        One row per whole frame inside the trajectory.
    """
    rng = np.random.default_rng(0) if rng is None else check_rng(rng)
    t = as_float_array(t_s, "t_s", ndim=1)
    q = as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4, ndim=2)
    if len(q) != len(t) or len(t) < 2:
        raise ValueError(f"q_body_to_icrs must have shape ({len(t)}, 4) with at least 2 rows, got {q.shape}")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t_s must be strictly increasing")
    norms = np.linalg.norm(q, axis=1)
    if np.any(norms < 1e-12):
        raise ValueError("q_body_to_icrs contains a zero quaternion")
    q = q / norms[:, None]
    if omega_gyro is not None:
        w = as_float_array(omega_gyro, "omega_gyro", last_dim=3, ndim=2)
        if len(w) != len(t) - 1:
            raise ValueError(f"omega_gyro must have shape ({len(t) - 1}, 3), got {w.shape}")
        dt = np.diff(t)
        if np.ptp(dt) > 1e-9 * dt[0]:
            raise ValueError("with omega_gyro, t_s must be uniformly spaced (the gyro's sample instants)")
        options["gyro_rate_hz"] = 1.0 / float(dt[0])
    config = UnitConfig(camera=camera, **options)
    unit = StarTrackerUnit(config, catalog=catalog)
    g = int(round(config.frame_period_s * config.gyro_rate_hz))  # gyro intervals per frame
    n_frames = int(np.floor((t[-1] - t[0]) / config.frame_period_s + 1e-9))
    if n_frames < 1:
        raise ValueError(f"the trajectory must span at least one frame ({config.frame_period_s} s)")
    if omega_gyro is None:
        times = t[0] + np.arange(n_frames * g + 1) * unit.gyro_period_s
        quats = quat_interpolate(t, q, np.minimum(times, t[-1]))
    else:
        times, quats = t, q
    unit.reset(rng)
    rows = dict(t=[], q=[], sig=[], w=[], valid=[], mode=[], n=[])
    samples = []
    for f in range(n_frames):
        sl = slice(f * g, (f + 1) * g + 1)
        unit.observe(times[sl], quats[sl], rng, omega_gyro=None if omega_gyro is None else w[f * g:(f + 1) * g])
        est = unit.estimate()
        rows["t"].append(times[sl][-1])
        rows["q"].append(est.q_body_to_icrs)
        rows["sig"].append(est.attitude_sigma_rad)
        rows["w"].append(est.omega_body)
        rows["valid"].append(est.valid)
        rows["mode"].append(unit.tracker_mode)
        rows["n"].append(unit.last_stats["n_attitude_samples"])
        samples.extend(unit.last_samples)
    return EstimateHistory(np.array(rows["t"]), np.array(rows["q"]), np.array(rows["sig"]), np.array(rows["w"]),
                           np.array(rows["valid"], dtype=bool), tuple(rows["mode"]), np.array(rows["n"], dtype=int),
                           samples)
