"""Scene truth: which catalog stars fall where on the detector, at which instants of a camera frame.

A frame of period ``T`` holds ``N`` exposures of length ``τ`` (the multi-exposure imaging approach,
MEIA, of paper 000 and its reference [22]): exposure ``i`` starts at ``t0 + offset + i Δt``. Each
exposure is stamped with its **mid instant**, and the attitude solved from the spots of exposure ``i``
carries that timestamp (docs/design.md, Conventions: Time). ``N = 1`` is the ordinary single-exposure frame.

Choosing N from the angular rate (:func:`choose_n_exposures`)
--------------------------------------------------------------
With the exposures spread evenly over the frame (``Δt = T / N``) a star whose image moves at
``v`` px/s leaves a streak of length ``v τ`` per exposure, and the gap between the end of one streak
and the start of the next is ``v (T/N - τ)``. The **no-overlap rule** asks that gap to be at least
``k σ`` (default ``k = 6``: the 3σ halos of consecutive spots do not touch)::

    v (T/N - τ) >= k σ    <=>    N <= v T / (v τ + k σ)

so ``N = clip(floor(v T / (v τ + k σ)), 1, n_max)``, which is non-decreasing in the rate. ``v`` is the
slowest image motion over the detector, so the rule holds for every star: for a scalar rate (a
cross-boresight slew, the turntable experiment of paper 000) ``v = f ω`` with ``f`` in pixels, the
image speed at the principal point; for an angular-velocity vector it is the minimum of the exact
pinhole motion field over a grid of detector points (a roll about the boresight has a still point,
so large roll rates push N down). Paper 000's camera (f = 5807 px) at 20°/s with 10 Hz frames,
τ = 1 ms and σ = 1.2 px gives ``v = 2027 px/s`` and ``N = floor(21.97) = 21``: a 210 Hz update rate,
the figure of paper 000 §1 (and §5: N goes from 1 to 21 as the rate goes from 0 to 20°/s).

The module is over 600 lines because the exposure plan, the bright bodies and the scene are the one
record of a frame's truth that every later room reads, and they are kept together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from startracker.catalog import StarCatalog
from startracker.optics import Camera
from startracker.validation import as_float_array, build_checked, check_int, check_positive
from startracker.kernels import scene as sk

__all__ = [
    "ExposurePlan",
    "choose_n_exposures",
    "min_image_speed_px_s",
    "image_flow_matrices",
    "BrightBody",
    "BrightBodyView",
    "Scene",
    "compute_scene",
    "compute_scenes",
    "scene_from_tracks",
]


# --------------------------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class ExposurePlan:
    """The exposures inside one camera frame.

    Parameters
    ----------
    n_exposures : int
        N >= 1 exposures per frame (1 = single exposure).
    exposure_s : float
        Length τ of each exposure, s (> 0).
    spacing_s : float, optional
        Δt between the starts of consecutive exposures, s; at least ``exposure_s`` when N > 1.
        Default ``frame_period_s / n_exposures`` (evenly spread: the attitude stream is uniform in time
        across frames, at ``N / frame_period_s`` Hz).
    frame_period_s : float
        Frame period T, s (> 0). 0.1 s is the 10 Hz of paper 000.
    start_offset_s : float
        Delay from the frame start to the start of the first exposure, s (>= 0).

    Raises
    ------
    ValueError
        N < 1, non-positive or non-finite times, overlapping exposures, or exposures that do not fit in
        the frame (``start_offset + (N-1) Δt + τ > T``).
    """

    n_exposures: int = 1
    exposure_s: float = 0.1
    spacing_s: float | None = None
    frame_period_s: float = 0.1
    start_offset_s: float = 0.0

    def __post_init__(self):
        n = check_int(self.n_exposures, "n_exposures", lo=1)
        tau = check_positive(self.exposure_s, "exposure_s")
        period = check_positive(self.frame_period_s, "frame_period_s")
        offset = check_positive(self.start_offset_s, "start_offset_s", allow_zero=True)
        spacing = period / n if self.spacing_s is None else check_positive(self.spacing_s, "spacing_s", allow_zero=True)
        if n > 1 and spacing < tau * (1 - 1e-12):
            raise ValueError(f"spacing_s ({spacing}) must be >= exposure_s ({tau}) so that exposures do not overlap")
        span = offset + (n - 1) * spacing + tau
        if span > period * (1 + 1e-9):
            raise ValueError(
                f"exposures do not fit in the frame: start_offset_s + (n_exposures-1)*spacing_s + exposure_s = {span:.6g} s"
                f" > frame_period_s = {period:.6g} s"
            )
        object.__setattr__(self, "n_exposures", n)
        object.__setattr__(self, "exposure_s", tau)
        object.__setattr__(self, "spacing_s", float(spacing))
        object.__setattr__(self, "frame_period_s", period)
        object.__setattr__(self, "start_offset_s", offset)
        # ``spacing · arange(N)``, once per plan (read-only; not a field: equality and hashing ignore it)
        steps = float(spacing) * np.arange(n)
        steps.setflags(write=False)
        object.__setattr__(self, "_start_steps", steps)

    # ------------------------------------------------------------------ timing
    def exposure_start_times(self, t_frame_start: float) -> np.ndarray:
        """Start instant of each exposure, s, shape (N,)."""
        tt = type(t_frame_start)
        if (tt is float or tt is np.float64) and math.isfinite(t_frame_start):  # the per-frame caller's float
            t0 = t_frame_start
        else:
            t0 = float(as_float_array(t_frame_start, "t_frame_start", ndim=0))
        return t0 + self.start_offset_s + self._start_steps

    def exposure_mid_times(self, t_frame_start: float) -> np.ndarray:
        """Timestamp of each exposure (its mid instant), s, shape (N,)."""
        t = self.exposure_start_times(t_frame_start)
        t += 0.5 * self.exposure_s  # in place: the array is this call's own
        return t

    def exposure_end_times(self, t_frame_start: float) -> np.ndarray:
        """End instant of each exposure, s, shape (N,)."""
        return self.exposure_start_times(t_frame_start) + self.exposure_s

    @property
    def integration_window_s(self) -> float:
        """From the start of the first exposure to the end of the last, s (the detector integrates dark
        current and cosmic rays over this window; light only during the exposures)."""
        return (self.n_exposures - 1) * self.spacing_s + self.exposure_s

    @property
    def total_exposure_s(self) -> float:
        """Summed open time N τ, s (sky and stray light accumulate over it)."""
        return self.n_exposures * self.exposure_s

    @property
    def update_rate_hz(self) -> float:
        """Attitude updates per second, N / T."""
        return self.n_exposures / self.frame_period_s

    # ------------------------------------------------------------------ adaptive plan
    @classmethod
    def for_rate(
        cls,
        rate_rad_s,
        camera: Camera,
        frame_period_s: float = 0.1,
        exposure_s: float = 1.0e-3,
        psf_sigma_px: float = 1.2,
        n_max: int = 21,
        min_gap_sigma: float = 6.0,
    ) -> "ExposurePlan":
        """The MEIA plan for an angular rate: N from :func:`choose_n_exposures`, spread evenly.

        Parameters are those of :func:`choose_n_exposures`. Returns an ``ExposurePlan`` with
        ``spacing_s = frame_period_s / N`` and no start offset.
        """
        n = choose_n_exposures(rate_rad_s, camera, frame_period_s, exposure_s, psf_sigma_px, n_max, min_gap_sigma)
        return cls(n_exposures=n, exposure_s=exposure_s, spacing_s=frame_period_s / n, frame_period_s=frame_period_s)


def _flow_matrices(camera: Camera, n_grid: int = 7) -> np.ndarray:
    """Pinhole motion-field matrices J (P, 2, 3) at a grid of detector points: ``xy_dot = J @ ω_cam``.

    For a star direction u fixed in inertial space, the camera-frame direction obeys du/dt = -ω × u;
    differentiating the pinhole ``x = f X/Z, y = f Y/Z`` (f in px, x, y from the principal point)
    gives  ẋ = (x y / f) ω_x - (f + x²/f) ω_y + y ω_z,  ẏ = (f + y²/f) ω_x - (x y / f) ω_y - x ω_z.
    """
    f = camera.focal_length_px
    w, h = camera.resolution
    cx, cy = camera.principal_point
    xs = np.linspace(-0.5, w - 0.5, n_grid) - cx
    ys = np.linspace(-0.5, h - 0.5, n_grid) - cy
    x, y = (a.ravel() for a in np.meshgrid(xs, ys))
    j = np.empty((len(x), 2, 3))
    j[:, 0, 0] = x * y / f
    j[:, 0, 1] = -(f + x * x / f)
    j[:, 0, 2] = y
    j[:, 1, 0] = f + y * y / f
    j[:, 1, 1] = -x * y / f
    j[:, 1, 2] = -x
    return j


_FLOW_CACHE: dict = {}


def image_flow_matrices(camera: Camera) -> np.ndarray:
    """The pinhole motion field of ``camera`` at a 7×7 grid of detector points: matrices J (49, 2, 3), px per rad,
    with ``xy_dot = J @ ω_cam`` (ω in the camera frame, rad/s). Computed once per (frozen) camera object; the array
    is read-only and shared (:func:`startracker.kernels.scene.min_image_speed` takes it).

    Parameters
    ----------
    camera : Camera
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a startracker.optics.Camera, got {type(camera).__name__}")
    hit = _FLOW_CACHE.get(id(camera))
    if hit is not None and hit[0] is camera:
        return hit[1]
    j = _flow_matrices(camera)
    j.setflags(write=False)
    if len(_FLOW_CACHE) > 64:
        _FLOW_CACHE.clear()
    _FLOW_CACHE[id(camera)] = (camera, j)
    return j


def min_image_speed_px_s(rate_rad_s, camera: Camera) -> float:
    """Slowest star-image speed over the detector, px/s.

    Parameters
    ----------
    rate_rad_s : float or array_like, shape (3,)
        A scalar is the magnitude of a cross-boresight rate (image speed ``f ω`` at the principal point,
        the minimum over the detector for such a rotation). A 3-vector is the body-frame angular
        velocity, rad/s: it is rotated into the camera frame with ``camera.q_cam_to_body`` and the
        exact pinhole motion field is minimised over a 7×7 grid of detector points.
    camera : Camera
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a startracker.optics.Camera, got {type(camera).__name__}")
    w = as_float_array(rate_rad_s, "rate_rad_s")
    if w.ndim == 0:
        if w < 0:
            raise ValueError(f"rate_rad_s must be >= 0 when given as a magnitude, got {float(w)}")
        return float(camera.focal_length_px * w)
    if w.shape != (3,):
        raise ValueError(f"rate_rad_s must be a scalar or a (3,) body-frame vector, got shape {w.shape}")
    return float(sk.min_image_speed(image_flow_matrices(camera), camera.r_cam_to_body, np.ascontiguousarray(w)))


def choose_n_exposures(
    rate_rad_s,
    camera: Camera,
    frame_period_s: float = 0.1,
    exposure_s: float = 1.0e-3,
    psf_sigma_px: float = 1.2,
    n_max: int = 21,
    min_gap_sigma: float = 6.0,
) -> int:
    """Number of exposures per frame for an angular rate (the no-overlap rule of the module docstring).

    ``N = clip(floor(v T / (v τ + k σ)), 1, n_max)`` with ``v`` = :func:`min_image_speed_px_s`:
    the largest N whose evenly spread exposures (Δt = T/N) leave a gap of at least ``k σ`` pixels between
    the end of one streak of a star and the start of the next. Non-decreasing in the rate.

    Parameters
    ----------
    rate_rad_s : float or array_like, shape (3,)
        Cross-boresight rate magnitude (rad/s, >= 0) or body-frame angular velocity vector (rad/s).
    camera : Camera
    frame_period_s : float
        Frame period T, s.
    exposure_s : float
        Exposure length τ, s.
    psf_sigma_px : float
        PSF standard deviation σ, px.
    n_max : int
        Upper bound on N (>= 1); 21 is paper 000's maximum (210 Hz at 10 Hz frames).
    min_gap_sigma : float
        k, the required gap in units of σ (> 0).

    Returns
    -------
    int
        N in [1, n_max].
    """
    period = check_positive(frame_period_s, "frame_period_s")
    tau = check_positive(exposure_s, "exposure_s")
    sigma = check_positive(psf_sigma_px, "psf_sigma_px")
    k = check_positive(min_gap_sigma, "min_gap_sigma")
    n_max = check_int(n_max, "n_max", lo=1)
    if tau > period:
        raise ValueError(f"exposure_s ({tau}) must not exceed frame_period_s ({period})")
    v = min_image_speed_px_s(rate_rad_s, camera)
    return int(sk.no_overlap_exposures(v, period, tau, sigma, k, n_max))


# --------------------------------------------------------------------------------------------- bodies
@dataclass(frozen=True)
class BrightBody:
    """A bright body off the field of view (stray-light source).

    Parameters
    ----------
    name : {"sun", "moon", "earth"}
        Selects the baffle response in ``SensorModel.stray_light``.
    direction_world : array_like, shape (3,)
        Direction from the spacecraft to the body (for the Earth: to the nearest limb point), ICRS.
    """

    name: str
    direction_world: tuple[float, float, float]

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise TypeError("name must be a string")
        d = as_float_array(self.direction_world, "direction_world", last_dim=3, ndim=1)
        n = np.linalg.norm(d)
        if n == 0:
            raise ValueError("direction_world must be non-zero")
        object.__setattr__(self, "direction_world", tuple(float(v) for v in d / n))


@dataclass(frozen=True)
class BrightBodyView:
    """A bright body as seen by the camera at each exposure mid-time.

    Attributes
    ----------
    name : str
    angle_rad : ndarray, shape (N,)
        Angle between the boresight and the body, rad.
    direction_cam : ndarray, shape (N, 3)
        Unit direction to the body in the camera frame.
    """

    name: str
    angle_rad: np.ndarray
    direction_cam: np.ndarray


# --------------------------------------------------------------------------------------------- scene
@dataclass(frozen=True, eq=False)
class Scene:
    """Truth of one camera frame: the stars on the detector at every exposure instant.

    Attributes
    ----------
    camera : Camera
    plan : ExposurePlan
    t_frame_start : float
        s.
    times : ndarray, shape (N,)
        Exposure timestamps (mid instants), s.
    path_times : ndarray, shape (N, S)
        Instants sampled evenly over each exposure, start to end inclusive (S odd >= 3), s.
    star_index : ndarray of int, shape (M,)
        Rows of the catalog.
    hip, vmag, bv : ndarray, shape (M,)
        Hipparcos number, V magnitude, B−V of each scene star.
    xy_path : ndarray, shape (N, S, M, 2)
        Pixel position (col, row) of each star at each ``path_times`` instant; the image of star m during
        exposure i is the polyline ``xy_path[i, :, m]`` (smear).
    visible : ndarray of bool, shape (N, M)
        The star's position at the exposure mid-time lies on the detector.
    q_body_to_icrs : ndarray, shape (N, 4)
        Attitude at the exposure mid-times.
    q_cam_to_icrs : ndarray, shape (N, 4)
        Camera attitude at the exposure mid-times (``q_body_to_icrs ⊗ q_cam_to_body``).
    bright_bodies : tuple of BrightBodyView
    """

    camera: Camera
    plan: ExposurePlan
    t_frame_start: float
    times: np.ndarray
    path_times: np.ndarray
    star_index: np.ndarray
    hip: np.ndarray
    vmag: np.ndarray
    bv: np.ndarray
    xy_path: np.ndarray
    visible: np.ndarray
    q_body_to_icrs: np.ndarray
    q_cam_to_icrs: np.ndarray
    bright_bodies: tuple = field(default=())

    @property
    def n_exposures(self) -> int:
        return self.plan.n_exposures

    @property
    def n_stars(self) -> int:
        return len(self.star_index)

    @property
    def xy(self) -> np.ndarray:
        """Positions at the exposure mid-times, shape (N, M, 2), px."""
        return self.xy_path[:, self.xy_path.shape[1] // 2]

    @property
    def xy_start(self) -> np.ndarray:
        """Positions at the exposure starts, shape (N, M, 2), px."""
        return self.xy_path[:, 0]

    @property
    def xy_end(self) -> np.ndarray:
        """Positions at the exposure ends, shape (N, M, 2), px."""
        return self.xy_path[:, -1]

    @property
    def xy_mean(self) -> np.ndarray:
        """Time-averaged position over each exposure (where the light's centre of mass falls), (N, M, 2).

        Trapezoid rule over the path samples; equal to ``xy`` for motion uniform in time along a line.
        """
        p = self.xy_path
        return (p[:, 1:-1].sum(axis=1) + 0.5 * (p[:, 0] + p[:, -1])) / (p.shape[1] - 1)

    @property
    def smear_px(self) -> np.ndarray:
        """Length of each streak (polyline length), shape (N, M), px."""
        return np.linalg.norm(np.diff(self.xy_path, axis=1), axis=-1).sum(axis=1)

    @property
    def velocity_px_s(self) -> np.ndarray:
        """Mean image velocity during each exposure, shape (N, M, 2), px/s."""
        return (self.xy_end - self.xy_start) / self.plan.exposure_s


AttitudeLike = Callable[[np.ndarray], np.ndarray] | tuple


def _evaluate_attitude(attitude, t: np.ndarray, validate: bool) -> np.ndarray:
    """Unit ``q_body_to_icrs`` (len(t), 4) at the instants ``t``, from a callable or a sampled history."""
    if callable(attitude):
        q = attitude(t)
        try:
            q = np.asarray(q, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("attitude(t) must return a numeric array of shape (len(t), 4)") from None
        if q.shape != (len(t), 4):
            raise ValueError(f"attitude(t) must return shape ({len(t)}, 4) (w, x, y, z), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError("attitude contains NaN or inf")
        n = np.sqrt(np.add.reduce(q * q, axis=1))[:, None]
        if np.any(n < 1e-9):
            raise ValueError("attitude contains a zero quaternion")
        return q / n
    if isinstance(attitude, (tuple, list)) and len(attitude) == 2:
        t_s, q_s = attitude
        if validate:  # the checks of startracker.rotations.quat_interpolate
            t_s = np.ascontiguousarray(as_float_array(t_s, "t_samples", ndim=1))
            q_s = np.ascontiguousarray(as_float_array(q_s, "q_samples", last_dim=4, ndim=2))
            if len(t_s) != len(q_s) or len(t_s) < 2:
                raise ValueError("t_samples and q_samples must have the same length >= 2")
            if np.any(np.diff(t_s) <= 0):
                raise ValueError("t_samples must be strictly increasing")
            if t[0] < t_s[0] - 1e-12 or t[-1] > t_s[-1] + 1e-12:
                raise ValueError(f"the exposures [{t[0]}, {t[-1]}] must lie in the attitude history [{t_s[0]}, {t_s[-1]}]")
            if np.any(np.all(q_s == 0.0, axis=-1)):
                raise ValueError("q_samples contains a zero quaternion, which is not a rotation")
        return sk.interpolate_attitudes(t_s, q_s, t)
    raise TypeError("attitude must be a callable t -> q_body_to_icrs (len(t), 4) or a tuple (t_samples, q_samples)")


_CAMERA_CACHE: dict = {}


def _camera_constants(camera: Camera):
    """The constants of a (frozen) camera a scene uses, computed once per camera object: the angle from the
    boresight to the farthest detector corner (unprojected, so distortion included, rad), the mounting as a
    quaternion and a matrix, and the in-plane rotation ``(cos θ, sin θ)`` of the kernels' pinhole (``(1, 0)`` for a
    plain camera) or None for a camera class that projects by a model of its own."""
    key = id(camera)
    hit = _CAMERA_CACHE.get(key)
    if hit is not None and hit[0] is camera:
        return hit[1]
    w_px, h_px = camera.resolution
    corners = np.array([[-0.5, -0.5], [w_px - 0.5, -0.5], [-0.5, h_px - 0.5], [w_px - 0.5, h_px - 0.5]])
    v_corner = camera.unproject(corners)
    half_diag = float(np.arccos(np.clip(v_corner[:, 2].min(), -1.0, 1.0)))
    q_cb = np.array(camera.q_cam_to_body, dtype=np.float64)
    r_cb = np.ascontiguousarray(camera.r_cam_to_body, dtype=np.float64)
    # the kernels' pinhole, on a detector rotated in its plane for a 3CMOS channel camera (a float rotation_rad, as
    # startracker.track.camera_projection_model reads it); None: a camera class with a projection of its own
    cls = type(camera)
    rot = getattr(camera, "rotation_rad", None)
    if cls.project is Camera.project:
        pinhole = (1.0, 0.0)
    elif isinstance(rot, float) and cls.unproject is not Camera.unproject:
        pinhole = (1.0, 0.0) if rot == 0.0 else (math.cos(rot), math.sin(rot))
    else:
        pinhole = None
    consts = (half_diag, q_cb, r_cb, pinhole, float(camera.focal_length_mm), float(camera.distortion_k1_per_mm2),
              float(camera.pixel_size_mm), float(camera.principal_point[0]), float(camera.principal_point[1]),
              int(w_px), int(h_px), float(camera.focal_length_px))
    if len(_CAMERA_CACHE) > 64:
        _CAMERA_CACHE.clear()
    _CAMERA_CACHE[key] = (camera, consts)
    return consts


_UNIT_PATH = {}
_NO_ROTATIONS = np.empty((0, 3, 3))  # scene_frame's rotations output for a frame without bright bodies (never written)


def _path_fractions(s: int) -> np.ndarray:
    """``linspace(0, 1, s)``, read-only, once per S."""
    f = _UNIT_PATH.get(s)
    if f is None:
        f = np.linspace(0.0, 1.0, s)
        f.setflags(write=False)
        _UNIT_PATH[s] = f
    return f


_PLAN_OFFSETS: dict = {}


def _plan_offsets(plan: ExposurePlan, s: int):
    """Per (frozen) plan and S, once: ``spacing · arange(N)``, ``τ · linspace(0, 1, S)`` (the path instants are
    ``(t0 + offset) + the first + the second``) and the rows of the mid instants, ``arange(N) S + S // 2``."""
    key = (plan, s)
    hit = _PLAN_OFFSETS.get(key)
    if hit is not None:
        return hit
    n = plan.n_exposures
    hit = (plan.spacing_s * np.arange(n), plan.exposure_s * _path_fractions(s), np.arange(n) * s + s // 2)
    for a in hit:
        a.setflags(write=False)
    if len(_PLAN_OFFSETS) > 256:
        _PLAN_OFFSETS.clear()
    _PLAN_OFFSETS[key] = hit
    return hit


def compute_scene(
    camera: Camera,
    catalog: StarCatalog,
    attitude: AttitudeLike,
    plan: ExposurePlan,
    t_frame_start: float = 0.0,
    *,
    bright_bodies: Sequence[BrightBody] = (),
    n_path_samples: int = 3,
    edge_margin_px: float = 6.0,
    validate: bool = True,
) -> Scene:
    """Where every catalog star falls on the detector during each exposure of a frame.

    Parameters
    ----------
    camera : Camera
        Its ``q_cam_to_body`` is the mounting.
    catalog : StarCatalog
        Stars to image (e.g. ``load_catalog(6.0)``).
    attitude : callable or tuple
        ``attitude(t)`` with ``t`` an array of s returning ``q_body_to_icrs`` (len(t), 4) (w, x, y, z),
        or a tuple ``(t_samples (S,), q_samples (S, 4))`` interpolated as
        :func:`startracker.rotations.quat_interpolate` does (scipy's Slerp; must cover the exposures).
    plan : ExposurePlan
    t_frame_start : float
        Frame start time, s.
    bright_bodies : sequence of BrightBody
        Stray-light sources (sun, moon, Earth limb).
    n_path_samples : int
        Odd number S >= 3 of instants sampled over each exposure for the smear path.
    edge_margin_px : float
        Stars whose path comes within this margin of the detector are kept (their light reaches the
        edge pixels); ``visible`` still requires the mid-time position to be on the detector.
    validate : bool
        False skips the argument checks, for a per-frame caller that passes the types above, a float
        ``t_frame_start``, an int S and a float margin, and a sampled history of float64 C-contiguous arrays
        (strictly increasing times covering the exposures, non-zero quaternions). A callable attitude is
        always checked.

    Returns
    -------
    Scene

    Notes
    -----
    Candidates come from one ``catalog.cone_search`` around the mean boresight, with a radius that covers
    the detector's corners (unprojected, so distortion is included), the boresight's motion over the
    frame and the margin; only candidates are projected, at the ``N × S`` path instants
    (:mod:`startracker.kernels.scene`; for a pinhole camera and a sampled history with ``validate=False``, the
    per-frame path, all of it in one compiled call, :func:`startracker.kernels.scene.scene_frame`). A detector rotated
    in its plane (a float ``rotation_rad``: :class:`startracker.color.ChannelCamera`) is the same compiled pinhole
    followed by the rotation; a camera class with a projection of its own has its ``project`` applied to the rotated
    directions.
    """
    if validate and not isinstance(camera, Camera):
        raise TypeError(f"camera must be a startracker.optics.Camera, got {type(camera).__name__}")
    return compute_scenes((camera,), catalog, attitude, plan, t_frame_start, bright_bodies=bright_bodies,
                          n_path_samples=n_path_samples, edge_margin_px=edge_margin_px, validate=validate)[0]


def compute_scenes(cameras: Sequence[Camera], catalog: StarCatalog, attitude: AttitudeLike, plan: ExposurePlan,
                   t_frame_start: float = 0.0, *, bright_bodies: Sequence[BrightBody] = (), n_path_samples: int = 3,
                   edge_margin_px: float = 6.0, validate: bool = True) -> tuple[Scene, ...]:
    """:func:`compute_scene` for several cameras that image one frame together (a 3CMOS head's three channels).

    The same scenes as one :func:`compute_scene` call per camera, with the frame's instants (and a callable
    attitude's values) computed once: the scenes share their ``times`` and ``path_times`` arrays.

    Parameters
    ----------
    cameras : sequence of Camera
    catalog, attitude, plan, t_frame_start, bright_bodies, n_path_samples, edge_margin_px, validate
        As :func:`compute_scene` (``validate=False`` also takes ``cameras`` as a tuple of cameras).

    Returns
    -------
    tuple of Scene
        One per camera, in order.
    """
    if validate:
        cameras = tuple(cameras)
        for i, camera in enumerate(cameras):
            if not isinstance(camera, Camera):
                raise TypeError(f"cameras[{i}] must be a startracker.optics.Camera, got {type(camera).__name__}")
        if not isinstance(catalog, StarCatalog):
            raise TypeError(f"catalog must be a StarCatalog, got {type(catalog).__name__}")
        if not isinstance(plan, ExposurePlan):
            raise TypeError(f"plan must be an ExposurePlan, got {type(plan).__name__}")
        t0 = float(as_float_array(t_frame_start, "t_frame_start", ndim=0))
        s = check_int(n_path_samples, "n_path_samples", lo=3)
        if s % 2 == 0:
            raise ValueError(f"n_path_samples must be odd (the middle sample is the timestamp), got {s}")
        margin = check_positive(edge_margin_px, "edge_margin_px", allow_zero=True)
        bodies = tuple(bright_bodies)
        for b in bodies:
            if not isinstance(b, BrightBody):
                raise TypeError("bright_bodies must contain BrightBody objects")
    else:
        t0, s, margin, bodies = t_frame_start, n_path_samples, edge_margin_px, bright_bodies

    n = plan.n_exposures
    start_steps, path_steps, mid_rows = _plan_offsets(plan, s)
    t_first = t0 + plan.start_offset_s
    sampled = not validate and isinstance(attitude, tuple) and len(attitude) == 2
    constants = [_camera_constants(camera) for camera in cameras]
    # the path instants, exposure-major, then the mid ones, in one buffer; scene_frame (the per-frame path: sampled
    # history, pinhole cameras) fills it in its call, otherwise numpy does (the same sums)
    instants = np.empty(n * s + n)
    path_times = instants[:n * s].reshape(n, s)
    times = instants[n * s:]
    if not (sampled and all(c[3] is not None for c in constants)):
        np.add.outer(t_first + start_steps, path_steps, out=path_times)  # starts[:, None] + path_steps[None, :]
        times[:] = path_times[:, s // 2]
    q_bw = None
    out = []
    for camera, consts in zip(cameras, constants):
        (half_diag, q_cb, r_cb, pinhole, f_mm, k1, pix_mm, cx, cy, w_px, h_px, f_px) = consts
        if pinhole is not None and sampled:
            # the per-frame path: attitudes, cone search, projection and the kept stars' fields in one compiled call
            # the rotations only for the bright bodies' views; the other outputs packed by kind (one boxed array
            # each), the fields their rows
            r_cw = np.empty((path_times.size, 3, 3)) if bodies else _NO_ROTATIONS
            q2, rows, mags, xy_path, visible = sk.scene_frame(
                attitude[0], attitude[1], t_first, start_steps, path_steps, instants, q_cb, r_cb, s, *catalog.z_index,
                catalog.vectors,
                catalog.hip, catalog.vmag, catalog.bv, half_diag, f_px, f_mm, k1, pix_mm, cx, cy, w_px, h_px,
                float(margin), *pinhole, r_cw)
            q_mid, q_cam_mid, idx, hip, vmag, bv = q2[0], q2[1], rows[0], rows[1], mags[0], mags[1]
        else:
            if q_bw is None:
                q_bw = _evaluate_attitude(attitude, path_times.ravel(), validate)
            r_cw, q_cam_mid, centre, drift = sk.camera_frames(q_bw, q_cb, r_cb, s)
            radius = min(half_diag + drift + (margin + 2.0) / f_px + 1e-6, math.pi)
            idx = catalog.cone_search(centre, radius, validate=False)  # a unit float64 centre, radius in (0, π]
            if pinhole is not None:
                keep, xy_path, visible = sk.project_scene(r_cw, catalog.vectors, idx, f_mm, k1, pix_mm, cx, cy, s,
                                                          w_px, h_px, float(margin), *pinhole)
            else:
                v_cam = sk.rotate_to_camera(r_cw, catalog.vectors, idx)
                xy, _, in_front = camera.project(v_cam.reshape(-1, 3), return_in_front=True, validate=False)
                keep, xy_path, visible = sk.select_near_detector(
                    np.ascontiguousarray(xy, dtype=np.float64).reshape(n * s, len(idx), 2),
                    np.ascontiguousarray(in_front).reshape(n * s, len(idx)), s, w_px, h_px, float(margin))
            idx = idx[keep]
            hip, vmag, bv, q_mid = catalog.hip[idx], catalog.vmag[idx], catalog.bv[idx], q_bw[mid_rows]

        views = []
        if bodies:
            r_cw_mid = r_cw[mid_rows]
            for b in bodies:
                d_cam = np.einsum("tji,j->ti", r_cw_mid, np.asarray(b.direction_world))
                views.append(BrightBodyView(b.name, np.arccos(np.clip(d_cam[:, 2], -1.0, 1.0)), d_cam))

        out.append(build_checked(Scene, {
            "camera": camera, "plan": plan, "t_frame_start": t0, "times": times, "path_times": path_times,
            "star_index": idx, "hip": hip, "vmag": vmag, "bv": bv, "xy_path": xy_path, "visible": visible,
            "q_body_to_icrs": q_mid, "q_cam_to_icrs": q_cam_mid, "bright_bodies": tuple(views)}))
    return tuple(out)


def scene_from_tracks(
    camera: Camera,
    plan: ExposurePlan,
    xy_mid_px,
    vmag,
    velocity_px_s=None,
    bv=None,
    t_frame_start: float = 0.0,
    n_path_samples: int = 3,
) -> Scene:
    """A synthetic scene: stars moving on straight lines at constant image velocity (tests, calibration).

    Star m is at ``xy_mid_px[m] + velocity_px_s[m] (t − t_c)`` with ``t_c`` the middle of the frame's
    integration window. Catalog fields are placeholders (``star_index = hip = arange(M)``).

    Parameters
    ----------
    camera : Camera
    plan : ExposurePlan
    xy_mid_px : array_like, shape (M, 2)
        Positions at ``t_c``, px.
    vmag : array_like, shape (M,)
    velocity_px_s : array_like, shape (M, 2), optional
        Image velocity, px/s (default still).
    bv : array_like, shape (M,), optional
    t_frame_start : float
    n_path_samples : int
        Odd S >= 3.

    Returns
    -------
    Scene
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a startracker.optics.Camera, got {type(camera).__name__}")
    if not isinstance(plan, ExposurePlan):
        raise TypeError(f"plan must be an ExposurePlan, got {type(plan).__name__}")
    xy = as_float_array(xy_mid_px, "xy_mid_px", last_dim=2, ndim=2)
    m = len(xy)
    vm = as_float_array(vmag, "vmag", ndim=1)
    if len(vm) != m:
        raise ValueError("vmag must have one entry per star")
    vel = np.zeros((m, 2)) if velocity_px_s is None else as_float_array(velocity_px_s, "velocity_px_s", last_dim=2, ndim=2)
    if len(vel) != m:
        raise ValueError("velocity_px_s must have one row per star")
    b = np.zeros(m) if bv is None else as_float_array(bv, "bv", ndim=1)
    s = check_int(n_path_samples, "n_path_samples", lo=3)
    if s % 2 == 0:
        raise ValueError(f"n_path_samples must be odd, got {s}")
    t0 = float(as_float_array(t_frame_start, "t_frame_start", ndim=0))
    starts = plan.exposure_start_times(t0)
    path_times = starts[:, None] + plan.exposure_s * np.linspace(0.0, 1.0, s)[None, :]
    t_c = starts[0] + 0.5 * plan.integration_window_s
    xy_path = xy[None, None] + vel[None, None] * (path_times - t_c)[:, :, None, None]
    w, h = camera.resolution
    mid = xy_path[:, s // 2]
    visible = (mid[..., 0] >= -0.5) & (mid[..., 0] <= w - 0.5) & (mid[..., 1] >= -0.5) & (mid[..., 1] <= h - 0.5)
    q_id = np.tile([1.0, 0.0, 0.0, 0.0], (plan.n_exposures, 1))
    return Scene(
        camera=camera,
        plan=plan,
        t_frame_start=t0,
        times=path_times[:, s // 2].copy(),
        path_times=path_times,
        star_index=np.arange(m, dtype=np.int64),
        hip=np.arange(m, dtype=np.int64),
        vmag=vm,
        bv=b,
        xy_path=xy_path,
        visible=visible,
        q_body_to_icrs=q_id,
        q_cam_to_icrs=q_id.copy(),
        bright_bodies=(),
    )
