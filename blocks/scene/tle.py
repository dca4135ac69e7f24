"""Two-line element sets: parsing, checksum validation, epoch age and SGP4 health checks.

The TLE format (NORAD/Space-Track; see Vallado et al. 2006, "Revisiting Spacetrack
Report #3", AIAA 2006-6753, and CelesTrak's "NORAD Two-Line Element Set Format"): two
69-character lines, optionally preceded by a name line; column 69 of each line is a
checksum, the sum modulo 10 of the digits in columns 1-68 with each minus sign counting 1.
"""

from __future__ import annotations

import functools
from datetime import datetime, timezone

import numpy as np
from sgp4.api import SGP4_ERRORS, Satrec
from skyfield.api import EarthSatellite

from evsda.blocks.ports.scene import Orbit
from evsda.graph import ParameterError, SceneError
from evsda.graph.errors import excerpt

from .ephemeris import NS_PER_DAY, timescale

LINE_LENGTH = 69
EARTH_EQUATORIAL_RADIUS_KM = 6378.137    # WGS84 [km]


def tle_checksum(line: str) -> int:
    """The checksum digit of a TLE line: digits of columns 1-68 summed, '-' counting 1, modulo 10."""
    total = 0
    for char in line[: LINE_LENGTH - 1]:
        if char.isdigit():
            total += int(char)
        elif char == "-":
            total += 1
    return total % 10


def parse_tles(text: str, source: str = "TLE text") -> list[Orbit]:
    """Every element set in ``text`` (two-line or three-line form), validated.

    Raises :class:`ParameterError` naming ``source`` and the line for a malformed line,
    a wrong checksum, or lines 1 and 2 of different satellites.
    """
    lines = [(number, raw.rstrip()) for number, raw in enumerate(text.splitlines(), start=1) if raw.strip()]
    if not any(line.startswith(("1 ", "2 ")) for _, line in lines):
        # not a TLE file at all: quote nothing from it (it may be any file its user can read)
        raise ParameterError(f"{source}: no two-line element set found (no line starts with '1 ' or '2 ')")
    orbits: list[Orbit] = []
    i = 0
    while i < len(lines):
        name = ""
        number, line = lines[i]
        if not line.startswith("1 "):
            name = line[2:].strip() if line.startswith("0 ") else line.strip()
            i += 1
            if i >= len(lines):
                raise ParameterError(f"{source}: line {number} ({excerpt(name, 30)}) is not followed by a two-line "
                                     f"element set")
        if i + 1 >= len(lines):
            raise ParameterError(f"{source}: line {lines[i][0]} has no line 2 after it")
        (n1, line1), (n2, line2) = lines[i], lines[i + 1]
        _check_line(line1, "1", n1, source)
        _check_line(line2, "2", n2, source)
        if line1[2:7] != line2[2:7]:
            raise ParameterError(f"{source}: lines {n1} and {n2} belong to different satellites "
                                 f"({line1[2:7].strip()} and {line2[2:7].strip()})")
        orbits.append(make_orbit(line1, line2, name or f"NORAD {line1[2:7].strip()}"))
        i += 2
    if not orbits:
        raise ParameterError(f"{source}: no two-line element set found")
    return orbits


def _check_line(line: str, kind: str, number: int, source: str) -> None:
    if not line.startswith(kind + " "):
        raise ParameterError(f"{source}: line {number} should be TLE line {kind} (starting '{kind} '), "
                             f"got {excerpt(line[:20])}")
    if len(line) != LINE_LENGTH:
        raise ParameterError(f"{source}: line {number} has {len(line)} characters, a TLE line has {LINE_LENGTH}")
    if not line[-1].isdigit():
        raise ParameterError(f"{source}: line {number} ends with {excerpt(line[-1])} where its checksum digit should be")
    expected = tle_checksum(line)
    if int(line[-1]) != expected:
        raise ParameterError(f"{source}: line {number} fails its checksum (column 69 says {line[-1]}, "
                             f"the line sums to {expected}); the element set is corrupted")


def make_orbit(line1: str, line2: str, name: str) -> Orbit:
    """An :class:`Orbit` port value from two already-checked TLE lines."""
    epoch = tle_epoch(line1, line2)
    return Orbit(name=name, catalog_number=line1[2:7].strip(), line1=line1, line2=line2,
                 epoch_utc=epoch.isoformat().replace("+00:00", "Z"))


def tle_epoch(line1: str, line2: str) -> datetime:
    """The element set's epoch (UTC)."""
    satrec = Satrec.twoline2rv(line1, line2)
    jd = satrec.jdsatepoch + satrec.jdsatepochF
    return _utc_from_jd(jd)


def _utc_from_jd(jd_utc: float) -> datetime:
    """A UTC Julian date as a datetime (TLE epochs are UTC)."""
    unix_s = (jd_utc - 2440587.5) * 86400.0
    return datetime.fromtimestamp(round(unix_s, 6), tz=timezone.utc)


@functools.lru_cache(maxsize=256)
def earth_satellite(line1: str, line2: str, name: str = "") -> EarthSatellite:
    """Skyfield's SGP4 satellite for a TLE (cached: construction parses the elements)."""
    return EarthSatellite(line1, line2, name, timescale())


def epoch_age_days(orbit: Orbit, when: datetime) -> float:
    """Days from the TLE epoch to ``when`` (negative if ``when`` is before the epoch)."""
    epoch = datetime.fromisoformat(orbit.epoch_utc.replace("Z", "+00:00"))
    return (when - epoch).total_seconds() / 86400.0


def check_propagation(orbit: Orbit, epoch: datetime, start_ns: int, stop_ns: int, who: str) -> None:
    """Raise :class:`SceneError` if SGP4 fails between the TLE epoch and the end of ``[start_ns, stop_ns]``.

    SGP4 flags a decayed orbit, or elements that drag has driven out of range, with an
    error code (Vallado et al. 2006, "Error codes") only around the moment of decay and
    returns plausible-looking numbers afterwards, so the check follows the orbit every
    minute from the element set's epoch through the run (and also flags positions below
    the Earth's surface, the retired error 5).
    """
    satrec = Satrec.twoline2rv(orbit.line1, orbit.line2)
    jd_tle = satrec.jdsatepoch + satrec.jdsatepochF
    jd_start = _julian_date_utc(epoch) + start_ns / NS_PER_DAY
    jd_stop = _julian_date_utc(epoch) + stop_ns / NS_PER_DAY
    first, last = min(jd_tle, jd_start), max(jd_tle, jd_stop)
    step_days = max(1.0 / 1440.0, (last - first) / 200_000)
    jd = np.append(np.arange(first, last, step_days), last)
    errors, r_km, _ = satrec.sgp4_array(np.floor(jd), jd - np.floor(jd))
    underground = np.linalg.norm(r_km, axis=-1) < EARTH_EQUATORIAL_RADIUS_KM * (1 - 1 / 298.257)
    bad = np.flatnonzero((errors != 0) | underground)
    if bad.size:
        code = int(errors[bad[0]])
        reason = SGP4_ERRORS.get(code, f"error code {code}") if code else "the satellite is below the Earth's surface"
        when = _utc_from_jd(jd[bad[0]]).isoformat(timespec="seconds").replace("+00:00", "Z")
        raise SceneError(f"{who}: SGP4 cannot propagate {orbit.name} ({orbit.catalog_number}) from its TLE epoch "
                         f"{orbit.epoch_utc} to the simulated time: at {when} {reason}; use an element set "
                         f"close to the simulated time")


def _julian_date_utc(when: datetime) -> float:
    return when.timestamp() / 86400.0 + 2440587.5
