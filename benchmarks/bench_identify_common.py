"""Helpers shared by the ``bench_identify_*.py`` scripts (not a benchmark itself).

``run_method`` identifies a list of synthetic frames (``startracker.simulation``) with one
method and scores every result against the truth: correct, ID failure (no answer), bad match (an answer
with a wrong attitude or a true star mislabelled). Latency is the result's ``latency_ms`` (wall clock);
the identification thread's CPU time is recorded beside it, because the benchmark machine is shared and
wall-clock percentiles then include time spent waiting for a core.
"""

from __future__ import annotations

import platform
import time
from dataclasses import dataclass

import numpy as np

from startracker.identify import identify
from startracker.simulation import count_false_labels, score_result

try:
    from tqdm import tqdm
except ImportError:  # tqdm is a dev dependency; the benchmarks run without it
    def tqdm(it, **_):
        return it


@dataclass
class MethodRun:
    method: str
    n: int
    correct: int
    fail: int
    wrong: int
    false_labelled: int
    latency_ms: np.ndarray
    cpu_ms: np.ndarray
    statuses: dict

    @property
    def success_pct(self) -> float:
        return 100.0 * self.correct / max(self.n, 1)

    def lat(self, q: float) -> float:
        return float(np.percentile(self.latency_ms, q)) if len(self.latency_ms) else float("nan")

    def cpu(self, q: float) -> float:
        return float(np.percentile(self.cpu_ms, q)) if len(self.cpu_ms) else float("nan")


def run_method(method, frames, cam, cat, db, desc=None, **options) -> MethodRun:
    """Identify every frame with ``method``; score each result against the truth."""
    correct = fail = wrong = fl = 0
    lat = np.empty(len(frames))
    cpu = np.empty(len(frames))
    statuses: dict = {}
    for t, f in enumerate(tqdm(frames, desc=desc or method, leave=False, mininterval=1.0)):
        c0 = time.thread_time()
        r = identify(f.xy, cam, cat, method=method, intensities=f.intensities, database=db, **options)
        cpu[t] = (time.thread_time() - c0) * 1e3
        lat[t] = r.latency_ms
        s = score_result(r, f)
        if s == "correct":
            correct += 1
            fl += count_false_labels(r, f)
        elif s == "fail":
            fail += 1
            statuses[r.status] = statuses.get(r.status, 0) + 1
        else:
            wrong += 1
            statuses["WRONG"] = statuses.get("WRONG", 0) + 1
    return MethodRun(method, len(frames), correct, fail, wrong, fl, lat, cpu, statuses)


def machine_line() -> str:
    import os

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, load average {load:.2f}, numpy {np.__version__}"


def print_table(header, rows, title=None):
    """Plain Markdown table."""
    if title:
        print(f"\n{title}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" for _ in header) + "|")
    for r in rows:
        print("| " + " | ".join(str(c) for c in r) + " |")


if __name__ == "__main__":
    print(__doc__)
