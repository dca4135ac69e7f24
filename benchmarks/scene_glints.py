"""Speed against error of the glint and Moon approximations (prints tables; no files).

    python benchmarks/scene_glints.py

1. A cylinder's side as facets against the exact diffuse cylinder, by number of facets.
2. A specular cylinder spinning about its own axis (a smooth one is steady): ripple by facets.
3. The Sun's disc as a Gaussian blur of the lobe against the exact convolution with the disc.
4. The Moon's place from DE421 knots (Hermite) against Skyfield at every sample.
5. The tumble's integration: time per 60 s segment and invariants after an hour.
"""

from __future__ import annotations

import time
from datetime import datetime, timezone

import numpy as np
from scipy.signal import fftconvolve
from skyfield.api import wgs84

from evsda.blocks.ports.scene import GROUND, Observer
from evsda.blocks.scene import brdf, facets
from evsda.blocks.scene.attitude import Spin, Tumble, direction_of_radec
from evsda.blocks.scene.ephemeris import planets, skyfield_time
from evsda.blocks.scene.geometry import ObserverModel
from evsda.blocks.scene.moon import MoonModel
from evsda.blocks.scene.reflectors import FacetReflector


def timed(function, repeat: int = 5) -> tuple[float, object]:
    """Median wall time [s] of ``repeat`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), result


def random_directions(n: int, seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def diffuse_cylinder() -> None:
    print("1. diffuse cylinder (r 1.95 m, L 11 m, albedo 0.3): facets against the exact integral, 10 000 geometries")
    s, o = random_directions(10_000, 1), random_directions(10_000, 2)
    exact = facets.diffuse_cylinder_side_reference(1.95, 11.0, 0.3, s, o)
    scale = 0.3 / np.pi * 1.95 * 11.0 * np.pi / 2
    print(f"   {'facets':>7} {'max error':>10} {'rms error':>10} {'time':>9}")
    for n in (16, 36, 72, 144, 576):
        spec = facets.FacetModelSpec(cylinder=facets.CylinderSpec(
            radius_m=1.95, length_m=11.0, end_caps=False, n_sides=n,
            brdf=facets.BrdfSpec(model="lambert", diffuse_albedo=0.3)))
        model = facets.build(spec)
        seconds, r = timed(lambda: model.reflectance_m2_sr(s, o))
        err = (r - exact) / scale
        print(f"   {n:7d} {np.abs(err).max():10.2e} {np.sqrt(np.mean(err**2)):10.2e} {seconds * 1e3:7.1f} ms")


def specular_ripple() -> None:
    print("2. specular cylinder spinning about its axis: peak-to-peak / mean of the light curve (a smooth one: 0)")
    sun = np.array([np.cos(0.6), 0.8 * np.sin(0.6), 0.6 * np.sin(0.6)])
    observer = np.array([np.cos(0.6), -0.8 * np.sin(0.6), -0.6 * np.sin(0.6)])
    t_ns = np.arange(0, 5_000_000_000, 2_000_000)
    law = Spin(np.array([0.0, 0.3, 1.0]), np.array([0.0, 0.0, 1.0]), 2 * np.pi / 5.0, 0.4)
    print(f"   {'exponent':>8} {'facets':>7} {'ripple':>9} {'time/2500 samples':>18}")
    for exponent in (300.0, 1000.0, 1e5):
        side = facets.BrdfSpec(model="phong", diffuse_albedo=0.1, specular_albedo=0.5, specular_exponent=exponent)
        auto = facets.cylinder_sides(facets.CylinderSpec(radius_m=1.95, length_m=11.0, brdf=side))
        for n in sorted({72, auto // 4, auto // 2, auto}):
            spec = facets.FacetModelSpec(cylinder=facets.CylinderSpec(radius_m=1.95, length_m=11.0, brdf=side,
                                                                      n_sides=max(8, n)))
            reflector = FacetReflector(facets.build(spec), law)
            seconds, curve = timed(lambda: reflector.reflectance_m2_sr(
                t_ns, None, None, np.tile(sun, (len(t_ns), 1)), np.tile(observer, (len(t_ns), 1))), repeat=3)
            mark = " (default)" if n == auto else ""
            ripple = np.ptp(curve) / curve.mean()
            print(f"   {exponent:8.0e} {max(8, n):7d} {ripple:9.2e} {seconds * 1e3:15.1f} ms{mark}")


def sun_disc_blur() -> None:
    print("3. the Sun's disc: Gaussian blur of a Phong lobe against the exact convolution (flat plate at the mirror)")
    a = brdf.SUN_ANGULAR_RADIUS_RAD
    print(f"   {'exponent':>8} {'peak: blur/exact':>17} {'energy: blur/exact':>19}")
    for exponent in (1e3, 1e4, 1e5, 1e6, 1e8):
        # offsets of the reflected direction from the lobe axis, on a fine 2-D grid [rad]
        half = 6.0 * max(a, 1.0 / np.sqrt(exponent))
        axis = np.linspace(-half, half, 801)
        dx, dy = np.meshgrid(axis, axis)
        step = axis[1] - axis[0]
        lobe = (exponent + 2) / (2 * np.pi) * np.cos(np.hypot(dx, dy)) ** exponent
        disc = (np.hypot(dx, dy) <= a).astype(float)
        disc /= disc.sum()
        exact = fftconvolve(lobe, disc, mode="same")
        blurred_m = float(brdf.sun_blurred_exponent(exponent))
        blurred = (blurred_m + 2) / (2 * np.pi) * np.cos(np.hypot(dx, dy)) ** blurred_m
        print(f"   {exponent:8.0e} {blurred.max() / exact.max():17.3f} "
              f"{blurred.sum() * step**2 / (exact.sum() * step**2):19.4f}")


def moon_place() -> None:
    print("4. the Moon from DE421 knots (10 s, Hermite) against Skyfield at every sample, Graz, 600 s at 10 ms")
    epoch = datetime(2023, 3, 7, 22, 0, 0, tzinfo=timezone.utc)
    graz = Observer(name="Graz", kind=GROUND, latitude_deg=47.0671, longitude_deg=15.4934, altitude_m=493.0)
    t_ns = np.arange(0, 600_000_000_000, 10_000_000)
    model = MoonModel(ObserverModel(graz, epoch, 10**10), epoch)
    fast_s, samples = timed(lambda: model.sample(t_ns), repeat=1)
    eph = planets()
    site = eph["earth"] + wgs84.latlon(47.0671, 15.4934, elevation_m=493.0)
    start = time.perf_counter()
    reference = (eph["moon"] - site).at(skyfield_time(epoch, t_ns)).position.m.T
    slow_s = time.perf_counter() - start
    reference /= np.linalg.norm(reference, axis=1, keepdims=True)
    error = np.degrees(np.arccos(np.clip(np.sum(reference * samples.direction, axis=1), -1, 1))) * 3600
    print(f"   {len(t_ns)} samples: knots {fast_s:.2f} s, Skyfield {slow_s:.2f} s; direction error max "
          f"{error.max():.2e} arcsec")


def tumble_cost() -> None:
    print("5. tumble (I = 9000, 90000, 91000 kg m^2): integration and invariants over one hour")
    law = Tumble(np.array([9000.0, 90000.0, 91000.0]), np.radians([20.0, 5.0, 30.0]), direction_of_radec(250, -20))
    seconds, _ = timed(lambda: law.state(np.array([3_599e9])), repeat=1)
    t_ns = np.linspace(0, 3_600e9, 20_001)
    _, omega = law.state(t_ns)
    momentum = np.einsum("nij,nj->ni", law.matrices(t_ns), law.inertia * omega)
    drift = np.degrees(np.arccos(np.clip(momentum @ direction_of_radec(250, -20) / np.linalg.norm(momentum, axis=1),
                                         -1, 1))).max() * 3600
    energy = np.sum(law.inertia * omega**2, axis=1)
    print(f"   60 segments in {seconds:.2f} s ({seconds / 60 * 1e3:.1f} ms per 60 s); momentum direction drift "
          f"{drift:.1e} arcsec, energy drift {np.ptp(energy) / energy[0]:.1e}")


if __name__ == "__main__":
    diffuse_cylinder()
    specular_ripple()
    sun_disc_blur()
    moon_place()
    tumble_cost()
