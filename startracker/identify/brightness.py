"""Brightness-referenced identification (paper 002, Zhang, Wang et al., Sensors 2014, §4.3).

The detections ``s_1 .. s_n`` (at most the ``max_stars`` brightest, 10 in the paper) are sorted by
intensity. Intensities serve twice, never as an absolute magnitude look-up:

* Ordering. When two detections' measured magnitudes differ by more than ``γ``, the brighter must be the
  brighter star ``I`` of its catalog pair and the dimmer ``J``; within ``γ`` both orientations are kept.
* Reference stars. A detection brighter than ``ref_mag`` (intensity above ``Mt``; magnitude 3 in the
  paper) is searched in the reference-pair catalog only (pairs whose brighter star is a bright star),
  a much smaller range.

Reference-star (three-star) mode, when ``n >= 4`` and ``s_1`` is brighter than ``Mt``. Loop order of
Fig. 5: ``i = 1 .. n−2`` while ``s_i`` is brighter than ``Mt``; ``j = n .. i+2``; ``k = j−1 .. i+1``
(the brightest with the dimmest). The k-vector ranges of pairs ``s_i s_j`` and ``s_i s_k`` give two
candidate sets for ``s_i``; their intersection ``R_i``, when non-empty and unique, identifies ``s_i``, its
partners identify ``s_j`` and ``s_k``, and the catalog angle ``θ_jk`` must match ``δ_jk`` (check step).

Four-star mode, otherwise (or when the reference mode found nothing): ``s_i`` with three dimmer stars
``s_j, s_k, s_l`` taken from the dim end (``j = n ..``, ``k = j−1 ..``, ``l = k−1 ..``); the three ranges of
``s_i s_j``, ``s_i s_k``, ``s_i s_l`` are intersected on ``s_i`` and the three remaining angles checked.

``n = 3``: only the uniqueness of the triangle can be checked. Every accepted group then goes through the
common verification (Wahba, re-projection, enough confirming stars).
"""

from __future__ import annotations

import numpy as np

from startracker.identify.frame import Frame, IdentifyOptions
from startracker.identify.pairs import join_equal
from startracker.identify.pyramid import triangles
from startracker.identify.verification import Match, best_of, triangle_false_rate, verify

__all__ = ["identify_brightness", "OrderedCandidates"]


class OrderedCandidates:
    """Catalog candidates of detection pairs ``(p, q)``, ``p`` brighter, with the brightness ordering.

    Parameters
    ----------
    pairs : StarPairCatalog
    frame : Frame
    gamma : float
        Magnitude difference above which the orientation is fixed (``p`` -> ``I``).
    first_mag_cap : float, optional
        Only catalog stars at least this bright may stand for ``p`` (reference mode).
    """

    def __init__(self, pairs, frame: Frame, gamma: float, first_mag_cap: float | None = None):
        self.pairs = pairs
        self.frame = frame
        self.gamma = gamma
        self.cap = first_mag_cap
        self.cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def get(self, p: int, q: int):
        """``(ids_p, ids_q)`` for detections ``p`` (brighter) and ``q``, looked up lazily (k-vector)."""
        key = (p, q)
        hit = self.cache.get(key)
        if hit is not None:
            return hit
        fr = self.frame
        pairs = self.pairs
        start, stop = pairs.range_one(float(fr.angle_rad[p, q]), float(fr.pair_tol_rad[p, q]))
        f, s = pairs.first[start:stop], pairs.second[start:stop]
        fixed = fr.mag[q] - fr.mag[p] > self.gamma
        if self.cap is None:
            hit = (f, s) if fixed else (np.concatenate([f, s]), np.concatenate([s, f]))
        else:
            ok_fwd = pairs.first_mag[start:stop] <= self.cap
            if fixed:
                hit = (f[ok_fwd], s[ok_fwd])
            else:
                ok_rev = pairs.second_mag[start:stop] <= self.cap
                hit = (np.concatenate([f[ok_fwd], s[ok_rev]]), np.concatenate([s[ok_fwd], f[ok_rev]]))
        self.cache[key] = hit
        return hit


def _verify_group(db, frame, opts, det, hyp, matches):
    lam = triangle_false_rate(frame, det[0], det[1], det[2], float(db.n_stars), db.clumping3)
    for h in hyp:
        m = verify(db, frame, np.asarray(det), h, lam, opts.false_alarm)
        if m is not None:
            matches.append(m)
    return len(hyp)


def _reference_mode(db, frame, opts, n, matches_out):
    cap = opts.ref_mag + 3.0 * opts.mag_sigma
    pairs = db.ref_pairs if (db.ref_pairs is not None and db.ref_mag_limit >= cap) else db.pairs
    cands = OrderedCandidates(pairs, frame, opts.gamma, first_mag_cap=cap)
    n_hyp = 0
    tried = 0
    for i in range(n - 2):
        if frame.mag[i] >= opts.ref_mag:
            break
        for j in range(n - 1, i + 1, -1):
            for k in range(j - 1, i, -1):
                tried += 1
                if tried > opts.max_combinations:
                    return n_hyp
                hyp = triangles(db, frame, cands, i, k, j)  # (s_i, s_k, s_j): both pairs share s_i
                if len(hyp) == 0 or len(np.unique(hyp[:, 0])) != 1:
                    continue  # R_i empty or not unique
                matches = []
                n_hyp += _verify_group(db, frame, opts, (i, k, j), hyp, matches)
                best, _ = best_of(matches, frame.match_tol_rad)
                if best is not None:
                    matches_out.append(best)
                    return n_hyp
    return n_hyp


def _four_star_mode(db, frame, opts, n, matches_out):
    cands = OrderedCandidates(db.pairs, frame, opts.gamma)
    nav = db.nav.vectors
    n_hyp = 0
    tried = 0
    for i in range(n - 3):
        for j in range(n - 1, i + 2, -1):
            for k in range(j - 1, i + 1, -1):
                tri = None
                for l in range(k - 1, i, -1):
                    tried += 1
                    if tried > opts.max_combinations:
                        return n_hyp
                    # Intersection of the three ranges on s_i.
                    a_l, d_l = cands.get(i, l)
                    if tri is None:
                        tri = triangles(db, frame, cands, i, j, k)  # checks δ_jk (and handedness)
                    if len(tri) == 0:
                        break
                    ti, li = join_equal(tri[:, 0], a_l)
                    if len(ti) == 0:
                        continue
                    b, c, d = tri[ti, 1], tri[ti, 2], d_l[li]
                    ok = (d != b) & (d != c)
                    for x, (p, q) in ((b, (j, l)), (c, (k, l))):
                        ang = np.arccos(np.clip(np.einsum("ij,ij->i", nav[x], nav[d]), -1, 1))
                        ok &= np.abs(ang - frame.angle_rad[p, q]) <= frame.pair_tol_rad[p, q]
                    if not ok.any():
                        continue
                    hyp = np.column_stack([tri[ti, 0], b, c, d])[ok]
                    hyp = np.unique(hyp, axis=0)
                    matches = []
                    n_hyp += _verify_group(db, frame, opts, (i, j, k, l), hyp, matches)
                    best, _ = best_of(matches, frame.match_tol_rad)
                    if best is not None:
                        matches_out.append(best)
                        return n_hyp
    return n_hyp


def identify_brightness(db, frame: Frame, opts: IdentifyOptions) -> tuple[Match | None, str, int]:
    """Brightness-referenced identification; returns (match, status, hypotheses verified)."""
    if frame.mag is None:
        raise ValueError("intensities are required for method='brightness'")
    n = min(frame.n, opts.max_stars or 10, len(frame.angle_rad))
    if n < 3:
        return None, "fewer than 3 usable detections", 0
    found: list[Match] = []
    if n == 3:
        cands = OrderedCandidates(db.pairs, frame, opts.gamma)
        hyp = triangles(db, frame, cands, 0, 1, 2)
        if len(hyp) != 1:
            return None, "three stars: no unique triangle", len(hyp)
        n_hyp = _verify_group(db, frame, opts, (0, 1, 2), hyp, found)
        if found:
            return found[0], "ok", n_hyp
        return None, "three stars: unique triangle not verified", n_hyp
    n_hyp = 0
    if frame.mag[0] < opts.ref_mag:
        n_hyp += _reference_mode(db, frame, opts, n, found)
        if found:
            return found[0], "ok", n_hyp
    n_hyp += _four_star_mode(db, frame, opts, n, found)
    if found:
        return found[0], "ok", n_hyp
    return None, "no star group was unique and verified", n_hyp
