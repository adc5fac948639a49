"""Test-session settings: the disk cache of identification databases lives in a temporary folder."""

import os

import pytest


@pytest.fixture(autouse=True, scope="session")
def _disk_cache_in_tmp(tmp_path_factory):
    old = os.environ.get("STARTRACKER_CACHE_DIR")
    os.environ["STARTRACKER_CACHE_DIR"] = str(tmp_path_factory.mktemp("startracker-cache"))
    yield
    if old is None:
        os.environ.pop("STARTRACKER_CACHE_DIR", None)
    else:
        os.environ["STARTRACKER_CACHE_DIR"] = old
