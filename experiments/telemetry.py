"""Writing experiment outputs: CSV telemetry, JSON summaries (atomically) and PNG plots."""

from __future__ import annotations

import csv
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["write_atomic", "write_json_atomic", "write_csv", "flatten_vectors", "plot_episode", "plot_campaign",
           "to_jsonable", "MODE_COLORS"]

MODE_COLORS = {"lost": "tab:red", "acquire": "tab:orange", "track": "tab:green"}


def _file_mode() -> int:
    """Permissions of a normally created file under the current umask (mkstemp alone gives 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def write_atomic(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a temporary file in the same folder, then rename."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, _file_mode())
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
    if callable(getattr(obj, "to_dict", None)):  # a StarTrackerSpec: its dict form
        return to_jsonable(obj.to_dict())
    return obj


def write_json_atomic(path, obj) -> None:
    write_atomic(path, json.dumps(to_jsonable(obj), indent=2, sort_keys=True) + "\n")


def flatten_vectors(row: dict) -> dict:
    """A row with array values spread into columns ``name_0``, ``name_1``, ..."""
    out = {}
    for k, v in row.items():
        if isinstance(v, (np.ndarray, list, tuple)) and np.ndim(v) == 1:
            out.update({f"{k}_{i}": x for i, x in enumerate(np.asarray(v).tolist())})
        else:
            out[k] = v
    return out


def write_csv(path, rows: list[dict]) -> None:
    """Rows of dicts (same keys) to CSV, atomically; vector values become one column per component."""
    if not rows:
        write_atomic(path, "")
        return
    import io

    rows = [flatten_vectors(r) for r in rows]

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0].keys()))
    w.writeheader()
    for r in rows:
        w.writerow({k: to_jsonable(v) for k, v in r.items()})
    write_atomic(path, buf.getvalue())


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def _mode_bands(ax, t, modes, dt):
    """Shade the time spans of each tracker mode other than 'track'; returns the modes that occur."""
    seen = []
    i = 0
    while i < len(modes):
        j = i
        while j + 1 < len(modes) and modes[j + 1] == modes[i]:
            j += 1
        if modes[i] != "track":
            ax.axvspan(t[i] - dt, t[j], color=MODE_COLORS.get(modes[i], "grey"), alpha=0.12, lw=0)
        if modes[i] not in seen:
            seen.append(modes[i])
        i = j + 1
    return seen


def plot_episode(out_dir, steps: list[dict], frames: list | None = None, summary: dict | None = None) -> list[Path]:
    """PNG plots of one episode.

    ``slew.png`` (task slew) or ``hold.png`` (task hold): pointing error with the settle tolerance and the settle
    instant, estimate error against truth split into cross-boresight and roll, true and estimated rate, wheel
    momentum and commanded torque, attitude update rate and matching latency; tracker modes other than 'track'
    shaded. ``star_frame.png``: the frame with the most exposures, per head, full frame and crops with truth and
    centroids. Returns the written paths (empty if matplotlib is not installed).
    """
    plt = _pyplot()
    if plt is None or not steps:
        return []
    from matplotlib.patches import Patch

    summary = summary or {}
    out_dir = Path(out_dir)
    task = summary.get("task", "slew")
    t = np.array([r["time_s"] for r in steps])
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.1
    modes = [r["tracker_mode"] for r in steps]
    tol = summary.get("settle_tolerance_deg")
    settle = summary.get("settle_time_s")
    written = []

    fig, ax = plt.subplots(6, 1, figsize=(9, 13), sharex=True)
    for a in ax:
        seen = _mode_bands(a, t, modes, dt)
    point = np.array([r["pointing_error_deg"] for r in steps])
    if task == "hold":
        ax[0].plot(t, point * 3600.0, color="tab:blue", label="true pointing error")
        ax[0].set_ylabel("pointing error\nto target [arcsec]")
        txt = (f"RMS {summary.get('pointing_error_rms_arcsec', float('nan')):.2f}\u2033, "
               f"max {summary.get('pointing_error_max_arcsec', float('nan')):.2f}\u2033; "
               f"stability (1 s) {summary.get('pointing_stability_arcsec_1s', float('nan')):.2f}\u2033; "
               f"rate jitter RMS {summary.get('jitter_rate_rms_arcsec_s', float('nan')):.2f}\u2033/s")
        ax[0].set_title(f"attitude hold, second half: {txt}", fontsize=9)
        if len(t) > 1:
            for a in ax:
                a.axvline(t[len(t) // 2], color="grey", ls="--", lw=0.8)
    else:
        ax[0].semilogy(t, np.maximum(point, 1e-6), color="tab:blue", label="true pointing error")
        ax[0].set_ylabel("pointing error\nto target [deg]")
        if tol is not None:
            ax[0].axhline(tol, color="k", ls=":", lw=1, label=f"settle tolerance {tol:g}\u00b0")
        if settle is not None and np.isfinite(settle):
            for a in ax:
                a.axvline(settle, color="tab:green", ls="--", lw=1)
            ax[0].plot([settle], [tol if tol else point[-1]], "v", color="tab:green", ms=8,
                       label=f"settled at {settle:.1f} s")
        ax[0].set_title(f"slew of {summary.get('slew_angle_deg', float('nan')):.1f}\u00b0, policy "
                        f"{summary.get('policy', '?')}, seed {summary.get('seed', '?')}", fontsize=9)
    ax[0].legend(loc="upper right", fontsize=8)

    cross = np.array([r["estimate_error_cross_boresight_arcsec"] for r in steps])
    roll = np.array([r["estimate_error_roll_arcsec"] for r in steps])
    ax[1].semilogy(t, np.maximum(cross, 1e-3), color="tab:blue", lw=1, label="cross-boresight")
    ax[1].semilogy(t, np.maximum(roll, 1e-3), color="tab:purple", lw=1, label="roll (about boresight)")
    ax[1].set_ylabel("estimate error\nvs truth [arcsec]")
    ax[1].legend(loc="upper right", fontsize=8)

    w_true = np.array([r["omega_true_body_deg_s"] for r in steps])
    w_est = np.array([r["omega_est_body_deg_s"] for r in steps])
    ax[2].plot(t, np.linalg.norm(w_true, axis=1), color="k", lw=1.2, label="|true|")
    for i, c in enumerate(("tab:red", "tab:green", "tab:blue")):
        ax[2].plot(t, w_est[:, i], color=c, lw=0.8, ls="--", label=f"est. {'xyz'[i]}")
    ax[2].set_ylabel("body rate [deg/s]")
    ax[2].legend(loc="upper right", fontsize=7, ncol=4)

    h = np.array([r["wheel_momentum_Nms"] for r in steps])
    for i in range(h.shape[1]):
        ax[3].plot(t, h[:, i], lw=1, label=f"wheel {i}")
    ax[3].set_ylabel("wheel momentum\n[N m s]")
    ax[3].legend(loc="upper right", fontsize=7, ncol=h.shape[1])
    tau = np.array([r["wheel_torque_cmd_Nm"] for r in steps])
    for i in range(tau.shape[1]):
        ax[4].step(t, tau[:, i], where="pre", lw=0.9, label=f"wheel {i}")
    ax[4].set_ylabel("commanded wheel\ntorque [N m]")

    ax[5].plot(t, [r["update_rate_hz"] for r in steps], color="tab:blue")
    ax[5].set_ylabel("attitude update\nrate [Hz]", color="tab:blue")
    ax5b = ax[5].twinx()
    ax5b.plot(t, [r["matching_latency_ms"] for r in steps], color="tab:purple", lw=0.8)
    ax5b.set_ylabel("matching latency\n[ms]", color="tab:purple")
    ax[5].set_xlabel("time [s]")
    shown = [m for m in seen if m != "track"]
    if shown:
        fig.legend(handles=[Patch(color=MODE_COLORS[m], alpha=0.3, label=f"tracker {m}") for m in shown],
                   loc="lower center", ncol=len(shown), fontsize=8)
    else:
        fig.text(0.5, 0.005, "tracker in 'track' mode throughout", ha="center", fontsize=8)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    p = out_dir / ("hold.png" if task == "hold" else "slew.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    written.append(p)
    if frames:
        written.append(plot_star_frame(out_dir / "star_frame.png", frames))
    return written


def _stretch(img, lo, hi):
    return np.arcsinh(np.clip((img - lo) / max(hi - lo, 1e-9), 0, None) * 20.0) / np.arcsinh(20.0)


def plot_star_frame(path, frames: list[dict]) -> Path:
    """One row per head: the whole frame (asinh stretch from the background) and two native-resolution crops around
    the brightest visible stars with the truth (circles: each exposure's centre) and the extracted centroids."""
    plt = _pyplot()
    n = len(frames)
    fig = plt.figure(figsize=(13.5, 5.0 * n), dpi=100)
    for row, f in enumerate(frames):
        img = np.asarray(f["image"], dtype=np.float64)
        rows_px, cols_px = img.shape
        bg = float(np.median(img[::4, ::4]))
        sd = float(1.4826 * np.median(np.abs(img[::4, ::4] - bg))) or 1.0
        top = 0.99 - row / n
        hgt = 0.97 / n
        ax0 = fig.add_axes([0.03, top - hgt, 0.38, hgt - 0.06])
        pool = max(1, cols_px // 512)  # max-pooling keeps point-like stars visible at this size
        pooled = img[: rows_px // pool * pool, : cols_px // pool * pool]
        pooled = pooled.reshape(rows_px // pool, pool, cols_px // pool, pool).max(axis=(1, 3))
        ax0.imshow(_stretch(pooled, bg + 3.0 * sd, bg + 40.0 * sd), cmap="gray",
                   extent=(-0.5, cols_px - 0.5, rows_px - 0.5, -0.5), interpolation="nearest")
        ax0.set_xticks([])
        ax0.set_yticks([])
        ax0.set_title(f"head {f['head']} ({f['camera']}, {f['channel']}, {pool}\u00d7{pool} max-pooled): "
                      f"frame at t = {f['t_frame_s']:.1f} s, "
                      f"{f['rate_deg_s']:.1f}\u00b0/s\nN = {f['n_exposures']} exposures, {f['n_stars']} stars, "
                      f"{len(f['centroid_xy'])} centroids (pixel path, from the true attitude); circles: catalog stars", fontsize=8)
        xy = np.asarray(f["truth_xy"]).reshape(-1, np.asarray(f["vmag"]).size, 2)
        vis = np.asarray(f["visible"]).reshape(xy.shape[:2])
        truth = xy[vis]
        cen = np.asarray(f["centroid_xy"]).reshape(-1, 2)
        half = 45
        mid = xy[xy.shape[0] // 2]  # each star's centre in the middle exposure
        inner = vis.all(axis=0) & np.all((mid > half + 8) & (mid < np.array([cols_px, rows_px]) - half - 8), axis=1)
        seen = vis.any(axis=0)
        ax0.plot(mid[seen, 0], mid[seen, 1], "o", mfc="none", mec="tab:orange", ms=7, mew=0.6, alpha=0.8)
        ax0.set_xlim(-0.5, cols_px - 0.5)
        ax0.set_ylim(rows_px - 0.5, -0.5)
        centres = []
        for i in np.argsort(np.where(inner, f["vmag"], np.inf)):  # two crops on distinct bright stars
            if not inner[i]:
                break
            if all(np.max(np.abs(mid[i] - o)) > 2 * half for o in centres):
                centres.append(mid[i])
            if len(centres) == 2:
                break
        for k, c in enumerate(centres):
            ax = fig.add_axes([0.45 + 0.28 * k, top - hgt, 0.26, hgt - 0.06])
            c0 = np.clip(np.rint(c).astype(int), half, np.array([cols_px, rows_px]) - half)
            sub = img[c0[1] - half:c0[1] + half, c0[0] - half:c0[0] + half]
            ext = (c0[0] - half - 0.5, c0[0] + half - 0.5, c0[1] + half - 0.5, c0[1] - half - 0.5)
            ax.imshow(_stretch(sub, bg + 2.0 * sd, float(np.percentile(sub, 99.8)) + sd), cmap="gray", extent=ext,
                      interpolation="nearest")
            tin = (np.abs(truth[:, 0] - c0[0]) < half) & (np.abs(truth[:, 1] - c0[1]) < half)
            ax.plot(truth[tin, 0], truth[tin, 1], "o", mfc="none", mec="tab:orange", ms=9, mew=0.8,
                    label="truth (exposure centre)")
            cin = (np.abs(cen[:, 0] - c0[0]) < half) & (np.abs(cen[:, 1] - c0[1]) < half)
            ax.plot(cen[cin, 0], cen[cin, 1], "+", color="tab:cyan", ms=8, mew=1.0, label="centroid")
            ax.set_xlim(ext[0], ext[1])
            ax.set_ylim(ext[2], ext[3])
            ax.set_title(f"crop {2 * half}\u00d7{2 * half} px at ({c0[0]}, {c0[1]})", fontsize=8)
            ax.tick_params(labelsize=7)
            if k == 0:
                ax.legend(fontsize=7, loc="lower left", framealpha=0.6)
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_campaign(out_dir, summary: list[dict], grid_keys: list[str], records: list[dict] | None = None) -> Path | None:
    """``campaign.png``: success rate and the median with its p10-p90 range of the main figures, one point per
    setting combination (labelled by the swept settings); with ``records`` (the run records) each seed's value is
    drawn as a small grey dot beside it."""
    plt = _pyplot()
    if plt is None or not summary:
        return None
    from experiments.settings import as_scalar_text

    per_point = [[] for _ in summary]
    for rec in records or []:
        st = rec.get("settings", {})
        for i, row in enumerate(summary):
            if all(row.get(k) == as_scalar_text(v) for k, v in st.items()):
                per_point[i].append(rec.get("summary", {}))
                break
    swept = [k for k in grid_keys if len({r.get(k) for r in summary}) > 1] or list(grid_keys)
    labels = ["\n".join(f"{k}={r.get(k)}" for k in swept) or "all" for r in summary]
    metrics = [("success_rate", "success rate", 1.0)]
    for m, name, scale in (("settle_time_s", "settle time [s]", 1.0),
                           ("final_pointing_error_deg", "final pointing\nerror [arcsec]", 3600.0),
                           ("attitude_error_rms_arcsec", "estimate error\nRMS [arcsec]", 1.0),
                           ("update_rate_hz_mean", "attitude update\nrate [Hz]", 1.0),
                           ("pointing_stability_arcsec_1s", "pointing stability\n1 s [arcsec]", 1.0),
                           ("jitter_rate_rms_arcsec_s", "rate jitter\nRMS [arcsec/s]", 1.0)):
        if any(r.get(f"{m}_median") is not None for r in summary):
            metrics.append((m, name, scale))
    x = np.arange(len(summary))
    fig, axes = plt.subplots(len(metrics), 1, figsize=(max(6, 1.3 * len(summary) + 3), 2.2 * len(metrics)),
                             sharex=True, squeeze=False)
    for ax, (m, name, scale) in zip(axes[:, 0], metrics):
        if m == "success_rate":
            ax.bar(x, [r["success_rate"] for r in summary], color="tab:green", alpha=0.7)
            for xi, r in zip(x, summary):
                ax.text(xi, r["success_rate"], f"{r['successes']}/{r['runs']}", ha="center", va="bottom", fontsize=8)
            ax.set_ylim(0, 1.15)
        else:
            def col(suffix):
                return scale * np.array([np.nan if r.get(f"{m}_{suffix}") is None else r[f"{m}_{suffix}"]
                                         for r in summary], float)

            med, lo, hi = col("median"), col("p10"), col("p90")
            ax.errorbar(x, med, yerr=[med - lo, hi - med], fmt="o", capsize=4, color="tab:blue",
                        label="median, p10-p90")
            for xi, sums in zip(x, per_point):
                v = [scale * su[m] for su in sums if su.get(m) is not None]
                if v:
                    ax.plot(np.full(len(v), xi + 0.12), v, ".", color="grey", ms=4, alpha=0.7,
                            label="one seed" if xi == 0 else None)
            if m == metrics[1][0]:
                ax.legend(fontsize=7, loc="best")
        ax.set_ylabel(name, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].set_title(f"campaign: median and p10-p90 over {summary[0]['runs']} seed(s) per point", fontsize=9)
    axes[-1, 0].set_xticks(x)
    axes[-1, 0].set_xticklabels(labels, fontsize=8)
    fig.tight_layout()
    p = Path(out_dir) / "campaign.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return p
