"""The pass finder and the satellite block: the quick-start pass, misses, GEO, windows, tracking."""

from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import GROUND, Observer, Pointing
from evsda.blocks.scene.geometry import NS_PER_S
from evsda.blocks.scene.passes import find_passes
from evsda.blocks.scene import pointing, satellite
from evsda.blocks.scene.satellite import Satellite
from evsda.blocks.scene.view import Reflector, SatelliteView
from evsda.graph import RunInfo, SceneError, Window


def run_block(block, scene, epoch, duration_s, window_s):
    block.setup(RunInfo(epoch=epoch, duration_ns=int(duration_s * 1e9), window_ns=int(window_s * 1e9)))
    run = block.run
    return [block.step(w, **scene)["sources"] for w in run.windows()]


def test_quickstart_pass(iss, graz, gen4, quickstart_pointing, pass_start):
    report = find_passes(SatelliteView(iss, graz, quickstart_pointing, gen4, pass_start), 0, 10 * NS_PER_S)
    assert len(report.passes) == 1
    crossing = report.passes[0]
    assert crossing.start_utc == pytest.approx(datetime(2023, 3, 20, 19, 19, 59, 720000, tzinfo=timezone.utc),
                                               abs=timedelta(milliseconds=2))
    assert 0.5 < crossing.duration_s < 0.56
    assert not crossing.starts_before_range and not crossing.ends_after_range


def test_never_in_the_field_is_one_clear_error(iss, graz, gen4, pass_start):
    block = Satellite(name="sat")
    scene = dict(orbit=iss, observer=graz, pointing=Pointing(mode="stare", azimuth_deg=180.0, elevation_deg=60.0),
                 focal_plane=gen4)
    with pytest.raises(SceneError) as error:
        run_block(block, scene, pass_start, 10, 0.1)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith("satellite 'sat': ISS (ZARYA) (25544) never enters the field of view between "
                              "2023-03-20T19:19:57.000Z and 2023-03-20T19:20:07.000Z; closest approach ")
    assert " deg outside the field's edge (" in message and " at 2023-03-20T19:" in message


def test_pass_under_way_before_the_window(iss, graz, gen4, quickstart_pointing, pass_start):
    start = pass_start + timedelta(seconds=3)                     # the ISS is mid-field at 19:20:00
    windows = run_block(Satellite(), dict(orbit=iss, observer=graz, pointing=quickstart_pointing, focal_plane=gen4),
                        start, 1.0, 0.25)
    assert np.isfinite(windows[0].x_px[0, 0])
    block = Satellite()
    block.setup(RunInfo(epoch=start, duration_ns=NS_PER_S))
    block.step(Window(0, 0, 10**8, start), orbit=iss, observer=graz, pointing=quickstart_pointing, focal_plane=gen4)
    assert block.passes.passes[0].starts_before_range and block.passes.passes[0].start_ns == 0


def test_results_do_not_depend_on_the_windows(iss, graz, gen4, quickstart_pointing, pass_start):
    scene = dict(orbit=iss, observer=graz, pointing=quickstart_pointing, focal_plane=gen4)
    one = run_block(Satellite(), scene, pass_start + timedelta(seconds=2.5), 1.0, 1.0)[0]
    many = run_block(Satellite(), scene, pass_start + timedelta(seconds=2.5), 1.0, 0.07)
    for name in ("t_ns", "x_px", "y_px", "photon_flux", "magnitude", "range_m", "zenith_angle_rad"):
        np.testing.assert_array_equal(np.concatenate([getattr(w, name) for w in many]), getattr(one, name))
    assert np.isfinite(one.x_px).sum() > 400 and one.t_ns[1] - one.t_ns[0] == 1_000_000


def test_windows_sampled_ahead_are_the_windows_sampled_one_by_one(iss, graz, gen4, quickstart_pointing, pass_start,
                                                                     monkeypatch):
    """The satellite block samples five windows at a time (satellite.WINDOWS_AHEAD) and keeps the rest: the same
    bytes as each window's own call, with the run's end inside a batch."""
    scene = dict(orbit=iss, observer=graz, pointing=quickstart_pointing, focal_plane=gen4)
    start = pass_start + timedelta(seconds=2.6)
    pointing._SHARED_MODELS.clear()           # the scene's models made afresh for each run: nothing kept between
    ahead = run_block(Satellite(), scene, start, 0.73, 0.1)
    monkeypatch.setattr(satellite, "WINDOWS_AHEAD", 1)
    pointing._SHARED_MODELS.clear()
    one_by_one = run_block(Satellite(), scene, start, 0.73, 0.1)
    assert np.isfinite(one_by_one[3].x_px).sum() > 50
    for a, b in zip(ahead, one_by_one, strict=True):
        for name in ("t_ns", "x_px", "y_px", "photon_flux", "magnitude", "range_m", "zenith_angle_rad",
                     "boresight_azimuth_rad", "field_rotation_rad"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes()


def test_geo_stare(tle):
    """A staring field on GALAXY 25 at 36 000 km keeps it in view for the whole run."""
    galaxy25 = tle("galaxy-25.tle")
    socorro = Observer(name="Socorro", kind=GROUND, latitude_deg=33.8172, longitude_deg=-106.6599, altitude_m=1510,
                       min_elevation_deg=10, max_sun_elevation_deg=-12, extinction_mag_per_airmass=0.15)
    epoch = datetime(2013, 3, 24, 4, 0, tzinfo=timezone.utc)
    fp = FocalPlane(1280, 720, 4.86e-6, 1.0)
    probe = SatelliteView(galaxy25, socorro, Pointing(mode="stare"), fp, epoch).sample(np.array([30 * NS_PER_S]))
    pointing = Pointing(mode="stare", azimuth_deg=float(np.degrees(probe.azimuth_rad[0])),
                        elevation_deg=float(np.degrees(probe.elevation_rad[0])))
    view = SatelliteView(galaxy25, socorro, pointing, fp, epoch, reflector=Reflector("plate", 40.0, 0.3, "bisector"))
    report = find_passes(view, 0, 60 * NS_PER_S)
    assert len(report.passes) == 1 and report.passes[0].starts_before_range and report.passes[0].ends_after_range
    s = view.sample(np.arange(0, 60 * NS_PER_S, NS_PER_S))
    assert np.all((s.range_m > 35.7e6) & (s.range_m < 41.7e6))
    drift_px = np.hypot(np.ptp(s.x_px), np.ptp(s.y_px))
    assert drift_px < 5                                              # geostationary: nearly fixed in a stare
    assert 9 < np.median(s.magnitude) < 13                           # a 40 m^2 GEO comsat is ~V 10-12


def test_rate_tracking_keeps_the_target_centred(iss, graz, gen4, pass_start):
    pointing = Pointing(mode="track", target_name=iss.name, target_line1=iss.line1, target_line2=iss.line2,
                        roll_deg=25.0)
    s = SatelliteView(iss, graz, pointing, gen4, pass_start).sample(np.arange(0, 20 * NS_PER_S, 10**7))
    assert np.abs(s.x_px - (gen4.width_px - 1) / 2).max() < 1e-6
    assert np.abs(s.y_px - (gen4.height_px - 1) / 2).max() < 1e-6
