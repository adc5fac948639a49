"""Geometric voting (Kolomenkin, Pollak, Shimshoni & Lindenbaum 2008), as paper 002 §2.2 describes it.

Voting. For every pair of detections, every catalog pair whose angle lies in the pair's window votes
for both of its stars as the identity of both detections (four votes). Each detection takes the
catalog star with the most votes.

Brightness. With measured magnitudes, a catalog pair votes only for the orientations whose magnitude
difference matches the detections' (a zero-point-free test within ``3 √2 mag_sigma``). On dense fields
(V <= 6, 20° field: thousands of catalog pairs in every window) the unrestricted votes of the original
method bury the true star's in chance votes; restricting them by brightness, as the brightness-referenced
method of paper 002 does for its pair orientation, restores the contrast.

Validation. Every pair of detections votes again, now only when the angle between their two assigned
catalog stars agrees with the measured one; wrong identities gather almost no validation votes while
correct ones support each other. The hypothesis is the most validated detection plus, in order of
validation votes, every detection whose identity agrees with all those already taken; it goes to the
common verification.
"""

from __future__ import annotations

import numpy as np

from startracker.identify.frame import Frame, IdentifyOptions
from startracker.identify.verification import Match, triangle_false_rate, verify
from startracker.kernels.identify import cast_votes as kernel_cast_votes

__all__ = ["identify_voting", "cast_votes"]

_NO_MAG = np.zeros(1)
_TOP = 32  # candidates per detection that enter the validation vote


def cast_votes(db, frame: Frame, pool: int, mag_tol: float | None = None) -> np.ndarray:
    """Vote table of the first ``pool`` detections.

    Parameters
    ----------
    db : StarDatabase
    frame : Frame
    pool : int
    mag_tol : float, optional
        With measured magnitudes, a catalog pair ``(I, J)`` votes for an orientation only when the
        detections' magnitude difference matches the catalog's within ``mag_tol`` (zero-point free):
        ``p = I, q = J`` when ``|(m_p − m_q) − (V_I − V_J)| <= mag_tol``, the reverse when
        ``|(m_p − m_q) + (V_I − V_J)| <= mag_tol``; each passing orientation gives two votes. Without,
        every pair votes for both stars as both detections (four votes).

    Returns
    -------
    ndarray of int, shape (pool, N)
        Votes for each (detection, navigation star).
    """
    pairs = db.pairs
    kv = pairs.kvector
    use_mag = mag_tol is not None and frame.mag is not None
    mag = frame.mag if use_mag else _NO_MAG
    return kernel_cast_votes(frame.angle_rad, frame.pair_tol_rad, pool, kv.sorted_values, kv.k, kv.a1, kv.b1,
                             pairs.first, pairs.second, pairs.first_mag, pairs.second_mag, mag,
                             float(mag_tol) if use_mag else 0.0, use_mag, db.n_stars)


def identify_voting(db, frame: Frame, opts: IdentifyOptions) -> tuple[Match | None, str, int]:
    """Geometric voting; returns (match, status, hypotheses verified)."""
    n = frame.n
    if n < 3:
        return None, "fewer than 3 usable detections", 0
    pool = min(n, opts.max_stars or 20, len(frame.angle_rad))
    votes = cast_votes(db, frame, pool, mag_tol=3.0 * np.sqrt(2.0) * opts.mag_sigma)
    # Validation vote over the best-voted candidates of every detection (not only the top one: on a dense
    # field a true star is often second or third behind a star with many chance partners). A candidate
    # gains a vote from every other detection that has a candidate at the measured angle from it.
    k_top = min(_TOP, db.n_stars)
    if k_top < db.n_stars:
        part = np.argpartition(-votes, k_top - 1, axis=1)[:, :k_top]
        order = np.argsort(-np.take_along_axis(votes, part, axis=1), axis=1, kind="stable")
        cand = np.take_along_axis(part, order, axis=1)  # (pool, K), most votes first
    else:
        cand = np.argsort(-votes, axis=1, kind="stable")[:, :k_top]
    has = np.take_along_axis(votes, cand, axis=1) > 0
    nav = db.nav.vectors
    p, q = np.triu_indices(pool, 1)
    vp = nav[cand[p]]  # (P, K, 3)
    vq = nav[cand[q]]
    cos_cat = np.einsum("pik,pjk->pij", vp, vq)  # (P, K, K)
    lo = np.cos(np.minimum(frame.angle_rad[p, q] + frame.pair_tol_rad[p, q], np.pi))[:, None, None]
    hi = np.cos(np.maximum(frame.angle_rad[p, q] - frame.pair_tol_rad[p, q], 0.0))[:, None, None]
    ok = (cos_cat >= lo) & (cos_cat <= hi) & has[p][:, :, None] & has[q][:, None, :]
    ok &= cand[p][:, :, None] != cand[q][:, None, :]
    support = np.zeros((pool, k_top), dtype=np.int64)
    np.add.at(support, (np.repeat(p, k_top), np.tile(np.arange(k_top), len(p))), ok.any(axis=2).ravel())
    np.add.at(support, (np.repeat(q, k_top), np.tile(np.arange(k_top), len(q))), ok.any(axis=1).ravel())
    best = support.argmax(axis=1)
    ident = cand[np.arange(pool), best]
    val = support[np.arange(pool), best]
    # Pairwise agreement of the chosen identities.
    cos_id = np.einsum("ij,ij->i", nav[ident[p]], nav[ident[q]])
    agree = (cos_id >= lo[:, 0, 0]) & (cos_id <= hi[:, 0, 0]) & (ident[p] != ident[q])
    if val.max() < 2:
        return None, "validation vote found no consistent stars", 0
    # The hypothesis: the most validated star and, in order of validation votes, every star whose
    # assigned identity agrees in angle with all those already taken (a greedy consistent set), so one
    # wrongly voted star cannot spoil the attitude fit.
    a_mat = np.zeros((pool, pool), dtype=bool)
    a_mat[p[agree], q[agree]] = True
    a_mat[q[agree], p[agree]] = True
    order = np.argsort(-val, kind="stable")
    keep = [int(order[0])]
    for j in order[1:]:
        if val[j] < 2:
            break
        if a_mat[j, keep].all():
            keep.append(int(j))
    if len(keep) < 3:
        return None, "fewer than 3 stars survived the validation vote", 0
    keep = np.array(keep)
    lam = triangle_false_rate(frame, keep[0], keep[1], keep[2], float(db.n_stars), db.clumping3)
    m = verify(db, frame, keep, ident[keep], lam, opts.false_alarm)
    if m is None:
        return None, "voted identities failed verification", 1
    return m, "ok", 1
