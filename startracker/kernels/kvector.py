"""k-vector kernel (Mortari 1997; paper 000 §3.1, eqs. 1-3), compiled, float64 arrays, no checks.

The checked API and the method's description are in :mod:`startracker.kvector`; this module builds the same table
in one compiled call for the tracker's per-frame DKVLUT (:mod:`startracker.kernels.track`).

It also holds the compiled kernels' sorting, selection and searching of sorted values (:func:`stable_argsort_into`,
:func:`partition_values`, :func:`median_value`, :func:`search_sorted`). They stand in for ``np.argsort``,
``np.partition``, ``np.median`` and ``np.searchsorted`` inside compiled code, with the same results on finite values:
numba's own versions are generic code that takes seconds to compile per element type (about 4 s for ``np.sort``), and
every kernel that calls them carries that code again into its own compiled module.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["kvector_build", "kvector_fill", "stable_argsort", "stable_argsort_into", "partition_values",
           "median_value", "search_sorted"]


@njit(cache=True, no_cfunc_wrapper=True)
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


@njit(cache=True, no_cfunc_wrapper=True)
def kvector_fill(values, order, s, k):
    """:func:`kvector_build` into preallocated arrays ``order``, ``s``, ``k`` (shape (n,) each); returns (a1, b1)."""
    n = values.shape[0]
    _bucket_argsort(values, order, s)
    d = (s[n - 1] - s[0]) / (n - 1) if n > 1 else 0.0
    if d <= 0.0:
        d = max(1.0, abs(s[0])) * 1e-9  # all values equal: any positive spacing works
    a1 = n * d / (n - 1) if n > 1 else d
    b1 = s[0] - d / 2.0 - a1
    # K(i) = #{j : S[j] <= h(i)} (h increases with i): each value is counted at the first i whose h(i) reaches it,
    # then the counts summed. That i is the line's inverse, corrected by the comparison itself (rarely a step), so
    # that K is the comparisons' exactly; walking both sequences together branches unpredictably at every step.
    inv = 1.0 / a1  # the guess only: the comparisons below decide
    for i in range(n):
        k[i] = 0
    for j in range(n):
        v = s[j]
        t = (v - b1) * inv - 1.0
        if not t > 0.0:
            i = 0
        elif t >= n:
            i = n
        else:
            i = int(math.ceil(t))
        while i > 0 and v <= a1 * (i + 0.0) + b1:  # h(i - 1) reaches v too
            i -= 1
        while i < n and v > a1 * (i + 1.0) + b1:
            i += 1
        if i < n:
            k[i] += 1
    c = 0
    for i in range(n):
        c += k[i]
        k[i] = c
    k[0] = 0
    k[n - 1] = n
    return a1, b1


@njit(cache=True, no_cfunc_wrapper=True)
def stable_argsort(values):
    """``np.argsort(values, kind="stable")`` (see :func:`stable_argsort_into`), shape (n,) -> int64 (n,)."""
    order = np.empty(values.shape[0], dtype=np.int64)
    stable_argsort_into(values, order)
    return order


@njit(cache=True, no_cfunc_wrapper=True)
def stable_argsort_into(values, order):
    """``np.argsort(values, kind="stable")`` in O(n) for spread-out values: a bucket sort.

    Values go into n equal-width bins between their minimum and maximum (a counting sort, stable), the bin index
    being a non-decreasing function of the value, so that every out-of-order pair lies within one bin; one
    insertion pass over the whole array (stable) then sorts the bins, a bin of more than 32 values being
    merge-sorted first. The same permutation as numpy's stable sort.

    Parameters
    ----------
    values : ndarray, shape (n,)
        Finite float64 values.
    order : ndarray of int64, shape (n,)
        Output, written in place.
    """
    _bucket_argsort(values, order, np.empty(values.shape[0]))


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _bucket_argsort(values, order, keys):
    """:func:`stable_argsort_into` that also writes the sorted values into ``keys`` (float64, shape (n,)): the
    insertion pass compares them in place, contiguous, instead of through ``order``."""
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
    if not (scale < np.inf):  # a range so small (subnormal) its inverse overflows: one bin, merge-sorted below
        scale = 0.0
    start = np.zeros(n + 1, dtype=np.int64)
    bins = np.empty(n, dtype=np.int64)
    top = n - 1
    for i in range(n):
        b = int((values[i] - lo) * scale)
        if b > top:
            b = top
        bins[i] = b
        start[b + 1] += 1
    crowded = False
    c = 0
    for b in range(1, n + 1):  # counts to starts, a running sum
        m = start[b]
        crowded |= m > 32
        c += m
        start[b] = c
    for i in range(n):  # afterwards start[b] is the end of bin b
        b = bins[i]
        p = start[b]
        order[p] = i
        keys[p] = values[i]
        start[b] = p + 1
    if crowded:
        tmp = np.empty(n, dtype=np.int64)
        a = np.int64(0)  # not a literal 0, which typing would first see and compile _merge_argsort for too
        for b in range(n):
            e = start[b]
            if e - a > 32:
                _merge_argsort(values, order, a, e, tmp)
                for p in range(a, e):
                    keys[p] = values[order[p]]
            a = e
    for j in range(1, n):  # insertion; the bins being in value order, no value moves out of its bin
        v = keys[j]
        if keys[j - 1] > v:
            cur = order[j]
            i = j - 1
            while i >= 0 and keys[i] > v:
                order[i + 1] = order[i]
                keys[i + 1] = keys[i]
                i -= 1
            order[i + 1] = cur
            keys[i + 1] = v


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _insertion_argsort(values, order, a, e):
    """Stable insertion sort of ``order[a:e]`` by ``values[order]``."""
    for j in range(a + 1, e):
        cur = order[j]
        v = values[cur]
        i = j - 1
        while i >= a and values[order[i]] > v:
            order[i + 1] = order[i]
            i -= 1
        order[i + 1] = cur


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _merge_argsort(values, order, a, e, tmp):
    """Stable sort of ``order[a:e]`` by ``values[order]``: insertion-sorted runs of 16, merged bottom-up.

    ``tmp`` (int64, at least ``e`` long) is scratch. Stable, so the same permutation as numpy's stable sort.
    """
    run = 16
    for r in range(a, e, run):
        _insertion_argsort(values, order, r, min(r + run, e))
    width = run
    src, dst = order, tmp
    in_tmp = False
    while width < e - a:
        for lo in range(a, e, 2 * width):
            mid = min(lo + width, e)
            hi = min(lo + 2 * width, e)
            i, j = lo, mid
            for t in range(lo, hi):
                # the left element first on a tie: stable
                if i < mid and (j >= hi or not values[src[j]] < values[src[i]]):
                    dst[t] = src[i]
                    i += 1
                else:
                    dst[t] = src[j]
                    j += 1
        src, dst = dst, src
        in_tmp = not in_tmp
        width *= 2
    if in_tmp:
        for t in range(a, e):
            order[t] = src[t]


@njit(cache=True, no_cfunc_wrapper=True)
def partition_values(a, kth):
    """``np.partition(a, kth)`` for a 1-d array without NaN: a copy with the ``kth`` smallest value at ``kth``, none
    larger before it and none smaller after it (quickselect, median-of-three pivots; insertion below 16 values).

    The selected value is the sorted array's (``np.sort(a)[kth]``), in O(n) on average instead of a sort's O(n log n):
    a frame's quartile or an instant's median needs nothing else. The partitions are branch-free (Lomuto's scheme,
    each value swapped and the boundary advanced by the comparison's outcome), the values below the pivot first,
    then those equal to it: a branch on each comparison would be mispredicted about one time in two.

    Parameters
    ----------
    a : ndarray, shape (n,)
        float64 or int64 values, n >= 1.
    kth : int
        0 <= kth < n.

    Returns
    -------
    ndarray, shape (n,)
        The partitioned copy, same dtype.
    """
    s = a.copy()
    lo, hi = 0, s.shape[0]  # the values of ranks [lo, hi) are in s[lo:hi], those below before, those above after
    while hi - lo > 16:
        p0, p1, p2 = s[lo], s[(lo + hi) >> 1], s[hi - 1]
        x = max(min(p0, p1), min(max(p0, p1), p2))  # median of three: sorted or reversed runs are no worst case
        j = lo
        for i in range(lo, hi):
            v = s[i]
            s[i] = s[j]
            s[j] = v
            j += v < x
        if kth < j:
            hi = j  # the pivot itself is not below x: the range shrinks
            continue
        e = j
        for i in range(j, hi):  # the values equal to x (none below it remain) next
            v = s[i]
            s[i] = s[e]
            s[e] = v
            e += v <= x
        if kth < e:
            return s
        lo = e
    for j in range(lo + 1, hi):
        cur = s[j]
        i = j - 1
        while i >= lo and s[i] > cur:
            s[i + 1] = s[i]
            i -= 1
        s[i + 1] = cur
    return s


@njit(cache=True, no_cfunc_wrapper=True)
def median_value(a):
    """``np.median(a)`` of a 1-d float64 array without NaN (NaN when empty): the middle value, or the mean
    ``(lo + hi) / 2`` of the two middle values, as numpy computes it (selected by :func:`partition_values`)."""
    n = a.shape[0]
    if n == 0:
        return np.nan
    half = n >> 1
    s = partition_values(a, half)
    if n & 1 == 0:
        lo = s[0]  # the largest value before the middle one: the sorted array's s[half - 1]
        for i in range(1, half):
            if s[i] > lo:
                lo = s[i]
        return (lo + s[half]) / 2
    return s[half]


@njit(cache=True, no_cfunc_wrapper=True)
def search_sorted(a, x, right):
    """``np.searchsorted(a, x, side="right" if right else "left")`` for ascending ``a`` and a non-NaN ``x``.

    Parameters
    ----------
    a : ndarray, shape (n,)
        Ascending float64 values.
    x : float
    right : bool
        False: the number of values ``< x``; True: the number of values ``<= x``.

    Returns
    -------
    int
    """
    lo = 0
    hi = a.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] < x or (right and a[mid] == x):
            lo = mid + 1
        else:
            hi = mid
    return lo
