"""Many objects from one catalogue: reading TLE and OMM files, bad entries, the screen against brute force,
catalogued objects against the single-satellite block, per-object metrics."""

import csv
import json
import warnings
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from sgp4.api import SatrecArray
from skyfield.api import EarthSatellite

from evsda import library
from evsda.blocks.ports import EventCause, Events, FocalPlane, PointSources, SourceKind
from evsda.blocks.ports.scene import GROUND, Observer, Pointing
from evsda.blocks.readout.object_metrics import ObjectMetrics
from evsda.blocks.scene import projection
from evsda.blocks.scene.element_sets import read_catalog, read_text
from evsda.blocks.scene.ephemeris import skyfield_time, timescale
from evsda.blocks.scene.geometry import ObserverModel
from evsda.blocks.scene.pointing import PointingModel
from evsda.blocks.scene.satellite import Satellite
from evsda.blocks.scene.satellite_catalog import CatalogAgeWarning, CatalogEntryWarning, SatelliteCatalog
from evsda.blocks.scene.screening import Screen
from evsda.blocks.scene.tle import make_orbit
from evsda.graph import ParameterError, RunInfo, SceneError, Window

NS = 10**9
CATALOG = "library:tle/celestrak-active-2026-03-19.tle.gz"
# a dense Starlink field: Graz, 2026-03-20 18:50 UTC, north-east at 30 deg (examples/starlink_field.yaml)
START = datetime(2026, 3, 20, 18, 50, tzinfo=timezone.utc)
GRAZ = Observer(name="Graz", kind=GROUND, latitude_deg=47.0671, longitude_deg=15.4934, altitude_m=493.0,
                min_elevation_deg=10.0, max_sun_elevation_deg=-12.0, extinction_mag_per_airmass=0.25)
NORTH_EAST = Pointing(mode="stare", azimuth_deg=35.0, elevation_deg=30.0)


def lens(fov_deg: float, width: int = 1280, height: int = 720) -> FocalPlane:
    pitch = 4.86e-6
    return FocalPlane(width, height, pitch, width * pitch / (2 * np.tan(np.radians(fov_deg) / 2)))


@pytest.fixture(scope="module")
def text():
    return read_text(library.resolve(CATALOG), "test")


@pytest.fixture(scope="module")
def catalog(text):
    return read_catalog(text, "tle", "test", skip_bad=False)


def test_the_bundled_catalogue_is_read_whole(catalog):
    assert len(catalog) == 14710 and not catalog.skipped
    ids = [o.object_id for o in catalog.objects]
    assert len(set(ids)) == len(ids)
    assert sum(o.name.startswith("STARLINK") for o in catalog.objects) == 9934
    iss = next(o for o in catalog.objects if o.object_id == "25544")
    assert iss.name == "ISS (ZARYA)"


BAD_TLE = """ISS (ZARYA)
1 25544U 98067A   26078.12958500  .00009105  00000+0  17698-3 0  9991
2 25544  51.6344  25.6919 0006229 207.4819 152.5840 15.48370465557798
CORRUPTED
1 20580U 90037B   26078.01202943  .00006585  00000+0  21509-3 0  9992
2 20580  28.4725 336.3997 0001574 225.3944 134.6524 15.29626908774743
1 25560U 98071A   26078.21336165  .00002447  00000+0  16116-3 0  9997
A NAME WITHOUT ELEMENTS
SWAS
1 25560U 98071A   26078.21336165  .00002447  00000+0  16116-3 0  9997
2 25560  69.8942  99.4320 0004936 355.6306   4.4814 15.08956307483690
ISS AGAIN
1 25544U 98067A   26078.12958500  .00009105  00000+0  17698-3 0  9991
2 25544  51.6344  25.6919 0006229 207.4819 152.5840 15.48370465557798
"""


def test_malformed_entries_are_named_and_refused(tmp_path):
    path = tmp_path / "bad.tle"
    path.write_text(BAD_TLE)
    with pytest.raises(ParameterError) as error:
        SatelliteCatalog(catalog_file=str(path))
    message = str(error.value)
    assert "line 4: line 5 fails its checksum (column 69 says '2', the line sums to 1)" in message
    assert "3 more malformed entries follow" in message and "on_bad_entry: skip" in message


def test_malformed_entries_can_be_skipped_with_each_line_named(tmp_path):
    path = tmp_path / "bad.tle"
    path.write_text(BAD_TLE)
    with pytest.warns(CatalogEntryWarning) as caught:
        block = SatelliteCatalog(catalog_file=str(path), on_bad_entry="skip")
    assert [o.name for o in block.catalog.objects] == ["ISS (ZARYA)", "SWAS"]
    message = str(caught[0].message)
    for fragment in ("skipped 4 malformed entries", "line 4: line 5 fails its checksum",
                     "line 7: TLE line 1 is not followed by a line 2",
                     "line 8: 'A NAME WITHOUT ELEMENTS' is not followed by a two-line element set",
                     "line 12: object 25544 (ISS AGAIN) appears again (first on line 1)"):
        assert fragment in message


def omm_fields(obj, line1: str, line2: str) -> dict:
    """The OMM of a TLE as CelesTrak writes it: the same numbers with their OMM keywords."""
    def exponent(field: str) -> float:                   # "-11606-4" -> -0.11606e-4
        field = field.strip()
        sign = -1.0 if field.startswith("-") else 1.0
        mantissa, power = field.lstrip("+-")[:-2], field[-2:]
        return sign * float("0." + mantissa) * 10 ** int(power)
    jd = obj.satrec.jdsatepoch + obj.satrec.jdsatepochF
    epoch = datetime(2000, 1, 1, 12, tzinfo=timezone.utc) + timedelta(days=jd - 2451545.0)
    return {"OBJECT_NAME": obj.name, "OBJECT_ID": "", "EPOCH": epoch.strftime("%Y-%m-%dT%H:%M:%S.%f"),
            "MEAN_MOTION": line2[52:63].strip(), "ECCENTRICITY": "0." + line2[26:33],
            "INCLINATION": line2[8:16].strip(), "RA_OF_ASC_NODE": line2[17:25].strip(),
            "ARG_OF_PERICENTER": line2[34:42].strip(), "MEAN_ANOMALY": line2[43:51].strip(),
            "EPHEMERIS_TYPE": "0", "CLASSIFICATION_TYPE": "U", "NORAD_CAT_ID": str(int(line1[2:7])),
            "ELEMENT_SET_NO": line1[64:68].strip(), "REV_AT_EPOCH": line2[63:68].strip(),
            "BSTAR": repr(exponent(line1[53:61])), "MEAN_MOTION_DOT": line1[33:43].strip(),
            "MEAN_MOTION_DDOT": repr(exponent(line1[44:52]))}


def test_omm_csv_json_and_xml_propagate_as_the_tle(tmp_path, text, catalog):
    lines = [line for line in text.splitlines() if line.strip()]
    picks = [0, 3000, 9000, 14000]                      # CALSPHERE 1, and objects across the file
    records, satrecs = [], []
    for k in picks:
        obj = catalog.objects[k]
        records.append(omm_fields(obj, lines[3 * k + 1], lines[3 * k + 2]))
        satrecs.append(obj.satrec)
    with open(tmp_path / "c.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(records[0]))
        writer.writeheader()
        writer.writerows(records)
    (tmp_path / "c.json").write_text(json.dumps(records))
    segments = "".join(
        "<segment><metadata>" + "".join(f"<{k}>{r[k]}</{k}>" for k in ("OBJECT_NAME", "OBJECT_ID")) + "</metadata>"
        "<data><meanElements>" + "".join(f"<{k}>{r[k]}</{k}>" for k in ("EPOCH", "MEAN_MOTION", "ECCENTRICITY",
        "INCLINATION", "RA_OF_ASC_NODE", "ARG_OF_PERICENTER", "MEAN_ANOMALY")) + "</meanElements><tleParameters>"
        + "".join(f"<{k}>{r[k]}</{k}>" for k in ("EPHEMERIS_TYPE", "CLASSIFICATION_TYPE", "NORAD_CAT_ID",
                                                "ELEMENT_SET_NO", "REV_AT_EPOCH", "BSTAR", "MEAN_MOTION_DOT",
                                                "MEAN_MOTION_DDOT")) + "</tleParameters></data></segment>"
        for r in records)
    (tmp_path / "c.xml").write_text(f"<ndm><omm><body>{segments}</body></omm></ndm>")
    jd = np.full(3, 2461120.0)
    fraction = np.array([0.25, 0.5, 0.75])               # 2026-03-20 18:00 .. 2026-03-21 06:00 UTC
    _, r_tle, _ = SatrecArray(satrecs).sgp4(jd, fraction)
    for name in ("c.csv", "c.json", "c.xml"):
        block = SatelliteCatalog(catalog_file=str(tmp_path / name))
        assert [o.object_id for o in block.catalog.objects] == [catalog.objects[k].object_id for k in picks]
        _, r_omm, _ = SatrecArray([o.satrec for o in block.catalog.objects]).sgp4(jd, fraction)
        assert np.abs(r_omm - r_tle).max() < 1e-3            # km: the same elements, the epoch to a microsecond


def test_omm_rows_with_missing_elements_are_named(tmp_path, text, catalog):
    lines = [line for line in text.splitlines() if line.strip()]
    good = omm_fields(catalog.objects[0], lines[1], lines[2])
    bad = dict(good, NORAD_CAT_ID="902", MEAN_MOTION="")
    with open(tmp_path / "c.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(good))
        writer.writeheader()
        writer.writerows([good, bad])
    with pytest.raises(ParameterError, match=r"line 3: missing MEAN_MOTION"):
        SatelliteCatalog(catalog_file=str(tmp_path / "c.csv"))


def test_per_object_properties_from_columns_or_defaults(tmp_path):
    (tmp_path / "c.tle").write_text(BAD_TLE.split("CORRUPTED")[0] + BAD_TLE.split("A NAME WITHOUT ELEMENTS\n")[1]
                                    .split("ISS AGAIN")[0])
    (tmp_path / "p.csv").write_text("NORAD_CAT_ID,AREA_M2,ALBEDO\n25544,2500,0.3\n")
    block = SatelliteCatalog(catalog_file=str(tmp_path / "c.tle"), properties_file=str(tmp_path / "p.csv"),
                             area_m2=4.0, albedo=0.1)
    iss, swas = block.catalog.objects
    assert (block._reflector(iss).area_m2, block._reflector(iss).albedo) == (2500.0, 0.3)
    assert (block._reflector(swas).area_m2, block._reflector(swas).albedo) == (4.0, 0.1)
    (tmp_path / "q.csv").write_text("NORAD_CAT_ID,ALBEDO\n25544,1.7\n")
    with pytest.raises(ParameterError, match=r"line 2: ALBEDO 1.7 is not physical"):
        SatelliteCatalog(catalog_file=str(tmp_path / "c.tle"), properties_file=str(tmp_path / "q.csv"))


def test_screen_positions_are_skyfields(catalog):
    """The screen's TEME -> GCRS positions equal Skyfield's EarthSatellite.at() (checks the frame rotation)."""
    objects = [catalog.objects[k] for k in (0, 5000, 12000)]
    pointing = PointingModel(NORTH_EAST, ObserverModel(GRAZ, START, 10 * NS), START, 10 * NS)
    screen = Screen([o.satrec for o in objects], pointing, lens(10.0), START, 0, 60 * NS)
    t = np.array([0, 30 * NS, 60 * NS])
    teme, r_obs, _, _ = screen._frame_quantities(t)
    r_km, _, _ = screen._propagate([o.satrec for o in objects], t)
    ours = np.einsum("jit,ntj->nti", teme, r_km) * 1000.0
    for n, obj in enumerate(objects):
        reference = EarthSatellite.from_satrec(obj.satrec, timescale()).at(skyfield_time(START, t)).position.m.T
        assert np.abs(ours[n] - reference).max() < 0.01               # m


def brute_force_in_field(satrecs, pointing, fp, duration_s, step_s=0.1):
    """Indices of the objects inside the detector at any sample ``step_s`` apart (all propagated)."""
    screen = Screen(satrecs, pointing, fp, START, 0, int(duration_s * NS))
    t = np.arange(0, int(duration_s * NS) + 1, int(step_s * NS))
    teme, r_obs, _, _ = screen._frame_quantities(t)
    b, r, u = pointing.frame(t.astype(float))
    r_km, _, errors = screen._propagate(satrecs, t)
    rel = np.einsum("jit,ntj->nti", teme, r_km) * 1000.0 - r_obs[None]
    x, y = projection.to_pixels(*projection.tangent_plane(*(np.einsum("ntk,tk->nt", rel, a) for a in (b, r, u))), fp)
    inside = projection.inside(x, y, fp) & (errors == 0)
    return set(np.flatnonzero(inside.any(axis=1)).tolist()), inside, t


def test_screen_misses_no_object_that_brute_force_finds(catalog):
    starlinks = [o for o in catalog.objects if o.name.startswith("STARLINK")][:4000]
    satrecs = [o.satrec for o in starlinks]
    fp = lens(20.0)
    pointing = PointingModel(NORTH_EAST, ObserverModel(GRAZ, START, 10 * NS), START, 10 * NS)
    result = Screen(satrecs, pointing, fp, START, 0, 30 * NS).run()
    found, inside, t = brute_force_in_field(satrecs, pointing, fp, 30.0)
    assert len(found) >= 3
    assert found <= set(result.intervals)                              # nothing missed ...
    assert len(result.intervals) <= len(found) + 3                     # ... and little extra work
    for n in found:                                                    # every in-field sample is covered
        covered = np.zeros(len(t), bool)
        for a, b in result.intervals[n]:
            covered |= (t >= a) & (t <= b)
        assert covered[inside[n]].all()


def test_a_catalogued_object_equals_the_satellite_block(tmp_path, catalog, text):
    """The catalogue's sampling of an object equals the satellite block's for its TLE, sample for sample."""
    lines = [line for line in text.splitlines() if line.strip()]
    index = next(k for k, o in enumerate(catalog.objects) if o.object_id == "48333")     # STARLINK-2475
    entry = "\n".join(lines[3 * index: 3 * index + 3]) + "\n"
    (tmp_path / "one.tle").write_text(entry)
    fp = lens(7.1)
    run = RunInfo(epoch=START, duration_ns=2 * NS, window_ns=NS)
    many = SatelliteCatalog(catalog_file=CATALOG, names="STARLINK-*", area_m2=1.04)
    single = Satellite(area_m2=1.04)
    many.setup(run)
    single.setup(run)
    orbit = make_orbit(lines[3 * index + 1], lines[3 * index + 2], lines[3 * index])
    for k in range(2):
        window = Window(k, k * NS, (k + 1) * NS, START)
        a = many.step(window, observer=GRAZ, pointing=NORTH_EAST, focal_plane=fp)["sources"]
        b = single.step(window, orbit=orbit, observer=GRAZ, pointing=NORTH_EAST, focal_plane=fp)["sources"]
        j = list(a.source_id).index("48333")
        assert np.isfinite(b.x_px).all()
        np.testing.assert_allclose(a.x_px[:, j], b.x_px[:, 0], atol=1e-9)
        np.testing.assert_allclose(a.y_px[:, j], b.y_px[:, 0], atol=1e-9)
        np.testing.assert_allclose(a.photon_flux[:, j], b.photon_flux[:, 0], rtol=1e-12)
    assert len(set(a.source_id)) == a.n_sources >= 2                   # distinct ids: one source per object
    assert (a.kind == SourceKind.SATELLITE).all()


def test_no_crossing_is_one_clear_error():
    block = SatelliteCatalog(catalog_file=CATALOG, names="STARLINK-*")
    block.setup(RunInfo(epoch=START, duration_ns=5 * NS, window_ns=NS))
    with pytest.raises(SceneError, match=r"none of the 9934 objects .* is observable in the field of view"):
        block.step(Window(0, 0, NS, START), observer=GRAZ, pointing=Pointing(mode="stare", azimuth_deg=200.0,
                                                                             elevation_deg=85.0),
                   focal_plane=lens(0.5))


def test_old_element_sets_are_counted_in_one_warning():
    block = SatelliteCatalog(catalog_file=CATALOG, max_tle_age_days=3.0)
    with pytest.warns(CatalogAgeWarning, match=r"of 14710 element sets are more than max_tle_age_days=3"):
        block.setup(RunInfo(epoch=START + timedelta(days=2), duration_ns=NS, window_ns=NS))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SatelliteCatalog(catalog_file=CATALOG, names="STARLINK-*").setup(RunInfo(epoch=START, duration_ns=NS,
                                                                                  window_ns=NS))


# -- per-object metrics ---------------------------------------------------------------------------------
def two_on_one_track(fp):
    """Two objects on the same row, 1 s apart, 100 pixels/s (a train), sampled every ms for 2 s."""
    t = np.arange(0, 2 * NS, 1_000_000)
    x = np.stack([10 + 100 * t / NS, 10 + 100 * (t / NS - 1.0)], axis=1)
    x[x < 0] = np.nan
    y = np.where(np.isfinite(x), 50.0, np.nan)
    n = len(t)
    return PointSources(fp, 5.5e-7, t, np.array(["00001", "00002"]), np.zeros(2, np.int8), x, y,
                        np.ones((n, 2)), np.full((n, 2), 9.0), np.full((n, 2), 1e6), np.zeros(n))


def events_of(fp, t_ns, x, y, p, cause):
    order = np.argsort(t_ns)
    t_ns = np.asarray(t_ns, np.int64)[order]
    return Events(fp, t_ns, t_ns + 1000, np.asarray(x, np.uint16)[order], np.asarray(y, np.uint16)[order],
                  np.asarray(p, np.int8)[order], np.asarray(cause, np.uint8)[order])


def test_object_metrics_tell_a_train_apart_by_time():
    fp = FocalPlane(400, 100, 1e-5, 1.0)
    sources = two_on_one_track(fp)
    # object 1 is at x = 60 at t = 0.5 s and object 2 at t = 1.5 s: the same pixel, one second apart
    t = np.array([0.5, 0.51, 0.52, 1.5, 1.51, 1.5, 0.8, 1.0]) * NS
    x = np.array([60, 59, 58, 60, 59, 61, 200, 60])
    y = np.array([50, 51, 49, 50, 50, 52, 50, 90])
    p = np.array([1, -1, -1, 1, -1, 1, 1, 1])
    cause = np.array([EventCause.SIGNAL, EventCause.SIGNAL, EventCause.SHOT, EventCause.SIGNAL, EventCause.SIGNAL,
                      EventCause.LEAK, EventCause.LEAK, EventCause.SHOT])
    block = ObjectMetrics(track_radius_px=3.0, latency_s=0.05)
    block.setup(RunInfo(duration_ns=2 * NS, window_ns=2 * NS))
    m = block.step(Window(0, 0, 2 * NS), events=events_of(fp, t, x, y, p, cause), sources=[sources])["metrics"].values
    assert (m["object_00001_events"], m["object_00001_signal_events"], m["object_00001_noise_events"]) == (3, 2, 1)
    assert (m["object_00001_on_events"], m["object_00001_off_events"]) == (1, 2)
    assert (m["object_00002_events"], m["object_00002_signal_events"], m["object_00002_noise_events"]) == (3, 2, 1)
    assert m["object_00001_snr"] == pytest.approx(2 / np.sqrt(3))
    assert m["object_00001_observed_s"] == pytest.approx(2.0) and m["object_00002_observed_s"] == pytest.approx(1.1)
    assert m["objects_observed"] == 2 and m["objects_with_signal"] == 2


def test_object_metrics_do_not_depend_on_the_windows():
    fp = FocalPlane(400, 100, 1e-5, 1.0)
    sources = two_on_one_track(fp)
    rng = np.random.default_rng(4)
    n = 3000
    t = np.sort(rng.integers(0, 2 * NS, n))
    k = np.searchsorted(sources.t_ns, t, side="right") - 1
    lag = rng.integers(0, 40, n)                                     # events up to 40 ms behind the object
    which = rng.integers(0, 2, n)
    base = sources.x_px[np.maximum(k - lag, 0), which]
    x = np.where(np.isfinite(base), base + rng.normal(0, 1, n), rng.uniform(0, 399, n)).clip(0, 399)
    y = (50 + rng.normal(0, 1.5, n)).clip(0, 99)
    events = events_of(fp, t, x, y, rng.choice([-1, 1], n), rng.integers(0, 4, n))
    whole = ObjectMetrics()
    whole.setup(RunInfo(duration_ns=2 * NS, window_ns=2 * NS))
    expected = whole.step(Window(0, 0, 2 * NS), events=events, sources=[sources])["metrics"].values
    split = ObjectMetrics()
    split.setup(RunInfo(duration_ns=2 * NS, window_ns=NS // 10))
    for w in range(20):
        lo, hi = w * NS // 10, (w + 1) * NS // 10
        sel = (events.t_trigger_ns >= lo) & (events.t_trigger_ns < hi)
        part = Events(fp, events.t_trigger_ns[sel], events.t_readout_ns[sel], events.x[sel], events.y[sel],
                      events.p[sel], events.cause[sel])
        rows = (sources.t_ns >= lo) & (sources.t_ns < hi)
        src = PointSources(fp, 5.5e-7, sources.t_ns[rows], sources.source_id, sources.kind, sources.x_px[rows],
                           sources.y_px[rows], sources.photon_flux[rows], sources.magnitude[rows],
                           sources.range_m[rows], sources.zenith_angle_rad[rows])
        values = split.step(Window(w, lo, hi), events=part, sources=[src])["metrics"].values
    assert values["object_00001_events"] > 1000
    assert values == expected


def test_damaged_and_oversized_compressed_catalogues_are_one_clear_error(tmp_path, monkeypatch):
    """A truncated .gz was an EOFError traceback; a gzip bomb was read whole. Each is one error naming the file."""
    from evsda.blocks.scene import element_sets

    whole = library.resolve(CATALOG).read_bytes()
    truncated, not_gzip = tmp_path / "truncated.tle.gz", tmp_path / "plain.tle.gz"
    truncated.write_bytes(whole[: len(whole) // 3])
    not_gzip.write_text("not compressed\n")
    with pytest.raises(ParameterError, match="truncated.tle.gz is a damaged or truncated gzip file"):
        SatelliteCatalog(catalog_file=str(truncated))
    with pytest.raises(ParameterError, match="plain.tle.gz is not a gzip file"):
        SatelliteCatalog(catalog_file=str(not_gzip))
    monkeypatch.setattr(element_sets, "MAX_CATALOG_BYTES", 1 << 20)       # the bundled one holds ~3 MB of text
    with pytest.raises(ParameterError, match="holds more than 1 MiB of text; a catalogue may not be larger"):
        SatelliteCatalog(catalog_file=CATALOG)
