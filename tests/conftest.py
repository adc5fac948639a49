"""Test-session settings (the disk cache of identification databases lives in a temporary folder) and the fixtures
several test modules share."""

import os

import numpy as np
import pytest

from startracker.catalog import load_catalog, select_navigation_stars
from startracker.multifov import MultiFovSensor, paper001_head
from startracker.optics import camera_preset
from startracker.rotations import quat_from_rotvec


@pytest.fixture(autouse=True, scope="session")
def _disk_cache_in_tmp(tmp_path_factory):
    old = os.environ.get("STARTRACKER_CACHE_DIR")
    os.environ["STARTRACKER_CACHE_DIR"] = str(tmp_path_factory.mktemp("startracker-cache"))
    yield
    if old is None:
        os.environ.pop("STARTRACKER_CACHE_DIR", None)
    else:
        os.environ["STARTRACKER_CACHE_DIR"] = old


@pytest.fixture(scope="module")
def nav():
    """Navigation stars for the tracker tests: V <= 6, close doubles (blended into one spot) removed."""
    return select_navigation_stars(load_catalog(6.0), min_separation_rad=np.radians(0.1))


@pytest.fixture(scope="module")
def cam():
    """Paper 000's camera on a tilted mounting (tracker tests)."""
    return camera_preset("paper000", q_cam_to_body=quat_from_rotvec([0.2, -0.1, 0.3]))


@pytest.fixture(scope="module")
def cat():
    """Navigation stars for the multi-FoV tests: V <= 6, none closer than 60″."""
    return select_navigation_stars(load_catalog(6.0), min_separation_rad=np.radians(60 / 3600))


@pytest.fixture(scope="module")
def sensor45():
    """Paper 001's two heads, 45° apart."""
    return MultiFovSensor.two_heads(paper001_head(), 45.0)
