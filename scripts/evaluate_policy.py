"""Evaluate policies on the agent benchmark and print one table (scripted baselines and the PPO checkpoint).

    python scripts/evaluate_policy.py --policies eigenaxis pd policies.rl:PPOPolicy --episodes 10
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.agent_benchmark import run_agent_benchmark  # noqa: E402
from experiments.cli import format_table  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policies", nargs="+", default=["eigenaxis", "pd", "policies.rl:PPOPolicy"])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--difficulties", nargs="+", default=["easy", "medium", "hard"])
    args = ap.parse_args()
    rows = []
    for p in args.policies:
        rows += run_agent_benchmark(p, difficulties=args.difficulties, n_per_difficulty=args.episodes)
    print(format_table(rows))


if __name__ == "__main__":
    main()
