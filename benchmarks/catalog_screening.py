"""Many objects from one catalogue: screening time against catalogue size, cost against crossing objects,
the screen against brute force, and the optics of N objects together against N single-object runs.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/catalog_screening.py [--quick]

Scene: the bundled CelesTrak active catalogue of 2026-03-19 (14 710 objects) seen from Graz on
2026-03-20 18:50 UTC, staring at azimuth 35 deg, elevation 30 deg (examples/starlink_field.yaml),
60 s runs. Times are wall-clock medians of repeats on this machine (see the load average printed).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings
from datetime import datetime, timezone

import numpy as np

from evsda import library
from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.ports import FocalPlane, PointSources
from evsda.blocks.ports.scene import GROUND, Observer, Pointing
from evsda.blocks.scene import projection
from evsda.blocks.scene.element_sets import read_catalog, read_text
from evsda.blocks.scene.geometry import ObserverModel
from evsda.blocks.scene.pointing import PointingModel
from evsda.blocks.scene.satellite_catalog import SatelliteCatalog
from evsda.blocks.scene.screening import Screen
from evsda.graph import NS_PER_S, RunInfo, Window

START = datetime(2026, 3, 20, 18, 50, tzinfo=timezone.utc)
GRAZ = Observer(name="Graz", kind=GROUND, latitude_deg=47.0671, longitude_deg=15.4934, altitude_m=493.0,
                min_elevation_deg=10.0, max_sun_elevation_deg=-12.0, extinction_mag_per_airmass=0.25)
POINTING = Pointing(mode="stare", azimuth_deg=35.0, elevation_deg=30.0)
CATALOG = "library:tle/celestrak-active-2026-03-19.tle.gz"
DURATION_NS = 60 * NS_PER_S


def field(fov_x_deg: float) -> FocalPlane:
    """A Gen4 HD sensor (1280 x 720, 4.86 um) behind the lens that gives this horizontal field."""
    pitch = 4.86e-6
    return FocalPlane(1280, 720, pitch, 1280 * pitch / (2 * np.tan(np.radians(fov_x_deg) / 2)))


def median_time(function, repeats: int) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - started)
    return statistics.median(times), result


def brute_force(satrecs, pointing, fp, step_ns=NS_PER_S // 10) -> set[int]:
    """Objects inside the detector at any 0.1 s sample, every object propagated at every sample."""
    screen = Screen(satrecs, pointing, fp, START, 0, DURATION_NS)
    found: set[int] = set()
    t_all = np.arange(0, DURATION_NS + 1, step_ns)
    for chunk in range(0, len(t_all), 60):
        t = t_all[chunk:chunk + 60]
        teme, r_obs, _, _ = screen._frame_quantities(t)
        axes = pointing.frame(t.astype(float))
        r_km, _, errors = screen._propagate(satrecs, t)
        rel = np.einsum("jit,ntj->nti", teme, r_km) * 1000.0 - r_obs[None]
        xi, eta = projection.tangent_plane(*(np.einsum("ntk,tk->nt", rel, a) for a in axes))
        inside = projection.inside(*projection.to_pixels(xi, eta, fp), fp) & (errors == 0)
        found |= set(np.flatnonzero(inside.any(axis=1)).tolist())
    return found


def screening_table(objects, repeats: int) -> None:
    print("\n1. Screening time against catalogue size (60 s run, 20 deg field), and against brute force")
    print(f"{'objects':>8} {'screen [s]':>11} {'coarse cand.':>13} {'after fine':>11} {'brute force 0.1 s [s]':>22}"
          f" {'in field':>9} {'missed':>7}")
    fp = field(20.0)
    pointing = PointingModel(POINTING, ObserverModel(GRAZ, START, 10 * NS_PER_S), START, 10 * NS_PER_S)
    for n in (1000, 3000, 10000, len(objects)):
        satrecs = [o.satrec for o in objects[:n]]
        seconds, result = median_time(lambda: Screen(satrecs, pointing, fp, START, 0, DURATION_NS).run(), repeats)
        if n == 10000:
            brute_s, found = median_time(lambda: brute_force(satrecs, pointing, fp), 1)
            missed = len(found - set(result.intervals))
            brute = f"{brute_s:22.1f} {len(found):9d} {missed:7d}"
        else:
            brute = f"{'-':>22} {'-':>9} {'-':>7}"
        print(f"{n:8d} {seconds:11.3f} {result.n_coarse_candidates:13d} {len(result.intervals):11d} {brute}")


def run_catalog_block(fp: FocalPlane, window_ns: int = NS_PER_S // 10):
    """The satellite_catalog block over the 60 s run: (prepare seconds, sampling seconds, block)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        block = SatelliteCatalog(catalog_file=CATALOG, area_m2=1.04, require_crossing=False)
        block.setup(RunInfo(epoch=START, duration_ns=DURATION_NS, window_ns=window_ns))
    started = time.perf_counter()
    block.prepare(Window(0, 0, window_ns, START), GRAZ, POINTING, fp)
    prepared = time.perf_counter() - started
    started = time.perf_counter()
    outputs = []
    for k in range(DURATION_NS // window_ns):
        window = Window(k, k * window_ns, (k + 1) * window_ns, START)
        outputs.append(block.step(window, observer=GRAZ, pointing=POINTING, focal_plane=fp)["sources"])
    return prepared, time.perf_counter() - started, block, outputs


def cost_table(fields) -> None:
    print("\n2. Cost against the objects that cross the field (all 14 710 objects screened every time; 60 s at 1 ms)")
    print(f"{'field [deg]':>11} {'crossing':>9} {'observable [s]':>15} {'screen+passes [s]':>18} {'sampling [s]':>13}"
          f" {'per object-second [ms]':>23}")
    for fov in fields:
        prepared, sampled, block, _ = run_catalog_block(field(fov))
        seconds = sum(p.duration_s for c in block.crossings for p in c.passes)
        per = 1000 * sampled / seconds if seconds else float("nan")
        print(f"{fov:11.1f} {len(block.crossings):9d} {seconds:15.1f} {prepared:18.2f} {sampled:13.2f} {per:23.1f}")


def column(src: PointSources, j: int) -> PointSources:
    pick = slice(j, j + 1)
    return PointSources(src.focal_plane, src.wavelength_m, src.t_ns, src.source_id[pick], src.kind[pick],
                        src.x_px[:, pick], src.y_px[:, pick], src.photon_flux[:, pick], src.magnitude[:, pick],
                        src.range_m[:, pick], src.zenith_angle_rad, src.boresight_azimuth_rad,
                        src.field_rotation_rad)


def optics_table(fov: float, simulated_s: float) -> None:
    print(f"\n3. Optics of N objects together against N single-object runs ({fov:g} deg field, first "
          f"{simulated_s:g} s, long-exposure PSF at 200 Hz as in examples/starlink_field.yaml)")
    _, _, block, outputs = run_catalog_block(field(fov))
    window_ns = NS_PER_S // 10
    windows = int(simulated_s * NS_PER_S) // window_ns
    n = len(block.crossings)

    def optics_run(select):
        optics = PointSourceOptics(aperture_m=0.0357, throughput=0.9, render_rate_hz=200.0, psf_path="long_exposure",
                                   seed=1, name="telescope/optics")
        optics.setup(RunInfo(epoch=START, duration_ns=DURATION_NS, window_ns=window_ns, seed=1))
        frames = []
        for k in range(windows):
            window = Window(k, k * window_ns, (k + 1) * window_ns, START)
            frames.append(optics.step(window, sources=[select(outputs[k])])["irradiance"])
        return frames

    together_s, together = median_time(lambda: optics_run(lambda s: s), 1)
    alone_s, total = 0.0, None
    for j in range(n):
        seconds, frames = median_time(lambda: optics_run(lambda s: column(s, j)), 1)
        alone_s += seconds
        images = [sum_stamps(f) for f in frames]
        total = images if total is None else [a + b for a, b in zip(total, images)]
    difference = max(float(np.abs(sum_stamps(f) - t).max()) for f, t in zip(together, total))
    peak = max(float(t.max()) for t in total)
    print(f"{'objects':>8} {'together [s]':>13} {'sum of single runs [s]':>23} {'ratio':>6} "
          f"{'max |difference| / peak flux':>29}")
    print(f"{n:8d} {together_s:13.2f} {alone_s:23.2f} {together_s / alone_s:6.2f} {difference / peak:29.1e}")


def sum_stamps(irradiance) -> np.ndarray:
    """Total stamp flux per (sample, pixel) on the detector [photon s^-1]."""
    fp = irradiance.focal_plane
    image = np.zeros((len(irradiance.t_ns), fp.height_px * fp.width_px))
    from evsda.blocks.pixel.sampling import stamp_pixels
    sparse = stamp_pixels(irradiance, np.arange(len(irradiance.t_ns)))
    np.add.at(image, (sparse.sample, sparse.pixel), sparse.flux)
    return image


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one repeat, fewer fields, 2 s of optics")
    args = parser.parse_args()
    repeats = 1 if args.quick else 3
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    started = time.perf_counter()
    catalog = read_catalog(read_text(library.resolve(CATALOG), "benchmark"), "tle", CATALOG, skip_bad=False)
    print(f"read {len(catalog)} objects in {time.perf_counter() - started:.2f} s")
    screening_table(catalog.objects, repeats)
    cost_table((7.1, 20.0) if args.quick else (2.0, 7.1, 20.0, 40.0))
    optics_table(40.0, 2.0 if args.quick else 10.0)


if __name__ == "__main__":
    main()
