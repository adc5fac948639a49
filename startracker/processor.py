"""The star tracker's on-board processor: a deterministic budget of how long a frame takes to process.

A sample leaves the tracker some time after its exposure: the detector is read out, the stars are centroided,
identified (lost in space) or matched to their predictions (tracking), and an attitude is solved per exposure
instant. :class:`ProcessorModel` gives each stage a cost in milliseconds; :meth:`ProcessorModel.frame_latency_ms`
adds them up for one frame from what the frame held. The figure is a model, not a measurement, so a run with the
same seed has the same latencies on every machine (the wall clock of this machine's Python is something else).
"""

from __future__ import annotations

from dataclasses import dataclass

from startracker.validation import check_real

__all__ = ["ProcessorModel"]


@dataclass(frozen=True)
class ProcessorModel:
    """Per-stage processing budget of a star tracker's processor, ms.

    The default is a radiation-tolerant embedded processor of the LEON4 / Cortex-R class (~100-200 MIPS) behind an
    FPGA that thresholds the pixels during readout, the architecture of today's commercial trackers:

    - ``readout_ms`` 5: reading the detector (windowed while tracking) and the FPGA's pixel pass, which streams;
    - ``centroid_ms_per_detection`` 0.005: first moments of one ~5×5 window, a few hundred instructions;
    - ``match_ms_per_detection`` 0.005: one look-up of the double k-vector table and its candidates per detection;
    - ``solve_ms_per_instant`` 0.1: one Wahba solution (q-method on 3×3 sums of ~20 stars) and its covariance;
    - ``identify_ms`` 30: a lost-in-space identification (pyramid search in the on-board database) when the
      tracker is not tracking;
    - ``overhead_ms`` 1: scheduling and the output message.

    A tracking frame of ~50 stars × 21 exposures then takes ~18 ms, inside the 10-100 ms "data latency" that
    commercial trackers specify, and a lost-in-space frame ~40 ms.

    Attributes
    ----------
    readout_ms, centroid_ms_per_detection, match_ms_per_detection, solve_ms_per_instant, identify_ms, overhead_ms :
        float
        Stage costs, ms (>= 0). ``ProcessorModel.instantaneous()`` is the tracker that computes in zero time.
    """

    readout_ms: float = 5.0
    centroid_ms_per_detection: float = 0.005
    match_ms_per_detection: float = 0.005
    solve_ms_per_instant: float = 0.1
    identify_ms: float = 30.0
    overhead_ms: float = 1.0

    def __post_init__(self):
        for name in ("readout_ms", "centroid_ms_per_detection", "match_ms_per_detection", "solve_ms_per_instant",
                     "identify_ms", "overhead_ms"):
            object.__setattr__(self, name, check_real(getattr(self, name), name, lo=0.0))

    @classmethod
    def instantaneous(cls) -> "ProcessorModel":
        """A processor with no delay at all (every sample reaches the filter at its exposure instant's frame end)."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    @classmethod
    def fixed(cls, latency_ms: float) -> "ProcessorModel":
        """A processor whose every frame takes ``latency_ms`` (all of it in the readout stage)."""
        return cls(readout_ms=latency_ms, centroid_ms_per_detection=0.0, match_ms_per_detection=0.0,
                   solve_ms_per_instant=0.0, identify_ms=0.0, overhead_ms=0.0)

    def frame_latency_ms(self, n_detections: int, n_instants: int, identified: bool) -> float:
        """Time from the end of a frame to its samples leaving the tracker, ms.

        Parameters
        ----------
        n_detections : int
            Detections of the frame (all exposures).
        n_instants : int
            Attitude solutions (exposure instants solved).
        identified : bool
            A lost-in-space identification ran (the tracker was not tracking), instead of matching.

        Returns
        -------
        float
        """
        work = self.centroid_ms_per_detection * n_detections + self.solve_ms_per_instant * n_instants
        work += self.identify_ms if identified else self.match_ms_per_detection * n_detections
        return self.readout_ms + self.overhead_ms + work
