"""Gymnasium's own checker on the raw environments, the wall-clock wrapper, and repeatable resets of one instance."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs
from envs.wrappers import WallClockLatency


def registered_ids():
    ids = sorted(k for k in gym.registry if k.startswith("startracker/"))
    assert set(envs.ENV_IDS) <= set(ids)
    return ids


@pytest.mark.parametrize("env_id", registered_ids())
def test_check_env_passes_on_the_raw_env(env_id):
    """No wrapper: info is a function of the seed and the actions (check_env compares it between two runs)."""
    env = gym.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", registered_ids())
def test_make_adds_the_wall_clock_wrapper_and_it_can_be_dropped(env_id):
    env = gym.make(env_id)
    assert isinstance(env, WallClockLatency)
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(env.action_space.sample())
    assert set(envs.WALL_CLOCK_INFO_KEYS) <= set(info) and info["matching_wall_clock_ms"] >= 0.0
    raw = env.unwrapped
    _, info_raw = raw.reset(seed=0)
    _, _, _, _, info_raw = raw.step(np.zeros(raw.action_space.shape, np.float32))
    assert not set(envs.WALL_CLOCK_INFO_KEYS) & set(info_raw)
    assert info_raw["matching_latency_ms"] > 0.0  # the modelled latency stays in the raw env's info
    env.close()


def episode(env, seed, n_steps):
    """Trajectory of true and estimated states and the full info, with actions drawn from their own generator."""
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed + 100)
    rows = [(obs, info["q_true"], info["q_est"], info["omega_true_body"], 0.0)]
    for _ in range(n_steps):
        obs, r, te, tr, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        rows.append((obs, info["q_true"], info["q_est"], info["omega_true_body"], r))
    state = env.spacecraft.get_state()
    return rows, info, state


@pytest.mark.parametrize("env_id", registered_ids())
def test_repeated_resets_of_one_instance_repeat_the_episode_bit_for_bit(env_id):
    """Reset twice with the same seed on one instance: the same trajectory, bit for bit, as on a fresh instance
    (the spacecraft's MuJoCo data carries nothing over: wheel angles, held commands, warm start)."""
    env = gym.make(env_id).unwrapped
    a, info_a, state_a = episode(env, 11, 25)
    b, info_b, state_b = episode(env, 11, 25)
    fresh = gym.make(env_id).unwrapped
    c, _, state_c = episode(fresh, 11, 25)
    for x, y, z in zip(a, b, c):
        for u, v, w in zip(x, y, z):
            assert np.array_equal(u, v) and np.array_equal(u, w)
    assert np.array_equal(state_a, state_b) and np.array_equal(state_a, state_c)
    assert info_a.keys() == info_b.keys()
    for k in info_a:
        assert np.array_equal(np.asarray(info_a[k]), np.asarray(info_b[k])), k
    env.close()
    fresh.close()
