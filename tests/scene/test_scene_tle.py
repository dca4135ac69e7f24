"""TLE parsing and checks against the sgp4 package's own verification file and Skyfield."""

import warnings
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
import sgp4
from skyfield.api import EarthSatellite

from evsda.blocks.scene.sources import TleAgeWarning, TleSource
from evsda.blocks.scene.tle import parse_tles, tle_checksum
from evsda.graph import ParameterError, RunInfo, SceneError

ISS_TEXT = """ISS (ZARYA)
1 25544U 98067A   23079.03815557  .00016821  00000+0  30934-3 0  9994
2 25544  51.6408  50.1970 0006203 111.3415   6.4805 15.49308950387965
"""


def vallado_tle(catalog: str) -> tuple[str, str]:
    """A TLE from Vallado's SGP4-VER.TLE as shipped by the sgp4 package (line 2 cut to 69 columns)."""
    lines = (Path(sgp4.__file__).parent / "SGP4-VER.TLE").read_text().splitlines()
    i = next(i for i, line in enumerate(lines) if line.startswith(f"1 {catalog}"))
    return lines[i].rstrip(), lines[i + 1][:69]


def test_checksums_of_every_verification_tle_and_bundled_tle():
    lines = (Path(sgp4.__file__).parent / "SGP4-VER.TLE").read_text().splitlines()
    checked = 0
    for line in lines:
        synthetic = line[2:6] == "3333"           # Vallado's hand-edited error-code cases
        if line[:2] in ("1 ", "2 ") and len(line.rstrip()) >= 69 and line[68].isdigit() and not synthetic:
            assert tle_checksum(line) == int(line[68]), line
            checked += 1
    assert checked > 50


def test_epoch_matches_skyfield(iss):
    satellite = EarthSatellite(iss.line1, iss.line2)
    ours = datetime.fromisoformat(iss.epoch_utc.replace("Z", "+00:00"))
    assert abs((ours - satellite.epoch.utc_datetime()).total_seconds()) < 1e-3


def test_bad_checksum_is_one_clear_error():
    corrupted = ISS_TEXT.replace("30934-3 0  9994", "30935-3 0  9994")
    with pytest.raises(ParameterError, match=r"line 2 fails its checksum"):
        parse_tles(corrupted, "iss.tle")


def test_mismatched_lines_and_truncated_lines():
    lines = ISS_TEXT.splitlines()
    other = vallado_tle("28057")
    with pytest.raises(ParameterError, match="different satellites"):
        parse_tles("\n".join([lines[1], other[1]]))
    with pytest.raises(ParameterError, match="has 60 characters"):
        parse_tles("\n".join([lines[1][:60], lines[2]]))


def test_select_from_a_file_with_several(tmp_path):
    line1, line2 = vallado_tle("28057")
    path = tmp_path / "two.tle"
    path.write_text(ISS_TEXT + f"CBERS 2\n{line1}\n{line2}\n")
    assert TleSource(tle_file=str(path), select="28057").orbit.name == "CBERS 2"
    assert TleSource(tle_file=str(path), select="iss (zarya)").orbit.catalog_number == "25544"
    with pytest.raises(ParameterError, match="choose one with 'select'"):
        TleSource(tle_file=str(path))
    with pytest.raises(ParameterError, match="exactly one of tle_file and tle_text"):
        TleSource(tle_file=str(path), tle_text=ISS_TEXT)


def test_tle_weeks_old_warns_with_its_age():
    source = TleSource(tle_text=ISS_TEXT, max_tle_age_days=14)
    start = datetime(2023, 4, 10, tzinfo=timezone.utc)          # three weeks after the epoch
    with pytest.warns(TleAgeWarning, match=r"21\.\d days"):
        source.setup(RunInfo(epoch=start, duration_ns=10**10))
    assert source.tle_age_days == pytest.approx(20.96, abs=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        TleSource(tle_text=ISS_TEXT).setup(RunInfo(epoch=start - timedelta(days=20), duration_ns=10**10))


def test_decayed_orbit_is_a_scene_error():
    # MINOTAUR R/B, decayed 2005-11-29 "(perigee = -51km), lost in 50 minutes" (Vallado's notes)
    line1, line2 = vallado_tle("28872")
    source = TleSource(tle_text=f"MINOTAUR R/B\n{line1}\n{line2}")
    with pytest.raises(SceneError, match=r"SGP4 cannot propagate MINOTAUR R/B \(28872\).* at 2005-11-29T01:"):
        source.setup(RunInfo(epoch=datetime(2005, 11, 29, 12, tzinfo=timezone.utc), duration_ns=10**10))
    # before the decay the same element set is fine
    source.setup(RunInfo(epoch=datetime(2005, 11, 29, 0, 40, tzinfo=timezone.utc), duration_ns=10**10))
