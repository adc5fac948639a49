"""Overlay the learning curves of several training runs (the ``curve.csv`` that ``scripts/train.py`` writes): the
evaluation's success rate and median final error against environment steps, one line per run.

    python scripts/compare_curves.py --out docs/rl_curve_ablation.png \
        "cubic, fine 0.2°, seed 0=runs/a/curve.csv" "linear, seed 0=runs/b/curve.csv"
"""

import argparse
import csv
from pathlib import Path


def read_curve(path) -> dict:
    """Columns of a curve CSV as lists of floats."""
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return {k: [float(r[k]) if r[k] not in ("", "nan") else float("nan") for r in rows] for k in rows[0]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="label=path/to/curve.csv")
    ap.add_argument("--out", required=True, help="PNG path")
    ap.add_argument("--title", default="SAC on AgileSlew-v1, ideal sensor: deterministic evaluation, 10 fixed scenarios")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 3.4), constrained_layout=True)
    for item in args.runs:
        label, _, path = item.rpartition("=")
        if not label:
            raise SystemExit(f"expected label=path, got {item!r}")
        c = read_curve(path)
        t = [x / 1000.0 for x in c["timesteps"]]
        ls = "--" if "linear" in label or "1°" in label or "fixed" in label else "-"
        ax[0].plot(t, [100 * v for v in c["eval_success_rate"]], ls, label=label)
        ax[1].semilogy(t, [max(v, 1e-4) for v in c["eval_final_error_deg_median"]], ls, label=label)
    ax[0].set_ylabel("settled (%)")
    ax[0].set_ylim(-5, 105)
    ax[1].axhline(0.05, color="k", ls=":", lw=0.8)
    ax[1].set_ylabel("final error, median (°); dotted: tolerance")
    ax[0].legend(fontsize=7)
    for a in ax:
        a.set_xlabel("environment steps incl. ~10k demonstration steps (thousands)")
        a.grid(alpha=0.3)
    fig.suptitle(args.title, fontsize=9)
    fig.savefig(Path(args.out), dpi=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
