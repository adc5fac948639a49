"""Inertial-aided triangle matching for distributed multiple FoVs (paper 001 §3.4, steps 1-4).

Per frame:

1. predict each head's LoS from the INS attitude (eqs. 6-7);
2. compute its error radius and catalog radius from the INS covariance (eqs. 8-14);
3. select the part catalog by cone search (eq. 15) and build its within- and cross-FoV argument sets
   (:class:`startracker.multifov.local_catalog.LocalCatalog`);
4. match the fused image against it.

Matching (triangle algorithm, paper 001 §3.4). The detections of all heads are put on one picture (their
body-frame directions, equal to rebuilding the fused image of :meth:`MultiFovSensor.fuse`). For a triangle
of observed stars ``(i, j, m)`` each side's measured angle is searched in the argument set of the heads the
two stars were seen in (within-FoV for one head, cross-FoV for two), ``[d − ε, d + ε]``; the candidate
pairs of sides ``ij`` and ``im`` are joined on the catalog star of ``i``, the third side is checked against
``d_jm``, and mirror images are dropped by the sign of the triple product. Every catalog triangle left is a
hypothesis: its attitude is solved (Wahba by SVD, batched over hypotheses) and verified by
re-projection: every observed star is turned into ICRS by the hypothesis and counted as matched when a
catalog star lies within its tolerance (noise plus the hypothesis' own attitude uncertainty); each
hypothesis is refitted on all its matches and re-verified with the tight tolerance. The reported attitude
is :func:`startracker.attitude.solve_wahba` on all matches of the accepted hypothesis.

It is reported as a success only when

* at least ``min_matched`` (3) stars match and the refitted residual is within the noise;
* a triangle alone (3 matches) is accepted only when the expected number of chance catalog triangles
  over the triangles tried is below ``false_alarm``; otherwise further detections must confirm it;
* no other hypothesis with a different attitude explains as many stars (else "ambiguous");
* with an INS prior, every head's solved LoS lies inside its predicted error radius (eq. 13);
* most catalog stars the solution puts on the detectors (brighter than the catalog limit minus a margin)
  were observed (a wrong attitude predicts stars that are not there).

Fallback. Without an INS prior, or when an error radius exceeds ``max_error_radius_deg`` (the INS error is
so large that the part catalog is no smaller than the sky), the same matcher runs on the all-sky catalog in
the same structure (:meth:`LocalCatalog.all_sky`, built once per matcher) and the result says so
(``method="multifov-allsky"``, ``fallback_all_sky=True``). A head whose error radius exceeds its FoV radius
is reported in ``status`` ("ins error exceeds fov") while the widened part catalog is still used.

The module is one class whose steps (triangle search, verification, acceptance rules above) share the
matcher's cached catalog state, so it stays whole at about 600 lines.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import binom

from startracker.attitude import RAD_TO_ARCSEC, solve_wahba
from startracker.catalog import StarCatalog
from startracker.identify.result import IdentificationResult
from startracker.multifov.heads import MultiFovSensor
from startracker.multifov.local_catalog import LocalCatalog, ObservedScope, predict_scopes
from startracker.rotations import quat_multiply

__all__ = ["MultiFovResult", "InertialAidedMatcher"]


@dataclass(frozen=True)
class MultiFovResult(IdentificationResult):
    """Outcome of one multi-FoV identification: an :class:`IdentificationResult` (same fields, same
    meaning, ``q_cam_to_icrs`` and ``covariance_rad2`` for the main head 0) plus the multi-head fields.

    Attributes
    ----------
    star_ids : ndarray of int, shape (n,)
        HIP number of each detection of all heads in head order, −1 where unmatched.
    latency_ms : float
        Wall-clock time of the call (INS prediction and part-catalog build included, all-sky build excluded).
    status : str
        "ok" or why not, plus notes ("ins error exceeds fov", "all-sky fallback: ...").
    method : str
        "multifov-local" or "multifov-allsky".
    n_required : int
        ``min_matched`` (a triangle needs confirming stars beyond it when chance triangles are likely).
    n_hypotheses : int
        Catalog triangles that reached verification.
    star_ids_per_head : tuple of ndarray of int
        ``star_ids`` split per head.
    q_body_to_icrs : ndarray, shape (4,)
        Body attitude (w, x, y, z); identity on failure.
    n_catalog_stars, n_catalog_pairs : int
        Size of the catalog matched against (part catalog, or all-sky): stars, and pairs in its argument sets.
    fallback_all_sky : bool
    scopes : tuple of ObservedScope or None
        The predicted scopes (None without an INS prior).
    """

    star_ids_per_head: tuple = ()
    q_body_to_icrs: np.ndarray | None = None
    n_catalog_stars: int = 0
    n_catalog_pairs: int = 0
    fallback_all_sky: bool = False
    scopes: tuple | None = None


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def _cross(u, v):
    """Cross product over the last axis (faster than numpy.cross for small arrays)."""
    return np.stack(
        [u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
         u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
         u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]],
        axis=-1,
    )


def _angles(u, v):
    """Angle between unit vectors (..., 3), rad, accurate at all sizes."""
    return np.arctan2(np.sqrt(np.sum(_cross(u, v) ** 2, axis=-1)), np.sum(u * v, axis=-1))


def _triangle_order(n: int):
    """Mortari's pyramid enumeration of triangles: varied star triples early."""
    for dj in range(1, n - 1):
        for dk in range(1, n - dj):
            for i in range(0, n - dj - dk):
                yield i, i + dj, i + dj + dk


class InertialAidedMatcher:
    """Triangle matching of a multi-head sensor against an INS-predicted part catalog.

    Parameters
    ----------
    sensor : MultiFovSensor
    catalog : StarCatalog
        Navigation stars (all-sky); its faintest star sets the verification limit.
    sigma_px : float
        1σ centroid noise per axis, px (> 0).
    n_sigma_match : float
        Tolerances in units of the noise: pair windows ``ε = n √2 σ_ang``, re-projection ``n σ``.
    n_sigma_ins : float
        Error radius in units of the INS cross-LoS 1σ (eq. 13).
    max_error_radius_deg : float
        Beyond this INS error radius the all-sky catalog is used instead of a part catalog. The part catalog's
        build grows with the square of its star count: past ~20° it costs more than matching on the prebuilt
        all-sky catalog, for the same success rate (benchmarks/bench_multifov.py).
    max_stars_per_head : int
        Brightest detections per head used to form triangles (all are used in verification).
    max_triangles : int
        Triangles tried before giving up.
    min_matched : int
        Matched stars needed for success (>= 3, the triangle).
    verify_mag_margin : float
        Catalog stars brighter than (catalog limit − margin) that the solution puts inside a detector must
        mostly be observed; ``max_missing_fraction`` of them may be missing.
    max_missing_fraction : float
    retry_all_sky : bool
        After a failed part-catalog match, try the all-sky catalog (reported as a fallback).
    installation_error_rad : float
        1σ error of the installation matrices, added to the cross-FoV tolerance.
    false_alarm : float
        Accepted probability of a wrong identification per frame: a triangle alone (3 matches) is accepted
        only when the expected number of chance catalog triangles over the triangles tried is below it,
        else further detections must confirm (as in the lost-in-space verification).
    pair_search : {"kvector", "scan"}
        Range search in the argument sets: the k-vector, or a scan of every pair (the conventional search,
        for comparing catalog sizes as paper 001 Fig. 20 does).
    """

    def __init__(
        self,
        sensor: MultiFovSensor,
        catalog: StarCatalog,
        *,
        sigma_px: float = 0.2,
        n_sigma_match: float = 5.0,
        n_sigma_ins: float = 5.0,
        max_error_radius_deg: float = 20.0,
        max_stars_per_head: int = 8,
        max_triangles: int = 120,
        min_matched: int = 3,
        verify_mag_margin: float = 0.5,
        max_missing_fraction: float = 0.5,
        retry_all_sky: bool = False,
        installation_error_rad: float = 0.0,
        false_alarm: float = 1e-3,
        pair_search: str = "kvector",
    ):
        if not isinstance(sensor, MultiFovSensor):
            raise TypeError("sensor must be a MultiFovSensor")
        if not isinstance(catalog, StarCatalog):
            raise TypeError("catalog must be a StarCatalog")
        if len(catalog) < 3:
            raise ValueError("catalog must hold at least 3 stars")
        for name, v, lo in (
            ("sigma_px", sigma_px, 0.0),
            ("n_sigma_match", n_sigma_match, 0.0),
            ("n_sigma_ins", n_sigma_ins, 0.0),
            ("max_error_radius_deg", max_error_radius_deg, 0.0),
        ):
            if not isinstance(v, (int, float, np.floating, np.integer)) or not np.isfinite(v) or v <= lo:
                raise ValueError(f"{name} must be a finite number > {lo}, got {v!r}")
        for name, v, lo in (("max_stars_per_head", max_stars_per_head, 3), ("max_triangles", max_triangles, 1),
                            ("min_matched", min_matched, 3)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if not (0.0 <= max_missing_fraction <= 1.0):
            raise ValueError(f"max_missing_fraction must be in [0, 1], got {max_missing_fraction}")
        if not (0.0 < false_alarm < 1.0):
            raise ValueError(f"false_alarm must be in (0, 1), got {false_alarm}")
        self.false_alarm = float(false_alarm)
        if pair_search not in ("kvector", "scan"):
            raise ValueError(f"pair_search must be 'kvector' or 'scan', got {pair_search!r}")
        self.pair_search = pair_search
        if not np.isfinite(installation_error_rad) or installation_error_rad < 0:
            raise ValueError(f"installation_error_rad must be >= 0, got {installation_error_rad}")
        if not np.isfinite(verify_mag_margin) or verify_mag_margin < 0:
            raise ValueError(f"verify_mag_margin must be >= 0, got {verify_mag_margin}")
        self.sensor = sensor
        self.catalog = catalog
        self.sigma_px = float(sigma_px)
        self.n_sigma_match = float(n_sigma_match)
        self.n_sigma_ins = float(n_sigma_ins)
        self.max_error_radius_rad = float(np.radians(max_error_radius_deg))
        self.max_stars_per_head = int(max_stars_per_head)
        self.max_triangles = int(max_triangles)
        self.min_matched = int(min_matched)
        self.verify_mag = float(catalog.vmag.max() - verify_mag_margin)
        self.max_missing_fraction = float(max_missing_fraction)
        self.retry_all_sky = bool(retry_all_sky)
        self.installation_error_rad = float(installation_error_rad)
        # Angular noise of one detection: the largest pixel angle of any head (at the principal point).
        ifov = max(h.pixel_size_mm / h.focal_length_mm for h in sensor.heads)
        self.sigma_rad = self.sigma_px * ifov
        self.pair_tol_rad = self.n_sigma_match * np.sqrt(2 * self.sigma_rad**2 + 2 * self.installation_error_rad**2)
        self.verify_tol_rad = self.n_sigma_match * np.sqrt(self.sigma_rad**2 + self.installation_error_rad**2)

    # ------------------------------------------------------------------ catalogs
    @cached_property
    def all_sky_catalog(self) -> LocalCatalog:
        """All-sky catalog in the part-catalog structure (built on first use, then reused)."""
        return LocalCatalog.all_sky(self.catalog, self.sensor, margin_rad=self.pair_tol_rad)

    @cached_property
    def _tree(self) -> cKDTree:
        return cKDTree(self.catalog.vectors)

    def predict_scopes(self, q_ins_body_to_icrs, attitude_cov_rad2) -> tuple[ObservedScope, ...]:
        """Steps 1-2: each head's estimated LoS, error radius and catalog radius (eqs. 6-14)."""
        return predict_scopes(self.sensor, q_ins_body_to_icrs, attitude_cov_rad2, n_sigma=self.n_sigma_ins)

    def local_catalog(self, scopes) -> LocalCatalog:
        """Step 3: the part catalog of the predicted scopes (eq. 15 and §3.4)."""
        return LocalCatalog.build(self.catalog, self.sensor, scopes, margin_rad=self.pair_tol_rad)

    # ------------------------------------------------------------------ public entry
    def identify(self, xy_per_head, q_ins_body_to_icrs=None, attitude_cov_rad2=None) -> MultiFovResult:
        """Identify the stars of all heads with the INS prior (steps 1-4), or all-sky without one.

        Parameters
        ----------
        xy_per_head : sequence of K array_like, shape (n_k, 2)
            Detections per head, pixel (column, row), brightest first.
        q_ins_body_to_icrs : array_like, shape (4,), optional
            INS attitude. Omit (with the covariance) for all-sky identification.
        attitude_cov_rad2 : float or array_like, shape (3, 3), optional
            Covariance of the INS attitude error (ICRS axes, rad²); a scalar is a per-axis variance.

        Returns
        -------
        MultiFovResult
            Failure is a status, never an exception.
        """
        t0 = time.perf_counter()
        if (q_ins_body_to_icrs is None) != (attitude_cov_rad2 is None):
            raise ValueError("give both q_ins_body_to_icrs and attitude_cov_rad2, or neither")
        v_body, head = self.sensor.body_vectors(xy_per_head)
        notes = []
        scopes = None
        local = None
        if q_ins_body_to_icrs is None:
            notes.append("all-sky fallback: no INS prior")
        else:
            scopes = self.predict_scopes(q_ins_body_to_icrs, attitude_cov_rad2)
            worst = max(s.error_radius_rad for s in scopes)
            if any(s.ins_error_exceeds_fov for s in scopes):
                notes.append("ins error exceeds fov")
            if worst > self.max_error_radius_rad:
                notes.append(
                    f"all-sky fallback: INS error radius {np.degrees(worst):.2f} deg > "
                    f"{np.degrees(self.max_error_radius_rad):.2f} deg"
                )
            else:
                local = self.local_catalog(scopes)
        if local is not None:
            res = self._match(v_body, head, local, scopes)
            if not res["success"] and self.retry_all_sky:
                notes.append(f"all-sky fallback: part catalog failed ({res['status']})")
                local = None
        if local is None:
            res = self._match(v_body, head, self.all_sky_catalog, None)
        return self._result(res, head, local if local is not None else self.all_sky_catalog, scopes, notes, t0)

    def match(self, xy_per_head, catalog: LocalCatalog) -> MultiFovResult:
        """Step 4 alone: match detections against a given part (or all-sky) catalog.

        The INS consistency check uses ``catalog.scopes`` when the catalog has them.
        """
        t0 = time.perf_counter()
        if not isinstance(catalog, LocalCatalog):
            raise TypeError("catalog must be a LocalCatalog")
        if len(catalog.star_sets) != self.sensor.n_heads:
            raise ValueError(f"catalog has {len(catalog.star_sets)} star sets, the sensor {self.sensor.n_heads} heads")
        v_body, head = self.sensor.body_vectors(xy_per_head)
        res = self._match(v_body, head, catalog, catalog.scopes)
        return self._result(res, head, catalog, catalog.scopes, [], t0)

    def _result(self, res, head, catalog: LocalCatalog, scopes, notes, t0) -> MultiFovResult:
        counts = np.bincount(head, minlength=self.sensor.n_heads)
        ids = res["star_ids"]
        c_main = self.sensor.heads[0].r_cam_to_body
        if res["success"]:
            q_b = res["q_body_to_icrs"]
            q_c = quat_multiply(q_b, np.asarray(self.sensor.heads[0].q_cam_to_body))
            q_c = q_c / np.linalg.norm(q_c)
            cov = c_main.T @ res["covariance_rad2"] @ c_main
        else:
            q_b, q_c = _IDENTITY.copy(), _IDENTITY.copy()
            cov = np.diag([np.inf] * 3)
        return MultiFovResult(
            success=bool(res["success"]),
            star_ids=ids,
            q_cam_to_icrs=q_c,
            n_matched=int(res["n_matched"]),
            residual_arcsec=float(res["residual_arcsec"]),
            latency_ms=(time.perf_counter() - t0) * 1e3,
            status="; ".join([res["status"]] + list(notes)),
            method="multifov-allsky" if catalog.scopes is None else "multifov-local",
            n_required=self.min_matched,
            n_hypotheses=int(res["n_hypotheses"]),
            covariance_rad2=cov,
            star_ids_per_head=tuple(np.split(ids, np.cumsum(counts)[:-1])),
            q_body_to_icrs=q_b,
            n_catalog_stars=catalog.n_stars,
            n_catalog_pairs=catalog.n_pairs,
            fallback_all_sky=catalog.scopes is None,
            scopes=scopes,
        )

    # ------------------------------------------------------------------ core
    def _fail(self, n: int, status: str, n_hyp: int = 0) -> dict:
        return dict(success=False, star_ids=np.full(n, -1, np.int64), q_body_to_icrs=None, covariance_rad2=None,
                    n_matched=0, residual_arcsec=np.inf, status=status, n_hypotheses=n_hyp)

    def _candidates(self, local: LocalCatalog, hi: int, hj: int, d: float):
        """Catalog assignments (a for the first star, b for the second) of one observed pair, and the
        number of pairs a window of this width holds by chance."""
        table, swapped = local.table(hi, hj)
        _, rows = table.query_many(d - self.pair_tol_rad, d + self.pair_tol_rad, search=self.pair_search)
        a, b = table.first[rows], table.second[rows]
        # Pairs expected in the window by chance: the table's mean density over its angle range.
        span = (table.angle_rad[-1] - table.angle_rad[0]) if len(table) else 1.0
        expected = len(table) * 2 * self.pair_tol_rad / (span + 2 * self.pair_tol_rad)
        return (b, a, expected) if swapped else (a, b, expected)

    def _verify(self, r_b2i, cov, v_body, max_tol_rad=np.radians(0.5)):
        """Re-projection of every detection under M attitudes: nearest catalog star within tolerance.

        Returns (match (M, n) catalog row or −1, angle (M, n)).
        """
        m, n = len(r_b2i), len(v_body)
        pred = np.einsum("mij,nj->mni", r_b2i, v_body)  # (M, n, 3)
        # Tolerance: noise plus the hypothesis' attitude uncertainty across each direction.
        tr = np.trace(cov, axis1=1, axis2=2)[:, None] - np.einsum("ni,mij,nj->mn", v_body, cov, v_body)
        tol = self.n_sigma_match * np.sqrt(self.sigma_rad**2 + self.installation_error_rad**2 + np.maximum(tr, 0.0))
        tol = np.minimum(tol, max_tol_rad)
        dist, idx = self._tree.query(pred.reshape(-1, 3), k=1)
        ang = 2 * np.arcsin(np.clip(dist / 2, 0, 1)).reshape(m, n)
        idx = idx.reshape(m, n)
        ok = ang <= tol
        return np.where(ok, idx, -1), ang

    def _match(self, v_body, head, local: LocalCatalog, scopes) -> dict:
        n = len(v_body)
        if n < 3:
            return self._fail(n, f"fewer than 3 stars ({n})")
        cat_vec = self.catalog.vectors
        # Stars used for triangles: the brightest per head, interleaved across heads.
        rank = np.zeros(n, np.int64)
        for k in range(self.sensor.n_heads):
            sel = np.flatnonzero(head == k)
            rank[sel] = np.arange(len(sel))
        usable = np.flatnonzero(rank < self.max_stars_per_head)
        usable = usable[np.lexsort((head[usable], rank[usable]))]
        pair_cache = {}

        def cands(i, j):
            key = (i, j)
            if key not in pair_cache:
                d = float(_angles(v_body[i], v_body[j]))
                pair_cache[key] = self._candidates(local, int(head[i]), int(head[j]), d)
            return pair_cache[key]

        best = None  # (n_matched, rms, R, assignment)
        accepted = []  # attitudes (3, 3) and counts of verified hypotheses
        n_tri = n_hyp = 0
        lam_total = 0.0  # expected number of chance catalog triangles over the triangles tried
        dens = self._densities(local)
        for ti, tj, tm in _triangle_order(len(usable)):
            if n_tri >= self.max_triangles:
                break
            n_tri += 1
            i, j, m = usable[ti], usable[tj], usable[tm]
            a_ij, b_ij, e_ij = cands(i, j)
            a_im, c_im, _ = cands(i, m)
            lam_total += self._chance_triangles(e_ij, dens[head[m]], v_body[i], v_body[j], v_body[m])
            if len(a_ij) == 0 or len(a_im) == 0:
                continue
            order = np.argsort(a_im, kind="stable")
            a_sorted, c_sorted = a_im[order], c_im[order]
            lo = np.searchsorted(a_sorted, a_ij, "left")
            hi = np.searchsorted(a_sorted, a_ij, "right")
            cnt = hi - lo
            if cnt.sum() == 0:
                continue
            rep = np.repeat(np.arange(len(a_ij)), cnt)
            pos = np.repeat(lo, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
            A, B, C = a_ij[rep], b_ij[rep], c_sorted[pos]
            keep = (A != B) & (B != C) & (A != C)
            A, B, C = A[keep], B[keep], C[keep]
            d_jm = float(_angles(v_body[j], v_body[m]))
            keep = np.abs(_angles(cat_vec[B], cat_vec[C]) - d_jm) <= self.pair_tol_rad
            A, B, C = A[keep], B[keep], C[keep]
            if len(A) == 0:
                continue
            # Mirror images: the triple product keeps its sign under a rotation.
            t_obs = float(np.dot(v_body[i], _cross(v_body[j], v_body[m])))
            t_cat = np.einsum("ni,ni->n", cat_vec[A], _cross(cat_vec[B], cat_vec[C]))
            tri_tol = 6 * self.pair_tol_rad * max(
                float(_angles(v_body[i], v_body[j])), float(_angles(v_body[i], v_body[m])), 1e-6
            )
            keep = (np.sign(t_cat) == np.sign(t_obs)) | (np.abs(t_cat) < tri_tol) | (abs(t_obs) < tri_tol)
            A, B, C = A[keep], B[keep], C[keep]
            if len(A) == 0:
                continue
            hyp = np.stack([A, B, C], axis=1)
            obs = np.stack([v_body[i], v_body[j], v_body[m]])
            r, cov3, rms = _fit(obs, cat_vec[hyp], self.sigma_rad)
            ok = rms <= 1.5 * self.n_sigma_match * self.sigma_rad
            if cov3 is None or not ok.any():
                continue
            n_hyp += int(ok.sum())
            r = r[ok]
            matched, _ = self._verify(r, np.broadcast_to(cov3, (len(r), 3, 3)), v_body)
            for h in range(len(r)):
                cand = self._refine(v_body, matched[h])
                if cand is None:
                    continue
                if scopes is not None and not self._consistent_with_ins(cand[2], scopes):
                    continue
                accepted.append(cand)
                if best is None or (cand[0], -cand[1]) > (best[0], -best[1]):
                    best = cand
            # A fourth star confirming a triangle (pyramid-style) settles it; keep going only while
            # nothing explains more than the triangle itself.
            if best is not None and best[0] >= 4 and best[0] >= min(n, 4):
                break
        if best is None:
            return self._fail(n, f"no verified match ({n_tri} triangles tried)", n_hyp)
        n_best, rms_best, r_best, assign, cov_best = best
        sep = np.radians(0.1)
        for other in accepted:
            if other[0] >= n_best and _rot_angle(other[2], r_best) > sep:
                return self._fail(n, "ambiguous: two attitudes explain the stars equally", n_hyp)
        n_req = max(self.min_matched, self._required_matches(lam_total, n))
        if n_best < n_req:
            return self._fail(
                n, f"only {n_best} stars matched, {n_req} required (chance triangles {lam_total:.2g})", n_hyp
            )
        missing, expected = self._missing(r_best, assign)
        if expected and missing > max(1, self.max_missing_fraction * expected):
            return self._fail(n, f"rejected: {missing} of {expected} predicted bright stars not observed", n_hyp)
        ids = np.where(assign >= 0, self.catalog.hip[np.maximum(assign, 0)], -1)
        sel = np.flatnonzero(assign >= 0)
        sol = solve_wahba(v_body[sel], self.catalog.vectors[assign[sel]], self.sigma_rad)
        if not sol.success:
            return self._fail(n, f"attitude solution failed: {sol.status}", n_hyp)
        return dict(success=True, star_ids=ids, q_body_to_icrs=sol.q_meas_to_ref, covariance_rad2=sol.covariance_rad2,
                    n_matched=n_best, residual_arcsec=sol.residual_rms_arcsec, status="ok", n_hypotheses=n_hyp)

    def _refine(self, v_body, assign):
        """Refit on every matched star, re-verify with the tight tolerance.

        Returns (count, rms_arcsec, R_body_to_icrs, assignment (n,), covariance (3, 3)) or None.
        """
        for _ in range(2):
            sel = np.flatnonzero(assign >= 0)
            # One catalog star may not explain two detections.
            _, first = np.unique(assign[sel], return_index=True)
            sel = sel[np.sort(first)]
            if len(sel) < 3:
                return None
            r, cov, _ = _fit(v_body[sel], self.catalog.vectors[assign[sel]][None], self.sigma_rad)
            if cov is None:
                return None
            new, _ = self._verify(r, cov[None], v_body)
            new = new[0]
            vals, cnts = np.unique(new[new >= 0], return_counts=True)
            new[np.isin(new, vals[cnts > 1])] = -1  # drop detections fighting over one catalog star
            assign = new
        sel = np.flatnonzero(assign >= 0)
        if len(sel) < 3:
            return None
        r, cov, rms = _fit(v_body[sel], self.catalog.vectors[assign[sel]][None], self.sigma_rad)
        if cov is None or rms[0] > self.n_sigma_match * self.sigma_rad:
            return None
        return (len(sel), float(rms[0]) * RAD_TO_ARCSEC, r[0], assign, cov)

    def _densities(self, local: LocalCatalog) -> np.ndarray:
        """Stars per steradian of each head's set, times 2 for the clumping of the sky (Milky Way)."""
        out = []
        for k, sk in enumerate(local.star_sets):
            if local.scopes is None:
                area = 4 * np.pi
            else:
                area = 2 * np.pi * (1 - np.cos(local.scopes[k].catalog_radius_rad))
            out.append(2.0 * len(sk) / area)
        return np.array(out)

    def _chance_triangles(self, n_pairs_ij: float, density_m: float, vi, vj, vm) -> float:
        """Expected number of wrong catalog triangles fitting one observed triangle.

        Each of the ``n_pairs_ij`` catalog pairs fitting side ij fixes (with the handedness) one point where
        the third star must lie, inside the intersection of two rings of width 2ε: area ``(2ε)² / sin γ``
        (γ: the triangle's angle at the third star); a star is there with probability ``ρ · area``.
        """
        a, b = vi - vm * np.dot(vi, vm), vj - vm * np.dot(vj, vm)
        sin_g = np.linalg.norm(_cross(a, b)) / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-300)
        return n_pairs_ij * density_m * (2 * self.pair_tol_rad) ** 2 / max(sin_g, 0.05)

    def _required_matches(self, lam: float, n_det: int) -> int:
        """Fewest matches keeping ``λ · P(chance confirmations by the other detections) <= false_alarm``."""
        p = min(1.0, 2.0 * len(self.catalog) / (4 * np.pi) * np.pi * self.verify_tol_rad**2)
        n_other = n_det - 3
        for e in range(0, n_other + 1):
            if lam * binom.sf(e - 1, n_other, p) <= self.false_alarm:
                return 3 + e
        return n_det + 1

    def _consistent_with_ins(self, r_b2i, scopes) -> bool:
        """Eq. 13 as a check: each solved LoS lies inside its predicted error radius."""
        los = (r_b2i @ self.sensor.boresights_body.T).T
        for s, l in zip(scopes, los):
            if _angles(l, s.los_icrs) > s.error_radius_rad + 2 * self.verify_tol_rad + 1e-12:
                return False
        return True

    def _missing(self, r_b2i, assign):
        """Catalog stars brighter than the verification limit that the solution puts inside a detector
        (3 px from the edge) but that no detection matched."""
        matched = assign[assign >= 0]
        expected = missing = 0
        for cam in self.sensor.heads:
            r_c2i = r_b2i @ cam.r_cam_to_body
            idx = self.catalog.cone_search(r_c2i[:, 2], cam.half_diagonal_fov_rad * 1.001)
            idx = idx[self.catalog.vmag[idx] <= self.verify_mag]
            if len(idx) == 0:
                continue
            xy, inf = cam.project(self.catalog.vectors[idx] @ r_c2i)
            w, h = cam.resolution
            inside = inf & (xy[:, 0] > 2.5) & (xy[:, 0] < w - 3.5) & (xy[:, 1] > 2.5) & (xy[:, 1] < h - 3.5)
            expected += int(inside.sum())
            missing += int(np.sum(~np.isin(idx[inside], matched)))
        return missing, expected


def _fit(b, c, sigma_rad):
    """Wahba by SVD for M hypotheses sharing the measured directions (Markley), for scoring.

    Parameters
    ----------
    b : ndarray, shape (k, 3)
        Measured body directions (the same for every hypothesis).
    c : ndarray, shape (M, k, 3)
        Catalog directions of each hypothesis.
    sigma_rad : float

    Returns
    -------
    R : ndarray, shape (M, 3, 3)
        Body -> ICRS rotations.
    cov : ndarray, shape (3, 3) or None
        QUEST covariance (body axes), the same for every hypothesis; None when the directions are
        (nearly) parallel.
    rms : ndarray, shape (M,)
        RMS residual angle, rad.
    """
    prof = np.einsum("mki,kj->mij", c, b)
    u, _, vt = np.linalg.svd(prof)
    d = np.linalg.det(u) * np.linalg.det(vt)
    u[:, :, 2] *= d[:, None]
    r = u @ vt
    info = (len(b) * np.eye(3) - b.T @ b) / sigma_rad**2
    w = np.linalg.eigvalsh(info)
    cov = None if w[0] <= 1e-10 * w[-1] else np.linalg.inv(info)
    rb = np.einsum("mij,kj->mki", r, b)
    res = 2 * np.arcsin(np.clip(np.linalg.norm(rb - c, axis=-1) / 2, 0.0, 1.0))
    return r, cov, np.sqrt(np.mean(res**2, axis=1))


def _rot_angle(r1, r2) -> float:
    c = (np.trace(r1.T @ r2) - 1) / 2
    return float(np.arccos(np.clip(c, -1.0, 1.0)))
