"""Frame time of the star image + centroiding paths (issue 3).

A multi-exposure frame of paper 000's camera (2048×2048, f = 31.94 mm): N = 15 exposures of 1 ms,
M = 30 stars (the 30 brightest in the field), cross-boresight slew at 13°/s, the full noise model of
``SensorModel.preset("paper000")`` (intensifier, dark, read noise, PRNU, hot pixels, cosmic rays, debris) and
the Sun 50° off the boresight (stray-light gradient). Paths timed in the same run:

* naive     — the same expected image, full-frame Poisson + Gaussian noise, quantisation, the background plane
              and threshold of ``extract_centroids``, ``scipy.ndimage.label`` and ``scipy.ndimage.center_of_mass``
              over the frame;
* full      — ``render_frame`` + ``extract_centroids`` (what ``render()`` costs);
* sparse    — ``simulate_detections(fidelity="pixel")``: windows around the spots, background crossings from
              their statistics, centroiding of the windows (target ≤ 10 ms);
* centroid  — ``simulate_detections(fidelity="centroid")``: detections from the calibrated error model;
* scene     — ``compute_scene`` alone (cone search + projection at the N × 3 path instants).

Run ``python benchmarks/bench_frame.py`` (30 repeats) or ``--quick`` (5). Prints wall-clock medians with
their interquartile range and best run, process CPU-time medians, and the CPU-time ratio to the naive path. Reference: LOST's C++ generator takes about 50 ms
for a 1024² frame (150 ms with blur).

``--pipeline``: the per-frame cost of the default env's frame (paper 000's camera, the env's V <= 6 catalog, the
truth as the env passes it: attitudes sampled every 10 ms over the frame, ``validate=False`` as the env calls) for
N = 1, 15 and 21 exposures (still, 13°/s and 20°/s): ``compute_scene``, ``simulate_detections(fidelity="centroid")``,
their sum, and the pixel path (``fidelity="pixel"``) on the same scene as the peer, with the ratio of the medians.
Each repeat times a loop of calls; the table gives the median [and the best] over the repeats of the per-call time.

``--env``: steps per second over 300 steps of ``gymnasium.make("startracker/AgileSlew-v0")`` (default config:
centroid fidelity) driven by ``policies.EigenaxisSlewPolicy.from_env``, reset with seed 0, median over the
repeats; the peer in the same run is the bare MuJoCo physics of the same spacecraft over the same 0.1 s periods.

To compare before and after, copy this file into a checkout of the earlier commit and run it there (it imports
the packages of the checkout it sits in): the peer columns tell how loaded the machine was in each run.
"""

from __future__ import annotations

import argparse
import inspect
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from startracker.catalog import load_catalog
from startracker.centroid import estimate_background, extract_centroids, simulate_detections
from startracker.imaging import SensorModel, render_expected, render_frame
from startracker.optics import camera_preset
from startracker.rotations import quat_integrate, quat_random, quat_rotate
from startracker.scene import BrightBody, ExposurePlan, compute_scene


def build_frame(seed: int = 3, n_exposures: int = 15, n_stars: int = 30, rate_deg_s: float = 13.0):
    rng = np.random.default_rng(seed)
    cam = camera_preset("paper000")
    cat = load_catalog(7.0)
    q0 = quat_random(rng)
    omega = np.radians(rate_deg_s) * np.array([0.8, 0.6, 0.0])

    def attitude(t):
        return quat_integrate(np.broadcast_to(q0, (len(t), 4)), omega, np.asarray(t))

    plan = ExposurePlan(n_exposures, 1e-3, frame_period_s=0.1)
    a = np.radians(50.0)
    sun = BrightBody("sun", quat_rotate(q0, np.array([np.sin(a), 0.0, np.cos(a)])))
    probe = compute_scene(cam, cat, attitude, plan, 0.0)
    vis = probe.visible.any(axis=0)
    vlim = np.sort(probe.vmag[vis])[min(n_stars, vis.sum()) - 1]
    cat30 = cat.subset(cat.vmag <= vlim + 1e-9)
    scene = compute_scene(cam, cat30, attitude, plan, 0.0, bright_bodies=[sun])
    return cam, cat30, attitude, plan, sun, scene


def naive_path(scene, model, rng, expected):
    """Full-frame Poisson + Gaussian noise, quantisation, threshold, label, center_of_mass over the frame.

    The Poisson field is drawn in units of ``g_eff = G F² c`` electrons (the per-pixel variance of light
    through the intensifier, see startracker/imaging), so the pixel statistics match the model's.
    """
    g_eff = max(model.intensifier_gain * model.excess_noise_factor**2 * model.splash_energy, 1.0)
    e = g_eff * rng.poisson(expected / g_eff) + rng.normal(0.0, model.read_noise_e, expected.shape)
    img = np.clip(np.rint(np.minimum(e, model.full_well_e) / model.gain_e_per_dn + model.bias_dn), 0, model.adc_max_dn)
    level, sigma, _ = estimate_background(img)  # the same background plane as extract_centroids
    rr = np.arange(img.shape[0])[:, None]
    cc = np.arange(img.shape[1])[None, :]
    bg = level(rr, cc)
    mask = img > bg + 5.0 * sigma(rr, cc)
    labels, n = ndimage.label(mask, structure=np.ones((3, 3)))
    com = ndimage.center_of_mass(np.where(mask, img - bg, 0.0), labels, np.arange(1, n + 1))
    return np.asarray(com).reshape(-1, 2)[:, ::-1]


def timed(fn, repeats):
    """Wall-clock and process CPU times (ms) of ``repeats`` calls, and the last result."""
    out = None
    wall, cpu = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return np.array(wall) * 1e3, np.array(cpu) * 1e3, out


def _env_frame(n_exposures: int, rate_deg_s: float, seed: int = 7):
    """The default env's frame: camera, catalog, truth history (10 ms samples over the frame), plan."""
    from startracker.rotations import quat_random as _qr

    rng = np.random.default_rng(seed)
    cam = camera_preset("paper000")
    cat = load_catalog(6.0)
    q0 = _qr(rng)
    omega = np.radians(rate_deg_s) * np.array([0.6, -0.8, 0.05])
    t_s = np.linspace(0.0, 0.1, 11)
    q_s = quat_integrate(np.broadcast_to(q0, (len(t_s), 4)), omega, t_s)
    plan = ExposurePlan(n_exposures, 1e-3, frame_period_s=0.1) if n_exposures > 1 else \
        ExposurePlan(1, 1e-3, frame_period_s=0.1, start_offset_s=0.0495)
    return cam, cat, (t_s, q_s), plan


def _per_call_ms(fn, calls: int, repeats: int) -> np.ndarray:
    out = np.empty(repeats)
    for r in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        out[r] = (time.perf_counter() - t0) / calls * 1e3
    return out


def pipeline_table(repeats: int, calls: int = 40):
    """Per-frame scene + centroid-fidelity cost for N = 1, 15, 21, with the pixel path as the peer."""
    model = SensorModel.preset("paper000")
    fast = {"validate": False} if "validate" in inspect.signature(compute_scene).parameters else {}
    fast_det = {"validate": False} if "validate" in inspect.signature(simulate_detections).parameters else {}
    print(f"per-frame cost, paper 000 camera, V <= 6 catalog, model {model.name}; medians over {repeats} repeats of "
          f"{calls} calls (pixel: {max(calls // 8, 2)}); load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; "
          f"validate=False: {bool(fast)}")
    print(f"{'N':>3s} {'rate':>6s} {'spots':>6s} {'scene ms':>15s} {'centroid ms':>15s} {'scene+centroid':>15s} "
          f"{'pixel ms (peer)':>16s} {'pixel/(s+c)':>11s}   (median [best] over the repeats)")
    rows = []
    for n, rate in ((1, 0.0), (15, 13.0), (21, 20.0)):
        cam, cat, truth, plan = _env_frame(n, rate)
        rng = np.random.default_rng(0)

        def scene():
            return compute_scene(cam, cat, truth, plan, 0.0, **fast)

        sc = scene()

        def centroid():
            return simulate_detections(sc, model, rng, fidelity="centroid", **fast_det)

        def both():
            return simulate_detections(scene(), model, rng, fidelity="centroid", **fast_det)

        def pixel():
            return simulate_detections(sc, model, rng, fidelity="pixel")

        for f in (scene, centroid, both, pixel):
            f()  # warm-up: compilation, caches
        ts = _per_call_ms(scene, calls, repeats)
        tc = _per_call_ms(centroid, calls, repeats)
        tb = _per_call_ms(both, calls, repeats)
        tp = _per_call_ms(pixel, max(calls // 8, 2), repeats)

        def fmt(a):
            return f"{np.median(a):6.3f} [{np.min(a):.3f}]"

        print(f"{n:3d} {rate:5.0f}° {int(sc.visible.sum()):6d} {fmt(ts):>15s} {fmt(tc):>15s} {fmt(tb):>15s} "
              f"{fmt(tp):>16s} {np.median(tp) / np.median(tb):10.1f}x")
        rows.append((n, np.median(ts), np.median(tc), np.median(tb), np.median(tp)))
    return rows


def env_steps(repeats: int, n_steps: int = 300):
    """Steps/s of the default env over ``n_steps`` steps (seed 0), and the bare physics as the peer."""
    import gymnasium as gym

    import envs  # noqa: F401
    from envs.spacecraft import Spacecraft
    from policies import EigenaxisSlewPolicy

    def run_env():
        env = gym.make("startracker/AgileSlew-v0")
        pol = EigenaxisSlewPolicy.from_env(env)
        obs, _ = env.reset(seed=0)
        t0 = time.perf_counter()
        for _ in range(n_steps):
            obs, _, te, tr, _ = env.step(pol.act(obs))
            if te or tr:
                obs, _ = env.reset()
        dt = time.perf_counter() - t0
        env.close()
        return n_steps / dt

    def run_physics():
        sc = Spacecraft()
        t0 = time.perf_counter()
        for _ in range(n_steps):
            sc.apply_wheel_torque(np.full(4, 0.01))
            for _ in range(10):
                sc.step(0.01)
        return n_steps / (time.perf_counter() - t0)

    run_env()  # warm-up: compilation, catalog, calibration of the heads
    env_r = np.array([run_env() for _ in range(repeats)])
    phys_r = np.array([run_physics() for _ in range(repeats)])
    print(f"AgileSlew-v0 default (centroid fidelity), {n_steps} steps, seed 0, EigenaxisSlewPolicy; medians over "
          f"{repeats} repeats; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'':28s} {'steps/s':>9s} {'(min-max)':>17s}")
    print(f"{'env step':28s} {np.median(env_r):9.1f} {env_r.min():8.1f}-{env_r.max():<8.1f}")
    print(f"{'physics only (peer)':28s} {np.median(phys_r):9.1f} {phys_r.min():8.1f}-{phys_r.max():<8.1f}")
    print(f"env step costs {np.median(phys_r) / np.median(env_r):.1f}x the physics")
    return np.median(env_r), np.median(phys_r)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 repeats instead of 30")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--pipeline", action="store_true", help="per-frame scene + centroid fidelity for N = 1, 15, 21")
    ap.add_argument("--env", action="store_true", help="steps/s of the default env over 300 steps")
    args = ap.parse_args(argv)
    reps = args.repeats or (5 if args.quick else 30)
    if args.pipeline or args.env:
        if args.pipeline:
            pipeline_table(max(reps, 5))
        if args.env:
            env_steps(max(min(reps, 5), 3))
        return
    cam, cat30, attitude, plan, sun, scene = build_frame()
    model = SensorModel.preset("paper000")
    rng = np.random.default_rng(0)
    expected = render_expected(scene, model)
    # warm-up (fixed pattern cache, index buffer, imports)
    render_frame(scene, model, rng)
    simulate_detections(scene, model, rng, "pixel")
    simulate_detections(scene, model, rng, "centroid")

    rows = []
    w, c, d = timed(lambda: naive_path(scene, model, rng, expected), max(3, reps // 5))
    rows.append(("naive full frame (Poisson+Gauss, label, center_of_mass)", w, c, len(d)))
    w, c, d = timed(lambda: extract_centroids(render_frame(scene, model, rng), saturation_dn=model.saturation_dn),
                    max(3, reps // 3))
    rows.append(("full frame: render_frame + extract_centroids", w, c, len(d)))
    w, c, d = timed(lambda: simulate_detections(scene, model, rng, "pixel"), reps * 4)
    rows.append(("sparse: simulate_detections(fidelity='pixel')", w, c, len(d)))
    w, c, d = timed(lambda: simulate_detections(scene, model, rng, "centroid"), reps * 10)
    rows.append(("centroid: simulate_detections(fidelity='centroid')", w, c, len(d)))
    w, c, s = timed(lambda: compute_scene(cam, cat30, attitude, plan, 0.0, bright_bodies=[sun]), reps * 10)
    rows.append(("scene: compute_scene", w, c, s.n_stars))

    naive_w = np.median(rows[0][1])
    naive_c = np.median(rows[0][2])
    print(f"paper 000 camera {cam.resolution[0]}x{cam.resolution[1]}, N = {plan.n_exposures} exposures, "
          f"M = {scene.n_stars} stars ({scene.visible.sum()} spots on the detector), model {model.name}; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'path':56s} {'wall ms':>9s} {'(IQR)':>15s} {'best':>8s} {'CPU ms':>8s} {'vs naive':>9s} {'detections':>11s}")
    for name, w, c, n in rows:
        q1, q3 = np.percentile(w, [25, 75])
        print(f"{name:56s} {np.median(w):9.2f} {q1:7.2f}-{q3:<7.2f} {np.min(w):8.2f} {np.median(c):8.2f} "
              f"{naive_c / np.median(c):8.0f}x {n:11d}")
    sw, sc_ = np.median(rows[2][1]), np.median(rows[2][2])
    verdict = "met" if min(sw, sc_) <= 10 else "NOT met"
    print(f"sparse pixel path target <= 10 ms: {verdict} (wall {sw:.2f} ms, CPU {sc_:.2f} ms); centroid fidelity "
          f"wall {np.median(rows[3][1]):.3f} ms, CPU {np.median(rows[3][2]):.3f} ms. 'vs naive' is the CPU-time ratio "
          f"(wall-clock is unreliable when the machine is oversubscribed; wall ratio sparse: {naive_w / sw:.0f}x).")


if __name__ == "__main__":
    main()
