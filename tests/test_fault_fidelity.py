"""Each fault kind bites the same way in both fidelities: under the fault, the pixel path (sparse rendering and
centroiding) and the centroid fidelity give the same number of star detections and the same centroid noise,
bright bodies included.

"The same" is the Monte Carlo error of the comparison (4 standard errors, computed here from the draws) plus the
calibrated model's stated accuracy: the centroid fidelity is a closed-form model fitted to the pixel path, and
the residual differences of the fit (a star count within 2 % of the visible spots, an RMS centroid error within
35 %) are many Monte Carlo errors wide at 40 frames. The fault's effect (the count under the fault over the
fault-free count) agrees to 0.03 plus its Monte Carlo error."""

import numpy as np
import pytest

from envs.faults import FAULT_KINDS, Fault, FaultSchedule
from startracker.catalog import load_catalog
from startracker.centroid.fidelity import simulate_detections
from startracker.imaging import KIND_STAR, SensorModel, background_field
from startracker.optics import camera_preset
from startracker.rotations import quat_from_rotvec, quat_multiply, quat_random, quat_rotate
from startracker.scene import BrightBody, ExposurePlan, compute_scene

N_FRAMES = 40
Z_MAX = 4.0  # Monte Carlo standard errors of a difference
COUNT_TOL = 0.02  # model accuracy: star count, fraction of the visible spots
NOISE_TOL = 0.35  # model accuracy: RMS centroid error, relative
EFFECT_TOL = 0.03  # model accuracy: count under the fault / fault-free count

# the env's two imaging modes: a 20 ms single exposure (hold, acquisition) and 5 × 1 ms at 10 °/s (slew)
PLANS = {
    "hold": (ExposurePlan(1, 0.02, frame_period_s=0.1, start_offset_s=0.04), 0.0),
    "slew": (ExposurePlan(5, 1e-3, frame_period_s=0.1), 10.0),
}


def scene_for(mode, body=None, angle_deg=None, seed=3):
    """A real sky (V <= 6.5) in one of PLANS; ``body`` at ``angle_deg`` from the boresight."""
    plan, rate_deg_s = PLANS[mode]
    cam = camera_preset("paper000")
    q0 = quat_random(np.random.default_rng(seed))
    w = np.radians(rate_deg_s) * np.array([0.3, 1.0, 0.0]) / np.hypot(0.3, 1.0)
    bodies = []
    if body is not None:
        b = quat_rotate(q0, np.array([0.0, 0.0, 1.0]))
        p = np.cross(b, [0.0, 0.0, 1.0])
        p /= np.linalg.norm(p)
        a = np.radians(angle_deg)
        bodies = [BrightBody(body, tuple(np.cos(a) * b + np.sin(a) * p))]
    return compute_scene(cam, load_catalog(6.5), lambda t: quat_multiply(np.tile(q0, (len(t), 1)),
                         quat_from_rotvec(np.outer(t, w))), plan, 0.0, bright_bodies=bodies)


def isolated(scene, r_px=15.0):
    """(N, M) mask: the star's spot has no other spot of the frame within ``r_px`` (blends aside)."""
    xy = scene.xy_mean.reshape(-1, 2)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return (d.min(axis=1) > r_px).reshape(scene.visible.shape)


def frame_stats(scene, fidelity, schedule=None, t=0.0):
    """Per frame the number of stars detected (first detection of each spot), and the squared centroid errors
    (per axis, px²) of the isolated stars; over N_FRAMES noise draws."""
    iso = isolated(scene)
    counts, sq = [], []
    fault_rng = np.random.default_rng(77)
    for k in range(N_FRAMES):
        det = simulate_detections(scene, SensorModel(), np.random.default_rng(1000 + k), fidelity)
        if schedule is not None:
            det = schedule.modify_detections(det, t, fault_rng, scene.camera.resolution)
        if det.truth_kind is None:  # a frame the fault replaced (one saturated blob): no star in it
            counts.append(0)
            continue
        st = np.flatnonzero(det.truth_kind == KIND_STAR)
        key = det.truth_exposure[st] * scene.n_stars + det.truth_star[st]
        _, first = np.unique(key, return_index=True)
        i = st[first]
        counts.append(len(i))
        e, s = det.truth_exposure[i], det.truth_star[i]
        err = det.xy[i] - scene.xy_mean[e, s]
        keep = iso[e, s] & np.all(np.abs(err) < 3.0, axis=1)
        sq.append((err[keep] ** 2).mean(axis=1))
    return np.array(counts, float), np.concatenate(sq) if sq else np.zeros(0)


def compare(a, b, n_visible):
    """Assert the two fidelities' frame statistics agree (module docstring); returns the mean counts."""
    (ca, sa), (cb, sb) = a, b
    se_n = np.hypot(ca.std(ddof=1), cb.std(ddof=1)) / np.sqrt(N_FRAMES)
    assert abs(ca.mean() - cb.mean()) <= Z_MAX * se_n + COUNT_TOL * n_visible, (ca.mean(), cb.mean())
    if len(sa) >= 20 and len(sb) >= 20:
        ra, rb = np.sqrt(sa.mean()), np.sqrt(sb.mean())
        # delta method: se(√m) = se(m) / (2√m)
        se = np.hypot(sa.std(ddof=1) / np.sqrt(len(sa)) / (2 * ra), sb.std(ddof=1) / np.sqrt(len(sb)) / (2 * rb))
        assert abs(ra - rb) <= Z_MAX * se + NOISE_TOL * max(ra, rb), (ra, rb)
    return ca, cb


# fault kind → severities; the kinds that do not touch a frame's detections are checked on the frame they leave
CASES = [
    ("stray_light", "sun", 20.0, "hold"), ("stray_light", "sun", 12.0, "hold"), ("stray_light", "sun", 10.0, "hold"),
    ("stray_light", "sun", 40.0, "slew"), ("stray_light", "sun", 15.0, "slew"), ("stray_light", "sun", 10.0, "slew"),
    ("stray_light", "moon", 8.0, "slew"), ("stray_light", "earth", 22.0, "slew"),
    ("false_objects", None, 0.2, "slew"), ("false_objects", None, 0.5, "hold"),
    ("dropout", None, 0.3, "slew"), ("dropout", None, 0.6, "hold"),
    ("saturated", None, 1.0, "hold"), ("blank", None, 1.0, "slew"),
]
UNTOUCHED = ["dropped_frame", "time_jitter", "gyro_bias_step", "gyro_saturation", "head_blinded"]


@pytest.mark.parametrize("kind,body,severity,mode", CASES)
def test_both_fidelities_agree_under_the_fault(kind, body, severity, mode):
    quiet = scene_for(mode)
    if kind == "stray_light":
        scene, sched = scene_for(mode, body, severity), None
    else:
        scene, sched = quiet, FaultSchedule([Fault(kind, 0.0, 1.0, severity)])
    n_vis = int(scene.visible.sum())
    cp, cc = compare(frame_stats(scene, "pixel", sched, 0.5), frame_stats(scene, "centroid", sched, 0.5), n_vis)
    # the fault's effect on the count, relative to each fidelity's own fault-free frames
    fp, fc = frame_stats(quiet, "pixel")[0], frame_stats(quiet, "centroid")[0]
    rp, rc = cp.mean() / fp.mean(), cc.mean() / fc.mean()
    se = np.hypot(cp.std(ddof=1) / fp.mean(), cc.std(ddof=1) / fc.mean()) / np.sqrt(N_FRAMES)
    assert abs(rp - rc) <= Z_MAX * se + EFFECT_TOL, (rp, rc)


@pytest.mark.parametrize("kind", UNTOUCHED)
def test_faults_outside_the_frame_leave_both_fidelities_detections_alone(kind):
    """These kinds act on timing, the gyro, whole frames or other heads: a frame's detections come out unchanged
    in either fidelity, so the fault-free agreement (the cases above at the quiet sky) is theirs."""
    scene = scene_for("slew")
    sched = FaultSchedule([Fault(kind, 0.0, 1.0)])
    for fidelity in ("pixel", "centroid"):
        det = simulate_detections(scene, SensorModel(), np.random.default_rng(0), fidelity)
        assert sched.modify_detections(det, 0.5, np.random.default_rng(1), scene.camera.resolution) is det
        assert sched.sun_direction_world(0.5, np.array([0.0, 0.0, 1.0]), np.random.default_rng(2)) is None


@pytest.mark.parametrize("mode", list(PLANS))
def test_both_fidelities_agree_on_a_quiet_sky(mode):
    scene = scene_for(mode)
    compare(frame_stats(scene, "pixel"), frame_stats(scene, "centroid"), int(scene.visible.sum()))


def test_the_cases_cover_every_fault_kind_and_stray_light_bites():
    assert {c[0] for c in CASES} | set(UNTOUCHED) == set(FAULT_KINDS)
    # the stray-light cases span unharmed to blinded frames
    bg = [background_field(scene_for(m, b, s), SensorModel()) for _, b, s, m in CASES[:3]]
    assert bg[0].mean_dn(bg[0].cx, bg[0].cy) < 0.2 * SensorModel().saturation_dn < bg[2].mean_dn(bg[2].cx, bg[2].cy)
