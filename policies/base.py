"""The policy interface every controller in this package implements."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["Policy", "ControllerSpec"]


@dataclass(frozen=True)
class ControllerSpec:
    """What a controller may know about the spacecraft: its design, never its state.

    Attributes
    ----------
    inertia_kg_m2 : ndarray, shape (3, 3)
        Bus inertia (body frame).
    wheel_axes_body : ndarray, shape (3, n_wheels)
        Unit spin axes of the reaction wheels in the body frame.
    wheel_max_torque_Nm : float
        Torque limit of each wheel; action +1 commands this torque.
    max_rate_rad_s : float
        Body-rate limit the slew profile should respect (wheel momentum and tracker limits).
    control_period_s : float
    observation_layout : dict[str, slice]
        Where each quantity sits in the observation vector.
    """

    inertia_kg_m2: np.ndarray
    wheel_axes_body: np.ndarray
    wheel_max_torque_Nm: float
    max_rate_rad_s: float
    control_period_s: float
    observation_layout: dict

    @cached_property
    def wheel_allocation(self) -> np.ndarray:
        """Least-norm allocation, shape (n_wheels, 3): wheel torques ``= -wheel_allocation @ torque_body`` (a
        constant of the design, computed once)."""
        return np.linalg.pinv(self.wheel_axes_body)

    def body_torque_to_action(self, torque_body_Nm) -> np.ndarray:
        """Wheel commands in [-1, 1] producing the body torque ``torque_body_Nm`` (3,) (N m).

        A wheel accelerated by torque τ pushes the bus with −τ along its axis, hence the sign.
        The least-norm wheel torques are scaled down together (direction kept) if one saturates.
        """
        tau_w = -self.wheel_allocation @ np.asarray(torque_body_Nm, dtype=np.float64)
        cmd = tau_w / self.wheel_max_torque_Nm
        peak = np.max(np.abs(cmd)) if cmd.size else 0.0
        if peak > 1.0:
            cmd = cmd / peak
        return cmd.astype(np.float32)

    def max_torque_about(self, axis_body) -> float:
        """Largest body torque (N m) the wheels can produce about a unit axis."""
        a = np.asarray(axis_body, dtype=np.float64)
        a = a / np.linalg.norm(a)
        tau_w = -self.wheel_allocation @ a
        return float(self.wheel_max_torque_Nm / np.max(np.abs(tau_w)))


class Policy(ABC):
    """A controller acting on the environment's observation only.

    Subclasses implement :meth:`act`. ``reset`` is called at the start of each episode.
    """

    def __init__(self, spec: ControllerSpec):
        if not isinstance(spec, ControllerSpec):
            raise TypeError(f"spec must be a ControllerSpec, got {type(spec).__name__}")
        self.spec = spec

    @classmethod
    def from_env(cls, env, **kwargs) -> "Policy":
        """Build the policy from an env's design parameters (``env.unwrapped.controller_spec()``)."""
        spec = env.unwrapped.controller_spec()
        return cls(spec if isinstance(spec, ControllerSpec) else ControllerSpec(**spec), **kwargs)

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode."""

    @abstractmethod
    def act(self, observation: np.ndarray) -> np.ndarray:
        """Wheel torque commands, shape (n_wheels,), in [-1, 1], from one observation."""

    def read(self, observation, name: str) -> np.ndarray:
        """One named quantity of an observation, float64 (``name`` is a key of ``spec.observation_layout``).

        Names: ``attitude_error_rotvec`` (rad, body), ``omega_body`` (rad/s), ``wheel_momentum_fraction``,
        ``tracker_mode`` (one-hot lost/acquire/track), ``attitude_sigma`` (rad).
        """
        layout = self.spec.observation_layout
        if name not in layout:
            raise ValueError(f"name must be one of {sorted(layout)}, got {name!r}")
        return np.asarray(observation, dtype=np.float64)[self.spec.observation_layout[name]]
