"""Campaign backends: local processes and a local Ray instance produce the same results files."""

import json

import pytest

from experiments.campaign import Campaign, expand_grid, load_results, run_campaign

DETERMINISTIC = ("success", "settle_time_s", "final_pointing_error_deg", "attitude_error_rms_arcsec", "steps",
                 "slew_angle_deg", "mode_share_track", "control_effort")


def small_grid():
    return {"policy": ["pd", "eigenaxis"], "max_episode_s": [1.0]}


def test_grid_expansion_and_errors():
    runs = expand_grid({"policy": ["pd", "eigenaxis"], "camera": ["paper000"]}, range(3))
    assert len(runs) == 6 and len({r.run_id for r in runs}) == 6
    with pytest.raises(ValueError, match="unknown grid"):
        expand_grid({"colour": ["red"]}, [0])
    with pytest.raises(ValueError, match="zero runs"):
        expand_grid({"policy": []}, [0])


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
            assert r[k] == other[k], k
    assert (tmp_path / "ray" / "results.csv").exists()
    # a corrupt run file is redone, never trusted
    first = sorted((tmp_path / "local" / "runs").glob("*.json"))[0]
    first.write_text("{not json")
    assert len(local.pending()) == 1
    run_campaign(local, backend="local", workers=1, progress=False)
    assert json.loads(first.read_text())["run_id"] == first.stem
    assert len(load_results(tmp_path / "local")) == 4
