"""The limiting-magnitude study: a design against a ladder of magnitudes, P_d against magnitude, the
50 % and 90 % points with their uncertainty, and the analytic cross-check (:mod:`.analytic`).

A design is a graph file holding one ``detection_scoring`` block and either

* one ``injected_sources`` block: every magnitude of the ladder is one run of the graph with
  ``<inject>.magnitude`` set (the points of a sweep, :func:`evsda.graph.sweep.run_sweep`, which
  skips points already complete, so an interrupted study resumes without recomputing them), or
* a ``star_field`` (a real star field): the graph runs ``repeats`` times (seeds 1, 2, ...) and the
  scoring's magnitude bins give P_d at the ladder's magnitudes, which must lie within the stars
  the field holds (the catalogue's brightest to ``faint_limit_mag``).

P_d(m) is fitted by maximum likelihood with the logistic ``1 / (1 + exp((m - m50) / w))`` to the
binomial counts (detected opportunities of all opportunities at each magnitude); ``m90 = m50 - w ln 9``
and the uncertainties follow from the inverse Hessian of the log-likelihood (Cramér-Rao; delta
method for ``m90``). The analytic limits come from the design's own blocks: its pixel (or frame
sensor), its optics' PSF rendered by its ``optics`` block, its sky, its detector.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import optimize, special

from evsda.blocks.ports import PointSources, SkyBackground
from evsda.graph import NS_PER_S, RunInfo, UserError, Window

from .analytic import EventDesign, EventLimit, FrameDesign, FrameLimit, PsfTable

PSF_PHASES = 8                   # sub-pixel source positions per axis of the PSF table [1]
PSF_SECONDS = 0.2                # renders averaged for the PSF table (turbulent PSFs wander) [s]
MAX_FRAME_EXPOSURE_S = 10.0      # longest exposure "auto" gives the frame baseline [s]
STILL_RATE_PX_S = 1e-3           # a source "held still" when checking whether motion stops the pixels [pixel s^-1]


@dataclass
class Curve:
    """One design's measured P_d against magnitude, its fit and its analytic cross-check."""

    graph: str
    kind: str                                  # "events" or "frames"
    magnitudes: np.ndarray
    opportunities: np.ndarray
    detected: np.ndarray
    fit: dict = field(default_factory=dict)
    analytic: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def pd(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.detected / self.opportunities


# -- the ladder and the fit ------------------------------------------------------------------------
def parse_ladder(text: str) -> list[float]:
    """``"8:14:0.5"`` (start:stop:step, stop included) or ``"8,9,10.5"`` [mag]."""
    try:
        if ":" in text:
            start, stop, step = (float(v) for v in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            n = int(math.floor((stop - start) / step + 1e-9)) + 1
            return [round(start + i * step, 6) for i in range(n)]
        values = [float(v) for v in text.split(",") if v.strip()]
        if not values:
            raise ValueError
        return sorted(values)
    except ValueError:
        raise UserError(f"--magnitudes {text!r}: expected START:STOP:STEP (e.g. 6:14:0.5) or a list (e.g. 8,9,10)") \
            from None


def fit_logistic(magnitudes, opportunities, detected) -> dict:
    """Maximum-likelihood logistic fit of P_d(m) with ``m50``, ``m90``, the width and their 1-sigma errors."""
    m = np.asarray(magnitudes, float)
    n = np.asarray(opportunities, float)
    k = np.asarray(detected, float)
    use = n > 0
    m, n, k = m[use], n[use], k[use]
    nan = float("nan")
    if m.size < 2 or k.sum() == 0 or k.sum() == n.sum():
        return {"m50": nan, "m50_err": nan, "m90": nan, "m90_err": nan, "width": nan, "brackets": False}
    all_found, none_found = m[k == n], m[k == 0]
    if all_found.size + none_found.size == m.size and all_found.size and none_found.size \
            and all_found.max() < none_found.min():
        # complete separation: no maximum-likelihood width; the 50 % point lies somewhere in the gap
        bright, faint = float(all_found.max()), float(none_found.min())
        return {"m50": (bright + faint) / 2, "m50_err": (faint - bright) / 2, "m90": nan, "m90_err": nan,
                "width": nan, "brackets": True, "gap": (bright, faint)}

    def nll(theta):
        m50, log_w = theta
        z = (m - m50) / math.exp(log_w)
        log_p = -np.logaddexp(0.0, z)            # log P_d
        log_q = -np.logaddexp(0.0, -z)           # log (1 - P_d)
        return -float(np.sum(k * log_p + (n - k) * log_q))

    pd = k / n
    crossing = m[np.argmin(np.abs(pd - 0.5))]
    best = optimize.minimize(nll, [crossing, math.log(0.3)], method="Nelder-Mead",
                             options={"xatol": 1e-6, "fatol": 1e-9, "maxiter": 4000})
    m50, log_w = best.x
    w = math.exp(log_w)
    hessian = _hessian(nll, best.x)
    try:
        cov = np.linalg.inv(hessian)
    except np.linalg.LinAlgError:
        cov = np.full((2, 2), np.nan)
    ln9 = math.log(9.0)
    # m90 = m50 - w ln 9; d m90 / d log_w = -w ln 9
    grad = np.array([1.0, -w * ln9])
    var90 = float(grad @ cov @ grad)
    brackets = bool((pd >= 0.9).any() and (pd <= 0.1).any())
    return {"m50": float(m50), "m50_err": float(math.sqrt(max(cov[0, 0], 0.0))), "m90": float(m50 - w * ln9),
            "m90_err": math.sqrt(max(var90, 0.0)), "width": float(w), "brackets": brackets}


def _hessian(f, x, h=1e-3) -> np.ndarray:
    x = np.asarray(x, float)
    out = np.empty((x.size, x.size))
    for i in range(x.size):
        for j in range(x.size):
            e_i, e_j = np.eye(x.size)[i] * h, np.eye(x.size)[j] * h
            out[i, j] = (f(x + e_i + e_j) - f(x + e_i - e_j) - f(x - e_i + e_j) + f(x - e_i - e_j)) / (4 * h * h)
    return out


# -- reading a design out of its graph ------------------------------------------------------------
@dataclass
class GraphDesign:
    """The blocks of a study graph that the study sets and the analytic limit reads."""

    path: str
    overrides: list[str]
    graph: object
    scoring: str
    injected: str | None
    stars: str | None
    detector: str
    kind: str                  # "events" or "frames"
    sensor: str                # the dvs_pixel or frame_sensor block
    optics: str

    def block(self, name: str):
        return self.graph.nodes[name].block


def inspect(path: str, overrides: list[str] = ()) -> GraphDesign:
    """Find the study's blocks in a graph file; one clear error if it cannot be studied."""
    from evsda.graph.graphfile import load_graph

    graph = load_graph(path, list(overrides))
    by_type: dict[str, list[str]] = {}
    for name, node in graph.nodes.items():
        by_type.setdefault(node.block.type_name, []).append(name)

    def one(types: tuple[str, ...], what: str, required: bool = True) -> str | None:
        found = [n for t in types for n in by_type.get(t, [])]
        if len(found) > 1:
            raise UserError(f"{path}: a limiting-magnitude study needs one {what}, the graph has {len(found)} "
                            f"({', '.join(found)})")
        if not found and required:
            raise UserError(f"{path}: a limiting-magnitude study needs a {what} ({' or '.join(types)} block); "
                            f"the graph has none")
        return found[0] if found else None

    scoring = one(("detection_scoring",), "scoring block")
    injected = one(("injected_sources",), "injected-source block", required=False)
    stars = one(("star_field",), "star field", required=False)
    if injected is None and stars is None:
        raise UserError(f"{path}: a limiting-magnitude study needs sources of known magnitude: an injected_sources "
                        f"block (a ladder of synthetic sources) or a star_field (a real star field)")
    detector = one(("event_detector", "frame_detector"), "detector")
    kind = "events" if graph.nodes[detector].block.type_name == "event_detector" else "frames"
    sensor = one(("dvs_pixel",) if kind == "events" else ("frame_sensor",), "sensor")
    optics = one(("optics",), "optics block")
    return GraphDesign(path, list(overrides), graph, scoring, injected, stars, detector, kind, sensor, optics)


def probe(design: GraphDesign) -> tuple[PointSources, SkyBackground | None]:
    """The design's sources and sky over its first window (a short run of the blocks upstream of them)."""
    from evsda.graph.executor import run_graph
    from evsda.graph.graphfile import load_graph

    window_s = design.graph.run_info().window_ns / NS_PER_S
    graph = load_graph(design.path, [*design.overrides, f"run.duration_s={window_s}"])
    source_block = design.injected or design.stars
    sky = [(src, sport) for src, sport, dst, dport in graph.connections if dst == design.optics and dport == "background"]
    graph.outputs.clear()
    graph.outputs.extend([(source_block, "sources"), *sky])
    result = run_graph(graph, None, progress=False)
    sources = result.outputs[(source_block, "sources")][0]
    background = result.outputs[sky[0]][0] if sky else None
    return sources, background


def psf_table(optics_block, focal_plane, wavelength_m: float, zenith_rad: float) -> PsfTable:
    """Fraction of the PSF in a pixel against the pixel's offset from the source, rendered by the design's own
    optics block (a fresh copy) for sources at ``PSF_PHASES`` sub-pixel phases per axis, averaged over
    ``PSF_SECONDS`` of renders."""
    from evsda.blocks.ports import FocalPlane, SourceKind

    optics = type(optics_block)(optics_block.params, name=optics_block.name, seed=optics_block.seed)
    n = PSF_PHASES
    phases = (np.arange(n) + 0.5) / n - 0.5
    px, py = np.meshgrid(phases, phases)
    side = 4096
    fp = FocalPlane(side, side, focal_plane.pixel_pitch_m, focal_plane.focal_length_m, focal_plane.spectral_response)
    centre = side // 2
    cadence = max(1, round(NS_PER_S / optics.params.render_rate_hz))
    duration = max(cadence, round(PSF_SECONDS * NS_PER_S))
    t = np.arange(0, duration, cadence, dtype=np.int64)
    k = px.size
    collected = optics.telescope.collecting_area_m2 * optics.params.throughput
    x = np.broadcast_to((centre + px.ravel())[None, :], (t.size, k)).copy()
    y = np.broadcast_to((centre + py.ravel())[None, :], (t.size, k)).copy()
    sources = PointSources(fp, wavelength_m, t, np.array([f"psf{i}" for i in range(k)]),
                           np.full(k, SourceKind.STAR, np.int8), x, y, np.full((t.size, k), 1.0 / collected),
                           np.zeros((t.size, k)), np.full((t.size, k), np.inf), np.full(t.size, zenith_rad))
    optics.setup(RunInfo(duration_ns=int(duration), window_ns=int(duration)))
    irradiance = optics.step(Window(0, 0, int(duration)), sources=[sources])["irradiance"]
    stamps = irradiance.stamp_flux.mean(axis=0)                      # [k, h, w]
    origin = irradiance.stamp_origin[0]                               # [k, 2]
    size = stamps.shape[-1]
    half = size // 2 + 1
    grid = np.arange(-half * n, half * n + 1) / n
    table = np.zeros((grid.size, grid.size))
    count = np.zeros_like(table)
    for s in range(k):
        cols = origin[s, 0] + np.arange(size) - (centre + px.ravel()[s])
        rows = origin[s, 1] + np.arange(size) - (centre + py.ravel()[s])
        ic = np.rint((cols + half) * n).astype(int)
        ir = np.rint((rows + half) * n).astype(int)
        ok_c = (ic >= 0) & (ic < grid.size)
        ok_r = (ir >= 0) & (ir < grid.size)
        sub = stamps[s][np.ix_(ok_r, ok_c)]
        table[np.ix_(ir[ok_r], ic[ok_c])] += sub
        count[np.ix_(ir[ok_r], ic[ok_c])] += 1
    filled = count > 0
    table[filled] /= count[filled]
    # offsets never sampled (between phases) take their neighbours' mean along each axis
    if not filled.all():
        from scipy.interpolate import griddata

        gy, gx = np.meshgrid(grid, grid, indexing="ij")
        table = griddata((gy[filled], gx[filled]), table[filled], (gy, gx), method="linear", fill_value=0.0)
    return PsfTable(grid, table)


def event_limit(design: GraphDesign, sources: PointSources, sky: SkyBackground | None) -> EventLimit:
    """The analytic event limit of a design (:class:`.analytic.EventLimit`)."""
    from evsda.blocks.pixel.model import PixelModel

    fp = sources.focal_plane
    optics = design.block(design.optics)
    pixel = PixelModel(design.block(design.sensor).params, fp.pixel_area_m2, sources.wavelength_m)
    detector = design.block(design.detector)
    collected = optics.telescope.collecting_area_m2 * optics.params.throughput
    flux0, rate, direction = _photons_and_motion(design, sources, collected)
    sky_photons = float(sky.photon_flux_per_pixel[0]) * collected if sky is not None else 0.0
    table = psf_table(optics, fp, sources.wavelength_m, float(sources.zenith_angle_rad[0]))
    dp = detector.params
    return EventLimit(EventDesign(pixel, table, flux0, sky_photons, rate, direction, detector.look_ns / NS_PER_S,
                                  dp.box_px, detector.velocities.shape[0], dp.false_alarm_rate_per_hour_per_mpx,
                                  fp.width_px * fp.height_px, dp.polarity))


def frame_limit(design: GraphDesign, sources: PointSources, sky: SkyBackground | None) -> FrameLimit:
    """The analytic frame limit of a design (:class:`.analytic.FrameLimit`)."""
    fp = sources.focal_plane
    optics = design.block(design.optics)
    camera = design.block(design.sensor)
    detector = design.block(design.detector)
    cp = camera.params
    collected = optics.telescope.collecting_area_m2 * optics.params.throughput
    flux0, rate, direction = _photons_and_motion(design, sources, collected)
    sky_photons = float(sky.photon_flux_per_pixel[0]) * collected if sky is not None else 0.0
    table = psf_table(optics, fp, sources.wavelength_m, float(sources.zenith_angle_rad[0]))
    fraction = _best_box_fraction(table, detector.params.box_px, rate * cp.exposure_s, direction)
    background = (cp.quantum_efficiency * sky_photons + camera.dark_e_per_s(fp)) * cp.exposure_s
    return FrameLimit(FrameDesign(cp.quantum_efficiency * flux0, fraction, background, cp.read_noise_e, cp.exposure_s,
                                  detector.params.box_px, detector.params.false_alarm_rate_per_hour_per_mpx))


def _photons_and_motion(design: GraphDesign, sources: PointSources, collected_m2: float):
    """Photons per second on the detector from a V = 0 source, and the apparent rate and direction."""
    if design.injected is not None:
        inject = design.block(design.injected)
        flux = float(sources.photon_flux[0, 0]) * 10 ** (0.4 * float(sources.magnitude[0, 0])) * collected_m2
        v = inject.velocity_px_s(sources.focal_plane)
        return flux, float(np.hypot(*v)), float(np.degrees(np.arctan2(v[1], v[0])))
    ok = np.isfinite(sources.x_px[0]) & np.isfinite(sources.x_px[-1]) & (sources.photon_flux[0] > 0)
    if not ok.any():
        raise UserError(f"{design.path}: no star of the field stays on the detector over the first window")
    s = np.flatnonzero(ok)[0]
    flux = float(sources.photon_flux[0, s]) * 10 ** (0.4 * float(sources.magnitude[0, s])) * collected_m2
    dt = (sources.t_ns[-1] - sources.t_ns[0]) / NS_PER_S
    v = np.array([sources.x_px[-1, s] - sources.x_px[0, s], sources.y_px[-1, s] - sources.y_px[0, s]]) / max(dt, 1e-9)
    return flux, float(np.hypot(*v)), float(np.degrees(np.arctan2(v[1], v[0])))


def _best_box_fraction(table: PsfTable, box: int, trail_px: float, direction_deg: float) -> float:
    """Fraction of a trailed source's light in the best-placed ``box x box`` pixels, averaged over sub-pixel phases."""
    angle = math.radians(direction_deg)
    s = np.linspace(-trail_px / 2, trail_px / 2, max(2, int(trail_px * 20) + 2))
    track = np.stack([s * math.cos(angle), s * math.sin(angle)], -1)
    phases = (np.arange(4) + 0.5) / 4 - 0.5
    best = []
    corners = np.arange(-box - 1, 2)
    for ph_x in phases:
        for ph_y in phases:
            source = track + np.array([ph_x, ph_y])           # positions relative to pixel (0, 0)'s centre
            fractions = []
            for cx in corners:
                for cy in corners:
                    total = 0.0
                    for i in range(box):
                        for j in range(box):
                            total += table(cx + i - source[:, 0], cy + j - source[:, 1]).mean()
                    fractions.append(total)
            best.append(max(fractions))
    return float(np.mean(best))


# -- running a study -----------------------------------------------------------------------------
def frame_exposure_for_motion(rate_px_s: float, longest_s: float) -> float:
    """The frame baseline's exposure for a source moving ``rate_px_s``: the time it takes to cross one pixel
    (a longer exposure trails the light over more pixels, and their noise), at most ``longest_s`` [s]."""
    if rate_px_s <= 0:
        return longest_s
    return float(min(longest_s, 1.0 / rate_px_s))


def run_design(path: str, magnitudes: list[float], out_dir: Path, overrides: list[str] = (), repeats: int = 1,
               jobs: int = 1, report=print) -> Curve:
    """Run one design over the ladder (resuming finished points) and return its measured curve, fitted."""
    from evsda.graph.sweep import run_sweep

    design = inspect(path, overrides)
    design_dir = out_dir / Path(path).stem
    check_ladder(design, magnitudes)
    if design.injected is not None and design.kind == "events":
        _check_searched(design)
    if design.injected is not None:
        grid = {f"{design.injected}.magnitude": list(magnitudes)}
        if repeats > 1:
            grid["run.seed"] = list(range(1, repeats + 1))
        rows = _finished(run_sweep(path, grid, design_dir, overrides=list(overrides), jobs=jobs, report=report),
                         design_dir)
        key = f"{design.injected}.magnitude"
        opp = np.array([sum(r.get("opportunities", 0) for r in rows if r[key] == m) for m in magnitudes], float)
        det = np.array([sum(r.get("detected_opportunities", 0) for r in rows if r[key] == m) for m in magnitudes],
                       float)
    else:
        rows = _finished(run_sweep(path, {"run.seed": list(range(1, repeats + 1))}, design_dir,
                                   overrides=list(overrides), jobs=jobs, report=report), design_dir)
        opp = np.array([sum(r.get(f"opportunities_m{m:.2f}", 0) for r in rows) for m in magnitudes], float)
        det = np.array([sum(r.get(f"detected_m{m:.2f}", 0) for r in rows) for m in magnitudes], float)
    if opp.sum() == 0:
        raise UserError(f"{path}: no source gave the scorer an opportunity at any rung: none stayed on the detector "
                        f"(inside its margins) for a whole look; the runs are kept in {design_dir}. Shorten the "
                        f"detector's look, slow the sources or enlarge the detector")
    curve = Curve(path, design.kind, np.asarray(magnitudes, float), opp, det)
    curve.fit = fit_logistic(curve.magnitudes, opp, det)
    if "gap" in curve.fit:
        curve.notes.append(f"P_d falls from 1 to 0 between V {curve.fit['gap'][0]:g} and {curve.fit['gap'][1]:g}: "
                           f"m50 is the middle of that gap (its half-width as error); refine the ladder there")
    elif not curve.fit["brackets"]:
        curve.notes.append("the ladder does not reach both P_d >= 0.9 and P_d <= 0.1: the fitted points are "
                           "extrapolated; extend the ladder")
    return curve


def check_ladder(design: GraphDesign, magnitudes: list[float]) -> None:
    """One error when a star-field design's ladder reaches beyond the stars its field holds."""
    if design.injected is not None:
        return
    stars = design.block(design.stars)
    width = design.block(design.scoring).params.magnitude_bin_mag
    faint, bright = stars.params.faint_limit_mag, BRIGHTEST_CATALOGUED_MAG
    off_bin = [m for m in magnitudes if abs(m / width - round(m / width)) > 1e-6]
    if off_bin:
        raise UserError(f"{design.path}: a star-field study reads P_d from the scoring's magnitude bins, centred on "
                        f"multiples of {design.scoring}.magnitude_bin_mag = {width:g}; "
                        f"{', '.join(f'{m:g}' for m in off_bin)} lie between bin centres: use a ladder on that grid")
    outside = [m for m in magnitudes if m - width / 2 < bright or m + width / 2 > faint]
    if outside:
        raise UserError(f"{design.path}: the star field '{design.stars}' holds stars from V {bright:g} (the "
                        f"catalogue's brightest) to V {faint:g} (its faint_limit_mag), so magnitudes "
                        f"{', '.join(f'{m:g}' for m in outside)} (bins of {width:g} mag) have no stars to score; "
                        f"keep the ladder within that range or raise faint_limit_mag (the star counts reach V 22)")


def _check_searched(design: GraphDesign) -> None:
    """One error when the event detector does not search the injected sources' apparent rate."""
    sources, _ = probe(design)
    speed = float(np.hypot(*design.block(design.injected).velocity_px_s(sources.focal_plane)))
    p = design.block(design.detector).params
    if not p.min_rate_px_s <= speed <= p.max_rate_px_s:
        raise UserError(f"{design.path}: the injected sources move {speed:.3g} pixel/s but the detector "
                        f"'{design.detector}' searches {p.min_rate_px_s:g} to {p.max_rate_px_s:g} pixel/s: it could "
                        f"never find them; set {design.detector}.max_rate_px_s (and min_rate_px_s) to include "
                        f"{speed:.3g}")


def _finished(result, design_dir: Path) -> list[dict]:
    """The rows of a study's sweep; one error naming the failed points (the finished ones are kept on disk)."""
    if result.failed:
        errors = sorted({r.get("error", "") for r in result.rows if r.get("status") == "failed"})
        raise UserError(f"{result.failed} point(s) of the study in {design_dir} failed ({'; '.join(errors)}); the "
                        f"finished points are kept: fix the cause and run the study again to complete it")
    return result.rows


BRIGHTEST_CATALOGUED_MAG = -1.5          # Sirius, the brightest star of the bundled Hipparcos excerpt [mag]


def design_limit(path: str, overrides: list[str] = ()) -> EventLimit | FrameLimit:
    """The analytic limit of a design (:class:`.analytic.EventLimit` or :class:`.analytic.FrameLimit`)."""
    design = inspect(path, overrides)
    sources, sky = probe(design)
    return event_limit(design, sources, sky) if design.kind == "events" else frame_limit(design, sources, sky)


def analytic_limits(limit: EventLimit | FrameLimit) -> dict:
    """The analytic 50 % and 90 % limits, and for events the contrast limit [mag] and the background."""
    if isinstance(limit, EventLimit):
        return {"m50": limit.magnitude_at(0.5), "m90": limit.magnitude_at(0.9), "contrast": limit.contrast_limit(),
                "background_hz": limit.background_hz, "k_threshold": limit.k_threshold, "mu": limit.mu}
    return {"m50": limit.magnitude_at(0.5), "m90": limit.magnitude_at(0.9), "z_threshold": limit.z}


def check_response(path: str, limit: EventLimit, brightest: float) -> None:
    """One error when no pixel can respond to the ladder's brightest rung: expected signal events in the
    detector's best box below one per look. Says whether the motion is the cause (the same source held still
    would raise a pixel's level by a threshold) or the ladder is too faint for the design at any rate."""
    signal = limit.expected_events(brightest)
    if signal >= 1.0:
        return
    d = limit.d
    theta = d.pixel.params.threshold_on
    still = EventLimit(replace(d, rate_px_s=STILL_RATE_PX_S)).rises(brightest).max()
    tau = limit.time_constant_s(brightest)
    if still >= theta and d.rate_px_s > 0:
        raise UserError(f"{path}: at {d.rate_px_s:.3g} pixel/s a source crosses a pixel in "
                        f"{1e3 / d.rate_px_s:.3g} ms, but the photoreceptor's time constant is {tau * 1e3:.3g} ms "
                        f"even with all of a V {brightest:g} source's light on the pixel: the best pixel's level "
                        f"rises by {limit.rises(brightest).max():.3g} (held still it would rise {still:.3g}, "
                        f"the threshold is {theta:g}) and the detector's box expects {signal:.2g} signal events per "
                        f"look: no pixel can respond to this motion. Slow the motion, or brighten the ladder")
    raise UserError(f"{path}: even the ladder's brightest rung, V {brightest:g}, raises no pixel's level by a "
                    f"threshold ({still:.3g} held still, threshold {theta:g}; photoreceptor time constant "
                    f"{tau * 1e3:.3g} ms): {signal:.2g} signal events per look are expected, so every rung would "
                    f"give P_d = 0; start the ladder brighter")


def frame_overrides(frame_path: str, overrides: list[str], event_path: str | None, exposure: str) -> list[str]:
    """``--set`` lines giving the frame baseline its exposure: ``auto`` chooses it for the motion
    (:func:`frame_exposure_for_motion`, at most the event detector's look if an event design is studied with
    it, else :data:`MAX_FRAME_EXPOSURE_S`), or a number of seconds; the frame rate follows (1 / exposure)."""
    design = inspect(frame_path, overrides)
    camera = design.sensor
    if exposure == "auto":
        sources, _ = probe(design)
        _, rate, _ = _photons_and_motion(design, sources, 1.0)
        longest = MAX_FRAME_EXPOSURE_S
        if event_path is not None:
            events = inspect(event_path)
            longest = events.block(events.detector).look_ns / NS_PER_S
        seconds = frame_exposure_for_motion(rate, min(longest, design.graph.run_info().duration_ns / NS_PER_S))
    else:
        try:
            seconds = float(exposure)
        except ValueError:
            raise UserError(f"--frame-exposure {exposure!r}: expected 'auto' or a number of seconds") from None
        if not seconds > 0:
            raise UserError(f"--frame-exposure must be positive, got {exposure}")
    seconds = round(seconds, 6)
    return [*overrides, f"{camera}.exposure_s={seconds!r}", f"{camera}.frame_rate_hz={1.0 / seconds!r}"]


def write_table(curves: list[Curve], path: Path) -> None:
    """One row per design and magnitude: opportunities, detections, P_d and its binomial error."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["graph", "kind", "magnitude", "opportunities", "detected", "p_d", "p_d_err"])
        for c in curves:
            for m, n, k in zip(c.magnitudes, c.opportunities, c.detected):
                p = k / n if n else float("nan")
                err = math.sqrt(max(p * (1 - p), 0.25 / n) / n) if n else float("nan")
                writer.writerow([c.graph, c.kind, f"{m:g}", int(n), int(k), f"{p:.4f}", f"{err:.4f}"])


def summary_lines(curves: list[Curve]) -> list[str]:
    """The study's table: per design, the fitted and analytic limits and their difference."""
    lines = [f"{'design':<36s} {'kind':<6s} {'m50 (sim)':>14s} {'m90 (sim)':>14s} {'m50 (analytic)':>15s} "
             f"{'difference':>10s} {'m90 (analytic)':>15s}"]
    for c in curves:
        f, a = c.fit, c.analytic
        diff = a.get("m50", float("nan")) - f["m50"]
        lines.append(f"{Path(c.graph).name:<36s} {c.kind:<6s} {f['m50']:7.2f} ± {f['m50_err']:4.2f} "
                     f"{f['m90']:7.2f} ± {f['m90_err']:4.2f} {a.get('m50', float('nan')):15.2f} {diff:+10.2f} "
                     f"{a.get('m90', float('nan')):15.2f}")
        for note in c.notes:
            lines.append(f"  note: {note}")
    return lines


def plot(curves: list[Curve], png: Path) -> None:
    """P_d against magnitude for every design: measured points with binomial errors, the fit, the analytic curve."""
    from matplotlib.figure import Figure        # not pyplot: a caller's backend is left alone, nothing stays open

    fig = Figure(figsize=(7.5, 4.5), dpi=120)
    ax = fig.add_subplot()
    for i, c in enumerate(curves):
        colour = f"C{i}"
        p = c.pd
        err = np.sqrt(np.maximum(p * (1 - p), 0.25 / np.maximum(c.opportunities, 1)) / np.maximum(c.opportunities, 1))
        label = f"{Path(c.graph).stem} ({c.kind})"
        ax.errorbar(c.magnitudes, p, yerr=err, fmt="o", color=colour, ms=4, capsize=2, label=label)
        fine = np.linspace(c.magnitudes.min(), c.magnitudes.max(), 400)
        if np.isfinite(c.fit["width"]):
            ax.plot(fine, special.expit(-(fine - c.fit["m50"]) / c.fit["width"]), color=colour, lw=1.2,
                    label=f"fit: m50 {c.fit['m50']:.2f} ± {c.fit['m50_err']:.2f}, m90 {c.fit['m90']:.2f}")
        if np.isfinite(c.analytic.get("m50", np.nan)):
            ax.axvline(c.analytic["m50"], color=colour, ls="--", lw=1,
                       label=f"analytic m50 {c.analytic['m50']:.2f}")
    ax.axhline(0.5, color="0.6", lw=0.6)
    ax.axhline(0.9, color="0.6", lw=0.6, ls=":")
    ax.set_xlabel("V magnitude")
    ax.set_ylabel("probability of detection per look")
    ax.set_ylim(-0.03, 1.03)
    ax.legend(fontsize=7, loc="lower left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    from evsda.graph.files import atomic_output

    with atomic_output(png, overwrite=True, what="figure") as tmp:
        fig.savefig(tmp, format="png")
