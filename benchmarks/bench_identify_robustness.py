"""All four lost-in-space methods on the same scenes: false stars and centroid noise.

Camera of paper 000 (20°×20°, 2048² px of 5.5 µm, 35.5″/px), stars to V = 6, 0.2 mag magnitude noise,
random attitudes. Two sweeps, every method on the same frames:

* false stars: 0, 3, 5 and 10 false stars placed at random on the detector with magnitudes inside the
  range of the 30 brightest true stars; the 30 brightest detections are handed to identification;
  0.5 px centroid noise;
* noise: 0.2, 0.5, 1 and 2 px (1σ per axis), every detection, no false star; the methods are told the
  noise (``sigma_px``).

Per cell: correct %, ID failures, bad matches (a success with a wrong attitude or a mislabelled true
star), median and 99th-percentile wall-clock latency, median thread CPU time, and the median latency
relative to the Pyramid on the same frames.

    python benchmarks/bench_identify_robustness.py            # 1,000 frames per cell
    python benchmarks/bench_identify_robustness.py --quick    # 100 frames per cell
"""

from __future__ import annotations

import argparse

import numpy as np

from bench_identify_common import machine_line, print_table, run_method
from startracker.catalog import load_catalog
from startracker.identify import build_database
from startracker.simulation import simulate_identification_frame
from startracker.optics import camera_preset
from startracker.rotations import quat_random

METHODS = ["pyramid", "brightness", "voting", "string"]
FALSE_STARS = [0, 3, 5, 10]
NOISE_PX = [0.2, 0.5, 1.0, 2.0]


def table(title, cells):
    rows = []
    for label, runs in cells:
        ref = runs["pyramid"].lat(50)
        for m in METHODS:
            r = runs[m]
            rows.append([label, m, f"{r.success_pct:.1f}", r.fail, r.wrong, f"{r.lat(50):.2f}", f"{r.lat(99):.2f}",
                         f"{r.cpu(50):.2f}", f"{r.lat(50) / ref:.1f}"])
    print_table(["case", "method", "correct %", "ID failures", "bad matches", "median ms", "p99 ms",
                 "median CPU ms", "median / pyramid"], rows, title=title)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="100 frames per cell")
    ap.add_argument("--trials", type=int, default=None, help="frames per cell (default 1,000)")
    ap.add_argument("--seed", type=int, default=4)
    args = ap.parse_args()
    n = args.trials or (100 if args.quick else 1000)

    cam = camera_preset("paper000")
    cat = load_catalog(6.0)
    db = build_database(cat, cam)
    print(f"# Lost-in-space robustness, all methods on the same frames ({n} per cell)\n")
    print(f"machine: {machine_line()}")
    print(f"database: {db.summary()}")
    rng = np.random.default_rng(args.seed)
    attitudes = quat_random(rng, n)

    cells = []
    for n_false in FALSE_STARS:
        frng = np.random.default_rng([args.seed, n_false])
        frames = [simulate_identification_frame(cat, cam, q, frng, sigma_px=0.5, mag_sigma=0.2, n_false=n_false,
                                                false_among=30, max_stars=30) for q in attitudes]
        runs = {m: run_method(m, frames, cam, cat, db, desc=f"{n_false} false: {m}", sigma_px=0.5) for m in METHODS}
        cells.append((f"{n_false} false / 30", runs))
    table("## False stars among the 30 brightest (0.5 px noise)", cells)

    cells = []
    for noise in NOISE_PX:
        frng = np.random.default_rng([args.seed, 1000 + int(noise * 10)])
        frames = [simulate_identification_frame(cat, cam, q, frng, sigma_px=noise, mag_sigma=0.2) for q in attitudes]
        runs = {m: run_method(m, frames, cam, cat, db, desc=f"{noise} px: {m}", sigma_px=noise) for m in METHODS}
        cells.append((f"{noise} px", runs))
    table("## Centroid noise (all detections, no false star)", cells)


if __name__ == "__main__":
    main()
