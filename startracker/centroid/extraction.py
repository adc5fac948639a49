"""Detections and sub-pixel centroids from an image or from sparse pixels (paper 002 §3).

Centroiding (paper 002 §3)
--------------------------
1. Background: the image's level and noise σ, from sigma-clipped statistics of 64×64 blocks (every
   second pixel), fitted by a plane (default), kept per block ("local") or pooled ("global").
2. Threshold: a pixel belongs to a spot when ``DN > background + k σ``; spots are the 8-connected
   components (``scipy.ndimage.label`` on an image; a union-find over the sparse pixel set for a
   :class:`~startracker.imaging.SparseFrame`); their pixels are gathered once and measured by the compiled
   kernels of :mod:`startracker.kernels.centroid_extraction` (no ``center_of_mass`` over the frame).
3. Centre of mass (§3.1, eqs. 1–3): ``x = Σ x DN' / Σ DN'`` over the component with the background
   subtracted, ``DN' = DN − background``.
4. Gaussian interpolation (§3.2, Quine 2007, eqs. 4–6): the brightest pixel and its brighter neighbour
   along each axis; their ratio equals ``g(x; a, b) / g(x; c, d)`` with ``g`` the Gaussian integrated
   over a pixel (eq. 5). The paper linearises this to a quadratic; here the ratio is inverted exactly
   (bisection, monotone in the offset). σ is ``psf_sigma_px`` if given, else estimated per spot from the
   log-parabola through the three pixels. Saturated spots fall back to the centre of mass.

Every spot is one detection, brightest (largest intensity) first; grouping spots into stars and
exposures is the tracker's job.

Fidelities of :func:`simulate_detections`
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from startracker.imaging import KIND_NOISE, KIND_STAR, SparseFrame
from startracker.kernels.centroid_extraction import (detect_sparse, gaussian_refine, measure_components, rank_components,
                                                    truth_labels)

__all__ = [
    "Centroids",
    "estimate_background",
    "extract_centroids",
    "detections_from_sparse",
    "check_k_sigma",
    "check_method",
    "check_min_area",
    "check_psf_sigma",
]


_METHODS = ("com", "gaussian")
_CLIP3_VAR = 1.0 - 6.0 * math.exp(-4.5) / math.sqrt(2 * math.pi) / math.erf(3.0 / math.sqrt(2.0))
_EIGHT = np.ones((3, 3), dtype=bool)



# ------------------------------------------------------------------------------------------ result
@dataclass(frozen=True, eq=False)
class Centroids:
    """Detected spots, brightest first.

    Attributes
    ----------
    xy : ndarray, shape (K, 2)
        Centroids (column, row), px; (0, 0) is the centre of the top-left pixel.
    intensity : ndarray, shape (K,)
        Background-subtracted sum over the spot, DN.
    area : ndarray of int, shape (K,)
        Pixels above the threshold.
    saturated : ndarray of bool, shape (K,)
        The spot has a pixel at or above the saturation level.
    peak : ndarray, shape (K,)
        Brightest pixel above the background, DN.
    snr : ndarray, shape (K,)
        ``intensity / (σ √area)`` with σ the background noise, a rough signal-to-noise ratio.
    background_dn, noise_dn : float
        Background level and σ at the detector centre, DN.
    truth_star : ndarray of int, shape (K,) or None
        Simulated detections only: scene star index, −1 for false detections.
    truth_exposure : ndarray of int, shape (K,) or None
        Exposure index, −1 when not a star or debris.
    truth_kind : ndarray of int, shape (K,) or None
        ``startracker.imaging.KIND_*`` (star, noise, hot pixel, cosmic ray, debris).
    truth_xy : ndarray, shape (K, 2) or None
        Where the source's light is centred (time average over the exposure), px.
    """

    xy: np.ndarray
    intensity: np.ndarray
    area: np.ndarray
    saturated: np.ndarray
    peak: np.ndarray
    snr: np.ndarray
    background_dn: float = float("nan")
    noise_dn: float = float("nan")
    truth_star: np.ndarray | None = None
    truth_exposure: np.ndarray | None = None
    truth_kind: np.ndarray | None = None
    truth_xy: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.intensity)

    @classmethod
    def empty(cls, background_dn=float("nan"), noise_dn=float("nan"), with_truth=False) -> "Centroids":
        z = np.zeros(0)
        t = np.zeros(0, dtype=np.int64) if with_truth else None
        return cls(np.zeros((0, 2)), z, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool), z, z,
                   float(background_dn), float(noise_dn), t, t, t, np.zeros((0, 2)) if with_truth else None)

    def subset(self, index) -> "Centroids":
        """The selected detections (boolean mask or index array), order kept."""
        idx = np.asarray(index)

        def pick(a):
            return None if a is None else a[idx]

        return Centroids(self.xy[idx], self.intensity[idx], self.area[idx], self.saturated[idx], self.peak[idx],
                         self.snr[idx], self.background_dn, self.noise_dn, pick(self.truth_star),
                         pick(self.truth_exposure), pick(self.truth_kind), pick(self.truth_xy))

    @property
    def is_true_star(self) -> np.ndarray:
        """(K,) bool, simulated detections only: the detection is a catalog star."""
        if self.truth_kind is None:
            raise ValueError("these centroids carry no truth labels (they come from an image)")
        return self.truth_kind == KIND_STAR


# ------------------------------------------------------------------------------------------ checks
def check_k_sigma(k_sigma):
    """Detection threshold ``k_sigma`` (σ above background) as a float > 0; TypeError/ValueError otherwise."""
    if isinstance(k_sigma, bool) or not isinstance(k_sigma, (int, float, np.integer, np.floating)):
        raise TypeError(f"k_sigma must be a number, got {type(k_sigma).__name__}")
    if not math.isfinite(k_sigma) or k_sigma <= 0:
        raise ValueError(f"k_sigma must be finite and > 0, got {k_sigma}")
    return float(k_sigma)


def check_method(method):
    """Raise ValueError unless ``method`` is a centroiding method (``"com"`` or ``"gaussian"``)."""
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")


def check_min_area(min_area_px):
    """Smallest accepted spot area ``min_area_px`` as an int >= 1; ValueError otherwise."""
    if isinstance(min_area_px, bool) or not isinstance(min_area_px, (int, np.integer)) or min_area_px < 1:
        raise ValueError(f"min_area_px must be an integer >= 1, got {min_area_px!r}")
    return int(min_area_px)


def check_psf_sigma(psf_sigma_px):
    """PSF σ ``psf_sigma_px`` as a float in (0, 50) px, or None (estimate per spot); ValueError otherwise."""
    if psf_sigma_px is None:
        return None
    if not isinstance(psf_sigma_px, (int, float, np.integer, np.floating)) or not (0 < psf_sigma_px < 50):
        raise ValueError(f"psf_sigma_px must be in (0, 50) px or None, got {psf_sigma_px!r}")
    return float(psf_sigma_px)


# ------------------------------------------------------------------------------------------ background
def _clipped_block_stats(image: np.ndarray, block_px: int):
    """Sigma-clipped mean and variance of every block (every second pixel), with block centres."""
    n_rows, n_cols = image.shape
    b = max(4, min(block_px, n_rows // 4, n_cols // 4))  # at least 4x4 blocks
    nby, nbx = n_rows // b, n_cols // b
    sub = image[: nby * b : 2, : nbx * b : 2].astype(np.float64)
    hb = (b + 1) // 2
    blocks = sub.reshape(nby, hb, nbx, hb).transpose(0, 2, 1, 3).reshape(nby, nbx, -1)
    med = np.median(blocks, axis=2, keepdims=True)
    mad = np.median(np.abs(blocks - med), axis=2, keepdims=True)
    s0 = np.maximum(1.4826 * mad, 0.5)
    mean, var = med[..., 0], (s0**2)[..., 0]
    centre = med
    half = 3.0 * s0
    for _ in range(3):
        keep = np.abs(blocks - centre) < half
        n = np.maximum(keep.sum(axis=2), 1)
        mean = np.where(keep, blocks, 0.0).sum(axis=2) / n
        var = np.where(keep, (blocks - mean[..., None]) ** 2, 0.0).sum(axis=2) / np.maximum(n - 1, 1)
        var = var / _CLIP3_VAR  # a Gaussian clipped at ±3σ keeps 97.3 % of its variance
        centre = mean[..., None]
        half = np.maximum(3.0 * np.sqrt(np.maximum(var, 0.0)), 0.5)[..., None]
    yc = (np.arange(nby) + 0.5) * b - 0.5
    xc = (np.arange(nbx) + 0.5) * b - 0.5
    return mean, var, xc, yc, b


def estimate_background(image, background: str = "plane", block_px: int = 64):
    """Background level and noise of an image.

    Parameters
    ----------
    image : ndarray, shape (n_rows, n_cols)
    background : {"plane", "local", "global"}
        "plane": least-squares planes through the blocks' clipped means and variances (smooth gradients
        such as stray light); "local": block values, nearest block; "global": one level and σ.
    block_px : int

    Returns
    -------
    level : callable (rows, cols) -> DN
    sigma : callable (rows, cols) -> DN
    (level_at_centre, sigma_at_centre) : (float, float)
    """
    if background not in ("plane", "local", "global"):
        raise ValueError(f"background must be 'plane', 'local' or 'global', got {background!r}")
    mean, var, xc, yc, b = _clipped_block_stats(image, block_px)
    n_rows, n_cols = image.shape
    if background == "global":
        m = float(np.median(mean))
        s = float(np.sqrt(np.median(var)))
        return (lambda r, c: np.full(np.broadcast(r, c).shape, m)), (lambda r, c: np.full(np.broadcast(r, c).shape, s)), (m, s)
    if background == "plane":
        X, Y = np.meshgrid(xc - n_cols / 2, yc - n_rows / 2)
        A = np.column_stack([np.ones(X.size), X.ravel(), Y.ravel()])
        # robust: drop blocks far from the median plane (bright stars, cosmic rays)
        cm, *_ = np.linalg.lstsq(A, mean.ravel(), rcond=None)
        cv, *_ = np.linalg.lstsq(A, var.ravel(), rcond=None)
        resid = mean.ravel() - A @ cm
        good = np.abs(resid) < 5 * np.sqrt(np.median(var)) / math.sqrt(max(b * b / 4, 1)) + 5 * np.median(np.abs(resid)) + 1e-9
        if good.sum() >= 3:
            cm, *_ = np.linalg.lstsq(A[good], mean.ravel()[good], rcond=None)
            cv, *_ = np.linalg.lstsq(A[good], var.ravel()[good], rcond=None)

        def level(r, c):
            return cm[0] + cm[1] * (np.asarray(c) - n_cols / 2) + cm[2] * (np.asarray(r) - n_rows / 2)

        def sigma(r, c):
            return np.sqrt(np.maximum(cv[0] + cv[1] * (np.asarray(c) - n_cols / 2) + cv[2] * (np.asarray(r) - n_rows / 2), 1e-12))

        return level, sigma, (float(cm[0]), float(math.sqrt(max(cv[0], 1e-12))))
    if background == "local":
        nby, nbx = mean.shape
        sd = np.sqrt(np.maximum(var, 1e-12))

        def pick(arr):
            def f(r, c):
                bi = np.clip(np.asarray(r) // b, 0, nby - 1)
                bj = np.clip(np.asarray(c) // b, 0, nbx - 1)
                return arr[bi, bj]

            return f

        return pick(mean), pick(sd), (float(mean[nby // 2, nbx // 2]), float(sd[nby // 2, nbx // 2]))
    raise ValueError(f"background must be 'plane', 'local' or 'global', got {background!r}")


# ------------------------------------------------------------------------------------------ measuring
def _measure(labels, n_comp, rows, cols, signal, sat_px, noise_px, method, lookup, psf_sigma_px, min_area_px):
    """Measure components from their pixels (the full-frame path; the sparse path runs in one kernel).

    labels (A,) in [0, n_comp); rows, cols (A,); signal (A,) DN above background; sat_px (A,) bool;
    noise_px (A,) background σ (DN); lookup(rows, cols) -> background-subtracted DN (NaN if unknown).
    Returns xy, intensity, area, saturated, peak, snr of the kept components, brightest first.
    """
    rows = rows.astype(np.float64)
    cols = cols.astype(np.float64)
    x, y, inten, area, sat, noise, peak, pk = measure_components(labels.astype(np.int64), int(n_comp), rows, cols,
                                                                 signal, sat_px.astype(bool), noise_px.astype(np.float64))
    if method == "gaussian" and n_comp:
        r0 = rows[pk].astype(np.int64)
        c0 = cols[pk].astype(np.int64)
        gaussian_refine(x, y, rows[pk], cols[pk], signal[pk], lookup(r0, c0 - 1), lookup(r0, c0 + 1),
                        lookup(r0 - 1, c0), lookup(r0 + 1, c0), sat,
                        float("nan") if psf_sigma_px is None else float(psf_sigma_px))
    keep, snr = rank_components(inten, area, noise, int(min_area_px))
    return np.column_stack([x[keep], y[keep]]), inten[keep], area[keep], sat[keep], peak[keep], snr


def extract_centroids(
    image,
    k_sigma: float = 5.0,
    method: str = "com",
    *,
    saturation_dn: float | None = None,
    min_area_px: int = 1,
    background: str = "plane",
    block_px: int = 64,
    psf_sigma_px: float | None = None,
) -> Centroids:
    """Detect the spots of a frame and measure their centroids.

    Parameters
    ----------
    image : array_like, shape (n_rows, n_cols)
        DN, ``image[row, col]``; finite.
    k_sigma : float
        Threshold above the background in units of its σ.
    method : {"com", "gaussian"}
        Centre of mass (paper 002 §3.1) or Gaussian interpolation (§3.2).
    saturation_dn : float, optional
        Pixels at or above it are saturated (``SensorModel.saturation_dn``); None: no flag.
    min_area_px : int
        Smallest spot kept, pixels.
    background : {"plane", "local", "global"}
        See :func:`estimate_background`.
    block_px : int
        Block size of the background statistics.
    psf_sigma_px : float, optional
        σ for the Gaussian interpolation; estimated per spot when None.

    Returns
    -------
    Centroids
        Brightest first; empty for an empty or fully saturated frame.

    Raises
    ------
    ValueError
        ``image`` not 2-D, too small, or containing NaN/inf; bad parameters.
    """
    if isinstance(image, (str, bytes)):
        raise TypeError("image must be a numeric 2-D array")
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D (rows, cols), got shape {img.shape}")
    if img.shape[0] < 4 or img.shape[1] < 4:
        raise ValueError(f"image must be at least 4x4 pixels, got {img.shape}")
    if not np.issubdtype(img.dtype, np.number) or np.issubdtype(img.dtype, np.complexfloating):
        raise TypeError(f"image must be real-valued, got dtype {img.dtype}")
    if np.issubdtype(img.dtype, np.floating) and not np.all(np.isfinite(img)):
        raise ValueError("image contains NaN or inf")
    k = check_k_sigma(k_sigma)
    check_method(method)
    min_area_px = check_min_area(min_area_px)
    psf_sigma_px = check_psf_sigma(psf_sigma_px)
    if saturation_dn is not None and not np.isfinite(saturation_dn):
        raise ValueError("saturation_dn must be finite or None")
    if isinstance(block_px, bool) or not isinstance(block_px, (int, np.integer)) or block_px < 4:
        raise ValueError(f"block_px must be an integer >= 4, got {block_px!r}")

    level, sigma, (bg0, s0) = estimate_background(img, background, int(block_px))
    n_rows, n_cols = img.shape
    rr = np.arange(n_rows)[:, None]
    cc = np.arange(n_cols)[None, :]
    thr = level(rr, cc) + k * sigma(rr, cc)
    mask = img > thr
    labels_img, n = ndimage.label(mask, structure=_EIGHT)
    if n == 0:
        return Centroids.empty(bg0, s0)
    rows, cols = np.nonzero(mask)
    lab = labels_img[rows, cols] - 1
    vals = img[rows, cols].astype(np.float64)
    signal = vals - level(rows, cols)
    sat_px = vals >= saturation_dn if saturation_dn is not None else np.zeros(len(vals), dtype=bool)

    def lookup(r, c):
        inside = (r >= 0) & (r < n_rows) & (c >= 0) & (c < n_cols)
        rc = np.clip(r, 0, n_rows - 1)
        ccl = np.clip(c, 0, n_cols - 1)
        return np.where(inside, img[rc, ccl] - level(rc, ccl), np.nan)

    xy, inten, area, sat, peak, snr = _measure(
        lab, n, rows, cols, signal, sat_px, sigma(rows, cols), method, lookup, psf_sigma_px, min_area_px
    )
    return Centroids(xy, inten, area.astype(np.int64), sat, peak, snr, bg0, s0)


# ------------------------------------------------------------------------------------------ pixel fidelity
def detections_from_sparse(sf, method: str = "com", *, min_area_px: int = 1, psf_sigma_px: float | None = None,
                           validate: bool = True) -> Centroids:
    """Components and centroids of a :class:`startracker.imaging.SparseFrame`, with truth labels.

    Parameters
    ----------
    sf : SparseFrame
    method : {"com", "gaussian"}
    min_area_px : int
    psf_sigma_px : float, optional
        As in :func:`extract_centroids`.
    validate : bool
        Check the arguments (False: the caller has checked them, as the per-frame path does).

    Returns
    -------
    Centroids
        Brightest first, with ``truth_star``, ``truth_exposure``, ``truth_kind``, ``truth_xy``.
    """
    if validate:
        if not isinstance(sf, SparseFrame):
            raise TypeError(f"sf must be a startracker.imaging.SparseFrame, got {type(sf).__name__}")
        check_method(method)
        min_area_px = check_min_area(min_area_px)
        psf_sigma_px = check_psf_sigma(psf_sigma_px)
    n_rows, n_cols = sf.shape
    xy, inten, area, sat, peak, snr, o = detect_sparse(
        sf.lin, sf.dn, sf.background_dn, sf.threshold_dn, float(sf.saturation_dn),
        float(sf.k_sigma), int(n_rows), int(n_cols), sf.buffer(), method == "gaussian",
        float("nan") if psf_sigma_px is None else float(psf_sigma_px), int(min_area_px), sf.entry_pixel,
        sf.entry_source, sf.entry_e)
    bg_c = sf.background_dn_centre
    sig_c = sf.noise_dn_centre
    if len(o) == 0:
        return Centroids.empty(bg_c, sig_c, with_truth=True)
    srcs = sf.sources
    t_kind, t_star, t_exp, t_xy = truth_labels(o, srcs.kind, srcs.star, srcs.exposure, srcs.xy, KIND_NOISE)
    return Centroids(xy, inten, area, sat, peak, snr, bg_c, sig_c, t_star, t_exp, t_kind, t_xy)
