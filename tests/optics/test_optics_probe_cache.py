"""`auto`'s probe results kept across runs (paths.PathChooser._remembered, evsda.graph.result_cache): a warm cache
gives what the probes compute, bit for bit, without running them; a change of any input the probes read misses.

The suite runs with the cache off (tests/conftest.py); these tests switch it on in the session's own folder."""

import dataclasses
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics import paths
from evsda.blocks.optics.atmosphere import Atmosphere
from evsda.blocks.optics.imaging import Imager
from evsda.blocks.optics.paths import PathChooser
from evsda.blocks.optics.pixel_view import PixelView, load_pixel_params
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.ports import FocalPlane
from evsda.graph.result_cache import code_digest
from evsda.library import resolve

FOCAL_PLANE = FocalPlane(640, 480, 4.86e-6, 1.2)        # 4.05 urad pixels
WAVELENGTH = 550e-9
#: test_optics_close_calls.py's conditions: a 10 cm aperture 20 deg from the zenith, LEO at 500 km, HV5/7-like
#: layers scaled to r0 = 10 cm (the pupil path's error ~0.09: a close call on the reference probes)
ATMOSPHERE = Atmosphere.hufnagel_valley(2).scaled_to_r0(0.1)
ZENITH_RAD, RANGE_M = np.deg2rad(20), 5e5
#: what the pixels see: a tracked satellite (still on the detector), 1e6 photon/s, a dark sky
SEEN = (0.0, 1e6, 10.0)


@pytest.fixture
def cache_on(monkeypatch, tmp_path):
    """The cache switched on in a folder of this test's own."""
    monkeypatch.setenv("EVSDA_CACHE", "on")
    monkeypatch.setenv("EVSDA_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def pixels(focal_plane=FOCAL_PLANE):
    return PixelView.of(load_pixel_params(resolve("library:sensors/prophesee_gen4.yaml"), "optics"),
                        focal_plane.pixel_area_m2, WAVELENGTH)


def make_imager(telescope=Telescope(0.1, 0.0), focal_plane=FOCAL_PLANE, wavelength=WAVELENGTH, atmosphere=ATMOSPHERE,
                seed=(3,), detector=True, **params):
    imager = Imager(telescope, focal_plane, wavelength, atmosphere, PointSourceOptics.Params(**params), seed=seed,
                    pixels=pixels(focal_plane) if detector else None)
    imager.ensure_geometry(ZENITH_RAD)
    return imager


def decisions(imager):
    """Everything the probes decide at the test's conditions: the bin's choice (with the averaging fit), the
    pupil path's error record and the instantaneous estimates."""
    chooser = imager.chooser
    choice = chooser.choose(ZENITH_RAD, RANGE_M, "sat", SEEN)
    return choice, chooser.pupil_estimate(ZENITH_RAD, RANGE_M), chooser._probe(*paths.representative_conditions(
        chooser.key(ZENITH_RAD, RANGE_M)))


def forbid_probes(monkeypatch):
    """Make the probes themselves fail: whatever is decided then comes from the cache."""
    def fail(*args, **kwargs):
        raise AssertionError("a probe ran on a warm cache")
    monkeypatch.setattr(PathChooser, "_reference_distances", fail)
    monkeypatch.setattr(PathChooser, "_analytic_distances", fail)


def test_a_warm_cache_gives_what_the_probes_compute_bit_for_bit(cache_on, monkeypatch):
    cold = decisions(make_imager())
    entries = sorted(p.name for p in cache_on.rglob("*.json"))
    assert len(entries) == 2                                            # the reference and the analytic probes
    assert cold[0].path == "pupil_fft" and "the pixels average" in cold[0].reason
    assert cold[1].frames >= paths.REFERENCE_PROBE_FRAMES[0] and set(cold[2][1]) == set(paths.ANALYTIC_PATHS)
    with monkeypatch.context() as m:
        forbid_probes(m)
        warm = decisions(make_imager())
    assert warm == cold                                                 # floats, reasons, frame counts: equal
    assert repr(warm) == repr(cold)
    assert sorted(p.name for p in cache_on.rglob("*.json")) == entries  # nothing new written
    monkeypatch.setenv("EVSDA_CACHE", "off")
    shutil.rmtree(cache_on)
    assert decisions(make_imager()) == cold                             # computed again, off
    assert not cache_on.exists()                                        # and nothing written


#: one change of each input the probes read (key of PathChooser._remembered), as make_imager's arguments
CHANGES = {
    "aperture": {"telescope": Telescope(0.11, 0.0)},
    "obscuration": {"telescope": Telescope(0.1, 0.2)},
    "throughput": {"telescope": Telescope(0.1, 0.0, 0.9)},
    "wavelength": {"wavelength": 600e-9},
    "turbulence strength": {"atmosphere": Atmosphere.hufnagel_valley(2).scaled_to_r0(0.12)},
    "a layer's altitude": {"atmosphere": dataclasses.replace(ATMOSPHERE, layers=(
        dataclasses.replace(ATMOSPHERE.layers[0], altitude_m=ATMOSPHERE.layers[0].altitude_m + 1.0),
        *ATMOSPHERE.layers[1:]))},
    "outer scale": {"atmosphere": dataclasses.replace(ATMOSPHERE, L0=30.0)},
    "no atmosphere": {"atmosphere": None},
    "pixel scale": {"focal_plane": FocalPlane(640, 480, 5e-6, 1.2)},
    "seed": {"seed": (4,)},
    "seed words": {"seed": (3, 0)},
    "tolerance": {"tolerance": 0.11},
    "focus": {"focus": "infinity"},
    "pupil grid": {"pupil_samples": 64},
    "stamp": {"stamp_size_px": 9},
    "reference grid": {"grid_size": 512},
    "no detector": {"detector": False},
}


def remembered(imager, probe="reference", conditions=None):
    """Whether the probe's result came from the cache (its compute was not called)."""
    called = []
    imager.chooser._remembered(probe, conditions or {"zenith_rad": ZENITH_RAD, "range_m": RANGE_M},
                               lambda: called.append(1) or 0.5, lambda v: v, float)
    return not called


def test_changing_any_one_input_misses(cache_on, monkeypatch):
    base = make_imager()
    assert not remembered(base) and remembered(make_imager())
    for name, change in CHANGES.items():
        imager = make_imager(**change)
        assert not remembered(imager), name
        assert remembered(imager), name
    assert not remembered(base, "analytic")                                             # another probe
    assert not remembered(base, conditions={"zenith_rad": ZENITH_RAD + 1e-9, "range_m": RANGE_M})
    assert not remembered(base, conditions={"zenith_rad": ZENITH_RAD, "range_m": RANGE_M * 2})
    with monkeypatch.context() as m:
        m.setattr(paths, "REFERENCE_PROBE_FRAMES", (4, 26))                              # the probes' frames
        assert not remembered(base)
    assert remembered(base)


def test_a_change_of_the_probes_code_misses(cache_on, monkeypatch, tmp_path):
    base = make_imager()
    assert not remembered(base) and remembered(base)
    code = tmp_path / "optics"
    shutil.copytree(Path(paths.__file__).parent, code, ignore=shutil.ignore_patterns("__pycache__"))
    cache = paths.ResultCache(paths.PROBE_CACHE.name, [code], paths.PROBE_CACHE.libraries)
    monkeypatch.setattr(paths, "PROBE_CACHE", cache)
    assert remembered(base)                                             # the same source: the same entries
    with (code / "reference_path.py").open("a") as file:
        file.write("\n# a change\n")
    code_digest.cache_clear()                                           # read once a process otherwise
    cache = paths.ResultCache(paths.PROBE_CACHE.name, [code], paths.PROBE_CACHE.libraries)
    monkeypatch.setattr(paths, "PROBE_CACHE", cache)
    assert not remembered(base)


def test_inputs_left_out_of_the_key_do_not_change_the_probes(monkeypatch):
    # what the key leaves out must not move a probe's result: the screens' method and update, their modes and
    # revisits, the render rate, the block's label, the threads, which detector (only whether there is one;
    # the choice itself reads its pixels, outside the probes). The cache is off here: both are computed
    base = decisions(make_imager())
    monkeypatch.setenv("EVSDA_THREADS", "1")
    davis = PixelView.of(load_pixel_params(resolve("library:sensors/davis346.yaml"), "optics"),
                         FOCAL_PLANE.pixel_area_m2, WAVELENGTH)
    imager = Imager(Telescope(0.1, 0.0), FOCAL_PLANE, WAVELENGTH, ATMOSPHERE,
                    PointSourceOptics.Params(screen_method="zernike", screen_update="regenerate", n_zernike_modes=20,
                                             screen_revisit_s=0.01, render_rate_hz=500.0),
                    seed=(3,), pixels=davis, label="other")
    imager.ensure_geometry(ZENITH_RAD)
    other = decisions(imager)
    assert other[1:] == base[1:]                                        # the probes' results
    assert other[0].estimates["pupil_fft"] == base[0].estimates["pupil_fft"]


def test_a_run_records_the_same_bytes_on_a_cold_and_a_warm_cache(cache_on, monkeypatch, tmp_path):
    # the main job's short version (tests/test_examples_identical.py) at tolerance 0.5 (cheaper probes, the same
    # paths); the warm run takes every probe from the disk
    sys.path.insert(0, str(Path(__file__).parents[1]))
    try:
        from test_examples_identical import SHORT, run_example
    finally:
        sys.path.pop(0)
    monkeypatch.setitem(SHORT, "iss_pass.yaml", {**SHORT["iss_pass.yaml"], "telescope/optics.tolerance": 0.5})
    _, cold = run_example("iss_pass.yaml", tmp_path / "cold.zarr")
    entries = sorted(p.name for p in cache_on.rglob("*.json"))
    assert entries
    forbid_probes(monkeypatch)
    _, warm = run_example("iss_pass.yaml", tmp_path / "warm.zarr")
    assert warm == cold
    assert sorted(p.name for p in cache_on.rglob("*.json")) == entries
    assert os.environ["EVSDA_CACHE"] == "on"
