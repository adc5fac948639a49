"""Monte Carlo campaigns: seeds × a grid of settings, resumable, on local processes or on Ray.

Each run is identified by a hash of its settings and seed and stored as ``<out>/runs/<run_id>.json`` the moment
it finishes (written atomically), so an interrupted campaign (Ctrl-C, a killed machine) loses no finished run and a
restart skips every run already on disk. ``results.csv`` (one row per run) and ``summary.csv`` (per grid point:
success rate, settle time, pointing and attitude errors, update rate, latency) are rebuilt from the run files.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.telemetry import to_jsonable, write_csv, write_json_atomic

__all__ = ["Campaign", "RunSpec", "expand_grid", "run_campaign", "load_results", "summarise_results", "GRID_KEYS"]

# Settings a campaign grid may vary: "policy" and the env's keyword arguments.
GRID_KEYS = (
    "policy", "camera", "exposure_mode", "n_exposures", "matcher", "identify_method", "gyro_grade", "fidelity",
    "frame_rate_hz", "wheel_max_torque_Nm", "slew_angle_deg", "max_episode_s", "task",
)


@dataclass(frozen=True)
class RunSpec:
    """One run: settings (policy + env keyword arguments + reset options) and a seed."""

    settings: tuple  # sorted (key, value) pairs
    seed: int

    @property
    def run_id(self) -> str:
        blob = json.dumps([list(self.settings), self.seed], sort_keys=True, default=str)
        return hashlib.sha1(blob.encode()).hexdigest()[:16]

    def as_dict(self) -> dict:
        return dict(self.settings)


def expand_grid(grid: dict, seeds) -> list[RunSpec]:
    """All combinations of ``grid`` (key -> list of values) times ``seeds``.

    Raises
    ------
    ValueError
        Unknown keys or an empty expansion.
    """
    unknown = sorted(set(grid) - set(GRID_KEYS))
    if unknown:
        raise ValueError(f"unknown grid setting(s) {unknown}; allowed: {', '.join(GRID_KEYS)}")
    keys = sorted(grid)
    values = [list(grid[k]) if isinstance(grid[k], (list, tuple)) else [grid[k]] for k in keys]
    seeds = list(seeds)
    runs = [
        RunSpec(tuple(zip(keys, combo)), int(s))
        for combo in itertools.product(*values)
        for s in seeds
    ]
    if not runs:
        raise ValueError("the grid expands to zero runs (an empty value list or no seeds)")
    return runs


def _execute(spec: RunSpec) -> dict:
    """Run one episode (in a worker process) and return its summary row."""
    from experiments.episode import run_episode

    s = spec.as_dict()
    policy = s.pop("policy", "eigenaxis")
    task = s.pop("task", "slew")
    options = {}
    if "slew_angle_deg" in s:
        options["slew_angle_deg"] = float(s.pop("slew_angle_deg"))
    env_id = "startracker/AgileSlew-v0" if task == "slew" else "startracker/AttitudeHold-v0"
    res = run_episode(env_id, policy=policy, seed=spec.seed, env_kwargs=s, reset_options=options or None)
    row = {"run_id": spec.run_id, **{k: v for k, v in spec.settings}, **res.summary}
    return to_jsonable(row)


class Campaign:
    """A campaign on disk.

    Parameters
    ----------
    out_dir : path
        Folder for ``runs/``, ``results.csv`` and ``summary.csv``; created if missing.
    grid : dict
        Setting -> list of values (keys in :data:`GRID_KEYS`).
    seeds : iterable of int
    """

    def __init__(self, out_dir, grid: dict, seeds):
        self.out_dir = Path(out_dir)
        self.runs = expand_grid(grid, seeds)
        self.grid = grid
        try:
            (self.out_dir / "runs").mkdir(parents=True, exist_ok=True)
            probe = self.out_dir / ".write_test"
            probe.write_text("ok")
            probe.unlink()
        except OSError as exc:
            raise ValueError(f"output folder {self.out_dir} is not writable: {exc}") from None

    def run_path(self, spec: RunSpec) -> Path:
        return self.out_dir / "runs" / f"{spec.run_id}.json"

    def pending(self) -> list[RunSpec]:
        return [r for r in self.runs if not self._finished(r)]

    def _finished(self, spec: RunSpec) -> bool:
        p = self.run_path(spec)
        if not p.exists():
            return False
        try:
            json.loads(p.read_text())
            return True
        except (OSError, ValueError):
            return False  # a corrupt file is redone, never trusted

    def save(self, row: dict) -> None:
        write_json_atomic(self.out_dir / "runs" / f"{row['run_id']}.json", row)


def run_campaign(campaign: Campaign, backend: str = "local", workers: int = 2, progress: bool = True,
                 max_runs: int | None = None) -> list[dict]:
    """Run every pending run of ``campaign``; finished runs are saved one by one as they complete.

    Parameters
    ----------
    backend : {"local", "ray"}
        Local worker processes, or Ray tasks (``ray.init()`` connects to ``RAY_ADDRESS`` if set, else starts a
        local instance). Both write the same run files.
    workers : int
        Local processes (ignored by Ray, which uses its cluster's resources).
    max_runs : int, optional
        Stop after this many new runs (used to test interruption and resumption).

    Returns
    -------
    list of dict
        All finished rows (old and new).
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    todo = campaign.pending()
    if max_runs is not None:
        todo = todo[: int(max_runs)]
    bar = _progress(len(campaign.runs), len(campaign.runs) - len(campaign.pending()), progress)
    try:
        if not todo:
            pass
        elif backend == "ray":
            _run_ray(campaign, todo, bar)
        elif workers <= 1:
            for spec in todo:
                campaign.save(_execute(spec))
                bar.update(1)
        else:
            _run_local(campaign, todo, workers, bar)
    finally:
        bar.close()
        rows = load_results(campaign.out_dir)
        write_csv(campaign.out_dir / "results.csv", rows)
        write_csv(campaign.out_dir / "summary.csv", summarise_results(rows))
    return rows


def _run_local(campaign, todo, workers, bar):
    with ProcessPoolExecutor(max_workers=int(workers)) as pool:
        pending = {pool.submit(_execute, s) for s in todo}
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    campaign.save(fut.result())
                    bar.update(1)
        except BaseException:
            for fut in pending:
                fut.cancel()
            raise


def _run_ray(campaign, todo, bar):
    try:
        import ray
    except ImportError:
        raise ValueError("backend 'ray' needs the optional extra: pip install 'startracker-gym[ray]'") from None
    started = False
    if not ray.is_initialized():
        ray.init(ignore_reinit_error=True, include_dashboard=False, log_to_driver=False)
        started = True
    try:
        remote = ray.remote(_execute)
        refs = [remote.remote(s) for s in todo]
        while refs:
            done, refs = ray.wait(refs, num_returns=1)
            for ref in done:
                campaign.save(ray.get(ref))
                bar.update(1)
    finally:
        if started:
            ray.shutdown()


class _NoBar:
    def update(self, n):
        pass

    def close(self):
        pass


def _progress(total, initial, enabled):
    if not enabled:
        return _NoBar()
    try:
        from tqdm import tqdm
    except ImportError:
        return _NoBar()
    return tqdm(total=total, initial=initial, desc="campaign", unit="run")


def load_results(out_dir) -> list[dict]:
    """All finished run rows in ``out_dir/runs`` (corrupt files are skipped), sorted by run id."""
    rows = []
    for p in sorted(Path(out_dir, "runs").glob("*.json")):
        try:
            rows.append(json.loads(p.read_text()))
        except (OSError, ValueError):
            continue
    return rows


def summarise_results(rows: list[dict]) -> list[dict]:
    """Per grid point (all settings but the seed): counts, success rate and medians of the key figures."""
    groups: dict = {}
    for r in rows:
        settings = tuple(sorted((k, str(v)) for k, v in r.items() if k in GRID_KEYS))
        groups.setdefault(settings, []).append(r)
    out = []
    for settings, rs in sorted(groups.items()):
        def med(key):
            vals = [x[key] for x in rs if x.get(key) is not None]
            return float(np.median(vals)) if vals else None

        out.append({
            **dict(settings),
            "runs": len(rs),
            "success_rate": float(np.mean([bool(x["success"]) for x in rs])),
            "settle_time_s_median": med("settle_time_s"),
            "final_pointing_error_deg_median": med("final_pointing_error_deg"),
            "attitude_error_rms_arcsec_median": med("attitude_error_rms_arcsec"),
            "update_rate_hz_mean_median": med("update_rate_hz_mean"),
            "matching_latency_ms_p99_median": med("matching_latency_ms_p99"),
            "mode_share_track_median": med("mode_share_track"),
            "lost_lock_events_total": int(sum(x.get("lost_lock_events", 0) for x in rs)),
            "control_effort_median": med("control_effort"),
        })
    return out
