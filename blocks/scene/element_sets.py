"""Catalogues of mean elements: a TLE file with many objects, or an OMM file (CSV, JSON, XML).

Current catalogues (CelesTrak, Space-Track) distribute the same SGP4 mean elements as
two-line element sets or as CCSDS Orbit Mean-Elements Messages (OMM, CCSDS 502.0-B-3);
CelesTrak's OMM CSV and JSON use the OMM keywords as column names (``OBJECT_NAME``,
``NORAD_CAT_ID``, ``EPOCH``, ``MEAN_MOTION`` [rev/day], ``ECCENTRICITY``, ``INCLINATION``,
``RA_OF_ASC_NODE``, ``ARG_OF_PERICENTER``, ``MEAN_ANOMALY`` [deg], ``BSTAR`` [1/earth radii],
``MEAN_MOTION_DOT``, ``MEAN_MOTION_DDOT``). Either becomes one ``Satrec`` per object through
the ``sgp4`` library (``twoline2rv``, or ``sgp4.omm.initialize``).

Per-object optical properties come from optional ``AREA_M2`` and ``ALBEDO`` columns
(in an OMM CSV/JSON catalogue, or in a separate properties CSV keyed by ``NORAD_CAT_ID``);
objects without them take the block's defaults.

A malformed entry (a bad TLE line or checksum, lines 1 and 2 of different objects, an
OMM row with a missing or non-numeric element, elements SGP4 rejects, a repeated
object) is named by its line; :func:`read_catalog` refuses the file or skips those
entries, as asked.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from sgp4 import omm
from sgp4.api import Satrec

from evsda.graph import ParameterError
from evsda.graph.errors import clip

from .tle import LINE_LENGTH, tle_checksum

OMM_ELEMENTS = ("EPOCH", "MEAN_MOTION", "ECCENTRICITY", "INCLINATION", "RA_OF_ASC_NODE", "ARG_OF_PERICENTER",
                "MEAN_ANOMALY", "BSTAR", "MEAN_MOTION_DOT", "MEAN_MOTION_DDOT")
OMM_DEFAULTS = {"CLASSIFICATION_TYPE": "U", "OBJECT_ID": "", "EPHEMERIS_TYPE": "0", "ELEMENT_SET_NO": "999",
                "REV_AT_EPOCH": "0"}
PROPERTY_COLUMNS = {"AREA_M2": "area_m2", "ALBEDO": "albedo"}
FORMATS = ("tle", "omm_csv", "omm_json", "omm_xml")
#: the most characters of a file's line an error message quotes (an object's name, a field)
NAME_QUOTED = 40
#: the largest catalogue read, decompressed [bytes]: every catalogued object (~30 000) as OMM JSON is
#: ~30 MB, so this bounds a gzip bomb without refusing any real catalogue
MAX_CATALOG_BYTES = 256 << 20


@dataclass
class CatalogObject:
    """One object of a catalogue: its id, name, SGP4 elements, where it was read, optical properties."""

    object_id: str                   # NORAD catalogue number, 5 digits as in a TLE (e.g. "00900", "44713")
    name: str
    satrec: Satrec
    line: int                        # line of the file it starts on
    area_m2: float = math.nan        # cross-section (sphere) or area (plate) [m^2]; NaN: the default
    albedo: float = math.nan         # diffuse reflectivity [1]; NaN: the default


@dataclass
class Catalog:
    """The objects read from one file and the entries skipped as malformed (``(line, reason)``)."""

    source: str
    objects: list[CatalogObject]
    skipped: list[tuple[int, str]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.objects)


class BadEntry(ValueError):
    """A malformed catalogue entry (message without the file name)."""


def read_text(path: Path, who: str) -> str:
    """A catalogue file's text (gzip-compressed if it ends in ``.gz``), at most :data:`MAX_CATALOG_BYTES`
    once decompressed; a damaged or truncated gzip stream is one error naming the file."""
    try:
        with (gzip.open if path.suffix == ".gz" else open)(path, "rb") as f:
            data = f.read(MAX_CATALOG_BYTES + 1)
    except gzip.BadGzipFile:
        raise ParameterError(f"{who}: {path} is not a gzip file (its name ends in .gz)") from None
    except (EOFError, zlib.error):
        raise ParameterError(f"{who}: {path} is a damaged or truncated gzip file") from None
    except OSError as exc:
        raise ParameterError(f"{who}: cannot read {path} ({exc.strerror or type(exc).__name__})") from None
    if len(data) > MAX_CATALOG_BYTES:
        raise ParameterError(f"{who}: {path} holds more than {MAX_CATALOG_BYTES >> 20} MiB of text; a catalogue "
                             f"may not be larger (select the objects with names: or split the file)")
    return data.decode("utf-8", errors="replace")


def guess_format(path: Path) -> str:
    """The catalogue format from the file name: ``.csv``, ``.json``, ``.xml``, else TLE."""
    suffixes = [s.lower() for s in path.suffixes if s.lower() != ".gz"]
    last = suffixes[-1] if suffixes else ""
    return {".csv": "omm_csv", ".json": "omm_json", ".xml": "omm_xml"}.get(last, "tle")


def read_catalog(text: str, fmt: str, source: str, skip_bad: bool) -> Catalog:
    """Every object of a catalogue ``text`` in format ``fmt`` (one of :data:`FORMATS`).

    With ``skip_bad`` a malformed entry is left out and listed in ``Catalog.skipped``;
    otherwise the first one raises a :class:`ParameterError` naming ``source`` and its line
    (and how many more there are).
    """
    if fmt == "tle" and not any(line.lstrip().startswith(("1 ", "2 ")) for line in text.splitlines()):
        # not a TLE file at all: quote nothing from it (it may be any file its user can read)
        raise ParameterError(f"{source}: no two-line element set found (no line starts with '1 ' or '2 ')")
    reader = {"tle": _tle_entries, "omm_csv": _omm_csv_entries, "omm_json": _omm_json_entries,
              "omm_xml": _omm_xml_entries}[fmt]
    objects: list[CatalogObject] = []
    skipped: list[tuple[int, str]] = []
    first_line: dict[str, int] = {}
    for line, entry in reader(text):
        try:
            if isinstance(entry, BadEntry):
                raise entry
            obj = entry()
            if obj.object_id in first_line:
                raise BadEntry(f"object {obj.object_id} ({obj.name}) appears again (first on line "
                               f"{first_line[obj.object_id]})")
        except BadEntry as bad:
            skipped.append((line, str(bad)))
            continue
        first_line[obj.object_id] = obj.line
        objects.append(obj)
    if skipped and not skip_bad:
        line, reason = skipped[0]
        more = f" ({len(skipped) - 1} more malformed entries follow)" if len(skipped) > 1 else ""
        raise ParameterError(f"{source}: line {line}: {reason}{more}; fix the file or set on_bad_entry: skip "
                             f"to leave such entries out")
    if not objects:
        raise ParameterError(f"{source}: no valid object found" + (f" ({len(skipped)} malformed entries skipped)"
                                                                   if skipped else ""))
    return Catalog(source, objects, skipped)


# -- two-line element sets ------------------------------------------------------------------------
def _tle_entries(text: str):
    """``(line, make_object or BadEntry)`` for each entry of a TLE file, resynchronising after a bad line."""
    lines = [(number, raw.rstrip()) for number, raw in enumerate(text.splitlines(), start=1) if raw.strip()]
    name, name_line = "", None
    i = 0
    while i < len(lines):
        number, line = lines[i]
        if line.startswith("1 ") and i + 1 < len(lines) and lines[i + 1][1].startswith("2 "):
            (n1, line1), (n2, line2) = lines[i], lines[i + 1]
            yield (name_line or n1), _tle_object(name, n1, line1, n2, line2, name_line or n1)
            name, name_line = "", None
            i += 2
            continue
        if name_line is not None:
            yield name_line, BadEntry(f"'{clip(name, NAME_QUOTED)}' is not followed by a two-line element set")
        if line.startswith("1 "):
            yield number, BadEntry("TLE line 1 is not followed by a line 2")
            name, name_line = "", None
        elif line.startswith("2 "):
            yield number, BadEntry("TLE line 2 without a line 1 before it")
            name, name_line = "", None
        else:
            name, name_line = (line[2:].strip() if line.startswith("0 ") else line.strip()), number
        i += 1
    if name_line is not None:
        yield name_line, BadEntry(f"'{clip(name, NAME_QUOTED)}' is not followed by a two-line element set")


def _check_tle_line(line: str, kind: str, number: int) -> None:
    if len(line) != LINE_LENGTH:
        raise BadEntry(f"line {number} has {len(line)} characters, a TLE line has {LINE_LENGTH}")
    if not line[-1].isdigit() or int(line[-1]) != tle_checksum(line):
        raise BadEntry(f"line {number} fails its checksum (column 69 says {line[-1]!r}, the line sums to "
                       f"{tle_checksum(line)})")


def _tle_object(name: str, n1: int, line1: str, n2: int, line2: str, first: int):
    def make() -> CatalogObject:
        _check_tle_line(line1, "1", n1)
        _check_tle_line(line2, "2", n2)
        if line1[2:7] != line2[2:7]:
            raise BadEntry(f"lines {n1} and {n2} belong to different objects ({line1[2:7].strip()} and "
                           f"{line2[2:7].strip()})")
        try:
            satrec = Satrec.twoline2rv(line1, line2)
        except ValueError as exc:
            raise BadEntry(f"lines {n1}-{n2} cannot be read as elements ({exc})") from None
        _check_satrec(satrec)
        object_id = line1[2:7].strip()
        return CatalogObject(object_id, name or f"NORAD {object_id}", satrec, first)
    return make


def _check_satrec(satrec: Satrec) -> None:
    if satrec.error:
        raise BadEntry(f"SGP4 rejects the elements (error {satrec.error})")
    if not 0.0 <= satrec.ecco < 1.0 or satrec.no_kozai <= 0:
        raise BadEntry(f"elements out of range (eccentricity {satrec.ecco}, mean motion "
                       f"{satrec.no_kozai * 720 / math.pi:.6g} rev/day)")


# -- orbit mean-elements messages ------------------------------------------------------------------
def _omm_csv_entries(text: str):
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip().upper() for h in (reader.fieldnames or [])]
    missing = [name for name in ("NORAD_CAT_ID",) + OMM_ELEMENTS if name not in header]
    if missing:
        yield 1, BadEntry(f"the CSV header lacks the OMM column(s) {', '.join(missing)}")
        return
    for row in reader:
        number = reader.line_num
        fields = {(k or "").strip().upper(): (v or "").strip() for k, v in row.items() if k is not None}
        if None in row:
            yield number, BadEntry(f"the row has {len(header) + len(row[None])} fields, the header {len(header)}")
            continue
        yield number, _omm_object(fields, number)


def _omm_json_entries(text: str):
    try:
        records = json.loads(text)
    except json.JSONDecodeError as exc:
        yield exc.lineno, BadEntry(f"not valid JSON ({exc.msg})")
        return
    if isinstance(records, dict):
        records = [records]
    if not isinstance(records, list):
        yield 1, BadEntry("an OMM JSON file holds a list of records")
        return
    # JSON has no useful line per record: entries are numbered by their position in the list (1-based)
    for index, record in enumerate(records, start=1):
        if not isinstance(record, dict):
            yield index, BadEntry(f"record {index} is not an object")
            continue
        yield index, _omm_object({str(k).upper(): "" if v is None else str(v) for k, v in record.items()}, index)


def _omm_xml_entries(text: str):
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        yield exc.position[0], BadEntry(f"not valid XML ({exc})")
        return
    for index, segment in enumerate(root.iter("segment"), start=1):
        fields = {}
        for tag in ("metadata", "data/meanElements", "data/tleParameters", "data/userDefinedParameters"):
            element = segment.find(tag)
            if element is not None:
                fields.update((child.tag.upper(), (child.text or "").strip()) for child in element)
        yield index, _omm_object(fields, index)


def _omm_object(fields: dict, number: int):
    def make() -> CatalogObject:
        missing = [name for name in ("NORAD_CAT_ID",) + OMM_ELEMENTS if not fields.get(name)]
        if missing:
            raise BadEntry(f"missing {', '.join(missing)}")
        completed = {**OMM_DEFAULTS, **{k: v for k, v in fields.items() if v}}
        completed["EPOCH"] = _omm_epoch(fields["EPOCH"])
        try:
            satnum = int(float(fields["NORAD_CAT_ID"]))
            completed["NORAD_CAT_ID"] = str(satnum)
            satrec = Satrec()
            omm.initialize(satrec, completed)
        except (ValueError, KeyError) as exc:
            raise BadEntry(f"an element is not a number ({exc})") from None
        _check_satrec(satrec)
        object_id = f"{satnum:05d}"
        obj = CatalogObject(object_id, fields.get("OBJECT_NAME") or f"NORAD {object_id}", satrec, number)
        _set_properties(obj, fields)
        return obj
    return make


def _omm_epoch(text: str) -> str:
    """An OMM epoch in the ``YYYY-MM-DDTHH:MM:SS.ffffff`` form ``sgp4.omm`` reads (UTC)."""
    try:
        when = datetime.fromisoformat(text.strip().rstrip("Z"))
    except ValueError:
        raise BadEntry(f"EPOCH '{clip(text, NAME_QUOTED)}' is not an ISO 8601 date and time") from None
    return when.strftime("%Y-%m-%dT%H:%M:%S.%f")


def _set_properties(obj: CatalogObject, fields: dict) -> None:
    for column, attribute in PROPERTY_COLUMNS.items():
        text = fields.get(column, "")
        if not text:
            continue
        try:
            value = float(text)
        except ValueError:
            raise BadEntry(f"{column} '{clip(text, NAME_QUOTED)}' is not a number") from None
        if not value > 0 or (column == "ALBEDO" and value > 1):
            raise BadEntry(f"{column} {value:g} is not physical (area > 0 m^2, 0 < albedo <= 1)")
        setattr(obj, attribute, value)


def apply_properties(catalog: Catalog, text: str, source: str) -> int:
    """Set ``AREA_M2``/``ALBEDO`` of the catalogue's objects from a CSV keyed by ``NORAD_CAT_ID``.

    Returns how many objects it matched; any malformed row is a :class:`ParameterError`.
    """
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip().upper() for h in (reader.fieldnames or [])]
    if "NORAD_CAT_ID" not in header or not set(PROPERTY_COLUMNS) & set(header):
        raise ParameterError(f"{source}: a properties file is a CSV file whose header (line 1) names a NORAD_CAT_ID "
                             f"column and AREA_M2 and/or ALBEDO")
    by_id = {obj.object_id: obj for obj in catalog.objects}
    matched = 0
    for row in reader:
        fields = {(k or "").strip().upper(): (v or "").strip() for k, v in row.items() if k is not None}
        try:
            object_id = f"{int(fields['NORAD_CAT_ID']):05d}"
        except ValueError:
            raise ParameterError(f"{source}: line {reader.line_num}: NORAD_CAT_ID "
                                 f"'{clip(fields['NORAD_CAT_ID'], NAME_QUOTED)}' is not a number") from None
        obj = by_id.get(object_id)
        if obj is None:
            continue
        try:
            _set_properties(obj, fields)
        except BadEntry as bad:
            raise ParameterError(f"{source}: line {reader.line_num}: {bad}") from None
        matched += 1
    return matched


def epoch_utc(obj: CatalogObject) -> str:
    """The object's element-set epoch, ISO 8601 UTC to the microsecond."""
    jd = obj.satrec.jdsatepoch + obj.satrec.jdsatepochF
    when = datetime.fromtimestamp(round((jd - 2440587.5) * 86400.0, 6), tz=timezone.utc)
    return when.isoformat().replace("+00:00", "Z")


def epoch_jd(objects: list[CatalogObject]) -> np.ndarray:
    """Element-set epochs as UTC Julian dates."""
    return np.array([o.satrec.jdsatepoch + o.satrec.jdsatepochF for o in objects])
