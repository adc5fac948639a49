"""Gymnasium side of startracker-gym. Importing this package registers the environment ids.

* ``startracker/AgileSlew-v0``: random large-angle slews to a target attitude.
* ``startracker/AttitudeHold-v0``: hold an inertial target under a disturbance torque.
"""

from gymnasium.envs.registration import register, registry

ENV_IDS = ("startracker/AgileSlew-v0", "startracker/AttitudeHold-v0")
# info entries measured on the wall clock of this machine: reported, never fed back, so not bit-for-bit repeatable
WALL_CLOCK_INFO_KEYS = ("matching_latency_ms", "matching_latency_ms_per_head", "latency_breakdown_ms")

if ENV_IDS[0] not in registry:
    register(
        id=ENV_IDS[0],
        entry_point="envs.agile_slew:AgileSlewEnv",
        kwargs={"task": "slew"},
        max_episode_steps=None,
    )
if ENV_IDS[1] not in registry:
    register(
        id=ENV_IDS[1],
        entry_point="envs.agile_slew:AgileSlewEnv",
        kwargs={"task": "hold", "max_episode_s": 60.0},
        max_episode_steps=None,
    )

__all__ = ["ENV_IDS", "WALL_CLOCK_INFO_KEYS"]
