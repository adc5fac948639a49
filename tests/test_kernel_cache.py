"""The compiled kernels' on-disk cache: one folder per version of the kernel sources, and a notice when it is empty."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from startracker.kernels import KERNEL_SOURCES_DIGEST, kernel_cache_dir, kernel_cache_is_empty

REPO = Path(__file__).resolve().parents[1]


def _import_kernels(cache_root: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_root), PYTHONPATH=str(REPO))
    env.pop("NUMBA_DISABLE_JIT", None)
    code = "import startracker.kernels as k; print(k.kernel_cache_dir())"
    return subprocess.run([sys.executable, "-W", "default", "-c", code], env=env, cwd=REPO, capture_output=True,
                          text=True, timeout=120)


def test_cache_folder_is_named_by_the_sources_digest(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert kernel_cache_dir() == tmp_path / f"startracker-{KERNEL_SOURCES_DIGEST}"
    assert len(KERNEL_SOURCES_DIGEST) == 16 and int(KERNEL_SOURCES_DIGEST, 16) >= 0


def test_empty_cache_is_announced_once_and_a_filled_one_is_not(tmp_path):
    cold = _import_kernels(tmp_path)
    assert cold.returncode == 0, cold.stderr
    folder = Path(cold.stdout.strip())
    assert folder == tmp_path / f"startracker-{KERNEL_SOURCES_DIGEST}"
    assert cold.stderr.count("KernelCompileWarning") == 1 and "compiles" in cold.stderr
    assert kernel_cache_is_empty(folder)
    # numba writes an index file (*.nbi) per cached function, in a subfolder per source folder
    (folder / "kernels_0").mkdir(parents=True)
    (folder / "kernels_0" / "rotations.quat_multiply-1.py311.nbi").write_bytes(b"")
    assert not kernel_cache_is_empty(folder)
    warm = _import_kernels(tmp_path)
    assert warm.returncode == 0, warm.stderr
    assert "KernelCompileWarning" not in warm.stderr


@pytest.mark.parametrize("name", ["missing", "empty"])
def test_missing_or_empty_folder_counts_as_empty(tmp_path, name):
    folder = tmp_path / "cache"
    if name == "empty":
        folder.mkdir()
    assert kernel_cache_is_empty(folder)
