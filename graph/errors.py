"""Errors a user can act on.

Every mistake in a graph file, a parameter or an input is a :class:`UserError`:
the command line prints its message (one clear line per problem, no traceback)
and exits with status 2. Anything else is a bug in evsda and exits with 1.
"""

from __future__ import annotations

import difflib
import reprlib
from dataclasses import dataclass
from typing import Any

_REPR = reprlib.Repr()
for _name, _limit in (("maxlevel", 2), ("maxtuple", 4), ("maxlist", 4), ("maxarray", 4), ("maxdict", 3),
                      ("maxset", 4), ("maxfrozenset", 4), ("maxdeque", 4), ("maxstring", 40), ("maxlong", 40),
                      ("maxother", 40)):
    setattr(_REPR, _name, _limit)


def clip(text: str, limit: int = 80) -> str:
    """``text`` on one line, control characters escaped, cut to ``limit`` characters."""
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in " ".join(str(text).split()))
    return text if len(text) <= limit else text[: limit - 1] + "…"


def suggest(name: str, choices) -> str:
    """``; did you mean 'a', 'b'?`` naming up to three of ``choices`` close to ``name``, or nothing."""
    close = difflib.get_close_matches(name, list(choices), n=3)
    return f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""


def excerpt(value: Any, limit: int = 60) -> str:
    """A short, printable repr of ``value`` for error messages: bounded however large or nested the
    value is (``reprlib`` stops early), control characters escaped, cut to ``limit`` characters."""
    return clip(_REPR.repr(value), limit)


class UserError(Exception):
    """A problem the user can fix: bad input, bad parameter, impossible scene."""


class ParameterError(UserError):
    """A block parameter is missing, mistyped or non-physical."""


class SceneError(UserError):
    """The scene cannot be simulated as described (e.g. the target never enters the field of view)."""


class InputError(UserError):
    """A block received an input it cannot use (wrong port type, wrong shape, wrong units)."""


class StoreError(UserError):
    """A run store cannot be created, resumed or read as asked."""


class Interrupted(KeyboardInterrupt):
    """A run stopped by SIGINT (Ctrl-C) or SIGTERM; what it committed is kept and ``--resume`` continues it."""

    def __init__(self, signal_name: str = "SIGINT", detail: str = ""):
        super().__init__(signal_name, detail)
        self.signal_name = signal_name
        self.detail = detail

    def __str__(self) -> str:
        return self.detail or "interrupted"


@dataclass(frozen=True)
class Problem:
    """One problem found while checking a graph: where it is and what was expected."""

    file: str
    where: str
    message: str

    def __str__(self) -> str:
        where = f" {self.where}:" if self.where else ""
        return f"{self.file}:{where} {self.message}"


class GraphError(UserError):
    """All problems found in a graph file, reported together."""

    def __init__(self, problems: list[Problem]):
        self.problems = list(problems)
        super().__init__("\n".join(str(p) for p in self.problems))
