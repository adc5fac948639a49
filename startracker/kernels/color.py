"""3CMOS kernels: pairing the centroids of two colour channels.

The checked API and the fusion it serves are in :mod:`startracker.color.fusion`. Coordinates are pixels of one
frame (the green channel's, after registration).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["mutual_nearest"]


@njit(cache=True, no_cfunc_wrapper=True)
def mutual_nearest(a, b, radius_px):
    """Index pairs (i into ``a``, j into ``b``) that are each other's nearest neighbour closer than ``radius_px``.

    Brute force over all pairs (a frame's channels hold tens of centroids); a tie goes to the lower index.

    Parameters
    ----------
    a : ndarray, shape (K, 2)
        Points, px.
    b : ndarray, shape (L, 2)
        Points, px.
    radius_px : float
        Pairs at this distance or farther are not neighbours, px.

    Returns
    -------
    i : ndarray of int64, shape (P,)
        Increasing indices into ``a``.
    j : ndarray of int64, shape (P,)
        Their partners in ``b``.
    """
    k = a.shape[0]
    m = b.shape[0]
    r2 = radius_px * radius_px
    best_a = np.full(k, -1, dtype=np.int64)
    best_a_d = np.full(k, np.inf)
    best_b = np.full(m, -1, dtype=np.int64)
    best_b_d = np.full(m, np.inf)
    for i in range(k):
        for j in range(m):
            dx = a[i, 0] - b[j, 0]
            dy = a[i, 1] - b[j, 1]
            d2 = dx * dx + dy * dy
            if d2 < r2:
                if d2 < best_a_d[i]:
                    best_a_d[i] = d2
                    best_a[i] = j
                if d2 < best_b_d[j]:
                    best_b_d[j] = d2
                    best_b[j] = i
    n = 0
    for i in range(k):
        j = best_a[i]
        if j >= 0 and best_b[j] == i:
            n += 1
    out_i = np.empty(n, dtype=np.int64)
    out_j = np.empty(n, dtype=np.int64)
    n = 0
    for i in range(k):
        j = best_a[i]
        if j >= 0 and best_b[j] == i:
            out_i[n] = i
            out_j[n] = j
            n += 1
    return out_i, out_j
