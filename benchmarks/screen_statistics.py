"""Statistics of walked (extended) layer screens against von Karman's, with their standard errors.

A footprint of ``--across`` samples (a circular pupil inside it) walks along a layer screen as a
star's line of sight sweeps a high layer, ``--speed`` samples per frame, for ``--columns``
columns; the window is sized as the optics block sizes it (:func:`.sizing.layer_grids`). Each
frame reads the screen on the integer grid of its footprint (the spline's values there), so the
references are exact for the grid:

1. the structure function along the walk and across it at lags 1 sample to the footprint, on
   pairs that straddle the seam between the regenerated (FFT) screen and the first extended
   columns, and on pairs far into the extension, against von Karman's ``D(r)``
   (:func:`.kolmogorov.structure_function`; Kolmogorov's ``6.88 (r/r0)^(5/3)`` below ``L0``);
2. residual variances after removing J = 1..21 Zernike modes on the pupil, against their exact
   expectation for von Karman phase on the same points, ``tr(P C P) / N`` with ``C = -D/2``
   (piston removed; Noll 1976 Table IV's values are its ``L0 -> inf`` limit, printed beside);
3. drift along a long walk: the lag-1 and footprint structure functions and the piston-removed
   variance in each tenth of the walk, and the structure function of one point's values over the
   whole walk at lags of 1 to 4096 samples (the large scales: :mod:`.large_scales`; a repeating
   screen would dip back towards 0), with the spread of the per-walk values against a Gaussian
   field's, ``sqrt(2 sum_(i,j) c_ij^2) / N`` with ``c_ij = (D(s+k) + D(s-k))/2 - D(s)``, ``s = j - i``
   (how far one walk's statistics stand for the ensemble's);
4. image wander: a footprint drifting diagonally (0.3, 0.4 samples per frame, 3000 frames, as the
   wind carries a static star's), the RMS difference between the mean tilts of the two halves.

Every figure is the mean over ``--seeds`` independent screens with its standard error (the
spread of the per-screen values / sqrt(seeds)), and the deviation in standard errors.

    OPENBLAS_NUM_THREADS=1 python benchmarks/screen_statistics.py [--seeds 200] [--columns 10000]
    ... --without-large-scales     # the conditional draws alone (outer scale L0, no modes): the screens before
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from evsda.blocks.optics.kolmogorov import structure_function
from evsda.blocks.optics import layer_screen
from evsda.blocks.optics.layer_screen import LayerScreen
from evsda.blocks.optics.screen_kernels import MARGIN
from evsda.blocks.optics.zernike import NOLL_1976_RESIDUALS, zernike_basis

DELTA_M = 0.02        # screen spacing [m] (D/8 of a 0.2 m aperture, as the tracked pass's high layers)
L0_M = 25.0           # outer scale [m] (the block's default)
N_MODES = 21


def window_width(across: int) -> int:
    """The block's window for a footprint ``across`` samples wide (:func:`.sizing.layer_grids`)."""
    n = across + across // 2 + 2 * MARGIN + 2
    return n + n % 2


def walk(seed: int, across: int, columns: int, speed: float) -> tuple[np.ndarray, int]:
    """Values (F, across + 1, across + 1) of each frame's footprint grid, and the index of the first frame whose
    footprint reaches the first extended column."""
    n = window_width(across)
    frames = int(columns / speed)
    start = 100.0
    left = start + np.floor(speed * np.arange(frames))
    grid = np.arange(across + 1.0)
    rows = np.tile(start + grid, (frames, 1))
    cols = left[:, None] + grid[None]
    screen = LayerScreen(n, DELTA_M, (seed,), L0=L0_M)
    out_t = np.zeros((frames, across + 1, across + 1))
    screen.accumulate(rows, cols, np.zeros(frames, np.int64), np.ones(frames), out_t)
    # the first window is centred on the first footprint: its last column is origin + n - 1
    first_new = int(np.floor(start + across / 2)) - n // 2 + n
    seam_frame = int(np.searchsorted(cols[:, -1], first_new))
    return out_t.transpose(0, 2, 1), seam_frame


def seam(seed: int, across: int, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean squared differences at ``lags`` [samples] of pairs straddling the seam between a regenerated window and
    the columns extended from it (along the extension), and across the extension direction within those new
    columns."""
    n = window_width(across)
    screen = LayerScreen(n, DELTA_M, (seed,), L0=L0_M)
    low = np.array([100.0, 100.0])
    screen.cover(low, low + across)
    first_new = int(screen.origin[1]) + n                       # the first column the extension draws
    screen.cover(low + [0, n // 2], low + across + [0, n // 2])     # about n / 2 new columns
    top, left = int(screen.origin[0]) + MARGIN, int(screen.origin[1]) + MARGIN
    grid = screen.sample(np.arange(top, top + n - 2 * MARGIN, dtype=float)[None],
                         np.arange(left, left + n - 2 * MARGIN, dtype=float)[None])[0]
    cols = np.arange(left, left + n - 2 * MARGIN)
    along, transverse = [], []
    for k in lags:
        straddle = (cols[:-k] < first_new) & (cols[k:] >= first_new)
        along.append(np.mean((grid[:, k:][:, straddle] - grid[:, :-k][:, straddle]) ** 2))
        new = cols >= first_new
        transverse.append(np.mean((grid[k:, new] - grid[:-k, new]) ** 2))
    return np.array(along), np.array(transverse)


def pupil_projector(across: int):
    """Points of the circular pupil on the footprint grid, and the orthonormal Zernike basis (J = 1..21) on them."""
    x = np.arange(across + 1.0) - across / 2
    xx, yy = np.meshgrid(x, x)
    inside = np.hypot(xx, yy) <= across / 2
    q, _ = np.linalg.qr(zernike_basis(N_MODES, xx[inside], yy[inside], across / 2).T)
    return inside, q, xx[inside], yy[inside]


def expected_residuals(across: int) -> np.ndarray:
    """``E[|phase - its first J modes|^2] / N`` [rad^2] for von Karman phase on the pupil's points, J = 1..21."""
    inside, q, x, y = pupil_projector(across)
    d = structure_function(np.hypot(x[:, None] - x[None], y[:, None] - y[None]) * DELTA_M, 1.0, L0_M)
    c = -0.5 * d                                          # a covariance up to a constant, which piston removal drops
    total = np.trace(c) - np.sum(q[:, :1] * (c @ q[:, :1]))
    removed = np.cumsum(np.einsum("ij,ij->j", q, c @ q))
    return (np.trace(c) - removed) / len(x), total


def residuals(values: np.ndarray, across: int) -> np.ndarray:
    """Per-frame residual variances (F, 21) after removing J = 1..21 modes."""
    inside, q, _, _ = pupil_projector(across)
    phase = values[:, inside]
    return (np.sum(phase**2, axis=1)[:, None] - np.cumsum((phase @ q) ** 2, axis=1)) / phase.shape[1]


def report(label: str, per_seed: np.ndarray, expected: np.ndarray, names) -> None:
    mean = per_seed.mean(axis=0)
    error = per_seed.std(axis=0, ddof=1) / np.sqrt(len(per_seed))
    print(f"  {label}")
    for name, m, e, x in zip(names, mean, error, expected):
        print(f"    {name:>12s}  {m:10.5f} +- {e:8.5f}   expected {x:10.5f}   ratio {m / x:6.3f}   "
              f"{(m - x) / e:+5.1f} SE")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=200)
    parser.add_argument("--columns", type=int, default=10000, help="columns walked per screen")
    parser.add_argument("--across", type=int, default=12, help="footprint width [samples]")
    parser.add_argument("--speed", type=float, default=1.0, help="columns per frame")
    parser.add_argument("--seam-screens", type=int, default=2000, help="screens for the seam statistics")
    parser.add_argument("--without-large-scales", action="store_true",
                        help="the conditional draws alone, with von Karman's L0 (the screens before the modes)")
    args = parser.parse_args()
    if args.without_large_scales:
        layer_screen.split_outer_scale = lambda n, delta, L0: L0
    across = args.across
    lags = np.array([1, 2, 4, 8, across])
    t0 = time.process_time()
    seams = np.array([seam(10_000 + seed, across, lags) for seed in range(args.seam_screens)])
    far_along, far_across, noll, blocks, series = [], [], [], [], []
    for seed in range(args.seeds):
        values, first = walk(seed, across, args.columns, args.speed)
        far = values[first + 2 * window_width(across):]
        far_along.append([np.mean((far[:, :, k:] - far[:, :, :-k]) ** 2) for k in lags])
        far_across.append([np.mean((far[:, k:, :] - far[:, :-k, :]) ** 2) for k in lags])
        noll.append(residuals(far, across).mean(axis=0))
        tenths = np.array_split(far, 10)
        blocks.append([[np.mean((b[:, :, 1:] - b[:, :, :-1]) ** 2), np.mean((b[:, :, across:] - b[:, :, :-across]) ** 2),
                        residuals(b, across)[:, 0].mean()] for b in tenths])
        point = far[:, across // 2, 0] if args.speed == 1.0 else None
        if point is not None:
            series.append(point)
    cpu = time.process_time() - t0
    n = window_width(across)
    L1 = LayerScreen(n, DELTA_M, (0,), L0=L0_M).L1
    print(f"{args.seeds} screens, window {n} samples for a {across}-sample footprint, {args.columns} columns walked "
          f"{args.speed:g} per frame; delta {DELTA_M} m, L0 {L0_M} m, r0 = 1 m; conditional draws' outer scale "
          f"L1 {L1:.2f} m{' (no large-scale modes)' if L1 == L0_M else ''}; {cpu:.1f} s CPU")
    expected = structure_function(lags * DELTA_M, 1.0, L0_M)
    names = [f"lag {k}" for k in lags]
    report(f"1. structure function [rad^2], pairs across the seam (regenerated | extended), along the walk "
           f"({args.seam_screens} screens)", seams[:, 0], expected, names)
    report("   across the walk, in the first extended columns", seams[:, 1], expected, names)
    report("   far into the extension, along the walk", np.array(far_along), expected, names)
    report("   far into the extension, across the walk", np.array(far_across), expected, names)
    noll_expected, _ = expected_residuals(across)
    js = [1, 2, 3, 4, 6, 10, 15, 21]
    report("2. residual variance after removing J modes [rad^2] (pupil of %d samples)" % across,
           np.array(noll)[:, [j - 1 for j in js]], noll_expected[[j - 1 for j in js]], [f"J = {j}" for j in js])
    scale = (across * DELTA_M) ** (5 / 3)
    print("     Noll 1976 (L0 = inf): " + "  ".join(f"J={j}: {NOLL_1976_RESIDUALS[j] * scale:.5f}" for j in js))
    blocks = np.array(blocks)                             # (seeds, 10, 3)
    print("3. along the walk, by tenths (mean over screens; SE):")
    for i, name in enumerate(("D(1 sample)", f"D({across} samples)", "piston-removed variance")):
        m = blocks[:, :, i].mean(axis=0)
        e = blocks[:, :, i].std(axis=0, ddof=1) / np.sqrt(len(blocks))
        slope = np.polyfit(np.arange(10), blocks[:, :, i].T, 1)[0]          # per screen, per tenth
        print(f"    {name:24s} " + " ".join(f"{x:.4f}" for x in m) + f"  (SE ~{e.mean():.4f}); trend per tenth "
              f"{slope.mean():+.5f} +- {slope.std(ddof=1) / np.sqrt(len(slope)):.5f}")
    if series:
        s = np.array(series)
        long_lags = np.array([k for k in (1, 4, 16, 64, 256, 1024, 2048, 4096) if k <= s.shape[1] // 2])
        per = np.array([[np.mean((x[k:] - x[:-k]) ** 2) for k in long_lags] for x in s])
        expected = structure_function(long_lags * DELTA_M, 1.0, L0_M)
        report("   one point's values over the walk: structure function at long lags", per, expected,
               [f"lag {k}" for k in long_lags])
        spread = per.std(axis=0, ddof=1) / expected
        gaussian = [gaussian_spread(k, s.shape[1]) / x for k, x in zip(long_lags, expected)]
        print("     spread of one walk's value / von Karman's: " + "  ".join(
            f"lag {k}: {a:.3f} (Gaussian field {b:.3f})" for k, a, b in zip(long_lags, spread, gaussian)))
    shifts = np.array([wander(seed, across) for seed in range(min(args.seeds, 150))])
    rms = np.sqrt(np.mean(shifts**2, axis=0))
    print(f"4. image wander, {len(shifts)} drifting footprints: RMS difference of the halves' mean tilts "
          f"x {rms[0]:.4f}, y {rms[1]:.4f} rad/sample (+- {rms.mean() / np.sqrt(2 * len(shifts)):.4f})")


def gaussian_spread(lag: int, length: int) -> float:
    """Standard deviation [rad^2] of one walk's mean squared difference at ``lag`` over ``length`` samples of a
    Gaussian field with von Karman's structure function D: ``Var = (2 / N^2) sum_(i,j) c_ij^2`` (Isserlis), with
    ``c_ij = (D(s + lag) + D(s - lag)) / 2 - D(s)`` the covariance of two differences ``s = j - i`` apart."""
    n = length - lag
    s = np.arange(-(n - 1), n)
    d = lambda k: structure_function(np.abs(k) * DELTA_M, 1.0, L0_M)
    c = 0.5 * (d(s + lag) + d(s - lag)) - d(s)
    return float(np.sqrt(2 * np.sum((n - np.abs(s)) * c**2)) / n)


def wander(seed: int, across: int, frames: int = 3000, velocity=(0.3, 0.4)) -> np.ndarray:
    """Difference between the mean tilts [rad per sample, r0 = 1 m] (x, y) of the second and first half of a
    drifting footprint's frames."""
    n = window_width(across)
    grid = np.arange(across + 1.0)
    x = grid - across / 2
    xx, yy = np.meshgrid(x, x)
    fit = np.linalg.pinv(np.c_[xx.ravel(), yy.ravel(), np.ones(xx.size)])
    rows = 100 + velocity[0] * np.arange(frames)
    cols = 100 + velocity[1] * np.arange(frames)
    out_t = np.zeros((frames, across + 1, across + 1))
    LayerScreen(n, DELTA_M, (20_000 + seed,), L0=L0_M).accumulate(rows[:, None] + grid, cols[:, None] + grid,
                                                                  np.zeros(frames, np.int64), np.ones(frames), out_t)
    tilt = out_t.transpose(0, 2, 1).reshape(frames, -1) @ fit.T
    return tilt[frames // 2:, :2].mean(axis=0) - tilt[:frames // 2, :2].mean(axis=0)


if __name__ == "__main__":
    main()
