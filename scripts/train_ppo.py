"""Train the PPO baseline on AgileSlew-v0 (needs the ``rl`` extra).

    python scripts/train_ppo.py --timesteps 100000 --envs 2 --out policies/checkpoints/ppo_agileslew.zip
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from policies.rl import DEFAULT_CHECKPOINT, train_ppo  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--timesteps", type=int, default=100_000)
    ap.add_argument("--envs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(DEFAULT_CHECKPOINT))
    args = ap.parse_args()
    t0 = time.perf_counter()
    train_ppo(args.timesteps, n_envs=args.envs, seed=args.seed, out_path=args.out)
    print(f"trained {args.timesteps} steps on {args.envs} envs in {time.perf_counter() - t0:.0f} s -> {args.out}")


if __name__ == "__main__":
    main()
