"""The command line: slew summary against the env's own info, campaigns interrupted and resumed, usage errors."""

import json
import os

import pytest

from experiments.cli import main
from experiments.episode import run_episode


def test_slew_json_matches_the_env(tmp_path, capsys):
    args = ["slew", "--json", "--no-plots", "--out", str(tmp_path), "--seed", "3", "--angle-deg", "30",
            "--max-episode-s", "8"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    direct = run_episode(policy="eigenaxis", seed=3, env_kwargs={"max_episode_s": 8.0},
                         reset_options={"slew_angle_deg": 30.0})
    # the CLI reports what the env's info said, step for step
    steps = direct.steps
    assert summary["slew_angle_deg"] == pytest.approx(30.0, abs=1e-6)
    assert summary["steps"] == len(steps)
    assert summary["final_pointing_error_deg"] == pytest.approx(steps[-1]["pointing_error_deg"], rel=1e-12)
    assert summary["update_rate_hz_max"] == pytest.approx(max(s["update_rate_hz"] for s in steps))
    assert summary["mode_share_track"] == pytest.approx(sum(s["tracker_mode"] == "track" for s in steps) / len(steps))
    assert (tmp_path / "steps.csv").exists() and (tmp_path / "summary.json").exists()


def test_campaign_interrupted_and_resumed_without_repeating(tmp_path, capsys):
    out = tmp_path / "camp"
    base = ["campaign", "--out", str(out), "--grid", "policy=pd,eigenaxis", "--grid", "max_episode_s=2",
            "--seeds", "2", "--workers", "1", "--no-progress"]
    assert main(base + ["--max-runs", "2"]) == 0
    first = sorted(os.listdir(out / "runs"))
    assert len(first) == 2
    stamps = {f: os.stat(out / "runs" / f).st_mtime_ns for f in first}
    assert main(base) == 0
    files = sorted(os.listdir(out / "runs"))
    assert len(files) == 4
    assert all(os.stat(out / "runs" / f).st_mtime_ns == stamps[f] for f in first)  # not redone
    rows = (out / "results.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 4
    capsys.readouterr()


@pytest.mark.parametrize(
    "args,word",
    [
        (["slew", "--policy", "nosuch", "--no-plots"], "policy"),
        (["campaign", "--grid", "colour=red"], "unknown grid setting"),
        (["campaign", "--grid", "policy="], "zero runs"),
        (["bench", "nosuch"], "unknown benchmark"),
    ],
)
def test_usage_errors_exit_2_with_one_line(args, word, tmp_path, capsys):
    if args[0] in ("slew", "campaign"):
        args = args + ["--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert word in err and len(err.splitlines()) == 1


def test_unwritable_output_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    blocker = ro / "file"
    blocker.write_text("x")
    assert main(["slew", "--no-plots", "--out", str(blocker / "sub")]) == 2
    assert "not writable" in capsys.readouterr().err
