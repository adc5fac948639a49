"""The Hipparcos catalog against independent facts: published J2000 positions and Johnson V magnitudes."""

import numpy as np
import pytest

from startracker.catalog import (
    load_catalog,
    radec_to_vector,
    select_navigation_stars,
    v_from_hp,
)

ARCSEC = np.radians(1 / 3600)


def hms(h, m, s):
    return np.radians(15 * (h + m / 60 + s / 3600))


def dms(sign, d, m, s):
    return sign * np.radians(d + m / 60 + s / 3600)


# SIMBAD ICRS J2000 positions (epoch 2000.0)
KNOWN_J2000 = {
    32349: (hms(6, 45, 8.917), dms(-1, 16, 42, 58.02)),  # Sirius
    91262: (hms(18, 36, 56.336), dms(1, 38, 47, 1.28)),  # Vega
    11767: (hms(2, 31, 49.09), dms(1, 89, 15, 50.79)),  # Polaris
}


@pytest.mark.parametrize("hip", sorted(KNOWN_J2000))
def test_known_stars_sit_at_their_j2000_position(hip):
    cat = load_catalog(mag_limit=6.0, epoch=2000.0)
    v = cat.vectors[cat.index_of(hip)[0]]
    truth = radec_to_vector(*KNOWN_J2000[hip])
    sep = np.arccos(np.clip(v @ truth, -1, 1))
    assert sep < 0.5 * ARCSEC


def test_proper_motion_is_applied():
    # Sirius moves 1.34"/yr: its 2000 and 2025 positions differ by ~33".
    v2000 = load_catalog(6.0, 2000.0)
    v2025 = load_catalog(6.0, 2025.0)
    a = v2000.vectors[v2000.index_of(32349)[0]]
    b = v2025.vectors[v2025.index_of(32349)[0]]
    assert np.arccos(a @ b) / ARCSEC == pytest.approx(1.339 * 25, rel=0.02)


# Johnson V of constant (or nearly constant) bright stars, Yale Bright Star Catalogue 5th ed.
KNOWN_V = {
    37279: 0.34,  # Procyon
    97649: 0.77,  # Altair
    7588: 0.46,  # Achernar
    49669: 1.35,  # Regulus
    102098: 1.25,  # Deneb
    113368: 1.16,  # Fomalhaut
    24608: 0.08,  # Capella
    71683: -0.01,  # alpha Cen A
    57632: 2.14,  # Denebola
    62956: 1.77,  # Alioth
    69673: -0.04,  # Arcturus
    91262: 0.03,  # Vega
    11767: 2.02,  # Polaris (mean)
}


def test_v_from_hp_matches_known_v_for_bright_stars():
    cat = load_catalog(mag_limit=6.0)
    idx = cat.index_of(list(KNOWN_V))
    assert np.all(idx >= 0)
    err = cat.vmag[idx] - np.array(list(KNOWN_V.values()))
    assert np.max(np.abs(err)) < 0.05, dict(zip(KNOWN_V, np.round(err, 3)))


def test_v_minus_hp_is_positive_for_blue_and_negative_for_red_stars():
    # Hp is broader and redder than V: a red star is brighter in Hp (Bessell 2000).
    assert v_from_hp([5.0], [-0.25])[0] > 5.0
    assert v_from_hp([5.0], [1.0])[0] < 5.0


def test_star_count_brighter_than_v6():
    n = len(load_catalog(mag_limit=6.0))
    assert 4800 <= n <= 5300  # ~5,000 naked-eye stars to V = 6


def test_catalog_is_sorted_brightest_first_and_unit():
    cat = load_catalog(mag_limit=5.0)
    assert np.all(np.diff(cat.vmag) >= 0)
    np.testing.assert_allclose(np.linalg.norm(cat.vectors, axis=1), 1.0, atol=1e-12)


def test_cone_search_equals_brute_force():
    cat = load_catalog(mag_limit=6.0)
    rng = np.random.default_rng(3)
    for _ in range(20):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        radius = rng.uniform(0.01, 0.5)
        brute = np.flatnonzero(cat.vectors @ d >= np.cos(radius))
        np.testing.assert_array_equal(cat.cone_search(d, radius), brute)


def test_navigation_selection_drops_fainter_of_close_pairs():
    cat = load_catalog(mag_limit=6.0)
    sep = np.radians(0.2)
    nav = select_navigation_stars(cat, min_separation_rad=sep)
    # no two survivors closer than sep
    from scipy.spatial import cKDTree

    assert len(cKDTree(nav.vectors).query_pairs(2 * np.sin(sep / 2))) == 0
    # each dropped star had a brighter neighbour within sep
    dropped = np.setdiff1d(cat.hip, nav.hip)
    assert len(dropped) > 0
    for h in dropped[:50]:
        v = cat.vectors[cat.index_of(h)[0]]
        m = cat.vmag[cat.index_of(h)[0]]
        close = cat.vectors @ v >= np.cos(sep)
        assert np.any(close & (cat.vmag <= m) & (cat.hip != h))
    merged = select_navigation_stars(cat, min_separation_rad=sep, mode="merge")
    assert len(merged) == len(nav)
    assert np.all(merged.vmag <= nav.vmag + 1e-12) or merged.vmag.sum() <= nav.vmag.sum()


@pytest.mark.parametrize("bad", [9.5, -3.0])
def test_magnitude_limit_outside_range_raises(bad):
    with pytest.raises(ValueError, match="mag_limit"):
        load_catalog(mag_limit=bad)


def test_bad_epoch_and_cone_inputs_raise():
    with pytest.raises(ValueError, match="epoch"):
        load_catalog(epoch=3000.0)
    cat = load_catalog(mag_limit=4.0)
    with pytest.raises(ValueError, match="direction"):
        cat.cone_search([0, 0, 0], 0.1)
    with pytest.raises(ValueError, match="radius_rad"):
        cat.cone_search([0, 0, 1], -0.1)
