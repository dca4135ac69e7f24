"""Scene geometry speed and accuracy: knot interpolation versus Skyfield at every sample.

    python benchmarks/scene_geometry.py

1. The satellite: a 10 s pass at 1 ms cadence (10 001 samples) through SatelliteView,
   for several knot spacings, against Skyfield's ``observe().apparent()`` at every sample.
2. The stars: ~1000 stars in a staring field for 10 s at 1 ms through StarField.project,
   against Skyfield's apparent places at a subset of the samples.
3. The pass finder over an hour.
"""

from __future__ import annotations

import time
from datetime import datetime, timezone

import numpy as np
from skyfield.api import Star

from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import GROUND, Observer, Pointing
from evsda.blocks.scene import projection
from evsda.blocks.scene.ephemeris import planets, skyfield_time, timescale
from evsda.blocks.scene.geometry import unit
from evsda.blocks.scene.passes import find_passes
from evsda.blocks.scene.stars import StarField
from evsda.blocks.scene.tle import earth_satellite, parse_tles
from evsda.blocks.scene.view import SatelliteView
from evsda import library
from evsda.graph import RunInfo, Window

NS = 10**9
START = datetime(2023, 3, 20, 19, 19, 57, tzinfo=timezone.utc)
GRAZ = Observer(name="Graz", kind=GROUND, latitude_deg=47.0671, longitude_deg=15.4934, altitude_m=493,
                min_elevation_deg=10, max_sun_elevation_deg=-12, extinction_mag_per_airmass=0.2)
STARE = Pointing(mode="stare", azimuth_deg=343.75, elevation_deg=40.57)
GEN4 = FocalPlane(1280, 720, 4.86e-6, 1.0)
ARCSEC = 3600 * 180 / np.pi


def best_of(n, f):
    times, result = [], None
    for _ in range(n):
        t0 = time.perf_counter()
        result = f()
        times.append(time.perf_counter() - t0)
    return min(times), result


def satellite() -> None:
    iss = parse_tles(library.path("tle/iss.tle").read_text())[0]
    t_ns = np.arange(0, 10 * NS + 1, 1_000_000)
    target = planets()["earth"] + earth_satellite(iss.line1, iss.line2)
    reference_view = SatelliteView(iss, GRAZ, STARE, GEN4, START)
    observer = reference_view.observer_model.skyfield_observer()
    t_sky, ref = best_of(1, lambda: observer.at(skyfield_time(START, t_ns)).observe(target).apparent().xyz.m.T)
    print(f"satellite, 10 s at 1 ms ({len(t_ns)} samples): Skyfield observe().apparent() at every sample "
          f"{t_sky * 1e3:.0f} ms")
    for knot_s in (1.0, 10.0, 60.0):
        def run():
            view = SatelliteView(iss, GRAZ, STARE, GEN4, START, knot_step_ns=int(knot_s * NS))
            return view, view.sample(t_ns)
        seconds, (view, samples) = best_of(3, run)
        from evsda.blocks.scene.geometry import apparent_position
        ours = apparent_position(view.track, view.observer_model, t_ns.astype(float))
        err = np.arccos(np.clip(np.sum(unit(ours) * unit(ref), axis=1), -1, 1)) * ARCSEC
        print(f"  knots every {knot_s:4.0f} s: full SatelliteView.sample (position, pixels, shadow, Sun, flux) "
              f"{seconds * 1e3:6.1f} ms; apparent-place error max {err.max() * 1e3:.2f} mas, "
              f"{err.max() * ARCSEC / ARCSEC / (np.degrees(GEN4.pixel_scale_rad) * 3600):.2e} pixel")


def stars() -> None:
    pitch = 4.86e-6
    fp = FocalPlane(1280, 720, pitch, 1280 * pitch / (2 * np.tan(np.radians(2.5))))    # 5 deg field
    run = RunInfo(epoch=START, duration_ns=10 * NS, window_ns=10 * NS, seed=1)
    block = StarField(faint_limit_mag=12.75, seed=1, name="stars")
    block.setup(run)
    window = Window(0, 0, 10 * NS, START)
    t_setup, _ = best_of(1, lambda: block._prepare(window, GRAZ, STARE, fp))
    t_ns = window.sample_times_ns(block.cadence_ns)
    seconds, (x, y) = best_of(3, lambda: block.project(t_ns))
    in_field = int(np.sum(projection.inside(x[0], y[0], fp)))
    step_s, out = best_of(1, lambda: block.step(window, GRAZ, STARE, fp))
    print(f"stars: {len(block._stars)} swept by a 5 deg staring field, {in_field} on the detector at the start; "
          f"setup {t_setup * 1e3:.0f} ms (catalogue, draws, knots)")
    windows = list(RunInfo(epoch=START, duration_ns=10 * NS, window_ns=NS // 10).windows())
    windowed_s, _ = best_of(2, lambda: [block.step(w, GRAZ, STARE, fp) for w in windows])
    print(f"  10 s at 1 ms ({len(t_ns)} samples x {len(block._stars)} stars): projection {seconds * 1e3:.0f} ms; "
          f"whole block step (fluxes, extinction, masks) {step_s * 1e3:.0f} ms as one window, "
          f"{windowed_s * 1e3:.0f} ms as 100 windows of 0.1 s")
    stars_ = block._stars
    star = Star(ra_hours=stars_.ra_deg / 15, dec_degrees=stars_.dec_deg, ra_mas_per_year=stars_.pm_ra_mas_yr,
                dec_mas_per_year=stars_.pm_dec_mas_yr, parallax_mas=stars_.parallax_mas,
                epoch=timescale().J(stars_.epoch_jyear))
    observer = block._observer.skyfield_observer()
    picks = np.linspace(0, len(t_ns) - 1, 41).astype(int)
    errors = []
    t0 = time.perf_counter()
    for k in picks:
        d = unit(observer.at(skyfield_time(START, t_ns[k:k + 1])[0]).observe(star).apparent().xyz.m.T)
        b, r, u = (np.repeat(a, len(stars_), axis=0) for a in block._pointing.frame(t_ns[k:k + 1]))
        xr, yr = projection.project(d, b, r, u, fp)
        errors.append(np.nanmax(np.hypot(x[k] - xr, y[k] - yr)))
    per_sample = (time.perf_counter() - t0) / len(picks)
    print(f"  Skyfield apparent places at every sample would take ~{per_sample * len(t_ns):.0f} s; "
          f"max position error of the knots {max(errors):.1e} pixel "
          f"({max(errors) * np.degrees(fp.pixel_scale_rad) * 3600 * 1e3:.2f} mas)")


def passes() -> None:
    iss = parse_tles(library.path("tle/iss.tle").read_text())[0]
    view = SatelliteView(iss, GRAZ, STARE, GEN4, START.replace(minute=0, second=0))
    seconds, report = best_of(1, lambda: find_passes(view, 0, 3600 * NS))
    print(f"pass finder over 1 h (0.36 x 0.2 deg field): {seconds * 1e3:.0f} ms, "
          f"{len(report.passes)} pass(es): {'; '.join(str(p) for p in report.passes)}")


if __name__ == "__main__":
    satellite()
    stars()
    passes()
