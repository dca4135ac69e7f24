"""Apparent directions, azimuth/elevation and range against Skyfield called directly."""

import os
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from skyfield.framelib import itrs

from evsda.blocks.ports.scene import GROUND, SPACE, Observer
from evsda.blocks.scene.ephemeris import planets, skyfield_time
from evsda.blocks.scene.geometry import ObserverModel, apparent_position, satellite_track, unit
from evsda.blocks.scene.pointing import azel_from_enu
from evsda.blocks.scene.tle import earth_satellite

ARCSEC = np.radians(1 / 3600)
KNOT_NS = 10 * 10**9


def ours_vs_skyfield(orbit, observer: Observer, epoch: datetime, t_ns: np.ndarray):
    """(our az, el, range), (Skyfield's az, el, range) of the apparent place."""
    model = ObserverModel(observer, epoch, KNOT_NS)
    apparent = apparent_position(satellite_track(epoch, KNOT_NS, orbit.line1, orbit.line2), model, t_ns)
    east, north, up = model.enu(t_ns)
    az, el = azel_from_enu(*(np.einsum("ij,ij->i", unit(apparent), a) for a in (east, north, up)))
    t = skyfield_time(epoch, t_ns)
    target = planets()["earth"] + earth_satellite(orbit.line1, orbit.line2)
    reference = model.skyfield_observer().at(t).observe(target).apparent()
    alt_ref, az_ref, dist_ref = reference.altaz()
    return (az, el, np.linalg.norm(apparent, axis=-1)), (az_ref.radians, alt_ref.radians, dist_ref.m)


def angular_error(ours, ref):
    (az, el, _), (az_ref, el_ref, _) = ours, ref
    daz = (az - az_ref + np.pi) % (2 * np.pi) - np.pi
    return np.hypot(daz * np.cos(el_ref), el - el_ref)


def random_times(seconds: float, n: int = 200, seed: int = 0) -> np.ndarray:
    return np.sort(np.random.default_rng(seed).integers(0, int(seconds * 1e9), n))


def test_iss_from_graz_matches_skyfield_sub_arcsecond(iss, graz, pass_start):
    t_ns = random_times(60.0)                              # the whole quick-start pass, off the knots
    ours, ref = ours_vs_skyfield(iss, graz, pass_start - timedelta(seconds=20), t_ns)
    assert angular_error(ours, ref).max() < 0.01 * ARCSEC
    assert np.abs(ours[2] - ref[2]).max() < 0.05                  # metres, of ~600 km


def test_geo_at_36000_km_matches_skyfield(tle):
    galaxy25 = tle("galaxy-25.tle")
    socorro = Observer(name="Socorro", kind=GROUND, latitude_deg=33.8172, longitude_deg=-106.6599, altitude_m=1510)
    ours, ref = ours_vs_skyfield(galaxy25, socorro, datetime(2013, 3, 24, 4, tzinfo=timezone.utc), random_times(600))
    assert angular_error(ours, ref).max() < 0.01 * ARCSEC
    assert np.all((ours[2] > 35.7e6) & (ours[2] < 41.7e6))        # GEO slant range from mid latitude
    assert np.abs(ours[2] - ref[2]).max() < 0.05


def test_polar_site_matches_skyfield(tle):
    rocket = tle("sl-16-rb.tle")                              # 71 deg inclination: reaches polar skies
    pole = Observer(name="pole", kind=GROUND, latitude_deg=89.99, longitude_deg=123.0, altitude_m=2800)
    ours, ref = ours_vs_skyfield(rocket, pole, datetime(2013, 3, 24, 20, tzinfo=timezone.utc), random_times(6000))
    assert angular_error(ours, ref).max() < 0.01 * ARCSEC


def test_space_observer_matches_skyfield(iss, tle):
    starlink = tle("starlink-2434.tle")
    observer = Observer(name=starlink.name, kind=SPACE, line1=starlink.line1, line2=starlink.line2)
    epoch = datetime(2023, 3, 20, 6, tzinfo=timezone.utc)
    t_ns = random_times(3000, n=100)
    model = ObserverModel(observer, epoch, KNOT_NS)
    ours = apparent_position(satellite_track(epoch, KNOT_NS, iss.line1, iss.line2), model, t_ns)
    target = planets()["earth"] + earth_satellite(iss.line1, iss.line2)
    ref = model.skyfield_observer().at(skyfield_time(epoch, t_ns)).observe(target).apparent().xyz.m.T
    separation = np.arccos(np.clip(np.sum(unit(ours) * unit(ref), axis=-1), -1, 1))
    assert separation.max() < 0.01 * ARCSEC
    assert np.abs(np.linalg.norm(ours, axis=-1) - np.linalg.norm(ref, axis=-1)).max() < 0.05


def test_earth_rotation_between_knots_matches_skyfield(graz, pass_start):
    t_ns = random_times(120)
    model = ObserverModel(graz, pass_start, KNOT_NS)
    ours = model.rotation.matrices(t_ns)
    ref = np.moveaxis(itrs.rotation_at(skyfield_time(pass_start, t_ns)), -1, 0).transpose(0, 2, 1)
    assert np.abs(ours - ref).max() < 1e-10                       # rad: 20 microarcseconds


@pytest.mark.parametrize("knot_step_s, bound_arcsec", [(1.0, 0.01), (10.0, 0.01), (60.0, 0.2)])
def test_knot_spacing_error_against_skyfield(iss, graz, pass_start, knot_step_s, bound_arcsec):
    """Hermite interpolation between knots versus Skyfield at every sample.

    The error grows with the knot spacing because SGP4's velocity is not exactly the
    derivative of its position (a few cm/s), not because of the cubic's own error.
    """
    t_ns = random_times(60.0, n=100, seed=3)
    model = ObserverModel(graz, pass_start, KNOT_NS)
    ours = apparent_position(satellite_track(pass_start, int(knot_step_s * 1e9), iss.line1, iss.line2), model, t_ns)
    target = planets()["earth"] + earth_satellite(iss.line1, iss.line2)
    ref = model.skyfield_observer().at(skyfield_time(pass_start, t_ns)).observe(target).apparent().xyz.m.T
    separation = np.arccos(np.clip(np.sum(unit(ours) * unit(ref), axis=-1), -1, 1))
    assert separation.max() < bound_arcsec * ARCSEC


def test_skyfield_data_folder_without_its_expiry_check(monkeypatch):
    """The loader reads skyfield-data's own folder without calling its expiry check, whose warning about
    finals2000A.all (a file evsda never reads) cannot be silenced thread-safely in a pipelined run."""
    import warnings

    import skyfield_data

    from evsda.blocks.scene.ephemeris import data_folder, loader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert data_folder() == skyfield_data.get_skyfield_data_path()

    def checked(*args, **kwargs):
        raise AssertionError("the expiry check ran")

    monkeypatch.setattr(skyfield_data, "get_skyfield_data_path", checked)
    assert loader.__wrapped__().path_to("de421.bsp") == os.path.join(data_folder(), "de421.bsp")


def test_kept_rows_of_a_longer_call_are_a_call_of_their_own(iss, graz, pass_start):
    """A model asked for times that a kept result holds as consecutive samples gives those rows: the bytes a
    call for those times alone makes (apparent places, states, the rotation, the horizon axes)."""
    t_ns = np.arange(3_000, 3_500, dtype=np.float64) * 1e6                       # 0.5 s at 1 ms
    part = t_ns[137:262]
    shared = ObserverModel(graz, pass_start, KNOT_NS)
    track = satellite_track(pass_start, KNOT_NS, iss.line1, iss.line2)
    apparent_position(track, shared, t_ns)
    shared.enu(t_ns)
    alone = ObserverModel(graz, pass_start, KNOT_NS)
    fresh_track = satellite_track(pass_start, KNOT_NS, iss.line1, iss.line2)
    pairs = [(apparent_position(track, shared, part), apparent_position(fresh_track, alone, part)),
             (track.state(part), fresh_track.state(part)), (shared.state(part), alone.state(part)),
             (shared.rotation.matrices(part), alone.rotation.matrices(part)), (shared.enu(part), alone.enu(part))]
    for kept, own in pairs:
        for a, b in zip(*(v if isinstance(v, tuple) else (v,) for v in (kept, own))):
            assert a.tobytes() == b.tobytes() and not a.flags.writeable
    assert track.state(part)[0].base is not None         # served from the longer call's rows, not computed again


@pytest.mark.parametrize("observer", ["graz", "space"])
def test_boresight_angles_are_the_frames_zenith_angle_and_horizon(iss, graz, tle, pass_start, observer):
    """PointingModel.boresight_angles (kept for the scene's blocks) holds the bytes of zenith_angle and horizon
    of the frame at the same times."""
    from evsda.blocks.ports.scene import Pointing
    from evsda.blocks.scene.pointing import PointingModel

    starlink = tle("starlink-2434.tle")
    site = graz if observer == "graz" else Observer(name=starlink.name, kind=SPACE, line1=starlink.line1,
                                                    line2=starlink.line2)
    pointing = Pointing(mode="track", target_line1=iss.line1, target_line2=iss.line2, roll_deg=10.0)
    t_ns = np.arange(2_000, 2_300, dtype=np.float64) * 1e6
    model = PointingModel(pointing, ObserverModel(site, pass_start, KNOT_NS), pass_start, KNOT_NS)
    zenith, azimuth, rotation = model.boresight_angles(t_ns)
    b, _, u = PointingModel(pointing, ObserverModel(site, pass_start, KNOT_NS), pass_start, KNOT_NS).frame(t_ns)
    other = PointingModel(pointing, ObserverModel(site, pass_start, KNOT_NS), pass_start, KNOT_NS)
    assert zenith.tobytes() == other.zenith_angle(t_ns, b).tobytes()
    assert b"".join(a.tobytes() for a in (azimuth, rotation)) == b"".join(a.tobytes() for a in other.horizon(t_ns, b, u))
    assert model.boresight_angles(t_ns[50:90])[2].tobytes() == rotation[50:90].tobytes()
