"""Soak: many env steps with random actions and random faults across seeds, centroid fidelity.

Checks, and prints as a table: no exception, no NaN/inf in observations or rewards, observations inside the
observation space, unit quaternions (truth and estimate), memory flat (resident set size of the first and last
10 % of the run), and the count of wrong attitudes reported as valid.

    python benchmarks/bench_soak.py [--steps 1000000] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402

import envs  # noqa: E402,F401


def rss_mb() -> float:
    """Resident set size of this process, MB (Linux /proc)."""
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    import os

    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def soak(n_steps: int, seed: int = 0, faults_per_min: float = 6.0, episode_s: float = 30.0, progress: bool = True):
    """Run ``n_steps`` and return the check results (dict). Raises nothing: failures are counted."""
    env = gym.make("startracker/AgileSlew-v0", max_episode_s=episode_s, random_faults_per_min=faults_per_min)
    rng = np.random.default_rng(seed)
    space = env.observation_space
    counts = dict(steps=0, episodes=0, exceptions=0, nonfinite_obs=0, nonfinite_reward=0, obs_outside_space=0,
                  nonunit_quaternions=0, wrong_attitudes=0)
    first_msg = None
    mem = []
    mark = max(1, n_steps // 10)
    bar = None
    if progress:
        try:
            from tqdm import tqdm

            bar = tqdm(total=n_steps, desc="soak", unit="step", mininterval=2.0)
        except ImportError:
            bar = None
    t0 = time.perf_counter()
    ep_seed = seed * 1_000_003
    obs, info = env.reset(seed=ep_seed)
    while counts["steps"] < n_steps:
        try:
            action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            obs, r, te, tr, info = env.step(action)
            counts["nonfinite_obs"] += int(not np.all(np.isfinite(obs)))
            counts["nonfinite_reward"] += int(not np.isfinite(r))
            counts["obs_outside_space"] += int(not space.contains(obs))
            for key in ("q_true", "q_est"):
                counts["nonunit_quaternions"] += int(abs(np.linalg.norm(info[key]) - 1.0) > 1e-9)
            if te or tr:
                counts["wrong_attitudes"] += info["n_wrong_samples_total"]
                counts["episodes"] += 1
                ep_seed += 1
                obs, info = env.reset(seed=ep_seed)
        except Exception as exc:  # a soak counts failures instead of stopping at the first
            counts["exceptions"] += 1
            first_msg = first_msg or f"{type(exc).__name__}: {exc}"
            ep_seed += 1
            obs, info = env.reset(seed=ep_seed)
        counts["steps"] += 1
        if counts["steps"] % mark == 0:
            mem.append(rss_mb())
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    counts["wrong_attitudes"] += info.get("n_wrong_samples_total", 0)
    wall = time.perf_counter() - t0
    env.close()
    return dict(counts, wall_s=wall, steps_per_s=counts["steps"] / wall,
                rss_first_mb=mem[0] if mem else rss_mb(), rss_last_mb=mem[-1] if mem else rss_mb(),
                first_exception=first_msg)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=1_000_000)
    ap.add_argument("--quick", action="store_true", help="10,000 steps")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    n = 10_000 if args.quick else args.steps
    res = soak(n, seed=args.seed)
    growth = res["rss_last_mb"] - res["rss_first_mb"]
    print(f"soak: {res['steps']} steps, {res['episodes']} episodes, {res['wall_s']:.0f} s ({res['steps_per_s']:.0f} steps/s)")
    print("| check | result | target |")
    print("|---|---|---|")
    for k in ("exceptions", "nonfinite_obs", "nonfinite_reward", "obs_outside_space", "nonunit_quaternions", "wrong_attitudes"):
        print(f"| {k} | {res[k]} | 0 |")
    print(f"| RSS first 10 % -> last 10 % | {res['rss_first_mb']:.0f} -> {res['rss_last_mb']:.0f} MB ({growth:+.1f}) | flat |")
    if res["first_exception"]:
        print(f"first exception: {res['first_exception']}")


if __name__ == "__main__":
    main()
