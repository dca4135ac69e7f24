"""Equivalent layers (blocks/optics/equivalent_layers.py) against closed forms of the full profile: r0 and the seeing
(Fried 1966; Hardy 1998 Eq. 3.40), the isoplanatic angle (Fried 1982; Hardy 1998 Eq. 3.61), Roddier's coherence
time and the point phase's temporal structure function of frozen-flow layers (Roddier 1981), and a star's image
motion's temporal structure function (Tyler 1994)."""

import itertools

import numpy as np
import pytest

from evsda.blocks.optics.atmosphere import Atmosphere, Layer
from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics.equivalent_layers import (AUTO_FEWEST, AUTO_TOLERANCE, auto_layers, best_groups,
                                                   equivalent_layers, footprint_winds, group_cost)
from evsda.blocks.ports import FocalPlane
from evsda.graph import RunInfo
from evsda.library import resolve

WAVELENGTH = 0.5e-6                       # [m]
K = 2 * np.pi / WAVELENGTH                # [1/m]
MEDIAN = "library:atmospheres/median_seeing.csv"
#: the tracked ISS's line of sight on the 10 s pass of benchmarks/end_to_end.yaml (zenith 63.7-65.7 deg): the rate
#: of its crossing per metre of altitude, (dx, dy)/dt in the screens' frame, measured on the pass (0.0110-0.0114,
#: -0.0079 to -0.0084) [1/s]; the median_seeing winds blow along +x
PASS_SIGHT_RATE = np.array([0.0112, -0.0082])


def median_seeing() -> Atmosphere:
    return Atmosphere.from_table(resolve(MEDIAN))


def columns(atmosphere: Atmosphere):
    """``J`` [m^(1/3)], altitudes [m] and wind vectors (L, 2) [m/s] of the layers."""
    return (np.array([layer.cn2_dh for layer in atmosphere.layers]),
            np.array([layer.altitude_m for layer in atmosphere.layers]),
            np.array([layer.wind_m_s for layer in atmosphere.layers]))


def fried_r0(atmosphere: Atmosphere, zenith: float = 0.0) -> float:
    """``r0 = (0.423 k^2 sec(z) sum J)^(-3/5)`` [m] (Hardy 1998 Eq. 3.40), written out here."""
    return float((0.423 * K**2 / np.cos(zenith) * columns(atmosphere)[0].sum()) ** (-3 / 5))


def isoplanatic_angle(atmosphere: Atmosphere, zenith: float = 0.0) -> float:
    """``theta0 = (2.914 k^2 sec(z)^(8/3) sum J h^(5/3))^(-3/5)`` [rad] (Hardy 1998 Eq. 3.61), written out here."""
    cn2, altitude, _ = columns(atmosphere)
    return float((2.914 * K**2 / np.cos(zenith) ** (8 / 3) * np.sum(cn2 * altitude ** (5 / 3))) ** (-3 / 5))


def phase_structure(atmosphere: Atmosphere, lag_s: float, sight_rate=(0.0, 0.0), zenith: float = 0.0) -> float:
    """The point phase's temporal structure function of frozen-flow Kolmogorov layers [rad^2],
    ``D(tau) = 6.88 sum_i (|u_i| tau / r0_i)^(5/3)`` (Fried 1966; Roddier 1981), each layer's footprint moving at
    ``u_i = h_i s' - v_i`` (blocks/optics/imaging.py) and ``r0_i = (0.423 k^2 sec(z) J_i)^(-3/5)``."""
    cn2, altitude, wind = columns(atmosphere)
    speed = np.hypot(*(altitude[:, None] * np.asarray(sight_rate) - wind).T)
    r0_i = (0.423 * K**2 / np.cos(zenith) * cn2) ** (-3 / 5)
    return float(6.88 * np.sum((speed * lag_s / r0_i) ** (5 / 3)))


def coherence_time(atmosphere: Atmosphere, sight_rate=(0.0, 0.0), zenith: float = 0.0) -> float:
    """Roddier's ``tau0`` [s]: the lag where ``D(tau) = 1 rad^2``, i.e. ``0.314 r0 / v_bar`` (Roddier 1981)."""
    return float((1.0 / phase_structure(atmosphere, 1.0, sight_rate, zenith)) ** (3 / 5))


@pytest.mark.parametrize("n_layers", [1, 2, 3, 4, 5, 6])
def test_r0_seeing_and_isoplanatic_angle_are_those_of_the_full_profile(n_layers):
    full = median_seeing()
    fewer = equivalent_layers(full, n_layers)
    assert len(fewer.layers) == n_layers
    for zenith in (0.0, np.deg2rad(65.0)):
        assert fried_r0(fewer, zenith) == pytest.approx(fried_r0(full, zenith), rel=1e-12)
        assert fewer.r0(WAVELENGTH, zenith) == pytest.approx(full.r0(WAVELENGTH, zenith), rel=1e-12)
        assert isoplanatic_angle(fewer, zenith) == pytest.approx(isoplanatic_angle(full, zenith), rel=1e-12)
        assert fewer.isoplanatic_angle(WAVELENGTH, zenith) == pytest.approx(isoplanatic_angle(full, zenith), rel=1e-12)
    # the table's published figures: r0 = 0.10 m at 500 nm, seeing 0.98 lambda / r0 = 1.01 arcsec (its header), and
    # theta0 of HV5/7 (7 urad at r0 = 5 cm, Valley 1980; Hardy 1998 Sec. 3.3.5) with J scaled by (5/10)^(5/3): x 2
    assert fried_r0(fewer) == pytest.approx(0.10, rel=1e-3)
    assert np.rad2deg(0.98 * WAVELENGTH / fried_r0(fewer)) * 3600 == pytest.approx(1.01, abs=0.005)
    assert isoplanatic_angle(fewer) == pytest.approx(14e-6, rel=0.05)


@pytest.mark.parametrize("n_layers", [1, 3, 4])
def test_a_stars_phase_structure_function_and_coherence_time_are_kept(n_layers):
    # a star's footprints move with the wind only: D(tau) ~ sum J |v|^(5/3) tau^(5/3), kept by the wind moment
    full = median_seeing()
    fewer = equivalent_layers(full, n_layers)
    for lag in (1e-4, 1e-3, 1e-2):
        assert phase_structure(fewer, lag) == pytest.approx(phase_structure(full, lag), rel=1e-12)
    assert coherence_time(fewer) == pytest.approx(coherence_time(full), rel=1e-12)
    # Roddier's tau0 = 0.314 r0 / v_bar, v_bar the J-weighted 5/3-moment of the winds: ~ 10 ms for median seeing
    cn2, _, wind = columns(full)
    v_bar = (np.sum(cn2 * np.hypot(*wind.T) ** (5 / 3)) / cn2.sum()) ** (3 / 5)
    assert coherence_time(fewer) == pytest.approx(0.314 * fried_r0(full) / v_bar, rel=2e-3)


@pytest.mark.parametrize("n_layers, tolerance", [(3, 0.04), (4, 0.01)])
def test_the_tracked_satellites_phase_structure_function_is_kept_within_a_few_percent(n_layers, tolerance):
    # the tracked ISS's footprints move at h s' - v: the slew's part is kept by the altitude moment, the wind's by
    # the wind moment, their mixture approximately (worst where a layer's footprint rests against its air)
    full, zenith = median_seeing(), np.deg2rad(65.0)
    fewer = equivalent_layers(full, n_layers)
    for rate in (PASS_SIGHT_RATE * 0.98, PASS_SIGHT_RATE, PASS_SIGHT_RATE * 1.02):
        ratio = phase_structure(fewer, 1e-3, rate, zenith) / phase_structure(full, 1e-3, rate, zenith)
        assert abs(ratio - 1) < tolerance
        assert coherence_time(fewer, rate, zenith) / coherence_time(full, rate, zenith) == pytest.approx(
            ratio ** (-3 / 5), rel=1e-9)
    # a slew that dwarfs every wind: D(tau) -> 6.88 (0.423 k^2 sec z) |s'|^(5/3) sum J h^(5/3) tau^(5/3), kept
    fast = PASS_SIGHT_RATE * 1e4
    assert phase_structure(fewer, 1e-3, fast, zenith) == pytest.approx(phase_structure(full, 1e-3, fast, zenith),
                                                                       rel=1e-3)


def image_motion_structure(atmosphere: Atmosphere, lag_s: float, diameter: float = 0.2) -> float:
    """A star's image motion (G-tilt, both axes) temporal structure function of frozen-flow von Karman layers, up to
    a constant: ``sum_i J_i int k^3 (k^2 + L0^-2)^(-11/6) [2 J1(kR)/(kR)]^2 (1 - J0(k |v_i| tau)) dk``, the aperture's
    mean gradient (Tyler 1994; Sasiela 1994, *Electromagnetic Wave Propagation in Turbulence*, Ch. 2), ``R = D/2``."""
    from scipy.special import j0, j1
    k = np.geomspace(1e-3, 1e4, 20001)
    filtered = k**4 * (k**2 + atmosphere.L0**-2) ** (-11 / 6) * (2 * j1(k * diameter / 2) / (k * diameter / 2)) ** 2
    cn2, _, wind = columns(atmosphere)
    shift = np.hypot(*wind.T)[:, None] * lag_s * k
    return float(np.sum(cn2 * np.trapezoid(filtered * (1 - j0(shift)), np.log(k), axis=1)))


def test_a_stars_image_motion_is_kept_within_four_percent_at_every_lag():
    # its short lags weigh the winds by v^2 (sum J v^2: 2.1 % low in 3 groups), its middle ones between: -1.6 % at
    # 0.5 ms, +3.7 % at 10 ms (docs/optics.md, "Equivalent layers"); the star events of the main job over 30 paired
    # draws: +0.4 +- 0.5 % (docs/speed.md, sixteenth session)
    full = median_seeing()
    fewer = equivalent_layers(full, 3)
    for lag, low, high in ((5e-4, -0.02, -0.01), (1e-2, 0.03, 0.045), (0.2, 0.0, 0.01), (1.0, 0.0, 0.005)):
        assert low < image_motion_structure(fewer, lag) / image_motion_structure(full, lag) - 1 < high


def test_the_groups_are_the_exhaustive_minimum_of_the_grouping_cost():
    rng = np.random.default_rng(5)
    for count, n_groups in ((7, 3), (8, 4), (6, 2), (9, 5)):
        altitude = np.sort(rng.uniform(0, 20e3, count))
        cn2 = rng.uniform(1e-15, 1e-13, count)
        chosen = best_groups(altitude, cn2, n_groups)
        assert [i for run in chosen for i in run] == list(range(count))
        exhaustive = min(sum(group_cost(altitude[a:b], cn2[a:b]) for a, b in zip((0, *cuts), (*cuts, count)))
                         for cuts in itertools.combinations(range(1, count), n_groups - 1))
        assert sum(group_cost(altitude[run.start:run.stop], cn2[run.start:run.stop]) for run in chosen) == \
            pytest.approx(exhaustive, rel=1e-12)


def test_winds_in_other_directions_keep_the_stars_moment_and_unsorted_layers_are_sorted():
    layers = (Layer(5000.0, 2e-14, 20.0, np.pi / 2), Layer(100.0, 5e-13, 5.0, 0.0), Layer(800.0, 1e-13, 8.0, np.pi))
    full = Atmosphere(layers)
    fewer = equivalent_layers(full, 2)
    assert [layer.altitude_m for layer in fewer.layers] == sorted(layer.altitude_m for layer in fewer.layers)
    assert phase_structure(fewer, 1e-3) == pytest.approx(phase_structure(full, 1e-3), rel=1e-12)
    assert isoplanatic_angle(fewer) == pytest.approx(isoplanatic_angle(full), rel=1e-12)


def test_a_profile_with_no_more_layers_is_returned_as_it_is():
    full = median_seeing()
    assert equivalent_layers(full, 7) is full and equivalent_layers(full, 12) is full
    with pytest.raises(ValueError):
        equivalent_layers(full, 0)


def test_the_block_renders_the_equivalent_layers_and_keeps_the_full_profile_for_its_render_intervals():
    params = {"atmosphere": "table", "profile_file": MEDIAN}
    assert PointSourceOptics.Params(**params).equivalent_layers == "auto"     # default; None: every layer
    blocks = [PointSourceOptics(**params, equivalent_layers=None), PointSourceOptics(**params, equivalent_layers=3),
              PointSourceOptics(**params)]
    for block in blocks:
        block.setup(RunInfo(seed=1))
        block._ensure_imager(FocalPlane(1280, 720, 4.86e-6, 0.4), 550e-9)
    assert [len(block._imager.atmosphere.layers) for block in blocks] == [7, 3, 3]
    assert blocks[0]._imager.atmosphere == median_seeing()
    assert blocks[2]._imager.atmosphere == blocks[1]._imager.atmosphere
    assert blocks[1]._intervals.layers[1].size == 7   # the render intervals' tau0 bound reads the full profile


def test_a_run_on_equivalent_layers_keeps_its_flux_and_does_not_depend_on_its_windows():
    # the default Hufnagel-Valley profile (4 layers) as 2, a satellite on the pupil path: the same stamps however the
    # run is cut into windows, the same collected flux as on every layer, other screens
    from evsda.blocks.ports import PointSources
    from evsda.graph import Window
    focal_plane = FocalPlane(640, 480, 4.86e-6, 1.2)

    def run(block, length_s):
        block.setup(RunInfo(duration_ns=40_000_000))
        stamps = []
        for i in range(round(0.04 / length_s)):
            window = Window.from_seconds(i * length_s, (i + 1) * length_s, index=i)
            t_ns = window.sample_times_ns(1_000_000)
            n = len(t_ns)
            sources = PointSources(focal_plane, 550e-9, t_ns, np.array(["25544"]), np.array([0], np.int8),
                                   (300.0 + 40.0 * t_ns * 1e-9)[:, None], np.full((n, 1), 200.0), np.full((n, 1), 2e4),
                                   np.full((n, 1), 8.0), np.full((n, 1), 6e5), np.full(n, np.deg2rad(30.0)))
            stamps.append(block.step(window, sources=[sources])["irradiance"].stamp_flux)
        return np.concatenate(stamps)

    params = dict(aperture_m=0.25, obscuration=0.2, seed=4, psf_path="pupil_fft", render_rate_hz=1000.0)
    fewer = run(PointSourceOptics(**params, equivalent_layers=2), 0.04)
    np.testing.assert_array_equal(fewer, run(PointSourceOptics(**params, equivalent_layers=2), 0.01))
    every = run(PointSourceOptics(**params, equivalent_layers=None), 0.04)
    assert not np.array_equal(fewer, every)
    frames = len(fewer)              # each frame's flux in its stamp: the same r0, within the screens' draws
    np.testing.assert_allclose(fewer.reshape(frames, -1).sum(axis=1), every.reshape(frames, -1).sum(axis=1),
                               rtol=0.02)


def footprint_moment(cn2, altitude, wind, sight_rate) -> float:
    """``sum J |h s' - w|^(5/3)`` [m^(1/3) (m/s)^(5/3)]: the footprints' speeds in the point phase's ``D(tau)``
    (Fried 1966; Roddier 1981), written out here."""
    moving = altitude[:, None] * np.asarray(sight_rate, dtype=float) - wind
    return float(np.sum(cn2 * np.hypot(*moving.T) ** (5 / 3)))


@pytest.mark.parametrize("profile", [MEDIAN, "library:atmospheres/las_campanas.csv",
                                     "library:atmospheres/mauna_kea.csv"])
@pytest.mark.parametrize("n_layers", [1, 2, 3, 4])
def test_each_sources_own_winds_keep_its_footprints_moment_exactly(profile, n_layers):
    # footprint_winds: the tracked ISS's s', a star's (0), a sidereal drift, a slew that dwarfs the winds, and one
    # where a layer's footprint rests against its air: sum J |h s' - w|^(5/3) is the full profile's to 1e-12
    full = Atmosphere.from_table(resolve(profile))
    fewer = equivalent_layers(full, n_layers)
    cn2, altitude, wind = columns(fewer)
    rest = columns(full)[2][-1] / columns(full)[1][-1]          # the top layer's footprint at rest in its air
    for rate in (PASS_SIGHT_RATE, -PASS_SIGHT_RATE, np.zeros(2), np.array([0.0, 1.7e-4]), PASS_SIGHT_RATE * 1e4,
                 rest):
        winds = footprint_winds(fewer, rate)
        assert footprint_moment(cn2, altitude, winds, rate) == pytest.approx(
            footprint_moment(*columns(full), rate), rel=1e-12)
    # a star (s' = 0) gets the groups' own winds
    np.testing.assert_allclose(footprint_winds(fewer, np.zeros(2)), wind, rtol=1e-12, atol=1e-12)
    if n_layers == 3 and profile == MEDIAN:     # the groups' common winds miss the ISS's by 3.3 % (docstring)
        ratio = footprint_moment(cn2, altitude, wind, PASS_SIGHT_RATE) / footprint_moment(*columns(full),
                                                                                            PASS_SIGHT_RATE)
        assert 0.96 < ratio < 0.975


def test_an_imager_on_equivalent_layers_carries_each_source_at_its_own_winds():
    # the source's rate between its first two render times fixes its winds (the first frame alone: no winds, its
    # footprints at h sight); its footprints then move at the exact moment's speeds; a star's at the groups' winds;
    # dropped with the screens; every layer: None (the profile's winds serve every source)
    from evsda.blocks.optics.imaging import Imager
    full = median_seeing()
    fewer = equivalent_layers(full, 3)
    imager = Imager.__new__(Imager)
    imager.atmosphere, imager.flows, imager.follow_sight_rate, imager.drifts = fewer, {}, False, {}
    t = np.array([0.25, 0.251, 0.252, 0.26])
    start = np.array([3e-4, -2e-4])
    for source, rate in (("25544", PASS_SIGHT_RATE), ("star", np.zeros(2))):
        sight = start + rate * (t - t[0])[:, None]
        winds, times = imager.source_flow(source, t[:1], sight[:1])
        assert not winds.any() and times.tolist() == [0.0]
        winds, times = imager.source_flow(source, t, sight)
        np.testing.assert_allclose(winds, footprint_winds(fewer, rate), rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(times, t - t[0])
        cn2, altitude, _ = columns(fewer)
        centre, _ = Imager.footprints_at(altitude[:, None], winds[:, None, :], times, sight, np.zeros(4),
                                         np.full(4, np.inf))
        moving = (centre[:, -1] - centre[:, 0]) / (t[-1] - t[0])            # u_g (L, 2) [m/s]
        assert float(np.sum(cn2 * np.hypot(*moving.T) ** (5 / 3))) == pytest.approx(
            footprint_moment(*columns(full), rate), rel=1e-9)
        assert imager.source_flow(source, t[2:], sight[2:])[0] is winds      # kept
    state = {"flows": {k: [a, b.tolist(), c.tolist()] for k, (a, b, c) in imager.flows.items()}}
    assert set(state["flows"]) == {"25544", "star"}
    imager.flows.pop("25544")                                               # as Imager.forget does
    assert imager.source_flow("25544", t[1:2], start[None])[1].tolist() == [0.0]
    imager.atmosphere = full
    assert imager.source_flow("star", t, np.zeros((4, 2))) is None


def long_pass_sight(t: np.ndarray) -> np.ndarray:
    """A line of sight (F, 2) [1] whose rate turns through 90 deg and grows tenfold over ``t`` [s], 0.003 -> 0.03 1/s
    (a tracked LEO pass's |s'| changes 2.2-fold between 10 deg elevation and culmination at 41 deg on the ISS's pass
    of benchmarks/equivalent_layers_long_pass.yaml, more on a higher pass)."""
    phase = (t - t[0]) / (t[-1] - t[0])
    speed, turn = 0.003 + 0.027 * phase**2, np.pi / 2 * phase
    rate = speed[:, None] * np.stack([np.cos(turn), -np.sin(turn)], axis=1)
    return np.array([0.01, 0.002]) + np.concatenate([np.zeros((1, 2)), np.cumsum(rate[1:] * np.diff(t)[:, None],
                                                                                 axis=0)])


def follower(atmosphere: Atmosphere):
    from evsda.blocks.optics.imaging import Imager
    imager = Imager.__new__(Imager)
    imager.atmosphere, imager.flows, imager.drifts, imager._members = atmosphere, {}, {}, None
    imager.follow_sight_rate = True
    return imager


@pytest.mark.parametrize("profile", [MEDIAN, "library:atmospheres/las_campanas.csv"])
@pytest.mark.parametrize("n_layers", [3, 4])
def test_following_the_sight_rate_keeps_the_moment_at_every_render_time_of_a_long_pass(profile, n_layers):
    # follow_sight_rate: at every render time of a 3-minute pass whose s' changes tenfold, the source's winds give its
    # footprints sum J |h s' - w|^(5/3) of the full profile to 1e-12 at the secant rate since the render time before,
    # and its drifts grow by w dt; fixed winds drift away from it (~1 % over the ISS's pass, docs/optics.md)
    full = Atmosphere.from_table(resolve(profile))
    fewer = equivalent_layers(full, n_layers)
    cn2, altitude, _ = columns(fewer)
    t = np.arange(0.0, 180.0, 0.01) + 12.5
    sight = long_pass_sight(t)
    imager = follower(fewer)
    drift = imager.source_flow("25544", t[:1], sight[:1])[0]
    assert imager.own_winds("25544") is None and not drift.any()
    worst, before = 0.0, drift[:, 0]
    for k in range(1, len(t)):
        drift, times = imager.source_flow("25544", t[k:k + 1], sight[k:k + 1])
        winds, rate = imager.own_winds("25544"), (sight[k] - sight[k - 1]) / (t[k] - t[k - 1])
        assert times is None
        worst = max(worst, abs(footprint_moment(cn2, altitude, winds, rate) / footprint_moment(*columns(full), rate)
                               - 1))
        np.testing.assert_allclose(drift[:, 0], before + winds * (t[k] - t[k - 1]), rtol=0, atol=1e-9)
        before = drift[:, 0]
    assert worst < 1e-12
    # the winds fixed at the first two render times drift away from it
    fixed = footprint_winds(fewer, (sight[1] - sight[0]) / (t[1] - t[0]))
    rates = np.diff(sight, axis=0) / np.diff(t)[:, None]
    assert max(abs(footprint_moment(cn2, altitude, fixed, rate) / footprint_moment(*columns(full), rate) - 1)
               for rate in rates[::100]) > 1e-3


def test_following_the_sight_rate_gives_the_same_drifts_however_the_render_times_are_cut():
    # the drift is advanced render time by render time: one call, windows of every length and a checkpoint between
    # give the same bytes; a render time at or before the last one is extrapolated with its winds, advancing nothing
    import copy
    fewer = equivalent_layers(median_seeing(), 3)
    t = np.arange(0.0, 20.0, 0.004)
    sight = long_pass_sight(t)
    whole = follower(fewer).source_flow("25544", t, sight)[0]
    for length in (1, 7, 250, 1001):
        imager = follower(fewer)
        cut = [imager.source_flow("25544", t[i:i + length], sight[i:i + length])[0]
               for i in range(0, len(t), length)]
        np.testing.assert_array_equal(np.concatenate(cut, axis=1), whole)
    imager = follower(fewer)
    first = imager.source_flow("25544", t[:2000], sight[:2000])[0]
    drifts = copy.deepcopy(imager.drifts)
    again = imager.source_flow("25544", t[1990:1995], sight[1990:1995])[0]
    np.testing.assert_allclose(again, first[:, 1999:] + imager.own_winds("25544")[:, None] * (t[1990:1995] - t[1999])
                               [:, None], rtol=0, atol=1e-9)
    assert all(np.array_equal(a, b) for a, b in zip(imager.drifts["25544"][1:], drifts["25544"][1:]))
    resumed = follower(fewer)
    resumed.drifts = {k: (v[0], *(np.array(a.tolist()) for a in v[1:])) for k, v in drifts.items()}
    np.testing.assert_array_equal(np.concatenate([first, resumed.source_flow("25544", t[2000:], sight[2000:])[0]],
                                                 axis=1), whole)


@pytest.mark.parametrize("profile, chosen, fewest", [(MEDIAN, 3, 3), ("library:atmospheres/las_campanas.csv", 3, 3),
                                                     ("library:atmospheres/mauna_kea.csv", 3, 2)])
def test_auto_takes_the_fewest_layers_that_keep_the_scintillation_and_image_motion_moments(profile, chosen, fewest):
    # sum J h^(5/6), sum J h^2 (Roddier 1981; Dravins et al. 1997) and sum J v^2 (Tyler 1994), written out here,
    # within AUTO_TOLERANCE with `chosen` groups and not with one fewer, but where AUTO_FEWEST decides (mauna_kea:
    # 2 groups are within the tolerance)
    full = Atmosphere.from_table(resolve(profile))

    def moments(atmosphere):
        cn2, altitude, wind = columns(atmosphere)
        return np.array([np.sum(cn2 * altitude ** (5 / 6)), np.sum(cn2 * altitude**2),
                         np.sum(cn2 * np.sum(wind**2, axis=1))])

    def within(count):
        return bool(np.all(np.abs(moments(equivalent_layers(full, count)) / moments(full) - 1) <= AUTO_TOLERANCE))
    assert AUTO_FEWEST == 3 and auto_layers(full) == chosen and auto_layers(full, fewest=1) == fewest
    assert within(fewest) and not within(fewest - 1)
    assert len(equivalent_layers(full, "auto").layers) == chosen
    one = Atmosphere((Layer(100.0, 1e-13, 5.0, 0.0),))
    assert auto_layers(one) == 1 and equivalent_layers(one, "auto") is one


def test_the_block_takes_auto():
    params = {"atmosphere": "table", "profile_file": MEDIAN}
    block = PointSourceOptics(**params, equivalent_layers="auto")
    block.setup(RunInfo(seed=1))
    block._ensure_imager(FocalPlane(1280, 720, 4.86e-6, 0.4), 550e-9)
    assert len(block._imager.atmosphere.layers) == 3
    for wrong in (0, 33, "all"):
        with pytest.raises(ValueError):
            PointSourceOptics.Params(**params, equivalent_layers=wrong)


@pytest.mark.parametrize("follow", [False, True])
@pytest.mark.parametrize("threads", ["1", "3"])
def test_each_sources_winds_do_not_depend_on_windows_threads_or_resume(tmp_path, monkeypatch, threads, follow):
    # a satellite held on the detector by a mount rising at ~1 deg/s and a star streaking down it
    # (tests/optics/test_optics_mount.py's scene), three windy layers as 2: each source's winds are those of its
    # line of sight's rate (at its first two render times, or at each with follow_sight_rate), the same stamps
    # however the run is cut into windows, on 1 or 3 threads and resumed
    import copy

    from evsda.blocks.ports import PointSources
    from evsda.graph import Window
    monkeypatch.setenv("EVSDA_THREADS", threads)
    focal_plane, cadence_ns = FocalPlane(640, 480, 4.86e-6, 1.2), 1_000_000
    turn = 3 * focal_plane.pixel_scale_rad / (cadence_ns * 1e-9)
    (tmp_path / "windy.csv").write_text("altitude_m,cn2_dh_m13,wind_speed_m_s,wind_direction_deg\n"
                                        "200,2e-13,6,0\n1500,5e-14,12,40\n9000,8e-14,30,100\n")
    params = dict(aperture_m=0.25, obscuration=0.2, psf_path="pupil_fft", seed=5, atmosphere="table",
                  profile_file=str(tmp_path / "windy.csv"), equivalent_layers=2, source_intervals=False,
                  follow_sight_rate=follow)

    def tracked(window):
        t_ns = window.sample_times_ns(cadence_ns)
        n_t, rise = len(t_ns), turn * t_ns * 1e-9
        star_y = 239.5 - np.tan(-40.5 * focal_plane.pixel_scale_rad - rise) / focal_plane.pixel_scale_rad
        return PointSources(focal_plane, 550e-9, t_ns, np.array(["25544", "HIP 1"]), np.array([0, 1], np.int8),
                            np.stack([np.full(n_t, 320.0), np.full(n_t, 319.5)], axis=1),
                            np.stack([np.full(n_t, 240.0), star_y], axis=1), np.full((n_t, 2), 3e5),
                            np.full((n_t, 2), 3.0), np.array([[8e5, np.inf]] * n_t), np.deg2rad(45.0) - rise,
                            np.full(n_t, 0.3), np.zeros(n_t))

    def run(windows, block=None):
        block = block or PointSourceOptics(**params)
        block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
        return block, np.concatenate([block.step(w, sources=[tracked(w)])["irradiance"].stamp_flux
                                      for w in windows])

    def windows_of(length_s):
        return [Window.from_seconds(i * length_s, (i + 1) * length_s, index=i) for i in range(round(0.02 / length_s))]

    block, whole = run(windows_of(0.02))
    imager = block._imager
    flows = {key.split(":")[-1]: flow for key, flow in imager.flows.items()}
    assert len(imager.drifts if follow else flows) == 2 and not (imager.flows if follow else imager.drifts)
    # each source's winds are footprint_winds at its line of sight's rate over its first two render times: the
    # satellite's ~sec z omega (sec 45 deg x 12 mrad/s), the star's ~0 (fixed in azimuth and elevation)
    sources = tracked(windows_of(0.02)[0])
    for column, name in enumerate(("25544", "HIP 1") if not follow else ()):
        start, first_sight, winds = flows[name]
        sight = imager.sight(sources.x_px[:2, column], sources.y_px[:2, column], sources.zenith_angle_rad[:2],
                             sources.boresight_azimuth_rad[:2], sources.field_rotation_rad[:2])
        rate = (sight[1] - sight[0]) / 1e-3
        assert start == 0.0 and np.hypot(*rate) == pytest.approx(0.0172 if column == 0 else 0.0, abs=1e-3)
        np.testing.assert_allclose(winds, footprint_winds(imager.atmosphere, rate), rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(whole, run(windows_of(0.004))[1])
    windows = windows_of(0.01)
    first, _ = run(windows[:1])
    state = copy.deepcopy(first.get_state())
    assert len(state["optics_state"]["drifts" if follow else "flows"]) == 2
    resumed = PointSourceOptics(**params)
    resumed.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    resumed.set_state(state)
    tail = resumed.step(windows[1], sources=[tracked(windows[1])])["irradiance"].stamp_flux
    np.testing.assert_array_equal(tail, whole[10:])


def test_a_source_with_its_own_winds_holds_its_screens_for_its_window_over_its_speeds():
    # hold_of: min over layers of n delta / |w| for a source with its own winds, at most MAX_HOLD_S; the common
    # hold_ns otherwise (every layer: the profile's winds)
    from types import SimpleNamespace

    from evsda.blocks.optics.imaging import MAX_HOLD_S, Imager
    imager = Imager.__new__(Imager)
    imager.atmosphere = equivalent_layers(median_seeing(), 3)
    imager.geometry = SimpleNamespace(layer_n=(64, 80, 96), layer_delta_m=(0.02, 0.03, 0.05))
    imager._hold, imager.flows, imager._holds, imager.drifts = (imager.geometry, 123), {}, {}, {}
    assert imager.hold_of("star") == 123
    winds = np.array([[3.0, 4.0], [0.0, -12.0], [0.0, 0.0]])              # 5, 12 and 0 m/s
    imager.flows["25544"] = (0.0, np.zeros(2), winds)
    assert imager.hold_of("25544") == round(min(64 * 0.02 / 5.0, 80 * 0.03 / 12.0, MAX_HOLD_S) * 1e9)
    imager.flows["calm"] = (0.0, np.zeros(2), np.zeros((3, 2)))
    assert imager.hold_of("calm") == round(MAX_HOLD_S * 1e9)
    # following its line of sight's rate: its winds at its last render time; none yet after its first
    imager.drifts["followed"] = (0.5, np.zeros(2), np.zeros((3, 2)), winds[::-1].copy())
    assert imager.hold_of("followed") == round(min(96 * 0.05 / 5.0, 80 * 0.03 / 12.0, MAX_HOLD_S) * 1e9)
    imager.drifts["new"] = (0.5, np.zeros(2), np.zeros((3, 2)), None)
    assert imager.hold_of("new") == 123


def footprint_winds_in_numpy(atmosphere: Atmosphere, sight_rate) -> np.ndarray:
    """The reference of :func:`.group_winds`: the groups' winds as footprint_winds wrote them in numpy before
    (seventeenth session): ``|u|^(5/3)`` as numpy's power of 5/3 and the sums as numpy adds them."""
    from evsda.blocks.optics.equivalent_layers import moment
    rate = np.asarray(sight_rate, dtype=float)
    winds = np.empty((len(atmosphere.layers), 2))
    for g, (layer, members) in enumerate(zip(atmosphere.layers, atmosphere.members)):
        cn2 = np.array([member.cn2_dh for member in members])
        moving = np.array([member.altitude_m * rate - member.wind_m_s for member in members])    # u_i (M, 2)
        speed = np.hypot(moving[:, 0], moving[:, 1])
        pull = np.sum((cn2 * speed ** (2 / 3))[:, None] * moving, axis=0)     # sum J |u|^(5/3) u / |u|
        toward = pull if np.any(pull) else moving[np.argmax(cn2)]
        norm = np.hypot(toward[0], toward[1])
        footprint = moment(cn2, speed) * toward / norm if norm > 0 else np.zeros(2)
        winds[g] = layer.altitude_m * rate - footprint
    return winds


def follow_drift_in_order(atmosphere: Atmosphere, t_s, sight, last_t, last_sight, winds):
    """The reference of :func:`.follow_drift`: its loop as the eighteenth session wrote it (each group's ``J`` sum
    and strongest member found again at every render time), in plain Python floats with libm's ``hypot`` and
    ``pow``; the drifts (G, F, 2) [m] from zero, the last render time and the winds of the last advance."""
    drift, winds, last_sight, out = np.zeros((len(atmosphere.layers), 2)), winds.copy(), list(last_sight), []
    for t, (x, y) in zip(t_s.tolist(), sight.tolist()):
        dt = t - last_t
        if not dt > 0:
            out.append(drift + winds * dt)
            continue
        rx, ry = (x - last_sight[0]) / dt, (y - last_sight[1]) / dt
        rx, ry = rx if np.isfinite(rx) else 0.0, ry if np.isfinite(ry) else 0.0
        for g, (layer, members) in enumerate(zip(atmosphere.layers, atmosphere.members)):
            cn2 = [member.cn2_dh for member in members]
            total, strongest = 0.0, 0
            for m, j in enumerate(cn2):
                total += j
                strongest = m if j > cn2[strongest] else strongest
            weights, moment, pull_x, pull_y = 0.0, 0.0, 0.0, 0.0
            for j, member in zip(cn2, members):
                ux, uy = member.altitude_m * rx - float(member.wind_m_s[0]), member.altitude_m * ry - float(
                    member.wind_m_s[1])
                speed = float(np.hypot(ux, uy))
                two_thirds = speed ** (2 / 3)
                weight = j if total > 0 else 1.0
                weights += weight
                moment += weight * (speed * two_thirds)
                pull_x += j * two_thirds * ux
                pull_y += j * two_thirds * uy
            if pull_x == 0.0 and pull_y == 0.0:
                pull_x = members[strongest].altitude_m * rx - float(members[strongest].wind_m_s[0])
                pull_y = members[strongest].altitude_m * ry - float(members[strongest].wind_m_s[1])
            norm = float(np.hypot(pull_x, pull_y))
            speed = (moment / weights) ** (3 / 5)
            fx, fy = (speed * pull_x / norm, speed * pull_y / norm) if norm > 0 else (0.0, 0.0)
            winds[g] = layer.altitude_m * rx - fx, layer.altitude_m * ry - fy
        drift = drift + winds * dt
        out.append(drift)
        last_t, last_sight = t, [x, y]
    return np.stack(out, axis=1), last_t, winds


def calm_groups() -> Atmosphere:
    """Five layers grouped as 2 and 3 (by hand: the best split would set the calm layers apart), the upper group
    without turbulence, so its 5/3-moments are unweighted."""
    from evsda.blocks.optics.equivalent_layers import equivalent_layer
    members = ((Layer(100.0, 2e-13, 5.0, 0.3), Layer(900.0, 5e-14, 9.0, 1.1)),
               (Layer(4000.0, 0.0, 14.0, 2.0), Layer(8000.0, 0.0, 30.0, -0.4), Layer(15000.0, 0.0, 8.0, 0.9)))
    return Atmosphere(tuple(equivalent_layer(group) for group in members), members=members)


def test_group_weights_are_fixed_per_group():
    # each member's weight is its J (1 where its group's J sum to zero: the unweighted moment), the sum of a group's
    # weights added in order, and its strongest member the first of its largest J
    from evsda.blocks.optics.equivalent_layers import member_columns
    fewer = calm_groups()
    first, cn2, weight, weights, strongest = (member_columns(fewer)[k] for k in (1, 3, 5, 6, 7))
    assert first.tolist() == [0, 2, 5] and strongest.tolist() == [0, 2]
    np.testing.assert_array_equal(weight, [2e-13, 5e-14, 1.0, 1.0, 1.0])
    assert weights.tolist() == [0.0 + 2e-13 + 5e-14, 3.0]
    tied = equivalent_layers(Atmosphere((Layer(10.0, 1e-14, 3.0, 0.0), Layer(20.0, 4e-14, 3.0, 0.0),
                                         Layer(30.0, 4e-14, 3.0, 0.0), Layer(9000.0, 1e-14, 3.0, 0.0))), 2)
    assert member_columns(tied)[7].tolist() == [1, 3]


@pytest.mark.parametrize("profile", [MEDIAN, "library:atmospheres/las_campanas.csv",
                                     "library:atmospheres/mauna_kea.csv", None])
@pytest.mark.parametrize("n_layers", [1, 2, 3, 4])
def test_footprint_winds_are_the_numpy_formulas_to_rounding(profile, n_layers):
    # group_winds against footprint_winds' former numpy: the same winds but for rounding (|u| |u|^(2/3) in place of
    # numpy's |u|^(5/3), which on AVX-512 is SVML's power, and the sums' order): within 1e-13 of the speeds at play
    fewer = calm_groups() if profile is None else equivalent_layers(Atmosphere.from_table(resolve(profile)),
                                                                   n_layers)
    full = Atmosphere(tuple(member for group in fewer.members for member in group))
    cn2, altitude, wind = columns(full)
    rest = wind[-1] / altitude[-1]                               # the top member's footprint at rest in its air
    rng = np.random.default_rng(n_layers)
    for rate in (PASS_SIGHT_RATE, np.zeros(2), np.array([0.0, 1.7e-4]), PASS_SIGHT_RATE * 1e4, rest,
                 *rng.normal(0.0, 0.01, (20, 2))):
        scale = np.max(altitude) * np.hypot(*rate) + np.max(np.hypot(*wind.T))               # [m/s]
        np.testing.assert_allclose(footprint_winds(fewer, rate), footprint_winds_in_numpy(fewer, rate), rtol=0,
                                   atol=1e-13 * scale)


@pytest.mark.parametrize("profile", [MEDIAN, "library:atmospheres/mauna_kea.csv", None])
def test_follow_drift_is_its_former_loop_bit_for_bit(profile):
    # the per-group sums hoisted out of the render times change no bit of the drifts or the winds, over a pass
    # whose s' grows tenfold, with a render time repeated (extrapolated, advancing nothing) and one going back
    fewer = calm_groups() if profile is None else equivalent_layers(Atmosphere.from_table(resolve(profile)), 3)
    t = np.arange(0.0, 20.0, 0.01) + 3.0
    sight = long_pass_sight(t)
    t[[700, 1400]], sight[[700, 1400]] = t[[699, 1300]], sight[[699, 1300]]
    imager = follower(fewer)
    drift = imager.source_flow("25544", t, sight)[0]
    expected, last_t, winds = follow_drift_in_order(fewer, t, sight, t[0], sight[0], np.zeros((len(fewer.layers),
                                                                                                2)))
    np.testing.assert_array_equal(drift, expected)
    np.testing.assert_array_equal(imager.own_winds("25544"), winds)
    assert imager.drifts["25544"][0] == last_t
    # and follow_drift's winds are footprint_winds' for the secant rate, bit for bit: one function for both
    rate = (sight[-1] - sight[-2]) / (t[-1] - t[-2])
    np.testing.assert_array_equal(imager.own_winds("25544"), footprint_winds(fewer, rate))
