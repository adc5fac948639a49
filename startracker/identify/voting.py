"""Geometric voting (Kolomenkin, Pollak, Shimshoni & Lindenbaum 2008), as paper 002 §2.2 describes it.

Voting. For every pair of detections, every catalog pair whose angle lies in the pair's window votes
for both of its stars as the identity of both detections (four votes). Each detection takes the
catalog star with the most votes.

Validation. Every pair of detections votes again, now only when the angle between their two assigned
catalog stars agrees with the measured one; wrong identities gather almost no validation votes while
correct ones support each other. The detections whose validation votes reach half the best count (and
at least two) form the hypothesis, which goes to the common verification.
"""

from __future__ import annotations

import numpy as np

from startracker.identify.frame import Frame, IdentifyOptions
from startracker.identify.pairs import expand_ranges
from startracker.identify.verification import Match, triangle_false_rate, verify

__all__ = ["identify_voting", "cast_votes"]


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
    p, q = np.triu_indices(pool, 1)
    start, stop = db.pairs.ranges(frame.angle_rad[p, q], frame.pair_tol_rad[p, q])
    qi, pi = expand_ranges(start, stop)
    a, b = db.pairs.first[pi].astype(np.int64), db.pairs.second[pi].astype(np.int64)
    n_nav = db.n_stars
    dp, dq = p[qi] * n_nav, q[qi] * n_nav
    if mag_tol is None or frame.mag is None:
        keys = np.concatenate([dp + a, dp + b, dq + a, dq + b])
    else:
        dm = (frame.mag[p] - frame.mag[q])[qi]
        dv = (db.pairs.first_mag[pi] - db.pairs.second_mag[pi]).astype(np.float64)
        fwd = np.abs(dm - dv) <= mag_tol
        rev = np.abs(dm + dv) <= mag_tol
        keys = np.concatenate([(dp + a)[fwd], (dq + b)[fwd], (dp + b)[rev], (dq + a)[rev]])
    return np.bincount(keys, minlength=pool * n_nav).reshape(pool, n_nav)


def identify_voting(db, frame: Frame, opts: IdentifyOptions) -> tuple[Match | None, str, int]:
    """Geometric voting; returns (match, status, hypotheses verified)."""
    n = frame.n
    if n < 3:
        return None, "fewer than 3 usable detections", 0
    pool = min(n, opts.max_stars or 20, len(frame.angle_rad))
    votes = cast_votes(db, frame, pool, mag_tol=3.0 * np.sqrt(2.0) * opts.mag_sigma)
    ident = votes.argmax(axis=1)
    has = votes[np.arange(pool), ident] > 0
    # Validation vote.
    nav = db.nav.vectors
    p, q = np.triu_indices(pool, 1)
    cos_cat = np.einsum("ij,ij->i", nav[ident[p]], nav[ident[q]])
    ang_cat = np.arccos(np.clip(cos_cat, -1.0, 1.0))
    agree = (np.abs(ang_cat - frame.angle_rad[p, q]) <= frame.pair_tol_rad[p, q]) & has[p] & has[q]
    agree &= ident[p] != ident[q]
    val = np.bincount(p[agree], minlength=pool) + np.bincount(q[agree], minlength=pool)
    if val.max() < 2:
        return None, "validation vote found no consistent stars", 0
    keep = np.flatnonzero((val >= max(2, 0.5 * val.max())))
    if len(keep) < 3:
        return None, "fewer than 3 stars survived the validation vote", 0
    # Order the kept stars by validation votes; the hypothesis triangle is the best-supported three.
    keep = keep[np.argsort(-val[keep], kind="stable")]
    lam = triangle_false_rate(frame, keep[0], keep[1], keep[2], float(db.n_stars), db.clumping3)
    m = verify(db, frame, keep, ident[keep], lam, opts.false_alarm)
    if m is None:
        return None, "voted identities failed verification", 1
    return m, "ok", 1
