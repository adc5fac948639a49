"""Train an RL baseline (SAC, PPO or TD3) on AgileSlew-v1 with the ideal sensor; writes the checkpoint and its
learning curve (CSV and PNG) into ``--out``.

    python scripts/train.py --algo sac --timesteps 100000 --demos 100 --seed 0 --out runs/sac

``--ship`` then copies the checkpoint into policies/checkpoints (refused if one is there, unless ``--overwrite``).
"""

import argparse
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from policies.rl import ALGOS, CHECKPOINT_DIR, ROBUST_ENV_KWARGS, TRAIN_ENV_KWARGS, checkpoint_paths, train  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--algo", choices=ALGOS, default="sac")
    ap.add_argument("--timesteps", type=int, default=None, help="default 100000")
    ap.add_argument("--envs", type=int, default=None, help="parallel in-process envs; default 2 (SAC, TD3), 8 (PPO)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="output directory, default runs/<algo>")
    ap.add_argument("--eval-every", type=int, default=10_000)
    ap.add_argument("--demos", type=int, default=None,
                    help="SAC/TD3: episodes of a scripted PD put into the replay buffer before learning (default 100)")
    ap.add_argument("--finetune", type=int, default=0,
                    help="SAC: further steps with the entropy coefficient fixed at --finetune-ent-coef")
    ap.add_argument("--finetune-ent-coef", type=float, default=1e-3)
    ap.add_argument("--init", default=None, help="start from this checkpoint's weights")
    ap.add_argument("--noise-range", action="store_true",
                    help="ideal sensor noise drawn per episode in 0.5-20 arcsec (the tracker's σ range)")
    ap.add_argument("--ship", action="store_true", help="copy the checkpoint into policies/checkpoints")
    ap.add_argument("--overwrite", action="store_true", help="allow --ship or --out to replace existing files")
    args = ap.parse_args(argv)
    timesteps = args.timesteps if args.timesteps is not None else 100_000
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
                 name=name, demo_episodes=demos,
                 env_kwargs=ROBUST_ENV_KWARGS if args.noise_range else TRAIN_ENV_KWARGS,
                 finetune_timesteps=args.finetune, finetune_ent_coef=args.finetune_ent_coef, init_from=args.init)
    print(f"trained {args.algo} for {timesteps} steps on {n_envs} env(s) in {time.perf_counter() - t0:.0f} s -> {out}/"
          f"{name}.zip, curve {out}/curve.png")
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
