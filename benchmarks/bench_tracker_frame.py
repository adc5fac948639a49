"""Replay timing of StarTracker.process_frame (and the exposure plan's two queries) on the frames of real episodes.

Usage: python benchmarks/bench_tracker_frame.py REPO [episodes] [repeats] ['env kwargs']

The default AgileSlew env runs ``episodes`` episodes with REPO's code; every StarTracker.process_frame call is recorded
with a shallow copy of the tracker taken before it (the frame only rebinds the tracker's attributes), then replayed
``repeats`` times on fresh copies. Printed: µs per frame (the best of the repeats, averaged over the frames of each
exposures-per-frame band) of process_frame, and of ``requested_n_exposures`` + ``separable_n_exposures`` on the state
after the frame (what the unit's exposure plan asks). Compare two repositories by alternating runs.
"""
import copy
import sys
import time

repo = sys.argv[1]
sys.path.insert(0, repo)
n_ep = int(sys.argv[2]) if len(sys.argv) > 2 else 2
reps = int(sys.argv[3]) if len(sys.argv) > 3 else 5
kw = eval(sys.argv[4]) if len(sys.argv) > 4 else {}

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import envs  # noqa: E402,F401
import startracker.sensor as se  # noqa: E402

sys.path.insert(0, repo + "/benchmarks")
from policies import EigenaxisSlewPolicy  # noqa: E402

rec = []
orig = se.StarTracker.process_frame


def spy(self, *a, **k):
    snap = copy.copy(self)
    out = orig(self, *a, **k)
    rec.append((snap, a, k, copy.copy(self), out))
    return out


se.StarTracker.process_frame = spy
env = gym.make("startracker/AgileSlew-v0", **kw).unwrapped
pol = EigenaxisSlewPolicy.from_env(env)
for s in range(n_ep):
    obs, _ = env.reset(seed=s, options={"slew_angle_deg": 120.0})
    done = False
    while not done:
        obs, _, te, tr, _ = env.step(pol.act(obs))
        done = te or tr
se.StarTracker.process_frame = orig


def band(n):
    return "1" if n == 1 else ("2-14" if n < 15 else ">=15")


clock = time.perf_counter
tot = {b: [0.0, 0.0, 0] for b in ("1", "2-14", ">=15")}
for snap, a, k, after, out in rec:
    best_f = best_p = float("inf")
    for _ in range(reps):
        t = copy.copy(snap)
        t0 = clock()
        res = orig(t, *a, **k)
        best_f = min(best_f, clock() - t0)
        u = copy.copy(after)
        t0 = clock()
        u.requested_n_exposures
        u.separable_n_exposures(1.5 * u.shift_k_sigma)
        best_p = min(best_p, clock() - t0)
    assert res.mode == out.mode and len(res.samples) == len(out.samples)
    for x, y in zip(res.samples, out.samples):
        assert x.t_s == y.t_s and np.array_equal(x.q_body_to_icrs, y.q_body_to_icrs)
    b = tot[band(len(np.atleast_1d(a[2])))]
    b[0] += best_f
    b[1] += best_p
    b[2] += 1
n_all = sum(v[2] for v in tot.values())
f_all = sum(v[0] for v in tot.values()) / n_all * 1e6
p_all = sum(v[1] for v in tot.values()) / n_all * 1e6
print(f"frames {n_all}  process_frame {f_all:.1f} us  plan {p_all:.1f} us  " + "  ".join(
    f"[{b}: n={v[2]} {v[0] / max(v[2], 1) * 1e6:.1f} / {v[1] / max(v[2], 1) * 1e6:.1f}]" for b, v in tot.items()))
