"""Quaternions (w, x, y, z), rotation matrices and rotation vectors.

Convention (docs/design.md, Conventions): scalar first, Hamilton product, unit norm. ``q_a_to_b`` maps the
coordinates of a vector in frame a to frame b, ``v_b = R(q_a_to_b) @ v_a``. Composition:
``q_a_to_c = quat_multiply(q_b_to_c, q_a_to_b)``.

This is the only module that talks to :class:`scipy.spatial.transform.Rotation`, which is scalar-last.
Every function is vectorised over leading axes: a quaternion array has shape ``(..., 4)``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from startracker.kernels import rotations as kernels
from startracker.validation import as_float_array

__all__ = [
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

    Raises
    ------
    ValueError
        ``q`` is not (..., 4), holds NaN or inf, or a quaternion of norm below 1e-12.
    """
    q = as_float_array(q, "q", last_dim=4)
    if np.any(kernels.vector_norm(q) < 1e-12):
        raise ValueError("q contains a zero quaternion, which is not a rotation")
    return kernels.quat_normalize(q)


def quat_multiply(q1, q2) -> np.ndarray:
    """Hamilton product ``q1 ⊗ q2`` (apply q2 first, then q1).

    Parameters
    ----------
    q1, q2 : array_like, shape (..., 4)
        Broadcastable quaternion arrays (w, x, y, z).

    Returns
    -------
    ndarray, shape (..., 4)

    Raises
    ------
    ValueError
        Either is not (..., 4) or holds NaN or inf, or their shapes do not broadcast.
    """
    q1 = as_float_array(q1, "q1", last_dim=4)
    q2 = as_float_array(q2, "q2", last_dim=4)
    try:
        np.broadcast_shapes(q1.shape, q2.shape)
    except ValueError:
        raise ValueError(f"q1 {q1.shape} and q2 {q2.shape} do not broadcast") from None
    return kernels.quat_multiply(q1, q2)


def quat_conjugate(q) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion), shape (..., 4).

    Raises
    ------
    ValueError
        ``q`` is not (..., 4) or holds NaN or inf.
    """
    return kernels.quat_conjugate(as_float_array(q, "q", last_dim=4))


def to_scipy(q) -> Rotation:
    """scipy ``Rotation`` from (..., 4) scalar-first quaternions."""
    q = as_float_array(q, "q", last_dim=4)
    return Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]] if q.ndim > 1 else q[[1, 2, 3, 0]])


def from_scipy(rot: Rotation) -> np.ndarray:
    """Scalar-first unit quaternion(s) with ``w >= 0`` from a scipy ``Rotation``."""
    xyzw = rot.as_quat()
    return kernels.canonical_sign(xyzw[..., [3, 0, 1, 2]])


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrices ``R(q)``, shape (..., 3, 3), with ``v_b = R @ v_a`` for ``q_a_to_b``."""
    return kernels.quat_to_matrix(as_float_array(q, "q", last_dim=4))


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
    q = kernels.canonical_sign(q)
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
    t, q, tq = _interpolation_inputs(t_samples, q_samples, t_query)
    if np.any(np.all(q == 0.0, axis=-1)):
        raise ValueError("q_samples contains a zero quaternion, which is not a rotation")
    # scipy's Slerp arithmetic, evaluated only on the intervals the queries use (kernels.quat_interpolate)
    return kernels.quat_interpolate(t, q, tq)


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


