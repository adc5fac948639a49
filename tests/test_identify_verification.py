"""Pieces of the identification: the false-alarm rule, the wrong-triangle rate, Mortari's triad order,
the Wahba solutions, the roll consistency of pattern strings."""

import math

import numpy as np
import pytest
from scipy import stats

from startracker.attitude import solve_wahba, solve_wahba_single
from startracker.catalog import load_catalog
from startracker.identify import build_database
from startracker.identify.frame import IdentifyOptions, prepare_frame
from startracker.identify.pattern_string import roll_inliers
from startracker.kernels.identify import binom_tail
from startracker.identify.pyramid import PairCandidates, smart_triads, triangles
from startracker.simulation import simulate_identification_frame
from startracker.identify.verification import (
    Match,
    best_of,
    fast_rotation,
    required_matches,
    triangle_false_rate,
)
from startracker.optics import camera_preset
from startracker.rotations import quat_from_rotvec, quat_random, quat_to_matrix


@pytest.mark.parametrize("n,p,e", [(64, 7e-4, 1), (64, 7e-4, 4), (9, 0.02, 4), (5, 0.5, 2), (100, 1e-6, 5), (30, 0.3, 0), (3, 0.2, 4)])
def test_binomial_tail(n, p, e):
    assert math.isclose(binom_tail(n, float(p), e), stats.binom.sf(e - 1, n, p), rel_tol=1e-6, abs_tol=1e-300)


def test_required_matches_follow_the_false_alarm_rule():
    # Loose tolerance, dense catalog: a triangle has ~1 wrong look-alike; with p = 1e-3 per detection
    # and 47 other detections, 3 confirmations give 47C3 p^3 ~ 1.6e-5 > 1e-6, 4 give ~1.8e-7.
    assert required_matches(1.0, 50, 1e-3, 1e-6) == 3 + 4
    # Precise measurements: a wrong triangle is itself rare, one confirming star suffices.
    assert required_matches(1e-5, 50, 1e-5, 1e-6) == 4
    # Three detections: the triangle alone, accepted only when it is unique enough.
    assert required_matches(1e-7, 3, 1e-3, 1e-6) == 3
    assert required_matches(1e-3, 3, 1e-3, 1e-6) == 4  # > n: impossible
    # Monotone: more chance coincidences or more look-alikes never lower the requirement.
    last = 0
    for p in np.geomspace(1e-6, 1e-1, 12):
        r = required_matches(1.0, 60, p, 1e-6)
        assert r >= last
        last = r


def test_wrong_triangle_rate_matches_the_catalog():
    """λ = 2 N³ ε³ R / π · clumping predicts how many catalog triangles fit three false stars."""
    cat = load_catalog(6.0)
    cam = camera_preset("paper000")
    db = build_database(cat, cam)
    opts = IdentifyOptions(sigma_px=0.5)
    rng = np.random.default_rng(7)
    lam, count = [], []
    for _ in range(150):
        f = simulate_identification_frame(cat, cam, quat_random(rng), rng, sigma_px=0.5, n_false=3,
                                          false_mag_range=(-5, -4))
        fr = prepare_frame(f.xy, cam, f.intensities, opts)
        i, j, k = 0, 1, 2  # the three false stars are the brightest
        assert np.all(f.hip[fr.index[:3]] == -1)
        count.append(len(triangles(db, fr, PairCandidates(db.pairs, fr), i, j, k)))
        lam.append(triangle_false_rate(fr, i, j, k, db.n_stars, db.clumping3))
    ratio = np.mean(count) / np.mean(lam)
    assert 0.35 < ratio < 1.2  # the formula is right to within its small-angle approximations


def test_smart_triad_order_is_mortaris():
    got = list(smart_triads(5))
    assert got == [(0, 1, 2), (1, 2, 3), (2, 3, 4), (0, 1, 3), (1, 2, 4), (0, 1, 4), (0, 2, 3), (1, 3, 4), (0, 2, 4), (0, 3, 4)]
    for n in (3, 4, 8, 12):
        t = list(smart_triads(n))
        assert len(t) == len(set(t)) == math.comb(n, 3)
        assert all(i < j < k for i, j, k in t)


def test_fast_rotation_recovers_proper_rotations():
    rng = np.random.default_rng(3)
    for _ in range(50):
        r = quat_to_matrix(quat_random(rng))
        b = rng.normal(size=(3, 3))
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        got = fast_rotation(b, b @ r.T)
        assert np.allclose(got, r, atol=1e-10)
    # Batched, and a mirrored set still gives a proper rotation (det +1), never a reflection.
    b = rng.normal(size=(4, 3, 3))
    mirror = b * np.array([1, 1, -1])
    rot = fast_rotation(b, mirror)
    assert np.allclose(np.linalg.det(rot), 1.0)


def test_solve_wahba_single_equals_solve_wahba():
    rng = np.random.default_rng(4)
    for _ in range(200):
        q = quat_random(rng)
        k = int(rng.integers(2, 40))
        b = rng.normal(size=(k, 3)) * rng.uniform(0.5, 2.0, (k, 1))
        r = (b / np.linalg.norm(b, axis=1, keepdims=True)) @ quat_to_matrix(q).T + rng.normal(0, 1e-5, (k, 3))
        sig = rng.uniform(1e-6, 1e-4, k)
        a, c = solve_wahba(b, r, sig), solve_wahba_single(b, r, sig)
        assert a.success and c.success
        assert np.allclose(a.q_meas_to_ref, c.q_meas_to_ref, atol=1e-12)
        assert np.allclose(a.covariance_rad2, c.covariance_rad2, rtol=1e-8, atol=0)
        assert math.isclose(a.residual_rms_arcsec, c.residual_rms_arcsec, rel_tol=1e-8, abs_tol=1e-9)
    assert solve_wahba_single(np.eye(3)[:1], np.eye(3)[:1]).status == solve_wahba(np.eye(3)[:1], np.eye(3)[:1]).status
    par = np.array([[0, 0, 1.0], [0, 0, 2.0]])
    assert not solve_wahba_single(par, par).success
    with pytest.raises(ValueError, match="v_meas"):
        solve_wahba_single(np.array([[np.nan, 0, 1.0], [0, 1, 0]]), np.eye(3)[:2])


def test_roll_inliers_find_the_consistent_correspondences():
    """Neighbours at known distances from a main star; two of them are swapped (same radial code)."""
    rng = np.random.default_rng(5)
    q = quat_from_rotvec(np.array([0.3, -0.2, 1.1]))
    r = quat_to_matrix(q)
    main = np.array([0.0, 0.0, 1.0])
    az = rng.uniform(0, 2 * np.pi, 8)
    th = np.radians(rng.uniform(1, 8, 8))
    nb = np.column_stack([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)])
    u_main = r @ main
    u_nb = nb @ r.T
    u_nb[[2, 5]] = u_nb[[5, 2]]  # a wrong pairing
    inl = roll_inliers(main, nb, th, u_main[None], u_nb[None], np.ones((1, 8), bool), np.radians(0.05))
    assert inl[0].tolist() == [True, True, False, True, True, False, True, True]


def test_two_different_verified_attitudes_are_ambiguous():
    eye = np.eye(3)
    rot = quat_to_matrix(quat_from_rotvec(np.array([0.0, 0.0, 0.5])))
    m = lambda r, n: Match(rot=r, det=np.arange(n), nav=np.arange(n), n_required=5, rms_rad=1e-5)
    best, status = best_of([m(eye, 8), m(rot, 7)], 1e-4)
    assert best is None and status.startswith("ambiguous")
    best, status = best_of([m(eye, 30), m(rot, 6)], 1e-4)  # overwhelming support wins
    assert best is not None and best.n_matched == 30
    best, status = best_of([m(eye, 8), m(eye, 7)], 1e-4)  # the same attitude twice is one answer
    assert best.n_matched == 8 and status == "ok"


def test_a_systematic_misfit_is_refused(monkeypatch):
    """Detections from a camera whose focal length is 0.1 % longer than the model (1 px at the edge):
    with 0.2 px of noise the inner half of the stars fit within 4σ and the outer half miss by a few σ.
    The misfit test refuses such an attitude (far too many near misses for false stars); without it the
    inner stars alone would pass; a tolerance that covers the error (sigma_px = 2) identifies every frame
    correctly."""
    from startracker.identify import identify
    from startracker.identify import verification
    from startracker.simulation import score_result
    from startracker.optics import Camera

    cat = load_catalog(6.0)
    cam = camera_preset("paper000")
    longer = Camera(resolution=(2048, 2048), pixel_size_um=5.5, focal_length_mm=31.94 * 1.001)
    rng = np.random.default_rng(3)
    frames = [simulate_identification_frame(cat, longer, quat_random(rng), rng, sigma_px=0.2) for _ in range(12)]
    for f in frames:
        assert not identify(f.xy, cam, cat, sigma_px=0.2).success
        assert score_result(identify(f.xy, cam, cat, sigma_px=2.0), f) == "correct"
    monkeypatch.setattr(verification, "MISFIT_P", 0.0)
    assert sum(identify(f.xy, cam, cat, sigma_px=0.2).success for f in frames) >= 10


def test_poisson_tail():
    from startracker.identify.verification import _poisson_tail

    for mu, k in [(0.01, 2), (0.5, 3), (3.0, 1), (2.0, 0), (1e-4, 4)]:
        assert math.isclose(_poisson_tail(mu, k), stats.poisson.sf(k - 1, mu), rel_tol=1e-6, abs_tol=1e-15)
