"""The ``evsda`` command.

Exit status: 0 success, 2 a user error (message on stderr, no traceback), 1 an
internal error (a bug: traceback on stderr).
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import math
import os
import signal
import sys
import threading
import warnings
from contextlib import contextmanager
from pathlib import Path

from . import __version__, registry
from . import schema as schema_module
from .commands import Command, add_figure_options, contributed_commands
from .errors import Interrupted, UserError
from .executor import run_graph
from .files import describe_os_error
from .graphfile import Graph, graph_from_dict, load_graph
from .limits import Limits
from .report import describe_block, describe_store, list_blocks, run_summary, store_info
from .result_cache import cache_root
from .scipy_imports import lean_array_api
from .store import RunStore
from .threads import limit_blas


def _load(args) -> Graph:
    lean_array_api()                # before the graph's blocks import SciPy
    limits = Limits.parse(getattr(args, "limit", ()))
    target = Path(args.graph)
    if target.is_dir() and (target / "zarr.json").exists():  # a run store: re-run its resolved graph
        graph_dict = RunStore.open(target).attrs["graph"]
        if args.set:
            raise UserError("--set cannot be combined with a run store as the graph; export its graph first")
        return graph_from_dict(graph_dict, file=str(target), limits=limits)
    return load_graph(args.graph, args.set, limits=limits)


def cmd_run(args) -> int:
    graph = _load(args)
    _collect_again()
    out = Path(args.output) if args.output else Path(f"{graph.name}.zarr")
    if not args.checkpoint_every >= 0 or args.checkpoint_every == float("inf"):
        raise UserError(f"--checkpoint-every must be a finite number of seconds >= 0, got {args.checkpoint_every}")
    with _cache_switch(args.cache):
        result = run_graph(graph, out, resume=args.resume, overwrite=args.overwrite, reuse=args.reuse,
                           progress=None if args.progress is None else args.progress,
                           checkpoint_every_s=args.checkpoint_every, keep_checkpoint=args.keep_checkpoint,
                           pipeline=args.pipeline, workers=args.workers)
    if not args.quiet:
        print(run_summary(graph, result), file=sys.stderr)
    if args.json:
        print(json.dumps({"store": str(out), "windows": result.store.committed_windows if result.store else 0,
                          "events": result.store.n_events if result.store else 0,
                          "metrics": {k: _plain(v) for k, v in result.metrics.items()},
                          "units": result.metric_units, "timing_s": result.timing_s, "reused": result.reused},
                         indent=2, allow_nan=False))
    return 0


@contextmanager
def _cache_switch(choice: bool | None):
    """``EVSDA_CACHE`` set by ``--cache`` / ``--no-cache`` while the command runs (a sweep's local workers, started
    inside, inherit it), and checked before any work (:func:`.result_cache.cache_root`)."""
    previous = os.environ.get("EVSDA_CACHE")
    if choice is not None:
        os.environ["EVSDA_CACHE"] = "on" if choice else "off"
    try:
        cache_root()
        yield
    finally:
        if previous is None:
            os.environ.pop("EVSDA_CACHE", None)
        else:
            os.environ["EVSDA_CACHE"] = previous


#: exit status of a sweep in which some points failed (the others finished; the last line counts them)
SWEEP_FAILED = 3


def _plain(value):
    """A metric as JSON allows it: non-finite numbers become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def cmd_info(args) -> int:
    store = RunStore.open(args.store)
    info = store_info(store)
    if args.json:
        info["metrics"] = {k: {**v, "value": _plain(v["value"])} for k, v in info["metrics"].items()}
        print(json.dumps(info, indent=2, allow_nan=False))
    else:
        print(describe_store(info))
    return 0


def cmd_sweep(args) -> int:
    from .sweep import parse_limits, read_grid, run_sweep

    grid = read_grid(args.grid, args.vary)
    out = Path(args.output) if args.output else Path(f"{Path(args.graph).stem}_sweep")
    report = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr))
    limits, max_points = parse_limits(args.limit)
    with _cache_switch(args.cache):
        result = run_sweep(args.graph, grid, out, overrides=args.set, jobs=args.jobs, scheduler=args.scheduler,
                           overwrite=args.overwrite, method=args.sample, points=args.points, seed=args.seed,
                           report=report, limits=limits, max_points=max_points)
    if result.failed and args.quiet:
        print(f"evsda: sweep: {result.failed} of {len(result.rows)} points failed (see {result.csv})", file=sys.stderr)
    return SWEEP_FAILED if result.failed else 0


def cmd_sweep_plot(args) -> int:
    from .files import check_figure_output, save_figure
    from .sweep_plot import plot_sweep, read_results

    check_figure_output(args.output, args.overwrite, args.dpi)
    figure = plot_sweep(read_results(args.sweep), args.metric, args.x, args.y)
    save_figure(figure, args.output, args.overwrite, args.dpi)
    if not args.quiet:
        print(f"{args.output}: {figure.axes[0].get_title()}", file=sys.stderr)
    return 0


def cmd_validate(args) -> int:
    graph = _load(args)
    print(f"{graph.file}: ok — {len(graph.nodes)} blocks, {len(graph.connections)} connections")
    return 0


def cmd_blocks(args) -> int:
    if args.name:
        cls = registry.get(args.name)
        if cls is None:
            raise UserError(f"{registry.unknown_block(args.name)}; `evsda blocks` lists them")
        print(describe_block(args.name, cls))
    else:
        print(list_blocks(registry.available()))
        for failure in registry.broken():
            print(f"evsda: warning: {failure}", file=sys.stderr)
    return 0


def cmd_schema(args) -> int:
    directory = Path(args.dir)
    if args.check:
        problems = schema_module.stale(directory)
        if problems:
            for line in problems:
                print(f"evsda: schema: {line}", file=sys.stderr)
            print("evsda: schema is stale; regenerate it with `evsda schema`", file=sys.stderr)
            return 1
        print(f"{directory}: schema is up to date")
        return 0
    written = schema_module.write(directory)
    print(f"wrote {len(written)} schema files to {directory}")
    return 0


def _common_options() -> argparse.ArgumentParser:
    """-v and -q, accepted before or after the command: every parser knows them, and SUPPRESS keeps a
    sub-command's parser from resetting what was given before it."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="log what blocks decide (paths taken, reuse)")
    common.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                        help="only errors and warnings: no summaries or progress lines")
    return common


def _graph_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("graph", help="graph file (a path or library:...), or a run store to re-run")
    p.add_argument("--set", action="append", default=[], metavar="BLOCK.PARAM=VALUE",
                   help="override a parameter (repeatable); included blocks are named include/block")


def _limit_arg(p: argparse.ArgumentParser, sweep: bool = False) -> None:
    if sweep:
        from .sweep import MAX_POINTS
    defaults = Limits()
    p.add_argument("--limit", action="append", default=[], metavar="NAME=VALUE",
                   help=f"raise a size limit checked before any work (repeatable): windows "
                        f"({defaults.windows:.0e}), pixels ({defaults.pixels:.3g}), window_bytes "
                        f"({defaults.window_bytes:.3g} bytes held per window)"
                        + (f" of each point, points ({MAX_POINTS:.0e}) in the sweep" if sweep else ""))


def _cache_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cache", action=argparse.BooleanOptionalAction, default=None,
                   help="take results computed before on the same inputs (auto's path-choice probes) from the "
                        "cache folder, EVSDA_CACHE_DIR or ~/.cache/evsda (default: on, unless EVSDA_CACHE=off)")


def _configure_run(p: argparse.ArgumentParser) -> None:
    _graph_args(p)
    _limit_arg(p)
    _cache_arg(p)
    p.add_argument("-o", "--output", help="run store to write (default: NAME.zarr)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in OUTPUT from its last checkpoint (from the start if nothing was committed)")
    p.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it is a run store")
    p.add_argument("--keep-checkpoint", action="store_true",
                   help="keep the blocks' state at the end of the run in the store (dropped by default)")
    p.add_argument("--reuse", action="append", default=[], metavar="STORE",
                   help="reuse matching upstream outputs from an earlier run store (repeatable)")
    p.add_argument("--checkpoint-every", type=float, default=30.0, metavar="SECONDS",
                   help="wall-clock seconds between checkpoints (0: after every window)")
    p.add_argument("--pipeline", action=argparse.BooleanOptionalAction, default=None,
                   help="step blocks of successive windows concurrently, recording the same bytes "
                        "(default: on, unless EVSDA_PIPELINE=0)")
    p.add_argument("--workers", action=argparse.BooleanOptionalAction, default=None,
                   help="step the blocks worth it (the optics) in worker processes of their own in a pipelined run, "
                        "recording the same bytes (default: off, unless EVSDA_WORKERS=1, or auto: where it may pay, "
                        "several cores and 16 windows or more)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="show a progress bar (default: when stderr is a terminal)")
    p.add_argument("--json", action="store_true",
                   help="print the store, event count, metrics (with units) and timing as JSON on stdout")


def _configure_sweep(p: argparse.ArgumentParser) -> None:
    from .sweep import SAMPLING

    _graph_args(p)
    _limit_arg(p, sweep=True)
    _cache_arg(p)
    p.add_argument("--grid", help="YAML file mapping block.param to a list of values or a range {min:, max:}")
    p.add_argument("--vary", action="append", default=[], metavar="BLOCK.PARAM=VALUES",
                   help="a parameter and its values, [v1, v2] or {min: a, max: b, log: true} (repeatable; "
                        "combined with --grid)")
    p.add_argument("--sample", choices=SAMPLING, default="grid",
                   help="grid: every combination of the lists; random or lhs (Latin hypercube): --points draws "
                        "from the lists and ranges")
    p.add_argument("--points", type=int, default=None, help="points drawn by --sample random or lhs")
    p.add_argument("--seed", type=int, default=0, help="seed of --sample random or lhs (default 0)")
    p.add_argument("-o", "--output", help="folder for one run store per point and the results table "
                                          "sweep.csv / sweep.parquet (default: GRAPH_sweep)")
    p.add_argument("-j", "--jobs", type=int, default=None,
                   help="worker processes of the local Dask cluster (default: one per core; 1: run the points "
                        "one after another in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run the points on a running Dask cluster (e.g. tcp://host:8786); its workers must reach "
                        "the output folder and have evsda installed")
    p.add_argument("--overwrite", action="store_true", help="recompute every point, replacing their stores")


def _configure_sweep_plot(p: argparse.ArgumentParser) -> None:
    p.add_argument("sweep", help="sweep folder (holding sweep.parquet or sweep.csv)")
    p.add_argument("metric", help="metric to draw (a column of the results table)")
    p.add_argument("--x", default=None, help="swept parameter on the x axis (default: the only one)")
    p.add_argument("--y", default=None, help="second swept parameter: points in the (x, y) plane coloured by the metric")
    add_figure_options(p, dpi=120.0)


def _configure_info(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", help="run store (.zarr)")
    p.add_argument("--json", action="store_true", help="print it as JSON")


def _configure_validate(p: argparse.ArgumentParser) -> None:
    _graph_args(p)
    _limit_arg(p)


def _configure_blocks(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", help="block type to describe")


def _configure_schema(p: argparse.ArgumentParser) -> None:
    p.add_argument("--check", action="store_true", help="fail if the files on disk are stale")
    p.add_argument("--dir", default="schema", help="schema folder (default: ./schema)")


#: the built-in commands in the order ``evsda --help`` lists them: name, help, options, function
BUILT_IN_COMMANDS = (
    ("run", "run a graph file", _configure_run, cmd_run),
    ("sweep", "run a graph over a grid of parameter values (a trade study)", _configure_sweep, cmd_sweep),
    ("sweep-plot", "draw a metric of a sweep against one or two swept parameters, failed points marked",
     _configure_sweep_plot, cmd_sweep_plot),
    ("info", "what a run store holds: graph, seed, epoch, events by cause, metrics, products, complete or "
             "resumable", _configure_info, cmd_info),
    ("validate", "check a graph file without running it", _configure_validate, cmd_validate),
    ("blocks", "list block types, or describe one", _configure_blocks, cmd_blocks),
    ("schema", "regenerate the JSON Schemas (or check that they are current)", _configure_schema, cmd_schema),
)


def build_parser(extra: list[Command], only: str | None = None) -> argparse.ArgumentParser:
    """The ``evsda`` parser with the built-in commands and ``extra``; ``only``: the one command's parser, as when
    the command line names a built-in command (:func:`_parser_for`)."""
    common = _common_options()
    parser = argparse.ArgumentParser(prog="evsda", parents=[common],
                                     description="Event-based sensor simulator for space domain awareness.")
    parser.add_argument("--version", action="version", version=f"evsda {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    commands = [*BUILT_IN_COMMANDS, *((c.name, c.help, c.configure, c.run) for c in extra)]
    for name, help_text, configure, func in commands:
        if only is not None and name != only:
            continue
        p = subparsers.add_parser(name, parents=[common], help=help_text)
        configure(p)
        p.set_defaults(func=func)
    return parser


def _configure_logging(args) -> None:
    args.verbose, args.quiet = getattr(args, "verbose", False), getattr(args, "quiet", False)
    logging.basicConfig(level=logging.INFO if args.verbose and not args.quiet else logging.WARNING,
                        format="evsda: %(name)s: %(message)s")


def _catch_sigterm():
    """Let SIGTERM end the command like Ctrl-C (main thread only); returns the handler to put back, or None."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _terminate)


def _run_command(args) -> int:
    with limit_blas(), warnings.catch_warnings():      # see evsda.graph.threads
        warnings.showwarning = _show_warning
        status = int(args.func(args) or 0)
    sys.stdout.flush()      # here, so that a closed pipe is caught in main rather than at exit
    return status


def _user_error_status(exc: UserError) -> int:
    for line in str(exc).splitlines():
        print(f"evsda: error: {line}", file=sys.stderr)
    return 2


def _interrupted_status(exc: KeyboardInterrupt) -> int:
    name = getattr(exc, "signal_name", "SIGINT")
    print(f"evsda: {exc if isinstance(exc, Interrupted) else 'interrupted'}", file=sys.stderr)
    return 128 + getattr(signal, name, signal.SIGINT)


def _broken_pipe_status() -> int:
    """The reader went away (`evsda blocks | head`): end quietly, as command-line tools do."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return 128 + signal.SIGPIPE


def _os_error_status(exc: OSError) -> int:
    print(f"evsda: error: {describe_os_error(exc)}", file=sys.stderr)
    return 2


def _failure_status(exc: BaseException) -> int:
    """The one line (or none, for a closed pipe) and the exit status of a command that raised ``exc``."""
    if isinstance(exc, UserError):
        return _user_error_status(exc)
    if isinstance(exc, KeyboardInterrupt):
        return _interrupted_status(exc)
    if isinstance(exc, BrokenPipeError):
        return _broken_pipe_status()
    return _os_error_status(exc)


def main(argv: list[str] | None = None) -> int:
    """The ``evsda`` command on ``argv`` (None: this process's command line, the ``evsda`` script's call, after which
    the interpreter ends: see :func:`_hold_collections` and :func:`_skip_exit_collection`); its exit status."""
    if argv is None:
        _hold_collections()
    try:
        return _main(argv)
    finally:
        _collect_again()
        if argv is None:
            _skip_exit_collection()


_held = False        # collections held off by _hold_collections


def _hold_collections() -> None:
    """No cyclic garbage collection while the command starts (its own process only): loading a graph imports its
    blocks, ~190 000 long-lived objects on the tracked pass (modules, classes, Numba's dispatchers) and almost no
    garbage, and each collection of the oldest generation walks every object alive. There the collector took 0.18 s
    of the load's 0.6 s of CPU (one walk of 0.12 s), and more in the first window, single-threaded, before any step
    can run beside it (docs/speed.md). :func:`_collect_again` turns collections back on."""
    global _held
    if gc.isenabled():
        gc.disable()
        _held = True


def _collect_again() -> None:
    """After the command's start (its graph loaded): collections back on, the objects made so far moved out of the
    collector's sight for good (``gc.freeze``): later collections walk only what the run makes, not the modules."""
    global _held
    if _held:
        gc.freeze()
        gc.enable()
        _held = False


def _skip_exit_collection() -> None:
    """Spare the interpreter's exit its cyclic garbage collections: they walk every object still alive (~170 000
    after a run: the blocks' modules, Numba's dispatchers and LLVM wrappers) several times, ~0.4 s of CPU after
    the tracked 10 s pass, against ~0.07 s once these objects are moved out of the collector's sight
    (``gc.freeze``). Nothing is lost: the run's store, files and lock are closed, and the process's memory goes
    back to the system whole when it ends. Only for the process's own command (a caller that goes on keeps its
    collections)."""
    gc.freeze()


#: the options accepted before the command (:func:`_common_options`)
_COMMON_FLAGS = ("-v", "--verbose", "-q", "--quiet")


def _named_built_in(argv: list[str]) -> str | None:
    """The built-in command that ``argv`` names (its first argument after -v/-q), or None: no command, another
    option first (``--help``, ``--version``), a contributed command or a mistake."""
    for arg in argv:
        if arg not in _COMMON_FLAGS:
            return arg if any(arg == name for name, *_ in BUILT_IN_COMMANDS) else None
    return None


def _parser_for(argv: list[str]) -> argparse.ArgumentParser:
    """The parser of this command line. A built-in command (``evsda run ...``) gets only its own parser: the
    contributed commands' modules (the blocks' plotting and export commands, ~12 ms of CPU at every start) and
    the other commands' set-up (the sweep's module) are not needed to parse it: it parses, helps and fails as
    with every command's parser. Anything else (``evsda --help``, a contributed command, a mistake) gets
    every command's parser, as argparse's listing and suggestions need."""
    named = _named_built_in(argv)
    if named is None:
        return build_parser(contributed_commands())
    return build_parser([], only=named)


def _main(argv: list[str] | None) -> int:
    try:
        parser = _parser_for(sys.argv[1:] if argv is None else argv)
    except UserError as exc:
        print(f"evsda: error: {exc}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is not cmd_run:        # a run turns collections back on once its graph is loaded
        _collect_again()
    _configure_logging(args)
    previous = _catch_sigterm()
    try:
        return _run_command(args)
    except (UserError, KeyboardInterrupt, OSError) as exc:     # BrokenPipeError is an OSError
        _quiet_abandoned_writes()
        return _failure_status(exc)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _quiet_abandoned_writes() -> None:
    """After a command stopped by a signal or an error: a Zarr write it left under way stays pending on
    Zarr's event loop, and asyncio reports it ("Task was destroyed but it is pending!") when the loop is
    dropped at exit; a Zarr call stopped between making its coroutine and handing it to the loop leaves a
    coroutine Python reports as "never awaited" when it is collected. Such a write was never committed
    (``--resume`` redoes it), so the reports would only add lines after the one that says what happened."""
    logging.getLogger("asyncio").disabled = True
    warnings.filterwarnings("ignore", message=r"coroutine .* was never awaited", category=RuntimeWarning)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning of a block (skipped catalogue entries, old element sets) as one ``evsda: warning:`` line,
    without the source file and line of the code that raised it."""
    print(f"evsda: warning: {' '.join(str(message).split())}", file=sys.stderr)


def _terminate(signum, frame) -> None:
    """SIGTERM ends a run like Ctrl-C: what is committed is kept, one line says so."""
    raise Interrupted("SIGTERM")


if __name__ == "__main__":
    sys.exit(main())
