"""Pipelined windows: blocks of different windows step at the same time, in threads.

A block's step over window ``k`` needs only its own state after window ``k - 1`` and its inputs at ``k``,
that is the steps of the blocks upstream of it at ``k``. Any order of steps that keeps these dependencies
gives every block the same inputs in the same order as the serial loop (window after window, blocks in
topological order), so a run records the same bytes whichever steps overlap; only the wall time changes.
The optics of window ``k + 1``, say, run while the pixels of window ``k`` do. Threads pay where the steps'
heavy parts release the GIL (compiled loops declared ``nogil``, FFTs, compression).

Rules:

* a block that feeds others steps over window ``k`` once one of them has finished window ``k - 1 -``
  :data:`WINDOWS_AHEAD` (or is on its first window, which carries its one-time set-up), and a block that feeds
  none once every block has (1: the optics of ``k + 1`` beside the pixels of ``k``; the cheap blocks upstream of
  the optics, the sources, are then done with ``k + 2`` before the pixels end ``k``, off the optics' chain); no
  step runs more than ``1 +`` :data:`WINDOWS_AHEAD` windows beyond the oldest unrecorded window (each in flight
  holds its values in memory); at the run's start both limits are :data:`SETUP_WINDOWS_AHEAD` windows further,
  one window fewer for each window recorded: the first steps carry the blocks' one-time set-ups (the pixels'
  first step, which builds every pixel's state from its first input, takes ~7 optics windows' wall on the tracked
  pass), and the optics' chain goes on beside it and while the pixels catch up (~0.65 optics windows' wall each)
  instead of waiting;
* the thread that finishes a step starts the steps this makes ready, itself running the same block's next step
  if ready, else the one furthest upstream (the next optics window, say, goes on at once on the thread that
  ended the previous one, or the pixels' step it waited for): no round trip through a scheduling thread, each of
  whose wake-ups waits for the interpreter lock;
* windows are handed back in order, to the calling thread, which records them (one thread writes the store); it is
  woken when the oldest window is complete or nothing runs, not at every step's end;
* a commit is a barrier: before the first step of window ``k + 1`` starts, the pipeline asks whether the
  blocks' state after window ``k`` is to be committed; if so, nothing of ``k + 1`` starts until ``k`` is handed
  back and its commit made, so every block's state is then its state after ``k``, as in the serial loop;
* an error: no step that comes after the failing one in the serial order (window, then topological order)
  starts; the steps before it finish and their windows are handed back; then the error the serial loop would
  have met first is raised, the same exception. An interrupt waits for the running steps (a fraction of a
  window each), then propagates.

The blocks' contract makes this safe: a block draws only from its own generator, changes only its own
state, and neither changes a value after returning it nor the values it is given (:mod:`.block`).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from .block import RunInfo, Window
from .errors import UserError
from .threads import running_step

#: windows a block runs ahead of the blocks it feeds (1: the optics of k + 1 beside the pixels of k)
WINDOWS_AHEAD = 1
#: windows a block may run further ahead at the run's start, one fewer for each window recorded: the first steps
#: carry the blocks' one-time set-ups (the pixels' state from their first input), during which, and while the
#: pixels catch up, the optics' chain goes on
SETUP_WINDOWS_AHEAD = 16

Values = dict[tuple[str, str], Any]


def pipeline_enabled(choice: bool | None = None) -> bool:
    """Whether windows are pipelined: ``choice`` if given, else ``EVSDA_PIPELINE`` (``1``, the default, or ``0``)."""
    if choice is not None:
        return bool(choice)
    text = os.environ.get("EVSDA_PIPELINE", "1").strip()
    if text not in ("0", "1"):
        raise UserError(f"EVSDA_PIPELINE must be 1 (pipeline windows, the default) or 0 (one step at a time), "
                        f"got {text!r}")
    return text == "1"


class Pipeline:
    """Steps the blocks ``order`` (topological) over windows, overlapping windows as dependencies allow.

    ``upstream[name]``: the blocks of ``order`` whose outputs ``name`` takes; ``gather(name, values)``: the
    inputs of ``name`` from one window's values; ``step(name, window, inputs)``: run one step, returning the
    block's outputs (called in a worker thread).
    """

    def __init__(self, order: list[str], upstream: dict[str, set[str]],
                 gather: Callable[[str, Values], dict[str, Any]],
                 step: Callable[[str, Window, dict[str, Any]], dict[str, Any]]):
        self.order = list(order)
        self.position = {name: i for i, name in enumerate(self.order)}
        self.upstream = {name: [u for u in upstream[name] if u in self.position] for name in self.order}
        self.downstream = {name: [d for d in self.order if name in self.upstream[d]] for name in self.order}
        self.gather, self.step = gather, step

    def windows(self, run: RunInfo, start: int, stop: int, loaded: Callable[[int], Values],
                commit_due: Callable[[int], bool]) -> Iterator[tuple[Window, list[tuple[str, dict]], bool]]:
        """``(window, [(block, outputs)] in topological order, commit)`` for windows ``start .. stop - 1``, in
        order. ``loaded(k)``: window ``k``'s values that no block here computes (read in order, once);
        ``commit_due(k)``: whether to commit after window ``k``, asked once per window (``commit``)."""
        with ThreadPoolExecutor(max(1, len(self.order)), thread_name_prefix="evsda-step") as pool:
            state = _State(self, run, start, stop, loaded, commit_due, pool)
            try:
                with state.lock:
                    state.launch()
                while state.released < stop:
                    yield state.next_window()
                    with state.lock:
                        state.commits.pop(state.released, None)
                        state.released += 1            # recorded (and committed): the steps it held back may start
                        state.launch()
            finally:
                with state.lock:
                    state.stopped = True           # start nothing more; the pool waits for the running steps


class _State:
    """The book-keeping of one :meth:`Pipeline.windows` call; every field is guarded by :attr:`lock`."""

    def __init__(self, pipeline: Pipeline, run: RunInfo, start: int, stop: int,
                 loaded: Callable[[int], Values], commit_due: Callable[[int], bool], pool: ThreadPoolExecutor):
        self.p, self.run, self.start, self.stop, self.pool = pipeline, run, start, stop, pool
        self.loaded, self.commit_due = loaded, commit_due
        self.lock = threading.Condition()
        self.values: dict[int, Values] = {}                         # window -> {(block, port): value}
        self.produced: dict[int, dict[int, tuple[str, dict]]] = {}  # window -> {position: (block, outputs)}
        self.done = {name: start - 1 for name in pipeline.order}    # the last window each block finished
        self.busy: set[str] = set()
        self.running = 0                                            # steps started and not yet harvested
        self.commits: dict[int, bool] = {}                          # commit decisions, by window
        self.failure: tuple[tuple[int, int], BaseException] | None = None
        self.crash: BaseException | None = None                     # an error of this module's own (a bug)
        self.created = start - 1                                    # the last window whose values exist
        self.next_out = start                                       # the next window to hand back
        self.released = start                                       # windows before it are recorded
        self.stopped = False

    def next_window(self) -> tuple[Window, list[tuple[str, dict]], bool]:
        """The oldest window once complete, with its commit decision (its values are dropped); or the error."""
        with self.lock:
            while not self._oldest_complete():
                if self.crash is not None:
                    raise self.crash
                if not self.running:
                    if self.failure is not None:
                        raise self.failure[1]
                    raise RuntimeError("pipeline stalled with nothing running (a bug in evsda)")
                self.lock.wait()
            k = self.next_out
            commit = self.commits.pop(k) if k in self.commits else self.commit_due(k)
            self.commits[k] = commit                   # the barrier holds until the window is released
            entries = self.produced.pop(k)
            del self.values[k]
            self.next_out += 1
        return self.run.window(k), [entries[i] for i in sorted(entries)], commit

    def _oldest_complete(self) -> bool:
        """Every block has finished the oldest window not yet handed back."""
        return all(done >= self.next_out for done in self.done.values())

    def _may_start(self, k: int) -> bool:
        """Window ``k`` may start: no window before it is still to be committed (asked in order, once each)."""
        for j in range(max(self.released, self.start), k):
            if j not in self.commits:
                self.commits[j] = self.commit_due(j)
            if self.commits[j]:
                return False
        return True

    def _horizon(self, name: str) -> int:
        """The last window ``name`` may step over now."""
        fed = self.p.downstream[name]
        # a block's first step carries its one-time set-up (Numba's cache loads, its state from its first input),
        # several later steps' worth: the blocks feeding it go on one window further meanwhile, and
        # SETUP_WINDOWS_AHEAD further at the start, one fewer for each window recorded
        behind = max(max(self.done[d], self.start) for d in fed) if fed else min(self.done.values())
        ahead = 1 + WINDOWS_AHEAD + max(0, SETUP_WINDOWS_AHEAD - (self.released - self.start))
        return min(behind + ahead, self.released + ahead, self.stop - 1)

    def launch(self, keep: str | None = None) -> tuple[str, int, dict] | None:
        """Start every step whose dependencies are met, on the pool; but if ``keep`` (the block whose step the
        calling thread just finished) is given, return one to run on the calling thread: that block's next one if
        ready (a chain of windows goes on where it is), else the one furthest upstream. Called with :attr:`lock`
        held."""
        if self.stopped or self.crash is not None:
            return None
        ready = []
        for name in self.p.order:
            k = self.done[name] + 1
            if name in self.busy or k > self._horizon(name):
                continue
            if self.failure is not None and (k, self.p.position[name]) >= self.failure[0]:
                continue
            if all(self.done[u] >= k for u in self.p.upstream[name]) and self._may_start(k):
                ready.append((name, k))
        if keep is not None:
            ready.sort(key=lambda task: task[0] != keep)          # stable: then in topological order
        kept = None
        for name, k in ready:
            while self.created < k:                                  # each window's loaded values, in order
                self.created += 1
                self.values[self.created] = dict(self.loaded(self.created))
                self.produced[self.created] = {}
            task = (name, k, self.p.gather(name, self.values[k]))
            self.busy.add(name)
            self.running += 1
            if keep is not None and kept is None:
                kept = task
            else:
                self.pool.submit(self._work, task)
        return kept

    def _work(self, task: tuple[str, int, dict] | None) -> None:
        """Run ``task``, then whatever it makes ready that this thread keeps, until nothing is left to keep."""
        try:
            while task is not None:
                name, k, inputs = task
                outputs, error = None, None
                try:
                    with running_step():
                        outputs = self.p.step(name, self.run.window(k), inputs)
                except BaseException as exc:           # noqa: BLE001 -- raised by the calling thread, in order
                    error = exc
                del inputs
                with self.lock:
                    self._harvest(name, k, outputs, error)
                    task = self.launch(keep=name)
                    if not self.running or self._oldest_complete():
                        self.lock.notify_all()         # the calling thread waits for nothing else (next_window)
        except BaseException as exc:                   # noqa: BLE001 -- a bug here: the calling thread raises it
            with self.lock:
                self.crash = exc
                self.lock.notify_all()

    def _harvest(self, name: str, k: int, outputs: dict | None, error: BaseException | None) -> None:
        """Take a finished step's outputs, or note its error if it comes first in the serial order."""
        self.busy.discard(name)
        self.running -= 1
        if error is not None:
            key = (k, self.p.position[name])
            if self.failure is None or key < self.failure[0]:
                self.failure = (key, error)
            return
        self.values[k].update({(name, port): value for port, value in outputs.items()})
        self.produced[k][self.p.position[name]] = (name, outputs)
        self.done[name] = k
