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


def test_count_wrong_bounds_decide_like_the_eigensolver():
    """count_wrong_samples decides most samples from trace bounds on λ_max; the count must equal the direct
    rule err > max(5 sqrt(λ_max), 20″) for errors on both sides of the threshold."""
    from startracker.onboard import count_wrong_samples
    from startracker.sensor import AttitudeSample

    rng = np.random.default_rng(5)
    times = np.linspace(0.0, 0.1, 11)
    quats = rot.quat_integrate(rot.quat_random(rng), [0.2, -0.1, 0.3], times)
    samples, expected = [], 0
    for k in range(200):
        a = rng.normal(size=(3, 3)) * 10 ** rng.uniform(-6, -3)
        cov = a @ a.T + 1e-14 * np.eye(3)
        sig = np.sqrt(np.max(np.linalg.eigvalsh(cov)))
        t = rng.uniform(0.0, 0.1)
        err = max(5 * sig, np.radians(20 / 3600)) * rng.uniform(0.5, 1.5)
        axis = rng.normal(size=3)
        q_true = rot.quat_interpolate(times, quats, t)
        q_meas = rot.quat_multiply(q_true, rot.quat_from_rotvec(axis / np.linalg.norm(axis) * err))
        samples.append(AttitudeSample(t, q_meas, cov, 5))
        expected += int(rot.quat_angle_between(q_true, q_meas) > max(5 * sig, np.radians(20 / 3600)))
    assert 0 < expected < 200
    assert count_wrong_samples(samples, np.zeros(len(samples)), times, quats) == expected


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
