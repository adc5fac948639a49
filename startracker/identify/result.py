"""The result every identification method returns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["IdentificationResult"]


@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of one lost-in-space identification.

    Attributes
    ----------
    success : bool
        True only when the verification accepted an attitude.
    star_ids : ndarray of int, shape (K,)
        HIP number of each input detection (in the caller's order), −1 when unidentified (false star,
        star not in the catalog, detection off the detector, or failure).
    q_cam_to_icrs : ndarray, shape (4,)
        Attitude (w, x, y, z), camera frame -> ICRS, solved on all matches with
        :func:`startracker.attitude.solve_wahba_single` (the single-problem form of ``solve_wahba``:
        SVD, QUEST covariance); the identity when ``success`` is False.
    n_matched : int
        Detections identified.
    residual_arcsec : float
        RMS angle between matched detections and their catalog stars; inf when ``success`` is False.
    latency_ms : float
        Wall-clock time of the identification (database look-up included, database build excluded).
    status : str
        "ok" or the reason for the failure.
    method : str
    n_required : int
        Matches the false-alarm rule asked for (0 when no hypothesis got that far).
    n_hypotheses : int
        Hypotheses that reached verification.
    covariance_rad2 : ndarray, shape (3, 3)
        QUEST covariance of the attitude error (camera frame), inf on failure.
    """

    success: bool
    star_ids: np.ndarray
    q_cam_to_icrs: np.ndarray
    n_matched: int
    residual_arcsec: float
    latency_ms: float
    status: str
    method: str
    n_required: int = 0
    n_hypotheses: int = 0
    covariance_rad2: np.ndarray | None = None
