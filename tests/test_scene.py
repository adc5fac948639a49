"""Scene truth: exposure plans, the no-overlap rule for N, star positions at the exposure instants."""

import dataclasses

import numpy as np
import pytest

from startracker.catalog import load_catalog
from startracker.optics import Camera, camera_preset
from startracker.rotations import quat_from_rotvec, quat_integrate, quat_multiply, quat_random, quat_to_matrix
from startracker.scene import (
    BrightBody,
    ExposurePlan,
    choose_n_exposures,
    compute_scene,
    compute_scenes,
    min_image_speed_px_s,
    scene_from_tracks,
)

CAM = camera_preset("paper000")
CAT = load_catalog(6.0)


def constant_rate(q0, omega_body):
    """Attitude history rotating at a constant body rate from q0 at t = 0."""
    return lambda t: quat_integrate(np.broadcast_to(q0, (len(t), 4)), omega_body, np.asarray(t))


def pinhole(cam, v_cam):
    """Independent pinhole: col = cx + f/p X/Z, row = cy + f/p Y/Z (no distortion)."""
    f_px = cam.focal_length_mm / (cam.pixel_size_um * 1e-3)
    return np.column_stack([cam.principal_point[0] + f_px * v_cam[:, 0] / v_cam[:, 2],
                            cam.principal_point[1] + f_px * v_cam[:, 1] / v_cam[:, 2]])


# ------------------------------------------------------------------------------------- plan
def test_exposure_mid_times_are_starts_plus_half_exposure():
    plan = ExposurePlan(n_exposures=4, exposure_s=0.002, spacing_s=0.02, frame_period_s=0.1, start_offset_s=0.001)
    np.testing.assert_allclose(plan.exposure_mid_times(10.0), 10.0 + 0.001 + 0.02 * np.arange(4) + 0.001)
    np.testing.assert_allclose(plan.exposure_end_times(10.0) - plan.exposure_start_times(10.0), 0.002)
    assert plan.update_rate_hz == pytest.approx(40.0)
    assert plan.integration_window_s == pytest.approx(0.062)
    assert plan.total_exposure_s == pytest.approx(0.008)


def test_default_spacing_spreads_exposures_evenly_over_the_frame():
    plan = ExposurePlan(n_exposures=5, exposure_s=1e-3, frame_period_s=0.1)
    assert plan.spacing_s == pytest.approx(0.02)
    # consecutive frames continue the uniform stream: the next frame's first exposure is one spacing later
    t = np.concatenate([plan.exposure_mid_times(0.0), plan.exposure_mid_times(0.1)])
    np.testing.assert_allclose(np.diff(t), 0.02)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(n_exposures=0, exposure_s=1e-3),
        dict(n_exposures=-2, exposure_s=1e-3),
        dict(n_exposures=3, exposure_s=-1e-3),
        dict(n_exposures=3, exposure_s=0.0),
        dict(n_exposures=3, exposure_s=float("nan")),
        dict(n_exposures=3, exposure_s=0.01, spacing_s=0.005),  # overlapping exposures
        dict(n_exposures=11, exposure_s=0.01, spacing_s=0.01, frame_period_s=0.1),  # 0.11 s > 0.1 s
        dict(n_exposures=1, exposure_s=0.2, frame_period_s=0.1),
        dict(n_exposures=2, exposure_s=1e-3, frame_period_s=float("inf")),
        dict(n_exposures=2, exposure_s=1e-3, start_offset_s=-0.01),
    ],
)
def test_bad_plans_raise_value_error(kwargs):
    with pytest.raises(ValueError):
        ExposurePlan(**kwargs)


def test_plan_type_errors():
    with pytest.raises(TypeError):
        ExposurePlan(n_exposures=2.5, exposure_s=1e-3)
    with pytest.raises(TypeError):
        ExposurePlan(n_exposures=True, exposure_s=1e-3)


# ------------------------------------------------------------------------------------- choosing N
def test_twenty_deg_per_s_gives_paper000_update_rate():
    """Paper 000 §1/§5: MEIA reaches 210 Hz at 20°/s with 10 Hz frames (N = 21)."""
    plan = ExposurePlan.for_rate(np.radians(20.0), CAM, frame_period_s=0.1)
    assert plan.n_exposures == 21
    assert plan.update_rate_hz == pytest.approx(210.0)
    # and without the cap, the rule itself gives 21 (v T / (v τ + 6σ) = 21.97)
    assert choose_n_exposures(np.radians(20.0), CAM, 0.1, 1e-3, 1.2, n_max=100) == 21
    assert choose_n_exposures(0.0, CAM) == 1


def test_n_is_monotone_in_rate_and_bounded():
    rates = np.radians(np.linspace(0.0, 40.0, 161))
    ns = [choose_n_exposures(r, CAM) for r in rates]
    assert np.all(np.diff(ns) >= 0)
    assert ns[0] == 1 and max(ns) == 21
    axis = np.array([0.6, -0.8, 0.3])
    ns_vec = [choose_n_exposures(r * axis / np.linalg.norm(axis), CAM) for r in rates]
    assert np.all(np.diff(ns_vec) >= 0)
    assert choose_n_exposures(np.radians(30.0), CAM, n_max=7) == 7


def test_rule_formula_by_hand():
    f_px = 31.94 / 5.5e-3
    v = f_px * np.radians(5.0)
    expected = int(np.floor(v * 0.1 / (v * 2e-3 + 6 * 1.5)))
    assert choose_n_exposures(np.radians(5.0), CAM, 0.1, 2e-3, 1.5) == expected
    assert min_image_speed_px_s(np.radians(5.0), CAM) == pytest.approx(v)


def test_slowest_image_speed_is_the_finite_difference_of_the_pinhole():
    """The slowest star-image speed over the 7×7 detector grid for a body rate, against the image motion of stars
    through an independent pinhole (``pinhole`` above): each grid point's star direction, the camera turned by
    ±ω dt about its mounting, the central difference of the projected positions."""
    from scipy.spatial.transform import Rotation

    mount = quat_from_rotvec(np.radians([10.0, -25.0, 40.0]))
    cam = dataclasses.replace(CAM, q_cam_to_body=mount)
    r_cb = Rotation.from_quat(mount, scalar_first=True)
    f_px = cam.focal_length_mm / (cam.pixel_size_um * 1e-3)
    cx, cy = cam.principal_point
    w, h = cam.resolution
    xs, ys = np.meshgrid(np.linspace(-0.5, w - 0.5, 7), np.linspace(-0.5, h - 0.5, 7))
    u = np.column_stack([(xs.ravel() - cx) / f_px, (ys.ravel() - cy) / f_px, np.ones(49)])
    dt = 1e-6
    for w_body in (np.radians([3.0, -1.0, 0.5]), np.radians([0.0, 0.0, 12.0]), np.radians([-7.0, 2.0, -4.0])):
        w_cam = r_cb.inv().apply(w_body)
        # a star fixed in inertial space seen from a camera turned by θ: v_cam(θ) = R(θ)ᵀ u
        ahead = pinhole(cam, Rotation.from_rotvec(w_cam * dt).inv().apply(u))
        behind = pinhole(cam, Rotation.from_rotvec(-w_cam * dt).inv().apply(u))
        truth = np.min(np.linalg.norm(ahead - behind, axis=1) / (2 * dt))
        assert min_image_speed_px_s(w_body, cam) == pytest.approx(truth, rel=1e-6, abs=1e-6)


def test_pure_roll_has_a_still_point_so_n_is_one():
    assert min_image_speed_px_s(np.array([0.0, 0.0, 0.3]), CAM) == pytest.approx(0.0, abs=1e-9)
    assert choose_n_exposures(np.array([0.0, 0.0, 0.3]), CAM) == 1


@pytest.mark.parametrize("bad", [float("nan"), -0.1, np.array([0.1, np.inf, 0.0]), np.zeros(2)])
def test_bad_rates_raise(bad):
    with pytest.raises(ValueError):
        choose_n_exposures(bad, CAM)


def segment_distance(p0, p1, q0, q1, n=41):
    """Minimum distance between two short segments (dense sampling, exact enough for a test)."""
    s = np.linspace(0, 1, n)[:, None]
    a = p0 + s * (p1 - p0)
    b = q0 + s * (q1 - q0)
    return np.min(np.linalg.norm(a[:, None] - b[None], axis=-1))


def test_spots_of_a_star_never_overlap_at_the_chosen_n():
    """At the chosen N, consecutive streaks of every star stay at least 6σ apart (the rule's promise)."""
    rng = np.random.default_rng(3)
    sigma = 1.2
    checked = 0
    for _ in range(12):
        rate = np.radians(rng.uniform(1.0, 25.0))
        q0 = quat_random(rng)
        # cross-boresight axis (camera +z is the body +z with the default mounting), plus a small roll
        phi = rng.uniform(0, 2 * np.pi)
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])
        omega = rate * axis + np.array([0.0, 0.0, rng.uniform(-0.02, 0.02)])
        plan = ExposurePlan.for_rate(omega, CAM, psf_sigma_px=sigma)
        if plan.n_exposures < 2:
            continue
        sc = compute_scene(CAM, CAT, constant_rate(q0, omega), plan, 0.0)
        for m in range(sc.n_stars):
            for i in range(plan.n_exposures - 1):
                if not (sc.visible[i, m] and sc.visible[i + 1, m]):
                    continue
                gap = segment_distance(sc.xy_start[i, m], sc.xy_end[i, m], sc.xy_start[i + 1, m], sc.xy_end[i + 1, m])
                assert gap >= 6 * sigma - 1e-6
                checked += 1
    assert checked > 500


# ------------------------------------------------------------------------------------- geometry
def test_positions_are_the_pinhole_projection_at_each_exposure_mid_time():
    rng = np.random.default_rng(0)
    q0 = quat_random(rng)
    omega = np.radians([3.0, -2.0, 1.0])
    plan = ExposurePlan(n_exposures=5, exposure_s=2e-3, frame_period_s=0.1)
    att = constant_rate(q0, omega)
    sc = compute_scene(CAM, CAT, att, plan, 0.05)
    assert sc.n_stars > 10
    np.testing.assert_allclose(sc.times, 0.05 + 0.02 * np.arange(5) + 1e-3)
    for i, t in enumerate(sc.times):
        r_bw = quat_to_matrix(att(np.array([t]))[0])
        v_cam = CAT.vectors[sc.star_index] @ r_bw  # R^T v (identity mounting)
        np.testing.assert_allclose(sc.xy[i], pinhole(CAM, v_cam), atol=1e-6)
    np.testing.assert_array_equal(sc.hip, CAT.hip[sc.star_index])
    np.testing.assert_allclose(sc.q_body_to_icrs, att(sc.times), atol=1e-12)


def test_cone_search_keeps_exactly_the_stars_brute_force_finds():
    rng = np.random.default_rng(1)
    for _ in range(5):
        q0 = quat_random(rng)
        plan = ExposurePlan(n_exposures=1, exposure_s=0.05)
        sc = compute_scene(CAM, CAT, lambda t: np.tile(q0, (len(t), 1)), plan, 0.0, edge_margin_px=0.0)
        v_cam = CAT.vectors @ quat_to_matrix(q0)
        front = v_cam[:, 2] > 0
        xy = pinhole(CAM, np.where(front[:, None], v_cam, 1.0))
        inside = front & (xy[:, 0] >= -0.5) & (xy[:, 0] <= 2047.5) & (xy[:, 1] >= -0.5) & (xy[:, 1] <= 2047.5)
        assert set(np.flatnonzero(inside)) == set(sc.star_index[sc.visible[0]])
        assert set(np.flatnonzero(inside)) == set(sc.star_index)


def test_mounting_and_sampled_attitude_agree_with_callable():
    """A star on the mounted camera's boresight lands on the principal point; tuple == callable."""
    q_cb = quat_from_rotvec(np.array([np.pi / 2, 0.0, 0.0]))  # camera +z = body -y
    cam = CAM.with_mounting(q_cb)
    q_bw = quat_random(np.random.default_rng(4))
    boresight_world = quat_to_matrix(quat_multiply(q_bw, q_cb)) @ np.array([0.0, 0.0, 1.0])
    star = int(np.argmax(CAT.vectors @ boresight_world))
    # rotate the body so that the boresight points exactly at the star
    axis = np.cross(boresight_world, CAT.vectors[star])
    ang = np.arcsin(np.linalg.norm(axis))
    q_fix = quat_multiply(quat_from_rotvec(axis / np.linalg.norm(axis) * ang), q_bw)
    plan = ExposurePlan(n_exposures=1, exposure_s=0.01)
    sc = compute_scene(cam, CAT, lambda t: np.tile(q_fix, (len(t), 1)), plan, 0.0)
    k = int(np.flatnonzero(sc.star_index == star)[0])
    np.testing.assert_allclose(sc.xy[0, k], cam.principal_point, atol=1e-6)
    omega = np.radians([1.0, 2.0, 0.5])
    att = constant_rate(q_fix, omega)
    ts = np.linspace(-0.1, 0.3, 401)
    plan5 = ExposurePlan(n_exposures=5, exposure_s=1e-3)
    a = compute_scene(cam, CAT, att, plan5, 0.0)
    b = compute_scene(cam, CAT, (ts, att(ts)), plan5, 0.0)
    np.testing.assert_array_equal(a.star_index, b.star_index)
    np.testing.assert_allclose(a.xy_path, b.xy_path, atol=1e-3)


def test_smear_length_is_focal_length_times_rate_times_exposure():
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    omega = np.array([np.radians(10.0), 0.0, 0.0])
    plan = ExposurePlan(n_exposures=3, exposure_s=2e-3)
    sc = compute_scene(CAM, CAT, constant_rate(q0, omega), plan, 0.0)
    assert sc.visible.sum() > 30
    f_px = CAM.focal_length_px
    # image speed of the pinhole for rotation about x: (x y / f, f + y²/f) ω
    y = sc.xy[..., 1] - CAM.principal_point[1]
    x = sc.xy[..., 0] - CAM.principal_point[0]
    speed = np.hypot(x * y / f_px, f_px + y * y / f_px) * omega[0]
    np.testing.assert_allclose(sc.smear_px[sc.visible], (speed * 2e-3)[sc.visible], rtol=2e-3)
    # uniform motion: the time-averaged position is the mid-time position
    np.testing.assert_allclose(sc.xy_mean, sc.xy, atol=1e-3)


def test_bright_body_angle():
    sun_dir = np.array([np.sin(np.radians(40)), 0.0, np.cos(np.radians(40))])
    sc = compute_scene(CAM, CAT, lambda t: np.tile([1.0, 0, 0, 0], (len(t), 1)), ExposurePlan(2, 1e-3), 0.0,
                       bright_bodies=[BrightBody("sun", sun_dir)])
    assert sc.bright_bodies[0].angle_rad == pytest.approx(np.radians(40.0))


@pytest.mark.parametrize(
    "attitude",
    [
        lambda t: np.full((len(t), 4), np.nan),
        lambda t: np.zeros((len(t), 4)),
        lambda t: np.ones((len(t), 3)),
        "not an attitude",
    ],
)
def test_bad_attitudes(attitude):
    with pytest.raises((ValueError, TypeError)):
        compute_scene(CAM, CAT, attitude, ExposurePlan(2, 1e-3), 0.0)


def test_bad_scene_arguments():
    att = lambda t: np.tile([1.0, 0, 0, 0], (len(t), 1))  # noqa: E731
    with pytest.raises(ValueError):
        compute_scene(CAM, CAT, att, ExposurePlan(2, 1e-3), float("nan"))
    with pytest.raises(ValueError):
        compute_scene(CAM, CAT, att, ExposurePlan(2, 1e-3), 0.0, n_path_samples=4)
    with pytest.raises(TypeError):
        compute_scene(CAM, CAT, att, "plan", 0.0)
    with pytest.raises(ValueError):  # samples that do not cover the exposures
        compute_scene(CAM, CAT, (np.array([0.0, 0.01]), np.tile([1.0, 0, 0, 0], (2, 1))), ExposurePlan(2, 1e-3), 0.0)


def test_scene_from_tracks_moves_linearly():
    cam = Camera(resolution=(128, 128))
    plan = ExposurePlan(4, 1e-3, frame_period_s=0.1)
    sc = scene_from_tracks(cam, plan, [[60.0, 70.0]], [5.0], [[100.0, -50.0]])
    t_c = 0.5 * plan.integration_window_s
    np.testing.assert_allclose(sc.xy[:, 0, 0], 60.0 + 100.0 * (sc.times - t_c))
    np.testing.assert_allclose(sc.smear_px[:, 0], np.hypot(100, 50) * 1e-3)


# ------------------------------------------------------------------------------------- compiled kernels
def explicit_projection(cam, q_body_to_icrs, v_icrs):
    """Independent reference: v_cam = R_cbᵀ R_bwᵀ v, then x' = f X/Z, y' = f Y/Z (mm), δ = k1 (x'² + y'²),
    col = cx + x' (1 + δ) / p, row = cy + y' (1 + δ) / p (paper 004 eqs. 1-3); rotations from scipy."""
    from scipy.spatial.transform import Rotation

    r_bw = Rotation.from_quat(np.roll(q_body_to_icrs, -1)).as_matrix()
    r_cb = Rotation.from_quat(np.roll(np.asarray(cam.q_cam_to_body), -1)).as_matrix()
    v_cam = v_icrs @ r_bw @ r_cb  # rows: (R_bw R_cb)ᵀ v
    xm = cam.focal_length_mm * v_cam[:, 0] / v_cam[:, 2]
    ym = cam.focal_length_mm * v_cam[:, 1] / v_cam[:, 2]
    d = 1.0 + cam.distortion_k1_per_mm2 * (xm**2 + ym**2)
    p = cam.pixel_size_um * 1e-3
    return np.column_stack([cam.principal_point[0] + xm * d / p, cam.principal_point[1] + ym * d / p]), v_cam[:, 2]


def test_every_path_point_is_the_explicit_distorted_pinhole():
    """Distortion, an off-centre principal point and a tilted mounting: every path sample of every star equals
    the textbook projection of its direction at that instant (attitude from the sampled truth)."""
    cam = Camera(resolution=(1024, 768), pixel_size_um=6.5, focal_length_mm=25.0, principal_point=(530.0, 370.0),
                 distortion_k1_per_mm2=2.0e-4, q_cam_to_body=tuple(quat_from_rotvec(np.array([0.3, -0.2, 0.1]))))
    rng = np.random.default_rng(11)
    q0 = quat_random(rng)
    att = constant_rate(q0, np.radians([4.0, -3.0, 2.0]))
    ts = np.linspace(0.0, 0.1, 11)
    plan = ExposurePlan(n_exposures=4, exposure_s=2e-3, frame_period_s=0.1)
    sc = compute_scene(cam, CAT, (ts, att(ts)), plan, 0.0, n_path_samples=5)
    assert sc.n_stars > 5
    from scipy.spatial.transform import Rotation, Slerp

    slerp = Slerp(ts, Rotation.from_quat(np.roll(att(ts), -1, axis=1)))
    for i in range(plan.n_exposures):
        for t in range(5):
            q = np.roll(slerp([sc.path_times[i, t]]).as_quat()[0], 1)
            xy, z = explicit_projection(cam, q, CAT.vectors[sc.star_index])
            assert np.all(z > 0)
            np.testing.assert_allclose(sc.xy_path[i, t], xy, rtol=0, atol=1e-8)


def test_interpolated_attitudes_are_scipy_slerp():
    """The compiled interpolation equals scipy's Slerp on an irregular, sign-flipping history, at the samples,
    between them and at the ends."""
    from scipy.spatial.transform import Rotation, Slerp

    from startracker.kernels.scene import interpolate_attitudes

    rng = np.random.default_rng(5)
    for _ in range(5):
        t_s = np.cumsum(rng.uniform(0.001, 0.02, 12))
        q_s = quat_integrate(np.broadcast_to(quat_random(rng), (12, 4)), rng.normal(0, 2.0, 3), t_s - t_s[0])
        q_s *= rng.choice([-1.0, 1.0], (12, 1)) * rng.uniform(0.5, 2.0, (12, 1))  # any sign and norm
        tq = np.concatenate([t_s, rng.uniform(t_s[0], t_s[-1], 40)])
        got = interpolate_attitudes(t_s, q_s, tq)
        ref = np.roll(Slerp(t_s, Rotation.from_quat(np.roll(q_s, -1, axis=1)))(tq).as_quat(), 1, axis=1)
        ref *= np.where(ref[:, :1] < 0, -1.0, 1.0)
        np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-15)
        assert np.all(got[:, 0] >= 0)
        np.testing.assert_allclose(got, ref, atol=2e-15)


def test_kept_and_visible_stars_are_the_brute_force_sets_with_a_margin():
    """Moving camera, margin 20 px: kept = in front and within the margin at some path instant; visible = in front
    over the whole exposure and on the detector at the mid instant; brute force over the whole catalog."""
    rng = np.random.default_rng(8)
    for _ in range(3):
        q0 = quat_random(rng)
        att = constant_rate(q0, np.radians([6.0, 5.0, -1.0]))
        plan = ExposurePlan(n_exposures=3, exposure_s=0.02, frame_period_s=0.1)
        margin = 20.0
        sc = compute_scene(CAM, CAT, att, plan, 0.0, edge_margin_px=margin)
        near_any = np.zeros(len(CAT.vectors), dtype=bool)
        vis = np.zeros((3, len(CAT.vectors)), dtype=bool)
        for i in range(3):
            front_all = np.ones(len(CAT.vectors), dtype=bool)
            for t in range(3):
                q = att(np.array([sc.path_times[i, t]]))[0]
                xy, z = explicit_projection(CAM, q, CAT.vectors)
                front = z > 0
                front_all &= front
                inside = (xy[:, 0] >= -0.5 - margin) & (xy[:, 0] <= 2047.5 + margin) & \
                    (xy[:, 1] >= -0.5 - margin) & (xy[:, 1] <= 2047.5 + margin)
                near_any |= front & inside
                if t == 1:
                    mid = (xy[:, 0] >= -0.5) & (xy[:, 0] <= 2047.5) & (xy[:, 1] >= -0.5) & (xy[:, 1] <= 2047.5)
            vis[i] = front_all & mid
        assert set(sc.star_index) == set(np.flatnonzero(near_any))
        assert sc.n_stars > np.count_nonzero(sc.visible.any(axis=0))  # the margin keeps some off-detector stars
        np.testing.assert_array_equal(sc.visible, vis[:, sc.star_index])
        assert np.all(np.diff(sc.star_index) > 0)


def test_channel_camera_scene_is_the_rotated_pinhole():
    """A 3CMOS channel's detector is rotated in its plane (paper 004 eq. 22): the scene on it is
    pp + R(θ)ᵀ (pinhole − pp), and its visibility uses the rotated positions."""
    from startracker.color import ChannelCamera

    base = Camera(resolution=(640, 512), pixel_size_um=5.5, focal_length_mm=16.0, distortion_k1_per_mm2=1e-4)
    theta = np.radians(3.0)
    ch = ChannelCamera.from_camera(base, rotation_rad=theta)
    q0 = quat_random(np.random.default_rng(21))
    att = constant_rate(q0, np.radians([1.0, 2.0, 0.0]))
    plan = ExposurePlan(2, 5e-3)
    sc = compute_scene(ch, CAT, att, plan, 0.0)
    assert sc.n_stars > 3
    c, s = np.cos(theta), np.sin(theta)
    pp = np.asarray(base.principal_point)
    for i in range(2):
        q = att(np.array([sc.times[i]]))[0]
        xy, _ = explicit_projection(base, q, CAT.vectors[sc.star_index])
        rot = pp + (xy - pp) @ np.array([[c, -s], [s, c]])
        np.testing.assert_allclose(sc.xy[i], rot, atol=1e-8)
        on = (rot[:, 0] >= -0.5) & (rot[:, 0] <= 639.5) & (rot[:, 1] >= -0.5) & (rot[:, 1] <= 511.5)
        np.testing.assert_array_equal(sc.visible[i], on)


def test_validate_false_gives_the_same_scene():
    q0 = quat_random(np.random.default_rng(3))
    att = constant_rate(q0, np.radians([2.0, 1.0, 0.5]))
    ts = np.linspace(0.0, 0.1, 11)
    plan = ExposurePlan(5, 1e-3)
    a = compute_scene(CAM, CAT, (ts, att(ts)), plan, 0.0)
    b = compute_scene(CAM, CAT, (ts, att(ts)), plan, 0.0, validate=False)
    for f in ("times", "path_times", "star_index", "xy_path", "visible", "q_body_to_icrs", "q_cam_to_icrs"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    # the camera attitude is the body attitude composed with the mounting
    np.testing.assert_allclose(a.q_cam_to_icrs, quat_multiply(a.q_body_to_icrs, np.asarray(CAM.q_cam_to_body)), atol=1e-15)


def test_per_frame_scene_and_detections_are_complete_dataclasses():
    """The head's per-frame Scene and Centroids are built with their fields set at once: every field is there, in
    order, as the generated __init__ would set them; the plan's times agree with its fields."""
    import dataclasses

    from startracker.head import make_head

    head = make_head("paper000")
    plan = ExposurePlan(n_exposures=4, exposure_s=0.002, frame_period_s=0.1)
    t = np.linspace(0.0, 0.2, 21)
    q = quat_integrate(np.array([1.0, 0.0, 0.0, 0.0]), np.radians([0.0, 3.0, 4.0]), t - 0.0)
    det, scene = head.detections(load_catalog(6.0), (t, np.ascontiguousarray(q)), plan, np.float64(0.05),
                                 np.random.default_rng(1))
    assert len(det) > 0 and scene.n_stars > 0
    for obj in (det, scene):
        names = [f.name for f in dataclasses.fields(obj)]
        assert list(vars(obj)) == names
        rebuilt = dataclasses.replace(obj)
        assert all(getattr(obj, n) is getattr(rebuilt, n) for n in names)
    # np.float64 frame times take the plan's fast path: the same instants as from their float
    np.testing.assert_array_equal(plan.exposure_mid_times(np.float64(0.05)), plan.exposure_mid_times(0.05))
    np.testing.assert_allclose(plan.exposure_mid_times(0.05), 0.05 + 0.025 * np.arange(4) + 0.001, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(scene.times, plan.exposure_mid_times(0.05))


def test_scenes_of_cameras_imaging_one_frame_are_each_cameras_scene():
    """compute_scenes (one frame, several cameras: the 3CMOS channels) gives each camera the scene compute_scene gives
    it, with a sampled history (checked or not) or a callable, and a bright body; bad cameras are named."""
    from startracker.color import ChannelCamera

    mounted = CAM.with_mounting(quat_from_rotvec(np.array([0.0, 0.2, 0.0])))
    small = Camera(resolution=(640, 512), pixel_size_um=5.5, focal_length_mm=16.0, distortion_k1_per_mm2=1e-4)
    cams = (CAM, ChannelCamera.from_camera(small, rotation_rad=np.radians(3.0)), mounted, small)
    q0 = quat_random(np.random.default_rng(8))
    att = constant_rate(q0, np.radians([2.0, 1.0, 0.5]))
    ts = np.linspace(0.0, 0.2, 21)
    sun = [BrightBody("sun", np.array([0.3, 0.1, 0.9]))]
    for attitude, validate in (((ts, att(ts)), False), ((ts, att(ts)), True), (att, True)):
        plan = ExposurePlan(3, 2e-3)
        got = compute_scenes(cams, CAT, attitude, plan, 0.05, bright_bodies=sun, validate=validate)
        assert len(got) == len(cams)
        for cam, sc in zip(cams, got):
            want = compute_scene(cam, CAT, attitude, plan, 0.05, bright_bodies=sun, validate=validate)
            assert sc.camera is cam and sc.n_stars > 0
            for f in ("times", "path_times", "star_index", "hip", "vmag", "bv", "xy_path", "visible", "q_body_to_icrs",
                      "q_cam_to_icrs"):
                np.testing.assert_array_equal(getattr(sc, f), getattr(want, f))
            np.testing.assert_array_equal(sc.bright_bodies[0].direction_cam, want.bright_bodies[0].direction_cam)
    with pytest.raises(TypeError, match=r"cameras\[1\]"):
        compute_scenes((CAM, "camera"), CAT, att, ExposurePlan(1, 1e-3), 0.0)
