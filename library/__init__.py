"""Bundled data: graph files, sensor and telescope presets, TLEs, star catalogue."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

PREFIX = "library:"


def path(relative: str) -> Path:
    """Filesystem path of a bundled file, e.g. ``path("tle/iss.tle")``."""
    return Path(str(files(__name__).joinpath(relative)))


def resolve(reference: str, base: Path | None = None) -> Path:
    """Resolve ``library:tle/iss.tle`` to the bundled file, or a plain path against ``base``."""
    if reference.startswith(PREFIX):
        return path(reference[len(PREFIX):])
    candidate = Path(reference).expanduser()
    if not candidate.is_absolute() and base is not None:
        candidate = base / candidate
    return candidate
