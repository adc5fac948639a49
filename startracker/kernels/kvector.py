"""k-vector kernel (Mortari 1997; paper 000 §3.1, eqs. 1-3), compiled, float64 arrays, no checks.

The checked API and the method's description are in :mod:`startracker.kvector`; this module builds the same table
in one compiled call for the tracker's per-frame DKVLUT (:mod:`startracker.kernels.track`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["kvector_build"]


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
        ``R``: ``values[order]`` ascending (stable: equal values keep their input order).
    sorted_values : ndarray, shape (n,)
        ``S``.
    k : ndarray of int64, shape (n,)
        ``k[i - 1]`` is the paper's ``K(i) = #{j : S[j] <= h(i)}``, with ``K(1) = 0`` and ``K(n) = n``.
    a1, b1 : float
        The line ``h(i) = a1 i + b1`` (1-based i) through ``(1, S[1] - D/2)`` and ``(n, S[n] + D/2)``.
    """
    n = values.shape[0]
    order = np.argsort(values, kind="mergesort")
    s = values[order]
    d = (s[n - 1] - s[0]) / (n - 1) if n > 1 else 0.0
    if d <= 0.0:
        d = max(1.0, abs(s[0])) * 1e-9  # all values equal: any positive spacing works
    a1 = n * d / (n - 1) if n > 1 else d
    b1 = s[0] - d / 2.0 - a1
    k = np.empty(n, dtype=np.int64)
    j = 0
    for i in range(n):
        h = a1 * (i + 1.0) + b1
        while j < n and s[j] <= h:
            j += 1
        k[i] = j
    k[0] = 0
    k[n - 1] = n
    return order, s, k, a1, b1
