"""Mortari's Pyramid (Mortari, Samaan, Bruccoleri & Junkins 2004), as paper 002 §2.1 describes it.

Triads ``(i, j, k)`` of the brightest detections are taken in the "smart" order, which changes all
three indices as fast as possible so that a false star does not spoil a long run of triads::

    for dj in 1 .. n-2:  for dk in 1 .. n-dj-1:  for i in 1 .. n-dj-dk:   (i, i+dj, i+dj+dk)

Within blocks of ten triads of that order the cheapest are tried first (the cost of a triad is the size
of its two shortest pair windows: short sides have few catalog pairs). For each triad the three
inter-star angles are looked up in the star-pair catalog with the k-vector;
the catalog triangles consistent with all three (and with the measured handedness) are the hypotheses.
A hypothesis needs a fourth detection ``r`` whose catalog star has the right angles to all three
(the pyramid); then the common verification decides, and reporting failure is preferred to a
low-confidence answer (two different verified attitudes make the frame ambiguous).

The loop runs compiled (:func:`startracker.kernels.identify.pyramid_search`; without a candidate filter
:func:`startracker.identify.identify` runs the whole frame in one compiled call,
:func:`startracker.kernels.identify.identify_pyramid_detections`); the numpy pieces
(:class:`PairCandidates`, :func:`triangles`, :func:`confirm_fourth`) serve the brightness-referenced
method and as the reference the kernel is tested against. :class:`CandidateFilter` makes the candidate
source injectable (colour-aided identification).
"""

from __future__ import annotations

import math

import numpy as np

from dataclasses import dataclass
from functools import lru_cache

from startracker.identify.frame import Frame, IdentifyOptions
from startracker.identify.pairs import join_equal
from startracker.identify import verification
from startracker.identify.verification import Match, fast_rotation, select_matches
from startracker.kernels.identify import pyramid_search

__all__ = ["smart_triads", "identify_pyramid", "PairCandidates", "triangles", "confirm_fourth", "CandidateFilter"]


def smart_triads(n: int):
    """Mortari's "smart" triad order over ``n`` stars (0-based indices, all C(n, 3) triads)."""
    for dj in range(1, n - 1):
        for dk in range(1, n - dj):
            for i in range(0, n - dj - dk):
                yield i, i + dj, i + dj + dk


class PairCandidates:
    """Catalog candidates of detection pairs, looked up lazily with the k-vector and cached per frame.

    ``get(p, q)`` returns ``(ids_p, ids_q)``: for every catalog pair in the window of the angle between
    detections ``p`` and ``q``, both orientations (``p`` = brighter or dimmer catalog star).
    """

    def __init__(self, pairs, frame: Frame):
        self.pairs = pairs
        self.frame = frame
        self.cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def fetch(self, keys):
        ang, tol = self.frame.angle_rad, self.frame.pair_tol_rad
        first, second = self.pairs.first, self.pairs.second
        for key in keys:
            if key in self.cache:
                continue
            p, q = key
            # The window of one pair is a contiguous slice of the angle-sorted catalog.
            start, stop = self.pairs.range_one(float(ang[p, q]), float(tol[p, q]))
            f = first[start:stop]
            s = second[start:stop]
            self.cache[key] = (np.concatenate([f, s]), np.concatenate([s, f]))

    def get(self, p: int, q: int):
        if (p, q) in self.cache:
            return self.cache[(p, q)]
        if (q, p) in self.cache:
            ids_q, ids_p = self.cache[(q, p)]
            return ids_p, ids_q
        self.fetch([(p, q)])
        return self.cache[(p, q)]

    def count(self, p: int, q: int) -> int:
        return len(self.get(p, q)[0])


def _cross(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (M, 3) arrays (cheaper than numpy.cross for small M)."""
    return np.column_stack(
        [
            x[:, 1] * y[:, 2] - x[:, 2] * y[:, 1],
            x[:, 2] * y[:, 0] - x[:, 0] * y[:, 2],
            x[:, 0] * y[:, 1] - x[:, 1] * y[:, 0],
        ]
    )


def triangles(db, frame: Frame, cands, i: int, j: int, k: int) -> np.ndarray:
    """Catalog triangles ``(a, b, c)`` matching detections ``(i, j, k)`` (angles and handedness).

    The candidates of ``s_i`` are the stars present in both windows ``(i, j)`` and ``(i, k)``; the two
    oriented candidate lists are pruned to them, joined on ``s_i``, and the third side checked.

    Returns
    -------
    ndarray of int, shape (H, 3)
        Navigation indices of the hypotheses.
    """
    empty = np.empty((0, 3), dtype=np.int64)
    ai, bj = cands.get(i, j)
    ai2, ck = cands.get(i, k)
    if len(ai) == 0 or len(ai2) == 0:
        return empty
    mark = np.zeros(db.n_stars, dtype=np.int8)
    mark[ai] = 1
    mark[ai2] |= 2
    k1 = mark[ai] == 3
    k2 = mark[ai2] == 3
    ai, bj, ai2, ck = ai[k1], bj[k1], ai2[k2], ck[k2]
    li, ri = join_equal(ai, ai2)
    if len(li) == 0:
        return empty
    a, b, c = ai[li], bj[li], ck[ri]
    nav = db.nav.vectors
    vb, vc = nav[b], nav[c]
    cos_bc = np.einsum("ij,ij->i", vb, vc)
    th, tol = frame.angle_rad[j, k], frame.pair_tol_rad[j, k]
    ok = (cos_bc <= math.cos(max(th - tol, 0.0))) & (cos_bc >= math.cos(min(th + tol, math.pi)))
    sel = np.flatnonzero(ok)
    if len(sel) == 0:
        return empty
    a, b, c = a[sel], b[sel], c[sel]
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = frame.v[[i, j, k]].tolist()
    s_meas = a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0)
    s_cat = np.einsum("ij,ij->i", nav[a], _cross(vb[sel], vc[sel]))
    same = (s_cat > 0) == (s_meas > 0)
    return np.column_stack([a[same], b[same], c[same]])


def confirm_fourth(db, frame: Frame, det3, hyp: np.ndarray, pool: int):
    """The pyramid step, batched: which hypotheses have a fourth detection that fits all three stars.

    Under a hypothesis' attitude a fourth detection ``r`` must point at a catalog star ``d``; its three
    angles to ``a, b, c`` then agree with the measured ones within the tolerance exactly when ``d`` lies
    within about that tolerance of the predicted direction. One k-d tree query for all hypotheses and
    all detections gives both this test (on the other stars of the pool) and the first round of the
    verification's matching (on every detection).

    Parameters
    ----------
    det3 : sequence of 3 int
        The detections of the triad.
    hyp : ndarray, shape (H, 3)
    pool : int
        Fourth stars are looked for among detections ``0 .. pool-1``.

    Returns
    -------
    ok : ndarray of bool, shape (H,)
    rot : ndarray, shape (H, 3, 3)
        Triad attitudes.
    first : list of (det, nav, dist) or None
        The unambiguous matches of every detection under each confirmed hypothesis.
    """
    v = frame.v
    nav = db.nav.vectors
    n = frame.n
    rot = fast_rotation(v[list(det3)][None], nav[hyp])
    w = (rot @ v.T).transpose(0, 2, 1).reshape(-1, 3)  # (H*n, 3) predicted ICRS directions
    chord = 2.0 * math.sin(frame.match_tol_rad / 2.0)
    dist, idx = db.tree.query(w, k=2, distance_upper_bound=3.0 * chord)
    dist = dist.reshape(len(hyp), n, 2)
    idx = idx.reshape(len(hyp), n, 2)
    others = np.ones(min(pool, n), dtype=bool)
    others[list(det3)] = False
    ok = (dist[:, : len(others), 0][:, others] <= chord).any(axis=1)
    first = [select_matches(dist[h], idx[h], chord) if ok[h] else None for h in range(len(hyp))]
    return ok, rot, first


@lru_cache(maxsize=64)
def triad_table(pool: int, max_triads: int) -> np.ndarray:
    """The first ``max_triads`` smart triads over ``pool`` stars, (T, 3) int64 (read-only, cached)."""
    out = np.array(list(smart_triads(pool))[:max_triads], dtype=np.int64).reshape(-1, 3)
    out.setflags(write=False)
    return out


@dataclass
class CandidateFilter:
    """The pyramid's candidate source, narrowed by one more per-star feature (e.g. the colour ratio).

    The pyramid's candidates for a detection pair are the catalog pairs in the k-vector window of their
    angle; with a filter, detection ``p`` may only stand for navigation stars ``s`` with
    ``lo[p] <= star_key[s] <= hi[p]`` (an infinite interval admits every star), and the expected number
    of wrong triangles ``λ`` of detections ``(i, j, k)`` is multiplied by ``false_rate_scale[i] ·
    false_rate_scale[j] · false_rate_scale[k]`` (the fraction of the catalog each detection admits), so
    the false-alarm rule keeps its meaning.

    Attributes
    ----------
    star_key : ndarray, shape (N,)
        Feature of each navigation star.
    lo, hi : ndarray, shape (n,)
        Admissible interval of each usable detection (frame order).
    false_rate_scale : ndarray, shape (n,)
        Fraction of the navigation stars each detection admits (1 without the feature).
    pairs_geometric, pairs_kept : int
        Filled by :func:`identify_pyramid`: catalog pair candidates (both orientations) in the windows
        looked up, and those the filter kept.
    """

    star_key: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    false_rate_scale: np.ndarray
    pairs_geometric: int = 0
    pairs_kept: int = 0


_NO_KEY = np.zeros(1)
_ONES = np.ones(256)  # the per-detection λ factors without a filter (only the first n are read)
SEARCH_STATUS = {1: "ambiguous: two different attitudes verified", 2: "no triad was confirmed and verified"}
CHEAP_FIRST = 10  # triads are tried cheapest first within blocks of this many (smart order across blocks)


def identify_pyramid(db, frame: Frame, opts: IdentifyOptions,
                     candidates: CandidateFilter | None = None) -> tuple[Match | None, str, int]:
    """Pyramid identification; returns (match, status, hypotheses verified).

    The whole loop (triads, pair windows, triangles, the fourth star, verification, the ambiguity rule)
    runs in :func:`startracker.kernels.identify.pyramid_search`.

    Parameters
    ----------
    db : StarDatabase
    frame : Frame
    opts : IdentifyOptions
    candidates : CandidateFilter, optional
        Narrows the candidate source (a method with one more per-star feature); None: angles only.
    """
    n = frame.n
    if n < 3:
        return None, "fewer than 3 usable detections", 0
    pool = min(n, opts.max_stars or 12, len(frame.angle_rad))
    triads = triad_table(pool, opts.max_triads)
    if candidates is None:
        rate = _ONES if n <= len(_ONES) else np.ones(n)
        key, lo, hi, filtered = _NO_KEY, _NO_KEY, _NO_KEY, False
    else:
        key = np.ascontiguousarray(candidates.star_key, dtype=np.float64)
        lo = np.ascontiguousarray(candidates.lo, dtype=np.float64)
        hi = np.ascontiguousarray(candidates.hi, dtype=np.float64)
        rate = np.ascontiguousarray(candidates.false_rate_scale, dtype=np.float64)
        filtered = True
    status, det, nav, n_req, n_hyp, rot, rms, counts = pyramid_search(
        frame.v, frame.angle_rad, frame.pair_tol_rad, triads, CHEAP_FIRST, pool, *db.search_arrays, key, lo, hi,
        filtered, rate, db.clumping3, db.density_eff_per_sr, frame.match_tol_rad, opts.false_alarm,
        verification.MAX_ROUNDS, verification.STABLE_FIT, verification.MISFIT_P)
    if candidates is not None:
        candidates.pairs_geometric += int(counts[0])
        candidates.pairs_kept += int(counts[1])
    if status == 0:
        return Match(rot=rot, det=det, nav=nav, n_required=int(n_req), rms_rad=float(rms)), "ok", int(n_hyp)
    return None, SEARCH_STATUS[int(status)], int(n_hyp)
