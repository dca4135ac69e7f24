"""Optics PSF paths: time per PSF, error of each fast path against the reference, and a rendered pass.

    python benchmarks/optics_paths.py            # about four minutes on 2 cores
    python benchmarks/optics_paths.py --quick    # smaller grids and fewer frames
    OPENBLAS_NUM_THREADS=1 python benchmarks/optics_paths.py   # on a machine shared with other jobs

1. Time per PSF of each path and grid size: the reference (paper Eq. 3-4, a point source
   propagated through the layers on N x N grids, N = 256 .. 4096), the pupil FFT (a turbulent
   pupil zero-padded to N x N), the analytic Airy and long-exposure PSFs on N x N sub-pixel
   grids, and the stamps as the block renders them.
2. Error of each fast path against the reference: total-variation distance
   (:func:`evsda.blocks.optics.paths.total_variation`, the fraction of the flux in the wrong
   pixels) between stamps rendered from the same screens at the same sub-pixel positions,
   for several apertures and turbulence strengths; with the block's own estimate and choice.
3. A turbulent pupil-FFT PSF on a 256 x 256 grid (target < 5 ms).
4. A 10 s LEO pass rendered at 1 kHz with frozen flow through the ``optics`` block
   (target < 10 s).

``--tables [--repeats K]`` prints only the CPU of the tracked pass's three long-exposure tables (the r0 of its
three zenith-angle bins, 2048 radii by 2048 frequencies) made as the block makes them, through one
:class:`.HankelKernel` (the Bessel functions made once), against each made alone, alternated, medians, and
whether they are the same numbers.
"""

from __future__ import annotations

import argparse
import logging
import os
import time

import numpy as np

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics.atmosphere import Atmosphere
from evsda.blocks.optics.fft_screens import fft_phase_screens
from evsda.blocks.optics.imaging import Imager
from evsda.blocks.optics.paths import LOG, total_variation
from evsda.blocks.optics.propagation import plane_spacings, point_source_field, propagate
from evsda.blocks.optics.psf import HankelKernel, long_exposure_profile, psf_fft
from evsda.blocks.optics.render import PupilRenderer, RadialRenderer, StampSampler
from evsda.blocks.optics.sampling import PropagationGrid, planes_for, violations
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.ports import FocalPlane, PointSources
from evsda.graph import RunInfo, Window

FOCAL_PLANE = FocalPlane(1280, 720, 4.86e-6, 1.0)     # Prophesee Gen4 pixels behind a 1 m focal length
WAVELENGTH = 550e-9                                   # [m]
ZENITH = np.deg2rad(30.0)                             # [rad]
RANGE = 6e5                                           # LEO slant range [m]


def best_of(repeats: int, f):
    """Smallest wall time [s] of ``repeats`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = f()
        times.append(time.perf_counter() - t0)
    return min(times), result


def ms(seconds: float) -> str:
    return f"{seconds * 1e3:9.2f} ms"


# -- 1. time per PSF -------------------------------------------------------------------------------
def reference_speed(sizes) -> None:
    """The paper's path on N x N grids: a LEO point source through HV5/7 layers (4 layers, D = 0.3 m)."""
    atmosphere = Atmosphere.hufnagel_valley(4).scaled_to_r0(0.1)
    imager = Imager(Telescope(0.3), FOCAL_PLANE, WAVELENGTH, atmosphere, PointSourceOptics.Params(), seed=(1,))
    imager.ensure_geometry(ZENITH)
    geometry, smallest, index = imager.reference.grid(ZENITH, RANGE)
    layer_planes = [smallest.planes_m[i - 1] for i in index.values()]
    layer_r0 = atmosphere.layer_r0(WAVELENGTH, ZENITH)
    print(f"reference path (paper Eq. 3-4): D = 0.3 m, r0 = {geometry.r0_m * 100:.1f} cm at 550 nm, range "
          f"{RANGE / 1e3:.0f} km, {len(index)} layers; smallest valid grid {smallest.describe()}")
    rng = np.random.default_rng(0)
    for n in sizes:
        grid = PropagationGrid(n, smallest.delta1_m, smallest.deltan_m,
                               planes_for(geometry, n, smallest.delta1_m, smallest.deltan_m, layer_planes))
        assert not violations(geometry, grid), violations(geometry, grid)
        spacing = plane_spacings(grid.delta1_m, grid.deltan_m, grid.planes_m)
        screens = {grid.planes_m.index(z) + 1: fft_phase_screens(rng, n, spacing[grid.planes_m.index(z) + 1],
                                                                 r0_l)[0]
                   for z, r0_l in zip(layer_planes, layer_r0)}
        source = point_source_field(n, grid.delta1_m, WAVELENGTH, RANGE, geometry.roi_m, curvature=False)

        def run():
            return propagate(source, WAVELENGTH, grid.delta1_m, grid.deltan_m, grid.planes_m, screens,
                             source_curvature=-RANGE, collimate=RANGE)

        seconds, _ = best_of(1 if n >= 2048 else 3, run)
        print(f"  N = {n:5d}  {len(grid.planes_m)} steps   {ms(seconds)} per propagation")


def pupil_fft_speed(sizes) -> None:
    """``|FFT(A exp(i phi))|^2`` zero-padded to N x N (pupil N/2 samples across), complex128."""
    rng = np.random.default_rng(0)
    print("pupil FFT PSF (Fraunhofer image of a turbulent pupil, D/r0 = 6, padded x2):")
    for n in sizes:
        m = n // 2
        telescope = Telescope(0.35)
        delta = 0.35 / (m - 2)
        amplitude = telescope.pupil(m, delta)
        phase = fft_phase_screens(rng, m, delta, 0.35 / 6)[0]
        seconds, _ = best_of(1 if n >= 4096 else 3, lambda: psf_fft(amplitude * np.exp(1j * phase), delta,
                                                                   WAVELENGTH, n))
        print(f"  N = {n:5d}  {ms(seconds)} per PSF")


def analytic_speed(sizes) -> None:
    """Analytic PSFs (``airy``, ``long_exposure``) evaluated and binned on N x N sub-pixel grids (8 per pixel)."""
    telescope = Telescope(0.35, 0.3)
    r0 = 0.35 / 7
    theta = np.linspace(0.0, 400 * FOCAL_PLANE.pixel_scale_rad, 4096)
    t_profile, seeing = best_of(1, lambda: long_exposure_profile(telescope, WAVELENGTH, r0, 25.0, theta, 2048))
    profiles = {"airy": telescope.airy(theta, WAVELENGTH), "long_exposure": seeing}
    print(f"analytic PSFs on N x N sub-pixel grids (D = 0.35 m; the long-exposure profile, tabulated once per "
          f"r0: {ms(t_profile)}):")
    offset = np.array([[0.2, -0.3]])
    for n in sizes:
        sampler = StampSampler(n // 8, FOCAL_PLANE.pixel_scale_rad, 8)
        times = {name: best_of(3, lambda: RadialRenderer(sampler, theta, profile).stamps(offset))[0]
                 for name, profile in profiles.items()}
        print(f"  N = {n:5d}  " + "  ".join(f"{name} {ms(t)}" for name, t in times.items()) + " per PSF")


def stamp_speed(frames: int) -> None:
    """What the block runs: pixel-integrated stamps per frame, batched over ``frames`` frames."""
    rng = np.random.default_rng(1)
    print(f"stamps as the block renders them (per frame, batches of {frames}):")
    for d, r0 in ((0.35, 0.05), (0.3, 0.1)):
        atmosphere = Atmosphere.hufnagel_valley(4).scaled_to_r0(r0)
        imager = Imager(Telescope(d), FOCAL_PLANE, WAVELENGTH, atmosphere, PointSourceOptics.Params(), seed=(1,))
        g = imager.ensure_geometry(ZENITH)
        offsets = rng.uniform(-0.5, 0.5, (frames, 2))
        phase = np.stack([fft_phase_screens(rng, g.n_pupil, g.delta_m, imager.r0(ZENITH))[0] for _ in range(frames)])
        renderer, amplitude = imager.pupil_renderer, imager.pupil_amplitude
        t_pupil, _ = best_of(3, lambda: renderer.stamps(amplitude, phase, offsets))
        t_airy, _ = best_of(3, lambda: imager.path_named["airy"].renderer(ZENITH).stamps(offsets))
        t_le, _ = best_of(3, lambda: imager.path_named["long_exposure"].renderer(ZENITH).stamps(offsets))
        print(f"  D = {d} m, D/r0 = {d / imager.r0(ZENITH):.2g}: pupil {g.n_pupil}^2 (FFT {renderer.padded}^2), "
              f"stamp {g.stamp_size}^2 px x {g.oversample}^2 sub-px: pupil_fft {ms(t_pupil / frames)}, "
              f"airy {ms(t_airy / frames)}, long_exposure {ms(t_le / frames)}")


# -- 2. errors against the reference ------------------------------------------------------------------
def path_errors(frames: int) -> None:
    """Distance of each fast path from the reference, stamps from the same screens and positions."""
    print(f"error against the reference (total-variation distance, mean +- sd over {frames} frames 50 ms apart; "
          f"zenith 30 deg, range {RANGE / 1e3:.0f} km):")
    cases = (("vacuum", 0.3, None), ("HV5/7", 0.1, 0.05), ("HV r0 = 10 cm", 0.3, 0.1), ("HV5/7", 0.35, 0.05))
    for label, d, r0 in cases:
        atmosphere = None if r0 is None else Atmosphere.hufnagel_valley(4).scaled_to_r0(r0)
        imager = Imager(Telescope(d), FOCAL_PLANE, WAVELENGTH, atmosphere, PointSourceOptics.Params(), seed=(3,))
        imager.ensure_geometry(ZENITH)
        _, grid, _ = imager.reference.grid(ZENITH, RANGE)
        rng = np.random.default_rng(2)
        errors = {"pupil_fft": [], "airy": [], "long_exposure": []}
        t0 = time.perf_counter()
        for k in range(frames):
            t, xy = 0.05 * k, FOCAL_PLANE.width_px / 2 + rng.uniform(-0.5, 0.5, 2)
            offset = xy[None] - np.round(xy[None])
            sight = imager.sight(*xy, ZENITH)
            field = imager.reference.field("s", t, sight, ZENITH, RANGE)
            phase = imager.reference.pupil_phase("s", t, sight, ZENITH, RANGE)
            reference = imager.pupil_renderer.stamps_from_field(field[None], offset)
            flux = reference.sum()
            stamps = {"pupil_fft": imager.pupil_renderer.stamps(imager.pupil_amplitude, phase[None], offset),
                      "airy": imager.path_named["airy"].renderer(ZENITH).stamps(offset)}
            if atmosphere is not None:
                stamps["long_exposure"] = imager.path_named["long_exposure"].renderer(ZENITH).stamps(offset)
            for name, stamp in stamps.items():
                errors[name].append(float(total_variation(stamp, reference, flux)[0]))
        per_frame = (time.perf_counter() - t0) / frames
        estimates = imager.chooser.estimate_errors(ZENITH, RANGE)
        choice = imager.chooser.choose(ZENITH, RANGE).path
        dr0 = "" if r0 is None else f", D/r0 = {d / imager.r0(ZENITH):.2g}"
        print(f"  {label}, D = {d} m{dr0} (reference N = {grid.n}, {len(grid.planes_m)} steps, "
              f"{per_frame * 1e3:.0f} ms per frame with its screens' upkeep); auto picks '{choice}'")
        for name, values in errors.items():
            if values:
                print(f"    {name:14s} measured {np.mean(values):.3f} +- {np.std(values):.3f}   "
                      f"block's estimate {estimates.get(name, float('nan')):.3f}")


# -- 3. the 5 ms target -------------------------------------------------------------------------------
def pupil_fft_256(frames: int) -> None:
    rng = np.random.default_rng(4)
    n_pupil, d = 128, 0.35
    delta = d / (n_pupil - 2)
    amplitude = Telescope(d, 0.3).pupil(n_pupil, delta)
    phase = fft_phase_screens(rng, n_pupil, delta, d / 7)[0]
    field = amplitude * np.exp(1j * phase)
    single, _ = best_of(20, lambda: psf_fft(field, delta, WAVELENGTH, 256, workers=1))
    single64, _ = best_of(20, lambda: psf_fft(field.astype(np.complex64), delta, WAVELENGTH, 256, workers=1))
    sampler = StampSampler(21, FOCAL_PLANE.pixel_scale_rad, 4)
    renderer = PupilRenderer(sampler, n_pupil, delta, WAVELENGTH, Telescope(d, 0.3).collecting_area_m2)
    phases = np.stack([fft_phase_screens(rng, n_pupil, delta, d / 7)[0] for _ in range(frames)])
    offsets = rng.uniform(-0.5, 0.5, (frames, 2))
    batch, _ = best_of(3, lambda: renderer.stamps(amplitude, phases, offsets))
    print(f"turbulent pupil-FFT PSF on a 256 x 256 grid (128-sample pupil, D/r0 = 7; target < 5 ms): "
          f"{ms(single)} complex128, {ms(single64)} complex64, one thread; "
          f"pixel-integrated 21 x 21 stamps (FFT {renderer.padded}^2) {ms(batch / frames)} per frame in batches of {frames}")


# -- 4. a pass ----------------------------------------------------------------------------------------
def leo_pass(duration_s: float, params: dict) -> None:
    """A satellite crossing the field for ``duration_s`` at 1 kHz, windows of 0.1 s."""
    messages: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: messages.append(record.getMessage())
    LOG.addHandler(handler)
    LOG.setLevel(logging.INFO)

    def track(window: Window) -> PointSources:
        t_ns = window.sample_times_ns(1_000_000)
        t = t_ns * 1e-9
        n = len(t)
        x, y = (100 + 100 * t)[:, None], (300 + 20 * t)[:, None]          # 0.5 mrad/s across the field
        return PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array(["25544"]), np.array([0], np.int8), x, y,
                            np.full((n, 1), 1e4), np.full((n, 1), 8.0), np.full((n, 1), RANGE), np.full(n, ZENITH))

    block = PointSourceOptics(seed=1, **params)
    block.setup(RunInfo(duration_ns=round(duration_s * 1e9)))
    windows = [Window.from_seconds(i * 0.1, (i + 1) * 0.1, index=i) for i in range(round(duration_s / 0.1))]
    wall0, cpu0 = time.perf_counter(), time.process_time()
    first = None
    frames = 0
    for window in windows:
        out = block.step(window, sources=[track(window)])["irradiance"]
        frames += len(out.t_ns)
        if first is None:
            first = time.perf_counter() - wall0
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    LOG.removeHandler(handler)
    path = next((m.split(": ", 1)[1] for m in messages if "path '" in m), "?")
    print(f"{duration_s:g} s pass at 1 kHz ({frames} frames), {params or 'defaults (D = 0.35 m, HV5/7)'}: "
          f"{wall:.2f} s wall, {cpu:.2f} s CPU (first window with the path decision {first:.2f} s; target < 10 s)")
    print(f"    {path}")


#: the tracked pass's three long-exposure tables as its block makes them: the r0 [m] of its zenith-angle bins'
#: centres, the telescope, the band's wavelength [m] and the table's last radius [rad] (2048 radii, 2048 frequencies)
PASS_TABLES_R0 = (0.06876026460792829, 0.07032212312778119, 0.07184851999291819)
PASS_TABLES = dict(telescope=Telescope(0.2, 0.4, 0.85), wavelength=5.682696831531468e-07,
                   last_radius=9.450482130558207e-05)


def table_cpu(repeats: int) -> None:
    """CPU [s] of the pass's three long-exposure tables, each alone against through one kernel (alternated)."""
    telescope, wavelength = PASS_TABLES["telescope"], PASS_TABLES["wavelength"]
    theta = np.linspace(0.0, PASS_TABLES["last_radius"], 2048)

    def tables(kernel):
        return [long_exposure_profile(telescope, wavelength, r0, 25.0, theta, 2048, kernel) for r0 in PASS_TABLES_R0]

    spent = {"each alone": [], "one kernel": []}
    for _ in range(repeats):
        for name, kernel in (("each alone", lambda: None), ("one kernel", HankelKernel)):
            t = time.process_time()
            made = tables(kernel())
            spent[name].append(time.process_time() - t)
            if name == "each alone":
                alone = made
    same = all(np.array_equal(a.view(np.uint64), b.view(np.uint64)) for a, b in zip(alone, made))
    print(f"the pass's 3 long-exposure tables (2048 x 2048), one thread, medians of {repeats}, "
          f"load {os.getloadavg()[0]:.2f}: each alone {np.median(spent['each alone']):.3f} s CPU, through one "
          f"kernel {np.median(spent['one kernel']):.3f} s; the same numbers: {same}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="smaller grids and fewer frames")
    parser.add_argument("--tables", action="store_true", help="only the pass's long-exposure tables' CPU")
    parser.add_argument("--repeats", type=int, default=5, help="with --tables: alternated rounds")
    args = parser.parse_args()
    if args.tables:
        table_cpu(args.repeats)
        return
    # OpenBLAS threads spin against other jobs on a shared machine: compare OPENBLAS_NUM_THREADS=1
    print(f"{os.cpu_count()} CPUs; numpy {np.__version__}; "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")
    sizes = (256, 512, 1024) if args.quick else (256, 512, 1024, 2048, 4096)
    reference_speed(sizes)
    pupil_fft_speed(sizes)
    analytic_speed(sizes)
    stamp_speed(64 if args.quick else 256)
    pupil_fft_256(64 if args.quick else 256)
    path_errors(4 if args.quick else 16)
    leo_pass(1.0 if args.quick else 10.0, {})
    if not args.quick:
        leo_pass(10.0, {"aperture_m": 0.3, "r0_500nm_m": 0.1})


if __name__ == "__main__":
    main()
