"""The agent benchmark: a fixed, versioned set of seeded scenarios per difficulty, for any policy.

Scenarios are part of the benchmark's version: a change to them, or to the env's behaviour, ships as a new
version so that tables stay comparable across papers and releases.
"""

from __future__ import annotations

import numpy as np

from experiments.episode import run_episode

__all__ = ["BENCHMARK_VERSION", "SCENARIOS", "scenarios", "run_agent_benchmark"]

BENCHMARK_VERSION = "agent-bench-v1"

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


def run_agent_benchmark(policy, difficulties=("easy", "medium", "hard"), n_per_difficulty: int = 10,
                        progress: bool = True) -> list[dict]:
    """Run ``policy`` on the benchmark and return one row per difficulty.

    Row keys: version, policy, difficulty, episodes, success_rate, settle_time_s_median, final_pointing_error_deg_median,
    control_effort_median, track_share_mean, attitude_error_rms_arcsec_median.
    """
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
        for seed, angle, kwargs in it:
            results.append(run_episode(policy=policy, seed=seed, env_kwargs=kwargs,
                                       reset_options={"slew_angle_deg": angle}).summary)
        settle = [r["settle_time_s"] for r in results if r["success"]]
        rows.append({
            "version": BENCHMARK_VERSION,
            "policy": results[0]["policy"] if results else str(policy),
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
