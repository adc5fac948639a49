"""On-disk cache of databases (arrays) built once per (catalog, camera): atomic, pickle-free, verified.

A cache entry is one file named by the SHA-256 of its key (the parameters that determine the database,
including a format version). Layout: a magic line, the length of a JSON header, the header (the key,
each array's name, dtype, shape and offset, and the SHA-256 of the payload), then the arrays' raw bytes
(little-endian, 64-byte aligned). Loading reads the file once, checks the magic, the key and the checksum,
and views the arrays in the payload (no copy, no pickle: dtypes are plain numeric or fixed-width strings).
A corrupt, truncated, stale (other key or version) or unreadable file is reported, deleted and rebuilt,
never trusted. Files are written to a temporary name in the same folder and renamed into place, so a
crash never leaves a half-written entry under the real name.

The folder is ``$STARTRACKER_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/startracker-gym``, else
``~/.cache/startracker-gym``; set ``STARTRACKER_CACHE_DIR`` to an empty string to disable the disk cache
(in-memory caches still apply). Used by :func:`startracker.identify.build_database`.
"""

from __future__ import annotations

import hashlib
import json
import mmap
import os
import struct
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "load_or_build", "key_digest", "entry_path", "CacheStats", "STATS"]

_MAGIC = b"STARTRACKER-CACHE 2\n"
_ALIGN = 64
_RESERVED = ("__cache_key__", "__cache_checksum__")


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
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    if xdg:
        return Path(xdg) / "startracker-gym"
    return Path.home() / ".cache" / "startracker-gym"


def key_digest(key: dict) -> str:
    """SHA-256 of a JSON-serialisable key (sorted), hex."""
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


def entry_path(key: dict, folder: Path | None = None) -> Path | None:
    """File of the entry of ``key`` (None when the disk cache is disabled)."""
    folder = cache_dir() if folder is None else Path(folder)
    return None if folder is None else folder / f"{key_digest(key)}.bin"


def _validate_arrays(arrays) -> dict[str, np.ndarray]:
    if not isinstance(arrays, dict) or not arrays:
        raise TypeError("build() must return a non-empty dict of numpy arrays")
    out = {}
    for k, v in arrays.items():
        a = np.asarray(v)
        if a.dtype == object or a.dtype.kind not in "biufcSU":
            raise TypeError(f"array {k!r} has dtype {a.dtype}: the cache stores plain numeric or string arrays only (no pickle)")
        if k in _RESERVED:
            raise ValueError(f"array name {k!r} is reserved")
        out[k] = a if a.flags.c_contiguous else a.copy(order="C")
    return out


def _layout(arrays: dict[str, np.ndarray]) -> tuple[list, int]:
    entries = []
    off = 0
    for name in sorted(arrays):
        a = arrays[name]
        dt = a.dtype.newbyteorder("<") if a.dtype.byteorder not in ("|", "<", "=") else a.dtype
        entries.append({"name": name, "dtype": dt.str, "shape": list(a.shape), "offset": off, "nbytes": a.nbytes})
        off += (a.nbytes + _ALIGN - 1) // _ALIGN * _ALIGN
    return entries, off


def _read(path: Path, key_text: str) -> dict[str, np.ndarray] | None:
    try:
        with open(path, "rb") as fh:
            # A read-only map: the arrays are views of the page cache, no copy (the map outlives a
            # later replacement of the file, which gets a new inode).
            raw = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError):
        return None
    try:
        if len(raw) < len(_MAGIC) + 8 or raw[: len(_MAGIC)] != _MAGIC:
            return None
        (hlen,) = struct.unpack_from("<Q", raw, len(_MAGIC))
        start = len(_MAGIC) + 8
        header = json.loads(raw[start : start + hlen].decode())
        if header.get("key") != key_text:
            return None  # stale: another version or parameters hashed to this name
        base = (start + hlen + _ALIGN - 1) // _ALIGN * _ALIGN
        payload = memoryview(raw)[base:]
        if len(payload) != header["payload_bytes"] or hashlib.sha256(payload).hexdigest() != header["sha256"]:
            return None
        out = {}
        for e in header["arrays"]:
            dt = np.dtype(e["dtype"])
            if dt.kind not in "biufcSU":
                return None
            count = int(np.prod(e["shape"], dtype=np.int64))
            a = np.frombuffer(raw, dtype=dt, count=count, offset=base + e["offset"]).reshape(tuple(e["shape"]))
            out[e["name"]] = a
        return out
    except (ValueError, KeyError, TypeError, struct.error, UnicodeDecodeError):
        return None


def _write_atomic(path: Path, arrays: dict[str, np.ndarray], key_text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    entries, total = _layout(arrays)
    payload = bytearray(total)
    for e in entries:
        a = arrays[e["name"]]
        payload[e["offset"] : e["offset"] + e["nbytes"]] = a.astype(np.dtype(e["dtype"]), copy=False).tobytes()
    header = json.dumps({"key": key_text, "arrays": entries, "payload_bytes": total,
                         "sha256": hashlib.sha256(payload).hexdigest()}).encode()
    start = len(_MAGIC) + 8
    base = (start + len(header) + _ALIGN - 1) // _ALIGN * _ALIGN
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(_MAGIC + struct.pack("<Q", len(header)) + header + b"\0" * (base - start - len(header)))
            fh.write(payload)
            fh.flush()
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
    path = entry_path(key, folder)
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
