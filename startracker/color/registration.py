"""Registration of the red and blue channels of a 3CMOS star sensor onto the green one (paper 004).

Model (paper 004 eqs. 13-18). A star centroid ``x_c`` on channel c (red or blue) maps into the green
channel's pixel frame as

``x_g = k R(θ) (x_c - x0) + x0 - Δ``,  ``R(θ) = [[cos θ, -sin θ], [sin θ, cos θ]]``

with ``k = F_g / F_c`` the focal-length ratio (which also absorbs the distortion difference, eq. 9),
``θ`` the in-plane rotation of the channel's detector, ``x0`` the channel's principal point and
``Δ = x0_c - x0_g`` the principal-point offset (eq. 14). ``x0`` is fixed (measured, e.g. the centroid at
the rotary table's zero position); any error in it is absorbed exactly by ``Δ``.

Calibration (paper 004 §3): star centroids of all channels at ``n`` rotary-table angles (eqs. 19-23,
:func:`generate_rotary_table_data`), then a two-step nonlinear least squares (first ``k, θ`` with ``Δ``
at its initial value, then all four), started from the zero-position estimate and from random
restarts, on :func:`scipy.optimize.least_squares` (:func:`calibrate_registration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from startracker.validation import as_float_array

__all__ = [
    "CHANNELS",
    "ColorRegistration",
    "RegistrationParams",
    "RotaryTableData",
    "calibrate_registration",
    "generate_rotary_table_data",
    "registration_rmse",
]

CHANNELS: tuple[str, str, str] = ("red", "green", "blue")

#: Minimum ratio of the two singular values of the centred calibration points; below it the points are
#: treated as collinear (a 2048-px line with 2 px of scatter across it gives 1e-3).
COLLINEAR_RATIO = 1e-3
#: Spread of the random restarts around the initial values (paper 004 §3.2, "random initial values within
#: a certain range" from the manufacturer's configuration): ±1 % in k, ±0.5° in θ, ±5 px in Δ.
RESTART_SPREAD = (0.01, np.radians(0.5), 5.0)


def _rot(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class RegistrationParams:
    """Calibrated registration of one channel onto the green channel (paper 004 eq. 15).

    Attributes
    ----------
    k : float
        Scale factor ``F_g / F_c`` (dimensionless).
    theta_rad : float
        Rotation θ in rad (paper's sign: ``x_g = k R(θ) (x_c - x0) + x0 - Δ``).
    dx_px, dy_px : float
        Translation ``Δ = (Δx, Δy)`` in pixels, subtracted (eq. 15).
    principal_point : (float, float)
        ``x0 = (x0, y0)`` of the channel used by the model, px.
    rmse_px : float
        Root mean square of the 2-D fit residuals over the calibration points, px (eq. 26 form).
    success : bool
        The calibration is usable. When False, ``status`` says why and :meth:`apply` refuses.
    status : str
        "ok" or the reason of failure.
    n_points : int
        Number of calibration point pairs.
    n_restarts : int
        Random restarts run in addition to the start from the zero-position estimate.
    cost : float
        Final least-squares cost ``0.5 * sum(r**2)``, px².
    q_per_px2 : float
        Differential radial distortion (only ``model="radial"``, an extension beyond paper 004):
        ``x_g = k R(θ) (x_c - x0) (1 + q |x_c - x0|²) + x0 - Δ``; 0 for the paper's model.
    model : str
        "paper" (the four parameters of eq. 17) or "radial" (plus ``q_per_px2``).
    """

    k: float
    theta_rad: float
    dx_px: float
    dy_px: float
    principal_point: tuple[float, float]
    rmse_px: float = float("nan")
    success: bool = True
    status: str = "ok"
    n_points: int = 0
    n_restarts: int = 0
    cost: float = float("nan")
    q_per_px2: float = 0.0
    model: str = "paper"

    @property
    def theta_deg(self) -> float:
        return float(np.degrees(self.theta_rad))

    @property
    def vector(self) -> np.ndarray:
        """Parameter vector ``u = (k, θ [rad], Δx [px], Δy [px])`` of paper 004 eq. 17, shape (4,)."""
        return np.array([self.k, self.theta_rad, self.dx_px, self.dy_px])

    def matrix(self) -> np.ndarray:
        """The transform as a (2, 3) affine matrix ``[A | b]`` with ``x_g = A @ x_c + b``.

        Exact for ``model="paper"``; for ``model="radial"`` it is the linear part only (``q`` dropped).
        """
        a = self.k * _rot(self.theta_rad)
        x0 = np.asarray(self.principal_point)
        b = x0 - a @ x0 - np.array([self.dx_px, self.dy_px])
        return np.column_stack([a, b])

    def _check_usable(self):
        if not self.success:
            raise ValueError(f"registration is not calibrated ({self.status}); refusing to apply it")

    def apply(self, xy_channel) -> np.ndarray:
        """Map channel pixel coordinates into the green channel's frame (eq. 17/18).

        Parameters
        ----------
        xy_channel : array_like, shape (K, 2) or (2,)
            Centroids on the red or blue detector, px.

        Returns
        -------
        ndarray, shape (K, 2) (or (2,))
            The same points in green-channel pixel coordinates.
        """
        self._check_usable()
        xy = as_float_array(xy_channel, "xy_channel", last_dim=2)
        if self.q_per_px2 != 0.0:
            x0 = np.asarray(self.principal_point)
            d = xy - x0
            xy = x0 + d * (1.0 + self.q_per_px2 * np.sum(d * d, axis=-1, keepdims=True))
        m = self.matrix()
        return xy @ m[:, :2].T + m[:, 2]

    def inverse(self, xy_green) -> np.ndarray:
        """Map green-frame pixel coordinates onto this channel's detector, shape (K, 2)."""
        self._check_usable()
        xy = as_float_array(xy_green, "xy_green", last_dim=2)
        m = self.matrix()
        lin = (xy - m[:, 2]) @ np.linalg.inv(m[:, :2]).T
        if self.q_per_px2 == 0.0:
            return lin
        # Invert r_d = r (1 + q r²) radially about x0 with Newton's method.
        x0 = np.asarray(self.principal_point)
        dd = lin - x0
        rd = np.linalg.norm(dd, axis=-1)
        r = rd.copy()
        q = self.q_per_px2
        for _ in range(30):
            step = (r * (1 + q * r * r) - rd) / (1 + 3 * q * r * r)
            r = r - step
            if np.all(np.abs(step) <= 1e-12 * np.maximum(rd, 1.0)):
                break
        scale = np.where(rd > 0, r / np.where(rd > 0, rd, 1.0), 1.0)
        return x0 + dd * scale[..., None]

    def equivalent_dx(self, principal_point) -> tuple[float, float]:
        """Δ of the same transform written about another principal point ``x0'``.

        ``Δ' = Δ + (I - k R(θ)) (x0' - x0)`` makes ``k R (x - x0') + x0' - Δ'`` identical to this
        transform: compare Δ from fits that used different ``x0``.
        """
        p = as_float_array(principal_point, "principal_point", last_dim=2, ndim=1)
        d = (np.eye(2) - self.k * _rot(self.theta_rad)) @ (p - np.asarray(self.principal_point))
        return (float(self.dx_px + d[0]), float(self.dy_px + d[1]))


def _model(u, d, x0):
    """u = (k, θ, Δx, Δy[, q]); d = x_c - x0 (n, 2) -> predicted green x (n,), y (n,)."""
    k, th, dx, dy = u[:4]
    f = 1.0 + u[4] * np.sum(d * d, axis=1) if len(u) > 4 else 1.0
    c, s = np.cos(th), np.sin(th)
    xg = k * f * (c * d[:, 0] - s * d[:, 1]) + x0[0] - dx
    yg = k * f * (s * d[:, 0] + c * d[:, 1]) + x0[1] - dy
    return xg, yg


def _residuals(u, d, x0, g):
    xg, yg = _model(u, d, x0)
    return np.concatenate([xg - g[:, 0], yg - g[:, 1]])


def _jacobian(u, d, x0, g):
    k, th = u[0], u[1]
    c, s = np.cos(th), np.sin(th)
    n = len(d)
    j = np.zeros((2 * n, len(u)))
    r2 = np.sum(d * d, axis=1)
    f = 1.0 + u[4] * r2 if len(u) > 4 else 1.0
    rx = c * d[:, 0] - s * d[:, 1]
    ry = s * d[:, 0] + c * d[:, 1]
    j[:n, 0], j[n:, 0] = f * rx, f * ry
    j[:n, 1], j[n:, 1] = -k * f * ry, k * f * rx
    j[:n, 2] = -1.0
    j[n:, 3] = -1.0
    if len(u) > 4:
        j[:n, 4], j[n:, 4] = k * r2 * rx, k * r2 * ry
    return j


def _two_step(u0, d, x0, g, radial=False):
    """Paper 004 §3.2: step 1 fits (k, θ) with Δ held at its initial value, step 2 fits all four.

    With ``radial`` a third step frees the differential distortion q as well (extension)."""
    delta = u0[2:]

    def r1(p):
        return _residuals(np.r_[p, delta], d, x0, g)

    def j1(p):
        return _jacobian(np.r_[p, delta], d, x0, g)[:, :2]

    s1 = least_squares(r1, u0[:2], jac=j1, method="lm", x_scale=np.array([1e-3, 1e-3]))
    s2 = least_squares(_residuals, np.r_[s1.x, delta], jac=_jacobian, method="lm", args=(d, x0, g),
                       x_scale=np.array([1e-3, 1e-3, 1.0, 1.0]))
    if not radial:
        return s2
    r2_max = float(np.max(np.sum(d * d, axis=1)))
    return least_squares(_residuals, np.r_[s2.x, 0.0], jac=_jacobian, method="lm", args=(d, x0, g),
                         x_scale=np.array([1e-3, 1e-3, 1.0, 1.0, 1e-3 / max(r2_max, 1.0)]))


def _line_angle(xy):
    """Direction angle (rad, in (-π/2, π/2]) of the total-least-squares line through points (n, 2)."""
    c = xy - xy.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    d = vt[0]
    if d[0] < 0 or (d[0] == 0 and d[1] < 0):
        d = -d
    return float(np.arctan2(d[1], d[0]))


def calibrate_registration(xy_channel, xy_green, principal_point=None, *, rng: np.random.Generator | None = None,
                           n_restarts: int = 8, zero_index: int | None = None, line_mask=None,
                           model: str = "paper") -> RegistrationParams:
    """Calibrate the registration of one channel onto green (paper 004 §3.2, eqs. 15-18, 24).

    Initial values (step 1 of §3.2): ``k = 1``; ``θ`` = angle between the lines fitted to the green and the
    channel centroids taken with the rotary table's external frame at zero (``line_mask``), else 0;
    ``x0`` = the channel centroid at the zero position (``zero_index``) unless ``principal_point`` is
    given; ``Δ`` from eq. 14, generalised to the mean of ``x_c - x_g`` (its least-squares value at
    ``k = 1, θ = 0``, equal to eq. 14 at the zero position). From this start and from ``n_restarts``
    random starts around it (±1 % in k, ±0.5° in θ, ±5 px in Δ) the two-step least squares runs (first
    ``k, θ``, then all four, Levenberg-Marquardt with the analytic Jacobian); the lowest cost wins.

    Parameters
    ----------
    xy_channel : array_like, shape (n, 2)
        Centroids on the red or blue detector, px. n >= 3, not collinear.
    xy_green : array_like, shape (n, 2)
        The same stars' centroids on the green detector, px.
    principal_point : (float, float), optional
        ``x0`` of the channel in px. Required unless ``zero_index`` is given.
    rng : numpy.random.Generator, optional
        Source of the random restarts; ``None`` uses ``numpy.random.default_rng(0)`` (reproducible).
    n_restarts : int
        Random restarts in addition to the deterministic start, >= 0.
    zero_index : int, optional
        Index of the point taken at the rotary table's zero position.
    line_mask : array_like of bool, shape (n,), optional
        Points taken with only the middle frame rotating (external frame at zero); at least 2.
    model : {"paper", "radial"}
        "paper": the four parameters of eq. 17. "radial" (extension, not in paper 004): a third step
        also fits a differential radial distortion ``q`` (1/px²), removing the residual that the paper's
        approximation ``m_c = m_g`` (eq. 8) leaves; needs >= 5 points.

    Returns
    -------
    RegistrationParams
        ``success`` False with a reason in ``status`` for degenerate geometry (collinear or coincident
        points) or an optimiser failure.

    Raises
    ------
    ValueError
        Shapes differ or are not (n, 2), fewer than 3 points, NaN/inf, neither ``principal_point`` nor
        ``zero_index`` given, bad ``n_restarts`` / ``zero_index`` / ``line_mask``.
    """
    xc = as_float_array(xy_channel, "xy_channel", last_dim=2, ndim=2)
    xg = as_float_array(xy_green, "xy_green", last_dim=2, ndim=2)
    if xc.shape != xg.shape:
        raise ValueError(f"xy_channel and xy_green must have the same shape, got {xc.shape} and {xg.shape}")
    n = len(xc)
    if n < 3:
        raise ValueError(f"xy_channel needs at least 3 calibration points (4 parameters, 2 equations each), got {n}")
    if model not in ("paper", "radial"):
        raise ValueError(f"model must be 'paper' or 'radial', got {model!r}")
    if model == "radial" and n < 5:
        raise ValueError(f"model='radial' needs at least 5 calibration points, got {n}")
    if isinstance(n_restarts, bool) or not isinstance(n_restarts, (int, np.integer)) or n_restarts < 0:
        raise ValueError(f"n_restarts must be a non-negative integer, got {n_restarts!r}")
    if rng is None:
        rng = np.random.default_rng(0)
    elif not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if zero_index is not None:
        if isinstance(zero_index, bool) or not isinstance(zero_index, (int, np.integer)) or not -n <= zero_index < n:
            raise ValueError(f"zero_index must be an integer index into the {n} points, got {zero_index!r}")
    if principal_point is None:
        if zero_index is None:
            raise ValueError("principal_point is required unless zero_index (the zero-position point) is given")
        x0 = xc[zero_index].copy()
    else:
        x0 = as_float_array(principal_point, "principal_point", last_dim=2, ndim=1)
    theta0 = 0.0
    if line_mask is not None:
        lm = np.asarray(line_mask)
        if lm.dtype != bool or lm.shape != (n,):
            raise ValueError(f"line_mask must be a boolean array of shape ({n},), got {lm.dtype} {lm.shape}")
        if lm.sum() < 2:
            raise ValueError("line_mask must select at least 2 points")
        theta0 = _line_angle(xg[lm]) - _line_angle(xc[lm])
        theta0 = (theta0 + np.pi / 2) % np.pi - np.pi / 2

    delta0 = np.mean(xc - xg, axis=0)

    def failed(reason, u=None):
        # The initial values, finite; success=False makes apply() refuse them.
        u = np.array([1.0, theta0, delta0[0], delta0[1]]) if u is None else u
        return RegistrationParams(k=float(u[0]), theta_rad=float(u[1]), dx_px=float(u[2]), dy_px=float(u[3]),
                                  principal_point=(float(x0[0]), float(x0[1])), success=False, status=reason,
                                  n_points=n, n_restarts=int(n_restarts), model=model)

    # Geometry: the points must span the image plane in both channels.
    for name, pts in (("xy_channel", xc), ("xy_green", xg)):
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if sv[0] < 1e-9 * max(1.0, np.abs(pts).max()):
            return failed(f"degenerate calibration data: all {name} points are coincident")
        if sv[1] < COLLINEAR_RATIO * sv[0]:
            return failed(f"degenerate calibration data: {name} points are collinear (singular-value ratio "
                          f"{sv[1] / sv[0]:.2e} < {COLLINEAR_RATIO:g}); rotate both table frames")

    d = xc - x0
    starts = [np.array([1.0, theta0, delta0[0], delta0[1]])]
    lo = np.array([1.0 - RESTART_SPREAD[0], theta0 - RESTART_SPREAD[1], delta0[0] - RESTART_SPREAD[2],
                   delta0[1] - RESTART_SPREAD[2]])
    hi = np.array([1.0 + RESTART_SPREAD[0], theta0 + RESTART_SPREAD[1], delta0[0] + RESTART_SPREAD[2],
                   delta0[1] + RESTART_SPREAD[2]])
    starts += list(rng.uniform(lo, hi, size=(n_restarts, 4)))
    best = None
    for u0 in starts:
        sol = _two_step(u0, d, x0, xg, radial=model == "radial")
        if sol.status > 0 and np.all(np.isfinite(sol.x)) and sol.x[0] > 0 and (best is None or sol.cost < best.cost):
            best = sol
    if best is None:
        return failed("least squares did not converge from any start")
    u = best.x.copy()
    u[1] = (u[1] + np.pi) % (2 * np.pi) - np.pi
    r = best.fun
    rmse = float(np.sqrt(2.0 * np.mean(r**2)))  # sqrt(mean over points of |r_i|^2)
    return RegistrationParams(k=float(u[0]), theta_rad=float(u[1]), dx_px=float(u[2]), dy_px=float(u[3]),
                              principal_point=(float(x0[0]), float(x0[1])), rmse_px=rmse, success=True,
                              status="ok", n_points=n, n_restarts=int(n_restarts), cost=float(best.cost),
                              q_per_px2=float(u[4]) if model == "radial" else 0.0, model=model)


def registration_rmse(xy_a, xy_b) -> float:
    """Paper 004 eq. 26: ``sqrt(mean_i |a_i - b_i|^2)`` over point pairs (n, 2), px."""
    a = as_float_array(xy_a, "xy_a", last_dim=2, ndim=2)
    b = as_float_array(xy_b, "xy_b", last_dim=2, ndim=2)
    if a.shape != b.shape or len(a) == 0:
        raise ValueError(f"xy_a and xy_b must have the same non-empty shape, got {a.shape} and {b.shape}")
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


# ---------------------------------------------------------------------------------------------- data
@dataclass(frozen=True)
class RotaryTableData:
    """Centroids of one star simulator seen at ``n`` rotary-table angles by all three channels.

    Attributes
    ----------
    phi1_rad : ndarray, shape (n,)
        External-frame angle φ1 (rotation about x, moves the star along the rows), rad.
    phi2_rad : ndarray, shape (n,)
        Middle-frame angle φ2 (rotation about y, moves the star along the columns), rad.
    v_cam : ndarray, shape (n, 3)
        Starlight direction in the sensor (green) frame, eq. 19-20.
    xy : ndarray, shape (3, n, 2)
        Measured (noisy) centroids per channel in (red, green, blue) order, px.
    xy_true : ndarray, shape (3, n, 2)
        Noise-free centroids, px.
    noise_px : float
        Standard deviation of the Gaussian noise added to each coordinate, px.
    zero_index : int
        Index of the zero position (φ1 = φ2 = 0), or -1 if absent.
    line_mask : ndarray of bool, shape (n,)
        Points with the external frame at zero (only the middle frame rotated).
    """

    phi1_rad: np.ndarray
    phi2_rad: np.ndarray
    v_cam: np.ndarray
    xy: np.ndarray
    xy_true: np.ndarray
    noise_px: float
    zero_index: int
    line_mask: np.ndarray

    def channel(self, channel, true: bool = False) -> np.ndarray:
        """Centroids (n, 2) of one channel ("red", "green", "blue" or 0..2)."""
        i = CHANNELS.index(channel) if isinstance(channel, str) and channel in CHANNELS else channel
        if not isinstance(i, (int, np.integer)) or not 0 <= i < 3:
            raise ValueError(f"channel must be one of {CHANNELS} or 0..2, got {channel!r}")
        return (self.xy_true if true else self.xy)[i]

    def __len__(self) -> int:
        return len(self.phi1_rad)


def rotary_table_vectors(phi1_rad, phi2_rad) -> np.ndarray:
    """Starlight direction ``V_c = R_rot V_0`` of paper 004 eqs. 19-20, shape (n, 3).

    ``R_rot = R_x(φ1) R_y(φ2)`` as printed, ``V_0 = (0, 0, 1)``:
    ``V_c = (-sin φ2, sin φ1 cos φ2, cos φ1 cos φ2)``.
    """
    p1 = as_float_array(phi1_rad, "phi1_rad")
    p2 = as_float_array(phi2_rad, "phi2_rad")
    if p1.shape != p2.shape:
        raise ValueError("phi1_rad and phi2_rad must have the same shape")
    return np.stack([-np.sin(p2), np.sin(p1) * np.cos(p2), np.cos(p1) * np.cos(p2)], axis=-1)


def generate_rotary_table_data(color_camera, rng: np.random.Generator, noise_px: float = 0.05, *,
                               n_angles: int = 137, step_deg: float = 0.9, range_deg=(8.0, 6.0),
                               layout: str = "grid") -> RotaryTableData:
    """Simulate the rotary-table calibration of paper 004 §3.1 and §4.1 (eqs. 19-23).

    ``layout="grid"``: ``n_angles`` nodes of the ``step_deg`` grid through zero inside the open range
    ``(-range_deg[0], +range_deg[0]) × (-range_deg[1], +range_deg[1])`` for (middle φ2, external φ1):
    the whole row with the external frame at zero (which holds the zero position, used for the initial
    values), the rest drawn without replacement from the other nodes. With the paper's 0.9° step the
    grid has 17 × 13 = 221 nodes, of which the paper uses 137 (Figure 4 is not reproduced in the text,
    so which 137 is a choice made here). ``layout="random"``: ``n_angles`` angles uniform over the range
    (the paper's 52 test points).

    Parameters
    ----------
    color_camera : ColorCamera
        Anything with ``project(v_cam) -> (xy (3, n, 2), in_frame (3, n))``.
    rng : numpy.random.Generator
        Draws the node selection and the noise.
    noise_px : float
        Standard deviation of the zero-mean Gaussian noise added to each centroid coordinate of each
        channel, px (paper: 0.05).
    n_angles : int
        Number of table positions (paper: 137 calibration, 52 test).
    step_deg : float
        Grid step (paper: 0.9°).
    range_deg : (float, float)
        Half ranges of (middle frame φ2, external frame φ1), deg (paper: 8°, 6°).
    layout : {"grid", "random"}

    Returns
    -------
    RotaryTableData
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if not (np.isfinite(noise_px) and noise_px >= 0):
        raise ValueError(f"noise_px must be a finite number >= 0, got {noise_px}")
    if isinstance(n_angles, bool) or not isinstance(n_angles, (int, np.integer)) or n_angles < 3:
        raise ValueError(f"n_angles must be an integer >= 3, got {n_angles!r}")
    rg = as_float_array(range_deg, "range_deg", last_dim=2, ndim=1)
    if np.any(rg <= 0) or np.any(rg >= 45):
        raise ValueError(f"range_deg must lie in (0, 45) deg, got {tuple(rg)}")
    if layout == "grid":
        if not (np.isfinite(step_deg) and 0 < step_deg < min(rg)):
            raise ValueError(f"step_deg must lie in (0, {min(rg)}), got {step_deg}")
        n2 = int(np.ceil(rg[0] / step_deg - 1e-9)) - 1
        n1 = int(np.ceil(rg[1] / step_deg - 1e-9)) - 1
        i2, i1 = np.meshgrid(np.arange(-n2, n2 + 1), np.arange(-n1, n1 + 1), indexing="xy")
        i2, i1 = i2.ravel(), i1.ravel()
        row = np.flatnonzero(i1 == 0)
        others = np.flatnonzero(i1 != 0)
        if not len(row) <= n_angles <= len(i1):
            raise ValueError(f"n_angles must lie in [{len(row)}, {len(i1)}] for this grid, got {n_angles}")
        pick = np.concatenate([row, np.sort(rng.choice(others, size=n_angles - len(row), replace=False))])
        phi2 = np.radians(i2[pick] * step_deg)
        phi1 = np.radians(i1[pick] * step_deg)
        zero_index = int(np.flatnonzero((i1[pick] == 0) & (i2[pick] == 0))[0])
        line_mask = i1[pick] == 0
    elif layout == "random":
        phi2 = np.radians(rng.uniform(-rg[0], rg[0], n_angles))
        phi1 = np.radians(rng.uniform(-rg[1], rg[1], n_angles))
        zero_index = -1
        line_mask = np.zeros(n_angles, bool)
    else:
        raise ValueError(f"layout must be 'grid' or 'random', got {layout!r}")
    v = rotary_table_vectors(phi1, phi2)
    if not callable(getattr(color_camera, "project", None)):
        raise TypeError(f"color_camera must be a ColorCamera, got {type(color_camera).__name__}")
    xy_true, in_frame = color_camera.project(v)
    xy_true = np.asarray(xy_true, float)
    if xy_true.shape != (3, len(v), 2):
        raise TypeError(f"color_camera must be a ColorCamera projecting onto 3 channels, got {type(color_camera).__name__}")
    if not np.all(in_frame):
        raise ValueError("range_deg puts the star off a detector; shrink range_deg")
    xy = xy_true + rng.normal(0.0, noise_px, size=xy_true.shape) if noise_px > 0 else xy_true.copy()
    return RotaryTableData(phi1_rad=phi1, phi2_rad=phi2, v_cam=v, xy=xy, xy_true=xy_true, noise_px=float(noise_px),
                           zero_index=zero_index, line_mask=line_mask)


@dataclass(frozen=True)
class ColorRegistration:
    """Registration of both the red and the blue channel onto green: what fusion needs.

    Attributes
    ----------
    red, blue : RegistrationParams
        Calibrated (``success``) transforms of the red and blue detectors into the green frame.
    """

    red: RegistrationParams
    blue: RegistrationParams

    def __post_init__(self):
        for name in ("red", "blue"):
            p = getattr(self, name)
            if not isinstance(p, RegistrationParams):
                raise TypeError(f"{name} must be a RegistrationParams, got {type(p).__name__}")
            if not p.success:
                raise ValueError(f"{name} registration failed ({p.status}); calibrate it again")

    @classmethod
    def calibrate(cls, data: RotaryTableData, rng: np.random.Generator | None = None, **kwargs) -> "ColorRegistration":
        """Calibrate both channels from rotary-table data (paper 004 §3); ``kwargs`` go to
        :func:`calibrate_registration` (``n_restarts``, ``model``). Raises ``ValueError`` if either fails."""
        if not isinstance(data, RotaryTableData):
            raise TypeError(f"data must be a RotaryTableData, got {type(data).__name__}")
        zero = data.zero_index if data.zero_index >= 0 else None
        pp = None if zero is not None else kwargs.pop("principal_point", None)
        line = data.line_mask if data.line_mask.sum() >= 2 else None
        out = {}
        for ch in ("red", "blue"):
            out[ch] = calibrate_registration(data.channel(ch), data.channel("green"), principal_point=pp, rng=rng,
                                             zero_index=zero, line_mask=line, **kwargs)
        return cls(**out)

    def _params(self, channel):
        if channel in ("green", 1):
            return None
        if channel in ("red", 0):
            return self.red
        if channel in ("blue", 2):
            return self.blue
        raise ValueError(f"channel must be one of {CHANNELS} or 0..2, got {channel!r}")

    def to_green(self, channel, xy) -> np.ndarray:
        """Channel pixel coordinates (K, 2) -> green frame (identity for green)."""
        p = self._params(channel)
        return as_float_array(xy, "xy", last_dim=2).copy() if p is None else p.apply(xy)

    def from_green(self, channel, xy_green) -> np.ndarray:
        """Green-frame pixel coordinates (K, 2) -> that channel's detector (identity for green)."""
        p = self._params(channel)
        return as_float_array(xy_green, "xy_green", last_dim=2).copy() if p is None else p.inverse(xy_green)
