"""Where lines of sight cross turbulent layers on a tracking and a staring mount (optics Imager.sight).

References nobody here wrote: Skyfield's apparent alt/az of the ISS and of RA/Dec points (the boresight
azimuth, the satellite's angular rate, the field rotation), the Earth's sidereal rate, and the flat-layer
geometry of the isoplanatic angle (two directions ``theta`` apart cross a layer at altitude ``h``
``h theta sec z`` apart across the beam; Fried 1982, Hardy 1998 Eq. 3.61).
"""

import numpy as np
import pytest
from skyfield.api import Star

from evsda.blocks.optics.atmosphere import Atmosphere, Layer
from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.imaging import Imager
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.ports.scene import Pointing
from evsda.blocks.scene import projection
from evsda.blocks.scene.ephemeris import planets, skyfield_time
from evsda.blocks.scene.geometry import OMEGA_EARTH_RAD_S, ObserverModel
from evsda.blocks.scene.pointing import PointingModel
from evsda.blocks.scene.tle import earth_satellite
from evsda.blocks.scene.view import SatelliteView

KNOT = 10 * 10**9
ALTITUDE_M = 5000.0
# the pass starts at its culmination, 40.7 deg elevation: 10 s in, the mount turns at ~0.9 deg/s in azimuth
# (the sky at ~0.7 deg/s)
T0_NS = 10 * 10**9


def imager(focal_plane):
    atmosphere = Atmosphere((Layer(ALTITUDE_M, 1e-13, 0.0, 0.0),))
    return Imager(Telescope(0.35), focal_plane, 550e-9, atmosphere, PointSourceOptics.Params(), seed=(1,))


def sensor(pointing, graz, pass_start, t_ns):
    model = PointingModel(pointing, ObserverModel(graz, pass_start, KNOT), pass_start, KNOT)
    b, r, u = model.frame(t_ns)
    zenith = model.zenith_angle(t_ns, b)
    azimuth, rotation = model.horizon(t_ns, b, u)
    return (b, r, u), zenith, azimuth, rotation


def skyfield_altaz(observer, epoch, t_ns, body):
    alt, az, _ = observer.at(skyfield_time(epoch, t_ns)).observe(body).apparent().altaz()
    return alt.radians, az.radians


def sky_rate(el, az, dt_s):
    """Angular speed [rad/s] between consecutive (elevation, azimuth) samples ``dt_s`` apart."""
    v = np.stack([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)], axis=-1)
    return np.arccos(np.clip(np.sum(v[1:] * v[:-1], axis=-1), -1, 1)) / dt_s


def test_boresight_azimuth_and_zenith_of_a_track_match_skyfield(iss, graz, gen4, pass_start):
    t_ns = T0_NS + np.arange(0, 10**10, 10**9)
    _, zenith, azimuth, rotation = sensor(Pointing(mode="track", target_line1=iss.line1, target_line2=iss.line2,
                                                   roll_deg=20.0), graz, pass_start, t_ns)
    observer = ObserverModel(graz, pass_start, KNOT).skyfield_observer()
    el, az = skyfield_altaz(observer, pass_start, t_ns, planets()["earth"] + earth_satellite(iss.line1, iss.line2))
    arcsec = np.radians(1 / 3600)
    assert np.abs(np.angle(np.exp(1j * (azimuth - az)))).max() * np.cos(el).max() < 0.05 * arcsec  # 0.004 measured
    assert np.abs((np.pi / 2 - zenith) - el).max() < 0.05 * arcsec                                 # 0.001
    np.testing.assert_allclose(rotation, np.radians(20.0), atol=1e-9)       # image up = elevation, turned by the roll


def test_field_rotation_of_a_sidereal_field_against_skyfield(graz, pass_start):
    """Sidereal: image up is celestial north; Skyfield's alt/az of a point 1 arcmin north gives its angle."""
    ra, dec = 150.0, 30.0
    t_ns = np.array([0, 600 * 10**9])
    _, _, azimuth, rotation = sensor(Pointing(mode="sidereal", ra_deg=ra, dec_deg=dec), graz, pass_start, t_ns)
    observer = ObserverModel(graz, pass_start, KNOT).skyfield_observer()
    el0, az0 = skyfield_altaz(observer, pass_start, t_ns, Star(ra_hours=ra / 15, dec_degrees=dec))
    el1, az1 = skyfield_altaz(observer, pass_start, t_ns, Star(ra_hours=ra / 15, dec_degrees=dec + 1 / 60))
    expected = np.arctan2(np.angle(np.exp(1j * (az1 - az0))) * np.cos(el0), el1 - el0)
    assert np.abs(np.angle(np.exp(1j * (rotation - expected)))).max() < 1e-3      # 3.6e-4 measured (the 1' step)
    assert np.abs(np.angle(np.exp(1j * (azimuth - az0)))).max() < np.radians(1 / 3600)
    assert abs(rotation[1] - rotation[0]) > np.radians(1)                  # the parallactic angle turns


def test_tracked_satellite_sweeps_the_layer_and_stars_ride_the_wind(iss, graz, gen4, pass_start):
    """Tracking the ISS at ~0.7 deg/s on the sky: its footprint moves at h sec(z) omega (Skyfield's omega), a
    star's by the sidereal rate only; the old offsets from the boresight did the reverse."""
    dt_ns = 10**8
    t_ns = T0_NS + np.arange(0, 11) * dt_ns
    pointing = Pointing(mode="track", target_line1=iss.line1, target_line2=iss.line2)
    (b, r, u), zenith, azimuth, rotation = sensor(pointing, graz, pass_start, t_ns)
    view = SatelliteView(iss, graz, pointing, gen4, pass_start).sample(t_ns)
    # a star 100 pixels right of the boresight at t0: fixed in the GCRS
    star = projection.deproject(np.array([639.5 + 100]), np.array([359.5]), b[:1], r[:1], u[:1], gen4)[0]
    x_star, y_star = projection.project(np.repeat(star[None], len(t_ns), 0), b, r, u, gen4)
    im = imager(gen4)
    im.set_frame(azimuth[0], zenith[0], rotation[0])
    h = ALTITUDE_M
    satellite = h * im.sight(view.x_px, view.y_px, zenith, azimuth, rotation)
    fixed = h * im.sight(x_star, y_star, zenith, azimuth, rotation)
    observer = ObserverModel(graz, pass_start, KNOT).skyfield_observer()
    el, az = skyfield_altaz(observer, pass_start, t_ns, planets()["earth"] + earth_satellite(iss.line1, iss.line2))
    omega = sky_rate(el, az, dt_ns / 1e9)                                  # [rad/s]
    assert 0.5 < np.degrees(omega.mean()) < 1.5                           # a fast tracked pass
    speed = np.hypot(*np.diff(satellite, axis=0).T) / (dt_ns / 1e9)         # [m/s]
    expected = h / np.cos(zenith[0]) * omega
    # across the beam at t0 exactly; cos z drifts by < 0.3 % over the second (z changes by ~1 deg)
    np.testing.assert_allclose(speed[:2], expected[:2], rtol=1e-4)      # 1e-5 measured
    np.testing.assert_allclose(speed, expected, rtol=3e-3)              # 3e-4 measured
    assert speed.min() > 50.0                                              # L omega = 7.7 km x 12 mrad/s
    # the star: sidereal rate only, though it streaks across the detector at ~1 deg/s
    star_speed = np.hypot(*np.diff(fixed, axis=0).T) / (dt_ns / 1e9)
    apparent = np.hypot(np.diff(x_star), np.diff(y_star)) * gen4.pixel_scale_rad / (dt_ns / 1e9)
    assert apparent.min() > 0.5 * omega.min()
    assert star_speed.max() < 1.3 * h / np.cos(zenith).min() ** 2 * OMEGA_EARTH_RAD_S   # < 1 m/s
    # the old footprints (offset from the boresight, h sec z theta) had it the other way round
    old_satellite = h / np.cos(zenith)[:, None] * (np.stack([view.x_px, view.y_px], -1) - im.boresight) \
        * gen4.pixel_scale_rad
    assert np.hypot(*np.diff(old_satellite, axis=0).T).max() / (dt_ns / 1e9) < 0.01 * speed.min()


def test_staring_mount_keeps_the_old_footprints_up_to_a_constant(graz, gen4, pass_start):
    """A stare at fixed azimuth/elevation: stars drift at the sidereal rate and each footprint's motion is the
    old ``h sec(z) theta`` to first order in the star's offset from the boresight."""
    t_ns = np.arange(0, 61) * 10**9
    (b, r, u), zenith, azimuth, rotation = sensor(Pointing(mode="stare", azimuth_deg=200.0, elevation_deg=35.0,
                                                           roll_deg=-15.0), graz, pass_start, t_ns)
    assert np.ptp(azimuth) < 1e-12 and np.ptp(zenith) < 1e-12
    im = imager(gen4)
    im.set_frame(azimuth[0], zenith[0], rotation[0])
    h = ALTITUDE_M
    for x0, y0 in ((639.5, 359.5), (100.0, 50.0), (1200.0, 700.0)):
        star = projection.deproject(np.array([x0]), np.array([y0]), b[:1], r[:1], u[:1], gen4)[0]
        x, y = projection.project(np.repeat(star[None], len(t_ns), 0), b, r, u, gen4)
        new = h * im.sight(x, y, zenith, azimuth, rotation)
        old = h / np.cos(zenith)[:, None] * (np.stack([x, y], -1) - im.boresight) * gen4.pixel_scale_rad
        moved_new, moved_old = new - new[0], old - old[0]
        drift = np.hypot(*moved_old[-1])
        assert drift == pytest.approx(h / np.cos(zenith[0]) * OMEGA_EARTH_RAD_S * 60, rel=0.5)  # ~ sidereal
        # first order in the offset theta from the boresight: |moved_new - moved_old| <~ theta tan(z) |moved_old|
        theta = np.hypot(x - 639.5, y - 359.5).max() * gen4.pixel_scale_rad
        assert np.abs(moved_new - moved_old).max() <= 2 * theta * np.tan(zenith[0]) * drift
        assert np.abs(moved_new - moved_old).max() <= 0.01 * drift


@pytest.mark.parametrize("mode", ["stare", "sidereal"])
def test_two_sources_keep_footprints_h_theta_sec_z_apart(graz, gen4, pass_start, mode):
    """Anisoplanatism: sources theta apart in any direction cross the layer h theta sec(z) apart across the beam,
    for any roll or field rotation (at the frame's time); the separation turns with the detector."""
    t_ns = np.array([0])
    pointing = Pointing(mode=mode, azimuth_deg=120.0, elevation_deg=50.0, ra_deg=80.0, dec_deg=40.0, roll_deg=35.0)
    (b, r, u), zenith, azimuth, rotation = sensor(pointing, graz, pass_start, t_ns)
    im = imager(gen4)
    im.set_frame(azimuth[0], zenith[0], rotation[0])
    h = ALTITUDE_M
    step_px = 20.0                                                         # 20 arcsec
    for dx, dy in ((step_px, 0.0), (0.0, step_px), (step_px * 0.6, -step_px * 0.8)):
        x = np.array([700.0, 700.0 + dx])
        y = np.array([300.0, 300.0 + dy])
        directions = projection.deproject(x, y, np.repeat(b, 2, 0), np.repeat(r, 2, 0), np.repeat(u, 2, 0), gen4)
        theta = np.arccos(np.dot(directions[0], directions[1]))            # true angle between the sources
        c = h * im.sight(x, y, np.repeat(zenith, 2), np.repeat(azimuth, 2), np.repeat(rotation, 2))
        gap = c[1] - c[0]
        assert np.hypot(*gap) == pytest.approx(h * theta / np.cos(zenith[0]), rel=2e-3)      # <= 4.4e-4 measured
        # and along the detector's direction between them (the screens' frame is the detector's at t0)
        assert np.degrees(np.arctan2(gap[1], gap[0]) - np.arctan2(dy, dx)) == pytest.approx(0.0, abs=0.1)


def test_without_the_boresight_the_old_staring_footprints(gen4):
    im = imager(gen4)
    x, y, z = np.array([10.0, 900.0]), np.array([700.0, 5.0]), np.full(2, np.radians(40))
    expected = (np.stack([x, y], -1) - im.boresight) * gen4.pixel_scale_rad / np.cos(z)[:, None]
    np.testing.assert_array_equal(im.sight(x, y, z), expected)
    im.set_frame(1.0, 0.5, 0.2)
    np.testing.assert_array_equal(im.sight(x, y, z, np.full(2, np.nan), np.full(2, np.nan)), expected)
