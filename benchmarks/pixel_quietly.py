"""``take_quietly`` of the pixel block on the tracked pass, replayed call by call (issue 13).

Captures the calls :func:`evsda.blocks.pixel.deferred.take_quietly` gets over the first ``--windows`` windows of the
pass's captured inputs (``benchmarks/pixel_gil.py --inputs F``; its pixels' state rows before and after each call),
then replays them on a sensor-sized state table (the rows written in, the caches flushed by a 64 MB write before
each call, as the block's scattered rows come cold), checks each call's rows bit for bit against the captured
ones and prints the thread CPU a window. ``--against DIR`` replays another checkout's ``take_quietly`` too
(``blocks/pixel`` copied into the temporary folder as ``pixel_gil.py --against`` does), call by call, alternating
which goes first, and prints the ratio of the sums and the median of the calls' ratios.

    OPENBLAS_NUM_THREADS=1 python benchmarks/pixel_quietly.py --inputs F [--windows 30] [--repeats 3] [--against DIR]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def captured_calls(inputs_file: Path, n_windows: int) -> list[dict]:
    """Each ``take_quietly`` call of the block's first ``n_windows`` windows: its arguments, its pixels' rows before
    and after."""
    from evsda.blocks.pixel import deferred, eventdriven
    sys.path.insert(0, str(Path(__file__).parent))
    import pixel_items

    calls = []
    take_quietly = deferred.take_quietly

    def recording(real, count, pixels, lo, end, steps, inputs, leak_hz, dt, large):
        call = {"pixels": pixels.copy(), "lo": lo.copy(), "end": end, "steps": steps.copy(), "inputs": inputs.copy(),
                "leak_hz": leak_hz, "dt": dt, "large": large, "real": real[pixels], "count": count[pixels]}
        take_quietly(real, count, pixels, lo, end, steps, inputs, leak_hz, dt, large)
        call["real_after"], call["count_after"] = real[pixels], count[pixels]
        calls.append(call)

    with open(inputs_file, "rb") as f:
        block, inputs = pickle.load(f)
    eventdriven._FIRST_CAPACITY = 1 << 22
    eventdriven.take_and_run = pixel_items._split_take_and_run({}, {})     # take_quietly called from Python
    deferred.take_quietly = recording
    try:
        for window, irradiance in inputs[:n_windows]:
            block.step(window, irradiance=irradiance)
    finally:
        deferred.take_quietly = take_quietly
    return calls


def other_take_quietly(against: Path):
    """``take_quietly`` of another checkout's ``blocks/pixel``, copied as the package ``quietly_against``."""
    root = Path(tempfile.gettempdir()) / f"quietly_against_{hashlib.sha256(bytes(against.resolve())).hexdigest()[:12]}"
    shutil.copytree(against / "blocks" / "pixel", root / "quietly_against", ignore=shutil.ignore_patterns("__pycache__"),
                    dirs_exist_ok=True)
    sys.path.insert(0, str(root))
    from quietly_against import deferred
    return deferred.take_quietly


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=Path, required=True, help="pickle of pixel_gil.py --inputs")
    parser.add_argument("--windows", type=int, default=30, help="windows whose calls are captured")
    parser.add_argument("--repeats", type=int, default=3, help="replays of every call")
    parser.add_argument("--against", type=Path, help="another checkout whose take_quietly is replayed too")
    args = parser.parse_args()
    os.environ["EVSDA_THREADS"] = "1"                  # the block's chunks one after the other, on this thread
    from evsda.blocks.pixel import deferred
    calls = captured_calls(args.inputs, args.windows)
    versions = {"this": deferred.take_quietly}
    if args.against is not None:
        versions[str(args.against)] = other_take_quietly(args.against)
    n = max(int(c["pixels"].max()) for c in calls) + 1
    real, count = np.zeros((n, calls[0]["real"].shape[1])), np.zeros((n, calls[0]["count"].shape[1]), np.int64)
    flush = np.zeros(8 << 20)

    def replay(function, call):
        real[call["pixels"]], count[call["pixels"]] = call["real"], call["count"]
        flush[:] += 1.0
        start = time.thread_time_ns()
        function(real, count, call["pixels"], call["lo"], call["end"], call["steps"], call["inputs"], call["leak_hz"],
                 call["dt"], call["large"])
        spent = time.thread_time_ns() - start
        if not (np.array_equal(real[call["pixels"]].view(np.int64), call["real_after"].view(np.int64))
                and np.array_equal(count[call["pixels"]], call["count_after"])):
            raise SystemExit("a replayed call's rows differ from the captured ones")
        return spent

    for function in versions.values():
        replay(function, calls[0])                     # compiles or loads
    spent = {name: [] for name in versions}
    for r in range(args.repeats):
        for i, call in enumerate(calls):
            names = list(versions) if (r + i) % 2 == 0 else list(versions)[::-1]
            for name in names:
                spent[name].append(replay(versions[name], call))
    per_window = args.repeats * args.windows
    print(f"take_quietly, {len(calls)} calls of {args.windows} windows ({sum(c['pixels'].size for c in calls)} pixels), "
          f"each replayed {args.repeats} times, rows bit for bit (load {os.getloadavg()[0]:.1f}):")
    this = np.array(spent["this"])
    for name, values in spent.items():
        values = np.array(values)
        print(f"  {name}: {values.sum() * 1e-6 / per_window:.3f} ms a window"
              + ("" if name == "this" else f"; this / it: ratio of sums {this.sum() / values.sum():.3f}, median of "
                                           f"the calls' ratios {np.median(this / values):.3f}"))


if __name__ == "__main__":
    main()
