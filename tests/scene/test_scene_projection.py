"""Gnomonic projection: round trip, a star pair against Skyfield, azimuth wrap, zenith pointing, roll."""

from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from skyfield.api import Star

from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import Pointing
from evsda.blocks.scene import projection
from evsda.blocks.scene.catalog import load_hipparcos
from evsda.blocks.scene.ephemeris import planets, skyfield_time, timescale
from evsda.blocks.scene.geometry import ObserverModel, unit
from evsda.blocks.scene.passes import find_passes
from evsda.blocks.scene.pointing import PointingModel
from evsda.blocks.scene.tle import earth_satellite
from evsda.blocks.scene.view import SatelliteView
from evsda import library

KNOT = 10 * 10**9


def wide(fov_deg: float) -> FocalPlane:
    pitch = 4.86e-6
    return FocalPlane(1280, 720, pitch, 1280 * pitch / (2 * np.tan(np.radians(fov_deg) / 2)))


def test_round_trip_pixels_directions_pixels(graz, gen4, pass_start):
    rng = np.random.default_rng(0)
    frame = PointingModel(Pointing(mode="stare", azimuth_deg=12.3, elevation_deg=33.0, roll_deg=17.0),
                          ObserverModel(graz, pass_start, KNOT), pass_start, KNOT).frame(np.zeros(1))
    b, r, u = (np.repeat(a, 1000, axis=0) for a in frame)
    for fp in (gen4, wide(60.0)):
        x = rng.uniform(-100, fp.width_px + 100, 1000)
        y = rng.uniform(-100, fp.height_px + 100, 1000)
        directions = projection.deproject(x, y, b, r, u, fp)
        x2, y2 = projection.project(directions, b, r, u, fp)
        assert np.abs(x2 - x).max() < 1e-7 and np.abs(y2 - y).max() < 1e-7


def test_star_pair_separation_against_skyfield(graz, pass_start):
    """Dubhe and Merak (the Pointers, ~5.4 deg apart) imaged in one 12 deg field."""
    catalog = load_hipparcos(str(library.path("stars/hip_main.dat.gz")))
    pick = np.isin(catalog.name, ["HIP 54061", "HIP 53910"])
    stars = catalog.select(pick)
    observer = ObserverModel(graz, pass_start, KNOT)
    t = skyfield_time(pass_start, np.zeros(1))[0]
    star = Star(ra_hours=stars.ra_deg / 15, dec_degrees=stars.dec_deg, ra_mas_per_year=stars.pm_ra_mas_yr,
                dec_mas_per_year=stars.pm_dec_mas_yr, parallax_mas=stars.parallax_mas,
                epoch=timescale().J(stars.epoch_jyear))
    apparent = observer.skyfield_observer().at(t).observe(star).apparent()
    directions = unit(apparent.xyz.m.T)
    middle = unit(directions.sum(axis=0))
    ra = np.degrees(np.arctan2(middle[1], middle[0])) % 360
    dec = np.degrees(np.arcsin(middle[2]))
    fp = wide(12.0)
    model = PointingModel(Pointing(mode="sidereal", ra_deg=ra, dec_deg=dec, roll_deg=30), observer, pass_start, KNOT)
    b, r, u = (np.repeat(a, 2, axis=0) for a in model.frame(np.zeros(1)))
    x, y = projection.project(directions, b, r, u, fp)
    assert projection.inside(x, y, fp).all()
    back = projection.deproject(x, y, b, r, u, fp)
    ours = np.degrees(np.arccos(np.dot(back[0], back[1])))
    reference = apparent[0].separation_from(apparent[1]).degrees
    assert ours == pytest.approx(reference, abs=1e-9)
    assert 5.3 < reference < 5.5


def skyfield_altaz(orbit, graz, epoch, t_ns):
    observer = ObserverModel(graz, epoch, KNOT).skyfield_observer()
    alt, az, _ = observer.at(skyfield_time(epoch, t_ns)).observe(
        planets()["earth"] + earth_satellite(orbit.line1, orbit.line2)).apparent().altaz()
    return az.radians, alt.radians


def test_azimuth_wrap_is_continuous(iss, graz, pass_start):
    """The ISS crosses azimuth 0/360 inside a staring field centred on north (t ~ 26-32 s)."""
    fp = wide(8.0)
    pointing = Pointing(mode="stare", azimuth_deg=0.0, elevation_deg=40.2)
    view = SatelliteView(iss, graz, pointing, fp, pass_start)
    report = find_passes(view, 20 * 10**9, 40 * 10**9)
    assert len(report.in_fov) == 1                                 # one crossing, not split at 360 -> 0
    t_ns = np.linspace(report.in_fov[0].start_ns, report.in_fov[0].stop_ns, 200).astype(np.int64)
    s = view.sample(t_ns)
    assert np.all(np.diff(s.x_px) > 0)                             # moving steadily across, no jump
    az, el = skyfield_altaz(iss, graz, pass_start, t_ns)
    assert az.min() < np.radians(1) and az.max() > np.radians(359)
    # expected tangent-plane position from Skyfield's alt/az and the stare frame written out by hand
    e0 = np.radians(40.2)
    sb = np.cos(az) * np.cos(el) * np.cos(e0) + np.sin(el) * np.sin(e0)
    xi = np.sin(az) * np.cos(el) / sb
    eta = (np.sin(el) * np.cos(e0) - np.cos(az) * np.cos(el) * np.sin(e0)) / sb
    x, y = projection.to_pixels(xi, eta, fp)
    scale_arcsec = np.degrees(fp.pixel_scale_rad) * 3600
    assert np.abs(s.x_px - x).max() * scale_arcsec < 0.05
    assert np.abs(s.y_px - y).max() * scale_arcsec < 0.05


def test_zenith_pointing(iss, graz):
    """Stare at the zenith while the ISS culminates at 85.6 deg (2023-03-19 18:30:53 UTC)."""
    epoch = datetime(2023, 3, 19, 18, 30, 43, tzinfo=timezone.utc)
    fp = wide(20.0)
    view = SatelliteView(iss, graz, Pointing(mode="stare", azimuth_deg=0.0, elevation_deg=90.0), fp, epoch)
    t_ns = np.arange(0, 20 * 10**9, 10**8)
    s = view.sample(t_ns)
    az, el = skyfield_altaz(iss, graz, epoch, t_ns)
    # looking up with image-up towards south (increasing elevation along azimuth 0) puts east on the right:
    # x - cx = tan(z) sin(A) f/p,  y - cy = tan(z) cos(A) f/p
    z = np.pi / 2 - el
    x, y = projection.to_pixels(np.tan(z) * np.sin(az), -np.tan(z) * np.cos(az), fp)
    near = z < np.radians(5)
    assert near.sum() > 20 and s.in_fov[near].all()
    scale_arcsec = np.degrees(fp.pixel_scale_rad) * 3600
    assert np.abs(s.x_px[near] - x[near]).max() * scale_arcsec < 0.05
    assert np.abs(s.y_px[near] - y[near]).max() * scale_arcsec < 0.05


def test_roll_turns_the_image(iss, graz, gen4, pass_start):
    t_ns = np.arange(2_700_000_000, 3_300_000_000, 50_000_000)
    base = SatelliteView(iss, graz, Pointing(mode="stare", azimuth_deg=343.75, elevation_deg=40.57), gen4,
                         pass_start).sample(t_ns)
    rolled = SatelliteView(iss, graz, Pointing(mode="stare", azimuth_deg=343.75, elevation_deg=40.57, roll_deg=90),
                           gen4, pass_start).sample(t_ns)
    cx, cy = projection.centre(gen4)
    # up turned onto right: a source to the right now appears below, one above now appears to the right
    np.testing.assert_allclose(rolled.x_px - cx, base.y_px - cy, atol=1e-6)
    np.testing.assert_allclose(rolled.y_px - cy, -(base.x_px - cx), atol=1e-6)
