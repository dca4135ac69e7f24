"""Earth's shadow against Skyfield's is_sunlit(), eclipse entry during a pass, the observer's Sun."""

from datetime import timedelta

import numpy as np
import pytest

from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import Pointing
from evsda.blocks.scene.ephemeris import planets, skyfield_time
from evsda.blocks.scene.geometry import NS_PER_S, satellite_track, sun_track
from evsda.blocks.scene.passes import find_passes, require_pass
from evsda.blocks.scene.satellite import Satellite
from evsda.blocks.scene.tle import earth_satellite
from evsda.blocks.scene.view import SatelliteView
from evsda.blocks.scene.visibility import lit_fraction, sun_centre_visible
from evsda.graph import RunInfo, SceneError, Window

KNOT = 10 * 10**9


def bisect(predicate, lo: int, hi: int, resolution: int = 100_000) -> int:
    """First time in [lo, hi] where ``predicate`` turns False (True at lo, False at hi)."""
    assert predicate(lo) and not predicate(hi)
    while hi - lo > resolution:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if predicate(mid) else (lo, mid)
    return hi


@pytest.fixture(scope="module")
def eclipse(iss, pass_start):
    """Eclipse entry of the ISS on 2023-03-20 ~19:20:08-20 UTC: Skyfield's and ours."""
    eph = planets()
    satellite = earth_satellite(iss.line1, iss.line2)
    skyfield_lit = lambda t_ns: bool(satellite.at(skyfield_time(pass_start, t_ns)).is_sunlit(eph))  # noqa: E731
    track, sun = satellite_track(pass_start, KNOT, iss.line1, iss.line2), sun_track(pass_start, KNOT)
    ours = lambda t_ns: bool(sun_centre_visible(track.state(t_ns)[0], sun.state(t_ns)[0])[0])  # noqa: E731
    fraction = lambda t_ns: float(lit_fraction(track.state(t_ns)[0], sun.state(t_ns)[0])[0])  # noqa: E731
    lo, hi = 5 * NS_PER_S, 40 * NS_PER_S
    return {"skyfield": bisect(skyfield_lit, lo, hi), "ours": bisect(ours, lo, hi), "fraction": fraction,
            "penumbra": bisect(lambda t: fraction(t) >= 1.0, lo, hi),
            "umbra": bisect(lambda t: fraction(t) > 0.0, lo, hi)}


def test_eclipse_entry_matches_skyfield_is_sunlit(eclipse):
    assert abs(eclipse["ours"] - eclipse["skyfield"]) <= 2_000_000          # 2 ms, ~15 m along track
    assert eclipse["fraction"](eclipse["skyfield"]) == pytest.approx(0.5, abs=0.05)   # Sun's centre on the limb


def test_penumbra_brackets_the_geometric_entry(eclipse):
    assert eclipse["penumbra"] < eclipse["skyfield"] < eclipse["umbra"]
    # the Sun's 0.53 deg disc sets behind the limb over a few seconds for a LEO orbit
    duration_s = (eclipse["umbra"] - eclipse["penumbra"]) / NS_PER_S
    assert 4 < duration_s < 15
    t = np.linspace(eclipse["penumbra"], eclipse["umbra"], 50).astype(np.int64)
    values = [eclipse["fraction"](int(ti)) for ti in t]
    assert np.all(np.diff(values) <= 1e-12)


def test_entering_eclipse_mid_pass(iss, graz, pass_start, eclipse):
    """A 20 deg staring field holds the ISS while it dims through the penumbra and vanishes in the umbra."""
    pitch = 4.86e-6
    fp = FocalPlane(1280, 720, pitch, 1280 * pitch / (2 * np.tan(np.radians(10))))
    pointing = Pointing(mode="stare", azimuth_deg=352.7, elevation_deg=40.6)
    view = SatelliteView(iss, graz, pointing, fp, pass_start)
    report = find_passes(view, 0, 30 * NS_PER_S)
    assert len(report.passes) == 1
    assert report.passes[0].stop_ns == pytest.approx(eclipse["umbra"], abs=2_000_000)
    assert report.in_fov[0].stop_ns > report.passes[0].stop_ns + 2 * NS_PER_S   # still in the field, but dark
    block = Satellite(area_m2=2500, albedo=0.3)
    block.setup(RunInfo(epoch=pass_start, duration_ns=30 * NS_PER_S))
    scene = dict(orbit=iss, observer=graz, pointing=pointing, focal_plane=fp)
    out = block.step(Window(0, eclipse["penumbra"] - NS_PER_S, eclipse["umbra"] + NS_PER_S, pass_start),
                     **scene)["sources"]
    lit = np.isfinite(out.x_px[:, 0])
    in_penumbra = (out.t_ns > eclipse["penumbra"]) & (out.t_ns < eclipse["umbra"])
    assert lit[out.t_ns < eclipse["umbra"]].all() and not lit[out.t_ns > eclipse["umbra"]].any()
    flux = out.photon_flux[:, 0]
    start = flux[np.searchsorted(out.t_ns, eclipse["penumbra"])]
    middle = flux[np.searchsorted(out.t_ns, (eclipse["penumbra"] + eclipse["umbra"]) // 2)]
    assert 0.2 < middle / start < 0.8
    late = in_penumbra & (out.t_ns > eclipse["penumbra"] + 0.2 * (eclipse["umbra"] - eclipse["penumbra"]))
    assert np.all(np.diff(flux[late]) < 0)
    assert out.photon_flux[out.t_ns > eclipse["umbra"], 0].max() == 0.0


def test_observer_sun_elevation_against_skyfield(iss, graz, pass_start):
    view = SatelliteView(iss, graz, Pointing(mode="stare"), FocalPlane(10, 10, 1e-5, 1.0),
                         pass_start - timedelta(hours=3))
    t_ns = np.arange(0, 4 * 3600 * NS_PER_S, 600 * NS_PER_S)
    ours = np.degrees(view.sample(t_ns).sun_elevation_rad)
    eph = planets()
    alt, _, _ = view.observer_model.skyfield_observer().at(skyfield_time(view.epoch, t_ns)).observe(
        eph["sun"]).apparent().altaz()
    assert np.abs(ours - alt.degrees).max() < 0.01            # geometric vs apparent Sun: ~20 arcsec


def test_daylight_pass_is_one_clear_error(iss, graz, pass_start, gen4, quickstart_pointing):
    """The quick-start crossing with a darkness limit the Sun (-22 deg) does not meet."""
    strict = type(graz)(**{**graz.__dict__, "max_sun_elevation_deg": -30.0})
    view = SatelliteView(iss, strict, quickstart_pointing, gen4, pass_start)
    report = find_passes(view, 0, 10 * NS_PER_S)
    with pytest.raises(SceneError, match=r"crosses the field of view .* never observable there: in daylight"):
        require_pass(report, "satellite 'sat'", "ISS")
