"""3CMOS fusion: the three channels registered into the green frame and merged (paper 004).

The channels' centroids merged (:func:`fuse_channel_centroids`), or the registered images summed
(:func:`fuse_channel_images`), and each star's colour ratio ``ln(red / blue)`` by aperture photometry
(:func:`aperture_photometry`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from startracker.color.registration import ColorRegistration
from startracker.kernels.color import mutual_nearest
from startracker.validation import as_float_array

__all__ = [
    "fuse_channel_images",
    "FusedDetections",
    "fuse_channel_centroids",
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


_NO_PAIRS = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


def _mutual_nearest(a: np.ndarray, b: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i into a, j into b) that are each other's nearest neighbour within ``radius``
    (:func:`startracker.kernels.color.mutual_nearest`)."""
    if len(a) == 0 or len(b) == 0:
        return _NO_PAIRS
    return mutual_nearest(np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64),
                          float(radius))


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


def _unpaired(n: int, paired: np.ndarray) -> np.ndarray:
    """Increasing indices in ``range(n)`` that ``paired`` (−1: none) does not hold."""
    free = np.ones(n, dtype=bool)
    free[paired[paired >= 0]] = False
    return np.flatnonzero(free)


def _fuse(cs, registration: ColorRegistration, match_radius_px: float, min_channels: int,
          gain_e_per_dn: float) -> FusedDetections:
    """:func:`fuse_channel_centroids` on checked channel detections."""
    xy, inten, var = [], [], []
    for i, c in enumerate(cs):
        p, it, area = c.xy, c.intensity, c.area
        noise = float(c.noise_dn) if math.isfinite(c.noise_dn) else 0.0
        it_pos = np.maximum(it, 1e-9)
        xy.append(registration.to_green(i, p) if len(p) else p)
        inten.append(it)
        var.append((it_pos / gain_e_per_dn + area * noise**2) / it_pos**2)
    r, g, b = 0, 1, 2
    n_g = len(xy[g])
    idx = np.full((n_g, 3), -1, dtype=np.int64)
    idx[:, g] = np.arange(n_g)
    gi, ri = _mutual_nearest(xy[g], xy[r], match_radius_px)
    idx[gi, r] = ri
    gi, bi = _mutual_nearest(xy[g], xy[b], match_radius_px)
    idx[gi, b] = bi
    free_r = _unpaired(len(xy[r]), idx[:, r])
    free_b = _unpaired(len(xy[b]), idx[:, b])
    ri, bi = _mutual_nearest(xy[r][free_r], xy[b][free_b], match_radius_px)
    rb = np.full((len(ri), 3), -1, dtype=np.int64)
    rb[:, r], rb[:, b] = free_r[ri], free_b[bi]
    rows = [idx, rb]
    if min_channels == 1:
        lone_r = np.setdiff1d(free_r, free_r[ri])
        lone_b = np.setdiff1d(free_b, free_b[bi])
        for ch, lone in ((r, lone_r), (b, lone_b)):
            t = np.full((len(lone), 3), -1, dtype=np.int64)
            t[:, ch] = lone
            rows.append(t)
    idx = np.concatenate(rows)
    present = idx >= 0
    n_ch = present.sum(axis=1)
    keep = n_ch >= min_channels
    idx, present, n_ch = idx[keep], present[keep], n_ch[keep]
    k = len(idx)
    w = np.zeros((k, 3))
    pos = np.zeros((k, 3, 2))
    it = np.zeros((k, 3))
    for ch in range(3):
        m = present[:, ch]
        j = idx[m, ch]
        w[m, ch] = 1.0 / var[ch][j]
        pos[m, ch] = xy[ch][j]
        it[m, ch] = inten[ch][j]
    fused = (w[..., None] * pos).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-300)[:, None]
    has_color = present[:, r] & present[:, b] & (it[:, r] > 0) & (it[:, b] > 0)
    ratio = np.full(k, np.nan)
    ratio[has_color] = np.log(it[has_color, r] / it[has_color, b])
    order = np.argsort(-it.sum(axis=1), kind="stable")
    return FusedDetections(xy=fused[order], intensity=it[order], channel_index=idx[order], n_channels=n_ch[order],
                           color_ratio=ratio[order], has_color=has_color[order])


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
