"""Detections and sub-pixel centroids: from an image, from sparse pixels, or from scene truth.

Centroiding (paper 002 §3)
--------------------------
1. Background: the image's level and noise σ, from sigma-clipped statistics of 64×64 blocks (every
   second pixel), fitted by a plane (default), kept per block ("local") or pooled ("global").
2. Threshold: a pixel belongs to a spot when ``DN > background + k σ``; spots are the 8-connected
   components (``scipy.ndimage.label``); their pixels are gathered once (no ``center_of_mass`` over
   the frame) and measured with ``numpy.bincount``.
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
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.special import erf, ndtr

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
    draw_false_pixels,
    draw_false_objects,
    fixed_pattern,
    render_sparse,
)
from startracker.scene import Scene

__all__ = [
    "Centroids",
    "extract_centroids",
    "simulate_detections",
    "detections_from_sparse",
    "CentroidErrorModel",
    "calibrate_error_model",
    "default_error_model",
    "estimate_background",
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
def _check_k(k_sigma):
    if isinstance(k_sigma, bool) or not isinstance(k_sigma, (int, float, np.integer, np.floating)):
        raise TypeError(f"k_sigma must be a number, got {type(k_sigma).__name__}")
    if not math.isfinite(k_sigma) or k_sigma <= 0:
        raise ValueError(f"k_sigma must be finite and > 0, got {k_sigma}")
    return float(k_sigma)


def _check_method(method):
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")


def _check_min_area(min_area_px):
    if isinstance(min_area_px, bool) or not isinstance(min_area_px, (int, np.integer)) or min_area_px < 1:
        raise ValueError(f"min_area_px must be an integer >= 1, got {min_area_px!r}")
    return int(min_area_px)


def _check_sigma(psf_sigma_px):
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
def _pixel_g(u, a, b, sigma):
    """Fraction of a unit Gaussian centred at u falling in [a, b] (paper 002 eq. 5)."""
    return ndtr((b - u) / sigma) - ndtr((a - u) / sigma)


def _gauss_axis_offset(i_minus, i_0, i_plus, sigma):
    """Sub-pixel offset along one axis from the brightest pixel and its neighbours (paper 002 §3.2).

    Returns the offset in [−0.5, 0.5] px, NaN where it cannot be formed (non-positive centre).
    """
    i_minus = np.where(np.isfinite(i_minus), i_minus, 0.0)
    i_plus = np.where(np.isfinite(i_plus), i_plus, 0.0)
    side = np.where(i_plus >= i_minus, 1.0, -1.0)
    i_n = np.maximum(i_plus, i_minus)
    ok = i_0 > 0
    rho = np.clip(np.where(ok, i_n / np.where(ok, i_0, 1.0), 0.0), 0.0, 1.0)
    lo = np.zeros_like(rho)
    hi = np.full_like(rho, 0.5)
    for _ in range(26):
        mid = 0.5 * (lo + hi)
        f = _pixel_g(mid, 0.5, 1.5, sigma) - rho * _pixel_g(mid, -0.5, 0.5, sigma)
        pos = f > 0
        hi = np.where(pos, mid, hi)
        lo = np.where(pos, lo, mid)
    return np.where(ok, side * 0.5 * (lo + hi), np.nan)


def _sigma_from_three(i_minus, i_0, i_plus, default):
    """PSF σ from the log-parabola through three pixels, minus pixel integration (1/12 px²)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        curv = -(np.log(i_minus) - 2 * np.log(i_0) + np.log(i_plus))
        s2 = 1.0 / curv - 1.0 / 12.0
    good = (i_minus > 0) & (i_plus > 0) & (i_0 > 0) & np.isfinite(s2) & (s2 > 0.05)
    return np.where(good, np.sqrt(np.clip(np.where(good, s2, 1.0), 0.05, 25.0)), default)


def _measure(labels, n_comp, rows, cols, signal, sat_px, noise_px, method, lookup, psf_sigma_px, min_area_px):
    """Measure components from their pixels.

    labels (A,) in [0, n_comp); rows, cols (A,); signal (A,) DN above background; sat_px (A,) bool;
    noise_px (A,) background σ (DN); lookup(rows, cols) -> background-subtracted DN (NaN if unknown).
    Returns (component ids kept, brightest first), xy, intensity, area, saturated, peak, snr.
    """
    area = np.bincount(labels, minlength=n_comp)
    inten = np.bincount(labels, signal, minlength=n_comp)
    sx = np.bincount(labels, signal * cols, minlength=n_comp)
    sy = np.bincount(labels, signal * rows, minlength=n_comp)
    sat = np.bincount(labels, sat_px, minlength=n_comp) > 0
    noise = np.bincount(labels, noise_px, minlength=n_comp) / np.maximum(area, 1)
    safe = np.where(inten > 0, inten, 1.0)
    x = sx / safe
    y = sy / safe
    # brightest pixel of each component
    peak = np.full(n_comp, -np.inf)
    np.maximum.at(peak, labels, signal)
    cand = np.flatnonzero(signal >= peak[labels])
    pk_of = np.full(n_comp, -1, dtype=np.int64)
    pk_of[labels[cand]] = cand
    pk = pk_of[pk_of >= 0]
    comp_of_pk = labels[pk]
    if method == "gaussian" and len(pk):
        r0 = rows[pk]
        c0 = cols[pk]
        i0 = signal[pk]
        il = lookup(r0, c0 - 1)
        ir = lookup(r0, c0 + 1)
        iu = lookup(r0 - 1, c0)
        idn = lookup(r0 + 1, c0)
        if psf_sigma_px is None:
            sxg = _sigma_from_three(il, i0, ir, 1.0)
            syg = _sigma_from_three(iu, i0, idn, 1.0)
        else:
            sxg = syg = psf_sigma_px
        dx = _gauss_axis_offset(il, i0, ir, sxg)
        dy = _gauss_axis_offset(iu, i0, idn, syg)
        use = ~sat[comp_of_pk]
        gx = np.where(use & np.isfinite(dx), c0 + dx, x[comp_of_pk])
        gy = np.where(use & np.isfinite(dy), r0 + dy, y[comp_of_pk])
        x[comp_of_pk] = gx
        y[comp_of_pk] = gy
    keep = np.flatnonzero((area >= min_area_px) & (inten > 0))
    keep = keep[np.argsort(-inten[keep], kind="stable")]
    snr = inten[keep] / (np.maximum(noise[keep], 1e-9) * np.sqrt(area[keep]))
    return keep, np.column_stack([x[keep], y[keep]]), inten[keep], area[keep], sat[keep], peak[keep], snr


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
    k = _check_k(k_sigma)
    _check_method(method)
    min_area_px = _check_min_area(min_area_px)
    psf_sigma_px = _check_sigma(psf_sigma_px)
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

    _, xy, inten, area, sat, peak, snr = _measure(
        lab, n, rows, cols, signal, sat_px, sigma(rows, cols), method, lookup, psf_sigma_px, min_area_px
    )
    return Centroids(xy, inten, area.astype(np.int64), sat, peak, snr, bg0, s0)


# ------------------------------------------------------------------------------------------ pixel fidelity
def detections_from_sparse(sf, method: str = "com", *, min_area_px: int = 1, psf_sigma_px: float | None = None) -> Centroids:
    """Components and centroids of a :class:`startracker.imaging.SparseFrame`, with truth labels."""
    _check_method(method)
    min_area_px = _check_min_area(min_area_px)
    above = np.flatnonzero(sf.dn > sf.threshold_dn)
    bg_c = sf.background_dn_centre
    sig_c = sf.noise_dn_centre
    if len(above) == 0:
        return Centroids.empty(bg_c, sig_c, with_truth=True)
    a = len(above)
    n_rows, n_cols = sf.shape
    lin_a = sf.lin[above]
    r, c = np.divmod(lin_a, n_cols)
    pos = np.full(len(sf.lin), -1, dtype=np.int64)
    pos[above] = np.arange(a)
    src_i, dst_i = [], []
    for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1)):
        inside = np.flatnonzero((r + dr < n_rows) & (c + dc >= 0) & (c + dc < n_cols))
        nb = sf._index.contains(lin_a[inside] + (dr * n_cols + dc))
        j = np.where(nb >= 0, pos[np.maximum(nb, 0)], -1)
        ok = j >= 0
        src_i.append(inside[ok])
        dst_i.append(j[ok])
    si = np.concatenate(src_i)
    di = np.concatenate(dst_i)
    if len(si):
        graph = coo_matrix((np.ones(len(si), dtype=np.int8), (si, di)), shape=(a, a)).tocsr()
        n_comp, lab = connected_components(graph, directed=False)
    else:
        n_comp, lab = a, np.arange(a)
    lab = lab.astype(np.int64)
    dn = sf.dn[above].astype(np.float64)
    bgp = sf.background_dn[above]
    signal = dn - bgp
    sat_px = dn >= sf.saturation_dn
    noise_px = (sf.threshold_dn[above] - bgp) / sf.k_sigma

    def lookup(rr, cc):
        ids = sf.pixel_ids(rr, cc)
        okk = ids >= 0
        ii = np.maximum(ids, 0)
        return np.where(okk, sf.dn[ii] - sf.background_dn[ii], np.nan)

    keep, xy, inten, area, sat, peak, snr = _measure(
        lab, n_comp, r, c, signal, sat_px, noise_px, method, lookup, psf_sigma_px, min_area_px
    )
    # truth: the source contributing most expected charge at any pixel of the component
    ep = pos[sf.entry_pixel]
    sel = ep >= 0
    comp = lab[ep[sel]]
    w = sf.entry_e[sel]
    src = sf.entry_source[sel]
    best = np.full(n_comp, -np.inf)
    np.maximum.at(best, comp, w)
    is_best = w >= best[comp]
    owner = np.full(n_comp, -1, dtype=np.int64)
    owner[comp[is_best]] = src[is_best]
    o = owner[keep]
    srcs = sf.sources
    has = o >= 0
    oo = np.maximum(o, 0)
    t_kind = np.where(has, srcs.kind[oo], KIND_NOISE)
    t_star = np.where(has, srcs.star[oo], -1)
    t_exp = np.where(has, srcs.exposure[oo], -1)
    t_xy = np.where(has[:, None], srcs.xy[oo], np.nan)
    return Centroids(xy, inten, area.astype(np.int64), sat, peak, snr, bg_c, sig_c, t_star.astype(np.int64),
                     t_exp.astype(np.int64), t_kind.astype(np.int64), t_xy)


# ------------------------------------------------------------------------------------------ centroid fidelity
@dataclass(frozen=True)
class CentroidErrorModel:
    """Calibration factors of the centroid-fidelity theory (module docstring).

    Attributes
    ----------
    peak_factor : float
        Multiplies the spot's expected peak pixel in the detection probability and the threshold radius
        (the brightest of several pixels near the centre beats the mean peak).
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
        _check_method(self.method)
        for name in ("peak_factor", "photon_factor", "background_factor", "locking_factor", "min_log_ratio"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be finite and > 0, got {v}")


# calibrate_error_model(SensorModel.preset(name), np.random.default_rng(2025), n_frames=16, method=method);
# tests/test_centroid.py checks that they still reproduce the pixel path.
DEFAULT_ERROR_MODELS = {
    ("paper000", "com"): CentroidErrorModel(1.425, 0.758, 1.011, 2.886, 0.5, "com"),
    ("paper000", "gaussian"): CentroidErrorModel(1.425, 3.417, 0.001, 0.001, 0.5, "gaussian"),
    ("paper000_cmos", "com"): CentroidErrorModel(1.200, 0.542, 1.494, 0.182, 0.5, "com"),
    ("paper000_cmos", "gaussian"): CentroidErrorModel(1.200, 12.367, 0.583, 0.345, 0.5, "gaussian"),
}


def default_error_model(model: SensorModel, method: str = "com") -> CentroidErrorModel:
    """The stored calibration for a preset (by ``model.name``); other models get the one of their
    detector kind (intensified or not). Run :func:`calibrate_error_model` for a model far from both."""
    _check_method(method)
    key = (model.name, method)
    if key not in DEFAULT_ERROR_MODELS:
        key = ("paper000" if model.intensified else "paper000_cmos", method)
    return DEFAULT_ERROR_MODELS[key]


def _spot_theory(s_units, gain, f2, sigma, sigma_o, c_splash, length, var_b, thr_e, err: CentroidErrorModel, intensified):
    """Closed-form statistics of a thresholded centre of mass for spots (all arrays (P,)).

    s_units : expected photoelectrons (or e⁻ for direct charge with gain 1); var_b : background variance
    (e⁻², incl. quantisation); thr_e : threshold above the background mean, e⁻.

    Model (σ_e² = σ² + 1/12 for pixel integration; L the smear length):

    * peak pixel ``P = G S φ(L) / (2π σ_e²)`` with ``φ`` the peak of a uniform streak convolved with the
      PSF; detection probability ``Φ((c_peak P − T) / sd(P))``;
    * threshold region: ``a = ln(c_peak P / T)`` (floored), radius ``R = σ_e √(2a)``, captured fraction
      ``f = 1 − e^{−a}``, truncated second moment ``m2 = σ_e² (1 − a e^{−a} / f)``;
    * centroid variance per axis = photon term (``F² m2 / (S f)``, plus ``L²/12`` along; for an intensifier
      the photoelectron scatter ``F² σ_o² / S`` plus the splash shape noise) + background term
      (``σ_b² Σ_Ω x² / (G S f)²`` over a stadium of radius R, length L, plus the support noise of the
      pixels at the threshold, ``(1/√π) T σ_b σ_e² / R ∮ x² dl / (G S f)²``) + pixel locking (the COM over a
      fixed set of pixels lags the true shift by ``1 − m2/σ_e²``, uniform over a pixel: that squared / 12).

    Returns a dict of arrays: p_det, ph/bg/lock for along and cross, var_along, var_cross, cap (captured
    e⁻), var_cap, area, peak (e⁻).
    """
    se2 = sigma**2 + 1.0 / 12.0
    se = np.sqrt(se2)
    lpos = np.maximum(length, 1e-9)
    phi = np.where(length > 1e-6, (np.sqrt(2 * np.pi) * se / lpos) * erf(lpos / (2 * np.sqrt(2) * se)), 1.0)
    total_e = gain * s_units
    peak = total_e * phi / (2 * np.pi * se2)
    s_safe = np.maximum(s_units, 1e-12)
    if intensified:
        var_peak = peak**2 * f2 / s_safe + gain * f2 * c_splash * peak + var_b
    else:
        var_peak = gain * f2 * peak + var_b
    cp = err.peak_factor * peak
    p_det = ndtr((cp - thr_e) / np.sqrt(var_peak))
    # a barely detected spot is an upward fluctuation that keeps its few brightest pixels: floor on a
    a = np.maximum(np.log(np.maximum(cp / np.maximum(thr_e, 1e-12), 1e-300)), err.min_log_ratio)
    r2 = 2.0 * se2 * a
    r = np.sqrt(r2)
    exp_a = np.exp(-a)
    frac = np.maximum(1.0 - exp_a, 1e-6)
    m2 = se2 * (1.0 - a * exp_a / frac)
    len2, len3 = length**2, length**3
    l2 = len2 / 12.0
    if intensified:
        ph_cross = f2 * (sigma_o**2 + c_splash * m2 / frac) / s_safe
        ph_along = f2 * (sigma_o**2 + l2 + c_splash * (m2 + l2) / frac) / s_safe
    else:
        ph_cross = f2 * m2 / (s_safe * frac)
        ph_along = f2 * (m2 + l2) / (s_safe * frac)
    cap = total_e * frac
    # (repeated subexpressions computed once: the same operations, so the same values)
    disc = np.pi * r2**2 / 4
    cap2 = np.maximum(cap, 1e-12) ** 2
    a_cross = disc + (2 * r) ** 3 * length / 12
    a_along = disc + 2 * r * len3 / 12 + np.pi * r2 * len2 / 4
    bg_cross = var_b * a_cross / cap2
    bg_along = var_b * a_along / cap2
    # support noise: pixels near the threshold join or leave the component at random, each carrying about T;
    # Σ p(1−p) T² x² over the edge ≈ (1/√π) T σ_b σ_e² / R · ∮ x² dl  (ring width σ_b / |∇s|, |∇s| = T R / σ_e²)
    edge_k = (1.0 / np.sqrt(np.pi)) * thr_e * np.sqrt(var_b) * se2 / np.maximum(r, 1e-6) / cap2
    side, ring = 2 * length * r2, np.pi * r2 * r
    bg_cross = bg_cross + edge_k * (side + ring)
    bg_along = bg_along + edge_k * (len3 / 6 + np.pi * r * len2 / 2 + ring + side)
    lock_cross = (1.0 - m2 / se2) ** 2 / 12.0
    lock_along = (1.0 - (m2 + l2) / (se2 + l2)) ** 2 / 12.0
    var_cross = err.photon_factor * ph_cross + err.background_factor * bg_cross + err.locking_factor * lock_cross
    var_along = err.photon_factor * ph_along + err.background_factor * bg_along + err.locking_factor * lock_along
    area = np.maximum(np.pi * r2 + 2 * r * length, 1.0)
    var_cap = gain * gain * f2 * s_units * frac + var_b * area
    return dict(p_det=p_det, ph_along=ph_along, ph_cross=ph_cross, bg_along=bg_along, bg_cross=bg_cross,
                lock_along=lock_along, lock_cross=lock_cross, var_along=var_along, var_cross=var_cross,
                cap=cap, var_cap=var_cap, area=area, peak=peak)


_THEORY_KEYS = ("p_det", "var_along", "var_cross", "cap", "var_cap", "area", "peak")


def _centroid_fidelity(scene: Scene, model: SensorModel, rng, k_sigma, err: CentroidErrorModel, include_false: bool) -> Centroids:
    cam = scene.camera
    n_cols, n_rows = cam.resolution
    bg = background_field(scene, model)
    g_dn = model.gain_e_per_dn
    n, m = scene.n_exposures, scene.n_stars
    tau = scene.plan.exposure_s
    fo = draw_false_objects(scene, model, rng) if include_false else None

    # optical spots: stars (exposure-major) then debris
    xy = scene.xy_mean.reshape(-1, 2)
    vis = scene.visible.reshape(-1)
    length = scene.smear_px.reshape(-1)
    d = (scene.xy_end - scene.xy_start).reshape(-1, 2)
    s_pe = np.tile(model.star_pe(scene.vmag, scene.bv, tau), n)
    kind = np.full(n * m, KIND_STAR)
    star = np.tile(np.arange(m), n)
    expo = np.repeat(np.arange(n), m)
    if include_false and len(fo.debris_vmag):
        nd = len(fo.debris_vmag)
        t_mid = scene.t_frame_start + 0.5 * scene.plan.frame_period_s
        t0 = scene.path_times[:, 0] - t_mid
        t1 = scene.path_times[:, -1] - t_mid
        p0 = fo.debris_xy0[None] + fo.debris_velocity_px_s[None] * t0[:, None, None]
        p1 = fo.debris_xy0[None] + fo.debris_velocity_px_s[None] * t1[:, None, None]
        dxy = 0.5 * (p0 + p1).reshape(-1, 2)
        inside = (dxy[:, 0] >= -0.5) & (dxy[:, 0] <= n_cols - 0.5) & (dxy[:, 1] >= -0.5) & (dxy[:, 1] <= n_rows - 0.5)
        xy = np.concatenate([xy, dxy])
        vis = np.concatenate([vis, inside])
        dd = (p1 - p0).reshape(-1, 2)
        d = np.concatenate([d, dd])
        length = np.concatenate([length, np.linalg.norm(dd, axis=1)])
        s_pe = np.concatenate([s_pe, np.tile(model.star_pe(fo.debris_vmag, np.zeros(nd), tau), n)])
        kind = np.concatenate([kind, np.full(n * nd, KIND_DEBRIS)])
        star = np.concatenate([star, np.full(n * nd, -1)])
        expo = np.concatenate([expo, np.repeat(np.arange(n), nd)])
    sel = np.flatnonzero(vis & (s_pe > 0))
    xy, d, length, s_pe = xy[sel], d[sel], length[sel], s_pe[sel]
    kind, star, expo = kind[sel], star[sel], expo[sel]
    var_b_dn2 = bg.var_e(xy[:, 0], xy[:, 1]) / g_dn**2 + 1.0 / 12.0
    var_b = var_b_dn2 * g_dn**2
    thr_e = k_sigma * np.sqrt(var_b)
    f2 = model.excess_noise_factor**2
    th = _spot_theory(
        s_pe, model.intensifier_gain, f2, model.sigma_px, model.optics_sigma_px, model.splash_energy, length,
        var_b, thr_e, err, model.intensified)
    p_det, v_al, v_cr, cap, v_cap, area, peak = (th[k] for k in _THEORY_KEYS)
    # direct charge: cosmic rays
    if include_false and len(fo.cosmic_e):
        cxy = 0.5 * (fo.cosmic_start_xy + fo.cosmic_end_xy)
        cd = fo.cosmic_end_xy - fo.cosmic_start_xy
        clen = np.linalg.norm(cd, axis=1)
        inside = (cxy[:, 0] >= -0.5) & (cxy[:, 0] <= n_cols - 0.5) & (cxy[:, 1] >= -0.5) & (cxy[:, 1] <= n_rows - 0.5)
        cxy, cd, clen, ce = cxy[inside], cd[inside], clen[inside], fo.cosmic_e[inside]
        cvb = (bg.var_e(cxy[:, 0], cxy[:, 1]) / g_dn**2 + 1.0 / 12.0) * g_dn**2
        cres = _spot_theory(ce, 1.0, 1.0, np.full(len(ce), COSMIC_SIGMA_PX), np.full(len(ce), COSMIC_SIGMA_PX), 1.0,
                            clen, cvb, k_sigma * np.sqrt(cvb), err, False)
        xy = np.concatenate([xy, cxy])
        d = np.concatenate([d, cd])
        length = np.concatenate([length, clen])
        var_b = np.concatenate([var_b, cvb])
        p_det, v_al, v_cr, cap, v_cap, area, peak = (np.concatenate([u, cres[k]]) for u, k in zip(
            (p_det, v_al, v_cr, cap, v_cap, area, peak), _THEORY_KEYS))
        kind = np.concatenate([kind, np.full(len(ce), KIND_COSMIC_RAY)])
        star = np.concatenate([star, np.full(len(ce), -1)])
        expo = np.concatenate([expo, np.full(len(ce), -1)])
    det = rng.random(len(p_det)) < p_det
    idx = np.flatnonzero(det)
    ln = np.maximum(length[idx], 1e-12)
    along = np.where(length[idx, None] > 1e-9, d[idx] / ln[:, None], np.array([1.0, 0.0]))
    z = rng.standard_normal((len(idx), 3))
    err_xy = along * (z[:, :1] * np.sqrt(v_al[idx])[:, None]) + np.stack([-along[:, 1], along[:, 0]], 1) * (z[:, 1:2] * np.sqrt(v_cr[idx])[:, None])
    truth_xy = xy[idx]
    out_xy = truth_xy + err_xy
    inten_e = np.maximum(cap[idx] + z[:, 2] * np.sqrt(v_cap[idx]), 1e-3)
    peak_e = peak[idx]
    det_area = area[idx]
    star, expo, kind = star[idx], expo[idx], kind[idx]
    var_bd = var_b[idx]
    # spots whose threshold regions touch are one component in the pixel path: merge them
    if len(idx) > 1:
        # expected threshold radius (without the detection calibration factor) plus half the streak
        se2 = np.where(kind == KIND_COSMIC_RAY, COSMIC_SIGMA_PX**2, model.sigma_px**2) + 1.0 / 12.0
        r_exp = np.sqrt(2.0 * se2 * np.log(np.maximum(peak_e / (k_sigma * np.sqrt(var_bd)), 1.0)))
        reach = r_exp + 0.5 * length[idx]
        pairs = _candidate_pairs(truth_xy, 2.0 * float(reach.max()) + 1e-9)
        if len(pairs):
            dxy = truth_xy[pairs[:, 0]] - truth_xy[pairs[:, 1]]
            pairs = pairs[dxy[:, 0] ** 2 + dxy[:, 1] ** 2 < (reach[pairs[:, 0]] + reach[pairs[:, 1]]) ** 2]
        if len(pairs):
            inv = np.unique(pairs)  # only the spots that merge are regrouped
            n_grp, grp = _pair_groups(len(inv), np.searchsorted(inv, pairs))
            w = inten_e[inv]
            wsum = np.bincount(grp, w, n_grp)
            mxy = np.column_stack([np.bincount(grp, w * out_xy[inv, 0], n_grp),
                                   np.bincount(grp, w * out_xy[inv, 1], n_grp)]) / wsum[:, None]
            lead = np.empty(n_grp, dtype=np.int64)
            order_w = np.argsort(w, kind="stable")
            lead[grp[order_w]] = inv[order_w]  # the brightest member labels the merged detection
            keep = np.ones(len(idx), dtype=bool)
            keep[inv] = False
            out_xy = np.concatenate([out_xy[keep], mxy])
            inten_e = np.concatenate([inten_e[keep], wsum])
            det_area = np.concatenate([det_area[keep], np.bincount(grp, det_area[inv], n_grp)])
            peak_e = np.concatenate([peak_e[keep], np.bincount(grp, peak_e[inv], n_grp)])
            star, expo, kind, var_bd, truth_xy = (np.concatenate([a[keep], a[lead]]) for a in (star, expo, kind, var_bd, truth_xy))
    bg_e = bg.mean_e(truth_xy[:, 0], truth_xy[:, 1])
    sat = (peak_e + bg_e) / g_dn + model.bias_dn >= model.saturation_dn
    sigma_dn = np.sqrt(var_bd) / g_dn
    det_area = np.maximum(np.rint(det_area), 1).astype(np.int64)
    parts = dict(
        xy=[out_xy], intensity=[inten_e / g_dn], area=[det_area], saturated=[sat],
        peak=[np.minimum(peak_e / g_dn, model.saturation_dn - model.bias_dn)],
        snr=[inten_e / g_dn / (sigma_dn * np.sqrt(det_area))], star=[star], exposure=[expo],
        kind=[kind], truth_xy=[truth_xy],
    )
    if include_false:
        # hot pixels: background + their own dark charge, detected when the drawn DN crosses the threshold
        _, hot_idx, hot_rate = fixed_pattern(model, cam.resolution)
        if len(hot_idx):
            hr, hc = np.divmod(hot_idx, n_cols)
            q = bg.gain * bg.optical_pe(hc, hr)
            hot_e = hot_rate * scene.plan.integration_window_s
            var0 = bg.enf2_c * q + bg.dark_e + bg.read_var_e2
            mean_dn0 = (q + bg.dark_e) / g_dn + model.bias_dn
            sd_dn0 = np.sqrt((var0 + (bg.prnu_sigma * q) ** 2) / g_dn**2 + 1.0 / 12.0)
            e = q + bg.dark_e + hot_e + np.sqrt(var0 + hot_e) * rng.standard_normal(len(hot_idx))
            dn = np.clip(np.rint(np.minimum(e, model.full_well_e) / g_dn + model.bias_dn), 0, model.adc_max_dn)
            hit = np.flatnonzero(dn > mean_dn0 + k_sigma * sd_dn0)
            if len(hit):
                hxy = np.column_stack([hc[hit], hr[hit]]).astype(float)
                _append_singletons(parts, hxy, dn[hit] - mean_dn0[hit] if np.ndim(mean_dn0) else dn[hit] - mean_dn0,
                                   dn[hit] >= model.saturation_dn, sd_dn0[hit] if np.ndim(sd_dn0) else sd_dn0, KIND_HOT_PIXEL)
        f_lin, f_dn = draw_false_pixels(bg, k_sigma, n_cols, n_rows, model, rng)
        if len(f_lin):
            fr, fc = np.divmod(f_lin, n_cols)
            fxy = np.stack([fc, fr], 1).astype(float)
            _append_singletons(parts, fxy, f_dn - bg.mean_dn(fc, fr), f_dn >= model.saturation_dn, bg.sigma_dn(fc, fr), KIND_NOISE)
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    order = np.argsort(-cat["intensity"], kind="stable")
    return Centroids(
        cat["xy"][order], cat["intensity"][order], cat["area"][order], cat["saturated"][order], cat["peak"][order],
        cat["snr"][order], float(bg.mean_dn(bg.cx, bg.cy)), float(bg.sigma_dn(bg.cx, bg.cy)),
        cat["star"][order].astype(np.int64), cat["exposure"][order].astype(np.int64),
        cat["kind"][order].astype(np.int64), cat["truth_xy"][order],
    )


_SWEEP_MAX_PAIRS = 200_000


def _candidate_pairs(xy: np.ndarray, r: float) -> np.ndarray:
    """Pairs (i, j), i < j, of points closer than ``r`` along x (a superset of the pairs within ``r``), by a sort
    and sweep over x. The caller's exact distance test then leaves the same set as a k-d tree's
    ``query_pairs(r)`` would (every pair it keeps is closer than ``r``), in another order; only the set is used.
    Falls back to the k-d tree when the x-window holds too many candidates."""
    n = len(xy)
    o = np.argsort(xy[:, 0], kind="stable")
    xs = xy[o, 0]
    cnt = np.searchsorted(xs, xs + r, side="right") - np.arange(1, n + 1)
    tot = int(cnt.sum())
    if tot > _SWEEP_MAX_PAIRS:
        tree = cKDTree(xy, leafsize=32, balanced_tree=False, compact_nodes=False)
        return tree.query_pairs(r, output_type="ndarray")
    first = np.repeat(np.arange(n), cnt)
    second = np.arange(tot) - np.repeat(np.cumsum(cnt) - cnt, cnt) + first + 1
    a, b = o[first], o[second]
    near = np.abs(xy[a, 1] - xy[b, 1]) <= r
    a, b = a[near], b[near]
    return np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)


def _pair_groups(n: int, pairs: np.ndarray):
    """Connected groups of n items linked by pairs (P, 2): min-label propagation (few short chains)."""
    lab = np.arange(n)
    i, j = pairs[:, 0], pairs[:, 1]
    while True:
        m = np.minimum(lab[i], lab[j])
        new = lab.copy()
        np.minimum.at(new, i, m)
        np.minimum.at(new, j, m)
        new = new[new]  # pointer jumping
        if np.array_equal(new, lab):
            break
        lab = new
    uniq, grp = np.unique(lab, return_inverse=True)
    return len(uniq), grp


def _append_singletons(parts, xy, signal_dn, sat, sigma_dn, kind):
    k = len(xy)
    parts["xy"].append(xy)
    parts["intensity"].append(signal_dn)
    parts["area"].append(np.ones(k, dtype=np.int64))
    parts["saturated"].append(np.asarray(sat, dtype=bool))
    parts["peak"].append(signal_dn)
    parts["snr"].append(signal_dn / np.maximum(sigma_dn, 1e-9))
    parts["star"].append(np.full(k, -1))
    parts["exposure"].append(np.full(k, -1))
    parts["kind"].append(np.full(k, kind))
    parts["truth_xy"].append(xy)


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

    Returns
    -------
    Centroids
        Brightest first, with ``truth_star``, ``truth_exposure``, ``truth_kind``, ``truth_xy``.
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
    if not isinstance(model, SensorModel):
        raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    k = _check_k(k_sigma)
    _check_method(method)
    min_area_px = _check_min_area(min_area_px)
    psf_sigma_px = _check_sigma(psf_sigma_px)
    if fidelity == "pixel":
        if include_false:
            sf = render_sparse(scene, model, rng, k)
        else:
            sf = render_sparse(scene, replace(model, hot_pixel_fraction=0.0), rng, k,
                               false_objects=FalseObjects.none(), draw_crossings=False)
        return detections_from_sparse(sf, method, min_area_px=min_area_px, psf_sigma_px=psf_sigma_px)
    if fidelity == "centroid":
        err = default_error_model(model, method) if error_model is None else error_model
        if not isinstance(err, CentroidErrorModel):
            raise TypeError("error_model must be a CentroidErrorModel")
        if err.method != method:
            raise ValueError(f"error_model was calibrated for method {err.method!r}, not {method!r}")
        c = _centroid_fidelity(scene, model, rng, k, err, include_false)
        if min_area_px > 1:
            c = c.subset(c.area >= min_area_px)
        return c
    raise ValueError(f"fidelity must be 'centroid' or 'pixel', got {fidelity!r}")


def _grid_scene(camera, plan, vmag_lo, vmag_hi, speed_px_s, spacing_px, rng):
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
) -> CentroidErrorModel:
    """Fit the centroid-fidelity factors to the pixel path (sparse rendering + centroiding).

    Stars on a 60-px grid, magnitudes spanning certain to rare detection, one exposure per frame at each
    streak length; no false objects. ``peak_factor`` maximises the Bernoulli likelihood of the pixel path's
    detections; the photon, background and pixel-locking factors are a non-negative weighted least-squares
    fit of the squared centroid errors (along and across the motion) on the three variance terms.

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
    k = _check_k(k_sigma)
    quiet = replace(model, hot_pixel_fraction=0.0, cosmic_ray_rate_per_cm2_s=0.0, debris_rate_per_frame=0.0)
    # magnitude where a still spot's peak equals the threshold
    probe = _grid_scene(cam, plan, 0.0, 0.0, 0.0, cam.resolution[0] / 2, rng)
    th0 = _theory_for_scene(probe, quiet, k, CentroidErrorModel(min_log_ratio=min_log_ratio, method=method))
    thr_e = k * math.sqrt(float(background_field(probe, quiet).var_e(0, 0)) + model.gain_e_per_dn**2 / 12)
    v_thr = float(2.5 * np.log10(np.median(th0["peak"]) / thr_e))
    rows = []
    for smear in smear_px:
        speed = float(smear) / tau
        for _ in range(int(n_frames)):
            sc = _grid_scene(cam, plan, v_thr - 4.0, v_thr + 0.8, float(speed), 60.0, rng)
            det = simulate_detections(sc, quiet, rng, "pixel", k_sigma=k, method=method, include_false=False)
            found, e = _star_errors(det, sc)
            rows.append((sc, found, e))
    base = CentroidErrorModel(min_log_ratio=min_log_ratio, method=method)

    def loglik(pf):
        ll = 0.0
        for sc, found, _ in rows:
            p = np.clip(_theory_for_scene(sc, quiet, k, replace(base, peak_factor=pf))["p_det"], 1e-9, 1 - 1e-9)
            vis = sc.visible.reshape(-1)
            ll += np.sum(np.where(found, np.log(p), np.log1p(-p))[vis])
        return ll

    grid = np.linspace(0.6, 3.0, 49)
    pf = float(grid[np.argmax([loglik(g) for g in grid])])
    fine = np.linspace(pf - 0.05, pf + 0.05, 21)
    pf = float(fine[np.argmax([loglik(g) for g in fine])])
    X, y = [], []
    for sc, found, e in rows:
        th = _theory_for_scene(sc, quiet, k, replace(base, peak_factor=pf))
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
