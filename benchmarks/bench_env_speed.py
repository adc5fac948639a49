"""Env speed: steps per second over whole eigenaxis-slew episodes of startracker/AgileSlew-v0, against the physics.

Rows, all measured in the same run, each the median of ``--repeats`` runs (default 5) of ``--episodes`` whole
episodes (default 2, 120° slews, seeds 0, 1, ...):

* default (centroid fidelity, multi-exposure, paper 000's camera, one head);
* pixel fidelity (sparse rendering and centroiding);
* single exposure (one exposure per frame: one attitude per frame);
* two heads (paper 001's layout, inertial aiding);
* 3CMOS (paper 004's colour head);
* the **physics-only floor**: a fresh ``Spacecraft`` given the same wheel commands, stepped over the same control
  periods with the same substeps (``Spacecraft.step_recording``), nothing else: what a step would cost with a star
  tracker that costs nothing.

Only the env is timed: the clock runs around ``env.reset`` and ``env.step`` and stops while the eigenaxis policy
computes the next action (the policy is the user's, not the env's cost). The floor is timed the same way, around
the ``Spacecraft`` calls only.

Each row gives steps/s and the ratio of its step time to the floor's (1.0 = free avionics). A second table gives,
per configuration, what a new env costs once in a warm process: ``gym.make`` and its first ``reset`` (part of the
steps/s above, since every run makes its own env), against a later reset. Then, with
``--vector-envs N`` (default 2; 0 skips it), the throughput a user gets from the default env on several cores, two
ways: gymnasium's ``AsyncVectorEnv`` with N worker processes, 120° slews back to back (autoreset), timed around
``vec.step`` only (autoreset steps not counted); and N processes each running whole episodes as the default row does
(after a warm-up episode of their own), at the same time, their steps/s summed. Each as aggregate env steps/s and its
ratio to the one-process default row of the same run; the vector env twice, alternating, with every info key and
with ``info_keys`` set to the four keys an RL run reads (``LEAN_INFO_KEYS``), each with the main process's CPU time
per vector step (the workers' results unpickled and their infos merged into arrays). This is throughput, not the
speed of one env: the issue's per-env target is the default row.
With ``--budget``, where a step's time goes, per configuration: the physics (``Spacecraft.step_recording``), the
compiled kernels (every numba function the package's modules hold under a public name, timed around each call from
Python, dispatch included; calls made inside compiled code are part of their caller's time) and the rest (Python,
numpy, the random draws), each in µs per step (medians over the repeats), with the kernels' time over the physics'
and the steps/s of physics plus kernels alone: the ceiling of this configuration if every line of Python around the
kernels cost nothing, with the kernels' arithmetic as it is. The timers add about 0.3 µs per timed call to the
rest. The same budget is then split by the exposures per frame N of each step's frame (1, 2-14, >= 15): the
multi-exposure frames near the top rate are where the compiled kernels' arithmetic dominates. Last, the four
largest kernels of each configuration, µs per step. Then the matcher table of ``bench_matching.py`` (DKVLUT vs compiled
brute force vs scipy's cKDTree) when ``--matchers`` is given.

    python benchmarks/bench_env_speed.py [--quick] [--repeats 5] [--episodes 2] [--vector-envs 2] [--budget] [--matchers]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import multiprocessing
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402
from numba.core.registry import CPUDispatcher  # noqa: E402

import envs  # noqa: E402,F401
from envs.spacecraft import Spacecraft  # noqa: E402
from policies import EigenaxisSlewPolicy  # noqa: E402

CONFIGS = {
    "default (centroid, multi-exposure)": {},
    "pixel fidelity": {"fidelity": "pixel"},
    "single exposure": {"exposure_mode": "single"},
    "two heads": {"n_heads": 2},
    "3CMOS": {"camera": "paper004_3cmos"},
}
# what an RL run reads from info: the reward terms and the settle timer (the vector-env rows' lean variant)
LEAN_INFO_KEYS = ("reward_pointing", "reward_effort", "reward_settle", "settled_s")
TARGETS = {
    "default (centroid, multi-exposure)": ">= 2000 steps/s, <= 2x floor",
    "pixel fidelity": ">= 500 steps/s",
    "two heads": ">= 1000 steps/s",
    "3CMOS": ">= 1000 steps/s",
}


def run_episodes(kwargs: dict, n_episodes: int, angle_deg: float, max_episode_s: float):
    """Whole episodes with the eigenaxis policy: (steps/s, steps, the actions of every step per episode).

    The clock runs only inside ``env.reset`` and ``env.step``. Also returned: the time of ``gym.make`` and of the
    first ``env.reset`` of this new env and the mean of its later resets, s (what a campaign that makes an env per
    run pays once per env, against what a reset costs).
    """
    clock = time.perf_counter
    t0 = clock()
    env = gym.make("startracker/AgileSlew-v0", max_episode_s=max_episode_s, **kwargs)
    make_s = clock() - t0
    pol = EigenaxisSlewPolicy.from_env(env)
    actions, steps = [], 0
    wall = 0.0
    first_reset_s = 0.0
    later_resets = []
    for k in range(n_episodes):
        t0 = clock()
        obs, _ = env.reset(seed=k, options={"slew_angle_deg": angle_deg})
        wall += clock() - t0
        if k == 0:
            first_reset_s = clock() - t0
        else:
            later_resets.append(clock() - t0)
        ep, done = [], False
        while not done:
            a = pol.act(obs)
            t0 = clock()
            obs, _, te, tr, _ = env.step(a)
            wall += clock() - t0
            ep.append(a)
            done = te or tr
        steps += len(ep)
        actions.append(np.array(ep))
    control_period_s = env.unwrapped.control_period_s
    substep_s = env.unwrapped.avionics.gyro_period_s
    env.close()
    later_reset_s = float(np.mean(later_resets)) if later_resets else float("nan")
    return steps / wall, steps, actions, control_period_s, substep_s, make_s, first_reset_s, later_reset_s


def physics_only(actions, control_period_s: float, substep_s: float) -> float:
    """The floor: the same commands on a bare Spacecraft over the same periods and substeps, steps/s."""
    sc = Spacecraft()
    n_sub = int(round(control_period_s / substep_s))
    steps = 0
    wall = 0.0
    clock = time.perf_counter
    for ep in actions:
        torques = np.clip(ep, -1.0, 1.0) * sc.wheel_max_torque_Nm  # the commands, outside the clock
        t0 = clock()
        sc.set_state(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), np.zeros(sc.n_wheels), time_s=0.0)
        for tau in torques:
            sc.apply_wheel_torque(tau)
            sc.step_recording(substep_s, n_sub)
        wall += clock() - t0
        steps += len(ep)
    return steps / wall


@contextlib.contextmanager
def timed_calls(totals: collections.Counter):
    """Time every call from Python of the compiled kernels and of ``Spacecraft.step_recording`` while the context is
    open: ``totals["kernels"]``, ``totals["kernel calls"]`` and ``totals["physics"]`` (s) accumulate, and each
    kernel's own time under ``"kernel: <module>.<name>"``.

    Each numba dispatcher held under a public name by a loaded ``startracker`` or ``envs`` module is replaced by a
    timing wrapper (one per dispatcher) and put back on exit.
    """
    clock = time.perf_counter
    wrappers, patched = {}, []

    def timing(dispatcher):
        key = f"kernel: {dispatcher.py_func.__module__.rsplit('.', 1)[-1]}.{dispatcher.__name__}"

        def call(*args):
            t0 = clock()
            out = dispatcher(*args)
            dt = clock() - t0
            totals["kernels"] += dt
            totals[key] += dt
            totals["kernel calls"] += 1
            return out
        return call

    for name, module in list(sys.modules.items()):
        if module is None or not name.split(".")[0] in ("startracker", "envs"):
            continue
        for attr, obj in list(vars(module).items()):
            if isinstance(obj, CPUDispatcher) and not attr.startswith("_"):
                if id(obj) not in wrappers:
                    wrappers[id(obj)] = timing(obj)
                patched.append((module, attr, obj))
                setattr(module, attr, wrappers[id(obj)])
    step_recording = Spacecraft.step_recording

    def timed_step_recording(self, substep_s, n_steps, **kwargs):
        t0 = clock()
        out = step_recording(self, substep_s, n_steps, **kwargs)
        totals["physics"] += clock() - t0
        return out

    Spacecraft.step_recording = timed_step_recording
    try:
        yield totals
    finally:
        Spacecraft.step_recording = step_recording
        for module, attr, obj in patched:
            setattr(module, attr, obj)


def step_budget(kwargs: dict, n_episodes: int, angle_deg: float, max_episode_s: float) -> dict:
    """Where a step's time goes over whole episodes (after a warm-up episode): µs per step of the env (reset and step),
    the physics, the compiled kernels and the rest, and the kernel calls per step (:func:`timed_calls`)."""
    env = gym.make("startracker/AgileSlew-v0", max_episode_s=max_episode_s, **kwargs)
    pol = EigenaxisSlewPolicy.from_env(env)
    obs, _ = env.reset(seed=0, options={"slew_angle_deg": angle_deg})
    for _ in range(20):  # warm-up: this configuration's kernels and databases
        obs, *_ = env.step(pol.act(obs))
    totals = collections.Counter()
    clock = time.perf_counter
    steps, wall = 0, 0.0
    by_n = {band: np.zeros(4) for band in N_BANDS}  # steps, env, physics, kernels (s)
    with timed_calls(totals):
        for k in range(n_episodes):
            t0 = clock()
            obs, _ = env.reset(seed=k, options={"slew_angle_deg": angle_deg})
            wall += clock() - t0
            done = False
            while not done:
                a = pol.act(obs)
                p0, k0 = totals["physics"], totals["kernels"]
                t0 = clock()
                obs, _, te, tr, info = env.step(a)
                dt = clock() - t0
                wall += dt
                steps += 1
                done = te or tr
                n = info["exposures_per_frame"]
                band = N_BANDS[0] if n == 1 else (N_BANDS[2] if n >= 15 else N_BANDS[1])
                by_n[band] += (1.0, dt, totals["physics"] - p0, totals["kernels"] - k0)
    env.close()
    us = 1e6 / steps
    return {"env": wall * us, "physics": totals["physics"] * us, "kernels": totals["kernels"] * us,
            "rest": (wall - totals["physics"] - totals["kernels"]) * us, "calls": totals["kernel calls"] / steps,
            "by_n": by_n,
            "by_kernel": {k[len("kernel: "):]: v * us for k, v in totals.items() if k.startswith("kernel: ")}}


N_BANDS = ("1", "2-14", ">= 15")
"""Bands of exposures per frame of :func:`step_budget`'s split (at rest, accelerating, near the top rate)."""


def run_vector(kwargs: dict, n_envs: int, n_vec_steps: int, angle_deg: float, max_episode_s: float):
    """Aggregate env steps/s of ``n_envs`` envs in gymnasium's ``AsyncVectorEnv`` (one process each), and the main
    process's CPU time per vector step, µs (unpickling and merging the workers' results: less noisy than wall time).

    Every episode is an ``angle_deg`` slew (``slew_angle_deg_range`` fixed), the eigenaxis policy acts per env outside
    the clock, and the steps that only autoreset a finished env are not counted.
    """
    def make():
        return gym.make("startracker/AgileSlew-v0", max_episode_s=max_episode_s,
                        slew_angle_deg_range=(angle_deg, angle_deg), **kwargs)

    vec = gym.vector.AsyncVectorEnv([make] * n_envs)
    template = make()
    pol = EigenaxisSlewPolicy.from_env(template)
    template.close()
    clock = time.perf_counter
    try:
        obs, _ = vec.reset(seed=list(range(n_envs)))
        done = np.zeros(n_envs, dtype=bool)
        steps, wall, cpu = 0, 0.0, 0.0
        for _ in range(n_vec_steps):
            act = np.stack([pol.act(o) for o in gym.vector.utils.iterate(vec.observation_space, obs)])
            t0, c0 = clock(), time.process_time()
            obs, _, te, tr, _ = vec.step(act)
            wall += clock() - t0
            cpu += time.process_time() - c0
            steps += int(np.count_nonzero(~done))  # an env that ended last step only resets in this one
            done = te | tr
    finally:
        vec.close()
    return steps / wall, cpu / n_vec_steps * 1e6


def episodes_in_process(job: tuple) -> float:
    """One worker of :func:`run_processes`: a warm-up episode, then :func:`run_episodes`' steps/s."""
    kwargs, n_episodes, angle_deg, max_episode_s = job
    run_episodes(kwargs, 1, angle_deg, 2.0)  # kernels from the cache (or inherited), databases
    return run_episodes(kwargs, n_episodes, angle_deg, max_episode_s)[0]


def run_processes(kwargs: dict, n_processes: int, n_episodes: int, angle_deg: float, max_episode_s: float) -> float:
    """Aggregate steps/s of ``n_processes`` processes running whole episodes at the same time (the sum of their
    steps/s, each timed as :func:`run_episodes` times it)."""
    with multiprocessing.get_context().Pool(n_processes) as pool:
        rates = pool.map(episodes_in_process, [(kwargs, n_episodes, angle_deg, max_episode_s)] * n_processes)
    return float(sum(rates))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="1 repeat of 1 short episode per row")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--angle-deg", type=float, default=120.0)
    ap.add_argument("--vector-envs", type=int, default=2,
                    help="worker processes of the AsyncVectorEnv throughput row (0: skip it)")
    ap.add_argument("--budget", action="store_true",
                    help="also print where a step's time goes (physics, compiled kernels, the rest) per configuration")
    ap.add_argument("--matchers", action="store_true", help="also print the matcher table (bench_matching)")
    args = ap.parse_args()
    reps, n_ep = (1, 1) if args.quick else (args.repeats, args.episodes)
    max_s = 15.0 if args.quick else 40.0

    results = {}
    new_env = {}
    floor = []
    for name, kw in CONFIGS.items():
        run_episodes(kw, 1, args.angle_deg, 2.0)  # warm-up: imports, databases, compiled kernels
    for _ in range(reps):  # interleaved, so the machine's load hits every row alike
        for name, kw in CONFIGS.items():
            sps, steps, actions, cp, sub, make_s, reset_s, later_s = run_episodes(kw, n_ep, args.angle_deg, max_s)
            results.setdefault(name, []).append((sps, steps))
            new_env.setdefault(name, []).append((make_s, reset_s, later_s))
            if name.startswith("default"):
                floor.append(physics_only(actions, cp, sub))
    floor_sps = float(np.median(floor))
    print(f"AgileSlew-v0, eigenaxis policy, {args.angle_deg:.0f}° slews, 0.1 s control period, 10 Hz frames, "
          f"100 Hz gyro substeps; median of {reps} runs x {n_ep} whole episodes")
    print("| configuration | steps/s (median) | min | max | step time / floor | steps per run | target |")
    print("|---|---|---|---|---|---|---|")
    for name, rows in results.items():
        sps = np.array([r[0] for r in rows])
        med = float(np.median(sps))
        print(f"| {name} | {med:.0f} | {sps.min():.0f} | {sps.max():.0f} | {floor_sps / med:.2f} | {rows[0][1]} | "
              f"{TARGETS.get(name, '')} |")
    print(f"| physics-only floor (same Spacecraft, same actions, same substeps) | {floor_sps:.0f} | "
          f"{min(floor):.0f} | {max(floor):.0f} | 1.00 | | |")
    print()
    print("A new env in a warm process (each run above makes its own; its first reset is in the steps/s), ms, median "
          f"of {reps}")
    print("| configuration | gym.make | first reset | a later reset |")
    print("|---|---|---|---|")
    for name, rows in new_env.items():
        ms = [1e3 * float(np.median([r[i] for r in rows])) for i in range(3)]
        print(f"| {name} | {ms[0]:.1f} | {ms[1]:.1f} | {ms[2]:.1f} |")
    if args.vector_envs > 0:
        n_vec = args.vector_envs
        one_env = float(np.median([r[0] for r in results["default (centroid, multi-exposure)"]]))
        run_vector({}, n_vec, 5, args.angle_deg, 2.0)  # warm-up: worker start, imports, kernels from the cache
        n_vs = 60 if args.quick else 300
        vec_runs = {"every info key": [], f"info_keys = {len(LEAN_INFO_KEYS)} reward keys": []}
        for _ in range(reps):  # the two kinds alternate, so that both see the same moments of the machine
            vec_runs["every info key"].append(run_vector({}, n_vec, n_vs, args.angle_deg, max_s))
            vec_runs[f"info_keys = {len(LEAN_INFO_KEYS)} reward keys"].append(
                run_vector({"info_keys": LEAN_INFO_KEYS}, n_vec, n_vs, args.angle_deg, max_s))
        print()
        print(f"Throughput on several cores: the default env in gymnasium's AsyncVectorEnv, {n_vec} worker processes, "
              f"{args.angle_deg:.0f}° slews back to back, median of {reps} runs of {n_vs} vector steps, with every "
              f"info key and with info_keys={LEAN_INFO_KEYS} (runs alternating), with the main process's CPU per "
              f"vector step (unpickling and merging the infos); and {n_vec} processes each running {n_ep} whole "
              f"episodes at once, median of {reps} runs")
        proc_sps = [run_processes({}, n_vec, n_ep, args.angle_deg, max_s) for _ in range(reps)]
        med_p = float(np.median(proc_sps))
        print("| configuration | aggregate env steps/s (median) | min | max | per env | vs one env (default row) "
              "| main process CPU per vector step, µs |")
        print("|---|---|---|---|---|---|---|")
        for label, runs in vec_runs.items():
            sps = [r[0] for r in runs]
            med = float(np.median(sps))
            print(f"| default, AsyncVectorEnv x {n_vec}, {label} | {med:.0f} | {min(sps):.0f} | {max(sps):.0f} | "
                  f"{med / n_vec:.0f} | {med / one_env:.2f} | {np.median([r[1] for r in runs]):.0f} |")
        print(f"| default, {n_vec} processes of whole episodes | {med_p:.0f} | {min(proc_sps):.0f} | "
              f"{max(proc_sps):.0f} | {med_p / n_vec:.0f} | {med_p / one_env:.2f} | — |")
    if args.budget:
        budgets = {name: [step_budget(kw, n_ep, args.angle_deg, max_s) for _ in range(reps)]
                   for name, kw in CONFIGS.items()}
        print()
        print(f"Where a step goes (µs per step, median of {reps} runs x {n_ep} whole episodes; kernels: every compiled "
              "call from Python, dispatch included; the timers add ~0.3 µs per kernel call to the rest)")
        print("| configuration | env | physics | compiled kernels | kernel calls per step | the rest (Python, numpy, draws) "
              "| kernels / physics | steps/s with no Python (physics + kernels) |")
        print("|---|---|---|---|---|---|---|---|")
        for name, runs in budgets.items():
            med = {key: float(np.median([r[key] for r in runs])) for key in runs[0] if not key.startswith("by_")}
            print(f"| {name} | {med['env']:.0f} | {med['physics']:.0f} | {med['kernels']:.0f} | {med['calls']:.1f} | "
                  f"{med['rest']:.0f} | {med['kernels'] / med['physics']:.2f} | "
                  f"{1e6 / (med['physics'] + med['kernels']):.0f} |")
        print()
        print("The same steps by the exposures per frame N of the step's frame (the paper 000 rule: N = 1 at rest, ~21 at "
              f"20°/s), µs per step, median of {reps} runs")
        print("| configuration | N | share of steps | share of time | env | physics | compiled kernels | the rest |")
        print("|---|---|---|---|---|---|---|---|")
        for name, runs in budgets.items():
            for band in N_BANDS:
                rows = [r["by_n"][band] for r in runs]
                if min(row[0] for row in rows) == 0:
                    continue
                steps_share = np.median([row[0] / sum(r["by_n"][b][0] for b in N_BANDS) for row, r in zip(rows, runs)])
                time_share = np.median([row[1] / sum(r["by_n"][b][1] for b in N_BANDS) for row, r in zip(rows, runs)])
                env_us, phys_us, kern_us = (float(np.median([1e6 * row[i] / row[0] for row in rows])) for i in (1, 2, 3))
                rest_us = float(np.median([1e6 * (row[1] - row[2] - row[3]) / row[0] for row in rows]))
                print(f"| {name} | {band} | {100 * steps_share:.0f} % | {100 * time_share:.0f} % | {env_us:.0f} | "
                      f"{phys_us:.0f} | {kern_us:.0f} | {rest_us:.0f} |")
        print()
        print(f"The largest compiled kernels, µs per step over whole episodes (median of {reps} runs; a kernel's time "
              "includes the compiled calls it makes)")
        print("| configuration | first | second | third | fourth |")
        print("|---|---|---|---|---|")
        for name, runs in budgets.items():
            names = set().union(*(r["by_kernel"] for r in runs))
            per = {k: float(np.median([r["by_kernel"].get(k, 0.0) for r in runs])) for k in names}
            top = sorted(per.items(), key=lambda kv: -kv[1])[:4]
            print(f"| {name} | " + " | ".join(f"`{k}` {v:.0f}" for k, v in top) + " |")
    if args.matchers:
        import bench_matching

        print()
        bench_matching.main(["--quick"] if args.quick else [])


if __name__ == "__main__":
    main()
