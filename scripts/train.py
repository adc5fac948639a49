"""Train an RL baseline (SAC, PPO or TD3) on AgileSlew-v1 with the ideal sensor; writes the checkpoint and its
learning curve (CSV and PNG) into ``--out``.

    python scripts/train.py --algo sac --out runs/sac

(SAC: 100 PD demonstrations, 60,000 steps with automatic entropy, 30,000 steps at a fixed entropy coefficient of
1e-4; the cubic action curve, the 0.2° scale of the observation's fine error entries, the ideal sensor's noise
drawn per episode over 0.5-20″. That is the shipped checkpoint's command: docs/rl.md.)

``--ship`` then copies the checkpoint into policies/checkpoints (refused if one is there, unless ``--overwrite``).
"""

import argparse
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from policies.rl import (ALGOS, CHECKPOINT_DIR, TRAIN_ENV_KWARGS, checkpoint_paths,  # noqa: E402
                         train)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--algo", choices=ALGOS, default="sac")
    ap.add_argument("--timesteps", type=int, default=None, help="default 60000 (SAC, TD3), 100000 (PPO)")
    ap.add_argument("--envs", type=int, default=None, help="parallel in-process envs; default 2 (SAC, TD3), 8 (PPO)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="output directory, default runs/<algo>")
    ap.add_argument("--eval-every", type=int, default=5_000)
    ap.add_argument("--demos", type=int, default=None,
                    help="SAC/TD3: episodes of a scripted PD put into the replay buffer before learning (default 100)")
    ap.add_argument("--finetune", type=int, default=None,
                    help="SAC: further steps with the entropy coefficient fixed at --finetune-ent-coef (default 30000)")
    ap.add_argument("--finetune-ent-coef", type=float, default=1e-4)
    ap.add_argument("--init", default=None, help="start from this checkpoint's weights")
    ap.add_argument("--action-curve", choices=("cubic", "linear"), default="cubic",
                    help="action -> torque: a³ (default) or a (the first shipped SAC's)")
    ap.add_argument("--fine-error-deg", type=float, default=0.2,
                    help="scale of the observation's tanh(error / scale) entries, deg (1 for the first shipped SAC's)")
    ap.add_argument("--fixed-noise", action="store_true",
                    help="ideal sensor noise fixed at 5 arcsec (the first shipped SAC's) instead of drawn per episode "
                         "in 0.5-20 arcsec (the tracker's σ range)")
    ap.add_argument("--ship", action="store_true", help="copy the checkpoint into policies/checkpoints")
    ap.add_argument("--overwrite", action="store_true", help="allow --ship or --out to replace existing files")
    args = ap.parse_args(argv)
    timesteps = args.timesteps if args.timesteps is not None else (100_000 if args.algo == "ppo" else 60_000)
    finetune = args.finetune if args.finetune is not None else (30_000 if args.algo == "sac" else 0)
    env_kwargs = dict(TRAIN_ENV_KWARGS, action_curve=args.action_curve, fine_error_deg=args.fine_error_deg)
    if args.fixed_noise:
        env_kwargs["ideal_attitude_noise_arcsec"] = 5.0
    demos = (0 if args.algo == "ppo" else 100) if args.demos is None else args.demos
    n_envs = args.envs or (8 if args.algo == "ppo" else 2)
    out = Path(args.out or f"runs/{args.algo}")
    name = f"{args.algo}_agileslew_v1"
    if out.resolve() == CHECKPOINT_DIR.resolve() and not args.overwrite:
        sys.exit(f"--out {out} is the shipped checkpoint directory: use --ship, or --overwrite to replace it")
    if checkpoint_paths(out / name)[0].exists() and not args.overwrite:
        sys.exit(f"{checkpoint_paths(out / name)[0]} exists: choose another --out or pass --overwrite")
    t0 = time.perf_counter()
    meta = train(args.algo, timesteps, out_dir=out, seed=args.seed, n_envs=n_envs, eval_every=args.eval_every,
                 name=name, demo_episodes=demos, env_kwargs=env_kwargs, finetune_timesteps=finetune,
                 finetune_ent_coef=args.finetune_ent_coef, init_from=args.init)
    print(f"trained {args.algo} for {timesteps} + {finetune} steps on {n_envs} env(s) in "
          f"{time.perf_counter() - t0:.0f} s -> {out}/{name}.zip, curve {out}/curve.png")
    if meta.get("final_eval"):
        print(f"last evaluation: {100 * meta['final_eval']['eval_success_rate']:.0f} % settled")
    if args.ship:
        src = checkpoint_paths(out / name)
        dst = checkpoint_paths(CHECKPOINT_DIR / name)
        if dst[0].exists() and not args.overwrite:
            sys.exit(f"{dst[0]} is shipped: pass --overwrite to replace it")
        for s, d in zip(src, dst):
            if s.exists():
                shutil.copy2(s, d)
        print(f"shipped -> {dst[0]}")


if __name__ == "__main__":
    main()
