"""The expected background of a frame (sky, stray light, dark current) and its false objects.

False objects are the transient sources drawn per frame: cosmic rays and debris crossing the field.
Part of :mod:`startracker.imaging`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from startracker.imaging.detector import SensorModel
from startracker.validation import build_checked, check_rng
from startracker.scene import Scene

__all__ = [
    "BackgroundField",
    "FalseObjects",
    "background_field",
    "draw_false_objects",
    "COSMIC_SIGMA_PX",
    "COSMIC_MAX_LEN_PX",
]


COSMIC_SIGMA_PX = 0.5
"""Charge diffusion of a cosmic-ray track, px (Gaussian σ across the track)."""
COSMIC_MAX_LEN_PX = 6.0
"""Longest cosmic-ray track on the detector, px."""


# ----------------------------------------------------------------------------------- background
@dataclass(frozen=True)
class BackgroundField:
    """Expected background of one frame; planar in the pixel coordinates.

    ``optical_pe(x, y) = opt0 + opt_dx (x − cx) + opt_dy (y − cy)`` photoelectrons accumulated over the N
    exposures (sky + stray light); dark current ``dark_e`` over the integration window.

    ``blinded`` says a bright body is inside its baffle's exclusion cone (a design limit). Whether stars are lost
    follows from the level itself, pixel by pixel, in both fidelities: no pixel reads above the detector's
    saturation, so where ``floor(threshold_dn) + 1`` exceeds it nothing can be detected.
    """

    opt0: float
    opt_dx: float
    opt_dy: float
    cx: float
    cy: float
    dark_e: float
    integration_s: float
    gain: float
    enf2_c: float  # G F² c, variance of pixel charge per unit charge for light through the intensifier
    read_var_e2: float
    prnu_sigma: float
    gain_e_per_dn: float
    bias_dn: float
    blinded: bool

    @property
    def flat(self) -> bool:
        """No gradient: the optical background is the same everywhere."""
        return self.opt_dx == 0.0 and self.opt_dy == 0.0

    def optical_pe(self, x, y) -> np.ndarray:
        if self.flat:
            v = max(self.opt0, 0.0)
            if np.ndim(x) == 0 and np.ndim(y) == 0:
                return v
            return np.full(np.broadcast_shapes(np.shape(x), np.shape(y)), v)
        return np.maximum(self.opt0 + self.opt_dx * (np.asarray(x) - self.cx) + self.opt_dy * (np.asarray(y) - self.cy), 0.0)

    def mean_e(self, x, y) -> np.ndarray:
        """Expected background charge (no hot pixels, no PRNU), e⁻."""
        return self.gain * self.optical_pe(x, y) + self.dark_e

    def var_e(self, x, y, include_prnu: bool = True) -> np.ndarray:
        """Pixel-to-pixel variance of the background, e⁻² (shot, dark, read; PRNU as a fixed pattern)."""
        q = self.gain * self.optical_pe(x, y)
        v = self.enf2_c * q + self.dark_e + self.read_var_e2
        if include_prnu:
            v = v + (self.prnu_sigma * q) ** 2
        return v

    def mean_dn(self, x, y) -> np.ndarray:
        return self.mean_e(x, y) / self.gain_e_per_dn + self.bias_dn

    def sigma_dn(self, x, y) -> np.ndarray:
        """Background noise in DN including quantisation (1/12 DN²)."""
        return np.sqrt(self.var_e(x, y) / self.gain_e_per_dn**2 + 1.0 / 12.0)

    def threshold_dn(self, x, y, k_sigma: float) -> np.ndarray:
        """Detection threshold ``mean + k σ`` in DN (a pixel is above it when DN > threshold)."""
        return self.mean_dn(x, y) + k_sigma * self.sigma_dn(x, y)

    # The values at the principal point, once per field: a quiet sky's field is one object for every frame
    # (background_field), and each per-frame call of the array methods on two scalars costs ~2.5 µs.
    @cached_property
    def var_e_centre(self) -> float:
        """:meth:`var_e` at the principal point ``(cx, cy)``, e⁻²."""
        return float(self.var_e(self.cx, self.cy))

    @cached_property
    def mean_dn_centre(self) -> float:
        """:meth:`mean_dn` at the principal point, DN."""
        return float(self.mean_dn(self.cx, self.cy))

    @cached_property
    def sigma_dn_centre(self) -> float:
        """:meth:`sigma_dn` at the principal point, DN."""
        return float(self.sigma_dn(self.cx, self.cy))


_QUIET_CACHE: dict = {}


def background_field(scene: Scene, model: SensorModel) -> BackgroundField:
    """The frame's expected background from the sky, the bright bodies (stray light) and dark current.

    Without bright bodies the background depends only on the (frozen) camera, plan and model: it is computed
    once per such triple and the same object is returned for every frame.

    Raises
    ------
    ValueError
        A bright body whose name has no entry in ``model.stray_light``.
    """
    cam = scene.camera
    plan = scene.plan
    if not scene.bright_bodies:
        key = (id(cam), id(model), plan)
        hit = _QUIET_CACHE.get(key)
        if hit is not None and hit[0] is cam and hit[1] is model:
            return hit[2]
        bg = _background_field(scene, cam, plan, model)
        if len(_QUIET_CACHE) > 64:
            _QUIET_CACHE.clear()
        _QUIET_CACHE[key] = (cam, model, bg)
        return bg
    return _background_field(scene, cam, plan, model)


def _background_field(scene: Scene, cam, plan, model: SensorModel) -> BackgroundField:
    t_open = plan.total_exposure_s
    sky_rate = model.photometry.surface_pe_rate_per_px(model.sky_mag_per_arcsec2, cam.pixel_size_um, cam.focal_length_mm)
    opt0 = sky_rate * t_open
    opt_dx = opt_dy = 0.0
    w, h = cam.resolution
    r_max = 0.5 * math.hypot(w, h)
    blinded = False
    for body in scene.bright_bodies:
        if body.name not in model.stray_light:
            raise ValueError(f"bright body {body.name!r} has no stray_light response (known: {sorted(model.stray_light)})")
        resp = model.stray_light[body.name]
        rate = float(np.mean(resp.pe_rate_per_px(body.angle_rad)))
        blinded |= bool(np.any(resp.inside_exclusion(body.angle_rad)))
        d = body.direction_cam.mean(axis=0)
        u = d[:2]
        nu = np.linalg.norm(u)
        u = u / nu if nu > 1e-12 else np.zeros(2)
        opt0 += rate * t_open
        opt_dx += rate * t_open * resp.gradient_fraction * u[0] / r_max
        opt_dy += rate * t_open * resp.gradient_fraction * u[1] / r_max
    g = model.intensifier_gain
    return BackgroundField(
        opt0=float(opt0),
        opt_dx=float(opt_dx),
        opt_dy=float(opt_dy),
        cx=cam.principal_point[0],
        cy=cam.principal_point[1],
        dark_e=model.dark_current_e_per_s * plan.integration_window_s,
        integration_s=plan.integration_window_s,
        gain=g,
        enf2_c=g * model.excess_noise_factor**2 * model.splash_energy,
        read_var_e2=model.read_noise_e**2,
        prnu_sigma=model.prnu_sigma,
        gain_e_per_dn=model.gain_e_per_dn,
        bias_dn=model.bias_dn,
        blinded=blinded,
    )


# ----------------------------------------------------------------------------------- false objects
@dataclass(frozen=True, eq=False)
class FalseObjects:
    """Non-star light of one frame.

    Attributes
    ----------
    debris_xy0 : ndarray, shape (D, 2)
        Debris position at the frame's middle instant, px.
    debris_velocity_px_s : ndarray, shape (D, 2)
    debris_vmag : ndarray, shape (D,)
    cosmic_start_xy, cosmic_end_xy : ndarray, shape (C, 2)
        Cosmic-ray track ends, px.
    cosmic_e : ndarray, shape (C,)
        Deposited charge, e⁻.
    """

    debris_xy0: np.ndarray
    debris_velocity_px_s: np.ndarray
    debris_vmag: np.ndarray
    cosmic_start_xy: np.ndarray
    cosmic_end_xy: np.ndarray
    cosmic_e: np.ndarray

    @classmethod
    def none(cls) -> "FalseObjects":
        """No false objects (one shared instance: its arrays are empty, so nothing can be written into them)."""
        return _NONE


_NONE = FalseObjects(*(np.zeros(shape) for shape in ((0, 2), (0, 2), 0, (0, 2), (0, 2), 0)))
_AREA_CACHE: dict = {}
_SIZE_CACHE: dict = {}
# the log-uniform debris speed, 100-20000 px/s (numpy's log, as the per-frame formula had it)
_LOG_SPEED_LO = np.log(100.0)
_LOG_SPEED_SPAN = np.log(20000.0) - np.log(100.0)


def _detector_size(cam) -> np.ndarray:
    """``(width, height)`` of a (frozen) camera's detector as a read-only float array, px (once per camera)."""
    hit = _SIZE_CACHE.get(id(cam))
    if hit is not None and hit[0] is cam:
        return hit[1]
    size = np.array(cam.resolution, dtype=float)
    size.setflags(write=False)
    if len(_SIZE_CACHE) > 64:
        _SIZE_CACHE.clear()
    _SIZE_CACHE[id(cam)] = (cam, size)
    return size


def _detector_area_cm2(cam) -> float:
    """Sensitive area of a (frozen) camera's detector, cm² (once per camera object)."""
    hit = _AREA_CACHE.get(id(cam))
    if hit is not None and hit[0] is cam:
        return hit[1]
    w, h = cam.resolution
    area = (w * cam.pixel_size_um * 1e-4) * (h * cam.pixel_size_um * 1e-4)
    if len(_AREA_CACHE) > 64:
        _AREA_CACHE.clear()
    _AREA_CACHE[id(cam)] = (cam, area)
    return area


def draw_false_objects(scene: Scene, model: SensorModel, rng: np.random.Generator, *, validate: bool = True) -> FalseObjects:
    """Draw the frame's debris streaks and cosmic-ray hits.

    Debris: ``Poisson(debris_rate_per_frame)`` objects, uniform over the detector, moving in a uniform
    direction at a log-uniform 100–20000 px/s (seen as one dash per exposure). Cosmic rays:
    ``Poisson(rate · area · integration window)`` straight tracks 0–6 px long, log-normal charge.
    ``validate=False`` skips the check of ``rng`` (a per-frame caller that checked it).
    """
    if validate:
        check_rng(rng)
    cam = scene.camera
    area_cm2 = _detector_area_cm2(cam)
    # two scalar draws: the same stream as one draw of the pair
    n_d = int(rng.poisson(model.debris_rate_per_frame))
    n_c = int(rng.poisson(model.cosmic_ray_rate_per_cm2_s * area_cm2 * scene.plan.integration_window_s))
    if n_d == 0 and n_c == 0:
        return _NONE
    size = _detector_size(cam)
    # the arithmetic of the original one-line formulas, in place where an array is this call's own, with the columns
    # joined by one concatenate (np.stack costs ~3 µs of Python a call): the same operations on the same operands
    if n_d:
        u = rng.random((n_d, 6))  # position (2), direction, log-speed, magnitude, unused
        xy0 = u[:, :2] * size
        xy0 -= 0.5
        ang = 2 * np.pi * u[:, 2]
        speed = np.exp(_LOG_SPEED_LO + _LOG_SPEED_SPAN * u[:, 3])
        vel = np.concatenate(((np.cos(ang) * speed)[:, None], (np.sin(ang) * speed)[:, None]), axis=1)
        vmag = model.debris_vmag_range[0] + (model.debris_vmag_range[1] - model.debris_vmag_range[0]) * u[:, 4]
    else:  # nothing drawn for no debris: the shared empty arrays
        xy0, vel, vmag = _NONE.debris_xy0, _NONE.debris_velocity_px_s, _NONE.debris_vmag
    if n_c:
        v = rng.random((n_c, 4))  # position (2), direction, length
        start = v[:, :2] * size
        start -= 0.5
        a = 2 * np.pi * v[:, 2]
        length = COSMIC_MAX_LEN_PX * v[:, 3]
        end = np.concatenate(((np.cos(a) * length)[:, None], (np.sin(a) * length)[:, None]), axis=1)
        end += start  # start + the track
        z = rng.standard_normal(n_c)
        z *= 0.6
        charge = np.exp(z)
        charge *= model.cosmic_ray_median_e
    else:
        start, end, charge = _NONE.cosmic_start_xy, _NONE.cosmic_end_xy, _NONE.cosmic_e
    # the fields set at once (FalseObjects has no checks of its own)
    return build_checked(FalseObjects, {"debris_xy0": xy0, "debris_velocity_px_s": vel, "debris_vmag": vmag,
                                        "cosmic_start_xy": start, "cosmic_end_xy": end, "cosmic_e": charge})


