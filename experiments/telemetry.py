"""Writing experiment outputs: CSV telemetry, JSON summaries (atomically) and PNG plots."""

from __future__ import annotations

import csv
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["write_atomic", "write_json_atomic", "write_csv", "plot_episode", "to_jsonable"]


def write_atomic(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a temporary file in the same folder, then rename."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def to_jsonable(obj):
    """Plain-Python copy of ``obj`` (numpy scalars and arrays, NaN -> None)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return None if not math.isfinite(f) else f
    return obj


def write_json_atomic(path, obj) -> None:
    write_atomic(path, json.dumps(to_jsonable(obj), indent=2, sort_keys=True) + "\n")


def write_csv(path, rows: list[dict]) -> None:
    """Rows of dicts (same keys) to CSV, atomically."""
    if not rows:
        write_atomic(path, "")
        return
    import io

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0].keys()))
    w.writeheader()
    for r in rows:
        w.writerow({k: to_jsonable(v) for k, v in r.items()})
    write_atomic(path, buf.getvalue())


def plot_episode(out_dir, steps: list[dict], frame: np.ndarray | None = None) -> list[Path]:
    """PNG plots of one episode: pointing and attitude error, rate, update rate, latency; and the star frame.

    Returns the written paths (empty if matplotlib is not installed).
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    out_dir = Path(out_dir)
    t = np.array([r["time_s"] for r in steps])
    written = []
    fig, ax = plt.subplots(4, 1, figsize=(8, 10), sharex=True)
    ax[0].semilogy(t, np.maximum([r["pointing_error_deg"] for r in steps], 1e-6))
    ax[0].set_ylabel("pointing error to target [deg]")
    err = np.array([r["attitude_error_arcsec"] for r in steps])
    modes = np.array([r["tracker_mode"] for r in steps])
    for m, c in (("track", "tab:green"), ("acquire", "tab:orange"), ("lost", "tab:red")):
        sel = modes == m
        ax[1].semilogy(t[sel], np.maximum(err[sel], 1e-3), ".", ms=3, color=c, label=m)
    ax[1].set_ylabel("estimate error [arcsec]")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[2].plot(t, [r["omega_true_norm_deg_s"] for r in steps], label="true")
    ax[2].plot(t, [r["omega_est_norm_deg_s"] for r in steps], "--", label="estimated")
    ax[2].set_ylabel("body rate [deg/s]")
    ax[2].legend(loc="upper right", fontsize=8)
    ax[3].plot(t, [r["update_rate_hz"] for r in steps], label="attitude update rate [Hz]")
    ax3b = ax[3].twinx()
    ax3b.plot(t, [r["matching_latency_ms"] for r in steps], color="tab:purple", lw=0.8)
    ax3b.set_ylabel("matching latency [ms]", color="tab:purple")
    ax[3].set_ylabel("update rate [Hz]")
    ax[3].set_xlabel("time [s]")
    fig.tight_layout()
    p = out_dir / "slew.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    written.append(p)
    if frame is not None:
        fig = plt.figure(figsize=(7, 7))
        plt.imshow(frame)
        plt.axis("off")
        plt.title("last star frame (detections boxed)")
        p = out_dir / "star_frame.png"
        fig.savefig(p, dpi=100, bbox_inches="tight")
        plt.close(fig)
        written.append(p)
    return written
