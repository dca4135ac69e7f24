"""Pipelined windows: blocks of different windows step at the same time, in threads.

A block's step over window ``k`` needs only its own state after window ``k - 1`` and its inputs at ``k``,
that is the steps of the blocks upstream of it at ``k``. Any order of steps that keeps these dependencies
gives every block the same inputs in the same order as the serial loop (window after window, blocks in
topological order), so a run records the same bytes whichever steps overlap; only the wall time changes.
The optics of window ``k + 1``, say, run while the pixels of window ``k`` do. Threads pay where the steps'
heavy parts release the GIL (compiled loops declared ``nogil``, FFTs, compression).

Rules:

* at most :data:`WINDOWS_AHEAD` windows beyond the oldest unrecorded one are in flight (each holds its
  values in memory);
* windows are handed back in order, to the calling thread, which records them (one thread writes the store);
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
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from typing import Any

from .block import RunInfo, Window
from .errors import UserError
from .threads import running_step

#: windows in flight beyond the oldest one not yet recorded (1: the optics of k + 1 beside the pixels of k)
WINDOWS_AHEAD = 1

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
        self.gather, self.step = gather, step

    def windows(self, run: RunInfo, start: int, stop: int, loaded: Callable[[int], Values],
                commit_due: Callable[[int], bool]) -> Iterator[tuple[Window, list[tuple[str, dict]], bool]]:
        """``(window, [(block, outputs)] in topological order, commit)`` for windows ``start .. stop - 1``, in
        order. ``loaded(k)``: window ``k``'s values that no block here computes (read in order, once);
        ``commit_due(k)``: whether to commit after window ``k``, asked once per window (``commit``)."""
        state = _State(self, run, start, stop, loaded, commit_due)
        with ThreadPoolExecutor(max(1, len(self.order)), thread_name_prefix="evsda-step") as pool:
            try:
                while state.next_out < stop:
                    state.launch(pool)
                    if state.window_complete(state.next_out):
                        yield state.hand_back()
                        continue
                    if not state.running:
                        if state.failure is not None:
                            raise state.failure[1]
                        raise RuntimeError("pipeline stalled with nothing running (a bug in evsda)")
                    finished, _ = wait(state.running, return_when=FIRST_COMPLETED)
                    for future in finished:
                        state.harvest(future)
            finally:
                state.stopped = True               # start nothing more; the pool waits for the running steps


def _counted(step, name, window, inputs):
    """``step(name, window, inputs)`` counted as a running step (:func:`.threads.running_step`)."""
    with running_step():
        return step(name, window, inputs)


class _State:
    """The book-keeping of one :meth:`Pipeline.windows` call."""

    def __init__(self, pipeline: Pipeline, run: RunInfo, start: int, stop: int,
                 loaded: Callable[[int], Values], commit_due: Callable[[int], bool]):
        self.p, self.run, self.start, self.stop = pipeline, run, start, stop
        self.loaded, self.commit_due = loaded, commit_due
        self.values: dict[int, Values] = {}                         # window -> {(block, port): value}
        self.produced: dict[int, dict[int, tuple[str, dict]]] = {}  # window -> {position: (block, outputs)}
        self.done = {name: start - 1 for name in pipeline.order}    # the last window each block finished
        self.running: dict[Future, tuple[str, int]] = {}
        self.busy: set[str] = set()
        self.commits: dict[int, bool] = {}                          # commit decisions, by window
        self.failure: tuple[tuple[int, int], BaseException] | None = None
        self.next_out = start
        self.stopped = False

    def window_complete(self, k: int) -> bool:
        return all(done >= k for done in self.done.values())

    def _may_start(self, k: int) -> bool:
        """Window ``k`` may start: its previous window is handed back, or will not be committed."""
        if k == self.start or self.next_out > k - 1:
            return True
        if k - 1 not in self.commits:
            self.commits[k - 1] = self.commit_due(k - 1)
        return not self.commits[k - 1]

    def launch(self, pool: ThreadPoolExecutor) -> None:
        """Start every step whose dependencies are met, window by window."""
        for k in range(self.next_out, min(self.stop, self.next_out + 1 + WINDOWS_AHEAD)):
            if self.stopped or not self._may_start(k):
                return
            if k not in self.values:
                self.values[k] = dict(self.loaded(k))
                self.produced[k] = {}
            for name in self.p.order:
                if name in self.busy or self.done[name] != k - 1:
                    continue
                if self.failure is not None and (k, self.p.position[name]) >= self.failure[0]:
                    continue
                if all(self.done[u] >= k for u in self.p.upstream[name]):
                    inputs = self.p.gather(name, self.values[k])
                    future = pool.submit(_counted, self.p.step, name, self.run.window(k), inputs)
                    self.running[future] = (name, k)
                    self.busy.add(name)

    def harvest(self, future: Future) -> None:
        """Take a finished step's outputs, or note its error if it comes first in the serial order."""
        name, k = self.running.pop(future)
        self.busy.discard(name)
        error = future.exception()
        if error is not None:
            key = (k, self.p.position[name])
            if self.failure is None or key < self.failure[0]:
                self.failure = (key, error)
            return
        outputs = future.result()
        self.values[k].update({(name, port): value for port, value in outputs.items()})
        self.produced[k][self.p.position[name]] = (name, outputs)
        self.done[name] = k

    def hand_back(self) -> tuple[Window, list[tuple[str, dict]], bool]:
        """The oldest window, complete, with its commit decision; its values are dropped."""
        k = self.next_out
        commit = self.commits.pop(k) if k in self.commits else self.commit_due(k)
        entries = self.produced.pop(k)
        produced = [entries[i] for i in sorted(entries)]
        del self.values[k]
        self.next_out += 1
        return self.run.window(k), produced, commit
