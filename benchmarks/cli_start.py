"""The fixed CPU cost of starting the ``evsda`` command (issue 13.3: import only what a run needs).

Prints, for each ``evsda`` executable given (default: the one beside this Python), the CPU seconds
(user + system, of the child process) of a fresh

* ``evsda --version`` (the command-line entry: the framework and every contributed command),
* ``evsda run`` of a one-block graph (a ground site, 0.1 s),
* ``evsda schema --check`` (imports every block to build the schemas; run in the executable's checkout),

medians of ``--repeats`` runs, the executables alternated run by run so that a changing load falls on
all of them alike, and the load average beside them. The test suite starts ~100 such processes.

    python benchmarks/cli_start.py [--repeats 5] [EVSDA ...]
"""

from __future__ import annotations

import argparse
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("evsda", nargs="*", default=[str(Path(sys.executable).with_name("evsda"))],
                        help="evsda executables to compare (default: the one beside this Python)")
    parser.add_argument("--repeats", type=int, default=5, help="runs of each command per executable (default 5)")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        graph = Path(tmp) / "site.yaml"
        graph.write_text(GRAPH)
        commands = {"--version": lambda exe, i: [exe, "--version"],
                    "run": lambda exe, i: [exe, "-q", "run", str(graph), "-o", str(Path(tmp) / f"r{i}.zarr")],
                    "schema --check": lambda exe, i: [exe, "schema", "--check"]}
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
        figures = ", ".join(f"{name} {statistics.median(cpu[exe, name]):.2f} s" for name in commands)
        print(f"  {checkouts[exe]}: {figures}")


if __name__ == "__main__":
    main()
