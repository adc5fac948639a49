"""Cold compile: the first default episode on an empty kernel cache, compiled as it goes versus ahead of it.

    python benchmarks/bench_compile.py [--repeats R] [--jobs J]

Each run uses a new, empty numba cache folder (``NUMBA_CACHE_DIR``) and fresh processes, alternating the modes:

- **as used** (the peer: what a first use did before ``startracker-gym compile``): one process makes the default
  env and runs one 120° eigenaxis slew, compiling each kernel at its first call;
- **compile, 1 process**: ``startracker-gym compile --jobs 1`` (every recorded signature, all configurations), then
  the same episode in a new process;
- **compile, J processes**: the same with ``--jobs J`` (default: the CPUs available);
- **compile the default env's only, J processes**: ``--default-only --jobs J`` (what ``make demo`` runs).

``compile`` without ``--default-only`` compiles every configuration's kernels (pixel, 3CMOS, ...), about a third
more than a default episode needs.

The table gives wall-clock seconds to the end of the episode (compile plus episode, process start-ups included),
median over the runs, and the ratio to the peer. Several minutes per repeat.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from startracker.compilation import default_jobs, load_signatures  # noqa: E402

EPISODE = """
import warnings
warnings.simplefilter("ignore")
from experiments.episode import run_episode
run_episode(reset_options={"slew_angle_deg": 120.0})
"""

def _run(cmd: list[str], cache: str) -> float:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
    env.pop("NUMBA_DISABLE_JIT", None)
    t = time.perf_counter()
    subprocess.run(cmd, env=env, cwd=ROOT, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def run_once(mode: str, jobs: int) -> tuple[float, float]:
    """``(compile s, episode s)`` of one cold run of ``mode`` ("lazy", "ahead" or "default") on a new cache folder."""
    with tempfile.TemporaryDirectory(prefix="bench-compile-") as cache:
        compile_s = 0.0
        if mode != "lazy":
            extra = ["--default-only"] if mode == "default" else []
            compile_s = _run([sys.executable, "-m", "experiments", "compile", "--jobs", str(jobs), "--no-progress"]
                             + extra, cache)
        episode_s = _run([sys.executable, "-c", EPISODE], cache)
    return compile_s, episode_s


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--jobs", type=int, default=default_jobs(), help="worker processes of the parallel row")
    p.add_argument("--quick", action="store_true", help="one repeat")
    args = p.parse_args(argv)
    repeats = 1 if args.quick else args.repeats
    if repeats < 1 or args.jobs < 1:
        p.error("--repeats and --jobs must be >= 1")
    entries = load_signatures()
    modes = [("as used (one process, compiled at first call)", "lazy", 1),
             ("startracker-gym compile --jobs 1, then the episode", "ahead", 1),
             (f"startracker-gym compile --jobs {args.jobs}, then the episode", "ahead", args.jobs),
             (f"startracker-gym compile --default-only --jobs {args.jobs}, then the episode", "default", args.jobs)]
    results = {name: [] for name, _, _ in modes}
    for r in range(repeats):
        order = modes if r % 2 == 0 else modes[::-1]
        for name, mode, jobs in order:
            c, e = run_once(mode, jobs)
            results[name].append((c, e))
            print(f"  repeat {r + 1}/{repeats}: {name}: compile {c:.1f} s, episode {e:.1f} s", file=sys.stderr,
                  flush=True)
    n_default = sum(e.workload == "default" for e in entries)
    print(f"Cold start of the default env on an empty kernel cache ({len(entries)} recorded signatures, {n_default} of "
          f"them the default env's; {sum(e.compile_s for e in entries):.0f} s of compilation when recorded; "
          f"{os.cpu_count()} CPUs); "
          f"wall-clock s, median of {repeats}")
    print("| mode | compile | first episode | total | min total | max total | total / as used |")
    print("|---|---|---|---|---|---|---|")
    peer = statistics.median(c + e for c, e in results[modes[0][0]])
    for name, _, _ in modes:
        tot = [c + e for c, e in results[name]]
        print(f"| {name} | {statistics.median(c for c, _ in results[name]):.1f} | "
              f"{statistics.median(e for _, e in results[name]):.1f} | {statistics.median(tot):.1f} | {min(tot):.1f} | "
              f"{max(tot):.1f} | {statistics.median(tot) / peer:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
