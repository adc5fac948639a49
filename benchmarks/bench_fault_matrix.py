"""Fault matrix: every fault at several severities over many seeds, in AttitudeHold and during a slew.

For each (fault, severity), the verdicts (an attitude is *wrong* when its true error fails the χ²(3) test on its own
covariance, at false-alarm probability 1e-9; *confidently wrong* when it is also flagged valid): wrong and confidently
wrong tracker samples (valid: the filter accepted it), wrong and confidently wrong estimates (one verdict per step;
valid: the estimate's own flag), all targets 0 for the confident ones; then the re-acquisition time (median, p99),
the matched stars and attitude error during the fault, the error after it, the EKF NEES (mean 3 when consistent; valid steps) and the share of
frames in track.

    python benchmarks/bench_fault_matrix.py [--quick] [--seeds N]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402

import envs  # noqa: E402,F401

T0, DUR, AFTER = 3.0, 3.0, 6.0
VERDICT_KEYS = ("wrong_samples", "confidently_wrong_samples", "wrong_estimates", "confidently_wrong_estimates")

MATRIX = [
    ("none", [None]),
    ("stray_light", [40.0, 20.0, 15.0, 10.0, 8.0]),
    ("false_objects", [0.1, 0.3, 0.5]),
    ("dropout", [0.3, 0.6, 0.9]),
    ("saturated", [1.0]),
    ("blank", [1.0]),
    ("dropped_frame", [1.0]),
    ("time_jitter", [1.0, 5.0]),
    ("gyro_bias_step", [0.02, 0.2]),
    ("gyro_saturation", [0.02, 1.0]),
]


def run_one(kind, severity, seed, task):
    faults = [] if kind == "none" else [dict(kind=kind, t_start_s=T0, duration_s=DUR, severity=severity)]
    kwargs = dict(faults=faults, max_episode_s=T0 + DUR + AFTER)
    env = gym.make(task, **kwargs)
    obs, _ = env.reset(seed=seed, options={"slew_angle_deg": 60.0} if "Slew" in task else None)
    from policies import EigenaxisSlewPolicy, ZeroPolicy

    pol = (EigenaxisSlewPolicy if "Slew" in task else ZeroPolicy).from_env(env)
    rows = []
    done = False
    while not done:
        obs, r, te, tr, info = env.step(pol.act(obs))
        rows.append(info)
        done = te or tr
    env.close()
    dur = [i for i in rows if T0 <= i["time_s"] <= T0 + DUR]
    aft = [i for i in rows if i["time_s"] > T0 + DUR + 2.0]
    nees = [i["ekf_nees"] for i in rows if i["ekf_nees"] is not None and i["estimate_valid"]]
    last = rows[-1]
    return dict(
        wrong_samples=last["n_wrong_samples_total"],
        confidently_wrong_samples=last["n_confidently_wrong_samples_total"],
        wrong_estimates=last["n_wrong_estimates_total"],
        confidently_wrong_estimates=last["n_confidently_wrong_estimates_total"],
        reacq=rows[-1]["reacquisition_times_s"],
        stars_during=float(np.mean([i["n_stars"] for i in dur])) if dur else np.nan,
        err_during=float(np.median([i["attitude_error_arcsec"] for i in dur])) if dur else np.nan,
        err_after=float(np.median([i["attitude_error_arcsec"] for i in aft])) if aft else np.nan,
        nees=float(np.mean(nees)) if nees else np.nan,
        track=float(np.mean([i["tracker_mode"] == "track" for i in rows])),
        track_during=float(np.mean([i["tracker_mode"] == "track" for i in dur])) if dur else np.nan,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument("--task", choices=("hold", "slew", "both"), default=None)
    ap.add_argument("--faults", nargs="*", default=None, help="only these fault kinds (and 'none')")
    args = ap.parse_args()
    n_seeds = args.seeds or (2 if args.quick else 10)
    tasks = ["startracker/AttitudeHold-v0"] if args.quick else ["startracker/AttitudeHold-v0", "startracker/AgileSlew-v0"]
    if args.task is not None:
        tasks = {"hold": ["startracker/AttitudeHold-v0"], "slew": ["startracker/AgileSlew-v0"],
                 "both": ["startracker/AttitudeHold-v0", "startracker/AgileSlew-v0"]}[args.task]
    matrix = [(k, s) for k, s in MATRIX if args.faults is None or k in args.faults or k == "none"]
    try:
        from tqdm import tqdm
    except ImportError:
        tqdm = None
    jobs = [(t, k, s) for t in tasks for k, sevs in matrix for s in sevs]
    it = tqdm(jobs, desc="fault matrix", unit="cell") if tqdm else jobs
    rows = []
    for task, kind, sev in it:
        res = [run_one(kind, sev, seed, task) for seed in range(n_seeds)]
        reacq = [x for r in res for x in r["reacq"]]
        rows.append(dict(
            task=task.split("/")[1].split("-")[0], fault=kind, severity="-" if sev is None else f"{sev:g}",
            runs=len(res),
            **{k: int(sum(r[k] for r in res)) for k in VERDICT_KEYS},
            reacq_med_s=float(np.median(reacq)) if reacq else np.nan,
            reacq_p99_s=float(np.percentile(reacq, 99)) if reacq else np.nan,
            stars_during=float(np.nanmean([r["stars_during"] for r in res])),
            err_during_arcsec=float(np.nanmedian([r["err_during"] for r in res])),
            err_after_arcsec=float(np.nanmedian([r["err_after"] for r in res])),
            nees_mean=float(np.nanmean([r["nees"] for r in res])),
            track_share=float(np.mean([r["track"] for r in res])),
            track_during=float(np.nanmean([r["track_during"] for r in res])),
        ))
    keys = list(rows[0])
    print(f"fault matrix: fault on [{T0}, {T0 + DUR}] s, {n_seeds} seeds per cell; NEES is 3 when the EKF is consistent")
    print("| " + " | ".join(keys) + " |")
    print("|" + "---|" * len(keys))
    for r in rows:
        print("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in r.values()) + " |")
    print("totals: " + ", ".join(f"{k} {sum(r[k] for r in rows)}" for k in VERDICT_KEYS))


if __name__ == "__main__":
    main()
