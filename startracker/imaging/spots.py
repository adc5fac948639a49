"""Light sources as spots: the table of sources, smeared spot paths, render windows, intensifier noise.

Part of :mod:`startracker.imaging`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from startracker.imaging.background import COSMIC_SIGMA_PX, BackgroundField, FalseObjects
from startracker.imaging.detector import SensorModel
from startracker.kernels.imaging import (frame_star_spots, render_spot_windows, shift_intensified_spots,
                                         spots_from_paths)
from startracker.scene import Scene

__all__ = [
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
]


KIND_STAR, KIND_NOISE, KIND_HOT_PIXEL, KIND_COSMIC_RAY, KIND_DEBRIS = range(5)
SOURCE_KIND_NAMES = ("star", "noise", "hot_pixel", "cosmic_ray", "debris")


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
class Spots:
    """Spot segments to render: sub-spot centres and weights, one Gaussian σ each."""

    sub_xy: np.ndarray  # (P, K, 2)
    sub_w: np.ndarray  # (P, K) expected pe (optical) or e- (direct)
    sigma: np.ndarray  # (P,)
    source: np.ndarray  # (P,) index into the SourceTable
    along: np.ndarray  # (P, 2) unit vector along the segment (x, y)
    length: np.ndarray  # (P,) segment length, px
    direct: bool  # charge deposited directly (cosmic rays) rather than light


def _paths_to_spots(paths, total, sigma, source, direct):
    """Split polylines (E, S, 2) sampled evenly in time into segments no longer than 4σ, sub-spots ≤ σ/2 apart."""
    if len(paths) == 0:
        return None
    sub, w, sig, path, along, length = spots_from_paths(np.ascontiguousarray(paths, dtype=np.float64),
                                                        np.ascontiguousarray(total, dtype=np.float64),
                                                        np.ascontiguousarray(sigma, dtype=np.float64))
    return Spots(sub, w, sig, source[path], along, length, direct)


def _on_detector(paths, margin, w, h):
    # a running min/max over the few samples: numpy's reduction over the middle axis of this strided view (a
    # reshaped np.moveaxis of the scene's paths) costs ~4x more
    lo = hi = paths[:, 0]
    for s in range(1, paths.shape[1]):
        lo = np.minimum(lo, paths[:, s])
        hi = np.maximum(hi, paths[:, s])
    return (hi[:, 0] >= -0.5 - margin) & (lo[:, 0] <= w - 0.5 + margin) & (hi[:, 1] >= -0.5 - margin) & (lo[:, 1] <= h - 0.5 + margin)


def frame_spots(scene: Scene, model: SensorModel, fo: FalseObjects):
    """All spots of a frame and the source table (stars, debris, cosmic rays; hot pixels appended later)."""
    cam = scene.camera
    w, h = cam.resolution
    n, m = scene.n_exposures, scene.n_stars
    tau = scene.plan.exposure_s
    sigma = model.sigma_px
    g = model.intensifier_gain
    margin = 5.0 * sigma

    pe_star = model.star_pe(scene.vmag, scene.bv, tau, validate=False)  # (M,), the scene's float64 magnitudes
    # the stars' sources and their paths on the detector in one compiled pass (the bulk of a frame's sources)
    star, expo, xy, exp_star, star_paths, star_total, star_source = frame_star_spots(
        np.ascontiguousarray(scene.xy_path, dtype=np.float64), np.ascontiguousarray(pe_star, dtype=np.float64),
        float(g), -0.5 - margin, w - 0.5 + margin, -0.5 - margin, h - 0.5 + margin)
    kinds = [np.full(n * m, KIND_STAR)]
    stars = [star]
    expos = [expo]
    xys = [xy]
    exp_e = [exp_star]
    optical_paths = [star_paths]
    optical_total = [star_total]
    optical_source = [star_source]
    q = n * m

    nd = len(fo.debris_vmag)
    if nd:
        t_mid = scene.t_frame_start + 0.5 * scene.plan.frame_period_s
        dt = scene.path_times - t_mid  # (N, S)
        paths = fo.debris_xy0[None, :, None, :] + fo.debris_velocity_px_s[None, :, None, :] * dt[:, None, :, None]
        paths = paths.reshape(n * nd, -1, 2)  # exposure-major
        pe_deb = model.star_pe(fo.debris_vmag, np.zeros(nd), tau, validate=False)
        kinds.append(np.full(n * nd, KIND_DEBRIS))
        stars.append(np.full(n * nd, -1))
        expos.append(np.repeat(np.arange(n), nd))
        mean_xy = 0.5 * (paths[:, 0] + paths[:, -1])
        xys.append(mean_xy)
        exp_e.append(np.tile(pe_deb * g, n))
        total = np.tile(pe_deb, n)
        keep = _on_detector(paths, margin, w, h) & (total > 0)  # the test frame_star_spots applies to the stars
        optical_paths.append(paths[keep])
        optical_total.append(total[keep])
        optical_source.append((q + np.arange(n * nd))[keep])
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
        cosmic = _paths_to_spots(cpaths, fo.cosmic_e, np.full(nc, COSMIC_SIGMA_PX), q + np.arange(nc), True)
        q += nc

    if nd:  # the kept debris after the kept stars
        paths, total, source = (np.concatenate(x) for x in (optical_paths, optical_total, optical_source))
    else:
        paths, total, source = star_paths, star_total, star_source
    optical = _paths_to_spots(paths, total, np.full(len(total), sigma), source, False)
    if len(kinds) == 1:  # stars only (most frames): their fresh arrays, no copies
        table = dict(kind=kinds[0], star=star, exposure=expo, xy=xy, expected_e=exp_star)
    else:
        table = dict(
            kind=np.concatenate(kinds),
            star=np.concatenate(stars),
            exposure=np.concatenate(expos),
            xy=np.concatenate(xys),
            expected_e=np.concatenate(exp_e),
        )
    return optical, cosmic, table


def randomize_intensified(spots: Spots, model: SensorModel, rng: np.random.Generator) -> None:
    """Photon-counting statistics of an intensified spot (module docstring), in place.

    Turns the expected photoelectrons of each segment into its random charge (e⁻) and shifts the segment by
    the scatter of its photoelectrons' positions.
    """
    n_pe = rng.poisson(spots.sub_w.sum(axis=1))
    g = model.intensifier_gain
    k = model.gamma_shape_per_pe
    if math.isinf(k):
        charge = g * n_pe.astype(np.float64)
    else:
        charge = rng.gamma(np.maximum(k * n_pe, 1e-300), g / k) * (n_pe > 0)
    z = rng.standard_normal((len(n_pe), 2))
    spots.sub_xy, spots.sub_w = shift_intensified_spots(spots.sub_xy, spots.along, spots.length, n_pe.astype(np.float64),
                                                        charge, z, float(model.excess_noise_factor),
                                                        float(model.optics_sigma_px))


def window_half_widths(spots: Spots, bg: "BackgroundField", e_per_unit: float, floor_frac: float) -> np.ndarray:
    """Per-spot window half width, px: where the spot's profile falls to ``floor_frac`` of the background
    noise σ (at least 2σ), +1 px so that every detected pixel has its neighbours. Shape (P,)."""
    peak_e = spots.sub_w.sum(axis=1) * e_per_unit / (2 * np.pi * spots.sigma**2)
    floor_e = floor_frac * math.sqrt(max(bg.var_e_centre, 1e-6))
    r = spots.sigma * np.sqrt(2.0 * np.log(np.maximum(peak_e / floor_e, math.e)))
    return np.ceil(np.maximum(r, 2.0 * spots.sigma)).astype(np.int64) + 1


def render_windows(spots: Spots, hw, n_cols: int, n_rows: int, min_value: float = 0.0):
    """Pixel-integrated Gaussian sub-spots summed into one window per spot.

    Parameters
    ----------
    spots : Spots
    hw : int or ndarray of int, shape (P,)
        Window half width beyond the extent of each spot's sub-spots, px.
    n_cols, n_rows : int
        Detector size, px.
    min_value : float
        Window pixels whose expected signal is below it are dropped (sparse path).

    Returns
    -------
    lin : ndarray of int64, shape (E,)
        Linear pixel index (row * n_cols + col) of every in-bounds window pixel.
    value : ndarray, shape (E,)
        Expected signal there (units of ``sub_w``).
    source : ndarray of int, shape (E,)
    """
    n_p = len(spots.sigma)
    if type(hw) is np.ndarray and hw.dtype == np.int64 and hw.shape == (n_p,) and hw.flags.c_contiguous \
            and hw.flags.writeable:  # window_half_widths' result (the kernel only reads it): no copy
        hw_a = hw
    else:  # a scalar or another layout: one writable int64 array, the kernel's one signature
        hw_a = np.broadcast_to(np.asarray(hw, dtype=np.int64), (n_p,)).copy()
    lin, val, p = render_spot_windows(np.ascontiguousarray(spots.sub_xy, dtype=np.float64),
                                      np.ascontiguousarray(spots.sub_w, dtype=np.float64),
                                      np.ascontiguousarray(spots.sigma, dtype=np.float64), hw_a, int(n_cols),
                                      int(n_rows), float(min_value))
    return lin, val, spots.source[p]
