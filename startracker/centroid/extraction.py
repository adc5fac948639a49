"""Detections and sub-pixel centroids from an image or from sparse pixels (paper 002 §3).

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.special import ndtr

from startracker.imaging import KIND_NOISE, KIND_STAR

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

    _, xy, inten, area, sat, peak, snr = _measure(
        lab, n, rows, cols, signal, sat_px, sigma(rows, cols), method, lookup, psf_sigma_px, min_area_px
    )
    return Centroids(xy, inten, area.astype(np.int64), sat, peak, snr, bg0, s0)


# ------------------------------------------------------------------------------------------ pixel fidelity
def detections_from_sparse(sf, method: str = "com", *, min_area_px: int = 1, psf_sigma_px: float | None = None) -> Centroids:
    """Components and centroids of a :class:`startracker.imaging.SparseFrame`, with truth labels."""
    check_method(method)
    min_area_px = check_min_area(min_area_px)
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
        nb = sf.linear_ids(lin_a[inside] + (dr * n_cols + dc))
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


