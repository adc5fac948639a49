"""The identification database: star-pair catalog (paper 002 §4.2.1), k-vector windows, pattern strings
(paper 003 §3.1), caching and the reported sizes."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from startracker.catalog import load_catalog
from startracker.identify import build_database
from startracker.identify.pattern_string import N_LEVELS, PatternCatalog, match_strings
from startracker.optics import camera_preset


@pytest.fixture(scope="module")
def small():
    """V <= 3.5 (about 270 stars) with the 20 deg camera: small enough for brute force."""
    cat = load_catalog(3.5)
    cam = camera_preset("paper000")
    return cat, cam, build_database(cat, cam, min_separation_px=0.0, cache=False)


def brute_pairs(vectors, max_angle):
    ang = np.arccos(np.clip(vectors @ vectors.T, -1, 1))
    i, j = np.nonzero(np.triu(ang < max_angle, 1))
    return {(a, b): ang[a, b] for a, b in zip(i.tolist(), j.tolist())}


def test_pair_catalog_equals_brute_force(small):
    cat, cam, db = small
    p = db.pairs
    assert len(db.nav) == len(cat)  # no blend removal asked for
    # Every pair closer than the FOV diagonal (with a 2 % margin), and only those.
    diag = 2 * cam.half_diagonal_fov_rad
    assert diag * 1.0 < p.max_angle_rad <= diag * 1.03
    brute = brute_pairs(db.nav.vectors, p.max_angle_rad)
    got = {(int(a), int(b)): float(t) for a, b, t in zip(p.first, p.second, p.angle_rad)}
    assert set(got) == set(brute)
    assert max(abs(got[k] - brute[k]) for k in got) < 1e-7
    # P sorted ascending; I is the brighter star, B_I <= B_J (paper 002 eq. 10).
    assert np.all(np.diff(p.angle_rad) >= 0)
    assert np.all(p.first_mag <= p.second_mag)
    assert np.allclose(p.first_mag, db.nav.vmag[p.first], atol=1e-5)
    # Reference pairs: exactly the pairs whose brighter star is brighter than the limit.
    ref = {(int(a), int(b)) for a, b in zip(db.ref_pairs.first, db.ref_pairs.second)}
    assert ref == {k for k in got if db.nav.vmag[k[0]] <= db.ref_mag_limit}


@settings(max_examples=300, deadline=None)
@given(st.floats(-0.01, 0.6), st.floats(0.0, 3e-3))
def test_k_vector_windows_are_exact(angle, tol):
    """One window through the scalar path, many through KVector.query_ranges, and brute force agree."""
    cat = load_catalog(3.5)
    db = build_database(cat, camera_preset("paper000"))
    p = db.pairs
    start, stop = p.range_one(angle, tol)
    s2, e2 = p.ranges([angle], tol)
    assert (start, stop) == (int(s2[0]), int(e2[0]))
    inside = np.flatnonzero((p.angle_rad >= angle - tol) & (p.angle_rad <= angle + tol))
    assert np.array_equal(np.arange(start, stop), inside)


def test_blended_stars_are_dropped_for_the_brighter():
    """Stars closer than 2 px form one spot: the navigation stars keep the brighter of each such pair."""
    cat = load_catalog(6.0)
    cam = camera_preset("paper000")
    db = build_database(cat, cam)
    pix = cam.pixel_size_mm / cam.focal_length_mm
    assert db.pairs.angle_rad[0] >= 2 * pix
    dropped = np.setdiff1d(cat.hip, db.nav.hip)
    assert 0 < len(dropped) < 0.05 * len(cat)
    for h in dropped[:20]:
        v = cat.vectors[cat.index_of(h)[0]]
        ang = np.arccos(np.clip(db.nav.vectors @ v, -1, 1))
        k = np.argmin(ang)
        assert ang[k] < 2 * pix and db.nav.vmag[k] <= cat.vmag[cat.index_of(h)[0]]


def test_pattern_strings_equal_brute_force():
    cat = load_catalog(6.0)
    cam = camera_preset("paper003")
    db = build_database(cat, cam)
    pc = db.patterns
    theta_max = np.radians(8.0)
    assert abs(pc.theta_max_rad - theta_max) < 1e-12  # 16 x 16 deg camera: half the side
    rng = np.random.default_rng(1)
    v = db.nav.vectors
    for g in rng.choice(len(pc.guide), 25, replace=False):
        main = pc.guide[g]
        ang = np.arccos(np.clip(v @ v[main], -1, 1))
        nb = np.flatnonzero((ang <= theta_max) & (np.arange(len(v)) != main))
        codes = np.sort(np.rint(ang[nb] / (theta_max / N_LEVELS)).astype(int))
        n = pc.length[g]
        assert n == len(nb)
        assert np.array_equal(pc.codes[g, :n], codes)
        assert np.all(pc.codes[g, n:] == 255)
        assert set(pc.neighbour[g, :n].tolist()) == set(nb.tolist())
        assert np.array_equal(pc.below[g, :], np.searchsorted(codes, np.arange(N_LEVELS + 2)))
    assert np.all(np.diff(pc.length) >= 0)  # clustered by string length


def paper_example_catalog():
    """Guide star 6897 of paper 003: string "3 143 435 375 787 979 838 491 919 394" = the two-digit codes below;
    and a second guide star whose codes are all far from it."""
    codes_6897 = [31, 43, 43, 53, 75, 78, 79, 79, 83, 84, 91, 91, 93, 94]
    other = [5, 10, 15, 20, 25, 60, 65, 70]
    rows = [other, codes_6897]
    l_max = max(map(len, rows))
    codes = np.full((2, l_max), 255, dtype=np.uint8)
    below = np.zeros((2, N_LEVELS + 2), dtype=np.uint16)
    for r, c in enumerate(rows):
        codes[r, : len(c)] = c
        below[r] = np.searchsorted(c, np.arange(N_LEVELS + 2))
    return PatternCatalog(
        guide=np.array([0, 6897], dtype=np.int32),
        length=np.array([len(other), len(codes_6897)], dtype=np.int16),
        codes=codes,
        neighbour=np.tile(np.arange(l_max, dtype=np.int32), (2, 1)),
        below=below,
        theta_max_rad=np.radians(8.0),
    )


@pytest.mark.parametrize(
    "observed,skips,matches",
    [
        ([31, 43, 53, 79, 94], 0, True),  # a subset (stars missing in the image): all found in order
        ([30, 44, 52, 80, 92], 0, True),  # every code off by one: |s - n| <= 1 still matches
        ([30, 44, 47, 52, 80], 1, True),  # one unmatched neighbour (47) is skipped
        ([30, 44, 47, 52, 62, 80], 1, False),  # a second unmatched neighbour makes the guide star fail
        ([29, 43, 53], 1, True),  # 29 is two levels off: skipped once
        ([43, 43, 43], 1, True),  # only two 43s: the third is the one skip
        ([43, 43, 43, 43], 1, False),
    ],
)
def test_tolerant_string_matching_paper_003(observed, skips, matches):
    pc = paper_example_catalog()
    rows, pos, sk = match_strings(pc, np.array(observed), max_skips=1)
    hit = 1 in rows.tolist()
    assert hit == matches
    if hit:
        k = rows.tolist().index(1)
        assert sk[k] == skips
        p = pos[k][pos[k] >= 0]
        assert np.all(np.diff(p) > 0)  # matched in order, each catalog code used once
        got = pc.codes[1, p].astype(int)
        obs = np.array(observed)[pos[k] >= 0]
        assert np.all(np.abs(got - obs) <= 1)
    assert 0 not in rows.tolist()  # the unrelated guide star never matches


def test_paper_003_catalog_size():
    """Guide stars to V 6 on a 16 x 16 deg camera. Paper 003: 3,283 guide stars (SAO, 3 deg rule),
    17.3 neighbours each, 149.4 kB with 2 B per code and 12 B per guide star. The stated 3 deg rule
    leaves 1,744 Hipparcos stars; 1.5 deg reproduces the paper's counts (see the benchmark)."""
    cat = load_catalog(6.0)
    cam = camera_preset("paper003")
    db3 = build_database(cat, cam, guide_min_separation_deg=3.0, cache=False)
    pc = db3.patterns
    v = db3.nav.vectors[pc.guide]
    sep = np.arccos(np.clip(v @ v.T, -1, 1)) + np.eye(len(v)) * 10
    assert sep.min() > np.radians(3.0)  # the thinning rule holds
    assert db3.pattern_catalog_bytes == 2 * int(pc.length.sum()) + 12 * len(pc.guide)
    db15 = build_database(cat, cam, guide_min_separation_deg=1.5, cache=False)
    assert abs(len(db15.patterns.guide) - 3283) / 3283 < 0.1
    assert abs(db15.patterns.mean_neighbours - 17.3) / 17.3 < 0.1
    assert abs(db15.pattern_catalog_bytes / 1000 - 149.4) / 149.4 < 0.1


def test_database_is_cached_and_reports_its_cost():
    cat = load_catalog(5.0)
    cam = camera_preset("zy3")
    a = build_database(cat, cam)
    b = build_database(cat, cam)
    c = build_database(cat, cam, cache=False)
    d = build_database(cat, cam, ref_mag_limit=3.0)
    assert a is b and c is not a and d is not a
    assert a.build_time_s > 0 and np.isfinite(a.build_time_s)
    p = a.pairs
    pairs_bytes = (p.first.nbytes + p.second.nbytes + p.first_mag.nbytes + p.second_mag.nbytes
                   + p.kvector.sorted_values.nbytes + p.kvector.order.nbytes + p.kvector.k.nbytes)
    assert p.nbytes == pairs_bytes
    assert a.memory_bytes > pairs_bytes + a.ref_pairs.nbytes + a.patterns.nbytes
    # Paper 002 §4.2.2: 1,604 BSC stars brighter than 5.0 give m = 44,234 pairs within the 20 deg FOV;
    # 1,645 Hipparcos stars (V <= 5) within the 28 deg diagonal give about twice as many.
    n20 = np.count_nonzero(p.angle_rad < np.radians(20.0))
    assert abs(len(a.nav) - 1604) < 80
    assert abs(n20 - 44234) / 44234 < 0.1
    with pytest.raises(TypeError, match="catalog"):
        build_database(cat.vectors, cam)
    with pytest.raises(TypeError, match="camera"):
        build_database(cat, "zy3")
    with pytest.raises(ValueError, match="min_separation_px"):
        build_database(cat, cam, min_separation_px=float("nan"))


def test_catalog_too_sparse_gives_an_empty_pair_catalog():
    cat = load_catalog(0.0)
    db = build_database(cat, camera_preset("paper000"), cache=False)
    assert db.mean_stars_per_fov < 1
    assert db.pairs.range_one(0.1, 0.1) in ((0, 0), (0, len(db.pairs)))
