"""Pixel path vs centroid fidelity per magnitude: detection rate and RMS radial centroid error (COM, 2 px smear,
stars on a 60 px grid, 6 frames), for the two detector presets; the tables of docs/imaging.md.

    python benchmarks/bench_fidelity.py [--frames 6]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from startracker.centroid.fidelity import grid_scene, simulate_detections  # noqa: E402
from startracker.imaging import KIND_STAR, SensorModel  # noqa: E402
from startracker.optics import camera_preset  # noqa: E402
from startracker.scene import ExposurePlan  # noqa: E402

PRESETS = {
    "paper000": (1e-3, [(2.0, 2.5), (3.0, 3.5), (4.0, 4.5), (5.0, 5.5), (6.0, 6.5), (6.5, 7.0), (7.0, 7.5)]),
    "paper000_cmos": (0.02, [(3, 4), (4, 5), (5, 6), (6, 7), (7, 8), (8, 9)]),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=6)
    args = ap.parse_args()
    cam = camera_preset("paper000")
    for name, (tau, bins) in PRESETS.items():
        model = SensorModel.preset(name)
        plan = ExposurePlan(1, tau, frame_period_s=max(0.1, tau))
        lo, hi = bins[0][0], bins[-1][1]
        acc = {f: ([], [], []) for f in ("pixel", "centroid")}
        for k in range(args.frames):
            sc = grid_scene(cam, plan, lo, hi, 2.0 / tau, 60.0, np.random.default_rng(100 + k))
            for fid, (vm, found, err) in acc.items():
                det = simulate_detections(sc, model, np.random.default_rng(200 + k), fid, include_false=False)
                st = np.flatnonzero(det.truth_kind == KIND_STAR)
                u, first = np.unique(det.truth_star[st], return_index=True)
                e = np.full(sc.n_stars, np.nan)
                e[u] = np.linalg.norm(det.xy[st[first]] - det.truth_xy[st[first]], axis=1)
                vm.append(sc.vmag)
                found.append(~np.isnan(e))
                err.append(e)
        head = f"| {name}, τ = {tau * 1e3:g} ms, V | " + " | ".join(f"{a:g}–{b:g}" for a, b in bins) + " |"
        print(head)
        print("|---" * (len(bins) + 1) + "|")
        cells_d, cells_e = [], []
        for a, b in bins:
            out_d, out_e = [], []
            for fid in ("pixel", "centroid"):
                vm, found, err = (np.concatenate(x) for x in acc[fid])
                m = (vm >= a) & (vm < b)
                e = err[m & found]
                e = e[e < 3.0]
                out_d.append(f"{found[m].mean():.2f}")
                out_e.append(f"{np.sqrt(np.mean(e ** 2)):.3f}" if len(e) else "—")
            cells_d.append(" / ".join(out_d))
            cells_e.append(" / ".join(out_e))
        print("| detected, pixel / centroid | " + " | ".join(cells_d) + " |")
        print("| RMS COM, pixel / centroid | " + " | ".join(cells_e) + " |")
        print()


if __name__ == "__main__":
    main()
