"""Pixels: star spots (PSF, smear), photometry, detector noise, stray light and false objects.

The signal chain of one frame (all randomness from the caller's ``rng``)::

    star V, B−V ── Photometry ──> photoelectrons per exposure  S = rate · τ
    spot shape  : Gaussian PSF σ = hypot(psf_sigma_px, defocus_sigma_px), pixel-integrated (erf), swept
                  along the true path of the exposure (smear; the path is cut into segments ≤ 4σ long,
                  each drawn as K sub-spots d ≤ σ/2 apart at the midpoints of equal time slices: the
                  centroid is exact and the along-track variance is short of the continuous streak's by
                  d²/12 ≤ σ²/48)
    optical bg  : sky (mag/arcsec²) + stray light of bright bodies, accumulated over the N exposures
    detector    : dark current and cosmic rays over the integration window, hot pixels, PRNU,
                  full well, read noise, gain (e-/DN), bias, ADC bits

Two detector kinds share the code:

* **CMOS** (``intensifier_gain == 1``): star photoelectrons are Poisson per pixel (exact).
* **Intensified CMOS** (``intensifier_gain > 1``, paper 000's multi-exposure tracker is intensified:
  its reference [22] is "Multiexposure imaging ... for intensified star trackers"). Each photoelectron
  of the photocathode is multiplied by the MCP into ``G`` electrons on average with excess-noise factor
  ``F`` (gain ~ Gamma, so var = G² F² S) and lands on the CMOS as a *splash* of width
  ``intensifier_splash_sigma_px``. A spot is therefore drawn as a smooth PSF whose total charge is
  ``Gamma(k n, G/k)`` with ``n ~ Poisson(S)``, ``k = 1/(F²−1)``, and whose centre is displaced by the
  scatter of the photoelectron positions (``N(0, F² σ_o² / n)`` with σ_o the optics' part of the PSF,
  plus ``F² L²/12 / n`` along a streak of length L); on top, each pixel carries Gaussian "shape noise"
  of variance ``G F² c Q`` (Q the pixel's charge, ``c = Σ K²`` the splash kernel's energy). Diffuse
  light through the intensifier gets the same pixel variance. This keeps the centroid and total-signal
  statistics of the photon-counting process while pixels stay smooth as a real intensified image.

Diffuse background (sky, stray light) and dark current are Gaussian with their shot-noise variance in
both kinds; read noise is Gaussian; charge is clipped at the full well, then quantised
``DN = clip(rint(e / gain + bias), 0, 2**bits − 1)``.

Rendering paths
---------------
* :func:`render_frame` draws the full frame (for ``render()`` and tests).
* :func:`render_sparse` draws only windows around the spots (the pixels where a spot's expected light
  exceeds 0.3 σ of the background noise: a dropped pixel's chance of crossing a 5σ threshold rises
  from 2.9e-7 to at most 1.3e-6, about 0.02 missed crossings per frame of 450 spots), hot pixels and
  cosmic rays, and draws the rest of the background's threshold crossings from its statistics: per
  cell of a grid fine enough that the background changes by < 0.25 DN across a cell (at most 64×64,
  one cell when the background is flat), a Poisson number of crossing pixels
  with mean ``n_px · P(DN > threshold)``, uniform positions, values from the Gaussian tail above the
  threshold, each with its 3×3 neighbourhood drawn as plain background. Pixels are deduplicated with a
  persistent index buffer (no sort), so overlapping windows share one noisy value. Both paths use
  :func:`_pixels_to_dn`, so their statistics agree (tests/test_imaging.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from types import MappingProxyType
from typing import Mapping

import numpy as np
from scipy.special import ndtr, ndtri

from startracker.photometry import Photometry
from startracker.scene import Scene

__all__ = [
    "SensorModel",
    "StrayLightResponse",
    "FalseObjects",
    "BackgroundField",
    "SourceTable",
    "SparseFrame",
    "draw_false_objects",
    "background_field",
    "fixed_pattern",
    "render_frame",
    "render_expected",
    "render_sparse",
    "KIND_STAR",
    "KIND_NOISE",
    "KIND_HOT_PIXEL",
    "KIND_COSMIC_RAY",
    "KIND_DEBRIS",
    "SOURCE_KIND_NAMES",
]

KIND_STAR, KIND_NOISE, KIND_HOT_PIXEL, KIND_COSMIC_RAY, KIND_DEBRIS = range(5)
SOURCE_KIND_NAMES = ("star", "noise", "hot_pixel", "cosmic_ray", "debris")
_COSMIC_SIGMA_PX = 0.5  # charge diffusion of a cosmic-ray track
_COSMIC_MAX_LEN_PX = 6.0
_SPARSE_FLOOR = 0.3  # sparse windows keep pixels whose expected light exceeds this fraction of the noise σ
_FULL_FLOOR = 0.02  # the full frame draws spots out to where they fall to this fraction of the noise σ
_FALSE_GRID = 64  # cells per axis for drawing the background's threshold crossings


def _num(value, name, lo=None, hi=None, lo_open=False, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    if integer and int(value) != value:
        raise ValueError(f"{name} must be an integer, got {value}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ValueError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {value}")
    if hi is not None and v > hi:
        raise ValueError(f"{name} must be <= {hi}, got {value}")
    return v


# ----------------------------------------------------------------------------------------- models
@dataclass(frozen=True)
class StrayLightResponse:
    """How much light a bright body scatters onto the detector, by angle from the boresight.

    Background rate at the principal point ``B(θ) = B_excl (θ_excl / θ)^p`` pe s⁻¹ px⁻¹, rising steeply
    inside the exclusion angle (the frame washes out and saturates); across the detector it ramps
    linearly toward the body: ``B(θ) (1 + g · (r · u) / r_max)`` with u the body's direction projected
    on the image plane and r_max the half-diagonal in px.

    Parameters
    ----------
    exclusion_angle_deg : float
        Baffle exclusion half-angle θ_excl, deg.
    pe_rate_at_exclusion_per_px_s : float
        B_excl, photoelectrons per pixel per second at θ = θ_excl.
    falloff_exponent : float
        p.
    gradient_fraction : float
        g in [0, 1).
    """

    exclusion_angle_deg: float
    pe_rate_at_exclusion_per_px_s: float
    falloff_exponent: float = 3.0
    gradient_fraction: float = 0.5

    def __post_init__(self):
        _num(self.exclusion_angle_deg, "exclusion_angle_deg", 0.0, 180.0, lo_open=True)
        _num(self.pe_rate_at_exclusion_per_px_s, "pe_rate_at_exclusion_per_px_s", 0.0)
        _num(self.falloff_exponent, "falloff_exponent", 0.0)
        _num(self.gradient_fraction, "gradient_fraction", 0.0, 0.999)

    def pe_rate_per_px(self, angle_rad) -> np.ndarray:
        """B(θ) at the principal point, pe s⁻¹ px⁻¹, for angles θ (rad) from the boresight."""
        theta = np.maximum(np.asarray(angle_rad, dtype=np.float64), 1e-4)
        return self.pe_rate_at_exclusion_per_px_s * (math.radians(self.exclusion_angle_deg) / theta) ** self.falloff_exponent

    def inside_exclusion(self, angle_rad) -> np.ndarray:
        """True where the body is inside the exclusion cone (the frame is blinded)."""
        return np.asarray(angle_rad) < math.radians(self.exclusion_angle_deg)


DEFAULT_STRAY_LIGHT = MappingProxyType(
    {
        "sun": StrayLightResponse(30.0, 200.0, 4.0, 0.6),
        "moon": StrayLightResponse(12.0, 5.0, 3.0, 0.4),
        "earth": StrayLightResponse(20.0, 50.0, 3.0, 0.6),
    }
)


@dataclass(frozen=True, eq=False)
class SensorModel:
    """Everything between photons at the aperture and numbers in the image (see the module docstring).

    Defaults are ``SensorModel.preset("paper000")``: paper 000's optics (f = 31.94 mm, 5.5 µm pixels,
    2048²) at f/1.2 behind an image intensifier, as a multi-exposure tracker must be to see stars in
    1 ms exposures. Use ``dataclasses.replace(model, read_noise_e=0.0)`` to vary one parameter.

    Parameters
    ----------
    psf_sigma_px : float
        Gaussian PSF standard deviation (optics and, when intensified, the splash), px.
    defocus_sigma_px : float
        Extra Gaussian blur added in quadrature (defocus), px.
    photometry : Photometry
        Aperture, band, transmission, QE, zero point.
    intensifier_gain : float
        Mean CMOS electrons per photoelectron, G (1 = no intensifier: a plain CMOS).
    excess_noise_factor : float
        F >= 1 of the intensifier gain (var = G² F² S); 1 for a plain CMOS.
    intensifier_splash_sigma_px : float
        Width of one photoelectron's splash on the CMOS, px (<= the total PSF σ).
    sky_mag_per_arcsec2 : float
        Diffuse sky (zodiacal light, background stars) surface brightness, V mag/arcsec².
    dark_current_e_per_s : float
        CMOS dark current, e⁻ px⁻¹ s⁻¹ (integrates over the integration window).
    read_noise_e : float
        e⁻ rms.
    prnu_sigma : float
        Pixel response non-uniformity, relative rms (fixed pattern).
    hot_pixel_fraction : float
        Fraction of pixels with a high dark current (fixed pattern).
    hot_pixel_dark_e_per_s : (float, float)
        Log-uniform range of the hot pixels' dark current, e⁻/s.
    full_well_e : float
        Charge clip, e⁻.
    adc_bits : int
        1..24.
    gain_e_per_dn : float
        Conversion gain, e⁻ per DN.
    bias_dn : float
        Offset added before quantisation, DN.
    stray_light : mapping str -> StrayLightResponse
        Baffle response per bright body (keys "sun", "moon", "earth").
    cosmic_ray_rate_per_cm2_s : float
        Hits per cm² of detector per second (≈ 5 in LEO away from the SAA).
    cosmic_ray_median_e : float
        Median charge of a hit (log-normal, σ_ln = 0.6), e⁻.
    debris_rate_per_frame : float
        Mean number of sunlit debris objects crossing a frame.
    debris_vmag_range : (float, float)
        Uniform V range of debris.
    fixed_pattern_seed : int
        Seed of the PRNU map and hot-pixel list (a property of the detector, not of a frame).
    name : str
    """

    psf_sigma_px: float = 1.2
    defocus_sigma_px: float = 0.0
    photometry: Photometry = field(default_factory=Photometry)
    intensifier_gain: float = 40.0
    excess_noise_factor: float = 1.3
    intensifier_splash_sigma_px: float = 0.9
    sky_mag_per_arcsec2: float = 22.5
    dark_current_e_per_s: float = 20.0
    read_noise_e: float = 5.0
    prnu_sigma: float = 0.01
    hot_pixel_fraction: float = 2e-6
    hot_pixel_dark_e_per_s: tuple[float, float] = (200.0, 5000.0)
    full_well_e: float = 15000.0
    adc_bits: int = 12
    gain_e_per_dn: float = 2.0
    bias_dn: float = 64.0
    stray_light: Mapping[str, StrayLightResponse] = field(default_factory=lambda: dict(DEFAULT_STRAY_LIGHT))
    cosmic_ray_rate_per_cm2_s: float = 5.0
    cosmic_ray_median_e: float = 2000.0
    debris_rate_per_frame: float = 0.05
    debris_vmag_range: tuple[float, float] = (3.0, 7.0)
    fixed_pattern_seed: int = 0
    name: str = "paper000"

    def __post_init__(self):
        _num(self.psf_sigma_px, "psf_sigma_px", 0.0, 50.0, lo_open=True)
        _num(self.defocus_sigma_px, "defocus_sigma_px", 0.0, 50.0)
        if not isinstance(self.photometry, Photometry):
            raise TypeError("photometry must be a startracker.photometry.Photometry")
        _num(self.intensifier_gain, "intensifier_gain", 1.0)
        _num(self.excess_noise_factor, "excess_noise_factor", 1.0, 10.0)
        _num(self.intensifier_splash_sigma_px, "intensifier_splash_sigma_px", 0.0, lo_open=True)
        if self.intensified and self.intensifier_splash_sigma_px > self.sigma_px:
            raise ValueError(
                f"intensifier_splash_sigma_px ({self.intensifier_splash_sigma_px}) must not exceed the PSF sigma ({self.sigma_px})"
            )
        _num(self.sky_mag_per_arcsec2, "sky_mag_per_arcsec2", 0.0, 40.0)
        _num(self.dark_current_e_per_s, "dark_current_e_per_s", 0.0)
        _num(self.read_noise_e, "read_noise_e", 0.0)
        _num(self.prnu_sigma, "prnu_sigma", 0.0, 0.5)
        _num(self.hot_pixel_fraction, "hot_pixel_fraction", 0.0, 0.01)
        lo_hot, hi_hot = self.hot_pixel_dark_e_per_s
        _num(lo_hot, "hot_pixel_dark_e_per_s[0]", 0.0, lo_open=True)
        _num(hi_hot, "hot_pixel_dark_e_per_s[1]", lo_hot)
        _num(self.full_well_e, "full_well_e", 1.0)
        _num(self.adc_bits, "adc_bits", 1, 24, integer=True)
        _num(self.gain_e_per_dn, "gain_e_per_dn", 0.0, lo_open=True)
        _num(self.bias_dn, "bias_dn", 0.0, 2.0**self.adc_bits - 1)
        for k, v in self.stray_light.items():
            if not isinstance(v, StrayLightResponse):
                raise TypeError(f"stray_light[{k!r}] must be a StrayLightResponse")
        _num(self.cosmic_ray_rate_per_cm2_s, "cosmic_ray_rate_per_cm2_s", 0.0)
        _num(self.cosmic_ray_median_e, "cosmic_ray_median_e", 0.0, lo_open=True)
        _num(self.debris_rate_per_frame, "debris_rate_per_frame", 0.0)
        _num(self.debris_vmag_range[0], "debris_vmag_range[0]", -5.0, 20.0)
        _num(self.debris_vmag_range[1], "debris_vmag_range[1]", self.debris_vmag_range[0], 20.0)
        _num(self.fixed_pattern_seed, "fixed_pattern_seed", 0, integer=True)
        object.__setattr__(self, "adc_bits", int(self.adc_bits))
        object.__setattr__(self, "stray_light", MappingProxyType(dict(self.stray_light)))

    # ------------------------------------------------------------------ presets
    @classmethod
    def preset(cls, name: str) -> "SensorModel":
        """``"paper000"``: intensified CMOS behind paper 000's optics (the MEIA tracker), the default.
        ``"paper000_cmos"``: the same optics on a plain CMOS (QE 0.6, 3 e⁻ read noise), for single
        long exposures."""
        if name == "paper000":
            return cls()
        if name == "paper000_cmos":
            return cls(
                psf_sigma_px=1.0,
                photometry=Photometry(aperture_diameter_mm=26.6, bandwidth_nm=400.0, transmission=0.8, quantum_efficiency=0.6),
                intensifier_gain=1.0,
                excess_noise_factor=1.0,
                read_noise_e=3.0,
                full_well_e=10000.0,
                gain_e_per_dn=2.5,
                name="paper000_cmos",
            )
        raise ValueError(f"preset name must be 'paper000' or 'paper000_cmos', got {name!r}")

    # ------------------------------------------------------------------ derived
    @property
    def sigma_px(self) -> float:
        """Total PSF standard deviation, hypot(psf_sigma_px, defocus_sigma_px), px."""
        return float(math.hypot(self.psf_sigma_px, self.defocus_sigma_px))

    @property
    def intensified(self) -> bool:
        return self.intensifier_gain > 1.0

    @property
    def optics_sigma_px(self) -> float:
        """Part of the PSF before the intensifier (scatter of photoelectron positions), px."""
        if not self.intensified:
            return self.sigma_px
        return float(math.sqrt(max(self.sigma_px**2 - self.intensifier_splash_sigma_px**2, 0.0)))

    @property
    def splash_energy(self) -> float:
        """c = Σ K² of the pixel-integrated splash kernel (1 without intensifier)."""
        if not self.intensified:
            return 1.0
        return _kernel_energy(self.intensifier_splash_sigma_px) ** 2

    @property
    def adc_max_dn(self) -> float:
        return float(2**self.adc_bits - 1)

    @property
    def saturation_dn(self) -> float:
        """Lowest DN of a saturated pixel: the ADC maximum or the full well, whichever comes first."""
        return float(min(self.adc_max_dn, np.rint(self.full_well_e / self.gain_e_per_dn + self.bias_dn)))

    @property
    def gamma_shape_per_pe(self) -> float:
        """k = 1/(F²−1) of the per-photoelectron gain distribution (inf when F = 1)."""
        f2 = self.excess_noise_factor**2
        return math.inf if f2 <= 1.0 else 1.0 / (f2 - 1.0)

    def star_pe(self, vmag, bv, exposure_s: float) -> np.ndarray:
        """Expected photoelectrons of stars in one exposure, shape like ``vmag``."""
        return self.photometry.pe_rate(vmag, bv) * float(exposure_s)


@lru_cache(maxsize=32)
def _kernel_energy(sigma_px: float) -> float:
    """Σ_k g(k)² of a 1-D pixel-integrated unit Gaussian centred on a pixel."""
    k = np.arange(-int(8 * sigma_px) - 2, int(8 * sigma_px) + 3)
    g = ndtr((k + 0.5) / sigma_px) - ndtr((k - 0.5) / sigma_px)
    return float(np.sum(g * g))


# ----------------------------------------------------------------------------------- fixed pattern
@lru_cache(maxsize=4)
def _fixed_pattern_cached(seed, prnu_sigma, hot_fraction, hot_lo, hot_hi, n_cols, n_rows):
    rng = np.random.default_rng([int(seed), 0x5EED])
    n = n_cols * n_rows
    prnu = (rng.standard_normal(n, dtype=np.float32) * np.float32(prnu_sigma)) if prnu_sigma > 0 else None
    n_hot = int(rng.poisson(hot_fraction * n))
    hot = np.unique(rng.integers(0, n, n_hot))
    rate = np.exp(rng.uniform(math.log(hot_lo), math.log(hot_hi), len(hot)))
    if prnu is not None:
        prnu.flags.writeable = False
    hot.flags.writeable = False
    rate.flags.writeable = False
    return prnu, hot, rate


def fixed_pattern(model: SensorModel, resolution: tuple[int, int]):
    """The detector's fixed pattern (deterministic from ``model.fixed_pattern_seed``; cached).

    Returns
    -------
    prnu : ndarray of float32, shape (n_rows * n_cols,) or None
        Relative gain deviation of each pixel (row-major linear index), None when ``prnu_sigma == 0``.
    hot_index : ndarray of int, shape (H,)
        Sorted linear indices of the hot pixels.
    hot_dark_e_per_s : ndarray, shape (H,)
        Their dark current, e⁻/s (added to the ordinary dark current).
    """
    return _fixed_pattern_cached(
        model.fixed_pattern_seed,
        model.prnu_sigma,
        model.hot_pixel_fraction,
        float(model.hot_pixel_dark_e_per_s[0]),
        float(model.hot_pixel_dark_e_per_s[1]),
        int(resolution[0]),
        int(resolution[1]),
    )


# ----------------------------------------------------------------------------------- background
@dataclass(frozen=True)
class BackgroundField:
    """Expected background of one frame; planar in the pixel coordinates.

    ``optical_pe(x, y) = opt0 + opt_dx (x − cx) + opt_dy (y − cy)`` photoelectrons accumulated over the N
    exposures (sky + stray light); dark current ``dark_e`` over the integration window.
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


def background_field(scene: Scene, model: SensorModel) -> BackgroundField:
    """The frame's expected background from the sky, the bright bodies (stray light) and dark current.

    Raises
    ------
    ValueError
        A bright body whose name has no entry in ``model.stray_light``.
    """
    cam = scene.camera
    plan = scene.plan
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
        z2 = np.zeros((0, 2))
        return cls(z2, z2, np.zeros(0), z2, z2, np.zeros(0))


def draw_false_objects(scene: Scene, model: SensorModel, rng: np.random.Generator) -> FalseObjects:
    """Draw the frame's debris streaks and cosmic-ray hits.

    Debris: ``Poisson(debris_rate_per_frame)`` objects, uniform over the detector, moving in a uniform
    direction at a log-uniform 100–20000 px/s (seen as one dash per exposure). Cosmic rays:
    ``Poisson(rate · area · integration window)`` straight tracks 0–6 px long, log-normal charge.
    """
    _check_rng(rng)
    cam = scene.camera
    w, h = cam.resolution
    area_cm2 = (w * cam.pixel_size_um * 1e-4) * (h * cam.pixel_size_um * 1e-4)
    n_d, n_c = (int(v) for v in rng.poisson([model.debris_rate_per_frame,
                                               model.cosmic_ray_rate_per_cm2_s * area_cm2 * scene.plan.integration_window_s]))
    if n_d == 0 and n_c == 0:
        return FalseObjects.none()
    size = np.array([w, h], dtype=float)
    u = rng.random((n_d, 6))  # position (2), direction, log-speed, magnitude, unused
    xy0 = u[:, :2] * size - 0.5
    ang = 2 * np.pi * u[:, 2]
    speed = np.exp(np.log(100.0) + (np.log(20000.0) - np.log(100.0)) * u[:, 3])
    vel = np.stack([np.cos(ang), np.sin(ang)], axis=1) * speed[:, None]
    vmag = model.debris_vmag_range[0] + (model.debris_vmag_range[1] - model.debris_vmag_range[0]) * u[:, 4]
    v = rng.random((n_c, 4))  # position (2), direction, length
    start = v[:, :2] * size - 0.5
    a = 2 * np.pi * v[:, 2]
    end = start + np.stack([np.cos(a), np.sin(a)], axis=1) * (_COSMIC_MAX_LEN_PX * v[:, 3])[:, None]
    charge = model.cosmic_ray_median_e * np.exp(0.6 * rng.standard_normal(n_c))
    return FalseObjects(xy0, vel, vmag, start, end, charge)


# ----------------------------------------------------------------------------------- sources
@dataclass(frozen=True, eq=False)
class SourceTable:
    """Every light source of a frame, for truth labels.

    Stars come first, exposure-major: source ``i * M + m`` is scene star m in exposure i.

    Attributes
    ----------
    kind : ndarray of int, shape (Q,)
        ``KIND_*`` code.
    star : ndarray of int, shape (Q,)
        Scene star index, −1 for other kinds.
    exposure : ndarray of int, shape (Q,)
        Exposure index (stars and debris), −1 otherwise.
    xy : ndarray, shape (Q, 2)
        Where the source's light is centred (time-averaged position over the exposure), px.
    expected_e : ndarray, shape (Q,)
        Expected charge of the source, e⁻.
    """

    kind: np.ndarray
    star: np.ndarray
    exposure: np.ndarray
    xy: np.ndarray
    expected_e: np.ndarray

    def __len__(self):
        return len(self.kind)


# ----------------------------------------------------------------------------------- spots
@dataclass
class _Spots:
    """Spot segments to render: sub-spot centres and weights, one Gaussian σ each."""

    sub_xy: np.ndarray  # (P, K, 2)
    sub_w: np.ndarray  # (P, K) expected pe (optical) or e- (direct)
    sigma: np.ndarray  # (P,)
    source: np.ndarray  # (P,) index into the SourceTable
    along: np.ndarray  # (P, 2) unit vector along the segment (x, y)
    length: np.ndarray  # (P,) segment length, px
    direct: bool  # charge deposited directly (cosmic rays) rather than light


def _resample_path(path: np.ndarray, n_seg: int) -> np.ndarray:
    """Positions at n_seg+1 instants evenly spaced in time along paths sampled evenly in time.

    path (E, S, 2) -> (E, n_seg+1, 2), linear between samples.
    """
    s = path.shape[1]
    f = np.linspace(0.0, s - 1.0, n_seg + 1)
    i0 = np.minimum(np.floor(f).astype(int), s - 2)
    w = (f - i0)[None, :, None]
    return path[:, i0] * (1 - w) + path[:, i0 + 1] * w


def _segments_to_spots(knots, total, sigma, source, direct, max_seg_px):
    """knots (E, n_seg+1, 2) of paths, total signal (E,), sigma (E,) -> _Spots with K sub-spots per segment."""
    e_n, n1, _ = knots.shape
    n_seg = n1 - 1
    a = knots[:, :-1].reshape(-1, 2)
    b = knots[:, 1:].reshape(-1, 2)
    d = b - a
    length = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2)
    sig = np.repeat(sigma, n_seg)
    k = int(max(1, math.ceil(float(np.max(length / (0.5 * sig), initial=0.0)))))
    frac = (np.arange(k) + 0.5) / k
    sub = a[:, None, :] + d[:, None, :] * frac[None, :, None]
    w = np.repeat(total / (n_seg * k), n_seg)[:, None] * np.ones((1, k))
    along = np.where(length[:, None] > 1e-12, d / np.maximum(length, 1e-12)[:, None], np.array([1.0, 0.0]))
    return _Spots(sub, w, sig, np.repeat(source, n_seg), along, length, direct)


def _paths_to_spots(paths, total, sigma, source, direct):
    """Split polylines (E, S, 2) sampled evenly in time into segments no longer than 4σ."""
    if len(paths) == 0:
        return None
    dp = np.diff(paths, axis=1)
    seg_len = np.sqrt(dp[..., 0] ** 2 + dp[..., 1] ** 2).sum(axis=1)
    n_seg = int(max(1, math.ceil(float(np.max(seg_len / (4.0 * sigma))))))
    return _segments_to_spots(_resample_path(paths, n_seg), total, sigma, source, direct, 4.0 * sigma)


def _on_detector(paths, margin, w, h):
    lo = paths.min(axis=1)
    hi = paths.max(axis=1)
    return (hi[:, 0] >= -0.5 - margin) & (lo[:, 0] <= w - 0.5 + margin) & (hi[:, 1] >= -0.5 - margin) & (lo[:, 1] <= h - 0.5 + margin)


def _frame_spots(scene: Scene, model: SensorModel, fo: FalseObjects):
    """All spots of a frame and the source table (stars, debris, cosmic rays; hot pixels appended later)."""
    cam = scene.camera
    w, h = cam.resolution
    n, m = scene.n_exposures, scene.n_stars
    tau = scene.plan.exposure_s
    sigma = model.sigma_px
    g = model.intensifier_gain
    margin = 5.0 * sigma

    pe_star = model.star_pe(scene.vmag, scene.bv, tau)  # (M,)
    kinds = [np.full(n * m, KIND_STAR)]
    stars = [np.tile(np.arange(m), n)]
    expos = [np.repeat(np.arange(n), m)]
    xys = [scene.xy_mean.reshape(-1, 2)]
    exp_e = [np.tile(pe_star * g, n)]
    optical_paths = [np.moveaxis(scene.xy_path, 1, 2).reshape(n * m, scene.xy_path.shape[1], 2)]  # (N*M, S, 2)
    optical_total = [np.tile(pe_star, n)]
    optical_source = [np.arange(n * m)]
    q = n * m

    nd = len(fo.debris_vmag)
    if nd:
        t_mid = scene.t_frame_start + 0.5 * scene.plan.frame_period_s
        dt = scene.path_times - t_mid  # (N, S)
        paths = fo.debris_xy0[None, :, None, :] + fo.debris_velocity_px_s[None, :, None, :] * dt[:, None, :, None]
        paths = paths.reshape(n * nd, -1, 2)  # exposure-major
        pe_deb = model.star_pe(fo.debris_vmag, np.zeros(nd), tau)
        kinds.append(np.full(n * nd, KIND_DEBRIS))
        stars.append(np.full(n * nd, -1))
        expos.append(np.repeat(np.arange(n), nd))
        mean_xy = 0.5 * (paths[:, 0] + paths[:, -1])
        xys.append(mean_xy)
        exp_e.append(np.tile(pe_deb * g, n))
        optical_paths.append(paths)
        optical_total.append(np.tile(pe_deb, n))
        optical_source.append(q + np.arange(n * nd))
        q += n * nd

    nc = len(fo.cosmic_e)
    cosmic = None
    if nc:
        kinds.append(np.full(nc, KIND_COSMIC_RAY))
        stars.append(np.full(nc, -1))
        expos.append(np.full(nc, -1))
        xys.append(0.5 * (fo.cosmic_start_xy + fo.cosmic_end_xy))
        exp_e.append(fo.cosmic_e)
        cpaths = np.stack([fo.cosmic_start_xy, fo.cosmic_end_xy], axis=1)
        cosmic = _paths_to_spots(cpaths, fo.cosmic_e, np.full(nc, _COSMIC_SIGMA_PX), q + np.arange(nc), True)
        q += nc

    paths = np.concatenate(optical_paths) if optical_paths else np.zeros((0, 3, 2))
    total = np.concatenate(optical_total)
    source = np.concatenate(optical_source)
    keep = _on_detector(paths, margin, w, h) & (total > 0)
    optical = _paths_to_spots(paths[keep], total[keep], np.full(int(keep.sum()), sigma), source[keep], False)
    table = dict(
        kind=np.concatenate(kinds),
        star=np.concatenate(stars),
        exposure=np.concatenate(expos),
        xy=np.concatenate(xys),
        expected_e=np.concatenate(exp_e),
    )
    return optical, cosmic, table


def _randomize_intensified(spots: _Spots, model: SensorModel, rng: np.random.Generator) -> None:
    """Photon-counting statistics of an intensified spot (module docstring), in place.

    Turns the expected photoelectrons of each segment into its random charge (e⁻) and shifts the segment by
    the scatter of its photoelectrons' positions.
    """
    s = spots.sub_w.sum(axis=1)
    n_pe = rng.poisson(s)
    g = model.intensifier_gain
    k = model.gamma_shape_per_pe
    if math.isinf(k):
        charge = g * n_pe
    else:
        charge = rng.gamma(np.maximum(k * n_pe, 1e-300), g / k) * (n_pe > 0)
    f2 = model.excess_noise_factor**2
    n_eff = np.maximum(n_pe, 1)
    so2 = model.optics_sigma_px**2
    sd_cross = np.sqrt(f2 * so2 / n_eff)
    sd_along = np.sqrt(f2 * (so2 + spots.length**2 / 12.0) / n_eff)
    z = rng.standard_normal((len(s), 2))
    shift = spots.along * (z[:, :1] * sd_along[:, None]) + np.stack([-spots.along[:, 1], spots.along[:, 0]], 1) * (z[:, 1:] * sd_cross[:, None])
    spots.sub_xy = spots.sub_xy + shift[:, None, :]
    k_sub = spots.sub_w.shape[1]
    spots.sub_w = np.repeat((charge / k_sub)[:, None], k_sub, axis=1)


def _window_half_widths(spots: _Spots, bg: "BackgroundField", e_per_unit: float, floor_frac: float) -> np.ndarray:
    """Per-spot window half width, px: where the spot's profile falls to ``floor_frac`` of the background
    noise σ (at least 2σ), +1 px so that every detected pixel has its neighbours. Shape (P,)."""
    peak_e = spots.sub_w.sum(axis=1) * e_per_unit / (2 * np.pi * spots.sigma**2)
    floor_e = floor_frac * math.sqrt(max(float(bg.var_e(bg.cx, bg.cy)), 1e-6))
    r = spots.sigma * np.sqrt(2.0 * np.log(np.maximum(peak_e / floor_e, math.e)))
    return np.ceil(np.maximum(r, 2.0 * spots.sigma)).astype(np.int64) + 1


def _render_bucketed(spots: _Spots, hw: np.ndarray, n_cols: int, n_rows: int, min_value: float = 0.0):
    """:func:`_render_windows` for groups of spots sharing a half width (a few groups per frame)."""
    out_l, out_v, out_s = [], [], []
    for h in np.unique(hw):
        sel = np.flatnonzero(hw == h)
        sub = _Spots(spots.sub_xy[sel], spots.sub_w[sel], spots.sigma[sel], spots.source[sel], spots.along[sel],
                     spots.length[sel], spots.direct)
        lin, val, src = _render_windows(sub, int(h), n_cols, n_rows, min_value)
        out_l.append(lin)
        out_v.append(val)
        out_s.append(src)
    if not out_l:
        return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64)
    return np.concatenate(out_l), np.concatenate(out_v), np.concatenate(out_s)


def _render_windows(spots: _Spots, hw: int, n_cols: int, n_rows: int, min_value: float = 0.0):
    """Pixel-integrated Gaussian sub-spots summed into one window per spot.

    Window pixels whose expected signal is below ``min_value`` are dropped (sparse path).

    Returns
    -------
    lin : ndarray of int64, shape (E,)
        Linear pixel index (row * n_cols + col) of every in-bounds window pixel.
    value : ndarray, shape (E,)
        Expected signal there (units of ``sub_w``).
    source : ndarray of int, shape (E,)
    """
    x = spots.sub_xy[..., 0]
    y = spots.sub_xy[..., 1]
    c_lo = np.rint(x.min(axis=1)).astype(np.int64) - hw
    c_hi = np.rint(x.max(axis=1)).astype(np.int64) + hw
    r_lo = np.rint(y.min(axis=1)).astype(np.int64) - hw
    r_hi = np.rint(y.max(axis=1)).astype(np.int64) + hw
    wc = int((c_hi - c_lo).max()) + 1
    wr = int((r_hi - r_lo).max()) + 1
    inv_s = (1.0 / spots.sigma)[:, None, None]
    ec = (c_lo[:, None] - 0.5 + np.arange(wc + 1))[:, None, :]
    er = (r_lo[:, None] - 0.5 + np.arange(wr + 1))[:, None, :]
    gx = np.diff(ndtr((ec - x[:, :, None]) * inv_s), axis=2)  # (P, K, Wc)
    gy = np.diff(ndtr((er - y[:, :, None]) * inv_s), axis=2)  # (P, K, Wr)
    gy *= spots.sub_w[:, :, None]
    val = np.matmul(gy.transpose(0, 2, 1), gx)  # (P, Wr, Wc)
    rows = r_lo[:, None] + np.arange(wr)
    cols = c_lo[:, None] + np.arange(wc)
    ok = ((rows >= 0) & (rows < n_rows))[:, :, None] & ((cols >= 0) & (cols < n_cols))[:, None, :]
    if min_value > 0:
        ok &= val >= min_value
    nz = np.flatnonzero(ok)
    p, rem = np.divmod(nz, wr * wc)
    r, c = np.divmod(rem, wc)
    lin = (r_lo[p] + r) * n_cols + (c_lo[p] + c)
    return lin, val.reshape(-1)[nz], spots.source[p]


# ----------------------------------------------------------------------------------- pixel values
def _pixels_to_dn(spot_opt, bg: BackgroundField, opt_bg, prnu, model: SensorModel, rng, *,
                  hot_at=None, hot_e=None, direct_at=None, direct_e=None, dtype=np.float64):
    """Random DN of pixels given their expected signals (shared by the full-frame and sparse paths).

    Parameters
    ----------
    spot_opt : ndarray, shape (U,)
        Intensified: the randomised spot charge, e⁻; CMOS: the expected star photoelectrons.
    opt_bg : float or ndarray, shape (U,)
        Optical background photoelectrons (``bg.optical_pe`` at the pixels).
    prnu : ndarray, shape (U,) or None
    hot_at, hot_e : indices into the U pixels and their extra dark charge (hot pixels), e⁻.
    direct_at, direct_e : indices and charge deposited directly (cosmic rays), e⁻.
    """
    g = model.intensifier_gain
    u = spot_opt.shape[0]
    base_var = bg.dark_e + bg.read_var_e2
    z = rng.standard_normal(u, dtype=dtype)
    if model.intensified:
        q = spot_opt + g * opt_bg if np.ndim(opt_bg) or opt_bg != 0 else spot_opt.copy()
        sd = np.sqrt(bg.enf2_c * q + base_var)
        if prnu is not None:
            q *= 1.0 + prnu
        e = q
        e += bg.dark_e
        e += sd * z
    else:
        b = g * opt_bg
        sd = np.sqrt(bg.enf2_c * b + base_var)
        e = sd * z
        e += (b * (1.0 + prnu) if prnu is not None else b) + bg.dark_e
        nz = np.flatnonzero(spot_opt > 0)
        if len(nz):
            n_pe = rng.poisson(spot_opt[nz])
            k = model.gamma_shape_per_pe
            if math.isinf(k):
                charge = g * n_pe.astype(np.float64)
            else:
                charge = rng.gamma(np.maximum(k * n_pe, 1e-300), g / k) * (n_pe > 0)
            e[nz] += (1.0 + prnu[nz]) * charge if prnu is not None else charge
    if hot_at is not None and len(hot_at):
        e[hot_at] += hot_e + np.sqrt(hot_e) * rng.standard_normal(len(hot_at))
    if direct_at is not None and len(direct_at):
        e[direct_at] += direct_e
    np.minimum(e, model.full_well_e, out=e)
    e *= 1.0 / model.gain_e_per_dn
    e += model.bias_dn
    np.rint(e, out=e)
    np.clip(e, 0.0, model.adc_max_dn, out=e)
    return e


def _check_rng(rng):
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")


def _check_inputs(scene, model, rng):
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a startracker.scene.Scene, got {type(scene).__name__}")
    if not isinstance(model, SensorModel):
        raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
    if rng is not None:
        _check_rng(rng)


def _prepare(scene, model, rng, false_objects):
    fo = draw_false_objects(scene, model, rng) if false_objects is None else false_objects
    if not isinstance(fo, FalseObjects):
        raise TypeError("false_objects must be a FalseObjects (or None to draw them)")
    optical, cosmic, table = _frame_spots(scene, model, fo)
    return fo, optical, cosmic, table


def _hot_expected(model, scene):
    _, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    return hot_idx, hot_rate * scene.plan.integration_window_s


# ----------------------------------------------------------------------------------- full frame
def render_frame(scene: Scene, model: SensorModel, rng: np.random.Generator, *, false_objects: FalseObjects | None = None) -> np.ndarray:
    """Draw the full detector frame (for display and tests; the fast path is :func:`render_sparse`).

    Parameters
    ----------
    scene : Scene
    model : SensorModel
    rng : numpy.random.Generator
    false_objects : FalseObjects, optional
        Debris and cosmic rays; drawn from ``rng`` when None (``FalseObjects.none()`` for none).

    Returns
    -------
    image : ndarray of float32, shape (n_rows, n_cols)
        DN, indexed ``image[row, col]``.
    """
    _check_inputs(scene, model, rng)
    _check_rng(rng)
    fo, optical, cosmic, _ = _prepare(scene, model, rng, false_objects)
    n_cols, n_rows = scene.camera.resolution
    n_px = n_cols * n_rows
    bg = background_field(scene, model)
    spot = np.zeros(n_px, dtype=np.float32)
    direct = np.zeros(n_px, dtype=np.float32) if cosmic is not None else None
    if optical is not None:
        hw = _window_half_widths(optical, bg, model.intensifier_gain, _FULL_FLOOR)
        if model.intensified:
            _randomize_intensified(optical, model, rng)
        lin, val, _ = _render_bucketed(optical, hw, n_cols, n_rows)
        np.add.at(spot, lin, val)
    if cosmic is not None:
        lin, val, _ = _render_windows(cosmic, 3, n_cols, n_rows)
        np.add.at(direct, lin, val)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    if bg.flat:
        opt = max(bg.opt0, 0.0)
    else:
        opt = bg.optical_pe(np.arange(n_cols, dtype=np.float32)[None, :], np.arange(n_rows, dtype=np.float32)[:, None]).astype(np.float32).ravel()
    d_at = np.flatnonzero(direct) if cosmic is not None else None
    dn = _pixels_to_dn(spot, bg, opt, prnu, model, rng, hot_at=hot_idx, hot_e=hot_rate * scene.plan.integration_window_s,
                       direct_at=d_at, direct_e=None if d_at is None else direct[d_at], dtype=np.float32)
    return dn.reshape(n_rows, n_cols).astype(np.float32, copy=False)


def render_expected(scene: Scene, model: SensorModel, *, include_background: bool = True,
                    false_objects: FalseObjects | None = None) -> np.ndarray:
    """Expected charge of every pixel without noise, clipping or quantisation, e⁻.

    ``(1 + PRNU) × G × (star light + sky + stray light) [+ dark + hot pixels] + cosmic-ray charge``;
    the background terms only with ``include_background``; no false objects unless given.

    Returns
    -------
    ndarray of float64, shape (n_rows, n_cols)
    """
    _check_inputs(scene, model, None)
    fo = FalseObjects.none() if false_objects is None else false_objects
    optical, cosmic, _ = _frame_spots(scene, model, fo)
    n_cols, n_rows = scene.camera.resolution
    n_px = n_cols * n_rows
    light = np.zeros(n_px)
    bg = background_field(scene, model)
    if optical is not None:
        hw = np.maximum(_window_half_widths(optical, bg, model.intensifier_gain, _FULL_FLOOR),
                        int(math.ceil(6 * model.sigma_px)) + 1)
        lin, val, _ = _render_bucketed(optical, hw, n_cols, n_rows)
        np.add.at(light, lin, val * model.intensifier_gain)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    if include_background:
        rows, cols = np.divmod(np.arange(n_px), n_cols)
        light += bg.gain * bg.optical_pe(cols, rows)
    img = light if prnu is None else light * (1.0 + prnu)
    if include_background:
        img += bg.dark_e
        img[hot_idx] += hot_rate * scene.plan.integration_window_s
    if cosmic is not None:
        lin, val, _ = _render_windows(cosmic, 3, n_cols, n_rows)
        np.add.at(img, lin, val)
    return img.reshape(n_rows, n_cols)


# ----------------------------------------------------------------------------------- sparse frame
class _PixelIndex:
    """Sort-free deduplication of linear pixel indices with a persistent int32 buffer.

    The buffer is never cleared: a lookup is valid only if the stored compact id points back to the same
    pixel (the 'sparse set' trick). One buffer per detector size is shared by all frames of the process
    (not thread-safe); a frame that finds the buffer taken over by a later frame rewrites its own ids
    (O(U)) before looking up.
    """

    _buffers: dict = {}
    _owner: dict = {}

    def __init__(self, n_px: int):
        buf = self._buffers.get(n_px)
        if buf is None:
            buf = np.zeros(n_px, dtype=np.int32)
            self._buffers[n_px] = buf
        self.n_px = n_px
        self.buf = buf
        self.uniq = np.zeros(0, dtype=np.int64)

    def unique(self, lin: np.ndarray):
        """Unique pixels of ``lin`` (E,) and, for each entry, its compact id. Returns (uniq (U,), inv (E,))."""
        e = np.arange(len(lin), dtype=np.int32)
        self.buf[lin] = e
        rep = self.buf[lin]
        first = np.flatnonzero(rep == e)
        compact = np.empty(len(lin), dtype=np.int32)
        compact[first] = np.arange(len(first), dtype=np.int32)
        inv = compact[rep]
        self.uniq = lin[first]
        self.buf[self.uniq] = np.arange(len(first), dtype=np.int32)
        self._owner[self.n_px] = self
        return self.uniq, inv

    def contains(self, lin: np.ndarray) -> np.ndarray:
        """Compact id of each pixel in ``lin`` among the last ``unique`` call's pixels, −1 if absent."""
        u = self.uniq
        if len(u) == 0:
            return np.full(len(lin), -1, dtype=np.int64)
        if self._owner.get(self.n_px) is not self:
            self.buf[u] = np.arange(len(u), dtype=np.int32)
            self._owner[self.n_px] = self
        cand = self.buf[lin].astype(np.int64)
        ok = (cand >= 0) & (cand < len(u))
        cand_c = np.where(ok, cand, 0)
        ok &= u[cand_c] == lin
        return np.where(ok, cand_c, -1)


@dataclass(frozen=True, eq=False)
class SparseFrame:
    """The pixels of a frame that matter: windows around the light sources and the background's
    threshold crossings (with their 3×3 neighbourhoods).

    Attributes
    ----------
    shape : (int, int)
        (n_rows, n_cols).
    lin : ndarray of int64, shape (U,)
        Linear pixel indices ``row * n_cols + col``.
    rows, cols : ndarray of int64, shape (U,)
    dn : ndarray of float32, shape (U,)
        Pixel values, DN.
    background_dn : ndarray, shape (U,)
        Expected background there, DN.
    threshold_dn : ndarray, shape (U,)
        Detection threshold ``background + k σ``, DN.
    saturation_dn : float
    sources : SourceTable
    entry_pixel, entry_source : ndarray of int, shape (E,)
        Per rendered entry: compact pixel id and source id.
    entry_e : ndarray, shape (E,)
        Expected charge that source puts in that pixel, e⁻ (for truth labels).
    k_sigma : float
    background_dn_centre, noise_dn_centre : float
        Background level and σ at the principal point, DN.
    """

    shape: tuple
    lin: np.ndarray
    dn: np.ndarray
    background_dn: np.ndarray
    threshold_dn: np.ndarray
    saturation_dn: float
    sources: SourceTable
    entry_pixel: np.ndarray
    entry_source: np.ndarray
    entry_e: np.ndarray
    k_sigma: float
    _index: _PixelIndex
    background_dn_centre: float = float("nan")
    noise_dn_centre: float = float("nan")

    @cached_property
    def _rows_cols(self):
        return np.divmod(self.lin, self.shape[1])

    @property
    def rows(self) -> np.ndarray:
        return self._rows_cols[0]

    @property
    def cols(self) -> np.ndarray:
        return self._rows_cols[1]

    def pixel_ids(self, rows, cols) -> np.ndarray:
        """Compact ids of pixels (−1 where not in the sparse set or off the detector)."""
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        n_rows, n_cols = self.shape
        inside = (rows >= 0) & (rows < n_rows) & (cols >= 0) & (cols < n_cols)
        lin = np.where(inside, rows * n_cols + cols, 0)
        ids = self._index.contains(lin)
        return np.where(inside, ids, -1)

    def to_image(self, fill: float | None = None) -> np.ndarray:
        """A full frame with the sparse pixels set and the rest at ``fill`` (default the mean background)."""
        n_rows, n_cols = self.shape
        f = float(np.median(self.background_dn)) if fill is None and len(self.lin) else (fill or 0.0)
        img = np.full(n_rows * n_cols, f, dtype=np.float32)
        img[self.lin] = self.dn
        return img.reshape(n_rows, n_cols)


def _false_pixels(bg: BackgroundField, k_sigma: float, n_cols: int, n_rows: int, model: SensorModel, rng):
    """Background pixels above the threshold, drawn from the noise statistics (module docstring).

    Returns linear indices (F,) and their DN values (F,).
    """
    if bg.flat:  # one cell: the crossing probability is the same everywhere
        mu_e = float(bg.mean_e(bg.cx, bg.cy))
        sd_e = math.sqrt(float(bg.var_e(bg.cx, bg.cy)))
        thr = float(bg.threshold_dn(bg.cx, bg.cy, k_sigma))
        z0 = ((math.floor(thr) + 0.5 - model.bias_dn) * model.gain_e_per_dn - mu_e) / sd_e
        p = float(ndtr(-z0)) if math.floor(thr) + 1 <= model.saturation_dn else 0.0  # a clipped pixel cannot cross
        tot = int(rng.poisson(p * n_cols * n_rows))
        if tot == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        lin = rng.integers(0, n_cols * n_rows, tot)
        z = np.maximum(-ndtri(np.clip(rng.random(tot) * p, 1e-300, None)), z0)
        e = np.minimum(mu_e + sd_e * z, model.full_well_e)
        dn = np.clip(np.rint(e / model.gain_e_per_dn + model.bias_dn), math.floor(thr) + 1, model.adc_max_dn)
        return lin, dn
    # cells fine enough that the background changes by < 0.25 DN across one (the crossing probability of
    # quantised pixels depends on where the threshold falls between two DN levels)
    dn_per_pe = bg.gain / model.gain_e_per_dn
    gx = int(min(_FALSE_GRID, n_cols, max(1, math.ceil(4 * abs(bg.opt_dx) * n_cols * dn_per_pe))))
    gy = int(min(_FALSE_GRID, n_rows, max(1, math.ceil(4 * abs(bg.opt_dy) * n_rows * dn_per_pe))))
    ce = np.linspace(-0.5, n_cols - 0.5, gx + 1)
    re = np.linspace(-0.5, n_rows - 0.5, gy + 1)
    xc = 0.5 * (ce[:-1] + ce[1:])[None, :]
    yc = 0.5 * (re[:-1] + re[1:])[:, None]
    mu_e = bg.mean_e(xc, yc)
    var_e = bg.var_e(xc, yc)
    sd_e = np.sqrt(var_e)
    thr = mu_e / model.gain_e_per_dn + model.bias_dn + k_sigma * np.sqrt(var_e / model.gain_e_per_dn**2 + 1.0 / 12.0)
    cut_e = (np.floor(thr) + 0.5 - model.bias_dn) * model.gain_e_per_dn  # DN > thr  <=>  e >= cut_e
    z0 = (cut_e - mu_e) / sd_e
    p = np.where(np.floor(thr) + 1 <= model.saturation_dn, ndtr(-z0), 0.0)  # a clipped pixel cannot cross
    n_in_cell = np.outer(np.diff(np.floor(re + 0.5)), np.diff(np.floor(ce + 0.5)))
    lam = np.cumsum((p * n_in_cell).ravel())
    # a Poisson process over the cells: Poisson total, cells in proportion to their expected counts
    tot = int(rng.poisson(lam[-1])) if lam[-1] > 0 else 0
    if tot == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    cell = np.minimum(np.searchsorted(lam, rng.random(tot) * lam[-1], side="right"), lam.size - 1)
    cy, cx = np.divmod(cell, gx)
    c0 = np.floor(ce[cx] + 0.5).astype(np.int64)
    c1 = np.floor(ce[cx + 1] + 0.5).astype(np.int64)
    r0 = np.floor(re[cy] + 0.5).astype(np.int64)
    r1 = np.floor(re[cy + 1] + 0.5).astype(np.int64)
    col = c0 + np.floor(rng.random(tot) * (c1 - c0)).astype(np.int64)
    row = r0 + np.floor(rng.random(tot) * (r1 - r0)).astype(np.int64)
    pc = p.ravel()[cell]
    u = rng.random(tot)
    z = -ndtri(np.clip(u * pc, 1e-300, None))  # Gaussian tail above z0
    z = np.maximum(z, z0.ravel()[cell])
    e = mu_e.ravel()[cell] + sd_e.ravel()[cell] * z
    e = np.minimum(e, model.full_well_e)
    dn = np.clip(np.rint(e / model.gain_e_per_dn + model.bias_dn), np.floor(thr.ravel()[cell]) + 1, model.adc_max_dn)
    return row * n_cols + col, dn


_NEIGHBOURS_3x3 = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])


def render_sparse(scene: Scene, model: SensorModel, rng: np.random.Generator, k_sigma: float = 5.0, *,
                  false_objects: FalseObjects | None = None, draw_crossings: bool = True) -> SparseFrame:
    """Draw only the pixels that can be detected: the fast path of the pixel fidelity.

    Parameters
    ----------
    scene, model, rng
    k_sigma : float
        Detection threshold in background σ (the background's threshold crossings are drawn for it).
    false_objects : FalseObjects, optional
    draw_crossings : bool
        Draw the background's threshold crossings away from the windows (False: a noise-free sky).

    Returns
    -------
    SparseFrame
    """
    _check_inputs(scene, model, rng)
    _check_rng(rng)
    k_sigma = _num(k_sigma, "k_sigma", 0.0, lo_open=True)
    fo, optical, cosmic, table = _prepare(scene, model, rng, false_objects)
    n_cols, n_rows = scene.camera.resolution
    n_px = n_cols * n_rows
    bg = background_field(scene, model)
    prnu, hot_idx, hot_rate = fixed_pattern(model, scene.camera.resolution)
    hot_e_all = hot_rate * scene.plan.integration_window_s
    q0 = len(table["kind"])

    lins, srcs, exp_e = [], [], []
    opt_val = dir_val = None
    if optical is not None:
        hw = _window_half_widths(optical, bg, model.intensifier_gain, _SPARSE_FLOOR)
        if model.intensified:
            _randomize_intensified(optical, model, rng)
        # drop window pixels whose expected light is below _SPARSE_FLOOR of the background noise (units of val)
        floor_e = _SPARSE_FLOOR * math.sqrt(float(bg.var_e(bg.cx, bg.cy)))
        lin, opt_val, src = _render_bucketed(optical, hw, n_cols, n_rows,
                                             floor_e if model.intensified else floor_e / model.intensifier_gain)
        lins.append(lin)
        srcs.append(src)
        exp_e.append(opt_val if model.intensified else opt_val * model.intensifier_gain)
    n_opt = len(opt_val) if opt_val is not None else 0
    if cosmic is not None:
        lin, dir_val, src = _render_windows(cosmic, 3, n_cols, n_rows)
        lins.append(lin)
        srcs.append(src)
        exp_e.append(dir_val)
    n_dir = len(dir_val) if dir_val is not None else 0
    # hot pixels with their 3x3 neighbourhoods
    n_hot = len(hot_idx)
    if n_hot:
        hr, hc = np.divmod(hot_idx, n_cols)
        nr = (hr[:, None] + _NEIGHBOURS_3x3[None, :, 0]).ravel()
        nc = (hc[:, None] + _NEIGHBOURS_3x3[None, :, 1]).ravel()
        ok = (nr >= 0) & (nr < n_rows) & (nc >= 0) & (nc < n_cols)
        centre = np.tile(np.arange(9) == 4, n_hot)
        lins.append((nr * n_cols + nc)[ok])
        srcs.append(np.repeat(q0 + np.arange(n_hot), 9)[ok])
        exp_e.append(np.where(centre, np.repeat(hot_e_all, 9), 0.0)[ok])
    q1 = q0 + n_hot

    # background threshold crossings outside the windows (kept only where no window pixel lies)
    if draw_crossings:
        f_lin, f_dn = _false_pixels(bg, k_sigma, n_cols, n_rows, model, rng)
    else:
        f_lin, f_dn = np.zeros(0, dtype=np.int64), np.zeros(0)
    n_base = int(sum(len(v) for v in lins))
    if len(f_lin) > 1:
        f_lin, first = np.unique(f_lin, return_index=True)
        f_dn = f_dn[first]
    n_false = len(f_lin)
    if n_false:
        fr, fc = np.divmod(f_lin, n_cols)
        nr = (fr[:, None] + _NEIGHBOURS_3x3[None, :, 0]).ravel()
        nc = (fc[:, None] + _NEIGHBOURS_3x3[None, :, 1]).ravel()
        ok = (nr >= 0) & (nr < n_rows) & (nc >= 0) & (nc < n_cols)
        lins.append((nr * n_cols + nc)[ok])
        srcs.append(np.repeat(q1 + np.arange(n_false), 9)[ok])
        exp_e.append(np.where(np.tile(np.arange(9) == 4, n_false), 1.0, 0.0)[ok])

    if lins:
        all_lin = np.concatenate(lins) if len(lins) > 1 else lins[0]
        all_src = np.concatenate(srcs) if len(srcs) > 1 else srcs[0]
        all_exp = np.concatenate(exp_e) if len(exp_e) > 1 else exp_e[0].copy()
    else:
        all_lin = np.zeros(0, dtype=np.int64)
        all_exp = np.zeros(0)
        all_src = np.zeros(0, dtype=np.int64)
    index = _PixelIndex(n_px)
    uniq, inv = index.unique(all_lin)
    u = len(uniq)
    spot_u = np.bincount(inv[:n_opt], opt_val, minlength=u) if n_opt else np.zeros(u)
    hot_pos = index.contains(hot_idx) if n_hot else np.zeros(0, dtype=np.int64)
    prnu_u = None if prnu is None else prnu[uniq].astype(np.float64)
    if bg.flat:
        opt_u = max(bg.opt0, 0.0)
    else:
        rows_u, cols_u = np.divmod(uniq, n_cols)
        opt_u = bg.optical_pe(cols_u, rows_u)
    if n_dir:
        dir_u = np.bincount(inv[n_opt:n_opt + n_dir], dir_val, minlength=u)
        d_at = np.flatnonzero(dir_u)
        d_e = dir_u[d_at]
    else:
        d_at = d_e = None
    dn = _pixels_to_dn(spot_u, bg, opt_u, prnu_u, model, rng, hot_at=hot_pos[hot_pos >= 0],
                       hot_e=hot_e_all[hot_pos >= 0], direct_at=d_at, direct_e=d_e)
    if n_false:
        f_uid = index.contains(f_lin)
        in_window = np.zeros(u, dtype=bool)
        in_window[inv[:n_base]] = True
        keep_f = ~in_window[f_uid]
        dn[f_uid[keep_f]] = f_dn[keep_f]
        # a crossing that fell on a window pixel is not a separate event: its 3x3 stays plain background
        drop_src = q1 + np.flatnonzero(~keep_f)
        if len(drop_src):
            all_exp[np.isin(all_src, drop_src)] = 0.0

    # source table: stars, debris, cosmic rays (from _frame_spots), hot pixels, background crossings
    hr, hc = np.divmod(hot_idx, n_cols)
    fr, fc = np.divmod(f_lin, n_cols)
    f_e = (f_dn - model.bias_dn) * model.gain_e_per_dn - (bg.mean_e(fc, fr) if n_false else 0.0)
    sources = SourceTable(
        kind=np.concatenate([table["kind"], np.full(n_hot, KIND_HOT_PIXEL), np.full(n_false, KIND_NOISE)]).astype(np.int64),
        star=np.concatenate([table["star"], np.full(n_hot + n_false, -1)]).astype(np.int64),
        exposure=np.concatenate([table["exposure"], np.full(n_hot + n_false, -1)]).astype(np.int64),
        xy=np.concatenate([table["xy"], np.stack([hc, hr], 1).astype(float), np.stack([fc, fr], 1).astype(float)]),
        expected_e=np.concatenate([table["expected_e"], hot_e_all, np.atleast_1d(f_e)[:n_false]]),
    )
    mean_dn_u = np.broadcast_to((bg.gain * opt_u + bg.dark_e) / model.gain_e_per_dn + model.bias_dn, (u,))
    q_u = bg.gain * opt_u
    sigma_dn_u = np.broadcast_to(np.sqrt((bg.enf2_c * q_u + bg.dark_e + bg.read_var_e2 + (bg.prnu_sigma * q_u) ** 2)
                                         / model.gain_e_per_dn**2 + 1.0 / 12.0), (u,))
    return SparseFrame(
        shape=(n_rows, n_cols),
        lin=uniq,
        dn=dn.astype(np.float32),
        background_dn=mean_dn_u,
        threshold_dn=np.broadcast_to(mean_dn_u + k_sigma * sigma_dn_u, (u,)),
        saturation_dn=model.saturation_dn,
        sources=sources,
        entry_pixel=inv.astype(np.int64),
        entry_source=all_src.astype(np.int64),
        entry_e=all_exp,
        k_sigma=k_sigma,
        _index=index,
        background_dn_centre=float(bg.mean_dn(bg.cx, bg.cy)),
        noise_dn_centre=float(bg.sigma_dn(bg.cx, bg.cy)),
    )
