"""How many cores a pipelined run is getting: its own CPU time against the wall over the last fraction of a second.

A pipelined run (:mod:`.executor_pipeline`) pays where its threads get a second core. Where they take turns on about
one, it pays only its costs: the interpreter lock handed over between its threads thousands of times a pass, each a
futex wake-up (48-66 us of CPU across the cores against 17.5 us on one, here), and on the tracked pass 5-8 % more CPU
than one step at a time for 1.03 against 0.99 cores (one other process spinning, docs/speed.md). :class:`CoreShare`
reads what the run gets (the CPU time of all its threads, ``time.process_time``, against ``time.perf_counter``), and
:class:`SoloPolicy` turns that into a choice: pipelined windows, or one step at a time on the thread that records
them, back to the pipeline once one step at a time reads a second core (the blocks' parallel loops find one), or
reads less than the pipeline did, or after a while. A run that may use one core only (``EVSDA_THREADS=1``, an
affinity mask of one core) goes one step at a time throughout.

``EVSDA_PIPELINE_ADAPT=on`` turns this on. With one core busy it made the tracked pass quicker in 5 of 5 pairs
(0.95-0.99, CPU -2 to -5 %, a third fewer voluntary switches), with both cores free it stayed pipelined; on a host
busy with several processes, where a pipelined run's second thread earns it a share of the other core (0.70 against
0.54 cores), it keeps the pipeline. It is off by default (the lead's call): where the host changed within a run it
lost a round, 6.23 against 5.36 s (docs/speed.md, twentieth session).
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Callable

from .errors import UserError

#: wall seconds over which the cores a run gets are read
GAUGE_SPAN_S = 0.4
#: pipelined, at least this many cores but fewer than :data:`SOLO_BELOW_CORES` over :data:`GAUGE_SPAN_S`: the run's
#: threads take turns on about one core; go one step at a time (the tracked pass reads 1.5-1.8 cores pipelined with
#: two free, 0.95-1.05 with one, 0.4-0.85 on a host busy with several other processes, where each runnable thread of
#: the run earns it a share of the other core too and the pipeline stays)
SOLO_ABOVE_CORES = 0.85
SOLO_BELOW_CORES = 1.25
#: one step at a time, at least this many cores over :data:`GAUGE_SPAN_S`: the blocks' parallel loops
#: (:func:`.threads.parallel_map`) found a second core; pipeline again (the tracked pass one step at a time reads
#: 1.3-1.6 cores with two free, 0.95-1.0 with one)
PIPELINE_ABOVE_CORES = 1.2
#: one step at a time, wall seconds after which the pipeline is tried again all the same (a graph with no parallel
#: loop cannot read above one core one step at a time)
SOLO_S = 3.0


def adapt_enabled() -> bool:
    """Whether a pipelined run goes one step at a time while the host leaves it one core: ``EVSDA_PIPELINE_ADAPT``
    (``off``, the default, or ``on``)."""
    text = os.environ.get("EVSDA_PIPELINE_ADAPT", "off").strip().lower()
    if text not in ("on", "off"):
        raise UserError(f"EVSDA_PIPELINE_ADAPT must be off (the default) or on, got {text!r}")
    return text == "on"


class CoreShare:
    """The cores a process got over the last ``span_s`` wall seconds or a little more: CPU seconds of all its
    threads per wall second, read at the marks it is given (the ends of steps)."""

    def __init__(self, span_s: float = GAUGE_SPAN_S, wall: Callable[[], float] = time.perf_counter,
                 cpu: Callable[[], float] = time.process_time):
        self.span_s, self.wall, self.cpu = span_s, wall, cpu
        self.marks: deque[tuple[float, float]] = deque()

    def mark(self) -> float | None:
        """Note the clocks now; the cores since the newest mark at least ``span_s`` old, or None if there is none."""
        now = self.wall(), self.cpu()
        self.marks.append(now)
        while len(self.marks) > 2 and now[0] - self.marks[1][0] >= self.span_s:
            self.marks.popleft()                   # the mark after it is old enough to start the span
        wall0, cpu0 = self.marks[0]
        if now[0] - wall0 < self.span_s:
            return None
        return (now[1] - cpu0) / (now[0] - wall0)

    def restart(self) -> None:
        """Read from now on only (a new way of running is read on its own)."""
        last = self.marks[-1] if self.marks else (self.wall(), self.cpu())
        self.marks.clear()
        self.marks.append(last)


class SoloPolicy:
    """Pipelined or one step at a time, from the cores the run gets over :data:`GAUGE_SPAN_S`: one step at a time
    when the pipeline reads about one core (from :data:`SOLO_ABOVE_CORES` up to :data:`SOLO_BELOW_CORES`), until one
    step at a time reads :data:`PIPELINE_ABOVE_CORES` or more (a second core is free) or for :data:`SOLO_S`; then
    pipelined again, to read the host anew. One step at a time reading under :data:`SOLO_ABOVE_CORES` means the
    pipeline's second thread was earning the run a share of the other core: pipelined again, and for :data:`SOLO_S`
    at least. Each way of running is read on its own span."""

    def __init__(self, share: CoreShare | None = None, low: float = SOLO_ABOVE_CORES, below: float = SOLO_BELOW_CORES,
                 above: float = PIPELINE_ABOVE_CORES, solo_s: float = SOLO_S):
        self.share = share or CoreShare()
        self.low, self.below, self.above, self.solo_s = low, below, above, solo_s
        self.solo = False
        self.until = 0.0               # one step at a time: when to try the pipeline; pipelined: not solo before

    def update(self) -> bool:
        """Read the cores now (a step has ended); whether the run goes one step at a time from here."""
        cores = self.share.mark()
        now = self.share.marks[-1][0]
        if self.solo:
            lost = cores is not None and cores < self.low
            if lost or now >= self.until or (cores is not None and cores >= self.above):
                self.solo, self.until = False, now + self.solo_s if lost else now
                self.share.restart()
        elif now >= self.until and cores is not None and self.low <= cores < self.below:
            self.solo, self.until = True, now + self.solo_s
            self.share.restart()
        return self.solo
