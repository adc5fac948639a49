"""The centroid-fidelity model: detections drawn from scene truth without pixels.

Fidelities of :func:`simulate_detections`
-----------------------------------------
* ``"pixel"``: :func:`startracker.imaging.render_sparse` then the same components and measurements on
  the sparse pixels (connectivity by a neighbour graph, ``scipy.sparse.csgraph``), with the threshold
  at the known background.
* ``"centroid"``: no pixels. Each spot's detection probability, centroid noise (along and across the
  smear) and intensity follow the linearised theory of a thresholded centre of mass on the same
  detector model, with three factors calibrated against the pixel path (:class:`CentroidErrorModel`,
  :func:`calibrate_error_model`); hot pixels, cosmic rays, debris and the background's threshold
  crossings are drawn from the same statistics as in the pixel path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from startracker.centroid.extraction import (
    Centroids,
    check_k_sigma,
    check_method,
    check_min_area,
    check_psf_sigma,
    detections_from_sparse,
)
from startracker.imaging import (
    COSMIC_SIGMA_PX,
    KIND_COSMIC_RAY,
    KIND_DEBRIS,
    KIND_HOT_PIXEL,
    KIND_NOISE,
    KIND_STAR,
    FalseObjects,
    SensorModel,
    background_field,
    draw_false_objects,
    draw_false_pixels,
    fixed_pattern,
    render_sparse,
)
from startracker.kernels import centroid as ck
from startracker.scene import Scene
from startracker.validation import as_float_array, build_checked, check_positive

__all__ = [
    "CentroidErrorModel",
    "DEFAULT_ERROR_MODELS",
    "default_error_model",
    "draw_centroid_inputs",
    "simulate_detections",
    "calibrate_error_model",
    "candidate_pairs",
    "grid_scene",
    "predicted_centroid_sigma_px",
]


# ------------------------------------------------------------------------------------------ centroid fidelity
@dataclass(frozen=True)
class CentroidErrorModel:
    """Calibration factors of the centroid-fidelity theory (module docstring).

    Attributes
    ----------
    peak_factor : float
        c in the effective peak ``P (1 + (c − 1) w)`` of the detection probability and the threshold radius, w
        the photon share of the peak pixel's variance (the brightest of several pixels near the centre beats
        the mean peak by photon clumping; a background-dominated noise, as under stray light, dilutes it).
    photon_factor : float
        Multiplies the photon (shot and gain) term of the centroid variance.
    background_factor : float
        Multiplies the background-noise term of the centroid variance.
    locking_factor : float
        Multiplies the pixel-locking term.
    min_log_ratio : float
        Floor of ``ln(peak / threshold)`` (the threshold region of a barely detected spot is about a
        ``sqrt(2 · min_log_ratio)`` σ disk).
    method : {"com", "gaussian"}
        Centroiding method these factors were calibrated for.
    """

    peak_factor: float = 1.0
    photon_factor: float = 1.0
    background_factor: float = 1.0
    locking_factor: float = 1.0
    min_log_ratio: float = 0.5
    method: str = "com"

    def __post_init__(self):
        check_method(self.method)
        for name in ("peak_factor", "photon_factor", "background_factor", "locking_factor", "min_log_ratio"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be finite and > 0, got {v}")


# calibrate_error_model(SensorModel.preset(name), np.random.default_rng(2025), n_frames=16, method=method);
# tests/test_centroid.py checks that they still reproduce the pixel path. paper000's centre of mass is fitted with
# background_sigma_ratios=(1, 1, 6): the quiet sky counted twice, so the one closed form stays within the theory's
# 10 % of the pixel path on a quiet sky (tests/test_preset_fidelity.py) and within its stated accuracy under stray
# light (tests/test_fault_fidelity.py).
DEFAULT_ERROR_MODELS = {
    ("paper000", "com"): CentroidErrorModel(1.385, 1.144, 1.700, 0.001, 0.5, "com"),
    ("paper000", "gaussian"): CentroidErrorModel(1.360, 3.307, 0.001, 1.426, 0.5, "gaussian"),
    ("paper000_cmos", "com"): CentroidErrorModel(1.345, 1.178, 1.366, 0.037, 0.5, "com"),
    ("paper000_cmos", "gaussian"): CentroidErrorModel(1.345, 13.915, 0.795, 0.205, 0.5, "gaussian"),
    # each preset's detector on its own camera at its own exposure (startracker.spec.preset_spec):
    # calibrate_error_model(spec.detector, np.random.default_rng(2025), camera=spec.camera,
    #                       exposure_s=spec.exposure.exposure_s, n_frames=16)
    ("zy3", "com"): CentroidErrorModel(1.065, 0.918, 0.898, 0.128, 0.5, "com"),
    ("paper003", "com"): CentroidErrorModel(1.185, 1.047, 0.936, 0.133, 0.5, "com"),
    ("paper004", "com"): CentroidErrorModel(1.165, 1.371, 1.514, 0.011, 0.5, "com"),
    ("paper004_3cmos", "com"): CentroidErrorModel(1.165, 1.371, 1.514, 0.011, 0.5, "com"),
}


def default_error_model(model: SensorModel, method: str = "com") -> CentroidErrorModel:
    """The stored calibration for a preset (by ``model.name``); other models get the one of their
    detector kind (intensified or not). Run :func:`calibrate_error_model` for a model far from both."""
    check_method(method)
    key = (model.name, method)
    if key not in DEFAULT_ERROR_MODELS:
        key = ("paper000" if model.intensified else "paper000_cmos", method)
    return DEFAULT_ERROR_MODELS[key]


def _spot_theory(s_units, gain, f2, sigma, sigma_o, c_splash, length, var_b, thr_e, err: CentroidErrorModel, intensified):
    """:func:`startracker.kernels.centroid.spot_theory` (the model is in its docstring) for arrays of spots,
    as a dict of (P,) arrays keyed by ``THEORY_COLUMNS``: p_det, ph/bg/lock for along and cross, var_along,
    var_cross, cap (captured e⁻), var_cap, area, peak (e⁻)."""
    # writable copies: a read-only array (a broadcast view) is another numba type, compiled again besides the one
    # the centroid kernel passes
    s_units, length, var_b, thr_e = (np.array(np.broadcast_to(np.asarray(v, dtype=np.float64), np.shape(s_units)))
                                     for v in (s_units, length, var_b, thr_e))
    cols = ck.spot_theory(s_units, float(gain), float(f2), float(sigma), float(sigma_o), float(c_splash), length, var_b,
                          thr_e, _factor_vector(err), bool(intensified))
    return {name: cols[:, i] for i, name in enumerate(ck.THEORY_COLUMNS)}


_PARAM_CACHE: dict = {}


def _cached(obj, build):
    """``build(obj)`` once per (frozen) object, read-only."""
    hit = _PARAM_CACHE.get(id(obj))
    if hit is not None and hit[0] is obj:
        return hit[1]
    v = build(obj)
    v.setflags(write=False)
    if len(_PARAM_CACHE) > 256:
        _PARAM_CACHE.clear()
    _PARAM_CACHE[id(obj)] = (obj, v)
    return v


def _factor_vector(err: CentroidErrorModel) -> np.ndarray:
    """The ``factors`` vector of :mod:`startracker.kernels.centroid`."""
    return _cached(err, lambda e: np.array([e.peak_factor, e.photon_factor, e.background_factor, e.locking_factor,
                                            e.min_log_ratio], dtype=np.float64))


def _sensor_vector(model: SensorModel) -> np.ndarray:
    """The ``sensor`` vector of :mod:`startracker.kernels.centroid`."""
    return _cached(model, lambda md: np.array([
        md.intensifier_gain, md.excess_noise_factor**2, md.sigma_px, md.optics_sigma_px, md.splash_energy,
        1.0 if md.intensified else 0.0, md.saturation_dn, md.bias_dn, md.full_well_e, md.adc_max_dn, md.gain_e_per_dn,
        COSMIC_SIGMA_PX], dtype=np.float64))


def _background_vector(bg) -> np.ndarray:
    """The ``background`` vector of :mod:`startracker.kernels.centroid` for a BackgroundField (once per object:
    a quiet sky's background is the same object frame after frame)."""
    return _cached(bg, lambda b: np.array([b.opt0, b.opt_dx, b.opt_dy, b.cx, b.cy, b.dark_e, b.gain, b.enf2_c,
                                           b.read_var_e2, b.prnu_sigma, b.gain_e_per_dn, b.bias_dn, b.integration_s],
                                          dtype=np.float64))


_KINDS = np.array([KIND_STAR, KIND_DEBRIS, KIND_COSMIC_RAY, KIND_HOT_PIXEL, KIND_NOISE], dtype=np.int64)
_NO_FALSE = FalseObjects.none()
_EMPTY_1 = np.zeros(0)
_EMPTY_I = np.zeros(0, dtype=np.int64)
_EMPTY_HOT_I = np.zeros(0, dtype=np.int64)
_EMPTY_HOT_I.setflags(write=False)  # like fixed_pattern's arrays: one kernel signature
_EMPTY_HOT = np.zeros(0)
_EMPTY_HOT.setflags(write=False)
_FRAME_CONSTANTS: dict = {}


def _frame_constants(model: SensorModel, scene: Scene, err: CentroidErrorModel) -> tuple:
    """What :func:`draw_centroid_inputs` needs of the (frozen) detector, camera, plan and error model, once per
    quadruple: ``(n_cols, n_rows, hot_index, hot_rate, sensor vector, factor vector, quiet background, its vector)``,
    the background that of a sky without bright bodies (:func:`startracker.imaging.background_field`). A per-frame
    caller passes the same objects frame after frame; each lookup of its own costs ~0.3-1 µs."""
    camera, plan = scene.camera, scene.plan
    key = (id(model), id(camera), id(err), id(plan))
    hit = _FRAME_CONSTANTS.get(key)
    if hit is not None and hit[0] is model and hit[1] is camera and hit[2] is err and hit[3] is plan:
        return hit[4]
    n_cols, n_rows = camera.resolution
    _, hot_idx, hot_rate = fixed_pattern(model, camera.resolution)
    quiet = background_field(replace(scene, bright_bodies=()) if scene.bright_bodies else scene, model)
    value = (n_cols, n_rows, hot_idx, hot_rate, _sensor_vector(model), _factor_vector(err), quiet,
             _background_vector(quiet))
    if len(_FRAME_CONSTANTS) > 64:
        _FRAME_CONSTANTS.clear()
    _FRAME_CONSTANTS[key] = (model, camera, err, plan, value)
    return value


def draw_centroid_inputs(scene: Scene, model: SensorModel, rng, k_sigma: float, err: CentroidErrorModel,
                         include_false: bool) -> tuple:
    """The draws of one frame in the centroid fidelity, as the arguments of
    :func:`startracker.kernels.centroid.centroid_detections` (in its order).

    For a per-frame caller that runs that kernel inside a compiled call of its own (the 3CMOS head's three channels
    and their fusion, :func:`startracker.color.simulate_fused_detections`); :func:`simulate_detections` is the checked
    entry. Nothing is checked: ``scene``, ``model``, a float ``k_sigma`` and ``err`` as :func:`simulate_detections`
    takes them. The draws, in order, are those of :func:`simulate_detections`' Notes.

    Returns
    -------
    tuple
        ``(xy_path, visible, star_pe, ..., n_cols, n_rows, kinds)``: the 25 arguments of ``centroid_detections``.
    """
    n_cols, n_rows, hot_idx, hot_rate, sensor_vec, factor_vec, bg, bg_vec = _frame_constants(model, scene, err)
    if scene.bright_bodies:  # stray light: this frame's own background
        bg = background_field(scene, model)
        bg_vec = _background_vector(bg)
    plan = scene.plan
    tau = plan.exposure_s
    n = plan.n_exposures
    fo = draw_false_objects(scene, model, rng, validate=False) if include_false else _NO_FALSE
    star_pe = model.star_pe(scene.vmag, scene.bv, tau, validate=False)  # the scene's float64 magnitudes
    nd = len(fo.debris_vmag)
    if nd:
        debris_pe = model.star_pe(fo.debris_vmag, np.zeros(nd), tau, validate=False)
        t_mid = scene.t_frame_start + 0.5 * plan.frame_period_s
        t_start = scene.path_times[:, 0] - t_mid
        t_end = scene.path_times[:, -1] - t_mid
    else:
        debris_pe = t_start = t_end = _EMPTY_1
    n_cand = n * len(scene.star_index) + n * nd + len(fo.cosmic_e)
    u = rng.random(n_cand)
    if include_false:
        # the candidates' three normals and the hot pixels' one in one draw (the stream of two draws in that order)
        n_z = 3 * n_cand
        zz = rng.standard_normal(n_z + len(hot_idx))
        z = zz[:n_z].reshape(n_cand, 3)
        z_hot = zz[n_z:] if len(hot_idx) else _EMPTY_1
        f_lin, f_dn = draw_false_pixels(bg, k_sigma, n_cols, n_rows, model, rng)
    else:
        z = rng.standard_normal((n_cand, 3))
        hot_idx, hot_rate, z_hot, f_lin, f_dn = _EMPTY_HOT_I, _EMPTY_HOT, _EMPTY_1, _EMPTY_I, _EMPTY_1
    return (scene.xy_path, scene.visible, star_pe, fo.debris_xy0, fo.debris_velocity_px_s, debris_pe, t_start, t_end,
            fo.cosmic_start_xy, fo.cosmic_end_xy, fo.cosmic_e, hot_idx, hot_rate, f_lin, f_dn,
            u, z, z_hot, bg_vec, sensor_vec, factor_vec, float(k_sigma),
            n_cols, n_rows, _KINDS)


def _centroid_fidelity(scene: Scene, model: SensorModel, rng, k_sigma, err: CentroidErrorModel, include_false: bool) -> Centroids:
    """The centroid fidelity (module docstring): the draws of the frame (:func:`draw_centroid_inputs`), then one kernel
    call (:func:`startracker.kernels.centroid.centroid_detections`)."""
    xys, vals, labels, sat, bg_dn, noise_dn = ck.centroid_detections(
        *draw_centroid_inputs(scene, model, rng, k_sigma, err, include_false))
    # the kernel's outputs packed by kind (one boxed array each), the fields their rows (indexing: cheaper than
    # unpacking an array by iteration)
    return build_checked(Centroids, {
        "xy": xys[0], "intensity": vals[0], "area": labels[0], "saturated": sat, "peak": vals[1], "snr": vals[2],
        "background_dn": bg_dn, "noise_dn": noise_dn, "truth_star": labels[1], "truth_exposure": labels[2],
        "truth_kind": labels[3], "truth_xy": xys[1]})


def candidate_pairs(xy: np.ndarray, r: float) -> np.ndarray:
    """Pairs (i, j), i < j, of points closer than ``r`` along x and along y (a superset of the pairs within
    ``r``), by a sort and sweep over x (:func:`startracker.kernels.centroid.candidate_pairs`). An exact distance
    test on them leaves the same set as a k-d tree's ``query_pairs(r)``.

    Parameters
    ----------
    xy : array_like, shape (K, 2)
    r : float
        >= 0, units of ``xy``.

    Returns
    -------
    ndarray of int64, shape (Q, 2)
    """
    pts = np.ascontiguousarray(as_float_array(xy, "xy", last_dim=2, ndim=2))
    return ck.candidate_pairs(pts, check_positive(r, "r", allow_zero=True))


def _pixel_fidelity(scene, model, rng, k, method, min_area_px, psf_sigma_px, include_false) -> Centroids:
    # checked by simulate_detections (or its per-frame caller's contract)
    if include_false:
        sf = render_sparse(scene, model, rng, k, validate=False)
    else:
        sf = render_sparse(scene, replace(model, hot_pixel_fraction=0.0), rng, k,
                           false_objects=FalseObjects.none(), draw_crossings=False, validate=False)
    return detections_from_sparse(sf, method, min_area_px=min_area_px, psf_sigma_px=psf_sigma_px, validate=False)


def simulate_detections(
    scene: Scene,
    model: SensorModel,
    rng: np.random.Generator,
    fidelity: str = "centroid",
    *,
    k_sigma: float = 5.0,
    method: str = "com",
    min_area_px: int = 1,
    psf_sigma_px: float | None = None,
    error_model: CentroidErrorModel | None = None,
    include_false: bool = True,
    validate: bool = True,
) -> Centroids:
    """Detections of one frame with truth labels, without drawing the full frame.

    Parameters
    ----------
    scene : Scene
    model : SensorModel
    rng : numpy.random.Generator
    fidelity : {"centroid", "pixel"}
        "pixel": sparse rendering and centroiding; "centroid": drawn from the calibrated error model.
    k_sigma, method, min_area_px, psf_sigma_px
        As in :func:`extract_centroids`.
    error_model : CentroidErrorModel, optional
        Centroid fidelity only; default :func:`default_error_model` for ``model`` and ``method``.
    include_false : bool
        Draw hot pixels, cosmic rays, debris and background threshold crossings.
    validate : bool
        False skips the argument checks, for a per-frame caller that passes the types above, a float
        ``k_sigma``, a known method and an int ``min_area_px``.

    Returns
    -------
    Centroids
        Brightest first, with ``truth_star``, ``truth_exposure``, ``truth_kind``, ``truth_xy``.

    Notes
    -----
    The centroid fidelity draws, in this order: the false objects (:func:`startracker.imaging.draw_false_objects`),
    one uniform and three normals per candidate spot (``N M + N D + C``: stars, debris dashes, cosmic rays), one
    normal per hot pixel, the background's threshold crossings; then one compiled call makes the detections
    (:func:`startracker.kernels.centroid.centroid_detections`).
    """
    if validate:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
        if not isinstance(model, SensorModel):
            raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        k_sigma = check_k_sigma(k_sigma)
        check_method(method)
        min_area_px = check_min_area(min_area_px)
        psf_sigma_px = check_psf_sigma(psf_sigma_px)
    if fidelity == "pixel":
        return _pixel_fidelity(scene, model, rng, k_sigma, method, min_area_px, psf_sigma_px, include_false)
    if fidelity == "centroid":
        err = default_error_model(model, method) if error_model is None else error_model
        if validate:
            if not isinstance(err, CentroidErrorModel):
                raise TypeError("error_model must be a CentroidErrorModel")
            if err.method != method:
                raise ValueError(f"error_model was calibrated for method {err.method!r}, not {method!r}")
        c = _centroid_fidelity(scene, model, rng, k_sigma, err, include_false)
        return c.subset(c.area >= min_area_px) if min_area_px > 1 else c
    raise ValueError(f"fidelity must be 'centroid' or 'pixel', got {fidelity!r}")


def grid_scene(camera, plan, vmag_lo, vmag_hi, speed_px_s, spacing_px, rng):
    """Stars on a jittered grid, random magnitudes and motion directions (calibration scenes)."""
    from startracker.scene import scene_from_tracks

    w, h = camera.resolution
    gx = np.arange(spacing_px / 2, w - spacing_px / 2 + 1e-9, spacing_px)
    gy = np.arange(spacing_px / 2, h - spacing_px / 2 + 1e-9, spacing_px)
    X, Y = np.meshgrid(gx, gy)
    xy = np.column_stack([X.ravel(), Y.ravel()]) + rng.uniform(-0.5, 0.5, (X.size, 2))
    vm = rng.uniform(vmag_lo, vmag_hi, len(xy))
    ang = rng.uniform(0, 2 * np.pi, len(xy))
    vel = speed_px_s * np.column_stack([np.cos(ang), np.sin(ang)])
    return scene_from_tracks(camera, plan, xy, vm, vel)


def _star_errors(det: Centroids, scene: Scene):
    """First detection of each scene star: detected (N*M,), error along/cross the motion (N*M, 2)."""
    n, m = scene.n_exposures, scene.n_stars
    found = np.zeros(n * m, dtype=bool)
    err = np.full((n * m, 2), np.nan)
    st = np.flatnonzero(det.truth_kind == KIND_STAR)
    key = det.truth_exposure[st] * m + det.truth_star[st]
    u, first = np.unique(key, return_index=True)
    found[u] = True
    e = det.xy[st[first]] - det.truth_xy[st[first]]
    d = (scene.xy_end - scene.xy_start).reshape(-1, 2)[u]
    ln = np.linalg.norm(d, axis=1)
    al = np.where(ln[:, None] > 1e-9, d / np.maximum(ln, 1e-12)[:, None], np.array([1.0, 0.0]))
    err[u, 0] = (e * al).sum(axis=1)
    err[u, 1] = -e[:, 0] * al[:, 1] + e[:, 1] * al[:, 0]
    return found, err


def _theory_for_scene(scene: Scene, model: SensorModel, k_sigma: float, err: CentroidErrorModel):
    bg = background_field(scene, model)
    xy = scene.xy_mean.reshape(-1, 2)
    var_b = (bg.var_e(xy[:, 0], xy[:, 1]) / model.gain_e_per_dn**2 + 1.0 / 12.0) * model.gain_e_per_dn**2
    s_pe = np.tile(model.star_pe(scene.vmag, scene.bv, scene.plan.exposure_s), scene.n_exposures)
    return _spot_theory(s_pe, model.intensifier_gain, model.excess_noise_factor**2, model.sigma_px,
                        model.optics_sigma_px, model.splash_energy, scene.smear_px.reshape(-1), var_b,
                        k_sigma * np.sqrt(var_b), err, model.intensified)


def _brighter_sky(model: SensorModel, scene: Scene, sigma_ratio: float) -> SensorModel:
    """``model`` with its sky brightened until the background noise σ is ``sigma_ratio`` times its own (the
    optical charge q solves ``enf2_c q + PRNU² q² = (ratio² − 1) var_e`` on top of the model's sky)."""
    if sigma_ratio == 1.0:
        return model
    if not sigma_ratio > 1.0:
        raise ValueError(f"background_sigma_ratios must be >= 1, got {sigma_ratio}")
    bg = background_field(scene, model)
    extra = (sigma_ratio**2 - 1.0) * bg.var_e_centre
    a, b = bg.prnu_sigma**2, bg.enf2_c
    q = extra / b if a == 0.0 else (-b + math.sqrt(b * b + 4.0 * a * extra)) / (2.0 * a)
    q_sky = bg.gain * max(bg.opt0, 1e-300)
    mag = model.sky_mag_per_arcsec2 - 2.5 * math.log10((q_sky + q) / q_sky)
    return replace(model, sky_mag_per_arcsec2=float(mag))


def calibrate_error_model(
    model: SensorModel,
    rng: np.random.Generator,
    *,
    camera=None,
    exposure_s: float | None = None,
    smear_px=(0.0, 2.0),
    n_frames: int = 4,
    k_sigma: float = 5.0,
    method: str = "com",
    min_log_ratio: float = 0.5,
    background_sigma_ratios=(1.0, 6.0),
) -> CentroidErrorModel:
    """Fit the centroid-fidelity factors to the pixel path (sparse rendering + centroiding).

    Stars on a 60-px grid, magnitudes spanning certain to rare detection, one exposure per frame at each
    streak length and background level; no false objects. ``peak_factor`` maximises the Bernoulli likelihood of
    the pixel path's detections; the photon, background and pixel-locking factors are a non-negative weighted
    least-squares fit of the squared centroid errors (along and across the motion) on the three variance terms.
    The background levels (the model's sky, and a brighter sky whose pixel noise σ is the given multiple of it,
    as stray light makes it) let the fit tell the photon terms from the background terms.

    Parameters
    ----------
    model : SensorModel
    rng : numpy.random.Generator
    camera : Camera, optional
        Default paper 000's.
    exposure_s : float, optional
        Default 1 ms with an intensifier, 20 ms without.
    smear_px : sequence of float
        Streak lengths to calibrate on (image speed = smear / exposure).
    n_frames : int
        Frames per speed.
    k_sigma : float
    method : {"com", "gaussian"}
    min_log_ratio : float
    background_sigma_ratios : sequence of float
        Background noise σ of the calibration frames, in units of the model's own sky (>= 1; 1: the model's sky).

    Returns
    -------
    CentroidErrorModel
    """
    from scipy.optimize import nnls

    from startracker.optics import camera_preset
    from startracker.scene import ExposurePlan

    if not isinstance(model, SensorModel):
        raise TypeError("model must be a SensorModel")
    cam = camera_preset("paper000") if camera is None else camera
    tau = (1e-3 if model.intensified else 0.02) if exposure_s is None else float(exposure_s)
    plan = ExposurePlan(1, tau, frame_period_s=max(0.1, tau))
    k = check_k_sigma(k_sigma)
    quiet = replace(model, hot_pixel_fraction=0.0, cosmic_ray_rate_per_cm2_s=0.0, debris_rate_per_frame=0.0)
    probe = grid_scene(cam, plan, 0.0, 0.0, 0.0, cam.resolution[0] / 2, rng)
    base = CentroidErrorModel(min_log_ratio=min_log_ratio, method=method)
    rows = []
    for ratio in background_sigma_ratios:
        md = _brighter_sky(quiet, probe, float(ratio))
        # magnitude where a still spot's peak equals the threshold
        th0 = _theory_for_scene(probe, md, k, base)
        thr_e = k * math.sqrt(float(background_field(probe, md).var_e(0, 0)) + model.gain_e_per_dn**2 / 12)
        v_thr = float(2.5 * np.log10(np.median(th0["peak"]) / thr_e))
        for smear in smear_px:
            speed = float(smear) / tau
            for _ in range(int(n_frames)):
                sc = grid_scene(cam, plan, v_thr - 4.0, v_thr + 0.8, float(speed), 60.0, rng)
                det = simulate_detections(sc, md, rng, "pixel", k_sigma=k, method=method, include_false=False)
                found, e = _star_errors(det, sc)
                rows.append((sc, md, found, e))

    def loglik(pf):
        ll = 0.0
        for sc, md, found, _ in rows:
            p = np.clip(_theory_for_scene(sc, md, k, replace(base, peak_factor=pf))["p_det"], 1e-9, 1 - 1e-9)
            vis = sc.visible.reshape(-1)
            ll += np.sum(np.where(found, np.log(p), np.log1p(-p))[vis])
        return ll

    grid = np.linspace(0.6, 3.0, 49)
    pf = float(grid[np.argmax([loglik(g) for g in grid])])
    fine = np.linspace(pf - 0.05, pf + 0.05, 21)
    pf = float(fine[np.argmax([loglik(g) for g in fine])])
    X, y = [], []
    for sc, md, found, e in rows:
        th = _theory_for_scene(sc, md, k, replace(base, peak_factor=pf))
        ok = found & np.all(np.abs(e) < 3.0, axis=1)
        for j, ax in enumerate(("along", "cross")):
            X.append(np.column_stack([th["ph_" + ax][ok], th["bg_" + ax][ok], th["lock_" + ax][ok]]))
            y.append(e[ok, j] ** 2)
    X = np.concatenate(X)
    y = np.concatenate(y)
    coef = np.ones(3)
    for _ in range(3):  # weights 1/predicted variance: the squared error of a Gaussian has sd ∝ its variance
        w = 1.0 / np.maximum(X @ coef, 1e-8)
        coef, _ = nnls(X * w[:, None], y * w)
        coef = np.maximum(coef, 1e-3)
    return CentroidErrorModel(pf, float(coef[0]), float(coef[1]), float(coef[2]), min_log_ratio, method)


def predicted_centroid_sigma_px(model: SensorModel, camera, vmag, exposure_s: float, *, smear_px: float = 0.0,
                                k_sigma: float = 5.0, method: str = "com", error_model: CentroidErrorModel | None = None):
    """Centroid error and detection probability of single spots, from the calibrated centroid-fidelity theory.

    The spots sit at the principal point of ``camera`` (quiet sky, no bright body), one exposure of
    ``exposure_s`` seconds, streaked by ``smear_px``.

    Parameters
    ----------
    model : SensorModel
    camera : startracker.optics.Camera
    vmag : array_like, shape (K,)
        V magnitudes (B−V = 0).
    exposure_s : float
        Exposure time, s.
    smear_px : float
        Streak length, px.
    k_sigma : float
    method : {"com", "gaussian"}
    error_model : CentroidErrorModel, optional
        Default :func:`default_error_model` of ``model``.

    Returns
    -------
    sigma_px : ndarray, shape (K,)
        Per-axis 1σ centroid error, sqrt of the mean of the along- and cross-motion variances, px.
    p_detect : ndarray, shape (K,)
        Detection probability.
    """
    from startracker.scene import ExposurePlan, scene_from_tracks

    if not isinstance(model, SensorModel):
        raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
    v = as_float_array(vmag, "vmag", ndim=1)
    tau = check_positive(exposure_s, "exposure_s")
    smear = check_positive(smear_px, "smear_px", allow_zero=True)
    err = default_error_model(model, method) if error_model is None else error_model
    plan = ExposurePlan(1, tau, frame_period_s=tau)
    xy = np.tile(np.asarray(camera.principal_point, dtype=np.float64), (len(v), 1))
    vel = np.tile([smear / tau, 0.0], (len(v), 1))
    th = _theory_for_scene(scene_from_tracks(camera, plan, xy, v, vel), model, check_k_sigma(k_sigma), err)
    return np.sqrt(0.5 * (th["var_along"] + th["var_cross"])), th["p_det"]
