"""Shared scene fixtures: the bundled ISS TLE over Graz on 2023-03-20 (library:tle/iss.tle)."""

from datetime import datetime, timezone

import pytest

from evsda import library
from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import GROUND, Observer, Pointing
from evsda.blocks.scene.tle import parse_tles

GRAZ = dict(latitude_deg=47.0671, longitude_deg=15.4934, altitude_m=493.0)
PASS_START = datetime(2023, 3, 20, 19, 19, 57, tzinfo=timezone.utc)   # the scene quick-start run (docs/scene.md)


def load_tle(name: str):
    return parse_tles(library.path(f"tle/{name}").read_text(), name)[0]


@pytest.fixture(scope="session")
def pass_start():
    return PASS_START


@pytest.fixture(scope="session")
def tle():
    """``tle("galaxy-25.tle")``: a bundled element set."""
    return load_tle


@pytest.fixture(scope="session")
def iss():
    return load_tle("iss.tle")


@pytest.fixture(scope="session")
def graz():
    return Observer(name="Graz", kind=GROUND, min_elevation_deg=10.0, max_sun_elevation_deg=-12.0,
                    extinction_mag_per_airmass=0.2, **GRAZ)


@pytest.fixture(scope="session")
def gen4():
    """1280x720 4.86 um pixels behind a 1 m focal length (0.5 m f/2): 1.0 arcsec per pixel."""
    return FocalPlane(1280, 720, 4.86e-6, 1.0)


@pytest.fixture(scope="session")
def quickstart_pointing():
    return Pointing(mode="stare", azimuth_deg=343.75, elevation_deg=40.57)
