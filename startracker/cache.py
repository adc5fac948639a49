"""On-disk cache of databases (arrays) built once per (catalog, camera): atomic, pickle-free, verified.

A cache entry is one ``.npz`` file named by the SHA-256 of its key (the parameters that determine the
database, including a format version). It holds the arrays plus two extra entries: the key itself and a
SHA-256 checksum of every array's bytes, dtype and shape. Loading uses ``allow_pickle=False`` and checks both;
a corrupt, truncated, stale (other key or version) or unreadable file is reported, deleted and rebuilt, never
trusted. Files are written to a temporary name in the same folder and renamed into place, so a crash never
leaves a half-written entry under the real name.

The folder is ``$STARTRACKER_CACHE_DIR`` if set, else ``~/.cache/startracker-gym``; set the variable to an empty
string to disable the disk cache (in-memory caches still apply).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "load_or_build", "key_digest", "CacheStats", "STATS"]

_KEY_ENTRY = "__cache_key__"
_SUM_ENTRY = "__cache_checksum__"


class CacheStats:
    """Counters of this process: hits, builds and rejected (corrupt or stale) files."""

    def __init__(self):
        self.hits = 0
        self.builds = 0
        self.rejected = 0

    def __repr__(self):
        return f"CacheStats(hits={self.hits}, builds={self.builds}, rejected={self.rejected})"


STATS = CacheStats()


def cache_dir() -> Path | None:
    """The cache folder, or None when disabled (``STARTRACKER_CACHE_DIR=""``)."""
    env = os.environ.get("STARTRACKER_CACHE_DIR")
    if env is not None:
        return Path(env) if env.strip() else None
    return Path.home() / ".cache" / "startracker-gym"


def key_digest(key: dict) -> str:
    """SHA-256 of a JSON-serialisable key (sorted), hex."""
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


def _checksum(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _validate_arrays(arrays) -> dict[str, np.ndarray]:
    if not isinstance(arrays, dict) or not arrays:
        raise TypeError("build() must return a non-empty dict of numpy arrays")
    out = {}
    for k, v in arrays.items():
        a = np.asarray(v)
        if a.dtype == object:
            raise TypeError(f"array {k!r} has dtype object: the cache stores plain arrays only (no pickle)")
        if k in (_KEY_ENTRY, _SUM_ENTRY):
            raise ValueError(f"array name {k!r} is reserved")
        out[k] = a
    return out


def _read(path: Path, key_text: str) -> dict[str, np.ndarray] | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            if _KEY_ENTRY not in z.files or _SUM_ENTRY not in z.files:
                return None
            if str(z[_KEY_ENTRY]) != key_text:
                return None  # stale: another version or parameters hashed to this name
            arrays = {k: z[k] for k in z.files if k not in (_KEY_ENTRY, _SUM_ENTRY)}
            if _checksum(arrays) != str(z[_SUM_ENTRY]):
                return None
            return arrays
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None


def _write_atomic(path: Path, arrays: dict[str, np.ndarray], key_text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp.npz")
    os.close(fd)
    try:
        payload = dict(arrays)
        payload[_KEY_ENTRY] = np.array(key_text)
        payload[_SUM_ENTRY] = np.array(_checksum(arrays))
        np.savez(tmp, **payload)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def load_or_build(key: dict, build, folder: Path | None = None) -> dict[str, np.ndarray]:
    """The arrays cached under ``key``, building and storing them on a miss.

    Parameters
    ----------
    key : dict
        JSON-serialisable description of everything the arrays depend on, including a format version
        (e.g. ``{"kind": "pair-catalog", "version": 3, "catalog": ..., "camera": ...}``).
    build : callable () -> dict[str, ndarray]
        Builds the arrays (numeric or string dtypes; no objects).
    folder : Path, optional
        Overrides :func:`cache_dir` (tests).

    Returns
    -------
    dict[str, ndarray]
    """
    if not isinstance(key, dict) or not key:
        raise TypeError("key must be a non-empty dict")
    folder = cache_dir() if folder is None else Path(folder)
    key_text = json.dumps(key, sort_keys=True, default=str)
    if folder is None:
        STATS.builds += 1
        return _validate_arrays(build())
    path = folder / f"{key_digest(key)}.npz"
    if path.exists():
        arrays = _read(path, key_text)
        if arrays is not None:
            STATS.hits += 1
            return arrays
        STATS.rejected += 1
        try:
            path.unlink()
        except OSError:
            pass
    arrays = _validate_arrays(build())
    STATS.builds += 1
    try:
        _write_atomic(path, arrays, key_text)
    except OSError:
        pass  # a read-only or full disk only costs the rebuild next time
    return arrays
