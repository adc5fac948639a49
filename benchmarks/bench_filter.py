"""Filter and gyro cost per frame: the compiled MEKF frame (``AttitudeEKF.process``) against filterpy's own
predict/update loop, and the compiled gyro model (``Gyro.measure``).

A frame is what the env fuses every 0.1 s control step: G = 10 gyro intervals of 10 ms and M = 1, 8 or 21 attitude
samples at random instants inside (gate at χ² = 30). Three ways, same inputs, same run:

- ``process``: ``AttitudeEKF.process(..., validate=False)``, one :func:`startracker.kernels.filter.fuse_frame` call
  plus the attribute glue (what the env calls);
- ``fuse_frame``: the kernel alone, on preallocated arrays;
- peer ``filterpy loop``: filterpy's ``ExtendedKalmanFilter.predict`` per interval and ``update`` per sample, with the
  model's Φ, Q, innovation and reset from the compiled kernels (the least Python a filterpy-based MEKF can run),
  and, for scale, the public per-call API (``AttitudeEKF.propagate`` / ``update``, input checks included).

Each is timed over a block of calls, the filter's state restored before every call, median over ``--repeats`` blocks
(>= 5). ``Gyro.measure`` is timed per call for 10 samples (one control step at 100 Hz). ``--env`` also runs 5 blocks
of 300 steps of ``startracker/AgileSlew-v0`` with the eigenaxis slew policy (steps/s per block, and the time per step
spent inside ``AttitudeEKF.process`` and ``Gyro.measure``, in situ). ``--compile`` times an import and the first calls
on an empty numba cache (a subprocess).

    python benchmarks/bench_filter.py [--quick] [--env] [--compile]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from filterpy.kalman import ExtendedKalmanFilter  # noqa: E402

from startracker.filter import AttitudeEKF  # noqa: E402
from startracker.imu import Gyro, gyro_preset  # noqa: E402
from startracker.kernels import filter as kf  # noqa: E402
from startracker.rotations import quat_from_rotvec, quat_multiply, quat_random  # noqa: E402

ARCSEC = math.pi / 180.0 / 3600.0
SV, SU, GATE = 2e-5, 1e-7, 30.0
H = np.hstack([np.eye(3), np.zeros((3, 3))])


def frame_inputs(m: int, rng):
    """A frame: 10 gyro intervals (rad/s, s), M attitude samples (unit quaternions, s, rad²) about the truth."""
    tg = 0.01 * np.arange(1, 11)
    w_true = rng.normal(0.0, 0.2, 3)
    wg = w_true + rng.normal(0.0, 1e-4, (10, 3))
    q0 = quat_random(rng)
    tm = np.sort(0.1 * rng.uniform(0.0, 1.0, m))
    qm = quat_multiply(quat_multiply(q0, quat_from_rotvec(np.outer(tm, w_true))), quat_from_rotvec(rng.normal(0, 5 * ARCSEC, (m, 3))))
    cov = np.ascontiguousarray(np.broadcast_to(np.diag([25.0, 25.0, 1600.0]) * ARCSEC**2, (m, 3, 3)))
    return q0, wg, tg, qm, tm, cov


def timed(fn, n_inner: int, repeats: int) -> float:
    """Median over ``repeats`` blocks of the mean time of one call, s."""
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(n_inner):
            fn()
        out.append((time.perf_counter() - t) / n_inner)
    return statistics.median(out)


def bench_frame(m: int, rng, n_inner: int, repeats: int) -> dict:
    q0, wg, tg, qm, tm, cov = frame_inputs(m, rng)
    f = AttitudeEKF(q0, arw_rad_sqrt_s=SV, rrw_rad_s_sqrt_s=SU, sigma_attitude_rad=20 * ARCSEC, gate_chi2=GATE)
    p0 = f.P.copy()
    b0 = np.zeros(3)

    def restore():
        f.q_body_to_icrs, f.bias_rad_s, f.t_s = q0, b0, 0.0
        f.ekf.P = p0

    def run_process():
        restore()
        f.process(wg, tg, qm, tm, cov, validate=False)

    q, b, P = q0.copy(), b0.copy(), p0.copy()
    acc, phi, qd, z = np.empty(m, dtype=bool), np.empty((6, 6)), np.empty((6, 6)), np.empty(3)
    rate_noise, nis, zs, ss = np.zeros((len(tg), 3)), np.empty(m), np.empty((m, 3)), np.empty((m, 3, 3))

    def run_kernel():
        q[:] = q0
        b[:] = b0
        P[:] = p0
        kf.fuse_frame(q, b, P, 0.0, wg, tg, qm, tm, cov, SV, SU, GATE, acc, phi, qd, z, rate_noise, nis, zs, ss)

    ref = ExtendedKalmanFilter(dim_x=6, dim_z=3)

    def run_filterpy():
        # filterpy's own predict/update; the MEKF bookkeeping (attitude, bias, reset) around it
        ref.x, ref.P = np.zeros((6, 1)), p0
        qq, bb, t, g = q0, b0, 0.0, 0
        for i in range(m + 1):
            t_next = tm[i] if i < m else tg[-1]
            while g < 10 and (i == m or tg[g] < t_next):
                w_hat = wg[g] - bb
                dt = tg[g] - t
                ref.F, ref.Q = kf.transition(w_hat, dt, SV, SU)
                ref.predict()
                qq = kf.quat_advance(qq, w_hat * dt)
                t = tg[g]
                g += 1
            if i == m:
                break
            dt = t_next - t
            if dt > 0.0:
                w_hat = wg[min(g, 9)] - bb
                ref.F, ref.Q = kf.transition(w_hat, dt, SV, SU)
                ref.predict()
                qq = kf.quat_advance(qq, w_hat * dt)
                t = t_next
            zz = kf.attitude_residual(qq, qm[i])
            if zz @ np.linalg.solve(ref.P[:3, :3] + cov[i], zz) > GATE:
                continue
            ref.update(zz.reshape(3, 1), lambda _x: H, lambda x: x[:3], R=cov[i])
            dx = ref.x[:, 0]
            qq = kf.quat_advance(qq, dx[:3].copy())
            bb = bb + dx[3:]
            ref.x = np.zeros((6, 1))

    def run_public():
        restore()
        gi, tt = 0, 0.0
        for i in range(m):
            while tg[gi] < tm[i]:
                f.propagate(wg[gi], tg[gi] - tt)
                tt = tg[gi]
                gi += 1
            f.update(qm[i], cov[i], tm[i], omega_gyro=wg[gi])
            tt = tm[i]
        while gi < 10:
            f.propagate(wg[gi], tg[gi] - tt)
            tt = tg[gi]
            gi += 1

    # all four give the same estimate (the tests prove it to rounding); check once here too
    run_process()
    q_a, p_a = f.q_body_to_icrs.copy(), f.P.copy()
    run_public()
    assert np.abs(q_a - f.q_body_to_icrs).max() < 1e-12 and np.abs(p_a - f.P).max() < 1e-9 * np.abs(p_a).max()
    slow = max(1, n_inner // 20)
    return dict(
        m=m,
        process=timed(run_process, n_inner, repeats),
        kernel=timed(run_kernel, n_inner, repeats),
        filterpy=timed(run_filterpy, slow, repeats),
        public=timed(run_public, slow, repeats),
    )


def bench_gyro(n_inner: int, repeats: int) -> list:
    rows = []
    u = np.zeros((10, 3))
    for grade in ("tactical", "industrial"):
        g = Gyro(gyro_preset(grade, rate_hz=100.0), np.random.default_rng(1))
        r = np.random.default_rng(2)
        rows.append((grade, "(10, 3)", timed(lambda: g.measure(u, r), n_inner, repeats)))
    g = Gyro(gyro_preset("tactical", rate_hz=100.0), np.random.default_rng(1))
    r = np.random.default_rng(2)
    u1 = np.zeros(3)
    rows.append(("tactical", "(3,)", timed(lambda: g.measure(u1, r), n_inner, repeats)))
    return rows


def bench_env(repeats: int = 5, steps: int = 300) -> tuple:
    """Steps/s of AgileSlew-v0 per block, and the wall time per step spent inside ``AttitudeEKF.process`` and
    ``Gyro.measure`` (in situ: caches cold from the rest of the step, unlike the loops above), µs."""
    import gymnasium as gym

    import envs  # noqa: F401
    from policies import EigenaxisSlewPolicy

    spent = {"process": 0.0, "measure": 0.0}
    originals = {"process": AttitudeEKF.process, "measure": Gyro.measure}

    def timed_method(key):
        orig = originals[key]

        def method(*a, **k):
            t = time.perf_counter()
            out = orig(*a, **k)
            spent[key] += time.perf_counter() - t
            return out

        return method

    AttitudeEKF.process, Gyro.measure = timed_method("process"), timed_method("measure")
    try:
        env = gym.make("startracker/AgileSlew-v0")
        pol = EigenaxisSlewPolicy.from_env(env)
        obs, _ = env.reset(seed=999)
        for _ in range(20):  # warm-up: first calls, numba cache load
            obs, *_ = env.step(pol.act(obs))
        spent.update(process=0.0, measure=0.0)
        rates = []
        for rep in range(repeats):
            obs, _ = env.reset(seed=rep)
            t = time.perf_counter()
            for _ in range(steps):
                obs, _, te, tr, _ = env.step(pol.act(obs))
                if te or tr:
                    obs, _ = env.reset(seed=100 + rep)
            rates.append(steps / (time.perf_counter() - t))
        env.close()
    finally:
        AttitudeEKF.process, Gyro.measure = originals["process"], originals["measure"]
    n = repeats * steps
    return rates, spent["process"] / n, spent["measure"] / n


_COMPILE = r"""
import time
t0 = time.perf_counter()
import numpy as np
from startracker.filter import AttitudeEKF
from startracker.imu import Gyro, gyro_preset
t1 = time.perf_counter()
f = AttitudeEKF([1.0, 0, 0, 0], arw_rad_sqrt_s=2e-5, gate_chi2=30.0)
f.process(np.zeros((2, 3)), [0.05, 0.1], [[1.0, 0, 0, 0]], [0.07], np.eye(3)[None] * 1e-9)
f.propagate(np.zeros(3), 0.1)
f.update([1.0, 0, 0, 0], np.eye(3) * 1e-9)
t2 = time.perf_counter()
Gyro(gyro_preset("industrial"), np.random.default_rng(0)).measure(np.zeros((10, 3)), np.random.default_rng(1))
t3 = time.perf_counter()
print(f"{t1 - t0:.3f} {t2 - t1:.3f} {t3 - t2:.3f}")
"""


def bench_compile() -> tuple:
    root = str(Path(__file__).resolve().parents[1])
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        cold = subprocess.run([sys.executable, "-c", _COMPILE], env=env, cwd=root, capture_output=True, text=True,
                              check=True).stdout.split()
        warm = subprocess.run([sys.executable, "-c", _COMPILE], env=env, cwd=root, capture_output=True, text=True,
                              check=True).stdout.split()
    return [float(x) for x in cold], [float(x) for x in warm]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer calls per block")
    ap.add_argument("--repeats", type=int, default=7, help="timed blocks per figure (>= 5)")
    ap.add_argument("--env", action="store_true", help="also 5 x 300 steps of AgileSlew-v0")
    ap.add_argument("--compile", action="store_true", help="also first-compile time on an empty numba cache")
    args = ap.parse_args(argv)
    repeats = max(5, args.repeats)
    n_inner = 200 if args.quick else 2000
    rng = np.random.default_rng(0)

    print(f"Frame fuse, G = 10 gyro intervals + M samples, median of {repeats} blocks, µs per frame")
    print("| M | process (compiled) | fuse_frame kernel | filterpy predict/update loop | propagate/update API |"
          " filterpy loop / process |")
    print("|---|---|---|---|---|---|")
    for m in (1, 8, 21):
        r = bench_frame(m, rng, n_inner, repeats)
        print(f"| {m} | {r['process'] * 1e6:.1f} | {r['kernel'] * 1e6:.1f} | {r['filterpy'] * 1e6:.0f} |"
              f" {r['public'] * 1e6:.0f} | {r['filterpy'] / r['process']:.0f}x |")

    print(f"\nGyro.measure per call, median of {repeats} blocks, µs")
    print("| grade | input | µs per call |")
    print("|---|---|---|")
    for grade, shape, t in bench_gyro(5 * n_inner, repeats):
        print(f"| {grade} | {shape} | {t * 1e6:.2f} |")

    if args.env:
        rates, t_process, t_measure = bench_env()
        print(f"\nAgileSlew-v0, 300 steps x 5, eigenaxis slew policy: steps/s per block {[round(x) for x in rates]},"
              f" median {statistics.median(rates):.0f}; per step inside AttitudeEKF.process {t_process * 1e6:.1f} µs,"
              f" inside Gyro.measure {t_measure * 1e6:.1f} µs")
    if args.compile:
        cold, warm = bench_compile()
        print("\nEmpty numba cache (s): import {:.2f}, filter kernels first call {:.2f}, gyro kernel first call {:.2f};"
              " cached: import {:.2f}, first calls {:.2f} / {:.2f}".format(*cold, *warm))


if __name__ == "__main__":
    main()
