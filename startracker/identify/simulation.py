"""Synthetic detection lists with known truth, for identification benchmarks.

Catalog stars are rotated into the camera frame at a given attitude and projected with the camera;
stars closer than ``blend_px`` to a brighter one merge into it (the detector sees one spot); Gaussian
centroid noise, magnitude noise, missing stars and false stars are added; the list is sorted by
intensity and cut to the brightest ``max_stars``. Intensities are fluxes relative to a V = 0 star, the
convention of :func:`startracker.identify.identify`'s default ``mag_zero_point``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from startracker.catalog import StarCatalog
from startracker.optics import Camera
from startracker.rotations import quat_angle_between, quat_to_matrix

__all__ = ["SyntheticFrame", "simulate_frame", "score_result", "false_labels"]


@dataclass(frozen=True)
class SyntheticFrame:
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


def simulate_frame(
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
) -> SyntheticFrame:
    """One synthetic frame.

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
    return SyntheticFrame(
        xy=xy,
        intensities=10.0 ** (-0.4 * mag_meas),
        hip=hip,
        q_cam_to_icrs=np.asarray(q_cam_to_icrs, dtype=float),
        n_true=int(np.sum(hip >= 0)),
    )


def score_result(result, frame: SyntheticFrame, attitude_tol_arcsec: float = 600.0) -> str:
    """Classify an identification against the truth.

    Returns
    -------
    str
        ``"fail"`` (no identification), ``"wrong"`` (success with a true star carrying another star's HIP,
        fewer than three true stars identified, or an attitude off by more than ``attitude_tol_arcsec``
        and more than six standard deviations of the reported covariance), ``"correct"`` otherwise. A
        wrong identification is off by degrees; the covariance term leaves room for the roll error of
        noisy or clustered stars. A false star labelled with the HIP of a catalog star it happens to sit
        on does not make the result wrong; :func:`false_labels` counts those.
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


def false_labels(result, frame: SyntheticFrame) -> int:
    """False stars that received a HIP number (coincidences with catalog stars)."""
    return int(np.sum((frame.hip < 0) & (result.star_ids >= 0)))
