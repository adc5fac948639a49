"""Camera kernels: the pinhole projection with first-order radial distortion, float64 arrays, no checks.

The checked API is :meth:`startracker.optics.Camera.project` / :meth:`~startracker.optics.Camera.unproject` (conventions: camera +z is the boresight, pixel
``(0, 0)`` the centre of the top-left pixel, distortion as in paper 004 eq. 3).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["project_pinhole", "unproject_pinhole"]


def project_pinhole(v: np.ndarray, focal_length_mm: float, k1_per_mm2: float, pixel_size_mm: float,
                    principal_point_px: np.ndarray):
    """Project camera-frame directions to distorted pixel coordinates.

    Parameters
    ----------
    v : ndarray, shape (K, 3)
        Non-zero directions in the camera frame, any norm.
    focal_length_mm, k1_per_mm2, pixel_size_mm : float
        Focal length (mm), first-order radial distortion coefficient (1/mm²), pixel pitch (mm).
    principal_point_px : ndarray, shape (2,)
        (column, row) of the principal point, px.

    Returns
    -------
    xy : ndarray, shape (K, 2)
        (column, row), px; finite but meaningless where ``in_front`` is False.
    in_front : ndarray of bool, shape (K,)
        Z > 0 (relative to the vector's norm).
    """
    z = v[:, 2]
    in_front = z > 1e-12 * np.sqrt(np.add.reduce(v * v, axis=1))
    z_safe = np.where(in_front, z, 1.0)
    xy = np.empty((len(v), 2))
    xy[:, 0] = focal_length_mm * v[:, 0] / z_safe
    xy[:, 1] = focal_length_mm * v[:, 1] / z_safe
    if k1_per_mm2 != 0.0:  # k1 = 0: the factor is exactly 1
        xy = xy * (1.0 + k1_per_mm2 * np.add.reduce(xy**2, axis=-1, keepdims=True))
    return xy / pixel_size_mm + principal_point_px, in_front


@njit(cache=True, no_cfunc_wrapper=True)
def unproject_pinhole(xy, focal_length_mm, k1_per_mm2, pixel_size_mm, ppx, ppy):
    """Distorted pixel coordinates to unit camera-frame directions (inverse of :func:`project_pinhole`).

    The radial distortion ``r_d = r (1 + k1 r²)`` is inverted per point by Newton's method from
    ``r = r_d`` (to 1e-15 relative, at most 20 steps), then ``v = (x_mm, y_mm, f_mm) / |·|``.

    Parameters
    ----------
    xy : ndarray, shape (K, 2)
        (column, row), px.
    focal_length_mm, k1_per_mm2, pixel_size_mm : float
        Focal length (mm), first-order radial distortion coefficient (1/mm²), pixel pitch (mm).
    ppx, ppy : float
        Principal point (column, row), px.

    Returns
    -------
    v : ndarray, shape (K, 3)
        Unit vectors, camera frame (Z > 0).
    """
    n = xy.shape[0]
    out = np.empty((n, 3))
    f2 = focal_length_mm * focal_length_mm
    for j in range(n):
        dx = (xy[j, 0] - ppx) * pixel_size_mm
        dy = (xy[j, 1] - ppy) * pixel_size_mm
        if k1_per_mm2 != 0.0:
            rd = math.sqrt(dx * dx + dy * dy)
            rr = rd
            for _ in range(20):
                step = (rr * (1.0 + k1_per_mm2 * rr * rr) - rd) / (1.0 + 3.0 * k1_per_mm2 * rr * rr)
                rr = rr - step
                if abs(step) <= 1e-15 * max(rd, 1e-30):
                    break
            if rd > 0.0:
                dx = dx * (rr / rd)
                dy = dy * (rr / rd)
        nv = math.sqrt(dx * dx + dy * dy + f2)
        out[j, 0] = dx / nv
        out[j, 1] = dy / nv
        out[j, 2] = focal_length_mm / nv
    return out
