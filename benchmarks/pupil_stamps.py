"""Pupil-path stamps at the tracked pass's geometry (issue 13): where a stamp's CPU goes, and the MFT alternative.

The geometry is the one benchmarks/end_to_end.yaml's optics log (``evsda -v run``): a 40 x 40 pupil of
5.26 mm samples (astrograph 200 mm, obscuration 0.4), 568 nm, 7 x 7 stamps of 12.15 urad pixels, so the padded FFT is
80 x 80 and the stamp spans 79 % of the image's period ``lambda / delta``. Turbulent phases come from
FFT screens at r0 = 7 cm; frames render 100 at a time, as a source's window at 1 kHz does. Prints, per PSF
(CPU time, medians over ``--repeats`` alternated rounds, one thread):

* ``PupilRenderer.stamps`` whole (phase to pixel energies);
* its zero-padded FFTs alone (rows of the pupil, then every column, in place, 16 frames at a time, through
  ``scipy.fft.fft``), the same through pocketfft's binding (without scipy's dispatch), as the renderer runs them
  here (compiled with pocketfft's bits: ``column_fft``, from the field written transposed), in double precision
  (complex128), without the pruning (every row of the padded grid: ``fft2``) and through numpy's own FFT (single
  precision since numpy 2);
* the pupil path again with the renderer's one-frame buffers 16 bytes off a cache line (numpy aligns to 16 bytes; the
  renderer's own start on one, ``render.aligned_empty``);
* ``stamps()`` whole in double precision (the tests' reference renderer, ``dtype=np.complex128``);
* a matrix Fourier transform (Soummer et al. 2007, Opt. Express 15, 15935) onto the same 80 x 80
  samples, the fewest that give an exact pixel integral (the intensity's 2n - 1 Fourier lags per
  axis): two complex64 products per PSF, 16 PSFs in one call for the first;
* the pixel-integration products ``B PSF B^T`` alone;
* the pupil path's stamps against the bare FFTs, pocketfft's and the renderer's (issue 13 asks the optics for <= 3x).

``--threads`` adds how well two threads overlap the pupil path (wall clock, medians of the rounds): two threads each
rendering ``FRAMES`` frames 10 times at once against the same 20 calls one after the other on one thread; 2x is no
interpreter lock held, 1x all of it (it needs two free cores: the load is printed). With ``--against`` the other
checkout's renderer is measured the same way, alternated.

``--profile`` adds where ``stamps()``'s time goes: cProfile (CPU clock) over 50 calls, each function's own time
per PSF (the profiler adds ~1 us per call it sees, ~1 us a PSF here).

``--against DIR`` adds, alternated, the same frames through another checkout's ``blocks/optics/render.py``
from the screens' transposed sum on: a renderer without the defocus argument gets the former steps (a
transposing copy, the defocus array added, then ``stamps``); one in four calls has a satellite's defocus.
``--pairs N`` (with ``--against``) instead compares the two pupil paths call by call, ``N`` pairs of ``FRAMES``-frame
calls interleaved (the order alternating), and prints each one's median and the median of the pairs' ratios with
their quartiles: on a loaded host the drift between rounds cancels within a pair.

``--items`` itemises the frame path (``render._stamp_frames``, the renderer's one compiled call a ``stamps()``): each
of its steps in a compiled loop of its own over ``FRAMES`` frames, the frame's buffers in cache (the loops ask for
the renderer's vector width, :func:`.column_fft.wide_vectors`): the tilted phase with its sine and cosine, the row
FFTs with the field's product and their transposition, the column FFTs with ``|.|^2``, ``B PSF B^T`` with the scale,
and ``_stamp_frames`` whole on the same frames (what is left is reading the phases and the calls).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/pupil_stamps.py [--repeats 7] [--profile] [--against DIR]
        [--threads] [--items] [--pairs N]
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import importlib.util
import inspect
import os
import pstats
import statistics
import sys
import threading
import time
import types
from pathlib import Path

import numba
import numpy as np
import scipy.fft as sfft
from numba.core import config as numba_config

from evsda.blocks.optics import column_fft, render
from evsda.blocks.optics.fft_screens import fft_phase_screens
from evsda.blocks.optics.render import STAMP_CHUNK, PupilRenderer, StampSampler, _fft, aligned_empty
from evsda.blocks.optics.telescope import Telescope

N_PUPIL, DELTA_M, WAVELENGTH_M, PIXEL_RAD, STAMP = 40, 0.2 / 38, 568.3e-9, 12.15e-6, 7
FRAMES = 100


def per_psf_us(work, frames: int) -> float:
    start = time.process_time()
    work()
    return (time.process_time() - start) / frames * 1e6


def render_module(checkout: Path):
    """``blocks/optics/render.py`` of another checkout, imported on its own in a package of that checkout's
    ``blocks/optics`` (so that its relative imports read that checkout's modules). Its compiled functions cache in a
    folder of this benchmark's own: in the checkout's ``__pycache__`` they would name this package, which that
    checkout's own runs cannot import (Numba reads ``NUMBA_CACHE_DIR`` once, at its import: set here as its config)."""
    path = (checkout / "blocks" / "optics" / "render.py").resolve()
    package = types.ModuleType("optics_" + hashlib.md5(str(path).encode()).hexdigest()[:8])
    package.__path__ = [str(path.parent)]
    sys.modules[package.__name__] = package
    spec = importlib.util.spec_from_file_location(package.__name__ + ".render", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    own_cache = numba_config.CACHE_DIR
    numba_config.CACHE_DIR = str(Path(os.environ.get("TMPDIR", "/tmp")) / "pupil_stamps_numba")
    try:
        spec.loader.exec_module(module)
    finally:
        numba_config.CACHE_DIR = own_cache
    return module


def numpy_aligned(renderer: PupilRenderer) -> PupilRenderer:
    """``renderer`` with its one-frame buffers (:meth:`.PupilRenderer._frame_buffers`, this thread's) moved 16 bytes
    off a cache line, where numpy's own allocations may start: the renderer before its buffers were aligned."""
    def moved(buffer):
        raw = aligned_empty(buffer.nbytes + 64, np.uint8)
        return raw[16:16 + buffer.nbytes].view(buffer.dtype).reshape(buffer.shape)
    renderer._local.one_frame = tuple(moved(buffer) for buffer in renderer._frame_buffers())
    return renderer


def pupil_path_render(renderer, amplitude, phase_t, offsets, curvature, r2):
    """The pupil path from the screens' transposed sum (F, x, y) to stamps, with ``renderer``'s own steps."""
    if "curvature_rad_m2" in inspect.signature(renderer.stamps).parameters:
        return renderer.stamps(amplitude, phase_t.transpose(0, 2, 1), offsets, curvature)
    phase = np.ascontiguousarray(phase_t.transpose(0, 2, 1))
    phase += curvature[:, None, None] * r2[None]
    return renderer.stamps(amplitude, phase, offsets)


def overlap(work, calls: int = 10) -> float:
    """Wall time of ``2 calls`` of ``work`` one after the other over that of two threads making ``calls`` each."""
    start = time.perf_counter()
    for _ in range(2 * calls):
        work()
    alone = time.perf_counter() - start
    threads = [threading.Thread(target=lambda: [work() for _ in range(calls)]) for _ in range(2)]
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return alone / (time.perf_counter() - start)


def profile(renderer, amplitude, phase, offsets, calls: int = 50) -> None:
    """Each function's own CPU time per PSF inside ``stamps()`` (numpy's ufuncs and BLAS count in their caller)."""
    profiler = cProfile.Profile(time.process_time)
    profiler.enable()
    for _ in range(calls):
        renderer.stamps(amplitude, phase, offsets)
    profiler.disable()
    stats = pstats.Stats(profiler).stats
    rows = sorted(((own, f"{Path(file).name}:{name}" if line else name) for (file, line, name), (_, _, own, _, _)
                   in stats.items()), reverse=True)
    print(f"where stamps() goes (cProfile, own time per PSF over {calls} calls of {len(phase)} frames):")
    for own, name in rows[:10]:
        print(f"  {name:60s} {own / (calls * len(phase)) * 1e6:6.2f} us")


@numba.njit(nogil=True)
def _sincos_frames(phase_t, curvature, r2, ky, kx, x, cosine, sine):
    """:func:`.render._stamp_frames`' first step alone: each frame's tilted phase with its float32 sine and cosine."""
    column_fft.wide_vectors()
    for f in range(phase_t.shape[0]):
        render._tilted_sincos_frame(phase_t[f], curvature[f], r2, ky[f], kx[f], x, cosine, sine)


@numba.njit(nogil=True)
def _row_frames(amplitude, cosine, sine, grid, scratch, twr, twi, frames):
    """The row FFTs of one field ``frames`` times (the field's product in the first pass, the last pass's
    transposition into the grid's real and imaginary rows), as :func:`.column_fft.field_powers` makes them."""
    column_fft.wide_vectors()
    flat_cosine, flat_sine = cosine.reshape(-1), sine.reshape(-1)
    for _ in range(frames):
        column_fft._radix2_8(amplitude, flat_cosine, flat_sine, scratch[2], scratch[3], twr, twi, 40, 40, True)
        column_fft._radix5(scratch[2], scratch[3], scratch[0], 40, 40, 1)
        column_fft._lanes_to_split_rows(scratch[0], grid)


@numba.njit(nogil=True)
def _column_frames(grid, psf, scratch, twr, twi, frames):
    """The column FFTs with ``|.|^2`` of one grid ``frames`` times, as :func:`.column_fft.field_powers` makes them."""
    column_fft.wide_vectors()
    flat_psf = psf.reshape(-1)
    for _ in range(frames):
        column_fft._radix2_8(grid, grid, grid[80:], scratch[2], scratch[3], twr, twi, 80, 160, False)
        column_fft._radix5_powers(scratch[2], scratch[3], flat_psf)


@numba.njit(nogil=True)
def _product_frames(psf, b, b_t, half, image, out, factor, area):
    """``B PSF B^T`` and the scale of one PSF into every frame of ``out``, as :func:`.render._stamp_frames` makes them."""
    column_fft.wide_vectors()
    m = image.shape[0]
    for f in range(out.shape[0]):
        np.dot(psf, b_t, half)
        np.dot(b, half, image)
        for i in range(m):
            for j in range(m):
                out[f, i, j] = np.float64(image[i, j]) * factor / area


def items(renderer: PupilRenderer, amplitude, phase_t, offsets, curvature, repeats: int) -> None:
    """``--items``: :func:`.render._stamp_frames`' steps each in a compiled loop of its own (module docstring)."""
    frames = len(phase_t)
    theta = offsets * renderer.sampler.pixel_scale_rad
    k = 2 * np.pi / renderer.wavelength
    ky, kx = k * theta[:, 1], k * theta[:, 0]
    amplitude_t = np.ascontiguousarray(amplitude.T[None]).astype(np.float32)
    cosine, sine, grid, psf, half, image, scratch = renderer._frame_buffers()
    twr, twi = column_fft.TWIDDLES
    factor, area = (renderer.delta**2 / renderer.wavelength) ** 2, float(renderer.area)
    out = np.empty((frames, renderer.sampler.size, renderer.sampler.size))
    steps = {
        "_stamp_frames whole": lambda: render._stamp_frames(
            phase_t, curvature, renderer.r2, ky, kx, renderer.x, amplitude_t, renderer.b, renderer.b_t, factor, area,
            out, cosine, sine, grid, psf, half, image, scratch, twr, twi),
        "  tilted phase, its sine and cosine": lambda: _sincos_frames(phase_t, curvature, renderer.r2, ky, kx,
                                                                      renderer.x, cosine, sine),
        "  row FFTs (the field's product, transposition)": lambda: _row_frames(
            amplitude_t[0].reshape(-1), cosine, sine, grid, scratch, twr, twi, frames),
        "  column FFTs with |.|^2": lambda: _column_frames(grid, psf, scratch, twr, twi, frames),
        "  B PSF B^T and the scale": lambda: _product_frames(psf, renderer.b, renderer.b_t, half, image, out, factor,
                                                             area)}
    for work in steps.values():
        work()                                                          # compiles the loops
    times = {name: [] for name in steps}
    loads = []
    for _ in range(repeats):
        loads.append(os.getloadavg()[0])
        for name, work in steps.items():
            times[name].append(statistics.median(per_psf_us(work, frames) for _ in range(10)))
    print(f"the frame path's steps, each in its own compiled loop over {frames} frames (buffers in cache); medians of "
          f"{repeats} rounds, load {statistics.median(loads):.1f}")
    medians = {name: statistics.median(values) for name, values in times.items()}
    for name, value in medians.items():
        print(f"  {name:50s} {value:6.2f} us per PSF")
    whole = medians["_stamp_frames whole"]
    print(f"  {'  the rest (the phases read, the calls)':50s} {whole - sum(list(medians.values())[1:]):6.2f} us per PSF")


def pairs(mine, theirs, count: int, label: str) -> None:
    """``--pairs``: the two pupil paths (callables of ``FRAMES`` frames) interleaved call by call (module docstring)."""
    own, other, ratios = [], [], []
    before = os.getloadavg()[0]
    for k in range(count):
        got = {}
        for name, work in ((("mine", mine), ("theirs", theirs)) if k % 2 == 0 else (("theirs", theirs), ("mine", mine))):
            got[name] = per_psf_us(work, FRAMES)
        own.append(got["mine"])
        other.append(got["theirs"])
        ratios.append(got["mine"] / got["theirs"])
    print(f"{count} interleaved pairs of {FRAMES}-frame calls, one thread, load {before:.1f}-{os.getloadavg()[0]:.1f}: "
          f"this tree {statistics.median(own):.2f}, {label} {statistics.median(other):.2f} us per PSF; the pairs' "
          f"ratio {statistics.median(ratios):.3f} (quartiles {np.percentile(ratios, 25):.3f}-"
          f"{np.percentile(ratios, 75):.3f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="alternated rounds (medians)")
    parser.add_argument("--profile", action="store_true", help="each function's own time in stamps()")
    parser.add_argument("--against", type=Path, help="another checkout: its pupil path from the screens' sum on")
    parser.add_argument("--threads", action="store_true", help="two threads' overlap of the pupil path (wall)")
    parser.add_argument("--items", action="store_true", help="the frame path's steps, each in a compiled loop")
    parser.add_argument("--pairs", type=int, help="with --against: this many interleaved pairs of calls instead")
    args = parser.parse_args()
    if args.pairs and not args.against:
        parser.error("--pairs needs --against")
    telescope = Telescope(0.2, 0.4)                                     # library:telescopes/astrograph_200mm.yaml
    renderer = PupilRenderer(StampSampler(STAMP, PIXEL_RAD, 9), N_PUPIL, DELTA_M, WAVELENGTH_M,
                             telescope.collecting_area_m2)
    double = PupilRenderer(StampSampler(STAMP, PIXEL_RAD, 9), N_PUPIL, DELTA_M, WAVELENGTH_M,
                           telescope.collecting_area_m2, dtype=np.complex128)
    amplitude = telescope.pupil(N_PUPIL, DELTA_M)
    rng = np.random.default_rng(1)
    phase = np.concatenate([fft_phase_screens(rng, 2 * N_PUPIL, DELTA_M, 0.07)[0][None, :N_PUPIL, :N_PUPIL]
                            for _ in range(FRAMES)])
    offsets = rng.uniform(-0.5, 0.5, (FRAMES, 2))
    n, size, chunk = N_PUPIL, renderer.padded, STAMP_CHUNK
    field = (amplitude * np.exp(1j * phase[:chunk])).astype(np.complex64)
    grid = np.zeros((chunk, size, size), np.complex64)
    psf = np.abs(sfft.fft2(np.pad(field, ((0, 0), (0, size - n), (0, size - n))))).astype(np.float32) ** 2
    lags = np.arange(size)
    w = np.exp(-2j * np.pi * np.outer(lags, np.arange(n) - n // 2) / size).astype(np.complex64)   # (L, n)
    w_t = np.ascontiguousarray(w.T)

    grid_double = np.zeros((chunk, size, size), np.complex128)

    def fft(grid=grid):
        grid[:, :n, :n] = field
        grid[:, :n, n:] = 0
        sfft.fft(grid[:, :n], axis=-1, workers=1, overwrite_x=True)
        grid[:, n:] = 0
        sfft.fft(grid, axis=-2, workers=1, overwrite_x=True)

    def binding():
        grid[:, :n, :n] = field
        grid[:, :n, n:] = 0
        _fft(grid[:, :n], 2)
        grid[:, n:] = 0
        _fft(grid, 1)

    scratch = aligned_empty((4, size * size), np.float32)

    field_t = np.ascontiguousarray(field.transpose(0, 2, 1))
    real_t, imag_t, ones = (np.ascontiguousarray(field_t.real), np.ascontiguousarray(field_t.imag),
                            np.ones((1, n, n), np.float32))

    def compiled_columns():
        column_fft.rows(ones, real_t, imag_t, grid, scratch)
        column_fft.columns(grid, scratch)

    def numpy_fft():
        grid[:, :n, :n] = field
        grid[:, :n, n:] = 0
        rows = grid[:, :n]
        np.fft.fft(rows, axis=-1, out=rows)
        grid[:, n:] = 0
        np.fft.fft(grid, axis=-2, out=grid)

    def unpruned():
        grid[:, :n, :n] = field
        grid[:, :n, n:] = 0
        grid[:, n:] = 0
        sfft.fft2(grid, workers=1, overwrite_x=True)

    def mft():
        along_x = (field.reshape(chunk * n, n) @ w_t).reshape(chunk, n, size)
        return np.matmul(w, along_x)

    phase_t = np.ascontiguousarray(phase.transpose(0, 2, 1))
    curvature = np.pi / WAVELENGTH_M * np.where(np.arange(FRAMES) % 4 == 0, 1 / 7.4e5, 0.0)
    binding_row, own_row = "  the same through the binding", "  the same as the renderer runs them"
    chunked = PupilRenderer(StampSampler(STAMP, PIXEL_RAD, 9), N_PUPIL, DELTA_M, WAVELENGTH_M,
                            telescope.collecting_area_m2)
    chunked._frames = False
    misaligned = numpy_aligned(PupilRenderer(StampSampler(STAMP, PIXEL_RAD, 9), N_PUPIL, DELTA_M, WAVELENGTH_M,
                                             telescope.collecting_area_m2))
    cases = {"stamps() whole": (lambda: renderer.stamps(amplitude, phase, offsets), FRAMES),
             "  the same chunk by chunk (numpy's products)": (lambda: chunked.stamps(amplitude, phase, offsets),
                                                              FRAMES),
             "pupil path from the screens' sum": (lambda: pupil_path_render(renderer, amplitude, phase_t, offsets,
                                                                             curvature, renderer.r2), FRAMES),
             "  the same, its buffers 16 bytes off a cache line": (
                 lambda: pupil_path_render(misaligned, amplitude, phase_t, offsets, curvature, renderer.r2), FRAMES),
             "stamps() whole, double precision": (lambda: double.stamps(amplitude, phase, offsets), FRAMES),
             "padded FFTs alone": (fft, chunk),
             binding_row: (binding, chunk),
             own_row: (compiled_columns, chunk),
             "  the same in complex128": (lambda: fft(grid_double), chunk),
             "  the same unpruned (fft2)": (unpruned, chunk)}
    if np.lib.NumpyVersion(np.__version__) >= "2.0.0":                  # out= and single-precision FFTs
        cases["  the same through numpy.fft"] = (numpy_fft, chunk)
    cases["MFT onto the same samples"] = (mft, chunk)
    cases["products B PSF B^T alone"] = (lambda: np.matmul(renderer.b, np.matmul(psf, renderer.b_t)), chunk)
    if args.against:
        module = render_module(args.against)
        other = module.PupilRenderer(module.StampSampler(STAMP, PIXEL_RAD, 9), N_PUPIL, DELTA_M, WAVELENGTH_M,
                                     telescope.collecting_area_m2)
        cases[f"  the same, {args.against}"] = (lambda: pupil_path_render(other, amplitude, phase_t, offsets,
                                                                           curvature, renderer.r2), FRAMES)
        mine, theirs = cases["pupil path from the screens' sum"][0](), cases[f"  the same, {args.against}"][0]()
        print(f"largest stamp difference {np.abs(mine - theirs).max() / theirs.max():.2g} of the peak")
        if args.pairs:
            pairs(cases["pupil path from the screens' sum"][0], cases[f"  the same, {args.against}"][0], args.pairs,
                  str(args.against))
            return
    if args.items:
        items(renderer, amplitude, phase_t, offsets, curvature, args.repeats)
        return
    for work, _ in cases.values():
        work()                                                          # first calls: Numba's cache, plans
    times = {name: [] for name in cases}
    loads = []
    for _ in range(args.repeats):
        loads.append(os.getloadavg()[0])
        for name, (work, frames) in cases.items():
            times[name].append(statistics.median(per_psf_us(work, frames) for _ in range(20)))
    print(f"pupil {n}^2, FFT {size}^2, stamps {STAMP}^2, one thread; medians of {args.repeats} rounds, "
          f"load {statistics.median(loads):.1f}")
    for name, values in times.items():
        print(f"  {name:40s} {statistics.median(values):6.1f} us per PSF")
    path = statistics.median(times["pupil path from the screens' sum"])
    print(f"  the pupil path's stamps against the bare FFTs: {path / statistics.median(times[binding_row]):.2f}x "
          f"pocketfft's, {path / statistics.median(times[own_row]):.2f}x its own")
    if args.threads:
        paths = {"this tree": cases["pupil path from the screens' sum"][0]}
        if args.against:
            paths[str(args.against)] = cases[f"  the same, {args.against}"][0]
        overlaps, loads = {name: [] for name in paths}, []
        for _ in range(args.repeats):
            loads.append(os.getloadavg()[0])
            for name, work in paths.items():
                overlaps[name].append(overlap(work))
        print(f"two threads at once against one after the other (wall; medians of {args.repeats} rounds, "
              f"load {statistics.median(loads):.1f}; 2x: no interpreter lock held):")
        for name, values in overlaps.items():
            print(f"  {name:40s} {statistics.median(values):5.2f}x  ({', '.join(f'{v:.2f}' for v in values)})")
    if args.profile:
        profile(renderer, amplitude, phase, offsets)


if __name__ == "__main__":
    main()

