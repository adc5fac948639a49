"""Compiling the kernels ahead of use (startracker.compilation, ``startracker-gym compile``)."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from numba.core import types

from startracker.compilation import SIGNATURES_PATH, compile_kernels, load_signatures, text_to_type, type_to_text

REPO = Path(__file__).resolve().parents[1]

TYPES = [
    types.Array(types.float64, 2, "C"), types.Array(types.float64, 1, "A"), types.Array(types.int64, 3, "F"),
    types.Array(types.boolean, 1, "C"), types.Array(types.float64, 2, "C", readonly=True), types.float64,
    types.int64, types.int32, types.uint64, types.boolean, types.UniTuple(types.float64, 3),
    types.Tuple((types.int64, types.Array(types.float64, 1, "C"))), types.literal(True), types.literal(3), types.none,
]


@pytest.mark.parametrize("t", TYPES, ids=str)
def test_type_text_round_trip(t):
    text = type_to_text(t)
    assert text_to_type(text) == t


def test_type_text_refuses_what_it_cannot_write_or_read():
    with pytest.raises(TypeError, match="t: no text form"):
        type_to_text(types.unicode_type)
    with pytest.raises(ValueError, match="text: not a numba type form"):
        text_to_type("Array(float64, 2")
    with pytest.raises(ValueError, match="text: not a numba type form"):
        text_to_type("__import__('os')")  # no builtins in the namespace
    with pytest.raises(ValueError, match="is not a numba type"):
        text_to_type("3")


def test_recorded_list_names_existing_kernels_in_callee_order():
    import importlib

    entries = load_signatures()
    assert len(entries) > 100
    for i, e in enumerate(entries):
        disp = getattr(importlib.import_module(e.module), e.name)
        sig = tuple(text_to_type(a) for a in e.args)
        assert len(sig) == disp.py_func.__code__.co_argcount, e  # the arguments of the kernel as it is now
        assert all(j < i for j in e.after)


def test_load_signatures_refuses_a_caller_listed_before_its_callee(tmp_path):
    path = tmp_path / "sigs.json"
    rows = [{"module": "m", "name": "a", "args": [], "compile_s": 0.1, "after": [1]},
            {"module": "m", "name": "b", "args": [], "compile_s": 0.1, "after": []}]
    path.write_text(json.dumps({"signatures": rows}))
    with pytest.raises(ValueError, match="must come after its callees"):
        load_signatures(path)
    path.write_text("{}")
    with pytest.raises(ValueError, match="not a kernel signature list"):
        load_signatures(path)


@pytest.mark.parametrize("jobs", [0, -1, 1.5, True])
def test_compile_kernels_refuses_bad_jobs(jobs):
    with pytest.raises(ValueError, match="jobs must be a positive integer"):
        compile_kernels(jobs)


def _run(code: str, cache: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(REPO))
    env.pop("NUMBA_DISABLE_JIT", None)
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=REPO, capture_output=True,
                          text=True, timeout=600)


def test_compile_kernels_fills_an_empty_cache_in_worker_processes(tmp_path):
    # a kernel and its callee (recorded order: callee first), and an entry of a kernel that no longer exists,
    # recorded by another workload than the default
    c2 = type_to_text(types.Array(types.float64, 2, "C"))
    c1 = type_to_text(types.Array(types.float64, 1, "C"))
    rows = [{"module": "startracker.kernels.rotations", "name": "normalize_rows", "args": [c2], "compile_s": 0.1,
             "after": [], "workload": "default"},
            {"module": "startracker.kernels.rotations", "name": "pointing_errors", "args": [c1, c1, c1],
             "compile_s": 0.1, "after": [0], "workload": "default"},
            {"module": "startracker.kernels.rotations", "name": "no_such_kernel", "args": [c1], "compile_s": 0.1,
             "after": [], "workload": "pixel fidelity"}]
    sigs = tmp_path / "sigs.json"
    sigs.write_text(json.dumps({"signatures": rows}))

    def run(default_only):
        code = f"""
            import warnings
            warnings.simplefilter("ignore")
            from startracker.compilation import compile_kernels
            from startracker.kernels import kernel_cache_dir
            r = compile_kernels(2, default_only={default_only}, progress=False, path={str(sigs)!r})
            print(r.n_signatures, r.n_compiled, r.n_cached, r.n_stale, r.jobs,
                  sorted(p.name.split("-")[0] for p in kernel_cache_dir().rglob("*.nbi")))
        """
        out = _run(code, tmp_path / "cache")
        assert out.returncode == 0, out.stderr
        return out.stdout

    cold = run(True)  # the default workload's two, in two worker processes
    assert cold.split()[:5] == ["2", "2", "0", "0", "2"]
    assert "rotations.normalize_rows" in cold and "rotations.pointing_errors" in cold
    warm = run(False)  # all three: the two found in the cache the workers wrote, the third stale
    assert warm.split()[:5] == ["3", "0", "2", "1", "2"]


def test_recorded_list_covers_what_a_default_episode_calls(tmp_path):
    # every kernel signature a default episode calls from Python is in the list (loaded from the session's cache,
    # or compiled here if it is cold); a kernel whose arguments changed without re-recording fails here
    code = """
        import warnings, importlib, pkgutil
        warnings.simplefilter("ignore")
        import startracker.kernels as K
        from experiments.episode import run_episode
        from startracker.compilation import type_to_text
        run_episode(env_kwargs={"max_episode_s": 6.0}, reset_options={"slew_angle_deg": 120.0})
        for m in pkgutil.iter_modules(K.__path__):
            mod = importlib.import_module("startracker.kernels." + m.name)
            for disp in vars(mod).values():
                f = getattr(disp, "py_func", None)
                if hasattr(disp, "signatures") and f is not None and f.__module__ == mod.__name__:
                    for sig in disp.signatures:
                        print(f.__module__, f.__name__, "|".join(type_to_text(t) for t in sig))
    """
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("NUMBA_DISABLE_JIT", None)
    run = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=REPO, capture_output=True,
                         text=True, timeout=900)
    assert run.returncode == 0, run.stderr
    called = {tuple(line.split(" ", 2)) for line in run.stdout.splitlines()}
    recorded = {(e.module, e.name, "|".join(e.args)) for e in load_signatures()}
    assert len(called) >= 20
    missing = called - recorded
    assert not missing, (f"re-record with scripts/record_kernel_signatures.py; not in {SIGNATURES_PATH.name}: "
                         f"{sorted(missing)[:3]}")
