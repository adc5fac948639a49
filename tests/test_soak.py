"""A short soak in CI: random actions and random faults must never produce an exception, NaN or a wrong attitude
sample, and a step that raises must not lose the counts of its episode."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

spec = importlib.util.spec_from_file_location("bench_soak", Path(__file__).resolve().parents[1] / "benchmarks" / "bench_soak.py")
bench_soak = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench_soak)


@pytest.mark.slow
def test_short_soak_is_clean():
    res = bench_soak.soak(10_000, seed=1, faults_per_min=10.0, episode_s=15.0, progress=False)
    assert res["exceptions"] == 0, res["first_exception"]
    for key in ("nonfinite_obs", "nonfinite_reward", "nonfinite_estimate", "obs_outside_space", "nonunit_quaternions",
                "wrong_samples", "confidently_wrong_samples"):
        assert res[key] == 0, (key, res)
    assert res["episodes"] >= 1
    assert res["rss_end_mb"] - res["rss_start_mb"] < 50.0


def test_a_step_that_raises_keeps_its_episodes_counts(monkeypatch):
    """Wrong samples reported before an exception in the same episode are counted, and the exception too."""
    from envs.agile_slew import AgileSlewEnv

    calls = {"n": 0}
    real_step = AgileSlewEnv.step

    def step(self, action):
        calls["n"] += 1
        obs, r, te, tr, info = real_step(self, action)
        if calls["n"] == 3:
            raise RuntimeError("injected")
        return obs, r, te, tr, dict(info, n_wrong_samples=1)  # every step reports one wrong sample

    monkeypatch.setattr(AgileSlewEnv, "step", step)
    res = bench_soak.soak(5, seed=0, faults_per_min=0.0, episode_s=30.0, progress=False)
    assert res["exceptions"] == 1 and res["first_exception"] == "RuntimeError: injected"
    assert res["wrong_samples"] == 4  # steps 1, 2, 4, 5; step 3 raised
    assert res["steps"] == 5 and res["episodes"] == 1


def test_soak_counts_the_envs_own_verdicts():
    """The soak's columns are the env's per-step verdicts, each read from its own info key."""
    info = dict(n_wrong_samples=3, n_confidently_wrong_samples=2, estimate_wrong=True, estimate_confidently_wrong=False)
    assert bench_soak.step_verdicts(info) == (3, 2, 1, 0)
    assert bench_soak.step_verdicts(dict(info, estimate_confidently_wrong=True))[3] == 1
    assert np.isfinite(bench_soak.rss_mb())
