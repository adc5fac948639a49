"""The array kernels: the arithmetic of the per-frame path, one module per room.

A kernel is a plain, public function on float64 arrays of documented shapes and units. It checks nothing: the
public API of each room (``startracker.rotations``, ``startracker.track``, ...) validates its arguments once and then
calls the kernel; code that has already validated (the star tracker, the env) calls the kernel directly. Kernels
never draw random numbers: a stochastic step receives its draws from the caller's ``numpy.random.Generator``.
Where a kernel is on the per-frame hot path it is compiled with numba (``@njit(cache=True, no_cfunc_wrapper=True)``:
nothing takes a kernel's C-callback address, and that wrapper is a few percent of the first compilation); a private
helper that only compiled code calls also gets ``no_cpython_wrapper=True`` (calling it from Python would crash the
interpreter, which is why only underscore names, never called from Python, get it). The others are vectorised
numpy. ``docs/design.md`` ("Validation and kernels") says how to add one.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import numba

__all__ = ["KERNEL_SOURCES_DIGEST", "KernelCompileWarning", "kernel_cache_dir", "kernel_cache_is_empty"]


class KernelCompileWarning(UserWarning):
    """Issued once, at import, when no compiled kernel is cached yet: this process compiles them on first use.

    Silence it with ``warnings.simplefilter("ignore", KernelCompileWarning)`` before importing the package.
    """


def _sources_digest() -> str:
    """SHA-1 of every kernel module's source, in name order (16 hex digits)."""
    h = hashlib.sha1()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


KERNEL_SOURCES_DIGEST = _sources_digest()


def kernel_cache_dir() -> Path:
    """Where numba keeps the compiled kernels: a folder named by :data:`KERNEL_SOURCES_DIGEST`.

    Numba checks a cached function against its own source file only, not against the kernels it calls in other
    modules: after an edit of ``kernels/attitude.py`` a cached ``kernels/track.py`` function would keep running the
    old Wahba code. Keying the whole cache by the digest of all kernel sources makes any edit recompile everything
    once. The folder is ``$NUMBA_CACHE_DIR/startracker-<digest>`` when the user sets ``NUMBA_CACHE_DIR``, else
    ``kernels/__pycache__/numba-<digest>`` beside the code when that is writable, else
    ``$XDG_CACHE_HOME/startracker-gym/numba-<digest>`` (``~/.cache`` by default) for a read-only install.

    Numba has one cache folder per process (``numba.config.CACHE_DIR``): importing the kernels sets it, so other
    ``cache=True`` functions compiled later in the same process are cached there too (each under its own source
    path; nothing is shared or overwritten).
    """
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        return Path(user) / f"startracker-{KERNEL_SOURCES_DIGEST}"
    beside = Path(__file__).parent / "__pycache__"
    try:
        beside.mkdir(exist_ok=True)
        if os.access(beside, os.W_OK):
            return beside / f"numba-{KERNEL_SOURCES_DIGEST}"
    except OSError:
        pass
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "startracker-gym" / f"numba-{KERNEL_SOURCES_DIGEST}"


def kernel_cache_is_empty(folder: Path | None = None) -> bool:
    """True when ``folder`` (default :func:`kernel_cache_dir`) holds no compiled kernel (numba's ``*.nbi`` index
    files): a fresh install, or the first run after an edit of any kernel source."""
    folder = kernel_cache_dir() if folder is None else Path(folder)
    return not any(folder.rglob("*.nbi")) if folder.is_dir() else True


# Set before any kernel module is imported (they import this package first), so every @njit(cache=True) below
# writes to and reads from the digest-keyed folder.
numba.config.CACHE_DIR = str(kernel_cache_dir())
# A first use compiles for one to two minutes with no output of its own: say so once, where it starts.
if not numba.config.DISABLE_JIT and kernel_cache_is_empty():
    warnings.warn(f"startracker-gym: no compiled kernels cached in {numba.config.CACHE_DIR} yet; this process compiles "
                  "them as they are first used (one to two minutes of CPU in all, once; later processes load them from "
                  "the cache in seconds). `startracker-gym compile` compiles them ahead, in parallel processes",
                  KernelCompileWarning, stacklevel=2)
