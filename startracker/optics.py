"""Camera model: pinhole, principal point, first-order radial distortion (paper 004 eq. 3), mounting.

Frames (docs/design.md, Conventions): camera +z is the boresight toward the sky, +x toward increasing pixel
column, +y toward increasing pixel row. Pixel coordinates ``xy[:, 0]`` = column, ``xy[:, 1]`` = row,
(0, 0) is the centre of the top-left pixel.

Projection of a camera-frame direction ``v = (X, Y, Z)``::

    x' = f X / Z,  y' = f Y / Z                      (focal plane, mm; paper 004 eq. 1)
    δ = m (x'² + y'²)                               (m: first-order radial distortion, 1/mm², eq. 3)
    col = cx + x' (1 + δ) / p,  row = cy + y' (1 + δ) / p   (p: pixel size in mm, eq. 2)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from startracker.rotations import quat_normalize, quat_to_matrix
from startracker.kernels import optics as optics_kernels
from startracker.validation import as_float_array

__all__ = ["Camera", "CAMERA_PRESETS", "camera_preset"]


@dataclass(frozen=True)
class Camera:
    """A pinhole star camera with first-order radial distortion and a body mounting.

    Parameters
    ----------
    resolution : (int, int)
        Detector size ``(n_cols, n_rows)`` in pixels.
    pixel_size_um : float
        Pixel pitch in µm (square pixels).
    focal_length_mm : float
        Focal length in mm.
    principal_point : (float, float), optional
        ``(cx, cy)`` in pixels; default the detector centre ``((n_cols-1)/2, (n_rows-1)/2)``.
    distortion_k1_per_mm2 : float
        First-order radial distortion coefficient ``m`` of paper 004 eq. 3, in 1/mm², applied to
        focal-plane coordinates in mm. 0 for an ideal pinhole.
    q_cam_to_body : array_like, shape (4,)
        Mounting quaternion (w, x, y, z), camera frame to body frame. Default identity.
    name : str
        Free label, e.g. the preset name.
    """

    resolution: tuple[int, int] = (2048, 2048)
    pixel_size_um: float = 5.5
    focal_length_mm: float = 31.94
    principal_point: tuple[float, float] | None = None
    distortion_k1_per_mm2: float = 0.0
    q_cam_to_body: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    name: str = "custom"
    _r_cam_to_body: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        res = tuple(self.resolution)
        if len(res) != 2 or any(int(r) != r or r < 2 for r in res):
            raise ValueError(f"resolution must be two integers >= 2 (n_cols, n_rows), got {self.resolution}")
        object.__setattr__(self, "resolution", (int(res[0]), int(res[1])))
        for name in ("pixel_size_um", "focal_length_mm"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")
        if not np.isfinite(self.distortion_k1_per_mm2):
            raise ValueError("distortion_k1_per_mm2 must be finite")
        if self.principal_point is None:
            pp = ((res[0] - 1) / 2.0, (res[1] - 1) / 2.0)
        else:
            pp = tuple(float(v) for v in as_float_array(self.principal_point, "principal_point", last_dim=2, ndim=1))
        object.__setattr__(self, "principal_point", pp)
        q = tuple(float(v) for v in quat_normalize(as_float_array(self.q_cam_to_body, "q_cam_to_body", 4, 1)))
        object.__setattr__(self, "q_cam_to_body", q)
        object.__setattr__(self, "_r_cam_to_body", quat_to_matrix(np.array(q)))
        # Distortion must stay monotone over the detector, or unproject is ambiguous.
        r_max = self.pixel_size_mm * 0.5 * np.hypot(*res) * 1.5
        if self.distortion_k1_per_mm2 < 0 and 1 + 3 * self.distortion_k1_per_mm2 * r_max**2 <= 0:
            raise ValueError("distortion_k1_per_mm2 is so negative that the image folds over inside the detector")

    # ------------------------------------------------------------------ geometry
    @property
    def pixel_size_mm(self) -> float:
        return self.pixel_size_um * 1e-3

    @property
    def focal_length_px(self) -> float:
        """Focal length in pixels, ``f / p``."""
        return self.focal_length_mm / self.pixel_size_mm

    @property
    def r_cam_to_body(self) -> np.ndarray:
        """Mounting rotation matrix (3, 3), ``v_body = R @ v_cam``."""
        return self._r_cam_to_body

    @property
    def half_fov_rad(self) -> tuple[float, float]:
        """Half field-of-view angles (x, y) in rad, measured from the principal point to the far edges."""
        cx, cy = self.principal_point
        w, h = self.resolution
        fx = max(cx + 0.5, w - 0.5 - cx) * self.pixel_size_mm
        fy = max(cy + 0.5, h - 0.5 - cy) * self.pixel_size_mm
        return (float(np.arctan(fx / self.focal_length_mm)), float(np.arctan(fy / self.focal_length_mm)))

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Full field of view (x, y) in degrees for a centred principal point."""
        return tuple(float(np.degrees(2 * a)) for a in self.half_fov_rad)

    @property
    def half_diagonal_fov_rad(self) -> float:
        """Angle from the boresight to the farthest detector corner, rad (undistorted)."""
        cx, cy = self.principal_point
        w, h = self.resolution
        dx = max(cx + 0.5, w - 0.5 - cx) * self.pixel_size_mm
        dy = max(cy + 0.5, h - 0.5 - cy) * self.pixel_size_mm
        return float(np.arctan(np.hypot(dx, dy) / self.focal_length_mm))

    # ------------------------------------------------------------------ projection
    def project(self, v_cam, return_in_front: bool = False, *, validate: bool = True):
        """Project camera-frame directions to pixel coordinates.

        Parameters
        ----------
        v_cam : array_like, shape (K, 3) or (3,)
            Directions in the camera frame (need not be unit length; must be non-zero).
        return_in_front : bool
            Also return the mask of points in front of the camera (Z > 0).
        validate : bool
            False skips the checks: for a caller passing a float64 (K, 3) array of non-zero directions.

        Returns
        -------
        xy : ndarray, shape (K, 2)
            Pixel coordinates (column, row). For points behind the camera (Z <= 0) the values are
            finite but meaningless: mask them with ``in_front``.
        in_frame : ndarray of bool, shape (K,)
            Point is in front of the camera and lands on the detector (inside the outer pixel edges).
        in_front : ndarray of bool, shape (K,)
            Only when ``return_in_front``.
        """
        if validate:
            v = as_float_array(v_cam, "v_cam", last_dim=3)
            if np.any(np.all(v == 0.0, axis=-1)):
                raise ValueError("v_cam contains a zero vector")
        else:
            v = v_cam
        single = v.ndim == 1
        xy, in_front = optics_kernels.project_pinhole(v.reshape(-1, 3), self.focal_length_mm, self.distortion_k1_per_mm2,
                                                      self.pixel_size_mm, np.asarray(self.principal_point, dtype=np.float64))
        w, h = self.resolution
        in_frame = (
            in_front
            & (xy[:, 0] >= -0.5)
            & (xy[:, 0] <= w - 0.5)
            & (xy[:, 1] >= -0.5)
            & (xy[:, 1] <= h - 0.5)
        )
        if single:
            xy, in_frame, in_front = xy[0], in_frame[0], in_front[0]
        if return_in_front:
            return xy, in_frame, in_front
        return xy, in_frame

    def distort_mm_to_px(self, xy_ideal_mm) -> np.ndarray:
        """Ideal focal-plane coordinates (K, 2) in mm -> distorted pixel coordinates (K, 2)."""
        xy = np.asarray(xy_ideal_mm, dtype=np.float64)
        r2 = np.sum(xy**2, axis=-1, keepdims=True)
        xy_d = xy * (1.0 + self.distortion_k1_per_mm2 * r2)
        return xy_d / self.pixel_size_mm + np.asarray(self.principal_point)

    def undistort_px_to_mm(self, xy_px) -> np.ndarray:
        """Distorted pixel coordinates (K, 2) -> ideal focal-plane coordinates (K, 2) in mm.

        Inverts ``r_d = r (1 + m r²)`` per point with Newton's method (converges to machine
        precision in a few iterations for any distortion that keeps the mapping monotone).
        """
        xy = as_float_array(xy_px, "xy", last_dim=2)
        d = (xy - np.asarray(self.principal_point)) * self.pixel_size_mm
        m = self.distortion_k1_per_mm2
        if m == 0.0:
            return d
        rd = np.linalg.norm(d, axis=-1)
        r = rd.copy()
        for _ in range(20):
            f = r * (1 + m * r * r) - rd
            step = f / (1 + 3 * m * r * r)
            r = r - step
            if np.all(np.abs(step) <= 1e-15 * np.maximum(rd, 1e-30)):
                break
        scale = np.where(rd > 0, r / np.where(rd > 0, rd, 1.0), 1.0)
        return d * scale[..., None]

    def unproject(self, xy) -> np.ndarray:
        """Pixel coordinates to unit camera-frame directions.

        Parameters
        ----------
        xy : array_like, shape (K, 2) or (2,)
            Pixel coordinates (column, row), distorted as measured.

        Returns
        -------
        v_cam : ndarray, shape (K, 3) or (3,)
            Unit vectors in the camera frame (Z > 0).
        """
        xy_arr = as_float_array(xy, "xy", last_dim=2)
        single = xy_arr.ndim == 1
        cx, cy = self.principal_point
        v = optics_kernels.unproject_pinhole(np.ascontiguousarray(xy_arr.reshape(-1, 2)), float(self.focal_length_mm),
                                             float(self.distortion_k1_per_mm2), self.pixel_size_mm, cx, cy)
        return v[0] if single else v

    def boresight_body(self) -> np.ndarray:
        """Boresight (camera +z) in the body frame, shape (3,)."""
        return self._r_cam_to_body[:, 2].copy()

    def with_mounting(self, q_cam_to_body, name: str | None = None) -> "Camera":
        """The same camera mounted differently."""
        return Camera(
            resolution=self.resolution,
            pixel_size_um=self.pixel_size_um,
            focal_length_mm=self.focal_length_mm,
            principal_point=self.principal_point,
            distortion_k1_per_mm2=self.distortion_k1_per_mm2,
            q_cam_to_body=tuple(np.asarray(q_cam_to_body, dtype=float)),
            name=self.name if name is None else name,
        )


def _focal_for_fov(fov_deg: float, n_px: int, pixel_size_um: float) -> float:
    return 0.5 * n_px * pixel_size_um * 1e-3 / np.tan(np.radians(fov_deg / 2))


# Paper cameras. Paper 003 gives only the 16°x16° FOV: 1024² pixels of 15 µm are assumed, focal
# length chosen for that FOV.
CAMERA_PRESETS: dict[str, dict] = {
    "paper000": dict(resolution=(2048, 2048), pixel_size_um=5.5, focal_length_mm=31.94),
    "zy3": dict(resolution=(1024, 1024), pixel_size_um=15.0, focal_length_mm=43.3),
    "paper003": dict(resolution=(1024, 1024), pixel_size_um=15.0, focal_length_mm=_focal_for_fov(16.0, 1024, 15.0)),
    "paper004": dict(
        resolution=(2064, 1544),
        pixel_size_um=3.45,
        focal_length_mm=25.0,
        principal_point=(1032.0, 772.0),
        distortion_k1_per_mm2=4.9e-5,
    ),
}


def camera_preset(name: str, q_cam_to_body=(1.0, 0.0, 0.0, 0.0)) -> Camera:
    """A camera of one of the papers: ``"paper000"`` (Table 2, 20°×20°), ``"zy3"`` (paper 002),
    ``"paper003"`` (16°×16°), ``"paper004"`` (green channel of Table 1, 16°×12°)."""
    if name not in CAMERA_PRESETS:
        raise ValueError(f"camera preset must be one of {sorted(CAMERA_PRESETS)}, got {name!r}")
    return Camera(**CAMERA_PRESETS[name], q_cam_to_body=q_cam_to_body, name=name)
