"""The star tracker unit's per-step glue, in situ: ``StarTrackerUnit.observe`` less the heads' imaging
(``MonoHead.detections`` / ``ColorHead.detections``) and the trackers' frames (``StarTracker.process_frame``).

What is left is the unit's own work per control step of ``startracker/AgileSlew-v0``: the gyro's samples, its
saturation and jump monitors, the exposure plan, the samples' verdicts, the delayed fusion, the monitors and the
span's figures. Each run plays one warm-up episode and four 120° eigenaxis slews, and prints the median, the first
quartile and the mean of the per-step glue (µs of the thread's CPU time); ``--compare REPO`` alternates runs of this checkout
and another one in fresh processes (A, B, A, B ...) and prints the medians of the runs' medians and their ratio, the
way to see a change of a few µs on a shared machine.

    python benchmarks/bench_unit_glue.py [--env-kwargs '{"n_heads": 2}'] [--compare OTHER_REPO] [--rounds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def glue_us(env_kwargs: dict) -> list[float]:
    """Per-step glue, µs, over four episodes of this checkout (imported from ``sys.path``)."""
    import gymnasium as gym
    import numpy as np

    import envs  # noqa: F401  (registers the env)
    from policies import EigenaxisSlewPolicy
    from startracker import head, onboard, sensor

    clk = time.thread_time_ns  # CPU time of this thread: a shared machine's other work stays out
    inner = [0]

    def timed(f):
        def g(*a, **k):
            t = clk()
            r = f(*a, **k)
            inner[0] += clk() - t
            return r
        return g

    sensor.StarTracker.process_frame = timed(sensor.StarTracker.process_frame)
    head.MonoHead.detections = timed(head.MonoHead.detections)
    head.ColorHead.detections = timed(head.ColorHead.detections)
    observe = onboard.StarTrackerUnit.observe
    rec = []

    def observe_timed(self, *a, **k):
        inner[0] = 0
        t = clk()
        observe(self, *a, **k)
        rec.append(clk() - t - inner[0])

    onboard.StarTrackerUnit.observe = observe_timed
    env = gym.make("startracker/AgileSlew-v0", **env_kwargs).unwrapped
    pol = EigenaxisSlewPolicy.from_env(env)

    def episode(seed):
        obs, _ = env.reset(seed=seed, options={"slew_angle_deg": 120.0})
        done = False
        while not done:
            obs, _, te, tr, _ = env.step(pol.act(obs))
            done = te or tr

    episode(99)
    rec.clear()
    for s in range(4):
        episode(s)
    return [v / 1e3 for v in rec]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env-kwargs", default="{}", help="JSON keyword arguments of gym.make")
    ap.add_argument("--compare", default=None, help="another checkout: alternate runs of the two")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repo", default=None, help=argparse.SUPPRESS)  # the child process' checkout
    args = ap.parse_args()
    if args.repo is not None or args.compare is None:
        repo = args.repo or HERE
        sys.path.insert(0, repo)
        v = glue_us(json.loads(args.env_kwargs))
        q = statistics.quantiles(v, n=4)
        print(f"glue_us median {statistics.median(v):.1f} p25 {q[0]:.1f} mean {statistics.fmean(v):.1f} steps {len(v)}")
        return
    runs = {HERE: [], args.compare: []}
    for r in range(args.rounds):
        for repo in ((HERE, args.compare) if r % 2 == 0 else (args.compare, HERE)):
            out = subprocess.run([sys.executable, os.path.abspath(__file__), "--repo", repo, "--env-kwargs",
                                  args.env_kwargs], capture_output=True, text=True, check=True, cwd=repo).stdout
            runs[repo].append(float(out.split()[2]))
    for repo, v in runs.items():
        print(f"{repo:40s} median of medians {statistics.median(v):7.1f} µs  runs {[round(x, 1) for x in v]}")
    print(f"ratio this/other {statistics.median(runs[HERE]) / statistics.median(runs[args.compare]):.3f}")


if __name__ == "__main__":
    main()
