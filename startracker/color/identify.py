"""Colour-aided lost-in-space identification for a 3CMOS star tracker.

The pyramid of :mod:`startracker.identify.pyramid` with one more feature per star: the colour ratio
``c = ln(e_red / e_blue)`` (:meth:`startracker.color.ChannelResponse.color_ratio`). The database stores
each navigation star's expected ratio (from its catalog B−V), and every star-pair window of the k-vector
search keeps only the catalog pairs whose two stars' expected ratios agree with the two detections'
measured ratios within ``color_tol_sigmas · hypot(σ_measured, σ_model)`` (Enright & McVittie 2013; Niu,
Wei & Li 2022, cited by paper 004 as the reason for the 3CMOS sensor). Fewer candidate pairs mean fewer
triangles and hypotheses (speed); the expected number of wrong catalog triangles ``λ`` of the false-alarm
rule is multiplied by the three detections' colour pass rates, so fewer confirming stars are required
(robustness with few stars or loose position tolerances). Detections without a colour (NaN ratio) are
not pruned. Verification is the common one of :mod:`startracker.identify.verification`. If the pruned
search finds nothing, the colour-blind pyramid runs on the same frame (``fallback``), so a wild colour
measurement cannot lose a frame the monochrome method identifies.

This module sits after :mod:`startracker.identify` in the import order (``color`` comes before
``centroid`` and ``identify`` and cannot import them).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from startracker.attitude import RAD_TO_ARCSEC, solve_wahba_single
from startracker.catalog import StarCatalog
from startracker.color.camera import DEFAULT_RESPONSE, ChannelResponse
from startracker.identify import IdentificationResult, StarDatabase, build_database
from startracker.identify.frame import Frame, IdentifyOptions, prepare_frame
from startracker.identify.pyramid import CandidateFilter, identify_pyramid
from startracker.identify.verification import Match
from startracker.optics import Camera
from startracker.validation import as_float_array

__all__ = ["ColorDatabase", "build_color_database", "identify_color", "ColorPruning"]

_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True, eq=False)
class ColorDatabase:
    """An identification database plus each navigation star's expected colour ratio.

    Attributes
    ----------
    db : StarDatabase
    star_ratio : ndarray, shape (n_nav,)
        Expected ``ln(e_red / e_blue)`` of every navigation star (catalog B−V through ``response``).
    response : ChannelResponse
    sorted_ratio : ndarray, shape (n_nav,)
        ``star_ratio`` sorted (pass rates of colour windows by binary search).
    """

    db: StarDatabase
    star_ratio: np.ndarray
    response: ChannelResponse
    sorted_ratio: np.ndarray

    @property
    def memory_bytes(self) -> int:
        return int(self.db.memory_bytes + self.star_ratio.nbytes + self.sorted_ratio.nbytes)


def build_color_database(catalog: StarCatalog, camera: Camera, response: ChannelResponse = DEFAULT_RESPONSE,
                         **build_kwargs) -> ColorDatabase:
    """:func:`startracker.identify.build_database` (cached) plus the stars' expected colour ratios."""
    if not isinstance(response, ChannelResponse):
        raise TypeError(f"response must be a ChannelResponse, got {type(response).__name__}")
    db = build_database(catalog, camera, **build_kwargs)
    ratio = response.color_ratio(np.clip(db.nav.bv, -0.6, 6.0)).astype(np.float32)
    return ColorDatabase(db=db, star_ratio=ratio, response=response, sorted_ratio=np.sort(ratio))


@dataclass
class ColorPruning:
    """What the colour pruning removed in one identification.

    Attributes
    ----------
    pairs_geometric : int
        Catalog pair candidates (both orientations) inside the angle windows that were looked up.
    pairs_kept : int
        Of those, the ones whose colours agree.
    """

    pairs_geometric: int = 0
    pairs_kept: int = 0

    @property
    def kept_fraction(self) -> float:
        return self.pairs_kept / self.pairs_geometric if self.pairs_geometric else 1.0


def _pass_rate(srt, det_ratio, det_tol) -> np.ndarray:
    """Fraction of navigation stars (sorted ratios ``srt``) whose colour passes each detection's window, (n,)."""
    out = np.ones(len(det_ratio))
    known = np.isfinite(det_ratio)
    lo = np.searchsorted(srt, det_ratio[known] - det_tol[known], side="left")
    hi = np.searchsorted(srt, det_ratio[known] + det_tol[known], side="right")
    out[known] = np.maximum(hi - lo, 1) / len(srt)
    return out


def _pyramid_color(cdb: ColorDatabase, frame: Frame, opts: IdentifyOptions, det_ratio, det_tol,
                   stats: ColorPruning) -> tuple[Match | None, str, int]:
    """The pyramid of :func:`startracker.identify.pyramid.identify_pyramid` with its candidate source
    narrowed by colour: detection ``p`` may only be a star whose expected ratio lies within ``det_tol[p]``
    of ``det_ratio[p]`` (any star where the ratio is NaN), and ``λ`` scaled by the colour pass rates."""
    known = np.isfinite(det_ratio)
    lo = np.where(known, det_ratio - det_tol, -np.inf)
    hi = np.where(known, det_ratio + det_tol, np.inf)
    cands = CandidateFilter(star_key=cdb.star_ratio, lo=lo, hi=hi,
                            false_rate_scale=_pass_rate(cdb.sorted_ratio, det_ratio, det_tol))
    match, status, n_hyp = identify_pyramid(cdb.db, frame, opts, candidates=cands)
    stats.pairs_geometric += cands.pairs_geometric
    stats.pairs_kept += cands.pairs_kept
    return match, status, n_hyp


def identify_color(xy, camera: Camera, catalog: StarCatalog, color_ratio, color_sigma=0.1, intensities=None,
                   database: ColorDatabase | None = None, *, color_model_sigma: float = 0.1,
                   color_tol_sigmas: float = 3.0, fallback: bool = True, return_pruning: bool = False, **options):
    """Lost-in-space identification with the colour ratio as an extra feature (pyramid).

    Parameters
    ----------
    xy : array_like, shape (K, 2)
        Detections (fused, in the green channel's frame), px; brightest first when ``intensities`` is None.
    camera : Camera
        The camera of ``xy`` (``ColorCamera.channel_camera("green")``).
    catalog : StarCatalog
    color_ratio : array_like, shape (K,)
        Measured ``ln(I_red / I_blue)`` per detection; NaN where unknown (not pruned).
    color_sigma : float or array_like, shape (K,)
        1σ of each measured ratio (>= 0).
    intensities : array_like, shape (K,), optional
        As :func:`startracker.identify.identify`.
    database : ColorDatabase, optional
        From :func:`build_color_database`; built (and cached) by default.
    color_model_sigma : float
        1σ disagreement between a star's true ratio and the one predicted from its catalog B−V (B−V
        errors, non-Planck spectra), added in quadrature.
    color_tol_sigmas : float
        Half-width of the colour window in combined σ (> 0).
    fallback : bool
        When the colour-pruned search finds nothing, run the plain (colour-blind) pyramid on the same
        frame, so a colour measurement far outside its window (blend, saturation, a 5σ draw) cannot lose a
        frame the monochrome method identifies. The result's ``method`` then reads
        ``"pyramid+color:fallback"``.
    return_pruning : bool
        Also return a :class:`ColorPruning`.
    **options
        :class:`startracker.identify.frame.IdentifyOptions` (``sigma_px``, ``false_alarm``, ...).

    Returns
    -------
    IdentificationResult
        ``method`` is ``"pyramid+color"`` (or ``"pyramid+color:fallback"``); failure is a status, never an
        exception.
    ColorPruning
        Only with ``return_pruning``.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera, got {type(camera).__name__}")
    if not isinstance(catalog, StarCatalog):
        raise TypeError(f"catalog must be a StarCatalog, got {type(catalog).__name__}")
    opts = IdentifyOptions.from_kwargs(options)
    xy_arr = as_float_array(xy, "xy")
    if xy_arr.ndim != 2 or xy_arr.shape[1] != 2:
        raise ValueError(f"xy must have shape (K, 2), got {xy_arr.shape}")
    k = len(xy_arr)
    ratio = np.asarray(color_ratio, dtype=np.float64)
    if ratio.shape != (k,):
        raise ValueError(f"color_ratio must have shape ({k},) to match xy, got {ratio.shape}")
    if np.any(np.isinf(ratio)):
        raise ValueError("color_ratio must be finite or NaN (unknown), got inf")
    sig = np.broadcast_to(np.asarray(color_sigma, dtype=np.float64), (k,)) if np.ndim(color_sigma) == 0 else \
        np.asarray(color_sigma, dtype=np.float64)
    if sig.shape != (k,) or not np.all(np.isfinite(sig)) or np.any(sig < 0):
        raise ValueError(f"color_sigma must be a finite scalar or ({k},) array >= 0")
    for name, v in (("color_model_sigma", color_model_sigma), ("color_tol_sigmas", color_tol_sigmas)):
        if not (np.isfinite(v) and v >= 0) or (name == "color_tol_sigmas" and v == 0):
            raise ValueError(f"{name} must be finite and {'> 0' if name == 'color_tol_sigmas' else '>= 0'}, got {v}")
    if database is None:
        database = build_color_database(catalog, camera)
    elif not isinstance(database, ColorDatabase):
        raise TypeError(f"database must be a ColorDatabase, got {type(database).__name__}")
    if database.db.camera != camera:
        raise ValueError("database was built for another camera")
    stats = ColorPruning()
    t0 = time.perf_counter()
    frame = prepare_frame(xy_arr, camera, intensities, opts)
    star_ids = np.full(k, -1, dtype=np.int64)
    det_ratio = ratio[frame.index]
    det_tol = color_tol_sigmas * np.hypot(sig[frame.index], color_model_sigma)

    def done(result):
        return (result, stats) if return_pruning else result

    def failure(status, n_req=0, n_hyp=0, method="pyramid+color"):
        return done(IdentificationResult(
            success=False, star_ids=star_ids, q_cam_to_icrs=_IDENTITY.copy(), n_matched=0,
            residual_arcsec=float("inf"), latency_ms=(time.perf_counter() - t0) * 1e3, status=status,
            method=method, n_required=n_req, n_hypotheses=n_hyp, covariance_rad2=np.diag([np.inf] * 3)))

    db = database.db
    if frame.n < 3:
        return failure("fewer than 3 usable detections")
    if len(db.pairs) == 0 or db.mean_stars_per_fov < 1.0:
        return failure(f"catalog too sparse for the field of view ({db.mean_stars_per_fov:.2f} stars per frame)")
    method = "pyramid+color"
    match, status, n_hyp = _pyramid_color(database, frame, opts, det_ratio, det_tol, stats)
    if match is None and fallback:
        method = "pyramid+color:fallback"
        match, status, n_hyp2 = identify_pyramid(db, frame, opts)
        n_hyp += n_hyp2
    if match is None:
        return failure(status, n_hyp=n_hyp, method=method)
    sol = solve_wahba_single(frame.v[match.det], db.nav.vectors[match.nav], sigma_rad=frame.sigma_rad)
    if not sol.success or sol.residual_rms_arcsec > frame.match_tol_rad * RAD_TO_ARCSEC:
        return failure(f"final attitude rejected: {sol.status}", match.n_required, n_hyp, method)
    star_ids[frame.index[match.det]] = db.nav.hip[match.nav]
    return done(IdentificationResult(
        success=True, star_ids=star_ids, q_cam_to_icrs=sol.q_meas_to_ref, n_matched=int(match.n_matched),
        residual_arcsec=float(sol.residual_rms_arcsec), latency_ms=(time.perf_counter() - t0) * 1e3, status="ok",
        method=method, n_required=int(match.n_required), n_hypotheses=int(n_hyp),
        covariance_rad2=sol.covariance_rad2))

