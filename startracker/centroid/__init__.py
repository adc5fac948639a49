"""Detections and sub-pixel centroids: from an image, from sparse pixels, or from scene truth.

Centroiding (paper 002 §3)
--------------------------
1. Background: the image's level and noise σ, from sigma-clipped statistics of 64×64 blocks (every
   second pixel), fitted by a plane (default), kept per block ("local") or pooled ("global").
2. Threshold: a pixel belongs to a spot when ``DN > background + k σ``; spots are the 8-connected
   components (``scipy.ndimage.label``); their pixels are gathered once (no ``center_of_mass`` over
   the frame) and measured with ``numpy.bincount``.
3. Centre of mass (§3.1, eqs. 1–3): ``x = Σ x DN' / Σ DN'`` over the component with the background
   subtracted, ``DN' = DN − background``.
4. Gaussian interpolation (§3.2, Quine 2007, eqs. 4–6): the brightest pixel and its brighter neighbour
   along each axis; their ratio equals ``g(x; a, b) / g(x; c, d)`` with ``g`` the Gaussian integrated
   over a pixel (eq. 5). The paper linearises this to a quadratic; here the ratio is inverted exactly
   (bisection, monotone in the offset). σ is ``psf_sigma_px`` if given, else estimated per spot from the
   log-parabola through the three pixels. Saturated spots fall back to the centre of mass.

Every spot is one detection, brightest (largest intensity) first; grouping spots into stars and
exposures is the tracker's job.

Fidelities of :func:`simulate_detections`
-----------------------------------------
* ``"pixel"``: :func:`startracker.imaging.render_sparse` then the same components and measurements on
  the sparse pixels (connectivity by a neighbour graph, ``scipy.sparse.csgraph``), with the threshold
  at the known background.
* ``"centroid"``: no pixels. Each spot's detection probability, centroid noise (along and across the
  smear) and intensity follow the linearised theory of a thresholded centre of mass on the same
  detector model, with three factors calibrated against the pixel path (:class:`CentroidErrorModel`,
  :func:`calibrate_error_model`); hot pixels, cosmic rays, debris and the background's threshold
  crossings are drawn from the same statistics as in the pixel path.

Modules
-------
* :mod:`~startracker.centroid.extraction`: :class:`Centroids`, :func:`estimate_background`,
  :func:`extract_centroids`, :func:`detections_from_sparse`.
* :mod:`~startracker.centroid.fidelity`: :class:`CentroidErrorModel`, :func:`default_error_model`,
  :func:`simulate_detections`, :func:`calibrate_error_model`.
"""

from startracker.centroid.extraction import (
    Centroids,
    check_k_sigma,
    check_method,
    check_min_area,
    check_psf_sigma,
    detections_from_sparse,
    estimate_background,
    extract_centroids,
)
from startracker.centroid.fidelity import (
    DEFAULT_ERROR_MODELS,
    CentroidErrorModel,
    calibrate_error_model,
    default_error_model,
    simulate_detections,
)

__all__ = [
    "Centroids",
    "estimate_background",
    "extract_centroids",
    "detections_from_sparse",
    "check_k_sigma",
    "check_method",
    "check_min_area",
    "check_psf_sigma",
    "CentroidErrorModel",
    "DEFAULT_ERROR_MODELS",
    "default_error_model",
    "simulate_detections",
    "calibrate_error_model",
]
