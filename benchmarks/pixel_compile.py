"""The pixel block's cold start (issue 13): Numba's first compiles in a fresh process without a cache.

CI and a user's first run have no Numba cache, so the pixel block's compiled loops are compiled
before its first window. This runs a small pixel run -- the Gen4 preset's pixel on a 320 x 180 sensor
(its pitch), a uniform sky that changes every 10 ms (the background changes the tracked pass defers)
and a spot streaking across, three 0.05 s windows on one thread -- in fresh processes, each with an
empty ``NUMBA_CACHE_DIR`` (cold) and then again with the cache that run filled (warm), alternately,
and prints the medians of:

* the process's CPU time (imports, the compiles or the cache loads, the run);
* the CPU time of each compiled function's own compile (Numba's ``numba:compile`` events, nested
  compiles of the functions it calls subtracted), largest first;
* the events' digest (the same in every run: the compiles change no result).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/pixel_compile.py [--repeats 3] [--preset prophesee_gen4]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

CHILD = r"""
import json, sys, time
clock = time.process_time
start = clock()
import hashlib
import numpy as np
from numba.core import event

own = {}                 # compiled function -> its own compile CPU time [s]
stack = []

class Listener(event.Listener):
    def on_start(self, ev):
        stack.append([clock(), 0.0])
    def on_end(self, ev):
        begun, nested = stack.pop()
        spent = clock() - begun
        name = ev.data["dispatcher"].py_func.__module__.rsplit(".", 1)[-1] + "." + ev.data["dispatcher"].__name__
        own[name] = own.get(name, 0.0) + spent - nested
        if stack:
            stack[-1][1] += spent

event.register("numba:compile", Listener())

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window
from evsda.graph.graphfile import load_graph
from evsda.library import resolve
import yaml

preset = sys.argv[1]
spec = yaml.safe_load(resolve(f"library:sensors/{preset}.yaml").read_text())
pixel = spec["blocks"]["pixel"]
params = dict(pixel.get("params", {}))
camera = spec["blocks"].get("camera", {}).get("params", {})
pitch = float(camera.get("pixel_pitch_m", 4.86e-6))
block = DvsPixel(seed=1, **params)
fp = FocalPlane(320, 180, pitch, 1.0)
window_s, windows, cadence_ns = 0.05, 3, 1_000_000
block.setup(RunInfo(duration_ns=round(windows * window_s * 1e9)))
digest = hashlib.sha256()
n_events = 0
size = 7
gy, gx = np.mgrid[0:size, 0:size]
for w in range(windows):
    window = Window.from_seconds(w * window_s, (w + 1) * window_s, index=w)
    t = np.arange(window.start_ns, window.stop_ns, cadence_ns, dtype=np.int64)
    sky = 3e3 * (1.0 - 3e-3 * np.floor(t / 1e7))                     # the sky changes every 10 ms
    xc, yc = 20.0 + 1500.0 * t * 1e-9, 90.0 + 200.0 * t * 1e-9         # a spot streaking at 1500 px/s
    x0, y0 = np.floor(xc).astype(int) - size // 2, np.floor(yc).astype(int) - size // 2
    stamp = 3e6 * np.exp(-((gx[None] + x0[:, None, None] - xc[:, None, None]) ** 2
                           + (gy[None] + y0[:, None, None] - yc[:, None, None]) ** 2) / (2 * 1.2 ** 2))
    irradiance = Irradiance(fp, 550e-9, t, sky, np.stack([x0, y0], -1).astype(np.int32)[:, None], stamp[:, None])
    events = block.step(window, irradiance=irradiance)["events"]
    n_events += len(events)
    for name in ("t_ns", "x", "y", "p", "cause"):
        digest.update(getattr(events, name).tobytes())
print(json.dumps({"cpu_s": clock() - start, "compile_s": sum(own.values()), "own": own, "events": n_events,
                  "digest": digest.hexdigest()[:16]}))
"""


def child(preset: str, cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, EVSDA_THREADS="1", OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD, preset], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="cold (and warm) runs, alternated")
    parser.add_argument("--preset", default="prophesee_gen4", help="library:sensors/ preset whose pixel runs")
    parser.add_argument("--top", type=int, default=8, help="compiled functions listed")
    args = parser.parse_args()
    cold, warm = [], []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as cache:
            cold.append(child(args.preset, cache))
            warm.append(child(args.preset, cache))
    load = os.getloadavg()
    median = statistics.median
    print(f"pixel block, {args.preset}, 320 x 180, three 0.05 s windows, one thread; "
          f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}; medians of {args.repeats}:")
    print(f"  cold (empty NUMBA_CACHE_DIR): {median(r['cpu_s'] for r in cold):.2f} s CPU, of which compiling "
          f"{median(r['compile_s'] for r in cold):.2f} s  (runs: " + ", ".join(f"{r['cpu_s']:.2f}" for r in cold) + ")")
    print(f"  warm (the cache it filled):   {median(r['cpu_s'] for r in warm):.2f} s CPU, of which compiling "
          f"{median(r['compile_s'] for r in warm):.2f} s  (runs: " + ", ".join(f"{r['cpu_s']:.2f}" for r in warm) + ")")
    names = sorted({n for r in cold for n in r["own"]}, key=lambda n: -median(r["own"].get(n, 0.0) for r in cold))
    print("  own compile CPU, cold: " + ", ".join(f"{n} {median(r['own'].get(n, 0.0) for r in cold):.2f} s"
                                                 for n in names[:args.top]))
    digests = {r["digest"] for r in cold + warm}
    print(f"  events {cold[0]['events']}, digest {' '.join(sorted(digests))}")


if __name__ == "__main__":
    main()
