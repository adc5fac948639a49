"""Tracking mode: star prediction, observed-to-predicted matching (DKVLUT, brute force, k-d tree), and
the grouping of a multi-exposure frame's matches into one attitude per exposure instant.

Paper 000 (Yu et al., Sensors 2021, 21, 3176) is the reference. A multi-exposure frame holds W = N·M spots
(N exposure instants, M navigation stars) in scan order; from the last attitude, rate and acceleration the
W spots are *predicted* in instant order (Fig. 1b), every observed spot is matched to the nearest predicted
spot inside the star-neighbourhood radius r, and the matches of each instant give one Wahba attitude.

Matchers (identical results, enforced by a property test)
---------------------------------------------------------
``"dkvlut"``
    Paper 000 §3: one k-vector per axis over the predicted coordinates (S, R, K, the line h = a1·i + b1 of
    eqs. 1-3, the tables of :class:`~startracker.kvector.KVector`). For every observed point: the line indices
    ``i_a = floor((x_p - r - b1)/a1)``, ``i_b = ceil((x_p + r - b1)/a1)`` (eq. 4), the candidate range
    ``u ∈ [K(i_a), K(i_b)]`` (eq. 5), ``R(u)`` the candidates, the intersection of the x and y candidate
    sets (eq. 6) and the nearest of the intersection (case c). The intersection is a square of side 2r; a
    final ``d² <= r²`` check turns it into the disc, so the result equals brute force within the radius.
``"brute"``
    Paper 000 §2, the "existing method": every observed point against every predicted point.
``"kdtree"``
    :class:`scipy.spatial.cKDTree` over the predicted points, nearest neighbour with an upper bound.

The DKVLUT and the brute force are compiled loops of the same arithmetic (:mod:`startracker.kernels.track`), so
their time ratio measures the algorithm. Match rule shared by all three: observed point q takes the predicted point p minimising
``d² = (x_q - x_p)² + (y_q - y_p)²`` (float64, this exact expression) among those with ``d² <= r²``;
ties go to the lowest predicted index; ``-1`` when none lies within r.

Prediction radius rule
----------------------
With σ_c the 1σ per-axis centroid noise (px) and σ_pred the 1σ per-axis prediction error (px) from the
attitude, rate and acceleration uncertainty propagated to the exposure instant (:func:`prediction_sigma_px`),
the observed-minus-predicted offset is a 2-D Gaussian of per-axis σ = √(σ_c² + σ_pred²), whose norm is
Rayleigh distributed: ``P(|e| > kσ) = exp(-k²/2)``. The radius is ``r = k σ`` with k = 6 (a true spot is
missed with probability 1.5e-8), clipped to ``[r_min, r_max]``.

The module is over 600 lines because prediction, matching and grouping are the three steps of one
tracking pass and share their unchecked fast paths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from startracker.catalog import StarCatalog
from startracker.optics import Camera
from startracker.rotations import quat_normalize
from startracker.validation import as_float_array
from startracker.kernels import track as track_kernels

__all__ = [
    "MATCH_METHODS",
    "DKVLUT",
    "KVectorTable",
    "match_stars",
    "PredictedStars",
    "predict_star_positions",
    "prediction_covariance",
    "prediction_sigma_px",
    "prediction_radius_px",
    "camera_projection_model",
    "InstantAttitudes",
    "attitudes_per_instant",
]

MATCH_METHODS = ("dkvlut", "brute", "kdtree")
RADIUS_K_SIGMA = 6.0  # P(true spot outside r) = exp(-k²/2) = 1.5e-8


# --------------------------------------------------------------------------------------------- matching
def _check_points(a, name: str) -> np.ndarray:
    if isinstance(a, (str, bytes)):
        raise TypeError(f"{name} must be a numeric array of shape (K, 2), got {type(a).__name__}")
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a numeric array of shape (K, 2): {exc}") from None
    if arr.size == 0:
        return np.empty((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (K, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def _check_radius(radius_px) -> float:
    if isinstance(radius_px, (bool, np.bool_)) or not isinstance(radius_px, (int, float, np.integer, np.floating)):
        raise TypeError(f"radius_px must be a real number, got {type(radius_px).__name__}")
    r = float(radius_px)
    if not np.isfinite(r) or r < 0:
        raise ValueError(f"radius_px must be finite and >= 0, got {radius_px}")
    return r


@dataclass(frozen=True)
class KVectorTable:
    """One axis of a :class:`DKVLUT`: paper 000's Table 1 (eqs. 1-3).

    Attributes
    ----------
    sorted_values : ndarray, shape (W,)
        ``S``, ascending, px.
    order : ndarray of int, shape (W,)
        ``R`` (0-based predicted indices): ``sorted_values[j] == coordinate[order[j]]``.
    k : ndarray of int, shape (W,)
        ``K`` (``k[i - 1]`` is the paper's ``K(i)``).
    a1, b1 : float
        The line ``h(i) = a1 i + b1`` (1-based i).
    """

    sorted_values: np.ndarray
    order: np.ndarray
    k: np.ndarray
    a1: float
    b1: float


class DKVLUT:
    """Paper 000's double k-vector lookup table over the predicted star points (a thin object over
    :func:`startracker.kernels.track.dkvlut_build` and :func:`~startracker.kernels.track.dkvlut_match`).

    Parameters
    ----------
    predicted_xy : array_like, shape (W, 2)
        Predicted spot centroids (column, row) in px, W >= 1, in any order.
    validate : bool
        False skips the checks: for a caller passing a C-contiguous float64 (W, 2) array of finite points.

    Attributes
    ----------
    kx, ky : KVectorTable
        The tables of eqs. 1-3 per axis: ``kx.sorted_values`` = S_x, ``kx.order`` = R_x (0-based),
        ``kx.k`` = K_x, ``kx.a1``, ``kx.b1``.

    Notes
    -----
    The intersection of eq. 6 is computed without sets: walking the shorter of an observed point's two
    candidate lists, a candidate belongs to the other axis' set when its row in that axis' table (the inverse
    permutation of R) lies inside that axis' range ``[u_a, u_b]``, an O(1) test.
    """

    __slots__ = ("xy", "n", "tables")

    def __init__(self, predicted_xy, *, validate: bool = True):
        xy = np.ascontiguousarray(_check_points(predicted_xy, "predicted_xy")) if validate else predicted_xy
        if len(xy) == 0:
            raise ValueError("predicted_xy must contain at least one point")
        self.xy = xy
        self.n = len(xy)
        #: ``(order, k, line, cross)`` of :func:`startracker.kernels.track.dkvlut_build`
        self.tables = track_kernels.dkvlut_build(xy)

    def _axis(self, a: int) -> KVectorTable:
        order, k, line, _ = self.tables
        return KVectorTable(self.xy[order[a], a], order[a], k[a], float(line[a, 5]), float(line[a, 1]))

    @property
    def kx(self) -> KVectorTable:
        return self._axis(0)

    @property
    def ky(self) -> KVectorTable:
        return self._axis(1)

    def candidate_ranges(self, observed_xy, radius_px):
        """Candidate table rows of every observed point on both axes (eqs. 4-5).

        Returns
        -------
        (start_x, stop_x), (start_y, stop_y) : tuples of ndarray of int, shape (Q,)
            ``kx.order[start_x[q]:stop_x[q]]`` is R_x(u_x) for observed point q (0-based predicted indices),
            i.e. the paper's 1-based rows ``u_x = K_x(i_a) .. K_x(i_b)``.
        """
        obs = np.ascontiguousarray(_check_points(observed_xy, "observed_xy"))
        order, k, line, _ = self.tables
        u = track_kernels.dkvlut_ranges(order, k, line, obs, _check_radius(radius_px))
        return (u[:, 0], u[:, 1]), (u[:, 2], u[:, 3])

    def candidates(self, observed_xy, radius_px) -> tuple[np.ndarray, np.ndarray]:
        """The intersection set R_P of eq. 6 for every observed point, as (query, predicted) pairs.

        Returns
        -------
        query_index, predicted_index : ndarray of int, shape (P,)
            Pairs with the predicted point in both the x and the y candidate set, grouped by query.
        """
        obs = np.ascontiguousarray(_check_points(observed_xy, "observed_xy"))
        order, k, line, cross = self.tables
        return track_kernels.dkvlut_candidates(order, k, line, cross, obs, _check_radius(radius_px))

    def match(self, observed_xy, radius_px, *, validate: bool = True) -> np.ndarray:
        """Nearest predicted point within ``radius_px`` of every observed point (see :func:`match_stars`).

        ``validate=False``: a C-contiguous float64 (Q, 2) array of finite points and a float radius >= 0.
        """
        if validate:
            observed_xy = np.ascontiguousarray(_check_points(observed_xy, "observed_xy"))
            radius_px = _check_radius(radius_px)
        order, k, line, cross = self.tables
        return track_kernels.dkvlut_match(self.xy, order, k, line, cross, observed_xy, radius_px)


def _match_kdtree(pred: np.ndarray, obs: np.ndarray, r: float) -> np.ndarray:
    n = len(pred)
    tree = cKDTree(pred)
    bound = r * (1 + 1e-9) + 1e-12
    k = 2 if n >= 2 else 1
    d, j = tree.query(obs, k=k, distance_upper_bound=bound)
    if k == 1:
        d, j = d[:, None], j[:, None]
    j0 = j[:, 0]
    found = j0 < n
    j0s = np.where(found, j0, 0)
    d2 = (obs[:, 0] - pred[j0s, 0]) ** 2 + (obs[:, 1] - pred[j0s, 1]) ** 2
    idx = np.where(found & (d2 <= r * r), j0, -1)
    if k == 2:
        # The tree's own arithmetic may order near-ties differently: settle them with the shared rule.
        amb = found & (j[:, 1] < n) & (d[:, 1] <= d[:, 0] * (1 + 1e-9) + 1e-12)
        if amb.any():
            idx[amb] = track_kernels.match_brute(pred, np.ascontiguousarray(obs[amb]), r)
    return idx.astype(np.int64)


def match_stars(predicted_xy, observed_xy, radius_px, method: str = "dkvlut", *, validate: bool = True) -> np.ndarray:
    """Match observed spots to predicted spots (star neighbourhood approach).

    Parameters
    ----------
    predicted_xy : array_like, shape (W, 2)
        Predicted centroids (column, row), px. May be empty.
    observed_xy : array_like, shape (Q, 2)
        Observed centroids in scan order (any order), px. May be empty.
    radius_px : float
        Star-neighbourhood radius r >= 0, px (see :func:`prediction_radius_px` for the rule).
    method : {"dkvlut", "brute", "kdtree"}
        Paper 000's double k-vector lookup table, the all-pairs "existing method" (both compiled), or scipy's
        cKDTree. All three return the same answer.
    validate : bool
        False skips the checks: for a caller passing C-contiguous float64 (W, 2) and (Q, 2) arrays of finite
        points, a float radius >= 0 and a known method (the star tracker's per-frame path).

    Returns
    -------
    idx : ndarray of int, shape (Q,)
        Index into ``predicted_xy`` of the nearest predicted point with distance <= r (ties to the lowest
        index), or -1. Several observed points may take the same predicted point.

    Raises
    ------
    ValueError
        Bad shapes, NaN/inf coordinates, negative radius, unknown method.
    """
    if validate:
        if method not in MATCH_METHODS:
            raise ValueError(f"method must be one of {MATCH_METHODS}, got {method!r}")
        pred = np.ascontiguousarray(_check_points(predicted_xy, "predicted_xy"))
        obs = np.ascontiguousarray(_check_points(observed_xy, "observed_xy"))
        r = _check_radius(radius_px)
    else:
        pred, obs, r = predicted_xy, observed_xy, radius_px
    if len(pred) == 0 or len(obs) == 0:
        return np.full(len(obs), -1, dtype=np.int64)
    if method == "dkvlut":
        return track_kernels.dkvlut_build_match(pred, obs, r)
    if method == "brute":
        return track_kernels.match_brute(pred, obs, r)
    return _match_kdtree(pred, obs, r)


# ------------------------------------------------------------------------------------------- prediction
@dataclass(frozen=True)
class PredictedStars:
    """Predicted spots of one multi-exposure frame, in instant order (paper 000 Fig. 1b).

    Attributes
    ----------
    xy : ndarray, shape (W, 2)
        Predicted centroids (column, row), px.
    star_index : ndarray of int, shape (W,)
        Catalog row of each spot.
    instant : ndarray of int, shape (W,)
        Exposure instant (0..N-1) of each spot; non-decreasing.
    on_detector : ndarray of bool, shape (W,)
        Spot lies on the detector (the rest lie within the margin outside it).
    times_s : ndarray, shape (N,)
        Exposure instants, s.
    q_body_to_icrs : ndarray, shape (N, 4)
        Predicted body attitude at each instant.
    """

    xy: np.ndarray
    star_index: np.ndarray
    instant: np.ndarray
    on_detector: np.ndarray
    times_s: np.ndarray
    q_body_to_icrs: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


def _check_vec3(a, name: str) -> np.ndarray:
    return as_float_array(a, name, last_dim=3, ndim=1)


def predict_star_positions(
    camera: Camera,
    catalog: StarCatalog,
    q_body_to_icrs,
    times_s,
    t_ref_s: float = 0.0,
    omega_body=None,
    alpha_body=None,
    margin_px: float = 0.0,
    *,
    validate: bool = True,
) -> PredictedStars:
    """Predicted pixel position of every catalog star in the field of view at each exposure instant.

    The attitude is propagated from ``t_ref_s`` to each instant by second-order integration
    (:func:`~startracker.rotations.quat_integrate`: rotation vector ω·dt + α·dt²/2 in the body frame), as
    paper 000 ref. [26] does with attitude, rate and acceleration.

    Parameters
    ----------
    camera : Camera
        Its ``q_cam_to_body`` mounting is applied.
    catalog : StarCatalog
    q_body_to_icrs : array_like, shape (4,)
        Body attitude at ``t_ref_s``.
    times_s : array_like, shape (N,)
        Exposure instants, s.
    t_ref_s : float
        Time of ``q_body_to_icrs``, s.
    omega_body : array_like, shape (3,), optional
        Body rate at ``t_ref_s``, rad/s (zero if None).
    alpha_body : array_like, shape (3,), optional
        Body angular acceleration, rad/s² (zero if None).
    margin_px : float
        Also keep spots up to this far outside the detector (a spot predicted just off the edge may be
        observed just inside it). >= 0.
    validate : bool
        False skips the checks and the normalisation: for a caller passing a unit canonical (4,) float64
        quaternion (as ``quat_normalize`` returns), (N,) float64 times, float ``t_ref_s`` and ``margin_px``,
        and (3,) float64 rates.

    Returns
    -------
    PredictedStars
    """
    if not validate:
        w = np.zeros(3) if omega_body is None else omega_body
        a = np.zeros(3) if alpha_body is None else alpha_body
        return _predict(camera, catalog, q_body_to_icrs, times_s, t_ref_s, w, a, margin_px)
    if not isinstance(camera, Camera):
        raise TypeError("camera must be a startracker.optics.Camera")
    if not isinstance(catalog, StarCatalog):
        raise TypeError("catalog must be a startracker.catalog.StarCatalog")
    q0 = quat_normalize(as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4, ndim=1))
    t = np.ascontiguousarray(np.atleast_1d(as_float_array(times_s, "times_s")))
    if t.ndim != 1 or len(t) == 0:
        raise ValueError(f"times_s must be a non-empty 1-D array, got shape {t.shape}")
    t_ref = float(as_float_array(t_ref_s, "t_ref_s"))
    w = np.zeros(3) if omega_body is None else np.ascontiguousarray(_check_vec3(omega_body, "omega_body"))
    a = np.zeros(3) if alpha_body is None else np.ascontiguousarray(_check_vec3(alpha_body, "alpha_body"))
    margin = float(as_float_array(margin_px, "margin_px"))
    if margin < 0:
        raise ValueError(f"margin_px must be >= 0, got {margin_px}")
    return _predict(camera, catalog, q0, t, t_ref, w, a, margin)


def camera_projection_model(camera: Camera):
    """The projection parameters ``(f_mm, k1_per_mm2, pixel_mm, ppx, ppy, cos θ, sin θ)`` of the kernels'
    camera model (:func:`startracker.kernels.track.project_frame`), or None for a camera class that projects
    by a model of its own (then its ``project``/``unproject`` methods are called).

    A plain :class:`~startracker.optics.Camera` has θ = 0; a subclass with a float ``rotation_rad`` (the 3CMOS
    channel cameras of :mod:`startracker.color`) is the same pinhole on a detector rotated in-plane by θ about
    the principal point.
    """
    cls = type(camera)
    if cls.project is Camera.project and cls.unproject is Camera.unproject:
        c, s = 1.0, 0.0
    else:
        rot = getattr(camera, "rotation_rad", None)
        if not isinstance(rot, (float, int)) or isinstance(rot, bool):
            return None
        c, s = (1.0, 0.0) if rot == 0.0 else (math.cos(rot), math.sin(rot))
    ppx, ppy = camera.principal_point
    return (float(camera.focal_length_mm), float(camera.distortion_k1_per_mm2), camera.pixel_size_mm, float(ppx),
            float(ppy), c, s)


def _predict(camera: Camera, catalog: StarCatalog, q0: np.ndarray, t: np.ndarray,
             t_ref: float, w: np.ndarray, a: np.ndarray, margin: float) -> PredictedStars:
    """The work of :func:`predict_star_positions`: ``q0`` a unit canonical (4,) float64 quaternion (as
    ``quat_normalize`` returns), ``t`` (N,) float64, ``w`` and ``a`` (3,) float64, ``margin`` >= 0."""
    q_body, r_cam_to_icrs, mid, spread = track_kernels.propagate_attitudes(
        q0, w, a, t - t_ref, np.array(camera.q_cam_to_body))
    # Candidate stars: one cone around the mean boresight wide enough for the whole frame.
    cone = min(math.pi, camera.half_diagonal_fov_rad + spread + margin / camera.focal_length_px + 0.02)
    cand = catalog.cone_search(mid, cone, validate=False)
    wdt, hgt = camera.resolution
    if len(cand) == 0:
        e = np.empty(0, dtype=np.int64)
        return PredictedStars(np.empty((0, 2)), e, e.copy(), np.empty(0, dtype=bool), t, q_body)
    model = camera_projection_model(camera)
    if model is not None:
        xy, star, inst, on_det = track_kernels.project_frame(catalog.vectors[cand], cand, r_cam_to_icrs, *model,
                                                             wdt, hgt, float(margin))
        return PredictedStars(xy, star, inst, on_det, t, q_body)
    # A camera with a projection of its own: through its methods.
    n_t = len(t)
    v_cam = catalog.vectors[cand][None] @ r_cam_to_icrs  # (R^T v)^T = v^T R per instant, (N, S, 3)
    xy, _, in_front = camera.project(v_cam.reshape(-1, 3), return_in_front=True, validate=False)
    x, y = xy[:, 0], xy[:, 1]
    keep = in_front & (x >= -0.5 - margin) & (x <= wdt - 0.5 + margin) & (y >= -0.5 - margin) & (y <= hgt - 0.5 + margin)
    on_det = (x >= -0.5) & (x <= wdt - 0.5) & (y >= -0.5) & (y <= hgt - 0.5)
    star = np.tile(cand, n_t)
    inst = np.repeat(np.arange(n_t), len(cand))
    return PredictedStars(np.ascontiguousarray(xy[keep]), star[keep], inst[keep], on_det[keep], t, q_body)


def _as_cov3(a, name: str) -> np.ndarray:
    c = as_float_array(a, name)
    c = c * np.eye(3) if c.ndim == 0 else c
    if c.shape != (3, 3):
        raise ValueError(f"{name} must be a float (isotropic variance) or shape (3, 3), got {c.shape}")
    return c


def prediction_covariance(cov_theta_body_rad2, dt_s, cov_omega_body=0.0, cov_alpha_body=0.0, *, validate: bool = True) -> np.ndarray:
    """Attitude error covariance after propagating for ``dt_s`` (body frame, rad²).

    ``P(dt) = P_θ + P_ω dt² + P_α dt⁴ / 4``: the second-order propagation of
    :func:`~startracker.rotations.quat_integrate` with independent attitude, rate and acceleration errors.

    Parameters
    ----------
    cov_theta_body_rad2 : array_like, shape (3, 3)
    dt_s : float or array_like, shape (N,)
    cov_omega_body : float or array_like, shape (3, 3)
        (rad/s)²; a float is an isotropic variance.
    cov_alpha_body : float or array_like, shape (3, 3)
        (rad/s²)², estimate error plus unmodelled change; a float is an isotropic variance.
    validate : bool
        False skips the checks when the three covariances are (3, 3) float64 arrays and ``dt_s`` is finite (a
        float or a float64 array), as the tracker's own state holds them; other forms are still converted.

    Returns
    -------
    ndarray, shape (3, 3) or (N, 3, 3)
    """
    p, pw, pa = cov_theta_body_rad2, cov_omega_body, cov_alpha_body
    if not validate and _is_cov3(p) and _is_cov3(pw) and _is_cov3(pa):
        dt = np.asarray(dt_s, dtype=np.float64)[..., None, None]
        return p + pw * dt**2 + pa * dt**4 / 4.0
    p = _as_cov3(cov_theta_body_rad2, "cov_theta_body_rad2")
    pw = _as_cov3(cov_omega_body, "cov_omega_body")
    pa = _as_cov3(cov_alpha_body, "cov_alpha_body")
    dt = as_float_array(dt_s, "dt_s")[..., None, None]
    return p + pw * dt**2 + pa * dt**4 / 4.0


def _is_cov3(a) -> bool:
    return type(a) is np.ndarray and a.shape == (3, 3) and a.dtype == np.float64


def prediction_sigma_px(camera: Camera, cov_theta_body_rad2, dt_s=0.0, cov_omega_body=0.0, cov_alpha_body=0.0, *,
                        validate: bool = True) -> float:
    """1σ per-axis prediction error of a spot, px, after propagating an attitude for ``dt_s``.

    From :func:`prediction_covariance` in the camera frame: a cross-boresight error moves every spot by
    ``f_px σ``, a roll error moves a spot by ``ρ σ`` with ρ up to the corner distance. Returns
    ``sqrt(f_px² max(P_xx, P_yy) + ρ_max² P_zz)`` for the largest ``|dt|``.

    Parameters
    ----------
    camera : Camera
    cov_theta_body_rad2 : array_like, shape (3, 3)
        Covariance of the attitude error rotation vector in the body frame, rad².
    dt_s : float or array_like
        Propagation time(s), s; the largest magnitude counts.
    cov_omega_body : float or array_like, shape (3, 3)
        Rate error covariance in the body frame, (rad/s)²; a float is an isotropic variance.
    cov_alpha_body : float or array_like, shape (3, 3)
        Acceleration error covariance (estimate and unmodelled change), (rad/s²)².
    validate : bool
        False skips the checks as :func:`prediction_covariance` does, for a finite float64 ``dt_s``.

    Returns
    -------
    float, px
    """
    if validate:
        dt_s = as_float_array(dt_s, "dt_s")
        p = _as_cov3(cov_theta_body_rad2, "cov_theta_body_rad2")
        pw = _as_cov3(cov_omega_body, "cov_omega_body")
        pa = _as_cov3(cov_alpha_body, "cov_alpha_body")
    else:
        p, pw, pa = (c if _is_cov3(c) else _as_cov3(c, name) for c, name in (
            (cov_theta_body_rad2, "cov_theta_body_rad2"), (cov_omega_body, "cov_omega_body"),
            (cov_alpha_body, "cov_alpha_body")))
    if type(dt_s) is float:
        dt = abs(dt_s)
    else:
        dt = float(np.max(np.abs(dt_s))) if np.size(dt_s) else 0.0
    w, h = camera.resolution
    return track_kernels.prediction_sigma_px(camera.r_cam_to_body, p, pw, pa, dt, camera.focal_length_px,
                                             math.hypot(w, h) / 2.0)


def prediction_radius_px(
    sigma_centroid_px: float,
    sigma_prediction_px: float = 0.0,
    k_sigma: float = RADIUS_K_SIGMA,
    r_min_px: float = 0.0,
    r_max_px: float = np.inf,
) -> float:
    """Star-neighbourhood radius from the prediction's uncertainty (module docstring: the rule).

    ``r = clip(k_sigma * sqrt(sigma_centroid_px² + sigma_prediction_px²), r_min_px, r_max_px)``; with the
    default k = 6 a true spot falls outside r with probability exp(-18) ≈ 1.5e-8.
    """
    for name, v in (("sigma_centroid_px", sigma_centroid_px), ("sigma_prediction_px", sigma_prediction_px), ("k_sigma", k_sigma)):
        if not math.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {v}")
    r = k_sigma * math.hypot(sigma_centroid_px, sigma_prediction_px)
    return float(min(max(r, r_min_px), r_max_px))


# ------------------------------------------------------------------------ grouping into N attitudes
@dataclass(frozen=True)
class InstantAttitudes:
    """One Wahba solution per exposure instant of a frame.

    Attributes
    ----------
    times_s : ndarray, shape (N,)
    q_body_to_icrs : ndarray, shape (N, 4)
        Identity where ``ok`` is False.
    covariance_rad2 : ndarray, shape (N, 3, 3)
        Attitude error covariance in the body frame (QUEST model), rad².
    residual_rms_arcsec : ndarray, shape (N,)
    n_stars : ndarray of int, shape (N,)
        Stars used per instant (after duplicate and outlier removal).
    ok : ndarray of bool, shape (N,)
        Solved with at least ``min_stars`` stars.
    assignment : ndarray of int, shape (K,)
        Per observed detection, the index into the prediction it was finally used for, or -1.
    n_outliers : int
        Matches removed by the residual test.
    """

    times_s: np.ndarray
    q_body_to_icrs: np.ndarray
    covariance_rad2: np.ndarray
    residual_rms_arcsec: np.ndarray
    n_stars: np.ndarray
    ok: np.ndarray
    assignment: np.ndarray
    n_outliers: int

    @property
    def skipped(self) -> np.ndarray:
        """Instants without a solution (too few stars)."""
        return np.flatnonzero(~self.ok)


def attitudes_per_instant(
    observed_xy,
    match_idx,
    prediction: PredictedStars,
    camera: Camera,
    catalog: StarCatalog,
    sigma_px: float,
    min_stars: int = 3,
    outlier_k_sigma: float = 5.0,
    *,
    validate: bool = True,
) -> InstantAttitudes:
    """Group matched detections by exposure instant and solve one Wahba problem per instant.

    Compiled (:func:`startracker.kernels.track.solve_instants`): one observed spot per predicted spot (the
    nearest, ties to the lowest observed index), then per instant the SVD Wahba solution with the QUEST
    covariance (:func:`startracker.kernels.attitude.solve_wahba_one`); stars whose residual exceeds ``outlier_k_sigma`` times the
    angular noise are dropped (the worst per instant first, until none remain) and the instant re-solved.

    Parameters
    ----------
    observed_xy : array_like, shape (K, 2)
        Detections, px.
    match_idx : array_like of int, shape (K,)
        :func:`match_stars` output against ``prediction.xy``.
    prediction : PredictedStars
    camera : Camera
    catalog : StarCatalog
    sigma_px : float
        1σ per-axis centroid noise, px; the angular noise is ``sigma_px / f_px``.
    min_stars : int
        Instants with fewer stars are skipped (>= 2).
    outlier_k_sigma : float
        Residual test threshold in units of the angular noise.
    validate : bool
        False skips the checks: ``observed_xy`` float64 (K, 2), ``match_idx`` int64 (K,) as :func:`match_stars`
        returns it for this prediction, a positive ``sigma_px`` and ``min_stars`` >= 2.

    Returns
    -------
    InstantAttitudes
    """
    if not validate:
        return _solve_instants(observed_xy, match_idx, prediction, camera, catalog, sigma_px, min_stars, outlier_k_sigma)
    obs = np.ascontiguousarray(_check_points(observed_xy, "observed_xy"))
    idx = np.ascontiguousarray(match_idx, dtype=np.int64)
    if idx.shape != (len(obs),):
        raise ValueError(f"match_idx must have shape ({len(obs)},), got {idx.shape}")
    if np.any(idx >= len(prediction)) or np.any(idx < -1):
        raise ValueError("match_idx must index prediction.xy or be -1")
    if not np.isfinite(sigma_px) or sigma_px <= 0:
        raise ValueError(f"sigma_px must be positive, got {sigma_px}")
    if int(min_stars) < 2:
        raise ValueError(f"min_stars must be >= 2, got {min_stars}")
    return _solve_instants(obs, idx, prediction, camera, catalog, sigma_px, min_stars, outlier_k_sigma)


def _solve_instants(obs, idx, prediction, camera, catalog, sigma_px, min_stars, outlier_k_sigma):
    """The work of :func:`attitudes_per_instant` on checked inputs (two kernel calls)."""
    model = camera_projection_model(camera)
    if model is not None:
        v_body = track_kernels.unproject_to_body(obs, *model, camera.r_cam_to_body)
    elif len(obs):
        v_body = np.ascontiguousarray(camera.unproject(obs) @ camera.r_cam_to_body.T)
    else:
        v_body = np.empty((0, 3))
    sigma_rad = sigma_px / camera.focal_length_px
    q, cov, rms, n_used, ok, assign, n_out = track_kernels.solve_instants(
        obs, v_body, idx, prediction.xy, prediction.instant, prediction.star_index, catalog.vectors,
        len(prediction.times_s), float(sigma_rad), int(min_stars), float(outlier_k_sigma * sigma_rad),
        np.zeros(len(obs)), np.zeros(0), 0.0)
    return InstantAttitudes(prediction.times_s.copy(), q, cov, rms, n_used, ok, assign, int(n_out))
