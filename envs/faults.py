"""Fault injection: what the sky and the hardware do to a star tracker, on demand and on a schedule.

A fault is ``Fault(kind, t_start_s, duration_s, severity)``; a ``FaultSchedule`` holds several and answers, at a
time, which are active and how they change a frame, its detections or the gyro samples. Kinds and what
``severity`` means:

============== ======================================================================================= =========
kind           effect                                                                                  severity
============== ======================================================================================= =========
stray_light    the sun at ``severity`` degrees from the boresight (a real bright body in the scene:      angle, °
               the imaging model raises the background, its gradient and its shot noise; where the
               background's threshold reaches saturation nothing is detected, in both fidelities: about
               10° blinds a 20 ms frame)
false_objects  extra false detections, ``severity`` × the number of true ones (0.5 = 50 % more),       fraction
               as bright as the stars (debris, glints)
dropout        each true star detection vanishes with probability ``severity``                       fraction
saturated      the frame is saturated: one huge blob, no usable detection                             —
blank          the frame is blank (shutter, readout failure): no detection                            —
dropped_frame  the frame never reaches the tracker                                                    —
time_jitter    frame timestamps off by a Gaussian error of ``severity`` ms (rendered at the true time) ms
gyro_bias_step the gyro bias jumps by ``severity`` °/s on a random axis while active                  °/s
gyro_saturation the gyro clips at ``severity`` °/s                                                      °/s
head_blinded   multi-head sensors: head index ``int(severity)`` sees nothing                          head
============== ======================================================================================= =========
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from startracker.head import Centroids

__all__ = ["Fault", "FaultSchedule", "FAULT_KINDS", "random_fault_schedule"]

FAULT_KINDS = (
    "stray_light", "false_objects", "dropout", "saturated", "blank", "dropped_frame", "time_jitter",
    "gyro_bias_step", "gyro_saturation", "head_blinded",
)

_DEFAULT_SEVERITY = {
    "stray_light": 25.0, "false_objects": 0.5, "dropout": 0.5, "saturated": 1.0, "blank": 1.0, "dropped_frame": 1.0,
    "time_jitter": 2.0, "gyro_bias_step": 0.05, "gyro_saturation": 5.0, "head_blinded": 1.0,
}


@dataclass(frozen=True)
class Fault:
    """One fault active on ``[t_start_s, t_start_s + duration_s)``.

    Parameters
    ----------
    kind : str
        One of :data:`FAULT_KINDS`.
    t_start_s : float
        Start, s of episode time (>= 0).
    duration_s : float
        Length, s (> 0; ``inf`` for the rest of the episode).
    severity : float, optional
        See the module table; default per kind.
    """

    kind: str
    t_start_s: float = 0.0
    duration_s: float = float("inf")
    severity: float | None = None

    def __post_init__(self):
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"fault kind must be one of {FAULT_KINDS}, got {self.kind!r}")
        if not np.isfinite(self.t_start_s) or self.t_start_s < 0:
            raise ValueError(f"t_start_s must be >= 0, got {self.t_start_s!r}")
        if not (self.duration_s > 0):
            raise ValueError(f"duration_s must be > 0, got {self.duration_s!r}")
        sev = _DEFAULT_SEVERITY[self.kind] if self.severity is None else float(self.severity)
        if not np.isfinite(sev) or sev < 0:
            raise ValueError(f"severity must be a finite number >= 0, got {self.severity!r}")
        if self.kind in ("dropout",) and sev > 1:
            raise ValueError(f"severity of 'dropout' is a probability in [0, 1], got {sev}")
        if self.kind == "stray_light" and sev > 180:
            raise ValueError(f"severity of 'stray_light' is an angle in [0, 180] deg, got {sev}")
        object.__setattr__(self, "severity", sev)

    def active(self, t: float) -> bool:
        return self.t_start_s <= t < self.t_start_s + self.duration_s

    @classmethod
    def from_dict(cls, d) -> "Fault":
        if isinstance(d, Fault):
            return d
        if not isinstance(d, dict):
            raise TypeError(f"a fault must be a Fault or a dict, got {type(d).__name__}")
        unknown = set(d) - {"kind", "t_start_s", "duration_s", "severity"}
        if unknown:
            raise ValueError(f"unknown fault field(s) {sorted(unknown)}")
        return cls(**d)


class FaultSchedule:
    """The faults of one episode.

    Parameters
    ----------
    faults : iterable of Fault or dict
    """

    def __init__(self, faults=()):
        self.faults = tuple(Fault.from_dict(f) for f in faults)
        self._bias_axis: dict[int, np.ndarray] = {}

    def __bool__(self) -> bool:
        return bool(self.faults)

    def active(self, t: float) -> list[Fault]:
        return [f for f in self.faults if f.active(t)]

    def active_kinds(self, t0: float, t1: float | None = None) -> list[str]:
        """Kinds active at any instant of ``[t0, t1]`` (sorted, unique)."""
        t1 = t0 if t1 is None else t1
        return sorted({f.kind for f in self.faults if f.t_start_s <= t1 and t0 < f.t_start_s + f.duration_s})

    def _get(self, t, kind):
        return [f for f in self.active(t) if f.kind == kind]

    # ------------------------------------------------------------------ frame level
    def frame_dropped(self, t: float) -> bool:
        return bool(self._get(t, "dropped_frame"))

    def sun_direction_world(self, t: float, boresight_world: np.ndarray, rng: np.random.Generator):
        """Direction of the sun for an active stray-light fault: at the fault's angle from the boresight."""
        f = self._get(t, "stray_light")
        if not f:
            return None
        angle = np.radians(f[0].severity)
        b = boresight_world / np.linalg.norm(boresight_world)
        perp = np.cross(b, [0.0, 0.0, 1.0] if abs(b[2]) < 0.9 else [1.0, 0.0, 0.0])
        perp /= np.linalg.norm(perp)
        return np.cos(angle) * b + np.sin(angle) * perp

    def timestamp_error_s(self, t: float, rng: np.random.Generator) -> float:
        f = self._get(t, "time_jitter")
        return float(rng.normal() * f[0].severity * 1e-3) if f else 0.0

    def modify_detections(self, det: Centroids, t: float, rng: np.random.Generator, resolution) -> Centroids:
        """Apply blank / saturated / dropout / false-object faults to one frame's detections."""
        if self._get(t, "blank"):
            return Centroids.empty(with_truth=det.truth_star is not None)
        if self._get(t, "saturated"):
            # a washed-out frame: one blob over the whole detector, flagged saturated
            w, h = resolution
            one = Centroids(np.array([[w / 2 - 0.5, h / 2 - 0.5]]), np.array([1e9]), np.array([w * h]),
                            np.array([True]), np.array([4095.0]), np.array([1e3]))
            return one
        out = det
        drop = self._get(t, "dropout")
        if drop and len(out):
            keep = rng.random(len(out)) >= drop[0].severity
            out = out.subset(np.flatnonzero(keep))
        fo = self._get(t, "false_objects")
        if fo and len(out):
            n_false = int(rng.poisson(fo[0].severity * len(out)))
            if n_false:
                w, h = resolution
                xy = np.column_stack([rng.uniform(-0.5, w - 0.5, n_false), rng.uniform(-0.5, h - 0.5, n_false)])
                # as bright as the frame's own detections, so brightness alone cannot reject them
                ref = np.abs(out.intensity)
                inten = rng.choice(ref[ref > 0] if np.any(ref > 0) else np.ones(1), n_false) * rng.uniform(0.5, 2.0, n_false)
                out = _concat(out, xy, inten)
        return out

    # ------------------------------------------------------------------ gyro
    def modify_gyro(self, omega_meas: np.ndarray, times: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Gyro samples (G, 3) at interval ends ``times`` (G,) with bias steps and saturation applied."""
        out = omega_meas
        for i, f in enumerate(self.faults):
            if f.kind not in ("gyro_bias_step", "gyro_saturation"):
                continue
            on = (times > f.t_start_s) & (times <= f.t_start_s + f.duration_s)
            if not on.any():
                continue
            out = out.copy() if out is omega_meas else out
            if f.kind == "gyro_bias_step":
                if i not in self._bias_axis:
                    a = rng.normal(size=3)
                    self._bias_axis[i] = a / np.linalg.norm(a)
                out[on] += self._bias_axis[i] * np.radians(f.severity)
            else:
                lim = np.radians(f.severity)
                out[on] = np.clip(out[on], -lim, lim)
        return out

    def blinded_heads(self, t: float) -> set[int]:
        return {int(f.severity) for f in self._get(t, "head_blinded")}


def _concat(det: Centroids, xy, intensity) -> Centroids:
    n = len(xy)
    truth = det.truth_star is not None

    def cat(a, b):
        return None if a is None else np.concatenate([a, b])

    merged = Centroids(
        np.concatenate([det.xy, xy]),
        np.concatenate([det.intensity, intensity]),
        np.concatenate([det.area, np.full(n, 4, dtype=det.area.dtype)]),
        np.concatenate([det.saturated, np.zeros(n, dtype=bool)]),
        np.concatenate([det.peak, intensity / 4]),
        np.concatenate([det.snr, np.full(n, 20.0)]),
        det.background_dn,
        det.noise_dn,
        cat(det.truth_star, np.full(n, -1)) if truth else None,
        cat(det.truth_exposure, np.full(n, -1)) if truth else None,
        cat(det.truth_kind, np.full(n, -1)) if truth else None,
        cat(det.truth_xy, xy) if truth else None,
    )
    order = np.argsort(-merged.intensity, kind="stable")  # brightest first, as the tracker expects
    return merged.subset(order)


def random_fault_schedule(rng: np.random.Generator, episode_s: float, rate_per_min: float = 2.0,
                          kinds=FAULT_KINDS) -> FaultSchedule:
    """Random faults for soak runs: Poisson arrivals, durations 0.2-5 s, severities across their range."""
    n = int(rng.poisson(rate_per_min * episode_s / 60.0))
    faults = []
    for _ in range(n):
        kind = str(rng.choice([k for k in kinds if k != "head_blinded"]))
        sev = {
            "stray_light": rng.uniform(5, 60), "false_objects": rng.uniform(0, 0.5), "dropout": rng.uniform(0, 0.9),
            "time_jitter": rng.uniform(0, 5), "gyro_bias_step": rng.uniform(0, 0.2), "gyro_saturation": rng.uniform(1, 30),
        }.get(kind, 1.0)
        faults.append(Fault(kind, float(rng.uniform(0, episode_s)), float(rng.uniform(0.2, 5.0)), float(sev)))
    return FaultSchedule(faults)

