"""Rotation kernels: quaternions (w, x, y, z), matrices and rotation vectors on float64 arrays, no checks.

The checked API is :mod:`startracker.rotations`; its docstrings give each function's meaning. Here, arrays are
float64 of shape ``(..., 4)`` (quaternions, non-zero), ``(..., 3)`` (vectors, rotation vectors in rad) or
``(..., 3, 3)`` (rotation matrices), broadcast over leading axes. Each public function reshapes its arguments to
rows and calls one numba-compiled loop (``@njit(cache=True)``), so a call costs about a microsecond whatever the
number of quaternions: these are the small, frequent operations of the env's per-frame glue.

Results are canonical: a quaternion and its negative are the same rotation, and every quaternion returned has its
first non-zero component positive (``w >= 0`` in practice).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from startracker.kernels.kvector import search_sorted

__all__ = [
    "vector_norm",
    "cross",
    "canonical_sign",
    "quat_normalize",
    "quat_conjugate",
    "quat_multiply",
    "quat_relative_rotvec",
    "relative_rotvec_rows",
    "interval_rates_rows",
    "normalize_rows",
    "interpolate_rows",
    "angle_between_rows",
    "pointing_errors",
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


# ------------------------------------------------------------------------------------ compiled row loops
@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _canon_into(q, out, k):
    """Write q (4,) into out[k] with its first non-zero component positive."""
    s = 1.0
    for i in range(4):
        if q[i] != 0.0:
            s = 1.0 if q[i] > 0.0 else -1.0
            break
    for i in range(4):
        out[k, i] = s * q[i]


@njit(cache=True, no_cfunc_wrapper=True)
def normalize_rows(q):
    """Unit canonical quaternions, row by row (first non-zero component positive).

    Parameters
    ----------
    q : ndarray, shape (n, 4)
        Quaternions (w, x, y, z), float64, C-contiguous, none zero.

    Returns
    -------
    ndarray, shape (n, 4)
        Each row divided by its norm, its sign chosen so that its first non-zero component is positive.
    """
    n = q.shape[0]
    out = np.empty((n, 4))
    tmp = np.empty(4)
    for k in range(n):
        s = math.sqrt(q[k, 0] ** 2 + q[k, 1] ** 2 + q[k, 2] ** 2 + q[k, 3] ** 2)
        for i in range(4):
            tmp[i] = q[k, i] / s
        _canon_into(tmp, out, k)
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def _canon_rows(q):
    n = q.shape[0]
    out = np.empty((n, 4))
    for k in range(n):
        _canon_into(q[k], out, k)
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def _multiply_rows(a, b):
    n = a.shape[0]
    out = np.empty((n, 4))
    for k in range(n):
        w1, x1, y1, z1 = a[k, 0], a[k, 1], a[k, 2], a[k, 3]
        w2, x2, y2, z2 = b[k, 0], b[k, 1], b[k, 2], b[k, 3]
        out[k, 0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
        out[k, 1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
        out[k, 2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
        out[k, 3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def _to_matrix_rows(q):
    n = q.shape[0]
    r = np.empty((n, 3, 3))
    for k in range(n):
        s = math.sqrt(q[k, 0] ** 2 + q[k, 1] ** 2 + q[k, 2] ** 2 + q[k, 3] ** 2)
        w, x, y, z = q[k, 0] / s, q[k, 1] / s, q[k, 2] / s, q[k, 3] / s
        r[k, 0, 0] = 1 - 2 * (y * y + z * z)
        r[k, 0, 1] = 2 * (x * y - w * z)
        r[k, 0, 2] = 2 * (x * z + w * y)
        r[k, 1, 0] = 2 * (x * y + w * z)
        r[k, 1, 1] = 1 - 2 * (x * x + z * z)
        r[k, 1, 2] = 2 * (y * z - w * x)
        r[k, 2, 0] = 2 * (x * z - w * y)
        r[k, 2, 1] = 2 * (y * z + w * x)
        r[k, 2, 2] = 1 - 2 * (x * x + y * y)
    return r


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _exp_into(rx, ry, rz, out, k):
    """Unit quaternion of the rotation vector (rx, ry, rz) rad into out[k], canonical sign."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle <= 1e-3:  # Taylor series of sin(a/2)/a: no division by a tiny angle
        a2 = angle * angle
        scale = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        scale = math.sin(0.5 * angle) / angle
    w = math.cos(0.5 * angle)
    s = -1.0 if (w < 0.0 or (w == 0.0 and (rx < 0.0 or (rx == 0.0 and (ry < 0.0 or (ry == 0.0 and rz < 0.0)))))) else 1.0
    out[k, 0] = s * w
    out[k, 1] = s * scale * rx
    out[k, 2] = s * scale * ry
    out[k, 3] = s * scale * rz


@njit(cache=True, no_cfunc_wrapper=True)
def _from_rotvec_rows(rv):
    n = rv.shape[0]
    out = np.empty((n, 4))
    for k in range(n):
        _exp_into(rv[k, 0], rv[k, 1], rv[k, 2], out, k)
    return out


@njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
def _log_into(w, x, y, z, out, k):
    """Rotation vector (angle in [0, π]) of the unit quaternion (w, x, y, z) into out[k]."""
    if w < 0.0 or (w == 0.0 and (x < 0.0 or (x == 0.0 and (y < 0.0 or (y == 0.0 and z < 0.0))))):
        w, x, y, z = -w, -x, -y, -z
    v = math.sqrt(x * x + y * y + z * z)
    angle = 2.0 * math.atan2(v, w)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0
    else:
        scale = angle / math.sin(0.5 * angle)
    out[k, 0] = scale * x
    out[k, 1] = scale * y
    out[k, 2] = scale * z


@njit(cache=True, no_cfunc_wrapper=True)
def _to_rotvec_rows(q):
    n = q.shape[0]
    out = np.empty((n, 3))
    for k in range(n):
        s = math.sqrt(q[k, 0] ** 2 + q[k, 1] ** 2 + q[k, 2] ** 2 + q[k, 3] ** 2)
        _log_into(q[k, 0] / s, q[k, 1] / s, q[k, 2] / s, q[k, 3] / s, out, k)
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def relative_rotvec_rows(a, b):
    """Rotation vector (n, 3), rad, angle in [0, π], of ``conj(a[k]) ⊗ b[k]`` for (n, 4) non-zero quaternions
    ``a``, ``b`` (the body-frame rotation from attitude ``a`` to ``b``): conjugate, product, normalisation and log
    in turn."""
    n = a.shape[0]
    out = np.empty((n, 3))
    for k in range(n):
        w1, x1, y1, z1 = a[k, 0], -a[k, 1], -a[k, 2], -a[k, 3]
        w2, x2, y2, z2 = b[k, 0], b[k, 1], b[k, 2], b[k, 3]
        w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
        x = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
        y = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
        z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
        s = math.sqrt(w**2 + x**2 + y**2 + z**2)
        _log_into(w / s, x / s, y / s, z / s, out, k)
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def angle_between_rows(a, b):
    """Rotation angle between two attitudes, row by row.

    Parameters
    ----------
    a, b : ndarray, shape (n, 4)
        Quaternions (w, x, y, z), float64, C-contiguous (normalised here).

    Returns
    -------
    ndarray, shape (n,)
        Angle of ``a⁻¹ b``, rad, in [0, π].
    """
    n = a.shape[0]
    out = np.empty(n)
    for k in range(n):
        sa = math.sqrt(a[k, 0] ** 2 + a[k, 1] ** 2 + a[k, 2] ** 2 + a[k, 3] ** 2)
        sb = math.sqrt(b[k, 0] ** 2 + b[k, 1] ** 2 + b[k, 2] ** 2 + b[k, 3] ** 2)
        w1, x1, y1, z1 = a[k, 0] / sa, -a[k, 1] / sa, -a[k, 2] / sa, -a[k, 3] / sa  # conjugate of a
        w2, x2, y2, z2 = b[k, 0] / sb, b[k, 1] / sb, b[k, 2] / sb, b[k, 3] / sb
        dw = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
        dx = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
        dy = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
        dz = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
        # 2 atan2(|vector part|, |scalar part|) stays accurate for small angles, unlike 2 acos
        out[k] = 2.0 * math.atan2(math.sqrt(dx * dx + dy * dy + dz * dz), abs(dw))
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def pointing_errors(q_true, q_est, q_target):
    """An env step's attitude figures in one call: :func:`angle_between_rows` and :func:`relative_rotvec_rows` on
    one row each.

    Parameters
    ----------
    q_true, q_est, q_target : ndarray, shape (4,)
        True, estimated and target body-to-ICRS quaternions (w, x, y, z), float64, C-contiguous, non-zero.

    Returns
    -------
    ndarray, shape (8,)
        ``[0]`` the pointing error, angle of ``q_true⁻¹ q_target`` (rad); ``[1]`` the estimation error, angle of
        ``q_true⁻¹ q_est`` (rad); ``[2:5]`` the rotation vector of ``q_est⁻¹ q_target`` (rad, body frame: the error
        the controller sees); ``[5:8]`` that of ``q_est⁻¹ q_true`` (rad: the estimate's error, for its NEES).
    """
    t = q_true.reshape(1, 4)
    e = q_est.reshape(1, 4)
    g = q_target.reshape(1, 4)
    out = np.empty(8)
    out[0] = angle_between_rows(t, g)[0]
    out[1] = angle_between_rows(t, e)[0]
    r = relative_rotvec_rows(e, g)
    d = relative_rotvec_rows(e, t)
    for i in range(3):
        out[2 + i] = r[0, i]
        out[5 + i] = d[0, i]
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def _integrate_rows(q, rv):
    """q (n, 4) unit, rv (n, 3) body-frame rotation vectors: normalize(q ⊗ exp(rv))."""
    n = q.shape[0]
    dq = _from_rotvec_rows(rv)
    out = _multiply_rows(q, dq)
    return normalize_rows(out)


@njit(cache=True, no_cfunc_wrapper=True)
def _from_matrix_rows(m):
    """Shepperd's method (the largest of the four squared components picks the branch)."""
    n = m.shape[0]
    out = np.empty((n, 4))
    tmp = np.empty(4)
    for k in range(n):
        a = m[k]
        tr = a[0, 0] + a[1, 1] + a[2, 2]
        if tr >= a[0, 0] and tr >= a[1, 1] and tr >= a[2, 2]:
            tmp[0] = 1.0 + tr
            tmp[1] = a[2, 1] - a[1, 2]
            tmp[2] = a[0, 2] - a[2, 0]
            tmp[3] = a[1, 0] - a[0, 1]
        elif a[0, 0] >= a[1, 1] and a[0, 0] >= a[2, 2]:
            tmp[0] = a[2, 1] - a[1, 2]
            tmp[1] = 1.0 - tr + 2.0 * a[0, 0]
            tmp[2] = a[1, 0] + a[0, 1]
            tmp[3] = a[2, 0] + a[0, 2]
        elif a[1, 1] >= a[2, 2]:
            tmp[0] = a[0, 2] - a[2, 0]
            tmp[1] = a[1, 0] + a[0, 1]
            tmp[2] = 1.0 - tr + 2.0 * a[1, 1]
            tmp[3] = a[2, 1] + a[1, 2]
        else:
            tmp[0] = a[1, 0] - a[0, 1]
            tmp[1] = a[2, 0] + a[0, 2]
            tmp[2] = a[2, 1] + a[1, 2]
            tmp[3] = 1.0 - tr + 2.0 * a[2, 2]
        s = math.sqrt(tmp[0] ** 2 + tmp[1] ** 2 + tmp[2] ** 2 + tmp[3] ** 2)
        for i in range(4):
            tmp[i] /= s
        _canon_into(tmp, out, k)
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def interpolate_rows(t, q, tq):
    """Slerp of an attitude history at other instants, clipped to its span.

    On each interval the rotation ``a⁻¹ b`` is scaled along its own axis, the shortest way round.

    Parameters
    ----------
    t : ndarray, shape (S,)
        Increasing instants of the history, s.
    q : ndarray, shape (S, 4)
        Unit quaternions (w, x, y, z) at ``t``.
    tq : ndarray, shape (Q,)
        Query instants, s (clipped to ``[t[0], t[-1]]``).

    Returns
    -------
    ndarray, shape (Q, 4)
        Interpolated unit quaternions.
    """
    nq = tq.shape[0]
    s = t.shape[0]
    out = np.empty((nq, 4))
    rv = np.empty((1, 3))
    step = np.empty((1, 4))
    row0 = np.int64(0)  # an int64, not a literal 0: the callees compile once, as for the other callers
    for k in range(nq):
        x = min(max(tq[k], t[0]), t[s - 1])
        i = search_sorted(t, x, np.bool_(False)) - 1  # a bool, not a literal (one compiled signature)
        if i < 0:
            i = 0
        if i > s - 2:
            i = s - 2
        alpha = (x - t[i]) / (t[i + 1] - t[i])
        aw, ax, ay, az = q[i, 0], -q[i, 1], -q[i, 2], -q[i, 3]  # a⁻¹ of the unit a
        bw, bx, by, bz = q[i + 1, 0], q[i + 1, 1], q[i + 1, 2], q[i + 1, 3]
        dw = aw * bw - ax * bx - ay * by - az * bz
        dx = aw * bx + ax * bw + ay * bz - az * by
        dy = aw * by - ax * bz + ay * bw + az * bx
        dz = aw * bz + ax * by - ay * bx + az * bw
        _log_into(dw, dx, dy, dz, rv, row0)
        _exp_into(alpha * rv[0, 0], alpha * rv[0, 1], alpha * rv[0, 2], step, row0)
        w1, x1, y1, z1 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        w2, x2, y2, z2 = step[0, 0], step[0, 1], step[0, 2], step[0, 3]
        tmp = np.empty(4)
        tmp[0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
        tmp[1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
        tmp[2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
        tmp[3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
        _canon_into(tmp, out, k)
    return out


@njit(cache=True, no_cfunc_wrapper=True)
def interval_rates_rows(t, q):
    """Mean body rate (n - 1, 3), rad/s, over each interval of an attitude history ``t`` (n,) s, ``q`` (n, 4)
    non-zero: the rotation vector of ``conj(q[k]) ⊗ q[k + 1]`` (:func:`relative_rotvec_rows`) over
    ``t[k + 1] - t[k]``, divided as numpy divides (the gyro's true rates of :meth:`startracker.onboard.StarTrackerUnit.observe`)."""
    rv = relative_rotvec_rows(q[:-1], q[1:])
    for k in range(rv.shape[0]):
        dt = t[k + 1] - t[k]
        rv[k, 0] = rv[k, 0] / dt
        rv[k, 1] = rv[k, 1] / dt
        rv[k, 2] = rv[k, 2] / dt
    return rv



# ---------------------------------------------------------------------------------------- public kernels
def _rows(a: np.ndarray, width: int) -> np.ndarray:
    r = np.ascontiguousarray(a, dtype=np.float64).reshape(-1, width)
    # a read-only array (a frozen constant, a broadcast view) is another numba type: a copy keeps one compilation
    return r if r.flags.writeable else r.copy()


def vector_norm(x: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """Euclidean norm over the last axis, shape ``x.shape[:-1]`` (``(..., 1)`` with ``keepdims``)."""
    return np.sqrt(np.add.reduce(x * x, axis=-1, keepdims=keepdims))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (length 3), broadcast over leading axes."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def canonical_sign(q: np.ndarray) -> np.ndarray:
    """q or -q, whichever has its first non-zero component positive; (..., 4) -> (..., 4)."""
    return _canon_rows(_rows(q, 4)).reshape(np.shape(q))


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit, canonical quaternions of non-zero (..., 4) quaternions."""
    return normalize_rows(_rows(q, 4)).reshape(np.shape(q))


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate of (..., 4) quaternions (the inverse of a unit quaternion)."""
    return q * _CONJ


def _pair_rows(q1: np.ndarray, q2: np.ndarray):
    """Two broadcastable (..., 4) arrays as row arrays of one length, and the broadcast shape."""
    s1, s2 = np.shape(q1), np.shape(q2)
    if s1 == s2:  # the usual case: no broadcasting machinery
        return _rows(q1, 4), _rows(q2, 4), s1
    shape = np.broadcast_shapes(s1, s2)
    return _rows(np.broadcast_to(q1, shape), 4), _rows(np.broadcast_to(q2, shape), 4), shape


def quat_multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product ``q1 ⊗ q2`` of broadcastable (..., 4) quaternions (not renormalised)."""
    a, b, shape = _pair_rows(q1, q2)
    return _multiply_rows(a, b).reshape(shape)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of non-zero (..., 4) quaternions (normalised first)."""
    return _to_matrix_rows(_rows(q, 4)).reshape(np.shape(q)[:-1] + (3, 3))


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R(q) @ v`` broadcast over leading axes: q (..., 4), v (..., 3) -> (..., 3)."""
    return np.einsum("...ij,...j->...i", quat_to_matrix(q), v)


def quat_from_rotvec(rv: np.ndarray) -> np.ndarray:
    """Unit canonical quaternions (..., 4) of rotation vectors (..., 3), rad."""
    return _from_rotvec_rows(_rows(rv, 3)).reshape(np.shape(rv)[:-1] + (4,))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), rad, angle in [0, π], of non-zero (..., 4) quaternions."""
    return _to_rotvec_rows(_rows(q, 4)).reshape(np.shape(q)[:-1] + (3,))


def quat_relative_rotvec(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Rotation vector (..., 3), rad, of ``conj(q1) ⊗ q2`` (the body-frame rotation from attitude ``q1`` to ``q2``):
    ``quat_to_rotvec(quat_multiply(quat_conjugate(q1), q2))`` bit for bit, in one compiled pass."""
    a, b, shape = _pair_rows(q1, q2)
    return relative_rotvec_rows(a, b).reshape(shape[:-1] + (3,))


def quat_integrate(q, omega_body, dt, alpha_body=None) -> np.ndarray:
    """Attitude ``q ⊗ exp(ω dt + α dt²/2)`` (body-frame increment), unit and canonical.

    ``q`` (4,) or (..., 4); ``omega_body``, ``alpha_body`` (3,) rad/s and rad/s²; ``dt`` s, scalar or an array
    broadcast against the leading shape. Returns (..., 4).
    """
    dt = np.asarray(dt, dtype=np.float64)[..., None]
    rv = omega_body * dt
    if alpha_body is not None:
        rv = rv + 0.5 * alpha_body * dt**2
    shape = np.broadcast_shapes(np.shape(q)[:-1], rv.shape[:-1])
    qq = np.broadcast_to(q, shape + (4,))
    rr = np.broadcast_to(rv, shape + (3,))
    return _integrate_rows(_rows(qq, 4), _rows(rr, 3)).reshape(shape + (4,))


def quat_angle_between(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, π]) of the rotation taking attitude ``q1`` to ``q2``; sign-invariant, shape (...)."""
    a, b, shape = _pair_rows(q1, q2)
    return angle_between_rows(a, b).reshape(shape[:-1])


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit canonical quaternions (..., 4) of rotation matrices (..., 3, 3) (orthonormal, det +1: Shepperd)."""
    mm = np.ascontiguousarray(m, dtype=np.float64).reshape(-1, 3, 3)
    return _from_matrix_rows(mm).reshape(np.shape(m)[:-2] + (4,))


def quat_interpolate(t: np.ndarray, q: np.ndarray, tq) -> np.ndarray:
    """Spherical-linear interpolation of the history ``t`` (S,) s strictly increasing, ``q`` (S, 4) non-zero, at
    ``tq`` (scalar or (Q,), clipped to ``[t[0], t[-1]]``); (4,) or (Q, 4), unit and canonical."""
    tq_arr = np.asarray(tq, dtype=np.float64)
    q_unit = normalize_rows(_rows(q, 4))
    out = interpolate_rows(np.ascontiguousarray(t, dtype=np.float64), q_unit, tq_arr.reshape(-1))
    return out[0] if tq_arr.ndim == 0 else out
