"""The compiled identification kernels against plain numpy / scipy references on random inputs, and the
identification database's disk cache (round trip, corrupt file rebuilt, changed options -> other key)."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from startracker.catalog import load_catalog
from startracker.identify import build_database, identify
from startracker.identify.database import database_key
from startracker.identify.frame import IdentifyOptions, prepare_frame
from startracker.identify.pairs import join_equal
from startracker.identify.pyramid import PairCandidates, triangles
from startracker.simulation import score_result, simulate_identification_frame as simulate_frame
from startracker.kernels.identify import (
    binom_tail,
    build_sky_grid,
    kvector_range,
    nearest_two,
    rotation_svd,
    select_matches,
    solve_attitude,
)
from startracker.kernels.algebra import quat_from_rotation
from startracker.kvector import KVector
from startracker.optics import camera_preset
from startracker.rotations import quat_from_matrix, quat_random, quat_to_matrix


def random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def test_nearest_two_equals_kd_tree():
    """Two nearest stars within a radius: the sky grid answers exactly as scipy's k-d tree."""
    rng = np.random.default_rng(1)
    stars = random_unit(rng, 4000)
    start, order = build_sky_grid(stars, 64)
    tree = cKDTree(stars)
    # queries near stars (the usual case), and anywhere
    q = np.vstack([stars[rng.integers(0, 4000, 500)] + rng.normal(0, 2e-3, (500, 3)), random_unit(rng, 500)])
    q /= np.linalg.norm(q, axis=1)[:, None]
    for radius in (1e-3, 5e-3, 0.05):
        dist = np.empty((len(q), 2))
        idx = np.empty((len(q), 2), dtype=np.int64)
        nearest_two(q, stars, start, order, 64, radius, dist, idx)
        d_ref, i_ref = tree.query(q, k=2, distance_upper_bound=radius)
        assert np.array_equal(np.isinf(dist), np.isinf(d_ref))
        fin = np.isfinite(d_ref)
        assert np.allclose(dist[fin], d_ref[fin], rtol=0, atol=1e-12)
        assert np.array_equal(idx[fin], i_ref[fin])
        assert np.all(idx[~fin] == len(stars))


def reference_select(dist, idx, chord):
    """The numpy rule: nearest within chord, second at least chord farther, one detection per star."""
    det = np.flatnonzero((dist[:, 0] <= chord) & (dist[:, 1] > dist[:, 0] + chord))
    nav, d = idx[det, 0], dist[det, 0]
    o = np.lexsort((d, nav))
    first = np.ones(len(o), dtype=bool)
    first[1:] = nav[o][1:] != nav[o][:-1]
    keep = np.sort(o[first])
    return det[keep], nav[keep], d[keep]


def test_select_matches_equals_numpy_rule():
    rng = np.random.default_rng(2)
    for _ in range(300):
        n = int(rng.integers(1, 30))
        d0 = rng.uniform(0, 2, n)
        dist = np.column_stack([d0, d0 + rng.exponential(1.0, n)])
        dist[rng.random(n) < 0.2, 1] = np.inf
        idx = np.column_stack([rng.integers(0, 8, n), rng.integers(0, 8, n)]).astype(np.int64)
        got = select_matches(dist, idx, 1.0)
        ref = reference_select(dist, idx, 1.0)
        for g, r in zip(got, ref):
            assert np.array_equal(g, r)


def test_rotation_and_final_least_squares_equal_numpy_svd():
    """Polar-Newton rotation equals the SVD solution; the final fit equals solve_wahba_single."""
    from startracker.attitude import solve_wahba_single

    rng = np.random.default_rng(3)
    for _ in range(300):
        m = int(rng.integers(3, 25))
        boresight = random_unit(rng, 1)[0]
        b = boresight + rng.normal(0, rng.choice([0.02, 0.1, 0.5]), (m, 3))
        b /= np.linalg.norm(b, axis=1)[:, None]
        q = quat_random(rng)
        r = b @ quat_to_matrix(q).T + rng.normal(0, 1e-5, (m, 3))
        r /= np.linalg.norm(r, axis=1)[:, None]
        u, _, vt = np.linalg.svd(r.T @ b)
        ref = u @ vt
        if np.linalg.det(ref) < 0:
            u[:, 2] *= -1
            ref = u @ vt
        assert np.abs(rotation_svd(b, r) - ref).max() < 1e-9
        assert np.allclose(quat_from_rotation(ref), quat_from_matrix(ref), atol=1e-12)
        ok, qk, rms, cov = solve_attitude(b, r, 1e-5)
        sol = solve_wahba_single(b, r, sigma_rad=1e-5)
        assert ok and sol.success
        assert np.allclose(qk, sol.q_meas_to_ref, atol=1e-10)
        assert math.isclose(rms * 206264.806, sol.residual_rms_arcsec, rel_tol=1e-6, abs_tol=1e-9)
        assert np.allclose(cov, sol.covariance_rad2, rtol=1e-8)


def test_kvector_range_equals_brute_force():
    rng = np.random.default_rng(4)
    vals = rng.uniform(0, 0.5, 5000)
    kv = KVector(vals)
    s = kv.sorted_values
    for _ in range(500):
        lo = rng.uniform(-0.05, 0.55)
        hi = lo + rng.uniform(-0.01, 0.05)
        a, b = kvector_range(s, kv.k, kv.a1, kv.b1, lo, hi)
        inside = np.flatnonzero((s >= lo) & (s <= hi))
        assert (a, b) == ((inside[0], inside[-1] + 1) if len(inside) else (a, a))


def test_binomial_tail_equals_scipy():
    from scipy import stats

    for n, p, e in [(17, 1e-3, 1), (17, 1e-3, 3), (40, 0.02, 5), (5, 0.5, 2), (10, 1e-6, 4)]:
        assert math.isclose(binom_tail(n, p, e), stats.binom.sf(e - 1, n, p), rel_tol=1e-5)


def test_join_equal_is_the_equality_join():
    rng = np.random.default_rng(5)
    a, b = rng.integers(0, 50, 200), rng.integers(0, 50, 150)
    li, ri = join_equal(a, b)
    got = sorted(zip(li.tolist(), ri.tolist()))
    ref = sorted((i, j) for i in range(len(a)) for j in range(len(b)) if a[i] == b[j])
    assert got == ref


@pytest.fixture(scope="module")
def zy3():
    cat = load_catalog(6.0)
    cam = camera_preset("zy3")
    return cat, cam, build_database(cat, cam)


def test_compiled_pyramid_finds_the_true_triangle_of_the_numpy_search(zy3):
    """The numpy triangle search (windows, join, handedness) holds the true triangle; the compiled pyramid
    returns an attitude whose first three matches are that triangle's stars."""
    cat, cam, db = zy3
    rng = np.random.default_rng(6)
    opts = IdentifyOptions()
    for _ in range(20):
        f = simulate_frame(cat, cam, quat_random(rng), rng, sigma_px=0.5, max_stars=20)
        fr = prepare_frame(f.xy, cam, f.intensities, opts, n_angles=12)
        hyp = triangles(db, fr, PairCandidates(db.pairs, fr), 0, 1, 2)
        true = [int(np.flatnonzero(db.nav.hip == h)[0]) if h in db.nav.hip else -1 for h in f.hip[fr.index[:3]]]
        assert any(list(row) == true for row in hyp.tolist())
        r = identify(f.xy, cam, cat, intensities=f.intensities, database=db)
        assert score_result(r, f) == "correct"
        assert np.array_equal(r.star_ids[fr.index[:3]], f.hip[fr.index[:3]])


@pytest.mark.parametrize("method", ["pyramid", "brightness", "voting", "string"])
def test_zero_wrong_with_many_false_stars(zy3, method):
    """Adversarial scenes: 10 false stars among the 20 brightest detections, magnitudes drawn among the
    true stars' (ZY-3 camera, V <= 6). A method may fail; it must never answer wrongly."""
    cat, cam, db = zy3
    rng = np.random.default_rng(7)
    wrong = correct = 0
    for q in quat_random(rng, 40):
        f = simulate_frame(cat, cam, q, rng, sigma_px=0.5, mag_sigma=0.2, n_false=10, false_among=20, max_stars=20)
        s = score_result(identify(f.xy, cam, cat, method=method, intensities=f.intensities, database=db), f)
        wrong += s == "wrong"
        correct += s == "correct"
    assert wrong == 0
    if method == "pyramid":
        assert correct >= 36
    elif method == "brightness":  # its pool is the 10 brightest detections: half of them false here
        assert correct >= 24


def test_database_disk_round_trip(tmp_path):
    """A database loaded from disk equals the one built: same arrays, same identification."""
    cat = load_catalog(4.5)
    cam = camera_preset("paper000")
    built = build_database(cat, cam, cache=False, disk_folder=tmp_path)
    loaded = build_database(cat, cam, cache=False, disk_folder=tmp_path)
    assert built.source == "built" and loaded.source == "disk"
    assert len(list(tmp_path.iterdir())) == 1
    for name in ("hip", "vectors", "vmag", "bv"):
        assert np.array_equal(getattr(built.nav, name), getattr(loaded.nav, name))
    for p, q in ((built.pairs, loaded.pairs), (built.ref_pairs, loaded.ref_pairs)):
        for name in ("first", "second", "first_mag", "second_mag", "angle_rad"):
            assert np.array_equal(getattr(p, name), getattr(q, name))
        assert np.array_equal(p.kvector.k, q.kvector.k) and p.kvector.a1 == q.kvector.a1
    for name in ("guide", "length", "codes", "neighbour", "below"):
        assert np.array_equal(getattr(built.patterns, name), getattr(loaded.patterns, name))
    assert np.array_equal(built.grid_start, loaded.grid_start) and np.array_equal(built.grid_stars, loaded.grid_stars)
    assert (built.clumping3, built.density_eff_per_sr) == (loaded.clumping3, loaded.density_eff_per_sr)
    rng = np.random.default_rng(8)
    for q in quat_random(rng, 10):
        f = simulate_frame(cat, cam, q, rng, sigma_px=0.5)
        a = identify(f.xy, cam, cat, database=built)
        b = identify(f.xy, cam, cat, database=loaded)
        assert a.success == b.success and np.array_equal(a.star_ids, b.star_ids)
        assert np.array_equal(a.q_cam_to_icrs, b.q_cam_to_icrs)


def test_built_and_loaded_databases_hand_the_kernels_the_same_kind_of_arrays(tmp_path):
    """Read-only arrays either way: numba compiles a kernel once per kind (writable or not) of each argument, so a
    built database and a loaded (memory-mapped, read-only) one must not differ there."""
    from numba import typeof

    cat = load_catalog(4.5)
    cam = camera_preset("paper000")
    built = build_database(cat, cam, cache=False, disk_folder=tmp_path)
    loaded = build_database(cat, cam, cache=False, disk_folder=tmp_path)
    assert built.source == "built" and loaded.source == "disk"
    kinds_built = [typeof(a) for a in built.search_arrays]
    assert kinds_built == [typeof(a) for a in loaded.search_arrays]
    assert all(not a.flags.writeable for a in built.search_arrays if isinstance(a, np.ndarray))
    assert not built.nav.vectors.flags.writeable and not built.nav.hip.flags.writeable
    assert cat.vectors.flags.writeable  # the caller's catalog is left as it was


def test_corrupt_database_file_is_rebuilt(tmp_path):
    cat = load_catalog(4.0)
    cam = camera_preset("paper000")
    build_database(cat, cam, cache=False, disk_folder=tmp_path)
    (path,) = tmp_path.iterdir()
    raw = bytearray(path.read_bytes())
    raw[-100] ^= 0xFF  # one byte of the payload
    path.write_bytes(bytes(raw))
    again = build_database(cat, cam, cache=False, disk_folder=tmp_path)
    assert again.source == "built"
    assert build_database(cat, cam, cache=False, disk_folder=tmp_path).source == "disk"


def test_changed_options_or_catalog_give_another_key():
    cat = load_catalog(4.0)
    cam = camera_preset("paper000")
    opts = dict(mag_limit=None, min_separation_px=2.0, ref_mag_limit=3.6, guide_mag_limit=None,
                guide_min_separation_deg=0.0)
    k0 = database_key(cat, cam, opts)
    assert database_key(cat, cam, dict(opts)) == k0
    assert database_key(cat, cam, dict(opts, ref_mag_limit=3.0)) != k0
    assert database_key(cat, camera_preset("zy3"), opts) != k0
    assert database_key(load_catalog(4.5), cam, opts) != k0


def test_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    from startracker import cache

    monkeypatch.setenv("STARTRACKER_CACHE_DIR", str(tmp_path / "a"))
    assert cache.cache_dir() == tmp_path / "a"
    monkeypatch.delenv("STARTRACKER_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.cache_dir() == tmp_path / "xdg" / "startracker-gym"
    monkeypatch.setenv("STARTRACKER_CACHE_DIR", "")
    assert cache.cache_dir() is None


@pytest.mark.parametrize("preset", ["zy3", "paper004"])
def test_prepared_frame_equals_numpy_reference(preset):
    """prepare_frame (one compiled call): brightest first (stable), off-detector points and duplicates
    dropped, unit vectors, magnitudes and the angle / window tables as a plain numpy computation gives."""
    cam = camera_preset(preset)
    w, h = cam.resolution
    rng = np.random.default_rng(11)
    opts = IdentifyOptions(sigma_px=0.7, floor_arcsec=3.0, mag_zero_point=1.5)
    for trial in range(20):
        k = int(rng.integers(0, 30))
        xy = np.column_stack([rng.uniform(-20, w + 20, k), rng.uniform(-20, h + 20, k)])
        if k > 4:  # near-duplicates of earlier detections, and exact edge pixels
            xy[3] = xy[1] + rng.normal(0, 0.005, 2)
            xy[4] = [-0.5, h - 0.5]
        inten = rng.choice([1.0, 2.0, 5.0], k) if trial % 2 else None
        fr = prepare_frame(xy, cam, inten, opts, n_angles=12)
        # numpy reference
        order = np.arange(k) if inten is None else np.argsort(-inten, kind="stable")
        on = (xy[:, 0] >= -0.5) & (xy[:, 0] <= w - 0.5) & (xy[:, 1] >= -0.5) & (xy[:, 1] <= h - 0.5)
        order = order[on[order]]
        u = cam.unproject(xy[order]) if len(order) else np.empty((0, 3))
        pix = cam.pixel_size_mm / cam.focal_length_mm
        sigma = 0.7 * pix
        dup_cos = math.cos(max(0.1 * sigma, 0.05 * pix))
        keep = [j for j in range(len(u)) if not any(u[i] @ u[j] > dup_cos for i in range(j))]
        assert np.array_equal(fr.index, order[keep])
        assert fr.n_dropped == k - len(keep) and fr.n_input == k
        np.testing.assert_allclose(fr.v, u[keep], rtol=0, atol=1e-15)
        if inten is None:
            assert fr.mag is None
        else:
            np.testing.assert_allclose(fr.mag, 1.5 - 2.5 * np.log10(inten[fr.index]), rtol=0, atol=1e-13)
        vm = fr.v[:12]
        ang = np.arctan2(np.linalg.norm(np.cross(vm[:, None], vm[None]), axis=-1), vm @ vm.T)
        np.testing.assert_allclose(fr.angle_rad, ang, rtol=0, atol=1e-15)
        floor = 3.0 * math.pi / 648000.0
        tol = np.hypot(3.0 * math.sqrt(2.0) * sigma, floor) + 1.1e-4 * ang
        np.testing.assert_allclose(fr.pair_tol_rad, tol, rtol=1e-14, atol=0)
        assert fr.match_tol_rad == pytest.approx(math.hypot(4.0 * sigma, floor), rel=1e-14)


def test_smart_triads_kernel_equals_mortari_order():
    """The compiled triad table is the smart order of the Python generator (truncated)."""
    from startracker.identify.pyramid import smart_triads as smart_triads_py
    from startracker.kernels.identify import smart_triads

    for n in (0, 2, 3, 4, 7, 12):
        for cap in (1, 10, 100, 1000):
            ref = np.array(list(smart_triads_py(n))[:cap], dtype=np.int64).reshape(-1, 3)
            assert np.array_equal(smart_triads(n, cap), ref)


def test_pair_count_estimate_tracks_exact_window_counts(zy3):
    """The cache-resident count table estimates a window's pairs within the pairs of one bin at each end."""
    from startracker.kernels.identify import pair_count_table, window_estimate

    _, _, db = zy3
    s = db.pairs.kvector.sorted_values
    cdf, bin_rad = pair_count_table(s)
    rng = np.random.default_rng(12)
    for _ in range(200):
        th, tol = rng.uniform(0, s[-1]), rng.uniform(1e-5, 3e-3)
        exact = 2 * (np.searchsorted(s, th + tol, side="right") - np.searchsorted(s, th - tol, side="left"))
        per_bin = 2 * max(np.diff(cdf[max(int((th - tol) / bin_rad) - 1, 0):int((th + tol) / bin_rad) + 3]).max(), 1)
        assert abs(window_estimate(cdf, bin_rad, th - tol, th + tol) - exact) <= 2 * per_bin


def test_one_call_pyramid_equals_the_staged_pipeline(zy3):
    """identify(method="pyramid") runs pixels -> labels in one compiled call; the staged pipeline (frame,
    pyramid search, final least squares) gives the same labels and attitude on the same scenes, with false
    stars and detections off the detector too."""
    from startracker.identify.pyramid import identify_pyramid
    from startracker.kernels.identify import solve_identified

    cat, cam, db = zy3
    rng = np.random.default_rng(13)
    opts = IdentifyOptions()
    n_ok = 0
    for t, q in enumerate(quat_random(rng, 30)):
        f = simulate_frame(cat, cam, q, rng, sigma_px=0.5, mag_sigma=0.2, n_false=5 * (t % 3), false_among=20,
                           max_stars=20)
        xy = f.xy.copy()
        if t % 4 == 0:
            xy[-1] = [-3.0, 10.0]
        r = identify(xy, cam, cat, intensities=f.intensities, database=db)
        fr = prepare_frame(xy, cam, f.intensities, opts, n_angles=12)
        match, status, n_hyp = identify_pyramid(db, fr, opts)
        assert r.n_hypotheses == n_hyp
        if match is None:
            assert not r.success and r.status == status and np.all(r.star_ids == -1)
            continue
        ok, q_ref, rms, cov, ids = solve_identified(fr.v, db.nav.vectors, db.nav.hip, fr.index, match.det,
                                                    match.nav, fr.n_input, fr.sigma_rad)
        assert r.success and r.status == "ok"
        assert np.array_equal(r.star_ids, ids) and np.array_equal(r.q_cam_to_icrs, q_ref)
        assert r.n_matched == match.n_matched and r.n_required == match.n_required
        assert r.residual_arcsec == pytest.approx(rms * 206264.80624709636, rel=1e-12)
        n_ok += 1
    assert n_ok >= 25
