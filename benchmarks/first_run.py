"""What the first ``evsda run`` after an install costs: Numba compiling the optics' and pixels' loops.

Runs the main job (``examples/iss_pass.yaml``, or ``--graph``) with ``evsda run`` in fresh processes, each
round twice: first with an empty Numba cache folder of its own (``NUMBA_CACHE_DIR`` in a temporary folder, as
after an install: every compiled loop is built and written), then again with the folder that run filled (every
later run). It prints the median wall and CPU times of both (the CPU of the run's own child processes included:
the pixels' loops compiled ahead, :mod:`evsda.graph.compile_ahead`), their difference (the first run's compile),
the load average around each run and the store's digest (the compiles change no result). ``--against`` another
checkout with its own ``.venv`` runs the same rounds there, alternated with this one's, each with its own empty
cache folder; ``--also-serial`` runs this checkout a second time with ``EVSDA_COMPILE_AHEAD=off`` (every loop
compiled in the run's own process, one after another). The probe-result cache is off (``EVSDA_CACHE=off``), so both runs do the same work otherwise. The
compile of each function: ``benchmarks/optics_compile.py``; the pixels' own: ``benchmarks/pixel_compile.py``.
``--code`` also prints a digest of the machine code each empty-cache run cached (``optics_compile.py --code``'s):
the same whichever process compiled each loop.
``--timeline`` instead runs this checkout once with an empty cache and prints where the first run's time goes: the
run's own compiles (each outermost one, from Numba's ``numba:compile`` events), the child compiling ahead (from its
start to its end), the pixel block's wait for it (and what it compiled itself meanwhile), and the run's end: which
of the two processes is the critical path; and in CPU seconds, which a loaded host does not stretch as it stretches the
wall, when each process's part would end on two free cores (``--against``: the other checkout's runs alternated).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/first_run.py [--repeats 2] [--against /work/h-audit] [--also-serial] [--code]
    OPENBLAS_NUM_THREADS=1 python benchmarks/first_run.py --timeline [--repeats 1] [--against /work/h-audit]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))

from end_to_end import alternated, checkouts, run_cli                 # noqa: E402
from optics_compile import machine_code                              # noqa: E402
from test_examples_identical import store_digest                     # noqa: E402

MAIN_JOB = Path(__file__).parents[1] / "examples" / "iss_pass.yaml"


SERIAL = "this, not ahead"       # this checkout with EVSDA_COMPILE_AHEAD=off

TIMELINE = r"""
import json, resource, sys, threading, time
begun = time.perf_counter()
def now():
    return round(time.perf_counter() - begun, 2)
cpu = time.process_time
from numba.core import event
from evsda.graph import compile_ahead
marks = {"compiles": [], "child": None, "wait": None}
depth = threading.local()

class Outermost(event.Listener):          # the run's own compiles, each outermost one (nested ones are inside it)
    def on_start(self, ev):
        depth.n = getattr(depth, "n", 0) + 1
        if depth.n == 1:
            f = ev.data["dispatcher"].py_func
            marks["compiles"].append([f.__module__.rsplit(".", 1)[-1] + "." + f.__qualname__, now(), None,
                                      time.thread_time()])
    def on_end(self, ev):
        depth.n -= 1
        if depth.n == 0:
            mark = [m for m in marks["compiles"] if m[2] is None][-1]
            mark[2], mark[3] = now(), time.thread_time() - mark[3]

event.register("numba:compile", Outermost())
start, wait = compile_ahead.Ahead.__init__, compile_ahead.Ahead.wait

def started(self, process, *tasks):
    start(self, process, *tasks)
    if process is not None:
        marks["child"] = [now(), None, cpu()]
        threading.Thread(target=lambda: (process.wait(), marks["child"].__setitem__(1, now())), daemon=True).start()

def waited(self):
    if self.process is None:
        return wait(self)
    waiting, process_cpu, thread_cpu = now(), cpu(), time.thread_time()
    wait(self)
    marks["wait"] = [waiting, now(), process_cpu, time.thread_time() - thread_cpu]

compile_ahead.Ahead.__init__, compile_ahead.Ahead.wait = started, waited
from evsda.graph.cli import main
status = main(["run", sys.argv[1], "-o", sys.argv[2], "--overwrite", "--no-progress",
               "--set", f"run.duration_s={sys.argv[3]}"])
marks["end"] = now()
children = resource.getrusage(resource.RUSAGE_CHILDREN)
marks["child_cpu"] = children.ru_utime + children.ru_stime
print("evsda-timeline " + json.dumps(marks))
"""


def rounds(graph: Path, duration: float, tmp: Path, checkout: Path | str | None, number: list[int],
           code: bool = False) -> dict:
    """One empty-cache run and one filled-cache run of ``checkout`` (None: this one; SERIAL: this one without
    compiling ahead), in a new cache folder; ``code``: with a digest of the machine code the first one cached."""
    number[0] += 1
    os.environ["NUMBA_CACHE_DIR"] = str(tmp / f"numba-{number[0]}")     # empty: compile everything
    os.environ["EVSDA_COMPILE_AHEAD"] = "off" if checkout == SERIAL else "on"
    python = None if checkout in (None, SERIAL) else checkout / ".venv" / "bin" / "python"
    store = tmp / "run.zarr"
    out = {}
    for cache in ("empty", "filled"):
        load = os.getloadavg()[0]
        run = run_cli(duration, store, graph=graph, python=python)
        run["load"] = (load, os.getloadavg()[0])
        run["digest"] = store_digest(store)[:8]
        if code and cache == "empty":
            digests = machine_code(os.environ["NUMBA_CACHE_DIR"])
            run["code"] = f"{hashlib.sha256(json.dumps(digests, sort_keys=True).encode()).hexdigest()[:16]} " \
                          f"({len(digests)} objects)"
        out[cache] = run
    return out


def timeline(graph: Path, duration: float, python: Path | None = None) -> None:
    """One run of this checkout (or ``python``'s) with an empty Numba cache: its compiles, the child's span, the
    wait, the end; and in CPU seconds, where the pixels would be ready on two free cores."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"), EVSDA_CACHE="off")
        load = os.getloadavg()[0]
        out = subprocess.run([str(python or sys.executable), "-c", TIMELINE, str(graph), str(Path(tmp) / "run.zarr"),
                              str(duration)], env=env, capture_output=True, text=True)
    lines = [x for x in out.stdout.splitlines() if x.startswith("evsda-timeline ")]
    if out.returncode or not lines:
        raise RuntimeError(f"evsda run failed ({out.returncode}):\n{(out.stdout + out.stderr)[-3000:]}")
    marks = json.loads(lines[-1].split(" ", 1)[1])
    compiles, child, wait = marks["compiles"], marks["child"], marks["wait"]
    print(f"{graph.name}, {duration:g} s simulated, empty Numba cache, {python or 'this checkout'}, load {load:.2f} -> "
          f"{os.getloadavg()[0]:.2f} (seconds from the run's start):")
    if compiles:
        print(f"  the run's own compiles: {compiles[0][1]:.1f} -> {compiles[-1][2]:.1f} s "
              f"({sum(b - a for _, a, b, _ in compiles):.1f} s in {len(compiles)} outermost compiles, "
              f"{sum(c for *_, c in compiles):.1f} s CPU)")
    print(f"  the child compiling ahead: {child[0]:.1f} -> {child[1]:.1f} s" if child else "  no child")
    if wait:
        print(f"  the pixel block waited for it: {wait[0]:.1f} -> {wait[1]:.1f} s, compiling {wait[3]:.1f} s CPU itself")
    print(f"  the run's end: {marks['end']:.1f} s")
    if child and wait:
        ours, theirs = wait[2] + wait[3], child[2] + marks["child_cpu"]
        print(f"  in CPU seconds of the run's process: the child started at {child[2]:.1f} and took "
              f"{marks['child_cpu']:.1f} (ends at {theirs:.1f}); the block's wait began at {wait[2]:.1f}, its own "
              f"compiles end at {ours:.1f}: on two free cores the pixels are ready at ~{max(ours, theirs):.1f}")
    for name, a, b, c in compiles:
        print(f"    {name:48s} {a:6.1f} {b:6.1f}  {c:5.1f} s CPU")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=MAIN_JOB, help="graph file (default: the main job)")
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds per run [s]")
    parser.add_argument("--repeats", type=int, default=2, help="rounds of an empty-cache and a filled-cache run")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv) run alternately")
    parser.add_argument("--also-serial", action="store_true", help="this checkout also with EVSDA_COMPILE_AHEAD=off")
    parser.add_argument("--timeline", action="store_true", help="one empty-cache run: where its time goes")
    parser.add_argument("--code", action="store_true", help="a digest of each empty-cache run's cached machine code")
    args = parser.parse_args()
    if args.timeline:
        trees = checkouts(parser, args.against)
        for _ in range(args.repeats):
            for checkout in trees.values():
                timeline(args.graph, args.duration, checkout and checkout / ".venv" / "bin" / "python")
        return
    os.environ["EVSDA_CACHE"] = "off"
    trees = checkouts(parser, args.against)
    if args.also_serial:
        trees[SERIAL] = SERIAL

    def show(k: int, name: str, result: dict, load: float) -> None:
        for cache, run in result.items():
            print(f"  {k + 1}. {name:16s} Numba cache {cache:6s} wall {run['wall_s']:6.1f} s  CPU {run['cpu_s']:6.1f} s"
                  f"  load {run['load'][0]:.2f} -> {run['load'][1]:.2f}  digest {run['digest']}"
                  + (f"  machine code {run['code']}" if "code" in run else ""), flush=True)

    number = [0]
    with tempfile.TemporaryDirectory() as tmp:
        runs, loads = alternated(trees, args.repeats,
                                 lambda tree: rounds(args.graph, args.duration, Path(tmp), tree, number, args.code),
                                 show)
    print(f"\n{args.graph.name}, {args.duration:g} s simulated, medians of {args.repeats} "
          f"(load {min(loads):.1f}-{max(loads):.1f}):")
    for name, results in runs.items():
        wall = {c: statistics.median(r[c]["wall_s"] for r in results) for c in ("empty", "filled")}
        cpu = {c: statistics.median(r[c]["cpu_s"] for r in results) for c in ("empty", "filled")}
        digests = " ".join(sorted({r[c]["digest"] for r in results for c in r}))
        print(f"  {name}: Numba cache empty wall {wall['empty']:5.1f} s CPU {cpu['empty']:5.1f} s; filled wall "
              f"{wall['filled']:4.1f} s CPU {cpu['filled']:4.1f} s; the first run's compile "
              f"{wall['empty'] - wall['filled']:.1f} s wall, {cpu['empty'] - cpu['filled']:.1f} s CPU; digest {digests}")


if __name__ == "__main__":
    main()
