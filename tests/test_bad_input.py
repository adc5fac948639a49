"""Every public entry point refuses malformed input with a ValueError/TypeError that names the argument.

The table below is also the table of what is checked in docs/reliability.md.
"""

import numpy as np
import pytest

from startracker.attitude import solve_wahba
from startracker.catalog import load_catalog
from startracker.centroid import extract_centroids
from startracker.color import calibrate_registration
from startracker.filter import AttitudeEKF
from startracker.identify import identify
from startracker.imu import GyroSpec, gyro_preset
from startracker.kvector import KVector
from startracker.optics import Camera, camera_preset
from startracker.rotations import quat_from_rotvec, quat_normalize
from startracker.scene import ExposurePlan, choose_n_exposures
from startracker.track import match_stars

NAN = float("nan")
CAM = camera_preset("paper000")
CAT = load_catalog(5.0)
GOOD_XY = np.array([[100.0, 200.0], [300.0, 400.0], [500.0, 600.0], [700.0, 800.0]])

CASES = [
    # (entry point, call, exception, word the message must contain)
    ("load_catalog", lambda: load_catalog(mag_limit=12.0), ValueError, "mag_limit"),
    ("load_catalog", lambda: load_catalog(mag_limit="6"), TypeError, "mag_limit"),
    ("load_catalog", lambda: load_catalog(epoch=NAN), ValueError, "epoch"),
    ("StarCatalog.cone_search", lambda: CAT.cone_search([0, 0, 0], 0.1), ValueError, "direction"),
    ("Camera", lambda: Camera(focal_length_mm=0.0), ValueError, "focal_length_mm"),
    ("Camera", lambda: Camera(resolution=(0, 10)), ValueError, "resolution"),
    ("Camera.project", lambda: CAM.project([[0, 0, NAN]]), ValueError, "v_cam"),
    ("Camera.project", lambda: CAM.project([[0, 0]]), ValueError, "v_cam"),
    ("Camera.unproject", lambda: CAM.unproject([[NAN, 1.0]]), ValueError, "xy"),
    ("camera_preset", lambda: camera_preset("hubble"), ValueError, "camera preset"),
    ("quat_normalize", lambda: quat_normalize([0, 0, 0, 0]), ValueError, "q"),
    ("quat_from_rotvec", lambda: quat_from_rotvec([1.0, NAN, 0.0]), ValueError, "rotvec"),
    ("solve_wahba", lambda: solve_wahba(np.eye(3), np.eye(2)), ValueError, "v_ref"),
    ("solve_wahba", lambda: solve_wahba(np.eye(3), np.eye(3), sigma_rad=0.0), ValueError, "sigma_rad"),
    ("KVector", lambda: KVector([1.0, NAN]), ValueError, "values"),
    ("KVector", lambda: KVector([]), ValueError, "values"),
    ("ExposurePlan", lambda: ExposurePlan(n_exposures=0), ValueError, "n_exposures"),
    ("ExposurePlan", lambda: ExposurePlan(exposure_s=-1e-3), ValueError, "exposure_s"),
    ("ExposurePlan", lambda: ExposurePlan(n_exposures=3, exposure_s=0.02, spacing_s=0.045, frame_period_s=0.1), ValueError, "fit"),
    ("choose_n_exposures", lambda: choose_n_exposures(NAN, CAM), ValueError, "rate_rad_s"),
    ("extract_centroids", lambda: extract_centroids(np.zeros(10)), ValueError, "image"),
    ("extract_centroids", lambda: extract_centroids(np.full((8, 8), NAN)), ValueError, "image"),
    ("identify", lambda: identify(np.array([[NAN, 1.0]] * 4), CAM, CAT), ValueError, "xy"),
    ("identify", lambda: identify(GOOD_XY, CAM, CAT, method="magic"), ValueError, "method"),
    ("match_stars", lambda: match_stars(GOOD_XY, GOOD_XY, -1.0), ValueError, "radius_px"),
    ("match_stars", lambda: match_stars(GOOD_XY, [[NAN, 0.0]], 5.0), ValueError, "observed_xy"),
    ("match_stars", lambda: match_stars(GOOD_XY, GOOD_XY, 5.0, method="magic"), ValueError, "method"),
    ("calibrate_registration", lambda: calibrate_registration(GOOD_XY[:2], GOOD_XY[:2], principal_point=(1, 1)),
     ValueError, "xy"),
    ("calibrate_registration", lambda: calibrate_registration(GOOD_XY, GOOD_XY[:3], principal_point=(1, 1)),
     ValueError, "xy"),
    ("gyro_preset", lambda: gyro_preset("toy"), ValueError, "grade"),
    ("GyroSpec", lambda: GyroSpec(rate_hz=-1.0), ValueError, "rate_hz"),
    ("AttitudeEKF", lambda: AttitudeEKF([0, 0, 0, 0], arw_rad_sqrt_s=1e-5), ValueError, "q_body_to_icrs"),
    ("AttitudeEKF.update", lambda: AttitudeEKF([1, 0, 0, 0], arw_rad_sqrt_s=1e-5).update([1, 0, 0, 0], -np.eye(3)),
     ValueError, "covariance_rad2"),
]


@pytest.mark.parametrize("name,call,exc,word", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_malformed_input_is_refused_with_a_named_argument(name, call, exc, word):
    with pytest.raises(exc) as info:
        call()
    assert word.lower() in str(info.value).lower(), str(info.value)


def test_failed_identification_is_a_status_not_an_exception():
    r = identify(GOOD_XY[:2], CAM, CAT)  # two points cannot identify anything
    assert not r.success and r.status
    assert np.all(np.asarray(r.star_ids) == -1)


def test_empty_and_saturated_frames_give_no_crash():
    assert len(extract_centroids(np.zeros((64, 64), np.float32))) == 0
    c = extract_centroids(np.full((64, 64), 4095.0, np.float32))
    assert len(c) <= 1
