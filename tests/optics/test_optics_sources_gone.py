"""The optics keep the screens of the sources in view only: a source that leaves drops them, one that comes back
gets a new independent draw, whatever the windows or a resume."""

import copy

import numpy as np

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.ports import FocalPlane, PointSources
from evsda.graph import RunInfo, Window

FOCAL_PLANE = FocalPlane(640, 480, 4.86e-6, 1.2)        # 4.05 urad pixels
WAVELENGTH = 550e-9
CADENCE_NS = 1_000_000
PARAMS = dict(aperture_m=0.25, obscuration=0.2, psf_path="pupil_fft", seed=3)


def sources(window, in_view):
    """Stars at fixed positions, each on the detector while ``in_view(i, t_s)`` (NaN position otherwise)."""
    t_ns = window.sample_times_ns(CADENCE_NS)
    t = t_ns * 1e-9
    n = 8
    shown = np.array([[in_view(i, ti) for i in range(n)] for ti in t]).reshape(len(t), n)
    x = np.where(shown, 100.0 + 50.0 * np.arange(n), np.nan)
    y = np.where(shown, 240.0, np.nan)
    return PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array([f"HIP {i}" for i in range(n)]),
                        np.ones(n, np.int8), x, y, np.full((len(t), n), 3e4), np.full((len(t), n), 6.0),
                        np.full((len(t), n), np.inf), np.full(len(t), np.deg2rad(30.0)))


def windows_of(length_s, total_s):
    n = int(round(total_s / length_s))
    return [Window.from_seconds(i * length_s, (i + 1) * length_s, index=i) for i in range(n)]


def run(block, windows, in_view, after=None):
    block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    out = []
    for w in windows:
        out.append(block.step(w, sources=[sources(w, in_view)])["irradiance"])
        if after:
            after(block)
    return out


def flux(outputs):
    """Each source's stamps (render time, source, y, x) over the run, by source id order of the input."""
    return np.concatenate([o.stamp_flux.sum(axis=1) for o in outputs])


def screen_bytes(block) -> int:
    """Bytes of the arrays in the optics' checkpoint state."""
    def walk(v):
        if isinstance(v, np.ndarray):
            return v.nbytes
        if isinstance(v, dict):
            return sum(walk(x) for x in v.values())
        if isinstance(v, (list, tuple)):
            return sum(walk(x) for x in v)
        return 0
    return walk(block.get_state())


def test_state_held_does_not_grow_with_the_sources_gone():
    # star i in view for 10 ms from 10 i ms, two at a time: eight come and go in 80 ms
    held, sizes = [], []

    def after(block):
        held.append(len(block._imager.holding()))
        sizes.append(screen_bytes(block))

    run(PointSourceOptics(**PARAMS), windows_of(0.01, 0.08), lambda i, t: 0.01 * i <= t < 0.01 * i + 0.015, after)
    assert max(held) <= 2
    assert sizes[0] > 0 and max(sizes) <= 2 * sizes[0]          # screens of the two in view, not of all eight
    # every source that left with screens counts one generation; the record is one integer per source
    block = PointSourceOptics(**PARAMS)
    run(block, windows_of(0.01, 0.08), lambda i, t: 0.01 * i <= t < 0.01 * i + 0.015)
    assert set(block._imager.generations.values()) == {1} and len(block._imager.generations) >= 6


def come_back(i, t):
    """Star 0 in view for 10 ms, away 10 ms, back; star 1 (a control) always in view."""
    return i == 1 or (i == 0 and not 0.01 <= t < 0.02)


def arrive_late(i, t):
    """Star 0 first seen at 20 ms; star 1 always in view."""
    return i == 1 or (i == 0 and t >= 0.02)


def test_a_source_that_comes_back_gets_a_fresh_draw():
    block = PointSourceOptics(**PARAMS)
    back = flux(run(block, windows_of(0.01, 0.03), come_back))
    late = flux(run(PointSourceOptics(**PARAMS), windows_of(0.01, 0.03), arrive_late))
    assert block._imager.generations == {"0:HIP 0": 1}
    # star 1 saw the same screens in both runs; star 0's screens after its return are a new draw, not the
    # screens a first arrival at that time gets from the source's first seed stream
    later = slice(20, 30)
    assert np.all(back[later].sum(axis=(1, 2)) > 0) and np.all(late[later].sum(axis=(1, 2)) > 0)
    single = [o.stamp_flux for o in run(PointSourceOptics(**PARAMS), windows_of(0.01, 0.03), come_back)]
    twin = [o.stamp_flux for o in run(PointSourceOptics(**PARAMS), windows_of(0.01, 0.03), arrive_late)]
    np.testing.assert_array_equal(single[2][:, 1], twin[2][:, 1])       # slot 1: star 1 in both
    assert not np.array_equal(single[2][:, 0], twin[2][:, 0])           # star 0: another draw


def test_returns_do_not_depend_on_windows_or_resume():
    whole = run(PointSourceOptics(**PARAMS), windows_of(0.03, 0.03), come_back)[0]
    cut = run(PointSourceOptics(**PARAMS), windows_of(0.005, 0.03), come_back)
    np.testing.assert_array_equal(whole.stamp_flux[20:], np.concatenate([o.stamp_flux for o in cut[4:]]))
    np.testing.assert_array_equal(whole.stamp_flux[:10], np.concatenate([o.stamp_flux for o in cut[:2]]))
    first = PointSourceOptics(**PARAMS)
    windows = windows_of(0.01, 0.03)
    run(first, windows[:2], come_back)
    state = copy.deepcopy(first.get_state())
    resumed = PointSourceOptics(**PARAMS)
    resumed.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    resumed.set_state(state)
    tail = resumed.step(windows[2], sources=[sources(windows[2], come_back)])["irradiance"]
    np.testing.assert_array_equal(tail.stamp_flux, whole.stamp_flux[20:])
