"""The command line: slew and hold summaries against the env's own telemetry, campaigns interrupted and resumed,
output hygiene, a user's own policy module, checkout-only benchmarks, and usage errors named in one line."""

import csv
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from experiments import cli
from experiments.cli import main
from experiments.episode import run_episode

ROOT = Path(__file__).resolve().parents[1]


def read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


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


def test_steps_csv_carries_vectors_consistent_with_the_scalars(tmp_path, capsys):
    assert main(["slew", "--no-plots", "--out", str(tmp_path), "--seed", "1", "--angle-deg", "40", "--axis", "x",
                 "--max-episode-s", "3"]) == 0
    capsys.readouterr()
    rows = read_csv(tmp_path / "steps.csv")
    assert len(rows) == 30
    # times are exact multiples of the 0.1 s step as written
    assert [r["time_s"] for r in rows[:3]] == ["0.1", "0.2", "0.3"]
    for r in rows[::7]:
        q_true = np.array([float(r[f"q_true_body_to_icrs_{i}"]) for i in range(4)])
        q_est = np.array([float(r[f"q_est_body_to_icrs_{i}"]) for i in range(4)])
        assert np.linalg.norm(q_true) == pytest.approx(1.0, abs=1e-9)
        # the error vector's length is the estimate error the env reports, computed here with scipy
        e = np.array([float(r[f"estimate_error_rotvec_body_arcsec_{i}"]) for i in range(3)])
        rel = Rotation.from_quat(q_true[[1, 2, 3, 0]]).inv() * Rotation.from_quat(q_est[[1, 2, 3, 0]])
        assert np.linalg.norm(e) == pytest.approx(np.degrees(rel.magnitude()) * 3600, rel=1e-6, abs=1e-6)
        assert np.linalg.norm(e) == pytest.approx(float(r["attitude_error_arcsec"]), rel=1e-6, abs=1e-6)
        # camera on +z: roll is the z component, cross-boresight the x-y part
        assert float(r["estimate_error_roll_arcsec"]) == pytest.approx(abs(e[2]), rel=1e-9, abs=1e-9)
        assert float(r["estimate_error_cross_boresight_arcsec"]) == pytest.approx(np.hypot(e[0], e[1]), rel=1e-9)
        # commanded wheel torque is the clipped action times the 0.5 N m limit
        for i in range(4):
            a = float(r[f"action_{i}"])
            assert float(r[f"wheel_torque_cmd_Nm_{i}"]) == pytest.approx(0.5 * np.clip(a, -1, 1), abs=1e-12)
    summary = json.loads((tmp_path / "summary.json").read_text())
    # provenance: the resolved env configuration, defaults included
    assert summary["env_config"]["camera"] == "paper000" and summary["env_config"]["n_heads"] == 1
    assert summary["env_config"]["max_episode_s"] == 3.0
    assert summary["provenance"]["code_sha1"] and "benchmark_version" in summary["provenance"]


def test_hold_reports_pointing_stability_and_jitter(tmp_path, capsys):
    assert main(["hold", "--json", "--no-plots", "--out", str(tmp_path), "--seed", "2", "--max-episode-s", "4"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert "settle_time_s" in s and s["success"] is False  # hold never terminates; the table shows hold figures
    rows = read_csv(tmp_path / "steps.csv")[20:]  # the second half of 40 steps
    q = np.array([[float(r[f"q_true_body_to_icrs_{i}"]) for i in (1, 2, 3, 0)] for r in rows])
    drift = [np.degrees((Rotation.from_quat(q[k]).inv() * Rotation.from_quat(q[k + 10])).magnitude()) * 3600
             for k in range(len(q) - 10)]
    assert s["pointing_stability_arcsec_1s"] == pytest.approx(max(drift), rel=1e-6)
    rate = np.array([float(r["omega_true_norm_deg_s"]) for r in rows]) * 3600
    assert s["jitter_rate_rms_arcsec_s"] == pytest.approx(np.sqrt(np.mean(rate**2)), rel=1e-6)
    point = np.array([float(r["pointing_error_deg"]) for r in rows]) * 3600
    assert s["pointing_error_rms_arcsec"] == pytest.approx(np.sqrt(np.mean(point**2)), rel=1e-6)
    assert main(["hold", "--no-plots", "--out", str(tmp_path), "--force", "--max-episode-s", "2"]) == 0
    out = capsys.readouterr().out
    assert "pointing stability" in out and "settle time" not in out


def test_output_folder_fresh_by_default_never_overwritten_and_group_readable(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    old = os.umask(0o022)
    try:
        assert main(["slew", "--no-plots", "--max-episode-s", "1"]) == 0
    finally:
        os.umask(old)
    made = list((tmp_path / "runs").iterdir())
    assert len(made) == 1 and made[0].name.startswith("slew-")
    for f in ("steps.csv", "summary.json"):
        mode = stat.S_IMODE(os.stat(made[0] / f).st_mode)
        assert mode & 0o044 == 0o044, oct(mode)  # group and others may read, like any file under umask 022
    capsys.readouterr()
    assert main(["slew", "--no-plots", "--max-episode-s", "1", "--out", str(made[0])]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["slew", "--no-plots", "--max-episode-s", "1", "--out", str(made[0]), "--force"]) == 0


def test_campaign_interrupted_and_resumed_without_repeating(tmp_path, capsys):
    out = tmp_path / "camp"
    base = ["campaign", "--out", str(out), "--grid", "policy=pd,eigenaxis", "--grid", "max_episode_s=2",
            "--seeds", "2", "--workers", "1", "--no-progress", "--no-plots"]
    assert main(base + ["--max-runs", "2"]) == 0
    first = sorted(os.listdir(out / "runs"))
    assert len(first) == 2
    stamps = {f: os.stat(out / "runs" / f).st_mtime_ns for f in first}
    capsys.readouterr()
    assert main(base) == 0
    assert "2 reused" in capsys.readouterr().err
    files = sorted(os.listdir(out / "runs"))
    assert len(files) == 4
    assert all(os.stat(out / "runs" / f).st_mtime_ns == stamps[f] for f in first)  # not redone
    rows = (out / "results.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 4
    # another grid in the same folder is refused rather than mixed in
    assert main(["campaign", "--out", str(out), "--grid", "policy=zero", "--seeds", "1", "--no-progress"]) == 2
    assert "another grid" in capsys.readouterr().err


USER_POLICY = '''
import numpy as np
from policies import Policy


class MyPD(Policy):
    def act(self, obs):
        e = self.read(obs, "attitude_error_rotvec")
        w = self.read(obs, "omega_body")
        J = self.spec.inertia_kg_m2
        return self.spec.body_torque_to_action(J @ (0.6 * e - 1.2 * w))
'''


def test_own_policy_module_from_the_users_folder(tmp_path):
    """As the console script runs it: its own folder first on sys.path, the user's folder as working directory."""
    user = tmp_path / "user"
    user.mkdir()
    (user / "mymodule.py").write_text(USER_POLICY)
    bindir = tmp_path / "bin"
    bindir.mkdir()
    script = bindir / "startracker-gym"
    script.write_text("import sys\nfrom experiments.cli import main\nsys.exit(main())\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, str(script), "slew", "--policy", "mymodule:MyPD", "--json", "--no-plots",
                          "--max-episode-s", "2", "--out", str(tmp_path / "o")], cwd=user, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["policy"] == "mymodule:MyPD"


def test_bench_outside_a_checkout_explains_itself(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "ROOT", tmp_path / "site-packages")  # an installed copy: no benchmarks/ beside it
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "list"]) == 0
    out = capsys.readouterr().out
    assert "agents" in out and "source checkout" in out
    assert main(["bench", "frame"]) == 2
    err = capsys.readouterr().err.strip()
    assert "source checkout" in err and len(err.splitlines()) == 1
    monkeypatch.chdir(ROOT)  # from a clone the scripts are found again
    assert main(["bench", "list"]) == 0
    assert "frame" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args,word",
    [
        (["slew", "--policy", "nosuch", "--no-plots"], "policy"),
        (["slew", "--angle-deg", "400"], "--angle-deg"),
        (["slew", "--angle-deg", "-30"], "--angle-deg"),
        (["slew", "--env", "slew_angle=30"], "did you mean 'slew_angle_deg'"),
        (["slew", "--camera", "nosuch"], "invalid choice"),
        (["slew", "--env", "n_heads=3"], "n_heads"),
        (["campaign", "--grid", "colour=red"], "unknown grid setting"),
        (["campaign", "--grid", "policy="], "zero runs"),
        (["campaign", "--grid", "camera=paper000,nosuch"], "nosuch"),
        (["campaign", "--workers", "0"], "--workers"),
        (["campaign", "--seeds", "0"], "--seeds"),
        (["campaign", "--env", "inertia_kg_m2=\"heavy\""], "inertia"),
        (["bench", "nosuch"], "unknown benchmark"),
    ],
)
def test_usage_errors_exit_2_with_one_line_before_any_run(args, word, tmp_path, capsys):
    if args[0] in ("slew", "campaign"):
        args = args + ["--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert word in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o" / "runs").exists() or not list((tmp_path / "o" / "runs").iterdir())
    assert not (tmp_path / "o" / "steps.csv").exists()


def test_help_lists_choices_defaults_and_grid_keys(capsys):
    assert main(["slew", "--help"]) == 0
    h = capsys.readouterr().out
    assert "{dkvlut,brute,kdtree}" in h and "env default: paper000" in h and "(default: 90.0)" in h
    assert main(["campaign", "--help"]) == 0
    h = " ".join(capsys.readouterr().out.split())
    for key in ("n_heads", "head_separation_deg", "mag_limit", "faults", "inertia_kg_m2", "slew_angle_deg"):
        assert key in h


def test_unwritable_output_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    blocker = ro / "file"
    blocker.write_text("x")
    assert main(["slew", "--no-plots", "--out", str(blocker / "sub")]) == 2
    assert "not writable" in capsys.readouterr().err


def test_python_m_experiments_runs_the_cli():
    res = subprocess.run([sys.executable, "-m", "experiments", "bench", "list"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0 and "agents" in res.stdout
    assert not (ROOT / "envs" / "__main__.py").exists()
