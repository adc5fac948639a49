"""Catalog kernel: the cone search over stars sorted by their ICRS z component (declination bands), compiled, no checks.

The checked API is :meth:`startracker.catalog.StarCatalog.cone_search`. A star within the angle ρ of a direction
at polar angle θ (``cos θ = d_z``) has ``z ∈ [cos(min(π, θ + ρ)), cos(max(0, θ − ρ))]``: two binary searches in
the sorted z values bound the band, and the chord test ``|v − d| <= 2 sin(ρ/2)`` decides inside it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.kvector import search_sorted, stable_argsort

__all__ = ["cone_search_sorted_z", "cone_search_angle"]


@njit(cache=True, no_cfunc_wrapper=True)
def cone_search_sorted_z(vectors_by_z, z_sorted, order, direction, radius_rad, chord_max):
    """Indices of the stars within ``radius_rad`` of ``direction``.

    Parameters
    ----------
    vectors_by_z : ndarray, shape (S, 3)
        Unit ICRS vectors of the catalog, sorted by z (``vectors[order]``).
    z_sorted : ndarray, shape (S,)
        ``vectors_by_z[:, 2]``, ascending.
    order : ndarray of int64, shape (S,)
        Catalog row of each sorted star.
    direction : ndarray, shape (3,)
        Unit direction, ICRS.
    radius_rad : float
        Cone half-angle, rad, in (0, π].
    chord_max : float
        Chord length accepted, ``2 sin(radius_rad / 2)`` (widened by the caller's tolerance).

    Returns
    -------
    ndarray of int64, shape (P,)
        Catalog rows, ascending.
    """
    theta = math.acos(min(1.0, max(-1.0, direction[2])))
    z_lo = math.cos(min(math.pi, theta + radius_rad)) - 1e-9
    z_hi = math.cos(max(0.0, theta - radius_rad)) + 1e-9
    # np.bool_: bools, not literals, as the other callers': the callee compiles once, not once per literal
    lo = search_sorted(z_sorted, z_lo, np.bool_(False))
    hi = search_sorted(z_sorted, z_hi, np.bool_(True))
    c2 = chord_max * chord_max
    key = np.empty(hi - lo)
    n = 0
    d0, d1, d2 = direction[0], direction[1], direction[2]
    for j in range(lo, hi):
        dx = vectors_by_z[j, 0] - d0
        dy = vectors_by_z[j, 1] - d1
        dz = vectors_by_z[j, 2] - d2
        # written always, kept when inside: no branch on a test that fails for most of the band
        key[n] = order[j]  # the row, exact as float64
        n += dx * dx + dy * dy + dz * dz <= c2
    # the rows ascending: distinct integers spread over the catalog, which the O(n) bucket sort orders with few
    # unpredictable branches (a heapsort mispredicts about one comparison in two)
    perm = stable_argsort(key[:n])
    rows = np.empty(n, dtype=np.int64)
    for j in range(n):
        rows[j] = int(key[perm[j]])
    return rows


@njit(cache=True, no_cfunc_wrapper=True)
def cone_search_angle(vectors_by_z, z_sorted, order, direction, radius_rad):
    """:func:`cone_search_sorted_z` with the chord of ``radius_rad`` widened by 1e-12 relative (what
    :meth:`startracker.catalog.StarCatalog.cone_search` accepts), and no star for an empty catalog.

    Parameters
    ----------
    vectors_by_z, z_sorted, order, direction, radius_rad
        As :func:`cone_search_sorted_z` (``radius_rad`` in (0, π]).

    Returns
    -------
    ndarray of int64, shape (P,)
        Catalog rows, ascending.
    """
    if order.shape[0] == 0:
        return np.empty(0, dtype=np.int64)
    chord = 2.0 * math.sin(radius_rad / 2.0) * (1 + 1e-12)
    return cone_search_sorted_z(vectors_by_z, z_sorted, order, direction, radius_rad, chord)
