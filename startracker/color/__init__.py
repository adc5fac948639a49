"""3CMOS colour star tracker (paper 004: Niu, Wei & Li, Sensors 24, 259, 2024).

A 3CMOS star sensor splits the starlight with a prism onto a red, a green and a blue detector. The
subsystem, in import order:

* :mod:`~startracker.color.registration`: the channel-to-green registration model and its calibration on
  rotary-table data (paper 004 eqs. 13-18, §3): :class:`ColorRegistration`, :func:`calibrate_registration`,
  :class:`RegistrationParams`, :func:`generate_rotary_table_data`;
* :mod:`~startracker.color.camera`: star colour -> channel electrons (:class:`ChannelResponse`) and the
  per-channel optics (:class:`ColorCamera`, paper 004 Table 1 as :meth:`ColorCamera.paper004`);
* :mod:`~startracker.color.channels`: the three channel scenes and images of one frame
  (:func:`channel_scenes`, :func:`render_color_frame`);
* :mod:`~startracker.color.fusion`: centroid- and pixel-level fusion into the green frame and the colour
  ratio by aperture photometry (:func:`fuse_channel_centroids`, :func:`fuse_channel_images`,
  :func:`aperture_photometry`);
* :mod:`~startracker.color.identify`: colour-aided lost-in-space identification (:func:`identify_color`).

The subsystem uses the mono-tracker rooms (optics, scene, imaging, identify); none of them imports it
(tests/test_layering.py). Channel order everywhere is ``CHANNELS = ("red", "green", "blue")``.
"""

from startracker.color.camera import (
    BANDS_NM,
    BV_RANGE,
    DEFAULT_RESPONSE,
    ChannelCamera,
    ChannelResponse,
    ColorCamera,
    bv_to_teff,
    planck_photon_radiance,
)
from startracker.color.channels import channel_scenes, paper004_sensor_model, render_color_frame
from startracker.color.fusion import (
    FusedDetections,
    aperture_photometry,
    color_ratio_from_fluxes,
    fuse_channel_centroids,
    fuse_channel_images,
    simulate_fused_detections,
)
from startracker.color.identify import ColorDatabase, ColorPruning, build_color_database, identify_color
from startracker.color.registration import (
    CHANNELS,
    ColorRegistration,
    RegistrationParams,
    RotaryTableData,
    calibrate_registration,
    generate_rotary_table_data,
    registration_rmse,
)

__all__ = [
    "CHANNELS",
    "BANDS_NM",
    "BV_RANGE",
    "DEFAULT_RESPONSE",
    "bv_to_teff",
    "planck_photon_radiance",
    "ChannelResponse",
    "ChannelCamera",
    "ColorCamera",
    "ColorRegistration",
    "RegistrationParams",
    "RotaryTableData",
    "calibrate_registration",
    "generate_rotary_table_data",
    "registration_rmse",
    "paper004_sensor_model",
    "channel_scenes",
    "render_color_frame",
    "fuse_channel_images",
    "FusedDetections",
    "fuse_channel_centroids",
    "simulate_fused_detections",
    "aperture_photometry",
    "color_ratio_from_fluxes",
    "ColorDatabase",
    "ColorPruning",
    "build_color_database",
    "identify_color",
]
