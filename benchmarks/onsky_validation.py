"""On-sky validation: the published on-sky limits of event cameras reproduced as graph files, each measured limit
beside the limit evsda predicts for the same setup, and the one number fitted to one of them.

McMahon-Crabtree & Monet (2021, Applied Optics 60(25), G144) measured Prophesee Gen3 event cameras on the night sky:

* setup 1 (FITTED): Gen3 VGA (15 um) behind an 85 mm f/1.4 lens, staring, sky ~20.3 mag/arcsec^2: stars to V 9.8;
* setup 2 (PREDICTION, another sensor): Gen3 HVGA-EM (20 um) behind the same lens under the same sky: V 6.9;
* setup 3 (PREDICTION, other optics and motion): Gen3 VGA behind a 200 mm f/2.0 lens, scanning: no star detected
  while scanning faster than 0.5 deg/s.

D. G. Monet (AFRL) stared with a Gen3 VGA and a Gen4 behind a 135 mm f/2.0 lens, cut the positive events into 5 s
slices, found the stars in each with SExtractor and matched them to Gaia DR2 ("Limiting Magnitude Analysis - update
14 Aug 2022", the figure in github gcohen/AMOS-Short-Course, Data/Monet/star_files): 90 % of the matched stars are
brighter than Gaia G 9.8 (Gen3) and G 10.1 (Gen4). The figure's legend pairs the two numbers the other way round;
its curves and their 90 % lines read as here.

* setup 4 (PREDICTION, other optics): Gen3 VGA behind the 135 mm f/2.0, staring: G 9.8;
* setup 5 (PREDICTION, another sensor with its own measured dark current, other optics): Gen4 behind it: G 10.1.

What is compared: the statistic Monet's figure reports, computed by evsda for each setup. A star counts as found in a
5 s slice when its positive events near its catalogued track stand out of the background as a source (``matched``:
:class:`evsda.blocks.detection.analytic.EventLimit` at the known position and velocity, ON events only, a chance
match probability of ``MATCH_FALSE_PROBABILITY`` per star and slice in place of SExtractor's unknown settings); each
star is counted in every slice it is found in; with star counts growing ``STAR_COUNT_SLOPE`` dex per magnitude (the
bright side of Monet's own histogram), the limit is the magnitude brighter than which 90 % of the found stars lie
(:meth:`~evsda.blocks.detection.analytic.EventLimit.matched_magnitude`). The 2022 figure is an "update" of the
limiting-magnitude analysis, so the 2021 stares' limits are taken as the same statistic. Monet's G magnitudes are
turned into V with Gaia's G - V polynomial in BP - RP (Riello et al. 2021, A&A 649, A3, Table C.2) at the Sun's
colour. Beside it the script prints the single-pixel *contrast limit* (the best-centred pixel's rise reaches
theta_ON: the 2021 paper's model criterion) and what evsda's own blind event detector reaches (the 50 % point of a
simulated limiting-magnitude study and its analytic cross-check): a stricter criterion than the measurements'.
The scan (setup 3) is compared on the contrast limit: its stars are streaks hundreds of pixels long in a 5 s slice,
which a point-source matching pipeline does not find at any brightness.

The sensors count the photons of their presets' spectral response (unfiltered silicon for the Gen3 VGA and Gen4, an
assumed curve: evsda.blocks.scene.spectra), not V-band photons; the script prints each setup's band factor and, for
the Gen4, how its prediction moves with the assumed silicon depth or behind a V filter.

The one fitted number is the Gen3 VGA dark current (``--fit``: the value at which setup 1's matched-star limit is
V 9.8; ``library/sensors/prophesee_gen3_vga.yaml`` holds it). Everything else stays as the presets give it.

    python benchmarks/onsky_validation.py [--fit] [--no-sim] [--jobs 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from scipy import optimize

from evsda.blocks.detection.analytic import EventLimit
from evsda.blocks.detection.study import analytic_limits, design_limit, parse_ladder, run_design
from evsda.blocks.scene import spectra
from evsda.graph.graphfile import load_graph

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
ELECTRON_C = 1.602176634e-19                # [C]
DARK_PARAM = "sensor/pixel.dark_current_density_A_m2"


@dataclass(frozen=True)
class Setup:
    """One published on-sky measurement and the graph file that reproduces it."""

    graph: str                      # file in examples/
    label: str                      # sensor, optics, motion, sky
    role: str                       # FITTED or PREDICTION
    measured: float | None          # measured limit in ``band`` [mag]; None for a bound stated in words
    band: str                       # "V" (2021 paper) or "G" (Gaia DR2 G, Monet 2022)
    measured_text: str              # the measurement as the source states it
    ladder: str                     # the simulated study's magnitudes [V mag]
    matched: bool = True            # the matched-star criterion applies (False: streaks, compared on the contrast)

    @property
    def path(self) -> str:
        return str(EXAMPLES / self.graph)

    @property
    def measured_v(self) -> float | None:
        """The measured limit in V [mag] (a G limit at the Sun's colour)."""
        if self.measured is None or self.band == "V":
            return self.measured
        return self.measured - g_minus_v(SUN_BP_RP)


SETUPS = (
    Setup("onsky_stare_85mm_vga.yaml", "Gen3 VGA 15 um, 85 mm f/1.4, stare (15\"/s), 20.3 mag/arcsec^2", "FITTED",
          9.8, "V", "V 9.8", "5:10:0.5"),
    Setup("onsky_stare_85mm_hvga.yaml", "Gen3 HVGA-EM 20 um, 85 mm f/1.4, stare (15\"/s), 20.3 mag/arcsec^2",
          "PREDICTION", 6.9, "V", "V 6.9", "4.5:9.5:0.5"),
    Setup("onsky_scan_200mm.yaml", "Gen3 VGA 15 um, 200 mm f/2.0, scan at 0.5 deg/s, 20.3 mag/arcsec^2",
          "PREDICTION", None, "V", "no star above 0.5 deg/s", "4:9:0.5", matched=False),
    Setup("onsky_stare_135mm_vga.yaml", "Gen3 VGA 15 um, 135 mm f/2.0, stare (15\"/s), sky 20.3 assumed",
          "PREDICTION", 9.8, "G", "G 9.8 (90 % of matches)", "5.5:10.5:0.5"),
    Setup("onsky_stare_135mm_gen4.yaml", "Gen4 4.86 um, 135 mm f/2.0, stare (15\"/s), sky 20.3 assumed",
          "PREDICTION", 10.1, "G", "G 10.1 (90 % of matches)", "4:9:0.5"),
)
GEN4 = SETUPS[4]
SLICE_S = 5.0                                # Monet's slices of the positive events (READMEstar) [s]
MATCH_FALSE_PROBABILITY = 1e-4               # chance that a catalogued star is matched to background events in a slice,
                                             # chosen so that the false matches fainter than G 11 are ~1 % of all matches,
                                             # as in Monet's figure (the script prints the model's share) [1]
STAR_COUNT_SLOPE = 0.5                       # d log10 N / dm: Monet's histogram (starhist.jpg) rises 0.44 (Gen3) and
                                             # 0.54 (Gen4) dex per mag over G 6.1-8.3, where every star is found [mag^-1]
MATCHED_FRACTION = 0.9                       # Monet's figure: 90 % of the matched stars brighter than the limit [1]
CATALOGUE_END = 12.0                         # the matched stars reach G 12 in Monet's figure [mag]
SUN_BP_RP = 0.82                             # the Sun's Gaia BP - RP (Casagrande & VandenBerg 2018, MNRAS 479, L102) [mag]
#: G - V = c0 + c1 x + c2 x^2 + c3 x^3, x = BP - RP (Riello et al. 2021, A&A 649, A3, Table C.2; sigma 0.030 mag)
G_MINUS_V_COEFFS = (-0.02704, 0.01424, -0.2156, 0.01426)
SCAN_RATES_DEG_S = (0.5, 1.0, 2.0, 4.0)      # rates at which the scan setup's contrast limit is printed [deg/s]
SILICON_DEPTHS_M = (2e-6, 5e-6)              # other collection depths of the presets' assumed silicon response [m]
BANDWIDTH_SLOWER = (0.1, 0.3, 3.0)           # factors by which the sensitivity lines slow the photoreceptor [1]
SCAN_PIXEL_ARCSEC = 15.47                    # 15 um at 200 mm [arcsec]
SCAN_SWATH_DEG = 480 * SCAN_PIXEL_ARCSEC / 3600.0   # the VGA's short side swept across the sky [deg]
SKY_DEG2 = 41252.96                          # the whole sky [deg^2]
CATALOG_COMPLETE_MAG = 6.5                   # the bundled Hipparcos excerpt is complete to V 6.5 (library/stars) [mag]


def cpu_s() -> float:
    """CPU seconds of this process and its finished children (the sweep's workers) [s]."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def g_minus_v(bp_rp: float) -> float:
    """Gaia G - Johnson V at colour ``bp_rp`` (Riello et al. 2021, Table C.2) [mag]."""
    return sum(c * bp_rp**i for i, c in enumerate(G_MINUS_V_COEFFS))


def contrast_limit(path: str, overrides: list[str] = ()) -> float:
    """The 2021 paper's model criterion in evsda: the magnitude at which the best-centred pixel's rise equals
    theta_ON [mag]."""
    return design_limit(path, list(overrides)).contrast_limit()


def matched_detector(path: str, overrides: list[str] = (), false_probability: float = MATCH_FALSE_PROBABILITY,
                     slice_s: float = SLICE_S) -> EventLimit:
    """The setup's pixel, optics and motion with Monet's detection: ON events of one slice in the detector's box on
    the star's known track (one trial velocity), the count threshold held to ``false_probability`` per star."""
    design = design_limit(path, list(overrides)).d
    per_hour_per_mpx = false_probability * 3600.0 / slice_s * 1e6    # one test per star and slice (significance.py)
    return EventLimit(dataclasses.replace(design, look_s=slice_s, polarity="on", n_velocities=1,
                                          false_alarm_rate_per_hour_per_mpx=per_hour_per_mpx))


def matched_limit(path: str, overrides: list[str] = (), slope: float = STAR_COUNT_SLOPE, **detector) -> float:
    """Monet's statistic in evsda: the V magnitude brighter than which 90 % of the stars found in 5 s slices lie
    (each star counted in every slice it is found in) [mag]."""
    faintest_v = CATALOGUE_END - g_minus_v(SUN_BP_RP)
    return matched_detector(path, overrides, **detector).matched_magnitude(MATCHED_FRACTION, slope, faintest_v)


def predicted_limit(setup: Setup, overrides: list[str] = ()) -> float:
    """The limit compared with ``setup``'s measurement: the matched-star limit, or for streaks the contrast limit."""
    return (matched_limit if setup.matched else contrast_limit)(setup.path, list(overrides))


def fit_dark_current(setup: Setup, report=print) -> float:
    """The dark-current density [A m^-2] at which ``setup``'s predicted limit equals its measured limit (Brent's
    method on log10 J between 1e-10 and 1e-4 A m^-2, 0.005 dex)."""

    def miss(log_j: float) -> float:
        value = predicted_limit(setup, [f"{DARK_PARAM}={10 ** log_j:.6g}"])
        report(f"  J = {10 ** log_j:.4g} A/m^2: predicted limit V {value:.3f}")
        return value - setup.measured_v

    return 10 ** optimize.brentq(miss, -10.0, -4.0, xtol=0.005)


def stars_brighter_per_deg2(magnitude: float) -> float:
    """Stars brighter than ``magnitude`` per square degree, averaged over the sky: the bundled Hipparcos excerpt
    (ESA 1997, SP-1200; complete to V ~7.3) [deg^-2]."""
    from evsda.blocks.scene.catalog import load_hipparcos
    from evsda.library import resolve

    catalog = load_hipparcos(str(resolve("library:stars/hip_main.dat.gz")))
    return float((catalog.vmag < magnitude).sum()) / SKY_DEG2


def scan_rate_overrides(rate_deg_s: float) -> list[str]:
    """The scan setup at another rate: sources, render cadence and the detector's velocity search moved with it."""
    rate_px_s = rate_deg_s * 3600.0 / SCAN_PIXEL_ARCSEC
    return [f"inject.rate_arcsec_s={rate_deg_s * 3600.0:g}", f"inject.cadence_s={0.5 / rate_px_s:.6g}",
            f"detector.min_rate_px_s={0.95 * rate_px_s:.6g}", f"detector.max_rate_px_s={1.05 * rate_px_s:.6g}",
            "detector.look_s=0.1", "detector.max_trial_velocities=200000"]


def print_sensitivities(stare: Setup, scan: Setup) -> None:
    """What the fit and the scan's prediction hang on: the stare's limit with the preset's prior dark current and
    without a low-pass, and both setups with the photoreceptor k times slower at every current (``cutoff_saturation``
    x k^(1/n) under the power law f = f_max (I / I_sat)^n)."""
    prior = predicted_limit(stare, [f"{DARK_PARAM}=1e-5"])
    static = predicted_limit(stare, ["sensor/pixel.cutoff_max_hz=0"])
    print(f"{stare.graph}: predicted limit with the prior dark current (1e-5 A/m^2) V {prior:.2f}; with the fitted one "
          f"and no low-pass V {static:.2f}")
    params = design_limit(stare.path).d.pixel.params
    for slower in BANDWIDTH_SLOWER:
        override = [f"sensor/pixel.cutoff_saturation={params.cutoff_saturation * slower ** (1 / params.cutoff_exponent):.6g}"]
        scans = ", ".join(f"{r:g} deg/s V {contrast_limit(scan.path, override + scan_rate_overrides(r)):.2f}"
                          for r in (0.5, 1.0))
        factor = f"{1 / slower:.3g}x faster" if slower < 1 else f"{slower:.3g}x slower"
        print(f"  photoreceptor {factor}: {stare.graph} "
              f"V {predicted_limit(stare, override):.2f}, {scan.graph} (contrast) {scans}")


def chance_share_fainter(setup: Setup, g_mag: float = 11.0) -> float:
    """Share of the stars matched in ``setup`` (chance matches included) fainter than ``g_mag`` in G: the model's
    false-match tail, to set beside the measured one [1]."""
    detector = matched_detector(setup.path)
    offset = g_minus_v(SUN_BP_RP)
    m, p_d, _ = detector.detection_curve(0.0, CATALOGUE_END - offset)
    density = p_d * 10.0 ** (STAR_COUNT_SLOPE * m)
    return float(density[m > g_mag - offset].sum() / density.sum())


def print_criterion_sensitivity(gen3: Setup, gen4: Setup) -> None:
    """How the 135 mm comparison (same lens, same pipeline, two sensors) hangs on the matched-star criterion's two
    assumed numbers, against the single-pixel contrast criterion: the Gen4-minus-Gen3 limit, measured +0.3."""
    measured = gen4.measured - gen3.measured
    contrast = contrast_limit(gen4.path) - contrast_limit(gen3.path)
    print(f"Gen4 minus Gen3 behind the 135 mm f/2.0: measured {measured:+.2f}; contrast criterion {contrast:+.2f}")
    for p_false in (1e-2, 1e-3, 1e-4):
        for slope in (0.45, STAR_COUNT_SLOPE, 0.55):
            a = matched_limit(gen3.path, slope=slope, false_probability=p_false)
            b = matched_limit(gen4.path, slope=slope, false_probability=p_false)
            print(f"  matched stars, chance {p_false:g} per star-slice, counts x10^{slope:g}/mag: Gen3 V {a:.2f}, "
                  f"Gen4 V {b:.2f}, difference {b - a:+.2f}")
    for setup in (gen3, gen4):
        d = matched_detector(setup.path)
        print(f"  {setup.graph}: a slice's ON background {d.mu:.2f} events in the {d.d.box_px}x{d.d.box_px} box, "
              f"threshold {d.k_threshold}; 50 % found per slice at V {d.magnitude_at(0.5):.2f}; chance matches "
              f"fainter than G 11: {100 * chance_share_fainter(setup):.1f} % of all (measured: about 1 %)")


def value_matching(setup: Setup, param: str, low: float, high: float) -> float:
    """The value of the graph parameter ``param`` (searched on a log scale between ``low`` and ``high``) at which
    ``setup``'s predicted limit equals its measured limit: what a miss asks of that one number (NaN if none in the
    range does)."""

    def miss(log_value: float) -> float:
        return predicted_limit(setup, [f"{param}={10 ** log_value:.6g}"]) - setup.measured_v

    a, b = math.log10(low), math.log10(high)
    if miss(a) * miss(b) > 0:
        return math.nan                                 # no value in the range reaches the measurement
    return 10 ** optimize.brentq(miss, a, b, xtol=0.002)


def print_what_the_misses_ask(hvga: Setup, gen4: Setup) -> None:
    """What each prediction that misses by more than 0.5 mag asks of one number, everything else as the presets give
    it (diagnostics, not applied: fitting them would be a second fit): the HVGA-EM's QE x fill factor or ON threshold,
    the Gen4's dark current."""
    qe = design_limit(hvga.path).d.pixel.params.quantum_efficiency
    theta = design_limit(hvga.path).d.pixel.params.threshold_on
    qe_asked = value_matching(hvga, "sensor/pixel.quantum_efficiency", 1e-3, qe)
    theta_asked = value_matching(hvga, "sensor/pixel.threshold_on", theta, 5.0)
    theta_text = "no theta_ON up to 5" if math.isnan(theta_asked) else f"theta_ON {theta_asked:.2f}"
    print(f"{hvga.graph}: {hvga.measured_text} asks QE x fill factor {qe_asked:.3g} (preset {qe:g}: {qe / qe_asked:.1f}x "
          f"fewer electrons per photon at the same dark current); {theta_text} does it (preset {theta:g})")
    j = value_matching(gen4, DARK_PARAM, 1e-8, 1e-3)
    pixel_area_m2 = 4.86e-6 ** 2
    print(f"{gen4.graph}: {gen4.measured_text} asks a dark current of {j:.3g} A/m^2 = {j * pixel_area_m2 * 1e15:.3g} fA "
          f"= {j * pixel_area_m2 / ELECTRON_C:.0f} e-/s on a 4.86 um pixel (preset: measured 5.5 fA = 34 300 e-/s)")


def print_band(setups, what_if) -> None:
    """The detectors' spectral response (evsda.blocks.scene.spectra): photons counted over the V band's, for sunlight
    (the sky) and a field star; for the setups ``what_if`` (those of a sensor with nothing fitted: a fitted sensor's
    dark current would be refitted), how the prediction moves with the assumed silicon depth or behind a V filter."""
    for setup in setups:
        spec = load_graph(setup.path).nodes["sensor/camera"].block.focal_plane.spectral_response
        star = float(spectra.star_band_factor(spec, spectra.FIELD_STAR_B_V))
        moves = []
        if spec.detector == "silicon" and setup in what_if:
            moves = [f"depth {d * 1e6:g} um V {predicted_limit(setup, [f'sensor/camera.silicon_depth_m={d:g}']):.2f}"
                     for d in SILICON_DEPTHS_M]
            moves.append(f"behind a V filter V {predicted_limit(setup, ['sensor/camera.filter=V']):.2f}")
        print(f"  {setup.graph}: response {spec.detector} ({spec.silicon_depth_m * 1e6:g} um), band factor sunlight "
              f"{spectra.sun_band_factor(spec):.2f}, a B-V {spectra.FIELD_STAR_B_V} star {star:.2f}; "
              + "; ".join(moves))


def run(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fit", action="store_true", help="fit the Gen3 VGA dark current to setup 1 and print it")
    parser.add_argument("--no-sim", action="store_true", help="leave out the simulated studies (analytic limits only)")
    parser.add_argument("--jobs", type=int, default=2, help="points of a study run at once")
    parser.add_argument("--out", help="study folder (default: a temporary one; an existing one is resumed)")
    args = parser.parse_args(argv)
    start, cpu0, load0 = time.perf_counter(), cpu_s(), os.getloadavg()[0]
    fitted = SETUPS[0]
    if args.fit:
        print(f"fitting the Gen3 VGA dark current to {fitted.graph} (measured {fitted.measured_text}):")
        j = fit_dark_current(fitted)
        pixel_area_m2 = 15e-6 ** 2
        print(f"fitted dark current density {j:.3g} A/m^2 = {j * 1e5:.3g} nA/cm^2 -> {j * pixel_area_m2:.3g} A = "
              f"{j * pixel_area_m2 / ELECTRON_C:.0f} e-/s on a 15 um pixel (preset prior 1e-5 A/m^2)")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(args.out or Path(scratch) / "onsky")
        for setup in SETUPS:
            limit = design_limit(setup.path)
            analytic = analytic_limits(limit)
            sim = {"m50": math.nan, "m50_err": math.nan, "cpu_s": math.nan, "wall_s": math.nan}
            if not args.no_sim:
                t0, c0 = time.perf_counter(), cpu_s()
                curve = run_design(setup.path, parse_ladder(setup.ladder), out, jobs=args.jobs, report=lambda *a: None)
                sim = {"m50": curve.fit["m50"], "m50_err": curve.fit["m50_err"], "cpu_s": cpu_s() - c0,
                       "wall_s": time.perf_counter() - t0}
            rows.append((setup, predicted_limit(setup), analytic, sim, limit.time_constant_s()))
    print()
    print(f"{'setup':<72s} {'role':<10s} {'measured':>24s} {'in V':>6s} {'predicted':>9s} {'diff':>6s} "
          f"{'contrast':>8s}   {'detector m50 sim':>16s} {'analytic':>8s}")
    for setup, predicted, analytic, sim, _ in rows:
        measured_v = setup.measured_v if setup.measured is not None else math.nan
        print(f"{setup.label:<72s} {setup.role:<10s} {setup.measured_text:>24s} {measured_v:6.2f} {predicted:9.2f} "
              f"{predicted - measured_v:+6.2f} {analytic['contrast']:8.2f}   {sim['m50']:9.2f} ± {sim['m50_err']:4.2f} "
              f"{analytic['m50']:8.2f}")
    print(f"in V: the measured limit in V (G - V = {g_minus_v(SUN_BP_RP):+.3f} at the Sun's BP - RP {SUN_BP_RP}; "
          f"{g_minus_v(0.5):+.3f} .. {g_minus_v(1.5):+.3f} for BP - RP 0.5 .. 1.5); predicted: Monet's statistic (90 % of "
          f"the stars found in {SLICE_S:g} s slices of ON events brighter), for the scan the contrast limit; diff = "
          f"predicted - measured; contrast: the best pixel's rise reaches theta_ON (the 2021 model's criterion); "
          f"detector m50: evsda's blind event detector (simulated study, and its analytic cross-check)")
    for setup, _, analytic, sim, tau in rows:
        print(f"  {setup.graph}: dark-pixel time constant under the sky {tau * 1e3:.3g} ms; detector threshold "
              f"{analytic['k_threshold']} events over a background of {analytic['mu']:.1f}; study ladder "
              f"{setup.ladder}: {sim['wall_s']:.0f} s wall, {sim['cpu_s']:.0f} CPU s")
    scan = SETUPS[2]
    limits = [contrast_limit(scan.path, scan_rate_overrides(r)) for r in SCAN_RATES_DEG_S]
    print(f"{scan.graph}: contrast limit against the scan rate, the Hipparcos stars brighter per deg^2 (the excerpt "
          f"is complete to V {CATALOG_COMPLETE_MAG:g}: fainter limits count the stars to V {CATALOG_COMPLETE_MAG:g}, "
          f"a lower bound), and the scanning time per such star in a {SCAN_SWATH_DEG:.2f} deg swath:")
    for r, m in zip(SCAN_RATES_DEG_S, limits):
        bound = m > CATALOG_COMPLETE_MAG
        density = stars_brighter_per_deg2(min(m, CATALOG_COMPLETE_MAG))
        print(f"  {r:g} deg/s: V {m:.2f}; {'>= ' if bound else ''}{density:.3f} per deg^2; one every "
              f"{'<= ' if bound else ''}{1.0 / (density * SCAN_SWATH_DEG * r):.1f} s")
    print_sensitivities(fitted, scan)
    print_criterion_sensitivity(SETUPS[3], GEN4)
    print_what_the_misses_ask(SETUPS[1], GEN4)
    print("spectral response (the presets' silicon curve is assumed: no measured QE(lambda) of these sensors found):")
    print_band(SETUPS, what_if=(GEN4,))
    print(f"all: {time.perf_counter() - start:.0f} s wall, {cpu_s() - cpu0:.0f} CPU s; load average {load0:.1f} "
          f"before, {os.getloadavg()[0]:.1f} after; {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    raise SystemExit(run())
