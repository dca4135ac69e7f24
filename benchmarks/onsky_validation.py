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
limiting-magnitude analysis, so the 2021 stares' limits are taken as the same statistic. Monet's G limits are
turned into V with the G - V of the stars matched near them (``matched_g_minus_v``): the colours (Hipparcos V - I_C,
B - V) of the bundled catalogue's faintest complete half-magnitude, each star's G - V from Riello et al. (2021, A&A
649, A3, Table C.2)'s polynomial in V - I_C, each colour weighted by how many of its stars the setup finds (its
electrons per V photon in the preset's response). Beside it the script prints the single-pixel *contrast limit* (the best-centred pixel's rise reaches
theta_ON: the 2021 paper's model criterion) and what evsda's own blind event detector reaches (the 50 % point of a
simulated limiting-magnitude study and its analytic cross-check): a stricter criterion than the measurements'.
The scan (setup 3) is compared on the contrast limit: its stars are streaks hundreds of pixels long in a 5 s slice,
which a point-source matching pipeline does not find at any brightness.

The sensors count the photons of their presets' spectral response (unfiltered silicon for the Gen3 VGA and Gen4, an
assumed curve: evsda.blocks.scene.spectra), not V-band photons; the script prints each setup's band factor and, for
the Gen4, how its prediction moves with the assumed silicon depth or behind a V filter.

The scan's diagnostics: the photoreceptor of the first-order circuit (NIST's fit with the exponent held at 1,
``benchmarks/pixel_latency_nist.py``), lenses that blur a star over 1-2 pixels (the dark current refitted with the
blur), a search needing 2-3 ON events per crossed pixel, and the star's V photons alone: what each moves, none fitted.

The one fitted number is the Gen3 VGA dark current (``--fit``: the value at which setup 1's matched-star limit is
V 9.8; ``library/sensors/prophesee_gen3_vga.yaml`` holds it). Everything else stays as the presets give it.

    python benchmarks/onsky_validation.py [--fit] [--no-sim] [--jobs 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import gzip
import math
import os
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage, optimize

from evsda.blocks.detection.analytic import EventLimit, PsfTable
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
        """The measured limit in V [mag]: a G limit less the G - V of the stars matched near it
        (:func:`matched_g_minus_v`)."""
        if self.measured is None or self.band == "V":
            return self.measured
        return self.measured - matched_g_minus_v(self.graph)


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
#: G - V = sum c_i y^i, y = V - I_C (Riello et al. 2021, Table C.2, as the Gaia DR3 documentation's photometric
#: relationships list it, read in PyGaia's ``gbrminv_from_vminic``; sigma 0.05 mag, -0.5 < V - I_C < 6)
G_MINUS_V_VI_COEFFS = (-0.01597, -0.02809, -0.2483, 0.03656, -0.002939)
COLOUR_SAMPLE_V = (6.0, 6.5)                 # the Hipparcos excerpt's faintest complete half-magnitude: the colours of
                                             # its stars stand for those of the stars matched near the limits [mag]
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


def g_minus_v_of_vi(v_minus_i):
    """Gaia G - Johnson V at Cousins colour ``V - I_C`` (Riello et al. 2021, Table C.2) [mag]."""
    return sum(c * v_minus_i**i for i, c in enumerate(G_MINUS_V_VI_COEFFS))


def colour_sample() -> tuple[np.ndarray, np.ndarray]:
    """(B - V, V - I_C) of the bundled Hipparcos stars of V in :data:`COLOUR_SAMPLE_V` with both colours (fields
    H37 and H40 of ``hip_main.dat``, ESA 1997) [mag]."""
    from evsda.library import resolve

    b_v, v_i = [], []
    with gzip.open(resolve("library:stars/hip_main.dat.gz"), "rt") as rows:
        for row in rows:
            field = row.split("|")
            try:
                v, bv, vi = float(field[5]), float(field[37]), float(field[40])
            except ValueError:
                continue                                                    # a colour left blank
            if COLOUR_SAMPLE_V[0] <= v < COLOUR_SAMPLE_V[1]:
                b_v.append(bv)
                v_i.append(vi)
    return np.array(b_v), np.array(v_i)


def population_limits(magnitudes: np.ndarray, found: np.ndarray, brighter_by: np.ndarray, g_minus_v_mag: np.ndarray,
                      slope: float = STAR_COUNT_SLOPE, fraction: float = MATCHED_FRACTION,
                      faintest_g: float = CATALOGUE_END) -> tuple[float, float]:
    """(V, G) brighter than which ``fraction`` of the stars found lie, for a mix of colours [mag].

    ``found``: the probability a star of the reference colour is found at V ``magnitudes`` (ascending grid, chance
    matches taken out); a star of colour ``c`` gives the electrons of a reference star ``brighter_by[c]`` brighter
    (``2.5 log10 kappa_c / kappa_ref``), so it is found with ``found(V - brighter_by[c])``; each colour of the sample
    is an equal share of the star counts ``10^(slope V)``, its G is ``V + g_minus_v_mag[c]``, and the counted stars
    end at G ``faintest_g`` (Monet's figure). Both quantiles come from the same found stars."""
    m = np.asarray(magnitudes, dtype=float)
    grid = np.arange(m[0] - 2.0, m[-1] + 2.0, 0.002)                       # common axis for V and G [mag]
    density_v, density_g = np.zeros_like(grid), np.zeros_like(grid)
    for shift, gv in zip(brighter_by, g_minus_v_mag):
        p_v = np.interp(grid - shift, m, found, left=1.0, right=0.0) * 10.0 ** (slope * grid)
        p_v = np.where(grid + gv <= faintest_g, p_v, 0.0)                  # stars matched to G faintest_g
        density_v += p_v
        density_g += np.interp(grid - gv, grid, p_v, left=0.0, right=0.0)  # the same stars on the G axis
    quantile = []
    for density in (density_v, density_g):
        cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]))])   # trapezoids
        quantile.append(float(np.interp(fraction * cumulative[-1], cumulative, grid)))
    return quantile[0], quantile[1]


@functools.cache
def matched_g_minus_v(graph: str) -> float:
    """G - V of the stars a setup matches near its limit: G90 - V90 of :func:`population_limits` over the colours of
    :func:`colour_sample`, each star's G - V from its V - I_C (:func:`g_minus_v_of_vi`), its electrons from its B - V
    (the preset's spectral response, :func:`evsda.blocks.scene.spectra.star_band_factor`) [mag]."""
    setup = next(s for s in SETUPS if s.graph == graph)
    b_v, v_i = colour_sample()
    spec = load_graph(setup.path).nodes["sensor/camera"].block.focal_plane.spectral_response
    kappa = spectra.star_band_factor(spec, b_v) / spectra.star_band_factor(spec, spectra.FIELD_STAR_B_V)
    detector = matched_detector(setup.path)
    m, p_d, chance = detector.detection_curve(0.0, CATALOGUE_END + 1.0)
    found = np.clip((p_d - chance) / (1.0 - chance), 0.0, 1.0)
    v90, g90 = population_limits(m, found, 2.5 * np.log10(kappa), g_minus_v_of_vi(v_i))
    return g90 - v90


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


def seconds_per_star(magnitude: float, rate_deg_s: float) -> str:
    """Scanning time per star brighter than ``magnitude`` in the scan's swath at ``rate_deg_s`` (the Hipparcos
    excerpt, "<=" where the limit is fainter than it is complete) [s], as text."""
    bound = "<= " if magnitude > CATALOG_COMPLETE_MAG else ""
    density = stars_brighter_per_deg2(min(magnitude, CATALOG_COMPLETE_MAG))
    return f"{bound}{1.0 / (density * SCAN_SWATH_DEG * rate_deg_s):.1f} s"


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


def print_first_order_law(stare: Setup, scan: Setup) -> None:
    """Setup 1 and the scan with the Gen3's NIST fit redone with ``cutoff_exponent`` held at 1, the first-order
    photoreceptor's law (``benchmarks/pixel_latency_nist.py``: ``effective_capacitance_F``): what the circuit's
    physics, rather than the fitted exponent, says below NIST's dimmest step."""
    from pixel_latency_nist import fit_bandwidth

    law = fit_bandwidth("prophesee_gen3_vga", exponent=1.0)
    override = ["sensor/pixel.cutoff_exponent=1", f"sensor/pixel.cutoff_saturation={law.saturation:.6g}"]
    scans = ", ".join(f"{r:g} deg/s V {m:.2f} (one per {seconds_per_star(m, r)})" for r, m in
                      ((r, contrast_limit(scan.path, override + scan_rate_overrides(r))) for r in SCAN_RATES_DEG_S))
    print(f"  first-order photoreceptor (NIST refit with n = 1: cutoff_saturation {law.saturation:.4g}, chi2 "
          f"{law.chi2:.2f}/7): {stare.graph} V {predicted_limit(stare, override):.2f}, {scan.graph} (contrast) {scans}")


def blurred_psf(psf: PsfTable, fwhm_px: float) -> PsfTable:
    """``psf`` convolved with a circular Gaussian of FWHM ``fwhm_px`` [pixel] (an optics blur the graph files' ideal
    lenses lack), on a grid extended to hold it."""
    step = float(psf.offsets_px[1] - psf.offsets_px[0])
    sigma = fwhm_px / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    half = step * math.ceil((float(np.abs(psf.offsets_px).max()) + 4.0 * sigma) / step)   # the table's points kept
    grid = np.arange(-half, half + step / 2, step)
    gx, gy = np.meshgrid(grid, grid)
    return PsfTable(grid, ndimage.gaussian_filter(psf(gx, gy), sigma / step, mode="constant"))


def print_optics_blur(stare: Setup, scan: Setup, fwhm_px=(1.0, 2.0)) -> None:
    """The scan with the lenses blurring a star over ``fwhm_px`` (Gaussian FWHM in 15 um pixels, the same on both
    lenses), the Gen3 dark current refitted on setup 1 with the same blur, as the one fit would be (a what-if: the
    examples' lenses are diffraction-limited and no blur was measured)."""
    faintest_v = CATALOGUE_END - g_minus_v(SUN_BP_RP)

    def stare_limit(log_j: float, fwhm: float) -> float:
        d = matched_detector(stare.path, [f"{DARK_PARAM}={10 ** log_j:.6g}"]).d
        blurred = EventLimit(dataclasses.replace(d, psf=blurred_psf(d.psf, fwhm)))
        return blurred.matched_magnitude(MATCHED_FRACTION, STAR_COUNT_SLOPE, faintest_v)

    for fwhm in fwhm_px:
        j = 10 ** optimize.brentq(lambda lj: stare_limit(lj, fwhm) - stare.measured_v, -9.0, -4.0, xtol=0.005)
        theta = design_limit(scan.path).d.pixel.params.threshold_on
        scans = {1: [], 2: []}
        for r in SCAN_RATES_DEG_S:
            for k in scans:
                extra = [f"{DARK_PARAM}={j:.6g}", f"sensor/pixel.threshold_on={k * theta:g}"]
                d = design_limit(scan.path, scan_rate_overrides(r) + extra).d
                m = EventLimit(dataclasses.replace(d, psf=blurred_psf(d.psf, fwhm))).contrast_limit()
                scans[k].append(f"{r:g} deg/s V {m:.2f} (one per {seconds_per_star(m, r)})")
        peak = blurred_psf(design_limit(scan.path).d.psf, fwhm).peak
        print(f"  lenses blurring a star over {fwhm:g} px FWHM ({fwhm * 15:g} um; a pixel then holds at most {peak:.2f} "
              f"of it): Gen3 dark current refitted {j:.3g} A/m^2; {scan.graph} (contrast) " + ", ".join(scans[1])
              + "; with 2 ON events per crossed pixel " + ", ".join(scans[2]))


def print_streak_criterion(scan: Setup, events_per_pixel=(2.0, 3.0)) -> None:
    """The scan's limit when a streak must hold ``k`` ON events per crossed pixel (the best pixel's rise reaching
    ``k theta_ON``): how a search needing more than the contrast limit's one event per pixel moves it."""
    theta = design_limit(scan.path).d.pixel.params.threshold_on
    for k in events_per_pixel:
        theta_k = [f"sensor/pixel.threshold_on={k * theta:g}"]
        limits = ", ".join(f"{r:g} deg/s V {m:.2f} (one per {seconds_per_star(m, r)})" for r, m in
                           ((r, contrast_limit(scan.path, scan_rate_overrides(r) + theta_k)) for r in SCAN_RATES_DEG_S))
        print(f"  a streak of {k:g} ON events per crossed pixel: {scan.graph} {limits}")


def print_scan_band(scan: Setup) -> None:
    """The scan with the sensor counting V photons only (``filter: V``; NIST's law unchanged, which pins the charge
    per threshold in the LEDs' electrons): the scan's best pixel integrates the star's charge, so its limit tests the
    star's electrons per V photon against the LEDs', the QE cancelling (a what-if: an NIR-blocking window or a
    response narrower than the assumed silicon curve lies between)."""
    band = ", ".join(f"{r:g} deg/s V {m:.2f} (one per {seconds_per_star(m, r)})" for r, m in
                     ((r, contrast_limit(scan.path, scan_rate_overrides(r) + ["sensor/camera.filter=V"]))
                      for r in SCAN_RATES_DEG_S))
    print(f"  counting the star's V photons only (band factor 1 in place of 3.98): {scan.graph} {band}")


def print_colours(setups) -> None:
    """The colours behind the G -> V conversion (:func:`matched_g_minus_v`)."""
    b_v, v_i = colour_sample()
    gv = g_minus_v_of_vi(v_i)
    print(f"G - V of the matched stars: the {b_v.size} Hipparcos stars of V {COLOUR_SAMPLE_V[0]:g}-{COLOUR_SAMPLE_V[1]:g} "
          f"(mean B-V {b_v.mean():.3f}, V-I_C {v_i.mean():.3f}; G - V from V-I_C: mean {gv.mean():+.3f}, median "
          f"{np.median(gv):+.3f}, 10-90 % {np.percentile(gv, 10):+.3f} .. {np.percentile(gv, 90):+.3f}); at the reference "
          f"colour (the Sun's BP - RP {SUN_BP_RP}) {g_minus_v(SUN_BP_RP):+.3f}")
    for setup in setups:
        print(f"  {setup.graph}: G90 - V90 of the stars it finds {matched_g_minus_v(setup.graph):+.3f} -> "
              f"{setup.measured_text} = V {setup.measured_v:.2f}")


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
              f"{seconds_per_star(m, r)}")
    print_sensitivities(fitted, scan)
    print_first_order_law(fitted, scan)
    print_optics_blur(fitted, scan)
    print_streak_criterion(scan)
    print_scan_band(scan)
    print_colours(SETUPS[3:])
    print_criterion_sensitivity(SETUPS[3], GEN4)
    print_what_the_misses_ask(SETUPS[1], GEN4)
    print("spectral response (the presets' silicon curve is assumed: no measured QE(lambda) of these sensors found):")
    print_band(SETUPS, what_if=(GEN4,))
    print(f"all: {time.perf_counter() - start:.0f} s wall, {cpu_s() - cpu0:.0f} CPU s; load average {load0:.1f} "
          f"before, {os.getloadavg()[0]:.1f} after; {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    raise SystemExit(run())
