"""Each fault kind bites: against the fault-free run with the same seed, the fault changes what it must change
(detections, tracker mode, samples, timing, gyro, attitude error), so a fault whose implementation is removed
fails its test here. The sun 10° off the boresight blinds the camera in both fidelities."""

import math

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from envs.faults import FAULT_KINDS, Fault, FaultSchedule
from policies import EigenaxisSlewPolicy, ZeroPolicy
from startracker import onboard
from startracker.catalog import load_catalog
from startracker.centroid.fidelity import simulate_detections
from startracker.imaging import KIND_STAR, SensorModel, background_field
from startracker.optics import camera_preset
from startracker.rotations import quat_random, quat_rotate
from startracker.scene import BrightBody, ExposurePlan, compute_scene

T_FAULT, D_FAULT = 2.0, 2.0
HOLD, SLEW = "startracker/AttitudeHold-v0", "startracker/AgileSlew-v0"


def run(kind=None, severity=None, task=HOLD, steps=70, seed=0, **kw):
    """Step an episode (zero torque in the hold, an eigenaxis slew of 90° otherwise); per step the info dict
    plus ``time_error_s``, the frame's injected time-tag error."""
    faults = [] if kind is None else [dict(kind=kind, t_start_s=T_FAULT, duration_s=D_FAULT, severity=severity)]
    env = gym.make(task, faults=faults, **kw)
    obs, _ = env.reset(seed=seed, options={"slew_angle_deg": 90.0} if task == SLEW else None)
    pol = (EigenaxisSlewPolicy if task == SLEW else ZeroPolicy).from_env(env)
    rows = []
    for _ in range(steps):
        obs, _, te, tr, info = env.step(pol.act(obs))
        rows.append(dict(info, time_error_s=env.unwrapped.avionics.last_time_error_s,
                         gyro_jumps=env.unwrapped.avionics.gyro_jumps_total))
        if te or tr:
            break
    env.close()
    return rows


def during(rows, skip_s=0.1):
    return [i for i in rows if T_FAULT + skip_s <= i["time_s"] <= T_FAULT + D_FAULT]


def mean_of(rows, key):
    return float(np.mean([i[key] for i in rows]))


# ------------------------------------------------------------------------------------------------ stray light
@pytest.mark.parametrize("fidelity", ["centroid", "pixel"])
def test_sun_10_deg_off_the_boresight_blinds_both_fidelities_and_the_tracker_reacquires(fidelity):
    """The stray light of a sun 10° off the boresight (inside the 30° exclusion cone) raises the background of a
    20 ms frame above the detector's saturation: no star is detected, the tracker goes lost, and it re-acquires
    within a second of the fault clearing."""
    base = run(fidelity=fidelity)
    rows = run("stray_light", 10.0, fidelity=fidelity)
    assert all(i["tracker_mode"] == "track" for i in during(base)) and mean_of(during(base), "n_stars") > 30
    blind = during(rows, skip_s=0.25)  # the first frame under the sun may still be matched against the track
    assert all(i["tracker_mode"] == "lost" for i in blind)
    assert all(i["n_stars"] == 0 and i["n_attitude_samples"] == 0 for i in blind)
    after = [i for i in rows if i["time_s"] >= T_FAULT + D_FAULT + 1.0]
    assert after and all(i["tracker_mode"] == "track" for i in after)
    assert rows[-1]["lost_lock_events"] >= 1 and base[-1]["lost_lock_events"] == 0
    assert 0 < rows[-1]["reacquisition_times_s"][0] <= D_FAULT + 1.0
    assert rows[-1]["n_wrong_samples_total"] == 0


def _sun_scene(angle_deg, exposure_s=0.02, seed=3):
    cam = camera_preset("paper000")
    q0 = quat_random(np.random.default_rng(seed))
    b = quat_rotate(q0, np.array([0.0, 0.0, 1.0]))
    p = np.cross(b, [0.0, 0.0, 1.0])
    p /= np.linalg.norm(p)
    a = np.radians(angle_deg)
    plan = ExposurePlan(1, exposure_s, frame_period_s=0.1, start_offset_s=0.5 * (0.1 - exposure_s))
    return compute_scene(cam, load_catalog(6.5), lambda t: np.tile(q0, (len(t), 1)), plan, 0.0,
                         bright_bodies=[BrightBody("sun", tuple(np.cos(a) * b + np.sin(a) * p))])


@pytest.mark.parametrize("fidelity", ["centroid", "pixel"])
def test_a_sun_saturating_the_background_leaves_no_detection_where_it_saturates(fidelity):
    """Per pixel region: with the sun 11° off, the background's detection threshold is above saturation on the
    sun's side of the detector and below it on the far side; every detection lies where a pixel can still cross."""
    model = SensorModel()
    sc = _sun_scene(11.0)
    bg = background_field(sc, model)
    w, h = sc.camera.resolution
    cols, rows = np.meshgrid(np.arange(0, w, 8.0), np.arange(0, h, 8.0))
    thr = bg.threshold_dn(cols, rows, 5.0)
    blind = np.floor(thr) + 1 > model.saturation_dn
    assert 0.2 < blind.mean() < 0.95  # a gradient across the saturation level
    n = 0
    for k in range(4):
        det = simulate_detections(sc, model, np.random.default_rng(k), fidelity)
        if len(det):
            t = bg.threshold_dn(det.xy[:, 0], det.xy[:, 1], 5.0)
            assert np.all(np.floor(t) <= model.saturation_dn + 1.0)  # within a pixel of the crossable region
        n += int(np.sum(det.truth_kind == KIND_STAR))
    quiet = simulate_detections(compute_scene(sc.camera, load_catalog(6.5), lambda t: np.tile(sc.q_body_to_icrs[0],
                                (len(t), 1)), sc.plan, 0.0), model, np.random.default_rng(0), fidelity)
    assert n / 4 < 0.6 * np.sum(quiet.truth_kind == KIND_STAR)


def test_stray_light_in_a_slew_costs_stars_and_lock():
    """The sun 15° off during a 17°/s slew (1 ms exposures): fewer matched stars and frames out of track."""
    base = during(run(task=SLEW))
    rows = during(run("stray_light", 15.0, task=SLEW))
    assert mean_of(rows, "n_stars") < 0.5 * mean_of(base, "n_stars")
    assert np.mean([i["tracker_mode"] == "track" for i in rows]) < 0.9
    assert all(i["tracker_mode"] == "track" for i in base)


# ------------------------------------------------------------------------------------------ frame-level faults
def _frames(n_frames=12, seed=5):
    """Real detections of a 1 ms frame of a random sky, a few noise draws of it."""
    cam = camera_preset("paper000")
    q0 = quat_random(np.random.default_rng(seed))
    sc = compute_scene(cam, load_catalog(6.5), lambda t: np.tile(q0, (len(t), 1)), ExposurePlan(1, 1e-3), 0.0)
    return [simulate_detections(sc, SensorModel(), np.random.default_rng(100 + k)) for k in range(n_frames)], cam


def test_false_objects_add_the_stated_fraction_of_false_detections():
    """``false_objects`` 0.5: the number added is Poisson with mean half the true detections (a 4σ bound on the
    total), they carry no star label, and outside its window the frame is untouched."""
    frames, cam = _frames()
    sched = FaultSchedule([Fault("false_objects", 1.0, 1.0, 0.5)])
    rng = np.random.default_rng(0)
    added, expected = 0, 0.0
    for det in frames:
        out = sched.modify_detections(det, 1.5, rng, cam.resolution)
        assert sched.modify_detections(det, 0.5, rng, cam.resolution) is det
        added += len(out) - len(det)
        expected += 0.5 * len(det)
        assert np.sum(out.truth_star >= 0) == np.sum(det.truth_star >= 0)
        assert np.all(np.diff(out.intensity) <= 0)  # brightest first, as the tracker expects
    assert abs(added - expected) < 4 * np.sqrt(expected) and added > 0.3 * expected


def test_dropout_removes_the_stated_fraction_of_detections_and_of_matched_stars():
    """``dropout`` 0.6 keeps each detection with probability 0.4 (binomial 4σ bound), and in the env the matched
    stars during the fault fall to about 40 % of the fault-free run's."""
    frames, cam = _frames()
    sched = FaultSchedule([Fault("dropout", 1.0, 1.0, 0.6)])
    rng = np.random.default_rng(1)
    n = sum(len(d) for d in frames)
    kept = sum(len(sched.modify_detections(d, 1.5, rng, cam.resolution)) for d in frames)
    assert abs(kept - 0.4 * n) < 4 * np.sqrt(n * 0.4 * 0.6)
    base, rows = during(run()), during(run("dropout", 0.6))
    ratio = mean_of(rows, "n_stars") / mean_of(base, "n_stars")
    assert 0.25 < ratio < 0.5


@pytest.mark.parametrize("kind", ["saturated", "blank"])
def test_dark_frames_lose_the_stars_and_the_track(kind):
    base, rows = during(run()), during(run(kind))
    assert all(i["tracker_mode"] == "track" and i["n_attitude_samples"] >= 1 for i in base)
    assert all(i["tracker_mode"] != "track" and i["n_stars"] == 0 and i["n_attitude_samples"] == 0 for i in rows[1:])


def test_dropped_frames_give_no_exposures_no_samples():
    base, rows = during(run()), during(run("dropped_frame"))
    assert all(i["exposures_per_frame"] >= 1 and i["n_attitude_samples"] >= 1 for i in base)
    assert all(i["exposures_per_frame"] == 0 and i["n_attitude_samples"] == 0 for i in rows)
    # the EKF coasts: its covariance grows over the gap
    sig = [i["attitude_sigma_arcsec"] for i in rows]
    assert sig[-1] > 1.3 * sig[0]


def test_time_jitter_tags_frames_with_the_stated_error_and_degrades_a_fast_slew():
    """``time_jitter`` 5 ms: the frames' time-tag errors have a standard deviation of 5 ms (χ² bound on the
    sample variance), none outside the fault; at 17°/s it costs attitude accuracy."""
    base = run(task=SLEW)
    rows = run("time_jitter", 5.0, task=SLEW)
    assert all(i["time_error_s"] == 0.0 for i in base)
    e = np.array([i["time_error_s"] for i in during(rows, skip_s=0.0)])
    outside = [i["time_error_s"] for i in rows if not T_FAULT <= i["time_s"] - 0.05 < T_FAULT + D_FAULT]
    assert np.all(np.array(outside) == 0.0)
    n = len(e)
    s2 = np.mean(e**2) / 0.005**2  # zero-mean Gaussian: n s² / σ² ~ χ²(n)
    assert abs(s2 - 1.0) < 4 * np.sqrt(2.0 / n)
    assert np.degrees(np.max(np.abs(during(rows)[0]["omega_true_body"]))) > 10.0
    assert np.median([i["attitude_error_arcsec"] for i in during(rows)]) > 3 * np.median(
        [i["attitude_error_arcsec"] for i in during(base)])


# ---------------------------------------------------------------------------------------------------- gyro
def test_gyro_bias_step_shifts_the_gyro_and_the_attitude_error_jumps(monkeypatch):
    """``gyro_bias_step`` 0.1 °/s: the gyro samples move by exactly 0.1 °/s along one unit axis while active; the
    unit's jump monitor sees the step (none in the fault-free run), and with the monitor off the attitude error
    during the fault peaks far above the fault-free run's."""
    sched = FaultSchedule([Fault("gyro_bias_step", 1.0, 1.0, 0.1)])
    t = np.linspace(0.0, 3.0, 301)
    w = np.random.default_rng(0).normal(size=(301, 3)) * 1e-3
    out = sched.modify_gyro(w, t, np.random.default_rng(1))
    on = (t > 1.0) & (t <= 2.0)
    np.testing.assert_allclose(np.linalg.norm(out[on] - w[on], axis=1), np.radians(0.1), rtol=1e-12)
    np.testing.assert_array_equal(out[~on], w[~on])
    base, rows = run(), run("gyro_bias_step", 0.1)
    assert rows[-1]["gyro_jumps"] >= 1 and base[-1]["gyro_jumps"] == 0
    monkeypatch.setattr(onboard, "GYRO_JUMP_CHI2_3", math.inf)
    unseen = during(run("gyro_bias_step", 0.1))
    assert max(i["attitude_error_arcsec"] for i in unseen) > 3 * max(i["attitude_error_arcsec"] for i in during(base))


def test_gyro_saturation_clips_the_rate_and_wrecks_the_estimate_in_a_slew():
    """``gyro_saturation`` 0.5 °/s during a 17°/s slew: every gyro axis is clipped at 0.5 °/s, and the fused
    attitude error grows by orders of magnitude over the fault-free run's."""
    sched = FaultSchedule([Fault("gyro_saturation", 0.0, 1.0, 0.5)])
    t = np.linspace(0.01, 1.0, 100)
    w = np.full((100, 3), np.radians(17.0)) * np.array([1.0, -1.0, 0.01])
    out = sched.modify_gyro(w, t, np.random.default_rng(0))
    np.testing.assert_allclose(out, np.clip(w, -np.radians(0.5), np.radians(0.5)), rtol=0, atol=0)
    base, rows = during(run(task=SLEW)), during(run("gyro_saturation", 0.5, task=SLEW))
    assert max(i["attitude_error_arcsec"] for i in rows) > 100 * max(i["attitude_error_arcsec"] for i in base)


def test_a_blinded_head_takes_its_stars_away():
    """``head_blinded`` 0 on a two-head sensor: the matched stars fall to the other head's share; it stays in track."""
    base, rows = during(run(n_heads=2)), during(run("head_blinded", 0, n_heads=2))
    ratio = mean_of(rows, "n_stars") / mean_of(base, "n_stars")
    assert 0.3 < ratio < 0.7
    assert all(i["tracker_mode"] == "track" for i in rows)


EFFECT_TESTS = {
    "stray_light": "test_sun_10_deg_off_the_boresight_blinds_both_fidelities_and_the_tracker_reacquires",
    "false_objects": "test_false_objects_add_the_stated_fraction_of_false_detections",
    "dropout": "test_dropout_removes_the_stated_fraction_of_detections_and_of_matched_stars",
    "saturated": "test_dark_frames_lose_the_stars_and_the_track",
    "blank": "test_dark_frames_lose_the_stars_and_the_track",
    "dropped_frame": "test_dropped_frames_give_no_exposures_no_samples",
    "time_jitter": "test_time_jitter_tags_frames_with_the_stated_error_and_degrades_a_fast_slew",
    "gyro_bias_step": "test_gyro_bias_step_shifts_the_gyro_and_the_attitude_error_jumps",
    "gyro_saturation": "test_gyro_saturation_clips_the_rate_and_wrecks_the_estimate_in_a_slew",
    "head_blinded": "test_a_blinded_head_takes_its_stars_away",
}


def test_every_fault_kind_has_an_effect_test():
    assert set(EFFECT_TESTS) == set(FAULT_KINDS)
    assert all(callable(globals()[name]) for name in EFFECT_TESTS.values())
