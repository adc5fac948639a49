"""A short soak in CI: random actions and random faults must never produce an exception, NaN or a wrong attitude."""

import importlib.util
from pathlib import Path

import pytest

spec = importlib.util.spec_from_file_location("bench_soak", Path(__file__).resolve().parents[1] / "benchmarks" / "bench_soak.py")
bench_soak = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench_soak)


@pytest.mark.slow
def test_short_soak_is_clean():
    res = bench_soak.soak(10_000, seed=1, faults_per_min=10.0, episode_s=15.0, progress=False)
    assert res["exceptions"] == 0, res["first_exception"]
    for key in ("nonfinite_obs", "nonfinite_reward", "obs_outside_space", "nonunit_quaternions", "wrong_attitudes"):
        assert res[key] == 0, (key, res)
    assert res["episodes"] >= 1
    assert res["rss_last_mb"] - res["rss_first_mb"] < 50.0
