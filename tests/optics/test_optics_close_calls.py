"""`auto`'s close calls: the pupil path's error against the Fresnel reference is decided with its standard error
(paths.pupil_verdict), so a path ~100x slower is taken only when the probes show the pupil path beyond the
tolerance; the probes' frames come in pairs from both halves of each complex FFT draw."""

import numpy as np
import pytest

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics.atmosphere import Atmosphere
from evsda.blocks.optics.imaging import Imager
from evsda.blocks.optics.paths import REFERENCE_PROBE_FRAMES, pupil_verdict
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.ports import FocalPlane

FOCAL_PLANE = FocalPlane(640, 480, 4.86e-6, 1.2)        # 4.05 urad pixels
WAVELENGTH = 550e-9
#: HV5/7-like layers up to 10 km on a 10 cm aperture 20 deg from the zenith, LEO at 500 km: the pupil path
#: misplaces ~9 % of the flux against the reference (24 frames: 0.084-0.107 over seeds 1-4), its
#: scintillation term (index 0.016) 0.05
ATMOSPHERE = Atmosphere.hufnagel_valley(2).scaled_to_r0(0.1)
ZENITH_RAD, RANGE_M = np.deg2rad(20), 5e5
#: the LEO bin's own probes (share_far_probes off: its bin would take the far one's, test_optics_shared_far_probes.py)
PARAMS = PointSourceOptics.Params(share_far_probes=False)


def probes(tolerance, seed, monkeypatch=None, threads="2"):
    """The chooser's pupil-error estimate (a PupilError) at ``tolerance``, the sampling of the default tolerance."""
    if monkeypatch is not None:
        monkeypatch.setenv("EVSDA_THREADS", threads)
    imager = Imager(Telescope(0.1, 0.0), FOCAL_PLANE, WAVELENGTH, ATMOSPHERE, PARAMS,
                    seed=(seed,))
    imager.ensure_geometry(ZENITH_RAD)
    imager.tolerance = tolerance
    return imager.chooser.pupil_estimate(ZENITH_RAD, RANGE_M)


def skewed_frames(rng, mean, n):
    """Per-frame distances as skewed as the tracked ISS's at 65 deg (spread / mean 0.58 on 24 frames: gamma)."""
    shape = 1 / 0.6**2
    return rng.gamma(shape, mean / shape, n)


def decide(rng, mean, tolerance, scintillation=0.0):
    """pupil_verdict fed frame pairs until it decides: (within, frames)."""
    frames = []
    while True:
        frames.extend(skewed_frames(rng, mean, 2))
        verdict = pupil_verdict(frames, scintillation, tolerance)
        if verdict is not None:
            return verdict[0], len(frames)


def decide_on(frames, tolerance, scintillation=0.0, curtail=True):
    """pupil_verdict fed the pairs of ``frames`` in order until it decides: (within, frames used)."""
    for n in range(2, len(frames) + 1, 2):
        verdict = pupil_verdict(list(frames[:n]), scintillation, tolerance, curtail=curtail)
        if verdict is not None:
            return verdict[0], n
    raise AssertionError("no verdict on every frame")


def test_an_error_at_the_tolerance_keeps_the_faster_path_whatever_the_seed():
    # the estimate of an error equal to the tolerance straddles it: decided on the mean (before), half of the
    # seeds went to the ~100x slower reference; the interval's rule keeps the pupil path on every seed
    decisions = [decide(np.random.default_rng(seed), 0.1, 0.1) for seed in range(100)]
    assert all(within for within, _ in decisions)
    assert np.mean([n for _, n in decisions]) > 8          # the close calls take more frames than the clear ones
    by_mean = [np.mean(skewed_frames(np.random.default_rng(seed), 0.1, 12)) > 0.1 for seed in range(100)]
    assert 20 < sum(by_mean) < 80                          # what deciding on the mean of 12 frames would have done


def test_clear_cases_are_decided_as_before():
    for seed in range(50):
        rng = np.random.default_rng(seed)
        assert decide(rng, 0.03, 0.1) == (True, REFERENCE_PROBE_FRAMES[0])      # well within: on the first frames
        assert decide(rng, 0.3, 0.1) == (False, REFERENCE_PROBE_FRAMES[1])      # well beyond: on every frame
    # a scintillation term above the tolerance settles it without a frame; below, it is the estimate's floor
    assert pupil_verdict([], 0.12, 0.1)[0] is False
    assert pupil_verdict([0.01] * 4, 0.095, 0.1) == (True, "<= tolerance 0.1 at 2 standard errors (0.095)")
    assert pupil_verdict([0.0, 0.2] * 2, 0.05, 0.1) is None                      # open: more frames
    assert pupil_verdict([0.0, 0.2] * 12, 0.05, 0.1)[0] is True                  # at the cap, open: within


def test_curtailed_verdict_is_the_full_rules_on_close_calls():
    # the hard cases: errors from the tolerance to twice it, where the full rule (every frame up to the cap before
    # it can reject) rejects on 0.1-93 % of the seeds; stopped once that rejection is out of reach, the verdict is
    # the full rule's but on a few seeds in a thousand (within where it rejects, never the other way), on fewer frames
    cap = REFERENCE_PROBE_FRAMES[1]
    for ratio, rejected in ((1.0, (0, 5)), (1.2, (10, 50)), (1.5, (300, 450)), (2.0, (900, 960))):
        full, curtailed = [], []
        for seed in range(1000):
            frames = skewed_frames(np.random.default_rng(seed), ratio * 0.1, cap)
            full.append(decide_on(frames, 0.1, curtail=False))
            curtailed.append(decide_on(frames, 0.1))
        assert rejected[0] <= sum(not within for within, _ in full) <= rejected[1]
        assert all(within for (full_within, _), (within, _) in zip(full, curtailed) if full_within)
        assert sum(a != b for (a, _), (b, _) in zip(full, curtailed)) <= 4
        assert all(n <= m for (_, m), (_, n) in zip(full, curtailed))
        if ratio == 1.0:
            assert np.mean([n for _, n in curtailed]) < 0.7 * np.mean([n for _, n in full])


def test_curtailed_verdict_on_real_probes_at_every_tolerance():
    # the real probe's 24 frames (seed 3: the most frames of seeds 1-4), decided at every tolerance from below the
    # scintillation floor to twice their mean, the rejection's edge (mean - 3 SE on 24 frames) included: the
    # curtailed verdict is the full rule's at each, on fewer frames where the full rule takes more than the first
    imager = Imager(Telescope(0.1, 0.0), FOCAL_PLANE, WAVELENGTH, ATMOSPHERE, PARAMS, seed=(3,))
    imager.ensure_geometry(ZENITH_RAD)
    key, conditions, _ = imager.chooser._reference_bin(ZENITH_RAD, RANGE_M)
    frames = []
    for pair in range(REFERENCE_PROBE_FRAMES[1] // 2):
        frames += imager.chooser._pair_distances(key, conditions["zenith_rad"], conditions["range_m"], pair)
    scintillation = conditions["scintillation"]
    edge = np.mean(frames) - 3 * np.std(frames, ddof=1) / np.sqrt(len(frames))
    tolerances = np.append(np.linspace(0.04, 2 * np.mean(frames), 200), edge + np.array([-1e-3, -1e-9, 1e-9, 1e-3]))
    used = []
    for tolerance in tolerances:
        full = decide_on(frames, tolerance, scintillation, curtail=False)
        curtailed = decide_on(frames, tolerance, scintillation)
        assert curtailed[0] == full[0], tolerance
        used.append((full[1], curtailed[1]))
    assert {within for within, _ in (decide_on(frames, t, scintillation) for t in tolerances)} == {True, False}
    assert sum(n for _, n in used) < 0.85 * sum(m for m, _ in used)


def test_pupil_path_error_is_a_close_call_decided_the_same_way_over_seeds():
    # the real probes at a tolerance equal to the pupil path's error: the seeds' means lie on both sides of it,
    # every seed keeps pupil_fft (decided on the mean of its frames, some seeds would take the reference)
    estimates = [probes(0.09, seed) for seed in range(1, 5)]
    assert all(e.within for e in estimates), [(e.error, e.frames) for e in estimates]
    assert min(e.error for e in estimates) < 0.09 < max(e.error for e in estimates)
    # clear cases: within on the first frames; beyond on every frame (the scintillation floor 0.05 is below it)
    clear = probes(0.9, 1)
    assert clear.within and clear.frames == REFERENCE_PROBE_FRAMES[0]
    beyond = probes(0.055, 1)
    assert not beyond.within and beyond.frames == REFERENCE_PROBE_FRAMES[1]
    assert beyond.error - 3 * beyond.standard_error > 0.055


def test_probe_verdict_does_not_depend_on_the_threads(monkeypatch):
    one, two = probes(0.09, 3, monkeypatch, "1"), probes(0.09, 3, monkeypatch, "2")
    assert (one.error, one.standard_error, one.frames, one.within) == (two.error, two.standard_error, two.frames,
                                                                         two.within)


def test_probe_pair_first_frame_is_a_frame_alone_and_the_second_its_twin():
    # the first frame of a pair is the probe frame made alone (same seed, bit for bit; the pair's fields are those
    # before the aperture, the field once times it); the second frame's screens are the imaginary halves of the
    # same draws (independence and statistics: test_optics_screens.py), not a draw of its own
    imager = Imager(Telescope(0.1, 0.0), FOCAL_PLANE, WAVELENGTH, ATMOSPHERE, PARAMS, seed=(1,))
    imager.ensure_geometry(ZENITH_RAD)
    reference = imager.reference

    def alone(name):
        field = reference.field(name, 0.0, np.zeros(2), ZENITH_RAD, RANGE_M, slack=1.0)
        phase = reference.pupil_phase(name, 0.0, np.zeros(2), ZENITH_RAD, RANGE_M)
        del reference.screens[name]
        return field, phase

    (field_a, phase_a), (field_b, phase_b) = reference.probe_pair(("a", "b"), ZENITH_RAD, RANGE_M)
    assert not reference.screens                                            # the probes' screens are dropped
    field, phase = alone("a")
    np.testing.assert_array_equal(field, field_a * imager.pupil_amplitude)
    np.testing.assert_array_equal(phase, phase_a)
    inside = imager.pupil_amplitude > 0
    spread = np.std(phase_a[inside])
    assert np.std((phase_b - phase_a)[inside]) > 0.3 * spread               # another screen ...
    assert np.std((alone("b")[1] - phase_b)[inside]) > 0.3 * spread         # ... not b's own draw
