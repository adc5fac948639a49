"""The star-pair catalog of paper 002 §4.2.1 on the generic k-vector.

Every pair of navigation stars closer than the field-of-view diagonal, sorted by inter-star angle,
with the brighter star's index ``I`` (``first``), the dimmer star's ``J`` (``second``) and their
magnitudes ``B_I``, ``B_J``. Range searches go through :class:`startracker.kvector.KVector` (exact).

A second, smaller catalog holds the pairs whose brighter star is a *reference star* (brighter than a
magnitude limit, paper 002 §4.3.1), so the brightness-referenced method searches a narrower range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from startracker.kvector import KVector

__all__ = ["StarPairCatalog", "build_pair_catalog"]


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
    kvector : KVector
        k-vector over ``angle_rad`` (its ``order`` is the identity because the angles are pre-sorted).
    max_angle_rad : float
        Largest angle stored (the FOV diagonal plus a margin).
    """

    first: np.ndarray
    second: np.ndarray
    first_mag: np.ndarray
    second_mag: np.ndarray
    kvector: KVector
    max_angle_rad: float

    def __len__(self) -> int:
        return len(self.first)

    @property
    def angle_rad(self) -> np.ndarray:
        """Inter-star angles (M,), rad, ascending (stored once, in the k-vector)."""
        return self.kvector.sorted_values

    @property
    def nbytes(self) -> int:
        """Memory of the arrays and the k-vector, bytes."""
        kv = self.kvector
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
        return self.kvector.query_ranges(a - t, a + t)

    def subset(self, mask) -> "StarPairCatalog":
        """The pairs selected by a boolean mask, with their own k-vector (angles stay sorted)."""
        mask = np.asarray(mask, dtype=bool)
        ang = self.angle_rad[mask]
        if len(ang) == 0:
            raise ValueError("subset would be empty")
        return StarPairCatalog(
            first=self.first[mask],
            second=self.second[mask],
            first_mag=self.first_mag[mask],
            second_mag=self.second_mag[mask],
            kvector=KVector(ang),
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
    pairs = cKDTree(vectors).query_pairs(chord, output_type="ndarray")
    if len(pairs) == 0:
        raise ValueError("no star pair lies within the field of view: the catalog is too sparse")
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
