"""Campaigns: grouping by the requested settings with spread, any env setting swept or fixed (lists and fault
schedules from the command line), provenance-keyed resume, and local workers and Ray giving the same results."""

import csv
import json

import numpy as np
import pytest

from experiments import provenance
from experiments.campaign import Campaign, expand_grid, load_results, run_campaign, summarise_results
from experiments.cli import main

DETERMINISTIC = ("success", "settle_time_s", "final_pointing_error_deg", "attitude_error_rms_arcsec", "steps",
                 "slew_angle_deg", "mode_share_track", "control_effort")


def read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def small_grid():
    return {"policy": ["pd", "eigenaxis"], "max_episode_s": [1.0]}


def test_grid_expansion_and_errors():
    runs = expand_grid({"policy": ["pd", "eigenaxis"], "camera": ["paper000"]}, range(3))
    assert len(runs) == 6 and len({r.run_id for r in runs}) == 6
    with pytest.raises(ValueError, match="unknown grid"):
        expand_grid({"colour": ["red"]}, [0])
    with pytest.raises(ValueError, match="zero runs"):
        expand_grid({"policy": []}, [0])
    with pytest.raises(ValueError, match="both in the grid and fixed"):
        expand_grid({"matcher": ["brute"]}, [0], fixed={"matcher": "kdtree"})


def test_rows_keyed_by_requested_settings_with_spread(tmp_path, capsys):
    out = tmp_path / "c"
    assert main(["campaign", "--seeds", "2", "--grid", "matcher=dkvlut,kdtree", "--grid", "policy=pd,eigenaxis",
                 "--grid", "slew_angle_deg=60", "--env", "max_episode_s=3", "--out", str(out), "--workers", "1",
                 "--no-progress"]) == 0
    table = capsys.readouterr().out
    summary = read_csv(out / "summary.csv")
    assert len(summary) == 4 and all(r["runs"] == "2" for r in summary)
    assert {(r["matcher"], r["policy"]) for r in summary} == {(m, p) for m in ("dkvlut", "kdtree")
                                                              for p in ("pd", "eigenaxis")}
    assert all(r["slew_angle_deg"] == "60" for r in summary)  # the grid value, not the achieved 59.99999...
    results = read_csv(out / "results.csv")
    assert len(results) == 8
    assert all(abs(float(r["slew_angle_deg_achieved"]) - 60.0) < 1e-6 for r in results)
    # spread: the median and p10/p90 of each point's seeds, recomputed here from the per-run rows
    for s in summary:
        vals = [float(r["attitude_error_rms_arcsec"]) for r in results
                if r["matcher"] == s["matcher"] and r["policy"] == s["policy"]]
        assert len(vals) == 2
        assert float(s["attitude_error_rms_arcsec_median"]) == pytest.approx(np.median(vals))
        assert float(s["attitude_error_rms_arcsec_p10"]) == pytest.approx(np.percentile(vals, 10))
        assert float(s["attitude_error_rms_arcsec_p90"]) == pytest.approx(np.percentile(vals, 90))
    assert "[" in table and "p10, p90" in table
    assert (out / "campaign.png").stat().st_size > 0


def test_random_angles_do_not_split_the_groups(tmp_path):
    camp = Campaign(tmp_path, {"policy": ["eigenaxis"], "max_episode_s": [1.0]}, [0, 1, 2])
    records = run_campaign(camp, workers=1, progress=False)
    angles = {r["summary"]["slew_angle_deg"] for r in records}
    assert len(angles) == 3  # three different random slews...
    (row,) = summarise_results(records)  # ...one setting combination
    assert row["runs"] == 3


def test_any_env_setting_swept_or_fixed_from_the_command_line(tmp_path, capsys):
    out = tmp_path / "c"
    fault = '[{"kind": "blank", "t_start_s": 0, "duration_s": 100}]'
    assert main(["campaign", "--seeds", "1", "--grid", "n_heads=1,2", "--grid", f"faults=[],{fault}",
                 "--env", "max_episode_s=2", "--env", "inertia_kg_m2=10,10,10", "--env", "slew_angle_deg=30",
                 "--out", str(out), "--workers", "1", "--no-progress", "--no-plots"]) == 0
    capsys.readouterr()
    records = load_results(out)
    assert len(records) == 4
    for r in records:
        cfg = r["env_config"]
        assert cfg["n_heads"] == r["settings"]["n_heads"]
        assert cfg["inertia_kg_m2"] == [10, 10, 10]
        blank = bool(r["settings"]["faults"])
        assert cfg["faults"] == ([{"kind": "blank", "t_start_s": 0, "duration_s": 100, "severity": 1.0}]
                                 if blank else [])
        # a blank detector the whole episode: the tracker never gets a fix; without it, it tracks
        if blank:
            assert r["summary"]["mode_share_track"] == 0.0
        else:
            assert r["summary"]["mode_share_track"] > 0.5
    assert len(summarise_results(records)) == 4


def _camp(tmp_path):
    return Campaign(tmp_path, {"policy": ["eigenaxis"], "max_episode_s": [1.0]}, [0, 1])


def test_changed_configuration_or_code_is_not_resumed(tmp_path, monkeypatch):
    camp = _camp(tmp_path)
    run_campaign(camp, workers=1, progress=False)
    assert camp.pending() == []
    # a run file written under another env configuration (e.g. an older default) is stale
    files = sorted((tmp_path / "runs").glob("*.json"))
    rec = json.loads(files[0].read_text())
    rec["env_config"]["mag_limit"] = 5.5
    files[0].write_text(json.dumps(rec))
    camp = _camp(tmp_path)
    assert [s.run_id for s in camp.pending()] == [files[0].stem]
    assert "env_config.mag_limit" in camp.describe_resume()
    run_campaign(camp, workers=1, progress=False)
    assert json.loads(files[0].read_text())["env_config"]["mag_limit"] == 6.0
    # a code change (another digest of the packages) makes every run stale
    monkeypatch.setattr(provenance, "code_digest", lambda: "0" * 40)
    camp = _camp(tmp_path)
    assert len(camp.pending()) == 2
    assert "code_sha1 (2)" in camp.describe_resume()


def test_local_workers_and_ray_give_identical_results(tmp_path):
    import ray  # a dev dependency: the Ray backend is tested on a local instance
    local = Campaign(tmp_path / "local", small_grid(), [0, 1])
    rows_local = run_campaign(local, backend="local", workers=2, progress=False)
    remote = Campaign(tmp_path / "ray", small_grid(), [0, 1])
    rows_ray = run_campaign(remote, backend="ray", progress=False)
    assert not ray.is_initialized()
    assert len(rows_local) == len(rows_ray) == 4
    by_id = {r["run_id"]: r for r in rows_ray}
    for r in rows_local:
        other = by_id[r["run_id"]]
        for k in DETERMINISTIC:
            assert r["summary"][k] == other["summary"][k], k
        assert r["key"] == other["key"]
    assert (tmp_path / "ray" / "results.csv").exists()
    # a corrupt run file is redone, never trusted
    first = sorted((tmp_path / "local" / "runs").glob("*.json"))[0]
    first.write_text("{not json")
    assert len(local.pending()) == 1
    assert "unreadable file" in local.describe_resume()
    run_campaign(local, backend="local", workers=1, progress=False)
    assert json.loads(first.read_text())["run_id"] == first.stem
    assert len(load_results(tmp_path / "local")) == 4
