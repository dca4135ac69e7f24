"""End to end speed (issue 13): the tracked LEO pass of benchmarks/end_to_end.yaml, as a user runs it.

Prints, each in fresh processes as a user meets them:

1. fixed costs: importing the CLI, loading the graph (which imports the blocks it names) and a
   one-window run, split by block (the optics' set-up and path choice, the pixels' start and
   the load of their compiled loop);
2. the whole run (``evsda run``, every core): wall time against the simulated time, CPU,
   peak memory, events, bytes per event in the finished store, time per block;
3. the optics block alone on one thread, windows not pipelined (so that the process's CPU time
   around its steps is the optics' own): its CPU against the bare FFT cost of the PSFs it
   rendered (a 2-D complex64 FFT of the zero-padded pupil per PSF, timed here on batches of
   256), the ratio issue 13 targets at <= 3.

Targets (issue 13): >= 2x real time in wall time on a 2-core machine, peak memory <= 1 GB,
optics <= 3x its FFT cost, <= 10 bytes per event.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/end_to_end.py [--duration 10] [--repeats 3]
    ... --optics-only --set telescope/optics.psf_path=pupil_fft    # every source through the pupil path
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

GRAPH = Path(__file__).with_name("end_to_end.yaml")


def fresh(code: str, env: dict | None = None, args=(), checkout: Path | None = None) -> dict:
    """Run ``code`` in a fresh interpreter (with ``args`` as its ``sys.argv[1:]`` and ``env`` added to the
    environment); it prints one JSON object as its last line. ``checkout``: run another checkout's code (its
    ``.venv``, from its folder) instead of this one's."""
    python = sys.executable if checkout is None else str(checkout / ".venv" / "bin" / "python")
    out = subprocess.run([python, "-c", code, *args], capture_output=True, text=True,
                         env={**os.environ, **(env or {})}, cwd=checkout)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


#: one thread, one step at a time: the process's CPU around a block's steps is that block's own
ONE_THREAD = {"EVSDA_THREADS": "1", "EVSDA_PIPELINE": "0"}


def checkouts(parser: argparse.ArgumentParser, against: Path | None) -> dict[str, Path | None]:
    """This checkout (``None``) and, given ``--against``, another one with its own ``.venv``, by name."""
    trees: dict[str, Path | None] = {"this checkout": None}
    if against is not None:
        if not (against / ".venv" / "bin" / "python").exists():
            parser.error(f"--against {against}: expected a checkout with its own .venv")
        trees[str(against)] = against
    return trees


def alternated(trees: dict[str, Path | None], repeats: int, run, show) -> tuple[dict[str, list], list[float]]:
    """``run(checkout)`` ``repeats`` times for each of ``trees``, alternated so that they share the machine's
    load; ``show(round, name, result, load)`` after each run. Returns the results by name and each run's load
    average (the mean of the readings before and after it)."""
    runs, loads = {name: [] for name in trees}, []
    for k in range(repeats):
        for name, checkout in trees.items():
            before = os.getloadavg()[0]
            runs[name].append(run(checkout))
            loads.append((before + os.getloadavg()[0]) / 2)
            show(k, name, runs[name][-1], loads[-1])
    return runs, loads


IMPORT_CLI = """
import json, time
t = time.perf_counter()
import evsda.graph.cli
print(json.dumps({"import_cli_s": time.perf_counter() - t}))
"""

LOAD_GRAPH = """
import json, sys, time
import evsda.graph.cli
from evsda.graph.graphfile import load_graph
t = time.perf_counter()
load_graph(sys.argv[1] if len(sys.argv) > 1 else %r, [])
print(json.dumps({"load_graph_s": time.perf_counter() - t, "modules": len(sys.modules)}))
"""

COMPILED_LOAD = """
import json, time
import numpy as np
t = time.perf_counter()
from evsda.blocks.pixel import DvsPixel
from evsda.blocks.optics.layer_screen import LayerScreen
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window
imported = time.perf_counter() - t
fp = FocalPlane(8, 8, 10e-6, 1.0)
t_ns = np.arange(0, 10_000_000, 1_000_000)
irradiance = Irradiance(fp, 550e-9, t_ns, np.full(t_ns.size, 1e5), np.zeros((t_ns.size, 0, 2), np.int32),
                        np.zeros((t_ns.size, 0, 1, 1)))
block = DvsPixel(seed=1)
block.setup(RunInfo(duration_ns=10_000_000))
t = time.perf_counter()
block.step(Window.from_seconds(0, 0.01), irradiance=irradiance)
pixel = time.perf_counter() - t
screen = LayerScreen(40, 0.02, (1,))
t = time.perf_counter()
screen.accumulate(np.tile(np.arange(12.0) + 14, (3, 1)), np.arange(12.0)[None] + 14 + np.arange(3.0)[:, None] * 5,
                  np.zeros(3, np.int64), np.ones(3), np.zeros((3, 12, 12)))
optics = time.perf_counter() - t
print(json.dumps({"import_s": imported, "pixel_s": pixel, "screens_s": optics}))
"""


#: ``evsda`` whose last line gives its own peak RSS and its largest reaped child's (the worker process) [kB]
PEAKS_CODE = ("import resource, sys; from evsda.graph.cli import main; status = main(); "
              "peak = lambda who: resource.getrusage(who).ru_maxrss; "
              "print('evsda-peaks-kb', peak(resource.RUSAGE_SELF), peak(resource.RUSAGE_CHILDREN), file=sys.stderr); "
              "sys.exit(status)")


def _pss_kb(pid: int) -> int:
    """Proportional set size of process ``pid`` [kB] (0 where it cannot be read)."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            return next((int(line.split()[1]) for line in f if line.startswith("Pss:")), 0)
    except (OSError, ValueError):
        return 0


def _sample_pss(pid: int, sampled: dict, done: threading.Event) -> None:
    """The largest sum of the PSS of ``pid`` and its children, every 0.2 s until ``done``, into ``sampled``."""
    while not done.wait(0.2):
        try:
            with open(f"/proc/{pid}/task/{pid}/children") as f:
                children = [int(c) for c in f.read().split()]
        except (OSError, ValueError):
            children = []
        sampled["pss_kb"] = max(sampled["pss_kb"], _pss_kb(pid) + sum(_pss_kb(c) for c in children))


def run_cli(duration: float, store: Path, settings=(), graph: Path = GRAPH, python: Path | None = None) -> dict:
    """``evsda run`` the benchmark graph (or ``graph``) in a child process (``settings``: more ``--set``
    values; ``python``: the interpreter, another checkout's, say; default this one): wall, CPU (the child's and its worker process's), peak memory (the sum of the child's peak RSS
    and its worker's: an upper bound of the two together; and, where Linux's ``smaps_rollup`` can be read, the
    largest sum of the two processes' proportional set sizes sampled every 0.2 s, shared pages counted once) and
    its summary."""
    t = time.perf_counter()
    child = subprocess.Popen([str(python or sys.executable), "-c", PEAKS_CODE,
                              "run", str(graph), "-o", str(store), "--overwrite",
                              "--no-progress", "--set", f"run.duration_s={duration}",
                              *(arg for setting in settings for arg in ("--set", setting))],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    sampled = {"pss_kb": 0}
    done = threading.Event()
    sampler = threading.Thread(target=_sample_pss, args=(child.pid, sampled, done), daemon=True)
    sampler.start()
    text = child.stdout.read()
    done.set()
    sampler.join()
    _, status, usage = os.wait4(child.pid, 0)       # this child's CPU (its reaped worker's included) and memory
    child.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t
    if child.returncode:
        raise RuntimeError(f"evsda run failed ({child.returncode}):\n{text[-3000:]}")
    blocks = {m.group(1): float(m.group(2))
              for m in re.finditer(r"^\s+(\S+)\s+([0-9.]+) s\s+[0-9.]+ %$", text, flags=re.M)}
    events = re.search(r"([0-9]+) events recorded; ([0-9.]+) MB on disk(?:, ([0-9.]+) bytes per event)?", text)
    peaks = re.search(r"^evsda-peaks-kb ([0-9]+) ([0-9]+)$", text, flags=re.M)
    own_kb, worker_kb = (int(peaks.group(1)), int(peaks.group(2))) if peaks else (usage.ru_maxrss, 0)
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_mb": (own_kb + worker_kb) / 1024,
            "own_peak_mb": own_kb / 1024, "worker_peak_mb": worker_kb / 1024,
            "pss_peak_mb": sampled["pss_kb"] / 1024 if sampled["pss_kb"] else float("nan"),
            "blocks": blocks,
            "events": int(events.group(1)) if events else 0, "store_mb": float(events.group(2)) if events else 0.0,
            "bytes_per_event": float(events.group(3)) if events and events.group(3) else float("nan")}


OPTICS_PROBE = """
import functools, json, sys, time
import numpy as np
import scipy.fft as sfft
from evsda.blocks.optics.block import PointSourceOptics
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

spent = {"cpu": 0.0, "frames": {}, "padded": 0}
step = PointSourceOptics.step
@functools.wraps(step)                     # the registry checks step()'s parameters against the block's inputs
def timed(self, *args, **kwargs):
    t = time.process_time()
    out = step(self, *args, **kwargs)
    spent["cpu"] += time.process_time() - t
    spent["frames"] = dict(self._imager.frames_rendered)
    spent["padded"] = self._imager.pupil_renderer.padded
    return out
PointSourceOptics.step = timed
graph = load_graph(%r, ["run.duration_s=%s", *%r])
run_graph(graph, %r, overwrite=True)

size = spent["padded"]
rng = np.random.default_rng(0)
batch = (rng.standard_normal((256, size, size)) + 1j * rng.standard_normal((256, size, size))).astype(np.complex64)
times = []
for _ in range(7):
    t = time.process_time()
    sfft.fft2(batch, workers=1)
    times.append(time.process_time() - t)
per_psf = float(np.median(times)) / 256
print(json.dumps({"optics_cpu_s": spent["cpu"], "frames": spent["frames"], "padded": size, "fft_per_psf_s": per_psf}))
"""


def fixed_costs_and_whole_run(args, store: Path) -> None:
    """Sections 1 and 2: fixed costs in fresh processes, then the whole run on every core."""
    print("\n1. fixed costs (fresh processes, medians of %d)" % args.repeats)
    cli = statistics.median(fresh(IMPORT_CLI)["import_cli_s"] for _ in range(args.repeats))
    loads = [fresh(LOAD_GRAPH % str(GRAPH)) for _ in range(args.repeats)]
    one = [run_cli(0.1, store, args.set) for _ in range(args.repeats)]
    print(f"  import the CLI                 {cli:7.2f} s")
    print(f"  load the graph (block imports) {statistics.median(x['load_graph_s'] for x in loads):7.2f} s "
          f"({loads[0]['modules']} modules loaded)")
    compiled = [fresh(COMPILED_LOAD) for _ in range(args.repeats)]
    print(f"  compiled loops, first call     {statistics.median(x['pixel_s'] for x in compiled):7.2f} s pixels "
          f"(8 x 8 sensor, one window), {statistics.median(x['screens_s'] for x in compiled):.2f} s screen walk "
          f"(Numba's cache loaded; their imports {statistics.median(x['import_s'] for x in compiled):.2f} s)")
    print(f"  a one-window (0.1 s) run       {statistics.median(x['wall_s'] for x in one):7.2f} s wall, "
          f"{statistics.median(x['cpu_s'] for x in one):.2f} s CPU, of which:")
    for name in sorted(one[0]["blocks"], key=lambda n: -one[0]["blocks"][n])[:5]:
        print(f"    {name:28s} {statistics.median(x['blocks'].get(name, 0.0) for x in one):7.2f} s")

    print(f"\n2. the whole run: {args.duration:g} s simulated, every core")
    full = run_cli(args.duration, store, args.set)
    print(f"  wall {full['wall_s']:.1f} s = {args.duration / full['wall_s']:.2f}x real time (target >= 2x); "
          f"CPU {full['cpu_s']:.1f} s; peak memory {full['peak_mb']:.0f} MB (target <= 1000)")
    print(f"  {full['events']} events, store {full['store_mb']:.1f} MB = {full['bytes_per_event']:.1f} bytes "
          f"per event (target <= 10)")
    for name, seconds in sorted(full["blocks"].items(), key=lambda kv: -kv[1])[:6]:
        print(f"    {name:28s} {seconds:7.2f} s")


def optics_probe(args, store: Path) -> None:
    """Section 3: the optics block's CPU on one thread, windows not pipelined, against the bare FFT cost."""
    print(f"\n3. optics on one thread ({args.duration:g} s simulated{', ' + ' '.join(args.set) if args.set else ''})")
    probe = fresh(OPTICS_PROBE % (str(GRAPH), args.duration, list(args.set), str(store)),
                  env={"EVSDA_THREADS": "1", "EVSDA_PIPELINE": "0"})
    # the FFT paths' PSFs (the analytic paths' stamps are tabulated profiles: no FFT)
    psfs = sum(n for path, n in probe["frames"].items() if path in ("pupil_fft", "reference"))
    fft = psfs * probe["fft_per_psf_s"]
    print(f"  PSFs rendered: {sum(probe['frames'].values())} {probe['frames']}")
    print(f"  bare FFT cost of the pupil/reference PSFs: {psfs} x {probe['fft_per_psf_s'] * 1e3:.3f} ms "
          f"({probe['padded']}^2 complex64) = {fft:.2f} s")
    print(f"  optics CPU {probe['optics_cpu_s']:.2f} s = {probe['optics_cpu_s'] / fft:.1f}x its FFT cost "
          f"(target <= 3x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds of the whole run [s]")
    parser.add_argument("--repeats", type=int, default=3, help="fresh processes per fixed cost (medians)")
    parser.add_argument("--skip-optics", action="store_true", help="leave out the single-thread optics probe")
    parser.add_argument("--optics-only", action="store_true", help="only the single-thread optics probe (section 3)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a graph setting for the timed runs (as evsda run --set), e.g. "
                             "telescope/optics.detector=null for the path choice without the detector")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} at the start; "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; settings {args.set}")

    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "run.zarr"
        run_cli(0.1, store, args.set)                             # warm the compiled caches once
        if not args.optics_only:
            fixed_costs_and_whole_run(args, store)
        if not args.skip_optics:
            optics_probe(args, store)
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
