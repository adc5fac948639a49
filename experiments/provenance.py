"""Where a result came from: package version, source revision, a digest of the code, and the resume key.

A campaign reuses a finished run only when its key (settings, seed, resolved env configuration, package version,
code digest, agent-benchmark version) equals the key the same run would get now, so a code change or a changed
default never resumes from stale runs.
"""

from __future__ import annotations

import functools
import hashlib
import json
import platform
import subprocess
from pathlib import Path

__all__ = ["PACKAGES", "package_version", "source_revision", "code_digest", "provenance", "run_key", "key_differences"]

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("startracker", "envs", "policies", "experiments")
# fields of a run record that decide whether it may be reused
KEY_FIELDS = ("settings", "seed", "env_id", "env_config", "package_version", "code_sha1", "benchmark_version")


@functools.lru_cache(maxsize=1)
def package_version() -> str:
    """The installed distribution's version, or ``"unknown"`` when running from a checkout that is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("startracker-gym")
    except PackageNotFoundError:
        return "unknown"


@functools.lru_cache(maxsize=1)
def source_revision() -> str | None:
    """``git`` commit of the source checkout (``+dirty`` when its code differs from it), None outside a checkout."""
    if not (ROOT / ".git").exists():
        return None
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10)
        if rev.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--", *PACKAGES], cwd=ROOT, capture_output=True,
                               text=True, timeout=10)
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-1 over every ``.py`` file of the four packages as imported (path and bytes): changes with any code edit,
    committed or not, in a checkout or an installed copy."""
    h = hashlib.sha1()
    for pkg in PACKAGES:
        base = ROOT / pkg
        for p in sorted(base.rglob("*.py")):
            h.update(str(p.relative_to(ROOT)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def provenance() -> dict:
    """Versions of this code and of the numerical stack, for run files and summaries."""
    import numpy
    import scipy

    from experiments.agent_benchmark import BENCHMARK_VERSION

    try:
        import mujoco

        mujoco_version = mujoco.__version__
    except ImportError:  # pragma: no cover - a hard dependency
        mujoco_version = None
    return {
        "package_version": package_version(),
        "source_revision": source_revision(),
        "code_sha1": code_digest(),
        "benchmark_version": BENCHMARK_VERSION,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "mujoco": mujoco_version,
    }


def run_key(record: dict) -> str:
    """SHA-1 of a run record's :data:`KEY_FIELDS` (canonical JSON)."""
    blob = json.dumps({k: record.get(k) for k in KEY_FIELDS}, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha1(blob.encode()).hexdigest()


def key_differences(old: dict, new: dict) -> list[str]:
    """The key fields on which two records differ, e.g. ``["code_sha1", "env_config.camera"]``."""
    out = []
    for k in KEY_FIELDS:
        a, b = old.get(k), new.get(k)
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            out += [f"{k}.{kk}" for kk in sorted(set(a) | set(b)) if a.get(kk) != b.get(kk)]
        else:
            out.append(k)
    return out
