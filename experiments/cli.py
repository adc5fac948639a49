"""``startracker-gym``: the command line (also ``python -m experiments``).

    startracker-gym slew      one closed-loop slew with a policy: summary table, telemetry, plots
    startracker-gym hold      one attitude-hold episode: pointing stability and jitter, telemetry, plots
    startracker-gym campaign  Monte Carlo over seeds and a grid of settings, resumable, local or Ray
    startracker-gym bench     run benchmarks/ by name (source checkout), or the agent benchmark for any policy
    startracker-gym compile   compile the numba kernels ahead of first use, in parallel processes

Every value is checked before any work starts; a mistake prints one line naming it and exits with 2.
"""

from __future__ import annotations

import argparse
import inspect
import json
import subprocess
import sys
import time
from pathlib import Path

__all__ = ["main", "build_parser", "format_table"]

ROOT = Path(__file__).resolve().parents[1]


class UsageError(Exception):
    """A mistake in the command line: one line on stderr, exit code 2."""


def _choices():
    """Names the env accepts, from the modules that define them."""
    from startracker.imu import GYRO_GRADES
    from startracker.onboard import HEAD_CAMERAS, IDENTIFY_METHODS, MATCHERS

    return {
        "camera": tuple(HEAD_CAMERAS), "fidelity": ("centroid", "pixel"), "matcher": tuple(MATCHERS),
        "identify_method": tuple(IDENTIFY_METHODS), "gyro_grade": tuple(GYRO_GRADES),
        "exposure_mode": ("single", "multi"),
    }


def _env_defaults() -> dict:
    from envs.agile_slew import AgileSlewEnv

    return {k: p.default for k, p in inspect.signature(AgileSlewEnv.__init__).parameters.items() if k != "self"}


def _key_values(pairs, flag: str) -> dict:
    from experiments.settings import check_setting_keys, parse_value

    out = {}
    for p in pairs or []:
        if "=" not in p:
            raise UsageError(f"{flag} expects KEY=VALUE, got {p!r}")
        k, v = p.split("=", 1)
        out[k.strip()] = parse_value(v)
    try:
        check_setting_keys(out, "setting")
    except ValueError as exc:
        raise UsageError(f"{flag}: {exc}")
    return out


def format_table(rows: list[dict], keys=None) -> str:
    """Rows of dicts as an aligned text table (floats to 4 significant digits)."""
    if not rows:
        return "(no rows)"
    keys = keys or list(rows[0].keys())

    def fmt(v):
        if isinstance(v, float):
            return "nan" if v != v else f"{v:.4g}"
        return "" if v is None else str(v)

    cells = [[fmt(r.get(k, "")) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    line = "  ".join(k.ljust(w) for k, w in zip(keys, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in cells]
    return "\n".join([line, sep, *body])


def _timestamped(prefix: str) -> Path:
    return Path("runs") / f"{prefix}-{time.strftime('%Y%m%d-%H%M%S')}"


def _prepare_out(out: Path, marker: str, force: bool) -> None:
    if (out / marker).exists() and not force:
        raise UsageError(f"output folder {out} already holds results ({marker}); pass --force to overwrite or choose "
                         "another --out")
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / ".write_test").write_text("")
        (out / ".write_test").unlink()
    except OSError as exc:
        raise UsageError(f"output folder {out} is not writable: {exc}")


def _progress_wanted(args) -> bool:
    return not args.no_progress and sys.stderr.isatty()


def _check_policy(name: str) -> None:
    from experiments.settings import ensure_working_directory_importable
    from policies import load_policy

    ensure_working_directory_importable()
    try:
        load_policy(str(name))
    except ValueError as exc:
        raise UsageError(str(exc))


# ---------------------------------------------------------------------------------------------------- slew / hold
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
_SENSOR_OPTIONS = ("camera", "fidelity", "matcher", "identify_method", "gyro_grade", "exposure_mode")


def _episode_settings(args, task: str) -> tuple[dict, dict]:
    """(env keyword arguments, reset options) from the command line, every value checked."""
    from experiments.settings import RESET_KEYS, env_keys

    fixed = _key_values(args.env, "--env")
    options = {k: fixed.pop(k) for k in RESET_KEYS if k in fixed}
    for k in ("policy", "task"):
        if k in fixed:
            raise UsageError(f"--env: give {k} with --{k.replace('_', '-')}" if k == "policy" else
                             f"--env: the task is chosen by the command (slew or hold), not --env {k}")
    kwargs = {k: v for k, v in fixed.items() if k in env_keys()}
    for key in _SENSOR_OPTIONS:
        v = getattr(args, key)
        if v is not None:
            kwargs[key] = v
    if args.max_episode_s is not None:
        if not args.max_episode_s > 0:
            raise UsageError(f"--max-episode-s must be > 0 s, got {args.max_episode_s}")
        kwargs["max_episode_s"] = args.max_episode_s
    if task == "slew":
        if args.angle_deg is not None:
            if not 0.0 <= args.angle_deg <= 180.0:
                raise UsageError(f"--angle-deg must be in [0, 180] deg (a slew is the shortest rotation), "
                                 f"got {args.angle_deg:g}")
            options["slew_angle_deg"] = args.angle_deg
        if args.axis != "random":
            options["slew_axis_body"] = _AXES[args.axis]
    kwargs["task"] = task
    return kwargs, options


def cmd_episode(args) -> int:
    from experiments.episode import run_episode
    from experiments.provenance import provenance
    from experiments.settings import split_settings, validate_settings
    from experiments.telemetry import plot_episode, to_jsonable, write_csv, write_json_atomic

    task = args.command
    kwargs, options = _episode_settings(args, task)
    _check_policy(args.policy)
    settings = {"policy": args.policy, **kwargs, **options}
    try:
        env_config = validate_settings(settings)
        env_id, _, env_kwargs, _ = split_settings(settings)
    except ValueError as exc:
        raise UsageError(str(exc))
    out = Path(args.out) if args.out else _timestamped(task)
    _prepare_out(out, "summary.json", args.force)
    try:
        res = run_episode(env_id, policy=args.policy, seed=args.seed, env_kwargs=env_kwargs,
                          reset_options=options or None, keep_frame=not args.no_plots)
    except (ValueError, TypeError) as exc:
        raise UsageError(str(exc))
    s = res.summary
    write_csv(out / "steps.csv", res.steps)
    write_json_atomic(out / "summary.json", {**s, "settings": settings, "env_config": env_config,
                                             "provenance": provenance()})
    plots = [] if args.no_plots else plot_episode(out, res.steps, res.frames, s)
    if args.json:
        print(json.dumps(to_jsonable(s), indent=2, sort_keys=True))
        return 0
    if task == "slew":
        rows = [
            ("slew angle", f"{s['slew_angle_deg']:.1f} deg"),
            ("settled", "yes" if s["success"] else "no"),
            ("settle time", f"{s['settle_time_s']:.1f} s"),
            ("final pointing error", f"{s['final_pointing_error_deg'] * 3600:.1f} arcsec"),
        ]
    else:
        rows = [
            ("pointing error to target RMS / max",
             f"{s['pointing_error_rms_arcsec']:.2f} / {s['pointing_error_max_arcsec']:.2f} arcsec"),
            ("pointing stability (largest drift in 1 s)", f"{s['pointing_stability_arcsec_1s']:.2f} arcsec"),
            ("rate jitter (RMS of the true body rate)", f"{s['jitter_rate_rms_arcsec_s']:.2f} arcsec/s"),
        ]
    rows += [
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
    print(f"startracker-gym {task}: policy {s['policy']}, seed {s['seed']}")
    for k, v in rows:
        print(f"  {k.ljust(w)}  {v}")
    print(f"telemetry: {out / 'steps.csv'}, summary: {out / 'summary.json'}")
    for p in plots:
        print(f"plot: {p}")
    return 0


# ---------------------------------------------------------------------------------------------------- campaign
def _parse_grid(items) -> dict:
    from experiments.settings import check_setting_keys, parse_values

    grid = {}
    for it in items or []:
        if "=" not in it:
            raise UsageError(f"--grid expects KEY=V1,V2,..., got {it!r}")
        k, v = it.split("=", 1)
        k = k.strip()
        try:
            check_setting_keys([k], "grid setting")
        except ValueError as exc:
            raise UsageError(str(exc))
        if k in grid:
            raise UsageError(f"--grid {k} given twice; list all its values once: {k}=V1,V2")
        grid[k] = parse_values(v)
    return grid


def _spread_text(row, m, scale=1.0, digits=3):
    med = row.get(f"{m}_median")
    if med is None:
        return "nan"
    lo, hi = row[f"{m}_p10"], row[f"{m}_p90"]
    if row["runs"] == 1:
        return f"{med * scale:.{digits}g}"
    return f"{med * scale:.{digits}g} [{lo * scale:.{digits}g}, {hi * scale:.{digits}g}]"


def cmd_campaign(args) -> int:
    from experiments.campaign import Campaign, run_campaign, summarise_results

    grid = _parse_grid(args.grid)
    fixed = _key_values(args.env, "--env")
    if "policy" not in grid and "policy" not in fixed:
        grid["policy"] = ["eigenaxis"]
    for p in grid.get("policy", []) + ([fixed["policy"]] if "policy" in fixed else []):
        _check_policy(p)
    out = Path(args.out) if args.out else _timestamped("campaign")
    manifest = out / "campaign.json"
    if manifest.exists() and not args.force:
        try:
            old = json.loads(manifest.read_text())
        except ValueError:
            old = {}
        from experiments.telemetry import to_jsonable

        if old.get("grid") != to_jsonable({k: list(v) for k, v in grid.items()}) or old.get("fixed") != to_jsonable(fixed):
            raise UsageError(f"{out} holds a campaign with another grid or fixed settings; use another --out, or "
                             "--force to add this one beside it")
    try:
        camp = Campaign(out, grid, range(args.seed0, args.seed0 + args.seeds), fixed=fixed)
    except ValueError as exc:
        raise UsageError(str(exc))
    print(camp.describe_resume() + f" -> {camp.out_dir}", file=sys.stderr)
    try:
        records = run_campaign(camp, backend=args.backend, workers=args.workers, progress=_progress_wanted(args),
                               max_runs=args.max_runs, plots=not args.no_plots)
    except KeyboardInterrupt:
        print(f"interrupted: finished runs are kept in {camp.out_dir / 'runs'}; run the same command to resume",
              file=sys.stderr)
        return 130
    except ValueError as exc:
        raise UsageError(str(exc))
    summary = summarise_results(records)
    swept = sorted(grid)
    display = []
    for r in summary:
        d = {k: r[k] for k in swept}
        d.update(runs=r["runs"], success=f"{r['successes']}/{r['runs']}")
        d["settle s"] = _spread_text(r, "settle_time_s")
        d["final err arcsec"] = _spread_text(r, "final_pointing_error_deg", 3600.0)
        d["est err RMS arcsec"] = _spread_text(r, "attitude_error_rms_arcsec")
        if "pointing_stability_arcsec_1s_median" in r:
            d["stability 1s arcsec"] = _spread_text(r, "pointing_stability_arcsec_1s")
            d["jitter arcsec/s"] = _spread_text(r, "jitter_rate_rms_arcsec_s")
        d["update Hz"] = _spread_text(r, "update_rate_hz_mean")
        display.append(d)
    if fixed:
        print("fixed: " + ", ".join(f"{k}={json.dumps(v)}" for k, v in sorted(fixed.items())))
    print(format_table(display))
    print("figures: median [p10, p90] over the seeds")
    files = f"results: {camp.out_dir / 'results.csv'}  summary: {camp.out_dir / 'summary.csv'}"
    if not args.no_plots and (camp.out_dir / "campaign.png").exists():
        files += f"  plot: {camp.out_dir / 'campaign.png'}"
    print(files)
    return 0


# ---------------------------------------------------------------------------------------------------- bench
def benchmark_scripts() -> dict:
    """``name -> path`` of ``benchmarks/bench_<name>.py`` in the source checkout (this package's parent folder, else
    the working directory); empty for an installed copy run outside a checkout."""
    for base in (ROOT, Path.cwd()):
        d = base / "benchmarks"
        if d.is_dir() and any(d.glob("bench_*.py")):
            return {p.stem.removeprefix("bench_"): p for p in sorted(d.glob("bench_*.py"))}
    return {}


_NO_CHECKOUT = ("the benchmark scripts belong to the source checkout and are not installed: run this from a clone of "
                "the repository (its benchmarks/ folder is found in the working directory); 'bench agents' works "
                "anywhere")


def cmd_compile(args) -> int:
    from startracker.compilation import compile_kernels

    if args.jobs is not None and args.jobs < 1:
        raise UsageError(f"--jobs must be >= 1, got {args.jobs}")
    r = compile_kernels(args.jobs, default_only=args.default_only, progress=_progress_wanted(args))
    if r.jobs == 0:
        print("NUMBA_DISABLE_JIT is set: nothing to compile")
        return 0
    print(f"{r.n_signatures} kernel signatures: {r.n_compiled} compiled, {r.n_cached} already cached"
          + (f", {r.n_stale} stale (they compile on first use)" if r.n_stale else "")
          + f"; {r.wall_s:.1f} s in {r.jobs} process{'es' if r.jobs > 1 else ''}; cache {r.cache_dir}")
    return 0


def cmd_bench(args) -> int:
    if args.name == "agents":
        from experiments.agent_benchmark import run_agent_benchmark

        if args.episodes < 1:
            raise UsageError(f"--episodes must be >= 1, got {args.episodes}")
        _check_policy(args.policy)
        rows = run_agent_benchmark(args.policy, n_per_difficulty=args.episodes, progress=_progress_wanted(args))
        print(format_table(rows))
        return 0
    scripts = benchmark_scripts()
    if args.name == "list":
        if not scripts:
            print(f"benchmarks: agents ({_NO_CHECKOUT})")
        else:
            print("benchmarks: agents, " + ", ".join(scripts))
        return 0
    if not scripts:
        raise UsageError(f"benchmark {args.name!r}: {_NO_CHECKOUT}")
    names = list(scripts) if args.name == "all" else [args.name]
    for n in names:
        if n not in scripts:
            raise UsageError(f"unknown benchmark {n!r}; available: agents, all, list, {', '.join(scripts)}")
    status = 0
    for n in names:
        print(f"== {n} ==", flush=True)
        cmd = [sys.executable, str(scripts[n])] + (["--quick"] if args.quick else [])
        status |= subprocess.call(cmd, cwd=scripts[n].parents[1])
    return 1 if status else 0


# ---------------------------------------------------------------------------------------------------- main
def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {v}")
    return v


class _Help(argparse.HelpFormatter):
    """Shows ``(default: X)`` for options with a real default (not None or a False flag)."""

    def _get_help_string(self, action):
        h = action.help or ""
        real = not (action.default is None or action.default is False or action.default == argparse.SUPPRESS)
        if real and "default" not in h and action.option_strings:
            h += " (default: %(default)s)"
        return h


class _Parser(argparse.ArgumentParser):
    """argparse with the one-line error of every other usage mistake (``--help`` still shows the usage)."""

    def error(self, message):
        self.exit(2, f"startracker-gym: error: {self.prog.removeprefix('startracker-gym ')}: {message}\n")


def _episode_parser(sub, name: str, help_text: str, choices: dict, defaults: dict):
    s = sub.add_parser(name, help=help_text, description=help_text,
                       formatter_class=_Help)
    s.add_argument("--policy", default="eigenaxis", help="pd | eigenaxis | random | zero | module:Class (a module in "
                   "the working directory or installed)")
    s.add_argument("--seed", type=int, default=0, help="seeds the env, every sensor error and the policy")
    if name == "slew":
        s.add_argument("--angle-deg", type=float, default=90.0, help="slew angle, deg, in [0, 180]")
        s.add_argument("--axis", default="random", choices=["random", "x", "y", "z"],
                       help="slew axis in the body frame; the camera looks along +z, so x and y stream stars across it")
    for key in _SENSOR_OPTIONS:
        s.add_argument(f"--{key.replace('_', '-')}", default=None, choices=choices[key],
                       help=f"env default: {defaults[key]}")
    reg = 60.0 if name == "hold" else defaults["max_episode_s"]
    s.add_argument("--max-episode-s", type=float, default=None, help=f"time limit, s (env default: {reg:g})")
    s.add_argument("--env", action="append", metavar="KEY=VALUE",
                   help="any other env argument or reset option, value as JSON where not a plain word "
                        "(repeatable): e.g. n_heads=2, inertia_kg_m2=[10,10,10], "
                        "faults='[{\"kind\": \"dropout\", \"t_start_s\": 2, \"duration_s\": 3}]'")
    s.add_argument("--out", default=None, help="folder for telemetry and plots (default: a new runs/"
                   f"{name}-YYYYmmdd-HHMMSS)")
    s.add_argument("--force", action="store_true", help="overwrite results already in --out")
    s.add_argument("--json", action="store_true", help="print the summary as JSON")
    s.add_argument("--no-plots", action="store_true", help="skip the PNG plots (and the star-frame render)")
    s.set_defaults(func=cmd_episode)
    return s


def build_parser() -> argparse.ArgumentParser:
    from experiments.settings import setting_keys

    choices = _choices()
    defaults = _env_defaults()
    p = _Parser(prog="startracker-gym", description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("\n\n")[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    _episode_parser(sub, "slew", "one closed-loop slew with the full sensor pipeline", choices, defaults)
    _episode_parser(sub, "hold", "one attitude-hold episode (startracker/AttitudeHold-v0)", choices, defaults)

    keys = ", ".join(setting_keys())
    c = sub.add_parser(
        "campaign", help="Monte Carlo over seeds and a grid of settings (resumable)",
        formatter_class=_Help,
        description="Monte Carlo over seeds and a grid of settings. Runs are saved as they finish; the same command "
                    "resumes, reusing a run only when its settings, env configuration and code are unchanged.",
        epilog=f"settings for --grid and --env: {keys}. task is slew or hold. Values are JSON where they are not plain "
               "words: --grid inertia_kg_m2=[5,6,4],[10,10,10]  --env faults='[{\"kind\": \"dropout\"}]'")
    c.add_argument("--grid", action="append", metavar="KEY=V1,V2", help="a setting and its values to sweep (repeatable)")
    c.add_argument("--env", action="append", metavar="KEY=VALUE", help="a setting fixed for every run (repeatable)")
    c.add_argument("--seeds", type=_positive_int, default=5, help="number of seeds per setting combination")
    c.add_argument("--seed0", type=int, default=0, help="first seed")
    c.add_argument("--out", default=None, help="campaign folder; an existing one is resumed (default: a new "
                   "runs/campaign-YYYYmmdd-HHMMSS)")
    c.add_argument("--force", action="store_true", help="use --out even if it holds a campaign with another grid")
    c.add_argument("--backend", default="local", choices=["local", "ray"], help="worker processes or Ray tasks")
    c.add_argument("--workers", type=_positive_int, default=2, help="local worker processes")
    c.add_argument("--max-runs", type=_positive_int, default=None, help="stop after this many new runs")
    c.add_argument("--no-progress", action="store_true", help="no progress bar (also off when stderr is not a terminal)")
    c.add_argument("--no-plots", action="store_true", help="skip campaign.png")
    c.set_defaults(func=cmd_campaign)

    b = sub.add_parser("bench", help="run benchmarks/ by name, or 'agents' for the agent benchmark",
                       formatter_class=_Help)
    b.add_argument("name", help="agents | all | list | a benchmark name (benchmarks/bench_<name>.py of a checkout)")
    b.add_argument("--quick", action="store_true", help="short runs")
    b.add_argument("--policy", default="eigenaxis", help="for 'agents': pd | eigenaxis | ... | module:Class")
    b.add_argument("--episodes", type=int, default=10, help="for 'agents': episodes per difficulty")
    b.add_argument("--no-progress", action="store_true", help="no progress bar (also off when stderr is not a terminal)")
    b.set_defaults(func=cmd_bench)

    k = sub.add_parser("compile", formatter_class=_Help,
                       help="compile the numba kernels ahead of first use, in parallel processes",
                       description="Compile every kernel signature the env's configurations use into the on-disk "
                                   "cache, in parallel worker processes (a first use otherwise compiles them one "
                                   "after another, in the process that needs them). Quick when they are cached.")
    k.add_argument("--jobs", type=int, default=None, help="worker processes (default: the CPUs available)")
    k.add_argument("--default-only", action="store_true", help="only what the default env uses (the rest compiles "
                   "on first use)")
    k.add_argument("--no-progress", action="store_true", help="no progress line (also off when stderr is not a "
                   "terminal)")
    k.set_defaults(func=cmd_compile)
    return p


def main(argv=None) -> int:
    if (sys.argv[1:] if argv is None else list(argv))[:1] == ["compile"]:
        import warnings

        # the notice of an empty kernel cache, issued while the parser imports the env: this command fills it
        warnings.filterwarnings("ignore", message="startracker-gym: no compiled kernels")
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2), already printed
        return int(exc.code or 0)
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"startracker-gym: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head`: stop quietly, as other command-line tools do
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    raise SystemExit(main())
