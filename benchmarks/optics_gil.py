"""How much of the optics' step runs without the interpreter lock (issue 13): what two threads could overlap.

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml) in a fresh process with
``EVSDA_THREADS=1``, ``EVSDA_PIPELINE=0`` and the probe cache off, and splits the optics block's step CPU time
(``time.thread_time``, one thread) into:

* compiled calls made without the interpreter lock (Numba functions compiled ``nogil``, called from Python; the time
  of their first call, the compiled code's load from Numba's cache, is left out and counted with the rest), by
  function;
* the path choice's probes (``PathChooser._probe`` and, where it exists, ``probe_ahead``: the probes
  helper's, at the head of the run), whole;
* the rest: the interpreter and numpy between those calls. NumPy's own loops (the stamps' ``sin`` and ``cos``, the
  pocketfft transforms of the probes) release the lock too, so this is an upper bound of what holds it.

``--functions`` adds that bound function by function: each of the optics' Python functions below (the block's
sample-and-hold, render loop and held stamps, the imager's calls, the pupil path, the screens' walk and
regenerations, the stamps, the probes whole) with its own time outside compiled calls that release the lock and
outside the other functions listed (its calls counted), a ranking of the Python that holds the lock. ``the step's
own`` is the step less all of them; the block's loop over the sources is counted with ``parallel_map`` (its
shared loop, ~1 us an item).

Each Python call of a compiled function goes through one timing wrapper (``Dispatcher.__call__``; ~0.3 us a call);
calls from compiled code to compiled code are not seen. ``--against DIR`` runs another checkout's code (its own
``.venv``) the same way, alternated; the medians over ``--repeats`` runs are printed, with the load average.

``--replay --against DIR`` instead steps this checkout's optics block and DIR's ``blocks/optics`` (imported here as a
package of its own; its compiled functions cache in a folder of this benchmark's, never in DIR) side by side in this
process over the run's captured inputs, window by window, alternating which goes first, and checks that their
irradiance and truth are the same bytes; it prints each one's CPU per window (after the first; the probes left out)
and the part of it outside compiled ``nogil`` calls (the same upper bound of the lock held). Separate runs of a
fresh process each drift by 10-20 % on this host, even on code both trees share; in one process the drift cancels.
``--inputs FILE`` keeps the captured block and inputs (pickled; read back if it exists).

``--replay --regions`` (no ``--against``) steps this checkout's block alone over those inputs and splits its CPU
outside compiled ``nogil`` calls by region: each of the functions in ``REGIONS`` (the step's phases before the render
loop, the render units, the pupil path's and renderer's Python, the screens' walk, the truth table) with its own time
outside those calls and outside the regions under it, and the step's own lines; only these functions are wrapped
(~0.3 us a call), so the figures are not a profiler's.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/optics_gil.py [--repeats 3] [--against DIR] [--functions]
    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/optics_gil.py --replay --against DIR [--inputs F] [--repeats 3]
    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/optics_gil.py --replay --regions [--inputs F] [--repeats 3]
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import importlib
import os
import pickle
import statistics
import sys
import tempfile
import time
import types
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from end_to_end import GRAPH, ONE_THREAD, alternated, checkouts, fresh  # noqa: E402

CHILD = r"""
import functools, json, sys, tempfile, time
from collections import defaultdict
clock = time.thread_time
spent, depth = defaultdict(float), [0]

from numba.core import dispatcher
from numba import _dispatcher
base_call = _dispatcher.Dispatcher.__call__
inner_compile = dispatcher.Dispatcher._compile_for_args
loading = [0.0]

def compile_for_args(self, *args, **kwargs):          # first calls: the cache's load (or a compile), lock held
    t = clock()
    try:
        return inner_compile(self, *args, **kwargs)
    finally:
        loading[0] += clock() - t
dispatcher.Dispatcher._compile_for_args = compile_for_args

released = [0.0]                                        # every compiled call without the lock, in the step

def call(self, *args, **kwargs):
    if depth[0] == 0 or not self.targetoptions.get("nogil"):
        return base_call(self, *args, **kwargs)
    t, load = clock(), loading[0]
    try:
        return base_call(self, *args, **kwargs)
    finally:
        d = clock() - t - (loading[0] - load)
        released[0] += d
        spent["nogil " + self.py_func.__module__.rpartition(".")[2] + "." + self.py_func.__name__] += d
dispatcher.Dispatcher.__call__ = call

from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.blocks.optics import block, paths

inside = defaultdict(int)

def timed(owner, attribute, label, outer=False):
    inner = getattr(owner, attribute)
    @functools.wraps(inner)
    def wrapper(*args, **kwargs):
        if inside[label]:                               # the outermost call of a label only
            return inner(*args, **kwargs)
        t, before = clock(), dict(spent)
        inside[label] += 1
        if outer:
            depth[0] += 1
        try:
            return inner(*args, **kwargs)
        finally:
            inside[label] -= 1
            if outer:
                depth[0] -= 1
            else:                                       # nested compiled calls count here, not twice
                for key in spent:
                    if key.startswith("nogil "):
                        spent[key] = before.get(key, 0.0)
            spent[label] += clock() - t
    setattr(owner, attribute, wrapper)

timed(block.PointSourceOptics, "step", "step", outer=True)
for name in ("_probe", "probe_ahead"):                  # the probes made as choices need them, or a window ahead
    if hasattr(paths.PathChooser, name):
        timed(paths.PathChooser, name, "probes")
if sys.argv[3] == "functions":                          # --functions: each function's own time holding the lock
    from evsda.blocks.optics import imaging, layer_screen, pupil_path, render, render_interval
    children = []                                       # held time of the listed calls inside the one running
    active = set()                                      # the labels being timed (one thread: EVSDA_THREADS=1)

    def held(owner, attribute, label, always=False):
        inner = owner.__dict__.get(attribute) if isinstance(owner, type) else None
        static = isinstance(inner, staticmethod)
        inner = getattr(owner, attribute)

        @functools.wraps(inner)
        def wrapper(*args, **kwargs):
            if (depth[0] == 0 and not always) or label in active:    # a call within its own label: counted there
                return inner(*args, **kwargs)
            t, free, load = clock(), released[0], loading[0]
            children.append(0.0)
            active.add(label)
            try:
                return inner(*args, **kwargs)
            finally:
                active.discard(label)
                inside_held = clock() - t - (released[0] - free) - (loading[0] - load)
                own = inside_held - children.pop()
                spent["own " + label] += own
                spent["calls " + label] += 1
                if children:
                    children[-1] += inside_held
        setattr(owner, attribute, staticmethod(wrapper) if static else wrapper)

    O, I, P, S = block.PointSourceOptics, imaging.Imager, pupil_path.PupilPath, layer_screen.LayerScreen
    for owner, attribute, label in (
            (O, "_held_samples", "block: sample and hold, rates"),
            (block, "parallel_map", "block: the render loop (every source)"), (O, "_render_held", "block: held stamps"),
            (block, "truth_rows", "block: truth table"), (render_interval.RenderInterval, "multiples",
                                                         "block: render intervals"),
            (I, "placement", "imager: placement, lines of sight"), (I, "prepare", "imager: path choices"),
            (I, "render", "imager: render"), (I, "render_many", "imager: render"), (I, "release", "imager: release"),
            (P, "render", "pupil path: render"), (P, "render_many", "pupil path: render"),
            (P, "turbulent_phase", "pupil path: phase (layers' grids)"),
            (P, "_phases", "pupil path: phase (layers' grids)"),
            (layer_screen, "walk_layers", "screens: walk (plan, runs, packing)"),
            (S, "regenerate", "screens: regenerate"), (S, "_fresh", "screens: fresh windows"),
            (S, "_cut_from_fft", "screens: FFT windows"), (S, "_large_scales", "screens: large-scale modes"),
            (render.PupilRenderer, "stamps", "stamps: tilt, sin, cos, calls"),
            (paths.PathChooser, "probe_ahead", "probes (whole, less the above)"),
            (paths.PathChooser, "_probe", "probes (whole, less the above)")):
        if hasattr(owner, attribute):
            held(owner, attribute, label)
    held(O, "step", "the step's own", always=True)     # outside the step's timing: its compiled calls counted
graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}"])
with tempfile.TemporaryDirectory() as tmp:
    run_graph(graph, tmp + "/run.zarr", overwrite=True, progress=False, checkpoint_every_s=1e9)
print(json.dumps(spent))
"""


def one_run(graph: Path, duration: float, checkout: Path | None, functions: bool = False) -> dict:
    """One fresh run's figures, the probe cache off; ``checkout``: another checkout's code (its ``.venv``);
    ``functions``: with each listed function's own time holding the lock."""
    return fresh(CHILD, {**ONE_THREAD, "EVSDA_CACHE": "off"},
                 (str(graph.resolve()), str(duration), "functions" if functions else "-"), checkout)


#: the replay's setting: one thread, one step at a time, no probe cache
REPLAY_ENV = {**ONE_THREAD, "EVSDA_CACHE": "off"}


def captured(graph: Path, duration: float):
    """A copy of the optics block before its first step and its (window, sources, background) of every window of a
    run of ``graph``."""
    from evsda.blocks.optics import block
    from evsda.graph.executor import run_graph
    from evsda.graph.graphfile import load_graph
    kept: dict = {"block": None, "inputs": []}
    step = block.PointSourceOptics.step

    def keeping(self, window, sources, background=None):
        if kept["block"] is None:
            kept["block"] = copy.deepcopy(self)
        kept["inputs"].append((window, sources, background))
        return step(self, window, sources, background)

    block.PointSourceOptics.step = keeping
    try:
        with tempfile.TemporaryDirectory() as tmp:
            run_graph(load_graph(graph, [f"run.duration_s={duration}"]), tmp + "/run.zarr", overwrite=True,
                      progress=False, checkpoint_every_s=1e9)
    finally:
        block.PointSourceOptics.step = step
    return kept["block"], kept["inputs"]


def optics_package(checkout: Path) -> types.ModuleType:
    """``blocks/optics`` of another checkout as a package of its own (its relative imports read that checkout's
    modules), every module imported at once (none later, by a call), its compiled functions cached in a folder of this
    benchmark's: in that checkout's ``__pycache__`` they would name this package, which its own runs cannot import.
    Numba reads its cache folder from its config when a module is compiled, so the folder stays set for the rest of
    this process (this checkout's modules are all imported by then)."""
    from numba.core import config as numba_config
    folder = (checkout / "blocks" / "optics").resolve()
    package = types.ModuleType("optics_" + hashlib.md5(str(folder).encode()).hexdigest()[:8])
    package.__path__ = [str(folder)]
    sys.modules[package.__name__] = package
    numba_config.CACHE_DIR = str(Path(tempfile.gettempdir()) / "optics_gil_numba")
    for module in sorted(folder.glob("*.py")):
        if module.stem not in ("__init__", "plots", "commands"):
            importlib.import_module(f"{package.__name__}.{module.stem}")
    return package


def time_released_calls() -> list[float]:
    """Time every call of a compiled ``nogil`` function in this process from now on (this thread's CPU, added into
    the returned one-item list [s]): Numba's ``Dispatcher.__call__`` wrapped."""
    from numba.core import dispatcher

    released, clock = [0.0], time.thread_time
    base_call = dispatcher.Dispatcher.__call__

    def call(self, *args, **kwargs):
        if not self.targetoptions.get("nogil"):
            return base_call(self, *args, **kwargs)
        t = clock()
        try:
            return base_call(self, *args, **kwargs)
        finally:
            released[0] += clock() - t
    dispatcher.Dispatcher.__call__ = call
    return released


def replay(pickled: bytes, inputs: list, against: Path, repeats: int) -> None:
    """:func:`captured`'s block stepped side by side with ``against``'s over its inputs (the module docstring)."""
    from evsda.blocks.optics import block, paths

    other = optics_package(against)
    clock, probing, released = time.thread_time, [0.0], time_released_calls()
    for chooser in (paths.PathChooser, other.paths.PathChooser):
        for name in ("_probe", "probe_ahead"):
            if hasattr(chooser, name):
                inner = getattr(chooser, name)

                def timed(*args, _inner=inner, **kwargs):
                    t = clock()
                    try:
                        return _inner(*args, **kwargs)
                    finally:
                        probing[0] += clock() - t
                setattr(chooser, name, timed)
    names, classes = ("this checkout", str(against)), (block.PointSourceOptics, other.block.PointSourceOptics)
    cpu, held = {name: [] for name in names}, {name: [] for name in names}
    for k in range(repeats):
        blocks = {}
        for name, cls in zip(names, classes):
            blocks[name] = pickle.loads(pickled)
            blocks[name].__class__ = cls
            blocks[name]._atmosphere, blocks[name]._atmosphere_ready = None, False     # each builds its own
        spent, outside = dict.fromkeys(names, 0.0), dict.fromkeys(names, 0.0)
        before = os.getloadavg()[0]
        for i, (window, sources, background) in enumerate(inputs):
            outputs = {}
            for name in (names if (i + k) % 2 == 0 else names[::-1]):
                t, probes, free = clock(), probing[0], released[0]
                outputs[name] = blocks[name].step(window, sources, background)
                step = clock() - t - (probing[0] - probes)
                if i:                                   # the first window: set-up, compiled code's load, probes
                    spent[name] += step
                    outside[name] += step - (released[0] - free)
            a, b = (outputs[name] for name in names)
            for x, y in zip(*((o["irradiance"].t_ns, o["irradiance"].background, o["irradiance"].stamp_origin,
                               o["irradiance"].stamp_flux) for o in (a, b))):
                if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
                    raise SystemExit(f"window {i}: the irradiance differs")
            if pickle.dumps(a["truth"]) != pickle.dumps(b["truth"]):
                raise SystemExit(f"window {i}: the truth differs")
        windows = len(inputs) - 1
        for name in names:
            cpu[name].append(1e3 * spent[name] / windows)
            held[name].append(1e3 * outside[name] / windows)
        print(f"  round {k + 1}: " + "; ".join(f"{name}: {cpu[name][-1]:.2f} ms, {held[name][-1]:.2f} outside "
                                             f"nogil calls" for name in names)
              + f" (load {(before + os.getloadavg()[0]) / 2:.1f}; outputs identical)", flush=True)
    print(f"\nthe optics' step a window over {windows} windows (after the first; probes left out), one thread, one "
          f"process [CPU ms]; medians of {repeats} rounds, every window's irradiance and truth identical")
    for label, figures in (("the step", cpu), ("  outside compiled nogil calls (upper bound of the lock held)", held)):
        mine, theirs = (statistics.median(figures[name]) for name in names)
        ratios = [a / b for a, b in zip(figures[names[0]], figures[names[1]])]
        print(f"  {label:62s} {mine:8.2f} {theirs:8.2f}   ratio {statistics.median(ratios):.3f} "
              f"({min(ratios):.3f}-{max(ratios):.3f})")


#: ``--regions``: (module, owner or None, function, label) of each region timed on its own
REGIONS = (("block", "PointSourceOptics", "_held_samples", "sample and hold, rates (_held_samples)"),
           ("render_interval", "RenderInterval", "multiples", "render intervals (multiples)"),
           ("paths", "PathChooser", "probe_ahead", "probes ahead (probe_ahead)"),
           ("imaging", "Imager", "placement", "placements (Imager.placement)"),
           ("paths", "PathChooser", "keys", "path bins (PathChooser.keys)"),
           ("imaging", "Imager", "prepare", "path choices (Imager.prepare)"),
           ("block", None, "parallel_map", "the render loop's units (render_together, render)"),
           ("imaging", "Imager", "render_many", "Imager and PupilPath render_many"),
           ("imaging", "Imager", "render", "sources alone (Imager.render)"),
           ("pupil_path", "PupilPath", "_phases", "the pupil path's _phases"),
           ("pupil_path", None, "accumulate_layers", "the screens' walk (accumulate_layers)"),
           ("render", "PupilRenderer", "stamps", "PupilRenderer.stamps"),
           ("block", "PointSourceOptics", "_held", "held frames (_held)"),
           ("block", None, "truth_rows", "truth table (truth_rows)"),
           ("imaging", "Imager", "release", "release"))


def regions(pickled: bytes, inputs: list, repeats: int) -> None:
    """``--regions``: this checkout's block over the captured inputs, its CPU outside compiled ``nogil`` calls by
    region (the module docstring)."""
    from evsda.blocks import optics

    clock, released, spent, stack = time.thread_time, time_released_calls(), {}, []

    def timed(inner, label):
        def wrapper(*args, **kwargs):
            t, free = clock(), released[0]
            stack.append(0.0)
            try:
                return inner(*args, **kwargs)
            finally:
                held = clock() - t - (released[0] - free)
                spent[label] = spent.get(label, 0.0) + held - stack.pop()
                if stack:
                    stack[-1] += held
        return wrapper

    for module, owner, name, label in REGIONS:
        namespace = importlib.import_module(f"{optics.__name__}.{module}")
        target = getattr(namespace, owner) if owner else namespace
        wrapper = timed(getattr(target, name), label)
        static = owner is not None and isinstance(target.__dict__.get(name), staticmethod)
        setattr(target, name, staticmethod(wrapper) if static else wrapper)
    per_round = {}
    for k in range(repeats):
        block = pickle.loads(pickled)
        block._atmosphere, block._atmosphere_ready = None, False
        block.step(*inputs[0])                                  # set-up, compiled code's load, window 0's probes
        spent.clear()
        total = outside = 0.0
        before = os.getloadavg()[0]
        for window, sources, background in inputs[1:]:
            t, free = clock(), released[0]
            stack.append(0.0)
            block.step(window, sources, background)
            below = stack.pop()
            step = clock() - t
            total += step
            outside += step - (released[0] - free)
            spent["the step's own lines"] = spent.get("the step's own lines", 0.0) + step - (released[0] - free) - below
        windows = len(inputs) - 1
        figures = {"the step": total, "  outside compiled nogil calls": outside,
                   **{"    " + label: value for label, value in spent.items()}}
        for label, value in figures.items():
            per_round.setdefault(label, []).append(1e3 * value / windows)
        print(f"  round {k + 1}: the step {1e3 * total / windows:.2f} ms, {1e3 * outside / windows:.2f} outside nogil "
              f"calls (load {(before + os.getloadavg()[0]) / 2:.1f})", flush=True)
    print(f"\nthis checkout's optics step a window over {windows} windows (after the first), one thread [CPU ms]; "
          f"medians of {repeats} rounds; each region's own time outside compiled nogil calls and the regions under it")
    totals = [label for label in per_round if not label.startswith("    ")]
    largest_first = sorted(set(per_round) - set(totals), key=lambda label: -statistics.median(per_round[label]))
    for label in totals + largest_first:
        print(f"  {label:62s} {statistics.median(per_round[label]):8.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--repeats", type=int, default=3, help="fresh runs of each tree (medians)")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv), alternated")
    parser.add_argument("--functions", action="store_true",
                        help="split the rest by the optics' Python functions (their own time holding the lock)")
    parser.add_argument("--replay", action="store_true",
                        help="with --against: both trees' optics blocks stepped side by side in this process over "
                             "the run's captured inputs, their outputs checked identical")
    parser.add_argument("--inputs", type=Path, help="with --replay: pickle of the captured block and inputs, written "
                                                    "if absent, else read")
    parser.add_argument("--regions", action="store_true",
                        help="with --replay (no --against): this checkout's CPU outside compiled nogil calls by region")
    args = parser.parse_args()
    if args.replay:
        if (args.against is None) != args.regions:
            parser.error("--replay needs --against, or --regions without it")
        os.environ.update(REPLAY_ENV)
        if args.inputs is not None and args.inputs.exists():
            with open(args.inputs, "rb") as f:
                pickled, inputs = pickle.load(f)
        else:
            optics, inputs = captured(args.graph, args.duration)
            pickled = pickle.dumps(optics, protocol=5)
            if args.inputs is not None:
                with open(args.inputs, "wb") as f:
                    pickle.dump((pickled, inputs), f, protocol=5)
        if args.regions:
            regions(pickled, inputs, args.repeats)
        else:
            replay(pickled, inputs, args.against, args.repeats)
        return
    trees = checkouts(parser, args.against)
    runs, loads = alternated(trees, args.repeats,
                             lambda checkout: one_run(args.graph, args.duration, checkout, args.functions),
                             lambda k, name, r, load: print(f"  {name}: step {r['step']:.2f} s CPU", flush=True))
    print(f"\n{args.graph.name}, {args.duration:g} s simulated, the optics' step on one thread [CPU s]; medians of "
          f"{args.repeats} fresh runs, load {statistics.median(loads):.1f} ({min(loads):.1f}-{max(loads):.1f})")
    keys = sorted({k for rs in runs.values() for r in rs for k in r if k.startswith("nogil ")},
                  key=lambda k: -statistics.median(r.get(k, 0.0) for r in runs["this checkout"]))
    med = {name: {k: statistics.median(r.get(k, 0.0) for r in rs) for k in ["step", "probes", *keys]}
           for name, rs in runs.items()}
    for m in med.values():
        m["nogil"] = sum(m[k] for k in keys)
        m["rest"] = m["step"] - m["probes"] - m["nogil"]
    print(f"  {'item':58s}" + "".join(f" {name[-14:]:>14s}" for name in trees))

    def row(label, key):
        print(f"  {label:58s}" + "".join(f" {med[name][key]:14.2f}" for name in trees))

    row("the optics' step", "step")
    row("  path-choice probes (whole)", "probes")
    row("  compiled, without the interpreter lock", "nogil")
    for k in keys:
        if max(med[name][k] for name in trees) >= 0.01:
            row("    " + k[6:], k)
    row("  the rest: the interpreter, numpy (upper bound of the lock held)", "rest")
    for name in trees:
        m = med[name]
        print(f"  {name}: outside the probes, {m['nogil'] / (m['step'] - m['probes']):.0%} of the step compiled "
              f"without the lock")
    if args.functions:
        own = sorted({k[4:] for rs in runs.values() for r in rs for k in r if k.startswith("own ")},
                     key=lambda k: -statistics.median(r.get("own " + k, 0.0) for r in runs["this checkout"]))
        print(f"\n  the optics' Python, each function's own time holding the lock [CPU s] (calls; us a call), "
              f"largest first:")
        for k in own:
            cells = []
            for name, rs in runs.items():
                t = statistics.median(r.get("own " + k, 0.0) for r in rs)
                n = statistics.median(r.get("calls " + k, 0) for r in rs)
                cells.append(f"{t:6.3f} ({n:5.0f}; {1e6 * t / n if n else 0.0:6.1f})")
            print(f"    {k:44s}" + "".join(f" {c:>26s}" for c in cells))


if __name__ == "__main__":
    main()
