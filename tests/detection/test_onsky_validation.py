"""The on-sky validation's machinery on small cases: the contrast criterion against the closed form of
McMahon-Crabtree & Monet's (2021) limiting-magnitude condition, the graph files against the setups the paper
describes, the fitted preset against the measurement it was fitted to, and the fit itself."""

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import constants

from evsda.blocks.detection.analytic import (EventDesign, EventLimit, PsfTable, background_rate_hz,
                                             matched_fraction_magnitude)
from evsda.blocks.detection.significance import poisson_p_value
from evsda.blocks.detection.study import design_limit
from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.model import PixelModel
from evsda.graph.graphfile import load_graph

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
ARCSEC_PER_RAD = 180 / math.pi * 3600


def _benchmark():
    spec = importlib.util.spec_from_file_location("onsky_validation", ROOT / "benchmarks" / "onsky_validation.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module               # its dataclasses look their module up while being built
    spec.loader.exec_module(module)
    return module


def _gaussian_psf(sigma_px: float) -> PsfTable:
    """Fraction of a Gaussian PSF (pixel-integrated, by erf) in a pixel at each offset of a 1/8-pixel grid."""
    from scipy.special import erf

    grid = np.arange(-4, 4 + 1e-9, 0.125)

    def band(c):
        s = sigma_px * math.sqrt(2)
        return 0.5 * (erf((c + 0.5) / s) - erf((c - 0.5) / s))

    return PsfTable(grid, band(grid)[:, None] * band(grid)[None, :])


def test_contrast_limit_is_the_papers_condition_without_bandwidth():
    # With the photoreceptor logarithmic down to the dark current and no low-pass (cutoff 0), the best-centred
    # pixel's rise is ln(1 + f_peak F_m / (F_sky + I_dark / (eta q))): it reaches theta at
    # F_m = (e^theta - 1) (F_sky + I_dark / (eta q)) / f_peak, the condition of McMahon-Crabtree & Monet (2021,
    # Appl. Opt. 60(25), G144): the star's change of the photocurrent equals the contrast threshold.
    eta, theta, j_dark, pitch, wavelength = 0.2, 0.2, 2e-7, 15e-6, 550e-9
    params = DvsPixel(quantum_efficiency=eta, knee_at_dark_current=True, dark_current_density_A_m2=j_dark,
                      cutoff_max_hz=0.0, threshold_on=theta, threshold_off=theta, threshold_sigma=0.0).params
    pixel = PixelModel(params, pitch**2, wavelength)
    psf = _gaussian_psf(0.6)
    flux0, sky = 3.0e7, 150.0                       # photons/s from V 0 and from the sky on a pixel
    limit = EventLimit(EventDesign(pixel, psf, flux0, sky, 0.01, 0.0, 5.0, 2, 5, 1.0, 65536))
    dark_photons = pixel.dark_current_A / (eta * constants.e)
    f_lim = (math.exp(theta) - 1) * (sky + dark_photons) / psf.peak
    expected = -2.5 * math.log10(f_lim / flux0)
    assert limit.contrast_limit(5.0, 15.0) == pytest.approx(expected, abs=0.005)
    # the same design with the dark current 50x higher (the preset's prior) is limited 2.5 log10 of the ratio of
    # the (sky + dark) currents brighter
    params_hot = params.model_copy(update={"dark_current_density_A_m2": 50 * j_dark})
    hot = EventLimit(EventDesign(PixelModel(params_hot, pitch**2, wavelength), psf, flux0, sky, 0.01, 0.0, 5.0, 2, 5,
                                 1.0, 65536))
    ratio = (sky + 50 * dark_photons) / (sky + dark_photons)
    assert limit.contrast_limit(5.0, 15.0) - hot.contrast_limit(3.0, 13.0) == pytest.approx(2.5 * math.log10(ratio), abs=0.01)


@pytest.mark.parametrize("graph, pixel_arcsec, aperture_m, rate_arcsec_s", [
    ("onsky_stare_85mm_vga.yaml", 36.4, 0.0607, 15.0),     # 15 um at 85 mm, f/1.4, the sidereal rate
    ("onsky_stare_85mm_hvga.yaml", 48.5, 0.0607, 15.0),    # 20 um at 85 mm
    ("onsky_scan_200mm.yaml", 15.5, 0.1, 1800.0),          # 15 um at 200 mm, f/2.0, scanning at 0.5 deg/s
    ("onsky_stare_135mm_vga.yaml", 22.9, 0.0675, 15.0),    # 15 um at 135 mm, f/2.0 (Monet 2022)
])
def test_graph_files_hold_the_papers_setups(graph, pixel_arcsec, aperture_m, rate_arcsec_s):
    g = load_graph(str(EXAMPLES / graph))
    by_type = {node.block.type_name: node.block for node in g.nodes.values()}
    cam = by_type["camera"].params
    assert cam.pixel_pitch_m / cam.focal_length_m * ARCSEC_PER_RAD == pytest.approx(pixel_arcsec, rel=0.002)
    assert by_type["optics"].params.aperture_m == pytest.approx(aperture_m, rel=0.002)
    assert by_type["sky_background"].params.surface_brightness_mag_arcsec2 == 20.3
    assert by_type["injected_sources"].params.rate_arcsec_s == rate_arcsec_s
    # the bandwidth's saturation current is a photocurrent at a given illuminance on the pixel: it scales with the
    # pixel area from the Gen3 VGA preset's (15 um)
    vga = load_graph("library:sensors/prophesee_gen3_vga.yaml", ["camera.focal_length_m=0.1"]).nodes["pixel"]
    vga = vga.block.params.cutoff_saturation
    assert by_type["dvs_pixel"].params.cutoff_saturation == pytest.approx(vga * (cam.pixel_pitch_m / 15e-6) ** 2,
                                                                         rel=0.001)


def test_gen4_setup_is_the_gen4_preset_unchanged_behind_the_135mm_lens():
    # Monet's 2022 Gen4 stare is a prediction: the graph takes every pixel number from the Gen4 preset (its measured
    # dark current included) and sets only the camera's geometry: 4.86 um at 135 mm f/2.0 is 7.43 arcsec per pixel.
    g = load_graph(str(EXAMPLES / "onsky_stare_135mm_gen4.yaml"))
    by_type = {node.block.type_name: node.block for node in g.nodes.values()}
    cam = by_type["camera"].params
    assert cam.pixel_pitch_m / cam.focal_length_m * ARCSEC_PER_RAD == pytest.approx(7.43, rel=0.002)
    assert by_type["optics"].params.aperture_m == pytest.approx(0.0675)
    preset = load_graph("library:sensors/prophesee_gen4.yaml", ["camera.focal_length_m=0.135"]).nodes["pixel"]
    assert by_type["dvs_pixel"].params == preset.block.params


def test_fitted_gen3_dark_current_reproduces_the_measurement_it_was_fitted_to():
    # The preset's dark current was fitted so that setup 1's predicted limit (Monet's statistic: 90 % of the stars
    # found in 5 s slices of ON events brighter) is McMahon-Crabtree & Monet's V 9.8; a change of the Gen3 preset
    # (QE, thresholds, bandwidth, noise) that moves it needs a new fit.
    bench = _benchmark()
    assert bench.predicted_limit(bench.SETUPS[0]) == pytest.approx(9.8, abs=0.05)


def test_fit_inverts_a_known_limit_against_dark_current(monkeypatch):
    # The fit finds the dark current at which the criterion equals the measured limit, on a log scale over
    # six decades: a stand-in criterion m(J) = 2 - 1.25 log10(J) is inverted exactly.
    bench = _benchmark()
    monkeypatch.setattr(bench, "predicted_limit",
                        lambda setup, overrides: 2.0 - 1.25 * math.log10(float(overrides[0].split("=")[1])))
    setup = bench.SETUPS[0]
    fitted = bench.fit_dark_current(setup, report=lambda *a: None)
    assert math.log10(fitted) == pytest.approx((2.0 - setup.measured) / 1.25, abs=0.01)


def test_what_a_miss_asks_inverts_a_known_limit_against_any_parameter(monkeypatch):
    # The diagnostics solve for the one number at which a setup's criterion equals its measurement: a stand-in
    # criterion m(qe) = 10 + 2.5 log10(qe / 0.2) is inverted at qe = 0.2 * 10^((m - 10) / 2.5).
    bench = _benchmark()
    monkeypatch.setattr(bench, "predicted_limit",
                        lambda setup, overrides: 10.0 + 2.5 * math.log10(float(overrides[0].split("=")[1]) / 0.2))
    setup = bench.SETUPS[1]
    asked = bench.value_matching(setup, "sensor/pixel.quantum_efficiency", 1e-3, 1.0)
    assert asked == pytest.approx(0.2 * 10 ** ((setup.measured - 10.0) / 2.5), rel=0.01)


def test_g_limits_are_compared_in_v_through_gaias_colour_polynomials(monkeypatch):
    # Monet's limits are Gaia G; the comparison is in V: V = G - (G - V), with G - V of the stars matched near the
    # limit (matched_g_minus_v), each from its Hipparcos V - I_C through Riello et al. (2021, Table C.2)'s polynomial;
    # the BP - RP polynomial of the same table gives the reference colour's (the Sun's BP - RP 0.82: about -0.15).
    # The 2021 limits are V already.
    bench = _benchmark()
    assert bench.g_minus_v(0.0) == pytest.approx(-0.02704)
    assert bench.g_minus_v(0.82) == pytest.approx(-0.02704 + 0.01424 * 0.82 - 0.2156 * 0.82**2 + 0.01426 * 0.82**3)
    assert bench.g_minus_v_of_vi(0.0) == pytest.approx(-0.01597)
    assert bench.g_minus_v_of_vi(1.0) == pytest.approx(-0.01597 - 0.02809 - 0.2483 + 0.03656 - 0.002939)
    # the two polynomials agree for a star of the Sun's colours (V - I_C 0.70, BP - RP 0.82) within their sigma
    assert bench.g_minus_v_of_vi(0.70) == pytest.approx(bench.g_minus_v(0.82), abs=0.03)
    monkeypatch.setattr(bench, "matched_g_minus_v", lambda graph: -0.2 if graph == bench.SETUPS[4].graph else None)
    gen4 = bench.SETUPS[4]
    assert gen4.band == "G" and gen4.measured_v == pytest.approx(10.1 + 0.2)
    assert bench.SETUPS[0].measured_v == 9.8


def test_colour_sample_is_the_catalogues_complete_faint_end():
    # The colours standing for the matched stars': every bundled Hipparcos star of V 6-6.5 with both colours; their
    # mean B - V is the field-star colour the synthetic stars take (0.66, docs/scene.md), their V - I_C ~0.7.
    bench = _benchmark()
    b_v, v_i = bench.colour_sample()
    assert b_v.size == v_i.size > 3000
    assert np.mean(b_v) == pytest.approx(0.66, abs=0.01) and 0.6 < np.mean(v_i) < 0.8


def test_population_limits_are_the_closed_form_for_sharp_limits():
    # Every reference star brighter than m0 found, none fainter, counts 10^(s V): 90 % of the found stars lie brighter
    # than m0 + log10(0.9) / s (matched_fraction_magnitude's closed form). One colour of G - V = c: its G quantile is
    # the V one plus c. A colour brighter_by d (more electrons per V photon) is found to m0 + d. Two colours of equal
    # share, G - V c1 and c2, both sharp at m0: the G quantile solves 0.9 = sum_i 10^(s (G - c_i - m0)) / 2, capped at
    # 1 each, which lies between the two one-colour values.
    bench = _benchmark()
    slope, m0 = 0.5, 9.0
    grid = np.arange(0.0, 13.0 + 1e-9, 0.001)
    found = (grid < m0).astype(float)
    v90 = m0 + math.log10(0.9) / slope
    v, g = bench.population_limits(grid, found, np.array([0.0]), np.array([-0.3]), faintest_g=20.0)
    assert v == pytest.approx(v90, abs=0.01) and g == pytest.approx(v90 - 0.3, abs=0.01)
    v, _ = bench.population_limits(grid, found, np.array([0.4]), np.array([0.0]), faintest_g=20.0)
    assert v == pytest.approx(v90 + 0.4, abs=0.01)
    c = np.array([-0.5, 0.0])
    v, g = bench.population_limits(grid, found, np.zeros(2), c, faintest_g=20.0)

    def share(gq):
        return np.minimum(10.0 ** (slope * (gq - c - m0)), 1.0).mean() - 0.9

    from scipy.optimize import brentq
    assert v == pytest.approx(v90, abs=0.01)
    assert g == pytest.approx(brentq(share, m0 - 3, m0 + 1), abs=0.01)
    assert v90 - 0.5 < g < v90


def test_blurred_psf_is_the_gaussian_of_the_summed_variances():
    # A pixel-integrated Gaussian PSF of sigma s1 blurred by a Gaussian of sigma s2 is the pixel-integrated Gaussian of
    # sigma sqrt(s1^2 + s2^2) (box * G1 * G2 = box * G12); the flux a pixel lattice catches stays 1.
    bench = _benchmark()
    s1, s2 = 0.4, 0.6
    blurred = bench.blurred_psf(_gaussian_psf(s1), s2 * 2.0 * math.sqrt(2.0 * math.log(2.0)))
    expected = _gaussian_psf(math.hypot(s1, s2))
    offsets = np.linspace(-2.0, 2.0, 9)
    dx, dy = np.meshgrid(offsets, offsets)
    assert np.allclose(blurred(dx, dy), expected(dx, dy), atol=2e-3)
    lattice = np.arange(-6.0, 6.5, 1.0) + 0.3
    lx, ly = np.meshgrid(lattice, lattice)
    assert blurred(lx, ly).sum() == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("slope, start", [(0.5, 0.0), (0.4, 6.0)])
def test_matched_fraction_magnitude_is_the_closed_form_for_a_sharp_limit(slope, start):
    # Every star brighter than m0 found, none fainter, counts growing as 10^(slope m): the cumulative count is
    # 10^(slope m) / (slope ln 10) up to m0, so 90 % of the found stars lie brighter than m0 + log10(0.9) / slope,
    # wherever the grid starts (the stars brighter than its start are counted in closed form).
    m0 = 9.0
    grid = np.arange(start, 12.0 + 1e-9, 0.001)
    found = (grid < m0).astype(float)
    value = matched_fraction_magnitude(grid, found, slope, 0.9)
    assert value == pytest.approx(m0 + math.log10(0.9) / slope, abs=0.003)


def test_background_counts_the_polarity_the_detector_reads():
    # The junction and parasitic leaks fire ON events only (they lower the comparator's memory, Eqs. 18-19); shot
    # noise fires each polarity at the rate of Eq. 20 (about R_n = 0.1 Hz in the dark). A detector reading ON events
    # counts the leaks and one polarity of shot noise, one reading OFF events the other polarity only.
    params = DvsPixel(leak_rate_hz=0.1, shot_noise_rate_hz=0.1, parasitic_rate_per_lux_hz=0.01).params
    pixel = PixelModel(params, (15e-6) ** 2, 550e-9)
    for flux in (0.0, 1e4):
        drive = pixel.drive(np.array([flux]))
        shot = float(drive.shot_p[0]) / pixel.dt_s
        assert 0.05 < shot <= 0.1
        assert background_rate_hz(pixel, flux, "off") == pytest.approx(shot)
        assert background_rate_hz(pixel, flux, "on") == pytest.approx(0.1 + float(drive.parasitic_hz[0]) + shot)
        assert background_rate_hz(pixel, flux, "both") == pytest.approx(
            background_rate_hz(pixel, flux, "on") + background_rate_hz(pixel, flux, "off"))


def test_off_events_count_only_the_fall_completed_within_the_look():
    # After a source has passed, a pixel falls back with its time constant under the sky (Eq. 16). Crossed at a
    # uniformly random moment of a look of T seconds, it completes on average 1 - (tau/T)(1 - exp(-T/tau)) of its
    # fall inside the look: all of it without a low-pass, T / (2 tau) when tau >> T (the mean of u/tau over u
    # uniform on [0, T]). A detector that reads ON events only counts none of the OFF events.
    psf, pitch, wavelength = _gaussian_psf(0.6), 15e-6, 550e-9

    def limit(polarity="both", **pixel):
        params = DvsPixel(quantum_efficiency=0.2, knee_at_dark_current=True, threshold_sigma=0.0, **pixel).params
        return EventLimit(EventDesign(PixelModel(params, pitch**2, wavelength), psf, 3.0e7, 150.0, 0.4, 0.0, 5.0, 2,
                                      5, 1.0, 65536, polarity))

    fast = limit(cutoff_max_hz=0.0, dark_current_density_A_m2=2e-7)
    assert fast.fall_fraction_in_look() == 1.0
    rise = fast.rises(8.0)
    on_only = limit("on", cutoff_max_hz=0.0, dark_current_density_A_m2=2e-7)
    assert fast.expected_events(8.0) > on_only.expected_events(8.0) > 0
    assert rise.max() / 0.2 > 1                       # the best pixel rises by more than a threshold: OFF events exist
    slow = limit(cutoff_max_hz=3000.0, cutoff_model="proportional", cutoff_saturation=2.9e6,
                 dark_current_density_A_m2=2e-7)
    tau = slow.time_constant_s()
    assert tau > 100 * 5.0
    assert slow.fall_fraction_in_look() == pytest.approx(5.0 / (2 * tau), rel=0.01)


def test_large_signal_fall_fraction_follows_the_photoreceptor_ode_and_the_pixels_steps():
    # The large-signal photoreceptor (Delbruck & Mead 1994: C dV/dt = I - I_0 e^V) falls back from a rise Delta L
    # as, in v = L - Y, dv/dt = a (1 - e^v), a = 1 / tau under the sky, v(0) = Delta L. Reference 1: that
    # ODE by SciPy's solve_ivp; reference 2: the simulated pixel's own step (lowpass.large_signal_step at its dt and
    # gain). The fall completed within the look, averaged over a crossing moment uniform in it, must be the
    # analytic c; the small-signal c (1 - (tau/T)(1 - e^-T/tau), exponential fall) is 0.37 where they give 0.57.
    from dataclasses import replace

    from scipy.integrate import solve_ivp

    from evsda.blocks.pixel import lowpass

    params = DvsPixel(quantum_efficiency=0.2, knee_at_dark_current=True, threshold_sigma=0.0,
                      dark_current_density_A_m2=2e-7, cutoff_max_hz=3000.0, cutoff_model="proportional",
                      cutoff_saturation=10.0, lowpass_form="large_signal").params
    pixel = PixelModel(params, (15e-6) ** 2, 550e-9)
    design = EventDesign(pixel, _gaussian_psf(0.6), 3.0e7, 150.0, 0.4, 0.0, 1.0, 2, 5, 1.0, 65536)
    tau = EventLimit(design).time_constant_s()
    assert 1e-3 < tau < 0.1                                  # a few hundred pixel steps per tau at most
    look = EventLimit(replace(design, look_s=tau))           # T / tau = 1: the fall half done in the look
    rises = np.array([0.02, 0.5, 2.0, 5.0])
    c = look.fall_fraction_in_look(rises)
    small = 1.0 - (1.0 - math.exp(-1.0))
    n_steps = int(round(tau / pixel.dt_s))
    for rise, analytic in zip(rises, c):
        # ODE: v and its running integral over [0, T]
        sol = solve_ivp(lambda t, z: [(1.0 - math.exp(z[0])) / tau, z[0]], (0.0, tau), [rise, 0.0],
                        rtol=1e-10, atol=1e-13, method="LSODA")
        ode = 1.0 - sol.y[1, -1] / (tau * rise)
        assert analytic == pytest.approx(ode, rel=1e-4)
        # the pixel's steps, gain from its own rate: L <- large_signal_step(L, Y, eps)
        gain = -math.expm1(-pixel.dt_s / tau)
        level, remaining = rise, []
        for _ in range(n_steps):
            level = float(lowpass.large_signal_step(level, 0.0, gain))
            remaining.append(level)
        stepped = 1.0 - np.mean(remaining) / rise
        assert analytic == pytest.approx(stepped, abs=2.0 / n_steps + 1e-4)
    assert c[0] == pytest.approx(small, rel=0.01)             # a small rise: the small-signal c
    assert c[2] > small + 0.15 and c[3] > c[2]                # a large one falls faster at first


def test_matched_detector_holds_each_star_and_slice_to_the_chance_probability():
    # Monet's detection in evsda: one test per catalogued star and 5 s slice (one trial velocity, the known track), ON
    # events only; its count threshold k is the smallest with P(N >= k | mu) <= the chance probability, mu the ON
    # background of the box over the slice (significance.py's rule with one trial per star).
    bench = _benchmark()
    detector = bench.matched_detector(bench.SETUPS[4].path, false_probability=1e-4)
    assert detector.d.look_s == bench.SLICE_S == 5.0 and detector.d.polarity == "on" and detector.d.n_velocities == 1
    assert detector.mu == pytest.approx(detector.background_hz * 5.0 * detector.d.box_px**2)
    assert poisson_p_value(detector.k_threshold, detector.mu) <= 1e-4 < poisson_p_value(detector.k_threshold - 1,
                                                                                           detector.mu)
