"""Main-star pattern strings (paper 003, Wang, Fei & Zhang 2009).

Catalog (§3.1). Each guide star is a main star; its neighbours are the guide stars within ``θmax`` of it
(``θmax``: from the detector centre to the middle of the nearer edge, 8° for a 16°×16° camera; a circle
keeps the pattern rotation invariant). The angle ``θ`` to each neighbour is quantised to one of 99 levels,
``n = round(θ / (θmax / 99))``, and the codes, sorted ascending, form the main star's pattern string. The
string length is stored as the clustering index, so a search only looks at strings at least as long as
the observed one (less the skips allowed).

Identification (§3.2). Each detection gets a credibility ``Q = M / n_neighbour`` (measured magnitude over
the number of detections within ``θmax``); the detection with the smallest ``Q`` is the main star. Its
observed string ``s`` is coded the same way and matched against every guide string with the tolerant,
KMP-like rule of the paper: observed codes are taken in order and each must find a later catalog code
with ``|s − n| ≤ 1``; one observed neighbour may stay unmatched (a planet, a false star), a second makes
the guide star fail. Surviving guide stars are verified (attitude, re-projection, counts); if none
verifies, the next main star is tried. Candidates are ranked by skips, then by how close the guide star's
catalog magnitude is to the measured one, and only the few whose neighbour correspondences agree on
one roll about the main star (most agreeing first) go to verification.

Magnitudes: ``M`` is the measured magnitude when intensities are given, otherwise the brightness rank
(1 for the brightest); it is floored at 0.1 so the ratio keeps its meaning for the few stars brighter
than magnitude 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from startracker.identify.frame import Frame, IdentifyOptions
from startracker.identify.verification import Match, best_of, triangle_false_rate, verify

__all__ = ["PatternCatalog", "build_pattern_catalog", "identify_pattern_string", "N_LEVELS"]

N_LEVELS = 99
_PAD = 255
_N_VERIFY = 5  # candidates verified per main star, best roll consistency first


@dataclass(frozen=True, eq=False)
class PatternCatalog:
    """Pattern strings of the guide stars, sorted by string length (the clustering index).

    Attributes
    ----------
    guide : ndarray of int32, shape (G,)
        Navigation index of each guide star (main star).
    length : ndarray of int16, shape (G,)
        String length (number of neighbours), ascending.
    codes : ndarray of uint8, shape (G, L)
        Sorted codes, padded with 255.
    neighbour : ndarray of int32, shape (G, L)
        Navigation index of the neighbour behind each code (−1 in the padding).
    below : ndarray of uint16, shape (G, 101)
        ``below[g, v]``: number of codes of string ``g`` smaller than ``v`` (a search index: the first
        position with a code >= v, so the tolerant match is a gather instead of a scan).
    theta_max_rad : float
        ``θmax``; one code level is ``θmax / 99``.
    """

    guide: np.ndarray
    length: np.ndarray
    codes: np.ndarray
    neighbour: np.ndarray
    below: np.ndarray
    theta_max_rad: float

    @property
    def level_rad(self) -> float:
        return self.theta_max_rad / N_LEVELS

    @property
    def nbytes(self) -> int:
        """Bytes held in memory (padded arrays)."""
        return int(self.guide.nbytes + self.length.nbytes + self.codes.nbytes + self.neighbour.nbytes + self.below.nbytes)

    @property
    def paper_bytes(self) -> int:
        """Size with paper 003's layout: 2 B per neighbour code, 2 B star number, 4+4 B RA/Dec, 2 B length."""
        return int(2 * int(self.length.sum()) + len(self.guide) * (2 + 4 + 4 + 2))

    @property
    def mean_neighbours(self) -> float:
        return float(self.length.mean()) if len(self.length) else 0.0


def build_pattern_catalog(pairs, guide_mask: np.ndarray, theta_max_rad: float) -> PatternCatalog:
    """Pattern strings from the star-pair catalog (pairs closer than ``θmax`` among guide stars).

    Parameters
    ----------
    pairs : StarPairCatalog
    guide_mask : ndarray of bool, shape (N,)
        Which navigation stars are guide stars.
    theta_max_rad : float
    """
    start, stop = pairs.range_one(theta_max_rad / 2.0, theta_max_rad / 2.0)  # angles in [0, θmax]
    sl = slice(start, stop)
    a, b, ang = pairs.first[sl], pairs.second[sl], pairs.angle_rad[sl]
    keep = guide_mask[a] & guide_mask[b]
    a, b, ang = a[keep], b[keep], ang[keep]
    main = np.concatenate([a, b])
    other = np.concatenate([b, a])
    code = np.rint(np.concatenate([ang, ang]) / (theta_max_rad / N_LEVELS)).astype(np.int64)
    guides = np.flatnonzero(guide_mask).astype(np.int32)
    row_of = np.full(len(guide_mask), -1, dtype=np.int64)
    row_of[guides] = np.arange(len(guides))
    rows = row_of[main]
    o = np.lexsort((code, rows))
    rows, other, code = rows[o], other[o], code[o]
    length = np.bincount(rows, minlength=len(guides))
    l_max = max(int(length.max()) if len(length) else 0, 1)
    offsets = np.cumsum(length) - length
    col = np.arange(len(rows)) - offsets[rows]
    codes = np.full((len(guides), l_max), _PAD, dtype=np.uint8)
    neigh = np.full((len(guides), l_max), -1, dtype=np.int32)
    codes[rows, col] = code
    neigh[rows, col] = other
    by_len = np.argsort(length, kind="stable")
    below = np.zeros((len(guides), N_LEVELS + 2), dtype=np.uint16)
    if len(rows):
        np.add.at(below, (rows, np.minimum(code, N_LEVELS) + 1), 1)
        below = np.cumsum(below, axis=1, dtype=np.uint16)
    return PatternCatalog(
        guide=guides[by_len],
        length=length[by_len].astype(np.int16),
        codes=codes[by_len],
        neighbour=neigh[by_len],
        below=below[by_len],
        theta_max_rad=float(theta_max_rad),
    )


def match_strings(cat: PatternCatalog, observed: np.ndarray, max_skips: int):
    """Tolerant in-order matching of one observed string against every long-enough guide string.

    Parameters
    ----------
    cat : PatternCatalog
    observed : ndarray of int, shape (q,)
        Observed codes, ascending.
    max_skips : int

    Returns
    -------
    rows : ndarray of int, shape (R,)
        Guide rows that match with at most ``max_skips`` unmatched observed codes.
    pos : ndarray of int, shape (R, q)
        Catalog column matched by each observed code (−1: skipped).
    skips : ndarray of int, shape (R,)
    """
    q = len(observed)
    first = int(np.searchsorted(cat.length, q - max_skips, side="left"))
    rows = np.arange(first, len(cat.guide))
    length = cat.length[rows].astype(np.int64)
    l_max = cat.codes.shape[1]
    ptr = np.zeros(len(rows), dtype=np.int64)
    skips = np.zeros(len(rows), dtype=np.int64)
    pos = np.full((len(rows), q), -1, dtype=np.int64)
    for t in range(q):  # one pass per observed code (a handful), vectorised over the guide strings
        if len(rows) == 0:
            break
        s_t = int(observed[t])
        # First position at or after the pointer whose code is >= s - 1; a match when its code <= s + 1.
        at = np.maximum(cat.below[rows, max(s_t - 1, 0)], ptr)
        code = cat.codes[rows, np.minimum(at, l_max - 1)]
        hit = (at < length) & (code <= s_t + 1)
        pos[hit, t] = at[hit]
        ptr[hit] = at[hit] + 1
        skips += ~hit
        if not hit.all():
            alive = skips <= max_skips
            if not alive.all():
                rows, length, ptr, skips, pos = rows[alive], length[alive], ptr[alive], skips[alive], pos[alive]
    return rows, pos, skips


def _azimuth(axis: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Azimuth (rad) of ``vec`` (..., K, 3) about unit ``axis`` (..., 3) in a right-handed basis."""
    ref = np.where(np.abs(axis[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = ref - axis * np.sum(ref * axis, axis=-1, keepdims=True)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.stack(
        [
            axis[..., 1] * e1[..., 2] - axis[..., 2] * e1[..., 1],
            axis[..., 2] * e1[..., 0] - axis[..., 0] * e1[..., 2],
            axis[..., 0] * e1[..., 1] - axis[..., 1] * e1[..., 0],
        ],
        axis=-1,
    )
    x = np.einsum("...kj,...j->...k", vec, e1)
    y = np.einsum("...kj,...j->...k", vec, e2)
    return np.arctan2(y, x)


def roll_inliers(v_main, v_nb, theta_nb, u_main, u_nb, valid, tol_rad: float):
    """Which (observed, catalog) neighbour correspondences agree on the roll about the main star.

    A string match fixes the main star and each neighbour's distance from it, not the azimuth. With the
    main star aligned to its catalog direction, each correspondence implies a roll ``Δφ`` about it (the
    difference of the azimuths in the two frames, constant for all true pairs because the rotation is
    proper); correct pairs agree within ``tol`` over their distance, wrong ones (neighbours with nearly
    the same code swapped, chance matches) scatter. Vectorised over C candidate guide stars.

    Parameters
    ----------
    v_main : ndarray, shape (3,)
        Main star, camera frame.
    v_nb : ndarray, shape (q, 3)
        Observed neighbours, camera frame.
    theta_nb : ndarray, shape (q,)
        Their angles from the main star, rad.
    u_main : ndarray, shape (C, 3)
        Catalog main star of each candidate, ICRS.
    u_nb : ndarray, shape (C, q, 3)
        Catalog neighbour matched to each observed neighbour (anything where not ``valid``).
    valid : ndarray of bool, shape (C, q)
    tol_rad : float

    Returns
    -------
    ndarray of bool, shape (C, q)
        The largest agreeing group of each candidate.
    """
    dphi = _azimuth(u_main, u_nb) - _azimuth(v_main, v_nb)[None, :]
    diff = np.abs((dphi[:, :, None] - dphi[:, None, :] + np.pi) % (2 * np.pi) - np.pi)
    agree = (diff * np.maximum(theta_nb[:, None], theta_nb[None, :]) <= tol_rad) & valid[:, :, None] & valid[:, None, :]
    best = agree.sum(axis=2).argmax(axis=1)
    return agree[np.arange(len(u_main)), best]


def identify_pattern_string(db, frame: Frame, opts: IdentifyOptions) -> tuple[Match | None, str, int]:
    """Paper 003's main-star string identification; returns (match, status, hypotheses verified)."""
    n = frame.n
    if n < 3:
        return None, "fewer than 3 usable detections", 0
    cat = db.patterns
    if len(cat.guide) == 0:
        return None, "no pattern strings in the database", 0
    theta_max = cat.theta_max_rad
    within = (frame.angle_rad <= theta_max) & ~np.eye(n, dtype=bool)
    n_neigh = within.sum(axis=1)
    if frame.mag is not None:
        m = np.maximum(frame.mag, 0.1)
    else:
        m = np.arange(1, n + 1, dtype=float)
    q_cred = np.where(n_neigh >= 2, m / np.maximum(n_neigh, 1), np.inf)
    mains = np.argsort(q_cred, kind="stable")[: opts.max_main_stars]
    mains = mains[np.isfinite(q_cred[mains])]
    if len(mains) == 0:
        return None, "no detection has two neighbours within theta_max", 0
    n_stars = float(db.n_stars)
    nav_vec = db.nav.vectors
    tol = 2.0 * frame.match_tol_rad
    n_hyp = 0
    for main in mains:
        others = np.flatnonzero(within[main])
        codes = np.rint(frame.angle_rad[main, others] / cat.level_rad).astype(np.int64)
        o = np.argsort(codes, kind="stable")
        others, codes = others[o], codes[o]
        rows, pos, skips = match_strings(cat, codes, opts.max_skips)
        if len(rows) == 0:
            continue
        # Rank: fewest skips, then the catalog magnitude nearest the measured one (when known).
        if frame.mag is not None:
            dmag = np.abs(db.nav.vmag[cat.guide[rows]] - frame.mag[main])
        else:
            dmag = np.abs(cat.length[rows] - len(codes)).astype(float)
        rank = np.lexsort((dmag, skips))[: opts.max_candidates]
        sub = rows[rank]
        p = pos[rank]
        valid = p >= 0
        nb = cat.neighbour[sub[:, None], np.maximum(p, 0)]
        inl = roll_inliers(frame.v[main], frame.v[others], frame.angle_rad[main, others], nav_vec[cat.guide[sub]],
                           nav_vec[nb], valid, tol)
        n_inl = inl.sum(axis=1)
        hyps = [(int(n_inl[c]), int(rank[c]), others[inl[c]], nb[c][inl[c]]) for c in np.flatnonzero(n_inl >= 2)]
        hyps.sort(key=lambda h: -h[0])
        matches = []
        for _, r, det_nb, nav_nb in hyps[:_N_VERIFY]:
            det = np.concatenate([[main], det_nb])
            nav = np.concatenate([[cat.guide[rows[r]]], nav_nb])
            n_hyp += 1
            lam = triangle_false_rate(frame, det[0], det[1], det[2], n_stars, db.clumping3)
            # A string match fixes the sides from the main star only to the code tolerance (±1.5 levels)
            # and the third side to the roll tolerance, far looser than the pair windows λ assumes;
            # and every candidate tried so far was a chance to be fooled (union bound).
            t3 = frame.pair_tol_rad[det[0], det[1]] * frame.pair_tol_rad[det[0], det[2]] * frame.pair_tol_rad[det[1], det[2]]
            loose = (1.5 * cat.level_rad) ** 2 * tol
            lam *= max(1.0, loose / t3) * n_hyp
            mt = verify(db, frame, det, nav, lam, opts.false_alarm)
            if mt is not None:
                matches.append(mt)
        best, status = best_of(matches, frame.match_tol_rad)
        if best is not None:
            return best, "ok", n_hyp
        if status.startswith("ambiguous"):
            return None, status, n_hyp
    return None, "no guide-star string verified", n_hyp
