"""A star tracker described as data: optics, detector, exposure, catalog, identification, matcher and thresholds.

:class:`StarTrackerSpec` is what a user writes to put a star tracker of their own into the loop. It holds

* ``camera`` -- the optics (:class:`startracker.optics.Camera`: resolution, pixel pitch, focal length, principal
  point, first-order radial distortion and the mounting ``q_cam_to_body``);
* ``detector`` -- the detector (:class:`startracker.imaging.SensorModel`: PSF σ, photometry with QE, intensifier,
  dark current, read noise, full well, ADC bits, conversion gain, ...);
* ``exposure`` -- :class:`ExposureSpec` (single or multi-exposure, exposure times, frame rate, the rule for N);
* ``mag_limit``, ``identify_method``, ``matcher``;
* ``tracker`` -- :class:`TrackerSpec`, the tracker's thresholds (its centroid σ comes from the detector unless
  given).

The presets of the papers are instances (:func:`preset_spec`, names :data:`PRESET_NAMES`). A spec converts to and
from a plain dict (:meth:`StarTrackerSpec.to_dict`, :meth:`StarTrackerSpec.from_dict`), so it survives
``gymnasium.make`` keyword arguments, pickling and JSON on the command line; a dict may start from a preset
(``{"preset": "zy3", "detector": {"read_noise_e": 30.0}}``) and give the camera's horizontal field of view
``fov_deg`` instead of its focal length. Invalid values raise ``ValueError`` naming the field and the accepted
range.

Example
-------
>>> from startracker.spec import StarTrackerSpec
>>> spec = StarTrackerSpec.from_dict({
...     "camera": {"resolution": [1280, 1024], "pixel_size_um": 4.8, "fov_deg": 12.0},
...     "detector": {"read_noise_e": 3.0, "dark_current_e_per_s": 10.0, "full_well_e": 12000.0,
...                  "photometry": {"aperture_diameter_mm": 25.0, "quantum_efficiency": 0.6}},
...     "exposure": {"exposure_s": 0.004, "single_exposure_s": 0.02},
... })
>>> round(spec.camera.fov_deg[0], 3)
12.0
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from startracker.centroid.fidelity import predicted_centroid_sigma_px
from startracker.imaging import SensorModel, StrayLightResponse
from startracker.optics import CAMERA_PRESETS, Camera
from startracker.photometry import Photometry
from startracker.validation import check_choice, check_int, check_real

__all__ = [
    "StarTrackerSpec",
    "ExposureSpec",
    "TrackerSpec",
    "PRESET_NAMES",
    "IDENTIFY_METHODS",
    "MATCHERS",
    "N_RULES",
    "preset_spec",
    "as_spec",
    "camera_to_dict",
    "camera_from_dict",
    "detector_to_dict",
    "detector_from_dict",
]

PRESET_NAMES = ("paper000", "zy3", "paper003", "paper004", "paper004_3cmos")
IDENTIFY_METHODS = ("pyramid", "voting", "brightness", "string")
MATCHERS = ("dkvlut", "brute", "kdtree")
#: How N follows the rate: "separation" keeps the streaks of one star ``min_gap_sigma`` PSF σ apart
#: (:func:`startracker.scene.choose_n_exposures`); "paper000" is paper 000's rate rule, one more exposure per
#: ``rate_per_exposure_deg_s`` (N = 1 at rest, 21 at 20°/s), overlapping spots left to the centroiding.
N_RULES = ("separation", "paper000")


def _fail(path: str, exc: Exception):
    """The same error, its message prefixed with the field's path in the spec."""
    return type(exc)(f"{path}: {exc}")


# ------------------------------------------------------------------------------------------ parts
@dataclass(frozen=True)
class ExposureSpec:
    """How the detector is exposed.

    Attributes
    ----------
    mode : {"single", "multi"}
        ``"multi"``: N exposures per frame while tracking (paper 000's MEIA); single while lost either way.
    exposure_s : float
        Exposure time of each exposure of a multi-exposure frame, s (> 0, <= the frame period).
    single_exposure_s : float
        Exposure time of a single-exposure (lost-in-space) frame, s (> 0, <= the frame period).
    frame_rate_hz : float
        Camera frame rate, Hz (0.1 .. 1000).
    n_exposures : int or "adaptive"
        N per multi-exposure frame (1 .. ``max_exposures``), or chosen from the rate by ``n_rule``.
    max_exposures : int
        Largest N (1 .. 100); N exposures must fit in a frame.
    n_rule : {"separation", "paper000"}
        See :data:`N_RULES`.
    min_gap_sigma : float
        ``"separation"``: required gap between the streaks of one star, PSF σ (0 .. 50].
    rate_per_exposure_deg_s : float
        ``"paper000"``: one more exposure per this much body rate, °/s (> 0).
    """

    mode: str = "multi"
    exposure_s: float = 1.0e-3
    single_exposure_s: float = 0.02
    frame_rate_hz: float = 10.0
    n_exposures: int | str = "adaptive"
    max_exposures: int = 21
    n_rule: str = "separation"
    min_gap_sigma: float = 6.0
    rate_per_exposure_deg_s: float = 1.0

    def __post_init__(self):
        check_choice(self.mode, "mode", ("single", "multi"))
        check_real(self.frame_rate_hz, "frame_rate_hz", 0.1, 1000.0)
        period = 1.0 / self.frame_rate_hz
        check_real(self.exposure_s, "exposure_s", 0.0, period, lo_open=True)
        check_real(self.single_exposure_s, "single_exposure_s", 0.0, period, lo_open=True)
        object.__setattr__(self, "max_exposures", check_int(self.max_exposures, "max_exposures", 1, 100))
        if self.max_exposures * self.exposure_s > period * (1 + 1e-9):
            raise ValueError(f"max_exposures must be in [1, {max(1, math.floor(period / self.exposure_s))}] "
                             f"(N exposures of {self.exposure_s} s in a {period:g} s frame), got {self.max_exposures}")
        n = self.n_exposures
        if n != "adaptive":
            if isinstance(n, (float, np.floating)) and float(n).is_integer():
                n = int(n)
            try:
                n = check_int(n, "n_exposures", 1, self.max_exposures)
            except (TypeError, ValueError):
                raise ValueError(f"n_exposures must be 'adaptive' or an int in [1, {self.max_exposures}], got {n!r}")
            object.__setattr__(self, "n_exposures", n)
        check_choice(self.n_rule, "n_rule", N_RULES)
        check_real(self.min_gap_sigma, "min_gap_sigma", 0.0, 50.0, lo_open=True)
        check_real(self.rate_per_exposure_deg_s, "rate_per_exposure_deg_s", 0.0, lo_open=True)
        for name in ("exposure_s", "single_exposure_s", "frame_rate_hz", "min_gap_sigma", "rate_per_exposure_deg_s"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self.frame_rate_hz


@dataclass(frozen=True)
class TrackerSpec:
    """Thresholds of the tracker's state machine (:class:`startracker.sensor.StarTracker`, same meanings).

    Attributes
    ----------
    centroid_sigma_px : float or None
        1σ per-axis centroid noise the tracker assumes, px (0 .. 10]; None: from the detector model
        (:meth:`StarTrackerSpec.centroid_sigma_px`).
    radius_k_sigma : float
        Matching radius in σ of the predicted position (> 0).
    radius_min_px, radius_max_px : float
        Matching radius bounds, px (0 <= min <= max).
    min_stars_per_instant : int
        Stars needed for an instant's attitude (>= 2).
    min_matched_fraction : float
        Lock test: matched share of the predicted spots, [0, 1].
    max_residual_arcsec : float or None
        Lock test on the RMS residual, arcsec (> 0); None: 3 × the expected.
    outlier_k_sigma : float
        Residual test of a match inside an instant (> 0).
    innovation_gate : float
        Lock test on the predicted-to-solved rotation, χ² with 3 dof (> 0).
    instant_gate : float
        Smoothness test of a frame's instants: leave-one-out χ² (3 dof) against a polynomial in time through the
        other instants above which an instant is not reported (> 0; :class:`startracker.sensor.StarTracker`).
    shift_k_sigma : float
        Spots of one star stay ``2 shift_k_sigma`` prediction σ apart (>= 0).
    accel_sigma_rad_s2 : float
        Unmodelled angular acceleration change, rad/s² (>= 0).
    max_rate_deg_s : float
        Largest plausible body rate, °/s (> 0).
    coast_max_s : float
        How long a lost lock may be recovered by prediction, s (>= 0).
    sigma_margin : float
        The tracker assumes the detector's centroid σ times this (1 .. 10; ``centroid_sigma_px=None``): one σ per
        head does not see what raises it frame by frame (stray light on the background, blends of near spots,
        faint streaks); with 2 the soak with random faults and torques has no attitude beyond 5σ.
    sigma_rate_deg_s : float
        The detector's centroid σ (``centroid_sigma_px=None``) is taken over still spots and spots streaked at
        this body rate, °/s (>= 0; default half the env's 20°/s rate limit): a streak's centroid is much less
        certain along it.
    """

    centroid_sigma_px: float | None = None
    radius_k_sigma: float = 6.0
    radius_min_px: float = 2.0
    radius_max_px: float = 40.0
    min_stars_per_instant: int = 3
    min_matched_fraction: float = 0.3
    max_residual_arcsec: float | None = None
    outlier_k_sigma: float = 5.0
    innovation_gate: float = 30.0
    instant_gate: float = 16.0
    shift_k_sigma: float = 4.0
    accel_sigma_rad_s2: float = 0.02
    max_rate_deg_s: float = 30.0
    coast_max_s: float = 1.0
    sigma_margin: float = 2.0
    sigma_rate_deg_s: float = 10.0

    def __post_init__(self):
        if self.centroid_sigma_px is not None:
            check_real(self.centroid_sigma_px, "centroid_sigma_px", 0.0, 10.0, lo_open=True)
        check_real(self.radius_k_sigma, "radius_k_sigma", 0.0, 100.0, lo_open=True)
        check_real(self.radius_min_px, "radius_min_px", 0.0, 1000.0)
        check_real(self.radius_max_px, "radius_max_px", self.radius_min_px, 10000.0, lo_open=self.radius_min_px == 0)
        object.__setattr__(self, "min_stars_per_instant", check_int(self.min_stars_per_instant, "min_stars_per_instant", 2, 1000))
        check_real(self.min_matched_fraction, "min_matched_fraction", 0.0, 1.0)
        if self.max_residual_arcsec is not None:
            check_real(self.max_residual_arcsec, "max_residual_arcsec", 0.0, lo_open=True)
        check_real(self.outlier_k_sigma, "outlier_k_sigma", 0.0, lo_open=True)
        check_real(self.innovation_gate, "innovation_gate", 0.0, lo_open=True)
        check_real(self.instant_gate, "instant_gate", 0.0, lo_open=True)
        check_real(self.shift_k_sigma, "shift_k_sigma", 0.0, 100.0)
        check_real(self.accel_sigma_rad_s2, "accel_sigma_rad_s2", 0.0)
        check_real(self.max_rate_deg_s, "max_rate_deg_s", 0.0, 360.0, lo_open=True)
        check_real(self.coast_max_s, "coast_max_s", 0.0)
        check_real(self.sigma_rate_deg_s, "sigma_rate_deg_s", 0.0, 360.0)
        check_real(self.sigma_margin, "sigma_margin", 1.0, 10.0)

    def tracker_kwargs(self) -> dict:
        """Keyword arguments of :class:`startracker.sensor.StarTracker` (without the centroid σ)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("centroid_sigma_px", "sigma_rate_deg_s", "sigma_margin")}


# ------------------------------------------------------------------------------------------ dict forms
_CAMERA_KEYS = ("resolution", "pixel_size_um", "focal_length_mm", "principal_point", "distortion_k1_per_mm2",
                "q_cam_to_body", "name")


def camera_to_dict(camera: Camera) -> dict:
    """The camera's fields as plain Python values (lists and floats)."""
    return dict(resolution=list(camera.resolution), pixel_size_um=float(camera.pixel_size_um),
                focal_length_mm=float(camera.focal_length_mm), principal_point=[float(v) for v in camera.principal_point],
                distortion_k1_per_mm2=float(camera.distortion_k1_per_mm2),
                q_cam_to_body=[float(v) for v in camera.q_cam_to_body], name=camera.name)


def camera_from_dict(d: dict, base: Camera | None = None) -> Camera:
    """A :class:`Camera` from a dict of its fields, over ``base`` (or the defaults); ``fov_deg`` (full
    horizontal field of view, deg, in (0, 180)) may replace ``focal_length_mm``."""
    _check_keys(d, _CAMERA_KEYS + ("fov_deg",), "camera")
    kw = camera_to_dict(base) if base is not None else {}
    if base is not None and "resolution" in d and "principal_point" not in d:
        kw.pop("principal_point")  # a new size re-centres the principal point
    kw.update({k: v for k, v in d.items() if k != "fov_deg"})
    if "fov_deg" in d:
        if "focal_length_mm" in d:
            raise ValueError("camera: give focal_length_mm or fov_deg, not both")
        fov = check_real(d["fov_deg"], "fov_deg", 0.0, 179.0, lo_open=True)
        n_cols = int(kw.get("resolution", (2048, 2048))[0])
        pitch_mm = float(kw.get("pixel_size_um", 5.5)) * 1e-3
        kw["focal_length_mm"] = 0.5 * n_cols * pitch_mm / math.tan(math.radians(fov) / 2)
    if "resolution" in kw:
        kw["resolution"] = tuple(kw["resolution"])
    if kw.get("q_cam_to_body") is not None:
        kw["q_cam_to_body"] = tuple(kw["q_cam_to_body"])
    return Camera(**kw)


_DETECTOR_SKIP = ("photometry", "stray_light")


def detector_to_dict(model: SensorModel) -> dict:
    """The detector's fields as plain Python values (photometry and stray light as nested dicts)."""
    out = {}
    for f in fields(model):
        v = getattr(model, f.name)
        if f.name == "photometry":
            out[f.name] = dataclasses.asdict(v)
        elif f.name == "stray_light":
            out[f.name] = {k: dataclasses.asdict(r) for k, r in v.items()}
        elif isinstance(v, tuple):
            out[f.name] = [float(x) for x in v]
        else:
            out[f.name] = v
    return out


def detector_from_dict(d, base: SensorModel | None = None) -> SensorModel:
    """A :class:`SensorModel` from a preset name (:meth:`SensorModel.preset`) or a dict of its fields over
    ``base`` (default the ``paper000`` preset); ``photometry`` and ``stray_light`` may be partial nested dicts."""
    if isinstance(d, str):
        return SensorModel.preset(d)
    if isinstance(d, SensorModel):
        return d
    if not isinstance(d, dict):
        raise TypeError(f"detector must be a SensorModel, a preset name or a dict, got {type(d).__name__}")
    base = SensorModel.preset("paper000") if base is None else base
    names = tuple(f.name for f in fields(SensorModel))
    _check_keys(d, names, "detector")
    kw = {}
    for k, v in d.items():
        if k == "photometry":
            if isinstance(v, Photometry):
                kw[k] = v
            else:
                pnames = tuple(f.name for f in fields(Photometry))
                _check_keys(v, pnames, "detector.photometry")
                try:
                    kw[k] = replace(base.photometry, **v)
                except (TypeError, ValueError) as exc:
                    raise _fail("detector.photometry", exc) from None
        elif k == "stray_light":
            kw[k] = {body: r if isinstance(r, StrayLightResponse) else StrayLightResponse(**r) for body, r in v.items()}
        elif k in ("hot_pixel_dark_e_per_s", "debris_vmag_range"):
            kw[k] = tuple(float(x) for x in v)
        else:
            kw[k] = v
    return replace(base, **kw)


def _check_keys(d, accepted, where: str) -> None:
    if not isinstance(d, dict):
        raise TypeError(f"{where} must be a dict, got {type(d).__name__}")
    unknown = sorted(set(d) - set(accepted))
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; accepted: {sorted(accepted)}")


# ------------------------------------------------------------------------------------------ the spec
@dataclass(frozen=True, eq=False)
class StarTrackerSpec:
    """One star-tracker head as data (see the module docstring).

    Attributes
    ----------
    camera : startracker.optics.Camera
        Optics and mounting ``q_cam_to_body``.
    detector : startracker.imaging.SensorModel
        Detector, photometry and noise.
    exposure : ExposureSpec
    mag_limit : float
        Catalog limit, V (0 .. 9).
    identify_method : str
        Lost-in-space method, one of :data:`IDENTIFY_METHODS`.
    matcher : str
        Tracking matcher, one of :data:`MATCHERS`.
    tracker : TrackerSpec
    color : bool
        True for paper 004's 3CMOS prism head (only the ``paper004_3cmos`` optics: three registered channels).
    name : str
        Free label (the preset name for presets).
    """

    camera: Camera = field(default_factory=Camera)
    detector: SensorModel = field(default_factory=SensorModel)
    exposure: ExposureSpec = field(default_factory=ExposureSpec)
    mag_limit: float = 6.0
    identify_method: str = "pyramid"
    matcher: str = "dkvlut"
    tracker: TrackerSpec = field(default_factory=TrackerSpec)
    color: bool = False
    name: str = "custom"

    def __post_init__(self):
        for attr, cls in (("camera", Camera), ("detector", SensorModel), ("exposure", ExposureSpec),
                          ("tracker", TrackerSpec)):
            if not isinstance(getattr(self, attr), cls):
                raise TypeError(f"{attr} must be a {cls.__module__}.{cls.__name__}, got {type(getattr(self, attr)).__name__}")
        object.__setattr__(self, "mag_limit", check_real(self.mag_limit, "mag_limit", 0.0, 9.0))
        check_choice(self.identify_method, "identify_method", IDENTIFY_METHODS)
        check_choice(self.matcher, "matcher", MATCHERS)
        if not isinstance(self.color, (bool, np.bool_)):
            raise TypeError(f"color must be a bool, got {type(self.color).__name__}")
        if self.color and tuple(self.camera.resolution) != tuple(CAMERA_PRESETS["paper004"]["resolution"]):
            raise ValueError("color: True is paper 004's 3CMOS prism head (the paper004 optics, 2064x1544), "
                             f"got a {self.camera.resolution[0]}x{self.camera.resolution[1]} camera")
        if not isinstance(self.name, str):
            raise TypeError("name must be a str")

    # ------------------------------------------------------------------ derived
    @property
    def frame_period_s(self) -> float:
        return self.exposure.frame_period_s

    def centroid_sigma_px(self) -> float:
        """The tracker's per-axis centroid σ, px: ``tracker.centroid_sigma_px`` if given, else the detector's
        (:meth:`detector_sigma_px`) times ``tracker.sigma_margin``."""
        if self.tracker.centroid_sigma_px is not None:
            return float(self.tracker.centroid_sigma_px)
        return self.tracker.sigma_margin * _detector_sigma_px(self)

    def detector_sigma_px(self) -> float:
        """The detector's per-axis centroid σ on a quiet sky, px.

        The RMS of the predicted centroid error (:func:`startracker.centroid.fidelity.
        predicted_centroid_sigma_px`, spots of one multi-exposure exposure) over the stars the tracker will
        see: one per 0.1 mag bin up to ``mag_limit``, weighted by the sky's star counts (×10^0.6 per
        magnitude) and by their detection probability, still and streaked at ``tracker.sigma_rate_deg_s``
        across the boresight (equal shares); at least 0.05 px (what the catalog and the distortion model
        leave).
        """
        return _detector_sigma_px(self)

    def with_mounting(self, q_cam_to_body) -> "StarTrackerSpec":
        """The same head mounted differently."""
        return replace(self, camera=self.camera.with_mounting(q_cam_to_body))

    # ------------------------------------------------------------------ dict form
    def to_dict(self) -> dict:
        """Plain Python values only (JSON-serialisable); :meth:`from_dict` rebuilds an equal spec."""
        return dict(camera=camera_to_dict(self.camera), detector=detector_to_dict(self.detector),
                    exposure=dataclasses.asdict(self.exposure), mag_limit=self.mag_limit,
                    identify_method=self.identify_method, matcher=self.matcher,
                    tracker=dataclasses.asdict(self.tracker), color=bool(self.color), name=self.name)

    @classmethod
    def from_dict(cls, d: dict) -> "StarTrackerSpec":
        """A spec from a dict (the form of :meth:`to_dict`; any part may be partial).

        ``"preset"`` (one of :data:`PRESET_NAMES`) starts from that preset; otherwise from the defaults (paper
        000's optics and detector). ``camera``, ``exposure`` and ``tracker`` update the base's fields;
        ``detector`` is a dict of fields over the base's detector or a :meth:`SensorModel.preset` name.

        Raises
        ------
        ValueError
            An unknown field, or a value out of its range (the message names the field, e.g.
            ``detector: read_noise_e must be >= 0.0, got -1``).
        """
        if isinstance(d, StarTrackerSpec):
            return d
        top = tuple(f.name for f in fields(cls)) + ("preset",)
        _check_keys(d, top, "camera spec")
        base = preset_spec(d["preset"]) if "preset" in d else cls()
        kw = {}
        for part, build in (("camera", lambda v: camera_from_dict(v, base.camera)),
                            ("detector", lambda v: detector_from_dict(v, base.detector)),
                            ("exposure", lambda v: _part_from_dict(ExposureSpec, v, base.exposure, "exposure")),
                            ("tracker", lambda v: _part_from_dict(TrackerSpec, v, base.tracker, "tracker"))):
            if part in d:
                v = d[part]
                if isinstance(v, (Camera, SensorModel, ExposureSpec, TrackerSpec)):
                    kw[part] = v
                    continue
                try:
                    kw[part] = build(v)
                except (TypeError, ValueError) as exc:
                    msg = str(exc)
                    raise (exc if msg.startswith(part) else _fail(part, exc)) from None
        for k in ("mag_limit", "identify_method", "matcher", "color", "name"):
            if k in d:
                kw[k] = d[k]
        if "preset" in d and "name" not in d and (set(d) - {"preset"}):
            kw["name"] = f"{d['preset']}+custom"
        return replace(base, **kw)

    def __reduce__(self):
        # SensorModel holds a read-only mapping (not picklable): a spec pickles as its dict
        return (StarTrackerSpec.from_dict, (self.to_dict(),))

    def __eq__(self, other):
        return isinstance(other, StarTrackerSpec) and self.to_dict() == other.to_dict()

    def __hash__(self):
        return hash(repr(self.to_dict()))


def _part_from_dict(cls, v, base, where):
    _check_keys(v, tuple(f.name for f in fields(cls)), where)
    return replace(base, **v)


_SIGMA_CACHE: dict = {}


def _detector_sigma_px(spec: StarTrackerSpec) -> float:
    key = (repr(detector_to_dict(spec.detector)), repr(camera_to_dict(spec.camera.with_mounting((1, 0, 0, 0)))),
           spec.exposure.exposure_s, spec.mag_limit, spec.tracker.sigma_rate_deg_s)
    hit = _SIGMA_CACHE.get(key)
    if hit is not None:
        return hit
    vmag = np.arange(-1.0, spec.mag_limit + 1e-9, 0.1)
    tau = spec.exposure.exposure_s
    num = den = 0.0
    for rate_deg_s in (0.0, spec.tracker.sigma_rate_deg_s):
        smear_px = math.radians(rate_deg_s) * spec.camera.focal_length_px * tau
        sigma, p_det = predicted_centroid_sigma_px(spec.detector, spec.camera, vmag, tau, smear_px=smear_px)
        w = 10.0 ** (0.6 * vmag) * p_det
        num += float(np.sum(w * sigma**2))
        den += float(np.sum(w))
    s = float(max(math.sqrt(num / den), 0.05)) if den > 0 else 1.0
    _SIGMA_CACHE[key] = s
    return s


# ------------------------------------------------------------------------------------------ presets
def preset_spec(name: str, q_cam_to_body=(1.0, 0.0, 0.0, 0.0)) -> StarTrackerSpec:
    """The star tracker of one of the papers, each with its own optics, detector and exposure.

    ``"paper000"``: paper 000's intensified multi-exposure tracker (Table 2 optics); ``"zy3"``: ZY-3's APS
    tracker (paper 002, Table 1: 125 ms exposures, 4 Hz, catalog <= 5.5); ``"paper003"``: paper 003's 16°×16°
    tracker; ``"paper004"``: one CMOS of paper 004's camera behind its lens (green channel of Table 1);
    ``"paper004_3cmos"``: paper 004's 3CMOS prism head. Detector sources and assumptions:
    :meth:`startracker.imaging.SensorModel.preset`.
    """
    check_choice(name, "camera", PRESET_NAMES)
    optics = "paper004" if name == "paper004_3cmos" else name
    camera = Camera(**CAMERA_PRESETS[optics], q_cam_to_body=q_cam_to_body, name=name)
    detector = SensorModel.preset(name)
    exposure = _PRESET_EXPOSURES[name]
    mag_limit = 5.5 if name == "zy3" else 6.0  # paper 002 Table 1: catalog <= 5.5; papers 000, 003: <= 6.0
    return StarTrackerSpec(camera=camera, detector=detector, exposure=exposure, mag_limit=mag_limit,
                           color=name == "paper004_3cmos", name=name)


_PRESET_EXPOSURES = {
    # paper 000: 1 ms exposures behind the intensifier (21 fit in a 10 Hz frame: 210 Hz, §1), 20 ms to acquire
    # (assumed). N by the paper's rule (1 -> 21 over 0 -> 20°/s, §5): spots that come near each other join in both
    # fidelities, and the tracker leaves joined spots out (photometric blend test) and instants off a smooth motion
    # out (smoothness test); n_rule="separation" is the older cap (no two spots of a star within 6 PSF σ)
    "paper000": ExposureSpec(mode="multi", exposure_s=1.0e-3, single_exposure_s=0.02, frame_rate_hz=10.0,
                             n_rule="paper000"),
    # paper 002 Table 1: exposure 125..500 ms, update rate 4 Hz; the shortest exposure (the least smear)
    "zy3": ExposureSpec(mode="single", exposure_s=0.125, single_exposure_s=0.125, frame_rate_hz=4.0, max_exposures=2),
    # paper 003 is silent: assumed 50 ms at 10 Hz, single exposure (a conventional tracker)
    "paper003": ExposureSpec(mode="single", exposure_s=0.05, single_exposure_s=0.05, frame_rate_hz=10.0,
                             max_exposures=2),
    # paper 004 is silent: assumed 10 ms multi-exposure on its plain CMOS, 20 ms to acquire, 10 Hz
    "paper004": ExposureSpec(mode="multi", exposure_s=0.01, single_exposure_s=0.02, frame_rate_hz=10.0, max_exposures=10),
    "paper004_3cmos": ExposureSpec(mode="multi", exposure_s=0.01, single_exposure_s=0.02, frame_rate_hz=10.0,
                                   max_exposures=10),
}


def as_spec(camera, q_cam_to_body=None) -> StarTrackerSpec:
    """A :class:`StarTrackerSpec` from a preset name, a spec or a dict (:meth:`StarTrackerSpec.from_dict`),
    optionally remounted."""
    if isinstance(camera, str):
        if camera not in PRESET_NAMES:
            raise ValueError(f"camera must be one of {PRESET_NAMES}, a StarTrackerSpec or a dict, got {camera!r}")
        spec = preset_spec(camera)
    elif isinstance(camera, StarTrackerSpec):
        spec = camera
    elif isinstance(camera, dict):
        spec = StarTrackerSpec.from_dict(camera)
    else:
        raise TypeError(f"camera must be a preset name, a StarTrackerSpec or a dict, got {type(camera).__name__}")
    return spec if q_cam_to_body is None else spec.with_mounting(q_cam_to_body)
