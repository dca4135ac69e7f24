"""The optics' ``share_far_probes`` (paths.PathChooser._shares_far, on by default): a finite-range pupil-error bin
whose propagation is the far source's within 5 % (Rytov variance, scintillation term; its defocus small) takes the
far bin's reference probes; it changes no decision on the tracked pass's first window nor on the close call of these
tests' conditions; off (the reference), each range bin has its own probes; the two never share cached probes."""

import functools
from pathlib import Path

import numpy as np
import pytest

from evsda.blocks.optics import paths
from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.paths import PathChooser
from evsda.blocks.optics.telescope import Telescope
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

from .test_optics_probe_ahead import WINDOW
from .test_optics_probe_cache import RANGE_M, SEEN, ZENITH_RAD, make_imager


def window_choices(imager):
    """The window's choices (one source at LEO range, one far), the reference probes made (their pupil-error
    bins) and the pupil-path estimates of both sources."""
    made = []
    distances = PathChooser._reference_distances

    def counted(self, key, *args):
        made.append(key)
        return distances(self, key, *args)
    chooser = imager.chooser
    with pytest.MonkeyPatch.context() as m:
        m.setattr(PathChooser, "_reference_distances", counted)
        choices = [chooser.choose(z, r, "s", SEEN) for z, r in ((ZENITH_RAD, RANGE_M), (ZENITH_RAD, np.inf))]
    return choices, made, [chooser.pupil_estimate(ZENITH_RAD, r) for r in (RANGE_M, np.inf)]


def test_off_each_range_bin_has_its_own_probes():
    choices, made, estimates = window_choices(make_imager(share_far_probes=False))
    assert len(made) == 2 and made[0][1] >= 0 and made[1][1] == -1
    assert estimates[0] is not estimates[1]


def test_on_a_leo_bin_takes_the_far_bins_probes_and_the_same_paths():
    off = window_choices(make_imager(share_far_probes=False))
    imager = make_imager(share_far_probes=True)
    choices, made, estimates = window_choices(imager)
    assert [key[1] for key in made] == [-1]                     # one reference probe: the far bin's
    assert estimates[0] is estimates[1] == off[2][1]            # the far bin's estimate, as off
    assert [c.path for c in choices] == [c.path for c in off[0]]
    assert choices[1] == off[0][1]                               # the far source's choice: the same in every number
    # the LEO window's choices made ahead (the probes' schedule) give the same: one reference bin
    ahead = make_imager()
    ahead.chooser.probe_ahead(*WINDOW)
    assert sum(name == "reference" for name, _ in ahead.chooser._ahead) == 1


def test_the_spherical_waves_rytov_variance_against_the_plane_waves():
    layers = make_imager().atmosphere.layers
    assert paths.spherical_wave_ratio(layers, ZENITH_RAD, 1e12) == pytest.approx(1.0, abs=1e-8)
    # one layer: ((1 - z/R))^(5/6) exactly; a layer beyond the source: 0
    one = layers[-1:]
    slant = one[0].altitude_m / np.cos(ZENITH_RAD)
    assert paths.spherical_wave_ratio(one, ZENITH_RAD, 4 * slant) == pytest.approx(0.75 ** (5 / 6), rel=1e-12)
    assert paths.spherical_wave_ratio(one, ZENITH_RAD, 0.5 * slant) == 0.0


def test_a_bin_unlike_the_far_one_keeps_its_own_probes():
    imager = make_imager(share_far_probes=True)
    z_bin = int(ZENITH_RAD // paths.PUPIL_ERROR_ZENITH_BIN_RAD)
    assert imager.chooser._shares_far(z_bin, int(np.log2(RANGE_M)))
    # a source at 33-66 km, ~6x the turbulence's slant height: its Rytov variance 0.87 of the far one's
    assert not imager.chooser._shares_far(z_bin, 15)
    # a 1 m telescope focused at infinity on LEO: ~1.6 rad rms of defocus
    big = make_imager(telescope=Telescope(1.0, 0.0), focus="infinity", share_far_probes=True)
    assert not big.chooser._shares_far(z_bin, int(np.log2(RANGE_M)))
    assert big.chooser._reference_bin(ZENITH_RAD, RANGE_M)[0][1] >= 0


def test_the_tracked_pass_first_window_makes_the_same_choices(monkeypatch, tmp_path):
    graph = Path(__file__).parents[2] / "benchmarks" / "end_to_end.yaml"

    def first_window(share):
        imagers = []
        step = PointSourceOptics.step

        @functools.wraps(step)
        def kept(self, *args, **kwargs):
            out = step(self, *args, **kwargs)
            imagers.append(self._imager)
            return out
        with monkeypatch.context() as m:
            m.setattr(PointSourceOptics, "step", kept)
            run_graph(load_graph(graph, {"telescope/optics.share_far_probes": share}), tmp_path / f"{share}.zarr",
                      overwrite=True, max_windows=1, progress=False, pipeline=False)
        chooser = imagers[0].chooser
        return {key: choice.path for key, choice in chooser._choices.items()}, sorted(chooser._pupil_errors)

    off, on = first_window(False), first_window(True)
    assert on[0] == off[0] and len(on[0]) > 10
    assert len(off[1]) == 2 and on[1] == [key for key in off[1] if key[1] == -1]     # the far bin only


def test_on_and_off_never_share_cached_probes():
    on, off = make_imager(share_far_probes=True).chooser, make_imager(share_far_probes=False).chooser
    conditions = on._reference_bin(ZENITH_RAD, np.inf)[1]
    assert on._cache_key("reference", conditions) != off._cache_key("reference", conditions)
    assert {**on._cache_key("reference", conditions), "share_far": False} == off._cache_key("reference", conditions)


def test_on_by_default():
    assert PointSourceOptics.Params().share_far_probes and make_imager().chooser.share_far
