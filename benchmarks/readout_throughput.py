"""Readout throughput: arbiters and event writers against the 10 M events/s target, and
the memory of exports versus the number of events (issue 6).

Prints
* arbiter throughput [M events/s] on 10 M events/s of uniform noise over a 1280 x 720
  sensor, cut into 0.1 s windows (the default window), plus the events dropped;
* writer throughput [M events/s] and peak resident memory [MB] of each export format
  for a small and a large number of events (default 1e6 and 1e8), each export in a
  fresh process so that its peak memory is its own. Flat memory: the two peaks agree.

    python benchmarks/readout_throughput.py [--events 1e8] [--formats aedat4 evt3 ...]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

W, H = 1280, 720
CHUNK = 1 << 20


def noise(n: int, duration_ns: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, duration_ns, n))
    return t, rng.integers(0, W, n).astype(np.uint16), rng.integers(0, H, n).astype(np.uint16)


def bench_arbiters(rate_eps: float = 10e6, duration_s: float = 1.0, window_s: float = 0.1) -> None:
    from evsda.blocks.ports import FocalPlane, TriggeredEvents
    from evsda.blocks.readout import ColumnBurstArbiter, IdealReadout, RowScanArbiter
    from evsda.graph import RunInfo, Window

    fp = FocalPlane(W, H, 4.86e-6, 1.0)
    duration_ns, window_ns = round(duration_s * 1e9), round(window_s * 1e9)
    t, x, y = noise(round(rate_eps * duration_s), duration_ns)
    p = np.ones(t.size, np.int8)
    c = np.zeros(t.size, np.uint8)
    cases = [("ideal_readout", IdealReadout()),
             ("row_scan_arbiter 100 MHz, bus 50 Mev/s", RowScanArbiter(clock_hz=100e6, bus_throughput_eps=50e6)),
             ("column_burst_arbiter 32 columns", ColumnBurstArbiter(clock_hz=100e6, bus_throughput_eps=50e6,
                                                                    group_width_px=32)),
             ("row_scan_arbiter saturated (bus 5 Mev/s)", RowScanArbiter(clock_hz=100e6, bus_throughput_eps=5e6))]
    print(f"arbiters: {t.size / 1e6:.0f} M events over {duration_s} s in {window_s} s windows, {W} x {H}")
    for name, block in cases:
        block.setup(RunInfo(duration_ns=duration_ns, window_ns=window_ns))
        edges = np.arange(0, duration_ns + 1, window_ns)
        idx = np.searchsorted(t, edges)
        recorded = dropped = 0
        start = time.perf_counter()
        for i in range(edges.size - 1):
            s = slice(idx[i], idx[i + 1])
            out = block.step(Window(i, int(edges[i]), int(edges[i + 1])),
                             events=TriggeredEvents(fp, t[s], x[s], y[s], p[s], c[s]))["events"]
            recorded += len(out)
            dropped += out.n_dropped
        elapsed = time.perf_counter() - start
        assert recorded + dropped == t.size
        print(f"  {name:42s} {t.size / elapsed / 1e6:6.1f} M events/s   recorded {recorded:>9d}  dropped {dropped:>8d}")


WORKER = r"""
import json, sys, time
import numpy as np
from evsda.blocks.readout.exporters import export_events
fmt, n, path, chunk = sys.argv[1], int(float(sys.argv[2])), sys.argv[3], int(sys.argv[4])
W, H = 1280, 720
rng = np.random.default_rng(0)
k = min(chunk, n)
step = np.cumsum(rng.integers(0, 200, k))          # one chunk's pattern, shifted in time for every chunk
x, y = rng.integers(0, W, k).astype(np.uint16), rng.integers(0, H, k).astype(np.uint16)
p, cause = rng.choice(np.array([-1, 1], np.int8), k), np.zeros(k, np.uint8)
def chunks():
    t = 16_000_000_000
    for lo in range(0, n, chunk):
        m = min(chunk, n - lo)
        readout = t + step[:m]
        t = int(readout[-1])
        yield {"t_trigger_ns": readout - 1000, "t_readout_ns": readout, "x": x[:m], "y": y[:m], "p": p[:m],
               "cause": cause[:m]}
start = time.perf_counter()
written = export_events(chunks(), path, fmt, W, H)
seconds = time.perf_counter() - start
hwm = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM"))
print(json.dumps({"written": written, "seconds": seconds, "peak_rss_mb": hwm / 1024}))
"""

SUFFIX = {"aedat4": ".aedat4", "evt2": ".raw", "evt3": ".raw", "hdf5": ".h5", "npy": ".npy"}


def run_worker(code: str, fmt: str, n: float, path: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", code, fmt, str(n), str(path), str(CHUNK)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_writers(formats: list[str], sizes: list[float]) -> None:
    print(f"writers: chunks of {CHUNK} events, {W} x {H}; each export in its own process "
          f"(peak memory = VmHWM of that process)")
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            for fmt in formats:
                path = Path(tmp) / f"out{SUFFIX[fmt]}"
                r = run_worker(WORKER, fmt, n, path)
                size_mb = path.stat().st_size / 1e6
                print(f"  {n:8.0e} events {fmt:7s} {r['written'] / r['seconds'] / 1e6:7.1f} M events/s  "
                      f"peak memory {r['peak_rss_mb']:6.0f} MB  file {size_mb:9.1f} MB")
                path.unlink()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=float, default=1e8, help="events of the large export")
    parser.add_argument("--formats", nargs="+", default=list(SUFFIX), choices=list(SUFFIX))
    parser.add_argument("--skip-arbiters", action="store_true")
    args = parser.parse_args()
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor())
    print(f"machine: {cpu}, python {platform.python_version()}, numpy {np.__version__}")
    if not args.skip_arbiters:
        bench_arbiters()
    bench_writers(args.formats, [1e6, args.events])


if __name__ == "__main__":
    main()
