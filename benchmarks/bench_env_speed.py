"""Env speed: steps per second over whole AgileSlew-v0 episodes with the scripted slew policy, and where a step's
time goes (physics, scene, detections, tracker, filter).

Peers measured in the same run: real time (the simulated seconds per wall second) and, for scale, the env with the
star tracker replaced by nothing (physics + policy only), which bounds what the sensor chain costs.

    python benchmarks/bench_env_speed.py [--quick] [--episodes N]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402

import envs  # noqa: E402,F401
from policies import EigenaxisSlewPolicy  # noqa: E402

STAGES = {
    "physics (MuJoCo RK4)": ("spacecraft.py", "step_recording"),
    "scene (truth projection)": ("scene.py", "compute_scene"),
    "detections (centroid/pixel)": ("centroid.py", "simulate_detections"),
    "tracker (identify/predict/match/Wahba)": ("sensor.py", "_run_frame"),
    "  of which matching": ("track.py", "match_stars"),
    "  of which Wahba": ("kernels/attitude.py", "solve_wahba_batch"),
    "filter (MEKF)": ("filter.py", "_fuse"),
    "gyro model": ("imu.py", "measure"),
}


def run_episodes(n_episodes, fidelity, seed0=0, max_episode_s=40.0, angle=90.0):
    env = gym.make("startracker/AgileSlew-v0", fidelity=fidelity, max_episode_s=max_episode_s)
    pol = EigenaxisSlewPolicy.from_env(env)
    steps = 0
    sim = 0.0
    t0 = time.perf_counter()
    for k in range(n_episodes):
        obs, _ = env.reset(seed=seed0 + k, options={"slew_angle_deg": angle})
        done = False
        while not done:
            obs, r, te, tr, info = env.step(pol.act(obs))
            steps += 1
            done = te or tr
        sim += info["time_s"]
    wall = time.perf_counter() - t0
    env.close()
    return steps / wall, sim / wall, steps


def physics_only(n_steps):
    from envs.spacecraft import Spacecraft

    sc = Spacecraft()
    t0 = time.perf_counter()
    for _ in range(n_steps):
        sc.apply_wheel_torque(np.full(4, 0.01))
        for _ in range(10):
            sc.step(0.01)
    return n_steps / (time.perf_counter() - t0)


def profile_stages(fidelity, n_steps=300):
    env = gym.make("startracker/AgileSlew-v0", fidelity=fidelity, max_episode_s=1e6)
    pol = EigenaxisSlewPolicy.from_env(env)
    obs, _ = env.reset(seed=99, options={"slew_angle_deg": 120.0})
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(n_steps):
        obs, *_ = env.step(pol.act(obs))
    prof.disable()
    st = pstats.Stats(prof)
    total = max(v[3] for v in st.stats.values())
    out = {}
    for name, (file, func) in STAGES.items():
        cum = sum(v[3] for (f, _, fn), v in st.stats.items() if f.endswith(file) and fn == func)
        out[name] = cum / n_steps * 1e3
    out["total per step (profiled)"] = total / n_steps * 1e3
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--episodes", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=None)
    args = ap.parse_args()
    n_ep = args.episodes or (1 if args.quick else 3)
    reps = args.repeats or (1 if args.quick else 3)
    rows = []
    for fid in ("centroid", "pixel"):
        run_episodes(1, fid, seed0=1000, max_episode_s=5.0)  # warm-up: databases, caches, imports
        res = [run_episodes(n_ep, fid) for _ in range(reps)]
        sps = np.array([r[0] for r in res])
        rt = np.array([r[1] for r in res])
        rows.append((fid, np.median(sps), sps.min(), sps.max(), np.median(rt), res[0][2]))
    phys = np.median([physics_only(300) for _ in range(reps)])
    print(f"AgileSlew-v0, eigenaxis policy, 90 deg slews, 0.1 s control period, 10 Hz frames, paper000 camera; "
          f"{reps} repeats x {n_ep} episodes")
    print("| fidelity | steps/s median | min | max | x real time | steps per repeat | target |")
    print("|---|---|---|---|---|---|---|")
    for fid, med, lo, hi, rt, n in rows:
        target = ">= 2000 steps/s" if fid == "centroid" else ">= 5x real time"
        print(f"| {fid} | {med:.0f} | {lo:.0f} | {hi:.0f} | {rt:.1f} | {n} | {target} |")
    print(f"| peer: physics only (MuJoCo 10 substeps + torque) | {phys:.0f} | | | {phys * 0.1:.0f} | | |")
    print(f"ratio physics-only / full chain (centroid): {phys / rows[0][1]:.1f}")
    for fid in ("centroid", "pixel"):
        st = profile_stages(fid, 100 if args.quick else 300)
        print(f"\nwhere a step's time goes ({fid} fidelity, cProfile, ms per step; profiling inflates the total):")
        print("| stage | ms/step |")
        print("|---|---|")
        for k, v in st.items():
            print(f"| {k} | {v:.3f} |")


if __name__ == "__main__":
    main()
