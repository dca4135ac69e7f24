"""What two threads of one process cost each other on this machine's cores, apart from evsda (issue 13).

Two probes in C (compiled here with ``cc``), each on cores 0 and 1:

* ``chunks``: two workers, threads of one process or two processes, each timing fixed chunks of work on its own
  thread clock (CPU time) and the wall clock. A chunk that ran whole on its core (CPU >= 97 % of its wall) is
  "alone" when the other worker's whole-on-core chunks cover < 5 % of it and "both on" when they cover > 95 %: the
  ratio of the two medians is what running at the same time costs a chunk, with the host's other load filtered out
  (a chunk queued behind another process is not whole on its core). Work: a dependent multiply-add chain (the core
  alone), or reads and writes of one double a 64-byte line over a private buffer of ``--mb`` MB (the caches: the
  VM's L2 is 1-2 MB a core, the L3 share ~16-20 MB on the nineteenth session's host).
* ``wake``: two threads handing a turn back and forth through a futex (a few us of work a turn), pinned to one core
  or to two: the CPU of a round trip, i.e. what waking a thread on the other core costs against on the same one.

On the nineteenth session's host (AMD EPYC under KVM, load 4-11) the chain read 0.996-1.007 and private buffers of up
to 8 MB 1.00-1.07, threads and processes alike, two 12 MB buffers 1.24-1.75x (both), and a round trip 17.5-18.7 us
CPU on one core against 48-66 us across the two (docs/speed.md, "Scheduling on the new machine").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHUNKS_C = r"""
#define _GNU_SOURCE
#include <pthread.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <sys/wait.h>
static int CHUNKS; static long WORK; static size_t BYTES; static const char *OUT;
static long long ns(clockid_t c) { struct timespec t; clock_gettime(c, &t); return t.tv_sec * 1000000000LL + t.tv_nsec; }
static volatile double sink;
static void *worker(void *arg) {
  int core = (int)(long)arg; cpu_set_t s; CPU_ZERO(&s); CPU_SET(core, &s); sched_setaffinity(0, sizeof s, &s);
  size_t n = BYTES / 8; double *buf = NULL;
  if (n) { buf = aligned_alloc(64, BYTES); for (size_t i = 0; i < n; i++) buf[i] = i * 1e-9; }
  long long *rec = malloc(sizeof(long long) * 3 * CHUNKS); double x = 1.0;
  for (int c = 0; c < CHUNKS; c++) {
    long long w0 = ns(CLOCK_MONOTONIC), c0 = ns(CLOCK_THREAD_CPUTIME_ID);
    if (!n) { for (long i = 0; i < WORK; i++) x = x * 1.0000001 + 1e-9; }
    else { for (long r = 0; r < WORK; r++) { double a = 0; for (size_t i = 0; i < n; i += 8) { a += buf[i]; buf[i] = a * 1e-12; } x += a; } }
    long long c1 = ns(CLOCK_THREAD_CPUTIME_ID), w1 = ns(CLOCK_MONOTONIC);
    rec[3 * c] = w0; rec[3 * c + 1] = w1; rec[3 * c + 2] = c1 - c0;
  }
  sink = x;
  char name[4096]; snprintf(name, sizeof name, "%s-%d.txt", OUT, core);
  FILE *f = fopen(name, "w");
  for (int c = 0; c < CHUNKS; c++) fprintf(f, "%lld %lld %lld\n", rec[3 * c], rec[3 * c + 1], rec[3 * c + 2]);
  fclose(f); return NULL;
}
int main(int argc, char **argv) {  /* OUT threads|processes WORK BYTES CHUNKS */
  OUT = argv[1]; WORK = atol(argv[3]); BYTES = atol(argv[4]); CHUNKS = atoi(argv[5]);
  if (!strcmp(argv[2], "threads")) {
    pthread_t t[2]; for (long i = 0; i < 2; i++) pthread_create(&t[i], 0, worker, (void *)i);
    for (int i = 0; i < 2; i++) pthread_join(t[i], 0);
  } else { for (long i = 0; i < 2; i++) if (!fork()) { worker((void *)i); _exit(0); } while (wait(0) > 0); }
  return 0;
}
"""

WAKE_C = r"""
#define _GNU_SOURCE
#include <linux/futex.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>
static _Atomic int turn = 0; static int N; static int cores[2]; static long long cpu[2];
static long long ns(clockid_t c) { struct timespec t; clock_gettime(c, &t); return t.tv_sec * 1000000000LL + t.tv_nsec; }
static void *w(void *a) {
  int me = (int)(long)a; cpu_set_t s; CPU_ZERO(&s); CPU_SET(cores[me], &s); sched_setaffinity(0, sizeof s, &s);
  long long c0 = ns(CLOCK_THREAD_CPUTIME_ID); volatile double x = 1;
  for (int i = 0; i < N; i++) {
    while (atomic_load(&turn) != me) syscall(SYS_futex, &turn, FUTEX_WAIT_PRIVATE, 1 - me, 0, 0, 0);
    for (int k = 0; k < 2000; k++) x = x * 1.0000001;
    atomic_store(&turn, 1 - me); syscall(SYS_futex, &turn, FUTEX_WAKE_PRIVATE, 1, 0, 0, 0);
  }
  cpu[me] = ns(CLOCK_THREAD_CPUTIME_ID) - c0; return 0;
}
int main(int argc, char **argv) {  /* N CORE0 CORE1 */
  N = atoi(argv[1]); cores[0] = atoi(argv[2]); cores[1] = atoi(argv[3]);
  pthread_t t[2]; long long w0 = ns(CLOCK_MONOTONIC);
  for (long i = 0; i < 2; i++) pthread_create(&t[i], 0, w, (void *)i);
  for (int i = 0; i < 2; i++) pthread_join(t[i], 0);
  printf("%.3f %.3f\n", (cpu[0] + cpu[1]) / 1e3 / N, (ns(CLOCK_MONOTONIC) - w0) / 1e3 / N);
  return 0;
}
"""


def build(folder: Path, name: str, source: str) -> Path:
    """``source`` compiled with the system's C compiler into ``folder/name``."""
    (folder / f"{name}.c").write_text(source)
    subprocess.run(["cc", "-O2", "-pthread", "-o", str(folder / name), str(folder / f"{name}.c")], check=True)
    return folder / name


def whole_on_core(chunks: np.ndarray) -> np.ndarray:
    """The chunks (rows of wall start, wall end, CPU [ns]) that ran whole on their core."""
    return chunks[chunks[:, 2] >= 0.97 * (chunks[:, 1] - chunks[:, 0])]


def covered(chunks: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The share of each chunk's wall that ``other``'s chunks cover."""
    other = other[np.argsort(other[:, 0])]
    share = np.zeros(len(chunks))
    for i, (start, end, _) in enumerate(chunks):
        j, cover = np.searchsorted(other[:, 1], start), 0
        while j < len(other) and other[j, 0] < end:
            cover += min(end, other[j, 1]) - max(start, other[j, 0])
            j += 1
        share[i] = cover / (end - start)
    return share


def chunk_costs(probe: Path, folder: Path, mode: str, work: int, nbytes: int, chunks: int) -> str:
    """One ``chunks`` run: each worker's whole-on-core chunks alone and both on, their median CPU and ratio."""
    out = folder / f"chunks-{mode}-{nbytes}"
    subprocess.run([str(probe), str(out), mode, str(work), str(nbytes), str(chunks)], check=True)
    records = [whole_on_core(np.loadtxt(f"{out}-{core}.txt", dtype=np.int64).reshape(-1, 3)) for core in (0, 1)]
    parts = []
    for core in (0, 1):
        mine, share = records[core], covered(records[core], records[1 - core])
        alone, both = mine[share < 0.05, 2] / 1e3, mine[share > 0.95, 2] / 1e3
        ratio = np.median(both) / np.median(alone) if len(alone) and len(both) else float("nan")
        parts.append(f"core {core}: alone {len(alone)} x {np.median(alone) if len(alone) else np.nan:.1f} us, "
                     f"both on {len(both)} x {np.median(both) if len(both) else np.nan:.1f} us, ratio {ratio:.3f}")
    return "; ".join(parts)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mb", default="0,4,12", help="buffer sizes a worker [MB], 0: the multiply-add chain")
    parser.add_argument("--chunks", type=int, default=1500, help="chunks a worker")
    parser.add_argument("--wakes", type=int, default=20000, help="round trips of the wake probe")
    args = parser.parse_args()
    if len(os.sched_getaffinity(0)) < 2 or not {0, 1} <= os.sched_getaffinity(0):
        sys.exit("needs cores 0 and 1")
    print(f"load {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="evsda-cores-") as tmp:
        folder = Path(tmp)
        chunks, wake = build(folder, "chunks", CHUNKS_C), build(folder, "wake", WAKE_C)
        for mb in (float(x) for x in args.mb.split(",")):
            nbytes = int(mb * (1 << 20))
            # ~0.5-0.8 ms a chunk: the chain's 300 000 steps, or ~48 MB of lines read a chunk
            work = 300_000 if not nbytes else max(1, int(48 / mb))
            for mode in ("threads", "processes"):
                what = "chain" if not nbytes else f"{mb:g} MB each"
                print(f"chunks, {what}, {mode}: {chunk_costs(chunks, folder, mode, work, nbytes, args.chunks)}")
        for cores in ((0, 0), (0, 1)):
            cpu_us, wall_us = subprocess.run([str(wake), str(args.wakes), *map(str, cores)], check=True,
                                             capture_output=True, text=True).stdout.split()
            print(f"wake, cores {cores[0]},{cores[1]}: {cpu_us} us CPU a round trip, {wall_us} us wall")
    print(f"load {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
