"""The RL baseline's plumbing: SB3 PPO on the env, saved, loaded as a Policy and run in the slew experiment.
(CI does not train: an untrained model exercises the same path.)"""

import gymnasium as gym
import numpy as np

import envs  # noqa: F401
from experiments.episode import run_episode
from policies.rl import PPOPolicy, make_training_env


def test_ppo_checkpoint_runs_as_a_policy(tmp_path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = SubprocVecEnv([make_training_env(0), make_training_env(1)])  # fresh processes, as training uses
    model = PPO("MlpPolicy", vec, n_steps=16, batch_size=16, seed=0, device="cpu")
    model.learn(total_timesteps=32)
    path = tmp_path / "ppo.zip"
    model.save(path)
    vec.close()
    env = gym.make("startracker/AgileSlew-v0")
    pol = PPOPolicy.from_env(env, checkpoint=path)
    obs, _ = env.reset(seed=0)
    a = pol.act(obs)
    assert a.shape == env.action_space.shape and np.all(np.isfinite(a))
    res = run_episode(policy=pol, seed=0, max_steps=5)
    assert res.summary["steps"] == 5
