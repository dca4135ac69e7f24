"""Equivalent layers over a minutes-long tracked pass: each source's footprint moment against the full profile's.

Geometry only, no pixels (issue 13). On equivalent layers each source's footprints move through group ``g`` at
``u_g = h_g s' - w_g`` (docs/optics.md, "Equivalent layers"; ``s'`` the rate of its line of sight's crossing per
metre of altitude, :meth:`.Imager.sight`). The point phase's temporal structure function is
``D(tau) ~ sum J |u|^(5/3) tau^(5/3)`` (Fried 1966; Roddier 1981) and ``tau0 ~ (sum J |u|^(5/3))^(-3/5)``.
This prints, at the ISS's render times over the pass of benchmarks/equivalent_layers_long_pass.yaml (tracked from
Graz, zenith 85 -> 49 -> 75 deg), the relative error of that moment and of ``tau0`` against the full profile's
``sum_i J_i |h_i s'(t) - v_i|^(5/3)`` for

* ``fixed``: the winds :func:`.footprint_winds` gives for ``s'`` between the source's first two render times,
  kept for the whole stretch (``Imager.source_flow`` with ``follow_sight_rate`` off, the default);
* ``common``: the groups' own winds (the reference path's and the modal screens');
* ``follow``: the winds of each render time's ``s'`` (``follow_sight_rate``: each footprint advanced by
  ``u_g(s'(t)) dt`` between render times, exact by construction; measured here through the imager itself).

The follow column reads the footprints' displacement between render times, so it is exact to their centres'
rounding (~1e-11 of the moment; the winds themselves to 1e-12, tests/optics/test_optics_equivalent_layers.py).
Each stretch also times :meth:`.Imager.source_flow` the two ways, a 0.1 s window's render times a call (CPU).
``s'(t)`` at render time ``k`` is the secant ``(sight_k - sight_{k-1}) / dt``, as the imager sees it. Each stretch
starts at ``--start`` seconds after 19:16 UTC (the 10 s pass of benchmarks/end_to_end.yaml starts at 154 s) and
lasts each of ``--durations``::

    python benchmarks/equivalent_layers_long_pass.py [--layers 3 4] [--step 0.001] [--start 154 0 60]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from evsda.blocks.optics.atmosphere import Atmosphere
from evsda.blocks.optics.equivalent_layers import equivalent_layers, footprint_winds
from evsda.blocks.optics.imaging import Imager
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.library import resolve

GRAPH = Path(__file__).with_suffix(".yaml")
PROFILE = "library:atmospheres/median_seeing.csv"


def track(step_s: float) -> dict:
    """The tracked ISS's held samples every ``step_s`` [s] over the graph's run: times [s] from its start, pixel
    position, zenith angle, the boresight's azimuth and the field rotation (in view only)."""
    result = run_graph(load_graph(GRAPH, [f"sat.cadence_s={step_s}"]), None, progress=False, pipeline=False)
    windows = result.outputs[("sat", "sources")]
    t0 = windows[0].t_ns[0]
    columns = {"t": np.concatenate([(w.t_ns - t0) * 1e-9 for w in windows]),
               "x": np.concatenate([w.x_px[:, 0] for w in windows]),
               "y": np.concatenate([w.y_px[:, 0] for w in windows]),
               "zenith": np.concatenate([np.broadcast_to(w.zenith_angle_rad, w.t_ns.shape) for w in windows]),
               "azimuth": np.concatenate([np.broadcast_to(w.boresight_azimuth_rad, w.t_ns.shape) for w in windows]),
               "rotation": np.concatenate([np.broadcast_to(w.field_rotation_rad, w.t_ns.shape) for w in windows])}
    seen = np.isfinite(columns["x"]) & np.isfinite(columns["y"])
    return {name: values[seen] for name, values in columns.items()}, windows[0].focal_plane


def sight_rates(samples: dict, focal_plane, first: int, last: int) -> tuple[np.ndarray, np.ndarray]:
    """The lines of sight (F, 2) of samples ``first:last`` in the screens' frame fixed at the first (the imager's
    :meth:`.Imager.sight`, on a stand-in imager) and their secant rates between consecutive samples (F - 1, 2)."""
    imager = Imager.__new__(Imager)
    imager.pixel_scale = focal_plane.pixel_scale_rad
    imager.boresight = np.array([(focal_plane.width_px - 1) / 2, (focal_plane.height_px - 1) / 2])
    imager.frame = None
    part = {name: values[first:last] for name, values in samples.items()}
    imager.set_frame(part["azimuth"][0], part["zenith"][0], part["rotation"][0])
    sight = imager.sight(part["x"], part["y"], part["zenith"], part["azimuth"], part["rotation"])
    return sight, np.diff(sight, axis=0) / np.diff(part["t"])[:, None]


def moments(cn2: np.ndarray, altitude: np.ndarray, winds: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """``sum J |h s' - w|^(5/3)`` at each rate (F,) [m^(1/3) (m/s)^(5/3)]; ``winds`` (L, 2) or (F, L, 2)."""
    moving = altitude[None, :, None] * rates[:, None, :] - winds
    return np.sum(cn2 * np.hypot(moving[..., 0], moving[..., 1]) ** (5 / 3), axis=1)


def columns(atmosphere: Atmosphere) -> tuple[np.ndarray, ...]:
    return (np.array([layer.cn2_dh for layer in atmosphere.layers]),
            np.array([layer.altitude_m for layer in atmosphere.layers]),
            np.array([layer.wind_m_s for layer in atmosphere.layers]))


def followed_moments(fewer: Atmosphere, t: np.ndarray, sight: np.ndarray) -> np.ndarray:
    """The footprints' moment at each render time after the first as the imager's ``follow_sight_rate`` moves
    them (:meth:`.Imager.source_flow` on a stand-in imager, the stretch in 1 s calls): their displacement between
    consecutive render times over ``dt``."""
    imager = Imager.__new__(Imager)
    imager.atmosphere, imager.flows, imager.drifts, imager._members = fewer, {}, {}, None
    imager.follow_sight_rate = True
    cn2, altitude, _ = columns(fewer)
    centres = []
    for part in np.array_split(np.arange(len(t)), max(1, int(np.ceil(t[-1] - t[0])))):
        drift = imager.source_flow("iss", t[part], sight[part])[0]
        centres.append(altitude[:, None, None] * sight[part][None] - drift)
    moving = np.diff(np.concatenate(centres, axis=1), axis=1) / np.diff(t)[None, :, None]   # (L, F - 1, 2)
    return np.sum(cn2[:, None] * np.hypot(moving[..., 0], moving[..., 1]) ** (5 / 3), axis=0)


def flow_cost(fewer: Atmosphere, t: np.ndarray, sight: np.ndarray, follow: bool, window_s: float = 0.1) -> float:
    """CPU time [us] of one :meth:`.Imager.source_flow` call of a ``window_s`` window's render times (the optics
    block's: one call a source and window), fixed winds or ``follow``, over the stretch (after a first call)."""
    imager = Imager.__new__(Imager)
    imager.atmosphere, imager.flows, imager.drifts, imager._members = fewer, {}, {}, None
    imager.follow_sight_rate = follow
    parts = np.array_split(np.arange(len(t)), max(2, int(round((t[-1] - t[0]) / window_s))))
    imager.source_flow("iss", t[parts[0]], sight[parts[0]])
    spent = time.thread_time_ns()
    for part in parts[1:]:
        imager.source_flow("iss", t[part], sight[part])
    return (time.thread_time_ns() - spent) / (len(parts) - 1) / 1e3


def report(name: str, error: np.ndarray) -> str:
    tau = (1 + error) ** (-3 / 5) - 1
    worst = np.argmax(np.abs(error))
    return (f"{name:7s} moment max {error[worst]:+.2e} median |.| {np.median(np.abs(error)):.2e}; "
            f"tau0 max {tau[worst]:+.2e} median |.| {np.median(np.abs(tau)):.2e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layers", nargs="+", type=int, default=[3, 4], help="equivalent layers [1]")
    parser.add_argument("--step", type=float, default=0.001, help="render times' spacing (the base cadence) [s]")
    parser.add_argument("--start", nargs="+", type=float, default=[154.0, 60.0],
                        help="stretches' starts after 19:16 UTC [s] (154: the 10 s pass's start; the ISS is in view "
                             "and sunlit from 60 s, zenith 79.4 deg, to 254 s, 49.3 deg)")
    parser.add_argument("--durations", nargs="+", type=float, default=[10.0, 60.0, 120.0, 200.0],
                        help="stretches' lengths [s] (cut at the graph's end)")
    parser.add_argument("--no-follow", action="store_true", help="leave out the follow_sight_rate column")
    args = parser.parse_args()
    samples, focal_plane = track(args.step)
    full = Atmosphere.from_table(resolve(PROFILE))
    print(f"{GRAPH.name}: {len(samples['t'])} render times every {args.step:g} s, zenith "
          f"{np.degrees(samples['zenith'].max()):.1f}-{np.degrees(samples['zenith'].min()):.1f} deg; {PROFILE}")
    for start in args.start:
        ends = set()
        for duration in args.durations:
            first = int(np.searchsorted(samples["t"], start))
            last = int(np.searchsorted(samples["t"], start + duration, side="right"))
            if last - first < 3 or last in ends:           # too short, or cut at the same end as a shorter one
                continue
            ends.add(last)
            sight, rates = sight_rates(samples, focal_plane, first, last)
            t = samples["t"][first:last]
            speed = np.hypot(*rates.T)
            print(f"\nstretch {start:g} s + {t[-1] - t[0]:.0f} s: zenith {np.degrees(samples['zenith'][first]):.1f}"
                  f" -> {np.degrees(samples['zenith'][last - 1]):.1f} deg, |s'| {speed[0]:.4f} -> "
                  f"{speed.min():.4f}..{speed.max():.4f} 1/s (x{speed.max() / speed.min():.1f})")
            exact = moments(*columns(full), rates)
            for n_layers in args.layers:
                fewer = equivalent_layers(full, n_layers)
                cn2, altitude, wind = columns(fewer)
                fixed = moments(cn2, altitude, footprint_winds(fewer, rates[0]), rates)
                print(f"  {n_layers} layers:")
                print("    " + report("fixed", fixed / exact - 1))
                print("    " + report("common", moments(cn2, altitude, wind, rates) / exact - 1))
                if not args.no_follow:
                    print("    " + report("follow", followed_moments(fewer, t, sight) / exact - 1))
                    costs = [flow_cost(fewer, t, sight, follow) for follow in (False, True, False, True)]
                    print(f"    source_flow a 0.1 s window ({round(0.1 / args.step)} render times): fixed "
                          f"{min(costs[::2]):.1f} us, follow {min(costs[1::2]):.1f} us CPU (the less of two)")


if __name__ == "__main__":
    sys.exit(main())
