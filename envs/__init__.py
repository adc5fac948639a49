"""Gymnasium side of startracker-gym. Importing this package registers the environment ids.

* ``startracker/AgileSlew-v0``: random large-angle slews to a target attitude.
* ``startracker/AttitudeHold-v0``: hold an inertial target under a disturbance torque.
* ``startracker/AgileSlew-v1``: the slew task shaped for learners (body-torque action, scaled observation, shaped
  reward, divergence termination, optional ideal sensor).

``gymnasium.make`` wraps each in :class:`envs.wrappers.WallClockLatency`, which adds this machine's wall-clock
matching time to ``info``; the environment itself (``env.unwrapped``) reports only what the seed and the actions
determine.
"""

import warnings

from gymnasium.envs.registration import WrapperSpec, register, registry

ENV_IDS = ("startracker/AgileSlew-v0", "startracker/AttitudeHold-v0", "startracker/AgileSlew-v1")
# info entries measured on the wall clock of this machine, added by the WallClockLatency wrapper: reported, never
# fed back, so not bit-for-bit repeatable (the raw environment has none)
WALL_CLOCK_INFO_KEYS = ("matching_wall_clock_ms", "matching_wall_clock_ms_per_head", "wall_clock_breakdown_ms")
WALL_CLOCK_WRAPPER = WrapperSpec("WallClockLatency", "envs.wrappers:WallClockLatency", {})

if ENV_IDS[0] not in registry:
    register(
        id=ENV_IDS[0],
        entry_point="envs.agile_slew:AgileSlewEnv",
        kwargs={"task": "slew"},
        max_episode_steps=None,
        additional_wrappers=(WALL_CLOCK_WRAPPER,),
    )
if ENV_IDS[1] not in registry:
    register(
        id=ENV_IDS[1],
        entry_point="envs.agile_slew:AgileSlewEnv",
        kwargs={"task": "hold", "max_episode_s": 60.0},
        max_episode_steps=None,
        additional_wrappers=(WALL_CLOCK_WRAPPER,),
    )
# -v1's default episode: 5-180 deg slews fit in 33.4 s (envs.agile_slew_v1.episode_seconds_for), 334 steps of 0.1 s
V1_MAX_EPISODE_STEPS = 334
if ENV_IDS[2] not in registry:
    register(
        id=ENV_IDS[2],
        entry_point="envs.agile_slew_v1:AgileSlewV1Env",
        max_episode_steps=V1_MAX_EPISODE_STEPS,
        additional_wrappers=(WALL_CLOCK_WRAPPER,),
    )

# gymnasium calls a lower version "out of date" once a higher one is registered; v0 is the engineer's task, not a
# deprecated one, so that one message is silenced
warnings.filterwarnings("ignore", message=r".*startracker/AgileSlew-v0 is out of date.*")

__all__ = ["ENV_IDS", "WALL_CLOCK_INFO_KEYS", "WALL_CLOCK_WRAPPER", "V1_MAX_EPISODE_STEPS"]
