"""Paper 001 like for like: the inertial-aided matcher's successes are counted apart from all-sky fallbacks, and
the heads' detections can carry missing and false stars and magnitude noise, as the single head's frames do."""

import dataclasses

import numpy as np
import pytest

from startracker.catalog import load_catalog, select_navigation_stars
from startracker.multifov import MatchTally, MultiFovSensor, classify_identification, paper001_head
from startracker.multifov.matcher import InertialAidedMatcher
from startracker.rotations import quat_from_rotvec, quat_multiply, quat_random

SIGMA_PX = 0.2


def rich_scene(sensor, cat, rng, min_stars=6):
    while True:
        q = quat_random(rng)
        if sensor.view(q, cat).n_fused >= min_stars:
            return q


def test_a_fallback_is_not_a_success_of_the_method(sensor45, cat):
    """Three frames of one scene, each identified correctly: by the part catalog (INS prior), by the all-sky
    fallback because the INS error radius is too large, and by the all-sky retry after the part catalog failed.
    Only the first is the method's success; a tally that counted fallbacks would give 3 of 3."""
    rng = np.random.default_rng(21)
    m = InertialAidedMatcher(sensor45, cat, sigma_px=SIGMA_PX, retry_all_sky=True)
    q = rich_scene(sensor45, cat, rng)
    xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX)
    truth = np.concatenate([cat.hip[i] for i in idx])  # the catalog's truth, not the matcher's output
    q_bad = quat_multiply(quat_from_rotvec(np.radians([10.0, 0.0, 0.0])), q)
    results = [
        m.identify(xy, q, np.radians(0.05) ** 2),  # honest, small INS error: part catalog
        m.identify(xy, q, np.radians(8.0) ** 2),  # error radius 5·8° = 40° > 20°: all-sky
        m.identify(xy, q_bad, np.radians(0.05) ** 2),  # INS 10° off claiming 0.05°: part catalog fails, retry
    ]
    # every one of them is a correct identification of the scene
    for r in results:
        assert r.success and np.all(r.star_ids == truth)
    tally = MatchTally()
    outcomes = [tally.add(r, truth, q) for r in results]
    assert outcomes == ["method", "fallback", "fallback"]
    assert tally.counts == {"method": 1, "fallback": 2, "wrong": 0, "failed": 0}
    assert tally.frames == 3
    assert tally.method_success_pct == pytest.approx(100.0 / 3)
    assert tally.fallback_pct == pytest.approx(200.0 / 3)


def test_wrong_and_failed_identifications_are_classified(sensor45, cat):
    rng = np.random.default_rng(22)
    m = InertialAidedMatcher(sensor45, cat, sigma_px=SIGMA_PX)
    q = rich_scene(sensor45, cat, rng)
    xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX)
    truth = np.concatenate([cat.hip[i] for i in idx])
    r = m.identify(xy, q, np.radians(0.05) ** 2)
    assert classify_identification(r, truth, q) == "method"
    # one detection given another star's HIP number: wrong, whatever the attitude
    ids = r.star_ids.copy()
    ids[0], ids[1] = ids[1], ids[0]
    assert classify_identification(dataclasses.replace(r, star_ids=ids), truth, q) == "wrong"
    # the right ids but an attitude 1° off (its covariance claims arcseconds): wrong
    q_off = quat_multiply(quat_from_rotvec(np.radians([1.0, 0.0, 0.0])), q)
    assert classify_identification(r, truth, q_off) == "wrong"
    # a false star (truth -1) left unmatched is right; given a HIP number it is wrong
    truth_false = truth.copy()
    truth_false[0] = -1
    assert classify_identification(dataclasses.replace(r, star_ids=np.where(truth_false < 0, -1, r.star_ids)),
                                   truth_false, q) == "method"
    assert classify_identification(r, truth_false, q) == "wrong"
    assert classify_identification(dataclasses.replace(r, success=False), truth, q) == "failed"
    with pytest.raises(ValueError, match="truth_hip"):
        classify_identification(r, truth[:-1], q)


def test_observe_defaults_draw_nothing_extra(sensor45, cat):
    """Without missing/false stars and magnitude noise the frames are those the matcher's figures were made with."""
    q = quat_random(np.random.default_rng(3))
    a = sensor45.observe(q, cat, np.random.default_rng(5), SIGMA_PX)
    b = sensor45.observe(q, cat, np.random.default_rng(5), SIGMA_PX, mag_sigma=0.0, n_false=0, missing=0)
    v = sensor45.view(q, cat)
    rng = np.random.default_rng(5)
    for k in range(2):
        np.testing.assert_array_equal(a[0][k], b[0][k])
        np.testing.assert_array_equal(a[1][k], v.star_index[k])
        np.testing.assert_array_equal(a[0][k], v.xy[k] + rng.normal(0.0, SIGMA_PX, v.xy[k].shape))


def test_observe_missing_false_and_magnitude_noise(sensor45, cat):
    rng = np.random.default_rng(7)
    n_reordered = n_frames = 0
    for _ in range(200):
        q = quat_random(rng)
        v = sensor45.view(q, cat)
        xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX, mag_sigma=0.5, n_false=2, missing=1)
        for k, cam in enumerate(sensor45.heads):
            true_k = idx[k][idx[k] >= 0]
            # one visible star missing (when there was one), each kept star a visible one, no duplicates
            assert len(true_k) == max(len(v.star_index[k]) - 1, 0)
            assert set(true_k.tolist()) <= set(v.star_index[k].tolist()) and len(set(true_k.tolist())) == len(true_k)
            # two false stars per head, on its detector
            fals = xy[k][idx[k] < 0]
            assert len(fals) == 2
            w, h = cam.resolution
            assert np.all((fals >= -0.5) & (fals <= np.array([w, h]) - 0.5))
            # true stars sit near their noise-free positions (σ 0.2 px)
            pos = {s: p for s, p in zip(v.star_index[k].tolist(), v.xy[k])}
            for s, p in zip(idx[k].tolist(), xy[k]):
                if s >= 0:
                    assert np.linalg.norm(p - pos[s]) < 2.0
            if len(true_k) >= 2:
                n_frames += 1
                # brightest first by the *measured* magnitude: with 0.5 mag of noise the catalog order is broken often
                n_reordered += bool(np.any(np.diff(cat.vmag[true_k]) < 0))
    assert n_frames > 100 and 0.1 * n_frames < n_reordered < n_frames
    with pytest.raises(ValueError, match="mag_sigma"):
        sensor45.observe(q, cat, rng, mag_sigma=-1.0)
    with pytest.raises(ValueError, match="n_false"):
        sensor45.observe(q, cat, rng, n_false=1.5)
    with pytest.raises(ValueError, match="missing"):
        sensor45.observe(q, cat, rng, missing=-1)
    with pytest.raises(TypeError, match="rng"):
        sensor45.observe(q, cat, None, n_false=1)


def test_matcher_with_faulty_detections_is_never_wrong(sensor45, cat):
    """Missing and false stars and magnitude noise on both heads: the method still succeeds on most frames with
    enough true stars, and never reports a wrong identification."""
    rng = np.random.default_rng(8)
    m = InertialAidedMatcher(sensor45, cat, sigma_px=SIGMA_PX)
    tally = MatchTally()
    n_enough = 0
    for _ in range(80):
        q = rich_scene(sensor45, cat, rng, min_stars=7)
        xy, idx = sensor45.observe(q, cat, rng, SIGMA_PX, mag_sigma=0.2, n_false=1, missing=1)
        truth = np.concatenate([np.where(i >= 0, cat.hip[np.maximum(i, 0)], -1) for i in idx])
        q_ins = quat_multiply(quat_from_rotvec(rng.normal(0.0, np.radians(0.5), 3)), q)
        tally.add(m.identify(xy, q_ins, np.radians(0.5) ** 2), truth, q)
        n_enough += 1
    assert tally.counts["wrong"] == 0
    assert tally.counts["fallback"] == 0
    assert tally.counts["method"] >= 0.8 * n_enough
