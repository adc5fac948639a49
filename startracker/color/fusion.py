"""3CMOS fusion: the three channels registered into the green frame and merged (paper 004).

The channels' centroids merged (:func:`fuse_channel_centroids`; drawn and merged in one compiled call in the centroid
fidelity: :func:`simulate_fused_detections`), or the registered images summed
(:func:`fuse_channel_images`), and each star's colour ratio ``ln(red / blue)`` by aperture photometry
(:func:`aperture_photometry`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from startracker.centroid.extraction import check_k_sigma
from startracker.centroid.fidelity import default_error_model, draw_centroid_inputs
from startracker.color.registration import ColorRegistration
from startracker.imaging import SensorModel
from startracker.kernels.color import fuse_channels, fused_centroid_detections
from startracker.scene import Scene
from startracker.validation import as_float_array, check_rng

__all__ = [
    "fuse_channel_images",
    "FusedDetections",
    "fuse_channel_centroids",
    "simulate_fused_detections",
    "aperture_photometry",
    "color_ratio_from_fluxes",
]

def _check_images(images) -> np.ndarray:
    if isinstance(images, np.ndarray):
        if images.ndim != 3 or images.shape[0] != 3:
            raise ValueError(f"images must have shape (3, n_rows, n_cols), got {images.shape}")
        arr = images
    else:
        ims = list(images)
        if len(ims) != 3:
            raise ValueError(f"images must hold 3 channel images (red, green, blue), got {len(ims)}")
        shapes = [np.shape(im) for im in ims]
        if len(set(shapes)) != 1 or len(shapes[0]) != 2:
            raise ValueError(f"channel images must be 2-D and of one shape, got {shapes}")
        arr = np.stack([np.asarray(im) for im in ims])
    if not np.issubdtype(arr.dtype, np.number):
        raise TypeError(f"images must be numeric, got dtype {arr.dtype}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("images contain NaN or inf")
    return arr


def fuse_channel_images(images, registration: ColorRegistration, order: int = 1,
                        block_rows: int = 256) -> np.ndarray:
    """Register the red and blue images onto the green frame and sum the three (pixel-level fusion).

    Each green pixel ``(col, row)`` takes the red (blue) value at ``registration.from_green`` of its
    position, interpolated with :func:`scipy.ndimage.map_coordinates` (``order=1``: bilinear, which keeps
    a spot's centre of mass under translation). Extract centroids from the result with
    :func:`startracker.centroid.extract_centroids` as from any frame.

    Parameters
    ----------
    images : array_like, shape (3, n_rows, n_cols)
        Red, green, blue DN.
    registration : ColorRegistration
    order : int
        Spline order of the interpolation, 0..3.
    block_rows : int
        Rows processed at once (memory).

    Returns
    -------
    ndarray of float32, shape (n_rows, n_cols)
        Fused image in the green frame, DN (sum of the three channels: three biases and backgrounds).
    """
    arr = _check_images(images)
    if not isinstance(registration, ColorRegistration):
        raise TypeError(f"registration must be a ColorRegistration, got {type(registration).__name__}")
    if order not in (0, 1, 2, 3):
        raise ValueError(f"order must be 0..3, got {order!r}")
    n_rows, n_cols = arr.shape[1:]
    out = arr[1].astype(np.float64)
    for ch, p in ((0, registration.red), (2, registration.blue)):
        img = arr[ch].astype(np.float64, copy=False)
        if p.q_per_px2 == 0.0:
            # x_c = A^-1 (x_g - b) in (col, row); affine_transform wants (row, col) index order.
            m = p.matrix()
            a_inv = np.linalg.inv(m[:, :2])
            off = -a_inv @ m[:, 2]
            swap = np.array([[0, 1], [1, 0]])
            out += ndimage.affine_transform(img, swap @ a_inv @ swap, offset=swap @ off, order=order,
                                            mode="nearest", prefilter=order > 1)
            continue
        cols = np.arange(n_cols, dtype=np.float64)
        for r0 in range(0, n_rows, block_rows):
            rows = np.arange(r0, min(r0 + block_rows, n_rows), dtype=np.float64)
            cc, rr = np.meshgrid(cols, rows)
            xy_c = p.inverse(np.column_stack([cc.ravel(), rr.ravel()]))
            vals = ndimage.map_coordinates(img, [xy_c[:, 1], xy_c[:, 0]], order=order, mode="nearest",
                                           prefilter=order > 1)
            out[r0:r0 + len(rows)] += vals.reshape(len(rows), n_cols)
    return out.astype(np.float32)


@dataclass(frozen=True, eq=False)
class FusedDetections:
    """Star detections fused over the three channels, in the green frame, brightest first.

    Attributes
    ----------
    xy : ndarray, shape (K, 2)
        Fused centroid (column, row) in the green channel's pixel frame, px.
    intensity : ndarray, shape (K, 3)
        Each channel's intensity (red, green, blue), DN; 0 where the channel did not detect the spot.
    channel_index : ndarray of int, shape (K, 3)
        Index of the detection in each channel's input, −1 where absent.
    n_channels : ndarray of int, shape (K,)
        Channels that detected the spot (1..3).
    color_ratio : ndarray, shape (K,)
        ``ln(I_red / I_blue)`` (compare :meth:`ChannelResponse.color_ratio`); NaN where red or blue is
        missing (see ``has_color``).
    has_color : ndarray of bool, shape (K,)
        Red and blue both detected.
    """

    xy: np.ndarray
    intensity: np.ndarray
    channel_index: np.ndarray
    n_channels: np.ndarray
    color_ratio: np.ndarray
    has_color: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)

    @property
    def total_intensity(self) -> np.ndarray:
        """Sum over the channels, DN, shape (K,)."""
        return self.intensity.sum(axis=1)


def fuse_channel_centroids(centroids, registration: ColorRegistration, *, match_radius_px: float = 2.0,
                           min_channels: int = 2, gain_e_per_dn: float = 1.0, validate: bool = True) -> FusedDetections:
    """Fuse the three channels' centroids into one detection list (centroid-level fusion).

    Red and blue centroids are mapped into the green frame with the calibrated registration; detections of
    different channels that are mutual nearest neighbours within ``match_radius_px`` form one star (green
    is the anchor; red-blue pairs without green are kept too). The fused position is the inverse-variance
    weighted mean with each channel's centroid variance taken ∝ ``(I/g + A σ²) / I²`` (shot noise of the
    spot plus the background noise σ over its area A, intensities in DN, g in e⁻/DN). Requiring
    ``min_channels >= 2`` rejects what only one detector sees: cosmic rays, hot pixels, noise.

    Parameters
    ----------
    centroids : sequence of 3 Centroids
        Red, green, blue detections (anything with ``xy (K, 2)``, ``intensity (K,)``, ``area (K,)``,
        ``noise_dn``), each in its own channel's pixel frame.
    registration : ColorRegistration
    match_radius_px : float
        Largest distance between a channel's registered centroid and the green one, px (> 0).
    min_channels : int
        1, 2 or 3.
    gain_e_per_dn : float
        Conversion gain of the detectors (> 0), e⁻/DN.
    validate : bool
        False skips the checks, for a per-frame caller passing three :class:`startracker.centroid.Centroids`
        (float64 (K, 2) ``xy``, (K,) ``intensity`` and ``area``), a ColorRegistration and valid floats.

    Returns
    -------
    FusedDetections
    """
    if not validate:
        return _fuse(centroids, registration, float(match_radius_px), min_channels, float(gain_e_per_dn))
    cs = list(centroids)
    if len(cs) != 3:
        raise ValueError(f"centroids must hold 3 channel detection lists (red, green, blue), got {len(cs)}")
    if not isinstance(registration, ColorRegistration):
        raise TypeError(f"registration must be a ColorRegistration, got {type(registration).__name__}")
    if not (np.isfinite(match_radius_px) and match_radius_px > 0):
        raise ValueError(f"match_radius_px must be finite and > 0, got {match_radius_px}")
    if min_channels not in (1, 2, 3):
        raise ValueError(f"min_channels must be 1, 2 or 3, got {min_channels!r}")
    if not (np.isfinite(gain_e_per_dn) and gain_e_per_dn > 0):
        raise ValueError(f"gain_e_per_dn must be finite and > 0, got {gain_e_per_dn}")
    checked = []
    for i, c in enumerate(cs):
        p = as_float_array(c.xy, f"centroids[{i}].xy", last_dim=2).reshape(-1, 2)
        it = as_float_array(c.intensity, f"centroids[{i}].intensity").reshape(-1)
        area = as_float_array(c.area, f"centroids[{i}].area").reshape(-1)
        if len(it) != len(p) or len(area) != len(p):
            raise ValueError(f"centroids[{i}] has inconsistent lengths")
        checked.append(_ChannelDetections(p, it, area, c.noise_dn))
    return _fuse(checked, registration, float(match_radius_px), min_channels, float(gain_e_per_dn))


@dataclass(frozen=True)
class _ChannelDetections:
    xy: np.ndarray
    intensity: np.ndarray
    area: np.ndarray
    noise_dn: float


_REGISTRATION_CACHE: dict = {}


def _registration_arrays(registration: ColorRegistration):
    """``(affine (2, 3), x0 (2,), q)`` of red and of blue onto green, as :func:`startracker.kernels.color.fuse_channels`
    takes them: once per (frozen) registration."""
    hit = _REGISTRATION_CACHE.get(id(registration))
    if hit is not None and hit[0] is registration:
        return hit[1]
    out = []
    for p in (registration.red, registration.blue):
        if not p.success:  # ChannelRegistration.apply's refusal
            raise ValueError(f"registration is not calibrated ({p.status}); refusing to apply it")
        out += [np.ascontiguousarray(p.matrix(), dtype=np.float64),
                np.array(p.principal_point, dtype=np.float64), float(p.q_per_px2)]
    value = tuple(out)
    if len(_REGISTRATION_CACHE) > 64:
        _REGISTRATION_CACHE.clear()
    _REGISTRATION_CACHE[id(registration)] = (registration, value)
    return value


def _fuse(cs, registration: ColorRegistration, match_radius_px: float, min_channels: int,
          gain_e_per_dn: float) -> FusedDetections:
    """:func:`fuse_channel_centroids` on checked channel detections: one compiled call
    (:func:`startracker.kernels.color.fuse_channels`)."""
    noise = np.array([float(c.noise_dn) for c in cs])
    xy = [np.ascontiguousarray(c.xy, dtype=np.float64).reshape(-1, 2) for c in cs]
    inten = [np.ascontiguousarray(c.intensity, dtype=np.float64) for c in cs]
    area = [np.ascontiguousarray(c.area, dtype=np.float64) for c in cs]
    fused, it, idx, n_ch, ratio, has_color = fuse_channels(*xy, *inten, *area, noise, *_registration_arrays(registration),
                                                           match_radius_px, int(min_channels), gain_e_per_dn)
    return FusedDetections(xy=fused, intensity=it, channel_index=idx, n_channels=n_ch, color_ratio=ratio,
                           has_color=has_color)


def simulate_fused_detections(scenes, model: SensorModel, rng: np.random.Generator, registration: ColorRegistration,
                              *, k_sigma: float = 5.0, match_radius_px: float = 2.0, min_channels: int = 2,
                              validate: bool = True) -> FusedDetections:
    """The fused detections of a 3CMOS frame in the centroid fidelity, without the per-channel detection lists.

    The same result, draw for draw, as :func:`startracker.centroid.simulate_detections` (``fidelity="centroid"``,
    centre of mass, false objects included) on each channel's scene in turn, then :func:`fuse_channel_centroids` with
    ``gain_e_per_dn = model.gain_e_per_dn``: the draws are made channel after channel, then the three channels'
    detections and their fusion run in one compiled call (:func:`startracker.kernels.color.fused_centroid_detections`).

    Parameters
    ----------
    scenes : sequence of 3 Scene
        Red, green, blue (:func:`startracker.color.channel_scenes`).
    model : SensorModel
        Each channel's detector.
    rng : numpy.random.Generator
    registration : ColorRegistration
    k_sigma : float
        Detection threshold, background σ.
    match_radius_px, min_channels
        As :func:`fuse_channel_centroids`.
    validate : bool
        False skips the checks, for a per-frame caller passing three scenes, a SensorModel, a Generator, a
        ColorRegistration, a float ``k_sigma`` and ``match_radius_px`` and an int ``min_channels``.

    Returns
    -------
    FusedDetections
    """
    if validate:
        scenes = tuple(scenes)
        if len(scenes) != 3 or not all(isinstance(sc, Scene) for sc in scenes):
            raise TypeError("scenes must be three startracker.scene.Scene objects (red, green, blue)")
        if not isinstance(model, SensorModel):
            raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
        check_rng(rng)
        if not isinstance(registration, ColorRegistration):
            raise TypeError(f"registration must be a ColorRegistration, got {type(registration).__name__}")
        k_sigma = check_k_sigma(k_sigma)
        if not (np.isfinite(match_radius_px) and match_radius_px > 0):
            raise ValueError(f"match_radius_px must be finite and > 0, got {match_radius_px}")
        if min_channels not in (1, 2, 3):
            raise ValueError(f"min_channels must be 1, 2 or 3, got {min_channels!r}")
    err = default_error_model(model, "com")
    inputs = [draw_centroid_inputs(sc, model, rng, k_sigma, err, True) for sc in scenes]
    fused, it, idx, n_ch, ratio, has_color = fused_centroid_detections(
        *inputs, *_registration_arrays(registration), float(match_radius_px), int(min_channels),
        float(model.gain_e_per_dn))
    return FusedDetections(xy=fused, intensity=it, channel_index=idx, n_channels=n_ch, color_ratio=ratio,
                           has_color=has_color)


def aperture_photometry(images, xy_green, registration: ColorRegistration, radius_px: float = 3.0,
                        annulus_px: tuple[float, float] = (5.0, 8.0)) -> np.ndarray:
    """Background-subtracted flux of each star in each channel, measured at its registered position.

    For every star the green-frame position is mapped onto each detector; the flux is the sum of the
    pixels whose centres lie within ``radius_px`` minus their number times the median of the annulus
    ``annulus_px`` (local background). Unbiased for faint spots, unlike a thresholded sum, so the ratio
    of two channels estimates the colour.

    Parameters
    ----------
    images : array_like, shape (3, n_rows, n_cols)
        Red, green, blue DN.
    xy_green : array_like, shape (K, 2)
        Star positions in the green frame, px.
    registration : ColorRegistration
    radius_px : float
        Aperture radius, px (0.5 .. 20).
    annulus_px : (float, float)
        Inner and outer radius of the background annulus, px (``radius_px < inner < outer <= 30``).

    Returns
    -------
    ndarray, shape (K, 3)
        Flux in DN per channel (red, green, blue). Stars whose aperture leaves a detector get 0 there.
    """
    arr = _check_images(images)
    xy = as_float_array(xy_green, "xy_green", last_dim=2).reshape(-1, 2)
    if not isinstance(registration, ColorRegistration):
        raise TypeError(f"registration must be a ColorRegistration, got {type(registration).__name__}")
    if not (np.isfinite(radius_px) and 0.5 <= radius_px <= 20):
        raise ValueError(f"radius_px must lie in [0.5, 20], got {radius_px}")
    a_in, a_out = (float(v) for v in as_float_array(annulus_px, "annulus_px", last_dim=2, ndim=1))
    if not radius_px < a_in < a_out <= 30:
        raise ValueError(f"annulus_px must satisfy radius_px < inner < outer <= 30, got {(a_in, a_out)}")
    n_rows, n_cols = arr.shape[1:]
    h = int(np.ceil(a_out))
    off = np.arange(-h, h + 1)
    dr, dc = np.meshgrid(off, off, indexing="ij")
    dr, dc = dr.ravel(), dc.ravel()
    out = np.zeros((len(xy), 3))
    if len(xy) == 0:
        return out
    for ch in range(3):
        p = registration.from_green(ch, xy)
        r0 = np.rint(p[:, 1]).astype(np.int64)
        c0 = np.rint(p[:, 0]).astype(np.int64)
        rr = r0[:, None] + dr[None, :]
        cc = c0[:, None] + dc[None, :]
        inside = (r0 - h >= 0) & (r0 + h < n_rows) & (c0 - h >= 0) & (c0 + h < n_cols)
        vals = arr[ch][np.clip(rr, 0, n_rows - 1), np.clip(cc, 0, n_cols - 1)].astype(np.float64)
        d = np.hypot(cc - p[:, :1], rr - p[:, 1:2])
        ap = d <= radius_px
        ann = (d >= a_in) & (d <= a_out)
        bg = np.nanmedian(np.where(ann, vals, np.nan), axis=1)
        flux = (np.where(ap, vals, 0.0).sum(axis=1) - ap.sum(axis=1) * bg)
        out[:, ch] = np.where(inside, flux, 0.0)
    return out


def color_ratio_from_fluxes(flux) -> tuple[np.ndarray, np.ndarray]:
    """``ln(F_red / F_blue)`` from (K, 3) channel fluxes.

    Returns
    -------
    ratio : ndarray, shape (K,)
        NaN where either flux is not positive (see ``valid``).
    valid : ndarray of bool, shape (K,)
    """
    f = as_float_array(flux, "flux", last_dim=3).reshape(-1, 3)
    valid = (f[:, 0] > 0) & (f[:, 2] > 0)
    ratio = np.full(len(f), np.nan)
    ratio[valid] = np.log(f[valid, 0] / f[valid, 2])
    return ratio, valid
