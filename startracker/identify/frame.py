"""One frame of detections prepared for identification, and the options every method shares.

Preparation: check the arrays, order the detections brightest first, drop points off the detector and
duplicates (they keep the label −1), turn pixels into camera-frame unit vectors with
:meth:`Camera.unproject`'s model, and tabulate the inter-star angles and their tolerances once (one
compiled call, :func:`startracker.kernels.identify.prepare_detections`).

Tolerances. With a centroid noise of ``sigma_px`` (1σ per axis) the angle between two stars is off by
``√2 σ`` (1σ). A pair window is ``± (pair_sigmas · √2 σ ⊕ floor) + aberration_scale · θ`` (⊕: root sum
of squares; the last term covers the differential velocity aberration, ~1e-4 of the angle, that no
rotation absorbs). After an attitude fit the residual of a star is Rayleigh-distributed, so the
verification radius is ``match_sigmas · σ ⊕ floor``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from startracker.kernels.identify import prepare_detections
from startracker.optics import Camera
from startracker.validation import as_float_array

__all__ = ["IdentifyOptions", "Frame", "prepare_frame", "detection_arguments", "ARCSEC"]

ARCSEC = np.pi / (180.0 * 3600.0)


@dataclass(frozen=True)
class IdentifyOptions:
    """Options of :func:`startracker.identify.identify` (keyword arguments).

    Attributes
    ----------
    sigma_px : float
        Expected centroid noise, 1σ per axis, pixels (> 0). Sets every tolerance.
    pair_sigmas : float
        Half-width of an inter-star-angle window in σ of the angle.
    match_sigmas : float
        Verification radius in σ of the centroid noise.
    floor_arcsec : float
        Added in quadrature to both tolerances (catalog, distortion and calibration errors).
    aberration_scale : float
        Relative widening of pair windows for differential velocity aberration (1.1e-4 covers a
        spacecraft in Earth orbit).
    false_alarm : float
        Largest accepted probability that a wrong hypothesis gathers its confirming matches by chance;
        sets how many detections must match (see :mod:`startracker.identify.verification`).
    max_stars : int or None
        How many of the brightest detections feed the hypothesis search (method default when None:
        pyramid 12, voting 20, brightness 10, string all). Verification always uses every detection.
    max_triads : int
        Pyramid: most triads tried (in Mortari's "smart" order).
    max_combinations : int
        Brightness-referenced: most star groups tried per mode.
    mag_zero_point : float
        Measured magnitude of a detection is ``mag_zero_point − 2.5 log10(intensity)``; the default 0
        means intensities are fluxes relative to a V = 0 star.
    mag_sigma : float
        1σ error of a measured magnitude (paper 002: 0.2 mag).
    gamma_mag : float or None
        Brightness method: two detections are ordered (brighter ↔ catalog ``I``) only when their
        measured magnitudes differ by more than this; default ``3 √2 mag_sigma``.
    ref_mag : float
        Brightness method: a detection brighter than this (intensity above Mt) is a reference star.
    max_skips : int
        Pattern strings: observed neighbours allowed to stay unmatched (paper 003: one).
    max_main_stars : int
        Pattern strings: main stars tried, in order of Q = M / n_neighbour.
    max_candidates : int
        Pattern strings: guide-star candidates examined per main star (the five whose neighbours agree
        best on the roll are verified).
    """

    sigma_px: float = 0.5
    pair_sigmas: float = 3.0
    match_sigmas: float = 4.0
    floor_arcsec: float = 5.0
    aberration_scale: float = 1.1e-4
    false_alarm: float = 1e-6
    max_stars: int | None = None
    max_triads: int = 100
    max_combinations: int = 200
    mag_zero_point: float = 0.0
    mag_sigma: float = 0.2
    gamma_mag: float | None = None
    ref_mag: float = 3.0
    max_skips: int = 1
    max_main_stars: int = 5
    max_candidates: int = 50

    @classmethod
    def from_kwargs(cls, options: dict) -> "IdentifyOptions":
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - names)
        if unknown:
            raise TypeError(f"unknown identify option(s) {unknown}; accepted: {sorted(names)}")
        opts = cls(**options)
        opts._check()
        return opts

    def _check(self):
        def positive(name, allow_zero=False):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
            if v < 0 or (v == 0 and not allow_zero):
                raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {v!r}")

        for name in ("sigma_px", "pair_sigmas", "match_sigmas", "false_alarm", "mag_sigma"):
            positive(name)
        for name in ("floor_arcsec", "aberration_scale"):
            positive(name, allow_zero=True)
        if not self.false_alarm < 1:
            raise ValueError(f"false_alarm must be in (0, 1), got {self.false_alarm}")
        for name in ("mag_zero_point", "ref_mag"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        if self.gamma_mag is not None:
            positive("gamma_mag", allow_zero=True)
        for name, lo in (("max_triads", 1), ("max_combinations", 1), ("max_skips", 0), ("max_main_stars", 1),
                         ("max_candidates", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if self.max_stars is not None and (
            isinstance(self.max_stars, bool) or not isinstance(self.max_stars, (int, np.integer)) or self.max_stars < 3
        ):
            raise ValueError(f"max_stars must be None or an integer >= 3, got {self.max_stars!r}")

    @property
    def gamma(self) -> float:
        return 3.0 * np.sqrt(2.0) * self.mag_sigma if self.gamma_mag is None else float(self.gamma_mag)


@dataclass
class Frame:
    """Detections ready for identification (only the usable ones, brightest first).

    Attributes
    ----------
    v : ndarray, shape (n, 3)
        Camera-frame unit vectors.
    mag : ndarray, shape (n,) or None
        Measured magnitudes (None when no intensities were given).
    index : ndarray of int, shape (n,)
        Row of each usable detection in the caller's ``xy``.
    n_input : int
        Rows of the caller's ``xy``.
    angle_rad : ndarray, shape (m, m)
        Inter-star angles of the first ``m <= n`` detections (the hypothesis pool, or all).
    pair_tol_rad : ndarray, shape (m, m)
        Half-width of the window of each pair's angle.
    match_tol_rad : float
        Verification radius.
    sigma_rad : float
        Centroid noise as an angle (1σ per axis).
    n_dropped : int
        Detections dropped as off the detector or duplicated.
    """

    v: np.ndarray
    mag: np.ndarray | None
    index: np.ndarray
    n_input: int
    angle_rad: np.ndarray
    pair_tol_rad: np.ndarray
    match_tol_rad: float
    sigma_rad: float
    n_dropped: int

    @property
    def n(self) -> int:
        return len(self.v)


def detection_arguments(xy, camera: Camera, intensities, opts: IdentifyOptions, n_angles: int | None = None):
    """Check detections and turn them, the camera and the options into the arguments of
    :func:`startracker.kernels.identify.prepare_detections`.

    Returns
    -------
    args : tuple
        The kernel's arguments.
    k : int
        Rows of ``xy``.
    sigma_rad, match_tol_rad : float
        Centroid noise as an angle and the verification radius.

    Raises
    ------
    ValueError
        ``xy`` is not a finite (K, 2) array, or ``intensities`` is not a finite positive (K,) array.
    """
    xy = _finite_array(xy, "xy")
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy must have shape (K, 2) (column, row in pixels), got {xy.shape}")
    k = len(xy)
    if intensities is not None:
        inten = _finite_array(intensities, "intensities")
        if inten.shape != (k,):
            raise ValueError(f"intensities must have shape ({k},) to match xy, got {inten.shape}")
        if k and not np.minimum.reduce(inten) > 0:
            raise ValueError("intensities must be positive")
    else:
        inten = _NO_INTENSITIES
    c = _camera_constants(camera)
    sigma_rad = opts.sigma_px * c[7]
    floor = opts.floor_arcsec * ARCSEC
    # Duplicates (closer than a tenth of the noise or 0.05 px): keep the brighter.
    dup_rad = max(0.1 * sigma_rad, 0.05 * c[7])
    n_tab = k if n_angles is None else int(n_angles)
    args = (np.ascontiguousarray(xy), np.ascontiguousarray(inten), intensities is not None,
            float(opts.mag_zero_point), c[0], c[1], c[2], c[3], c[4], c[5], c[6], n_tab, math.cos(dup_rad),
            opts.pair_sigmas * _SQRT2 * sigma_rad, floor, float(opts.aberration_scale))
    return args, k, sigma_rad, math.hypot(opts.match_sigmas * sigma_rad, floor)


def prepare_frame(xy, camera: Camera, intensities, opts: IdentifyOptions, n_angles: int | None = None) -> Frame:
    """Validate and prepare detections (see the module docstring).

    ``n_angles`` limits the angle tables to the brightest detections (None: all).

    Raises
    ------
    ValueError
        ``xy`` is not a finite (K, 2) array, or ``intensities`` is not a finite positive (K,) array.
    """
    args, k, sigma_rad, match_tol = detection_arguments(xy, camera, intensities, opts, n_angles)
    index, v, mag, ang, pair_tol = prepare_detections(*args)
    return Frame(
        v=v,
        mag=None if intensities is None else mag,
        index=index,
        n_input=k,
        angle_rad=ang,
        pair_tol_rad=pair_tol,
        match_tol_rad=match_tol,
        sigma_rad=sigma_rad,
        n_dropped=k - len(index),
    )


_NO_INTENSITIES = np.ones(0)
_SQRT2 = math.sqrt(2.0)
_CAMERA_CONSTANTS: dict = {}


def _finite_array(a, name: str) -> np.ndarray:
    """``a`` as a finite float64 array (a float64 array whose sum is finite holds no NaN or inf)."""
    if type(a) is np.ndarray and a.dtype == np.float64 and math.isfinite(np.add.reduce(a, axis=None)):
        return a
    return as_float_array(a, name)


def _camera_constants(camera: Camera) -> tuple:
    """The camera model as plain numbers for the frame kernel, computed once per camera object."""
    hit = _CAMERA_CONSTANTS.get(id(camera))
    if hit is not None and hit[0] is camera:
        return hit[1]
    w, h = camera.resolution
    cx, cy = camera.principal_point
    c = (int(w), int(h), float(camera.focal_length_mm), float(camera.distortion_k1_per_mm2),
         float(camera.pixel_size_mm), float(cx), float(cy), float(camera.pixel_size_mm / camera.focal_length_mm))
    if len(_CAMERA_CONSTANTS) > 64:
        _CAMERA_CONSTANTS.clear()
    _CAMERA_CONSTANTS[id(camera)] = (camera, c)  # holding the camera keeps its id from being reused
    return c
