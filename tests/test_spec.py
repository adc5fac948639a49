"""StarTrackerSpec: a user's own star tracker described as data, built into heads, the unit and the env; the
presets, each with the numbers of its paper's table."""

from __future__ import annotations

import json
import math
import pickle

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)
from policies.scripted import EigenaxisSlewPolicy
from startracker.head import ColorHead, MonoHead, make_head
from startracker.imaging import SensorModel
from startracker.imu import gyro_preset
from startracker.onboard import StarTrackerUnit, UnitConfig, gyro_rate_sigma_rad_s
from startracker.sensor import StarTracker
from startracker.spec import PRESET_NAMES, ExposureSpec, StarTrackerSpec, TrackerSpec, preset_spec

# A camera that is none of the presets: 12° horizontal field, 1280x1024 pixels of 4.8 µm, a plain CMOS of its own
# (3 e- read noise, 10 e-/s dark, 12 ke- full well, 25 mm pupil, QE 0.6), 10 ms multi-exposures.
CUSTOM = {
    "camera": {"resolution": [1280, 1024], "pixel_size_um": 4.8, "fov_deg": 12.0, "distortion_k1_per_mm2": 2e-5,
               "name": "my12deg"},
    "detector": {"psf_sigma_px": 1.0, "intensifier_gain": 1.0, "excess_noise_factor": 1.0, "read_noise_e": 3.0,
                 "dark_current_e_per_s": 10.0, "full_well_e": 12000.0, "adc_bits": 12, "gain_e_per_dn": 3.0,
                 "photometry": {"aperture_diameter_mm": 25.0, "quantum_efficiency": 0.6, "transmission": 0.8},
                 "name": "my-cmos"},
    "exposure": {"mode": "multi", "exposure_s": 0.01, "single_exposure_s": 0.03, "max_exposures": 10},
    "mag_limit": 6.5,
    "name": "my-tracker",
}


def test_custom_spec_builds_with_its_own_geometry_and_noise():
    spec = StarTrackerSpec.from_dict(CUSTOM)
    cam = spec.camera
    assert cam.resolution == (1280, 1024) and cam.pixel_size_um == 4.8
    # focal length from the field: half the detector width over tan(6°)
    assert cam.focal_length_mm == pytest.approx(0.5 * 1280 * 4.8e-3 / math.tan(math.radians(6.0)))
    assert cam.fov_deg[0] == pytest.approx(12.0)
    assert spec.detector.read_noise_e == 3.0 and not spec.detector.intensified
    assert spec.detector.photometry.aperture_diameter_mm == 25.0
    assert spec.exposure.exposure_s == 0.01 and spec.mag_limit == 6.5
    head = make_head(CUSTOM)
    assert isinstance(head, MonoHead) and head.sensor_model.read_noise_e == 3.0 and head.exposure_s == 0.01


def test_dict_json_and_pickle_round_trips():
    spec = StarTrackerSpec.from_dict(CUSTOM)
    d = spec.to_dict()
    again = StarTrackerSpec.from_dict(json.loads(json.dumps(d)))
    assert again == spec and again.to_dict() == d
    assert pickle.loads(pickle.dumps(spec)) == spec
    for name in PRESET_NAMES:
        p = preset_spec(name)
        assert StarTrackerSpec.from_dict(json.loads(json.dumps(p.to_dict()))) == p
    # a preset with one field changed
    z = StarTrackerSpec.from_dict({"preset": "zy3", "detector": {"read_noise_e": 30.0}})
    assert z.detector.read_noise_e == 30.0 and z.detector.dark_current_e_per_s == preset_spec("zy3").detector.dark_current_e_per_s


@pytest.mark.parametrize("d, field, rng_text", [
    ({"camera": {"pixel_size_um": -1.0}}, "pixel_size_um", "positive"),
    ({"detector": {"read_noise_e": -1.0}}, "read_noise_e", ">= 0"),
    ({"detector": {"adc_bits": 40}}, "adc_bits", "<= 24"),
    ({"detector": {"photometry": {"quantum_efficiency": 1.5}}}, "quantum_efficiency", "(0, 1]"),
    ({"exposure": {"exposure_s": 0.5}}, "exposure_s", "<= 0.1"),
    ({"exposure": {"mode": "burst"}}, "mode", "'single', 'multi'"),
    ({"exposure": {"max_exposures": 200}}, "max_exposures", "[1, 100]"),
    ({"tracker": {"min_stars_per_instant": 1}}, "min_stars_per_instant", "[2, 1000]"),
    ({"mag_limit": 12.0}, "mag_limit", "<= 9"),
    ({"matcher": "nearest"}, "matcher", "dkvlut"),
    ({"camera": {"fov_deg": 200.0}}, "fov_deg", "<= 179"),
    ({"detector": {"read_noise": 1.0}}, "read_noise", "accepted"),
])
def test_invalid_values_name_the_field_and_its_range(d, field, rng_text):
    with pytest.raises(ValueError) as exc:
        StarTrackerSpec.from_dict(d)
    assert field in str(exc.value) and rng_text in str(exc.value)


def test_n_exposures_must_fit_in_the_frame():
    with pytest.raises(ValueError, match=r"max_exposures must be in \[1, 10\]"):
        ExposureSpec(exposure_s=0.01, max_exposures=21)


def test_tracker_spec_defaults_are_the_trackers():
    import inspect

    sig = inspect.signature(StarTracker.__init__).parameters
    for name, value in TrackerSpec().tracker_kwargs().items():
        assert sig[name].default == value, name


def test_heads_take_a_list_of_specs_each_with_its_own_mounting():
    q_tilt = (math.cos(math.radians(20)), math.sin(math.radians(20)), 0.0, 0.0)  # 40° about body x
    a = StarTrackerSpec.from_dict(CUSTOM)
    b = preset_spec("paper000").with_mounting(q_tilt)
    # every head of a unit runs at one frame rate: the custom camera's 10 Hz is the preset's
    unit = StarTrackerUnit(UnitConfig(camera=[a.to_dict(), b], gyro_grade="ideal"))
    assert len(unit.heads) == 2 and unit.config.n_heads == 2
    assert unit.heads[0].camera.resolution == (1280, 1024) and unit.heads[1].camera.resolution == (2048, 2048)
    np.testing.assert_allclose(unit.heads[1].camera.boresight_body(), [0.0, -math.sin(math.radians(40)), math.cos(math.radians(40))],
                               atol=1e-12)
    assert unit.heads[0].sensor_model.read_noise_e == 3.0 and unit.heads[1].sensor_model.intensified
    with pytest.raises(ValueError, match="n_heads"):
        UnitConfig(camera=[a, b], n_heads=3)


def test_env_accepts_a_spec_object_and_a_dict_alike():
    spec = StarTrackerSpec.from_dict(CUSTOM)
    e1 = gym.make("startracker/AgileSlew-v0", camera=spec)
    e2 = gym.make("startracker/AgileSlew-v0", camera=CUSTOM)
    o1, _ = e1.reset(seed=3)
    o2, _ = e2.reset(seed=3)
    np.testing.assert_array_equal(o1, o2)
    assert e1.unwrapped.avionics.heads[0].camera.resolution == (1280, 1024)
    # the env (and its config) pickle, as vector envs need
    u = pickle.loads(pickle.dumps(e1.unwrapped.avionics.config))
    assert u.heads[0] == spec
    e1.close(), e2.close()


def test_a_users_camera_tracks_in_a_closed_loop_slew():
    """gymnasium.make with the user's dict; an eigenaxis slew of 25°: the tracker locks and tracks, and its
    fused attitude agrees with the truth to a few of the detector's centroid σ on the sky."""
    env = gym.make("startracker/AgileSlew-v0", camera=CUSTOM, max_episode_s=25.0, slew_angle_deg_range=(25.0, 25.0))
    policy = EigenaxisSlewPolicy.from_env(env)
    obs, info = env.reset(seed=1)
    spec = StarTrackerSpec.from_dict(CUSTOM)
    arcsec_per_px = math.degrees(spec.camera.pixel_size_mm / spec.camera.focal_length_mm) * 3600
    sigma_px = env.unwrapped.avionics.trackers[0].centroid_sigma_px
    assert sigma_px == pytest.approx(spec.centroid_sigma_px())
    modes, errors, rates = [], [], []
    done = False
    while not done:
        obs, _, term, trunc, info = env.step(policy.act(obs))
        done = term or trunc
        modes.append(info["tracker_mode"])
        rates.append(np.degrees(np.linalg.norm(info["omega_true_body"])))
        if info["tracker_mode"] == "track":
            errors.append(info["attitude_error_arcsec"])
    env.close()
    assert max(rates) > 3.0  # it did slew
    assert modes.count("track") >= 0.8 * len(modes)
    assert info["n_wrong_samples_total"] == 0
    # a single star's 5σ on the sky bounds the fused error (many stars and the gyro make it smaller)
    assert np.percentile(errors, 95) < 5.0 * sigma_px * arcsec_per_px
    assert info["pointing_error_deg"] < 0.1


# ------------------------------------------------------------------------------------------ presets, per paper
def test_paper000_preset_is_table2_and_intensified():
    s = preset_spec("paper000")
    assert s.camera.resolution == (2048, 2048) and s.camera.pixel_size_um == 5.5 and s.camera.focal_length_mm == 31.94
    assert s.camera.fov_deg[0] == pytest.approx(20.0, abs=0.1)  # Table 2: 20° x 20°
    assert s.detector.intensified and s.exposure.mode == "multi" and s.exposure.max_exposures >= 21
    assert s.exposure.exposure_s * 21 <= s.frame_period_s  # 21 exposures fit in a 10 Hz frame: 210 Hz
    assert s.mag_limit == 6.0  # §4: navigation stars <= 6.0 M


def test_zy3_preset_is_paper002_table1():
    s = preset_spec("zy3")
    assert s.camera.resolution == (1024, 1024) and s.camera.pixel_size_um == 15.0 and s.camera.focal_length_mm == 43.3
    assert s.camera.fov_deg[0] == pytest.approx(2 * math.degrees(math.atan(512 * 15e-3 / 43.3)))  # ~20°
    assert 0.125 <= s.exposure.exposure_s <= 0.5  # exposure time 125 ms ~ 500 ms
    assert s.exposure.frame_rate_hz == 4.0  # update rate 4 Hz
    assert s.mag_limit == 5.5  # catalog size <= 5.5 magnitude
    assert not s.detector.intensified  # an APS
    # stellar detection threshold 6.5 magnitude: the detection probability crosses 1/2 there
    from startracker.centroid.fidelity import predicted_centroid_sigma_px

    _, p = predicted_centroid_sigma_px(s.detector, s.camera, [5.5, 6.3, 6.7, 7.5], s.exposure.exposure_s)
    assert p[0] > 0.99 and p[1] > 0.5 > p[2] and p[3] < 0.05


def test_paper003_preset_is_16_by_16_degrees():
    s = preset_spec("paper003")
    assert s.camera.fov_deg == pytest.approx((16.0, 16.0))
    assert s.mag_limit == 6.0 and not s.detector.intensified
    # the assumed aperture: every catalog star (V <= 6) is seen, half of those at V = 6.5
    from startracker.centroid.fidelity import predicted_centroid_sigma_px

    _, p = predicted_centroid_sigma_px(s.detector, s.camera, [6.0, 6.3, 6.7], s.exposure.exposure_s)
    assert p[0] > 0.95 and p[1] > 0.5 > p[2]


def test_paper004_presets_are_table1_and_plain_cmos():
    for name in ("paper004", "paper004_3cmos"):
        s = preset_spec(name)
        assert s.camera.resolution == (2064, 1544) and s.camera.pixel_size_um == 3.45
        assert s.camera.focal_length_mm == 25.0 and s.camera.distortion_k1_per_mm2 == 4.9e-5  # green, Table 1
        assert s.camera.fov_deg == pytest.approx((16.0, 12.0), abs=0.3)  # §4.1: 16° x 12°
        assert not s.detector.intensified
    assert isinstance(make_head("paper004_3cmos"), ColorHead)
    assert make_head("paper004_3cmos").sensor_model.name == "paper004_3cmos"


def test_color_heads_share_one_ground_calibration():
    """The 3CMOS unit's ground calibration is a property of the unit: every ColorHead holds the same fitted pair (built
    once per process, not once per env), equal to a calibration run afresh with CALIBRATION_SEED."""
    from startracker.color import ColorCamera, ColorRegistration, generate_rotary_table_data
    from startracker.head import CALIBRATION_SEED

    a, b = ColorHead(), make_head("paper004_3cmos")
    assert a.registration is b.registration and a.color_camera is b.color_camera
    rng = np.random.default_rng(CALIBRATION_SEED)
    cam = ColorCamera.paper004(translation="table2")
    fresh = ColorRegistration.calibrate(generate_rotary_table_data(cam, rng), rng=rng)
    xy = np.array([[10.0, 20.0], [1032.0, 772.0], [2000.0, 1500.0]])
    for ch in ("red", "blue"):
        np.testing.assert_array_equal(a.registration.to_green(ch, xy), fresh.to_green(ch, xy))
        np.testing.assert_array_equal(a.color_camera.project_channel(ch, np.array([[0.01, 0.02, 1.0]]))[0],
                                      cam.project_channel(ch, np.array([[0.01, 0.02, 1.0]]))[0])


def test_each_preset_has_its_own_detector_and_exposure():
    dets = {n: preset_spec(n).detector for n in PRESET_NAMES}
    keys = {(d.read_noise_e, d.dark_current_e_per_s, d.full_well_e, d.intensifier_gain, d.photometry.aperture_diameter_mm)
            for n, d in dets.items() if n != "paper004_3cmos"}
    assert len(keys) == 4  # paper000, zy3, paper003, paper004 all differ
    for n in PRESET_NAMES:
        head = make_head(n)
        assert head.sensor_model.name == n and head.exposure_s == preset_spec(n).exposure.exposure_s


# ------------------------------------------------------------------------------------------ the tracker's inputs
def test_tracker_sigma_comes_from_the_detector_and_gyro_sigma_from_the_grade():
    for grade in ("navigation", "tactical", "industrial"):
        unit = StarTrackerUnit(UnitConfig(camera="paper004", gyro_grade=grade))
        g = gyro_preset(grade, rate_hz=100.0)
        per_sample = g.arw_rad_sqrt_s * math.sqrt(100.0)  # white rate noise of one 10 ms average
        assert unit.trackers[0].gyro_sigma_rad_s == pytest.approx(gyro_rate_sigma_rad_s(g))
        assert unit.trackers[0].gyro_sigma_rad_s >= per_sample
    assert gyro_rate_sigma_rad_s(gyro_preset("tactical")) == pytest.approx(3.6e-4, rel=0.03)
    # the detector decides the tracker's centroid σ: the intensified 1 ms camera is noisier than ZY-3's 125 ms
    s000 = StarTrackerUnit(UnitConfig(camera="paper000")).trackers[0].centroid_sigma_px
    szy3 = StarTrackerUnit(UnitConfig(camera="zy3")).trackers[0].centroid_sigma_px
    assert s000 == pytest.approx(preset_spec("paper000").centroid_sigma_px()) and s000 > szy3
    # an explicit σ wins
    fixed = StarTrackerSpec.from_dict({"preset": "paper000", "tracker": {"centroid_sigma_px": 0.7}})
    assert StarTrackerUnit(UnitConfig(camera=fixed)).trackers[0].centroid_sigma_px == 0.7


def test_detector_sigma_is_the_weighted_rms_of_the_theory():
    from startracker.centroid.fidelity import predicted_centroid_sigma_px

    s = preset_spec("paper004")
    v = np.arange(-1.0, s.mag_limit + 1e-9, 0.1)
    tau = s.exposure.exposure_s
    still, p0 = predicted_centroid_sigma_px(s.detector, s.camera, v, tau)
    streak_px = math.radians(s.tracker.sigma_rate_deg_s) * s.camera.focal_length_px * tau
    moving, p1 = predicted_centroid_sigma_px(s.detector, s.camera, v, tau, smear_px=streak_px)
    w0, w1 = 10 ** (0.6 * v) * p0, 10 ** (0.6 * v) * p1
    expected = math.sqrt((np.sum(w0 * still**2) + np.sum(w1 * moving**2)) / (np.sum(w0) + np.sum(w1)))
    assert s.detector_sigma_px() == pytest.approx(expected)
    assert s.centroid_sigma_px() == pytest.approx(s.tracker.sigma_margin * expected)
    assert np.all(moving[p1 > 0.5] > still[p1 > 0.5])  # a streak's centroid is less certain
    # a quieter detector gives a smaller σ star by star (its population RMS may not fall: it detects fainter stars)
    quiet = StarTrackerSpec.from_dict({"preset": "paper004", "detector": {"read_noise_e": 0.5}})
    still_q, p_q = predicted_centroid_sigma_px(quiet.detector, quiet.camera, v, tau)
    both = (p0 > 0.5) & (p_q > 0.5)
    assert both.sum() > 20 and np.all(still_q[both] < still[both])
    assert np.all(p_q >= p0 - 1e-12)  # and detects at least as much
    assert isinstance(s.detector, SensorModel)


def test_the_cli_takes_a_spec_as_env_json(tmp_path, capsys):
    from experiments.cli import main

    assert main(["slew", "--no-plots", "--out", str(tmp_path), "--seed", "2", "--max-episode-s", "1",
                 "--env", "camera=" + json.dumps(CUSTOM)]) == 0
    capsys.readouterr()
    summary = json.loads((tmp_path / "summary.json").read_text())
    cam = summary["env_config"]["camera"]
    assert StarTrackerSpec.from_dict(cam) == StarTrackerSpec.from_dict(CUSTOM)
    assert summary["env_config"]["frame_rate_hz"] == 10.0 and summary["env_config"]["mag_limit"] == 6.5


def test_the_readme_example_runs():
    """The README's "Describe your own star tracker" block, as written."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    section = text.split("### Describe your own star tracker", 1)[1]
    code = section.split("```python", 1)[1].split("```", 1)[0]
    namespace = {}
    exec(compile(code, "README.md", "exec"), namespace)
    env = namespace["env"]
    assert env.unwrapped.avionics.heads[0].camera.resolution == (1280, 1024)
    assert env.unwrapped.avionics.trackers[0].centroid_sigma_px == pytest.approx(namespace["spec"].centroid_sigma_px())
    env.close()
