"""The detector model: sensor parameters, stray-light response and the fixed pattern (PRNU, hot pixels).

Part of :mod:`startracker.imaging` (the signal chain is described there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from types import MappingProxyType
from typing import Mapping

import numpy as np
from scipy.special import ndtr

from startracker.photometry import Photometry
from startracker.validation import check_real

__all__ = [
    "SensorModel",
    "StrayLightResponse",
    "DEFAULT_STRAY_LIGHT",
    "DETECTOR_PRESETS",
    "fixed_pattern",
]


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
        check_real(self.exclusion_angle_deg, "exclusion_angle_deg", 0.0, 180.0, lo_open=True)
        check_real(self.pe_rate_at_exclusion_per_px_s, "pe_rate_at_exclusion_per_px_s", 0.0)
        check_real(self.falloff_exponent, "falloff_exponent", 0.0)
        check_real(self.gradient_fraction, "gradient_fraction", 0.0, 0.999)

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


_PAPER004_CMOS = MappingProxyType(dict(  # paper 004 (comment below)
        psf_sigma_px=1.0,
        photometry=dict(aperture_diameter_mm=17.9, bandwidth_nm=280.0, transmission=0.8, quantum_efficiency=0.65),
        intensifier_gain=1.0, excess_noise_factor=1.0,
        dark_current_e_per_s=5.0, read_noise_e=2.5, full_well_e=10500.0, adc_bits=12, gain_e_per_dn=2.6,
    ))

# Detector presets: SensorModel fields (the rest keep their defaults, paper 000's values). Where a paper is silent
# the value is an assumption, said so.
DETECTOR_PRESETS: Mapping[str, Mapping] = MappingProxyType({
    # Paper 000, Table 2 gives only the optics (20°x20°, f = 31.94 mm, 2048², 5.5 µm). Its MEIA tracker is
    # intensified (refs. 9, 22): assumed an image intensifier of gain 40 (excess noise 1.3, splash 0.9 px) on a
    # CMOS with 5 e- read noise, 20 e-/s dark, 15 ke- full well, 12 bit, 2 e-/DN; f/1.2 (26.6 mm pupil),
    # QE 0.25 of the photocathode over 400 nm; PSF 1.2 px (the SensorModel defaults).
    "paper000": {},
    "paper000_cmos": dict(
        psf_sigma_px=1.0,
        photometry=dict(aperture_diameter_mm=26.6, bandwidth_nm=400.0, transmission=0.8, quantum_efficiency=0.6),
        intensifier_gain=1.0, excess_noise_factor=1.0, read_noise_e=3.0, full_well_e=10000.0, gain_e_per_dn=2.5,
    ),
    # Paper 002, Table 1: ZY-3's APS, 1024x1024, 15 µm, f = 43.3 mm, exposure 125-500 ms, detection threshold
    # V = 6.5, catalog <= 5.5. The paper names no part; that format is the STAR1000 APS's, and its datasheet
    # values are assumed: read noise 47 e-, dark current 3130 e-/s (25 °C), full well 135 ke-, QE x fill factor
    # 0.2 averaged over 400 nm, PRNU 1 %. Assumed a 12-bit ADC over the full well (33 e-/DN) and a defocused
    # PSF of σ = 0.8 px (15 µm pixels). The aperture is not given: 27 mm (f/1.6) puts the 50 % detection
    # point of a 125 ms exposure at V = 6.5, the stated threshold (tests/test_spec.py checks it).
    "zy3": dict(
        psf_sigma_px=0.8,
        photometry=dict(aperture_diameter_mm=27.0, bandwidth_nm=400.0, transmission=0.8, quantum_efficiency=0.2),
        intensifier_gain=1.0, excess_noise_factor=1.0,
        dark_current_e_per_s=3130.0, read_noise_e=47.0, full_well_e=135000.0, adc_bits=12, gain_e_per_dn=33.0,
        hot_pixel_dark_e_per_s=(2.0e4, 2.0e5),
    ),
    # Paper 003 gives the 16°x16° field and a CCD ("CCD plane", N_x x N_y pixels) and no detector data.
    # Assumed (as optics.py's camera) 1024², 15 µm, and a frame-transfer CCD: read noise 10 e-, dark 50 e-/s,
    # full well 100 ke-, QE 0.5 over 400 nm, 14 bit at 6.1 e-/DN, PSF σ 0.8 px; the aperture (11.8 mm) puts the
    # 50 % detection point of a 50 ms exposure at V = 6.5, half a magnitude beyond the paper's V <= 6 catalog.
    "paper003": dict(
        psf_sigma_px=0.8,
        photometry=dict(aperture_diameter_mm=11.8, bandwidth_nm=400.0, transmission=0.8, quantum_efficiency=0.5),
        intensifier_gain=1.0, excess_noise_factor=1.0,
        dark_current_e_per_s=50.0, read_noise_e=10.0, full_well_e=100000.0, adc_bits=14, gain_e_per_dn=6.1,
    ),
    # Paper 004, §4.1 and Table 1: 2064x1544, 3.45 µm, f = 25 mm; one plain CMOS receiving the whole band (no
    # prism). The paper names no detector: a Sony IMX265-class global-shutter CMOS is assumed (read noise
    # 2.5 e-, full well 10.5 ke-, 12 bit at 2.6 e-/DN, dark 5 e-/s), f/1.4 (17.9 mm pupil), QE 0.65 over
    # 280 nm with transmission 0.8, PSF σ 1.0 px.
    "paper004": _PAPER004_CMOS,
    # Paper 004's 3CMOS head: three detectors as "paper004" behind the prism; the photometry describes the three
    # channels together (each receives its share, startracker.color.channels), so its colour term stays 0.
    "paper004_3cmos": _PAPER004_CMOS,
})


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
        check_real(self.psf_sigma_px, "psf_sigma_px", 0.0, 50.0, lo_open=True)
        check_real(self.defocus_sigma_px, "defocus_sigma_px", 0.0, 50.0)
        if not isinstance(self.photometry, Photometry):
            raise TypeError("photometry must be a startracker.photometry.Photometry")
        check_real(self.intensifier_gain, "intensifier_gain", 1.0)
        check_real(self.excess_noise_factor, "excess_noise_factor", 1.0, 10.0)
        check_real(self.intensifier_splash_sigma_px, "intensifier_splash_sigma_px", 0.0, lo_open=True)
        if self.intensified and self.intensifier_splash_sigma_px > self.sigma_px:
            raise ValueError(
                f"intensifier_splash_sigma_px ({self.intensifier_splash_sigma_px}) must not exceed the PSF sigma ({self.sigma_px})"
            )
        check_real(self.sky_mag_per_arcsec2, "sky_mag_per_arcsec2", 0.0, 40.0)
        check_real(self.dark_current_e_per_s, "dark_current_e_per_s", 0.0)
        check_real(self.read_noise_e, "read_noise_e", 0.0)
        check_real(self.prnu_sigma, "prnu_sigma", 0.0, 0.5)
        check_real(self.hot_pixel_fraction, "hot_pixel_fraction", 0.0, 0.01)
        lo_hot, hi_hot = self.hot_pixel_dark_e_per_s
        check_real(lo_hot, "hot_pixel_dark_e_per_s[0]", 0.0, lo_open=True)
        check_real(hi_hot, "hot_pixel_dark_e_per_s[1]", lo_hot)
        check_real(self.full_well_e, "full_well_e", 1.0)
        check_real(self.adc_bits, "adc_bits", 1, 24, integer=True)
        check_real(self.gain_e_per_dn, "gain_e_per_dn", 0.0, lo_open=True)
        check_real(self.bias_dn, "bias_dn", 0.0, 2.0**self.adc_bits - 1)
        for k, v in self.stray_light.items():
            if not isinstance(v, StrayLightResponse):
                raise TypeError(f"stray_light[{k!r}] must be a StrayLightResponse")
        check_real(self.cosmic_ray_rate_per_cm2_s, "cosmic_ray_rate_per_cm2_s", 0.0)
        check_real(self.cosmic_ray_median_e, "cosmic_ray_median_e", 0.0, lo_open=True)
        check_real(self.debris_rate_per_frame, "debris_rate_per_frame", 0.0)
        check_real(self.debris_vmag_range[0], "debris_vmag_range[0]", -5.0, 20.0)
        check_real(self.debris_vmag_range[1], "debris_vmag_range[1]", self.debris_vmag_range[0], 20.0)
        check_real(self.fixed_pattern_seed, "fixed_pattern_seed", 0, integer=True)
        object.__setattr__(self, "adc_bits", int(self.adc_bits))
        object.__setattr__(self, "stray_light", MappingProxyType(dict(self.stray_light)))

    # ------------------------------------------------------------------ presets
    @classmethod
    def preset(cls, name: str) -> "SensorModel":
        """The detector of one of the papers' star trackers (names :data:`DETECTOR_PRESETS`).

        Each field's source is in :data:`DETECTOR_PRESETS`' comments: the paper's table where it gives the
        value, else a stated assumption (a named detector of the format the paper gives, or a choice that
        reproduces a figure the paper states, such as ZY-3's detection threshold).

        * ``"paper000"``: intensified CMOS behind paper 000's optics (the MEIA tracker), the default.
        * ``"paper000_cmos"``: the same optics on a plain CMOS (QE 0.6, 3 e⁻ read noise), for single long
          exposures.
        * ``"zy3"``: ZY-3's APS (paper 002, Table 1: 1024², 15 µm, 125-500 ms, threshold V = 6.5).
        * ``"paper003"``: paper 003's 16°×16° tracker (a CCD; the paper gives no detector data).
        * ``"paper004"``: one of paper 004's CMOS detectors (3.45 µm, 2064×1544) taking the whole band.
        * ``"paper004_3cmos"``: paper 004's three prism channels (photometry of the three together).
        """
        if name not in DETECTOR_PRESETS:
            raise ValueError(f"preset name must be one of {tuple(DETECTOR_PRESETS)}, got {name!r}")
        kw = dict(DETECTOR_PRESETS[name])
        if "photometry" in kw:
            kw["photometry"] = Photometry(**kw["photometry"])
        return cls(**kw, name=name)

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

    def star_pe(self, vmag, bv, exposure_s: float, *, validate: bool = True) -> np.ndarray:
        """Expected photoelectrons of stars in one exposure of ``exposure_s`` seconds, shape like ``vmag``
        (``validate`` as :meth:`startracker.photometry.Photometry.pe_rate`)."""
        return self.photometry.pe_rate(vmag, bv, validate=validate) * float(exposure_s)


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


