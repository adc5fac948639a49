"""Arrays handed back to Python by the compiled kernels, per env step, by call site.

numba boxes every array a kernel returns (an NRT adaptation and an unpickling of the array's type, ~0.3-0.5 µs
each, against ~0.1 µs for an array passed in): a kernel that hands back its outputs packed by kind (one array per
dtype and shape class, the caller's fields its rows) pays it once per kind. This counts the unpicklings
(``numba.core.serialize._numba_unpickle``, one per boxed array) during whole episodes of the default env, per step,
by the Python line that called the kernel.

    python benchmarks/bench_boxed_arrays.py [--episodes N] [--env-kwargs '{"n_heads": 2}']
"""

from __future__ import annotations

import argparse
import collections
import inspect
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numba.core.serialize as serialize  # noqa: E402

COUNTS = collections.Counter()
COUNTING = [False]
UNPICKLE = serialize._numba_unpickle


def counting_unpickle(*args):
    if COUNTING[0]:
        frame = inspect.currentframe().f_back  # the Python frame that called the kernel
        name = frame.f_code.co_filename
        COUNTS[(str(Path(name).relative_to(ROOT)) if name.startswith(str(ROOT)) else name, frame.f_lineno,
                frame.f_code.co_name)] += 1
    return UNPICKLE(*args)


# installed before any kernel is loaded: compiled code holds the function it finds at load time
serialize._numba_unpickle = counting_unpickle

import gymnasium as gym  # noqa: E402

import envs  # noqa: E402,F401
from policies import EigenaxisSlewPolicy  # noqa: E402


def run(episodes: int, kwargs: dict) -> int:
    steps = 0
    for seed in range(episodes):
        env = gym.make("startracker/AgileSlew-v0", **kwargs)
        policy = EigenaxisSlewPolicy.from_env(env)
        obs, _ = env.reset(seed=seed, options={"slew_angle_deg": 120.0})
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy.act(obs))
            steps += 1
            done = terminated or truncated
    return steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--env-kwargs", default="{}", help="JSON keyword arguments of the env")
    args = parser.parse_args()
    kwargs = json.loads(args.env_kwargs)
    run(1, kwargs)  # compiled kernels loaded, caches warm
    COUNTING[0] = True
    steps = run(args.episodes, kwargs)
    COUNTING[0] = False
    print(f"{steps} steps; boxed arrays per step by call site:")
    for (path, line, func), n in COUNTS.most_common(25):
        print(f"  {n / steps:6.2f}  {path}:{line} ({func})")
    print(f"  total {sum(COUNTS.values()) / steps:.1f} per step")


if __name__ == "__main__":
    main()
