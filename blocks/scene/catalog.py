"""The bundled Hipparcos excerpt (ESA 1997, SP-1200), read without pandas."""

from __future__ import annotations

import functools
import gzip
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evsda.graph import ParameterError, UserError
from evsda.graph.files import check_regular_file

HIPPARCOS_EPOCH_JYEAR = 1991.25       # catalogue epoch of positions (Julian year, TT)


@dataclass(frozen=True)
class StarCatalog:
    """Stars with ICRS positions at ``epoch_jyear`` and proper motions."""

    name: np.ndarray                  # str [n], e.g. "HIP 32349"
    vmag: np.ndarray                  # Johnson V [mag]
    ra_deg: np.ndarray                # ICRS right ascension [deg]
    dec_deg: np.ndarray               # ICRS declination [deg]
    pm_ra_mas_yr: np.ndarray          # proper motion in RA times cos(Dec) [mas/yr]
    pm_dec_mas_yr: np.ndarray         # proper motion in Dec [mas/yr]
    parallax_mas: np.ndarray          # [mas]
    epoch_jyear: float = HIPPARCOS_EPOCH_JYEAR
    b_v: np.ndarray | None = None     # Johnson B - V [mag]; NaN (or None: all) where not known

    def __len__(self) -> int:
        return int(self.vmag.shape[0])

    @property
    def colour(self) -> np.ndarray:
        """B - V of every star, NaN where not known [mag]."""
        return np.full(len(self), np.nan) if self.b_v is None else self.b_v

    def select(self, mask: np.ndarray) -> "StarCatalog":
        return StarCatalog(self.name[mask], self.vmag[mask], self.ra_deg[mask], self.dec_deg[mask],
                           self.pm_ra_mas_yr[mask], self.pm_dec_mas_yr[mask], self.parallax_mas[mask],
                           self.epoch_jyear, self.colour[mask])

    def unit_vectors(self) -> np.ndarray:
        """ICRS unit vectors at the catalogue epoch, ``[n, 3]``."""
        ra, dec = np.radians(self.ra_deg), np.radians(self.dec_deg)
        return np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=-1)


@functools.lru_cache(maxsize=4)
def load_hipparcos(path: str) -> StarCatalog:
    """Read ``hip_main.dat`` (pipe-separated, optionally gzipped): fields HIP, Vmag, RAdeg, DEdeg, Plx, pmRA, pmDE
    and B-V (H37; NaN where blank).

    Stars without an astrometric solution (blank RA) are skipped; a missing parallax or
    proper motion counts as 0.
    """
    opener = gzip.open if Path(path).suffix == ".gz" else open
    rows = []
    try:
        check_regular_file(path, "star catalogue", max_bytes=None)      # a FIFO would block the reader
    except UserError as exc:
        raise ParameterError(str(exc)) from None
    try:
        with open(path, "rb") as f:      # gzip's reader in one call: ~25 against ~30 ms CPU through gzip.open
            data = f.read()
        catalog = _fixed_layout(gzip.decompress(data) if opener is gzip.open else data)
        if catalog is not None:
            return catalog
        with opener(path, "rt", encoding="ascii", errors="replace") as f:
            for number, line in enumerate(f, start=1):
                fields = line.split("|", 38)     # H0-H37 (the last field read) and the rest
                if len(fields) < 14 or not fields[8].strip() or not fields[5].strip():
                    continue
                rows.append((fields[1].strip(), *_numbers(fields, path, number), _colour(fields)))
    except (OSError, EOFError) as exc:      # gzip raises BadGzipFile (an OSError) or EOFError for a damaged file
        raise ParameterError(f"star catalogue {path} cannot be read ({exc.strerror or type(exc).__name__})") from None
    if not rows:
        raise ParameterError(f"star catalogue {path!r} holds no Hipparcos records")
    hip, *columns, b_v = zip(*rows)
    return StarCatalog(np.array([f"HIP {h}" for h in hip]), *(np.array(column) for column in columns),
                       b_v=np.array(b_v))


def _fixed_layout(data: bytes) -> StarCatalog | None:
    """The catalogue read column by column when every line has the first line's length and its separators up to
    H37 where the first line has them (the layout of ``hip_main.dat``: lines of 450 characters), or None (then
    the records are read line by line).

    The same records and the same numbers as the line-by-line reader: each field is the same characters, read
    as Python's ``float`` reads them (:func:`_decimals`, ``float`` itself for what that does not read). A field
    read that is empty, holds other than printable ASCII (which ``str.strip`` and ``bytes.strip``, or the text
    decoding, would treat differently) or is no number leaves the file to the line-by-line reader (whose error
    then names the line). The bundled 9 933 stars: ~9 ms against the line-by-line reader's ~40 (load 4;
    docs/speed.md).
    """
    width = data.find(b"\n") + 1
    if width <= 1 or len(data) % width or b"\r" in data or data.count(b"\n") != len(data) // width:
        return None
    text = np.frombuffer(data, np.uint8).reshape(-1, width)
    ends = np.flatnonzero(text[0] == 124)[:38]      # the separators after fields H0-H37
    if ends.size < 38 or not (text[:, -1] == 10).all():
        return None
    head = text[:, : ends[-1] + 1]
    if np.count_nonzero(head == 124) != head.shape[0] * ends.size or not (head[:, ends] == 124).all():
        return None
    starts = np.concatenate([[0], ends[:-1] + 1])
    fields = {n: np.ascontiguousarray(text[:, starts[n]: ends[n]]) for n in (1, 5, 8, 9, 11, 12, 13, 37)}
    if any(field.shape[1] == 0 or np.count_nonzero((field < 32) | (field > 126)) for field in fields.values()):
        return None
    # reduced along the rows of the transposed copy: ~5x quicker than along each record's few characters
    blank = {n: (np.ascontiguousarray(field.T) == 32).all(axis=0) for n, field in fields.items()}
    keep = ~(blank[5] | blank[8])
    if not keep.any():
        return None

    def kept(n: int) -> np.ndarray:         # field Hn of the records read, as bytes with the blanks around it
        return fields[n][keep].view(f"S{fields[n].shape[1]}").ravel()

    try:
        columns = [_numbers_or_zero(fields[n][keep], kept(n), blank[n][keep]) for n, _ in _NUMERIC_FIELDS]
    except ValueError:
        return None
    hip = np.char.add("HIP ", np.char.strip(kept(1)).astype(str))
    b_v, read = _decimals(fields[37][keep])
    texts = kept(37)
    for row in np.flatnonzero(~read).tolist():
        b_v[row] = _number_or_nan(texts[row])
    return StarCatalog(hip.astype(f"U{int(np.char.str_len(hip).max())}"), *columns, b_v=b_v)


def _numbers_or_zero(field: np.ndarray, texts: np.ndarray, blank: np.ndarray) -> np.ndarray:
    """Python's ``float`` of each row of ``field`` (its characters ``[n, width]``; ``texts`` the same rows as
    bytes; blanks around a number allowed), 0 where the field is blank; ValueError where one is no number."""
    values, read = _decimals(field)
    values[blank] = 0.0
    for row in np.flatnonzero(~(read | blank)).tolist():
        values[row] = float(texts[row])
    return values


#: the most digits :func:`_decimals` reads (10**15 < 2**53: the digits as an integer are an exact double)
_MAX_DIGITS = 15
#: ``10**k`` for ``k <= _MAX_DIGITS`` as doubles, each exact (integers below 2**53), made from Python's integers: a
#: vectorised ``pow`` need not give exact powers on every machine
_POWERS_OF_TEN = np.array([float(10**k) for k in range(_MAX_DIGITS + 1)])


def _decimals(field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row of ``field`` (ASCII characters ``[n, width]``) read as a plain decimal number where it is one:
    ``(values, read)``, ``read`` False (and the value undefined) where the row is anything else.

    A plain decimal here is blanks, an optional sign, 1 to 15 digits with at most one point among them, blanks
    (``" -15.07"``, ``"+38.30408636"``, ``"5."``, ``".5"``). Its value is the digits as one integer ``m`` over
    ``10**f`` (``f`` the digits after the point), one IEEE division, negated for a minus sign: ``m`` < 10**15
    < 2**53 and ``10**f`` are exact doubles, so the quotient is the decimal's correctly rounded double (Clinger
    1990, the exact case), which is what Python's ``float`` returns (correctly rounded; the sign of a zero
    kept). So the same bits as ``float`` of each row, with NumPy over the column a character at a time (Horner's
    scheme); the rows not read (blank, exponents, underscores, other characters) are left to ``float``.
    """
    n = field.shape[0]
    mantissa = np.zeros(n, np.int64)
    n_digits, after = np.zeros(n, np.int64), np.zeros(n, np.int64)
    bad, begun, ended, point, minus = (np.zeros(n, bool) for _ in range(5))
    for column in np.ascontiguousarray(field.T):
        blank = column == 32
        digit = (column >= 48) & (column <= 57)
        is_point = column == 46
        is_minus = column == 45
        sign = is_minus | (column == 43)
        bad |= ~(blank | digit | is_point | sign)
        bad |= ended & ~blank                       # a character after the trailing blanks
        bad |= sign & begun                         # a sign after the first character
        bad |= is_point & point                     # a second point
        ended |= begun & blank
        begun |= ~blank
        point |= is_point
        minus |= is_minus
        np.multiply(mantissa, 10, out=mantissa, where=digit)
        np.add(mantissa, column - 48, out=mantissa, where=digit, casting="unsafe")
        n_digits += digit
        after += digit & point
    read = ~bad & (n_digits >= 1) & (n_digits <= _MAX_DIGITS)
    values = mantissa.astype(np.float64) / _POWERS_OF_TEN[np.minimum(after, _MAX_DIGITS)]
    np.negative(values, out=values, where=minus)
    return values, read


def _number_or_nan(text: str | bytes) -> float:
    """Python's ``float`` of ``text``, NaN where it is no number."""
    try:
        return float(text)
    except ValueError:
        return float("nan")


def _colour(fields: list[str]) -> float:
    """B - V (Hipparcos field H37) of a record, NaN if blank, absent or not a number [mag]."""
    return _number_or_nan(fields[37]) if len(fields) > 37 else float("nan")


#: the numeric fields read from a hip_main.dat record, by their Hipparcos field numbers H5 (Vmag), H8 (RAdeg),
#: H9 (DEdeg), H12 (pmRA), H13 (pmDE), H11 (Plx): field Hn is the n-th '|'-separated field from 0; a blank
#: parallax or proper motion counts as 0
_NUMERIC_FIELDS = ((5, "Vmag"), (8, "RAdeg"), (9, "DEdeg"), (12, "pmRA"), (13, "pmDE"), (11, "Plx"))


def _numbers(fields: list[str], path: str, number: int) -> list[float]:
    values = []
    for index, name in _NUMERIC_FIELDS:
        text = fields[index].strip()
        try:
            values.append(float(text) if text else 0.0)
        except ValueError:
            raise ParameterError(f"star catalogue {path}: line {number}: field H{index} ({name}) is not a number; "
                                 f"expected the Hipparcos main catalogue (hip_main.dat)") from None
    return values
