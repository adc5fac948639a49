"""``startracker-gym``: the command line (also ``python -m envs``).

    startracker-gym slew      one closed-loop slew with a scripted policy: summary table, telemetry, plots
    startracker-gym campaign  Monte Carlo over seeds and a grid of settings, resumable, local or Ray
    startracker-gym bench     run benchmarks/ by name, or the agent benchmark for any policy

Errors in what the user typed (unknown names, unwritable folders, empty grids) print one line and exit with 2.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

__all__ = ["main", "build_parser", "format_table"]

ROOT = Path(__file__).resolve().parents[1]


class UsageError(Exception):
    """A mistake in the command line: one line on stderr, exit code 2."""


def _parse_value(text: str):
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return text


def _env_kwargs(pairs) -> dict:
    out = {}
    for p in pairs or []:
        if "=" not in p:
            raise UsageError(f"--env expects key=value, got {p!r}")
        k, v = p.split("=", 1)
        out[k.strip()] = _parse_value(v.strip())
    return out


def format_table(rows: list[dict], keys=None) -> str:
    if not rows:
        return "(no rows)"
    keys = keys or list(rows[0].keys())

    def fmt(v):
        if isinstance(v, float):
            return "nan" if v != v else f"{v:.4g}"
        return str(v)

    cells = [[fmt(r.get(k, "")) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    line = "  ".join(k.ljust(w) for k, w in zip(keys, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in cells]
    return "\n".join([line, sep, *body])


# ---------------------------------------------------------------------------------------------------- slew
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _slew_options(args) -> dict:
    opts = {"slew_angle_deg": args.angle_deg}
    if args.axis != "random":
        opts["slew_axis_body"] = _AXES[args.axis]
    return opts


def cmd_slew(args) -> int:
    from experiments.episode import run_episode
    from experiments.telemetry import plot_episode, write_csv, write_json_atomic

    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / ".write_test").write_text("")
        (out / ".write_test").unlink()
    except OSError as exc:
        raise UsageError(f"output folder {out} is not writable: {exc}")
    kwargs = _env_kwargs(args.env)
    for key in ("camera", "fidelity", "matcher", "gyro_grade", "exposure_mode", "identify_method"):
        v = getattr(args, key)
        if v is not None:
            kwargs[key] = v
    if args.max_episode_s is not None:
        kwargs["max_episode_s"] = args.max_episode_s
    try:
        res = run_episode(
            "startracker/AgileSlew-v0",
            policy=args.policy,
            seed=args.seed,
            env_kwargs=kwargs,
            reset_options=_slew_options(args),
            keep_frame=not args.no_plots,
        )
    except (ValueError, TypeError) as exc:
        raise UsageError(str(exc))
    s = res.summary
    write_csv(out / "steps.csv", res.steps)
    write_json_atomic(out / "summary.json", s)
    plots = [] if args.no_plots else plot_episode(out, res.steps, res.last_frame)
    if args.json:
        from experiments.telemetry import to_jsonable

        print(json.dumps(to_jsonable(s), indent=2, sort_keys=True))
        return 0
    rows = [
        ("slew angle", f"{s['slew_angle_deg']:.1f} deg"),
        ("settled", "yes" if s["success"] else "no"),
        ("settle time", f"{s['settle_time_s']:.1f} s"),
        ("final pointing error", f"{s['final_pointing_error_deg'] * 3600:.1f} arcsec"),
        ("attitude error (estimate vs truth, tracking) RMS / max",
         f"{s['attitude_error_rms_arcsec']:.2f} / {s['attitude_error_max_arcsec']:.2f} arcsec"),
        ("attitude update rate mean / max", f"{s['update_rate_hz_mean']:.0f} / {s['update_rate_hz_max']:.0f} Hz"),
        ("matching latency p50 / p99", f"{s['matching_latency_ms_p50']:.3f} / {s['matching_latency_ms_p99']:.3f} ms"),
        ("tracker mode time: lost / acquire / track",
         f"{100 * s['mode_share_lost']:.0f} / {100 * s['mode_share_acquire']:.0f} / {100 * s['mode_share_track']:.0f} %"),
        ("lost-lock events", str(s["lost_lock_events"])),
        ("control effort", f"{s['control_effort']:.3f}"),
        ("simulation speed", f"{s['steps_per_s']:.0f} steps/s ({s['steps']} steps, {s['sim_time_s']:.1f} s simulated)"),
    ]
    w = max(len(k) for k, _ in rows)
    print(f"startracker-gym slew: policy {s['policy']}, seed {s['seed']}")
    for k, v in rows:
        print(f"  {k.ljust(w)}  {v}")
    print(f"telemetry: {out / 'steps.csv'}, summary: {out / 'summary.json'}")
    for p in plots:
        print(f"plot: {p}")
    return 0


# ---------------------------------------------------------------------------------------------------- campaign
def _parse_grid(items) -> dict:
    from experiments.campaign import GRID_KEYS

    grid = {}
    for it in items or []:
        if "=" not in it:
            raise UsageError(f"--grid expects key=v1,v2,..., got {it!r}")
        k, v = it.split("=", 1)
        k = k.strip()
        if k not in GRID_KEYS:
            raise UsageError(f"unknown grid setting {k!r}; allowed: {', '.join(GRID_KEYS)}")
        vals = [_parse_value(x.strip()) for x in v.split(",") if x.strip()]
        grid[k] = vals
    return grid


def cmd_campaign(args) -> int:
    from experiments.campaign import Campaign, run_campaign
    from policies import load_policy

    grid = _parse_grid(args.grid)
    grid.setdefault("policy", ["eigenaxis"])
    for p in grid["policy"]:
        try:
            load_policy(str(p))
        except ValueError as exc:
            raise UsageError(str(exc))
    if args.seeds < 1:
        raise UsageError("--seeds must be >= 1")
    try:
        camp = Campaign(args.out, grid, range(args.seed0, args.seed0 + args.seeds))
    except ValueError as exc:
        raise UsageError(str(exc))
    n_done = len(camp.runs) - len(camp.pending())
    print(f"campaign: {len(camp.runs)} runs ({n_done} already finished) -> {camp.out_dir}", file=sys.stderr)
    try:
        rows = run_campaign(camp, backend=args.backend, workers=args.workers, progress=not args.no_progress,
                            max_runs=args.max_runs)
    except KeyboardInterrupt:
        print(f"interrupted: finished runs are kept in {camp.out_dir / 'runs'}; run the same command to resume",
              file=sys.stderr)
        return 130
    except ValueError as exc:
        raise UsageError(str(exc))
    from experiments.campaign import summarise_results

    print(format_table(summarise_results(rows)))
    print(f"results: {camp.out_dir / 'results.csv'}  summary: {camp.out_dir / 'summary.csv'}")
    return 0


# ---------------------------------------------------------------------------------------------------- bench
def _benchmark_scripts() -> dict:
    return {p.stem.removeprefix("bench_"): p for p in sorted((ROOT / "benchmarks").glob("bench_*.py"))}


def cmd_bench(args) -> int:
    scripts = _benchmark_scripts()
    if args.name == "agents":
        from experiments.agent_benchmark import run_agent_benchmark
        from policies import load_policy

        try:
            load_policy(args.policy)
        except ValueError as exc:
            raise UsageError(str(exc))
        rows = run_agent_benchmark(args.policy, n_per_difficulty=args.episodes, progress=not args.no_progress)
        print(format_table(rows))
        return 0
    if args.name == "list":
        print("benchmarks: agents, " + ", ".join(scripts))
        return 0
    names = list(scripts) if args.name == "all" else [args.name]
    for n in names:
        if n not in scripts:
            raise UsageError(f"unknown benchmark {n!r}; available: agents, all, list, {', '.join(scripts)}")
    status = 0
    for n in names:
        print(f"== {n} ==", flush=True)
        cmd = [sys.executable, str(scripts[n])] + (["--quick"] if args.quick else [])
        status |= subprocess.call(cmd, cwd=ROOT)
    return 1 if status else 0


# ---------------------------------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="startracker-gym", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("slew", help="one closed-loop slew with the full sensor pipeline")
    s.add_argument("--policy", default="eigenaxis", help="pd | eigenaxis | random | zero | module:Class")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--angle-deg", type=float, default=90.0, help="slew angle (default 90)")
    s.add_argument("--axis", default="random", choices=["random", "x", "y", "z"],
                   help="slew axis in the body frame; the camera looks along +z, so x and y stream stars across it")
    s.add_argument("--camera", default=None)
    s.add_argument("--fidelity", default=None, choices=["centroid", "pixel"])
    s.add_argument("--matcher", default=None)
    s.add_argument("--identify-method", default=None)
    s.add_argument("--gyro-grade", default=None)
    s.add_argument("--exposure-mode", default=None)
    s.add_argument("--max-episode-s", type=float, default=None)
    s.add_argument("--env", action="append", metavar="KEY=VALUE", help="any other env keyword argument")
    s.add_argument("--out", default="demo_output", help="folder for telemetry and plots")
    s.add_argument("--json", action="store_true", help="print the summary as JSON")
    s.add_argument("--no-plots", action="store_true")
    s.set_defaults(func=cmd_slew)

    c = sub.add_parser("campaign", help="Monte Carlo over seeds and a grid of settings (resumable)")
    c.add_argument("--grid", action="append", metavar="KEY=V1,V2", help="a setting and its values (repeatable)")
    c.add_argument("--seeds", type=int, default=5, help="number of seeds per grid point")
    c.add_argument("--seed0", type=int, default=0)
    c.add_argument("--out", default="runs/campaign")
    c.add_argument("--backend", default="local", choices=["local", "ray"])
    c.add_argument("--workers", type=int, default=2)
    c.add_argument("--max-runs", type=int, default=None, help="stop after this many new runs")
    c.add_argument("--no-progress", action="store_true")
    c.set_defaults(func=cmd_campaign)

    b = sub.add_parser("bench", help="run benchmarks/ by name, or 'agents' for the agent benchmark")
    b.add_argument("name", help="agents | all | list | a benchmark name (bench_<name>.py)")
    b.add_argument("--quick", action="store_true")
    b.add_argument("--policy", default="eigenaxis", help="for 'agents': pd | eigenaxis | ... | module:Class")
    b.add_argument("--episodes", type=int, default=10, help="for 'agents': episodes per difficulty")
    b.add_argument("--no-progress", action="store_true")
    b.set_defaults(func=cmd_bench)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"startracker-gym: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
