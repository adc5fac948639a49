"""Camera heads: the true attitude history in, detections and the scene out, and a picture when someone looks.

A head is one optical unit of the star tracker, built from a :class:`startracker.spec.StarTrackerSpec` (a preset
name, a spec or its dict): optics (:class:`startracker.optics.Camera`, with its mounting ``q_cam_to_body``),
detector (:class:`startracker.imaging.SensorModel`) and the exposure time it is run with. Given
the catalog, the truth history ``(t_s (S,), q_body_to_icrs (S, 4))`` that covers a frame, the frame's exposure plan
and a random generator, :meth:`MonoHead.detections` returns what the detector reports (``fidelity="centroid"``:
drawn from the scene truth with the pixel path's error model; ``"pixel"``: sparse rendering and centroiding) and
the scene it imaged; :meth:`MonoHead.render` draws the full picture of that scene (only when someone looks).

``MonoHead``: one detector (paper 000's intensified camera, ZY-3's APS, a user's own, ...), each preset with
its own detector (:func:`startracker.spec.preset_spec`). ``ColorHead``: paper 004's 3CMOS prism
camera: three channel scenes, per-channel detections, registered onto green with the calibration of paper 004 §3
(done once, on the ground: a simulated rotary table with a fixed seed) and fused at centroid level.

Example
-------
>>> import numpy as np
>>> from startracker.catalog import load_catalog
>>> from startracker.head import make_head
>>> from startracker.scene import ExposurePlan
>>> head = make_head("paper000")
>>> t = np.linspace(0.0, 0.1, 11); q = np.tile([1.0, 0.0, 0.0, 0.0], (11, 1))
>>> det, scene = head.detections(load_catalog(6.0), (t, q), ExposurePlan(n_exposures=1, exposure_s=1e-3, frame_period_s=0.1), 0.0,
...                              np.random.default_rng(0))
>>> det.xy.shape[1]
2
"""

from __future__ import annotations

import functools

import numpy as np

from startracker.centroid import Centroids, simulate_detections
from startracker.imaging import SensorModel, render_frame
from startracker.scene import compute_scenes
from startracker.spec import PRESET_NAMES, StarTrackerSpec, as_spec

__all__ = ["MonoHead", "ColorHead", "make_head", "HEAD_CAMERAS", "Centroids", "StarTrackerSpec"]

HEAD_CAMERAS = PRESET_NAMES
CALIBRATION_SEED = 2024  # the ground calibration of the 3CMOS head (a property of the unit, not of an episode)


@functools.lru_cache(maxsize=1)
def _ground_calibrated_camera():
    """Paper 004's 3CMOS camera (Table 2 translations) and its ground calibration (seed ``CALIBRATION_SEED``): the
    same frozen pair for every :class:`ColorHead`, so built once per process (the fit takes ~30 ms, per env before)."""
    from startracker.color import ColorCamera, ColorRegistration, generate_rotary_table_data

    color_camera = ColorCamera.paper004(translation="table2")
    rng = np.random.default_rng(CALIBRATION_SEED)
    return color_camera, ColorRegistration.calibrate(generate_rotary_table_data(color_camera, rng), rng=rng)


def _to_rgb(planes) -> np.ndarray:
    """(3, rows, cols) DN -> (rows, cols, 3) uint8: black at background + 2σ (robust), asinh stretch, so noise
    stays dark and faint stars remain visible next to bright ones."""
    planes = np.asarray(planes, dtype=np.float64)
    sub = planes[:, ::4, ::4]
    med = np.median(sub, axis=(1, 2), keepdims=True)
    sigma = 1.4826 * np.median(np.abs(sub - med), axis=(1, 2), keepdims=True)
    x = np.clip(planes - med - 2.0 * sigma, 0, None) / np.maximum(sigma, 1e-9)
    top = max(float(np.percentile(x[:, ::2, ::2], 99.99)), 1.0)  # not the max: one cosmic ray would dim everything
    out = np.clip(np.arcsinh(x / 3.0) / np.arcsinh(top / 3.0), 0, 1)
    return (np.moveaxis(out, 0, -1) * 255).astype(np.uint8)


def _mark(rgb: np.ndarray, xy, color=(0, 255, 0), half: int = 6) -> np.ndarray:
    """Square boxes around detections (vectorised over the detections)."""
    h, w = rgb.shape[:2]
    if len(xy) == 0:
        return rgb
    c = np.round(np.asarray(xy)).astype(int)
    d = np.arange(-half, half + 1)
    for side in (-half, half):  # four edges, all detections at once
        for cols, rows in ((c[:, :1] + d, c[:, 1:2] + side + 0 * d), (c[:, :1] + side + 0 * d, c[:, 1:2] + d)):
            ok = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
            rgb[rows[ok], cols[ok]] = color
    return rgb


class MonoHead:
    """One monochrome detector behind its optics, as a :class:`startracker.spec.StarTrackerSpec` describes it.

    Parameters
    ----------
    spec : str, StarTrackerSpec or dict
        A preset of :data:`HEAD_CAMERAS` (``"paper000"``, ``"zy3"``, ...), a spec or its dict form.
    q_cam_to_body : array_like, shape (4,), optional
        Mounting of the camera in the body frame (w, x, y, z), replacing the spec's.

    Attributes
    ----------
    spec : StarTrackerSpec
    camera : startracker.optics.Camera
    sensor_model : startracker.imaging.SensorModel
    exposure_s : float
        Exposure time of each exposure of a multi-exposure frame, s (the spec's).
    is_color : bool
        False.
    """

    is_color = False

    def __init__(self, spec="paper000", q_cam_to_body=None):
        self.spec = as_spec(spec, q_cam_to_body)
        if self.spec.color:
            raise ValueError("a colour (3CMOS) spec needs a ColorHead: use make_head")
        self.camera_name = self.spec.name
        self.camera = self.spec.camera
        self.sensor_model = self.spec.detector
        self.exposure_s = self.spec.exposure.exposure_s

    def detections(self, catalog, truth, plan, t_frame, rng, fidelity="centroid", bright_bodies=()):
        """Image one frame of the truth history and detect its stars.

        Parameters
        ----------
        catalog : startracker.catalog.StarCatalog
            Stars to image.
        truth : tuple (t_s (S,), q_body_to_icrs (S, 4)) or callable
            True attitude history covering the frame's exposures (s; w, x, y, z), interpolated by slerp; or
            ``truth(t) -> (len(t), 4)``.
        plan : startracker.scene.ExposurePlan
            Exposures of the frame.
        t_frame : float
            Frame start, s.
        rng : numpy.random.Generator
            Every noise draw of the detections.
        fidelity : {"centroid", "pixel"}
            Where detections come from (see the module docstring).
        bright_bodies : sequence of startracker.scene.BrightBody
            Stray-light sources in the scene.

        Returns
        -------
        det : Centroids
            Detections: ``det.xy`` (K, 2) px, ``det.intensity`` (K,), with truth labels.
        scene : startracker.scene.Scene
            What was imaged (for :meth:`render`).
        """
        # the head's own camera, model and plan, and the unit's float64 truth history: checked where they were built
        # (compute_scene's own body, without its call)
        scene = compute_scenes((self.camera,), catalog, truth, plan, t_frame, bright_bodies=bright_bodies,
                               validate=False)[0]
        det = simulate_detections(scene, self.sensor_model, rng, fidelity=fidelity, validate=False)
        return det, scene

    def render(self, scene, det) -> np.ndarray:
        """The full frame of ``scene`` (fixed-seed noise) with the detections ``det`` boxed.

        Returns
        -------
        ndarray of uint8, shape (rows, cols, 3)
        """
        image = render_frame(scene, self.sensor_model, np.random.default_rng(0))
        rgb = _to_rgb(np.stack([image] * 3))
        return _mark(rgb, det.xy)

    def __getstate__(self):
        # SensorModel holds a read-only mapping proxy (not picklable): rebuild from the spec's dict on load
        return {"spec": self.spec.to_dict()}

    def __setstate__(self, d):
        self.__init__(d["spec"])


class ColorHead:
    """Paper 004's 3CMOS head: red, green, blue detectors registered onto green and fused at centroid level.

    Parameters
    ----------
    spec : str, StarTrackerSpec or dict
        ``"paper004_3cmos"`` or a spec with ``color=True`` (paper 004's optics; its detector and exposure may
        differ from the preset's).

    Attributes
    ----------
    spec : StarTrackerSpec
    color_camera : startracker.color.ColorCamera
    camera : startracker.optics.Camera
        The green channel's camera (the registration target): the tracker's camera.
    sensor_model : startracker.imaging.SensorModel
        Each channel's detector (the spec's).
    exposure_s : float
        Exposure time of each exposure of a multi-exposure frame, s (the spec's).
    registration : startracker.color.ColorRegistration
        Ground calibration (seed ``CALIBRATION_SEED``).
    is_color : bool
        True.
    """

    is_color = True

    def __init__(self, spec="paper004_3cmos"):
        self.spec = as_spec(spec)
        if not self.spec.color:
            raise ValueError("a ColorHead needs a colour spec (color=True), e.g. 'paper004_3cmos'")
        self.camera_name = self.spec.name
        self.color_camera, self.registration = _ground_calibrated_camera()
        self.camera = self.color_camera.channel_camera("green")
        self.sensor_model = self.spec.detector
        self.exposure_s = self.spec.exposure.exposure_s

    def detections(self, catalog, truth, plan, t_frame, rng, fidelity="centroid", bright_bodies=()):
        """As :meth:`MonoHead.detections`; ``scene`` is the list of the three channel scenes (red, green, blue)
        and ``det`` the fused detections in green-channel pixels (intensity: the sum over the channels)."""
        from startracker.color import channel_scenes, fuse_channel_centroids, simulate_fused_detections

        scenes = channel_scenes(self.color_camera, catalog, truth, plan, t_frame, bright_bodies=bright_bodies, validate=False)
        if fidelity == "centroid":  # the three channels' detections and their fusion in one compiled call
            fused = simulate_fused_detections(scenes, self.sensor_model, rng, self.registration, validate=False)
        else:
            per_channel = [simulate_detections(sc, self.sensor_model, rng, fidelity=fidelity, validate=False)
                           for sc in scenes]
            fused = fuse_channel_centroids(per_channel, self.registration, gain_e_per_dn=self.sensor_model.gain_e_per_dn,
                                           validate=False)
        n = len(fused)
        total = fused.total_intensity
        det = Centroids(fused.xy, total, np.full(n, 1, dtype=np.int64), np.zeros(n, dtype=bool), total, total)
        return det, scenes

    def render(self, scenes, det) -> np.ndarray:
        """The three channels, each registered onto green, as one colour picture (red, green, blue)."""
        from startracker.color import fuse_channel_images, render_color_frame

        images = render_color_frame(scenes, self.sensor_model, np.random.default_rng(0))
        zero = np.zeros_like(images[0])
        red = fuse_channel_images(np.stack([images[0], zero, zero]), self.registration)
        blue = fuse_channel_images(np.stack([zero, zero, images[2]]), self.registration)
        rgb = _to_rgb(np.stack([red, images[1], blue]))
        return _mark(rgb, det.xy, color=(255, 255, 0))

    def __getstate__(self):
        return {"spec": self.spec.to_dict()}

    def __setstate__(self, d):
        self.__init__(d["spec"])


def make_head(camera="paper000", q_cam_to_body=None):
    """The head a camera describes.

    Parameters
    ----------
    camera : str, StarTrackerSpec or dict
        One of :data:`HEAD_CAMERAS`, a spec, or its dict form (:meth:`StarTrackerSpec.from_dict`); a colour spec
        (``"paper004_3cmos"``) gives a :class:`ColorHead`, the others a :class:`MonoHead`.
    q_cam_to_body : array_like, shape (4,), optional
        Mounting replacing the spec's (monochrome heads; the colour head is mounted along body +z).

    Returns
    -------
    MonoHead or ColorHead
    """
    spec = as_spec(camera)
    if spec.color:
        return ColorHead(spec)
    return MonoHead(spec, q_cam_to_body)
