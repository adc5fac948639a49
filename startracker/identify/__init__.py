"""Lost-in-space star identification: pyramid, geometric voting, brightness-referenced, main-star strings.

One entry point, :func:`identify`, one result type, :class:`IdentificationResult`, and one database per
(catalog, camera), :func:`build_database`, shared by all methods (star-pair catalog on the k-vector,
reference-star pairs, pattern strings, k-d tree). Every method proposes hypotheses in its own way and
ends with the same verification (:mod:`startracker.identify.verification`): Wahba attitude, every
detection matched against the catalog, acceptance only with enough confirming stars for the false-alarm
limit; then all detections are labelled with HIP numbers (−1 for the rest).

Example
-------
>>> from startracker.catalog import load_catalog
>>> from startracker.optics import camera_preset
>>> from startracker.identify import identify
>>> r = identify(xy, camera_preset("paper000"), load_catalog(6.0), method="pyramid")  # doctest: +SKIP
>>> r.success, r.star_ids, r.q_cam_to_icrs, r.latency_ms                           # doctest: +SKIP
"""

from __future__ import annotations

import time

import numpy as np

from startracker.attitude import RAD_TO_ARCSEC
from startracker.catalog import StarCatalog
from startracker.identify.brightness import identify_brightness
from startracker.identify.database import StarDatabase, build_database, clear_database_cache, default_database
from startracker.identify.frame import IdentifyOptions, detection_arguments, prepare_frame
from startracker.identify.pattern_string import identify_pattern_string
from startracker.identify.pyramid import CHEAP_FIRST, SEARCH_STATUS, identify_pyramid
from startracker.identify.result import IdentificationResult
from startracker.identify.voting import identify_voting
from startracker.identify import verification
from startracker.kernels.identify import (STATUS_FEW, STATUS_PARALLEL, STATUS_RESIDUAL, identify_pyramid_detections,
                                          solve_identified)
from startracker.optics import Camera

__all__ = [
    "identify",
    "IdentificationResult",
    "build_database",
    "StarDatabase",
    "IdentifyOptions",
    "clear_database_cache",
    "METHODS",
]

METHODS = {
    "pyramid": identify_pyramid,
    "voting": identify_voting,
    "brightness": identify_brightness,
    "string": identify_pattern_string,
}

_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
_POOL = {"pyramid": 12, "voting": 20, "brightness": 10}  # default hypothesis pools (max_stars)
_DEFAULT_OPTIONS = IdentifyOptions()
_OPTIONS_CACHE: dict = {}


def _options(options: dict) -> IdentifyOptions:
    if not options:
        return _DEFAULT_OPTIONS
    try:
        key = tuple(sorted(options.items()))
        hash(key)
    except TypeError:
        return IdentifyOptions.from_kwargs(options)
    opts = _OPTIONS_CACHE.get(key)
    if opts is None:
        opts = IdentifyOptions.from_kwargs(options)
        if len(_OPTIONS_CACHE) > 256:
            _OPTIONS_CACHE.clear()
        _OPTIONS_CACHE[key] = opts
    return opts


def identify(
    xy,
    camera: Camera,
    catalog: StarCatalog,
    method: str = "pyramid",
    intensities=None,
    database: StarDatabase | None = None,
    **options,
) -> IdentificationResult:
    """Identify detected stars with no prior attitude.

    Parameters
    ----------
    xy : array_like, shape (K, 2)
        Detections in pixels (column, row), brightest first when ``intensities`` is None.
    camera : Camera
    catalog : StarCatalog
        Stars the camera can see (e.g. ``load_catalog(6.0)``).
    method : {"pyramid", "voting", "brightness", "string"}
    intensities : array_like, shape (K,), optional
        Positive detection intensities; the detections are ordered by them. The brightness method needs
        them (measured magnitude ``mag_zero_point − 2.5 log10(intensity)``).
    database : StarDatabase, optional
        From :func:`build_database`; by default the cached database of ``(catalog, camera)``.
    **options
        See :class:`startracker.identify.frame.IdentifyOptions` (``sigma_px``, ``false_alarm``, ...).

    Returns
    -------
    IdentificationResult
        A failure is ``success=False`` with a ``status``, never an exception.

    Raises
    ------
    ValueError
        Malformed ``xy`` / ``intensities`` (shape, NaN, inf, non-positive intensity), an unknown
        ``method``, a bad option value, or a database built for another camera.
    TypeError
        Wrong argument types or unknown option names.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera, got {type(camera).__name__}")
    if not isinstance(catalog, StarCatalog):
        raise TypeError(f"catalog must be a StarCatalog, got {type(catalog).__name__}")
    opts = _options(options)
    if method == "brightness" and intensities is None:
        raise ValueError("intensities are required for method='brightness'")
    if database is None:
        database = default_database(catalog, camera)
    elif not isinstance(database, StarDatabase):
        raise TypeError(f"database must be a StarDatabase, got {type(database).__name__}")
    elif database.camera is not camera and database.camera != camera:
        raise ValueError("database was built for another camera")
    t0 = time.perf_counter()
    if method == "pyramid" and database.usable:
        return _identify_pyramid(xy, camera, intensities, database, opts, t0)
    frame = prepare_frame(xy, camera, intensities, opts, n_angles=None if method == "string" else (opts.max_stars or _POOL[method]))
    if frame.n < 3:
        extra = f" ({frame.n_dropped} off the detector or duplicated)" if frame.n_dropped else ""
        return _failure(frame.n_input, method, t0, f"fewer than 3 usable detections{extra}")
    if not database.usable:
        return _failure(frame.n_input, method, t0, (
            f"catalog too sparse for the field of view ({database.mean_stars_per_fov:.2f} stars per frame on "
            f"average, {len(database.pairs)} star pairs)"))
    match, status, n_hyp = METHODS[method](database, frame, opts)
    if match is None:
        return _failure(frame.n_input, method, t0, status, n_hyp=n_hyp)
    # Final least squares on every match (compiled; the same solution as solve_wahba_single) and the labels.
    ok, q, rms_rad, cov, star_ids = solve_identified(frame.v, database.nav.vectors, database.nav.hip, frame.index,
                                                     match.det, match.nav, frame.n_input, frame.sigma_rad)
    if not ok:
        return _failure(frame.n_input, method, t0, _PARALLEL, match.n_required, n_hyp)
    if rms_rad > frame.match_tol_rad:
        return _failure(frame.n_input, method, t0, _RESIDUAL, match.n_required, n_hyp)
    return IdentificationResult(
        success=True,
        star_ids=star_ids,
        q_cam_to_icrs=q,
        n_matched=len(match.det),
        residual_arcsec=rms_rad * RAD_TO_ARCSEC,
        latency_ms=(time.perf_counter() - t0) * 1e3,
        status="ok",
        method=method,
        n_required=int(match.n_required),
        n_hypotheses=int(n_hyp),
        covariance_rad2=cov,
    )


def _identify_pyramid(xy, camera, intensities, database, opts, t0) -> IdentificationResult:
    """The pyramid without a candidate filter: one compiled call from pixels to labels and attitude."""
    pool = opts.max_stars or _POOL["pyramid"]
    args, k, sigma_rad, match_tol = detection_arguments(xy, camera, intensities, opts, pool)
    code, star_ids, q, cov, n_matched, n_req, n_hyp, n_usable, rms_rad = identify_pyramid_detections(
        *args, pool, opts.max_triads, CHEAP_FIRST, *database.search_arrays, database.nav.hip, database.clumping3,
        database.density_eff_per_sr, sigma_rad, match_tol, opts.false_alarm, verification.MAX_ROUNDS,
        verification.STABLE_FIT, verification.MISFIT_P)
    if code == 0:
        return IdentificationResult(
            success=True,
            star_ids=star_ids,
            q_cam_to_icrs=q,
            n_matched=n_matched,
            residual_arcsec=rms_rad * RAD_TO_ARCSEC,
            latency_ms=(time.perf_counter() - t0) * 1e3,
            status="ok",
            method="pyramid",
            n_required=n_req,
            n_hypotheses=n_hyp,
            covariance_rad2=cov,
        )
    # a failure: the kernel's labels (all -1) and identity attitude are fresh arrays of the failure's values
    if code == STATUS_FEW:
        extra = f" ({k - n_usable} off the detector or duplicated)" if n_usable < k else ""
        return _failure(k, "pyramid", t0, f"fewer than 3 usable detections{extra}", star_ids=star_ids, q=q)
    return _failure(k, "pyramid", t0, _PYRAMID_STATUS[code], n_req, n_hyp, star_ids, q)


_PARALLEL = "final attitude rejected: vectors are parallel: attitude not observable"
_RESIDUAL = "final attitude rejected: residual above the verification radius"
_PYRAMID_STATUS = {STATUS_PARALLEL: _PARALLEL, STATUS_RESIDUAL: _RESIDUAL, **SEARCH_STATUS}  # by failure code
_INF3 = np.full(3, np.inf)


def _failure(k: int, method: str, t0: float, status: str, n_req: int = 0, n_hyp: int = 0, star_ids=None,
             q=None) -> IdentificationResult:
    """A failed identification; ``star_ids`` (k,) all -1 and ``q`` the identity may be given as fresh arrays."""
    return IdentificationResult(
        success=False,
        star_ids=np.full(k, -1, dtype=np.int64) if star_ids is None else star_ids,
        q_cam_to_icrs=_IDENTITY.copy() if q is None else q,
        n_matched=0,
        residual_arcsec=float("inf"),
        latency_ms=(time.perf_counter() - t0) * 1e3,
        status=status,
        method=method,
        n_required=n_req,
        n_hypotheses=n_hyp,
        covariance_rad2=np.diag(_INF3),
    )
