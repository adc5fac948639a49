"""Quaternions (w, x, y, z), rotation matrices and rotation vectors.

Convention (shared/DESIGN.md §2): scalar first, Hamilton product, unit norm. ``q_a_to_b`` maps the
coordinates of a vector in frame a to frame b, ``v_b = R(q_a_to_b) @ v_a``. Composition:
``q_a_to_c = quat_multiply(q_b_to_c, q_a_to_b)``.

This is the only module that talks to :class:`scipy.spatial.transform.Rotation`, which is scalar-last.
Every function is vectorised over leading axes: a quaternion array has shape ``(..., 4)``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "as_float_array",
    "quat_normalize",
    "quat_multiply",
    "quat_conjugate",
    "quat_to_matrix",
    "quat_from_matrix",
    "quat_to_rotvec",
    "quat_from_rotvec",
    "quat_angle_between",
    "quat_rotate",
    "quat_random",
    "quat_integrate",
    "quat_interpolate",
    "to_scipy",
    "from_scipy",
    "skew",
]


def as_float_array(a, name: str, last_dim: int | None = None, ndim: int | None = None) -> np.ndarray:
    """Convert ``a`` to a finite float64 array, raising a ``ValueError`` that names ``name``.

    Parameters
    ----------
    a : array_like
    name : str
        Argument name used in error messages.
    last_dim : int, optional
        Required size of the last axis.
    ndim : int, optional
        Required number of dimensions.
    """
    if isinstance(a, (str, bytes)):
        raise TypeError(f"{name} must be a numeric array, got {type(a).__name__}")
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a numeric array: {exc}") from None
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimension(s), got shape {arr.shape}")
    if last_dim is not None and (arr.ndim == 0 or arr.shape[-1] != last_dim):
        raise ValueError(f"{name} must have last dimension {last_dim}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def quat_normalize(q) -> np.ndarray:
    """Unit-normalise quaternions and fix the sign so that ``w >= 0`` (first non-zero component > 0).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternions (w, x, y, z), any non-zero norm.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternions with non-negative scalar part (the same rotation).
    """
    q = as_float_array(q, "q", last_dim=4)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("q contains a zero quaternion, which is not a rotation")
    return _canonical_sign(q / n)


def _canonical_sign(q: np.ndarray) -> np.ndarray:
    """q and -q are the same rotation: pick the one whose first non-zero component is positive."""
    first = np.take_along_axis(q, np.argmax(q != 0.0, axis=-1)[..., None], axis=-1)
    return np.where(first < 0.0, -q, q)


def quat_multiply(q1, q2) -> np.ndarray:
    """Hamilton product ``q1 ⊗ q2`` (apply q2 first, then q1).

    Parameters
    ----------
    q1, q2 : array_like, shape (..., 4)
        Broadcastable quaternion arrays (w, x, y, z).

    Returns
    -------
    ndarray, shape (..., 4)
    """
    q1 = np.asarray(q1, dtype=np.float64)
    q2 = np.asarray(q2, dtype=np.float64)
    w1, x1, y1, z1 = np.moveaxis(q1, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q2, -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quat_conjugate(q) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion), shape (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def to_scipy(q) -> Rotation:
    """scipy ``Rotation`` from (..., 4) scalar-first quaternions."""
    q = as_float_array(q, "q", last_dim=4)
    return Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]] if q.ndim > 1 else q[[1, 2, 3, 0]])


def from_scipy(rot: Rotation) -> np.ndarray:
    """Scalar-first unit quaternion(s) with ``w >= 0`` from a scipy ``Rotation``."""
    xyzw = rot.as_quat()
    return _canonical_sign(xyzw[..., [3, 0, 1, 2]])


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrices ``R(q)``, shape (..., 3, 3), with ``v_b = R @ v_a`` for ``q_a_to_b``."""
    return _quat_to_matrix_unchecked(as_float_array(q, "q", last_dim=4))


def quat_from_matrix(matrix) -> np.ndarray:
    """Quaternions (..., 4) from rotation matrices (..., 3, 3); scipy's robust (Shepperd) method."""
    m = as_float_array(matrix, "matrix")
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"matrix must have shape (..., 3, 3), got {m.shape}")
    lead = m.shape[:-2]
    q = from_scipy(Rotation.from_matrix(m.reshape(-1, 3, 3)))
    return q.reshape(lead + (4,))


def quat_to_rotvec(q) -> np.ndarray:
    """Rotation vectors (axis × angle, rad), shape (..., 3), angle in [0, π]."""
    q = quat_normalize(q)
    lead = q.shape[:-1]
    return to_scipy(q.reshape(-1, 4)).as_rotvec().reshape(lead + (3,))


def quat_from_rotvec(rotvec) -> np.ndarray:
    """Unit quaternions (..., 4) from rotation vectors (..., 3) in rad."""
    rv = as_float_array(rotvec, "rotvec", last_dim=3)
    lead = rv.shape[:-1]
    return from_scipy(Rotation.from_rotvec(rv.reshape(-1, 3))).reshape(lead + (4,))


def quat_angle_between(q1, q2) -> np.ndarray:
    """Angle (rad, in [0, π]) of the rotation taking attitude ``q1`` to ``q2``; sign-invariant."""
    q1 = quat_normalize(q1)
    q2 = quat_normalize(q2)
    d = np.abs(np.sum(q1 * q2, axis=-1))
    # 2*atan2(|vector part of q1* q2|, |dot|) is accurate for small angles, unlike 2*acos(dot).
    dq = quat_multiply(quat_conjugate(q1), q2)
    return 2.0 * np.arctan2(np.linalg.norm(dq[..., 1:], axis=-1), d)


def quat_rotate(q, v) -> np.ndarray:
    """Rotate vectors: ``R(q) @ v`` broadcast over leading axes.

    Parameters
    ----------
    q : array_like, shape (4,) or (..., 4)
    v : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3)
    """
    r = quat_to_matrix(q)
    v = np.asarray(v, dtype=np.float64)
    return np.einsum("...ij,...j->...i", r, v)


def quat_random(rng: np.random.Generator, size: int | None = None) -> np.ndarray:
    """Uniformly distributed random unit quaternions (Shoemake), shape (4,) or (size, 4), ``w >= 0``."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    n = 1 if size is None else int(size)
    u1, u2, u3 = rng.random((3, n))
    q = np.stack(
        [
            np.sqrt(u1) * np.cos(2 * np.pi * u3),
            np.sqrt(1 - u1) * np.sin(2 * np.pi * u2),
            np.sqrt(1 - u1) * np.cos(2 * np.pi * u2),
            np.sqrt(u1) * np.sin(2 * np.pi * u3),
        ],
        axis=-1,
    )
    q = _canonical_sign(q)
    return q[0] if size is None else q


def quat_integrate(q_body_to_icrs, omega_body, dt, alpha_body=None) -> np.ndarray:
    """Propagate attitude over ``dt`` seconds with body rate ``omega_body`` (rad/s).

    Second order when ``alpha_body`` (rad/s², body frame) is given: the rotation vector over the
    step is ``ω dt + α dt²/2``; the neglected coning term is ``|α × ω| dt³ / 12``, below 1e-6 rad
    for a 0.1 s prediction at 20°/s and 1°/s².

    Parameters
    ----------
    q_body_to_icrs : array_like, shape (4,) or (..., 4)
    omega_body : array_like, shape (3,) or (..., 3)
        Body angular rate in rad/s.
    dt : float or array_like, broadcastable to the leading shape
        Time step(s) in s (may be negative).
    alpha_body : array_like, shape (3,), optional
        Body angular acceleration in rad/s².

    Returns
    -------
    ndarray, shape (..., 4)
    """
    q = np.asarray(q_body_to_icrs, dtype=np.float64)
    w = np.asarray(omega_body, dtype=np.float64)
    dt = np.asarray(dt, dtype=np.float64)[..., None]
    rv = w * dt
    if alpha_body is not None:
        rv = rv + 0.5 * np.asarray(alpha_body, dtype=np.float64) * dt**2
    dq = quat_from_rotvec(rv)
    # Body-frame increment: q(t+dt) = q(t) ⊗ dq.
    return quat_normalize(quat_multiply(q, dq))


def skew(v) -> np.ndarray:
    """Cross-product matrices [v×], shape (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], axis=-2
    )


def quat_interpolate(t_samples, q_samples, t_query) -> np.ndarray:
    """Spherical-linear interpolation of an attitude history.

    Parameters
    ----------
    t_samples : array_like, shape (S,)
        Strictly increasing sample times, s. S >= 2.
    q_samples : array_like, shape (S, 4)
        Attitudes (w, x, y, z) at those times.
    t_query : array_like, shape (Q,) or scalar
        Times inside ``[t_samples[0], t_samples[-1]]``.

    Returns
    -------
    ndarray, shape (Q, 4) or (4,)
    """
    from scipy.spatial.transform import Slerp

    t, q, tq = _interpolation_inputs(t_samples, q_samples, t_query)
    slerp = Slerp(t, to_scipy(q))
    out = from_scipy(slerp(np.clip(tq, t[0], t[-1])))
    return out


# ----------------------------------------------------------------------------------------------------------
# Internal fast paths (hot loops of the env: a few quaternions per call). No input validation: callers pass
# float64 arrays of the right shape that they built themselves. Each reproduces its public counterpart's
# arithmetic operation for operation (scipy's Cython kernels included: libm ``atan2`` per element, the
# x, y, z, w summation order of its norms), so results are bit-for-bit those of the public functions.
# ----------------------------------------------------------------------------------------------------------
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])
_EYE3 = np.eye(3)
_INV_XYZW = np.array([-1.0, -1.0, -1.0, 1.0])


def _norm_last(x: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1)`` without its dispatch overhead (the same ufunc calls)."""
    return np.sqrt(np.add.reduce(x * x, axis=-1, keepdims=keepdims))


def _canonical_sign_fast(q: np.ndarray) -> np.ndarray:
    """:func:`_canonical_sign` with a shortcut for the usual case of non-zero scalar parts."""
    w = q[..., 0]
    if (w != 0.0).all():
        neg = w < 0.0
        if not neg.any():
            return q  # callers pass arrays they just created: no copy needed
        return np.where(neg[..., None], -q, q)
    return _canonical_sign(q)


def _quat_normalize_unchecked(q: np.ndarray) -> np.ndarray:
    """:func:`quat_normalize` for a float64 array of non-zero quaternions."""
    return _canonical_sign_fast(q / _norm_last(q, keepdims=True))


def _quat_conjugate_unchecked(q: np.ndarray) -> np.ndarray:
    return q * _CONJ


def _quat_multiply_unchecked(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """:func:`quat_multiply` for float64 arrays (broadcast over leading axes)."""
    w1, x1, y1, z1 = q1[..., 0], q1[..., 1], q1[..., 2], q1[..., 3]
    w2, x2, y2, z2 = q2[..., 0], q2[..., 1], q2[..., 2], q2[..., 3]
    out = np.empty(np.broadcast_shapes(q1.shape, q2.shape))
    out[..., 0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    out[..., 1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    out[..., 2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    out[..., 3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    return out


def _quat_to_matrix_unchecked(q: np.ndarray) -> np.ndarray:
    """:func:`quat_to_matrix` for a float64 (..., 4) array."""
    q = q / _norm_last(q, keepdims=True)
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


def _quat_rotate_unchecked(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`quat_rotate` for float64 arrays."""
    return np.einsum("...ij,...j->...i", _quat_to_matrix_unchecked(q), v)


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
    angle = _norm_last(rv, keepdims=True)
    small = angle <= 1e-3
    a2 = angle * angle
    scale = np.where(small, 0.5 - a2 / 48 + a2 * a2 / 3840, np.sin(angle / 2) / np.where(small, 1.0, angle))
    out = np.empty(rv.shape[:-1] + (4,))
    out[..., :3] = scale * rv
    out[..., 3:] = np.cos(angle / 2)
    return out


def _from_xyzw(xyzw: np.ndarray) -> np.ndarray:
    """:func:`from_scipy` on raw (x, y, z, w) rows."""
    return _canonical_sign_fast(xyzw[..., [3, 0, 1, 2]])


def _quat_from_rotvec_unchecked(rv: np.ndarray) -> np.ndarray:
    """:func:`quat_from_rotvec` for a float64 (..., 3) array."""
    return _from_xyzw(_scipy_from_rotvec_xyzw(rv))


def _quat_to_rotvec_unchecked(q: np.ndarray) -> np.ndarray:
    """:func:`quat_to_rotvec` for a float64 (..., 4) array of non-zero quaternions."""
    qn = _quat_normalize_unchecked(q)
    lead = qn.shape[:-1]
    return _scipy_as_rotvec_xyzw(_xyzw_normalized(qn.reshape(-1, 4))).reshape(lead + (3,))


def _quat_integrate_unchecked(q, omega_body, dt, alpha_body=None) -> np.ndarray:
    """:func:`quat_integrate` for float64 arrays."""
    dt = np.asarray(dt, dtype=np.float64)[..., None]
    rv = omega_body * dt
    if alpha_body is not None:
        rv = rv + 0.5 * alpha_body * dt**2
    return _quat_normalize_unchecked(_quat_multiply_unchecked(q, _quat_from_rotvec_unchecked(rv)))


def _quat_angle_between_unchecked(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """:func:`quat_angle_between` for float64 arrays of non-zero quaternions."""
    q1 = _quat_normalize_unchecked(q1)
    q2 = _quat_normalize_unchecked(q2)
    d = np.abs(np.add.reduce(q1 * q2, axis=-1))
    dq = _quat_multiply_unchecked(q1 * _CONJ, q2)
    return 2.0 * np.arctan2(_norm_last(dq[..., 1:]), d)


# Shepperd's four branches as picks from the ten values (1-tr+2m00, 1-tr+2m11, 1-tr+2m22, m10+m01, m20+m02,
# m21+m12, m21-m12, m02-m20, m10-m01, 1+tr), already in (w, x, y, z) order; row = scipy's branch choice.
_SHEPPERD_WXYZ = np.array([[6, 0, 3, 4], [7, 3, 1, 5], [8, 4, 5, 2], [9, 6, 7, 8]])
_ORTHO_TOL = 1e-12 + 1e-5 * np.eye(3)  # np.isclose(gram, I, atol=1e-12) as scipy tests it


def _quat_from_matrix_unchecked(m: np.ndarray) -> np.ndarray:
    """:func:`quat_from_matrix` for float64 (..., 3, 3) rotation matrices (scipy's checks and Shepperd's method,
    vectorised; matrices scipy would re-orthogonalise or reject go through the public function)."""
    lead = m.shape[:-2]
    mm = m.reshape(-1, 3, 3)
    gram = mm @ np.transpose(mm, (0, 2, 1))
    if not ((np.abs(gram - _EYE3) <= _ORTHO_TOL).all() and (np.linalg.det(mm) > 0.0).all()):
        return quat_from_matrix(m)
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
    return _canonical_sign_fast(q).reshape(lead + (4,))


def _interpolation_inputs(t_samples, q_samples, t_query):
    """The checks of :func:`quat_interpolate`; returns float64 ``(t, q, t_query)``."""
    t = as_float_array(t_samples, "t_samples", ndim=1)
    q = as_float_array(q_samples, "q_samples", last_dim=4, ndim=2)
    if len(t) != len(q) or len(t) < 2:
        raise ValueError("t_samples and q_samples must have the same length >= 2")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t_samples must be strictly increasing")
    tq = as_float_array(t_query, "t_query")
    if np.any(tq < t[0] - 1e-12) or np.any(tq > t[-1] + 1e-12):
        raise ValueError(f"t_query must lie in [{t[0]}, {t[-1]}]")
    return t, q, tq


def _quat_interpolate_fast(t_samples, q_samples, t_query) -> np.ndarray:
    """:func:`quat_interpolate` (same checks, same result) through :func:`_quat_interpolate_unchecked`."""
    t, q, tq = _interpolation_inputs(t_samples, q_samples, t_query)
    if np.any(np.all(q == 0.0, axis=-1)):
        return quat_interpolate(t, q, tq)  # scipy's error for a zero quaternion
    return _quat_interpolate_unchecked(t, q, tq)


def _quat_interpolate_unchecked(t: np.ndarray, q: np.ndarray, tq) -> np.ndarray:
    """:func:`quat_interpolate` for a valid history (float64, strictly increasing ``t``, ``tq`` inside it):
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
