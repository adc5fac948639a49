"""Soak: many env steps with random actions and random faults across seeds, centroid fidelity.

Counts, in one table: exceptions, NaN/inf in observations, rewards and the estimate, observations outside the
observation space, non-unit quaternions (truth and estimate), wrong and confidently wrong attitude samples and
EKF estimates, and the resident set size of each worker process after its first step and at its end.

The run is cut into chunks of ``--chunk`` steps (a fresh env, seed ``seed · 1,000,003 + chunk index``), so the
result does not depend on how many processes share them (``--procs``). Every count is taken step by step: a step
that raises still leaves the counts of the steps before it in its episode, and the episode is reset with the
next seed.

Verdicts (:func:`step_verdicts`): the env's own per-step verdicts (``info["n_wrong_samples"]``,
``info["n_confidently_wrong_samples"]``, ``info["estimate_wrong"]``, ``info["estimate_confidently_wrong"]``): wrong
when the true error fails the χ²(3) test on the attitude's own covariance (false-alarm probability 1e-9),
confidently wrong when it is also flagged valid (docs/reliability.md).

    python benchmarks/bench_soak.py [--steps 1000000] [--procs 2] [--quick]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402

import envs  # noqa: E402,F401

COUNT_KEYS = ("exceptions", "nonfinite_obs", "nonfinite_reward", "nonfinite_estimate", "obs_outside_space",
              "nonunit_quaternions", "wrong_samples", "confidently_wrong_samples", "wrong_estimates",
              "confidently_wrong_estimates")
"""The checks of the table, each with target 0."""


def rss_mb() -> float:
    """Resident set size of this process, MB (Linux /proc)."""
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def step_verdicts(info: dict) -> tuple[int, int, int, int]:
    """(wrong samples, confidently wrong samples, wrong estimate, confidently wrong estimate) of one step.

    Read from the env's ``info``; a step without a filter yet has no estimate verdict (both 0).
    """
    return (int(info["n_wrong_samples"]), int(info["n_confidently_wrong_samples"]),
            int(bool(info["estimate_wrong"])), int(bool(info["estimate_confidently_wrong"])))


def soak(n_steps: int, seed: int = 0, faults_per_min: float = 6.0, episode_s: float = 30.0, progress=True,
         task: str = "startracker/AgileSlew-v0"):
    """Run ``n_steps`` env steps and return the counts (dict). Raises nothing: failures are counted.

    ``progress``: True for a progress bar, False for none, or a callable ``progress(n)`` told every step.
    """
    rss_start = None
    env = gym.make(task, max_episode_s=episode_s, random_faults_per_min=faults_per_min)
    rng = np.random.default_rng(seed)
    space = env.observation_space
    counts = dict.fromkeys(COUNT_KEYS, 0)
    counts.update(steps=0, episodes=0)
    first_msg = None
    bar = None
    if progress is True:
        try:
            from tqdm import tqdm

            bar = tqdm(total=n_steps, desc="soak", unit="step", mininterval=2.0)
        except ImportError:
            bar = None
    tick = progress if callable(progress) else (bar.update if bar is not None else None)
    t0 = time.perf_counter()
    ep_seed = seed * 1_000_003
    obs, info = env.reset(seed=ep_seed)
    k = 0  # step of the episode
    where = []  # (check, episode seed, step of the episode): what to replay
    while counts["steps"] < n_steps:
        try:
            k += 1
            action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            obs, r, te, tr, info = env.step(action)
            counts["nonfinite_obs"] += int(not np.all(np.isfinite(obs)))
            counts["nonfinite_reward"] += int(not np.isfinite(r))
            counts["nonfinite_estimate"] += int(not (np.all(np.isfinite(info["q_est"]))
                                                     and np.all(np.isfinite(info["omega_est_body"]))
                                                     and np.isfinite(info["attitude_sigma_arcsec"])))
            counts["obs_outside_space"] += int(not space.contains(obs))
            for key in ("q_true", "q_est"):
                counts["nonunit_quaternions"] += int(not abs(np.linalg.norm(info[key]) - 1.0) <= 1e-9)
            ws, cs, we, ce = step_verdicts(info)
            counts["wrong_samples"] += ws
            counts["confidently_wrong_samples"] += cs
            counts["wrong_estimates"] += we
            counts["confidently_wrong_estimates"] += ce
            if cs or ce:
                where.append(("confidently_wrong_samples" if cs else "confidently_wrong_estimates", ep_seed, k))
            if te or tr:
                counts["episodes"] += 1
                ep_seed += 1
                k = 0
                obs, info = env.reset(seed=ep_seed)
        except Exception as exc:  # a soak counts failures instead of stopping at the first
            counts["exceptions"] += 1
            where.append(("exceptions", ep_seed, k))
            k = 0
            counts["episodes"] += 1  # the episode ends there, its counts so far are kept
            first_msg = first_msg or f"{type(exc).__name__}: {exc}"
            ep_seed += 1
            obs, info = env.reset(seed=ep_seed)
        counts["steps"] += 1
        if rss_start is None:  # after the first step: imports, compiled kernels and caches are loaded
            rss_start = rss_mb()
        if tick is not None:
            tick(1)
    if bar is not None:
        bar.close()
    wall = time.perf_counter() - t0
    env.close()
    return dict(counts, wall_s=wall, steps_per_s=counts["steps"] / wall, rss_start_mb=rss_mb() if rss_start is None else rss_start,
                rss_end_mb=rss_mb(),
                first_exception=first_msg, pid=os.getpid(), where=where)


def _chunk(args):
    i, n, seed, faults_per_min, episode_s = args
    return i, soak(n, seed=seed * 1_000_003 + i, faults_per_min=faults_per_min, episode_s=episode_s, progress=False)


def soak_parallel(n_steps: int, seed: int = 0, procs: int = 1, chunk: int = 10_000, faults_per_min: float = 6.0,
                  episode_s: float = 30.0, progress: bool = True, out_path: str | None = None) -> dict:
    """``n_steps`` in chunks of ``chunk`` steps over ``procs`` processes; counts summed, RSS per process (the
    first chunk's start, the last chunk's end). ``out_path``: the table of the chunks done so far is rewritten
    there after each chunk (a long run that is stopped still leaves its figures)."""
    jobs = [(i, min(chunk, n_steps - i * chunk), seed, faults_per_min, episode_s)
            for i in range(-(-n_steps // chunk))]
    bar = None
    if progress:
        try:
            from tqdm import tqdm

            bar = tqdm(total=n_steps, desc="soak", unit="step", mininterval=5.0)
        except ImportError:
            bar = None
    t0 = time.perf_counter()
    results = []

    def summary():
        done = sorted(results, key=lambda x: x[0])
        out = {k: sum(r[k] for _, r in done) for k in (*COUNT_KEYS, "steps", "episodes")}
        rss = {}
        for _, r in done:
            first = rss.setdefault(r["pid"], [r["rss_start_mb"], r["rss_end_mb"]])
            first[1] = r["rss_end_mb"]
        wall = time.perf_counter() - t0
        out.update(wall_s=wall, steps_per_s=out["steps"] / wall, procs=procs, rss_mb=list(rss.values()),
                   first_exception=next((r["first_exception"] for _, r in done if r["first_exception"]), None),
                   where=[(i, *w) for i, r in done for w in r["where"]])
        return out

    if procs <= 1:
        it = map(_chunk, jobs)
        pool = None
    else:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(procs)
        it = pool.imap_unordered(_chunk, jobs)
    for i, res in it:
        results.append((i, res))
        if bar is not None:
            bar.update(res["steps"])
        if out_path:
            Path(out_path).write_text(table(summary()) + "\n")
    if pool is not None:
        pool.close()
        pool.join()
    if bar is not None:
        bar.close()
    return summary()


def table(res: dict) -> str:
    """The soak's one table (markdown)."""
    lines = [f"soak: {res['steps']} steps, {res['episodes']} episodes, {res['procs']} process(es), "
             f"{res['wall_s']:.0f} s ({res['steps_per_s']:.0f} steps/s)",
             "| check | result | target |", "|---|---|---|"]
    lines += [f"| {k} | {res[k]} | 0 |" for k in COUNT_KEYS]
    for j, (a, b) in enumerate(res["rss_mb"]):
        lines.append(f"| RSS of process {j + 1}, start -> end | {a:.0f} -> {b:.0f} MB ({b - a:+.1f}) | flat |")
    if res["first_exception"]:
        lines.append(f"first exception: {res['first_exception']}")
    if res.get("where"):
        lines.append("where (chunk, check, episode seed, step of the episode; the chunk's actions come from "
                     "numpy.random.default_rng(seed · 1,000,003 + chunk)):")
        lines += [f"  {i}, {check}, {ep}, {k}" for i, check, ep, k in res["where"][:30]]
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=1_000_000)
    ap.add_argument("--quick", action="store_true", help="10,000 steps")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--procs", type=int, default=1)
    ap.add_argument("--chunk", type=int, default=10_000)
    ap.add_argument("--faults-per-min", type=float, default=6.0)
    ap.add_argument("--out", default=None, help="file the table so far is rewritten to after every chunk")
    args = ap.parse_args()
    n = 10_000 if args.quick else args.steps
    res = soak_parallel(n, seed=args.seed, procs=args.procs, chunk=args.chunk, faults_per_min=args.faults_per_min,
                        out_path=args.out)
    print(table(res))


if __name__ == "__main__":
    main()
