"""Evaluate policies on the agent benchmark and print one table (scripted baselines and the RL checkpoints).

    python scripts/evaluate_policy.py --policies eigenaxis pd sac ppo --episodes 10
    python scripts/evaluate_policy.py --policies sac --sensor ideal      # the same agent without the tracker

Each policy runs on the env it acts on (AgileSlew-v0 for the scripted controllers, AgileSlew-v1 for the trained
ones); ``--markdown`` prints the table as Markdown.
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.agent_benchmark import run_agent_benchmark  # noqa: E402
from experiments.cli import format_table  # noqa: E402

COLUMNS = ("policy", "env_id", "sensor", "difficulty", "episodes", "success_rate", "settle_time_s_median",
           "final_pointing_error_deg_median", "control_effort_median", "track_share_mean",
           "attitude_error_rms_arcsec_median")


def markdown(rows) -> str:
    head = "| policy | env | sensor | difficulty | episodes | success | settle time (s) | final error (°) | effort | " \
           "time in track | attitude error RMS (″) |"
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        lines.append(f"| {r['policy']} | {r['env_id'].split('/')[-1]} | {r['sensor']} | {r['difficulty']} | "
                     f"{r['episodes']} | {100 * r['success_rate']:.0f} % | {r['settle_time_s_median']:.1f} | "
                     f"{r['final_pointing_error_deg_median']:.3g} | {r['control_effort_median']:.4f} | "
                     f"{100 * r['track_share_mean']:.0f} % | {r['attitude_error_rms_arcsec_median']:.1f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policies", nargs="+", default=["eigenaxis", "pd", "sac", "ppo"])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--difficulties", nargs="+", default=["easy", "medium", "hard"])
    ap.add_argument("--sensor", choices=("tracker", "ideal"), default=None,
                    help="ideal: AgileSlew-v1 policies with the ideal sensor instead of the star tracker")
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for p in args.policies:
        rows += run_agent_benchmark(p, difficulties=args.difficulties, n_per_difficulty=args.episodes,
                                    sensor=args.sensor if args.sensor == "ideal" else None, progress=False)
    print(markdown(rows) if args.markdown else format_table(rows))


if __name__ == "__main__":
    main()
