"""The k-vector range search (Mortari 1997), generic and vectorised over many queries.

Build once on an array of values ``y`` (n,): sort it into ``S`` with ``order`` (the original index of each
sorted element), fit the straight line through the end points widened by half the mean spacing, and
tabulate ``K[i]`` = number of elements of ``S`` at or below the line at ``i``. This is exactly the table of
paper 000 §3.1 (eqs. 1-3)::

    D  = (S[n] - S[1]) / (n - 1)
    a1 = n D / (n - 1),   b1 = S[1] - D/2 - a1          h(i) = a1 i + b1,  i = 1..n
    K(i) = #{ j : S[j] <= h(i) },  K(1) = 0, K(n) = n

A range query ``[lo, hi]`` maps to line indices ``i_a = floor((lo - b1)/a1)``, ``i_b = ceil((hi - b1)/a1)``
(eq. 4), whose ``K`` values bound the answer; a couple of elements at each end are then trimmed so the
result equals a brute-force range search exactly (the line bins hold one element on average).

Used by the star-pair catalog (lost-in-space identification) and the tracker's DKVLUT.
"""

from __future__ import annotations

import numpy as np

from startracker.validation import as_float_array

__all__ = ["KVector"]


class KVector:
    """Sorted values with a k-vector for O(1) range look-ups.

    Parameters
    ----------
    values : array_like, shape (n,)
        Finite values, any order. n >= 1.

    Attributes
    ----------
    sorted_values : ndarray, shape (n,)
        ``S``, ascending.
    order : ndarray of int, shape (n,)
        ``R``: ``sorted_values[j] == values[order[j]]`` (0-based).
    k : ndarray of int, shape (n,)
        ``K`` of paper 000 (``k[i-1]`` is the paper's ``K(i)``).
    a1, b1 : float
        The fitted line ``h(i) = a1 i + b1`` (1-based ``i``, as in the paper).
    """

    __slots__ = ("sorted_values", "order", "k", "a1", "b1", "n")

    def __init__(self, values):
        y = as_float_array(values, "values", ndim=1)
        n = len(y)
        if n == 0:
            raise ValueError("values must contain at least one element")
        self.order = np.argsort(y, kind="stable")
        self.sorted_values = y[self.order]
        self.n = n
        s = self.sorted_values
        d = (s[-1] - s[0]) / (n - 1) if n > 1 else 0.0
        if d <= 0.0:
            d = max(1.0, abs(s[0])) * 1e-9  # all values equal: any positive spacing works
        self.a1 = n * d / (n - 1) if n > 1 else d
        self.b1 = s[0] - d / 2.0 - self.a1
        h = self.a1 * np.arange(1, n + 1) + self.b1
        k = np.searchsorted(s, h, side="right")  # build only: #{S <= h(i)}
        k[0] = 0
        k[-1] = n
        self.k = k

    @classmethod
    def from_arrays(cls, sorted_values, order, k, a1: float, b1: float) -> "KVector":
        """A k-vector from its stored arrays (a disk cache), without re-sorting.

        Parameters
        ----------
        sorted_values : ndarray, shape (n,)
            ``S``, ascending.
        order : ndarray of int, shape (n,) or None
            ``R``; None for values that were given sorted (the identity).
        k : ndarray of int, shape (n,)
            ``K``.
        a1, b1 : float
            The fitted line.
        """
        s = np.ascontiguousarray(sorted_values, dtype=np.float64)
        n = len(s)
        if n == 0 or s.ndim != 1 or len(k) != n or (order is not None and len(order) != n):
            raise ValueError("sorted_values, order and k must be 1-D arrays of the same non-zero length")
        kv = cls.__new__(cls)
        kv.sorted_values = s
        kv.order = np.arange(n) if order is None else np.asarray(order, dtype=np.int64)
        kv.k = np.asarray(k, dtype=np.int64)
        kv.a1 = float(a1)
        kv.b1 = float(b1)
        kv.n = n
        return kv

    def __len__(self) -> int:
        return self.n

    def line_indices(self, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """Paper 000 eq. 4: 1-based line indices ``(i_a, i_b)`` clipped to ``[1, n]``."""
        ia = np.floor((np.asarray(lo, dtype=np.float64) - self.b1) / self.a1)
        ib = np.ceil((np.asarray(hi, dtype=np.float64) - self.b1) / self.a1)
        ia = np.clip(np.nan_to_num(ia, nan=1.0, posinf=self.n, neginf=1.0), 1, self.n).astype(np.int64)
        ib = np.clip(np.nan_to_num(ib, nan=1.0, posinf=self.n, neginf=1.0), 1, self.n).astype(np.int64)
        return ia, ib

    def query_ranges(self, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """Exact ranges of ``sorted_values`` inside ``[lo, hi]``, for many queries at once.

        Parameters
        ----------
        lo, hi : array_like, shape (Q,) or scalar
            Closed query intervals. ``lo > hi`` gives an empty range.

        Returns
        -------
        start, stop : ndarray of int, shape (Q,)
            ``sorted_values[start[q]:stop[q]]`` are exactly the values in ``[lo[q], hi[q]]``.
        """
        lo = np.atleast_1d(np.asarray(lo, dtype=np.float64))
        hi = np.atleast_1d(np.asarray(hi, dtype=np.float64))
        lo, hi = np.broadcast_arrays(lo, hi)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("lo and hi must be finite")
        s = self.sorted_values
        n = self.n
        ia, ib = self.line_indices(lo, hi)
        start = self.k[ia - 1].copy()
        stop = self.k[ib - 1].copy()
        # Trim to the exact answer: only a few elements per bin, so a few vectorised passes.
        while True:
            move = (start > 0) & (s[np.maximum(start - 1, 0)] >= lo)
            if not move.any():
                break
            start[move] -= 1
        while True:
            move = (start < n) & (s[np.minimum(start, n - 1)] < lo)
            if not move.any():
                break
            start[move] += 1
        while True:
            move = (stop < n) & (s[np.minimum(stop, n - 1)] <= hi)
            if not move.any():
                break
            stop[move] += 1
        while True:
            move = (stop > 0) & (s[np.maximum(stop - 1, 0)] > hi)
            if not move.any():
                break
            stop[move] -= 1
        stop = np.maximum(stop, start)
        return start, stop

    def query(self, lo: float, hi: float) -> np.ndarray:
        """Original indices of the values in ``[lo, hi]`` (one query), ascending by value."""
        start, stop = self.query_ranges(lo, hi)
        return self.order[start[0] : stop[0]]

    def query_many(self, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """All (query, element) pairs with the element's value in the query's interval.

        Returns
        -------
        query_index : ndarray of int, shape (P,)
        element_index : ndarray of int, shape (P,)
            Original indices into ``values``.
        """
        start, stop = self.query_ranges(lo, hi)
        counts = stop - start
        total = int(counts.sum())
        qidx = np.repeat(np.arange(len(start)), counts)
        offsets = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
        pos = np.repeat(start, counts) + offsets
        return qidx, self.order[pos]
