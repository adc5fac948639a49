"""Record the kernel signatures the env compiles, for ``startracker-gym compile`` (startracker/compilation.py).

    python scripts/record_kernel_signatures.py            # writes startracker/data/kernel_signatures.json
    python scripts/record_kernel_signatures.py --out F.json

Runs whole 120° eigenaxis slews of ``startracker/AgileSlew-v0`` (``experiments.episode.run_episode``, as
``startracker-gym slew`` does, with its star-frame render) in a child process on an empty numba cache (a temporary
folder, so the project's cache is untouched): the default configuration first, then pixel fidelity,
single exposure, two heads, 3CMOS (alone and in pixel fidelity) and random faults (centroid and pixel). Every
compilation of a ``startracker`` kernel is listed in the order it finished (callees before their callers), with
its own compile time, the kernels it compiled as its callees (``after``: a worker of ``startracker-gym compile``
starts it once they are cached) and the first workload that compiled it (``startracker-gym compile
--default-only`` takes those of "default"). Re-run it after changing a kernel's arguments;
``tests/test_compilation.py`` fails when the list no longer covers a default episode. Takes a few minutes (it
compiles everything once, in one process).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# (name, env keyword arguments): the default first, so its kernels lead the list
WORKLOADS = [
    ("default", {}),
    ("pixel fidelity", {"fidelity": "pixel"}),
    ("single exposure", {"exposure_mode": "single"}),
    ("two heads", {"n_heads": 2}),
    ("3CMOS", {"camera": "paper004_3cmos"}),
    ("3CMOS pixel", {"camera": "paper004_3cmos", "fidelity": "pixel"}),
    ("random faults", {"random_faults_per_min": 30.0}),
    ("random faults, pixel", {"random_faults_per_min": 30.0, "fidelity": "pixel"}),
]


def _child(out: Path) -> None:
    """Run the workloads on the (empty) cache this process was given and write the list."""
    import warnings

    warnings.simplefilter("ignore")
    from numba.core import event

    from startracker.compilation import type_to_text

    stack, rows, seen = [], [], {}
    current = [WORKLOADS[0][0]]  # the workload running: the first to compile a signature is its "workload"

    class Listener(event.Listener):
        # one compile event per (kernel, signature); the events that end while another is open are its callees
        def on_start(self, ev):
            stack.append([ev.data["dispatcher"], tuple(ev.data["args"]), time.perf_counter(), 0.0, []])

        def on_end(self, ev):
            disp, sig, t0, child_s, callees = stack.pop()
            dt = time.perf_counter() - t0
            if stack:
                stack[-1][3] += dt
            module = disp.py_func.__module__
            key = (module, disp.py_func.__name__, sig)
            if not module.startswith("startracker.") or key in seen:
                if stack:  # a numba-internal implementation: its kernel callees belong to the open kernel
                    stack[-1][4].extend(callees)
                return
            seen[key] = len(rows)
            rows.append({"module": module, "name": disp.py_func.__name__, "args": [type_to_text(a) for a in sig],
                         "compile_s": round(dt - child_s, 3), "after": sorted(set(callees)),
                         "workload": current[0]})
            if stack:
                stack[-1][4].append(seen[key])

    event.register("numba:compile", Listener())
    from experiments.episode import run_episode

    for name, kw in WORKLOADS:
        current[0] = name
        t = time.perf_counter()
        # keep_frame: the star-frame render of `startracker-gym slew`'s plots too (make demo's kernels are "default")
        run_episode(env_kwargs=kw, reset_options={"slew_angle_deg": 120.0}, keep_frame=True)
        print(f"  {name}: {time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
    import numba

    doc = {"about": "kernel signatures compiled by the env's episodes, callees first (scripts/"
                    "record_kernel_signatures.py); startracker-gym compile compiles them ahead of use",
           "numba": numba.__version__, "workloads": [w for w, _ in WORKLOADS],
           "total_compile_s": round(sum(r["compile_s"] for r in rows), 1), "signatures": rows}
    out.write_text(json.dumps(doc, indent=1) + "\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=ROOT / "startracker" / "data" / "kernel_signatures.json")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        _child(args.out)
        return 0
    with tempfile.TemporaryDirectory(prefix="startracker-record-") as cache:
        path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=path)
        env.pop("NUMBA_DISABLE_JIT", None)
        t = time.perf_counter()
        print(f"recording on an empty cache ({cache}):", file=sys.stderr)
        subprocess.run([sys.executable, __file__, "--child", "--out", str(args.out)], env=env, check=True, cwd=ROOT)
    doc = json.loads(args.out.read_text())
    print(f"{len(doc['signatures'])} signatures, {doc['total_compile_s']} s of compilation, recorded in "
          f"{time.perf_counter() - t:.0f} s: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
