"""Scoring inertial-aided identifications like for like with paper 001: the method's own successes apart from
the all-sky fallbacks.

Paper 001's success rate (98.80 / 88.58 / 41.67 % for gyro drifts 0.004 / 1 / 5 °/h, §4.2) is the share of epochs
that the *inertial-aided* matcher identifies correctly against its part catalog. :class:`InertialAidedMatcher`
falls back to the all-sky catalog when the INS error radius is too large (or, with ``retry_all_sky``, when the part
catalog fails); an identification found that way is a lost-in-space success, not one of the method's. Counting it
as the method's would hide exactly the loss the paper measures (a drifting INS whose part catalog no longer holds
the imaged stars). So every frame is put in exactly one class:

* ``"method"``: a correct identification from the part catalog (``fallback_all_sky`` False): the method's success;
* ``"fallback"``: a correct identification by the all-sky fallback: counted apart, **not** a success of the method;
* ``"wrong"``: a reported success that is not correct (either catalog): must stay 0;
* ``"failed"``: no identification.

Correct means: at least 3 stars matched, every identified detection carries its true HIP number (a false star left
unmatched is right, a false star given a HIP number is wrong), and the attitude lies within ``max(10", 6σ)`` of the
truth, σ the largest axis of the result's own covariance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from startracker.attitude import RAD_TO_ARCSEC
from startracker.rotations import quat_angle_between
from startracker.validation import as_float_array

__all__ = ["OUTCOMES", "classify_identification", "MatchTally"]

OUTCOMES = ("method", "fallback", "wrong", "failed")
"""The classes of :func:`classify_identification`, each frame in exactly one."""


def classify_identification(result, truth_hip, q_true_body_to_icrs) -> str:
    """The class of one identification against the truth (module docstring).

    Parameters
    ----------
    result : startracker.multifov.MultiFovResult
    truth_hip : array_like of int, shape (n,)
        True HIP number of every detection in the result's order (heads concatenated), −1 for a false star.
    q_true_body_to_icrs : array_like, shape (4,)
        True body attitude.

    Returns
    -------
    str
        One of :data:`OUTCOMES`.
    """
    truth = np.asarray(truth_hip, dtype=np.int64).ravel()
    ids = np.asarray(result.star_ids, dtype=np.int64).ravel()
    if len(truth) != len(ids):
        raise ValueError(f"truth_hip has {len(truth)} entries, the result {len(ids)} detections")
    q_true = as_float_array(q_true_body_to_icrs, "q_true_body_to_icrs", last_dim=4, ndim=1)
    if not result.success:
        return "failed"
    ids_ok = bool(np.all((ids == truth) | (ids == -1))) and result.n_matched >= 3
    err_arcsec = quat_angle_between(result.q_body_to_icrs, q_true) * RAD_TO_ARCSEC
    sigma_arcsec = np.sqrt(np.linalg.eigvalsh(result.covariance_rad2)[-1]) * RAD_TO_ARCSEC
    if not (ids_ok and err_arcsec < max(10.0, 6.0 * sigma_arcsec)):
        return "wrong"
    return "fallback" if result.fallback_all_sky else "method"


@dataclass
class MatchTally:
    """Counts of :func:`classify_identification` over frames.

    Attributes
    ----------
    counts : dict
        Frames per class of :data:`OUTCOMES`.
    """

    counts: dict = field(default_factory=lambda: dict.fromkeys(OUTCOMES, 0))

    def add(self, result, truth_hip, q_true_body_to_icrs) -> str:
        """Classify one frame, count it, and return its class."""
        outcome = classify_identification(result, truth_hip, q_true_body_to_icrs)
        self.counts[outcome] += 1
        return outcome

    @property
    def frames(self) -> int:
        """Frames counted."""
        return sum(self.counts.values())

    @property
    def method_success_pct(self) -> float:
        """The method's success rate (paper 001's figure): correct part-catalog identifications over all frames, %."""
        return 100.0 * self.counts["method"] / self.frames if self.frames else float("nan")

    @property
    def fallback_pct(self) -> float:
        """Frames identified by the all-sky fallback (correctly), %: not successes of the method."""
        return 100.0 * self.counts["fallback"] / self.frames if self.frames else float("nan")
