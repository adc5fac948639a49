"""RL baselines: Stable-Baselines3 SAC and PPO on AgileSlew-v1 (optional extra ``rl``).

A checkpoint is a directory-free triple next to each other: ``<name>.zip`` (the SB3 model), ``<name>.json`` (what it
was trained on: algorithm, env id, the env keyword arguments that define its action and observation, training
settings) and, when observation/reward normalisation was used, ``<name>_vecnormalize.pkl``. :class:`SB3Policy`
wraps one as a :class:`~policies.base.Policy`; :class:`SACPolicy` and :class:`PPOPolicy` load the shipped
checkpoints (``load_policy("sac")``, ``load_policy("ppo")``), so a trained agent runs in the slew experiments,
campaigns and the agent benchmark on the env it was trained for (:meth:`SB3Policy.trained_env`).

Training (:func:`train`, ``scripts/train.py``) writes the checkpoint triple plus a learning curve (CSV and PNG):
deterministic evaluations on fixed scenarios during training.
"""

from __future__ import annotations

import csv
import json
import os
import time
from pathlib import Path

import numpy as np

from envs.agile_slew_v1 import action_from_command
from policies.base import ControllerSpec, Policy

__all__ = ["SB3Policy", "SACPolicy", "PPOPolicy", "train", "train_ppo", "make_training_env", "ALGOS",
           "CHECKPOINT_DIR", "DEFAULT_CHECKPOINT", "TRAIN_ENV_KWARGS", "LINEAR_ENV_KWARGS", "ROBUST_ENV_KWARGS",
           "evaluate_model", "plot_curve"]

CHECKPOINT_DIR = Path(__file__).resolve().parent / "checkpoints"
DEFAULT_CHECKPOINT = CHECKPOINT_DIR / "ppo_agileslew_v1.zip"
ALGOS = ("sac", "ppo", "td3")
V1_ID = "startracker/AgileSlew-v1"
# the training task: -v1 with the ideal sensor (cheap; the tracker's own cost is measured by evaluating on it),
# slews that cover the agent benchmark's easy level with margin, the env's default settle tolerances; the cubic
# action curve (small torques reachable); the attitude noise, and so the observed σ, drawn per episode over the range
# the EKF reports (0.5-20″), so that the policy does not key on one σ value the tracker never shows
TRAIN_ENV_KWARGS = dict(sensor="ideal", action_mode="body_torque", action_curve="cubic", fine_error_deg=0.2,
                        slew_angle_deg_range=(10.0, 60.0), ideal_attitude_noise_arcsec=(0.5, 20.0))
# the first shipped SAC's task (linear action, fixed 5″ noise): kept for comparison runs
LINEAR_ENV_KWARGS = dict(sensor="ideal", action_mode="body_torque", slew_angle_deg_range=(10.0, 60.0))
ROBUST_ENV_KWARGS = dict(LINEAR_ENV_KWARGS, ideal_attitude_noise_arcsec=(0.5, 20.0))
# entries of the training env's kwargs that define the policy's interface (kept when evaluating elsewhere)
INTERFACE_KEYS = ("action_mode", "action_curve", "fine_error_deg")
CURVE_FIELDS = ("timesteps", "wall_s", "cpu_s", "episodes", "train_return_mean", "train_success_rate",
                "eval_return_mean", "eval_success_rate", "eval_final_error_deg_median", "eval_settle_time_s_median")


def _require_sb3():
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        raise ImportError("the RL baseline needs the optional extra: pip install 'startracker-gym[rl]'") from None


def make_training_env(seed: int = 0, env_id: str = "startracker/AgileSlew-v0", **env_kwargs):
    """A factory for one training env. For ``-v0`` (the default): centroid fidelity, 40 s episodes, 10-90° slews
    unless overridden; for other ids the given keyword arguments only."""
    if env_id == "startracker/AgileSlew-v0":
        kwargs = dict(fidelity="centroid", max_episode_s=40.0, slew_angle_deg_range=(10.0, 90.0))
    else:
        kwargs = {}
    kwargs.update(env_kwargs)

    def _make():
        # imported here: SubprocVecEnv builds envs in fresh processes, which must register the ids themselves
        import gymnasium as gym
        from stable_baselines3.common.monitor import Monitor

        import envs  # noqa: F401

        env = Monitor(gym.make(env_id, **kwargs), info_keywords=("settled",) if env_id == V1_ID else ())
        env.reset(seed=seed)
        return env

    return _make


def _algo_class(algo: str):
    import stable_baselines3 as sb3

    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    return {"sac": sb3.SAC, "ppo": sb3.PPO, "td3": sb3.TD3}[algo]


def _model_kwargs(algo: str, seed: int) -> dict:
    """Hyperparameters per algorithm: small nets (2 cores), discount for ~10-20 s episodes at 0.1 s steps."""
    common = dict(seed=seed, verbose=0, device="cpu", gamma=0.99)
    if algo == "sac":
        return dict(common, learning_rate=1e-3, buffer_size=300_000, batch_size=256, learning_starts=2_000,
                    train_freq=1, gradient_steps=1, tau=0.01, policy_kwargs=dict(net_arch=[64, 64]))
    if algo == "td3":
        return dict(common, learning_rate=1e-3, buffer_size=300_000, batch_size=256, learning_starts=2_000,
                    train_freq=1, gradient_steps=1, policy_kwargs=dict(net_arch=[64, 64]))
    return dict(common, n_steps=1024, batch_size=256, learning_rate=3e-4, gae_lambda=0.95, n_epochs=10,
                ent_coef=0.0, clip_range=0.2, policy_kwargs=dict(net_arch=[64, 64], log_std_init=-1.0))


def checkpoint_paths(path) -> tuple[Path, Path, Path]:
    """(model .zip, metadata .json, VecNormalize .pkl) of a checkpoint given by its .zip path or stem."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix == ".zip" else p
    return stem.with_suffix(".zip"), stem.with_suffix(".json"), stem.parent / f"{stem.name}_vecnormalize.pkl"


# ---------------------------------------------------------------------------------------------------- evaluation
def eval_scenarios(n: int, angle_range=(20.0, 45.0)):
    """Fixed evaluation scenarios during training: (seed, slew angle) pairs, the same at every evaluation."""
    angles = np.random.default_rng(77).uniform(*angle_range, size=n)
    return [(500_000 + i, float(a)) for i, a in enumerate(angles)]


def evaluate_model(model, env_kwargs: dict, n_episodes: int = 10, vecnormalize=None, env_id: str = V1_ID,
                   angle_range=(20.0, 45.0)) -> dict:
    """Deterministic episodes of ``model`` on fixed scenarios: return, success rate, final error, settle time."""
    import gymnasium as gym

    import envs  # noqa: F401

    env = gym.make(env_id, **env_kwargs)
    returns, success, final_err, settle = [], [], [], []
    try:
        for seed, angle in eval_scenarios(n_episodes, angle_range):
            obs, info = env.reset(seed=seed, options={"slew_angle_deg": angle})
            total, done = 0.0, False
            while not done:
                o = vecnormalize.normalize_obs(obs) if vecnormalize is not None else obs
                action, _ = model.predict(o, deterministic=True)
                obs, r, term, trunc, info = env.step(action)
                total += r
                done = term or trunc
            returns.append(total)
            ok = bool(info.get("settled", False))
            success.append(ok)
            final_err.append(info["pointing_error_deg"])
            if ok:
                settle.append(info["time_s"] - env.unwrapped.settle_hold_s)
    finally:
        env.close()
    return dict(eval_return_mean=float(np.mean(returns)), eval_success_rate=float(np.mean(success)),
                eval_final_error_deg_median=float(np.median(final_err)),
                eval_settle_time_s_median=float(np.median(settle)) if settle else float("nan"))


def plot_curve(rows: list[dict], path, title: str = "", stage_starts=()) -> Path | None:
    """Learning curve PNG: return, success rate and final error against environment steps (None without
    matplotlib); ``stage_starts`` (environment steps) are marked by dotted lines (e.g. the fine-tuning stage)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    t = np.array([r["timesteps"] for r in rows], dtype=float) / 1000.0
    fig, ax = plt.subplots(1, 3, figsize=(11, 3.0), constrained_layout=True)
    ax[0].plot(t, [r["train_return_mean"] for r in rows], label="training episodes (stochastic)")
    ax[0].plot(t, [r["eval_return_mean"] for r in rows], label="evaluation (deterministic)")
    ax[0].set_ylabel("episode return")
    ax[0].legend(fontsize=7)
    ax[1].plot(t, [100 * r["train_success_rate"] for r in rows], label="training")
    ax[1].plot(t, [100 * r["eval_success_rate"] for r in rows], label="evaluation")
    ax[1].set_ylabel("settled (%)")
    ax[1].set_ylim(-5, 105)
    ax[1].legend(fontsize=7)
    ax[2].semilogy(t, [max(r["eval_final_error_deg_median"], 1e-4) for r in rows])
    ax[2].axhline(0.05, color="k", ls="--", lw=0.8, label="settle tolerance")
    ax[2].legend(fontsize=7)
    ax[2].set_ylabel("final error, median (°)")
    for a in ax:
        for x in stage_starts:
            a.axvline(x / 1000.0, color="grey", ls=":", lw=1.0)
        a.set_xlabel("environment steps (thousands)")
        a.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=9)
    path = Path(path)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------------- training
def demonstration_action(obs, inertia_kg_m2, max_rate_rad_s: float, wheel_max_torque_Nm: float,
                         action_curve: str = "linear") -> np.ndarray:
    """A rate-limited PD on the AgileSlew-v1 observation (decoded with its documented scales), (3,) in [-1, 1]
    (the action that gives the PD's torque through ``action_curve``): the demonstrations that seed an off-policy
    learner's replay buffer (``train(..., demo_episodes=N)``)."""
    e = np.asarray(obs[0:3], dtype=np.float64) * np.pi
    w = np.asarray(obs[6:9], dtype=np.float64) * max_rate_rad_s
    w_ref = np.clip(e / 1.8, -0.3, 0.3)
    tau = np.asarray(inertia_kg_m2) @ (1.8 * (w_ref - w))
    return action_from_command(np.clip(tau / wheel_max_torque_Nm, -1.0, 1.0), action_curve)


def add_demonstrations(model, vec, n_episodes: int, noise: float, seed: int) -> int:
    """Run :func:`demonstration_action` (plus Gaussian noise of std ``noise``, fading inside 5°) on the training envs for
    ``n_episodes`` episodes and add every transition to ``model.replay_buffer``; returns the transitions added."""
    rng = np.random.default_rng(seed)
    spec = vec.env_method("controller_spec")[0]
    max_rate = vec.get_attr("max_rate_rad_s")[0]
    curve = vec.get_attr("action_curve")[0]
    obs = vec.reset()
    done_episodes, n = 0, 0
    while done_episodes < n_episodes:
        raw = vec.get_original_obs() if hasattr(vec, "get_original_obs") else obs
        actions = np.stack([demonstration_action(o, spec["inertia_kg_m2"], max_rate, spec["wheel_max_torque_Nm"],
                                                 curve) for o in raw])
        # exploration noise fades inside 5° so that the demonstrations also settle (0.05°/s is 9 % of one step's
        # full-torque rate change)
        fade = np.minimum(np.linalg.norm(raw[:, 0:3] * np.pi, axis=1, keepdims=True) / np.radians(5.0), 1.0)
        actions = np.clip(actions + fade * rng.normal(0.0, noise, actions.shape), -1.0, 1.0).astype(np.float32)
        new_obs, rewards, dones, infos = vec.step(actions)
        next_obs = new_obs.copy()
        for i, d in enumerate(dones):
            if d:
                next_obs[i] = infos[i]["terminal_observation"]
                done_episodes += 1
        model.replay_buffer.add(obs, next_obs, actions, rewards, dones, infos)
        obs = new_obs
        n += len(actions)
    return n


def train(algo: str = "sac", total_timesteps: int = 150_000, out_dir="runs/sac", seed: int = 0, n_envs: int = 1,
          eval_every: int = 10_000, eval_episodes: int = 10, env_kwargs: dict | None = None,
          normalize: bool | None = None, progress: bool = True, name: str | None = None,
          demo_episodes: int = 0, demo_noise: float = 0.1, finetune_timesteps: int = 0,
          finetune_ent_coef: float = 1e-3, init_from=None) -> dict:
    """Train one agent on AgileSlew-v1 and write its checkpoint and learning curve into ``out_dir``.

    Parameters
    ----------
    algo : {"sac", "ppo", "td3"}
    total_timesteps : int
        Environment steps across all envs.
    out_dir : path
        Receives ``<name>.zip``, ``<name>.json``, ``<name>_vecnormalize.pkl`` (if normalised), ``curve.csv``,
        ``curve.png``.
    seed : int
        Seeds the model, the envs (env i gets ``seed + i``) and the evaluation scenarios are fixed.
    n_envs : int
        Parallel envs (in-process: the ideal-sensor env costs a fraction of a gradient step).
    eval_every : int
        Steps between deterministic evaluations (the learning curve's points).
    env_kwargs : dict, optional
        Training env arguments; default :data:`TRAIN_ENV_KWARGS`.
    normalize : bool, optional
        Wrap in ``VecNormalize`` (observation and reward); default True for PPO, False otherwise.
    name : str, optional
        Checkpoint stem; default ``<algo>_agileslew_v1``.
    demo_episodes : int
        Off-policy algorithms: episodes of :func:`demonstration_action` (with Gaussian action noise of std
        ``demo_noise``) put into the replay buffer before learning; counted in the curve's steps.
    finetune_timesteps : int
        SAC: further steps after ``total_timesteps`` with the entropy coefficient fixed at ``finetune_ent_coef``
        (a nearly deterministic policy: precision for the settle window, which exploration noise keeps missing).
    init_from : path, optional
        Start from this SB3 checkpoint's weights instead of a fresh network.

    Returns
    -------
    dict
        The metadata written to ``<name>.json``.
    """
    _require_sb3()
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    torch.set_num_threads(1)  # the machine's cores go to the envs and other jobs; small nets gain nothing from more
    kwargs = dict(TRAIN_ENV_KWARGS if env_kwargs is None else env_kwargs)
    normalize = (algo == "ppo") if normalize is None else bool(normalize)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = name or f"{algo}_agileslew_v1"
    zip_path, json_path, vn_path = checkpoint_paths(out_dir / name)
    best_zip, best_json, best_vn = checkpoint_paths(out_dir / f"{name}_best")
    vec = DummyVecEnv([make_training_env(seed + i, env_id=V1_ID, **kwargs) for i in range(n_envs)])
    vec.seed(seed)
    if normalize:
        vec = VecNormalize(vec, norm_obs=True, norm_reward=True, gamma=0.99)
    model = _algo_class(algo)("MlpPolicy", vec, **_model_kwargs(algo, seed))
    n_demo = 0
    if demo_episodes:
        if algo == "ppo":
            raise ValueError("demo_episodes needs an off-policy algorithm (sac, td3)")
        n_demo = add_demonstrations(model, vec, demo_episodes, demo_noise, seed)
    rows: list[dict] = []
    # evaluated as the agent benchmark's easy level is scored: 60 s episodes, the env's settle tolerances
    eval_kwargs = dict(kwargs, max_episode_s=60.0, max_episode_steps=600)
    t0, c0 = time.perf_counter(), time.process_time()

    class Curve(BaseCallback):
        def __init__(self):
            super().__init__()
            self.returns, self.successes, self.episodes, self.next_eval = [], [], 0, eval_every
            self.best_key, self.best_row = (0.0, -np.inf), None

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", ()):
                ep = info.get("episode")
                if ep is not None:
                    self.returns.append(float(ep["r"]))
                    self.successes.append(bool(info.get("settled", False)))
                    self.episodes += 1
            if self.num_timesteps >= self.next_eval:
                self.next_eval += eval_every
                self.record()
            return True

        def record(self):
            vn = vec if normalize else None
            ev = evaluate_model(self.model, eval_kwargs, eval_episodes, vecnormalize=vn)
            recent = slice(-50, None)
            row = dict(timesteps=int(self.num_timesteps) + n_demo, wall_s=round(time.perf_counter() - t0, 1),
                       cpu_s=round(time.process_time() - c0, 1), episodes=self.episodes,
                       train_return_mean=float(np.mean(self.returns[recent])) if self.returns else float("nan"),
                       train_success_rate=float(np.mean(self.successes[recent])) if self.successes else 0.0, **ev)
            rows.append(row)
            _write_curve(rows, out_dir / "curve.csv")
            key = (row["eval_success_rate"], row["eval_return_mean"])
            if row["eval_success_rate"] > 0 and key > self.best_key:
                # the best evaluated model so far (success, then return), shipped if the last one is worse
                self.best_key, self.best_row = key, row
                self.model.save(best_zip)
                if normalize:
                    vec.save(str(best_vn))
            if progress:
                print(f"[{algo}] {row['timesteps']:>7d} steps {row['wall_s']:>6.0f} s  episodes {row['episodes']:>5d}  "
                      f"train return {row['train_return_mean']:7.2f} settled {100 * row['train_success_rate']:3.0f} %  "
                      f"eval return {row['eval_return_mean']:7.2f} settled {100 * row['eval_success_rate']:3.0f} %  "
                      f"final error {row['eval_final_error_deg_median']:.3g}°  cpu {row['cpu_s']:.0f} s  "
                      f"load {os.getloadavg()[0]:.1f}", flush=True)

    if init_from is not None:
        model.set_parameters(str(init_from), exact_match=False, device="cpu")  # a fine-tuned one has no entropy optimiser
        model.learning_starts = 0  # a trained actor explores better than uniform random actions
    curve = Curve()
    if total_timesteps > 0:
        model.learn(total_timesteps=int(total_timesteps), callback=curve, progress_bar=False)
    if finetune_timesteps:
        if algo != "sac":
            raise ValueError("finetune_timesteps needs algo='sac'")
        model.ent_coef_optimizer = None  # SB3's SAC then uses ent_coef_tensor as a constant
        model.ent_coef = float(finetune_ent_coef)  # saved so, the checkpoint loads as a fixed-entropy SAC
        model.ent_coef_tensor = torch.tensor(float(finetune_ent_coef))
        lr = float(model.learning_rate) / 3.0  # smaller steps once the policy is near its goal
        model.lr_schedule = lambda _progress: lr
        model.learn(total_timesteps=int(finetune_timesteps), callback=curve, progress_bar=False,
                    reset_num_timesteps=total_timesteps == 0)
    if not rows or rows[-1]["timesteps"] != model.num_timesteps + n_demo:
        curve.record()  # the final model is on the curve too
    wall = time.perf_counter() - t0
    model.save(zip_path)
    if normalize:
        vec.save(str(vn_path))
    import stable_baselines3

    meta = dict(algo=algo, env_id=V1_ID, env_kwargs={k: kwargs[k] for k in INTERFACE_KEYS if k in kwargs},
                train_env_kwargs={k: list(v) if isinstance(v, tuple) else v for k, v in kwargs.items()},
                total_timesteps=int(total_timesteps), finetune_timesteps=int(finetune_timesteps),
                finetune_ent_coef=finetune_ent_coef, init_from=str(init_from) if init_from else None, demo_episodes=demo_episodes, demo_noise=demo_noise,
                demo_transitions=n_demo, n_envs=n_envs, seed=seed, normalize=normalize,
                wall_s=round(wall, 1), cpu_s=round(time.process_time() - c0, 1),
                load_average_end=[round(v, 2) for v in os.getloadavg()], torch_threads=1, sb3_version=stable_baselines3.__version__,
                hyperparameters={k: v for k, v in _model_kwargs(algo, seed).items() if k not in ("verbose", "device")},
                final_eval=rows[-1] if rows else None)
    json_path.write_text(json.dumps(meta, indent=2, default=str) + "\n")
    if curve.best_row is not None:
        best_json.write_text(json.dumps(dict(meta, final_eval=curve.best_row, best_of_curve=True), indent=2,
                                        default=str) + "\n")
    stages = (n_demo + total_timesteps,) if finetune_timesteps and total_timesteps else ()
    plot_curve(rows, out_dir / "curve.png", stage_starts=stages,
               title=f"{algo.upper()} on AgileSlew-v1 (ideal sensor, {kwargs.get('action_curve', 'linear')} action), "
                     f"seed {seed}" + (" · dotted: fixed-entropy fine-tuning starts" if stages else ""))
    vec.close()
    return meta


def _write_curve(rows, path):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CURVE_FIELDS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in CURVE_FIELDS})


def train_ppo(total_timesteps: int = 100_000, n_envs: int = 2, seed: int = 0, out_path=None, progress: bool = True,
              **env_kwargs):
    """PPO on AgileSlew-v1 (see :func:`train`), the checkpoint stem taken from ``out_path``."""
    out = Path(out_path) if out_path is not None else Path("runs/ppo/ppo_agileslew_v1.zip")
    kwargs = dict(TRAIN_ENV_KWARGS, **env_kwargs)
    return train("ppo", total_timesteps, out_dir=out.parent, seed=seed, n_envs=n_envs, env_kwargs=kwargs,
                 progress=progress, name=out.with_suffix("").name)


# ---------------------------------------------------------------------------------------------------- the policy
class SB3Policy(Policy):
    """A trained SB3 model acting on the env's observation (deterministic actions).

    Parameters
    ----------
    spec : ControllerSpec
    checkpoint : path, optional
        The ``.zip`` written by :func:`train`; default the class's shipped checkpoint (or ``$STARTRACKER_<ALGO>_CHECKPOINT``).
        Its ``.json`` names the algorithm and the env it was trained for; without one the model is taken as a
        ``-v0`` PPO model.
    """

    algo = "sac"
    default_checkpoint = CHECKPOINT_DIR / "sac_agileslew_v1.zip"

    def __init__(self, spec: ControllerSpec, checkpoint=None):
        super().__init__(spec)
        _require_sb3()
        path = self.resolve_checkpoint(checkpoint)
        zip_path, _, vn_path = checkpoint_paths(path)
        if not zip_path.exists():
            raise ValueError(f"checkpoint {zip_path} does not exist: train one with scripts/train.py")
        self.metadata = self.read_metadata(zip_path)
        # a fine-tuned SAC was trained with a fixed entropy coefficient: it loads as one
        custom = {"ent_coef": self.metadata["finetune_ent_coef"]} if self.metadata.get("finetune_timesteps") else None
        self.model = _algo_class(self.metadata["algo"]).load(zip_path, device="cpu", custom_objects=custom)
        self.vecnormalize = None
        if self.metadata.get("normalize") and vn_path.exists():
            import pickle

            with open(vn_path, "rb") as f:
                self.vecnormalize = pickle.load(f)
            self.vecnormalize.training = False
        self.checkpoint = zip_path
        # an instance answers for its own checkpoint (the classmethod for the class's default one)
        self.trained_env = lambda: (self.metadata["env_id"], dict(self.metadata.get("env_kwargs", {})))

    @classmethod
    def resolve_checkpoint(cls, checkpoint=None) -> Path:
        env_var = f"STARTRACKER_{cls.algo.upper()}_CHECKPOINT"
        return Path(checkpoint or os.environ.get(env_var, cls.default_checkpoint))

    @classmethod
    def read_metadata(cls, zip_path) -> dict:
        _, json_path, _ = checkpoint_paths(zip_path)
        if json_path.exists():
            return json.loads(json_path.read_text())
        return dict(algo=cls.algo, env_id="startracker/AgileSlew-v0", env_kwargs={}, normalize=False)

    @classmethod
    def trained_env(cls, checkpoint=None) -> tuple[str, dict]:
        """(env id, env keyword arguments that define the policy's action and observation) of the checkpoint."""
        meta = cls.read_metadata(checkpoint_paths(cls.resolve_checkpoint(checkpoint))[0])
        return meta["env_id"], dict(meta.get("env_kwargs", {}))

    def act(self, observation):
        obs = np.asarray(observation, dtype=np.float32)
        if self.vecnormalize is not None:
            obs = self.vecnormalize.normalize_obs(obs).astype(np.float32)
        action, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(action, dtype=np.float32)


class SACPolicy(SB3Policy):
    """The shipped SAC checkpoint on AgileSlew-v1 (``load_policy("sac")``)."""

    algo = "sac"
    default_checkpoint = CHECKPOINT_DIR / "sac_agileslew_v1.zip"


class PPOPolicy(SB3Policy):
    """The shipped PPO checkpoint on AgileSlew-v1 (``load_policy("ppo")``)."""

    algo = "ppo"
    default_checkpoint = DEFAULT_CHECKPOINT
