"""Distributed multiple fields of view (paper 001: "A Novel Inertial-aided Star Pattern Matching Method for
Distributed Multiple FoVs").

Several small, non-overlapping optical heads at large installation angles on one body; the stars of the
auxiliary heads are moved into the extended image plane of the main head and matched as one picture, with
the INS attitude narrowing the search. In import order:

* :mod:`~startracker.multifov.heads`: the heads and the fused FoV (:class:`MultiFovSensor`,
  :class:`FusedImage`, :class:`SkyView`, :func:`paper001_head`, eqs. 1-5);
* :mod:`~startracker.multifov.ins_error`: the INS attitude error from gyro drift
  (:func:`propagate_attitude_error`, :func:`attitude_sigma_bound_rad`);
* :mod:`~startracker.multifov.local_catalog`: the predicted observed scope of each head and its local star
  catalog (:func:`predict_scopes`, :class:`LocalCatalog`, eqs. 6-14);
* :mod:`~startracker.multifov.matcher`: the inertial-aided cross-FoV matcher (:class:`InertialAidedMatcher`);
* :mod:`~startracker.multifov.tally`: scoring like paper 001, the method's successes apart from all-sky
  fallbacks (:class:`MatchTally`, :func:`classify_identification`).

The subsystem uses the mono-tracker rooms (optics, catalog, kvector, attitude, identify's result type);
none of them imports it (tests/test_layering.py).
"""

from startracker.multifov.heads import (
    PAPER001_HEAD,
    FusedImage,
    MultiFovSensor,
    SkyView,
    installation_quaternions,
    paper001_head,
)
from startracker.multifov.ins_error import attitude_sigma_bound_rad, propagate_attitude_error
from startracker.multifov.local_catalog import LocalCatalog, ObservedScope, PairTable, los_bias_angles, predict_scopes
from startracker.multifov.matcher import InertialAidedMatcher, MultiFovResult
from startracker.multifov.tally import OUTCOMES, MatchTally, classify_identification

__all__ = [
    "MultiFovSensor",
    "FusedImage",
    "SkyView",
    "installation_quaternions",
    "PAPER001_HEAD",
    "paper001_head",
    "propagate_attitude_error",
    "attitude_sigma_bound_rad",
    "ObservedScope",
    "predict_scopes",
    "PairTable",
    "LocalCatalog",
    "los_bias_angles",
    "MultiFovResult",
    "InertialAidedMatcher",
    "OUTCOMES",
    "MatchTally",
    "classify_identification",
]
