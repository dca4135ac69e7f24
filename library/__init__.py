"""Bundled data: graph files, sensor and telescope presets, TLEs, star catalogue."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

PREFIX = "library:"


def path(relative: str) -> Path:
    """Filesystem path of a bundled file, e.g. ``path("tle/iss.tle")``."""
    return Path(str(files(__name__).joinpath(relative)))


def resolve(reference: str, base: Path | None = None) -> Path:
    """Resolve ``library:tle/iss.tle`` to the bundled file, or a plain path against ``base``.

    A ``library:`` reference cannot leave the bundled library (``library:../x`` is refused).
    """
    if reference.startswith(PREFIX):
        relative = reference[len(PREFIX):]
        root = Path(str(files(__name__))).resolve()
        target = path(relative)
        if Path(relative).is_absolute() or not target.resolve().is_relative_to(root):
            from evsda.graph.errors import UserError

            raise UserError(f"{reference[:80]}: a library: path must name a file inside the bundled library")
        return target
    candidate = Path(reference).expanduser()
    if not candidate.is_absolute() and base is not None:
        candidate = base / candidate
    return candidate
