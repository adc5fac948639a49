"""3CMOS colour star tracker, the camera: star colour -> channel electrons and per-channel optics (paper 004).

* **star colour**: B−V -> effective temperature (Ballesteros 2012, EPL 97, 34008), a Planck photon
  spectrum through each channel's band (blue 400–500 nm, green 490–590 nm, red 580–680 nm) and a
  detector QE curve -> relative electrons per channel (:class:`ChannelResponse`);
* **per-channel optics**: :class:`ColorCamera`, three :class:`~startracker.optics.Camera` objects that
  share the optics (detector size, pixel pitch, mounting) but each have their own focal length,
  principal point, first-order radial distortion and an in-plane detector rotation (paper 004
  eqs. 1-3 and 21-23, Table 1 as :meth:`ColorCamera.paper004`).

Channel order everywhere is ``CHANNELS = ("red", "green", "blue")``: arrays with a channel axis index it
in that order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from startracker.color.registration import CHANNELS, RegistrationParams
from startracker.optics import Camera
from startracker.validation import as_float_array

__all__ = [
    "BANDS_NM",
    "BV_RANGE",
    "DEFAULT_RESPONSE",
    "bv_to_teff",
    "planck_photon_radiance",
    "ChannelResponse",
    "ChannelCamera",
    "ColorCamera",
]

#: Detection bands of the JAI AP-3200T prism camera used in paper 004 §4.3, nm.
BANDS_NM: dict[str, tuple[float, float]] = {"red": (580.0, 680.0), "green": (490.0, 590.0), "blue": (400.0, 500.0)}

# Physical constants (CODATA 2018, exact in the SI).
_H = 6.62607015e-34  # J s
_C = 299792458.0  # m / s
_KB = 1.380649e-23  # J / K
_C2_NM_K = _H * _C / _KB * 1e9  # second radiation constant hc/k in nm K (1.4387768775e7)

#: B−V accepted by :func:`bv_to_teff`. The Hipparcos catalog spans −0.40 .. 5.46; the formula is singular
#: at B−V = −0.674.
BV_RANGE = (-0.6, 6.0)

# Quantum efficiency of a front-illuminated global-shutter CMOS of the Sony Pregius family (the IMX265,
# 3.45 µm pixels, 2064×1544, is the detector of the AP-3200T of paper 004). Representative values
# shaped after the manufacturer's published relative response with a 65 % peak; not a measurement.
_QE_WAVELENGTH_NM = np.array([380, 400, 425, 450, 475, 500, 525, 550, 575, 600, 625, 650, 675, 700, 720], float)
_QE_VALUE = np.array([0.25, 0.38, 0.50, 0.58, 0.63, 0.65, 0.65, 0.63, 0.59, 0.55, 0.50, 0.45, 0.40, 0.35, 0.31])

# Johnson V passband approximated by a Gaussian (centre 551 nm, FWHM 88 nm; Bessell 1990): only used to
# give stars of equal V magnitude the same V-band flux, so that channel electrons scale with 10^(-0.4 V).
_V_CENTER_NM = 551.0
_V_SIGMA_NM = 88.0 / 2.3548200450309493


def bv_to_teff(bv) -> np.ndarray:
    """Effective temperature from the B−V colour index (Ballesteros 2012, EPL 97, 34008, eq. 14).

    ``T = 4600 K * (1 / (0.92 (B−V) + 1.7) + 1 / (0.92 (B−V) + 0.62))``, derived for black bodies
    and calibrated on main-sequence stars; about 3 % accurate for 3 000 K .. 10 000 K and cruder outside
    (hot stars saturate in B−V).

    Parameters
    ----------
    bv : array_like, shape (K,) or scalar
        B−V in magnitudes, within ``BV_RANGE`` = (−0.6, 6.0).

    Returns
    -------
    teff_k : ndarray, same shape as ``bv``
        Effective temperature in kelvin.
    """
    b = as_float_array(bv, "bv")
    if np.any((b < BV_RANGE[0]) | (b > BV_RANGE[1])):
        raise ValueError(f"bv must lie in [{BV_RANGE[0]}, {BV_RANGE[1]}] mag (Ballesteros 2012 formula), got "
                         f"min {b.min():.3f}, max {b.max():.3f}")
    return 4600.0 * (1.0 / (0.92 * b + 1.7) + 1.0 / (0.92 * b + 0.62))


def planck_photon_radiance(wavelength_nm, teff_k) -> np.ndarray:
    """Black-body photon spectral radiance, up to a constant factor.

    ``N_λ(T) ∝ B_λ(T) λ / (h c) ∝ λ^-4 / (exp(hc / (λ k T)) - 1)`` (photons per unit wavelength).

    Parameters
    ----------
    wavelength_nm : array_like, shape (L,)
        Wavelengths in nm (> 0).
    teff_k : array_like, shape (K,) or scalar
        Temperatures in K (> 0).

    Returns
    -------
    ndarray, shape (K, L) (or (L,) for a scalar temperature)
        Photon radiance in units of ``2 c / (1 nm)^4`` per steradian; only ratios are meaningful here.
    """
    lam = as_float_array(wavelength_nm, "wavelength_nm")
    t = as_float_array(teff_k, "teff_k")
    if np.any(lam <= 0):
        raise ValueError("wavelength_nm must be positive")
    if np.any(t <= 0):
        raise ValueError("teff_k must be positive")
    x = _C2_NM_K / (np.atleast_1d(t)[:, None] * np.atleast_1d(lam)[None, :])
    out = np.atleast_1d(lam)[None, :] ** -4.0 / np.expm1(x)
    return out[0] if t.ndim == 0 else out


@dataclass(frozen=True)
class ChannelResponse:
    """Relative electrons collected by each channel of a 3CMOS sensor from a star of given colour.

    Each channel collects ``∫ N_λ(T) QE(λ) S_c(λ) dλ`` where ``N_λ`` is the star's Planck photon spectrum
    scaled to a fixed V-band flux (so that stars of equal V magnitude are compared), ``QE`` the detector
    quantum efficiency and ``S_c`` the channel's top-hat band. The result is normalised so that a star of
    B−V = 0 (Vega-like, T ≈ 10 100 K by the Ballesteros relation) yields a channel sum of exactly 1:
    multiply by a monochrome imaging model's electrons for a V-magnitude star to get each channel's signal.

    Parameters
    ----------
    bands_nm : dict, optional
        ``{"red": (lo, hi), "green": (lo, hi), "blue": (lo, hi)}`` in nm; default :data:`BANDS_NM`.
    qe_wavelength_nm, qe : array_like, shape (L,), optional
        QE curve sampled at increasing wavelengths (fractions in [0, 1]); linear interpolation between
        samples. Default: a representative Sony Pregius front-illuminated CMOS curve (65 % peak).
    step_nm : float
        Integration step of the trapezoid rule, nm.
    """

    bands_nm: dict = field(default_factory=lambda: dict(BANDS_NM))
    qe_wavelength_nm: tuple = tuple(_QE_WAVELENGTH_NM)
    qe: tuple = tuple(_QE_VALUE)
    step_nm: float = 1.0

    def __post_init__(self):
        if set(self.bands_nm) != set(CHANNELS):
            raise ValueError(f"bands_nm must have exactly the keys {CHANNELS}, got {sorted(self.bands_nm)}")
        bands = {}
        for c in CHANNELS:
            lo, hi = (float(v) for v in as_float_array(self.bands_nm[c], f"bands_nm[{c!r}]", last_dim=2, ndim=1))
            if not 0 < lo < hi:
                raise ValueError(f"bands_nm[{c!r}] must satisfy 0 < lo < hi, got ({lo}, {hi})")
            bands[c] = (lo, hi)
        object.__setattr__(self, "bands_nm", bands)
        wl = as_float_array(self.qe_wavelength_nm, "qe_wavelength_nm", ndim=1)
        qe = as_float_array(self.qe, "qe", ndim=1)
        if wl.shape != qe.shape or wl.size < 2:
            raise ValueError("qe_wavelength_nm and qe must be 1-D of the same length >= 2")
        if np.any(np.diff(wl) <= 0):
            raise ValueError("qe_wavelength_nm must be strictly increasing")
        if np.any((qe < 0) | (qe > 1)):
            raise ValueError("qe must lie in [0, 1]")
        if not (np.isfinite(self.step_nm) and 0 < self.step_nm <= 10):
            raise ValueError(f"step_nm must lie in (0, 10] nm, got {self.step_nm}")
        object.__setattr__(self, "qe_wavelength_nm", tuple(wl))
        object.__setattr__(self, "qe", tuple(qe))

    # ---------------------------------------------------------------- tables
    @cached_property
    def _weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Wavelength grid (L,), channel weights QE*S_c*trapezoid (L, 3), V-band weights (L,)."""
        lo = min(b[0] for b in self.bands_nm.values())
        hi = max(b[1] for b in self.bands_nm.values())
        lo_v, hi_v = _V_CENTER_NM - 5 * _V_SIGMA_NM, _V_CENTER_NM + 5 * _V_SIGMA_NM
        lo, hi = min(lo, lo_v), max(hi, hi_v)
        n = int(np.ceil((hi - lo) / self.step_nm)) + 1
        lam = np.linspace(lo, hi, n)
        dl = np.full(n, lam[1] - lam[0])
        dl[[0, -1]] *= 0.5  # trapezoid
        qe = np.interp(lam, self.qe_wavelength_nm, self.qe, left=0.0, right=0.0)
        w = np.empty((n, 3))
        for i, c in enumerate(CHANNELS):
            b_lo, b_hi = self.bands_nm[c]
            # Top-hat band; the two edge samples get the fraction of their cell inside the band so the
            # integral is continuous in the band edges.
            cell_lo, cell_hi = lam - 0.5 * (lam[1] - lam[0]), lam + 0.5 * (lam[1] - lam[0])
            inside = np.clip((np.minimum(cell_hi, b_hi) - np.maximum(cell_lo, b_lo)) / (cell_hi - cell_lo), 0, 1)
            w[:, i] = qe * inside * (lam[1] - lam[0])
        # V-band flux is an energy flux: photon radiance * h c / λ -> weight by 1/λ (constants dropped).
        wv = np.exp(-0.5 * ((lam - _V_CENTER_NM) / _V_SIGMA_NM) ** 2) * dl / lam
        return lam, w, wv

    def _raw(self, teff_k: np.ndarray) -> np.ndarray:
        lam, w, wv = self._weights
        out = np.empty((teff_k.size, 3))
        for s in range(0, teff_k.size, 4096):  # chunks keep the (K, L) spectrum matrix small
            spec = planck_photon_radiance(lam, teff_k[s:s + 4096])
            out[s:s + 4096] = (spec @ w) / (spec @ wv)[:, None]
        return out

    @cached_property
    def _norm(self) -> float:
        return float(self._raw(np.atleast_1d(bv_to_teff(0.0))).sum())

    # ---------------------------------------------------------------- public
    def electrons(self, bv) -> np.ndarray:
        """Relative electrons per channel for stars of equal V magnitude.

        Parameters
        ----------
        bv : array_like, shape (K,)
            B−V colour indices, mag.

        Returns
        -------
        ndarray, shape (K, 3)
            Electrons in (red, green, blue), relative to the channel sum of a B−V = 0 star of the same V.
        """
        b = as_float_array(bv, "bv")
        return self._raw(np.atleast_1d(bv_to_teff(b)).ravel()) / self._norm

    def fractions(self, bv) -> np.ndarray:
        """Share of each channel in the star's total signal, shape (K, 3), rows sum to 1."""
        e = self.electrons(bv)
        return e / e.sum(axis=1, keepdims=True)

    def color_ratio(self, bv) -> np.ndarray:
        """The colour feature used for identification: ``ln(e_red / e_blue)``, shape (K,).

        Monotone increasing in B−V (redder star, larger ratio), 0 where red and blue collect equally.
        """
        e = self.electrons(bv)
        return np.log(e[:, 0] / e[:, 2])


DEFAULT_RESPONSE = ChannelResponse()


def _rot2(theta_rad: float) -> np.ndarray:
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class ChannelCamera(Camera):
    """One channel of a :class:`ColorCamera`: a :class:`~startracker.optics.Camera` whose detector is rotated
    in its plane by ``rotation_rad`` about the principal point (paper 004 eq. 22).

    ``project`` returns ``pp + R(θ)^T (Camera.project(v) - pp)``; ``unproject`` inverts it. Everything else
    (resolution, focal length, distortion, mounting) is the parent's, so a ``ChannelCamera`` goes wherever a
    ``Camera`` does (scene, imaging, identification).

    Parameters
    ----------
    rotation_rad : float
        In-plane rotation θ of the detector, rad, within ±5°.
    (all other parameters as :class:`~startracker.optics.Camera`)
    """

    rotation_rad: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        if not isinstance(self.rotation_rad, (int, float, np.floating, np.integer)) or not np.isfinite(self.rotation_rad) \
                or abs(self.rotation_rad) > np.radians(5.0):
            raise ValueError(f"rotation_rad must be finite and within ±5° (detector alignment), got {self.rotation_rad!r}")
        object.__setattr__(self, "rotation_rad", float(self.rotation_rad))

    @classmethod
    def from_camera(cls, camera: Camera, rotation_rad: float = 0.0, name: str | None = None) -> "ChannelCamera":
        return cls(resolution=camera.resolution, pixel_size_um=camera.pixel_size_um,
                   focal_length_mm=camera.focal_length_mm, principal_point=camera.principal_point,
                   distortion_k1_per_mm2=camera.distortion_k1_per_mm2, q_cam_to_body=camera.q_cam_to_body,
                   name=camera.name if name is None else name, rotation_rad=rotation_rad)

    def project(self, v_cam, return_in_front: bool = False, *, validate: bool = True):
        """As :meth:`Camera.project`, on the rotated detector (paper 004 eqs. 22-23)."""
        xy, _, in_front = super().project(v_cam, return_in_front=True, validate=validate)
        single = np.ndim(xy) == 1
        xy = np.atleast_2d(xy)
        if self.rotation_rad != 0.0:
            pp = np.asarray(self.principal_point)
            xy = pp + (xy - pp) @ _rot2(self.rotation_rad)  # row-vector form of R(θ)^T (xy - pp)
        w, h = self.resolution
        in_frame = (np.atleast_1d(in_front) & (xy[:, 0] >= -0.5) & (xy[:, 0] <= w - 0.5) & (xy[:, 1] >= -0.5)
                    & (xy[:, 1] <= h - 0.5))
        if single:
            xy, in_frame = xy[0], in_frame[0]
        return (xy, in_frame, in_front) if return_in_front else (xy, in_frame)

    def unproject(self, xy) -> np.ndarray:
        """As :meth:`Camera.unproject`, from the rotated detector."""
        xy_arr = as_float_array(xy, "xy", last_dim=2)
        if self.rotation_rad != 0.0:
            pp = np.asarray(self.principal_point)
            xy_arr = pp + (xy_arr - pp) @ _rot2(self.rotation_rad).T
        return super().unproject(xy_arr)

    def with_mounting(self, q_cam_to_body, name: str | None = None) -> "ChannelCamera":
        return ChannelCamera.from_camera(super().with_mounting(q_cam_to_body, name), self.rotation_rad)


@dataclass(frozen=True)
class ColorCamera:
    """Three detectors behind one lens and a colour-splitting prism (paper 004 §2.1, eqs. 21-23).

    The sensor frame is the green channel's camera frame (paper 004 §3.1). Channel ``c`` images a
    camera-frame direction ``v`` as

    ``xy_c = pp_c + R(θ_c)^T (Camera_c.project(v) - pp_c)``  (eq. 22 with ``R(θ) = [[cos, -sin], [sin, cos]]``)

    where ``Camera_c`` holds the channel's focal length ``F_c``, principal point ``pp_c`` and radial
    distortion ``m_c`` (eqs. 1-3) and ``θ_c`` is the in-plane rotation of the channel's detector, with the
    sign of paper 004: the registration ``x_g = k R(θ) (x_c - x0) + x0 - Δ`` that maps the channel onto
    green has ``θ = θ_c``, ``k = F_g / F_c`` and ``Δ = pp_c - pp_g`` (eqs. 14-15; exact when ``m_c = m_g``).

    Parameters
    ----------
    red, green, blue : Camera
        The channels. They must share resolution, pixel size and mounting (one sensor head).
    rotation_rad : (float, float, float)
        In-plane rotations ``(θ_r, θ_g, θ_b)`` in rad relative to the green frame; ``θ_g`` must be 0.
    response : ChannelResponse
        Spectral response of the three channels.
    name : str
        Free label.
    """

    red: Camera
    green: Camera
    blue: Camera
    rotation_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    response: ChannelResponse = DEFAULT_RESPONSE
    name: str = "custom"
    _channels: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        for c in CHANNELS:
            if not isinstance(getattr(self, c), Camera):
                raise TypeError(f"{c} must be a startracker.optics.Camera, got {type(getattr(self, c)).__name__}")
        g = self.green
        for c in ("red", "blue"):
            cam = getattr(self, c)
            if cam.resolution != g.resolution:
                raise ValueError(f"{c}.resolution {cam.resolution} differs from green.resolution {g.resolution}")
            if cam.pixel_size_um != g.pixel_size_um:
                raise ValueError(f"{c}.pixel_size_um {cam.pixel_size_um} differs from green's {g.pixel_size_um}")
            if not np.allclose(cam.q_cam_to_body, g.q_cam_to_body, atol=1e-12):
                raise ValueError(f"{c}.q_cam_to_body differs from green's: the channels share one mounting")
        rot = as_float_array(self.rotation_rad, "rotation_rad", last_dim=3, ndim=1)
        if rot[1] != 0.0:
            raise ValueError(f"rotation_rad[1] (green) must be 0: green is the reference frame, got {rot[1]}")
        if np.any(np.abs(rot) > np.radians(5.0)):
            raise ValueError(f"rotation_rad must stay within ±5° (detector alignment error), got {np.degrees(rot)} deg")
        object.__setattr__(self, "rotation_rad", tuple(float(v) for v in rot))
        if not isinstance(self.response, ChannelResponse):
            raise TypeError("response must be a ChannelResponse")
        object.__setattr__(self, "_channels", tuple(
            ChannelCamera.from_camera(cam, th) for cam, th in zip((self.red, self.green, self.blue), rot)))

    # ---------------------------------------------------------------- presets
    @classmethod
    def paper004(cls, translation: str = "table1", q_cam_to_body=(1.0, 0.0, 0.0, 0.0),
                 response: ChannelResponse = DEFAULT_RESPONSE) -> "ColorCamera":
        """The simulated 3CMOS sensor of paper 004 §4.1 (2064×1544 px of 3.45 µm, 16°×12°).

        Focal lengths and distortion from Table 1, rotations from Table 2 (θ_rg = 0.07°, θ_bg = −0.05°).

        Parameters
        ----------
        translation : {"table1", "table2"}
            ``"table1"``: principal points of Table 1 (red (1033.9, 774.3), green (1032, 772), blue
            (1030.6, 770.4)), i.e. Δ_rg = (1.9, 2.3) px and Δ_bg = (−1.4, −1.6) px by eq. 14.
            ``"table2"``: principal points chosen so that eq. 14 gives Table 2's translations
            Δ_rg = (0.3, 0.5) px and Δ_bg = (−0.4, −0.6) px. The paper's Tables 1 and 2 disagree on the
            translation (Table 2 claims to follow from Table 1); both readings are offered.
        q_cam_to_body : array_like, shape (4,)
            Mounting of the sensor head.
        response : ChannelResponse
            Spectral response.
        """
        if translation not in ("table1", "table2"):
            raise ValueError(f"translation must be 'table1' or 'table2', got {translation!r}")
        pp_g = (1032.0, 772.0)
        if translation == "table1":
            pp = {"red": (1033.9, 774.3), "green": pp_g, "blue": (1030.6, 770.4)}
        else:
            pp = {"red": (pp_g[0] + 0.3, pp_g[1] + 0.5), "green": pp_g, "blue": (pp_g[0] - 0.4, pp_g[1] - 0.6)}
        focal = {"red": 25.0601, "green": 25.0, "blue": 24.95}
        m = {"red": 5.7e-5, "green": 4.9e-5, "blue": 3.6e-5}
        cams = {
            c: Camera(resolution=(2064, 1544), pixel_size_um=3.45, focal_length_mm=focal[c], principal_point=pp[c],
                      distortion_k1_per_mm2=m[c], q_cam_to_body=q_cam_to_body, name=f"paper004-{c}")
            for c in CHANNELS
        }
        return cls(**cams, rotation_rad=(np.radians(0.07), 0.0, np.radians(-0.05)), response=response,
                   name=f"paper004-{translation}")

    # ---------------------------------------------------------------- geometry
    @property
    def cameras(self) -> tuple[Camera, Camera, Camera]:
        """The three channel cameras in ``CHANNELS`` order."""
        return (self.red, self.green, self.blue)

    @property
    def resolution(self) -> tuple[int, int]:
        return self.green.resolution

    def channel_index(self, channel) -> int:
        """Index of a channel given by name ("red", "green", "blue") or index 0..2."""
        if isinstance(channel, str):
            if channel not in CHANNELS:
                raise ValueError(f"channel must be one of {CHANNELS}, got {channel!r}")
            return CHANNELS.index(channel)
        if isinstance(channel, (int, np.integer)) and 0 <= channel < 3:
            return int(channel)
        raise ValueError(f"channel must be one of {CHANNELS} or 0..2, got {channel!r}")

    def channel_camera(self, channel) -> ChannelCamera:
        """The :class:`ChannelCamera` (optics + detector rotation) of one channel, usable as a ``Camera``."""
        return self._channels[self.channel_index(channel)]

    @property
    def channel_cameras(self) -> tuple[ChannelCamera, ChannelCamera, ChannelCamera]:
        """The three channel cameras in ``CHANNELS`` order."""
        return self._channels

    def project_channel(self, channel, v_cam) -> tuple[np.ndarray, np.ndarray]:
        """Project camera-frame directions onto one channel's detector (paper 004 eqs. 21-23).

        Parameters
        ----------
        channel : str or int
            "red", "green", "blue" or 0, 1, 2.
        v_cam : array_like, shape (K, 3)
            Directions in the sensor (green camera) frame.

        Returns
        -------
        xy : ndarray, shape (K, 2)
            Pixel coordinates (column, row) on that detector.
        in_frame : ndarray of bool, shape (K,)
            In front of the camera and on the detector.
        """
        return self.channel_camera(channel).project(v_cam)

    def project(self, v_cam) -> tuple[np.ndarray, np.ndarray]:
        """Project onto all three channels.

        Returns
        -------
        xy : ndarray, shape (3, K, 2)
            Pixel coordinates per channel in ``CHANNELS`` order.
        in_frame : ndarray of bool, shape (3, K)
        """
        out = [self.project_channel(i, v_cam) for i in range(3)]
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])

    def unproject_channel(self, channel, xy) -> np.ndarray:
        """Pixel coordinates on one channel's detector -> unit directions in the sensor frame, (K, 3)."""
        return self.channel_camera(channel).unproject(xy)

    def registration_truth(self, channel) -> RegistrationParams:
        """The registration parameters implied by the channel models (paper 004 eqs. 6, 14, 15).

        ``k = F_g / F_c``, ``θ = θ_c``, ``Δ = pp_c - pp_g`` with ``x0 = pp_c``. Exact for the pinhole part;
        the radial distortion difference ``m_c - m_g`` is what the paper's model neglects (eq. 8), so a
        least-squares fit converges to slightly different values even without noise.
        """
        i = self.channel_index(channel)
        cam, g = self.cameras[i], self.green
        pp_c, pp_g = np.asarray(cam.principal_point), np.asarray(g.principal_point)
        d = pp_c - pp_g
        return RegistrationParams(
            k=g.focal_length_mm / cam.focal_length_mm, theta_rad=self.rotation_rad[i], dx_px=float(d[0]),
            dy_px=float(d[1]), principal_point=(float(pp_c[0]), float(pp_c[1])), rmse_px=0.0, success=True,
            status="truth from the channel models", n_points=0,
        )

