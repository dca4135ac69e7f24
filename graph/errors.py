"""Errors a user can act on.

Every mistake in a graph file, a parameter or an input is a :class:`UserError`:
the command line prints its message (one clear line per problem, no traceback)
and exits with status 2. Anything else is a bug in evsda and exits with 1.
"""

from __future__ import annotations

from dataclasses import dataclass


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
