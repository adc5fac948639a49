"""RL baseline: Stable-Baselines3 PPO on AgileSlew-v0 (optional extra ``rl``).

Training runs on vectorised envs (``gymnasium.vector.AsyncVectorEnv`` through SB3's ``SubprocVecEnv``); the trained
model is wrapped as a :class:`~policies.base.Policy`, so it runs in the same slew experiments, campaigns and agent
benchmark as the scripted controllers (``--policy policies.rl:PPOPolicy`` with ``STARTRACKER_PPO_CHECKPOINT`` set,
or ``PPOPolicy(spec, checkpoint=...)``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from policies.base import ControllerSpec, Policy

__all__ = ["PPOPolicy", "train_ppo", "make_training_env"]

DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "ppo_agileslew.zip"


def _require_sb3():
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        raise ImportError("the RL baseline needs the optional extra: pip install 'startracker-gym[rl]'") from None


def make_training_env(seed: int = 0, **env_kwargs):
    """A factory for one training env (centroid fidelity, shorter episodes and moderate slews by default)."""
    kwargs = dict(fidelity="centroid", max_episode_s=40.0, slew_angle_deg_range=(10.0, 90.0))
    kwargs.update(env_kwargs)

    def _make():
        # imported here: SubprocVecEnv builds envs in fresh processes, which must register the ids themselves
        import gymnasium as gym

        import envs  # noqa: F401

        env = gym.make("startracker/AgileSlew-v0", **kwargs)
        env.reset(seed=seed)
        return env

    return _make


def train_ppo(total_timesteps: int = 100_000, n_envs: int = 2, seed: int = 0, out_path=DEFAULT_CHECKPOINT,
              progress: bool = True, **env_kwargs):
    """Train PPO and save the model.

    Parameters
    ----------
    total_timesteps : int
        Environment steps across all envs.
    n_envs : int
        Parallel envs (subprocesses when > 1).
    seed : int
    out_path : path
        Where the ``.zip`` checkpoint goes.

    Returns
    -------
    stable_baselines3.PPO
    """
    _require_sb3()
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    fns = [make_training_env(seed + i, **env_kwargs) for i in range(n_envs)]
    vec = SubprocVecEnv(fns) if n_envs > 1 else DummyVecEnv(fns)
    model = PPO("MlpPolicy", vec, n_steps=512, batch_size=256, learning_rate=3e-4, gamma=0.995, gae_lambda=0.95,
                ent_coef=0.0, policy_kwargs=dict(net_arch=[64, 64]), seed=seed, verbose=0, device="cpu")
    model.learn(total_timesteps=int(total_timesteps), progress_bar=progress and _has_rich())
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    model.save(out_path)
    vec.close()
    return model


def _has_rich() -> bool:
    try:
        import rich  # noqa: F401
        import tqdm  # noqa: F401

        return True
    except ImportError:
        return False


class PPOPolicy(Policy):
    """A trained SB3 PPO model acting on the env's observation (deterministic actions).

    Parameters
    ----------
    spec : ControllerSpec
    checkpoint : path, optional
        The ``.zip`` saved by :func:`train_ppo`; default ``$STARTRACKER_PPO_CHECKPOINT`` or the packaged path.
    """

    def __init__(self, spec: ControllerSpec, checkpoint=None):
        super().__init__(spec)
        _require_sb3()
        from stable_baselines3 import PPO

        path = Path(checkpoint or os.environ.get("STARTRACKER_PPO_CHECKPOINT", DEFAULT_CHECKPOINT))
        if not path.exists():
            raise ValueError(f"checkpoint {path} does not exist: train one with scripts/train_ppo.py")
        self.model = PPO.load(path, device="cpu")

    def act(self, observation):
        action, _ = self.model.predict(np.asarray(observation, dtype=np.float32), deterministic=True)
        return np.asarray(action, dtype=np.float32)
