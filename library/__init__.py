"""Bundled data: graph files, sensor and telescope presets, TLEs, star catalogue."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

PREFIX = "library:"


#: sub-folders of the library that are packages of their own (``examples/``: the repository's example
#: scenes, installed inside the library and mapped to the examples/ folder of a source checkout)
SUBPACKAGES = {"examples": f"{__name__}.examples"}


def _root(relative: str) -> tuple[Path, str]:
    """The folder holding ``relative`` and its path inside it."""
    first, sep, rest = relative.partition("/")
    if sep and first in SUBPACKAGES:
        return Path(str(files(SUBPACKAGES[first]))), rest
    return Path(str(files(__name__))), relative


def path(relative: str) -> Path:
    """Filesystem path of a bundled file, e.g. ``path("tle/iss.tle")`` or ``path("examples/iss_pass.yaml")``."""
    root, rest = _root(relative)
    return root / rest


def resolve(reference: str, base: Path | None = None) -> Path:
    """Resolve ``library:tle/iss.tle`` to the bundled file, or a plain path against ``base``.

    A ``library:`` reference cannot leave the bundled library (``library:../x`` is refused).
    """
    if reference.startswith(PREFIX):
        relative = reference[len(PREFIX):]
        root = _root(relative)[0].resolve()
        target = path(relative)
        if Path(relative).is_absolute() or not target.resolve().is_relative_to(root):
            from evsda.graph.errors import UserError

            raise UserError(f"{reference[:80]}: a library: path must name a file inside the bundled library")
        return target
    candidate = Path(reference).expanduser()
    if not candidate.is_absolute() and base is not None:
        candidate = base / candidate
    return candidate
