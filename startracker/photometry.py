"""Photometry: V magnitude -> photoelectrons per second through a star camera.

A star of Johnson magnitude V delivers (Pogson: 5 magnitudes = a factor 100)::

    rate_pe_s = Φ0 · 10^(-0.4 (V + c (B−V))) · Δλ · A · T · QE

with Φ0 the photon flux density of a V = 0 star (≈ 1.0e4 photons s⁻¹ cm⁻² nm⁻¹ at 550 nm: 3.63e-9
erg s⁻¹ cm⁻² Å⁻¹ divided by the photon energy 3.61e-12 erg), Δλ the effective bandwidth (nm),
A = π D²/4 the entrance-pupil area (cm²), T the optics' transmission and QE the detector's (or the
photocathode's) quantum efficiency. ``c`` is an optional colour term for a band wider or redder than V
(0 by default: the band is treated as V). Diffuse light given as a surface brightness (mag/arcsec²)
is converted with the pixel's solid angle ``(p/f)²``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from startracker.validation import as_float_array

__all__ = ["Photometry", "ARCSEC_PER_RAD", "V0_PHOTONS_S_CM2_NM"]

ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi
V0_PHOTONS_S_CM2_NM = 1.0e4


def _check_positive(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")


@dataclass(frozen=True)
class Photometry:
    """Throughput of a star camera from V magnitude to photoelectrons.

    Parameters
    ----------
    aperture_diameter_mm : float
        Entrance-pupil diameter D, mm.
    bandwidth_nm : float
        Effective bandwidth Δλ, nm.
    transmission : float
        Optics transmission T in (0, 1].
    quantum_efficiency : float
        QE in (0, 1] of the detector (or of an intensifier's photocathode).
    zero_point_photons_s_cm2_nm : float
        Φ0, photon flux density of a V = 0 star, photons s⁻¹ cm⁻² nm⁻¹.
    color_term_per_bv : float
        c: the band's magnitude is ``V + c (B−V)``.
    """

    aperture_diameter_mm: float = 26.6
    bandwidth_nm: float = 400.0
    transmission: float = 0.75
    quantum_efficiency: float = 0.25
    zero_point_photons_s_cm2_nm: float = V0_PHOTONS_S_CM2_NM
    color_term_per_bv: float = 0.0

    def __post_init__(self):
        for name in ("aperture_diameter_mm", "bandwidth_nm", "zero_point_photons_s_cm2_nm"):
            _check_positive(getattr(self, name), name)
        for name in ("transmission", "quantum_efficiency"):
            _check_positive(getattr(self, name), name)
            if getattr(self, name) > 1:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        if not math.isfinite(self.color_term_per_bv):
            raise ValueError("color_term_per_bv must be finite")

    @property
    def aperture_area_cm2(self) -> float:
        """π D² / 4 in cm²."""
        return math.pi * (0.1 * self.aperture_diameter_mm) ** 2 / 4.0

    @cached_property  # the fields are frozen; read every frame (star_pe)
    def pe_per_s_at_v0(self) -> float:
        """Photoelectrons per second from a V = 0, B−V = 0 star."""
        return (
            self.zero_point_photons_s_cm2_nm
            * self.bandwidth_nm
            * self.aperture_area_cm2
            * self.transmission
            * self.quantum_efficiency
        )

    def pe_rate(self, vmag, bv=0.0, *, validate: bool = True) -> np.ndarray:
        """Photoelectron rate of stars, pe/s.

        Parameters
        ----------
        vmag : array_like, shape (K,)
            V magnitudes.
        bv : array_like, shape (K,) or scalar
            B−V colour indices (used only through ``color_term_per_bv``).
        validate : bool
            False takes ``vmag`` and ``bv`` as they are: float64 arrays (or floats) the caller has checked, as a
            frame's scene holds them (the per-frame path).

        Returns
        -------
        ndarray, shape (K,)
        """
        if validate:
            vmag = as_float_array(vmag, "vmag")
            bv = as_float_array(bv, "bv")
        return self.pe_per_s_at_v0 * 10.0 ** (-0.4 * (vmag + self.color_term_per_bv * bv))

    def magnitude_of_rate(self, pe_per_s) -> np.ndarray:
        """Inverse of :meth:`pe_rate` for B−V = 0: the V magnitude giving ``pe_per_s``."""
        r = as_float_array(pe_per_s, "pe_per_s")
        if np.any(r <= 0):
            raise ValueError("pe_per_s must be > 0")
        return -2.5 * np.log10(r / self.pe_per_s_at_v0)

    def surface_pe_rate_per_px(self, mag_per_arcsec2: float, pixel_size_um: float, focal_length_mm: float) -> float:
        """Photoelectron rate per pixel from a uniform surface brightness, pe s⁻¹ px⁻¹.

        Parameters
        ----------
        mag_per_arcsec2 : float
            V surface brightness (e.g. ≈ 22.5 for the zodiacal/diffuse sky away from the ecliptic).
        pixel_size_um, focal_length_mm : float
            Give the pixel's solid angle ``(p / f)²`` sr.
        """
        pix_arcsec = (pixel_size_um * 1e-3 / focal_length_mm) * ARCSEC_PER_RAD
        return float(self.pe_per_s_at_v0 * 10.0 ** (-0.4 * mag_per_arcsec2) * pix_arcsec**2)
