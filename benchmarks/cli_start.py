"""The fixed CPU cost of starting the ``evsda`` command (issue 13.3: import only what a run needs).

Prints, for each ``evsda`` executable given (default: the one beside this Python), the CPU seconds
(user + system, of the child process) of a fresh

* ``evsda --version`` (the command-line entry: the framework and every contributed command),
* ``evsda run`` of a one-block graph (a ground site, 0.1 s),
* ``evsda schema --check`` (imports every block to build the schemas; run in the executable's checkout),
* ``evsda validate`` of the tracked pass (``benchmarks/end_to_end.yaml``: the command line and the graph's load,
  what a run of the pass does before its first step but the run's set-up),

medians of ``--repeats`` runs, the executables alternated run by run so that a changing load falls on
all of them alike, and the load average beside them. The test suite starts ~100 such processes.

``--parts GRAPH`` instead splits the one-core start of ``evsda run GRAPH`` before its first step (CPU seconds of
each part in a fresh process of this checkout, the libraries imported one after the other in the order a run
needs them, medians of ``--repeats``): NumPy, pydantic, the rest of the command line, networkx, Numba,
SciPy, Skyfield, loading the graph (our block modules, the YAML, the checks), the first call of a compiled function
(Numba's set-up and one load from its cache, as ``run_graph`` loads: :mod:`evsda.graph.numba_loads`,
``EVSDA_LAZY_REGISTRIES=off`` for Numba's own) and Zarr (the store, after the first window). Each part twice: as the checkouts run (editable installs with ``PYTHONDONTWRITEBYTECODE=1``: our modules
compiled from source at every start) and with compiled bytecode (``PYTHONPYCACHEPREFIX``, filled by one unmeasured
run first: what an installed package starts with).

    python benchmarks/cli_start.py [--repeats 5] [--command NAME ...] [EVSDA ...]
    python benchmarks/cli_start.py --parts benchmarks/end_to_end.yaml [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

GRAPH = """evsda: 1
run: {start: "2024-03-01T02:15:00Z", duration_s: 0.1, window_s: 0.1}
blocks:
  site: {type: ground_site, params: {latitude_deg: 47.0, longitude_deg: 15.4}}
"""


def child_cpu_s(argv: list[str], cwd: Path) -> float:
    """User + system CPU seconds of one run of ``argv`` (it must succeed)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, cwd=cwd, check=True, capture_output=True, env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def checkout_of(evsda: str) -> Path:
    """The source checkout an ``evsda`` executable runs (where ``schema/`` lives)."""
    python = Path(evsda).with_name("python")
    out = subprocess.run([str(python), "-c", "import evsda.graph; print(evsda.graph.__file__)"],
                         check=True, capture_output=True, text=True)
    return Path(out.stdout.strip()).parents[1]


#: the parts of a run's start, timed one after the other in a fresh process (``{graph}``: the graph file)
PARTS = {
    "numpy": "import numpy",
    "pydantic": "import pydantic, pydantic_core",
    "the rest of the command line": "import evsda.graph.cli\nevsda.graph.cli.lean_array_api()",   # as a run calls it
    "networkx": "import networkx",
    "numba, llvmlite": "import numba",
    "scipy.special (with SciPy's array-API set-up)": "import scipy.special",
    "scipy.constants, fft, linalg": "import scipy.constants, scipy.fft, scipy.linalg",
    "skyfield": "import skyfield.api",
    "loading the graph (our block modules, YAML, checks)":
        "from evsda.graph.graphfile import load_graph\nload_graph({graph!r}, ['run.duration_s=1'])",
    "the first compiled call (Numba's set-up, a cached load)":
        "import numpy as np\nfrom evsda.graph.numba_loads import lazy_registries\n"
        "from evsda.blocks.pixel.drive_kernel import drive_rows\nlazy_registries()\n"
        "drive_rows(np.ones(1), np.zeros(64), np.zeros((1, 64)))",        # sizes beyond its indices
    "zarr (the store, after the first window)": "import zarr",
}

PARTS_CHILD = """
import json, time
spent = {{}}
for label, statement in {parts!r}.items():
    start = time.process_time()
    exec(statement, {{}})
    spent[label] = time.process_time() - start
print(json.dumps(spent))
"""


def start_parts(graph: Path, repeats: int) -> None:
    """Print the CPU seconds of each part of a run's start (:data:`PARTS`), without and with compiled bytecode."""
    parts = {label: statement.format(graph=str(graph.resolve())) for label, statement in PARTS.items()}
    child = [sys.executable, "-c", PARTS_CHILD.format(parts=parts)]
    with tempfile.TemporaryDirectory() as prefix:
        environments = {"from source": dict(os.environ, PYTHONDONTWRITEBYTECODE="1"),
                        "compiled": {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"},
                                     "PYTHONPYCACHEPREFIX": prefix}}
        subprocess.run(child, check=True, capture_output=True, env=environments["compiled"])  # fills the prefix
        runs = {name: [] for name in environments}
        loads = [os.getloadavg()[0]]
        for _ in range(repeats):
            for name, env in environments.items():
                out = subprocess.run(child, check=True, capture_output=True, text=True,
                                     env=dict(env, OPENBLAS_NUM_THREADS="1"))
                runs[name].append(json.loads(out.stdout))
            loads.append(os.getloadavg()[0])
    print(f"CPU seconds of a run's start, one part after the other in a fresh process, medians of {repeats} "
          f"(alternated); load average {min(loads):.1f}-{max(loads):.1f}")
    print(f"  {'part':52s} {'from source':>11s} {'compiled':>9s}")
    medians = {name: {label: statistics.median(r[label] for r in runs[name]) for label in parts} for name in runs}
    for label in parts:
        print(f"  {label:52s} {medians['from source'][label]:11.3f} {medians['compiled'][label]:9.3f}")
    print(f"  {'all':52s} {sum(medians['from source'].values()):11.3f} {sum(medians['compiled'].values()):9.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("evsda", nargs="*", default=[str(Path(sys.executable).with_name("evsda"))],
                        help="evsda executables to compare (default: the one beside this Python)")
    parser.add_argument("--repeats", type=int, default=5, help="runs of each command per executable (default 5)")
    parser.add_argument("--command", action="append", default=[], metavar="NAME",
                        help="time only this command (repeatable): --version, run, schema --check, validate pass")
    parser.add_argument("--parts", type=Path, metavar="GRAPH",
                        help="split the start of a run of GRAPH instead (this checkout; see the module's docstring)")
    args = parser.parse_args()
    if args.parts is not None:
        start_parts(args.parts, args.repeats)
        return

    with tempfile.TemporaryDirectory() as tmp:
        graph = Path(tmp) / "site.yaml"
        graph.write_text(GRAPH)
        commands = {"--version": lambda exe, i: [exe, "--version"],
                    "run": lambda exe, i: [exe, "-q", "run", str(graph), "-o", str(Path(tmp) / f"r{i}.zarr")],
                    "schema --check": lambda exe, i: [exe, "schema", "--check"],
                    "validate pass": lambda exe, i: [exe, "validate", "benchmarks/end_to_end.yaml"]}
        commands = {name: argv for name, argv in commands.items() if not args.command or name in args.command}
        checkouts = {exe: checkout_of(exe) for exe in args.evsda}
        cpu = {(exe, name): [] for exe in args.evsda for name in commands}
        loads = [os.getloadavg()[0]]
        k = 0
        for _ in range(args.repeats):
            for name, argv in commands.items():
                for exe in args.evsda:
                    k += 1
                    cpu[exe, name].append(child_cpu_s(argv(exe, k), checkouts[exe]))
            loads.append(os.getloadavg()[0])

    print(f"CPU seconds of a fresh evsda process, medians of {args.repeats} (alternated); "
          f"load average {min(loads):.1f}-{max(loads):.1f}")
    for exe in args.evsda:
        figures = ", ".join(f"{name} {statistics.median(cpu[exe, name]):.3f} s" for name in commands)
        print(f"  {checkouts[exe]}: {figures}")


if __name__ == "__main__":
    main()
