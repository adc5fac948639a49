"""Wrappers of the startracker environments.

:class:`WallClockLatency` reports this machine's wall-clock time of the star tracker's prediction and matching, the
way Gymnasium reports wall time (``RecordEpisodeStatistics`` puts the episode's elapsed time in ``info``): by a
wrapper, outside the environment, so that the environment's own ``info`` stays a function of the seed and the
actions. ``gymnasium.make`` applies it to every ``startracker/*`` id (the registration's ``additional_wrappers``);
``env.unwrapped`` or ``gymnasium.make(id).env`` drop it. The simulated tracker's latency, from its processor model,
is ``info["matching_latency_ms"]`` in the environment itself.
"""

from __future__ import annotations

import gymnasium as gym

from envs import WALL_CLOCK_INFO_KEYS

__all__ = ["WallClockLatency", "WALL_CLOCK_INFO_KEY"]

WALL_CLOCK_INFO_KEY = "matching_wall_clock_ms"


class WallClockLatency(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Adds ``info["matching_wall_clock_ms"]``: the wall clock of one frame's tracking work on this machine
    (prediction, matching, grouping by instant, the N Wahba solutions and the lock tests, summed over the heads), ms
    (mean over the step's frames; 0 when no tracking attempt ran), with ``matching_wall_clock_ms_per_head`` and
    ``wall_clock_breakdown_ms`` (``predict_match``, ``group_solve_test``, ``identify``). A measurement of the computer, not
    of the simulation: never fed back, and not repeatable bit for bit.

    Parameters
    ----------
    env : gymnasium.Env
        A startracker environment (its ``unwrapped`` has ``matching_wall_clock_ms``).
    """

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        if not hasattr(env.unwrapped, "wall_clock_info"):
            raise TypeError("WallClockLatency wraps a startracker environment (one with wall_clock_info)")
        self._base = env.unwrapped  # found once: the wrapper chain is fixed
        wanted = getattr(self._base, "info_keys", None)  # the env's info_keys: only the wall-clock keys it names
        self._keys = WALL_CLOCK_INFO_KEYS if wanted is None else tuple(k for k in wanted if k in WALL_CLOCK_INFO_KEYS)

    def _add_wall_clock(self, info: dict) -> dict:
        if self._keys:
            wall = self._base.wall_clock_info
            info.update((k, wall[k]) for k in self._keys)
        return info

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return obs, self._add_wall_clock(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._add_wall_clock(info)
