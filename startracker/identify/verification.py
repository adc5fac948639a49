"""The verification every method ends with, and the false-alarm rule that decides acceptance.

A hypothesis (some detections paired with navigation stars) gives an attitude (Wahba, SVD). Every
detection is rotated into ICRS and matched to the nearest navigation star within the verification
radius (the same as re-projecting the catalog into the image and matching there, but in angle space,
so it holds across the whole detector), one catalog star per detection; a detection with a second
catalog star almost as near is ambiguous and left out. The attitude is refitted on all matches and the
matching repeated until the set of matches no longer changes.

Acceptance. A wrong hypothesis built from three detections is a catalog triangle that happens to fit
the measured one. For a triangle with sides known to ``±ε`` the expected number of such catalog
triangles (with the right handedness) is, for ``N`` stars spread over the sphere,

    λ = 2 N³ ε³ R / π · c₃

with ``R`` the triangle's circumradius (small-angle geometry: ``λ`` grows as the triangle flattens,
where mirror images become ambiguous) and ``c₃ = ⟨ρ³⟩ / ⟨ρ⟩³`` the clumping of the catalog (Milky Way),
measured once per database. Under a wrong attitude each other detection lands within the verification
radius ``r`` of some catalog star with probability ``p = ρ_eff π r²``. A hypothesis is accepted with
``3 + e`` matches only when ``λ · P(Binomial(n − 3, p) ≥ e) ≤ false_alarm`` (and ``e ≥ 1`` whenever a
fourth detection exists), so the required number of confirming stars grows with loose tolerances,
dense catalogs and many detections, and shrinks for precise measurements.

Misfit test. The unmatched detections must look like false stars: at random places, so few of them have
a catalog star just beyond the radius (between r and 3r); more near misses than a Poisson law allows at
1e-3 mean the attitude is slightly wrong (a thin triad can converge to a self-consistent wrong roll that
matches only the stars around it) and the hypothesis is refused. Two different attitudes that both pass
make the frame ambiguous (:func:`best_of`): failure is reported rather than a coin toss.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from startracker.identify.frame import Frame
from startracker.kernels.identify import binom_tail, verify_hypothesis

MAX_ROUNDS = 8  # refinement rounds of the verification
STABLE_FIT = 10  # matches above which a refit that only adds matches ends the refinement
MISFIT_P = 1e-3  # near misses less likely than this under a correct attitude reject it
_EYE = np.eye(3)

__all__ = ["Match", "fast_rotation", "triangle_false_rate", "required_matches", "verify", "match_detections", "select_matches", "best_of"]


@dataclass
class Match:
    """A verified identification.

    Attributes
    ----------
    rot : ndarray, shape (3, 3)
        Camera -> ICRS rotation matrix fitted on the final matches.
    det : ndarray of int, shape (m,)
        Matched detections (frame indices).
    nav : ndarray of int, shape (m,)
        Their navigation-catalog indices.
    n_required : int
        Matches the false-alarm rule asked for.
    rms_rad : float
        RMS angular residual of the matches.
    """

    rot: np.ndarray
    det: np.ndarray
    nav: np.ndarray
    n_required: int
    rms_rad: float

    @property
    def n_matched(self) -> int:
        return len(self.det)


def fast_rotation(b, r) -> np.ndarray:
    """Unweighted Wahba rotation(s) by SVD (Markley), ``r ≈ R @ b``.

    Parameters
    ----------
    b : ndarray, shape (..., m, 3)
        Measured unit vectors (camera frame).
    r : ndarray, shape (..., m, 3)
        Reference unit vectors (ICRS).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Proper rotation matrices. Used to score hypotheses; the reported attitude comes from
        :func:`startracker.attitude.solve_wahba`.
    """
    att = np.swapaxes(r, -1, -2) @ b
    u, _, vt = np.linalg.svd(att)
    rot = u @ vt
    if rot.ndim == 2:
        det = (rot[0, 0] * (rot[1, 1] * rot[2, 2] - rot[1, 2] * rot[2, 1])
               - rot[0, 1] * (rot[1, 0] * rot[2, 2] - rot[1, 2] * rot[2, 0])
               + rot[0, 2] * (rot[1, 0] * rot[2, 1] - rot[1, 1] * rot[2, 0]))
        if det < 0:
            u[:, 2] = -u[:, 2]
            rot = u @ vt
        return rot
    flip = np.linalg.det(rot) < 0
    if np.any(flip):
        u[..., :, 2] = np.where(flip[..., None], -u[..., :, 2], u[..., :, 2])
        rot = u @ vt
    return rot


def triangle_false_rate(frame: Frame, i: int, j: int, k: int, n_stars: float, clumping: float) -> float:
    """Expected number of wrong catalog triangles matching detections (i, j, k), ``λ`` above."""
    a, b, c = frame.angle_rad[i, j], frame.angle_rad[i, k], frame.angle_rad[j, k]
    eps = (frame.pair_tol_rad[i, j] * frame.pair_tol_rad[i, k] * frame.pair_tol_rad[j, k]) ** (1.0 / 3.0)
    s = 0.5 * (a + b + c)
    area2 = max(s * (s - a) * (s - b) * (s - c), 0.0)
    area = math.sqrt(area2)
    radius = a * b * c / (4.0 * area) if area > 0 else np.inf
    radius = min(radius, 10.0)
    return 2.0 * n_stars**3 * eps**3 * radius / math.pi * clumping


def _poisson_tail(mu: float, k: int) -> float:
    """P(Poisson(mu) >= k)."""
    if k <= 0:
        return 1.0
    term = math.exp(-mu)
    cdf = 0.0
    for x in range(k):
        cdf += term
        term *= mu / (x + 1)
    return max(0.0, 1.0 - cdf)


def required_matches(lam: float, n_det: int, p: float, false_alarm: float) -> int:
    """Smallest number of matched detections that keeps ``λ · P(chance confirmations)`` below the limit.

    Parameters
    ----------
    lam : float
        Expected number of wrong hypotheses of this kind.
    n_det : int
        Usable detections in the frame.
    p : float
        Probability that one detection lands near some catalog star under a wrong attitude.
    false_alarm : float

    Returns
    -------
    int
        ``3 + e``; more than ``n_det`` when no number of matches would be convincing.
    """
    n_other = n_det - 3
    e = 1 if n_other >= 1 else 0
    while e <= n_other:
        if lam * binom_tail(int(n_other), float(p), int(e)) <= false_alarm:
            return 3 + e
        e += 1
    return n_det + 1


def select_matches(dist: np.ndarray, idx: np.ndarray, chord: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unambiguous, one-to-one matches from a two-nearest-neighbour query (see :func:`match_detections`).

    Parameters
    ----------
    dist, idx : ndarray, shape (n, 2)
        Chord distances and navigation indices of the two nearest stars of each detection.
    chord : float
        Verification radius as a chord.
    """
    det = np.flatnonzero((dist[:, 0] <= chord) & (dist[:, 1] > dist[:, 0] + chord))
    nav = idx[det, 0]
    d = dist[det, 0]
    if len(nav) > 1 and len(set(nav.tolist())) < len(nav):
        o = np.lexsort((d, nav))
        first = np.ones(len(o), dtype=bool)
        first[1:] = nav[o][1:] != nav[o][:-1]
        keep = np.sort(o[first])
        det, nav, d = det[keep], nav[keep], d[keep]
    return det, nav, d


def match_detections(db, v_icrs: np.ndarray, tol_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest navigation star of each direction within ``tol_rad``, unambiguous and one star per detection.

    A detection whose second-nearest catalog star is not at least ``tol_rad`` farther than the nearest
    is ambiguous (two stars a few noise widths apart) and stays unmatched; a star claimed by two
    detections keeps the nearer one.

    Parameters
    ----------
    db : StarDatabase
    v_icrs : ndarray, shape (n, 3)
        Detections rotated into ICRS.
    tol_rad : float

    Returns
    -------
    det, nav : ndarray of int, shape (m,)
        Matched detection rows and navigation indices.
    dist : ndarray, shape (m,)
        Chord distances.
    """
    chord = 2.0 * math.sin(tol_rad / 2.0)
    dist, idx = db.tree.query(v_icrs, k=2, distance_upper_bound=3.0 * chord)
    return select_matches(dist, idx, chord)


def verify(db, frame: Frame, det_idx, nav_idx, lam: float, false_alarm: float, rot=None, first=None) -> Match | None:
    """Check one hypothesis against all detections; a :class:`Match` when it passes, else None.

    Parameters
    ----------
    db : StarDatabase
    frame : Frame
    det_idx, nav_idx : array_like of int, shape (h,)
        The hypothesis: detection ``det_idx[t]`` is navigation star ``nav_idx[t]`` (h >= 2).
    lam : float
        Expected number of wrong hypotheses of this kind (:func:`triangle_false_rate`).
    false_alarm : float
    rot : ndarray, shape (3, 3), optional
        The hypothesis attitude if already computed.
    first : (det, nav), optional
        Ignored (kept for callers that computed the first matches; the compiled verification
        recomputes them under ``rot``, with the same result).

    The loop runs in :func:`startracker.kernels.identify.verify_hypothesis`.
    """
    det0 = np.ascontiguousarray(det_idx, dtype=np.int64)
    nav0 = np.ascontiguousarray(nav_idx, dtype=np.int64)
    have_rot = rot is not None
    rot0 = np.ascontiguousarray(rot, dtype=np.float64) if have_rot else _EYE
    ok, rot_v, det, nav, n_req, rms = verify_hypothesis(
        frame.v, db.nav.vectors, db.grid_start, db.grid_stars, db.grid_cells, det0, nav0, rot0, have_rot, lam,
        false_alarm, frame.match_tol_rad, db.density_eff_per_sr, MAX_ROUNDS, STABLE_FIT, MISFIT_P)
    if not ok:
        return None
    return Match(rot=rot_v, det=det, nav=nav, n_required=int(n_req), rms_rad=float(rms))


def best_of(matches: list[Match], tol_rad: float) -> tuple[Match | None, str]:
    """The hypothesis to report among verified ones; refuse when two different attitudes both pass.

    Two matches that agree on the attitude (within the verification radius) are the same answer. When
    they disagree the one with more matches wins only if it has at least twice as many confirming stars
    beyond the required number; otherwise the frame is ambiguous.
    """
    if not matches:
        return None, "no hypothesis verified"
    matches = sorted(matches, key=lambda m: (-m.n_matched, m.rms_rad))
    best = matches[0]
    for other in matches[1:]:
        c = (np.trace(best.rot.T @ other.rot) - 1.0) / 2.0
        ang = math.acos(max(-1.0, min(1.0, c)))
        if ang > tol_rad:
            margin_best = best.n_matched - 3
            margin_other = other.n_matched - 3
            if margin_best < 2 * margin_other + 2:
                return None, "ambiguous: two different attitudes verified"
    return best, "ok"
