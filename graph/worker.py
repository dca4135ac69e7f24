"""A block stepped in a worker process of its own, beside the run's other blocks.

Pipelined windows (:mod:`.executor_pipeline`) run the blocks' steps in threads of one process, and threads share
one interpreter lock (GIL): the Python between a block's compiled calls runs one thread at a time, and every
hand-over of the lock costs CPU. A block whose steps are long and hold the lock for much of their time (the
block says so: :attr:`~evsda.graph.block.Block.worth_a_process`) steps faster in a process of its own: its chain
of windows then runs beside the others' with nothing shared.

The worker is a fresh interpreter (``python -m evsda.graph.worker``: the "spawn" start, safe beside threads and
Numba's, unlike a fork of a process that has threads; and it imports nothing of the caller's ``__main__``). It
builds the block from its class, parameters, name and seed, and then runs what it is sent, in order, through the
block contract: ``setup(run)``, ``step(window, **inputs)``, ``get_state()`` (checkpoints), ``set_state(state)``
(resume) and ``finish()``. Messages are pickled over a socket pair (:mod:`multiprocessing.connection`); the block
draws only from its own generator, so where it steps changes no number.

* An exception in the worker is raised in the caller: the same type and message (the worker's traceback is
  added as a note).
* A worker that dies (killed, a crash) is one :class:`WorkerDied` error naming the block and how it ended.
* A worker that cannot start (no ``fork``/``exec``, its block's class not importable in a fresh interpreter)
  leaves the block in the caller's process, as without a worker (logged at ``-v``).
* The worker ignores SIGINT (a Ctrl-C reaches the terminal's whole process group): the caller stops it, after
  the step it is running. It ends when the caller closes it, when its connection closes, or when its parent
  process is gone.
* Its log records and warnings are handed to the caller's ``logging`` and ``warnings``.
"""

from __future__ import annotations

import importlib
import logging
import os
import pickle
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
import warnings
from typing import TYPE_CHECKING, Any

from .block import Block
from .errors import UserError
from .numba_loads import lazy_registries
from .scipy_imports import lean_array_api
from .threads import limit_blas, usable_cores

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

log = logging.getLogger("evsda.worker")

#: seconds a closing worker is given to end on its own before it is killed
CLOSE_TIMEOUT_S = 5.0
#: seconds between the worker's checks that its parent process is still there
PARENT_CHECK_S = 0.5


#: the fewest windows a run must step for a worker to pay for its start where the choice is automatic: the
#: worker's start takes ~0.8 s wall and ~0.9 s CPU (measured, docs/speed.md), and on the tracked pass what it can
#: save a window is at most the shorter of the two halves' steps (~0.12 s of optics, ~0.13 s of the rest a
#: window): an estimate, from CPU times, of where it breaks even with a margin, not a measured wall time
MIN_WINDOWS = 16


def workers_choice(choice: bool | str | None = None) -> str:
    """``"auto"``, ``"on"`` or ``"off"``: from ``choice`` (True, False, ``"auto"``) if given, else from
    ``EVSDA_WORKERS`` (``0``, the default; ``auto``; ``1``). Off by default: on the tracked pass a worker for
    the optics showed no wall-time gain (12.4 against 12.0 s on a quiet 2-core machine, docs/speed.md), and it
    costs CPU and memory."""
    if choice is not None and choice != "auto":
        return "on" if choice else "off"
    text = "auto" if choice == "auto" else os.environ.get("EVSDA_WORKERS", "0").strip()
    if text not in ("auto", "0", "1"):
        raise UserError(f"EVSDA_WORKERS must be 0 (every block in the run's process, the default), auto (blocks "
                        f"worth it step in worker processes where that pays) or 1 (wherever a block is worth it), "
                        f"got {text!r}")
    return {"auto": "auto", "1": "on", "0": "off"}[text]


def threads_per_worker() -> int:
    """The threads (``EVSDA_THREADS``) a worker's block may use: half the cores, at least one. The run's own
    steps count a worker's step as one running beside them and yield a helper thread to it
    (:func:`.threads.running_step`), so on two cores each process keeps one busy."""
    return max(1, usable_cores() // 2)


def workers_pay(windows: int) -> bool:
    """Whether worker processes pay for a run of ``windows`` windows: two cores or more, and at least
    :data:`MIN_WINDOWS` windows."""
    return usable_cores() >= 2 and windows >= MIN_WINDOWS


class WorkerDied(UserError):
    """A block's worker process ended without being asked to (killed, out of memory, a crash)."""


class _StartFailed(Exception):
    """The worker could not be started or could not build its block (the block then runs in the caller)."""


def _signal_name(returncode: int | None) -> str:
    if returncode is None:
        return "its connection closed"
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exited with status {returncode}"


class WorkerBlock:
    """``block``'s lifecycle calls (setup, step, get_state, set_state, finish), run in a worker process.

    ``setup`` and ``set_state`` are sent without waiting (the worker's start and set-up run beside the caller's
    own); their outcome is checked before the next call that waits for an answer, or by :meth:`settle`. If the
    worker cannot start, the calls so far are replayed on ``block`` itself and every later call goes to it.
    ``threads``: the ``EVSDA_THREADS`` the worker's block runs with (None: the caller's environment).
    """

    def __init__(self, block: Block, threads: int | None = None):
        self.block = block
        self.local: Block | None = None          # the block itself, once the worker could not start
        self.pending: list[tuple[str, tuple]] = []   # calls sent, their answers not yet read
        self.sent: list[tuple[str, tuple]] = []      # setup/set_state calls, replayed on a failed start
        self.started = False                         # the worker built the block
        self.peak_rss_mb: float | None = None
        #: the worker's wall time [s] stepping, and waiting for a step between its first and its last
        self.stepping_s = self.waiting_s = 0.0
        self.cpu_s = 0.0                             # the worker's CPU time, its start included [s]
        self._lock = threading.Lock()
        self.process: subprocess.Popen | None = None
        self.conn: Connection | None = None
        try:
            self._start(threads)
        except (_StartFailed, OSError, ValueError, pickle.PicklingError, AttributeError, TypeError) as exc:
            self._fall_back(str(exc) if isinstance(exc, _StartFailed) else f"{type(exc).__name__}: {exc}")

    # -- the caller's side of the block contract -------------------------------------------------
    def setup(self, run) -> None:
        self._post("setup", run)

    def set_state(self, state: dict) -> None:
        self._post("set_state", state)

    def step(self, window, **inputs) -> dict:
        return self._call("step", window, inputs)

    def get_state(self) -> dict:
        return self._call("get_state")

    def finish(self) -> dict:
        return self._call("finish")

    @property
    def in_worker(self) -> bool:
        """Whether the block steps in the worker (False after a failed start)."""
        return self.local is None

    def settle(self) -> None:
        """Wait for the answers to the calls sent without waiting; raise the first one's error."""
        with self._lock:
            self._settle()

    def close(self, kill: bool = False) -> None:
        """End the worker (at once with ``kill``, else once it has answered what it was sent), and reap it."""
        process, conn = self.process, self.conn
        self.process = self.conn = None
        if process is None:
            return
        try:
            if not kill and process.poll() is None:
                try:
                    conn.send(("close", ()))
                    deadline = time.monotonic() + CLOSE_TIMEOUT_S
                    while conn.poll(max(0.0, deadline - time.monotonic())):
                        message = conn.recv()
                        if message[0] == "closed":
                            self.peak_rss_mb, self.stepping_s, self.waiting_s, self.cpu_s = message[1:]
                            break
                        self._forward(message)
                except (OSError, EOFError):
                    pass
            try:
                process.wait(timeout=0 if kill else CLOSE_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                pass
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
            conn.close()

    # -- plumbing --------------------------------------------------------------------------------
    def _start(self, threads: int | None) -> None:
        block = self.block
        cls = type(block)
        if "<locals>" in cls.__qualname__ or cls.__module__ == "__main__":
            raise _StartFailed(f"{cls.__qualname__} cannot be imported by a fresh interpreter")
        levels = {name: logger.level for name, logger in logging.root.manager.loggerDict.items()
                  if isinstance(logger, logging.Logger) and logger.level}
        header = (list(sys.path), cls.__module__, cls.__qualname__, block.name, block.seed,
                  logging.getLogger().getEffectiveLevel(), levels, threads, os.getpid())
        params = pickle.dumps(block.params, protocol=pickle.HIGHEST_PROTOCOL)   # unpicklable parameters fail here
        from multiprocessing.connection import Connection     # here: a run without a worker does without it

        ours, theirs = socket.socketpair()
        try:
            self.process = subprocess.Popen([sys.executable, "-m", "evsda.graph.worker", str(theirs.fileno())],
                                            pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, close_fds=True)
        finally:
            theirs.close()
        self.conn = Connection(ours.detach())
        self.conn.send(header)
        self.conn.send_bytes(params)
        self.pending.append(("start", ()))

    def _fall_back(self, why: str) -> None:
        """Run the block in this process from now on: replay the calls sent so far on it."""
        if self.process is not None:
            self.close(kill=True)
        log.info("%s steps in this process: its worker process could not start (%s)", self.block.label, why)
        self.local, self.pending = self.block, []
        for name, args in self.sent:
            getattr(self.local, name)(*args)
        self.sent = []

    def _post(self, name: str, *args) -> None:
        with self._lock:
            if self.local is not None:
                getattr(self.local, name)(*args)
                return
            if not self.started:
                self.sent.append((name, args))
            self.pending.append((name, args))
            try:
                self._send(name, args)
            except WorkerDied:
                if self.started:
                    raise
                # it ended while starting: reading its answer to "start" says why, and replays this call here

    def _call(self, name: str, *args):
        with self._lock:
            self._settle()
            if self.local is not None:
                if name == "step":
                    window, inputs = args
                    return self.local.step(window, **inputs)
                return getattr(self.local, name)(*args)
            self._send(name, args)
            return self._answer(name)

    def _settle(self) -> None:
        while self.pending and self.local is None:
            name, _ = self.pending[0]
            try:
                self._answer(name)
            finally:
                if self.pending and self.pending[0][0] == name:
                    self.pending.pop(0)

    def _send(self, name: str, args: tuple) -> None:
        try:
            self.conn.send((name, args))
        except (OSError, EOFError):
            raise self._died(name) from None

    def _answer(self, name: str):
        """Read the worker's answer to call ``name`` (forwarding its log records and warnings)."""
        while True:
            try:
                message = self.conn.recv()
            except (OSError, EOFError):
                if not self.started:
                    self._fall_back(f"it ended before building the block: {_signal_name(self._returncode())}")
                    return None
                raise self._died(name) from None
            kind = message[0]
            if kind == "ok":
                if name == "start":
                    self.started, self.sent = True, []   # nothing to replay any more
                return message[1]
            if kind == "start_failed":
                self._fall_back(message[1])
                return None
            if kind == "error":
                raise _rebuilt(*message[1:], self.block.label)
            self._forward(message)

    @staticmethod
    def _forward(message) -> None:
        kind = message[0]
        if kind == "log":
            record = message[1]
            logging.getLogger(record.name).handle(record)
        elif kind == "warning":
            category, text = message[1:]
            warnings.warn(text, category, stacklevel=1)

    def _returncode(self) -> int | None:
        try:
            return self.process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            return None

    def _died(self, name: str) -> WorkerDied:
        what = "stepping a window" if name == "step" else f"answering {name}()"
        return WorkerDied(f"{self.block.label}: its worker process ended while {what} "
                          f"({_signal_name(self._returncode())})")


def _rebuilt(error: BaseException | None, type_name: str, text: str, trace: str, label: str) -> BaseException:
    """The worker's exception, raised here: the same type and message, its traceback as a note."""
    if error is None:
        error = RuntimeError(f"{type_name}: {text}")
    error.add_note(f"(raised in the worker process of {label})\n{trace}")
    return error


# -- the worker process ---------------------------------------------------------------------------
class _Forwarder(logging.Handler):
    """Hands each log record to the caller, formatted (its arguments need not pickle)."""

    def __init__(self, conn: Connection, lock: threading.Lock):
        super().__init__()
        self.conn, self.sending = conn, lock          # (``self.lock`` is the handler's own)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            record.msg, record.args = record.getMessage(), None
            if record.exc_info:
                record.exc_text = logging.Formatter().formatException(record.exc_info)
                record.exc_info = None
            with self.sending:
                self.conn.send(("log", record))
        except Exception:                               # noqa: BLE001 -- logging must not break a step
            self.handleError(record)


def _portable(exc: BaseException) -> BaseException | None:
    """``exc`` if it survives pickling with its type and message, else None."""
    try:
        copy = pickle.loads(pickle.dumps(exc))
    except Exception:                                   # noqa: BLE001
        return None
    return copy if type(copy) is type(exc) and str(copy) == str(exc) else None


def _watch_parent(parent: int) -> None:
    """End this process when its parent is gone (a caller killed while this worker was stepping)."""
    while True:
        time.sleep(PARENT_CHECK_S)
        if os.getppid() != parent:
            os._exit(1)


def _serve(conn: Connection) -> None:
    sys_path, module, qualname, name, seed, level, levels, threads, parent = conn.recv()
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    sys.path[:] = sys_path
    if threads is not None:
        os.environ["EVSDA_THREADS"] = str(threads)
    try:
        lean_array_api()                                # before the block's modules import SciPy
        cls: Any = importlib.import_module(module)
        for part in qualname.split("."):
            cls = getattr(cls, part)
        block = cls(pickle.loads(conn.recv_bytes()), name=name, seed=seed)
        lazy_registries()                               # the block's modules are imported (Numba, if it uses it)
        limit_blas()           # again: a limit holds only the BLAS libraries loaded when it is set (threadpoolctl),
        # and the block's modules load SciPy's own after main() set it; with more threads its products round otherwise
    except Exception as exc:                            # noqa: BLE001 -- reported; the caller runs the block
        conn.send(("start_failed", f"{type(exc).__name__}: {exc}"))
        return
    lock = threading.Lock()
    root = logging.getLogger()
    root.setLevel(level)
    for logger_name, logger_level in levels.items():
        logging.getLogger(logger_name).setLevel(logger_level)
    root.addHandler(_Forwarder(conn, lock))

    def show_warning(message, category, filename, lineno, file=None, line=None):
        with lock:
            conn.send(("warning", category, str(message)))

    warnings.showwarning = show_warning
    with lock:
        conn.send(("ok", None))
    stepping = waiting = 0.0
    last_step: float | None = None           # when the last step's answer was sent
    while True:
        try:
            op, args = conn.recv()
        except (EOFError, OSError):
            return
        if op == "close":
            import resource                     # POSIX only, as the worker is
            usage = resource.getrusage(resource.RUSAGE_SELF)
            with lock:
                conn.send(("closed", usage.ru_maxrss / 1024, stepping, waiting, usage.ru_utime + usage.ru_stime))
            return
        try:
            if op == "step":
                start = time.perf_counter()
                waiting += start - last_step if last_step is not None else 0.0
                window, inputs = args
                result = block.step(window, **inputs)
                stepping += time.perf_counter() - start
            else:
                result = getattr(block, op)(*args)
            answer = ("ok", result)
        except Exception as exc:                        # noqa: BLE001 -- raised again in the caller
            answer = ("error", _portable(exc), type(exc).__name__, str(exc), traceback.format_exc())
        with lock:
            conn.send(answer)
        if op == "step":
            last_step = time.perf_counter()


def main(argv: list[str]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)        # the caller stops this worker (see the module docstring)
    from multiprocessing.connection import Connection

    from .threads import keep_freed_memory, limit_malloc_arenas
    limit_malloc_arenas()
    keep_freed_memory()
    conn = Connection(int(argv[0]))
    try:
        with limit_blas():
            _serve(conn)
    except (EOFError, OSError, KeyboardInterrupt):
        pass
    finally:
        conn.close()


if __name__ == "__main__":
    main(sys.argv[1:])
