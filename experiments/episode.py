"""Run one closed-loop episode and summarise it: the unit of every slew experiment, campaign and agent benchmark."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import gymnasium as gym

import envs  # noqa: F401  (registers the ids)
from policies import Policy, load_policy
from startracker.rotations import quat_angle_between, quat_conjugate, quat_multiply, quat_to_rotvec

__all__ = ["EpisodeResult", "run_episode", "summarise", "STEP_FIELDS", "STEP_VECTORS", "RESET_OPTIONS"]

STEP_FIELDS = (
    "time_s", "pointing_error_deg", "attitude_error_arcsec", "omega_true_norm_deg_s", "omega_est_norm_deg_s",
    "tracker_mode", "n_stars", "exposures_per_frame", "n_attitude_samples", "update_rate_hz",
    "matching_latency_ms", "reward", "reward_pointing", "reward_effort", "reward_settle", "action_norm",
    "estimate_error_cross_boresight_arcsec", "estimate_error_roll_arcsec",
)
# vector telemetry per step (CSV columns name_0, name_1, ...); quaternions (w, x, y, z), body frame unless named
STEP_VECTORS = (
    "q_true_body_to_icrs", "q_est_body_to_icrs", "q_target_body_to_icrs", "estimate_error_rotvec_body_arcsec",
    "omega_true_body_deg_s", "omega_est_body_deg_s", "wheel_speed_rad_s", "wheel_momentum_Nms",
    "wheel_torque_cmd_Nm", "action",
)
# options AgileSlewEnv.reset understands
RESET_OPTIONS = ("slew_angle_deg", "slew_axis_body", "q_target", "faults")


@dataclass
class EpisodeResult:
    """One episode: a summary and the per-step telemetry.

    Attributes
    ----------
    summary : dict
        Scalars (see :func:`summarise`).
    steps : list of dict
        One row per env step with the keys of ``STEP_FIELDS``.
    frames : list of dict
        When requested: the star frame with the most exposures of the episode, rendered at pixel level from the
        true attitude, one dict per head (see :func:`render_frames`).
    """

    summary: dict
    steps: list = field(default_factory=list)
    frames: list = field(default_factory=list)


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
        Also render the star frame with the most exposures (every head) for plots.
    max_steps : int, optional
        Stop early after this many steps.

    Raises
    ------
    ValueError
        An unknown reset option (e.g. ``slew_angle``), or any value the env refuses.
    """
    options = dict(reset_options or {})
    unknown = sorted(set(options) - set(RESET_OPTIONS))
    if unknown:
        raise ValueError(f"unknown reset option(s) {unknown}; allowed: {', '.join(RESET_OPTIONS)}")
    env_kwargs = dict(env_kwargs or {})
    spec = gym.spec(env_id)
    if spec.max_episode_steps is not None and "max_episode_s" in env_kwargs and "max_episode_steps" not in env_kwargs:
        # an id registered with a step limit (AgileSlew-v1): the limit follows the episode time asked for
        env_kwargs["max_episode_steps"] = int(round(env_kwargs["max_episode_s"] / env_kwargs.get("control_period_s", 0.1)))
    env = gym.make(env_id, **env_kwargs)
    try:
        pol = _make_policy(policy, env, seed)
        obs, info = env.reset(seed=seed, options=options or None)
        u = env.unwrapped
        boresight = _mean_boresight(u)
        wheel_inertia = float(u.spacecraft.wheel_inertia_kg_m2)
        max_torque = np.asarray(u.spacecraft.wheel_max_torque_Nm, dtype=np.float64)
        rows = []
        wall0 = time.perf_counter()
        first_info = info
        done = False
        n = 0
        while not done:
            action = pol.act(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            # an action that is not one command per wheel (AgileSlew-v1's body torque): the wheels' own commands
            wheel_cmd = None if np.shape(action) == max_torque.shape else u.spacecraft.commanded_wheel_torque_Nm
            rows.append(_row(info, reward, action, u.control_period_s, boresight, u.spacecraft.wheel_speeds_rad_s,
                             wheel_inertia, max_torque, wheel_cmd))
            done = terminated or truncated
            n += 1
            if max_steps is not None and n >= max_steps:
                break
        wall = time.perf_counter() - wall0
        frames = render_frames(u, first_info, rows, seed) if keep_frame and rows else []
        # an env that also ends episodes on divergence (AgileSlew-v1) says which end it was
        settled = bool(rows) and done and terminated and not info.get("diverged", False)
        summary = summarise(rows, first_info, info, terminated=settled,
                            control_period_s=u.control_period_s, settle_hold_s=u.settle_hold_s, wall_s=wall,
                            task=u.task)
        summary.update(env_id=env_id, seed=int(seed), policy=_policy_name(policy),
                       settle_tolerance_deg=float(np.degrees(u.settle_tolerance_rad)), task=u.task)
        return EpisodeResult(summary=summary, steps=rows, frames=frames)
    finally:
        env.close()


def _mean_boresight(env) -> np.ndarray:
    """Unit mean boresight of the camera heads in the body frame (+z for one head or two symmetric about +z)."""
    b = np.sum([h.camera.boresight_body() for h in env.avionics.heads], axis=0)
    return b / np.linalg.norm(b)


def render_frames(env, first_info: dict, rows: list, seed: int) -> list[dict]:
    """The frame with the most exposures of an episode (the middle one of a tie), re-imaged at pixel level.

    The true attitude over that step (interpolated between the step's end points) is imaged by each head with
    the head's own detector model and exposure plan, and centroids are extracted from the image, so the picture
    shows what the pixel path sees at that instant (with ``fidelity="centroid"`` the env itself never renders).

    Returns
    -------
    list of dict, one per head
        ``head`` (index), ``camera`` (name), ``image`` (rows, cols) DN (green channel for the 3CMOS head),
        ``truth_xy`` (n_exposures, n_stars, 2) px (each star's centre in each exposure), ``visible``
        (n_exposures, n_stars) bool, ``vmag`` (n_stars,), ``centroid_xy`` (m, 2) px, ``n_exposures``, ``t_frame_s``,
        ``rate_deg_s``, ``n_stars``, ``channel``.
    """
    from startracker.centroid import extract_centroids
    from startracker.imaging import render_frame
    from startracker.scene import ExposurePlan, compute_scene

    n_exp = np.array([r["exposures_per_frame"] for r in rows])
    best = np.flatnonzero(n_exp == n_exp.max())
    k = int(best[len(best) // 2])
    prev = rows[k - 1] if k > 0 else {"time_s": first_info["time_s"], "q_true_body_to_icrs": first_info["q_true"]}
    t0, t1 = float(prev["time_s"]), float(rows[k]["time_s"])
    truth = (np.array([t0, t1]), np.array([prev["q_true_body_to_icrs"], rows[k]["q_true_body_to_icrs"]]))
    frame_period = env.avionics.config.frame_period_s
    n = max(int(n_exp[k]), 1)
    rng = np.random.default_rng(seed)
    out = []
    for i, head in enumerate(env.avionics.heads):
        plan = ExposurePlan(n_exposures=n, exposure_s=head.exposure_s, frame_period_s=frame_period)
        if getattr(head, "is_color", False):
            from startracker.color import channel_scenes, render_color_frame

            scene = channel_scenes(head.color_camera, env.avionics.catalog, truth, plan, t0)[1]
            image = render_color_frame(channel_scenes(head.color_camera, env.avionics.catalog, truth, plan, t0),
                                       head.sensor_model, rng)[1]
            channel = "green"
        else:
            scene = compute_scene(head.camera, env.avionics.catalog, truth, plan, t0)
            image = render_frame(scene, head.sensor_model, rng)
            channel = "mono"
        det = extract_centroids(image, saturation_dn=head.sensor_model.saturation_dn)
        out.append({
            "head": i, "camera": getattr(head, "camera_name", str(i)), "image": image, "channel": channel,
            "truth_xy": np.asarray(scene.xy), "visible": np.asarray(scene.visible), "vmag": np.asarray(scene.vmag),
            "centroid_xy": np.asarray(det.xy), "n_exposures": n, "t_frame_s": t0,
            "rate_deg_s": float(np.linalg.norm(rows[k]["omega_true_body_deg_s"])), "n_stars": int(scene.n_stars),
        })
    return out


def _policy_name(policy) -> str:
    if isinstance(policy, str):
        return policy
    if isinstance(policy, type):
        return f"{policy.__module__}:{policy.__name__}"
    return f"{type(policy).__module__}:{type(policy).__name__}"


def _row(info: dict, reward: float, action, control_period_s, boresight, wheel_speed, wheel_inertia, max_torque,
         wheel_cmd=None) -> dict:
    q_true = np.asarray(info["q_true"], dtype=np.float64)
    q_est = np.asarray(info["q_est"], dtype=np.float64)
    # estimate error as a body-frame rotation vector (estimate relative to truth), split about the boresight
    err = np.degrees(quat_to_rotvec(quat_multiply(quat_conjugate(q_true), q_est))) * 3600.0
    roll = float(err @ boresight)
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    # times are multiples of the control period: round away the float sum's last bits
    t = round(round(info["time_s"] / control_period_s) * control_period_s, 9)
    return {
        "time_s": t,
        "pointing_error_deg": info["pointing_error_deg"],
        "attitude_error_arcsec": info["attitude_error_arcsec"],
        "omega_true_norm_deg_s": float(np.degrees(np.linalg.norm(info["omega_true_body"]))),
        "omega_est_norm_deg_s": float(np.degrees(np.linalg.norm(info.get("omega_est_body", np.zeros(3))))),
        "tracker_mode": info["tracker_mode"],
        "estimate_valid": bool(info["estimate_valid"]),
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
        "estimate_error_cross_boresight_arcsec": float(np.linalg.norm(err - roll * boresight)),
        "estimate_error_roll_arcsec": abs(roll),
        "q_true_body_to_icrs": q_true,
        "q_est_body_to_icrs": q_est,
        "q_target_body_to_icrs": np.asarray(info["q_target"], dtype=np.float64),
        "estimate_error_rotvec_body_arcsec": err,
        "omega_true_body_deg_s": np.degrees(np.asarray(info["omega_true_body"], dtype=np.float64)),
        "omega_est_body_deg_s": np.degrees(np.asarray(info.get("omega_est_body", np.zeros(3)), dtype=np.float64)),
        "wheel_speed_rad_s": np.array(wheel_speed, dtype=np.float64),
        "wheel_momentum_Nms": wheel_inertia * np.array(wheel_speed, dtype=np.float64),
        "wheel_torque_cmd_Nm": a * max_torque if wheel_cmd is None else np.asarray(wheel_cmd, dtype=np.float64),
        "action": np.array(action, dtype=np.float64),
    }


def summarise(rows, first_info, last_info, terminated: bool, control_period_s: float, settle_hold_s: float,
              wall_s: float = float("nan"), task: str = "slew") -> dict:
    """Scalars of one episode.

    Keys: slew_angle_deg, success, settle_time_s (first instant of the final settled hold, NaN if never),
    final_pointing_error_deg, attitude_error_rms_arcsec / _max_arcsec / _p95_arcsec (estimate vs truth over the
    steps where the tracker held lock and the estimate was valid: one that says it is not, e.g. before the first fix
    has reached the filter, is not scored as an error), update_rate_hz_mean / _max, matching_latency_ms_p50 / _p99,
    mode_share_lost / _acquire / _track, lost_lock_events, control_effort (Σ mean(a²) dt), steps, sim_time_s,
    wall_s, steps_per_s.

    For ``task="hold"`` also, over the second half of the episode (after the capture transient):
    pointing_error_rms_arcsec / _max_arcsec (true attitude to target), pointing_stability_arcsec_1s (largest true
    rotation within any 1 s: drift) and jitter_rate_rms_arcsec_s (RMS of the true body rate).
    """
    n = len(rows)
    err = np.array([r["attitude_error_arcsec"] for r in rows]) if n else np.zeros(0)
    modes = np.array([r["tracker_mode"] for r in rows]) if n else np.zeros(0, dtype=str)
    track = modes == "track"
    valid = np.array([r.get("estimate_valid", True) for r in rows], dtype=bool) if n else np.zeros(0, dtype=bool)
    lat = np.array([r["matching_latency_ms"] for r in rows if r["tracker_mode"] == "track"])
    rate = np.array([r["update_rate_hz"] for r in rows]) if n else np.zeros(0)
    effort = float(sum(-r["reward_effort"] for r in rows))
    sim_time = rows[-1]["time_s"] if n else 0.0
    settle_time = sim_time - settle_hold_s if terminated else float("nan")
    e_track = err[track & valid]
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
        **(_hold_figures(rows, control_period_s) if task == "hold" else {}),
    }


def _hold_figures(rows, control_period_s: float) -> dict:
    nan = float("nan")
    rows = rows[len(rows) // 2:]
    if not rows:
        return dict(pointing_error_rms_arcsec=nan, pointing_error_max_arcsec=nan, pointing_stability_arcsec_1s=nan,
                    jitter_rate_rms_arcsec_s=nan)
    point = np.array([r["pointing_error_deg"] for r in rows]) * 3600.0
    q = np.array([r["q_true_body_to_icrs"] for r in rows])
    lag = max(int(round(1.0 / control_period_s)), 1)
    drift = np.degrees(quat_angle_between(q[:-lag], q[lag:])) * 3600.0 if len(q) > lag else np.zeros(0)
    rate = np.array([np.linalg.norm(r["omega_true_body_deg_s"]) for r in rows]) * 3600.0
    return {
        "pointing_error_rms_arcsec": float(np.sqrt(np.mean(point**2))),
        "pointing_error_max_arcsec": float(np.max(point)),
        "pointing_stability_arcsec_1s": float(np.max(drift)) if drift.size else nan,
        "jitter_rate_rms_arcsec_s": float(np.sqrt(np.mean(rate**2))),
    }
