"""k-vector kernel (Mortari 1997; paper 000 §3.1, eqs. 1-3), compiled, float64 arrays, no checks.

The checked API and the method's description are in :mod:`startracker.kvector`; this module builds the same table
in one compiled call for the tracker's per-frame DKVLUT (:mod:`startracker.kernels.track`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["kvector_build", "kvector_fill", "stable_argsort", "stable_argsort_into"]


@njit(cache=True)
def kvector_build(values):
    """Sort ``values`` and tabulate the k-vector of paper 000 eqs. 1-3.

    Parameters
    ----------
    values : ndarray, shape (n,)
        Finite float64 values, any order, n >= 1.

    Returns
    -------
    order : ndarray of int64, shape (n,)
        ``R``: ``values[order]`` ascending (stable: equal values keep their input order; :func:`stable_argsort`).
    sorted_values : ndarray, shape (n,)
        ``S``.
    k : ndarray of int64, shape (n,)
        ``k[i - 1]`` is the paper's ``K(i) = #{j : S[j] <= h(i)}``, with ``K(1) = 0`` and ``K(n) = n``.
    a1, b1 : float
        The line ``h(i) = a1 i + b1`` (1-based i) through ``(1, S[1] - D/2)`` and ``(n, S[n] + D/2)``.
    """
    n = values.shape[0]
    order = np.empty(n, dtype=np.int64)
    s = np.empty(n)
    k = np.empty(n, dtype=np.int64)
    a1, b1 = kvector_fill(values, order, s, k)
    return order, s, k, a1, b1


@njit(cache=True)
def kvector_fill(values, order, s, k):
    """:func:`kvector_build` into preallocated arrays ``order``, ``s``, ``k`` (shape (n,) each); returns (a1, b1)."""
    n = values.shape[0]
    stable_argsort_into(values, order)
    for j in range(n):
        s[j] = values[order[j]]
    d = (s[n - 1] - s[0]) / (n - 1) if n > 1 else 0.0
    if d <= 0.0:
        d = max(1.0, abs(s[0])) * 1e-9  # all values equal: any positive spacing works
    a1 = n * d / (n - 1) if n > 1 else d
    b1 = s[0] - d / 2.0 - a1
    j = 0
    for i in range(n):
        h = a1 * (i + 1.0) + b1
        while j < n and s[j] <= h:
            j += 1
        k[i] = j
    k[0] = 0
    k[n - 1] = n
    return a1, b1


@njit(cache=True)
def stable_argsort(values):
    """``np.argsort(values, kind="stable")`` (see :func:`stable_argsort_into`), shape (n,) -> int64 (n,)."""
    order = np.empty(values.shape[0], dtype=np.int64)
    stable_argsort_into(values, order)
    return order


@njit(cache=True)
def stable_argsort_into(values, order):
    """``np.argsort(values, kind="stable")`` in O(n) for spread-out values: a bucket sort.

    Values go into n equal-width bins between their minimum and maximum (a counting sort, stable), then each bin
    is sorted by insertion (stable; a bin of more than 32 values by merge sort), the bin index being a
    non-decreasing function of the value. The same permutation as numpy's stable sort.

    Parameters
    ----------
    values : ndarray, shape (n,)
        Finite float64 values.
    order : ndarray of int64, shape (n,)
        Output, written in place.
    """
    n = values.shape[0]
    if n == 0:
        return
    lo, hi = values[0], values[0]
    for i in range(1, n):
        v = values[i]
        if v < lo:
            lo = v
        elif v > hi:
            hi = v
    scale = (n - 1) / (hi - lo) if hi > lo else 0.0
    if not (scale < np.inf):  # a range so small (subnormal) its inverse overflows
        fallback = np.argsort(values, kind="mergesort")
        for i in range(n):
            order[i] = fallback[i]
        return
    start = np.zeros(n + 1, dtype=np.int64)
    bins = np.empty(n, dtype=np.int64)
    top = n - 1
    for i in range(n):
        b = int((values[i] - lo) * scale)
        if b > top:
            b = top
        bins[i] = b
        start[b + 1] += 1
    for b in range(n):
        start[b + 1] += start[b]
    fill = start[:n].copy()
    for i in range(n):
        b = bins[i]
        order[fill[b]] = i
        fill[b] += 1
    for b in range(n):
        a, e = start[b], start[b + 1]
        if e - a < 2:
            continue
        if e - a > 32:
            seg = order[a:e].copy()
            sub = np.argsort(values[seg], kind="mergesort")
            for j in range(e - a):
                order[a + j] = seg[sub[j]]
        else:
            for j in range(a + 1, e):
                cur = order[j]
                v = values[cur]
                i = j - 1
                while i >= a and values[order[i]] > v:
                    order[i + 1] = order[i]
                    i -= 1
                order[i + 1] = cur
