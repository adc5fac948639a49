"""3CMOS channel imaging: the three channel scenes of one frame and their images (paper 004).

Single or multi-exposure (:func:`channel_scenes`, :func:`startracker.scene.compute_scenes` for the three channels) and
their images (:func:`render_color_frame`, :func:`startracker.imaging.render_frame` per detector).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from startracker.catalog import StarCatalog
from startracker.color.camera import BV_RANGE, DEFAULT_RESPONSE, ChannelResponse, ColorCamera
from startracker.imaging import FalseObjects, SensorModel, draw_false_objects, render_frame
from startracker.optics import Camera
from startracker.scene import ExposurePlan, Scene, compute_scenes

__all__ = [
    "paper004_sensor_model",
    "channel_scenes",
    "render_color_frame",
]

def paper004_sensor_model(**overrides) -> SensorModel:
    """Detector model of the three channels of paper 004's AP-3200T-class prism camera.

    A plain (not intensified) global-shutter CMOS like the Sony IMX265 (3.45 µm, read noise ≈ 2.5 e⁻, full
    well ≈ 10 500 e⁻, 12 bit) behind the 25 mm lens at f/1.4 (entrance pupil 17.9 mm, an assumption: the
    paper does not give the aperture). The photometry describes **all three channels together** (prism
    and optics transmission 0.8, QE 0.65 over the 280 nm the channels span); each channel receives the
    share :meth:`ChannelResponse.electrons` of a star's light (:func:`channel_scenes`), so
    ``color_term_per_bv`` must stay 0. Keyword arguments override any :class:`SensorModel` field.
    """
    # the values and their sources: SensorModel.preset("paper004_3cmos") (startracker.imaging.detector)
    return replace(SensorModel.preset("paper004_3cmos"), **overrides) if overrides else SensorModel.preset("paper004_3cmos")


def channel_scenes(color_camera: ColorCamera, catalog: StarCatalog, attitude, plan: ExposurePlan,
                   t_frame_start: float = 0.0, **scene_kwargs) -> tuple[Scene, Scene, Scene]:
    """The truth of one frame on each channel's detector (single or multi-exposure).

    Each channel's scene comes from :func:`startracker.scene.compute_scenes` (one frame, three cameras) with that
    channel's :class:`ChannelCamera` (its own focal length, principal point, distortion and detector rotation).
    The stars' ``vmag`` in a channel's scene is the **channel magnitude**
    ``V − 2.5 log10(e_c(B−V))`` with ``e_c`` from ``color_camera.response``: rendered with a
    :class:`SensorModel` whose photometry describes the whole sensor (:func:`paper004_sensor_model`),
    each channel then collects its share of the star's light. ``bv`` keeps the catalog value.

    Parameters
    ----------
    color_camera : ColorCamera
    catalog, attitude, plan, t_frame_start, scene_kwargs
        As :func:`startracker.scene.compute_scene`.

    Returns
    -------
    (Scene, Scene, Scene)
        Red, green, blue.
    """
    if not isinstance(color_camera, ColorCamera):
        raise TypeError(f"color_camera must be a ColorCamera, got {type(color_camera).__name__}")
    shift = _channel_magnitude_shift(color_camera, catalog) if isinstance(catalog, StarCatalog) else None
    scenes = compute_scenes(color_camera.channel_cameras, catalog, attitude, plan, t_frame_start, **scene_kwargs)
    for i, sc in enumerate(scenes):
        if sc.n_stars:
            # a fresh scene nobody else holds: set its channel magnitudes in place rather than copy it
            object.__setattr__(sc, "vmag", sc.vmag - shift[i][sc.star_index])
    return scenes


_SHIFT_CACHE: dict = {}


def _channel_magnitude_shift(color_camera: ColorCamera, catalog: StarCatalog) -> np.ndarray:
    """``2.5 log10 e_c(B−V)`` of every catalog star in every channel, (3, n_stars): computed once per spectral
    response and catalog, since a star's channel magnitude is ``V`` minus it. The response is keyed by value: each
    new env builds its own colour camera, and the Planck integrals over a whole catalog take ~150 ms."""
    r = color_camera.response
    key = (tuple(sorted(r.bands_nm.items())), r.qe_wavelength_nm, r.qe, r.step_nm, id(catalog))
    hit = _SHIFT_CACHE.get(key)
    if hit is not None and hit[0] is catalog:
        return hit[1]
    if len(catalog.bv):
        # one contiguous row per channel: a frame picks its stars' shifts from a row
        shift = np.ascontiguousarray((2.5 * np.log10(r.electrons(np.clip(catalog.bv, *BV_RANGE)))).T)
    else:
        shift = np.zeros((3, 0))
    shift.setflags(write=False)
    if len(_SHIFT_CACHE) > 16:
        _SHIFT_CACHE.clear()
    _SHIFT_CACHE[key] = (catalog, shift)
    return shift


def _map_between_channels(cam_from: Camera, cam_to: Camera, xy: np.ndarray) -> np.ndarray:
    if len(xy) == 0:
        return xy.copy()
    return cam_to.project(cam_from.unproject(xy))[0]


def render_color_frame(scenes, model: SensorModel, rng: np.random.Generator, *,
                       false_objects: bool = True, debris_bv: float = 0.65,
                       response: ChannelResponse = DEFAULT_RESPONSE) -> np.ndarray:
    """Render the three channel images of one frame with :func:`startracker.imaging.render_frame`.

    Every channel is its own detector: its fixed pattern (PRNU, hot pixels) uses
    ``model.fixed_pattern_seed + channel``, and cosmic rays hit each detector independently. Debris is
    light, so the same debris objects (drawn once, on green) appear in all three channels, mapped
    through the channel optics and split with the colour of sunlight (``debris_bv``).

    Parameters
    ----------
    scenes : sequence of 3 Scene
        From :func:`channel_scenes` (red, green, blue), same plan and detector size.
    model : SensorModel
        Detector model of each channel (``photometry.color_term_per_bv`` must be 0).
    rng : numpy.random.Generator
    false_objects : bool
        Draw cosmic rays and debris (False: none).
    debris_bv : float
        Colour of debris (reflected sunlight, B−V ≈ 0.65).
    response : ChannelResponse
        Splits the debris light between the channels (use the ``ColorCamera``'s).

    Returns
    -------
    images : ndarray of float32, shape (3, n_rows, n_cols)
        DN per channel, red, green, blue; ``images[c, row, col]``.
    """
    scenes = tuple(scenes)
    if len(scenes) != 3 or not all(isinstance(s, Scene) for s in scenes):
        raise TypeError("scenes must be three startracker.scene.Scene objects (red, green, blue)")
    if len({s.camera.resolution for s in scenes}) != 1:
        raise ValueError(f"scenes must share one detector size, got {[s.camera.resolution for s in scenes]}")
    if len({(s.plan, s.t_frame_start) for s in scenes}) != 1:
        raise ValueError("scenes must share one exposure plan and frame start")
    if not isinstance(model, SensorModel):
        raise TypeError(f"model must be a SensorModel, got {type(model).__name__}")
    if model.photometry.color_term_per_bv != 0.0:
        raise ValueError("model.photometry.color_term_per_bv must be 0: the channel split comes from ChannelResponse")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    models = [replace(model, fixed_pattern_seed=model.fixed_pattern_seed + i) for i in range(3)]
    if false_objects:
        fo_g = draw_false_objects(scenes[1], models[1], rng)
        share = response.electrons([debris_bv])[0]
    images = []
    for i, sc in enumerate(scenes):
        if false_objects:
            fo = draw_false_objects(sc, models[i], rng)  # this detector's cosmic rays
            xy0 = _map_between_channels(scenes[1].camera, sc.camera, fo_g.debris_xy0)
            xy1 = _map_between_channels(scenes[1].camera, sc.camera, fo_g.debris_xy0 + 1e-3 * fo_g.debris_velocity_px_s)
            fo = replace(fo, debris_xy0=xy0, debris_velocity_px_s=(xy1 - xy0) / 1e-3,
                         debris_vmag=fo_g.debris_vmag - 2.5 * np.log10(share[i]))
        else:
            fo = FalseObjects.none()
        images.append(render_frame(sc, models[i], rng, false_objects=fo))
    return np.stack(images)


