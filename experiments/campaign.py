"""Monte Carlo campaigns: seeds × a grid of settings, resumable, on local processes or on Ray.

A campaign is a grid (setting -> values to sweep) plus fixed settings, times seeds. Settings are ``policy``, any
keyword argument of the env and the reset options (:func:`experiments.settings.setting_keys`). Every distinct
setting combination is checked (its policy loaded, its env built once) before the first run starts.

Each run is stored as ``<out>/runs/<run_id>.json`` the moment it finishes (written atomically), with its requested
settings, the resolved env configuration, the provenance (package version, source revision, code digest,
benchmark version) and its summary. ``run_id`` names a run (settings + seed); the record's ``key`` also covers
the configuration and the code, and a restart reuses a run file only when the key matches: an interrupted campaign
loses no finished run, a changed one never reuses a stale run. ``results.csv`` (one row per run) and
``summary.csv`` (per setting combination: counts, success rate, median and p10-p90 of the key figures) are
rebuilt from the run files, grouped by the requested settings, never by achieved values.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.provenance import key_differences, provenance, run_key
from experiments.settings import (
    as_scalar_text, check_setting_keys, ensure_working_directory_importable, split_settings, validate_settings,
)
from experiments.telemetry import to_jsonable, write_csv, write_json_atomic

__all__ = ["Campaign", "RunSpec", "expand_grid", "run_campaign", "load_results", "summarise_results",
           "flatten_record", "SUMMARY_METRICS"]

# summary figures reported per setting combination with their spread (median, p10, p90)
SUMMARY_METRICS = (
    "settle_time_s", "final_pointing_error_deg", "attitude_error_rms_arcsec", "update_rate_hz_mean",
    "matching_latency_ms_p99", "mode_share_track", "control_effort", "pointing_error_rms_arcsec",
    "pointing_stability_arcsec_1s", "jitter_rate_rms_arcsec_s",
)


def _canonical(settings: dict) -> str:
    return json.dumps(to_jsonable(settings), sort_keys=True, separators=(",", ":"), default=str)


@dataclass(frozen=True)
class RunSpec:
    """One run: requested settings (policy, env keyword arguments, reset options) and a seed."""

    settings_json: str  # canonical JSON of the settings dict
    seed: int

    @property
    def run_id(self) -> str:
        blob = json.dumps([self.settings_json, self.seed])
        return hashlib.sha1(blob.encode()).hexdigest()[:16]

    @property
    def settings(self) -> dict:
        return json.loads(self.settings_json)


def expand_grid(grid: dict, seeds, fixed: dict | None = None) -> list[RunSpec]:
    """All combinations of ``grid`` (key -> list of values) with the ``fixed`` settings, times ``seeds``.

    Raises
    ------
    ValueError
        Unknown keys, a key both swept and fixed, or an empty expansion.
    """
    fixed = dict(fixed or {})
    check_setting_keys(grid, "grid setting")
    check_setting_keys(fixed, "setting")
    both = sorted(set(grid) & set(fixed))
    if both:
        raise ValueError(f"setting(s) {both} are both in the grid and fixed; give each once")
    keys = sorted(grid)
    values = [list(grid[k]) if isinstance(grid[k], (list, tuple)) else [grid[k]] for k in keys]
    seeds = [int(s) for s in seeds]
    runs = [
        RunSpec(_canonical({**fixed, **dict(zip(keys, combo))}), s)
        for combo in itertools.product(*values)
        for s in seeds
    ]
    if not runs:
        raise ValueError("the grid expands to zero runs (an empty value list or no seeds)")
    return runs


def _execute(spec: RunSpec, base: dict, search_dir: str | None = None) -> dict:
    """Run one episode (in a worker process) and return its run record (``base`` holds env config and provenance).

    ``search_dir``: the launching process's working directory, put on ``sys.path`` so a ``module:Class`` policy of
    the user's folder loads in workers that start elsewhere (Ray)."""
    import sys

    from experiments.episode import run_episode

    ensure_working_directory_importable()
    if search_dir and search_dir not in sys.path:
        sys.path.insert(0, search_dir)
    env_id, policy, kwargs, options = split_settings(spec.settings)
    res = run_episode(env_id, policy=policy, seed=spec.seed, env_kwargs=kwargs, reset_options=options or None)
    return to_jsonable({**base, "summary": res.summary})


class Campaign:
    """A campaign on disk.

    Parameters
    ----------
    out_dir : path
        Folder for ``runs/``, ``results.csv``, ``summary.csv`` and ``campaign.json``; created if missing.
    grid : dict
        Setting -> list of values to sweep.
    seeds : iterable of int
    fixed : dict, optional
        Settings shared by every run (the command line's ``--env``).

    Raises
    ------
    ValueError
        Any unknown or refused setting (every combination is checked here, before any run), or an unwritable folder.
    """

    def __init__(self, out_dir, grid: dict, seeds, fixed: dict | None = None):
        self.out_dir = Path(out_dir)
        self.grid = {k: list(v) if isinstance(v, (list, tuple)) else [v] for k, v in grid.items()}
        self.fixed = dict(fixed or {})
        self.runs = expand_grid(self.grid, seeds, self.fixed)
        self.provenance = provenance()
        self._base = {}
        for sj in dict.fromkeys(r.settings_json for r in self.runs):
            settings = json.loads(sj)
            env_id = split_settings(settings)[0]
            self._base[sj] = {"settings": settings, "env_id": env_id, "env_config": validate_settings(settings)}
        try:
            (self.out_dir / "runs").mkdir(parents=True, exist_ok=True)
            probe = self.out_dir / ".write_test"
            probe.write_text("ok")
            probe.unlink()
        except OSError as exc:
            raise ValueError(f"output folder {self.out_dir} is not writable: {exc}") from None
        self.stale: dict[str, list[str]] = {}  # run_id -> key fields that changed since the file was written
        self._scan()

    def base_record(self, spec: RunSpec) -> dict:
        """Everything a run's record holds before it runs, including its ``key``."""
        rec = {"run_id": spec.run_id, "seed": spec.seed, **self._base[spec.settings_json],
               "provenance": self.provenance, "package_version": self.provenance["package_version"],
               "code_sha1": self.provenance["code_sha1"], "benchmark_version": self.provenance["benchmark_version"]}
        rec = to_jsonable(rec)
        rec["key"] = run_key(rec)
        return rec

    def run_path(self, spec: RunSpec) -> Path:
        return self.out_dir / "runs" / f"{spec.run_id}.json"

    def _scan(self) -> None:
        self._finished = set()
        self.stale = {}
        for spec in self.runs:
            p = self.run_path(spec)
            if not p.exists():
                continue
            try:
                old = json.loads(p.read_text())
            except (OSError, ValueError):
                self.stale[spec.run_id] = ["unreadable file"]  # a corrupt file is redone, never trusted
                continue
            new = self.base_record(spec)
            # the key is recomputed from what the file says, so an edited or older record cannot pass for current
            if run_key(old) == new["key"] and "summary" in old:
                self._finished.add(spec.run_id)
            else:
                self.stale[spec.run_id] = key_differences(old, new) or ["record format"]

    def pending(self) -> list[RunSpec]:
        self._scan()
        return [r for r in self.runs if r.run_id not in self._finished]

    def describe_resume(self) -> str:
        """One line: how many runs are reused, how many stale ones are redone and why."""
        self._scan()
        n = len(self.runs)
        msg = f"campaign: {n} runs, {len(self._finished)} reused from {self.out_dir / 'runs'}"
        if self.stale:
            reasons: dict[str, int] = {}
            for fields in self.stale.values():
                for f in fields:
                    reasons[f] = reasons.get(f, 0) + 1
            why = ", ".join(f"{f} ({c})" for f, c in sorted(reasons.items()))
            msg += f"; {len(self.stale)} finished earlier but redone because these changed: {why}"
        return msg

    def save(self, record: dict) -> None:
        write_json_atomic(self.out_dir / "runs" / f"{record['run_id']}.json", record)

    def records(self) -> list[dict]:
        """The current, valid records of this campaign's runs, in grid order."""
        self._scan()
        out = []
        for spec in self.runs:
            if spec.run_id in self._finished:
                out.append(json.loads(self.run_path(spec).read_text()))
        return out

    def manifest(self) -> dict:
        return to_jsonable({"grid": self.grid, "fixed": self.fixed, "seeds": sorted({r.seed for r in self.runs}),
                            "n_runs": len(self.runs), "provenance": self.provenance,
                            "env_configs": list(self._base.values())})


def run_campaign(campaign: Campaign, backend: str = "local", workers: int = 2, progress: bool = True,
                 max_runs: int | None = None, plots: bool = False) -> list[dict]:
    """Run every pending run of ``campaign``; finished runs are saved one by one as they complete.

    Parameters
    ----------
    backend : {"local", "ray"}
        Local worker processes, or Ray tasks (``ray.init()`` connects to ``RAY_ADDRESS`` if set, else starts a
        local instance). Both write the same run files.
    workers : int
        Local processes, >= 1 (ignored by Ray, which uses its cluster's resources).
    max_runs : int, optional
        Stop after this many new runs (used to test interruption and resumption).
    plots : bool
        Also draw ``campaign.png`` (metrics against the settings, with spread).

    Returns
    -------
    list of dict
        All current run records of the campaign (reused and new).
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    todo = campaign.pending()
    if max_runs is not None:
        todo = todo[: int(max_runs)]
    jobs = [(s, campaign.base_record(s)) for s in todo]
    bar = _progress(len(campaign.runs), len(campaign.runs) - len(campaign.pending()), progress)
    try:
        if not jobs:
            pass
        elif backend == "ray":
            _run_ray(campaign, jobs, bar)
        elif workers == 1:
            for spec, base in jobs:
                campaign.save(_execute(spec, base))
                bar.update(1)
        else:
            _run_local(campaign, jobs, int(workers), bar)
    finally:
        bar.close()
        records = campaign.records()
        write_json_atomic(campaign.out_dir / "campaign.json", campaign.manifest())
        write_csv(campaign.out_dir / "results.csv", [flatten_record(r) for r in records])
        summary = summarise_results(records)
        write_csv(campaign.out_dir / "summary.csv", summary)
        if plots and summary:
            from experiments.telemetry import plot_campaign

            plot_campaign(campaign.out_dir, summary, list(campaign.grid), records)
    return records


def _run_local(campaign, jobs, workers, bar):
    with ProcessPoolExecutor(max_workers=workers) as pool:
        pending = {pool.submit(_execute, s, b, os.getcwd()) for s, b in jobs}
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


def _run_ray(campaign, jobs, bar):
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
        refs = [remote.remote(s, b, os.getcwd()) for s, b in jobs]
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
    """Every readable run record in ``out_dir/runs`` (corrupt files skipped), sorted by run id.

    Unlike :meth:`Campaign.records` this does not check the records against the current code.
    """
    rows = []
    for p in sorted(Path(out_dir, "runs").glob("*.json")):
        try:
            rows.append(json.loads(p.read_text()))
        except (OSError, ValueError):
            continue
    return rows


def flatten_record(record: dict) -> dict:
    """One ``results.csv`` row: run id, seed, the requested settings, then the summary. A summary figure that shares
    a setting's name (the achieved ``slew_angle_deg``) gets the suffix ``_achieved``."""
    settings = record.get("settings", {})
    row = {"run_id": record["run_id"], "seed": record["seed"]}
    row.update({k: as_scalar_text(v) for k, v in sorted(settings.items())})
    for k, v in record.get("summary", {}).items():
        if k in ("seed",):
            continue
        if k in settings:
            if k == "policy":
                continue
            k = f"{k}_achieved"
        row[k] = v
    row["code_sha1"] = record.get("code_sha1")
    row["source_revision"] = record.get("provenance", {}).get("source_revision")
    return row


def _spread(vals) -> tuple:
    v = np.asarray([x for x in vals if x is not None and np.isfinite(x)], dtype=float)
    if not v.size:
        return None, None, None
    return float(np.median(v)), float(np.percentile(v, 10)), float(np.percentile(v, 90))


def summarise_results(records: list[dict]) -> list[dict]:
    """Per requested setting combination (all settings but the seed): runs, successes, success rate, and for each
    figure of :data:`SUMMARY_METRICS` present: ``<figure>_median``, ``_p10``, ``_p90`` over the seeds."""
    groups: dict = {}
    for r in records:
        groups.setdefault(_canonical(r["settings"]), []).append(r)
    out = []
    for sj, rs in groups.items():
        settings = json.loads(sj)
        sums = [r["summary"] for r in rs]
        row = {k: as_scalar_text(v) for k, v in sorted(settings.items())}
        ok = [bool(s.get("success")) for s in sums]
        row.update(runs=len(rs), successes=int(sum(ok)), success_rate=float(np.mean(ok)))
        for m in SUMMARY_METRICS:
            if not any(s.get(m) is not None for s in sums) and not any(m in s for s in sums):
                continue
            med, p10, p90 = _spread(s.get(m) for s in sums)
            row[f"{m}_median"], row[f"{m}_p10"], row[f"{m}_p90"] = med, p10, p90
        row["lost_lock_events_total"] = int(sum(s.get("lost_lock_events", 0) for s in sums))
        out.append(row)
    return out
