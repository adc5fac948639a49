"""Rotation kernels: quaternions (w, x, y, z), matrices and rotation vectors on float64 arrays, no checks.

The checked API is :mod:`startracker.rotations`; its docstrings give each function's meaning. Here, arrays are
float64 of shape ``(..., 4)`` (quaternions, non-zero), ``(..., 3)`` (vectors, rotation vectors in rad) or
``(..., 3, 3)`` (rotation matrices), broadcast over leading axes. These are the hot path of the env (a few
quaternions per call); each reproduces scipy's ``Rotation`` arithmetic operation for operation (its Cython
kernels included: libm ``atan2`` per element, the x, y, z, w summation order of its norms), so results are bit for
bit those of scipy, which :mod:`startracker.rotations` uses for its one-off conversions.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "vector_norm",
    "cross",
    "canonical_sign",
    "quat_normalize",
    "quat_conjugate",
    "quat_multiply",
    "quat_to_matrix",
    "quat_rotate",
    "quat_from_rotvec",
    "quat_to_rotvec",
    "quat_integrate",
    "quat_angle_between",
    "quat_from_matrix",
    "quat_interpolate",
]

_CONJ = np.array([1.0, -1.0, -1.0, -1.0])
_EYE3 = np.eye(3)
_INV_XYZW = np.array([-1.0, -1.0, -1.0, 1.0])


def vector_norm(x: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """Euclidean norm over the last axis: ``np.linalg.norm(x, axis=-1)`` without its dispatch overhead (the same
    ufunc calls), shape ``x.shape[:-1]`` (``(..., 1)`` with ``keepdims``)."""
    return np.sqrt(np.add.reduce(x * x, axis=-1, keepdims=keepdims))


def canonical_sign(q: np.ndarray) -> np.ndarray:
    """q and -q are the same rotation: the one whose first non-zero component is positive; (..., 4) -> (..., 4).
    A shortcut serves the usual case of non-zero scalar parts (and returns ``q`` itself when nothing flips)."""
    w = q[..., 0]
    if (w != 0.0).all():
        neg = w < 0.0
        if not neg.any():
            return q  # callers pass arrays they just created: no copy needed
        return np.where(neg[..., None], -q, q)
    first = np.take_along_axis(q, np.argmax(q != 0.0, axis=-1)[..., None], axis=-1)
    return np.where(first < 0.0, -q, q)


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_normalize` for a float64 array of non-zero quaternions."""
    return canonical_sign(q / vector_norm(q, keepdims=True))


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate of (..., 4) quaternions (the inverse of a unit quaternion)."""
    return q * _CONJ


def quat_multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_multiply` for float64 arrays (broadcast over leading axes)."""
    w1, x1, y1, z1 = q1[..., 0], q1[..., 1], q1[..., 2], q1[..., 3]
    w2, x2, y2, z2 = q2[..., 0], q2[..., 1], q2[..., 2], q2[..., 3]
    out = np.empty(np.broadcast_shapes(q1.shape, q2.shape))
    out[..., 0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    out[..., 1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    out[..., 2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    out[..., 3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    return out


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_to_matrix` for a float64 (..., 4) array."""
    q = q / vector_norm(q, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - w * z)
    r[..., 0, 2] = 2 * (x * z + w * y)
    r[..., 1, 0] = 2 * (x * y + w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - w * x)
    r[..., 2, 0] = 2 * (x * z - w * y)
    r[..., 2, 1] = 2 * (y * z + w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_rotate` for float64 arrays."""
    return np.einsum("...ij,...j->...i", quat_to_matrix(q), v)


def _xyzw_normalized(q: np.ndarray) -> np.ndarray:
    """scipy's ``Rotation.from_quat`` normalisation of (w, x, y, z) rows, returned as (x, y, z, w) rows:
    ``sqrt(((x² + y²) + z²) + w²)`` in that order, as its Cython kernel sums."""
    xyzw = q[..., [1, 2, 3, 0]]
    s = xyzw * xyzw
    n = np.sqrt(((s[..., 0] + s[..., 1]) + s[..., 2]) + s[..., 3])
    return xyzw / n[..., None]


def _scipy_normalize_xyzw(xyzw: np.ndarray) -> np.ndarray:
    s = xyzw * xyzw
    n = np.sqrt(((s[..., 0] + s[..., 1]) + s[..., 2]) + s[..., 3])
    return xyzw / n[..., None]


def _scipy_compose_xyzw(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """scipy's ``_compose_quat_single`` (x, y, z, w), vectorised, then its normalisation."""
    p0, p1, p2, p3 = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    out[..., 0] = p3 * q0 + q3 * p0 + (p1 * q2 - p2 * q1)
    out[..., 1] = p3 * q1 + q3 * p1 + (p2 * q0 - p0 * q2)
    out[..., 2] = p3 * q2 + q3 * p2 + (p0 * q1 - p1 * q0)
    out[..., 3] = p3 * q3 - p0 * q0 - p1 * q1 - p2 * q2
    return _scipy_normalize_xyzw(out)


def _scipy_as_rotvec_xyzw(xyzw: np.ndarray) -> np.ndarray:
    """scipy's Cython ``as_rotvec`` for (n, 4) unit (x, y, z, w) rows (libm atan2/sin, element by element)."""
    out = []
    for x, y, z, w in xyzw.tolist():
        if w < 0 or (w == 0 and (x < 0 or (x == 0 and (y < 0 or (y == 0 and z < 0))))):
            x, y, z, w = -x, -y, -z, -w
        angle = 2 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
        if angle <= 1e-3:
            a2 = angle * angle
            scale = 2 + a2 / 12 + 7 * a2 * a2 / 2880
        else:
            scale = angle / math.sin(angle / 2)
        out.append((scale * x, scale * y, scale * z))
    return np.array(out, dtype=np.float64).reshape(len(out), 3)


def _scipy_from_rotvec_xyzw(rv: np.ndarray) -> np.ndarray:
    """scipy's ``from_rotvec`` (x, y, z, w), vectorised (its per-element formulas, numpy sin/cos)."""
    angle = vector_norm(rv, keepdims=True)
    small = angle <= 1e-3
    a2 = angle * angle
    scale = np.where(small, 0.5 - a2 / 48 + a2 * a2 / 3840, np.sin(angle / 2) / np.where(small, 1.0, angle))
    out = np.empty(rv.shape[:-1] + (4,))
    out[..., :3] = scale * rv
    out[..., 3:] = np.cos(angle / 2)
    return out


def _from_xyzw(xyzw: np.ndarray) -> np.ndarray:
    """:func:`from_scipy` on raw (x, y, z, w) rows."""
    return canonical_sign(xyzw[..., [3, 0, 1, 2]])


def quat_from_rotvec(rv: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_from_rotvec` for a float64 (..., 3) array."""
    return _from_xyzw(_scipy_from_rotvec_xyzw(rv))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_to_rotvec` for a float64 (..., 4) array of non-zero quaternions."""
    qn = quat_normalize(q)
    lead = qn.shape[:-1]
    return _scipy_as_rotvec_xyzw(_xyzw_normalized(qn.reshape(-1, 4))).reshape(lead + (3,))


def quat_integrate(q, omega_body, dt, alpha_body=None) -> np.ndarray:
    """:func:`startracker.rotations.quat_integrate` for float64 arrays."""
    dt = np.asarray(dt, dtype=np.float64)[..., None]
    rv = omega_body * dt
    if alpha_body is not None:
        rv = rv + 0.5 * alpha_body * dt**2
    return quat_normalize(quat_multiply(q, quat_from_rotvec(rv)))


def quat_angle_between(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_angle_between` for float64 arrays of non-zero quaternions."""
    q1 = quat_normalize(q1)
    q2 = quat_normalize(q2)
    d = np.abs(np.add.reduce(q1 * q2, axis=-1))
    dq = quat_multiply(q1 * _CONJ, q2)
    return 2.0 * np.arctan2(vector_norm(dq[..., 1:]), d)


# Shepperd's four branches as picks from the ten values (1-tr+2m00, 1-tr+2m11, 1-tr+2m22, m10+m01, m20+m02,
# m21+m12, m21-m12, m02-m20, m10-m01, 1+tr), already in (w, x, y, z) order; row = scipy's branch choice.
_SHEPPERD_WXYZ = np.array([[6, 0, 3, 4], [7, 3, 1, 5], [8, 4, 5, 2], [9, 6, 7, 8]])
_ORTHO_TOL = 1e-12 + 1e-5 * np.eye(3)  # np.isclose(gram, I, atol=1e-12) as scipy tests it


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """:func:`startracker.rotations.quat_from_matrix` for float64 (..., 3, 3) rotation matrices (scipy's checks and Shepperd's method,
    vectorised; matrices scipy would re-orthogonalise or reject go through scipy itself)."""
    lead = m.shape[:-2]
    mm = m.reshape(-1, 3, 3)
    gram = mm @ np.transpose(mm, (0, 2, 1))
    if not ((np.abs(gram - _EYE3) <= _ORTHO_TOL).all() and (np.linalg.det(mm) > 0.0).all()):
        # scipy re-orthogonalises (or rejects) such matrices: let it
        return canonical_sign(Rotation.from_matrix(mm).as_quat()[:, [3, 0, 1, 2]]).reshape(lead + (4,))
    f = mm.reshape(-1, 9)
    diag = f[:, [0, 4, 8]]
    tr = f[:, 0] + f[:, 4] + f[:, 8]
    choice = np.argmax(np.concatenate([diag, tr[:, None]], axis=1), axis=1)
    vals = np.concatenate(
        [(1 - tr)[:, None] + 2 * diag, f[:, [3, 6, 7]] + f[:, [1, 2, 5]], f[:, [7, 2, 3]] - f[:, [5, 6, 1]], (1 + tr)[:, None]],
        axis=1,
    )
    q = vals[np.arange(len(vals))[:, None], _SHEPPERD_WXYZ[choice]]  # (w, x, y, z)
    s2 = q * q
    q = q / np.sqrt(((s2[:, 1] + s2[:, 2]) + s2[:, 3]) + s2[:, 0])[:, None]  # scipy's x, y, z, w summation order
    return canonical_sign(q).reshape(lead + (4,))



def quat_interpolate(t: np.ndarray, q: np.ndarray, tq) -> np.ndarray:
    """:func:`startracker.rotations.quat_interpolate` for a valid history (float64, strictly increasing ``t``, ``tq`` inside it):
    scipy's ``Slerp`` arithmetic, with the interval rotation vectors computed only for the intervals used."""
    tq = np.asarray(tq, dtype=np.float64)
    scalar = tq.ndim == 0
    tq = np.minimum(np.maximum(tq.reshape(-1), t[0]), t[-1])  # np.clip
    ind = np.searchsorted(t, tq) - 1
    ind[tq == t[0]] = 0
    lo, hi = int(ind.min()), int(ind.max())
    xyzw = _xyzw_normalized(q[lo : hi + 2])
    p = xyzw[:-1]
    delta = _scipy_as_rotvec_xyzw(_scipy_compose_xyzw(p * _INV_XYZW, xyzw[1:]))
    k = ind - lo
    alpha = (tq - t[ind]) / (t[ind + 1] - t[ind])
    out = _from_xyzw(_scipy_compose_xyzw(p[k], _scipy_from_rotvec_xyzw(delta[k] * alpha[:, None])))
    return out[0] if scalar else out


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` over the last axis (length 3): the same products and differences without its overhead."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out
