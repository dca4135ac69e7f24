"""Size limits checked before any work: window count, sensor pixels, memory per window.

A graph that would list a billion windows or allocate a 65 535 x 65 535 sensor is refused by
``validate`` (and ``run``) with the estimate and the limit named, instead of exhausting memory
later. Blocks state what they will allocate through :meth:`Block.footprint`; the framework
adds it up. A user raises a limit explicitly (``--limit pixels=1e8``, or ``Limits(pixels=...)``
from Python).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from .errors import UserError, clip


@dataclass(frozen=True)
class Footprint:
    """What a block will hold while it runs, estimated from its parameters alone."""

    pixels: int = 0                 # pixels of a sensor the block defines [pixel]
    bytes_per_pixel: float = 0.0    # memory the block holds per sensor pixel [byte]
    bytes_per_window: float = 0.0   # memory the block allocates per window besides [byte]


@dataclass(frozen=True)
class Limits:
    """The limits and their defaults (each named in the message that refuses a graph)."""

    windows: int = 10_000_000           # executor windows in a run
    pixels: int = 1 << 25               # pixels of one sensor (33.5 M: 4x the largest event sensors made)
    window_bytes: float = 16 * 2**30    # memory the blocks allocate for one window [byte]

    @classmethod
    def parse(cls, items: list[str] | tuple[str, ...] = ()) -> "Limits":
        """Limits from ``NAME=VALUE`` strings (``--limit windows=2e7``)."""
        limits = cls()
        names = [f.name for f in fields(cls)]
        for item in items:
            name, sep, text = item.partition("=")
            name = name.strip()
            if not sep or name not in names:
                raise UserError(f"--limit {clip(item, 40)}: expected NAME=VALUE with NAME one of {', '.join(names)}")
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not (math.isfinite(value) and value > 0):
                raise UserError(f"--limit {name}: expected a positive finite number, got {clip(text, 40)}")
            limits = replace(limits, **{name: int(value) if name != "window_bytes" else value})
        return limits


def check(n_windows: int, footprints: dict[str, Footprint], limits: Limits) -> list[tuple[str, str]]:
    """``(where, message)`` for every limit the run would exceed."""
    problems = []
    if n_windows > limits.windows:
        problems.append(("run", f"{n_windows:.4g} windows (duration_s / window_s) is more than the limit of "
                                f"{limits.windows:.4g}; use a longer window_s, or raise the limit with "
                                f"--limit windows={n_windows:.4g}"))
    pixels = max((f.pixels for f in footprints.values()), default=0)
    for name, footprint in footprints.items():
        if footprint.pixels > limits.pixels:
            problems.append((f"block '{name}'", f"a sensor of {footprint.pixels:.4g} pixels is more than the limit "
                                                f"of {limits.pixels:.4g}; raise it with "
                                                f"--limit pixels={footprint.pixels:.4g} if that is meant"))
    total = sum(f.bytes_per_pixel * pixels + f.bytes_per_window for f in footprints.values())
    if total > limits.window_bytes and pixels <= limits.pixels:
        biggest = max(footprints, key=lambda n: footprints[n].bytes_per_pixel * pixels + footprints[n].bytes_per_window)
        problems.append(("run", f"the blocks would hold about {total / 2**30:.3g} GiB per window (most in "
                                f"'{biggest}'), more than the limit of {limits.window_bytes / 2**30:.3g} GiB; "
                                f"raise it with --limit window_bytes={total:.3g} if the machine has the memory"))
    return problems
