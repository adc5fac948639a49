"""Experiment figures: the star frame is the one with the most exposures, imaged per head, with centroids on the
truth; the slew, hold and campaign plots are written."""

import numpy as np

from experiments.episode import run_episode
from experiments.telemetry import plot_campaign, plot_episode



def nearest(a, b):
    """Distance from each point of ``a`` to the nearest point of ``b`` (px)."""
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    return d.min(axis=1)


def test_star_frame_is_mid_slew_per_head_and_centroids_sit_on_the_truth(tmp_path):
    res = run_episode(policy="eigenaxis", seed=4, env_kwargs={"max_episode_s": 4.0, "n_heads": 2},
                      reset_options={"slew_angle_deg": 90.0, "slew_axis_body": (1.0, 0.0, 0.0)}, keep_frame=True)
    frames = res.frames
    assert [f["head"] for f in frames] == [0, 1]
    n_max = max(r["exposures_per_frame"] for r in res.steps)
    assert n_max > 1
    for f in frames:
        assert f["n_exposures"] == n_max  # the frame with the most exposures, not the last one at rest
        assert f["truth_xy"].shape[0] == n_max and f["image"].shape == (2048, 2048)
        # spots of stars well above the noise: a centroid within half a pixel of the exposure's true centre
        vis = f["visible"]
        bright = vis & (f["vmag"][None, :] < 5.0)
        truth = f["truth_xy"][bright]
        assert len(truth) >= 10
        assert np.median(nearest(truth, f["centroid_xy"])) < 0.5
    # the two heads look at different skies
    assert not np.allclose(frames[0]["image"][::64, ::64], frames[1]["image"][::64, ::64])
    paths = plot_episode(tmp_path, res.steps, frames, res.summary)
    assert [p.name for p in paths] == ["slew.png", "star_frame.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_hold_and_campaign_plots(tmp_path):
    res = run_episode("startracker/AttitudeHold-v0", policy="pd", seed=1, env_kwargs={"max_episode_s": 3.0})
    (p,) = plot_episode(tmp_path, res.steps, [], res.summary)
    assert p.name == "hold.png" and p.stat().st_size > 10_000
    summary = [{"matcher": m, "runs": 2, "successes": 1, "success_rate": 0.5, "settle_time_s_median": 9.0,
                "settle_time_s_p10": 8.5, "settle_time_s_p90": 9.5} for m in ("dkvlut", "kdtree")]
    assert plot_campaign(tmp_path, summary, ["matcher"]).stat().st_size > 5_000


def test_episode_error_figures_leave_out_estimates_flagged_invalid():
    """An estimate that says it is invalid (before the first fix reaches the filter) is not scored as an error."""
    from experiments.episode import summarise

    def row(t, err, valid):
        return dict(time_s=t, attitude_error_arcsec=err, tracker_mode="track", estimate_valid=valid,
                    matching_latency_ms=1.0, update_rate_hz=10.0, reward_effort=0.0, pointing_error_deg=1.0)

    rows = [row(0.1, 2.8e5, False)] + [row(0.1 * (i + 2), 3.0 + i % 2, True) for i in range(9)]
    info = dict(pointing_error_deg=1.0, lost_lock_events=0)
    s = summarise(rows, info, info, terminated=False, control_period_s=0.1, settle_hold_s=2.0)
    e = [3.0 + i % 2 for i in range(9)]
    assert s["attitude_error_max_arcsec"] == 4.0
    assert abs(s["attitude_error_rms_arcsec"] - (sum(x * x for x in e) / 9) ** 0.5) < 1e-12
