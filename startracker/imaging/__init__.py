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

Modules
-------
* :mod:`~startracker.imaging.detector`: :class:`SensorModel`, :class:`StrayLightResponse`, the fixed pattern.
* :mod:`~startracker.imaging.background`: :class:`BackgroundField`, :class:`FalseObjects`.
* :mod:`~startracker.imaging.spots`: :class:`SourceTable`, spot paths and windows, intensifier noise.
* :mod:`~startracker.imaging.render`: :func:`render_frame`, :func:`render_expected`, :func:`render_sparse`.
"""

from startracker.imaging.background import (
    BackgroundField,
    COSMIC_MAX_LEN_PX,
    COSMIC_SIGMA_PX,
    FalseObjects,
    background_field,
    draw_false_objects,
)
from startracker.imaging.detector import (
    DEFAULT_STRAY_LIGHT,
    DETECTOR_PRESETS,
    SensorModel,
    StrayLightResponse,
    fixed_pattern,
)
from startracker.imaging.render import (
    SparseFrame,
    draw_false_pixels,
    render_expected,
    render_frame,
    render_sparse,
)
from startracker.imaging.spots import (
    KIND_COSMIC_RAY,
    KIND_DEBRIS,
    KIND_HOT_PIXEL,
    KIND_NOISE,
    KIND_STAR,
    SOURCE_KIND_NAMES,
    SourceTable,
    Spots,
    frame_spots,
    randomize_intensified,
    render_windows,
    window_half_widths,
)

__all__ = [
    "SensorModel",
    "StrayLightResponse",
    "DEFAULT_STRAY_LIGHT",
    "DETECTOR_PRESETS",
    "fixed_pattern",
    "BackgroundField",
    "FalseObjects",
    "background_field",
    "draw_false_objects",
    "COSMIC_SIGMA_PX",
    "COSMIC_MAX_LEN_PX",
    "SourceTable",
    "Spots",
    "KIND_STAR",
    "KIND_NOISE",
    "KIND_HOT_PIXEL",
    "KIND_COSMIC_RAY",
    "KIND_DEBRIS",
    "SOURCE_KIND_NAMES",
    "frame_spots",
    "randomize_intensified",
    "window_half_widths",
    "render_windows",
    "SparseFrame",
    "render_frame",
    "render_expected",
    "render_sparse",
    "draw_false_pixels",
]
