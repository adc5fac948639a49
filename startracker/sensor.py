"""The star tracker: one call runs one camera frame through the lost -> acquire -> track state machine.

Modes (``StarTracker.mode``, and ``FrameResult.mode`` = the mode *after* the frame)
------------------------------------------------------------------------------------
``lost``
    No usable attitude. First, if a recent lock (younger than ``coast_max_s``) or a ``q_body_prior`` is
    available, the frame is tried as a tracking frame from that state with the radius grown by the gap
    (a short outage recovers straight to ``track``). Otherwise lost-in-space identification
    (:func:`startracker.identify.identify`) runs on a single-exposure frame; a success becomes a
    *candidate* and the mode ``acquire``. No sample is emitted from an unconfirmed identification.
``acquire``
    The next frame confirms the candidate. With a gyro rate, by tracking: prediction from the candidate
    attitude and the gyro rate, DKVLUT matching, the lock test. Without a gyro, by a second independent
    identification whose rotation from the candidate implies a rate below ``max_rate_deg_s`` (two wrong
    identifications agreeing that closely are practically impossible); that rate then seeds tracking.
    Confirmed: samples are emitted and the mode is ``track``; not confirmed: ``lost`` (or a new candidate).
``track``
    Paper 000's tracking mode: predicted spots at the N exposure instants from the last attitude, rate
    and acceleration (:func:`startracker.track.predict_star_positions`), matched with the chosen matcher
    inside the radius of the prediction's uncertainty (:func:`startracker.track.prediction_radius_px`),
    grouped by instant into N Wahba attitudes (:func:`startracker.track.attitudes_per_instant`).

Lock test (every tracking attempt): at least one instant solved with ``min_stars_per_instant`` stars;
matched fraction of the predicted on-detector spots >= ``min_matched_fraction``; RMS residual <=
``max_residual_arcsec``; neither the first nor the last instant nearly empty (the signature of a frame
matched one exposure off); the solved attitudes within ``innovation_gate`` (χ²) of the prediction. Failing
it drops the tracker to ``lost``: stray light, a frame of false objects or a broken motion model loses the
lock instead of producing a confident wrong attitude.

Exposure plan: while lost or acquiring a single exposure is requested (lost-in-space needs one spot per
star); while tracking ``N = clip(1 + round(|ω| / rate_per_exposure_deg_s), 1, max_exposures)``, paper 000
§5's plan (N from 1 to 21 as the rate goes from 0 to 20 °/s, spots of one star ~10 px apart), further
capped so that consecutive spots of a star stay ``2 shift_k_sigma`` prediction σ apart, and 1 until the
acceleration has been estimated. A frame with more exposures than the prediction can separate is refused
(the tracker does not guess which exposure a spot belongs to).

Motion state after a tracked frame: the last solved instant's attitude and covariance; the body rate
from a least-squares line through the instants' rotation vectors (or the gyro, or the rotation between
two frames for N = 1); the angular acceleration from the change of rate between frames (or between gyro
readings).

The module is over 600 lines because it is one state machine (:class:`StarTracker`): its modes share the
motion state and the attempt bookkeeping, which a split would have to pass between files.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from startracker.attitude import RAD_TO_ARCSEC
from startracker.catalog import StarCatalog
from startracker.identify import METHODS as ID_METHODS
from startracker.identify import IdentificationResult, identify
from startracker.optics import Camera
from startracker.rotations import quat_conjugate, quat_multiply, quat_normalize, quat_to_rotvec
from startracker.validation import as_float_array, build_checked, check_positive
from startracker.track import (
    MATCH_METHODS,
    camera_projection_model,
    RADIUS_K_SIGMA,
    prediction_radius_px,
    attitudes_per_instant,
    match_stars,
    predict_star_positions,
    prediction_covariance,
    prediction_sigma_px,
)
from startracker.kernels import rotations as rk
from startracker.kernels import sensor as sensor_kernels
from startracker.kernels import track as track_kernels

__all__ = ["StarTracker", "FrameResult", "AttitudeSample", "AttitudeSamples", "NO_SAMPLES", "MotionState", "MODES"]

MODES = ("lost", "acquire", "track")

_NO_FLUX = np.zeros(0)
_NO_FLUX.setflags(write=False)


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a`` made read-only (a constant shared by motion states)."""
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class AttitudeSample:
    """One attitude measurement, at one exposure instant.

    Attributes
    ----------
    t_s : float
        Exposure instant (mid-exposure), s.
    q_body_to_icrs : ndarray, shape (4,)
    covariance_rad2 : ndarray, shape (3, 3)
        Covariance of the attitude error rotation vector in the body frame (``q_true = q ⊗ δq(δθ)``), rad².
    n_stars : int
    """

    t_s: float
    q_body_to_icrs: np.ndarray
    covariance_rad2: np.ndarray
    n_stars: int


@dataclass(frozen=True)
class AttitudeSamples:
    """Attitude samples as arrays, one row per exposure instant, time-ordered: what a frame (or an observed span)
    produced, without one object per sample. The per-frame path hands these on; :meth:`to_list` gives the
    :class:`AttitudeSample` objects.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
        Exposure instants (mid-exposure), s.
    q_body_to_icrs : ndarray, shape (n, 4)
    covariance_rad2 : ndarray, shape (n, 3, 3)
        As :attr:`AttitudeSample.covariance_rad2`, rad².
    n_stars : ndarray of int64, shape (n,)
    """

    t_s: np.ndarray
    q_body_to_icrs: np.ndarray
    covariance_rad2: np.ndarray
    n_stars: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)

    def to_list(self) -> list[AttitudeSample]:
        """One :class:`AttitudeSample` per row (Python float ``t_s`` and int ``n_stars``), on copies of the arrays:
        the samples share no memory with this batch."""
        if not len(self.t_s):
            return []
        q, c = self.q_body_to_icrs.copy(), self.covariance_rad2.copy()
        return [build_checked(AttitudeSample, {"t_s": t, "q_body_to_icrs": qi, "covariance_rad2": ci, "n_stars": n})
                for t, qi, ci, n in zip(self.t_s.tolist(), q, c, self.n_stars.tolist())]

    @staticmethod
    def concatenate(batches) -> "AttitudeSamples":
        """The rows of several batches, in order (one batch: itself; none: :data:`NO_SAMPLES`)."""
        batches = [b for b in batches if len(b)]
        if not batches:
            return NO_SAMPLES
        if len(batches) == 1:
            return batches[0]
        return build_checked(AttitudeSamples, {
            "t_s": np.concatenate([b.t_s for b in batches]),
            "q_body_to_icrs": np.concatenate([b.q_body_to_icrs for b in batches]),
            "covariance_rad2": np.concatenate([b.covariance_rad2 for b in batches]),
            "n_stars": np.concatenate([b.n_stars for b in batches])})


NO_SAMPLES = AttitudeSamples(_frozen(np.zeros(0)), _frozen(np.zeros((0, 4))), _frozen(np.zeros((0, 3, 3))),
                             _frozen(np.zeros(0, dtype=np.int64)))
"""The empty batch (read-only arrays, shared)."""


@dataclass(frozen=True)
class FrameResult:
    """What one frame produced.

    Attributes
    ----------
    mode : str
        Mode after this frame: "lost", "acquire" or "track".
    attitude_samples : AttitudeSamples
        Up to N samples (one per solved exposure instant), time-ordered, as arrays.
    samples : list of AttitudeSample
        The same samples as objects (a property: built at each access, on copies of the arrays).
    n_matched : int
        Detections used (tracking) or identified (lost-in-space).
    n_detections : int
    matching_latency_ms : float
        Wall clock of the tracking attempt in this frame: prediction, matching, the per-instant solutions and their
        smoothness test (0 when no tracking attempt ran).
    update_rate_hz : float
        Samples of this frame divided by the frame interval.
    status : str
    n_exposures : int
        Exposure instants of this frame.
    n_predicted : int
        Predicted spots on the detector (tracking attempts).
    radius_px : float
        Star-neighbourhood radius used (0 without a tracking attempt).
    identify_latency_ms : float
        Wall clock of lost-in-space identification (0 when it did not run).
    residual_arcsec : float
        RMS residual over the solved instants (inf when none).
    skipped_instants : tuple of int
        Exposure instants without a solution.
    """

    mode: str
    attitude_samples: AttitudeSamples
    n_matched: int
    n_detections: int
    matching_latency_ms: float
    update_rate_hz: float
    status: str
    n_exposures: int = 1
    n_predicted: int = 0
    radius_px: float = 0.0
    identify_latency_ms: float = 0.0
    residual_arcsec: float = float("inf")
    skipped_instants: tuple = ()

    @property
    def samples(self) -> list[AttitudeSample]:
        """:attr:`attitude_samples` as :class:`AttitudeSample` objects (a new list at each access: keep it)."""
        return self.attitude_samples.to_list()


@dataclass(frozen=True)
class MotionState:
    """Attitude, rate and acceleration at a reference time, with their uncertainty (body frame).

    Attributes
    ----------
    t_s : float
        Reference time: the last solved exposure instant, s.
    q_body_to_icrs : ndarray, shape (4,)
    cov_theta_rad2 : ndarray, shape (3, 3)
    omega_body : ndarray, shape (3,)
        Rate at ``t_s``, rad/s.
    cov_omega : ndarray, shape (3, 3)
        (rad/s)².
    alpha_body : ndarray, shape (3,)
        Angular acceleration, rad/s².
    cov_alpha : ndarray, shape (3, 3)
        Error of the acceleration estimate, (rad/s²)² (the unmodelled change is added when predicting).
    rate_meas : tuple (t_s, omega (3,), cov (3, 3)) or None
        The last rate *measurement* (fit over a frame's instants, two-frame difference or gyro) and its
        time, differenced with the next one into the acceleration.
    alpha_known : bool
        The acceleration was estimated (two rate measurements); until then the plan asks for N = 1.
    """

    t_s: float
    q_body_to_icrs: np.ndarray
    cov_theta_rad2: np.ndarray
    omega_body: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cov_omega: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    alpha_body: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cov_alpha: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    rate_meas: tuple | None = None
    alpha_known: bool = False


@dataclass
class _Candidate:
    t_s: float
    q_body_to_icrs: np.ndarray
    cov_theta_rad2: np.ndarray
    n_matched: int


@dataclass
class _Attempt:
    ok: bool
    status: str
    samples: AttitudeSamples
    n_matched: int = 0
    n_predicted: int = 0
    radius_px: float = 0.0
    latency_ms: float = 0.0
    residual_arcsec: float = float("inf")
    skipped: tuple = ()
    state: MotionState | None = None


class StarTracker:
    """Lost-in-space identification plus multi-exposure tracking, one frame per call.

    Parameters
    ----------
    camera : Camera
        Its ``q_cam_to_body`` mounting turns camera attitudes into body attitudes.
    catalog : StarCatalog
        Navigation stars, used for identification and prediction (close doubles that blend into one spot
        are best removed with :func:`startracker.catalog.select_navigation_stars`).
    identify_method : str
        Lost-in-space method of :func:`startracker.identify.identify`.
    matcher : {"dkvlut", "brute", "kdtree"}
    centroid_sigma_px : float
        1σ per-axis centroid noise, px: weights, radius, residual tests, identification tolerances.
    frame_period_s : float
        Frame interval assumed before two frames have been seen.
    max_exposures : int
        Largest N of the exposure plan.
    rate_per_exposure_deg_s : float
        One more exposure per this much body rate.
    radius_k_sigma, radius_min_px, radius_max_px : float
        Radius rule ``r = clip(k √(σ_c² + σ_pred²), r_min, r_max)``.
    min_stars_per_instant : int
        Stars needed for an instant's attitude.
    min_matched_fraction : float
        Lock test: matched share of the predicted on-detector spots.
    max_residual_arcsec : float, optional
        Lock test on the RMS residual; default 3 × the expected √2 σ_c / f_px.
    outlier_k_sigma : float
        Residual test removing a wrong match inside an instant.
    innovation_gate : float
        Lock test: mean over the solved instants of ``δᵀ S⁻¹ δ``, δ the rotation from the predicted to the
        solved attitude and S the sum of their covariances (χ² with 3 degrees of freedom: 30 is exceeded
        with probability 1e-6 when the motion model holds). It catches a whole frame matched one exposure
        off (spots of instant n taken for instant n ± 1), which no residual can see.
    instant_gate : float
        Smoothness test of a tracked frame's instants: an instant whose attitude lies further than this χ² (3
        degrees of freedom) from a polynomial in time through the other instants is not reported (one matched an
        exposure off: its spots taken for the neighbouring exposure's, or pulled by spots joined across
        exposures); more than a third such and the frame is refused. 16 is exceeded with probability 1e-3 by an
        instant that is right (a sample lost, 0.1 % of the rate), and lies well under the verdict's 44.8 on the
        instant's own covariance (the leave-one-out covariance adds the fit's); ``inf`` disables the test.
    star_flux : array_like, shape (C,), optional
        Expected signal of each catalog star in one exposure (relative; e.g. the detector's
        ``SensorModel.star_pe(vmag, bv, 1.0)``). Given, a match whose intensity over its star's expected signal exceeds
        ``blend_flux_ratio`` times the frame's lower quartile of that ratio is not used: it holds more than one exposure's
        light (spots joined across exposures: their centroid lies between the exposures and would pull the instant
        along the motion). Needs the detections' ``intensity``.
    blend_flux_ratio : float
        Threshold of that photometric blend test (> 1): a join of two equal exposures carries 2.
    scale_by_residuals : bool
        Each instant's covariance grows by its a-posteriori variance factor, ``rms² / (2 σ_c² (1 - 3 / 2n))`` with
        ``n`` its stars, when that exceeds 1 (never shrinks): residuals larger than the centroid model claims
        (streaks in stray light, a rate beyond the model) widen the sample's covariance instead of leaving it
        confidently wrong. Default True.
    shift_k_sigma : float
        Exposure plan: N is also limited so that the spots of one star stay ``2 shift_k_sigma`` prediction
        σ apart, keeping that one-exposure-off match improbable.
    accel_sigma_rad_s2 : float
        Unmodelled change of the angular acceleration over a prediction (1σ per axis), rad/s².
    recovery_accel_sigma_rad_s2 : float
        Acceleration uncertainty assumed when recovering a lost lock from the old state (the lock was
        usually lost because the motion model failed).
    gyro_sigma_rad_s : float
        1σ per-axis error of a gyro rate passed as ``omega_body``.
    max_rate_deg_s : float
        Largest plausible body rate (confirmation of two identifications without a gyro).
    coast_max_s : float
        How long a lost lock may be recovered from the old state by prediction.
    prior_sigma_rad : float
        1σ per-axis error assumed for a ``q_body_prior``.
    identify_options : dict, optional
        Extra keyword options for ``identify`` (``sigma_px`` defaults to ``centroid_sigma_px``).
    """

    def __init__(
        self,
        camera: Camera,
        catalog: StarCatalog,
        identify_method: str = "pyramid",
        matcher: str = "dkvlut",
        centroid_sigma_px: float = 0.5,
        frame_period_s: float = 0.1,
        max_exposures: int = 21,
        rate_per_exposure_deg_s: float = 1.0,
        radius_k_sigma: float = RADIUS_K_SIGMA,
        radius_min_px: float = 2.0,
        radius_max_px: float = 40.0,
        min_stars_per_instant: int = 3,
        min_matched_fraction: float = 0.3,
        max_residual_arcsec: float | None = None,
        outlier_k_sigma: float = 5.0,
        innovation_gate: float = 30.0,
        instant_gate: float = 16.0,
        star_flux=None,
        blend_flux_ratio: float = 1.6,
        scale_by_residuals: bool = True,
        shift_k_sigma: float = 4.0,
        accel_sigma_rad_s2: float = 0.02,
        recovery_accel_sigma_rad_s2: float = 0.2,
        gyro_sigma_rad_s: float = 1e-4,
        max_rate_deg_s: float = 30.0,
        coast_max_s: float = 1.0,
        prior_sigma_rad: float = 1e-3,
        identify_options: dict | None = None,
    ):
        if not isinstance(camera, Camera):
            raise TypeError(f"camera must be a startracker.optics.Camera, got {type(camera).__name__}")
        if not isinstance(catalog, StarCatalog):
            raise TypeError(f"catalog must be a startracker.catalog.StarCatalog, got {type(catalog).__name__}")
        if matcher not in MATCH_METHODS:
            raise ValueError(f"matcher must be one of {MATCH_METHODS}, got {matcher!r}")
        if identify_method not in ID_METHODS:
            raise ValueError(f"identify_method must be one of {sorted(ID_METHODS)}, got {identify_method!r}")
        self.camera = camera
        self.catalog = catalog
        self.identify_method = identify_method
        self.matcher = matcher
        self.centroid_sigma_px = check_positive(centroid_sigma_px, "centroid_sigma_px")
        self.frame_period_s = check_positive(frame_period_s, "frame_period_s")
        if isinstance(max_exposures, bool) or int(max_exposures) != max_exposures or max_exposures < 1:
            raise ValueError(f"max_exposures must be an integer >= 1, got {max_exposures!r}")
        self.max_exposures = int(max_exposures)
        self.rate_per_exposure_deg_s = check_positive(rate_per_exposure_deg_s, "rate_per_exposure_deg_s")
        self.radius_k_sigma = check_positive(radius_k_sigma, "radius_k_sigma")
        self.radius_min_px = check_positive(radius_min_px, "radius_min_px", allow_zero=True)
        self.radius_max_px = check_positive(radius_max_px, "radius_max_px")
        if self.radius_max_px < self.radius_min_px:
            raise ValueError("radius_max_px must be >= radius_min_px")
        if isinstance(min_stars_per_instant, bool) or int(min_stars_per_instant) != min_stars_per_instant or min_stars_per_instant < 2:
            raise ValueError(f"min_stars_per_instant must be an integer >= 2, got {min_stars_per_instant!r}")
        self.min_stars_per_instant = int(min_stars_per_instant)
        self.min_matched_fraction = check_positive(min_matched_fraction, "min_matched_fraction", allow_zero=True)
        if self.min_matched_fraction > 1:
            raise ValueError(f"min_matched_fraction must be in [0, 1], got {min_matched_fraction}")
        self.sigma_rad = self.centroid_sigma_px / camera.focal_length_px
        expected = np.sqrt(2.0) * self.sigma_rad * RAD_TO_ARCSEC
        self._residual_expected_arcsec = float(expected)  # RMS of a star's 2-D residual for the model's σ
        self.max_residual_arcsec = (
            3.0 * expected if max_residual_arcsec is None else check_positive(max_residual_arcsec, "max_residual_arcsec")
        )
        self.outlier_k_sigma = check_positive(outlier_k_sigma, "outlier_k_sigma")
        self.innovation_gate = check_positive(innovation_gate, "innovation_gate")
        self.instant_gate = math.inf if instant_gate == math.inf else check_positive(instant_gate, "instant_gate")
        if star_flux is None:
            self._star_flux = np.zeros(0)
        else:
            self._star_flux = np.ascontiguousarray(as_float_array(star_flux, "star_flux", ndim=1))
            if len(self._star_flux) != len(catalog.vmag) or np.any(self._star_flux <= 0):
                raise ValueError(f"star_flux must hold one positive value per catalog star ({len(catalog.vmag)})")
        self.blend_flux_ratio = check_positive(blend_flux_ratio, "blend_flux_ratio")
        if not isinstance(scale_by_residuals, (bool, np.bool_)):
            raise TypeError(f"scale_by_residuals must be a bool, got {type(scale_by_residuals).__name__}")
        self.scale_by_residuals = bool(scale_by_residuals)
        if self.blend_flux_ratio <= 1.0:
            raise ValueError(f"blend_flux_ratio must be > 1, got {blend_flux_ratio}")
        self._intensity = np.zeros(0)  # this frame's detection intensities (the photometric blend test)
        self._flux = _NO_FLUX
        self.shift_k_sigma = check_positive(shift_k_sigma, "shift_k_sigma", allow_zero=True)
        self.accel_sigma_rad_s2 = check_positive(accel_sigma_rad_s2, "accel_sigma_rad_s2", allow_zero=True)
        self.recovery_accel_sigma_rad_s2 = check_positive(recovery_accel_sigma_rad_s2, "recovery_accel_sigma_rad_s2", allow_zero=True)
        self.gyro_sigma_rad_s = check_positive(gyro_sigma_rad_s, "gyro_sigma_rad_s", allow_zero=True)
        self.max_rate_rad_s = float(np.radians(check_positive(max_rate_deg_s, "max_rate_deg_s")))
        self.coast_max_s = check_positive(coast_max_s, "coast_max_s", allow_zero=True)
        self.prior_sigma_rad = check_positive(prior_sigma_rad, "prior_sigma_rad")
        self.identify_options = {"sigma_px": self.centroid_sigma_px, **(identify_options or {})}
        # Per-frame constants, built once (read-only: the motion state shares them)
        self._eye3 = _frozen(np.eye(3))
        self._var_gyro = _frozen(self.gyro_sigma_rad_s**2 * np.eye(3))
        self._var_proc = _frozen(self.accel_sigma_rad_s2**2 * np.eye(3))
        # the lost path's covariances: a recovery's extra acceleration variance (None when 0: nothing added), and a
        # prior's attitude and rate without a gyro (with one, _var_gyro); the last two writable like the per-frame
        # covariances they stand for (one kernel signature; nothing writes them)
        self._var_recovery = (None if self.recovery_accel_sigma_rad_s2**2 == 0
                              else _frozen(self.recovery_accel_sigma_rad_s2**2 * self._eye3))
        self._cov_prior = self.prior_sigma_rad**2 * np.eye(3)
        self._var_rate_unknown = self.max_rate_rad_s**2 * np.eye(3)
        # the error of a frame's gyro acceleration (process_frame's alpha_body), alone and with the unmodelled change
        # (writable like the per-frame covariances they stand for: one kernel signature; nothing writes them)
        self._cov_alpha_gyro = 2.0 * self._var_gyro / self.frame_period_s**2
        self._cov_alpha_gyro_total = self._cov_alpha_gyro + self._var_proc
        self._r_cam_to_body = camera.r_cam_to_body
        self._r_body_to_cam = _frozen(np.ascontiguousarray(camera.r_cam_to_body.T))
        self._f_px = float(camera.focal_length_px)
        self._rho_max_px = math.hypot(*camera.resolution) / 2.0
        # The compiled frame (track_frame) needs the kernels' camera model and a compiled matcher; a camera
        # projecting by a model of its own, or the cKDTree matcher, goes through the public stages one by one.
        model = camera_projection_model(camera)
        self._frame_model = None if model is None or matcher == "kdtree" else (*model, *map(int, camera.resolution))
        self._q_cam_to_body = _frozen(np.array(camera.q_cam_to_body, dtype=np.float64))
        self._q_body_to_cam = rk.quat_conjugate(self._q_cam_to_body)  # writable: a read-only array compiles anew
        self._half_diag_fov_rad = float(camera.half_diagonal_fov_rad)
        self.reset()

    # ------------------------------------------------------------------ public state
    def reset(self) -> None:
        """Forget everything: mode ``lost``, no motion state, no candidate, no frame history."""
        self._mode = "lost"
        self._state: MotionState | None = None
        self._candidate: _Candidate | None = None
        self._last_frame_time: float | None = None
        self._frame_interval_s = self.frame_period_s
        self._last_gyro: tuple | None = None
        self._frame_alpha = None  # this frame's gyro acceleration (process_frame's alpha_body), rad/s²
        self._last_exp_centre = 0.0
        self._dt_frame = self.frame_period_s
        self._motion_cache = None  # (state, interval, exposure centre, _next_frame_motion's value)

    def _previous_gyro(self, t_frame: float):
        """The previous frame's gyro reading as a rate measurement, if recent (else None)."""
        g = self._last_gyro
        return g if g is not None and 0 < t_frame - g[0] <= self.coast_max_s else None

    @property
    def mode(self) -> str:
        """Current mode: "lost", "acquire" or "track"."""
        return self._mode

    @property
    def state(self) -> MotionState | None:
        """Motion state of the last lock (kept while lost, for recovery), or None."""
        return self._state

    @property
    def requested_n_exposures(self) -> int:
        """Exposures the next frame should have: 1 while lost or acquiring, else the exposure plan's N.

        ``N = min(1 + round(|ω| / rate_per_exposure_deg_s), N_sep)``, clipped to ``[1, max_exposures]``,
        where ``N_sep`` (:meth:`separable_n_exposures` with ``2 · shift_k_sigma``) keeps the spots of one star
        (travel ``|ω_⊥| T f_px`` over a frame, split in N) ``2 · shift_k_sigma`` prediction σ apart. 1 until
        the acceleration has been estimated (right after acquisition or recovery, without a gyro: one more
        single-exposure frame).
        """
        return self.separable_n_exposures(2.0 * self.shift_k_sigma, cap_by_rate=True)

    def separable_n_exposures(self, spacing_sigma: float, cap_by_rate: bool = False) -> int:
        """The largest N whose spots of one star stay ``spacing_sigma`` prediction σ apart on the next frame.

        1 while not tracking or before the acceleration is known; ``max_exposures`` when the prediction is exact
        or ``spacing_sigma`` is 0. With ``cap_by_rate`` also at most ``1 + round(|ω| / rate_per_exposure_deg_s)``.
        The frame step refuses frames whose spots are closer than ``1.5 · shift_k_sigma`` σ.
        """
        st = self._state
        if self._mode != "track" or st is None or not st.alpha_known:
            return 1
        n_rate, sigma, travel_px = self._next_frame_motion(st)
        n_top = n_rate if cap_by_rate else self.max_exposures
        n_sep = n_top if spacing_sigma == 0 or sigma == 0 else int(travel_px / (spacing_sigma * sigma))
        return min(max(min(n_top, n_sep), 1), self.max_exposures)  # np.clip on Python ints

    def _next_frame_motion(self, st: MotionState):
        """``(N by rate, prediction σ px, travel px)`` of the next frame from the motion state ``st``: the plan's
        ``1 + round(|ω| / rate_per_exposure_deg_s)``, the prediction's 1σ spot error at the next frame's last exposure
        and a star's image travel over a frame period. Computed once per state and frame (the exposure plan asks for
        it twice: :attr:`requested_n_exposures`, then :meth:`separable_n_exposures` for the detector's limit)."""
        period = self._frame_interval_s
        hit = self._motion_cache
        if hit is not None and hit[0] is st and hit[1] == period and hit[2] == self._last_exp_centre:
            return hit[3]
        w = st.omega_body
        w0, w1, w2 = w.tolist()  # Python floats: the same products and sum as on numpy scalars, without their boxing
        n_rate = 1 + round(math.degrees(math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)) / self.rate_per_exposure_deg_s)
        # The next frame's last exposure: its centre is one interval after the last frame's centre, and its
        # exposures spread over at most a frame period.
        horizon = max(period, self._last_exp_centre + 1.5 * period - st.t_s)
        # the motion state holds (3, 3) float64 covariances: the kernel of prediction_sigma_px directly
        sigma = track_kernels.prediction_sigma_px(self._r_cam_to_body, st.cov_theta_rad2, st.cov_omega,
                                                  self._cov_alpha_total(st), float(horizon), self._f_px, self._rho_max_px)
        wx, wy, _ = np.dot(self._r_body_to_cam, w).tolist()  # BLAS gemv like @, without the matmul ufunc machinery
        travel_px = math.hypot(wx, wy) * period * self._f_px
        value = (n_rate, sigma, travel_px)
        self._motion_cache = (st, period, self._last_exp_centre, value)
        return value

    # ------------------------------------------------------------------ one frame
    def process_frame(self, xy, intensity, exposure_times, frame_time, omega_body=None, q_body_prior=None, *,
                      alpha_body=None, validate: bool = True) -> FrameResult:
        """Run one frame of detections through the state machine.

        Parameters
        ----------
        xy : array_like, shape (K, 2)
            Detections (column, row), px: N spots per star in a multi-exposure frame, any order.
        intensity : array_like, shape (K,) or None
            Positive detection intensities (lost-in-space orders by them; None: ``xy`` is brightest first).
        exposure_times : array_like, shape (N,)
            Mid-exposure instants, s, strictly increasing.
        frame_time : float
            Time stamp of the frame (for the update rate, and of the gyro reading), s.
        omega_body : array_like, shape (3,), optional
            Gyro body rate at ``frame_time``, rad/s.
        q_body_prior : array_like, shape (4,), optional
            External attitude prior at ``frame_time`` (e.g. a filter's propagated estimate), used to
            recover while lost.
        alpha_body : array_like, shape (3,), optional
            With ``omega_body``: the gyro's mean angular acceleration over this frame, rad/s² (the change of its rate
            over the frame over the frame period; the frame is processed after its readout, when the gyro has
            measured it). Used for the prediction instead of the acceleration over the previous frame, which a
            torque change at the frame's start makes stale; 1σ ``√2 gyro_sigma_rad_s / frame_period_s`` per axis.
        validate : bool
            False skips the checks, for a caller passing inputs in the form they produce: float64 ``xy`` (K, 2),
            positive float64 ``intensity`` (K,) or None, strictly increasing float64 ``exposure_times`` (N,),
            float ``frame_time``, float64 ``omega_body`` (3,) or None, unit canonical float64 ``q_body_prior``
            (4,) (as ``quat_normalize`` returns) or None.

        Returns
        -------
        FrameResult
        """
        self._frame_alpha = None
        if not validate:
            if alpha_body is not None and omega_body is not None:
                self._frame_alpha = alpha_body
            return self._run_frame(xy, intensity, exposure_times, frame_time, omega_body, q_body_prior)
        xy = np.empty((0, 2)) if np.size(xy) == 0 else as_float_array(xy, "xy", last_dim=2, ndim=2)
        if intensity is not None:
            intensity = np.empty(0) if np.size(intensity) == 0 else as_float_array(intensity, "intensity", ndim=1)
            if len(intensity) != len(xy):
                raise ValueError(f"intensity must have shape ({len(xy)},), got {intensity.shape}")
            if np.any(intensity <= 0):
                raise ValueError("intensity must be positive")
        t_exp = np.atleast_1d(as_float_array(exposure_times, "exposure_times"))
        if t_exp.ndim != 1 or len(t_exp) == 0:
            raise ValueError(f"exposure_times must be a non-empty 1-D array, got shape {t_exp.shape}")
        if np.any(np.diff(t_exp) <= 0):
            raise ValueError("exposure_times must be strictly increasing")
        t_frame = float(as_float_array(frame_time, "frame_time"))
        gyro = None if omega_body is None else as_float_array(omega_body, "omega_body", last_dim=3, ndim=1)
        prior = None if q_body_prior is None else quat_normalize(as_float_array(q_body_prior, "q_body_prior", 4, 1))
        if alpha_body is not None and gyro is not None:
            self._frame_alpha = as_float_array(alpha_body, "alpha_body", last_dim=3, ndim=1)
        return self._run_frame(xy, intensity, t_exp, t_frame, gyro, prior)

    def _run_frame(self, xy, intensity, t_exp, t_frame, gyro, prior) -> FrameResult:
        """The work of :meth:`process_frame` on checked inputs."""
        if len(self._star_flux) and intensity is not None and len(intensity) == len(xy):
            self._intensity, self._flux = np.ascontiguousarray(intensity, dtype=np.float64), self._star_flux
        else:  # no photometric blend test without intensities
            self._intensity, self._flux = np.zeros(len(xy)), _NO_FLUX
        if self._last_frame_time is not None and t_frame <= self._last_frame_time:
            self.reset()  # time went backwards: a new run, nothing of the old one is valid
        dt_frame = self.frame_period_s if self._last_frame_time is None else t_frame - self._last_frame_time
        self._dt_frame = dt_frame  # the update rate of the results built below
        if self._mode == "track":
            att = self._track(xy, t_exp, self._state, gyro, t_frame)
            if att.ok:
                result = self._accept(att, xy, t_exp)
            else:
                self._mode = "lost"
                result = self._result(att, xy, t_exp, status=f"lock lost: {att.status}")
        elif self._mode == "acquire":
            result = self._acquire(xy, intensity, t_exp, gyro, t_frame)
        else:
            result = self._lost(xy, intensity, t_exp, gyro, t_frame, prior)

        if self._last_frame_time is not None:
            self._frame_interval_s = dt_frame
        self._last_frame_time = t_frame
        self._last_gyro = None if gyro is None else (t_frame, gyro, self._var_gyro)
        self._last_exp_centre = 0.5 * (float(t_exp[0]) + float(t_exp[-1]))
        r = result
        rate = len(r.attitude_samples) / dt_frame
        if r.mode == self._mode and r.update_rate_hz == rate:  # built final (the tracking paths): no copy
            return r
        return FrameResult(self._mode, r.attitude_samples, r.n_matched, r.n_detections, r.matching_latency_ms,
                           rate, r.status, r.n_exposures, r.n_predicted, r.radius_px,
                           r.identify_latency_ms, r.residual_arcsec, r.skipped_instants)

    # ------------------------------------------------------------------ modes
    def _lost(self, xy, intensity, t_exp, gyro, t_frame, prior) -> FrameResult:
        tried = []
        latency = 0.0
        st = self._state
        if st is not None and 0 <= t_exp[-1] - st.t_s <= self.coast_max_s:
            att = self._track(xy, t_exp, st, gyro, t_frame, self._var_recovery)
            latency += att.latency_ms
            if att.ok:
                return self._accept(att, xy, t_exp, status=f"recovered by prediction after {t_exp[0] - st.t_s:.3f} s")
            tried.append(f"recovery failed ({att.status})")
        if prior is not None:
            if gyro is None:
                st = MotionState(t_frame, prior, self._cov_prior, np.zeros(3), self._var_rate_unknown)
            else:
                st = MotionState(t_frame, prior, self._cov_prior, gyro, self._var_gyro,
                                 rate_meas=self._previous_gyro(t_frame))
            att = self._track(xy, t_exp, st, gyro, t_frame)
            latency += att.latency_ms
            if att.ok:
                return self._accept(att, xy, t_exp, status="recovered from the attitude prior")
            tried.append(f"prior failed ({att.status})")
        if len(t_exp) != 1:
            status = "; ".join(tried + [f"{len(t_exp)}-exposure frame: lost-in-space needs a single exposure"])
            return FrameResult("lost", NO_SAMPLES, 0, len(xy), latency, 0.0, status, len(t_exp))
        res = self._identify(xy, intensity)
        if not res.success:
            status = "; ".join(tried + [f"identification failed: {res.status}"])
            return FrameResult("lost", NO_SAMPLES, 0, len(xy), latency, 0.0, status, 1, identify_latency_ms=res.latency_ms)
        q_body, cov_body = self._camera_to_body(res)
        self._candidate = _Candidate(float(t_exp[0]), q_body, cov_body, int(res.n_matched))
        self._mode = "acquire"
        status = "; ".join(tried + [f"identified {res.n_matched} stars ({res.residual_arcsec:.1f}\"), awaiting confirmation"])
        return FrameResult(
            "acquire", NO_SAMPLES, int(res.n_matched), len(xy), latency, 0.0, status, 1,
            identify_latency_ms=res.latency_ms, residual_arcsec=float(res.residual_arcsec),
        )

    def _acquire(self, xy, intensity, t_exp, gyro, t_frame) -> FrameResult:
        cand = self._candidate
        dt = float(t_exp[0] - cand.t_s)
        if not (0 < dt <= self.coast_max_s):
            self._mode, self._candidate = "lost", None
            return self._lost(xy, intensity, t_exp, gyro, t_frame, None)
        if gyro is not None:
            var_g = self._var_gyro
            st = MotionState(cand.t_s, cand.q_body_to_icrs, cand.cov_theta_rad2, gyro, var_g, rate_meas=self._previous_gyro(t_frame))
            att = self._track(xy, t_exp, st, gyro, t_frame)
            if att.ok:
                return self._accept(att, xy, t_exp, status="acquired: identification confirmed by tracking")
            self._mode, self._candidate = "lost", None
            status = f"acquisition not confirmed ({att.status})"
            if len(t_exp) == 1:  # this frame may start a new acquisition
                fallback = self._lost(xy, intensity, t_exp, gyro, t_frame, None)
                return replace(fallback, status=f"{status}; {fallback.status}")
            return self._result(att, xy, t_exp, status=status)
        if len(t_exp) != 1:
            self._mode, self._candidate = "lost", None
            return FrameResult("lost", NO_SAMPLES, 0, len(xy), 0.0, 0.0, "acquisition without a gyro needs a single-exposure frame", len(t_exp))
        res = self._identify(xy, intensity)
        if not res.success:
            self._mode, self._candidate = "lost", None
            return FrameResult("lost", NO_SAMPLES, 0, len(xy), 0.0, 0.0, f"acquisition: identification failed: {res.status}", 1,
                               identify_latency_ms=res.latency_ms)
        q2, cov2 = self._camera_to_body(res)
        rate = quat_to_rotvec(quat_multiply(quat_conjugate(cand.q_body_to_icrs), q2)) / dt
        if np.linalg.norm(rate) > self.max_rate_rad_s:
            self._candidate = _Candidate(float(t_exp[0]), q2, cov2, int(res.n_matched))
            status = f"identifications disagree ({np.degrees(np.linalg.norm(rate)):.1f} °/s implied): new candidate"
            return FrameResult("acquire", NO_SAMPLES, int(res.n_matched), len(xy), 0.0, 0.0, status, 1,
                               identify_latency_ms=res.latency_ms, residual_arcsec=float(res.residual_arcsec))
        # The mean rate over [t1, t2] is a rate measurement at the midpoint.
        cov_m = (cand.cov_theta_rad2 + cov2) / dt**2
        t_m = cand.t_s + dt / 2
        cov_w = cov_m + self.accel_sigma_rad_s2**2 * (dt / 2) ** 2 * np.eye(3)
        st = MotionState(cand.t_s, cand.q_body_to_icrs, cand.cov_theta_rad2, rate, cov_w, rate_meas=(t_m, rate, cov_m))
        att = self._track(xy, t_exp, st, None, t_frame)
        if att.ok:
            out = self._accept(att, xy, t_exp, status=f"acquired: two identifications agree ({np.degrees(np.linalg.norm(rate)):.2f} °/s)")
            return replace(out, identify_latency_ms=res.latency_ms)
        self._mode, self._candidate = "lost", None
        return self._result(att, xy, t_exp, status=f"acquisition not confirmed ({att.status})")

    # ------------------------------------------------------------------ tracking
    def _cov_alpha_total(self, st: MotionState) -> np.ndarray:
        return st.cov_alpha + self._var_proc

    def _propagation(self, st: MotionState, gyro, t_frame):
        """Rate at ``st.t_s``, acceleration and their covariances used to propagate ``st``."""
        if gyro is None:
            return st.omega_body, st.alpha_body, st.cov_omega, self._cov_alpha_total(st)
        # Gyro readings at this and the previous frame: the rate in between is their interpolation (the
        # slope is the acceleration), with the gyro's error; the unmodelled acceleration change only
        # enters the propagation.
        lever = st.t_s - t_frame
        # (kernels.sensor: gyro + alpha lever and var_g + cov lever², rate differences, in one call each)
        alpha = self._frame_alpha
        if alpha is not None:
            # the gyro's own acceleration over this frame: a torque change at the frame's start is in it
            w, cov_w = sensor_kernels.rate_at(gyro, self._var_gyro, alpha, self._cov_alpha_gyro, lever, lever**2)
            return w, alpha, cov_w, self._cov_alpha_gyro_total
        var_g = self._var_gyro
        var_proc = self._var_proc
        prev = st.rate_meas
        if prev is not None and 0 < t_frame - prev[0] <= self.coast_max_s:
            dt = t_frame - prev[0]
            alpha, cov_a = sensor_kernels.rate_difference(gyro, var_g, prev[1], prev[2], dt, dt**2)
            w, cov_w = sensor_kernels.rate_at(gyro, var_g, alpha, cov_a, lever, lever**2)
            return w, alpha, cov_w, cov_a + var_proc
        # one reading only: extrapolating it to st.t_s also carries the unmodelled acceleration
        alpha, cov_a = st.alpha_body, st.cov_alpha
        cov_a_total = cov_a + var_proc
        w, cov_w = sensor_kernels.rate_at(gyro, var_g, alpha, cov_a_total, lever, lever**2)
        return w, alpha, cov_w, cov_a_total

    def _track(self, xy, t_exp, st: MotionState, gyro, t_frame, extra_cov_alpha=None) -> _Attempt:
        t0 = time.perf_counter()
        omega, alpha, cov_w, cov_a = self._propagation(st, gyro, t_frame)
        if extra_cov_alpha is not None:
            cov_a = cov_a + extra_cov_alpha
        # the largest propagation time of the frame is at one of its ends (t_exp increases); the instants as Python
        # floats (the same values, exactly)
        tl = t_exp.tolist()
        horizon = max(abs(tl[0] - st.t_s), abs(tl[-1] - st.t_s))
        sig_pred = track_kernels.prediction_sigma_px(self._r_cam_to_body, st.cov_theta_rad2, cov_w, cov_a, horizon,
                                                     self._f_px, self._rho_max_px)
        if sig_pred < math.inf:  # prediction_radius_px's rule, without its checks of the tracker's own numbers
            r = min(max(self.radius_k_sigma * math.hypot(self.centroid_sigma_px, sig_pred), self.radius_min_px),
                    self.radius_max_px)
        else:  # its clear error for a diverged state
            r = prediction_radius_px(self.centroid_sigma_px, sig_pred, self.radius_k_sigma, self.radius_min_px,
                                     self.radius_max_px)
        if len(tl) > 1:
            # Spots of one star one exposure apart must be well separated against the prediction error,
            # or the whole frame may match one exposure off (3/4 of the exposure plan's margin).
            wx, wy, _ = np.dot(self._r_body_to_cam, omega).tolist()  # BLAS gemv like @, without the matmul ufunc
            # the smallest exposure spacing on Python floats (the same differences, exactly)
            spacing_px = math.hypot(wx, wy) * min([b - a for a, b in zip(tl, tl[1:])]) * self._f_px
            if spacing_px < 1.5 * self.shift_k_sigma * sig_pred:
                latency = (time.perf_counter() - t0) * 1e3
                return _Attempt(False, f"prediction too uncertain for {len(t_exp)} exposures (spots {spacing_px:.1f} px "
                                       f"apart, prediction σ {sig_pred:.1f} px)", NO_SAMPLES, 0, 0, r, latency)
        t_ref = float(st.t_s)
        if self._frame_model is not None:
            # the state's attitude normalised, prediction's attitudes, cone search, projection, matching, N Wahba,
            # innovation, then the smoothness test and covariance scaling of the solved instants: one compiled call
            (n_pred, n_matched, nis, n_off, values, counts, q_sol,
             cov_sol) = track_kernels.track_frame_from_state(
                st.q_body_to_icrs, omega, alpha, t_exp, t_ref, self._q_cam_to_body, self._half_diag_fov_rad, self._f_px,
                *self.catalog.z_index, self.catalog.vectors, *self._frame_model, xy, float(r), self.matcher == "brute",
                self._r_cam_to_body, self.sigma_rad, self.min_stars_per_instant, self.outlier_k_sigma * self.sigma_rad,
                st.cov_theta_rad2, cov_w, cov_a, self._intensity, self._flux, self.blend_flux_ratio, self.instant_gate,
                self._residual_expected_arcsec, self.scale_by_residuals)
            # its per-instant arrays packed by kind (one boxed array each): rows and the kept instants' row slices;
            # the solved instants' flags (counts[3]) as booleans only when some instant is not solved
            m = len(q_sol)
            rms_all, n_stars, t_s, kept, n_sol = values[0], counts[0], values[1, :m], counts[1, :m], counts[2, :m]
            ok = None
        else:
            (n_pred, n_matched, rms_all, n_stars, ok, nis, n_off, kept, t_s, q_sol, cov_sol,
             n_sol) = self._track_stages(xy, t_exp, st.q_body_to_icrs, t_ref, omega, alpha, float(r), st.cov_theta_rad2,
                                         cov_w, cov_a)
        latency = (time.perf_counter() - t0) * 1e3
        if n_pred == 0:
            return _Attempt(False, "no catalog star predicted on the detector", NO_SAMPLES, 0, 0, r, latency)
        frac = n_matched / n_pred
        n_t = len(t_exp)
        n_ok = n_off + len(kept)  # the solved instants: accept_instants' off ones and kept ones
        if n_ok == n_t:  # all solved: no gather
            skipped = ()
            if n_ok == 1:  # np.dot of one element is its one rounded square
                x = float(rms_all[0])
                rms = math.sqrt(x * x)
            else:
                rms = math.sqrt(float(np.dot(rms_all, rms_all)) / n_ok)
        else:
            if ok is None:
                ok = counts[3] != 0
            skipped = tuple((~ok).nonzero()[0].tolist())
            if n_ok:
                res_ok = rms_all[ok.nonzero()[0]]
                rms = math.sqrt(float(np.dot(res_ok, res_ok)) / n_ok)
            else:
                rms = float("inf")
        # a refusal's fields after its status and (no) samples
        base = (n_matched, n_pred, r, latency, rms, skipped)
        if not n_ok:
            return _Attempt(False, f"no exposure instant with {self.min_stars_per_instant} matched stars ({n_matched}/{n_pred} matched)", NO_SAMPLES, *base)
        if frac < self.min_matched_fraction:
            return _Attempt(False, f"matched {n_matched}/{n_pred} predicted spots ({100 * frac:.0f} % < {100 * self.min_matched_fraction:.0f} %)", NO_SAMPLES, *base)
        if rms > self.max_residual_arcsec:
            return _Attempt(False, f"residual {rms:.1f}\" > {self.max_residual_arcsec:.1f}\"", NO_SAMPLES, *base)
        # A frame matched one exposure off leaves the first (prediction lagging) or last (leading) instant
        # without stars while the others are full; a state already off by one exposure agrees with its own
        # prediction, so only this test sees it.
        if n_t >= 2:
            n_st = n_stars.tolist()
            ordered = sorted(n_st)
            half = len(ordered) // 2
            median = ordered[half] if len(ordered) % 2 else 0.5 * (ordered[half - 1] + ordered[half])
            if min(n_st[0], n_st[-1]) < 0.5 * median:
                return _Attempt(False, f"first/last instant nearly empty ({n_st[0]}, {n_st[-1]} stars, median "
                                       f"{median:.0f}): matched one exposure off", NO_SAMPLES, *base)
        # Innovation: solved vs predicted attitude at each solved instant.
        if nis > self.innovation_gate:
            return _Attempt(False, f"solution off the prediction (innovation χ² {nis:.0f} > {self.innovation_gate:.0f})", NO_SAMPLES, *base)
        # Smoothness: an instant matched one exposure off (its spots taken for the neighbour's) sits on the trajectory
        # at the wrong time. Neither the residual nor the mean innovation over many instants sees one such instant;
        # its attitude against a polynomial through the other instants does (kernels.sensor.smooth_instants). Then
        # residuals larger than the centroid model claims (streaks in stray light, a rate beyond the model): the
        # instant's covariance grows by its a-posteriori variance factor, never shrinks (2 n - 3 degrees of freedom).
        # Both ran with the frame (kernels.sensor.accept_instants, compiled), on the frame's own copies: no sample
        # shares memory with another or with the tracker.
        if n_off:
            if 3 * n_off > n_ok:
                return _Attempt(False, f"{n_off}/{n_ok} instants off a smooth motion (matched an exposure off)",
                                NO_SAMPLES, *base)
            n_ok = len(kept)
            skipped = tuple(sorted(set(range(n_t)) - set(kept.tolist())))
        # the kernel's fresh arrays (t_s and n_sol rows of its packed outputs), no object per sample
        samples = build_checked(AttitudeSamples, {"t_s": t_s, "q_body_to_icrs": q_sol, "covariance_rad2": cov_sol,
                                                  "n_stars": n_sol})
        new_state = self._update_state(st, t_s, q_sol, cov_sol, gyro, t_frame)
        status = f"tracking {n_ok}/{n_t} instants, {n_matched}/{n_pred} spots, r = {r:.1f} px"
        if skipped:
            status += f", skipped instants {list(skipped)}"
        return _Attempt(True, status, samples, n_matched, n_pred, r, latency, rms, skipped, new_state)

    def _track_stages(self, xy, t_exp, q_state, t_ref, omega, alpha, r, cov_theta, cov_w, cov_a):
        """The compiled frame's results through the public stages (a camera with its own projection, cKDTree)."""
        # quat_normalize's kernel on the state's one row (its float64 copy: no wrapper for one quaternion)
        q0 = rk.normalize_rows(np.ascontiguousarray(q_state, dtype=np.float64).reshape(1, 4))[0]
        pred = predict_star_positions(self.camera, self.catalog, q0, t_exp, t_ref, omega, alpha, r, validate=False)
        idx = match_stars(pred.xy, xy, r, self.matcher, validate=False)
        n_pred = int(pred.on_detector.sum())
        inst = attitudes_per_instant(xy, idx, pred, self.camera, self.catalog, self.centroid_sigma_px,
                                     self.min_stars_per_instant, self.outlier_k_sigma, validate=False)
        n_matched = int(np.count_nonzero(inst.assignment >= 0))
        sel = np.flatnonzero(inst.ok)
        nis = sensor_kernels.innovation_chi2_mean(pred.q_body_to_icrs[sel], inst.q_body_to_icrs[sel],
                                                  inst.covariance_rad2[sel], t_exp[sel] - t_ref, cov_theta, cov_w,
                                                  cov_a)
        accepted = sensor_kernels.accept_instants(sel, t_exp, pred.q_body_to_icrs, inst.q_body_to_icrs,
                                                  inst.covariance_rad2, inst.residual_rms_arcsec, inst.n_stars,
                                                  self.instant_gate, self._residual_expected_arcsec,
                                                  self.scale_by_residuals)
        return (n_pred, n_matched, inst.residual_rms_arcsec, inst.n_stars, inst.ok, nis) + accepted

    def _update_state(self, st: MotionState, t, q, covs, gyro, t_frame) -> MotionState:
        """New motion state from a tracked frame's solved instants ``t`` (n,), ``q`` (n, 4), ``covs`` (n, 3, 3)
        (see the module docstring)."""
        # copies: the state must not share memory with the samples handed to the caller
        t_ref, q_ref, cov_ref = float(t[-1]), q[-1].copy(), covs[-1].copy()
        # A rate measurement (time, rate, covariance).
        if gyro is not None:
            meas = (t_frame, gyro, self._var_gyro)
        elif len(t) >= 3:
            # Least-squares line θ(τ) = c + ω τ through the rotation vectors relative to the last instant:
            # its slope is the rate at the mean time.
            theta = rk.quat_relative_rotvec(q_ref[None], q)
            tau = t - t_ref
            sxx = float(np.sum((tau - tau.mean()) ** 2))
            w_fit = ((tau - tau.mean()) @ (theta - theta.mean(axis=0))) / sxx
            meas = (float(t.mean()), w_fit, covs.mean(axis=0) / sxx)
        elif t_ref > st.t_s:
            dt = t_ref - st.t_s
            rotvec = rk.quat_relative_rotvec(np.asarray(st.q_body_to_icrs, dtype=np.float64), q_ref)
            meas = (st.t_s + dt / 2, rotvec / dt, (st.cov_theta_rad2 + cov_ref) / dt**2)
        else:
            meas = None
        if meas is None:
            omega, alpha, cov_w, _ = self._propagation(st, None, t_frame)
            lever = t_ref - st.t_s
            return replace(st, t_s=t_ref, q_body_to_icrs=q_ref, cov_theta_rad2=cov_ref, omega_body=omega + alpha * lever)
        t_m, w_m, cov_m = meas
        prev = st.rate_meas
        alpha_known = False
        lever = t_ref - t_m
        if prev is not None and 0.5 * self._frame_interval_s <= t_m - prev[0] <= self.coast_max_s:
            dtm = t_m - prev[0]
            # the acceleration from the two rates, then the rate carried to t_ref: one compiled call
            alpha, cov_alpha, omega, cov_w = sensor_kernels.rate_difference_at(
                w_m, cov_m, prev[1], prev[2], dtm, dtm**2, self._var_proc, lever, lever**2)
            alpha_known = True
        else:
            if prev is not None and 0 <= t_m - prev[0] < 0.5 * self._frame_interval_s:
                # Too close to the previous measurement to difference: keep the earlier one and its estimate.
                alpha, cov_alpha, alpha_known, meas = st.alpha_body, st.cov_alpha, st.alpha_known, prev
            else:
                alpha, cov_alpha = np.zeros(3), np.zeros((3, 3))
            omega, cov_w = sensor_kernels.rate_at(w_m, cov_m, alpha, cov_alpha + self._var_proc, lever, lever**2)
        return build_checked(MotionState, {"t_s": t_ref, "q_body_to_icrs": q_ref, "cov_theta_rad2": cov_ref,
                                    "omega_body": omega, "cov_omega": cov_w, "alpha_body": alpha,
                                    "cov_alpha": cov_alpha, "rate_meas": meas, "alpha_known": alpha_known})

    # ------------------------------------------------------------------ helpers
    def _identify(self, xy, intensity):
        if len(xy) < 3:
            return IdentificationResult(False, np.full(len(xy), -1), np.array([1.0, 0, 0, 0]), 0, np.inf, 0.0,
                                        "fewer than 3 detections", self.identify_method)
        return identify(xy, self.camera, self.catalog, method=self.identify_method, intensities=intensity,
                        **self.identify_options)

    def _camera_to_body(self, res):
        # the kernel layer on the identification's unit float64 attitude and the mounting's conjugate built once: the
        # public functions' values without their checks
        q_body = rk.quat_normalize(rk.quat_multiply(res.q_cam_to_icrs, self._q_body_to_cam))
        cov_cam = res.covariance_rad2
        if cov_cam is None or not np.all(np.isfinite(cov_cam)):
            s = max(res.residual_arcsec, 1.0) / RAD_TO_ARCSEC
            cov_cam = s**2 * np.eye(3)
        r = self.camera.r_cam_to_body
        return q_body, r @ cov_cam @ r.T

    def _accept(self, att: _Attempt, xy, t_exp, status=None) -> FrameResult:
        self._state = att.state
        self._candidate = None
        self._mode = "track"
        return self._result(att, xy, t_exp, status=status, samples=att.samples)

    def _result(self, att: _Attempt, xy, t_exp, status=None, samples=None) -> FrameResult:
        text = att.status if status is None else (status if not att.ok else f"{status}; {att.status}")
        samples = NO_SAMPLES if samples is None else samples  # the attempt's own arrays (nothing else holds them)
        return build_checked(FrameResult, {
            "mode": self._mode, "attitude_samples": samples, "n_matched": att.n_matched, "n_detections": len(xy),
            "matching_latency_ms": att.latency_ms, "update_rate_hz": len(samples) / self._dt_frame, "status": text,
            "n_exposures": len(t_exp), "n_predicted": att.n_predicted, "radius_px": att.radius_px,
            "identify_latency_ms": 0.0, "residual_arcsec": att.residual_arcsec, "skipped_instants": att.skipped})
