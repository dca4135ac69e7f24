"""Where the wall time of a run goes, thread by thread (issue 13): a timeline of one ``evsda run``.

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml, pipelined as by default) in a
child process that notes, on each thread, when each block step (block, window), each item of the blocks'
parallel loops (:func:`evsda.graph.threads.parallel_map`), each recording of a window, each Numba cache load,
each path choice and probe starts and ends, with the thread's CPU time at both ends. The parent reads every
thread's scheduler statistics (``/proc/PID/task/TID/schedstat``: time on a core, time queued for one) and the
machine's (``/proc/stat``) every ``--sample-ms``. It prints:

* the stretches of the wall: the interpreter and imports, the graph's load, the blocks' set-up, the first
  window until the pixels start (the optics' first window, its path-choice probes and Numba loads), the
  steady part, the tail after the optics' last step, the finish and the store; for each, how many of the
  run's threads were on a core on average and how much the machine's other processes ran;
* how long the run had no core, one core or both busy (``--cores``), and the core-seconds left idle;
* per thread: its steps, time on a core, time queued for a core (taken by other processes), and time in a
  step off a core (waiting for the interpreter lock, or for helpers at the end of a parallel loop);
* the optics' chain of windows: its steps' wall, and the gaps between one optics step and the next, with
  what the optics waited for;
* ``blocked_s``: the time the step threads spent in steps neither on a core nor queued for one (waiting for the
  interpreter lock, or for helpers at the end of a parallel loop), summed over the threads;
* with ``--quiet``, one line a run: wall, CPU, cores, peak memory, each block's CPU (the optics', the pixels', the
  other blocks' together: steps and their loops' items on other threads; and the CPU outside the steps: the
  imports, the store, the pipeline's threads), ``kslices`` (thousands of times the run's threads were put on a
  core: how often their work was interleaved), ``kmigrations`` (thousands of times they were moved to another core,
  read every tenth sample), ``kvoluntary`` and ``kinvoluntary`` (thousands of times they left a core to wait, for the
  interpreter lock say, and were taken off one still runnable), the wall with one core or none busy, the optics' gaps,
  when the
  graph was loaded and the pixels' first step started, and the wall after the optics' last step (the tail, the
  finish and the exit).

``--pin CPUS`` runs the child on those cores only (``0``: one core) while it still plans for every core of the
machine (``EVSDA_THREADS``, unless set): its threads then take turns on the pinned cores, so the CPU time of two
variants compares their scheduling (the interpreter lock's hand-overs, context switches, threads sharing a core)
apart from how much slower each thread runs on this host when two of them run at once.

``TIMELINE_SWITCH_INTERVAL_S`` in a variant's environment sets the child's ``sys.setswitchinterval`` (CPython's
default 0.005 s: how long a thread that wants the interpreter lock waits before the holder is asked to hand it
over), e.g. ``--variant si20:TIMELINE_SWITCH_INTERVAL_S=0.02``; ``TIMELINE_PIN=0`` runs that variant's child on
those cores only (set ``EVSDA_THREADS`` beside it to plan for both: ``--variant pin0:TIMELINE_PIN=0,EVSDA_THREADS=2``,
pinned against free in the same minutes); ``TIMELINE_BATCH=1`` makes every thread of the child a ``SCHED_BATCH`` one
(Linux: a woken thread waits for the running one's turn to end instead of taking its core). ``--blocks`` adds each
block's CPU to the one line a run.

``--concurrency`` fits, over every run, each block-window's CPU against the share of its wall during which two of
the run's threads were on the two cores at once and the share during which one ran beside another process (each
block-window against its own mean over the runs, so only the same work is compared): with ``--variant
pin0:TIMELINE_PIN=0,EVSDA_THREADS=2`` on a quiet machine, what running at once costs. Noisy: 10 runs or more.

``--trace out.json`` writes the spans and the cores-busy counter in Chrome's trace format (open it in
https://ui.perfetto.dev). ``--against OTHER`` runs another checkout's ``evsda`` (its own ``.venv``) too,
alternated. Run it with the probe cache off, as the benchmarks do:

    EVSDA_CACHE=off OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/framework_timeline.py [--duration 10]
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

GRAPH = Path(__file__).with_name("end_to_end.yaml")

#: the child: ``evsda`` (its CLI's ``main``) with spans noted on every thread; argv[1] is where the spans go
CHILD = r'''
import json, os, sys, threading, time
T0 = time.monotonic()
if os.environ.get("TIMELINE_SWITCH_INTERVAL_S"):           # a variant: the interpreter lock's hand-over interval
    sys.setswitchinterval(float(os.environ["TIMELINE_SWITCH_INTERVAL_S"]))
if os.environ.get("TIMELINE_PIN"):                         # a variant: every thread on these cores
    os.sched_setaffinity(0, {int(c) for c in os.environ["TIMELINE_PIN"].split(",")})
if os.environ.get("TIMELINE_BATCH"):                       # a variant: every thread SCHED_BATCH (no wake-up preemption)
    os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
import evsda.graph.cli as cli
from evsda.graph import executor as ex, threads as th
T_IMPORTED = time.monotonic()
spans, names, local = [], {}, threading.local()

def note(kind, label, window, t0, c0):
    tid = threading.get_native_id()
    names.setdefault(tid, threading.current_thread().name)
    spans.append((tid, kind, label, window, t0, time.monotonic(), c0, time.thread_time()))

def spanned(kind, label_of, window_of=lambda *a: -1):
    def wrap(fn):
        def inner(*args, **kwargs):
            t0, c0 = time.monotonic(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                note(kind, label_of(*args), window_of(*args), t0, c0)
        inner.__wrapped__ = fn
        return inner
    return wrap

def step(fn):
    def inner(self, name, window, inputs):
        local.block, local.window = name, window.index
        t0, c0 = time.monotonic(), time.thread_time()
        try:
            return fn(self, name, window, inputs)
        finally:
            note("step", name, window.index, t0, c0)
            local.block = None
    return inner

plain_map = th.parallel_map
def parallel_map(fn, items, threads):
    block, window = getattr(local, "block", None), getattr(local, "window", -1)
    def item(x):
        t0, c0 = time.monotonic(), time.thread_time()
        try:
            return fn(x)
        finally:
            note("item", block, window, t0, c0)
    return plain_map(item, items, threads)
th.parallel_map = parallel_map

ex.Executor._step_block = step(ex.Executor._step_block)
ex.Executor._record_window = spanned("store", lambda *a: "record", lambda s, w, *a: w.index)(ex.Executor._record_window)
ex.Executor._commit = spanned("store", lambda *a: "commit")(ex.Executor._commit)
for method in ("_execute", "_run_windows", "_finish_blocks", "_finish_store"):
    setattr(ex.Executor, method, spanned("phase", lambda *a, m=method: m)(getattr(ex.Executor, method)))

plain_load = cli.load_graph
def load_graph(*args, **kwargs):
    t0, c0 = time.monotonic(), time.thread_time()
    graph = plain_load(*args, **kwargs)
    note("phase", "load_graph", -1, t0, c0)
    for module in list(sys.modules.values()):             # the blocks imported parallel_map by name
        if getattr(module, "parallel_map", None) is plain_map:
            module.parallel_map = parallel_map
    extras = [("numba.core.caching", "Cache", "_load_overload", "numba load"),   # under numba_loads' edit too
              ("evsda.blocks.optics.imaging", "Imager", "prepare", "path choice"),
              ("evsda.blocks.optics.paths", "PathChooser", "_remembered", "probe"),
              ("evsda.blocks.optics.paths", "PathChooser", "probe_ahead", "probe")]
    for module, cls, method, kind in extras:
        owner = getattr(sys.modules.get(module), cls, None)
        if owner is not None and hasattr(owner, method):
            setattr(owner, method, spanned(kind, lambda *a: getattr(local, "block", None),
                                           lambda *a: getattr(local, "window", -1))(getattr(owner, method)))
    return graph
cli.load_graph = load_graph

spans_path, sys.argv = sys.argv[1], ["evsda", *sys.argv[2:]]
try:
    status = cli.main()                                    # as the evsda script calls it
finally:
    text = json.dumps({"t0": T0, "imported": T_IMPORTED, "end": time.monotonic(), "spans": spans,
                       "names": {str(k): v for k, v in names.items()}})
    with open(spans_path, "w") as f:
        f.write(text[:-1] + ', "dumped": %r}' % time.monotonic())      # the exit starts here
sys.exit(status)
'''

CLOCK_TICK_S = 1 / os.sysconf("SC_CLK_TCK")
#: ``--blocks``: each block's CPU in the one line a run
BLOCKS_IN_LINE = False


def _per_thread(pid: int, read) -> dict[int, object]:
    """``read(tid)`` of each thread of ``pid`` that it reads (threads that end meanwhile, or files the kernel does
    not show, left out)."""
    out = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            value = read(f"/proc/{pid}/task/{tid}")
        except (OSError, ValueError):
            continue
        if value is not None:
            out[int(tid)] = value
    return out


def _schedstat(pid: int) -> dict[int, tuple[int, int, int]]:
    """Each thread of ``pid``: (time on a core [ns], time queued for one [ns], times it was put on a core)."""
    def read(task: str) -> tuple[int, int, int]:
        with open(f"{task}/schedstat") as f:
            on_core, queued, slices = f.read().split()
        return int(on_core), int(queued), int(slices)
    return _per_thread(pid, read)


#: the counts of ``/proc/PID/task/TID/sched`` read for each thread
SCHED_COUNTS = ("se.nr_migrations", "nr_voluntary_switches", "nr_involuntary_switches")


def _sched_counts(pid: int) -> dict[int, tuple[int, ...]]:
    """Each thread of ``pid``: the times the scheduler moved it to another core, the times it left a core waiting
    (a lock, a condition, I/O) and the times it was taken off one still runnable (:data:`SCHED_COUNTS` of
    ``/proc/PID/task/TID/sched``; empty where the kernel does not show them)."""
    def read(task: str) -> tuple[int, ...] | None:
        counts = {}
        with open(f"{task}/sched") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() in SCHED_COUNTS:
                    counts[key.strip()] = int(float(value))
        return tuple(counts[k] for k in SCHED_COUNTS) if len(counts) == len(SCHED_COUNTS) else None
    return _per_thread(pid, read)


def _machine_busy() -> float:
    """The machine's busy time, every core, since boot [s] (``/proc/stat``)."""
    with open("/proc/stat") as f:
        values = [int(v) for v in f.readline().split()[1:]]
    return (sum(values[:8]) - values[3] - values[4]) * CLOCK_TICK_S      # all but idle and iowait


def sample_run(python: Path, graph: Path, duration: float, store: Path, sample_s: float, env: dict,
               pin: set[int] | None = None) -> dict:
    """One timed run (``env``: more environment; ``pin``: the cores it may run on, default any): the child's spans
    and the samples [(t, {tid: (on core, queued)}, machine busy)]."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as f:
        spans_path = Path(f.name)
    env = {**os.environ, **env}
    start = time.monotonic()
    child = subprocess.Popen([str(python), "-c", CHILD, str(spans_path), "run", str(graph), "-o", str(store),
                              "--overwrite", "--no-progress", "--quiet", "--set", f"run.duration_s={duration}"],
                             env=env, stderr=(errors := tempfile.TemporaryFile("w+")),
                             preexec_fn=None if pin is None else lambda: os.sched_setaffinity(0, pin))
    samples, last, moved = [], {}, {}
    while True:
        pid, status, usage = os.wait4(child.pid, os.WNOHANG)
        if pid:
            break
        last.update(_schedstat(child.pid))                  # a thread that ended keeps its last reading
        if len(samples) % 10 == 0:
            moved.update(_sched_counts(child.pid))
        samples.append((time.monotonic(), dict(last), _machine_busy()))
        time.sleep(sample_s)
    end = time.monotonic()
    samples.append((end, dict(last), _machine_busy()))
    child.returncode = os.waitstatus_to_exitcode(status)           # reaped here, with its peak memory
    if child.returncode:
        errors.seek(0)
        raise RuntimeError(f"evsda run failed ({child.returncode}): {errors.read()[-3000:]}")
    data = json.loads(spans_path.read_text())
    spans_path.unlink()
    data.update(start=start, stop=end, samples=samples, peak_mb=usage.ru_maxrss / 1024,
                sched_counts={tid: list(c) for tid, c in moved.items()})
    return data


def busy_series(data: dict, cores: int) -> list[tuple[float, float, float, float]]:
    """Per sample interval: (start, end, the run's threads on a core, the machine's other processes on one)."""
    out = []
    for (t0, a, m0), (t1, b, m1) in zip(data["samples"], data["samples"][1:]):
        dt = t1 - t0
        if dt <= 0:
            continue
        ours = sum(b[tid][0] - a.get(tid, (0, 0, 0))[0] for tid in b) / 1e9 / dt
        others = max(0.0, (m1 - m0) / dt - ours)
        out.append((t0, t1, min(ours, cores), min(others, cores)))
    return out


def average_over(series, a: float, b: float) -> tuple[float, float]:
    """The run's and the others' cores busy on average over [a, b]."""
    ours = others = 0.0
    for t0, t1, o, x in series:
        overlap = min(b, t1) - max(a, t0)
        if overlap > 0:
            ours += o * overlap
            others += x * overlap
    return (ours / (b - a), others / (b - a)) if b > a else (0.0, 0.0)


def stretches(data: dict) -> list[tuple[str, float, float]]:
    """The stretches of the wall: (what, start, end), on the parent's clock."""
    spans = data["spans"]
    phase = {s[2]: s for s in spans if s[1] == "phase"}
    steps = [s for s in spans if s[1] == "step"]
    optics = sorted((s for s in steps if s[2].endswith("optics")), key=lambda s: s[4])
    pixels = sorted((s for s in steps if s[2].endswith("pixel")), key=lambda s: s[4])
    marks = [("interpreter start and imports", data["start"], data["imported"]),
             ("graph load (block imports)", data["imported"], phase["load_graph"][5]),
             ("set-up (store, blocks' setup)", phase["load_graph"][5], phase["_run_windows"][4]),
             ("window 0 until the pixels start", phase["_run_windows"][4], pixels[0][4] if pixels else phase["_run_windows"][4]),
             ("steady: pixels started, optics on", pixels[0][4] if pixels else phase["_run_windows"][4],
              optics[-1][5] if optics else phase["_run_windows"][5]),
             ("tail: after the optics' last step", optics[-1][5] if optics else phase["_run_windows"][5],
              phase["_run_windows"][5]),
             ("finish, store, summary", phase["_run_windows"][5], data["end"]),
             ("interpreter exit", data["dumped"], data["stop"])]
    return marks


def report(data: dict, cores: int, label: str) -> dict:
    """Print the figures of one run; return the headline ones."""
    series = busy_series(data, cores)
    wall = data["stop"] - data["start"]
    last = data["samples"][-1][1]
    cpu = sum(on for on, _, _ in last.values()) / 1e9
    queued = sum(q for _, q, _ in last.values()) / 1e9
    slices = sum(n for _, _, n in last.values())
    print(f"\n== {label}: wall {wall:.2f} s, the run's threads on a core {cpu:.2f} s ({cpu / wall:.2f} cores on "
          f"average of {cores}), queued for a core {queued:.2f} s, peak {data['peak_mb']:.0f} MB")
    print("  stretch                                   from     to   wall  our cores  others' cores")
    for what, a, b in stretches(data):
        ours, others = average_over(series, a, b)
        print(f"  {what:38s} {a - data['start']:6.2f} {b - data['start']:6.2f} {b - a:6.2f}   {ours:6.2f}     {others:6.2f}")
    levels = [0.0] * 3
    for t0, t1, ours, _ in series:
        levels[0 if ours < 0.5 else 1 if ours < 1.5 else 2] += t1 - t0
    idle = cores * wall - cpu
    others_idle = sum((t1 - t0) * min(x, cores - o) for t0, t1, o, x in series)
    print(f"  wall with no core busy (< 0.5) {levels[0]:.2f} s, one (0.5-1.5) {levels[1]:.2f} s, two (>= 1.5) "
          f"{levels[2]:.2f} s; {idle:.2f} core-s not ours, of which other processes ran {others_idle:.2f}")

    spans = data["spans"]
    by_thread = defaultdict(list)
    for s in spans:
        by_thread[s[0]].append(s)
    print("  thread                 blocks (steps / items)                           on core  queued  in step off core"
          "  switches: waited / taken off")
    blocked = 0.0
    for tid, (on, q, _) in sorted(last.items(), key=lambda kv: -kv[1][0]):
        own = by_thread.get(tid, [])
        steps = [s for s in own if s[1] == "step"]
        items = [s for s in own if s[1] == "item"]
        counted = defaultdict(int)
        for s in steps:
            counted[s[2]] += 1
        for s in items:
            counted[f"{s[2]} items"] += 1
        top = ", ".join(f"{n} {c}" for n, c in sorted(counted.items(), key=lambda kv: -kv[1])[:3])
        in_steps = sum(s[5] - s[4] for s in steps)
        off = in_steps - sum(s[7] - s[6] for s in steps)
        name = data["names"].get(str(tid), "main" if tid == min(last) else "?")
        if steps:
            blocked += max(0.0, off - q / 1e9)
        if on / 1e9 >= 0.01:
            _, waited, taken = data["sched_counts"].get(tid, (0, 0, 0))
            print(f"  {name[:22]:22s} {top[:48]:48s} {on / 1e9:7.2f} {q / 1e9:7.2f}  {off:7.2f}  {waited:7d} / {taken:d}")

    print("  block            steps  wall in steps  CPU in steps  CPU of its items (all threads)")
    blocks = defaultdict(lambda: [0, 0.0, 0.0, 0.0])
    for s in spans:
        if s[1] == "step":
            b = blocks[s[2]]
            b[0] += 1
            b[1] += s[5] - s[4]
            b[2] += s[7] - s[6]
        elif s[1] == "item" and s[2]:
            blocks[s[2]][3] += s[7] - s[6]
    for name, (n, w, c, i) in sorted(blocks.items(), key=lambda kv: -kv[1][1])[:6]:
        print(f"  {name:16s} {n:5d}  {w:13.2f}  {c:12.2f}  {i:10.2f}")
    extra = defaultdict(lambda: [0, 0.0, 0.0])
    for s in spans:
        if s[1] in ("numba load", "path choice", "probe", "store"):
            e = extra[(s[1], s[3] == 0)]
            e[0] += 1
            e[1] += s[5] - s[4]
            e[2] += s[7] - s[6]
    for (kind, first), (n, w, c) in sorted(extra.items()):
        print(f"  {kind + (' (window 0)' if first else ''):28s} {n:5d} spans, wall {w:6.2f} s, CPU {c:6.2f} s")

    optics = sorted((s for s in spans if s[1] == "step" and s[2].endswith("optics")), key=lambda s: s[3])
    window_end = defaultdict(float)                      # each window's last step's end
    for s in spans:
        if s[1] == "step":
            window_end[s[3]] = max(window_end[s[3]], s[5])
    gaps = [b[4] - a[5] for a, b in zip(optics, optics[1:])]
    limit = sum(min(g, max(0.0, window_end[b[3] - 2] - a[5])) for g, a, b in zip(gaps, optics, optics[1:])
                if b[3] - 2 in window_end)
    total_gap = sum(gaps)
    print(f"  optics chain: {len(optics)} steps, {sum(s[5] - s[4] for s in optics):.2f} s in steps; gaps between "
          f"steps {total_gap:.2f} s (median {statistics.median(gaps) * 1e3 if gaps else 0:.1f} ms), {limit:.2f} s "
          f"of them waiting for window k - 2 to end (the windows-ahead limit)")
    marks = {what: (a, b) for what, a, b in stretches(data)}
    by_block = block_cpu(spans)
    optics_cpu = sum(c for name, c in by_block.items() if name.endswith("optics"))
    pixel_cpu = sum(c for name, c in by_block.items() if name.endswith("pixel"))
    return {"wall_s": wall, "cpu_s": cpu, "queued_s": queued, "cores": cpu / wall, "peak_mb": data["peak_mb"],
            "optics_cpu_s": optics_cpu, "pixel_cpu_s": pixel_cpu,
            "other_blocks_cpu_s": sum(by_block.values()) - optics_cpu - pixel_cpu,
            "outside_steps_cpu_s": cpu - sum(by_block.values()), "kslices": slices / 1e3,
            **{f"k{name}": sum(c[i] for c in data["sched_counts"].values()) / 1e3
               for i, name in enumerate(("migrations", "voluntary", "involuntary"))},
            "one_or_none_s": levels[0] + levels[1], "optics_gaps_s": total_gap, "blocked_s": blocked,
            "loaded_s": marks["graph load (block imports)"][1] - data["start"],
            "pixels_start_s": marks["window 0 until the pixels start"][1] - data["start"],
            "after_optics_s": data["stop"] - marks["tail: after the optics' last step"][0],
            **({f"cpu_{name.rsplit('/', 1)[-1]}": c for name, c in sorted(by_block.items(), key=lambda kv: -kv[1])}
               if BLOCKS_IN_LINE else {})}


def block_cpu(spans: list) -> dict[str, float]:
    """Each block's CPU over the run [s]: its steps, and the items of its parallel loops run by other threads (an
    item on the step's own thread is inside the step)."""
    cpu = defaultdict(float)
    step_thread = {}
    for s in spans:
        if s[1] == "step":
            cpu[s[2]] += s[7] - s[6]
            step_thread[(s[2], s[3])] = s[0]
    for s in spans:
        if s[1] == "item" and s[2] and step_thread.get((s[2], s[3])) != s[0]:
            cpu[s[2]] += s[7] - s[6]
    return dict(cpu)


def unit_concurrency(data: dict, first_window: int = 2) -> dict[tuple[str, int], tuple[float, float, float]]:
    """Each block's work over each window from ``first_window`` on (the first ones carry set-ups and compiles),
    ``(block, window)``: its CPU [s] (its step and its loops' items on other threads, as :func:`block_cpu` counts
    them) and, weighted by its spans' CPU, the share of its spans' wall during which two of the run's threads were on
    the two cores at once and the share during which one of the run's threads ran beside another process (from the
    samples: ``max(0, ours - 1)`` and ``max(0, min(ours, 1) + others - 1)`` cores an interval)."""
    intervals = []
    for (t0, a, m0), (t1, b, m1) in zip(data["samples"], data["samples"][1:]):
        if t1 > t0:
            ours = sum(b[tid][0] - a.get(tid, (0, 0, 0))[0] for tid in b) / 1e9 / (t1 - t0)
            others = max(0.0, (m1 - m0) / (t1 - t0) - ours)
            intervals.append((t0, t1, max(0.0, ours - 1), max(0.0, min(ours, 1.0) + others - 1)))
    starts = [i[0] for i in intervals]
    step_thread = {(s[2], s[3]): s[0] for s in data["spans"] if s[1] == "step"}
    units = defaultdict(lambda: [0.0, 0.0, 0.0])
    for tid, kind, label, window, a, b, c0, c1 in data["spans"]:
        if kind not in ("step", "item") or not label or window < first_window or b <= a:
            continue
        if kind == "item" and step_thread.get((label, window)) == tid:
            continue                                       # inside its step's span already
        both, beside, seen = 0.0, 0.0, 0.0
        for t0, t1, two_ours, ours_and_other in intervals[max(0, bisect.bisect_right(starts, a) - 1):]:
            if t0 >= b:
                break
            overlap = min(b, t1) - max(a, t0)
            if overlap > 0:
                both += overlap * two_ours
                beside += overlap * ours_and_other
                seen += overlap
        if seen > 0:
            unit = units[(label, window)]
            unit[0] += c1 - c0
            unit[1] += (c1 - c0) * both / seen
            unit[2] += (c1 - c0) * beside / seen
    return {key: (c, o / c, m / c) for key, (c, o, m) in units.items() if c > 0}


def fit_concurrency(runs: list[dict], smallest_s: float = 0.002) -> None:
    """Print, pooled over the runs, how a block-window's CPU grows with the run's other threads on a core meanwhile
    and with the other processes' busy cores: log CPU against both, each unit against its own mean over the runs
    (so only the same work is compared), weighted by the unit's CPU, per block and for all."""
    keys = set.intersection(*(set(r) for r in runs))
    rows = defaultdict(list)
    for key in keys:
        values = [r[key] for r in runs]
        mean_cpu = statistics.fmean(v[0] for v in values)
        if mean_cpu < smallest_s:
            continue
        logs = [math.log(v[0]) for v in values]
        means = [statistics.fmean(x) for x in (logs, [v[1] for v in values], [v[2] for v in values])]
        for lg, (_, ours, machine) in zip(logs, values):
            rows[key[0]].append((mean_cpu, lg - means[0], ours - means[1], machine - means[2]))
    rows["all"] = [row for block in list(rows) for row in rows[block]]
    print(f"\nCPU of the same block-window against concurrency, {len(runs)} runs (weighted least squares, no intercept):")
    print("  block              units  two of ours at once (all the span)  ours beside another process (all the span)")
    for block, data in sorted(rows.items(), key=lambda kv: -sum(r[0] for r in kv[1])):
        w = [r[0] for r in data]
        sxx = sum(wi * r[2] ** 2 for wi, r in zip(w, data))
        syy = sum(wi * r[3] ** 2 for wi, r in zip(w, data))
        sxy = sum(wi * r[2] * r[3] for wi, r in zip(w, data))
        sx = sum(wi * r[2] * r[1] for wi, r in zip(w, data))
        sy = sum(wi * r[3] * r[1] for wi, r in zip(w, data))
        det = sxx * syy - sxy ** 2
        if det <= 0 or len(data) < 10:
            continue
        b_ours, b_machine = (syy * sx - sxy * sy) / det, (sxx * sy - sxy * sx) / det
        residual = sum(wi * (r[1] - b_ours * r[2] - b_machine * r[3]) ** 2 for wi, r in zip(w, data)) / sum(w)
        scale = residual * sum(w) / max(1, len(data) - 2)
        print(f"  {block[:18]:18s} {len(data):6d}  {math.expm1(b_ours) * 100:+7.1f} % (+- {math.sqrt(scale * syy / det) * 100:4.1f})"
              f"                {math.expm1(b_machine) * 100:+7.1f} % (+- {math.sqrt(scale * sxx / det) * 100:4.1f})")


def write_trace(data: dict, path: Path, cores: int) -> None:
    """The spans and the cores-busy counter in Chrome's trace format [us]."""
    t0 = data["start"]
    events = [{"name": f"{s[2]} {s[3]}" if s[3] >= 0 else str(s[2]), "cat": s[1], "ph": "X", "pid": 1, "tid": s[0],
               "ts": (s[4] - t0) * 1e6, "dur": (s[5] - s[4]) * 1e6, "args": {"cpu_s": s[7] - s[6]}}
              for s in data["spans"]]
    events += [{"name": "thread_name", "ph": "M", "pid": 1, "tid": int(tid), "args": {"name": name}}
               for tid, name in data["names"].items()]
    events += [{"name": "cores busy", "ph": "C", "pid": 1, "ts": (a - t0) * 1e6, "args": {"ours": o, "others": x}}
               for a, _, o, x in busy_series(data, cores)]
    path.write_text(json.dumps({"traceEvents": events}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each checkout or variant, alternated")
    parser.add_argument("--sample-ms", type=float, default=10.0, help="scheduler statistics read every [ms]")
    parser.add_argument("--cores", type=int, default=len(os.sched_getaffinity(0)), help="the machine's cores")
    parser.add_argument("--serial", action="store_true", help="one step at a time (EVSDA_PIPELINE=0)")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv), run alternately")
    parser.add_argument("--variant", action="append", default=[], metavar="LABEL:VAR=VALUE[,VAR=VALUE]",
                        help="this checkout with more environment, run alternately (repeat for more)")
    parser.add_argument("--pin", metavar="CPUS", help="run on these cores only, e.g. 0 or 0,1, planning for every "
                                                      "core (EVSDA_THREADS = the machine's cores unless set)")
    parser.add_argument("--quiet", action="store_true", help="print only one line a run and the medians")
    parser.add_argument("--blocks", action="store_true", help="each block's CPU in the one line a run too")
    parser.add_argument("--concurrency", action="store_true",
                        help="at the end, fit each block-window's CPU against the run's other threads on a core and the "
                             "other processes' busy cores meanwhile (pooled over every run of every variant)")
    parser.add_argument("--trace", type=Path, help="write the last run's spans here (Chrome trace format)")
    args = parser.parse_args()
    global BLOCKS_IN_LINE
    BLOCKS_IN_LINE = args.blocks
    pipeline = {"EVSDA_PIPELINE": "0" if args.serial else "1"}
    pin = None if args.pin is None else {int(cpu) for cpu in args.pin.split(",")}
    if pin is not None:
        pipeline["EVSDA_THREADS"] = os.environ.get("EVSDA_THREADS") or str(len(os.sched_getaffinity(0)))
    runs = {"this": (Path(sys.executable), pipeline)}
    for text in args.variant:
        label, _, settings = text.partition(":")
        runs[label] = (Path(sys.executable), {**pipeline, **dict(kv.split("=", 1) for kv in settings.split(","))})
    if args.against is not None:
        runs[str(args.against)] = (args.against / ".venv" / "bin" / "python", pipeline)
    print(f"{args.graph.name}, {args.duration:g} s simulated, {'serial' if args.serial else 'pipelined'}; "
          f"EVSDA_CACHE={os.environ.get('EVSDA_CACHE', 'unset')}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; load {os.getloadavg()[0]:.2f}"
          + ("" if pin is None else f"; pinned to cores {sorted(pin)}, EVSDA_THREADS={pipeline['EVSDA_THREADS']}"))
    headline = defaultdict(list)
    concurrency = []
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for label, (python, env) in runs.items():
                load = os.getloadavg()[0]
                data = sample_run(python, args.graph, args.duration, Path(tmp) / "run.zarr", args.sample_ms / 1e3, env,
                                   pin)
                title = f"{label} run {repeat + 1}, load {load:.2f}-{os.getloadavg()[0]:.2f}"
                if args.quiet:
                    with open(os.devnull, "w") as sink:
                        stdout, sys.stdout = sys.stdout, sink
                        try:
                            figures = report(data, args.cores, title)
                        finally:
                            sys.stdout = stdout
                    print(f"  {title}: " + ", ".join(f"{k} {v:.2f}" for k, v in figures.items()), flush=True)
                else:
                    figures = report(data, args.cores, title)
                headline[label].append(figures)
                if args.concurrency:
                    concurrency.append(unit_concurrency(data))
                if args.trace is not None:
                    write_trace(data, args.trace, args.cores)
    if args.repeats > 1 or len(runs) > 1:
        print("\nmedians (queued_s: the run's threads waiting for a core that another process held):")
        for label, rows in headline.items():
            print(f"  {label:30s} " + ", ".join(f"{k} {statistics.median(r[k] for r in rows):.2f}" for k in rows[0]))
    if len(concurrency) > 2:
        fit_concurrency(concurrency)


if __name__ == "__main__":
    main()
