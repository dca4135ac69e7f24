"""Sub-commands of ``evsda`` contributed by other packages.

The framework's own commands (``run``, ``validate``, ``blocks``, ``schema``) live in
:mod:`evsda.graph.cli`. Commands that need physics or file formats (``render``,
``export``, ``plot-pass``...) are contributed through the entry-point group
``evsda.commands``: each entry point names a :class:`Command` instance or a list
of them.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from importlib.metadata import entry_points

ENTRY_POINT_GROUP = "evsda.commands"


class Command:
    """One ``evsda NAME ...`` sub-command."""

    name: str = ""
    help: str = ""

    def configure(self, parser: argparse.ArgumentParser) -> None:
        """Add this command's arguments to ``parser``."""

    def run(self, args: argparse.Namespace) -> int:
        """Do the work; return the exit status (raise UserError for the user's mistakes)."""
        raise NotImplementedError


def add_figure_options(parser: argparse.ArgumentParser, dpi: float = 100.0, aliases: tuple[str, ...] = ()) -> None:
    """The output options every plot command shares: ``-o/--output FILE`` (format from the extension),
    ``--dpi`` and ``--overwrite``. Check them with :func:`evsda.graph.files.check_figure_output` before any
    work and save with :func:`evsda.graph.files.save_figure`."""
    parser.add_argument("-o", "--output", *aliases, dest="output", required=True,
                        help="figure file to write; the extension gives the format (png, pdf, svg ...)"
                             + (f"; {', '.join(aliases)} is its old name" if aliases else ""))
    parser.add_argument("--dpi", type=float, default=dpi, help=f"resolution [dots per inch] (default {dpi:g})")
    parser.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it exists")


def contributed_commands() -> list[Command]:
    """Every command advertised in the ``evsda.commands`` entry-point group."""
    commands: list[Command] = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        obj = ep.load()
        items = obj if isinstance(obj, Iterable) else [obj]
        commands.extend(items)
    return sorted(commands, key=lambda c: c.name)


def check_seconds(option: str, value: float | None, bound_s: float = 1e9) -> None:
    """Refuse a time option (``--start-s``, ``--time-s`` ...) that is not a finite number of seconds within
    ``bound_s`` of the run's start (NaN or 1e300 would overflow the nanosecond clock)."""
    from .errors import UserError

    if value is not None and not abs(value) < bound_s:
        raise UserError(f"{option} must be a finite time in seconds (within {bound_s:g} s), got {value}")
