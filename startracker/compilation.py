"""Compiling the kernel layer ahead of use, in parallel (``startracker-gym compile``).

Numba compiles a kernel the first time it is called, in the process that calls it, one kernel after another: a
default env's first episode on a fresh machine spends one to two minutes of CPU there (``KernelCompileWarning``).
:func:`compile_kernels` does the same work ahead of time in ``jobs`` worker processes, into the same on-disk cache
(:func:`startracker.kernels.kernel_cache_dir`), so that the env's first episode only loads them.

It needs to know which signatures to compile: numba types a kernel by the arguments of its first call. The list is
``startracker/data/kernel_signatures.json``, written by ``scripts/record_kernel_signatures.py`` from the env's own
episodes on an empty cache (the default env, then the other configurations of ``benchmarks/bench_env_speed.py`` and
the faults): every signature any of them compiled, callees before their callers, with the seconds it took. Each
worker takes the next signature as soon as it finishes one; a kernel starts only once the callees it compiled when
recorded are cached (otherwise its worker would compile them a second time). Numba writes its cache files to a
temporary name and renames them, so two workers writing one entry is safe.

A signature the list lacks still compiles on first use, as before; a stale entry (a kernel renamed or retyped since
the list was recorded) is skipped and counted. ``tests/test_compilation.py`` checks that the list covers what a
default episode calls.

Types are stored as text that evaluates to the numba type in the namespace of ``numba.core.types``
(``Array(float64, 2, 'C')``, ``UniTuple(int64, 3)``, ``literal(True)``): readable, and independent of pickle.
"""

from __future__ import annotations

import heapq
import importlib
import json
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import NamedTuple

__all__ = ["KernelSignature", "CompileReport", "SIGNATURES_PATH", "load_signatures", "compile_kernels",
           "type_to_text", "text_to_type", "default_jobs"]

SIGNATURES_PATH = Path(__file__).parent / "data" / "kernel_signatures.json"


class KernelSignature(NamedTuple):
    """One compiled signature of one kernel.

    Attributes
    ----------
    module : str
        The kernel's module (``startracker.kernels.track``).
    name : str
        The kernel's name in it.
    args : tuple of str
        Its argument types as text (:func:`type_to_text`).
    compile_s : float
        Seconds its compilation took when recorded, excluding the callees it compiled (for the record only).
    after : tuple of int
        Indices (into the list) of the kernels it compiled as its callees when recorded: it starts once they are
        cached, so that no two workers compile the same callee.
    workload : str
        The first recorded workload that compiled it ("default": the default env; "pixel fidelity", ...).
    """

    module: str
    name: str
    args: tuple
    compile_s: float
    after: tuple = ()
    workload: str = "default"


@dataclass(frozen=True)
class CompileReport:
    """What :func:`compile_kernels` did.

    Attributes
    ----------
    n_signatures : int
        Signatures in the list.
    n_compiled : int
        Compiled now (not found in the cache).
    n_cached : int
        Already in the cache.
    n_stale : int
        Skipped: the kernel no longer exists, or its argument types no longer fit it.
    jobs : int
        Worker processes used (1: this process; 0: none, numba's JIT is disabled).
    wall_s : float
        Wall-clock time, s.
    cache_dir : str
        The cache folder.
    """

    n_signatures: int
    n_compiled: int
    n_cached: int
    n_stale: int
    jobs: int
    wall_s: float
    cache_dir: str


def type_to_text(t) -> str:
    """A numba type as text that :func:`text_to_type` turns back into it.

    Parameters
    ----------
    t : numba.core.types.Type
        An array, number, boolean, tuple, literal or none type (what the kernels take).

    Returns
    -------
    str

    Raises
    ------
    TypeError
        For any other kind of type.
    """
    from numba.core import types

    if isinstance(t, types.Array):
        ro = "" if t.mutable else ", readonly=True"
        return f"Array({type_to_text(t.dtype)}, {t.ndim}, {t.layout!r}{ro})"
    if isinstance(t, types.Literal):
        return f"literal({t.literal_value!r})"
    if isinstance(t, types.Boolean):
        return "boolean"
    if isinstance(t, (types.Integer, types.Float)):
        return str(t)
    if isinstance(t, types.UniTuple):
        return f"UniTuple({type_to_text(t.dtype)}, {t.count})"
    if isinstance(t, types.Tuple):
        return "Tuple((" + "".join(type_to_text(x) + ", " for x in t.types) + "))"
    if isinstance(t, types.NoneType):
        return "none"
    raise TypeError(f"t: no text form for the numba type {t!r} ({type(t).__name__})")


def text_to_type(text: str):
    """The numba type that :func:`type_to_text` wrote as ``text``.

    Parameters
    ----------
    text : str

    Returns
    -------
    numba.core.types.Type

    Raises
    ------
    TypeError
        If ``text`` is not a str.
    ValueError
        If ``text`` is not such a form.
    """
    from numba.core import types

    if not isinstance(text, str):
        raise TypeError(f"text must be a str, got {type(text).__name__}")
    try:
        t = eval(text, {"__builtins__": {}}, vars(types))  # names of numba.core.types only, no builtins
    except Exception as exc:
        raise ValueError(f"text: not a numba type form: {text!r} ({exc})") from None
    if not isinstance(t, types.Type):
        raise ValueError(f"text: {text!r} is not a numba type")
    return t


def load_signatures(path: str | os.PathLike | None = None) -> list[KernelSignature]:
    """The recorded signatures, in their compile order (callees first).

    Parameters
    ----------
    path : path-like, optional
        The JSON list (default :data:`SIGNATURES_PATH`).

    Returns
    -------
    list of KernelSignature
    """
    path = SIGNATURES_PATH if path is None else Path(path)
    try:
        doc = json.loads(Path(path).read_text())
        rows = doc["signatures"]
        out = [KernelSignature(r["module"], r["name"], tuple(r["args"]), float(r["compile_s"]),
                               tuple(int(i) for i in r.get("after", ())), str(r.get("workload", "default")))
               for r in rows]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"path: {path} is not a kernel signature list ({exc})") from None
    for i, e in enumerate(out):
        if any(not 0 <= j < i for j in e.after):
            raise ValueError(f"path: {path}: entry {i} ({e.name}) must come after its callees {list(e.after)}")
    return out


def default_jobs() -> int:
    """The CPUs this process may run on (``os.sched_getaffinity``, else ``os.cpu_count()``), at least 1."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


def _compile_one(module: str, name: str, args: tuple) -> tuple[str, str]:
    """Compile one signature in this process: ``("compiled" | "cached" | "stale", detail)``."""
    try:
        disp = getattr(importlib.import_module(module), name)
        sig = tuple(text_to_type(a) for a in args)
    except (ImportError, AttributeError, ValueError) as exc:
        return "stale", f"{module}.{name}: {exc}"
    if not hasattr(disp, "compile") or not hasattr(disp, "stats"):
        return "stale", f"{module}.{name} is no longer a compiled kernel"
    if sig in disp.overloads:
        return "cached", ""
    misses = sum(disp.stats.cache_misses.values())
    try:
        disp.compile(sig)
    except Exception as exc:  # numba's typing errors: the kernel changed since the list was recorded
        return "stale", f"{module}.{name}{sig}: {type(exc).__name__}"
    return ("compiled" if sum(disp.stats.cache_misses.values()) > misses else "cached"), ""


def _worker_init():
    import warnings

    # each worker would otherwise repeat the parent's notice of an empty cache
    warnings.filterwarnings("ignore", message="startracker-gym: no compiled kernels")


def compile_kernels(jobs: int | None = None, *, default_only: bool = False, progress: bool | None = None,
                    path: str | os.PathLike | None = None) -> CompileReport:
    """Compile every recorded kernel signature into the on-disk cache, in ``jobs`` processes.

    Signatures already cached load in milliseconds, so a second call is quick (a few seconds, mostly starting the
    workers). With ``NUMBA_DISABLE_JIT`` set there is nothing to compile.

    Parameters
    ----------
    jobs : int, optional
        Worker processes (default :func:`default_jobs`); 1 compiles in this process.
    default_only : bool
        Only the default env's signatures (those its recorded workload "default" compiled): what a first default
        episode and ``startracker-gym slew``'s frame render need, most of the work. The others still compile on
        first use.
    progress : bool, optional
        A progress line on stderr (default: when stderr is a terminal).
    path : path-like, optional
        The signature list (default :data:`SIGNATURES_PATH`).

    Returns
    -------
    CompileReport

    Raises
    ------
    ValueError
        If ``jobs`` is not a positive integer, or the list cannot be read.
    """
    if jobs is None:
        jobs = default_jobs()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs must be a positive integer, got {jobs!r}")
    import numba

    from startracker.kernels import kernel_cache_dir

    entries = load_signatures(path)
    if default_only:
        # the default workload was recorded first: its signatures lead the list, and their callees are among them
        n = sum(e.workload == "default" for e in entries)
        if any(e.workload != "default" for e in entries[:n]):
            raise ValueError(f"path: the default workload's signatures must lead the list {path or SIGNATURES_PATH}")
        entries = entries[:n]
    progress = sys.stderr.isatty() if progress is None else bool(progress)
    t0 = time.perf_counter()
    counts = {"compiled": 0, "cached": 0, "stale": 0}
    stale = []
    if numba.config.DISABLE_JIT:
        return CompileReport(len(entries), 0, 0, 0, 0, 0.0, str(kernel_cache_dir()))
    jobs = min(jobs, max(len(entries), 1))

    def tally(i, outcome):
        counts[outcome[0]] += 1
        if outcome[0] == "stale":
            stale.append(outcome[1])
        if progress:
            print(f"\rcompiling kernels ({jobs} process{'es' if jobs > 1 else ''}): {i}/{len(entries)}, "
                  f"{time.perf_counter() - t0:.0f} s", end="", file=sys.stderr, flush=True)

    if jobs == 1:
        for i, e in enumerate(entries, 1):
            tally(i, _compile_one(e.module, e.name, e.args))
    else:
        # spawn: a fresh interpreter per worker (no fork of a process that may hold compiled state or threads).
        # At most `jobs` tasks in flight, each started once its recorded callees are done: a worker that started a
        # caller early would compile those callees a second time.
        waiting = [len(e.after) for e in entries]
        callers = [[] for _ in entries]
        for i, e in enumerate(entries):
            for j in e.after:
                callers[j].append(i)
        ready = [i for i, n in enumerate(waiting) if n == 0]
        heapq.heapify(ready)
        done = 0
        with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=_worker_init) as pool:
            running = {}
            while ready or running:
                while ready and len(running) < jobs:
                    i = heapq.heappop(ready)  # the list's order among the ready ones
                    e = entries[i]
                    running[pool.submit(_compile_one, e.module, e.name, e.args)] = i
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for f in finished:
                    i = running.pop(f)
                    done += 1
                    tally(done, f.result())
                    for k in callers[i]:
                        waiting[k] -= 1
                        if waiting[k] == 0:
                            heapq.heappush(ready, k)
    if progress:
        print(file=sys.stderr)
    if stale:
        import warnings

        warnings.warn(f"{len(stale)} recorded kernel signature(s) no longer fit the code (they compile on first use "
                      f"instead; re-record with scripts/record_kernel_signatures.py): {stale[0]}", stacklevel=2)
    return CompileReport(len(entries), counts["compiled"], counts["cached"], counts["stale"], jobs,
                         time.perf_counter() - t0, str(kernel_cache_dir()))
