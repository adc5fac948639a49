"""Scripted attitude controllers: quaternion-feedback PD, eigenaxis bang-coast-bang slew, random."""

from __future__ import annotations

import numpy as np

from policies.base import ControllerSpec, Policy

__all__ = ["PDPolicy", "EigenaxisSlewPolicy", "RandomPolicy", "ZeroPolicy"]


class PDPolicy(Policy):
    """Quaternion-feedback PD (Wie 1989): τ = J (ωn² e − 2ζ ωn ω).

    ``e`` is the estimated attitude error rotation vector toward the target (body frame, rad), ``ω`` the
    estimated body rate. The natural frequency is chosen so that a full-torque step stays in the linear
    range for small errors; large slews saturate the wheels and the motion is slow but stable.

    Parameters
    ----------
    spec : ControllerSpec
    natural_frequency_rad_s : float
        ωn, default 0.5 rad/s.
    damping_ratio : float
        ζ, default 0.9.
    """

    def __init__(self, spec: ControllerSpec, natural_frequency_rad_s: float = 0.5, damping_ratio: float = 0.9):
        super().__init__(spec)
        if natural_frequency_rad_s <= 0 or damping_ratio <= 0:
            raise ValueError("natural_frequency_rad_s and damping_ratio must be positive")
        self.wn = float(natural_frequency_rad_s)
        self.zeta = float(damping_ratio)

    def act(self, observation):
        e = self.read(observation, "attitude_error_rotvec")
        w = self.read(observation, "omega_body")
        torque = self.spec.inertia_kg_m2 @ (self.wn**2 * e - 2 * self.zeta * self.wn * w)
        return self.spec.body_torque_to_action(torque)


class EigenaxisSlewPolicy(Policy):
    """Eigenaxis slew with a bang-coast-bang rate profile, then PD capture.

    Along the error axis ``n`` the commanded rate is ``ω_ref = min(ω_max, sqrt(2 η α θ))``: full
    acceleration, coast at the rate limit, and deceleration on the parabola that stops at the target,
    where ``α`` is the acceleration the wheels can give about ``n`` and ``η < 1`` a margin. A rate loop
    tracks ``ω_ref n`` (with gyroscopic feed-forward); inside ``capture_angle_rad`` a PD takes over.

    Parameters
    ----------
    spec : ControllerSpec
    accel_margin : float
        η in (0, 1], fraction of the available acceleration used on the deceleration parabola.
    rate_gain_rad_s : float
        Bandwidth of the rate loop.
    capture_angle_rad : float
        Below this error the PD of :class:`PDPolicy` is used.
    terminal_gain_rad_s : float
        Near the target the commanded rate is at most ``terminal_gain · θ`` (exponential approach).
    """

    def __init__(
        self,
        spec: ControllerSpec,
        accel_margin: float = 0.7,
        rate_gain_rad_s: float = 4.0,
        capture_angle_rad: float = np.radians(0.05),
        terminal_gain_rad_s: float = 0.8,
    ):
        super().__init__(spec)
        if not 0 < accel_margin <= 1:
            raise ValueError(f"accel_margin must be in (0, 1], got {accel_margin}")
        self.eta = float(accel_margin)
        self.k_rate = float(rate_gain_rad_s)
        self.capture = float(capture_angle_rad)
        if terminal_gain_rad_s <= 0:
            raise ValueError(f"terminal_gain_rad_s must be > 0, got {terminal_gain_rad_s}")
        self.terminal_gain = float(terminal_gain_rad_s)
        self._pd = PDPolicy(spec, natural_frequency_rad_s=1.0, damping_ratio=0.9)

    def act(self, observation):
        e = self.read(observation, "attitude_error_rotvec")
        w = self.read(observation, "omega_body")
        theta = float(np.linalg.norm(e))
        if theta < self.capture:
            return self._pd.act(observation)
        n = e / theta
        j = self.spec.inertia_kg_m2
        jn = float(n @ j @ n)
        alpha = self.spec.max_torque_about(n) / jn
        # deceleration must also absorb the sampling delay of one control period
        w_ref_mag = min(self.spec.max_rate_rad_s, np.sqrt(2 * self.eta * alpha * theta))
        w_ref_mag = max(0.0, w_ref_mag - alpha * self.spec.control_period_s * 0.5)
        # near the target the parabola's slope is infinite: blend into an exponential approach (time constant
        # 1/terminal_gain) so the PD capture starts from a rate it can absorb without overshoot
        w_ref_mag = min(w_ref_mag, self.terminal_gain * theta)
        w_ref = w_ref_mag * n
        torque = j @ (self.k_rate * (w_ref - w)) + np.cross(w, j @ w)
        return self.spec.body_torque_to_action(torque)


class RandomPolicy(Policy):
    """Uniform random wheel commands in [-1, 1] (seeded by :meth:`reset`)."""

    def __init__(self, spec: ControllerSpec, seed: int | None = None):
        super().__init__(spec)
        self._rng = np.random.default_rng(seed)

    def reset(self, seed=None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)

    def act(self, observation):
        n = self.spec.wheel_axes_body.shape[1]
        return self._rng.uniform(-1.0, 1.0, n).astype(np.float32)


class ZeroPolicy(Policy):
    """No torque: the spacecraft drifts (a baseline for the hold task and for tracker evaluation)."""

    def act(self, observation):
        return np.zeros(self.spec.wheel_axes_body.shape[1], dtype=np.float32)
