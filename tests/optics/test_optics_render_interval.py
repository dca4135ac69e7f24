"""A render interval per source (``source_intervals``, blocks/optics/render_interval.py): Roddier's coherence time
against hand-computed values, the intervals the block gives a fast-tracked satellite (the base rate) and a still star
on a slow footprint (longer), the stamp held between render times, and results independent of windows and resume."""

import copy

import numpy as np
import pytest

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics.atmosphere import Atmosphere
from evsda.blocks.optics.render_interval import RenderInterval, coherence_time_s, interval_multiples, longest_interval_s
from evsda.blocks.ports import FocalPlane, PointSources
from evsda.graph import RunInfo, Window

FOCAL_PLANE = FocalPlane(640, 480, 4.86e-6, 1.2)        # 4.05 urad pixels
WAVELENGTH = 550e-9
CADENCE_NS = 1_000_000
ZENITH = np.deg2rad(30.0)
# one layer at 1 km, 1e-13 m^1/3 of Cn^2 dh, 10 m/s: r0 = (0.423 k^2 sec z Cn^2 dh)^(-3/5) = 0.32912 m at 550 nm and
# 30 deg (k = 1.14240e7 m^-1: 0.423 k^2 sec z Cn^2 dh = 6.3746 m^-5/3), by hand
ONE_LAYER = "altitude_m,cn2_dh_m13,wind_speed_m_s,wind_direction_deg\n1000,1.0e-13,10,0\n"
R0_BY_HAND_M = 0.32910


@pytest.fixture
def params(tmp_path):
    (tmp_path / "one.csv").write_text(ONE_LAYER)
    return dict(aperture_m=0.25, obscuration=0.2, psf_path="pupil_fft", seed=5, atmosphere="table",
                profile_file=str(tmp_path / "one.csv"), source_intervals=True, interval_factor=1.0)


def test_roddier_tau0_by_hand_and_its_definition():
    # two layers, 60 % at 10 m/s and 40 % at 20 m/s: v_bar = (0.6 * 46.4159 + 0.4 * 147.361)^(3/5) = 86.794^0.6
    # = 14.558 m/s; tau0 = 0.31437 * 0.1 / 14.558 = 2.1595 ms (Roddier 1981; 0.31437 = 6.88^(-3/5))
    tau0 = coherence_time_s(0.1, np.array([0.6, 0.4]), np.array([10.0, 20.0]))
    assert tau0 == pytest.approx(2.1595e-3, rel=1e-4)
    # the definition: the phase structure function of the frozen-flow layers, sum 6.88 (v_i t / r0_i)^(5/3) with
    # r0_i^(-5/3) = c_i r0^(-5/3) (Fried 1966), is 1 rad^2 at t = tau0
    r0_i = 0.1 * np.array([0.6, 0.4]) ** (-3 / 5)
    assert np.sum(6.88 * (np.array([10.0, 20.0]) * tau0 / r0_i) ** (5 / 3)) == pytest.approx(1.0, rel=1e-3)
    # one layer: 0.314 r0 / v; no motion: never decorrelates
    assert coherence_time_s(0.2, np.array([1.0]), np.array([5.0])) == pytest.approx(0.31437 * 0.2 / 5, rel=1e-4)
    assert coherence_time_s(0.2, np.array([1.0]), np.array([0.0])) == np.inf


def test_intervals_are_the_longest_power_of_two_within_the_bounds():
    m = interval_multiples(np.array([0.5e-3, 1e-3, 1.99e-3, 2e-3, 7.9e-3, np.inf, np.nan]), CADENCE_NS)
    np.testing.assert_array_equal(m, [1, 1, 1, 2, 4, 2**30, 1])
    # the factor scales tau0 and the pixels' response, never the pixel crossing (a held image jumps <= 1 pixel)
    longest = longest_interval_s(np.array([2e-3, 2e-3, 9e-3]), np.array([np.inf, 3e-3, np.inf]),
                                 np.array([np.inf, np.inf, 1.5e-3]), 2.0)
    np.testing.assert_allclose(longest, [4e-3, 3e-3, 3e-3])


def test_rule_reads_the_optics_own_r0_and_footprint_speeds(tmp_path):
    (tmp_path / "one.csv").write_text(ONE_LAYER)
    atmosphere = Atmosphere.from_table(tmp_path / "one.csv")
    assert atmosphere.r0(WAVELENGTH, ZENITH) == pytest.approx(R0_BY_HAND_M, rel=1e-4)
    rule = RenderInterval(atmosphere, WAVELENGTH, FOCAL_PLANE.pixel_scale_rad, None, 2.0)
    # a star, its line of sight still: the wind alone, tau0 = 0.31437 * 0.32910 / 10 = 10.346 ms
    # a satellite tracked at 0.01 rad/s: L omega + |v| = 1154.7 m * 0.01 + 10 = 21.547 m/s, tau0 = 4.802 ms
    turn_px_s = 0.01 / FOCAL_PLANE.pixel_scale_rad
    tau0 = rule.coherence_s(np.full(2, ZENITH), np.array([0.0, turn_px_s]))
    np.testing.assert_allclose(tau0, [10.346e-3, 4.802e-3], rtol=1e-4)
    # still on the detector, no detector named (no response bound), factor 2: 20.7 and 9.6 ms, intervals of 16 and
    # 8 render times of 1 ms
    seen = np.array([[0.0, 1e5, 10.0, 0.0], [0.0, 1e7, 10.0, turn_px_s]])
    np.testing.assert_array_equal(rule.multiples(CADENCE_NS, seen, np.full(2, ZENITH)), [16, 8])
    # the star streaking at 400 pixel/s crosses a pixel in 2.5 ms: 2; an unknown rate (a run's first sample): 1
    seen = np.array([[400.0, 1e5, 10.0, 0.0], [np.nan, 1e5, 10.0, 0.0]])
    np.testing.assert_array_equal(rule.multiples(CADENCE_NS, seen, np.full(2, ZENITH)), [2, 1])


def sources(window, turn_rad_s):
    """A satellite held at the detector's centre by a mount rising in elevation at ``turn_rad_s`` from 60 deg of
    zenith angle, and a star still on the detector (its line of sight turning with the mount only if it is tracked:
    here the star is a second input seen from a staring mount, the same geometry with the mount still)."""
    t_ns = window.sample_times_ns(CADENCE_NS)
    t = t_ns * 1e-9
    n_t = len(t)
    zenith = ZENITH + np.zeros(n_t)
    tracked = PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array(["25544"]), np.array([0], np.int8),
                           np.full((n_t, 1), 320.0), np.full((n_t, 1), 240.0),
                           np.full((n_t, 1), 3e5) * (1 + 0.5 * np.sin(60 * t))[:, None], np.full((n_t, 1), 3.0),
                           np.full((n_t, 1), 8e5), zenith - turn_rad_s * t, np.full(n_t, 0.3), np.zeros(n_t))
    staring = PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array(["HIP 1"]), np.array([1], np.int8),
                           np.full((n_t, 1), 100.3), np.full((n_t, 1), 80.6), np.full((n_t, 1), 3e5),
                           np.full((n_t, 1), 6.0), np.full((n_t, 1), np.inf), zenith, np.full(n_t, 0.3), np.zeros(n_t))
    return [tracked, staring]


def windows_of(length_s, total_s):
    n = int(round(total_s / length_s))
    return [Window.from_seconds(i * length_s, (i + 1) * length_s, index=i) for i in range(n)]


def run(params, windows, turn_rad_s=0.05, block=None):
    block = block or PointSourceOptics(**params)
    block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    out = [block.step(w, sources=sources(w, turn_rad_s))["irradiance"] for w in windows]
    return block, np.concatenate([o.stamp_flux for o in out]), np.concatenate([o.stamp_origin for o in out])


def test_fast_tracked_satellite_at_the_base_rate_slow_star_held(params):
    # tracked at 0.05 rad/s: L omega + |v| = 67.7 m/s, tau0 = 1.53 ms: every render time; the star still on a
    # staring mount: tau0 = 10.35 ms, rendered every 8th render time and held between
    block, stamps, origin = run(params, windows_of(0.02, 0.04))
    _, every, _ = run({**params, "source_intervals": False}, windows_of(0.02, 0.04))
    satellite, star = 0, 1
    assert block._imager.frames_rendered["pupil_fft"] == 40 + 5                # 40 + 40 / 8
    np.testing.assert_array_equal(stamps[:, satellite], every[:, satellite])   # bit for bit the base rate
    # the star's rendered frames (multiples of 8 ms) are the base rate's: its screens walk the same draws
    rendered = np.arange(0, 40, 8)
    np.testing.assert_array_equal(stamps[rendered, star], every[rendered, star])
    # between them the last rendered stamp is held, at its placement (the flux is constant here)
    for k in range(40):
        np.testing.assert_array_equal(stamps[k, star], every[k - k % 8, star])
        np.testing.assert_array_equal(origin[k, star], origin[k - k % 8, star])
    assert not np.array_equal(every[1, star], every[0, star])                  # the base rate's stamp did change


def test_a_held_stamp_takes_the_flux_of_each_render_time(params):
    # the satellite tracked slowly (tau0 = 0.31437 * 0.3291 / (1154.7 * 0.002 + 10) = 8.4 ms): held over 8 render
    # times while its flux follows the input at every one
    block, stamps, _ = run(params, windows_of(0.016, 0.016), turn_rad_s=0.002)
    assert block._imager.frames_rendered["pupil_fft"] == 2 + 2
    t = np.arange(16) * 1e-3
    held = stamps[:8, 0]                                                       # the stamp of render time 0
    input_flux = 1 + 0.5 * np.sin(60 * t[:8])
    np.testing.assert_allclose(held, held[0] * (input_flux / input_flux[0])[:, None, None], rtol=1e-12)
    assert input_flux.max() / input_flux.min() > 1.15


def test_held_stamps_do_not_depend_on_windows_or_resume(params):
    whole = run(params, windows_of(0.03, 0.03), turn_rad_s=0.002)[1]
    for length in (0.003, 0.007):
        stitched = run(params, windows_of(length, 0.03 + length / 2)[:int(round(0.03 / length))], turn_rad_s=0.002)[1]
        np.testing.assert_array_equal(whole[:len(stitched)], stitched)
    windows = [Window.from_seconds(0.0, 0.013, index=0), Window.from_seconds(0.013, 0.03, index=1)]   # mid-hold
    first, _, _ = run(params, windows[:1], turn_rad_s=0.002)
    state = copy.deepcopy(first.get_state())
    assert set(state["held_stamps"]) == {"0:25544", "1:HIP 1"}
    resumed = PointSourceOptics(**params)
    resumed.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    resumed.set_state(state)
    tail = resumed.step(windows[1], sources=sources(windows[1], 0.002))["irradiance"].stamp_flux
    np.testing.assert_array_equal(tail, whole[13:])


def test_held_stamps_rendered_together_are_those_rendered_alone(params, monkeypatch):
    # the satellite tracked slowly and the star, both held over the same 8 render times: rendered together (one walk
    # of both sources' screens and one stamps call for their fresh frames, PointSourceOptics.step's groups) against
    # each alone (Imager.renders_together off), over windows that start and end mid-hold, bit for bit
    from evsda.blocks.optics.imaging import Imager

    windows = [Window.from_seconds(0.0, 0.013, index=0), Window.from_seconds(0.013, 0.035, index=1)]
    calls = []
    render_many = Imager.render_many
    monkeypatch.setattr(Imager, "render_many", lambda self, sources, t_s, *rest: calls.append(
        (len(sources), len(t_s))) or render_many(self, sources, t_s, *rest))
    block, together, origin = run(params, windows, turn_rad_s=0.002)
    assert calls == [(2, 2), (2, 3)]                       # render times 0, 8 | 16, 24, 32 of 13 and 22
    monkeypatch.setattr(Imager, "renders_together", lambda self, path: False)
    alone_block, alone, alone_origin = run(params, windows, turn_rad_s=0.002)
    assert calls == [(2, 2), (2, 3)]
    np.testing.assert_array_equal(together, alone)
    np.testing.assert_array_equal(origin, alone_origin)
    assert block._imager.frames_rendered == alone_block._imager.frames_rendered
    assert block.held_stamps.keys() == alone_block.held_stamps.keys()
    for key, record in block.held_stamps.items():
        assert record["path"] == alone_block.held_stamps[key]["path"]
        assert record["t_ns"] == alone_block.held_stamps[key]["t_ns"]
        np.testing.assert_array_equal(record["stamp"], alone_block.held_stamps[key]["stamp"])
