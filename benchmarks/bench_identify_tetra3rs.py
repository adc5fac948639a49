"""Lost-in-space against the open Rust solver tetra3rs: same scenes, same verdict, one run.

Scenes: the ZY-3 camera of paper 002 (20°×20°, 1024² px of 15 µm, f = 43.3 mm), stars to V = 6, the
20 brightest detections handed to the solvers, random attitudes, 0.2 mag intensity noise. Sweeps:
centroid noise 0.5 / 1 / 2 px (1σ per axis, no false star) and 0 / 5 / 10 false stars among the 20
(0.5 px; false-star magnitudes drawn inside the range of the 20 brightest true stars). Every solver sees
the same detections.

Verdict (the same for every solver): correct when the solver reports success and its boresight is
within 60″ of the truth at 0.5 px of noise (the limit scales with the noise: 120″ at 1 px, 240″ at 2 px,
since a correct 2 px solution misses 60″ by chance); wrong when it reports success with the boresight
farther off; failed otherwise. For our methods the star labels are checked too (``mislabelled``: a
success with a true star carrying another star's HIP), which a boresight verdict alone cannot see.
Time: wall clock around each solver's call on one frame (ours: ``identify``; tetra3rs:
``solve_from_centroids``), median and 90th percentile, and the ratio of medians to tetra3rs in the same
run. The machine is shared, so percentiles include waiting for a core.

tetra3rs is an optional peer: the benchmark creates its own virtual environment
(``$STARTRACKER_CACHE_DIR`` or the user cache folder, ``tetra3rs-venv``), installs ``tetra3rs`` from PyPI
into it on first use and runs it in a subprocess on the same frames; when that fails it prints a one-line
notice and reports our methods alone. Its database is generated once (bundled Gaia catalogue, maximum
field 20°) and saved beside the venv.

Also reported: the identification database's build time, size and disk-cache load time (a fresh process
loads the file written by the build).

    python benchmarks/bench_identify_tetra3rs.py            # 300 attitudes per case
    python benchmarks/bench_identify_tetra3rs.py --quick    # 100
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import venv
from pathlib import Path

import numpy as np

from bench_identify_common import machine_line, print_table
from startracker import cache
from startracker.catalog import load_catalog
from startracker.identify import build_database, clear_database_cache, identify
from startracker.simulation import simulate_identification_frame as simulate_frame
from startracker.optics import camera_preset
from startracker.rotations import quat_random, quat_to_matrix

METHODS = ["pyramid", "brightness", "voting", "string"]
VERDICT_ARCSEC = 60.0
NOISE_CASES = [("0.5 px", 0.5, 0), ("1 px", 1.0, 0), ("2 px", 2.0, 0)]
FALSE_CASES = [("5 false / 20", 0.5, 5), ("10 false / 20", 0.5, 10)]

PEER_SCRIPT = r'''
import json, sys, time
import numpy as np
import tetra3rs
cfg = json.loads(sys.argv[1])
data = np.load(cfg["frames"])
dbp = cfg["database"]
try:
    db = tetra3rs.SolverDatabase.load_from_file(dbp)
except Exception:
    t0 = time.perf_counter()
    db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=cfg["fov_deg"], min_fov_deg=cfg["fov_deg"])
    db.save_to_file(dbp)
    print(json.dumps({"generated_s": time.perf_counter() - t0}), file=sys.stderr)
xy_all, counts = data["xy"], data["counts"]
w, h = cfg["width"], cfg["height"]
out = []
start = 0
for n in counts.tolist():
    xy = xy_all[start:start + n]
    start += n
    cen = np.column_stack([xy[:, 0] - (w - 1) / 2.0, xy[:, 1] - (h - 1) / 2.0, data["flux"][start - n:start]])
    t0 = time.perf_counter()
    r = db.solve_from_centroids(cen, fov_estimate_deg=cfg["fov_deg"], image_width=w, image_height=h)
    dt = (time.perf_counter() - t0) * 1e3
    if r:
        out.append([1.0, float(r.ra_deg), float(r.dec_deg), dt])
    else:
        out.append([0.0, 0.0, 0.0, dt])
np.save(cfg["out"], np.array(out))
'''


def peer_python(folder: Path) -> Path | None:
    """The tetra3rs venv's python, created and filled on first use; None (with a notice) when impossible."""
    env_dir = folder / "tetra3rs-venv"
    py = env_dir / "bin" / "python"
    try:
        if py.exists() and subprocess.run([str(py), "-c", "import tetra3rs"], capture_output=True).returncode == 0:
            return py
        venv.create(env_dir, with_pip=True, clear=True)
        r = subprocess.run([str(py), "-m", "pip", "install", "-q", "tetra3rs", "numpy"], capture_output=True, text=True)
        if r.returncode != 0:
            print(f"tetra3rs unavailable (pip install failed: {r.stderr.strip().splitlines()[-1:]}); peer skipped")
            return None
        return py
    except Exception as e:  # noqa: BLE001 - any failure only skips the optional peer
        print(f"tetra3rs unavailable ({type(e).__name__}: {e}); peer skipped")
        return None


def run_peer(py: Path, folder: Path, frames, cam) -> np.ndarray | None:
    with tempfile.TemporaryDirectory() as tmp:
        fpath, opath = Path(tmp) / "frames.npz", Path(tmp) / "out.npy"
        np.savez(fpath, xy=np.vstack([f.xy for f in frames]), flux=np.concatenate([f.intensities for f in frames]),
                 counts=np.array([len(f.xy) for f in frames]))
        cfg = dict(frames=str(fpath), out=str(opath), database=str(folder / "tetra3rs-zy3-20deg.bin"),
                   fov_deg=float(cam.fov_deg[0]), width=cam.resolution[0], height=cam.resolution[1])
        r = subprocess.run([str(py), "-c", PEER_SCRIPT, json.dumps(cfg)], capture_output=True, text=True)
        if r.returncode != 0:
            print(f"tetra3rs run failed ({r.stderr.strip().splitlines()[-1:]}); peer skipped")
            return None
        if r.stderr.strip():
            print(f"tetra3rs database: {r.stderr.strip()}")
        return np.load(opath)


def boresight_error_arcsec(q_true, ra_deg, dec_deg) -> float:
    b_true = quat_to_matrix(q_true)[:, 2]
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    b = np.array([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])
    return float(np.degrees(np.arccos(np.clip(b @ b_true, -1, 1))) * 3600)


def score(success, err_arcsec, sigma_px=0.5):
    if not success:
        return "fail"
    return "correct" if err_arcsec <= VERDICT_ARCSEC * max(sigma_px, 0.5) / 0.5 else "wrong"


def run_ours(method, frames, cam, cat, db, sigma_px):
    verdicts, ms, mislabelled = [], [], 0
    for f in frames:
        t0 = time.perf_counter()
        r = identify(f.xy, cam, cat, method=method, intensities=f.intensities, database=db, sigma_px=sigma_px)
        ms.append((time.perf_counter() - t0) * 1e3)
        bore = quat_to_matrix(r.q_cam_to_icrs)[:, 2]
        ra, dec = np.degrees(np.arctan2(bore[1], bore[0])), np.degrees(np.arcsin(np.clip(bore[2], -1, 1)))
        verdicts.append(score(r.success, boresight_error_arcsec(f.q_cam_to_icrs, ra, dec), sigma_px))
        true = f.hip >= 0
        mislabelled += bool(r.success and np.any((r.star_ids[true] >= 0) & (r.star_ids[true] != f.hip[true])))
    return verdicts, np.array(ms), mislabelled


def row(case, name, verdicts, ms, ref_median, mislabelled="-"):
    n = len(verdicts)
    c, w, fl = verdicts.count("correct"), verdicts.count("wrong"), verdicts.count("fail")
    med, p90 = float(np.median(ms)), float(np.percentile(ms, 90))
    ratio = f"{med / ref_median:.2f}" if ref_median else "-"
    return [case, name, f"{100 * c / n:.1f}", w, mislabelled, fl, f"{med:.3f}", f"{p90:.3f}", ratio]


def database_costs(cat_mag, preset):
    """Build time and size, and the disk-cache load time in a fresh process (same cache folder)."""
    code = (
        "import time; from startracker.catalog import load_catalog; from startracker.optics import camera_preset;"
        "from startracker.identify import build_database;"
        f"c = load_catalog({cat_mag}); cam = camera_preset('{preset}'); t0 = time.perf_counter();"
        "db = build_database(c, cam); print(db.source, time.perf_counter() - t0, db.build_time_s)"
    )
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=root).stdout.split()
           for _ in range(3)]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="100 attitudes per case")
    ap.add_argument("--trials", type=int, default=None, help="attitudes per case (default 300)")
    ap.add_argument("--seed", type=int, default=18)
    ap.add_argument("--no-peer", action="store_true", help="skip tetra3rs")
    args = ap.parse_args()
    n = args.trials or (100 if args.quick else 300)

    cam = camera_preset("zy3")
    cat = load_catalog(6.0)
    folder = cache.cache_dir() or Path(tempfile.gettempdir()) / "startracker-gym"
    folder.mkdir(parents=True, exist_ok=True)
    print(f"# Lost-in-space vs tetra3rs ({n} attitudes per case, ZY-3 camera, V <= 6, 20 brightest)\n")
    print(f"machine: {machine_line()}")
    costs = database_costs(6.0, "zy3")
    clear_database_cache()
    db = build_database(cat, cam)
    print(f"database: {db.summary()}")
    print("database in fresh processes (source, wall s, build s): " + "; ".join(" ".join(c) for c in costs))
    disk_file = cache.entry_path({"probe": 0}, folder)
    print(f"disk cache folder: {disk_file.parent if disk_file else 'disabled'}")
    py = None if args.no_peer else peer_python(folder)
    rng = np.random.default_rng(args.seed)
    attitudes = quat_random(rng, n)
    rows = []
    for label, sigma, n_false in NOISE_CASES + FALSE_CASES:
        frng = np.random.default_rng([args.seed, int(sigma * 10), n_false])
        frames = [simulate_frame(cat, cam, q, frng, sigma_px=sigma, mag_sigma=0.2, n_false=n_false,
                                 false_among=20 if n_false else None, max_stars=20) for q in attitudes]
        peer = run_peer(py, folder, frames, cam) if py is not None else None
        ref = None
        if peer is not None:
            v = [score(bool(s), boresight_error_arcsec(f.q_cam_to_icrs, ra, dec), sigma)
                 for f, (s, ra, dec, _) in zip(frames, peer)]
            ref = float(np.median(peer[:, 3]))
            rows.append(row(label, "tetra3rs", v, peer[:, 3], ref))
        for m in METHODS:
            v, ms, bad = run_ours(m, frames, cam, cat, db, max(sigma, 0.5))
            rows.append(row(label, m, v, ms, ref, bad))
        print(f"  done: {label}", file=sys.stderr)
    print_table(["case", "solver", "correct %", "wrong", "mislabelled", "failed", "median ms", "p90 ms",
                 "median / tetra3rs"], rows, title="## Correct: boresight within 60 arcsec (x noise / 0.5 px)")


if __name__ == "__main__":
    main()
