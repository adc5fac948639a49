"""Synthetic detection lists with known truth (no pixels), for tests and benchmarks.

Two generators:

* :func:`simulate_tracking_frame` -> :class:`TrackingFrame`: the detections of one multi-exposure frame
  during a slew, every spot labelled with its catalog row and exposure instant (the tracker's input,
  :mod:`startracker.track`).
* :func:`simulate_identification_frame` -> :class:`IdentificationFrame`: one single-exposure detection
  list at a fixed attitude, with HIP truth (the lost-in-space input, :mod:`startracker.identify`);
  :func:`score_result` and :func:`count_false_labels` grade an identification against it.

Place in the import order: this module uses :mod:`startracker.track` (its star prediction) and sits above
both rooms; no module of ``startracker`` imports it (tests/test_layering.py), only tests, benchmarks and
scripts.

Identification frames: catalog stars are rotated into the camera frame at a given attitude and projected
with the camera; stars closer than ``blend_px`` to a brighter one merge into it (the detector sees one
spot); Gaussian centroid noise, magnitude noise, missing stars and false stars are added; the list is sorted by
intensity and cut to the brightest ``max_stars``. Intensities are fluxes relative to a V = 0 star, the
convention of :func:`startracker.identify.identify`'s default ``mag_zero_point``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from startracker.catalog import StarCatalog
from startracker.optics import Camera
from startracker.rotations import quat_angle_between, quat_to_matrix
from startracker.track import predict_star_positions

__all__ = [
    "TrackingFrame",
    "simulate_tracking_frame",
    "IdentificationFrame",
    "simulate_identification_frame",
    "score_result",
    "count_false_labels",
]


# --------------------------------------------------------------------------- tracking frames
@dataclass(frozen=True)
class TrackingFrame:
    """Detections of one (multi-)exposure frame built straight from the catalog (no pixels).

    Attributes
    ----------
    xy : ndarray, shape (K, 2)
        Detections in scan order (row, then column), px.
    intensity : ndarray, shape (K,)
        Relative spot brightness (∝ 10^(-0.4 V) / N for stars).
    star_index : ndarray of int, shape (K,)
        Catalog row, -1 for false objects.
    instant : ndarray of int, shape (K,)
        Exposure instant, -1 for false objects.
    exposure_times_s : ndarray, shape (N,)
    q_body_to_icrs : ndarray, shape (N, 4)
        True body attitude at each instant.
    xy_true : ndarray, shape (K, 2)
        Noise-free positions (false objects: their drawn positions).
    """

    xy: np.ndarray
    intensity: np.ndarray
    star_index: np.ndarray
    instant: np.ndarray
    exposure_times_s: np.ndarray
    q_body_to_icrs: np.ndarray
    xy_true: np.ndarray


def simulate_tracking_frame(
    camera: Camera,
    catalog: StarCatalog,
    q_body_to_icrs,
    omega_body,
    exposure_times_s,
    rng: np.random.Generator,
    t_ref_s: float = 0.0,
    alpha_body=None,
    sigma_px: float = 0.0,
    n_false: int = 0,
    p_detect: float = 1.0,
) -> TrackingFrame:
    """Truth detections of a multi-exposure frame during a slew, for tests and benchmarks.

    Stars of ``catalog`` are projected at each exposure instant of the attitude trajectory
    ``q(t) = quat_integrate(q_body_to_icrs, omega_body, t - t_ref_s, alpha_body)``; each spot on the detector
    is kept with probability ``p_detect``, gets Gaussian noise of ``sigma_px`` per axis, and ``n_false``
    false objects are drawn uniformly over the detector. Detections come out in scan order.

    Parameters
    ----------
    camera, catalog
    q_body_to_icrs : array_like, shape (4,)
        True attitude at ``t_ref_s``.
    omega_body : array_like, shape (3,)
        True body rate, rad/s.
    exposure_times_s : array_like, shape (N,)
    rng : numpy.random.Generator
    t_ref_s : float
    alpha_body : array_like, shape (3,), optional
        True angular acceleration, rad/s².
    sigma_px : float
        Centroid noise, px (1σ per axis).
    n_false : int
        False objects.
    p_detect : float
        Detection probability of a star spot.

    Returns
    -------
    TrackingFrame
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    if sigma_px < 0 or n_false < 0 or not (0.0 <= p_detect <= 1.0):
        raise ValueError("sigma_px and n_false must be >= 0 and p_detect in [0, 1]")
    pred = predict_star_positions(camera, catalog, q_body_to_icrs, exposure_times_s, t_ref_s, omega_body, alpha_body)
    n_t = len(pred.times_s)
    keep = rng.random(len(pred)) < p_detect
    xy_true = pred.xy[keep]
    star = pred.star_index[keep]
    inst = pred.instant[keep]
    xy = xy_true + rng.normal(0.0, sigma_px, xy_true.shape) if sigma_px > 0 else xy_true.copy()
    inten = 1e3 * 10 ** (-0.4 * (catalog.vmag[star] - 6.0)) / n_t
    w, h = camera.resolution
    fxy = rng.uniform([-0.5, -0.5], [w - 0.5, h - 0.5], (int(n_false), 2))
    fint = 1e3 * 10 ** (-0.4 * rng.uniform(3.0, 7.0, int(n_false))) / n_t
    xy = np.concatenate([xy, fxy])
    xy_true = np.concatenate([xy_true, fxy])
    inten = np.concatenate([inten, fint])
    star = np.concatenate([star, np.full(int(n_false), -1)])
    inst = np.concatenate([inst, np.full(int(n_false), -1)])
    o = np.lexsort((xy[:, 0], np.floor(xy[:, 1])))
    return TrackingFrame(xy[o], inten[o], star[o], inst[o], pred.times_s, pred.q_body_to_icrs, xy_true[o])


# --------------------------------------------------------------------------- identification frames
@dataclass(frozen=True)
class IdentificationFrame:
    """Detections with their truth.

    Attributes
    ----------
    xy : ndarray, shape (K, 2)
        Pixel positions (column, row), brightest first.
    intensities : ndarray, shape (K,)
        Measured fluxes (V = 0 star = 1).
    hip : ndarray of int, shape (K,)
        True HIP number, −1 for false stars.
    q_cam_to_icrs : ndarray, shape (4,)
    n_true : int
        True stars among the detections.
    """

    xy: np.ndarray
    intensities: np.ndarray
    hip: np.ndarray
    q_cam_to_icrs: np.ndarray
    n_true: int


def simulate_identification_frame(
    catalog: StarCatalog,
    camera: Camera,
    q_cam_to_icrs,
    rng: np.random.Generator,
    *,
    sigma_px: float = 0.5,
    mag_sigma: float = 0.0,
    n_false: int = 0,
    false_mag_range: tuple[float, float] | None = None,
    false_among: int | None = None,
    missing: int = 0,
    max_stars: int | None = None,
    blend_px: float = 2.0,
) -> IdentificationFrame:
    """One synthetic single-exposure detection list at ``q_cam_to_icrs`` for identification.

    Parameters
    ----------
    catalog : StarCatalog
    camera : Camera
    q_cam_to_icrs : array_like, shape (4,)
    rng : numpy.random.Generator
    sigma_px : float
        Centroid noise, 1σ per axis, px.
    mag_sigma : float
        Magnitude noise, 1σ.
    n_false : int
        False stars, uniform over the detector.
    false_mag_range : (float, float), optional
        Uniform range of their magnitudes (default: the range of the true detections).
    false_among : int, optional
        Draw false-star magnitudes inside the range of the ``false_among`` brightest true stars, so they
        sit among the brightest (overrides ``false_mag_range``).
    missing : int
        True stars removed at random (not counting blends).
    max_stars : int, optional
        Keep only the brightest detections.
    blend_px : float
        Stars closer than this to a brighter star are not detected separately.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    r = quat_to_matrix(np.asarray(q_cam_to_icrs, dtype=float))
    boresight = r[:, 2]
    near = catalog.cone_search(boresight, min(camera.half_diagonal_fov_rad * 1.05, np.pi))
    v_cam = catalog.vectors[near] @ r  # R^T v
    xy, inside, front = camera.project(v_cam, return_in_front=True)
    # Blends first, over the whole cone: a faint star next to a brighter one just off the edge is part of
    # that star's spot, as the catalog of navigation stars has it.
    idx, xy, inside = near[front], xy[front], inside[front]
    o = np.argsort(catalog.vmag[idx], kind="stable")
    idx, xy, inside = idx[o], xy[o], inside[o]
    if len(idx) > 1 and blend_px > 0:
        d = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
        close = np.triu(d < blend_px, 1)
        inside &= ~close.any(axis=0)
    idx, xy = idx[inside], xy[inside]
    mag = catalog.vmag[idx]
    if missing > 0 and len(idx) > 0:
        drop = rng.choice(len(idx), size=min(missing, len(idx)), replace=False)
        keep = np.ones(len(idx), dtype=bool)
        keep[drop] = False
        idx, xy, mag = idx[keep], xy[keep], mag[keep]
    xy = xy + rng.normal(0.0, sigma_px, xy.shape) if sigma_px > 0 else xy.copy()
    mag_meas = mag + (rng.normal(0.0, mag_sigma, len(mag)) if mag_sigma > 0 else 0.0)
    hip = catalog.hip[idx].copy()
    w, h = camera.resolution
    on = (xy[:, 0] >= -0.5) & (xy[:, 0] <= w - 0.5) & (xy[:, 1] >= -0.5) & (xy[:, 1] <= h - 0.5)
    xy, mag_meas, hip = xy[on], mag_meas[on], hip[on]
    if n_false > 0:
        fxy = np.column_stack([rng.uniform(-0.5, w - 0.5, n_false), rng.uniform(-0.5, h - 0.5, n_false)])
        if false_among is not None and len(mag_meas) > 0:
            ms = np.sort(mag_meas)[: max(1, false_among)]
            lo, hi = ms[0], ms[-1]
        elif false_mag_range is not None:
            lo, hi = false_mag_range
        else:
            lo, hi = (mag_meas.min(), mag_meas.max()) if len(mag_meas) else (0.0, 6.0)
        fm = rng.uniform(lo, hi, n_false)
        xy = np.vstack([xy, fxy])
        mag_meas = np.concatenate([mag_meas, fm])
        hip = np.concatenate([hip, np.full(n_false, -1, dtype=np.int64)])
    o = np.argsort(mag_meas, kind="stable")
    if max_stars is not None:
        o = o[:max_stars]
    xy, mag_meas, hip = xy[o], mag_meas[o], hip[o]
    return IdentificationFrame(
        xy=xy,
        intensities=10.0 ** (-0.4 * mag_meas),
        hip=hip,
        q_cam_to_icrs=np.asarray(q_cam_to_icrs, dtype=float),
        n_true=int(np.sum(hip >= 0)),
    )


def score_result(result, frame: IdentificationFrame, attitude_tol_arcsec: float = 600.0) -> str:
    """Classify an identification against the truth.

    Returns
    -------
    str
        ``"fail"`` (no identification), ``"wrong"`` (success with a true star carrying another star's HIP,
        fewer than three true stars identified, or an attitude off by more than ``attitude_tol_arcsec``
        and more than six standard deviations of the reported covariance), ``"correct"`` otherwise. A
        wrong identification is off by degrees; the covariance term leaves room for the roll error of
        noisy or clustered stars. A false star labelled with the HIP of a catalog star it happens to sit
        on does not make the result wrong; :func:`count_false_labels` counts those.
    """
    if not result.success:
        return "fail"
    err = float(np.degrees(quat_angle_between(result.q_cam_to_icrs, frame.q_cam_to_icrs)) * 3600.0)
    cov = result.covariance_rad2
    sig = float(np.degrees(np.sqrt(np.max(np.linalg.eigvalsh(cov)))) * 3600.0) if cov is not None else 0.0
    true = frame.hip >= 0
    labelled = result.star_ids[true] >= 0
    mislabelled = np.any(labelled & (result.star_ids[true] != frame.hip[true]))
    if mislabelled or np.count_nonzero(labelled) < 3 or err > max(attitude_tol_arcsec, 6.0 * sig):
        return "wrong"
    return "correct"


def count_false_labels(result, frame: IdentificationFrame) -> int:
    """False stars that received a HIP number (coincidences with catalog stars)."""
    return int(np.sum((frame.hip < 0) & (result.star_ids >= 0)))
