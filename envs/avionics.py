"""The env's avionics: the onboard star tracker unit, configured from the env's keyword arguments.

The env owns the loop: it steps the spacecraft, records the truth history of the step
(:meth:`envs.spacecraft.Spacecraft.step_recording`) and hands it to :meth:`Avionics.observe`, which samples the
gyro, images and processes the camera frames and runs the filter over it (:class:`startracker.onboard.StarTrackerUnit`).
The avionics never integrate physics.
"""

from __future__ import annotations

from dataclasses import dataclass

from startracker.onboard import Estimate, MODES, StarTrackerUnit, UnitConfig

__all__ = ["Avionics", "AvionicsConfig", "Estimate", "TRACKER_MODES"]

TRACKER_MODES = MODES


@dataclass(frozen=True)
class AvionicsConfig(UnitConfig):
    """The unit's settings (:class:`startracker.onboard.UnitConfig`) plus the env's control period.

    Attributes
    ----------
    control_period_s : float
        Time between actions, s: a whole number of frame periods.
    """

    control_period_s: float = 0.1

    def __post_init__(self):
        # whole frames per control period first: a frame rate the env cannot step is the env argument to name
        if self.frame_period_s is not None:
            self._check_ratio()
        super().__post_init__()  # resolves the frame period from the camera spec
        self._check_ratio()

    def _check_ratio(self) -> None:
        ratio = self.control_period_s / self.frame_period_s
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(
                "frame_rate_hz * control_period_s must be a positive integer (whole frames per control period), "
                f"got {ratio:.6g}"
            )


class Avionics(StarTrackerUnit):
    """Star tracker heads + gyro + MEKF observing the spacecraft's truth history.

    Parameters
    ----------
    config : AvionicsConfig, optional
        Default ``AvionicsConfig()``.
    """

    def __init__(self, config: AvionicsConfig | None = None):
        config = AvionicsConfig() if config is None else config
        if not isinstance(config, AvionicsConfig):
            raise TypeError("config must be an AvionicsConfig")
        super().__init__(config)
