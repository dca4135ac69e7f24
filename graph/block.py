"""The block contract.

A block is a class with

* ``type_name``: the name graph files use (``type: dvs_pixel``);
* ``Params``: a frozen pydantic model (:class:`~evsda.graph.params.BlockParams`);
* ``inputs`` / ``outputs``: dicts of :class:`~evsda.graph.ports.Input` and
  :class:`~evsda.graph.ports.Output`, typed from the port vocabulary;
* ``state``: the names of the attributes that hold its state between windows
  (numpy arrays, numbers, strings, or ``None``), saved in checkpoints;
* ``step(window, **inputs) -> {output: value}``: advance over one time window.

Optional hooks: ``setup(run)`` once before the first window (also on resume, before
the state is restored) and ``finish()`` after the last window, which may return
final outputs (e.g. a metrics summary).

A run may step a block in a worker process of its own (``worth_a_process``, :mod:`.worker`): there it
is built again from its class, parameters, name and seed, and sees only these calls, so it keeps
nothing a run relies on outside its ``state``, and its parameters, inputs, outputs and state pickle.

Every block runs on its own, outside any graph::

    >>> from evsda.graph import Window
    >>> block = SomeBlock(gain=2.0, seed=1)          # doctest: +SKIP
    >>> out = block.step(Window.from_seconds(0.0, 0.1), signal=value)   # doctest: +SKIP

Each block draws random numbers only from ``self.rng``, a ``numpy.random.Generator``
derived from the graph seed and the block's name (:func:`block_rng`), so adding an
unrelated block to a graph changes nothing else.

A block changes only its own state: never a value it returned (a block downstream may still be reading
it while this block steps over the next window, see :mod:`~evsda.graph.executor_pipeline`), nor a value
it was given.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from typing import Any, ClassVar

import numpy as np
from pydantic import ValidationError

from .errors import InputError, ParameterError, excerpt
from .limits import Footprint
from .params import BlockParams, describe_validation_error
from .ports import Input, Output, PortValue, port_type_label

NS_PER_S = 1_000_000_000

DEFAULT_EPOCH = datetime(2024, 1, 1, tzinfo=timezone.utc)


def parse_epoch(value: str | datetime) -> datetime:
    """An ISO 8601 UTC instant (``2024-03-01T02:15:00Z``) as an aware datetime."""
    if isinstance(value, datetime):
        epoch = value
    else:
        try:
            epoch = datetime.fromisoformat(str(value).replace("Z", "+00:00"))
        except ValueError as exc:
            raise ParameterError(
                f"start time {value!r} is not an ISO 8601 UTC instant such as 2024-03-01T02:15:00Z"
            ) from exc
    if epoch.tzinfo is None:
        epoch = epoch.replace(tzinfo=timezone.utc)
    return epoch.astimezone(timezone.utc)


@dataclass(frozen=True)
class Window:
    """A half-open slice ``[start_ns, stop_ns)`` of simulated time.

    Times are integer nanoseconds since the run's start ``epoch`` (UTC).
    """

    index: int
    start_ns: int
    stop_ns: int
    epoch: datetime = DEFAULT_EPOCH

    def __post_init__(self):
        for name in ("index", "start_ns", "stop_ns"):
            if not isinstance(getattr(self, name), (int, np.integer)) or isinstance(getattr(self, name), bool):
                raise InputError(f"Window {name} must be an integer, got {excerpt(getattr(self, name))}")
        if self.stop_ns < self.start_ns:
            raise InputError(f"Window stops ({self.stop_ns} ns) before it starts ({self.start_ns} ns)")

    @classmethod
    def from_seconds(cls, start_s: float, stop_s: float, index: int = 0, epoch: datetime | str = DEFAULT_EPOCH):
        """A window from times in seconds since ``epoch``."""
        for name, value in (("start_s", start_s), ("stop_s", stop_s)):
            if not isinstance(value, (int, float, np.integer, np.floating)) or not np.isfinite(value):
                raise InputError(f"Window {name} must be a finite number of seconds, got {excerpt(value)}")
        return cls(index, round(start_s * NS_PER_S), round(stop_s * NS_PER_S), parse_epoch(epoch))

    @property
    def duration_ns(self) -> int:
        return self.stop_ns - self.start_ns

    @property
    def duration_s(self) -> float:
        return self.duration_ns / NS_PER_S

    @property
    def start_utc(self) -> datetime:
        return self.epoch + timedelta(microseconds=self.start_ns / 1000)

    def sample_times_ns(self, cadence_ns: int) -> np.ndarray:
        """Sample times of a global grid ``k * cadence_ns`` that fall inside this window [ns].

        Using one grid for the whole run keeps a block's samples identical whatever
        the window length, so results do not depend on how a run is cut into windows.
        """
        if cadence_ns <= 0:
            raise ValueError(f"cadence must be a positive number of nanoseconds, got {cadence_ns}")
        first = -(-self.start_ns // cadence_ns)
        last = -(-self.stop_ns // cadence_ns)
        return np.arange(first, last, dtype=np.int64) * np.int64(cadence_ns)


@dataclass(frozen=True)
class RunInfo:
    """What a block may know about the whole run before it starts."""

    epoch: datetime = DEFAULT_EPOCH
    duration_ns: int = NS_PER_S
    window_ns: int = NS_PER_S // 10
    seed: int = 0
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        if self.duration_ns <= 0 or self.window_ns <= 0:
            raise ParameterError(f"a run needs a positive duration and window, got {self.duration_ns} ns and "
                                 f"{self.window_ns} ns")
        if self.seed < 0:
            raise ParameterError(f"the seed must be a non-negative integer, got {self.seed}")

    @property
    def n_windows(self) -> int:
        return -(-self.duration_ns // self.window_ns)

    def window(self, index: int) -> Window:
        """Window ``index`` of the run."""
        start = index * self.window_ns
        return Window(index, start, min(start + self.window_ns, self.duration_ns), self.epoch)

    def windows(self, start: int = 0):
        """The run's windows in order (generated one at a time), from window ``start``."""
        for index in range(start, self.n_windows):
            yield self.window(index)


def block_rng(seed: int, name: str) -> np.random.Generator:
    """The random generator of block ``name`` in a run seeded with ``seed``.

    Derived with a SeedSequence from the seed and a SHA-256 of the name, so it is
    stable across processes and platforms and independent between blocks.
    """
    digest = hashlib.sha256(name.encode("utf-8")).digest()
    words = [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, *words])))


class Block:
    """Base class of every block (see the module docstring for the contract)."""

    type_name: ClassVar[str] = ""
    Params: ClassVar[type[BlockParams]] = BlockParams
    inputs: ClassVar[dict[str, Input]] = {}
    outputs: ClassVar[dict[str, Output]] = {}
    state: ClassVar[tuple[str, ...]] = ()
    #: the block writes user-facing results (a sink); requested by default in a run
    is_sink: ClassVar[bool] = False
    #: its steps are long and hold the interpreter lock for much of their time, so that a pipelined run on
    #: several cores steps it faster in a worker process of its own (:mod:`~evsda.graph.worker`)
    worth_a_process: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs):
        """Every block's ``step`` checks its arguments (a block used from Python is as strict as in a graph)."""
        super().__init_subclass__(**kwargs)
        step = cls.__dict__.get("step")
        if step is not None and not getattr(step, "_checks_inputs", False):
            cls.step = _checked_step(step)

    def __init__(self, params: BlockParams | dict | None = None, /, *, name: str | None = None,
                 seed: int = 0, **param_values):
        if isinstance(params, BlockParams):
            if param_values:
                params = params.model_copy(update=param_values)
                params = type(params).model_validate(params.model_dump())
        else:
            values = dict(params or {})
            values.update(param_values)
            try:
                params = self.Params(**values)
            except ValidationError as exc:
                lines = [f"{self.type_name} parameter '{loc}': {msg}" for loc, msg in describe_validation_error(exc)]
                raise ParameterError("; ".join(lines)) from None
        self.params = params
        self.name = name or self.type_name
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ParameterError(f"{self.label}: the seed must be a non-negative integer, "
                                 f"got {excerpt(seed)}")
        self.seed = int(seed)
        self.rng = block_rng(self.seed, self.name)
        self._run: RunInfo | None = None

    # -- lifecycle ---------------------------------------------------------------------
    def setup(self, run: RunInfo) -> None:
        """Prepare for a run (called once, before the first window, also on resume)."""
        self._run = run

    @property
    def run(self) -> RunInfo:
        """The run this block was set up for; RuntimeError before :meth:`setup`."""
        if self._run is None:
            raise RuntimeError(f"{self.label} needs setup(RunInfo(...)) before step()")
        return self._run

    @property
    def run_info(self) -> RunInfo | None:
        """The run this block was set up for (read-only), or None when it runs on its own without setup."""
        return self._run

    def run_span_ns(self, window: Window) -> tuple[int, int]:
        """``[start, stop)`` of the whole run [ns], or of ``window`` when the block runs without setup."""
        return (0, self._run.duration_ns) if self._run is not None else (window.start_ns, window.stop_ns)

    @property
    def label(self) -> str:
        """How messages name this block: its type and name (``satellite 'sat'``)."""
        return f"{self.type_name} '{self.name}'"

    def step(self, window: Window, **inputs) -> dict[str, PortValue]:
        """Advance over ``window`` and return a value for every output port."""
        raise NotImplementedError

    def finish(self) -> dict[str, PortValue]:
        """Called after the last window; may return final outputs."""
        return {}

    def footprint(self, run: RunInfo) -> Footprint:
        """What the block will allocate, from its parameters (checked against :class:`Limits` before a run)."""
        return Footprint()

    # -- state ------------------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """The block's state and RNG state, serialisable by the checkpoint store."""
        state = {name: getattr(self, name) for name in self.state}
        state["__rng__"] = self.rng.bit_generator.state
        return state

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`get_state` returned."""
        for name in self.state:
            setattr(self, name, state.get(name))
        if "__rng__" in state:
            self.rng.bit_generator.state = state["__rng__"]

    # -- checks -----------------------------------------------------------------------
    def check_inputs(self, inputs: dict[str, Any]) -> None:
        """Raise :class:`InputError` if an input value has the wrong port type."""
        for port_name, value in inputs.items():
            spec = self.inputs.get(port_name)
            if spec is None:
                raise InputError(f"{self.label} has no input port '{port_name}'; "
                                 f"it has {sorted(self.inputs) or 'none'}")
            values = value if spec.multi else [value]
            for item in values:
                if item is not None and not isinstance(item, spec.type):
                    raise InputError(f"{self.label} input '{port_name}' expects "
                                     f"{port_type_label(spec.type)}, got {type(item).__name__}")

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, {self.params!r})"


def step_signature_problems(block_class: type[Block]) -> list[str]:
    """Where ``block_class.step``'s parameters disagree with its ``inputs`` (empty when they agree).

    A block declares each input twice, once in ``inputs`` (port type, description, required) and
    once as a ``step()`` parameter (so it runs from Python with named arguments); this is the rule
    that keeps the two one declaration: the same names, a required input without a default, an
    optional one defaulting to ``None``, and no ``*args`` or ``**inputs`` catch-all.
    :func:`~evsda.graph.registry.register` refuses a block that breaks it.
    """
    parameters = list(inspect.signature(inspect.unwrap(block_class.step)).parameters.values())[2:]
    problems = [f"step() takes *{p.name}/**{p.name}" for p in parameters
                if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    named = {p.name: p for p in parameters if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
    if set(named) != set(block_class.inputs):
        problems.append(f"step() parameters {sorted(named)} != inputs {sorted(block_class.inputs)}")
    for port, spec in block_class.inputs.items():
        parameter = named.get(port)
        if parameter is None:
            continue
        has_default = parameter.default is not inspect.Parameter.empty
        if spec.required and has_default:
            problems.append(f"required input '{port}' has a default in step()")
        if not spec.required and (not has_default or parameter.default is not None):
            problems.append(f"optional input '{port}' must default to None in step()")
    return problems


def _checked_step(step):
    """``step`` with its window and inputs checked first: a missing required input, an unknown one, a
    value of the wrong port type, or a window that is not a :class:`Window` is an :class:`InputError`."""
    names = None

    @functools.wraps(step)
    def checked(self, window=None, *args, **inputs):
        nonlocal names
        if args:      # inputs given by position, in the order of step's parameters
            if names is None:
                names = [n for n in inspect.signature(step).parameters][2:]
            if len(args) > len(names):
                raise InputError(f"{self.label} step() takes {len(names)} inputs, got {len(args)}")
            for name, value in zip(names, args):
                if name in inputs:
                    raise InputError(f"{self.label} input '{name}' is given twice")
                inputs[name] = value
        if not isinstance(window, Window):
            raise InputError(f"{self.label} step() needs a Window first, got {excerpt(window)}")
        for port, spec in type(self).inputs.items():
            value = inputs.get(port)
            if spec.required and (value is None or (spec.multi and not value)):
                raise InputError(f"{self.label} is missing its required input '{port}' "
                                 f"({port_type_label(spec.type)})")
            if spec.multi and value is not None and not isinstance(value, (list, tuple)):
                raise InputError(f"{self.label} input '{port}' takes a list of "
                                 f"{port_type_label(spec.type)} values, got {type(value).__name__}")
        self.check_inputs(inputs)
        return step(self, window, **inputs)

    checked._checks_inputs = True
    return checked
