"""Inertial prediction of each head's observed scope and the dynamic local ("part") catalog (paper 001 §3.2-3.4).

Our reading of the equations whose symbols the extraction lost:

* **eq. 6 (LoS of head k).** ``l_k = C_b^i C_k z``: the head's boresight ``z = (0, 0, 1)`` through its
  installation matrix ``C_k`` (head -> body) and the body attitude ``C_b^i`` (body -> ICRS).
* **eq. 7 (estimated LoS).** The same with the INS attitude, ``l̂_k = Ĉ_b^i C_k z``.
* **eqs. 8-10 (bias rotation).** The INS attitude is the truth turned by a small rotation:
  ``Ĉ_b^i = (I + [μ×]) C_b^i`` with ``μ`` the INS attitude error in ICRS axes (platform error and position
  error combined, see :mod:`startracker.multifov.ins_error`); so ``l̂_k = R(μ) l_k`` and ``μ`` is the Euler (rotation)
  vector of eq. 10 taking the real LoS to the estimated one, the same for every head.
* **eqs. 11-12 (bias angle).** The estimated LoS lies on the cone of half-angle ``α_k`` about the real one,
  ``α_k = ∠(l̂_k, l_k)``; to first order ``α_k = |μ × l_k|``, the part of ``μ`` across the LoS (a roll about
  the LoS moves no LoS). Exactly, ``α_k = 2 asin(sin(|μ|/2) |n × l_k|) ≤ |μ × l_k|`` (``n = μ/|μ|``), so the
  linear value is an upper bound at any size.
* **eq. 13 (error radius).** ``ρ_e,k`` bounds ``α_k``. The INS does not know its error, only its covariance
  ``P`` (3×3, rad², ICRS); here ``ρ_e,k = n_σ √λ_max(Π_k P Π_k)`` with ``Π_k = I − l̂_k l̂_kᵀ``: the largest
  1σ of the error across the LoS times ``n_σ`` (default 5: a 2-D Gaussian leaves a 5σ circle with probability
  3.7e-6).
* **eq. 14 (catalog radius).** ``R_k = ρ_fov,k + ρ_e,k``, ``ρ_fov,k`` the FoV radius (boresight to the
  farthest detector corner).
* **eq. 15 (star selection).** Star ``s`` enters head k's part catalog when ``∠(s, l̂_k) ≤ R_k``. By the
  triangle inequality every star the head truly sees (``∠(s, l_k) ≤ ρ_fov,k``) passes when ``α_k ≤ ρ_e,k``.

§3.4 (pattern structure). The selected stars form sets ``S_k``. Two argument (angular distance) sets are
built from them: within one FoV, all pairs of ``S_k`` closer than the FoV diameter (``2 ρ_fov,k``); across a
pair of FoVs ``k < l``, all pairs ``(a ∈ S_k, b ∈ S_l)`` whose angle can occur between the two heads,
``θ_kl ± (ρ_fov,k + ρ_fov,l)`` with ``θ_kl`` the installation angle between their boresights. The two sets
have different value ranges, so each is divided into its own intervals ("packet storage", paper ref. [18]):
each :class:`PairTable` is one argument set sorted by angle with a :class:`~startracker.kvector.KVector`,
whose line splits the table's own range into equal intervals (packets) of about one pair each and whose
``K`` table gives where each packet starts; a range query reads the packets covering ``[d − ε, d + ε]``
and trims to the exact range.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from startracker.catalog import StarCatalog
from startracker.kvector import KVector
from startracker.multifov.heads import MultiFovSensor
from startracker.rotations import quat_to_matrix
from startracker.validation import as_float_array

__all__ = ["ObservedScope", "predict_scopes", "PairTable", "LocalCatalog", "los_bias_angles"]

_CHUNK = 1024


@dataclass(frozen=True)
class ObservedScope:
    """Predicted observed scope of one head (paper 001 eqs. 6-14).

    Attributes
    ----------
    head : int
    los_icrs : ndarray, shape (3,)
        Estimated LoS ``l̂_k`` (unit, ICRS), eq. 7.
    fov_radius_rad : float
        ``ρ_fov,k``: boresight to the farthest detector corner.
    error_radius_rad : float
        ``ρ_e,k`` (eq. 13), the bound of the LoS bias angle.
    catalog_radius_rad : float
        ``R_k = ρ_fov,k + ρ_e,k`` (eq. 14), clipped to π.
    """

    head: int
    los_icrs: np.ndarray
    fov_radius_rad: float
    error_radius_rad: float
    catalog_radius_rad: float

    @property
    def ins_error_exceeds_fov(self) -> bool:
        """The error radius is larger than the FoV radius: the paper's small-bias assumption fails."""
        return self.error_radius_rad > self.fov_radius_rad


def _check_cov(attitude_cov_rad2) -> np.ndarray:
    p = as_float_array(attitude_cov_rad2, "attitude_cov_rad2")
    if p.ndim == 0:
        if p < 0:
            raise ValueError(f"attitude_cov_rad2 must be >= 0, got {float(p)}")
        return np.eye(3) * float(p)
    if p.shape != (3, 3):
        raise ValueError(f"attitude_cov_rad2 must be a scalar variance or a (3, 3) matrix, got shape {p.shape}")
    if np.abs(p - p.T).max() > 1e-9 * max(1e-300, np.abs(p).max()):
        raise ValueError("attitude_cov_rad2 must be symmetric")
    if np.linalg.eigvalsh(p)[0] < -1e-12 * max(1e-300, np.abs(p).max()):
        raise ValueError("attitude_cov_rad2 must be positive semi-definite")
    return p


def predict_scopes(
    sensor: MultiFovSensor, q_ins_body_to_icrs, attitude_cov_rad2, n_sigma: float = 5.0
) -> tuple[ObservedScope, ...]:
    """Each head's estimated LoS, error radius and catalog radius from the INS (eqs. 6-14).

    Parameters
    ----------
    sensor : MultiFovSensor
    q_ins_body_to_icrs : array_like, shape (4,)
        INS attitude (w, x, y, z).
    attitude_cov_rad2 : float or array_like, shape (3, 3)
        Covariance of the INS attitude error ``μ`` (ICRS axes, rad²); a scalar is a per-axis variance.
    n_sigma : float
        Error radius in units of the largest cross-LoS 1σ (> 0).

    Returns
    -------
    tuple of ObservedScope, one per head.
    """
    if not isinstance(sensor, MultiFovSensor):
        raise TypeError("sensor must be a MultiFovSensor")
    if not np.isfinite(n_sigma) or n_sigma <= 0:
        raise ValueError(f"n_sigma must be > 0, got {n_sigma}")
    r_b2i = quat_to_matrix(as_float_array(q_ins_body_to_icrs, "q_ins_body_to_icrs", last_dim=4, ndim=1))
    p = _check_cov(attitude_cov_rad2)
    los = (r_b2i @ sensor.boresights_body.T).T  # eq. 7, (K, 3)
    out = []
    for k, (l, rho_fov) in enumerate(zip(los, sensor.half_diagonal_fov_rad)):
        proj = np.eye(3) - np.outer(l, l)
        lam = max(0.0, float(np.linalg.eigvalsh(proj @ p @ proj)[-1]))
        rho_e = n_sigma * np.sqrt(lam)  # eq. 13
        out.append(ObservedScope(k, l, float(rho_fov), float(rho_e), float(min(np.pi, rho_fov + rho_e))))  # eq. 14
    return tuple(out)


def los_bias_angles(sensor: MultiFovSensor, mu_icrs, q_body_to_icrs) -> np.ndarray:
    """True LoS bias angle of each head (eq. 12) for an INS error ``μ``: ``∠(R(μ) l_k, l_k)``.

    Parameters
    ----------
    sensor : MultiFovSensor
    mu_icrs : array_like, shape (..., 3)
        INS attitude error (rotation vector, rad, ICRS), ``q_ins = exp(μ) ⊗ q``.
    q_body_to_icrs : array_like, shape (..., 4)
        True attitude.

    Returns
    -------
    ndarray, shape (..., K)
        rad.
    """
    mu = as_float_array(mu_icrs, "mu_icrs", last_dim=3)
    r = quat_to_matrix(as_float_array(q_body_to_icrs, "q_body_to_icrs", last_dim=4))
    los = np.einsum("...ij,kj->...ki", r, sensor.boresights_body)  # (..., K, 3)
    theta = np.linalg.norm(mu, axis=-1)[..., None]
    n = mu[..., None, :] / np.where(theta > 0, theta, 1.0)[..., None]
    s = np.linalg.norm(np.cross(n, los), axis=-1)
    return 2 * np.arcsin(np.clip(np.sin(theta / 2) * s, 0.0, 1.0))


@dataclass(frozen=True, eq=False)
class PairTable:
    """One argument set of the part catalog: directed star pairs sorted by angular distance.

    Attributes
    ----------
    heads : (int, int)
        ``(k, l)``: the first star belongs to head k's set, the second to head l's.
    first, second : ndarray of int, shape (P,)
        Catalog rows.
    angle_rad : ndarray, shape (P,)
        Ascending.
    kvector : KVector or None
        Range search over ``angle_rad`` (None for an empty table).
    """

    heads: tuple
    first: np.ndarray
    second: np.ndarray
    angle_rad: np.ndarray
    kvector: KVector | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.angle_rad)

    @classmethod
    def from_pairs(cls, heads, first, second, angle_rad) -> "PairTable":
        order = np.argsort(angle_rad, kind="stable")
        a = np.asarray(angle_rad, dtype=np.float64)[order]
        kv = KVector(a) if len(a) else None
        if kv is not None:
            a = kv.sorted_values  # the same values (already sorted): share the array
        return cls(tuple(heads), np.asarray(first)[order], np.asarray(second)[order], a, kv)

    def query_many(self, lo_rad, hi_rad, search: str = "kvector") -> tuple[np.ndarray, np.ndarray]:
        """All (query, pair row) with the pair's angle in ``[lo, hi]``; rows index ``first``/``second``.

        Parameters
        ----------
        lo_rad, hi_rad : array_like, shape (Q,) or scalar
        search : {"kvector", "scan"}
            ``"kvector"``: the k-vector range search (O(1) per query). ``"scan"``: compare every stored
            angle (O(P) per query), the conventional search whose cost grows with the catalog, kept as the
            peer of the catalog-size experiment (paper 001 Fig. 20). Both return the same rows.
        """
        lo = np.atleast_1d(np.asarray(lo_rad, dtype=np.float64))
        hi = np.atleast_1d(np.asarray(hi_rad, dtype=np.float64))
        if search not in ("kvector", "scan"):
            raise ValueError(f"search must be 'kvector' or 'scan', got {search!r}")
        if self.kvector is None:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        if search == "scan":
            lo, hi = np.broadcast_arrays(lo, hi)
            qs, rows = [], []
            for q in range(len(lo)):  # one pass over the whole table per query: that is the point
                r = np.flatnonzero((self.angle_rad >= lo[q]) & (self.angle_rad <= hi[q]))
                qs.append(np.full(len(r), q, np.int64))
                rows.append(r)
            return np.concatenate(qs), np.concatenate(rows)
        qi, rows = self.kvector.query_many(lo, hi)
        return qi, rows  # kvector was built on the sorted angles, so its "original" index is the row


def _pairs_between(vec_a, idx_a, vec_b, idx_b, lo_rad, hi_rad, same_set: bool):
    """Directed pairs (a, b), a != b, with lo <= angle <= hi, by chunked dense dot products.

    With ``same_set`` (the within-FoV set: ``vec_a is vec_b``) only a < b is computed and mirrored.
    The angle is ``arccos`` of the dot product: its rounding error, 1e-16 / sin θ, stays far below any
    matching tolerance for the separations kept (close doubles are removed from navigation catalogs).
    """
    cos_hi, cos_lo = np.cos(min(np.pi, hi_rad)), np.cos(max(0.0, lo_rad))
    fa, fb, ang = [np.empty(0, np.int32)], [np.empty(0, np.int32)], [np.empty(0)]
    for s in range(0, len(vec_a), _CHUNK):
        b_from = s if same_set else 0
        c = vec_a[s : s + _CHUNK] @ vec_b[b_from:].T
        ok = (c >= cos_hi) & (c <= cos_lo)
        if same_set:
            ok &= np.arange(s, s + len(c))[:, None] < np.arange(b_from, len(vec_b))[None, :]
        i, j = np.nonzero(ok)
        a = np.arccos(np.clip(c[i, j], -1.0, 1.0))
        ia, jb = idx_a[s + i].astype(np.int32), idx_b[b_from + j].astype(np.int32)
        keep = ia != jb
        fa.append(ia[keep])
        fb.append(jb[keep])
        ang.append(a[keep])
    fa, fb, ang = np.concatenate(fa), np.concatenate(fb), np.concatenate(ang)
    if same_set:
        fa, fb, ang = np.concatenate([fa, fb]), np.concatenate([fb, fa]), np.concatenate([ang, ang])
    return fa, fb, ang


@dataclass(frozen=True, eq=False)
class LocalCatalog:
    """The part catalog of one frame: per-head star sets (eq. 15) and the §3.4 argument sets.

    Build with :meth:`build` (local, from predicted scopes) or :meth:`all_sky` (every star in every head's
    set: the conventional all-sky catalog with the same structure).

    Attributes
    ----------
    catalog : StarCatalog
        The all-sky catalog the sets index into.
    scopes : tuple of ObservedScope or None
        None for the all-sky catalog.
    star_sets : tuple of ndarray of int
        ``S_k``: catalog rows per head.
    tables : dict[(int, int), PairTable]
        ``(k, k)``: within-FoV pairs in both orders; ``(k, l)``, k < l: cross-FoV pairs ``(a ∈ S_k, b ∈ S_l)``.
    margin_rad : float
        Added to every pair-angle range so that measured angles with noise still find their pair.
    """

    catalog: StarCatalog
    scopes: tuple | None
    star_sets: tuple
    tables: dict
    margin_rad: float

    @cached_property
    def stars(self) -> np.ndarray:
        """Union of the star sets, sorted catalog rows."""
        return np.unique(np.concatenate(self.star_sets)) if self.star_sets else np.empty(0, np.int64)

    @property
    def n_stars(self) -> int:
        return len(self.stars)

    @cached_property
    def nbytes(self) -> int:
        """Memory of the star sets and argument sets (pairs, angles, k-vectors), bytes."""
        total = sum(s.nbytes for s in self.star_sets)
        for t in self.tables.values():
            total += t.first.nbytes + t.second.nbytes + t.angle_rad.nbytes
            if t.kvector is not None:
                total += t.kvector.order.nbytes + t.kvector.k.nbytes
        return int(total)

    @cached_property
    def n_pairs(self) -> int:
        return int(sum(len(t) for t in self.tables.values()))

    def table(self, k: int, l: int) -> tuple[PairTable, bool]:
        """The argument set for observed stars in heads k then l, and whether its columns are swapped."""
        if k <= l:
            return self.tables[(k, l)], False
        return self.tables[(l, k)], True

    @classmethod
    def _from_sets(cls, catalog, sensor, star_sets, scopes, margin_rad):
        if not np.isfinite(margin_rad) or margin_rad < 0:
            raise ValueError(f"margin_rad must be >= 0, got {margin_rad}")
        hd = sensor.half_diagonal_fov_rad
        ang = sensor.installation_angles_rad
        tables = {}
        vec = catalog.vectors
        for k in range(sensor.n_heads):
            sk = star_sets[k]
            for l in range(k, sensor.n_heads):
                sl = star_sets[l]
                if k == l:
                    lo, hi = 0.0, 2 * hd[k] + margin_rad
                else:
                    lo = max(0.0, ang[k, l] - hd[k] - hd[l] - margin_rad)
                    hi = min(np.pi, ang[k, l] + hd[k] + hd[l] + margin_rad)
                fa, fb, a = _pairs_between(vec[sk], sk, vec[sl], sl, lo, hi, same_set=k == l)
                tables[(k, l)] = PairTable.from_pairs((k, l), fa, fb, a)
        return cls(catalog, scopes, tuple(star_sets), tables, float(margin_rad))

    @classmethod
    def build(
        cls, catalog: StarCatalog, sensor: MultiFovSensor, scopes, margin_rad: float = 0.0
    ) -> "LocalCatalog":
        """Select each head's stars by eq. 15 and build the within- and cross-FoV argument sets.

        Parameters
        ----------
        catalog : StarCatalog
            All-sky catalog (navigation stars).
        sensor : MultiFovSensor
        scopes : sequence of ObservedScope
            From :func:`predict_scopes`, one per head.
        margin_rad : float
            Widening of every pair-angle range (matching tolerance), rad.
        """
        if not isinstance(catalog, StarCatalog):
            raise TypeError("catalog must be a StarCatalog")
        if not isinstance(sensor, MultiFovSensor):
            raise TypeError("sensor must be a MultiFovSensor")
        scopes = tuple(scopes)
        if len(scopes) != sensor.n_heads or not all(isinstance(s, ObservedScope) for s in scopes):
            raise ValueError(f"scopes must hold one ObservedScope per head ({sensor.n_heads})")
        sets = tuple(catalog.cone_search(s.los_icrs, s.catalog_radius_rad) for s in scopes)  # eq. 15
        return cls._from_sets(catalog, sensor, sets, scopes, margin_rad)

    @classmethod
    def all_sky(cls, catalog: StarCatalog, sensor: MultiFovSensor, margin_rad: float = 0.0) -> "LocalCatalog":
        """The conventional all-sky catalog in the same structure (every star in every head's set)."""
        if not isinstance(catalog, StarCatalog):
            raise TypeError("catalog must be a StarCatalog")
        every = np.arange(len(catalog), dtype=np.int64)
        return cls._from_sets(catalog, sensor, tuple(every for _ in range(sensor.n_heads)), None, margin_rad)
