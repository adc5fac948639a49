"""The star-pair catalog of paper 002 §4.2.1 on the generic k-vector.

Every pair of navigation stars closer than the field-of-view diagonal, sorted by inter-star angle,
with the brighter star's index ``I`` (``first``), the dimmer star's ``J`` (``second``) and their
magnitudes ``B_I``, ``B_J``. Range searches go through :class:`startracker.kvector.KVector` (exact).

A second, smaller catalog holds the pairs whose brighter star is a *reference star* (brighter than a
magnitude limit, paper 002 §4.3.1), so the brightness-referenced method searches a narrower range.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np
from scipy.spatial import cKDTree

from startracker.kvector import KVector

__all__ = ["StarPairCatalog", "build_pair_catalog", "expand_ranges", "join_equal"]


@dataclass(frozen=True, eq=False)
class StarPairCatalog:
    """Star pairs sorted by angle, searchable by k-vector.

    Attributes
    ----------
    angle_rad : ndarray, shape (M,)
        Inter-star angles in rad, ascending (``P`` of paper 002, as angles rather than cosines).
    first : ndarray of int32, shape (M,)
        Brighter star of each pair (``I``), an index into the navigation catalog.
    second : ndarray of int32, shape (M,)
        Dimmer star (``J``).
    first_mag, second_mag : ndarray of float32, shape (M,)
        ``B_I`` and ``B_J`` (V magnitudes).
    kvector : KVector or None
        k-vector over ``angle_rad`` (its ``order`` is the identity because the angles are pre-sorted);
        None when there is no pair (a catalog too sparse for the field of view).
    max_angle_rad : float
        Largest angle stored (the FOV diagonal plus a margin).
    """

    first: np.ndarray
    second: np.ndarray
    first_mag: np.ndarray
    second_mag: np.ndarray
    kvector: KVector | None
    max_angle_rad: float

    def __len__(self) -> int:
        return len(self.first)

    @property
    def angle_rad(self) -> np.ndarray:
        """Inter-star angles (M,), rad, ascending (stored once, in the k-vector)."""
        return self.kvector.sorted_values if self.kvector is not None else np.empty(0)

    @property
    def nbytes(self) -> int:
        """Memory of the arrays and the k-vector, bytes."""
        kv = self.kvector
        if kv is None:
            return 0
        return int(
            self.first.nbytes
            + self.second.nbytes
            + self.first_mag.nbytes
            + self.second_mag.nbytes
            + kv.sorted_values.nbytes
            + kv.order.nbytes
            + kv.k.nbytes
        )

    def ranges(self, angle_rad, tol_rad) -> tuple[np.ndarray, np.ndarray]:
        """Index ranges of the pairs with angle in ``[angle - tol, angle + tol]`` (k-vector search).

        Parameters
        ----------
        angle_rad : array_like, shape (Q,)
            Measured inter-star angles, rad.
        tol_rad : float or array_like, shape (Q,)
            Half-width of each window, rad.

        Returns
        -------
        start, stop : ndarray of int, shape (Q,)
            Pairs ``start[q]:stop[q]`` of this catalog lie in window ``q``.
        """
        a = np.atleast_1d(np.asarray(angle_rad, dtype=np.float64))
        t = np.asarray(tol_rad, dtype=np.float64)
        if self.kvector is None:
            z = np.zeros(len(a), dtype=np.int64)
            return z, z.copy()
        return self.kvector.query_ranges(a - t, a + t)

    def range_one(self, angle_rad: float, tol_rad: float) -> tuple[int, int]:
        """:meth:`ranges` for a single window, on Python scalars (a handful of queries per frame).

        The same k-vector look-up (paper 000 eq. 4: line indices, then ``K``) and the same exact trimming
        as :meth:`startracker.kvector.KVector.query_ranges`, without the array overhead.
        """
        kv = self.kvector
        if kv is None:
            return 0, 0
        s = kv.sorted_values
        n = kv.n
        lo = angle_rad - tol_rad
        hi = angle_rad + tol_rad
        ia = min(max(math.floor((lo - kv.b1) / kv.a1), 1), n)
        ib = min(max(math.ceil((hi - kv.b1) / kv.a1), 1), n)
        start = int(kv.k[ia - 1])
        stop = int(kv.k[ib - 1])
        while start > 0 and s[start - 1] >= lo:
            start -= 1
        while start < n and s[start] < lo:
            start += 1
        while stop < n and s[stop] <= hi:
            stop += 1
        while stop > 0 and s[stop - 1] > hi:
            stop -= 1
        return start, max(stop, start)

    def subset(self, mask) -> "StarPairCatalog":
        """The pairs selected by a boolean mask, with their own k-vector (angles stay sorted)."""
        mask = np.asarray(mask, dtype=bool)
        ang = self.angle_rad[mask]
        return StarPairCatalog(
            first=self.first[mask],
            second=self.second[mask],
            first_mag=self.first_mag[mask],
            second_mag=self.second_mag[mask],
            kvector=KVector(ang) if len(ang) else None,
            max_angle_rad=self.max_angle_rad,
        )


def expand_ranges(start: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All ``(query, pair)`` index pairs inside the ranges ``start[q]:stop[q]``.

    Returns
    -------
    query_index, pair_index : ndarray of int, shape (P,)
    """
    counts = stop - start
    total = int(counts.sum())
    qidx = np.repeat(np.arange(len(start)), counts)
    offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return qidx, np.repeat(start, counts) + offsets


def join_equal(a_left: np.ndarray, a_right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All index pairs (l, r) with ``a_left[l] == a_right[r]`` (vectorised sort join).

    Parameters
    ----------
    a_left, a_right : ndarray of int, shape (L,) and (R,)
        Star indices (e.g. the candidates of one detection from two pair windows).

    Returns
    -------
    li, ri : ndarray of int, shape (P,)
    """
    if len(a_left) == 0 or len(a_right) == 0:
        e = np.empty(0, dtype=np.int64)
        return e, e
    key = a_right.astype(np.int16) if a_right.max() < 32768 else a_right  # int16 sorts by radix
    o = np.argsort(key, kind="stable")
    srt = a_right[o]
    lo = np.searchsorted(srt, a_left, side="left")
    hi = np.searchsorted(srt, a_left, side="right")
    cnt = hi - lo
    total = int(cnt.sum())
    if total == 0:
        e = np.empty(0, dtype=np.int64)
        return e, e
    li = np.repeat(np.arange(len(a_left)), cnt)
    offs = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    ri = o[np.repeat(lo, cnt) + offs]
    return li, ri


def build_pair_catalog(vectors: np.ndarray, vmag: np.ndarray, max_angle_rad: float) -> StarPairCatalog:
    """All pairs of stars closer than ``max_angle_rad``.

    Parameters
    ----------
    vectors : ndarray, shape (N, 3)
        Unit vectors (ICRS) of the navigation stars, brightest first.
    vmag : ndarray, shape (N,)
        Their V magnitudes (non-decreasing).
    max_angle_rad : float
        Largest inter-star angle to store, rad (the FOV diagonal).

    Returns
    -------
    StarPairCatalog
    """
    if not (0 < max_angle_rad < np.pi):
        raise ValueError(f"max_angle_rad must be in (0, pi), got {max_angle_rad}")
    chord = 2.0 * np.sin(max_angle_rad / 2.0)
    if len(vectors) >= 2:
        pairs = cKDTree(vectors).query_pairs(chord, output_type="ndarray")
    else:
        pairs = np.empty((0, 2), dtype=np.int64)
    if len(pairs) == 0:  # a catalog too sparse for the field of view: identification will say so
        e = np.empty(0, dtype=np.int32)
        f = np.empty(0, dtype=np.float32)
        return StarPairCatalog(first=e, second=e.copy(), first_mag=f, second_mag=f.copy(), kvector=None,
                               max_angle_rad=float(max_angle_rad))
    i = pairs.min(axis=1)  # rows are brightest first: the lower index is the brighter star (I)
    j = pairs.max(axis=1)
    vi, vj = vectors[i], vectors[j]
    ang = np.arctan2(np.linalg.norm(np.cross(vi, vj), axis=1), np.sum(vi * vj, axis=1))
    order = np.argsort(ang, kind="stable")
    ang = ang[order]
    i = i[order].astype(np.int32)
    j = j[order].astype(np.int32)
    return StarPairCatalog(
        first=i,
        second=j,
        first_mag=vmag[i].astype(np.float32),
        second_mag=vmag[j].astype(np.float32),
        kvector=KVector(ang),
        max_angle_rad=float(max_angle_rad),
    )
