"""What the first run compiles (issue 13): every compiled function of the main job, its specialisations and their CPU.

A user's first ``evsda run``, CI and a sweep on a new machine have no Numba cache: every compiled loop is built
before it first runs. This runs the main job (``examples/iss_pass.yaml``, or ``--graph``) with ``evsda run`` in a
fresh process, one thread (``EVSDA_THREADS=1``: compiles on another thread would be counted twice), the probe-result
cache off, with an empty ``NUMBA_CACHE_DIR`` (cold) and then again with the cache that run filled (warm), and prints
the medians of:

* the process's CPU time, cold and warm (their difference: the first run's compile);
* the CPU time of each compiled function's own compile (Numba's ``numba:compile`` events, nested compiles of the
  functions it calls subtracted), summed by package (optics, pixel, the rest) and listed largest first with the
  number of type specialisations compiled (more than one: the same loop compiled again for other argument types);
* the same summed by module;
* Numba's own helpers (``np.empty``, ``np.argsort``, the error message of a slice assignment) compiled inside them,
  with the functions that pulled them in (their time is counted in those functions' own);
* the store's events digest (the same in every run: the compiles change no result).

``--list`` prints each function's signatures, to find duplicates from literal or differing argument types.
``--code`` also prints a digest of the machine code the cold run cached (each cached object disassembled with
``objdump``, Numba's numbered symbol names aside): the same digest, the same instructions (e.g. with and without
``EVSDA_QUICKER_TYPING=off``).
The pixels' own cold start on a small scene: ``benchmarks/pixel_compile.py``.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/optics_compile.py [--repeats 1] [--top 25] [--list]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle
import re
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

MAIN_JOB = Path(__file__).parents[1] / "examples" / "iss_pass.yaml"

CHILD = r"""
import json, sys, time
clock = time.process_time
start = clock()
from numba.core import event

own, signatures, pulled = {}, {}, {}  # function -> own compile CPU [s], its compiled argument types; Numba's helpers
stack = []               # [function, start CPU, nested compiles' CPU] of the compiles under way

def name_of(ev):
    f = ev.data["dispatcher"].py_func
    return f.__module__.replace("evsda.blocks.", "") + "." + f.__qualname__

class Listener(event.Listener):
    def on_start(self, ev):
        stack.append([name_of(ev), clock(), 0.0])
    def on_end(self, ev):
        name, begun, nested = stack.pop()
        spent = clock() - begun
        signatures.setdefault(name, []).append(str(ev.data["args"]))
        if name.startswith("numba.") and stack:          # Numba's own helper: its caller's cost
            caller = stack[-1][0]
            if not caller.startswith("numba."):         # the outermost helper: the time of those inside it
                pulled.setdefault(name, {}).setdefault(caller, 0.0)
                pulled[name][caller] += spent
            return
        own[name] = own.get(name, 0.0) + spent - nested
        if stack:
            stack[-1][2] += spent

event.register("numba:compile", Listener())
from evsda.graph.cli import main
status = main(["run", sys.argv[1], "-o", sys.argv[2], "--overwrite", "--no-progress",
               "--set", f"run.duration_s={sys.argv[3]}"])
sys.path.insert(0, sys.argv[4])
from test_examples_identical import store_digest
print("evsda-compile " + json.dumps({"status": status, "cpu_s": clock() - start, "own": own,
                                     "signatures": signatures, "pulled": pulled, "digest": store_digest(sys.argv[2])[:16]}))
"""


def child(graph: Path, duration: float, cache_dir: str, store: Path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, EVSDA_THREADS="1", OPENBLAS_NUM_THREADS="1", EVSDA_CACHE="off")
    out = subprocess.run([sys.executable, "-c", CHILD, str(graph), str(store), str(duration),
                          str(Path(__file__).parents[1] / "tests")],
                         env=env, capture_output=True, text=True)
    lines = [x for x in out.stdout.splitlines() if x.startswith("evsda-compile ")]
    if out.returncode or not lines:
        raise RuntimeError(f"evsda run failed ({out.returncode}):\n{(out.stdout + out.stderr)[-3000:]}")
    return json.loads(lines[-1].split(" ", 1)[1])


def machine_code(cache_dir: str) -> dict[str, str]:
    """Each cached object's file name -> a digest of its disassembled instructions and relocations, Numba's numbered
    symbol names (and a temporary file's name) aside."""
    digests = {}
    with tempfile.TemporaryDirectory() as tmp:
        for path in sorted(Path(cache_dir).rglob("*.nbc")):
            obj = Path(tmp) / "code.o"
            obj.write_bytes(pickle.loads(path.read_bytes())[0][2][0])     # the library's ELF object
            code = subprocess.run(["objdump", "-d", "-r", "--no-show-raw-insn", str(obj)], capture_output=True,
                                  text=True, check=True).stdout
            code = re.sub(r"_ZN\S+|\b\w*\$\d+\w*", "SYMBOL", code.split(str(obj), 1)[-1])
            digests[path.name] = hashlib.sha256(code.encode()).hexdigest()[:16]
    return digests


def package(name: str) -> str:
    """The block package a compiled function lives in (optics, pixel) or "other"."""
    head = name.split(".", 1)[0]
    return head if head in ("optics", "pixel") else "other"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=MAIN_JOB, help="graph file (default: the main job)")
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds per run [s]")
    parser.add_argument("--repeats", type=int, default=1, help="cold (and warm) runs, alternated")
    parser.add_argument("--top", type=int, default=25, help="compiled functions listed")
    parser.add_argument("--list", action="store_true", help="print every function's compiled signatures")
    parser.add_argument("--code", action="store_true", help="print a digest of the cold run's cached machine code")
    args = parser.parse_args()
    cold, warm, codes = [], [], []
    load = [os.getloadavg()[0]]
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            cache, store = str(Path(tmp) / "numba"), Path(tmp) / "run.zarr"
            cold.append(child(args.graph, args.duration, cache, store))
            if args.code:
                codes.append(machine_code(cache))
            warm.append(child(args.graph, args.duration, cache, store))
            load.append(os.getloadavg()[0])
    median = statistics.median
    print(f"{args.graph.name}, {args.duration:g} s simulated, one thread, probe cache off; "
          f"load {' -> '.join(f'{x:.1f}' for x in load)}; medians of {args.repeats}:")
    for label, runs in (("cold (empty NUMBA_CACHE_DIR)", cold), ("warm (the cache it filled)  ", warm)):
        print(f"  {label}: {median(r['cpu_s'] for r in runs):6.2f} s CPU, of which compiling "
              f"{median(sum(r['own'].values()) for r in runs):5.2f} s, "
              f"{median(sum(map(len, r['signatures'].values())) for r in runs):.0f} specialisations")
    names = sorted({n for r in cold for n in r["own"]}, key=lambda n: -median(r["own"].get(n, 0.0) for r in cold))
    share = {p: median(sum(t for n, t in r["own"].items() if package(n) == p) for r in cold)
             for p in ("optics", "pixel", "other")}
    count = {p: sum(len(cold[0]["signatures"].get(n, ())) for n in names if package(n) == p) for p in share}
    print("  own compile CPU by package, cold: " + ", ".join(f"{p} {share[p]:.2f} s ({count[p]} specialisations)"
                                                         for p in share))
    modules = {}
    for n in names:
        modules.setdefault(n.split(".<locals>")[0].rsplit(".", 1)[0], []).append(n)
    by_module = sorted(((median(sum(r["own"].get(n, 0.0) for n in ns) for r in cold), m, ns)
                        for m, ns in modules.items()), reverse=True)
    print("  by module: " + ", ".join(f"{m} {t:.2f} s ({sum(len(cold[0]['signatures'].get(n, ())) for n in ns)})"
                                      for t, m, ns in by_module))
    print(f"  {'function':58s} {'CPU [s]':>8s} {'specs':>5s}")
    for n in names[:args.top]:
        sigs = cold[0]["signatures"].get(n, [])
        print(f"  {n:58s} {median(r['own'].get(n, 0.0) for r in cold):8.2f} {len(sigs):5d}")
    rest = names[args.top:]
    if rest:
        print(f"  ... {len(rest)} more: {median(sum(r['own'].get(n, 0.0) for n in rest) for r in cold):.2f} s")
    helpers = {}
    for r in cold:
        for h, callers in r["pulled"].items():
            helpers.setdefault(h, []).append(callers)
    helpers = sorted(helpers.items(), key=lambda kv: -median(sum(c.values()) for c in kv[1]))
    print("  Numba's helpers compiled inside them (counted above in their callers'):")
    for h, callers in helpers[:args.top // 2]:
        total = median(sum(c.values()) for c in callers)
        who = sorted(callers[0].items(), key=lambda kv: -kv[1])
        print(f"    {h} {total:.2f} s: " + ", ".join(f"{c} {t:.2f}" for c, t in who[:4])
              + (f" and {len(who) - 4} more" if len(who) > 4 else ""))
    if args.list:
        for n in names:
            for s in cold[0]["signatures"].get(n, []):
                print(f"    {n}{s}")
    print(f"  digest {' '.join(sorted({r['digest'] for r in cold + warm}))}")
    for code in codes:
        whole = hashlib.sha256(json.dumps(code, sort_keys=True).encode()).hexdigest()[:16]
        print(f"  machine code {whole} ({len(code)} cached objects)")


if __name__ == "__main__":
    main()
