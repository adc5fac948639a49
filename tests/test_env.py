"""The Gymnasium environments: API conformance, determinism, pickling, vector envs, bad input, info contract."""

import pickle

import gymnasium as gym
import numpy as np
import pytest

import envs
from startracker.rotations import quat_angle_between

ENV_IDS = list(envs.ENV_IDS)
INFO_KEYS = {
    "q_true", "q_est", "attitude_error_arcsec", "update_rate_hz", "matching_latency_ms", "tracker_mode",
    "n_stars", "exposures_per_frame", "reward_pointing", "reward_effort", "reward_settle",
}


def rollout(env_id, seed, n, **kwargs):
    env = gym.make(env_id, **kwargs)
    obs, info = env.reset(seed=seed)
    out = [obs]
    rewards = []
    rng = np.random.default_rng(seed)
    for _ in range(n):
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        out.append(obs)
        rewards.append(r)
    env.close()
    return np.array(out), np.array(rewards), info


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_same_seed_same_episode_bit_for_bit(env_id):
    o1, r1, i1 = rollout(env_id, 7, 15)
    o2, r2, i2 = rollout(env_id, 7, 15)
    assert np.array_equal(o1, o2) and np.array_equal(r1, r2)
    assert np.array_equal(i1["q_true"], i2["q_true"]) and np.array_equal(i1["q_est"], i2["q_est"])
    o3, _, _ = rollout(env_id, 8, 3)
    assert not np.array_equal(o1[:4], o3)


def test_info_contract_and_observation_bounds():
    env = gym.make("startracker/AgileSlew-v0")
    obs, info = env.reset(seed=1)
    assert INFO_KEYS <= set(info)
    for _ in range(10):
        obs, r, term, trunc, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        assert INFO_KEYS <= set(info)
        assert info["tracker_mode"] in ("lost", "acquire", "track")
        assert np.isclose(np.linalg.norm(info["q_true"]), 1.0) and np.isclose(np.linalg.norm(info["q_est"]), 1.0)
        assert np.isclose(r, info["reward_pointing"] + info["reward_effort"] + info["reward_settle"])
        # the attitude error reported is the angle between the truth and the estimate
        assert info["attitude_error_arcsec"] == pytest.approx(
            np.degrees(quat_angle_between(info["q_true"], info["q_est"])) * 3600, rel=1e-9, abs=1e-6)
    env.close()


def test_tracker_locks_and_estimate_is_accurate_at_rest():
    env = gym.make("startracker/AttitudeHold-v0")
    env.reset(seed=3)
    errs = []
    for _ in range(20):
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
        errs.append(info["attitude_error_arcsec"])
    assert info["tracker_mode"] == "track"
    assert info["update_rate_hz"] >= 10.0
    assert np.median(errs[-10:]) < 30.0  # paper000 camera: a few arcsec cross-boresight, roll larger
    env.close()


def test_env_pickles_and_continues_identically():
    env = gym.make("startracker/AgileSlew-v0").unwrapped
    env.reset(seed=4)
    for _ in range(3):
        env.step(np.full(env.action_space.shape, 0.3, np.float32))
    clone = pickle.loads(pickle.dumps(env))
    a = np.full(env.action_space.shape, -0.2, np.float32)
    o1 = env.step(a)[0]
    o2 = clone.step(a)[0]
    assert np.array_equal(o1, o2)


@pytest.mark.parametrize("env_id", ["startracker/AgileSlew-v0", "startracker/AgileSlew-v1"])
def test_info_keys_returns_only_the_named_keys_of_the_same_episode(env_id):
    wanted = ("settled_s", "reward_pointing", "matching_wall_clock_ms", "q_est")
    full, lean = gym.make(env_id), gym.make(env_id, info_keys=wanted)
    (o_f, i_f), (o_l, i_l) = full.reset(seed=3), lean.reset(seed=3)
    rng = np.random.default_rng(3)
    for step in range(12):
        assert set(i_l) == set(wanted)
        assert np.array_equal(o_f, o_l)
        for k in ("settled_s", "reward_pointing", "q_est"):  # the wall clock differs from run to run
            assert np.array_equal(i_f[k], i_l[k])
        a = rng.uniform(-1, 1, full.action_space.shape).astype(np.float32)
        o_f, r_f, *_, i_f = full.step(a)
        o_l, r_l, *_, i_l = lean.step(a)
        assert r_f == r_l


def test_full_info_holds_exactly_the_listed_keys():
    for env_id in ENV_IDS:
        env = gym.make(env_id)
        _, info = env.reset(seed=0)
        listed = env.unwrapped.available_info_keys + envs.WALL_CLOCK_INFO_KEYS
        assert set(info) == set(listed) and len(listed) == len(set(listed))
        assert set(env.step(env.action_space.sample())[4]) == set(listed)
        assert set(gym.make(env_id, info_keys=()).reset(seed=0)[1]) == set()


@pytest.mark.parametrize("bad,error", [("settled_s", TypeError), (["settled_s", 3], TypeError), (7, TypeError),
                                       (["settled_s", "no_such_key"], ValueError)])
def test_bad_info_keys_are_refused_by_name(bad, error):
    with pytest.raises(error, match="info_keys"):
        gym.make("startracker/AgileSlew-v0", info_keys=bad)


def test_async_vector_env_with_few_info_keys():
    keys = ("reward_pointing", "settled_s")
    vec = gym.vector.AsyncVectorEnv([lambda: gym.make("startracker/AgileSlew-v0", info_keys=keys)] * 2)
    vec.reset(seed=[0, 1])
    _, _, _, _, info = vec.step(vec.action_space.sample())
    assert set(info) == set(keys) | {"_" + k for k in keys} and info["reward_pointing"].shape == (2,)
    vec.close()


def test_async_vector_env_runs():
    vec = gym.vector.AsyncVectorEnv([lambda: gym.make("startracker/AgileSlew-v0")] * 2)
    obs, info = vec.reset(seed=[0, 1])
    assert obs.shape == (2,) + vec.single_observation_space.shape
    for _ in range(3):
        obs, r, term, trunc, info = vec.step(vec.action_space.sample())
    assert np.all(np.isfinite(obs)) and np.all(np.isfinite(r))
    vec.close()


@pytest.mark.parametrize(
    "kwargs,word",
    [
        (dict(fidelity="photon"), "fidelity"),
        (dict(camera="hubble"), "camera"),
        (dict(control_period_s=-0.1), "control_period_s"),
        (dict(n_exposures=0), "n_exposures"),
        (dict(matcher="magic"), "matcher"),
        (dict(identify_method="guess"), "identify_method"),
        (dict(gyro_grade="toy"), "gyro_grade"),
        (dict(frame_rate_hz=3.0), "frame_rate_hz"),
        (dict(slew_angle_deg_range=(10, 200)), "slew_angle_deg_range"),
    ],
)
def test_invalid_kwargs_raise_at_make(kwargs, word):
    with pytest.raises(ValueError, match=word):
        gym.make("startracker/AgileSlew-v0", **kwargs)


def test_unknown_render_mode_raises():
    from envs.agile_slew import AgileSlewEnv

    with pytest.raises(ValueError, match="render_mode"):
        AgileSlewEnv(render_mode="human")


def test_bad_actions_are_refused_without_corrupting_state():
    env = gym.make("startracker/AgileSlew-v0").unwrapped
    env.reset(seed=5)
    q_before = env.spacecraft.q_body_to_icrs.copy()
    t_before = env.spacecraft.time_s
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0, 0, 0], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, np.float32))
    assert env.spacecraft.time_s == t_before and np.array_equal(env.spacecraft.q_body_to_icrs, q_before)
    obs, *_ = env.step(np.array([5.0, -5.0, 0.0, 0.0], np.float32))  # clipped like Gymnasium does
    assert np.all(np.isfinite(obs))


def test_render_returns_star_image():
    env = gym.make("startracker/AgileSlew-v0", render_mode="rgb_array")
    env.reset(seed=6)
    env.step(np.zeros(env.action_space.shape, np.float32))
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert img.shape[:2] == (2048, 2048)
    assert img.max() > img.mean()  # stars stand out of the background
    env.close()


def test_3cmos_head_tracks_and_renders_colour():
    env = gym.make("startracker/AttitudeHold-v0", camera="paper004_3cmos", render_mode="rgb_array")
    env.reset(seed=2)
    errs = []
    for _ in range(15):
        info = env.step(np.zeros(env.action_space.shape, np.float32))[4]
        errs.append(info["attitude_error_arcsec"])
    assert info["tracker_mode"] == "track"
    assert np.median(errs[-5:]) < 30.0
    img = env.render()
    assert img.shape == (1544, 2064, 3)
    # a colour picture: the red and blue planes are not copies of green
    assert not np.array_equal(img[..., 0], img[..., 1]) and not np.array_equal(img[..., 2], img[..., 1])
    env.close()


def test_two_heads_beat_one_in_attitude_error():
    def median_error(n_heads):
        # no processing delay: at the step's end the estimate has seen the last frame of every head (with a delay
        # it has not, and the gyro's propagation since the previous frame dominates both errors)
        env = gym.make("startracker/AttitudeHold-v0", n_heads=n_heads, processor=0.0)
        errs = []
        for seed in (0, 1):
            env.reset(seed=seed)
            for k in range(25):
                info = env.step(np.zeros(env.action_space.shape, np.float32))[4]
                if k >= 10:
                    errs.append(info["attitude_error_arcsec"])
        env.close()
        return np.median(errs)

    # a second boresight 45 deg away observes the first head's roll axis cross-boresight
    assert median_error(2) < 0.85 * median_error(1)


def test_two_head_kwargs_are_validated():
    with pytest.raises(ValueError, match="n_heads"):
        gym.make("startracker/AgileSlew-v0", n_heads=3)
    with pytest.raises(ValueError, match="head_separation_deg"):
        gym.make("startracker/AgileSlew-v0", n_heads=2, head_separation_deg=2.0)
