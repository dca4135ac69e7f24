"""CPU time of the path choice's reference probes (``psf_path: auto``) on the tracked pass of end_to_end.yaml.

Runs one window of the pass (so that the optics block builds its imager and meets the run's
conditions), then times, on one thread with the cache of probe results across runs off,
:meth:`.PathChooser.pupil_estimate` afresh for each pupil-error bin the run met (the Fresnel reference propagations, 4-24 per bin), alternating the
probes' frame pairs made from both halves of each complex FFT draw (``both``: as ``auto`` does,
:meth:`.LayerScreen.twin`) and the second frame of each pair drawn on its own (``one``: every frame
its own draw, the probes' cost before). Prints the medians of ``--repeats`` rounds (and the least: on a shared
host the load only adds time) and each bin's estimate, frames and verdict. ``--all-frames`` makes every bin take all
24 frames (a tolerance no estimate can clear: the same count both ways, the cost per frame). ``--against DIR`` alternates this tree's
probes (pairs, as ``auto`` makes them) with those through another checkout's path chooser and reference path (its
``blocks/optics/paths.py`` and ``reference_path.py`` with its ``propagation.py``, ``layer_screen.py`` and
``fft_screens.py``), and prints how far the estimates of the two are apart. Every round starts cold, as a run's
first probes do: the screens' spectra and the propagation's transfer functions and vacuum steps kept within a
process are emptied first.

``--ahead`` times instead, in wall time on the process's threads (every core unless ``EVSDA_THREADS`` says
otherwise), all the probes the pass's first window makes (both pupil-error bins and the analytic-path probes,
their long-exposure tables included), alternating :meth:`.PathChooser.probe_ahead` (every bin's probes in one
schedule, as the optics block makes them) and the choices made one bin after another (each bin's probes alone, as
before), and checks that both give the same choices and estimates (compared with ``repr``). With ``--speculate``
the first way is instead the schedule made ahead as before the fifteenth session: a thread with nothing else to make
begins the next pair of a bin even where the one pair being measured is likely to decide it
(``_PairRun.likely_decided`` always False); each way's pairs begun and propagations made are printed.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/path_probes.py [--repeats 5] [--all-frames] [--against DIR]
    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/path_probes.py --ahead [--speculate] [--repeats 5]

``--fresh`` times what a run pays: in fresh processes (this checkout's and, with ``--against``, the other's own
``.venv``, alternated), a run of ``--graph`` (default: the tracked pass, its first window: ``--duration 0.1``) with
the probe cache off and one step at a time (``EVSDA_PIPELINE=0``, so that the process's CPU time during the probes
is theirs), on the process's threads; it prints the medians of the first optics step up to its probes (wall, and its
thread's CPU: the imager, the sampling, the window's samples), of the first window's probes (wall and CPU: the run's
first compiled code is among them, Numba's typing and target contexts, ~0.2 s of interpreter) and of all of the
run's probes, Numba's cached loads (how many, and their threads' CPU in ``Cache._load_overload``) and the
process's CPU, and whether every run gave the same choices and estimates (a digest of their ``repr``). ``--variant
LABEL:VAR=VALUE`` adds this checkout with more environment, alternated (e.g. ``off:EVSDA_KEPT_SYMBOLS=off``); a
setting whose name holds a ``.`` is a graph override instead (``--set``, e.g.
``reference:telescope/optics.share_far_probes=false``).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/path_probes.py --fresh [--against DIR] [--repeats 5]
        [--graph examples/iss_pass.yaml --duration 4] [--variant LABEL:VAR=VALUE[,VAR=VALUE]]
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from evsda.blocks.optics import fft_screens, propagation
from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.layer_screen import LayerScreen
from evsda.blocks.optics import reference_path
from evsda.blocks.optics.paths import ANALYTIC_PATHS, PUPIL_ERROR_ZENITH_BIN_RAD, PathChooser, _PairRun
from evsda.blocks.threads import worker_threads
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

GRAPH = Path(__file__).with_name("end_to_end.yaml")


def checkout_module(checkout: Path, name: str):
    """``blocks/optics/<name>.py`` of another checkout, imported inside this tree's optics package (its relative
    imports are this tree's modules)."""
    spec = importlib.util.spec_from_file_location(f"evsda.blocks.optics._against_{name}",
                                                  checkout / "blocks" / "optics" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module                 # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@functools.lru_cache(maxsize=None)
def checkout_modules(checkout: Path) -> dict:
    """Another checkout's reference path: its ``reference_path.py`` with its ``propagation.py``, ``layer_screen.py``
    and that one's ``fft_screens.py`` (the FFT screens' draws, spectra and transforms); the rest is this tree's."""
    modules = {name: checkout_module(checkout, name)
               for name in ("reference_path", "propagation", "layer_screen", "fft_screens", "paths")}
    for name in ("propagate", "propagate_point_source", "point_source_field"):
        if hasattr(modules["propagation"], name):
            setattr(modules["reference_path"], name, getattr(modules["propagation"], name))
    modules["reference_path"].LayerScreen = modules["layer_screen"].LayerScreen
    modules["layer_screen"].fft_spline_corners = modules["fft_screens"].fft_spline_corners
    return modules


def against(checkout: Path, imager) -> Callable[[], None]:
    """Make ``imager``'s reference path and path chooser those of ``checkout`` (:func:`checkout_modules`: the
    chooser's probes call the reference path's methods as they are there); returns the undo."""
    reference, chooser = imager.reference, imager.chooser
    kept = reference.__class__, chooser.__class__
    modules = checkout_modules(checkout)
    reference.__class__ = modules["reference_path"].ReferencePath
    chooser.__class__ = modules["paths"].PathChooser

    def undo():
        reference.__class__, chooser.__class__ = kept
    return undo


def forget_tables(checkout: Path | None) -> None:
    """Empty the tables kept across probes within a process (the FFT screens' spectra, the propagation's transfer
    functions), this tree's and ``checkout``'s, so that every round costs what a run's first probes cost."""
    trees = [{"fft_screens": fft_screens, "propagation": propagation}]
    if checkout is not None:
        trees.append(checkout_modules(checkout))
    for modules in trees:
        modules["fft_screens"]._spectra.cache_clear()
        for name in ("_kept_transfer_functions", "_vacuum_head"):
            kept = getattr(modules["propagation"], name, None)
            if kept is not None:
                kept.cache_clear()


def ahead_or_not(imager, frames: tuple, repeats: int, speculate: bool = False) -> None:
    """``--ahead``: the probes of the first window's ``frames`` (zenith angles, ranges, what the pixels see, in view:
    (render times, tracks) as the block gives them) made one bin after another (``speculate``: made ahead as before
    the fifteenth session, a pair begun beside one likely to decide) and made ahead, alternated, from cold each
    round."""
    chooser = imager.chooser
    chooser.forced_path = "auto"

    def cold():
        chooser.forget()
        for path in ANALYTIC_PATHS:
            imager.path_named[path].forget()
        forget_tables(None)

    def choices():
        return [chooser.choose_key(key, zenith_rad) for key, zenith_rad in first.items()]

    zenith, range_m, seen, visible = frames
    first = {}
    for i, key in enumerate(chooser.keys(zenith[visible], range_m[visible], seen[visible])):
        first.setdefault(key, float(zenith[visible][i]))
    likely = _PairRun.likely_decided

    def speculating():
        _PairRun.likely_decided = lambda run: False
        try:
            chooser.probe_ahead(*frames)
        finally:
            _PairRun.likely_decided = likely

    ways = {"made ahead, speculating": speculating} if speculate else {"one bin after another": lambda: None}
    ways["made ahead"] = lambda: chooser.probe_ahead(*frames)
    counts = {name: [] for name in ways}
    take, propagate = _PairRun.take, reference_path.propagate_point_source

    def counted(count, call):
        def wrapped(*args, **kwargs):
            count[0] += 1
            return call(*args, **kwargs)
        return wrapped
    times = {name: [] for name in ways}
    made = {}
    loads = []
    for _ in range(repeats):
        loads.append(os.getloadavg()[0])
        for name, way in ways.items():
            cold()
            pairs, propagations = [0], [0]
            _PairRun.take = counted(pairs, take)
            reference_path.propagate_point_source = counted(propagations, propagate)
            t, c = time.perf_counter(), time.process_time()
            try:
                way()
                chosen = choices()
            finally:
                _PairRun.take, reference_path.propagate_point_source = take, propagate
            times[name].append((time.perf_counter() - t, time.process_time() - c))
            counts[name].append((pairs[0], propagations[0]))
            made[name] = repr((chosen, sorted(chooser._pupil_errors.items()), sorted(chooser._estimates.items())))
    print(f"  the first window's {len(first)} bins ({len(chooser._pupil_errors)} pupil-error bins, "
          f"{len(chooser._estimates)} analytic probes), {worker_threads()} threads:")
    for name, values in times.items():
        print(f"  {name}: {statistics.median(w for w, _ in values):.3f} s wall, "
              f"{statistics.median(c for _, c in values):.3f} s CPU (medians of {repeats}; wall "
              f"{', '.join(f'{w:.3f}' for w, _ in values)}; CPU {', '.join(f'{c:.3f}' for _, c in values)}); "
              f"pairs begun, propagations: {sorted(set(counts[name]))}")
    first_way, second_way = ways
    ratio = statistics.median(w for w, _ in times[second_way]) / statistics.median(w for w, _ in times[first_way])
    print(f"  wall ratio {second_way} / {first_way}: {ratio:.2f}; load {statistics.median(loads):.1f}; choices and "
          f"estimates {'the same' if made[first_way] == made[second_way] else 'DIFFERENT'}")


#: the child of ``--fresh``: argv graph, duration; prints the probes' spans (wall, CPU) and the choices' digest
FRESH = r"""
import functools, hashlib, json, sys, tempfile, time
from numba.core import caching
from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.paths import PathChooser
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
spans, imagers, started, before, loads = [], [], [], [], []
probe_ahead, step, load = PathChooser.probe_ahead, PointSourceOptics.step, caching.Cache._load_overload

def loaded(self, *args):                   # a cached compiled function loaded: its thread's CPU
    c = time.thread_time()
    try:
        return load(self, *args)
    finally:
        loads.append(time.thread_time() - c)

def timed(self, *args):
    t, c = time.perf_counter(), time.process_time()
    if not before:                         # the first step up to its probes, on its thread
        before.append((t - started[0][0], time.thread_time() - started[0][1]))
    try:
        return probe_ahead(self, *args)
    finally:
        spans.append((time.perf_counter() - t, time.process_time() - c))

@functools.wraps(step)
def kept(self, *args, **kwargs):
    if not started:
        started.append((time.perf_counter(), time.thread_time()))
    out = step(self, *args, **kwargs)
    if self._imager not in imagers:
        imagers.append(self._imager)
    return out

PathChooser.probe_ahead, PointSourceOptics.step, caching.Cache._load_overload = timed, kept, loaded
graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}", *sys.argv[3:]])
with tempfile.TemporaryDirectory() as tmp:
    run_graph(graph, tmp + "/run.zarr", overwrite=True, progress=False, checkpoint_every_s=1e9)
made = repr([(sorted(c._choices.items()), sorted(c._pupil_errors.items()), sorted(c._estimates.items(), key=repr))
             for c in (imager.chooser for imager in imagers)])
print(json.dumps({"first": spans[0], "before": before[0], "all": [sum(s[0] for s in spans), sum(s[1] for s in spans)],
                  "loads": [len(loads), sum(loads)], "cpu": time.process_time(),
                  "digest": hashlib.sha256(made.encode()).hexdigest()[:16]}))
"""


def fresh_runs(args) -> None:
    """``--fresh``: the probes as a run pays them, in fresh processes of each checkout, alternated."""
    sys.path.insert(0, str(Path(__file__).parent))
    from end_to_end import alternated, checkouts, fresh

    trees = {name: (checkout, {}) for name, checkout in checkouts(argparse.ArgumentParser(), args.against).items()}
    for variant in args.variant:
        label, _, settings = variant.partition(":")
        trees[label] = (None, dict(setting.split("=", 1) for setting in settings.split(",")))
    env = {"EVSDA_CACHE": "off", "EVSDA_PIPELINE": "0"}

    def run(tree):
        checkout, more = tree
        sets = [f"{name}={value}" for name, value in more.items() if "." in name]
        more_env = {name: value for name, value in more.items() if "." not in name}
        return fresh(FRESH, {**env, **more_env}, (str(args.graph.resolve()), str(args.duration), *sets), checkout)

    def show(k, name, out, load):
        print(f"  run {k + 1} ({name}): the first optics step before its probes {1e3 * out['before'][0]:.1f} ms wall, "
              f"{1e3 * out['before'][1]:.1f} ms CPU; first window's probes {out['first'][0]:.3f} s wall, "
              f"{out['first'][1]:.3f} s CPU; all {out['all'][0]:.3f} s wall; {out['loads'][0]} cached loads "
              f"{1e3 * out['loads'][1]:.0f} ms CPU; the process {out['cpu']:.2f} s CPU; load {load:.2f}", flush=True)

    runs, loads = alternated(trees, args.repeats, run, show)
    print(f"\n{args.graph.name}, {args.duration:g} s, {os.environ.get('EVSDA_THREADS', 'all')} threads, medians of "
          f"{args.repeats} fresh runs, load {statistics.median(loads):.2f} ({min(loads):.2f}-{max(loads):.2f}):")
    for name, values in runs.items():
        first = [v["first"] for v in values]
        ahead = [v["before"] for v in values]
        print(f"  {name}: the first optics step before its probes {1e3 * statistics.median(w for w, _ in ahead):.1f} ms "
              f"wall, {1e3 * statistics.median(c for _, c in ahead):.1f} ms CPU (its thread's)")
        print(f"  {name}: first window's probes {statistics.median(w for w, _ in first):.3f} s wall, "
              f"{statistics.median(c for _, c in first):.3f} s CPU; all probes "
              f"{statistics.median(v['all'][0] for v in values):.3f} s wall, "
              f"{statistics.median(v['all'][1] for v in values):.3f} s CPU")
        print(f"  {name}: cached loads {statistics.median(v['loads'][0] for v in values):.0f}, "
              f"{1e3 * statistics.median(v['loads'][1] for v in values):.0f} ms CPU (their threads'); the process "
              f"{statistics.median(v['cpu'] for v in values):.2f} s CPU")
    digests = {v["digest"] for values in runs.values() for v in values}
    print(f"  choices and estimates: {'the same in every run' if len(digests) == 1 else 'DIFFERENT'} "
          f"({', '.join(sorted(digests))})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--all-frames", action="store_true", help="every bin takes all 24 frames")
    parser.add_argument("--against", type=Path, help="another checkout: its probes, propagation and FFT screens' cut")
    parser.add_argument("--ahead", action="store_true", help="the first window's probes made ahead or one bin "
                        "after another, wall time on the process's threads")
    parser.add_argument("--speculate", action="store_true", help="with --ahead: against the schedule made ahead "
                        "that begins a pair beside one likely to decide (before the fifteenth session)")
    parser.add_argument("--fresh", action="store_true", help="the probes as a run pays them, in fresh processes")
    parser.add_argument("--graph", type=Path, default=GRAPH, help="with --fresh: the graph (default: the pass)")
    parser.add_argument("--duration", type=float, default=0.1, help="with --fresh: simulated seconds [s]")
    parser.add_argument("--variant", action="append", default=[], metavar="LABEL:VAR=VALUE[,VAR=VALUE]",
                        help="with --fresh: this checkout with more environment (or, a name with a '.', a graph "
                        "override), alternated (repeat for more)")
    args = parser.parse_args()
    if args.fresh:
        return fresh_runs(args)
    if not args.ahead:
        os.environ["EVSDA_THREADS"] = "1"
    os.environ["EVSDA_CACHE"] = "off"      # the probes themselves, every round (not the results kept across runs)

    imagers, windows = [], []
    step = PointSourceOptics.step
    probe_ahead = PathChooser.probe_ahead

    @functools.wraps(step)                 # the registry checks step()'s parameters against the block's inputs
    def kept(self, *a, **k):
        out = step(self, *a, **k)
        imagers.append(self._imager)
        return out

    def noted(self, *a):                   # the frames of the first window, as the block gives them
        windows.append(a)
        return probe_ahead(self, *a)

    PointSourceOptics.step = kept
    PathChooser.probe_ahead = noted
    with tempfile.TemporaryDirectory() as tmp:
        run_graph(load_graph(str(GRAPH), ["run.duration_s=0.002", "telescope/optics.psf_path=pupil_fft"]),
                  Path(tmp) / "probe.zarr", overwrite=True)
    PointSourceOptics.step = step
    PathChooser.probe_ahead = probe_ahead
    imager = imagers[-1]
    chooser = imager.chooser
    if args.ahead:
        return ahead_or_not(imager, windows[0], args.repeats, args.speculate)
    if args.all_frames:
        imager.tolerance = float("nan")
    bins = [(6, 19), (6, -1)]              # the tracked pass at 65 deg: the ISS (7.4e5 m) and the stars (far)
    conditions = [((z + 0.5) * PUPIL_ERROR_ZENITH_BIN_RAD, np.inf if r < 0 else 2.0 ** (r + 0.5)) for z, r in bins]

    twin = LayerScreen.twin

    def one_draw_a_frame():
        LayerScreen.twin = lambda self, seed: None
        return lambda: setattr(LayerScreen, "twin", twin)

    if args.against:
        ways = {str(args.against): lambda: against(args.against, imager), "this tree": lambda: (lambda: None)}
    else:
        ways = {"one draw(s) a pair": one_draw_a_frame, "both draw(s) a pair": lambda: (lambda: None)}
    times = {name: [] for name in ways}
    estimates = {}
    loads = []
    for _ in range(args.repeats):
        loads.append(os.getloadavg()[0])
        for name, way in ways.items():
            undo = way()
            chooser._pupil_errors.clear()
            forget_tables(args.against)
            t = time.process_time()
            estimates[name] = [chooser.pupil_estimate(z, r) for z, r in conditions]
            times[name].append(time.process_time() - t)
            undo()
    for name in ways:
        found = ", ".join(f"{e.error:.3g} +- {e.standard_error:.2g} on {e.frames} ({'in' if e.within else 'out'})"
                          for e in estimates[name])
        print(f"  {name}: {statistics.median(times[name]):6.2f} s CPU (median of {args.repeats}, least "
              f"{min(times[name]):.2f}; {', '.join(f'{t:.2f}' for t in times[name])}); bins {bins}: {found}")
    first, second = ways
    print(f"  ratio {second} / {first}: {statistics.median(times[second]) / statistics.median(times[first]):.2f} "
          f"(medians), {min(times[second]) / min(times[first]):.2f} (least); load {statistics.median(loads):.1f}")
    if args.against:
        pairs = list(zip(*estimates.values()))
        apart = max(abs(a.error - b.error) for a, b in pairs)
        print(f"  estimates apart by at most {apart:.2g}; frames {[(a.frames, b.frames) for a, b in pairs]}; "
              f"verdicts {'the same' if all(a.within == b.within for a, b in pairs) else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
