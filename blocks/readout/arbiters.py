"""Arbiters: how triggered events leave the pixel array (paper Sec. 2.5, Eq. 22).

Each arbiter consumes :class:`TriggeredEvents` and produces :class:`Events`, the paper's
Eq. 22 record ``e = {t_a, x, y, p, t_t}``: ``t_a`` when the readout recorded the event,
``t_t`` when the pixel triggered it. A graph swaps one for another by its ``type``.

* ``ideal_readout`` records every event when it triggers (``t_a = t_t``, nothing lost).
* ``row_scan_arbiter`` is the paper's row-then-column readout: a row scanner visits the
  rows in turn, ``row_cycles`` clock ticks per row; at its visit it latches the row's
  pending requests, which then leave in column order through the output FIFO and bus.
* ``column_burst_arbiter`` is the group readout of paper Sec. 2.5 ([2, 21]): a scanner
  visits groups of ``group_width_px`` columns in turn and takes all pending events of a
  group in one grant; they share the grant's timestamp.

The scanners of both arbiters are modelled the same way (integer ticks of a clock of
``clock_hz`` started at the run epoch, see :mod:`.clock`):

1. Scanner. Visit ``v`` happens at tick ``v * cycles`` and serves line ``v mod n_lines``
   (a row, or a group of columns). An event that triggers at ``t_t`` on line ``l`` is
   latched at the first visit of ``l`` at or after ``t_t``. A pixel holds one request:
   events of a pixel latched by the same visit beyond the first are lost (the paper's
   "events missed while a pixel's event waits for recording") and counted as dropped.
2. Output FIFO and bus (:mod:`.output_fifo`). Latched events enter a FIFO of
   ``queue_depth`` events in scan order (row scan: column order; burst: column then
   row); a bus carries one event every ``clock_hz / bus_throughput_eps`` ticks.
   An event arriving at a full FIFO is dropped and counted (``Events.n_dropped``).
3. Timestamp. Row scan: ``t_a`` is the tick the bus takes the event. Burst: ``t_a`` is
   the tick the bus takes the first event of the group's grant, shared by the group.

Conservation is exact: every triggered event is recorded, dropped, or still pending in
the block's ``state`` at the end of a window (carried to the next). In the run's last
window (known from ``setup(RunInfo)``) pending events are read out after the end of the
run (``flush_at_end``) or counted as dropped, so that over a run
``triggered = recorded + dropped``. Events are emitted sorted by ``t_a``; an event is
emitted in the window that contains its ``t_a``, so the output does not depend on the
window length.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field, model_validator

from evsda.blocks.ports import Events, FocalPlane, TriggeredEvents
from evsda.graph import Block, BlockParams, Input, Output, Window

from .clock import MAX_CLOCK_HZ, ceil_tick, floor_div, floor_mod, tick_ns
from .output_fifo import NEVER, run_fifo

EVENT_FIELDS = ("t_ns", "x", "y", "p", "cause")
_DTYPES = {"t_ns": np.int64, "t_a_ns": np.int64, "x": np.uint16, "y": np.uint16, "p": np.int8, "cause": np.uint8}


def _empty(fields) -> dict[str, np.ndarray]:
    return {name: np.zeros(0, _DTYPES[name]) for name in fields}


def _take(arrays: dict[str, np.ndarray], index) -> dict[str, np.ndarray]:
    return {name: value[index] for name, value in arrays.items()}


def _concat(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {name: np.concatenate([a[name], b[name]]) for name in a}


def _events(focal_plane: FocalPlane, rec: dict[str, np.ndarray], n_dropped: int) -> Events:
    return Events(focal_plane, rec["t_ns"], rec["t_a_ns"], rec["x"], rec["y"], rec["p"], rec["cause"],
                  n_dropped=int(n_dropped))


class IdealReadout(Block):
    """Readout without latency or loss: every triggered event is recorded when it triggers.

    The reference against which the scanning arbiters' delays and losses are measured:
    ``t_a = t_t`` for every event of paper Eq. 22, and ``n_dropped = 0``.
    """

    type_name = "ideal_readout"

    class Params(BlockParams):
        pass

    inputs = {"events": Input(TriggeredEvents, "events as the pixels trigger them")}
    outputs = {"events": Output(Events, "events as recorded (t_a = t_t), sorted by readout time")}

    def step(self, window: Window, events: TriggeredEvents) -> dict:
        return {"events": Events(events.focal_plane, events.t_ns.astype(np.int64), events.t_ns.astype(np.int64),
                                 events.x.astype(np.uint16), events.y.astype(np.uint16),
                                 events.p.astype(np.int8), events.cause.astype(np.uint8), n_dropped=0)}


class ScanParams(BlockParams):
    """Clock, bus and FIFO of a scanning readout."""

    clock_hz: float = Field(100e6, gt=0, le=MAX_CLOCK_HZ,
                            description="Arbiter clock frequency, a whole number of hertz [Hz]")
    bus_throughput_eps: float = Field(50e6, gt=0,
                                      description="Events the output bus carries per second; the clock "
                                                  "frequency must be a whole multiple of it [event s^-1]")
    queue_depth: int = Field(64, ge=1, description="Events the output FIFO holds while they wait for the bus [event]")
    flush_at_end: bool = Field(True, description="In the run's last window, read out the events still pending "
                                                 "(their readout times fall after the run); if false they are "
                                                 "counted as dropped [-]")

    @model_validator(mode="after")
    def _clock_divides(self):
        if self.clock_hz != round(self.clock_hz):
            raise ValueError(f"clock_hz must be a whole number of hertz, got {self.clock_hz}")
        ratio = self.clock_hz / self.bus_throughput_eps
        cycles = max(1, round(ratio))
        if ratio < 1 - 1e-9 or abs(ratio - cycles) > 1e-9 * ratio:
            near = self.clock_hz / max(1, math.floor(ratio))
            raise ValueError(f"bus_throughput_eps must be clock_hz / N for a whole N >= 1 (one event per N "
                             f"clock ticks); got {self.bus_throughput_eps:g} with clock_hz {self.clock_hz:g}, "
                             f"e.g. use {near:g}")
        return self


class _ScanningArbiter(Block):
    """Common engine of the scanning arbiters (see the module docstring)."""

    Params = ScanParams
    inputs = {"events": Input(TriggeredEvents, "events as the pixels trigger them")}
    outputs = {"events": Output(Events, "events as recorded {t_a, x, y, p, t_t} (Eq. 22), sorted by readout time")}
    state = ("pending", "held", "fifo_waiting", "fifo_last_grant")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.clock = int(round(self.params.clock_hz))
        self.bus_cycles = int(round(self.params.clock_hz / self.params.bus_throughput_eps))
        self.pending = _empty(EVENT_FIELDS)                # triggered, not yet in the FIFO
        self.held = _empty((*EVENT_FIELDS, "t_a_ns"))      # accepted, recorded after the current window
        self.fifo_waiting = np.zeros(0, np.int64)          # grant ticks of accepted events not yet on the bus
        self.fifo_last_grant = int(NEVER)

    # -- what differs between arbiters ---------------------------------------------------------
    def _latch(self, k_t: np.ndarray, x: np.ndarray, y: np.ndarray, fp: FocalPlane):
        """``(visit, tick, order)``: the scanner visit that latches each event, its tick, and the
        event's place within that visit (``0 <= order < self._span(fp)``)."""
        raise NotImplementedError

    def _span(self, fp: FocalPlane) -> int:
        raise NotImplementedError

    def _timestamps(self, visit: np.ndarray, grant: np.ndarray) -> np.ndarray:
        """Readout ticks of accepted events (in FIFO order) from their visits and bus grants."""
        return grant

    # -- the engine -------------------------------------------------------------------------------
    @property
    def n_pending(self) -> int:
        """Events triggered but neither recorded nor dropped yet."""
        return int(self.pending["t_ns"].size + self.held["t_ns"].size)

    def step(self, window: Window, events: TriggeredEvents) -> dict:
        fp = events.focal_plane
        new = {name: np.asarray(getattr(events, name), _DTYPES[name]) for name in EVENT_FIELDS}
        pending = _concat(self.pending, new) if self.pending["t_ns"].size else new
        last = self.run_info is not None and window.stop_ns >= self.run.duration_ns
        flush = last and self.params.flush_at_end
        horizon = None if flush else int(ceil_tick(window.stop_ns, self.clock))   # first tick not in this window

        visit, latch, order = self._latch(ceil_tick(pending["t_ns"], self.clock), pending["x"], pending["y"], fp)
        key = visit * np.int64(self._span(fp)) + order
        sort = np.argsort(key, kind="stable")        # scan order; stable keeps a pixel's earliest request first
        latch = latch[sort]
        ready = latch.size if horizon is None else int(np.searchsorted(latch, horizon, side="left"))
        key = key[sort[:ready]]
        first = np.ones(ready, dtype=bool)           # one request per pixel per visit
        np.not_equal(key[1:], key[:-1], out=first[1:])
        n_busy = int(ready - np.count_nonzero(first))

        fifo = run_fifo(latch[:ready] if n_busy == 0 else latch[:ready][first], self.bus_cycles,
                        self.params.queue_depth, self.fifo_waiting, self.fifo_last_grant)
        n_full = int(fifo.accepted.size - np.count_nonzero(fifo.accepted))
        into, grant = sort[:ready], fifo.grant
        if n_busy or n_full:
            into = into[np.flatnonzero(first)[fifo.accepted]]
            grant = grant[fifo.accepted]
        accepted = _take(pending, into)
        accepted["t_a_ns"] = tick_ns(self._timestamps(visit[into], grant), self.clock)
        n_dropped = n_busy + n_full
        pending = _take(pending, sort[ready:])

        # held events were recorded before these
        recorded = _concat(self.held, accepted) if self.held["t_ns"].size else accepted
        emit = recorded["t_a_ns"].size if horizon is None else int(
            np.searchsorted(recorded["t_a_ns"], window.stop_ns, side="left"))
        self.held = _take(recorded, slice(emit, None))
        self.pending = pending
        waiting = np.concatenate([self.fifo_waiting, grant])
        self.fifo_waiting = np.sort(waiting[waiting >= horizon]) if horizon is not None else np.zeros(0, np.int64)
        self.fifo_last_grant = int(fifo.last_grant)
        if last and not flush:                       # pending at the end of the run: never recorded
            n_dropped += self.n_pending
            self.pending, self.held = _empty(EVENT_FIELDS), _empty((*EVENT_FIELDS, "t_a_ns"))
        return {"events": _events(fp, _take(recorded, slice(0, emit)), n_dropped)}


class RowScanArbiter(_ScanningArbiter):
    """Row-then-column scanning readout (paper Sec. 2.5, Eq. 22).

    A row scanner visits row ``v mod H`` at tick ``v * row_cycles`` of a ``clock_hz``
    clock; it latches the row's pending requests, which leave in column order through a
    FIFO of ``queue_depth`` events and a bus of ``bus_throughput_eps``; ``t_a`` is the
    tick the bus takes the event. Example: at 100 MHz with ``row_cycles=1`` and a bus of
    50 Mevent/s, an event triggered at t = 0 in row 3 is latched at 30 ns and recorded at
    30 ns if the bus is free; the next event of the same row follows 20 ns later.
    """

    type_name = "row_scan_arbiter"

    class Params(ScanParams):
        row_cycles: int = Field(1, ge=1, description="Clock ticks the scanner spends on each row [1]")

    def _span(self, fp):
        return fp.width_px

    def _latch(self, k_t, x, y, fp):
        c = self.params.row_cycles
        v0 = k_t if c == 1 else -floor_div(-k_t, c)         # first visit at or after the trigger
        visit = v0 + floor_mod(y.astype(np.int64) - v0, fp.height_px)
        return visit, visit if c == 1 else visit * c, x.astype(np.int64)


class ColumnBurstArbiter(_ScanningArbiter):
    """Column-group (burst) readout: all pending events of a group of columns in one grant.

    A scanner visits group ``v mod G`` (``G = ceil(W / group_width_px)``) at tick
    ``v * group_cycles``; every pending event of the group is latched, enters the FIFO in
    column-then-row order, and is stamped with the tick the bus takes the group's first
    event (paper Sec. 2.5: "addresses an entire column as a group" [2, 21]).
    """

    type_name = "column_burst_arbiter"

    class Params(ScanParams):
        group_width_px: int = Field(1, ge=1, description="Columns read together in one grant [pixel]")
        group_cycles: int = Field(1, ge=1, description="Clock ticks the scanner spends on each group [1]")

    def _span(self, fp):
        return self.params.group_width_px * fp.height_px

    def _latch(self, k_t, x, y, fp):
        c, gw = self.params.group_cycles, self.params.group_width_px
        n_groups = -(-fp.width_px // gw)
        x = x.astype(np.int64)
        v0 = -floor_div(-k_t, c)
        column_group = floor_div(x, gw)
        visit = v0 + floor_mod(column_group - v0, n_groups)
        return visit, visit * c, (x - column_group * gw) * fp.height_px + y.astype(np.int64)

    def _timestamps(self, visit, grant):
        # a group's events share one latch tick, so a grant never straddles two windows
        starts = np.ones(visit.size, dtype=bool)
        starts[1:] = visit[1:] != visit[:-1]
        first = np.maximum.accumulate(np.where(starts, np.arange(visit.size), 0))
        return grant[first]
