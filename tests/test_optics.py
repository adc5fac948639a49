"""Camera geometry: pinhole facts, distortion round trip, presets of the papers."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from startracker.optics import Camera, camera_preset


def test_boresight_star_projects_to_principal_point():
    cam = Camera(principal_point=(1000.25, 1030.75), distortion_k1_per_mm2=5e-5)
    xy, inside = cam.project(np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(xy[0], [1000.25, 1030.75], atol=1e-12)
    assert inside[0]


def test_detector_centre_convention():
    cam = Camera(resolution=(2048, 2048))
    assert cam.principal_point == (1023.5, 1023.5)


def test_pinhole_offset_matches_focal_length_in_pixels():
    cam = camera_preset("paper000")
    angle = np.radians(5.0)
    xy, _ = cam.project(np.array([[np.sin(angle), 0.0, np.cos(angle)]]))
    expected = 1023.5 + 31.94 / 5.5e-3 * np.tan(angle)
    assert xy[0, 0] == pytest.approx(expected, abs=1e-9)
    assert xy[0, 1] == pytest.approx(1023.5, abs=1e-9)


def test_distortion_follows_paper004_eq3():
    m = 4.9e-5  # 1/mm^2
    cam = Camera(resolution=(2064, 1544), pixel_size_um=3.45, focal_length_mm=25.0, principal_point=(1032, 772),
                 distortion_k1_per_mm2=m)
    v = np.array([[0.1, -0.05, 1.0]])
    x_ideal, y_ideal = 25.0 * 0.1, 25.0 * -0.05
    r2 = x_ideal**2 + y_ideal**2
    xy, _ = cam.project(v)
    assert xy[0, 0] == pytest.approx(1032 + (x_ideal + x_ideal * m * r2) / 3.45e-3, abs=1e-9)
    assert xy[0, 1] == pytest.approx(772 + (y_ideal + y_ideal * m * r2) / 3.45e-3, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.17, 0.17), st.floats(-0.17, 0.17), st.sampled_from([-3e-5, 0.0, 4.9e-5, 2e-4]))
def test_unproject_inverts_project_including_distortion(tx, ty, m):
    cam = Camera(distortion_k1_per_mm2=m)
    v = np.array([[tx, ty, 1.0]])
    v /= np.linalg.norm(v)
    xy, _ = cam.project(v)
    np.testing.assert_allclose(cam.unproject(xy), v, atol=1e-12)


def test_points_behind_camera_and_off_detector_are_flagged():
    cam = camera_preset("paper000")
    v = np.array([[0, 0, 1.0], [0, 0, -1.0], [0.5, 0, 0.5], [0.0, 0.1, 1.0]])
    xy, inside, in_front = cam.project(v, return_in_front=True)
    assert inside.tolist() == [True, False, False, True]
    assert in_front.tolist() == [True, False, True, True]
    assert np.all(np.isfinite(xy))


@pytest.mark.parametrize(
    "name,fov",
    [("paper000", (20.0, 20.0)), ("zy3", (20.1, 20.1)), ("paper003", (16.0, 16.0)), ("paper004", (16.2, 12.2))],
)
def test_presets_have_the_papers_fields_of_view(name, fov):
    assert camera_preset(name).fov_deg == pytest.approx(fov, abs=0.05)


def test_mounting_rotates_boresight():
    q = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0])  # 90 deg about x
    cam = Camera(q_cam_to_body=q)
    np.testing.assert_allclose(cam.boresight_body(), [0, -1, 0], atol=1e-15)


@pytest.mark.parametrize(
    "kwargs,word",
    [
        (dict(focal_length_mm=0.0), "focal_length_mm"),
        (dict(focal_length_mm=-3.0), "focal_length_mm"),
        (dict(pixel_size_um=float("nan")), "pixel_size_um"),
        (dict(resolution=(10,)), "resolution"),
        (dict(principal_point=(1.0, float("inf"))), "principal_point"),
        (dict(q_cam_to_body=(0, 0, 0, 0)), "q"),
    ],
)
def test_bad_camera_parameters_raise(kwargs, word):
    with pytest.raises(ValueError, match=word):
        Camera(**kwargs)


def test_bad_vectors_raise():
    cam = Camera()
    with pytest.raises(ValueError, match="v_cam"):
        cam.project(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="v_cam"):
        cam.project(np.ones((2, 2)))
    with pytest.raises(ValueError, match="xy"):
        cam.unproject([[np.nan, 1.0]])


def _radius_closed_form(rd, m):
    """Undistorted radius: the root of m r³ + r − r_d = 0 on the monotone branch (Cardano / Viète)."""
    if m == 0.0 or rd == 0.0:
        return rd
    p, q = 1.0 / m, -rd / m  # r³ + p r + q = 0
    disc = q * q / 4.0 + p**3 / 27.0
    if disc >= 0.0:  # one real root (m > 0)
        s = np.sqrt(disc)
        return float(np.cbrt(-q / 2.0 + s) + np.cbrt(-q / 2.0 - s))
    # three real roots (m < 0): the smallest positive one is below the fold radius 1/sqrt(-3m)
    roots = [2.0 * np.sqrt(-p / 3.0) * np.cos(np.arccos(1.5 * q / p * np.sqrt(-3.0 / p)) / 3.0 - 2.0 * np.pi * k / 3.0)
             for k in range(3)]
    return float(min(r for r in roots if r > 0))


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.5, 2063.5), st.floats(-0.5, 1543.5), st.sampled_from([-3e-5, 0.0, 4.9e-5, 2e-4]))
def test_unproject_kernel_matches_closed_form(col, row, m):
    from startracker.kernels.optics import unproject_pinhole

    cam = Camera(resolution=(2064, 1544), pixel_size_um=3.45, focal_length_mm=25.0, principal_point=(1032.0, 772.0),
                 distortion_k1_per_mm2=m)
    dx, dy = (col - 1032.0) * 3.45e-3, (row - 772.0) * 3.45e-3
    rd = np.hypot(dx, dy)
    r = _radius_closed_form(rd, m)
    scale = r / rd if rd > 0 else 1.0
    expected = np.array([dx * scale, dy * scale, 25.0])
    expected /= np.linalg.norm(expected)
    v = unproject_pinhole(np.array([[col, row]]), 25.0, m, 3.45e-3, 1032.0, 772.0)
    np.testing.assert_allclose(v[0], expected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(cam.unproject([col, row]), expected, rtol=0, atol=1e-13)
    assert abs(np.linalg.norm(v[0]) - 1.0) < 1e-15 and v[0, 2] > 0


def test_unproject_shapes_and_checks():
    cam = camera_preset("paper004")
    xy = np.array([[10.0, 20.0], [1032.0, 772.0], [2000.0, 1500.0]])
    v = cam.unproject(xy)
    assert v.shape == (3, 3) and cam.unproject(xy[1]).shape == (3,)
    np.testing.assert_allclose(v[1], [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_array_equal(cam.unproject(xy[:, :].tolist()), v)
    with pytest.raises(ValueError, match="xy"):
        cam.unproject([[1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match="xy"):
        cam.unproject([[np.inf, 1.0]])
