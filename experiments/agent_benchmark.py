"""The agent benchmark: a fixed, versioned set of seeded scenarios per difficulty, for any policy.

Scenarios are part of the benchmark's version: a change to them, or to the env's behaviour, ships as a new
version so that tables stay comparable across papers and releases. Each policy runs on the env it acts on
(:func:`policies.policy_env`: ``AgileSlew-v0`` for the scripted controllers, the trained env for an RL checkpoint,
e.g. ``AgileSlew-v1`` with its body-torque action), with the scenario's sensors, slew and time limit, and the
env's default settle criterion (0.05°, 0.05°/s, held 2 s) in every version of the env.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import envs  # noqa: F401  (registers the ids)
from experiments.episode import run_episode
from policies import Policy, load_policy, policy_env

__all__ = ["BENCHMARK_VERSION", "SCENARIOS", "scenarios", "run_agent_benchmark", "scenario_env"]

# v2: each policy on its own env id (v1 for the RL baselines); an episode ended by divergence is not a success
BENCHMARK_VERSION = "agent-bench-v2"

# difficulty -> (slew angle range deg, env keyword arguments); seeds 1000.. per difficulty
SCENARIOS = {
    "easy": ((20.0, 45.0), dict(gyro_grade="navigation", camera="paper000", exposure_mode="multi", max_episode_s=60.0)),
    "medium": ((45.0, 120.0), dict(gyro_grade="tactical", camera="paper000", exposure_mode="multi", max_episode_s=90.0)),
    "hard": ((120.0, 180.0), dict(gyro_grade="industrial", camera="zy3", exposure_mode="multi", max_episode_s=120.0)),
}


def scenarios(difficulty: str, n: int):
    """The first ``n`` scenarios of a difficulty: list of (seed, slew_angle_deg, env_kwargs)."""
    if difficulty not in SCENARIOS:
        raise ValueError(f"difficulty must be one of {sorted(SCENARIOS)}, got {difficulty!r}")
    (lo, hi), kwargs = SCENARIOS[difficulty]
    base = {"easy": 1000, "medium": 2000, "hard": 3000}[difficulty]
    angles = np.random.default_rng(base).uniform(lo, hi, size=n)  # fixed by the version, not by the caller
    return [(base + i, float(angles[i]), dict(kwargs)) for i in range(n)]


def scenario_env(policy, scenario_kwargs: dict, sensor: str | None = None) -> tuple[str, dict]:
    """(env id, keyword arguments) of one scenario for ``policy``: the policy's env and interface arguments, the
    scenario's, and a step limit that matches the scenario's time limit. ``sensor="ideal"`` swaps the tracker
    for the ideal sensor (AgileSlew-v1 only)."""
    env_id, kwargs = policy_env(policy)
    kwargs = {**kwargs, **scenario_kwargs}
    if sensor is not None:
        if env_id != "startracker/AgileSlew-v1":
            raise ValueError(f"sensor={sensor!r} needs a policy on startracker/AgileSlew-v1, not {env_id}")
        kwargs["sensor"] = sensor
    spec = gym.spec(env_id)
    if spec.max_episode_steps is not None:
        dt = float(kwargs.get("control_period_s", 0.1))
        kwargs["max_episode_steps"] = int(round(kwargs["max_episode_s"] / dt))
    return env_id, kwargs


def run_agent_benchmark(policy, difficulties=("easy", "medium", "hard"), n_per_difficulty: int = 10,
                        progress: bool = True, sensor: str | None = None) -> list[dict]:
    """Run ``policy`` on the benchmark and return one row per difficulty.

    ``policy`` is a name (``eigenaxis``, ``sac``, ``module:Class``), a Policy class or an instance; a trained
    policy is loaded once and reused. ``sensor="ideal"`` runs an AgileSlew-v1 policy with the ideal sensor instead
    of the star tracker (the tracker's cost to the controller is the difference).

    Row keys: version, policy, env_id, sensor, difficulty, episodes, success_rate, settle_time_s_median,
    final_pointing_error_deg_median, control_effort_median, track_share_mean, attitude_error_rms_arcsec_median.
    """
    name = policy if isinstance(policy, str) else None
    cls = load_policy(policy) if isinstance(policy, str) else policy
    instance = cls if isinstance(cls, Policy) else None
    rows = []
    for d in difficulties:
        results = []
        items = scenarios(d, n_per_difficulty)
        it = items
        if progress:
            try:
                from tqdm import tqdm

                it = tqdm(items, desc=f"{d}", unit="ep")
            except ImportError:
                pass
        env_id = None
        for seed, angle, kwargs in it:
            env_id, env_kwargs = scenario_env(instance or cls, kwargs, sensor)
            if instance is None:
                env = gym.make(env_id, **env_kwargs)
                instance = cls.from_env(env)
                env.close()
            res = run_episode(env_id=env_id, policy=instance, seed=seed, env_kwargs=env_kwargs,
                              reset_options={"slew_angle_deg": angle}).summary
            res["policy"] = name or res["policy"]
            results.append(res)
        settle = [r["settle_time_s"] for r in results if r["success"]]
        rows.append({
            "version": BENCHMARK_VERSION,
            "policy": results[0]["policy"] if results else str(policy),
            "env_id": env_id,
            "sensor": sensor or "tracker",
            "difficulty": d,
            "episodes": len(results),
            "success_rate": float(np.mean([r["success"] for r in results])),
            "settle_time_s_median": float(np.median(settle)) if settle else float("nan"),
            "final_pointing_error_deg_median": float(np.median([r["final_pointing_error_deg"] for r in results])),
            "control_effort_median": float(np.median([r["control_effort"] for r in results])),
            "track_share_mean": float(np.mean([r["mode_share_track"] for r in results])),
            "attitude_error_rms_arcsec_median": float(np.nanmedian([r["attitude_error_rms_arcsec"] for r in results])),
        })
    return rows
