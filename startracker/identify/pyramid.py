"""Mortari's Pyramid (Mortari, Samaan, Bruccoleri & Junkins 2004), as paper 002 §2.1 describes it.

Triads ``(i, j, k)`` of the brightest detections are taken in the "smart" order, which changes all
three indices as fast as possible so that a false star does not spoil a long run of triads::

    for dj in 1 .. n-2:  for dk in 1 .. n-dj-1:  for i in 1 .. n-dj-dk:   (i, i+dj, i+dj+dk)

For each triad the three inter-star angles are looked up in the star-pair catalog with the k-vector;
the catalog triangles consistent with all three (and with the measured handedness) are the hypotheses.
A hypothesis needs a fourth detection ``r`` whose catalog star has the right angles to all three
(the pyramid); then the common verification decides, and reporting failure is preferred to a
low-confidence answer (two different verified attitudes make the frame ambiguous).
"""

from __future__ import annotations

import math

import numpy as np

from startracker.identify.frame import Frame, IdentifyOptions
from startracker.identify.verification import Match, best_of, fast_rotation, select_matches, triangle_false_rate, verify

__all__ = ["smart_triads", "identify_pyramid", "PairCandidates", "triangles", "confirm_fourth"]


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


def _join(a_left: np.ndarray, a_right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All index pairs (l, r) with ``a_left[l] == a_right[r]`` (vectorised sort join)."""
    if len(a_left) == 0 or len(a_right) == 0:
        e = np.empty(0, dtype=np.int64)
        return e, e
    key = a_right.astype(np.int16) if a_right.max() < 32768 else a_right  # int16 sorts by radix
    o = np.argsort(key, kind="stable")
    srt = a_right[o]
    lo = np.searchsorted(srt, a_left, side="left")
    hi = np.searchsorted(srt, a_left, side="right")
    cnt = hi - lo
    total = int(cnt.sum())
    if total == 0:
        e = np.empty(0, dtype=np.int64)
        return e, e
    li = np.repeat(np.arange(len(a_left)), cnt)
    offs = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    ri = o[np.repeat(lo, cnt) + offs]
    return li, ri


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
    li, ri = _join(ai, ai2)
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


def identify_pyramid(db, frame: Frame, opts: IdentifyOptions) -> tuple[Match | None, str, int]:
    """Pyramid identification; returns (match, status, hypotheses verified)."""
    n = frame.n
    if n < 3:
        return None, "fewer than 3 usable detections", 0
    pool = min(n, opts.max_stars or 12, len(frame.angle_rad))
    cands = PairCandidates(db.pairs, frame)
    n_stars = float(db.n_stars)
    n_hyp = 0
    ambiguous = False
    for t, (i, j, k) in enumerate(smart_triads(pool)):
        if t >= opts.max_triads:
            break
        cands.fetch([(i, j), (i, k), (j, k)])
        # Apex opposite the widest window: the join then runs on the two shortest candidate lists.
        c_ij, c_ik, c_jk = cands.count(i, j), cands.count(i, k), cands.count(j, k)
        if c_ij >= c_ik and c_ij >= c_jk:
            i, j, k = k, i, j
        elif c_ik >= c_jk:
            i, j, k = j, i, k
        hyp = triangles(db, frame, cands, i, j, k)
        if len(hyp) == 0:
            continue
        ok, rot, first = confirm_fourth(db, frame, (i, j, k), hyp, max(pool, 4))
        if n == 3:
            ok[:] = True  # no fourth star exists: the false-alarm rule alone decides
            first = [None] * len(hyp)
        lam = triangle_false_rate(frame, i, j, k, n_stars, db.clumping3)
        matches = []
        for h in np.flatnonzero(ok):  # hypotheses that survived the pyramid: a handful
            n_hyp += 1
            m = verify(db, frame, np.array([i, j, k]), hyp[h], lam, opts.false_alarm, rot=rot[h], first=first[h])
            if m is not None:
                matches.append(m)
        best, status = best_of(matches, frame.match_tol_rad)
        if best is not None:
            return best, "ok", n_hyp
        ambiguous |= status.startswith("ambiguous")
    if ambiguous:
        return None, "ambiguous: two different attitudes verified", n_hyp
    return None, "no triad was confirmed and verified", n_hyp
