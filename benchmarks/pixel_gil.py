"""Where the pixel block's CPU goes per window in the tracked pass (issue 13): GIL-held Python and NumPy
against the compiled ``nogil`` kernels.

Runs ``benchmarks/end_to_end.yaml`` for ``--duration`` simulated seconds keeping the pixel block's
inputs, then steps a fresh copy of the block over them again (windows after the first) under cProfile
with a CPU-time clock, and prints, per window: the block's CPU (every thread), the compiled kernels it
calls on its own thread (``nogil``: they run beside other blocks' steps), and the rest, held under the
GIL, with its largest items. The events' digest is printed to compare versions.

``--inputs FILE`` keeps the captured inputs in FILE (pickled; read back if it exists), so that versions
of the pixel code are stepped over the same inputs without running the pass again; ``--no-profile``
prints the block's CPU per window (``EVSDA_THREADS=1``: the process's, one thread) without cProfile.
``--against DIR`` steps a copy of another checkout's ``blocks/pixel`` (DIR, e.g. the session's start) beside
this one in the same process, window by window, alternating which goes first, checks that their events are
the same, and prints both blocks' CPU per window and their ratio (the host's drift cancels); the copy is kept in
the temporary folder, one per checkout, so that its Numba cache serves the next run. ``--held`` prints,
without cProfile, the block's CPU a window outside its compiled loops (the Python and NumPy that hold the GIL; the
loops' calls timed each, their argument checks counted with them), with ``--against`` for both checkouts and each
compiled loop's CPU a window in both; run it
with ``EVSDA_THREADS=1``, which keeps every call on the block's thread. ``--threads N`` steps two copies of this
checkout's block, on one thread and on N, alternately, and prints both CPU per window (the block's own threads'
cost, with no other block beside it).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/pixel_gil.py [--duration 2] [--inputs F] [--no-profile]
        [--against DIR] [--held] [--threads N]
"""

from __future__ import annotations

import argparse
import cProfile
import copy
import hashlib
import io
import os
import pickle
import pstats
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from evsda.blocks.pixel import block as pixel_block
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

GRAPH = Path(__file__).with_name("end_to_end.yaml")
#: compiled kernels the block calls on its own thread, all ``nogil``
KERNELS = ("select_pixels", "take_and_run", "drive_rows", "own_changes", "under_stamps", "_adds_flux",
           "_sum_stamps", "_summed_stamps", "window_changes", "time_ordered")


def timed_loops(package: str, spent: dict) -> None:
    """Wraps every compiled loop that ``package``'s modules (``evsda.blocks.pixel`` or a copy) call by a global name
    in a timer adding its thread CPU to ``spent[name]`` [ns]."""
    import numba

    def timer(name, loop):
        def timed(*args):
            start = time.thread_time_ns()
            try:
                return loop(*args)
            finally:
                spent[name] = spent.get(name, 0) + time.thread_time_ns() - start
        return timed

    for module in [m for name, m in list(sys.modules.items()) if name.startswith(package + ".")]:
        for name, value in list(vars(module).items()):
            if isinstance(value, numba.core.registry.CPUDispatcher):
                setattr(module, name, timer(name, value))


def pixel_inputs(duration_s: float) -> tuple[pixel_block.DvsPixel, list]:
    """A fresh copy of the pass's pixel block and its (window, irradiance) inputs."""
    kept: dict = {"block": None, "inputs": []}
    step = pixel_block.DvsPixel.step

    def keeping(self, window, irradiance):
        if kept["block"] is None:
            if self._ahead is not None:      # compile_ahead's handle holds a lock, which cannot be copied
                self._ahead.wait()
                self._ahead = None
            kept["block"] = copy.deepcopy(self)
        kept["inputs"].append((window, irradiance))
        return step(self, window, irradiance)

    pixel_block.DvsPixel.step = keeping
    try:
        with tempfile.TemporaryDirectory() as tmp:
            run_graph(load_graph(str(GRAPH), [f"run.duration_s={duration_s}"]), Path(tmp) / "run", progress=False)
    finally:
        pixel_block.DvsPixel.step = step
    return kept["block"], kept["inputs"]


class _Against(pickle.Unpickler):
    """Unpickles the block as an instance of the copied package ``pixel_against`` (another checkout's code)."""

    def find_class(self, module, name):
        if module.startswith("evsda.blocks.pixel."):
            module = "pixel_against." + module[len("evsda.blocks.pixel."):]
        return super().find_class(module, name)


def side_by_side(pickled: bytes, inputs: list, against: Path, held: bool = False) -> None:
    """Steps this checkout's block and ``against``'s (``blocks/pixel`` copied) alternately window by window over
    the same inputs (windows after the first), checks their events are the same, prints the CPU per window
    (``held``: also outside the compiled loops, :func:`timed_loops`)."""
    # one folder per checkout, kept: its copy's Numba cache serves the next run (copytree keeps the files' times,
    # which Numba's cache checks; a changed file is copied again and compiled again)
    root = Path(tempfile.gettempdir()) / f"pixel_against_{hashlib.sha256(bytes(against.resolve())).hexdigest()[:12]}"
    shutil.copytree(against / "blocks" / "pixel", root / "pixel_against", ignore=shutil.ignore_patterns("__pycache__"),
                    dirs_exist_ok=True)
    sys.path.insert(0, str(root))
    blocks = {"this": pickle.loads(pickled), "against": _Against(io.BytesIO(pickled)).load()}
    window, irradiance = inputs[0]
    for block in blocks.values():
        block.step(window, irradiance=irradiance)                # start-up and compiled loops' load, not timed
    spent: dict = {"this": {}, "against": {}}
    if held:
        timed_loops("evsda.blocks.pixel", spent["this"])
        timed_loops("pixel_against", spent["against"])
    cpu: dict = {"this": [], "against": []}
    loops: dict = {"this": [], "against": []}
    for i, (window, irradiance) in enumerate(inputs[1:]):
        events = {}
        for name in ("this", "against") if i % 2 else ("against", "this"):
            before = sum(spent[name].values())
            start = time.process_time()
            events[name] = blocks[name].step(window, irradiance=irradiance)["events"]
            cpu[name].append(time.process_time() - start)
            loops[name].append((sum(spent[name].values()) - before) * 1e-9)
        for field in ("t_ns", "x", "y", "p", "cause"):
            if not np.array_equal(getattr(events["this"], field), getattr(events["against"], field)):
                raise SystemExit(f"window {i + 1}: the events' {field} differ from {against}'s")
    this, other = np.array(cpu["this"]), np.array(cpu["against"])
    print(f"pixel block, {this.size} windows after the first, alternated in one process (load "
          f"{os.getloadavg()[0]:.1f}), the same events: {against} {np.median(other) * 1e3:.2f} ms -> this "
          f"{np.median(this) * 1e3:.2f} ms CPU a window (medians); sums {other.sum():.3f} -> {this.sum():.3f} s, "
          f"ratio of sums {this.sum() / other.sum():.3f}, median of the windows' ratios {np.median(this / other):.3f}")
    if held:
        this_held, other_held = this - np.array(loops["this"]), other - np.array(loops["against"])
        print(f"  outside the compiled loops (GIL held): {against} {np.median(other_held) * 1e3:.2f} ms -> this "
              f"{np.median(this_held) * 1e3:.2f} ms a window (medians); sums {other_held.sum():.3f} -> "
              f"{this_held.sum():.3f} s")
        names = sorted(set(spent["this"]) | set(spent["against"]),
                       key=lambda name: -spent["this"].get(name, 0) - spent["against"].get(name, 0))
        print("  the compiled loops (ms a window, " + f"{against} -> this): " + ", ".join(
            f"{name} {spent['against'].get(name, 0) * 1e-6 / this.size:.2f} -> "
            f"{spent['this'].get(name, 0) * 1e-6 / this.size:.2f}" for name in names))


def threads_side_by_side(pickled: bytes, inputs: list, threads: int) -> None:
    """Steps two copies of this checkout's block alternately window by window over the same inputs, one on one
    thread and one on ``threads`` (``EVSDA_THREADS`` set before each step), checks their events are the same and
    prints the CPU per window of both (every thread of the process) and their ratio: what the block's own threads
    cost, without another block beside it."""
    blocks = {1: pickle.loads(pickled), threads: pickle.loads(pickled)}
    window, irradiance = inputs[0]
    for n, block in blocks.items():
        os.environ["EVSDA_THREADS"] = str(n)
        block.step(window, irradiance=irradiance)                # start-up and compiled loops' load, not timed
    cpu: dict = {n: [] for n in blocks}
    for i, (window, irradiance) in enumerate(inputs[1:]):
        events = {}
        for n in list(blocks) if i % 2 else list(blocks)[::-1]:
            os.environ["EVSDA_THREADS"] = str(n)
            start = time.process_time()
            events[n] = blocks[n].step(window, irradiance=irradiance)["events"]
            cpu[n].append(time.process_time() - start)
        for field in ("t_ns", "x", "y", "p", "cause"):
            if not np.array_equal(getattr(events[1], field), getattr(events[threads], field)):
                raise SystemExit(f"window {i + 1}: the events' {field} differ between 1 and {threads} threads")
    one, more = np.array(cpu[1]), np.array(cpu[threads])
    print(f"pixel block, {one.size} windows after the first, alternated in one process (load "
          f"{os.getloadavg()[0]:.1f}), the same events: 1 thread {np.median(one) * 1e3:.2f} ms -> {threads} threads "
          f"{np.median(more) * 1e3:.2f} ms CPU a window (medians, every thread); sums {one.sum():.3f} -> "
          f"{more.sum():.3f} s, ratio of sums {more.sum() / one.sum():.3f}, median of the windows' ratios "
          f"{np.median(more / one):.3f}")


def held_per_window(block, inputs: list) -> None:
    """Prints the block's CPU a window and the part outside its compiled loops (:func:`timed_loops`), the largest
    loops, and the events' digest."""
    digest = hashlib.sha256()
    window, irradiance = inputs[0]
    block.step(window, irradiance=irradiance)                    # start-up and compiled loops' load, not timed
    spent: dict = {}
    timed_loops("evsda.blocks.pixel", spent)
    cpu = []
    for window, irradiance in inputs[1:]:
        start = time.process_time()
        events = block.step(window, irradiance=irradiance)["events"]
        cpu.append(time.process_time() - start)
        for name in ("t_ns", "x", "y", "p", "cause"):
            digest.update(getattr(events, name).tobytes())
        digest.update(str(events.n_loss).encode())
    n, loops = len(cpu), sum(spent.values()) * 1e-9
    print(f"pixel block, {n} windows after the first (load {os.getloadavg()[0]:.1f}): {sum(cpu) / n * 1e3:.2f} ms CPU "
          f"a window, outside the compiled loops (GIL held) {(sum(cpu) - loops) / n * 1e3:.2f} ms; loops: "
          + ", ".join(f"{k} {v * 1e-6 / n:.2f}" for k, v in sorted(spent.items(), key=lambda kv: -kv[1])))
    print(f"  events' digest {digest.hexdigest()[:16]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=2.0, help="simulated seconds of the pass [s]")
    parser.add_argument("--inputs", type=Path, help="pickle of the captured inputs: written if absent, else read")
    parser.add_argument("--no-profile", action="store_true", help="CPU per window only, without cProfile")
    parser.add_argument("--against", type=Path, help="another checkout whose blocks/pixel steps beside this one")
    parser.add_argument("--held", action="store_true", help="CPU outside the compiled loops, without cProfile")
    parser.add_argument("--threads", type=int, help="this block on 1 and on THREADS threads, alternated")
    args = parser.parse_args()
    if args.inputs is not None and args.inputs.exists():
        with open(args.inputs, "rb") as f:
            block, inputs = pickle.load(f)
    else:
        block, inputs = pixel_inputs(args.duration)
        if args.inputs is not None:
            with open(args.inputs, "wb") as f:
                pickle.dump((block, inputs), f, protocol=5)
    if args.threads is not None:
        threads_side_by_side(pickle.dumps(block, protocol=5), inputs, args.threads)
        return
    if args.against is not None:
        side_by_side(pickle.dumps(block, protocol=5), inputs, args.against, args.held)
        return
    if args.held:
        held_per_window(block, inputs)
        return
    digest = hashlib.sha256()
    window, irradiance = inputs[0]
    block.step(window, irradiance=irradiance)                    # start-up and compiled loops' load, not timed
    profile = cProfile.Profile(time.process_time)
    cpu = time.process_time()
    if not args.no_profile:
        profile.enable()
    for window, irradiance in inputs[1:]:
        events = block.step(window, irradiance=irradiance)["events"]
        for name in ("t_ns", "x", "y", "p", "cause"):
            digest.update(getattr(events, name).tobytes())
        digest.update(str(events.n_loss).encode())
    profile.disable()
    cpu = time.process_time() - cpu
    n = len(inputs) - 1
    if args.no_profile:
        load = os.getloadavg()
        print(f"pixel block, {n} windows after the first: {cpu / n * 1e3:.1f} ms CPU a window (not profiled; "
              f"load {load[0]:.1f}); events' digest {digest.hexdigest()[:16]}")
        return
    kernels, held = {}, []
    for (path, _, name), (_, _, own_s, _, _) in pstats.Stats(profile).stats.items():
        if name in KERNELS:
            kernels[name] = kernels.get(name, 0.0) + own_s
        elif "acquire" not in name and name != "wait":            # waits: the pixel chunks' threads
            held.append((own_s, f"{Path(path).name}:{name}"))
    print(f"pixel block, {n} windows of the {args.duration:g} s tracked pass (windows after the first), per window:")
    print(f"  CPU (every thread, profiled) {cpu / n * 1e3:.1f} ms")
    print("  compiled nogil kernels on the block's thread: "
          + ", ".join(f"{k} {v / n * 1e3:.1f} ms" for k, v in sorted(kernels.items(), key=lambda kv: -kv[1])))
    print(f"  GIL-held Python and NumPy {sum(s for s, _ in held) / n * 1e3:.1f} ms; largest: "
          + ", ".join(f"{name} {s / n * 1e3:.2f}" for s, name in sorted(held, reverse=True)[:6]))
    print(f"  events' digest {digest.hexdigest()[:16]}")


if __name__ == "__main__":
    main()
