"""The array kernels (``startracker.kernels``) against independent references, bit for bit where they promise it.

The rotation kernels reproduce scipy's ``Rotation``/``Slerp`` arithmetic: compared with ``==`` against scipy itself
(or against the checked functions that call scipy) on random inputs, including edge cases (zero scalar parts,
negative signs, tiny and large angles, query times on the samples). The ``validate=False`` paths of the checked API
are compared with their validating path.
"""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from startracker import rotations as rot
from startracker.attitude import solve_wahba_batch
from startracker.centroid.fidelity import candidate_pairs
from startracker.optics import camera_preset
from scipy.spatial.transform import Rotation, Slerp

from startracker.kernels import rotations as rk
from startracker.track import prediction_covariance, prediction_sigma_px


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert np.array_equal(a, b), np.max(np.abs(a - b))


def _close(a, b, tol=1e-13):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol)


def _random_quats(rng, n):
    q = rng.normal(size=(n, 4)) * rng.choice([1e-3, 1.0, 1e3])
    q[rng.random(n) < 0.15, 0] = 0.0  # the canonical-sign rule beyond w
    return q


@pytest.mark.parametrize("seed", range(6))
def test_quaternion_kernels_equal_public_functions(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        n = int(rng.integers(1, 25))
        q = _random_quats(rng, n)
        q2 = rot.quat_normalize(rng.normal(size=(n, 4)))
        _close(rk.quat_normalize(q), rot.quat_normalize(q))
        _close(rk.quat_multiply(q, q2), rot.quat_multiply(q, q2))
        _close(rk.quat_multiply(q[0], q2), rot.quat_multiply(q[0], q2))
        np.testing.assert_allclose(rk.quat_to_matrix(q), Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix(), rtol=0, atol=1e-15)
        _close(rk.quat_angle_between(q, q2), rot.quat_angle_between(q, q2))
        scale = 10 ** rng.uniform(-9, 0.6)  # both sides of scipy's small-angle branch (1e-3 rad)
        rv = rng.normal(size=(n, 3)) * scale
        _close(rk.quat_from_rotvec(rv), rot.quat_from_rotvec(rv))
        _close(rk.quat_to_rotvec(q), rot.quat_to_rotvec(q))
        small = rot.quat_normalize(q2 * [1.0, scale, scale, scale])
        np.testing.assert_allclose(rk.quat_to_rotvec(small), rot.quat_to_rotvec(small), rtol=1e-12, atol=1e-300)
        w, a, dt = rng.normal(size=3) * scale, rng.normal(size=3) * scale, rng.uniform(-0.1, 0.1, n)
        _close(rk.quat_integrate(q2[0], w, dt, a), rot.quat_integrate(q2[0], w, dt, a))
        _close(rk.quat_integrate(q2[0], w, dt), rot.quat_integrate(q2[0], w, dt))
        m = rot.quat_to_matrix(q2) @ rot.quat_to_matrix(rot.quat_normalize(rng.normal(size=4)))
        _close(rk.quat_from_matrix(m), rot.quat_from_matrix(m))
        _close(rk.quat_from_matrix(m[0]), rot.quat_from_matrix(m[0]))


@pytest.mark.parametrize("seed", range(3))
def test_relative_rotvec_kernel_is_conjugate_product_log(seed):
    """One pass equals the three kernels it fuses bit for bit, and scipy's ``(R1⁻¹ R2).as_rotvec()``."""
    rng = np.random.default_rng(seed)
    for n in (1, 2, 7, 21):
        q1 = _random_quats(rng, n)
        scale = 10 ** rng.uniform(-9, 0.5)  # both sides of the small-angle branch
        q2 = rot.quat_multiply(q1, rot.quat_from_rotvec(rng.normal(size=(n, 3)) * scale))
        fused = rk.quat_relative_rotvec(q1, q2)
        assert np.array_equal(fused, rk.quat_to_rotvec(rk.quat_multiply(rk.quat_conjugate(q1), q2)))
        assert np.array_equal(rk.quat_relative_rotvec(q1[0], q2), rk.quat_to_rotvec(rk.quat_multiply(rk.quat_conjugate(q1[0]), q2)))
        ref = (Rotation.from_quat(q1[:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(q2[:, [1, 2, 3, 0]])).as_rotvec()
        np.testing.assert_allclose(fused, ref, rtol=1e-9, atol=1e-15)


def test_matrix_kernel_on_each_shepperd_branch():
    """Half-turns about x, y, z and the identity select each of Shepperd's four branches."""
    for rv in ([np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi], [0, 0, 0], [2.0, -1.0, 0.5]):
        m = Rotation.from_rotvec(rv).as_matrix()
        q = rk.quat_from_matrix(m)
        np.testing.assert_allclose(rk.quat_to_matrix(q), m, atol=1e-15)
        assert q[np.flatnonzero(q)[0]] > 0  # canonical sign


@pytest.mark.parametrize("seed", range(4))
def test_interpolation_kernel_equals_scipy_slerp(seed):
    rng = np.random.default_rng(100 + seed)
    for _ in range(40):
        s = int(rng.integers(2, 15))
        t = np.cumsum(rng.uniform(1e-3, 2e-2, s)) + rng.uniform(0, 100)
        w = rng.normal(size=3) * 10 ** rng.uniform(-6, 1)
        q = rot.quat_integrate(rot.quat_random(rng), w, t - t[0]) * rng.choice([1.0, -1.0], size=(s, 1))
        tq = rng.uniform(t[0], t[-1], int(rng.integers(1, 70)))
        tq[0], tq[-1] = t[0], t[-1]
        tq[len(tq) // 2] = t[s // 2]  # exactly on an interior sample
        ref = rot.from_scipy(Slerp(t, rot.to_scipy(q))(tq))
        _close(rk.quat_interpolate(t, q, tq), ref)
        _close(rot.quat_interpolate(t, q, tq), ref)
        ts = float(rng.uniform(t[0], t[-1]))
        _close(rk.quat_interpolate(t, q, ts), rot.from_scipy(Slerp(t, rot.to_scipy(q))(ts)))


def test_interpolation_checks_its_inputs():
    t = np.array([0.0, 1.0])
    q = np.array([[1.0, 0, 0, 0], [0.0, 1, 0, 0]])
    with pytest.raises(ValueError, match="t_query"):
        rot.quat_interpolate(t, q, 2.0)
    with pytest.raises(ValueError, match="increasing"):
        rot.quat_interpolate(t[::-1], q, 0.5)
    with pytest.raises(ValueError, match="zero quaternion"):
        rot.quat_interpolate(t, np.zeros((2, 4)), 0.5)


def test_wahba_batch_unchanged_by_the_internal_split():
    """solve_wahba_batch against an explicit SVD solution (its own definition, independent of the refactor)."""
    rng = np.random.default_rng(3)
    q_true = rot.quat_random(rng, 4)
    v_ref = rng.normal(size=(4, 6, 3))
    v_ref /= np.linalg.norm(v_ref, axis=-1, keepdims=True)
    v_meas = np.einsum("bji,bkj->bki", rot.quat_to_matrix(q_true), v_ref)  # R^T v
    q, cov, rms, ok = solve_wahba_batch(v_meas, v_ref, 1e-5)
    assert ok.all() and np.all(rms < 1e-6)
    assert np.all(np.degrees(rot.quat_angle_between(q, q_true)) * 3600 < 1e-6)


def test_prediction_covariance_unvalidated_path_equals_validated_path():
    rng = np.random.default_rng(4)
    cam = camera_preset("paper000")
    for _ in range(20):
        a = rng.normal(size=(3, 3, 3)) * 1e-4
        p, pw, pa = (x @ x.T for x in a)
        dt = rng.uniform(-0.2, 0.2, 5)
        _same(prediction_covariance(p, dt, pw, pa, validate=False), prediction_covariance(p, dt, pw, pa))
        _same(prediction_covariance(p, dt, pw, pa), p + pw * dt[:, None, None] ** 2 + pa * dt[:, None, None] ** 4 / 4)
        assert prediction_sigma_px(cam, p, dt, pw, pa, validate=False) == prediction_sigma_px(cam, p, dt, pw, pa)
        # scalars (isotropic variances) are converted either way
        assert prediction_sigma_px(cam, p, 0.1, 1e-8, 1e-6, validate=False) == prediction_sigma_px(cam, p, 0.1, 1e-8, 1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_sweep_pairs_leave_the_same_set_as_the_kdtree(seed):
    """The merge step keeps the pairs closer than the sum of their reaches (< r): same set either way."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 400))
    xy = rng.uniform(0, 300, (n, 2))
    xy[: n // 4, 0] = xy[0, 0]  # ties in x
    reach = rng.uniform(0.5, 6.0, n)
    r = 2.0 * float(reach.max()) + 1e-9

    def kept(pairs):
        d = xy[pairs[:, 0]] - xy[pairs[:, 1]]
        ok = d[:, 0] ** 2 + d[:, 1] ** 2 < (reach[pairs[:, 0]] + reach[pairs[:, 1]]) ** 2
        return {tuple(p) for p in np.sort(pairs[ok], axis=1).tolist()}

    ref = cKDTree(xy).query_pairs(r, output_type="ndarray")
    sweep = candidate_pairs(xy, r)
    assert np.all(sweep[:, 0] < sweep[:, 1])
    assert kept(sweep) == kept(ref)


def test_order_decreasing_is_numpys_stable_argsort_of_the_negated_keys():
    """The radix order of the centroid kernels equals numpy's stable argsort of -key: spread and clustered keys,
    exact ties, keys a few ulps apart (equal upper 32 bits), negative and infinite ones, few keys (the insertion
    sort up to 64), tiny and empty inputs."""
    from startracker.kernels.centroid import order_decreasing

    rng = np.random.default_rng(7)
    near = 1.0 + rng.integers(0, 40, 1000) * np.finfo(float).eps  # one upper half, many lower halves, ties
    cases = [rng.normal(size=1000), 10 ** rng.uniform(-3, 5, 900), np.round(rng.normal(size=1000), 1) + 0.0,
             np.repeat(rng.random(50), 20), near, np.concatenate([near, -near, near * 3.0]),
             np.array([0.0, 1.0, -1.0, 1e-300, -1e-300, np.inf, -np.inf, 5e-324]), np.zeros(5), np.ones(1),
             rng.normal(size=40), np.repeat(rng.normal(size=8), 8), near[:64], 10 ** rng.uniform(-3, 5, 65),
             np.zeros(0)]
    for key in cases:
        np.testing.assert_array_equal(order_decreasing(key), np.argsort(-key, kind="stable"))


@pytest.mark.parametrize("seed", range(4))
def test_saddle_search_finds_the_exhaustive_least_point(seed):
    """The bounded bisection of the near-overlap model returns the first least of the 33 summed profile values,
    as evaluating every point does: still and streaked spots, equal twins (ties), near and far pairs."""
    from startracker.kernels.centroid import profile_at, profile_terms, saddle_search

    rng = np.random.default_rng(seed)
    a, b, lows = np.empty(33), np.empty(33), np.empty(24, dtype=np.int64)
    n_inner = 0
    for _ in range(400):
        se2 = rng.uniform(0.3, 4.0, 2)
        half = np.where(rng.random(2) < 0.3, 0.0, rng.uniform(0.0, 12.0, 2))
        peak = 10 ** rng.uniform(1, 5, 2)
        if rng.random() < 0.25:  # twins: the sum is symmetric, its least values come in equal pairs
            se2[1], half[1], peak[1] = se2[0], half[0], peak[0]
        d = rng.uniform(0.0, 25.0) if rng.random() < 0.9 else 0.0
        ti, tj = profile_terms(se2[0], half[0]), profile_terms(se2[1], half[1])
        v = [profile_at(d * k / 32.0, peak[0], half[0], ti) + profile_at(d - d * k / 32.0, peak[1], half[1], tj)
             for k in range(33)]
        a[:], b[:] = np.nan, np.nan  # the search reads the caller's first three points only
        for k in (0, 16, 32):
            a[k] = profile_at(d * k / 32.0, peak[0], half[0], ti)
            b[k] = profile_at(d - d * k / 32.0, peak[1], half[1], tj)
        k = saddle_search(d, peak[0], half[0], ti, peak[1], half[1], tj, a, b, lows)
        assert k == int(np.argmin(v)), (k, int(np.argmin(v)))
        assert a[k] + b[k] == v[k]
        n_inner += 0 < k < 32
    assert n_inner > 100  # interior saddles, not just the ends


def test_consistency_nis_equals_the_rotation_vector_quadratic_form():
    """kernels.sensor.consistency_nis = δθᵀ C⁻¹ δθ with δθ the rotation vector of q_est* ⊗ q_true (scipy's
    rotation vector, numpy's solve), for any sign of either quaternion; a singular covariance gives inf."""
    from scipy.spatial.transform import Rotation

    from startracker.kernels.sensor import consistency_nis

    rng = np.random.default_rng(5)
    n = 200
    q_true = rot.quat_random(rng, n)
    err = rng.normal(size=(n, 3)) * 10 ** rng.uniform(-6, -1, (n, 1))
    q_est = np.array([rot.quat_multiply(q, rot.quat_from_rotvec(-e)) for q, e in zip(q_true, err)])
    a = rng.normal(size=(n, 3, 3)) * 10 ** rng.uniform(-6, -3, (n, 1, 1))
    cov = a @ np.swapaxes(a, 1, 2) + 1e-14 * np.eye(3)
    sign = np.where(rng.random((n, 1)) < 0.5, -1.0, 1.0)
    got = consistency_nis(q_true * sign, q_est, cov)
    r_est = Rotation.from_quat(q_est[:, [1, 2, 3, 0]])
    r_true = Rotation.from_quat(q_true[:, [1, 2, 3, 0]])
    d = (r_est.inv() * r_true).as_rotvec()
    ref = np.einsum("ni,ni->n", d, np.linalg.solve(cov, d[..., None])[..., 0])
    np.testing.assert_allclose(got, ref, rtol=1e-7)
    np.testing.assert_allclose(d, err, rtol=1e-6, atol=1e-15)
    assert consistency_nis(q_true[:1], q_est[:1], np.zeros((1, 3, 3)))[0] == np.inf


def test_projection_kernel_equals_the_pinhole_model():
    from startracker.color import ColorCamera
    from startracker.optics import CAMERA_PRESETS

    rng = np.random.default_rng(6)
    cams = [camera_preset(name) for name in CAMERA_PRESETS]
    cams.append(ColorCamera.paper004(translation="table2").channel_camera("red"))  # overrides project
    for cam in cams:
        v = rng.normal(size=(400, 3))
        v[:, 2] = np.abs(v[:, 2]) * rng.choice([5.0, -1.0, 1e-14], size=400)  # in front, behind, grazing
        xy, _, front = cam.project(v, return_in_front=True)
        xy_f, _, front_f = cam.project(v, return_in_front=True, validate=False)
        _same(xy_f, xy)
        _same(front_f, front)
        # the model itself: x = cx + (f/p) X/Z (1 + k1 r²), r the ideal focal-plane radius in mm (paper 004 eq. 3)
        ok = front & (type(cam).project is type(camera_preset("paper000")).project)
        if ok.any():
            xm = cam.focal_length_mm * v[ok, :2] / v[ok, 2:3]
            r2 = np.sum(xm**2, axis=1, keepdims=True)
            ref = xm * (1 + cam.distortion_k1_per_mm2 * r2) / cam.pixel_size_mm + np.asarray(cam.principal_point)
            np.testing.assert_allclose(xy[ok], ref, rtol=1e-12, atol=1e-9)


# ------------------------------------------------------------------------------- tracking kernels
def _numpy_kvector(values):
    """Paper 000 eqs. 1-3 written directly with numpy (stable sort, K(i) = #{S <= h(i)})."""
    order = np.argsort(values, kind="stable")
    s = values[order]
    n = len(s)
    d = (s[-1] - s[0]) / (n - 1) if n > 1 else 0.0
    if d <= 0.0:
        d = max(1.0, abs(s[0])) * 1e-9
    a1 = n * d / (n - 1) if n > 1 else d
    b1 = s[0] - d / 2.0 - a1
    k = np.searchsorted(s, a1 * np.arange(1, n + 1) + b1, side="right")
    k[0], k[-1] = 0, n
    return order, s, k, a1, b1


@pytest.mark.parametrize("seed", range(4))
def test_kvector_kernel_and_bucket_sort_equal_numpy(seed):
    from startracker.kernels.kvector import kvector_build, stable_argsort

    rng = np.random.default_rng(seed)
    cases = [rng.uniform(0, 2048, 450), rng.integers(-3, 4, 200).astype(float),  # many ties
             np.r_[rng.normal(0, 1e-6, 100), 1e6],  # one far value: a crowded bin
             np.full(7, 3.5), rng.standard_cauchy(300), np.array([2.0])]
    for v in cases:
        assert np.array_equal(stable_argsort(v), np.argsort(v, kind="stable"))
        order, s, k, a1, b1 = kvector_build(v)
        ro, rs, rkk, ra1, rb1 = _numpy_kvector(v)
        assert np.array_equal(order, ro) and np.array_equal(s, rs) and np.array_equal(k, rkk)
        assert a1 == ra1 and b1 == rb1


def test_cone_search_equals_explicit_dot_products():
    from startracker.catalog import load_catalog

    cat = load_catalog(6.0)
    rng = np.random.default_rng(11)
    for _ in range(300):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        radius = rng.choice([rng.uniform(1e-3, 0.05), rng.uniform(0.05, 0.5), rng.uniform(0.5, np.pi)])
        ang = np.arccos(np.clip(cat.vectors @ d, -1.0, 1.0))
        got = cat.cone_search(d * 3.0, radius)  # any norm
        assert np.all(np.diff(got) > 0)
        clear = np.abs(ang - radius) > 1e-9  # stars on the rim within rounding may go either way
        assert set(got.tolist()) & set(np.flatnonzero(clear).tolist()) == set(np.flatnonzero(clear & (ang <= radius)).tolist())
        assert np.array_equal(cat.cone_search(d, radius, validate=False), got)
    many = cat.cone_search(np.eye(3), 0.2)
    assert [m.tolist() for m in many] == [cat.cone_search(e, 0.2).tolist() for e in np.eye(3)]


def _wahba_svd_reference(b, r, w):
    """Markley's SVD solution and the QUEST covariance, numpy."""
    u, _, vt = np.linalg.svd((r * w[:, None]).T @ b)
    u[:, 2] *= np.linalg.det(u) * np.linalg.det(vt)
    info = w.sum() * np.eye(3) - (b * w[:, None]).T @ b
    return u @ vt, np.linalg.inv(info)


@pytest.mark.parametrize("seed", range(3))
def test_wahba_kernel_equals_svd_and_scipy(seed):
    from startracker.kernels.attitude import solve_wahba_batch as kernel

    rng = np.random.default_rng(seed)
    for trial in range(300):
        k = int(rng.integers(2, 40))
        truth = Rotation.random(random_state=rng)
        b = rng.normal(size=(k, 3))
        b[:, 2] += rng.choice([0.0, 3.0, 60.0])  # whole sky, 20° and 1° fields
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        r = truth.apply(b) + rng.normal(0, 10 ** rng.uniform(-7, -3), (k, 3))
        r /= np.linalg.norm(r, axis=1, keepdims=True)
        sig = rng.uniform(0.5e-5, 2e-5, k)
        q, cov, rms, ok = kernel(b[None], r[None], sig[None], np.ones((1, k), dtype=bool))
        a_ref, cov_ref = _wahba_svd_reference(b, r, sig**-2)
        a = Rotation.from_quat(q[0, [1, 2, 3, 0]]).as_matrix()
        s = np.linalg.svd((r * sig[:, None] ** -2).T @ b, compute_uv=False)
        gap = (s[1] + s[2]) / s.sum()  # the eigen-gap that conditions the attitude (narrow fields: small)
        assert ok[0] and np.abs(a - a_ref).max() < 1e-14 / gap + 1e-14
        np.testing.assert_allclose(cov[0], cov_ref, rtol=1e-8, atol=1e-8 * np.abs(cov_ref).max())
        sp, _ = Rotation.align_vectors(r, b, weights=sig**-2)
        assert np.abs(a - sp.as_matrix()).max() < 1e-12 / gap + 1e-12
        ab = b @ a.T
        ang = np.arctan2(np.linalg.norm(np.cross(ab, r), axis=1), np.sum(ab * r, axis=1))  # accurate when small
        assert rms[0] == pytest.approx(np.sqrt(np.mean(ang**2)) * 180 / np.pi * 3600, rel=1e-6, abs=1e-9)


def test_track_kernels_match_rule_against_numpy_brute_force():
    from startracker.kernels import track as tk

    rng = np.random.default_rng(12)
    for _ in range(50):
        pred = np.round(rng.uniform(0, 60, (int(rng.integers(1, 80)), 2)), int(rng.integers(0, 3)))  # exact ties
        obs = np.round(rng.uniform(-5, 65, (int(rng.integers(0, 60)), 2)), 1)
        r = float(rng.choice([0.0, 0.5, 2.0, 7.0]))
        d2 = (obs[:, None, 0] - pred[None, :, 0]) ** 2 + (obs[:, None, 1] - pred[None, :, 1]) ** 2
        ref = np.where(d2.min(axis=1, initial=np.inf) <= r * r, np.argmin(d2, axis=1) if len(obs) else 0, -1) if len(obs) else np.empty(0, int)
        tables = tk.dkvlut_build(pred)
        assert np.array_equal(tk.dkvlut_match(pred, *tables, obs, r), ref)
        assert np.array_equal(tk.match_brute(pred, obs, r), ref)


def test_prediction_sigma_kernel_equals_the_covariance_formula():
    cam = camera_preset("paper000", q_cam_to_body=rot.quat_from_rotvec([0.2, 0.5, -0.3]))
    rng = np.random.default_rng(13)
    for _ in range(20):
        a = [rng.normal(size=(3, 3)) for _ in range(3)]
        p, pw, pa = (x @ x.T * s for x, s in zip(a, (1e-9, 1e-8, 1e-7)))
        dt = rng.uniform(-0.2, 0.2, 5)
        pt = p + pw * np.max(np.abs(dt)) ** 2 + pa * np.max(np.abs(dt)) ** 4 / 4
        c = cam.r_cam_to_body.T @ pt @ cam.r_cam_to_body
        rho = np.hypot(*cam.resolution) / 2
        ref = np.sqrt(cam.focal_length_px**2 * max(c[0, 0], c[1, 1]) + rho**2 * c[2, 2])
        assert prediction_sigma_px(cam, p, dt, pw, pa) == pytest.approx(ref, rel=1e-12)
        assert prediction_sigma_px(cam, p, dt, pw, pa, validate=False) == pytest.approx(ref, rel=1e-12)


_FRAME_SCRIPT = """
import hashlib, numpy as np
from startracker.catalog import load_catalog
from startracker.optics import camera_preset
from startracker.track import predict_star_positions, match_stars, attitudes_per_instant
cam = camera_preset("paper000"); cat = load_catalog(6.0)
rng = np.random.default_rng(4)
q = np.array([0.5, 0.5, 0.5, 0.5]); t = np.linspace(0.0, 0.1, 11); w = np.radians([1.0, 8.0, 0.5])
pred = predict_star_positions(cam, cat, q, t, 0.05, w, np.array([0.0, 0.1, 0.0]), 4.0)
obs = pred.xy + rng.normal(0.0, 0.5, pred.xy.shape)
h = hashlib.sha256()
for m in ("dkvlut", "brute", "kdtree"):
    idx = match_stars(pred.xy, obs, 3.0, m)
    h.update(idx.tobytes())
inst = attitudes_per_instant(obs, idx, pred, cam, cat, 0.5)
for a in (pred.xy, pred.star_index, pred.q_body_to_icrs, inst.q_body_to_icrs, inst.covariance_rad2,
          inst.residual_rms_arcsec, inst.assignment):
    h.update(np.ascontiguousarray(a).tobytes())
print(h.hexdigest())
"""


def test_tracking_kernels_bit_identical_across_processes_and_a_fresh_numba_cache(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=str(root))
    fresh = subprocess.run([sys.executable, "-c", _FRAME_SCRIPT], cwd=root, env=env, capture_output=True, text=True,
                           check=True).stdout.strip()
    env.pop("NUMBA_CACHE_DIR")
    cached = subprocess.run([sys.executable, "-c", _FRAME_SCRIPT], cwd=root, env=env, capture_output=True, text=True,
                            check=True).stdout.strip()
    assert len(fresh) == 64 and fresh == cached


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_monitor_kernels_equal_their_numpy_formulas(seed):
    """The innovation monitor's and the timing test's statistics, compiled, against the same quantities written with
    numpy's solve and einsum: the window's spread and mean, the newest delivery's mean χ² and largest NIS (NaN
    skipped), and the timing statistic c² / (p + 1 / Σ 1/r) with its loose-prediction flag."""
    from startracker.kernels import filter as fk

    rng = np.random.default_rng(seed)
    m = 5
    a = rng.normal(size=(m, 3, 3)) * 1e-5
    r_cov = a @ a.transpose(0, 2, 1) + np.eye(3) * 1e-11
    b = rng.normal(size=(3, 3)) * 3e-5
    p_pred = b @ b.T
    s = r_cov + p_pred
    z = rng.normal(size=(m, 3)) * 2e-5
    nis = np.array([zi @ np.linalg.solve(si, zi) for zi, si in zip(z, s)])
    nis_with_stale = np.concatenate([[np.nan], nis])
    k = 4
    ring = (np.zeros(k), np.zeros(k), np.zeros((k, 3)), np.zeros((k, 3, 3)))
    ring[0][1], ring[1][1], ring[2][1], ring[3][1] = 7.0, 2.0, z[0] * 2, s[0] * 2  # an earlier delivery
    total, n, mean_chi2, delivery_chi2, max_nis, n_nis = fk.innovation_window(nis_with_stale, z, s, *ring, 0)
    zs, ss = z.sum(axis=0), s.sum(axis=0)
    assert total == pytest.approx(nis.sum() + 7.0, rel=1e-12) and n == m + 2
    zw, sw = zs + z[0] * 2, ss + s[0] * 2
    assert mean_chi2 == pytest.approx(zw @ np.linalg.solve(sw, zw), rel=1e-9)
    assert delivery_chi2 == pytest.approx(zs @ np.linalg.solve(ss, zs), rel=1e-9)
    assert max_nis == nis.max() and n_nis == m

    w = rng.normal(size=3)
    u = w / np.linalg.norm(w)
    r = np.einsum("i,mij,j->m", u, r_cov, u)
    p = max(float(np.max(np.einsum("i,mij,j->m", u, s, u) - r)), 0.0)
    v = 1.0 / np.sum(1.0 / r)
    c = np.sum((z @ u) / r) * v
    stat, loose = fk.timing_statistic(u, z, s, r_cov, 4.0)
    assert stat == pytest.approx(c * c / (p + v), rel=1e-9)
    assert loose == (p > 4.0 * r.min())
    assert fk.timing_statistic(u, z, s, r_cov, p / r.min() * 1.01)[1] is False
    assert fk.timing_statistic(u, z, s, r_cov, p / r.min() * 0.99)[1] is True


@pytest.mark.parametrize("seed", range(3))
def test_interval_rates_kernel_equals_scipy_over_each_interval(seed):
    """The mean body rate over each interval of a history: scipy's ``(R_k⁻¹ R_k+1).as_rotvec() / Δt``, and bit for bit
    the relative rotation vector divided by numpy's ``np.diff``."""
    rng = np.random.default_rng(seed)
    for n in (2, 3, 11, 31):
        t = np.cumsum(rng.uniform(1e-3, 2e-2, n)) + rng.uniform(-1, 100)
        w = rng.normal(size=3) * 10 ** rng.uniform(-6, 0.5)
        q = rot.quat_integrate(rot.quat_random(rng), w, t - t[0]) * rng.choice([1.0, -1.0], size=(n, 1))
        rates = rk.interval_rates_rows(t, q)
        r = Rotation.from_quat(q[:, [1, 2, 3, 0]])
        ref = (r[:-1].inv() * r[1:]).as_rotvec() / np.diff(t)[:, None]
        np.testing.assert_allclose(rates, ref, rtol=1e-8, atol=1e-13)
        np.testing.assert_allclose(rates, np.broadcast_to(w, rates.shape), rtol=1e-6, atol=1e-12)
        assert np.array_equal(rates, rk.quat_relative_rotvec(q[:-1], q[1:]) / np.diff(t)[:, None])


@pytest.mark.parametrize("seed", range(3))
def test_gyro_measure_history_against_scipy_rates_and_measure(seed):
    """Gyro.measure_history (kernels.imu.gyro_samples_of_history): an ideal gyro reads scipy's
    ``(R_k⁻¹ R_k+1).as_rotvec() / Δt`` of each interval; a noisy one, bit for bit, what ``measure`` of the interval
    rates reads from the same generator state (same samples, same bias states after, same draws taken)."""
    from startracker.imu import Gyro, gyro_preset

    rng = np.random.default_rng(seed)
    for n in (2, 3, 11, 31):
        t = np.cumsum(rng.uniform(1e-3, 2e-2, n)) + rng.uniform(-1, 100)
        w = rng.normal(size=3) * 10 ** rng.uniform(-6, 0.5)
        q = rot.quat_integrate(rot.quat_random(rng), w, t - t[0]) * rng.choice([1.0, -1.0], size=(n, 1))
        r = Rotation.from_quat(q[:, [1, 2, 3, 0]])
        ref = (r[:-1].inv() * r[1:]).as_rotvec() / np.diff(t)[:, None]
        ideal = Gyro(gyro_preset("ideal"), np.random.default_rng(0))
        np.testing.assert_allclose(ideal.measure_history(t, q, np.random.default_rng(1)), ref, rtol=1e-8, atol=1e-13)
        for grade in ("tactical", "industrial", "paper001-cond2"):
            g_a, g_b = Gyro(gyro_preset(grade), np.random.default_rng(5)), Gyro(gyro_preset(grade), np.random.default_rng(5))
            r_a, r_b = np.random.default_rng(seed + 10), np.random.default_rng(seed + 10)
            y_a = g_a.measure_history(t, q, r_a)
            y_b = g_b.measure(rk.interval_rates_rows(t, q), r_b)
            assert y_a.shape == (n - 1, 3) and np.array_equal(y_a, y_b)
            assert np.array_equal(g_a.bias_rad_s, g_b.bias_rad_s)
            assert r_a.random() == r_b.random()  # the same number of draws taken
    g = Gyro(gyro_preset("tactical"), np.random.default_rng(0))
    with pytest.raises(ValueError, match="q_body_to_icrs"):
        g.measure_history(t, q[:-1], np.random.default_rng(1))
    with pytest.raises(ValueError, match="times_s"):
        g.measure_history(t[::-1], q, np.random.default_rng(1))
    with pytest.raises(TypeError, match="rng"):
        g.measure_history(t, q, 1)


@pytest.mark.parametrize("seed", range(3))
def test_wrong_sample_flags_against_scipy_slerp_and_solve(seed):
    """The sample verdict's kernel: for samples inside the truth history, wrong exactly when the error (scipy's
    ``(R_meas⁻¹ R_true).as_rotvec()`` against scipy's Slerp of the truth) fails χ²(3) on the sample's own covariance
    (``np.linalg.solve``); samples before or after the history are never wrong. Errors are drawn at k σ with k far
    from the threshold's √44.8 ≈ 6.7 so that rounding cannot flip a verdict."""
    from startracker.kernels.sensor import wrong_sample_flags

    rng = np.random.default_rng(seed)
    s = 11
    t_hist = np.linspace(2.0, 2.1, s)
    w = rng.normal(size=3) * 0.2
    q_hist = rot.quat_integrate(rot.quat_random(rng), w, t_hist - t_hist[0])
    n = 30
    t_true = rng.uniform(1.95, 2.15, n)  # some outside the history
    t_true[0], t_true[1] = t_hist[0], t_hist[-1]  # on its ends: judged
    q_true = rot.from_scipy(Slerp(t_hist, rot.to_scipy(q_hist))(np.clip(t_true, t_hist[0], t_hist[-1])))
    a = rng.normal(size=(n, 3, 3)) * 1e-5
    cov = a @ a.transpose(0, 2, 1) + np.eye(3) * 1e-11
    k = rng.choice([0.5, 2.0, 12.0, 30.0], size=n)
    err = np.array([np.linalg.cholesky(c) @ (u / np.linalg.norm(u)) * kk
                    for c, u, kk in zip(cov, rng.normal(size=(n, 3)), k)])
    q_meas = rot.quat_multiply(q_true, rot.quat_from_rotvec(-err))  # q_true = q_meas ⊗ exp(err)
    flags = wrong_sample_flags(t_true, q_meas, cov, t_hist, q_hist, VERDICT)
    inside = (t_true >= t_hist[0]) & (t_true <= t_hist[-1])
    d = (Rotation.from_quat(q_meas[:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(q_true[:, [1, 2, 3, 0]])).as_rotvec()
    nis = np.array([di @ np.linalg.solve(c, di) for di, c in zip(d, cov)])
    np.testing.assert_allclose(nis, k**2, rtol=1e-6)
    assert flags.dtype == np.bool_ and inside.sum() not in (0, n)
    assert np.array_equal(flags, inside & (nis > VERDICT))
    assert flags.any() and (inside & ~flags).any()
    assert not wrong_sample_flags(t_true + 10.0, q_meas, cov, t_hist, q_hist, VERDICT).any()


VERDICT = 44.8  # the χ²(3) level of startracker.onboard.VERDICT_CHI2_3, rounded


def test_rate_kernels_are_the_numpy_expressions_bit_for_bit():
    """kernels.sensor.rate_difference and rate_at give exactly the floats of the numpy expressions they replace in the
    tracker's motion state ((ω₁ − ω₀)/dt, (C₁ + C₀)/dt², ω + α lever, C_ω + C_α lever²): episodes stay the same."""
    from startracker.kernels.sensor import rate_at, rate_difference

    rng = np.random.default_rng(14)
    for _ in range(200):
        w1, w0, a = rng.normal(0, 0.3, (3, 3))
        c1, c0, ca = (m @ m.T * 10.0 ** rng.uniform(-12, -4) for m in rng.normal(size=(3, 3, 3)))
        dt, lever = rng.uniform(1e-3, 1.0), rng.uniform(-0.2, 0.2)
        alpha, cov_alpha = rate_difference(w1, c1, w0, c0, dt, dt**2)
        np.testing.assert_array_equal(alpha, (w1 - w0) / dt)
        np.testing.assert_array_equal(cov_alpha, (c1 + c0) / dt**2)
        w, cov = rate_at(w1, c1, a, ca, lever, lever**2)
        np.testing.assert_array_equal(w, w1 + a * lever)
        np.testing.assert_array_equal(cov, c1 + ca * lever**2)


def test_rate_difference_at_is_the_motion_states_numpy_update_bit_for_bit():
    """kernels.sensor.rate_difference_at gives exactly the floats of the motion state's numpy update it replaces:
    α = (ω₁ − ω₀)/dt, C_α = (C₁ + C₀)/dt², then ω₁ + α lever and C₁ + (C_α + C_extra) lever²."""
    from startracker.kernels.sensor import rate_difference_at

    rng = np.random.default_rng(15)
    for _ in range(200):
        w1, w0 = rng.normal(0, 0.3, (2, 3))
        c1, c0, cx = (m @ m.T * 10.0 ** rng.uniform(-12, -4) for m in rng.normal(size=(3, 3, 3)))
        dt, lever = rng.uniform(1e-3, 1.0), rng.uniform(-0.2, 0.2)
        alpha, cov_alpha, w, cov = rate_difference_at(w1, c1, w0, c0, dt, dt**2, cx, lever, lever**2)
        a_ref = (w1 - w0) / dt
        ca_ref = (c1 + c0) / dt**2
        np.testing.assert_array_equal(alpha, a_ref)
        np.testing.assert_array_equal(cov_alpha, ca_ref)
        np.testing.assert_array_equal(w, w1 + a_ref * lever)
        np.testing.assert_array_equal(cov, c1 + (ca_ref + cx) * lever**2)


@pytest.mark.parametrize("seed", range(3))
def test_delivery_kernels_equal_their_numpy_formulas(seed):
    """A delivery's rows made unit bit for bit as ``q / np.linalg.norm(q, axis=1)[:, None]`` with the order test of
    ``np.diff(t) >= 0`` (NaN instants count as in order, as numpy's comparison says), and its tallies after fusion:
    the last accepted index, ``count_nonzero(wrong)`` and ``count_nonzero(wrong & accepted)``."""
    from startracker.kernels import filter as fk

    rng = np.random.default_rng(seed)
    for m in (1, 2, 7, 21):
        q = rng.normal(size=(m, 4)) * rng.choice([1e-3, 1.0, 1e3], size=(m, 1))
        t = np.sort(rng.uniform(0.0, 1.0, m))
        unit, in_order = fk.delivery_rows(q, t)
        _same(unit, q / np.linalg.norm(q, axis=1)[:, None])
        assert in_order is True
        if m > 1:
            t_swapped = t.copy()
            t_swapped[[0, -1]] = t_swapped[[-1, 0]]
            assert bool((t_swapped[1:] < t_swapped[:-1]).any())
            assert fk.delivery_rows(q, t_swapped)[1] is False
        accepted = rng.random(m) < 0.6
        wrong = rng.random(m) < 0.4
        last, n_wrong, n_confident = fk.delivery_counts(accepted, wrong)
        assert last == (np.flatnonzero(accepted)[-1] if accepted.any() else -1)
        assert n_wrong == np.count_nonzero(wrong) and n_confident == np.count_nonzero(wrong & accepted)
    t_nan = np.array([0.0, np.nan, 0.1])
    assert not (t_nan[1:] < t_nan[:-1]).any()
    assert fk.delivery_rows(np.ones((3, 4)), t_nan)[1] is True


@pytest.mark.parametrize("seed", range(3))
def test_delivery_tallies_count_by_numpy_and_equal_the_window(seed):
    """delivery_tallies: the counts numpy's flatnonzero / count_nonzero give, and innovation_window's statistics and
    ring bit for bit (on a copy of the ring); a delivery without innovations leaves the ring as it was."""
    from startracker.kernels import filter as fk

    rng = np.random.default_rng(seed)
    k = 5
    for m in (1, 4, 9):
        accepted = rng.random(m) < 0.6
        wrong = rng.random(m) < 0.4
        a = rng.normal(size=(m, 3, 3)) * 1e-5
        s = a @ a.transpose(0, 2, 1) + np.eye(3) * 1e-11
        z = rng.normal(size=(m, 3)) * 2e-5
        nis = np.array([zi @ np.linalg.solve(si, zi) for zi, si in zip(z, s)])
        ring = (rng.random(k), rng.integers(0, 3, k).astype(float), rng.normal(size=(k, 3)) * 1e-5,
                np.broadcast_to(np.eye(3) * 1e-9, (k, 3, 3)).copy())
        ring_ref = tuple(r.copy() for r in ring)
        slot = int(rng.integers(k))
        last, n_wrong, n_confident, windowed, window = fk.delivery_tallies(accepted, wrong, nis, z, s, *ring, slot)
        assert last == (np.flatnonzero(accepted)[-1] if accepted.any() else -1)
        assert n_wrong == np.count_nonzero(wrong) and n_confident == np.count_nonzero(wrong & accepted)
        assert windowed is True
        assert window == fk.innovation_window(nis, z, s, *ring_ref, slot)
        assert all(np.array_equal(r, r_ref) for r, r_ref in zip(ring, ring_ref))
        before = tuple(r.copy() for r in ring)
        out = fk.delivery_tallies(accepted, wrong, nis, np.zeros((0, 3)), np.zeros((0, 3, 3)), *ring, slot)
        assert out[:4] == (last, n_wrong, n_confident, False)
        assert all(np.array_equal(r, b) for r, b in zip(ring, before))


@pytest.mark.parametrize("seed", range(4))
def test_gyro_jump_looks_equal_two_statistics_on_the_concatenated_windows(seed):
    """The jump monitor's two looks in one call: the first look is gyro_jump_statistic on the previous and this
    span's readings; only when it finds nothing beyond the threshold, the second on the three spans' readings; the
    step's estimate is the look's own, bit for bit."""
    from startracker.kernels import filter as fk

    rng = np.random.default_rng(seed)
    n = 10
    sigma2 = 1e-8
    designs = {}
    for n_prev, n_cur, n_next in ((n, n, 0), (n, n, n)):
        k = n_prev + n_cur + n_next
        tau = np.arange(k, dtype=np.float64) - n_prev + 0.5
        cols = [np.ones(k), tau, np.maximum(tau, 0.0)] + ([np.maximum(tau - n_cur, 0.0)] if n_next else [])
        x = np.column_stack(cols)
        mm = np.ascontiguousarray(np.eye(k) - x @ np.linalg.pinv(x))
        steps = np.tril(np.ones((k, k)))
        den = np.einsum("gj,gh,hj->j", steps, mm, steps)
        den[den < 1e-9] = 0.0
        den[:n_prev] = 0.0
        den[n_prev + n_cur:] = 0.0
        designs[n_next] = (mm, den, n_prev)
    for step_at in (None, 3 * n - 2, 2 * n + 3, n + 8):  # none, in this span, in the previous span (late), early
        y = rng.normal(size=(3 * n, 3)) * 1e-4 + 0.01 * np.linspace(0, 1, 3 * n)[:, None]
        if step_at is not None:
            y[step_at:] += 0.004 * rng.normal(size=3)
        prev2, prev, cur = y[:n], y[n:2 * n], y[2 * n:]
        for second in (False, True):
            m2, den2, first2 = designs[n] if second else (np.zeros((0, 0)), np.zeros(0), 0)
            delta = np.zeros(3)
            look, j = fk.gyro_jump_looks(prev2, prev, cur, *designs[0], m2, den2, first2, sigma2, 40.0, delta)
            d1 = np.zeros(3)
            t1, j1 = fk.gyro_jump_statistic(np.concatenate([prev, cur]), *designs[0], sigma2, d1)
            if j1 >= 0 and t1 > 40.0:
                assert (look, j) == (1, j1)
                _same(delta, d1)
                continue
            if not second:
                assert (look, j) == (0, j1)
                continue
            d2 = np.zeros(3)
            t2, j2 = fk.gyro_jump_statistic(np.concatenate([prev2, prev, cur]), m2, den2, first2, sigma2, d2)
            assert (look, j) == ((2 if j2 >= 0 and t2 > 40.0 else 0), j2)
            if look == 2:
                _same(delta, d2)


def test_buffer_append_and_nonpositive_test_equal_numpy():
    """The delayed fusion's buffer append is ``np.concatenate`` of each pair (zeros for an empty rate noise), bit for
    bit, from an empty buffer too; the detections' test is ``(values <= 0).any()`` (NaN is not <= 0)."""
    from startracker.kernels import filter as fk
    from startracker.kernels import sensor as sk

    rng = np.random.default_rng(7)
    for n, g in ((0, 10), (7, 10), (12, 1)):
        tg, wg, rn = rng.random(n), rng.normal(size=(n, 3)), rng.random((n, 3))
        t_new, w_new, rn_new = rng.random(g), rng.normal(size=(g, 3)), rng.random((g, 3))
        for noise in (rn_new, np.zeros((0, 3))):
            t_out, wr = fk.append_intervals(tg, wg, rn, t_new, w_new, noise)
            out = (t_out, wr[0], wr[1])
            ref_noise = noise if len(noise) else np.zeros((g, 3))
            for a, b in zip(out, (np.concatenate([tg, t_new]), np.concatenate([wg, w_new]),
                                  np.concatenate([rn, ref_noise]))):
                _same(a, b)
    for values in (np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0, 3.0]), np.array([1.0, np.nan]),
                   np.array([2.0, -1e-300]), np.zeros(0), rng.normal(size=50)):
        assert sk.any_nonpositive(values) == bool((values <= 0).any())
