"""The pixel block's compiled loop ``take_and_run`` itemised on the tracked pass (issue 13).

Steps the pass's pixel block over its captured inputs (``benchmarks/pixel_gil.py --inputs F``) with
:func:`evsda.blocks.pixel.deferred.take_and_run` replaced by its four parts called one after the other from
Python, each timed (thread CPU): ``take_quietly`` (the kept background changes), the sweep of the stamps'
changes (``sweep_own``, the pixels with own changes and the others apart), ``drive_left`` and ``run_pixels``, the last split into the pixels with own input
changes (under the stamps) and the others (due for a noise event, or able to fire under the background's changes
they take); prints, per window, their CPU, pixels and events, and the cost per pixel turn and per
event. The same events (the digest is printed: the pass's is 1b87e2a1a2537608).

``--perf FILE`` also samples the stepping with ``perf record`` (software clock) into FILE, having written
``/tmp/perf-PID.map`` of every compiled function of the pixel package, compiled in this process (an empty
``NUMBA_CACHE_DIR`` is set, so the first window compiles for ~1 min): ``perf report -i FILE`` then names the
compiled functions, those LLVM did not inline, and the C library's.

    OPENBLAS_NUM_THREADS=1 EVSDA_THREADS=1 python benchmarks/pixel_items.py --inputs F [--perf FILE]

Another checkout's parts: run this file with that checkout's Python (its evsda), with a Numba cache folder of its
own (``NUMBA_CACHE_DIR``: its tree is left as it is), e.g. ``/work/h-audit/.venv/bin/python``.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _split_take_and_run(spent: dict, counts: dict):
    """``take_and_run`` as its parts, each timed into ``spent`` [ns]; pixels and events counted into ``counts``."""
    import inspect

    from evsda.blocks.pixel import deferred, own_sweep, pixel_loop
    # a checkout before the sweep handed its bounds on (run with its Python: the same parts, without them)
    hands_on = "known_step" in inspect.signature(own_sweep.sweep_own.py_func).parameters

    def part(name, function, *args):
        start = time.thread_time_ns()
        out = function(*args)
        spent[name] = spent.get(name, 0) + time.thread_time_ns() - start
        return out

    def take_and_run(real, count, next_step, wake, envelope, pixels, quiet_lo, quiet_end, shared_step, shared_input,
                     change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k, n_end, leak_hz, dt,
                     large, k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma, th_floor, ev_step, ev_pixel,
                     ev_pol, ev_cause):
        quiet = quiet_lo >= 0
        if quiet.any():
            part("take_quietly", deferred.take_quietly, real, count, pixels[quiet], quiet_lo[quiet], quiet_end,
                 shared_step, shared_input, leak_hz, dt, large)
        own = (change_hi > change_lo) & (change_lo < n_own)     # before the sweep moves change_lo
        for name, which in (("run_pixels background", ~own), ("run_pixels stamps", own)):
            counts[name + " changes"] = counts.get(name + " changes", 0) + int((change_hi - change_lo)[which].sum())
        known = (np.empty(pixels.size, np.int64), np.empty(pixels.size), np.empty(pixels.size))
        for name, which in (("sweep background", ~own), ("sweep stamps", own)):     # pixels apart: the same bits
            lo = np.ascontiguousarray(change_lo[which])
            known_part = tuple(np.empty(np.count_nonzero(which), v.dtype) for v in known)
            swept = part(name, own_sweep.sweep_own, real, count, np.ascontiguousarray(pixels[which]), lo,
                         np.ascontiguousarray(change_hi[which]), change_step, change_input, n_own, own_flux, drive_k,
                         n_end, leak_hz, dt, large, *(known_part if hands_on else ()))
            change_lo[which] = lo
            for whole, piece in zip(known, known_part):
                whole[which] = piece
            counts[name + " changes"] = counts.get(name + " changes", 0) + int(swept)
        part("drive_left", own_sweep.drive_left, pixels, change_lo, change_hi, n_own, own_flux, drive_k, change_input)
        n_events, lost = np.int64(0), 0.0
        for name, which in (("run_pixels background", ~own), ("run_pixels stamps", own)):
            before = n_events
            n_events, done, lost = part(name, pixel_loop.run_pixels, real, count, next_step, wake, envelope,
                                        np.ascontiguousarray(pixels[which]), np.ascontiguousarray(change_lo[which]),
                                        np.ascontiguousarray(change_hi[which]), pixel_loop.NEVER, change_step,
                                        change_input, n_end, leak_hz, dt, large, k_refr, q, key, redraw, th_mean_on,
                                        th_mean_off, th_sigma, th_floor, ev_step, ev_pixel, ev_pol, ev_cause,
                                        np.int64(n_events), lost, pixel_loop._LAZY,
                                        *((np.ascontiguousarray(v[which]) for v in known) if hands_on else ()))
            if done < np.count_nonzero(which):
                raise SystemExit("an event buffer ran out of room: raise the capacity")
            counts[name + " pixels"] = counts.get(name + " pixels", 0) + int(np.count_nonzero(which))
            counts[name + " events"] = counts.get(name + " events", 0) + int(n_events - before)
        counts["quiet pixels"] = counts.get("quiet pixels", 0) + int(np.count_nonzero(quiet))
        return n_events, pixels.size, lost

    return take_and_run


def _short(mangled: str) -> str:
    """``module.function`` of a Numba function's mangled name (``_ZN<len><name>...``), else the name."""
    if not mangled.startswith("_ZN"):
        return mangled
    parts, i = [], 3
    while i < len(mangled) and mangled[i].isdigit():
        j = i
        while mangled[j].isdigit():
            j += 1
        size = int(mangled[i:j])
        parts.append(mangled[j:j + size])
        i = j + size
    return ".".join(parts[-2:]) if parts else mangled


def _perf_map(path: Path) -> int:
    """Writes the addresses of every function of the pixel package's compiled code (compiled in this process) to
    ``path`` in perf's map format; returns how many."""
    import numba
    rows = []
    for name, module in list(sys.modules.items()):
        if not name.startswith("evsda.blocks.pixel."):
            continue
        for value in vars(module).values():
            if not isinstance(value, numba.core.registry.CPUDispatcher):
                continue
            for cres in value.overloads.values():
                library = cres.library
                module_ir = getattr(library, "_final_module", None)
                if module_ir is None:
                    continue
                for function in module_ir.functions:
                    if function.is_declaration:
                        continue
                    address = library.get_pointer_to_function(function.name)
                    if address:
                        rows.append((address, _short(function.name)))
    rows = sorted(set(rows))
    with open(path, "w") as f:
        for (address, name), following in zip(rows, rows[1:] + [(rows[-1][0] + 4096, "")]):
            f.write(f"{address:x} {min(following[0] - address, 1 << 20):x} {name}\n")
    return len(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=Path, required=True, help="pickle of pixel_gil.py --inputs")
    parser.add_argument("--perf", type=Path, help="perf record's output file (samples the stepping)")
    args = parser.parse_args()
    if args.perf is not None:
        os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="pixel_items_cache_")
    from evsda.blocks.pixel import eventdriven
    with open(args.inputs, "rb") as f:
        block, inputs = pickle.load(f)
    eventdriven._FIRST_CAPACITY = 1 << 22        # room for every event of a chunk: run_pixels is called twice
    spent, counts = {}, {}
    eventdriven.take_and_run = _split_take_and_run(spent, counts)
    select = eventdriven.select_pixels

    def counted_select(real, count, next_step, wake, applied, touched, changed, n_end, *rest):
        first, stop = rest[-2:]
        envelope = rest[5]              # its last entry, where there are four: the wake codes' first step
        wake_from = int(envelope[3]) if envelope.size > 3 else 0
        counts["awake"] = counts.get("awake", 0) + int(np.count_nonzero(wake[first:stop].astype(np.int64) + wake_from
                                                                        < n_end))
        start = time.thread_time_ns()
        out = select(real, count, next_step, wake, applied, touched, changed, n_end, *rest)
        spent["select_pixels"] = spent.get("select_pixels", 0) + time.thread_time_ns() - start
        counts["selected"] = counts.get("selected", 0) + out[0].size
        return out

    eventdriven.select_pixels = counted_select
    window, irradiance = inputs[0]
    block.step(window, irradiance=irradiance)     # start-up, compiles or cache loads: not counted
    spent.clear()
    counts.clear()
    recorder = None
    if args.perf is not None:
        # the other compiled functions compile at their first call (take_quietly's when changes are kept): four
        # windows more before the map
        for window, irradiance in inputs[1:5]:
            block.step(window, irradiance=irradiance)
        inputs = inputs[4:]
        spent.clear()
        counts.clear()
        print(f"perf map: {_perf_map(Path(f'/tmp/perf-{os.getpid()}.map'))} functions")
        recorder = subprocess.Popen(["perf", "record", "-F", "2000", "-o", str(args.perf), "-p",
                                     str(os.getpid())], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.0)
    digest = hashlib.sha256()
    start = time.process_time()
    for window, irradiance in inputs[1:]:
        events = block.step(window, irradiance=irradiance)["events"]
        for name in ("t_ns", "x", "y", "p", "cause"):
            digest.update(getattr(events, name).tobytes())
        digest.update(str(events.n_loss).encode())
    cpu = time.process_time() - start
    if recorder is not None:
        recorder.send_signal(signal.SIGINT)
        recorder.wait()
    n = len(inputs) - 1
    print(f"pixel block, {n} windows (load {os.getloadavg()[0]:.1f}): {cpu / n * 1e3:.2f} ms CPU a window; "
          f"take_and_run's parts and select_pixels (ms a window): "
          + ", ".join(f"{k} {v * 1e-6 / n:.2f}" for k, v in sorted(spent.items(), key=lambda kv: -kv[1])))
    for name in ("run_pixels background", "run_pixels stamps"):
        pixels, events = counts.get(name + " pixels", 0), counts.get(name + " events", 0)
        ns = spent.get(name, 0)
        print(f"  {name}: {pixels / n:.0f} pixels, {counts.get(name + ' changes', 0) / n:.0f} changes (before the "
              f"sweep), {events / n:.0f} events a window; "
              f"{ns / max(pixels, 1):.0f} ns a pixel, {ns / max(events, 1):.0f} ns an event")
    for name in ("sweep background", "sweep stamps"):
        print(f"  {name}: {counts.get(name + ' changes', 0) / n:.0f} changes swept a window, "
              f"{spent.get(name, 0) / max(counts.get(name + ' changes', 0), 1):.0f} ns a change")
    print(f"  select_pixels: {counts.get('awake', 0) / n:.0f} pixels awake (wake before the window's end), "
          f"{counts.get('selected', 0) / n:.0f} selected a window")
    print(f"  take_quietly: {counts.get('quiet pixels', 0) / n:.0f} pixels a window")
    print(f"  events' digest {digest.hexdigest()[:16]}")


if __name__ == "__main__":
    main()
