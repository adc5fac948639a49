"""Frame time of the pixel fidelity: the sparse pixel path against the full frame, N = 1, 15, 21 exposures.

The frame of ``bench_frame.py`` (paper 000's 2048×2048 camera, the 30 brightest stars, cross-boresight slew at
13°/s, ``SensorModel.preset("paper000")`` with every noise source and false object, the Sun 50° off the boresight)
with N exposures of 1 ms. Paths timed in the same run, per N:

* sparse — ``render_sparse`` + ``detections_from_sparse`` (what ``fidelity="pixel"`` costs per frame; the per-frame
           caller's ``validate=False`` where the installed code has it);
* full   — ``render_frame`` + ``extract_centroids`` (the peer: the whole frame drawn and searched).

The sparse path is also split: ``render_sparse`` alone (its compiled ``sparse_pixel_set``, windows and noise) and
``detections_from_sparse`` alone on one rendered frame (its compiled ``detect_sparse``: components, centroids,
truth owners).

Prints medians over the repeats of the process CPU time (robust on a shared machine) and of the wall-clock time,
and the ratio full / sparse. Run ``python benchmarks/bench_pixel_path.py`` (20 repeats of the sparse path, 5 of
the full frame) or ``--quick``. To compare with another checkout, run this file with that checkout first on
``PYTHONPATH``: it only uses the public API.
"""

from __future__ import annotations

import argparse
import inspect
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_frame import build_frame  # noqa: E402

import startracker  # noqa: E402
from startracker.centroid import detections_from_sparse, extract_centroids  # noqa: E402
from startracker.imaging import SensorModel, render_frame, render_sparse  # noqa: E402


def timed(fn, repeats):
    """Medians of the process CPU time and wall-clock time (ms) of ``repeats`` calls, and the last result."""
    cpu, wall = [], []
    out = None
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(cpu)) * 1e3, float(np.median(wall)) * 1e3, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10 sparse / 5 full-frame repeats")
    ap.add_argument("--exposures", type=int, nargs="*", default=[1, 15, 21])
    args = ap.parse_args(argv)
    reps_sparse, reps_full = (10, 5) if args.quick else (20, 5)
    model = SensorModel.preset("paper000")
    fast = {"validate": False} if "validate" in inspect.signature(render_sparse).parameters else {}
    fast_d = {"validate": False} if "validate" in inspect.signature(detections_from_sparse).parameters else {}
    print(f"startracker from {os.path.dirname(startracker.__file__)}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs; model {model.name}")
    print(f"{'N':>3s} {'spots':>6s} {'sparse CPU ms':>14s} {'wall ms':>8s} {'render':>7s} {'detect':>7s} {'det':>5s} "
          f"{'full CPU ms':>12s} {'wall ms':>8s} {'det':>5s} {'full/sparse CPU':>16s}")
    for n in args.exposures:
        *_, scene = build_frame(n_exposures=n)
        rng = np.random.default_rng(0)

        def sparse():
            sf = render_sparse(scene, model, rng, 5.0, **fast)
            return detections_from_sparse(sf, "com", **fast_d)

        def full():
            return extract_centroids(render_frame(scene, model, rng), saturation_dn=model.saturation_dn)

        sparse()  # warm-up: compilation or cache load, fixed pattern, index buffer
        full()
        sc, sw, sd = timed(sparse, reps_sparse)
        rc, _, sf = timed(lambda: render_sparse(scene, model, rng, 5.0, **fast), reps_sparse)
        dc, _, _ = timed(lambda: detections_from_sparse(sf, "com", **fast_d), reps_sparse)
        fc, fw, fd = timed(full, reps_full)
        print(f"{n:3d} {int(scene.visible.sum()):6d} {sc:14.2f} {sw:8.2f} {rc:7.2f} {dc:7.2f} {len(sd):5d} {fc:12.1f} "
              f"{fw:8.1f} {len(fd):5d} {fc / sc:15.0f}x")


if __name__ == "__main__":
    main()
