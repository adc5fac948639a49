"""Fixed-size algebra shared by the compiled kernels: 3×3 determinants and inverses, quaternion products and
normalisation, rotation matrix ↔ quaternion; compiled, no checks.

Quaternions are (w, x, y, z); "canonical" means the first non-zero component is positive. The identification,
attitude and tracking kernels all call these (numba inlines nothing across modules by itself, but a compiled
function calls another module's compiled function directly, without Python in between).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "det3_entries",
    "det3",
    "inv_transpose3",
    "quat_multiply_into",
    "quat_normalize_canonical",
    "quat_to_rotation",
    "quat_from_rotation",
    "mahalanobis3",
]


@njit(cache=True, no_cfunc_wrapper=True)
def det3_entries(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """Determinant of the 3×3 matrix of the nine entries (row-major), by the first row's cofactors."""
    return a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)


@njit(cache=True, no_cfunc_wrapper=True)
def det3(m):
    """Determinant of a 3×3 matrix ``m`` (shape (3, 3))."""
    return det3_entries(m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1], m[2, 2])


@njit(cache=True, no_cfunc_wrapper=True)
def inv_transpose3(m, d):
    """Inverse transpose of a 3×3 matrix with determinant ``d`` (the cofactor matrix over ``d``), shape (3, 3)."""
    c = np.empty((3, 3))
    c[0, 0] = (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) / d
    c[0, 1] = (m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]) / d
    c[0, 2] = (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]) / d
    c[1, 0] = (m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]) / d
    c[1, 1] = (m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]) / d
    c[1, 2] = (m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]) / d
    c[2, 0] = (m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]) / d
    c[2, 1] = (m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]) / d
    c[2, 2] = (m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]) / d
    return c


@njit(cache=True, no_cfunc_wrapper=True)
def quat_multiply_into(a, b, out):
    """Hamilton product ``a ⊗ b`` of two (4,) quaternions, written into ``out`` (4,) (not aliasing ``a``, ``b``)."""
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@njit(cache=True, no_cfunc_wrapper=True)
def quat_normalize_canonical(q):
    """Scale the (4,) quaternion ``q`` in place to unit norm, canonical sign."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = 1.0
    for i in range(4):
        if q[i] != 0.0:
            sign = 1.0 if q[i] > 0.0 else -1.0
            break
    for i in range(4):
        q[i] = sign * q[i] / n


@njit(cache=True, no_cfunc_wrapper=True)
def quat_to_rotation(q, m):
    """Rotation matrix ``m`` (3, 3, written in place) of the (4,) quaternion ``q``, normalised first."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    m[0, 0] = 1 - 2 * (y * y + z * z)
    m[0, 1] = 2 * (x * y - w * z)
    m[0, 2] = 2 * (x * z + w * y)
    m[1, 0] = 2 * (x * y + w * z)
    m[1, 1] = 1 - 2 * (x * x + z * z)
    m[1, 2] = 2 * (y * z - w * x)
    m[2, 0] = 2 * (x * z - w * y)
    m[2, 1] = 2 * (y * z + w * x)
    m[2, 2] = 1 - 2 * (x * x + y * y)


@njit(cache=True, no_cfunc_wrapper=True)
def quat_from_rotation(m):
    """Unit canonical quaternion of a proper rotation matrix (Shepperd's method).

    Parameters
    ----------
    m : ndarray, shape (3, 3)

    Returns
    -------
    ndarray, shape (4,)
    """
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    big = max(max(tr, m[0, 0]), max(m[1, 1], m[2, 2]))
    q = np.empty(4)
    if big == tr:
        s = 2.0 * math.sqrt(1.0 + tr)
        q[0], q[1], q[2], q[3] = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif big == m[0, 0]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q[0], q[1], q[2], q[3] = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif big == m[1, 1]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q[0], q[1], q[2], q[3] = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q[0], q[1], q[2], q[3] = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        q[i] /= nq
    for i in range(4):
        if q[i] != 0.0:
            if q[i] < 0:
                for j in range(4):
                    q[j] = -q[j]
            break
    return q


@njit(cache=True, no_cfunc_wrapper=True)
def mahalanobis3(s, d0, d1, d2):
    """``dᵀ S⁻¹ d`` for a symmetric (3, 3) ``s`` and the vector (d0, d1, d2), by Cholesky ``S = L Lᵀ`` (then
    ``|L⁻¹ d|²``); ``inf`` when ``s`` is not positive definite."""
    a00 = s[0, 0]
    if not a00 > 0.0:
        return math.inf
    l00 = math.sqrt(a00)
    l10 = s[1, 0] / l00
    l20 = s[2, 0] / l00
    a11 = s[1, 1] - l10 * l10
    if not a11 > 0.0:
        return math.inf
    l11 = math.sqrt(a11)
    l21 = (s[2, 1] - l20 * l10) / l11
    a22 = s[2, 2] - l20 * l20 - l21 * l21
    if not a22 > 0.0:
        return math.inf
    l22 = math.sqrt(a22)
    u0 = d0 / l00
    u1 = (d1 - l10 * u0) / l11
    u2 = (d2 - l20 * u0 - l21 * u1) / l22
    return u0 * u0 + u1 * u1 + u2 * u2
