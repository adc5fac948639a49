"""Multi-exposure N: paper 000's rate rule against the separation cap, closed loop at 20°/s.

A 150° eigenaxis slew about body x (cross-boresight: stars stream across the detector at the full rate), paper
000's camera, 10 Hz frames, tactical gyro, centroid (or pixel) fidelity. Two rules for N
(``StarTrackerSpec.exposure.n_rule``):

* ``separation``: N is the smaller of the tracker's request (spots of one star 2 × 4 prediction σ apart) and the
  detector's no-overlap rule (streaks 6 PSF σ apart);
* ``paper000``: paper 000's rule, N = 1 + round(|ω| / 1°/s), 21 at 20°/s (210 Hz).

Reports, per rule, the exposures per frame and the update rate (distinct attitude instants per second) while
coasting at 20°/s or more, and the fused attitude error (EKF against truth) over the same steps and over the slew
(steps in track with a valid estimate: before the first fix reaches the filter the estimate claims nothing).

    python benchmarks/bench_update_rate_rule.py [--seeds N] [--fidelity pixel]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402

import envs  # noqa: E402,F401
from policies import EigenaxisSlewPolicy  # noqa: E402
from startracker.rotations import quat_conjugate, quat_from_rotvec, quat_multiply, quat_random, quat_to_rotvec  # noqa: E402

ARCSEC = 180 / np.pi * 3600


def run(seed, rule, fidelity="centroid", angle_deg=150.0):
    camera = {"preset": "paper000", "exposure": {"n_rule": rule}}
    # the controller may command 21°/s, so that the coast is at (not just below) 20°/s
    env = gym.make("startracker/AgileSlew-v0", camera=camera, gyro_grade="tactical", fidelity=fidelity,
                   max_episode_s=30.0, max_rate_deg_s=21.0)
    q0 = quat_random(np.random.default_rng(seed))
    target = quat_multiply(q0, quat_from_rotvec([np.radians(angle_deg), 0.0, 0.0]))
    obs, info = env.reset(seed=seed, options={"q_target": target})
    env.unwrapped.spacecraft.set_state(q0, np.zeros(3), np.zeros(4), time_s=0.0)
    pol = EigenaxisSlewPolicy.from_env(env)
    rows = []
    done = False
    while not done:
        obs, r, te, tr, info = env.step(pol.act(obs))
        d = quat_to_rotvec(quat_multiply(quat_conjugate(info["q_est"]), info["q_true"]))
        rows.append((np.degrees(np.linalg.norm(info["omega_true_body"])), info["update_rate_hz"],
                     info["exposures_per_frame"], np.hypot(d[0], d[1]) * ARCSEC, abs(d[2]) * ARCSEC,
                     info["tracker_mode"] == "track" and info["estimate_valid"], info["lost_lock_events"],
                     info["n_wrong_samples_total"]))
        done = te or tr
    env.close()
    a = np.array(rows, dtype=float)
    rate, upd, n_exp, cross, roll, track = a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5] > 0
    fast = rate >= 20.0
    return dict(n_fast=float(np.median(n_exp[fast])), update_fast=float(np.median(upd[fast])),
                cross_fast=float(np.sqrt(np.mean(cross[fast & track] ** 2 / 2))),
                roll_fast=float(np.sqrt(np.mean(roll[fast & track] ** 2))),
                cross_all=float(np.sqrt(np.mean(cross[track] ** 2 / 2))), lost=int(a[-1, 6]), wrong=int(a[-1, 7]),
                fast_s=float(fast.sum() * 0.1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--fidelity", choices=("centroid", "pixel"), default="centroid")
    args = ap.parse_args()
    print(f"150 deg slew about body x, paper000 camera, 10 Hz frames, tactical gyro, {args.fidelity} fidelity; "
          f"{args.seeds} seeds per row, medians (lost-lock events and wrong samples: totals)")
    print("| N rule | N at >= 20 deg/s | update rate at >= 20 deg/s (Hz) | cross-boresight RMS per axis, >= 20 deg/s "
          "(arcsec) | roll RMS, >= 20 deg/s (arcsec) | cross-boresight RMS, whole slew (arcsec) | lost-lock events | "
          "wrong samples | time >= 20 deg/s (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for rule in ("separation", "paper000"):
        res = [run(s, rule, args.fidelity) for s in range(args.seeds)]
        med = {k: float(np.median([r[k] for r in res])) for k in res[0]}
        print(f"| {rule} | {med['n_fast']:.0f} | {med['update_fast']:.0f} | {med['cross_fast']:.2f} | "
              f"{med['roll_fast']:.1f} | {med['cross_all']:.2f} | {sum(r['lost'] for r in res)} | "
              f"{sum(r['wrong'] for r in res)} | {med['fast_s']:.1f} |", flush=True)
    print("paper 000: N 1 -> 21 as the rate rises 0 -> 20 deg/s, 210 Hz")


if __name__ == "__main__":
    main()
