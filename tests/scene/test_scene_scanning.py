"""Scanning, raster and slew pointing: kinematics, frames against Skyfield, star streak rates, cadence limits."""

import numpy as np
import pytest
from skyfield.api import Star

from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import Pointing
from evsda.blocks.scene import projection
from evsda.blocks.scene.ephemeris import planets, skyfield_time
from evsda.blocks.scene.geometry import ObserverModel, unit
from evsda.blocks.scene.pointing import PointingModel, check_sampling
from evsda.blocks.scene.scanning import Move, Raster, Slew
from evsda.blocks.scene.sources import PointingLaw
from evsda.blocks.scene.stars import StarField
from evsda.blocks.scene.tle import earth_satellite
from evsda.blocks.scene.view import SatelliteView
from evsda.graph import ParameterError, RunInfo, Window

NS = 10**9
KNOT = 10 * NS


def field(fov_deg: float, width: int = 1280, height: int = 720) -> FocalPlane:
    pitch = 4.86e-6
    return FocalPlane(width, height, pitch, width * pitch / (2 * np.tan(np.radians(fov_deg) / 2)))


def derivative(f, t, h):
    return (f(t + h) - f(t - h)) / (2 * h)


@pytest.mark.parametrize("distance, rate, accel", [(10.0, 2.0, 1.0), (1.0, 2.0, 1.0), (0.3, 5.0, 20.0)])
def test_move_respects_its_limits_and_arrives(distance, rate, accel):
    move = Move(distance, rate, accel)
    t = np.linspace(0, move.duration, 20001)
    s = move.position(t)
    v = np.gradient(s, t)
    a = np.gradient(v, t)
    assert s[0] == 0 and s[-1] == pytest.approx(distance, abs=1e-12)
    assert v.max() <= rate * (1 + 1e-6) and v.max() == pytest.approx(min(rate, np.sqrt(distance * accel)), rel=1e-3)
    assert np.abs(a[2:-2]).max() <= accel * 1.01
    # time-optimal: trapezoid d/v + v/a when the rate limit is reached, else the triangle 2 sqrt(d/a)
    expected = distance / rate + rate / accel if distance >= rate**2 / accel else 2 * np.sqrt(distance / accel)
    assert move.duration == pytest.approx(expected, rel=1e-12)


def test_raster_is_continuous_and_within_limits():
    raster = Raster(100.0, 40.0, width_deg=4.0, rows=3, row_step_deg=1.0, scan_rate_deg_s=1.0,
                    step_rate_deg_s=2.0, max_accel_deg_s2=4.0)
    dt = 1e-3
    t = np.arange(0, 2.5 * raster.period_s, dt)
    lon, lat = raster.coordinates(t)
    v_lon, v_lat = np.gradient(lon, dt), np.gradient(lat, dt)
    assert np.abs(np.diff(lon)).max() <= 1.0 * dt * (1 + 1e-6)          # never jumps, rows at <= scan rate
    assert np.abs(v_lat).max() <= 2.0 * (1 + 1e-6)
    assert np.abs(np.gradient(v_lon, dt)[2:-2]).max() <= 4.0 * 1.01        # turnarounds accelerate at <= 4 deg/s^2
    assert set(np.round(lat[np.abs(v_lon) > 0.5], 9)) == {39.0, 40.0, 41.0}
    assert lon.min() == pytest.approx(98.0) and lon.max() == pytest.approx(102.0)
    assert np.abs(v_lon).max() == pytest.approx(1.0)                      # the scan rate holds mid-row


def test_slew_follows_the_great_circle_and_holds_its_ends():
    slew = Slew(10.0, 30.0, 50.0, 60.0, start_s=1.0, max_rate_deg_s=5.0, max_accel_deg_s2=2.0)
    lon, lat = slew.coordinates(np.array([0.0, 1.0, 1.0 + slew.move.duration, 100.0]))
    np.testing.assert_allclose([lon[0], lat[0], lon[1], lat[1]], [10, 30, 10, 30], atol=1e-9)
    np.testing.assert_allclose([lon[2], lat[2], lon[3], lat[3]], [50, 60, 50, 60], atol=1e-9)
    t = np.linspace(0.5, 1.5 + slew.move.duration, 5001)
    v = np.radians(np.column_stack(slew.coordinates(t)))
    direction = np.column_stack([np.cos(v[:, 1]) * np.cos(v[:, 0]), np.cos(v[:, 1]) * np.sin(v[:, 0]),
                                 np.sin(v[:, 1])])
    normal = unit(np.cross(slew.a, slew.b))
    assert np.abs(direction @ normal).max() < 1e-12                          # on the great circle
    speed = np.degrees(np.arccos(np.clip(np.sum(direction[1:] * direction[:-1], axis=1), -1, 1))) / np.diff(t)
    assert speed.max() <= 5.0 * 1.001


def test_radec_scan_at_zero_rate_is_sidereal_tracking(graz, pass_start):
    observer = ObserverModel(graz, pass_start, KNOT)
    t = np.linspace(0, 30 * NS, 7)
    sidereal = PointingModel(Pointing(mode="sidereal", ra_deg=120, dec_deg=30, roll_deg=5), observer, pass_start,
                             KNOT).frame(t)
    scan = PointingModel(Pointing(mode="scan", coordinates="radec", ra_deg=120, dec_deg=30, roll_deg=5), observer,
                         pass_start, KNOT).frame(t)
    for a, b in zip(sidereal, scan):
        # Skyfield's apparent place adds the Sun's light deflection (~3 mas here), the scan does not
        assert np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1, 1))).max() * 3600 < 0.01


def test_radec_scan_boresight_is_skyfields_apparent_place(graz, pass_start):
    observer = ObserverModel(graz, pass_start, KNOT)
    pointing = Pointing(mode="scan", coordinates="radec", ra_deg=200.0, dec_deg=-10.0, lon_rate_deg_s=0.2,
                        lat_rate_deg_s=-0.1)
    t = np.linspace(0, 20 * NS, 5)
    b, _, _ = PointingModel(pointing, observer, pass_start, KNOT).frame(t)
    for k, t_ns in enumerate(t):
        star = Star(ra_hours=(200.0 + 0.2 * t_ns / NS) / 15, dec_degrees=-10.0 - 0.1 * t_ns / NS)
        ref = unit(observer.skyfield_observer().at(skyfield_time(pass_start, t_ns)).observe(star).apparent().xyz.m)
        assert np.degrees(np.arccos(np.clip(b[k] @ ref, -1, 1))) * 3600 < 0.01


def test_satellite_in_an_azimuth_scan_against_skyfield(iss, graz, pass_start):
    """The quick start's ISS crossing seen from a field scanning in azimuth at 0.5 deg/s."""
    fp = field(4.0)
    az0, el0, rate = 342.0, 40.57, 0.5
    pointing = Pointing(mode="scan", azimuth_deg=az0, elevation_deg=el0, lon_rate_deg_s=rate)
    view = SatelliteView(iss, graz, pointing, fp, pass_start)
    t_ns = np.arange(2_000_000_000, 4_000_000_000, 20_000_000)
    s = view.sample(t_ns)
    observer = ObserverModel(graz, pass_start, KNOT).skyfield_observer()
    alt, az, _ = observer.at(skyfield_time(pass_start, t_ns)).observe(
        planets()["earth"] + earth_satellite(iss.line1, iss.line2)).apparent().altaz()
    a, e = az.radians, alt.radians
    a0, e0 = np.radians(az0 + rate * t_ns / NS), np.radians(el0)
    # the frame written out by hand: boresight at (a0, e0), up towards increasing elevation
    sb = np.cos(a - a0) * np.cos(e) * np.cos(e0) + np.sin(e) * np.sin(e0)
    xi = np.sin(a - a0) * np.cos(e) / sb
    eta = (np.sin(e) * np.cos(e0) - np.cos(a - a0) * np.cos(e) * np.sin(e0)) / sb
    x, y = projection.to_pixels(xi, eta, fp)
    inside = s.in_fov
    assert inside.sum() > 20
    scale_arcsec = np.degrees(fp.pixel_scale_rad) * 3600
    assert np.abs(s.x_px[inside] - x[inside]).max() * scale_arcsec < 0.05
    assert np.abs(s.y_px[inside] - y[inside]).max() * scale_arcsec < 0.05


def run_stars(observer, epoch, pointing, fp, duration_s, cadence_s=1e-3, faint=9.0):
    block = StarField(faint_limit_mag=faint, cadence_s=cadence_s)
    block.setup(RunInfo(epoch=epoch, duration_ns=int(duration_s * NS), window_ns=int(duration_s * NS), seed=3))
    out = block.step(Window(0, 0, int(duration_s * NS), epoch), observer=observer, pointing=pointing,
                     focal_plane=fp)["sources"]
    return block, out


def streak_rates(out, fp, half_window=5):
    """Image rate [pixel/s] of each star where it passes closest to the detector's centre."""
    cx, cy = projection.centre(fp)
    t = out.t_ns / NS
    rates = []
    for j in range(out.n_sources):
        x, y = out.x_px[:, j], out.y_px[:, j]
        seen = np.flatnonzero(np.isfinite(x))
        if seen.size < 4 * half_window:
            continue
        k = seen[np.argmin(np.hypot(x[seen] - cx, y[seen] - cy))]
        lo, hi = k - half_window, k + half_window
        if lo < 0 or hi >= len(t) or not np.isfinite(x[[lo, hi]]).all():
            continue
        rates.append(((x[hi] - x[lo]) / (t[hi] - t[lo]), (y[hi] - y[lo]) / (t[hi] - t[lo]),
                      np.hypot(x[k] - cx, y[k] - cy), j))
    return np.array(rates)


def test_star_streaks_move_at_the_commanded_radec_rate(graz, pass_start):
    """Scanning east and north, every star streaks west (+x) at rate_RA cos(Dec) and south (+y) at rate_Dec."""
    fp = field(1.0)
    ra_rate, dec_rate = 0.05, 0.02                       # deg/s: 52 and 20 pixels/s
    pointing = Pointing(mode="scan", coordinates="radec", ra_deg=150.0, dec_deg=20.0, lon_rate_deg_s=ra_rate,
                        lat_rate_deg_s=dec_rate)
    block, out = run_stars(graz, pass_start, pointing, fp, duration_s=20.0, faint=12.0)
    rates = streak_rates(out, fp)
    near = rates[rates[:, 2] < 300]                      # within 300 pixels (0.23 deg) of the centre
    assert len(near) >= 3
    scale_deg = np.degrees(fp.pixel_scale_rad)
    dec = block._stars.dec_deg[near[:, 3].astype(int)]
    np.testing.assert_allclose(near[:, 0], ra_rate * np.cos(np.radians(dec)) / scale_deg, rtol=2e-3)
    np.testing.assert_allclose(near[:, 1], dec_rate / scale_deg, rtol=2e-3)


def test_star_streaks_in_an_azimuth_scan_add_the_commanded_rate(graz, pass_start):
    """Stars cross an azimuth scan rate cos(el) faster than a stare, towards -x (the scan goes towards +x)."""
    fp = field(1.0)
    rate, el = 0.05, 40.0
    scan = Pointing(mode="scan", azimuth_deg=180.0, elevation_deg=el, lon_rate_deg_s=rate)
    block, out = run_stars(graz, pass_start, scan, fp, duration_s=1.0, faint=12.0)
    stare = PointingModel(Pointing(mode="stare", azimuth_deg=180.0, elevation_deg=el), block._observer, pass_start,
                          KNOT)
    # at t = 0 both frames coincide: a star's image velocity differs by the scan's, -rate cos(el) along x
    t = out.t_ns[:3]
    k, w = block._knot_weights(t)
    (s0,) = block._places.values(k)
    (s1,) = block._places.values(k + 1)
    places = unit(s0 + w[:, None, None] * (s1 - s0))
    axes = stare.frame(t.astype(float))
    x_stare, y_stare = projection.to_pixels(*projection.tangent_plane(
        *[np.einsum("tsk,tk->ts", places, a) for a in axes]), fp)
    cx, cy = projection.centre(fp)
    dt = (t[2] - t[0]) / NS
    near = np.isfinite(out.x_px[:3]).all(axis=0) & (np.hypot(out.x_px[0] - cx, out.y_px[0] - cy) < 400)
    assert near.sum() >= 2
    vx = (out.x_px[2, near] - out.x_px[0, near] - (x_stare[2, near] - x_stare[0, near])) / dt
    vy = (out.y_px[2, near] - out.y_px[0, near] - (y_stare[2, near] - y_stare[0, near])) / dt
    expected = -rate * np.cos(np.radians(el)) / np.degrees(fp.pixel_scale_rad)
    # the frame also turns about the boresight at rate sin(el) (about the vertical, seen from below): a star
    # off-centre moves by that turn times its offset, perpendicular to it
    turn = np.radians(rate * np.sin(np.radians(el)))
    dx, dy = out.x_px[0, near] - cx, out.y_px[0, near] - cy
    np.testing.assert_allclose(vx, expected - turn * dy, rtol=0, atol=2e-3 * abs(expected))
    np.testing.assert_allclose(vy, turn * dx, rtol=0, atol=2e-3 * abs(expected))


def test_raster_keeps_every_star_the_field_sweeps(graz, pass_start):
    """Turnarounds inside a projection chunk: the block's stars equal a brute-force projection of the catalogue."""
    fp = field(0.3, 64, 48)
    # one row swept back and forth, 2.5 s a cycle (each sweep 0.84 / 0.8 + 0.8 / 4 = 1.25 s): the projection's 5 s
    # chunk probes its start, middle and end, all at the row's western end, while the field sweeps the row between
    pointing = Pointing(mode="raster", coordinates="radec", ra_deg=150.0, dec_deg=20.0, raster_width_deg=0.84,
                        raster_rows=1, scan_rate_deg_s=0.8, max_rate_deg_s=1.0, max_acceleration_deg_s2=4.0)
    block, out = run_stars(graz, pass_start, pointing, fp, duration_s=5.0, cadence_s=5e-3, faint=13.0)
    picks = np.arange(0, len(out.t_ns), 7)
    axes = block._pointing.frame(out.t_ns[picks].astype(float))
    k, w = block._knot_weights(out.t_ns[picks])
    (s0,) = block._places.values(k)
    (s1,) = block._places.values(k + 1)
    places = unit(s0 + w[:, None, None] * (s1 - s0))                           # [n_t, n_stars, 3]
    dots = [np.einsum("tsk,tk->ts", places, a) for a in axes]
    x, y = projection.to_pixels(*projection.tangent_plane(*dots), fp)
    on = projection.inside(x, y, fp)
    assert on.any(axis=0).sum() >= 10
    np.testing.assert_allclose(out.x_px[picks][on], x[on], atol=1e-9)
    assert np.isfinite(out.x_px[picks][on]).all()
    assert not np.isfinite(out.x_px[picks][~on]).any()


def test_a_scan_too_fast_for_the_cadence_is_refused_with_the_largest_usable_rate(graz, pass_start):
    fp = field(0.9)                                       # 2.5 arcsec per pixel
    observer = ObserverModel(graz, pass_start, KNOT)
    fast = Pointing(mode="scan", coordinates="radec", ra_deg=150.0, dec_deg=20.0, lon_rate_deg_s=2.0)
    model = PointingModel(fast, observer, pass_start, KNOT)
    with pytest.raises(ParameterError) as error:
        check_sampling(model, fp, 10**6, 0, 5 * NS, "star_field 'stars'")
    message = str(error.value)
    assert "star_field 'stars'" in message and "largest usable" in message
    usable = float(message.split("ra_rate_deg_s = ")[1].split()[0])
    # the sky moves rate cos(dec) on the sky; one pixel per millisecond is 2.53 arcsec / 1 ms
    expected = np.degrees(fp.pixel_scale_rad) / 1e-3 / np.cos(np.radians(20.0))
    assert usable == pytest.approx(expected, rel=0.01)
    ok = Pointing(mode="scan", coordinates="radec", ra_deg=150.0, dec_deg=20.0, lon_rate_deg_s=0.98 * usable)
    check_sampling(PointingModel(ok, observer, pass_start, KNOT), fp, 10**6, 0, 5 * NS, "star_field 'stars'")
    with pytest.raises(ParameterError, match="largest usable"):
        run_stars(graz, pass_start, fast, fp, duration_s=1.0)


def test_pointing_block_checks_its_law():
    with pytest.raises(ParameterError, match="needs scan_rate_deg_s, max_rate_deg_s, max_acceleration_deg_s2"):
        PointingLaw(mode="raster", raster_width_deg=2.0)
    with pytest.raises(ParameterError, match="takes azimuth_rate_deg_s and elevation_rate_deg_s"):
        PointingLaw(mode="scan", ra_rate_deg_s=1.0)
    with pytest.raises(ParameterError, match="needs to_ra_deg, to_dec_deg"):
        PointingLaw(mode="slew", coordinates="radec", max_rate_deg_s=1, max_acceleration_deg_s2=1)
    over_the_top = PointingLaw(mode="scan", elevation_deg=80.0, elevation_rate_deg_s=1.0)
    with pytest.raises(ParameterError, match="reaches elevation 90.0"):
        over_the_top.setup(RunInfo(duration_ns=20 * NS))
    through_zenith = PointingLaw(mode="slew", azimuth_deg=0.0, elevation_deg=60.0, to_azimuth_deg=180.0,
                                 to_elevation_deg=60.0, max_rate_deg_s=5, max_acceleration_deg_s2=2)
    with pytest.raises(ParameterError, match="passes 0.00 deg from the zenith"):
        through_zenith.setup(RunInfo(duration_ns=20 * NS))
