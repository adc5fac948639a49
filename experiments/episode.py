"""Run one closed-loop episode and summarise it: the unit of every slew experiment, campaign and agent benchmark."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import gymnasium as gym

import envs  # noqa: F401  (registers the ids)
from policies import Policy, load_policy

__all__ = ["EpisodeResult", "run_episode", "summarise"]

STEP_FIELDS = (
    "time_s", "pointing_error_deg", "attitude_error_arcsec", "omega_true_norm_deg_s", "omega_est_norm_deg_s",
    "tracker_mode", "n_stars", "exposures_per_frame", "n_attitude_samples", "update_rate_hz",
    "matching_latency_ms", "reward", "reward_pointing", "reward_effort", "reward_settle", "action_norm",
)


@dataclass
class EpisodeResult:
    """One episode: a summary and the per-step telemetry.

    Attributes
    ----------
    summary : dict
        Scalars (see :func:`summarise`).
    steps : list of dict
        One row per env step with the keys of ``STEP_FIELDS``.
    last_frame : ndarray or None
        RGB image of the last star frame when requested.
    """

    summary: dict
    steps: list = field(default_factory=list)
    last_frame: np.ndarray | None = None


def _make_policy(policy, env, seed):
    if isinstance(policy, Policy):
        p = policy
    else:
        cls = load_policy(policy) if isinstance(policy, str) else policy
        p = cls.from_env(env)
    p.reset(seed=seed)
    return p


def run_episode(
    env_id: str = "startracker/AgileSlew-v0",
    policy="eigenaxis",
    seed: int = 0,
    env_kwargs: dict | None = None,
    reset_options: dict | None = None,
    keep_frame: bool = False,
    max_steps: int | None = None,
) -> EpisodeResult:
    """Run one episode of ``env_id`` with ``policy`` and return its summary and telemetry.

    Parameters
    ----------
    env_id : str
    policy : str, Policy class or Policy
        A name of :data:`policies.POLICIES`, ``"module:Class"``, a class, or an instance.
    seed : int
        Seeds the env (and through it every sensor error) and the policy.
    env_kwargs : dict
        Keyword arguments for ``gymnasium.make``.
    reset_options : dict
        Passed to ``reset`` (e.g. ``{"slew_angle_deg": 90}``).
    keep_frame : bool
        Keep an RGB image of the last star frame (renders one full frame at the end).
    max_steps : int, optional
        Stop early after this many steps.
    """
    kwargs = dict(env_kwargs or {})
    if keep_frame:
        kwargs["render_mode"] = "rgb_array"
    env = gym.make(env_id, **kwargs)
    try:
        pol = _make_policy(policy, env, seed)
        obs, info = env.reset(seed=seed, options=reset_options)
        rows = []
        wall0 = time.perf_counter()
        first_info = info
        done = False
        n = 0
        while not done:
            action = pol.act(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            rows.append(_row(info, reward, action))
            done = terminated or truncated
            n += 1
            if max_steps is not None and n >= max_steps:
                break
        wall = time.perf_counter() - wall0
        frame = env.render() if keep_frame else None
        summary = summarise(rows, first_info, info, terminated=bool(rows) and done and terminated,
                            control_period_s=env.unwrapped.control_period_s,
                            settle_hold_s=env.unwrapped.settle_hold_s, wall_s=wall)
        summary.update(env_id=env_id, seed=int(seed), policy=_policy_name(policy))
        return EpisodeResult(summary=summary, steps=rows, last_frame=frame)
    finally:
        env.close()


def _policy_name(policy) -> str:
    if isinstance(policy, str):
        return policy
    if isinstance(policy, type):
        return f"{policy.__module__}:{policy.__name__}"
    return f"{type(policy).__module__}:{type(policy).__name__}"


def _row(info: dict, reward: float, action) -> dict:
    return {
        "time_s": info["time_s"],
        "pointing_error_deg": info["pointing_error_deg"],
        "attitude_error_arcsec": info["attitude_error_arcsec"],
        "omega_true_norm_deg_s": float(np.degrees(np.linalg.norm(info["omega_true_body"]))),
        "omega_est_norm_deg_s": float(np.degrees(np.linalg.norm(info.get("omega_est_body", np.zeros(3))))),
        "tracker_mode": info["tracker_mode"],
        "n_stars": info["n_stars"],
        "exposures_per_frame": info["exposures_per_frame"],
        "n_attitude_samples": info["n_attitude_samples"],
        "update_rate_hz": info["update_rate_hz"],
        "matching_latency_ms": info["matching_latency_ms"],
        "reward": float(reward),
        "reward_pointing": info["reward_pointing"],
        "reward_effort": info["reward_effort"],
        "reward_settle": info["reward_settle"],
        "action_norm": float(np.linalg.norm(action)),
    }


def summarise(rows, first_info, last_info, terminated: bool, control_period_s: float, settle_hold_s: float,
              wall_s: float = float("nan")) -> dict:
    """Scalars of one episode.

    Keys: slew_angle_deg, success, settle_time_s (first instant of the final settled hold, NaN if never),
    final_pointing_error_deg, attitude_error_rms_arcsec / _max_arcsec / _p95_arcsec (estimate vs truth over the
    steps where the tracker held lock), update_rate_hz_mean / _max, matching_latency_ms_p50 / _p99,
    mode_share_lost / _acquire / _track, lost_lock_events, control_effort (Σ mean(a²) dt), steps, sim_time_s,
    wall_s, steps_per_s.
    """
    n = len(rows)
    err = np.array([r["attitude_error_arcsec"] for r in rows]) if n else np.zeros(0)
    modes = np.array([r["tracker_mode"] for r in rows]) if n else np.zeros(0, dtype=str)
    track = modes == "track"
    lat = np.array([r["matching_latency_ms"] for r in rows if r["tracker_mode"] == "track"])
    rate = np.array([r["update_rate_hz"] for r in rows]) if n else np.zeros(0)
    effort = float(sum(-r["reward_effort"] for r in rows))
    sim_time = rows[-1]["time_s"] if n else 0.0
    settle_time = sim_time - settle_hold_s if terminated else float("nan")
    e_track = err[track]
    return {
        "slew_angle_deg": float(first_info["pointing_error_deg"]),
        "success": bool(terminated),
        "settle_time_s": float(settle_time),
        "final_pointing_error_deg": float(last_info["pointing_error_deg"]),
        "attitude_error_rms_arcsec": float(np.sqrt(np.mean(e_track**2))) if e_track.size else float("nan"),
        "attitude_error_max_arcsec": float(np.max(e_track)) if e_track.size else float("nan"),
        "attitude_error_p95_arcsec": float(np.percentile(e_track, 95)) if e_track.size else float("nan"),
        "update_rate_hz_mean": float(np.mean(rate)) if n else 0.0,
        "update_rate_hz_max": float(np.max(rate)) if n else 0.0,
        "matching_latency_ms_p50": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "matching_latency_ms_p99": float(np.percentile(lat, 99)) if lat.size else float("nan"),
        "mode_share_lost": float(np.mean(modes == "lost")) if n else 1.0,
        "mode_share_acquire": float(np.mean(modes == "acquire")) if n else 0.0,
        "mode_share_track": float(np.mean(track)) if n else 0.0,
        "lost_lock_events": int(last_info["lost_lock_events"]),
        "control_effort": effort,
        "steps": n,
        "sim_time_s": float(sim_time),
        "wall_s": float(wall_s),
        "steps_per_s": float(n / wall_s) if wall_s > 0 else float("nan"),
    }
