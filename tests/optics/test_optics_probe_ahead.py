"""`auto`'s probes made ahead (paths.PathChooser.probe_ahead): every bin a window meets, probed in one schedule on
every core, gives the choices, estimates and verdicts that one choice at a time gives, bit for bit, whatever the
threads; a pair's verdict is taken in pair order however the pairs finish."""

import numpy as np
import pytest

from evsda.blocks.optics import paths
from evsda.blocks.optics.paths import PathChooser, _PairRun, pupil_verdict

from .test_optics_probe_cache import RANGE_M, SEEN, ZENITH_RAD, make_imager

#: a window's frames: the satellite (LEO) and a star (far) at the same zenith angle: two pupil-error bins (two
#: reference probes) and two analytic-path probes sharing one long-exposure table
ZENITHS = np.full(4, ZENITH_RAD)
RANGES = np.array([RANGE_M, np.inf, RANGE_M, np.inf])
SEENS = np.array([SEEN] * 4)
#: the same frames as a window's (render times, tracks): the satellite's track, then the star's
WINDOW = (ZENITHS.reshape(2, 2), RANGES.reshape(2, 2), SEENS.reshape(2, 2, 3), np.ones((2, 2), bool))


def one_at_a_time(imager):
    chooser = imager.chooser
    choices = [chooser.choose(z, r, "s", s) for z, r, s in zip(ZENITHS, RANGES, SEENS)]
    return repr((choices, [chooser.pupil_estimate(z, r) for z, r in zip(ZENITHS, RANGES)],
                 sorted(chooser._estimates.items(), key=repr)))


@pytest.mark.parametrize("threads", ["1", "2"])
@pytest.mark.parametrize("share", [False, True])
def test_probes_made_ahead_give_the_choices_made_one_at_a_time(monkeypatch, threads, share):
    expected = one_at_a_time(make_imager(share_far_probes=share))
    monkeypatch.setenv("EVSDA_THREADS", threads)
    imager = make_imager(share_far_probes=share)
    imager.chooser.probe_ahead(*WINDOW)
    # two reference probes (one with share_far_probes: the LEO bin takes the far one's), two analytic ones
    assert len(imager.chooser._ahead) == (3 if share else 4)
    with monkeypatch.context() as m:                           # the choices take them: no probe runs again
        for name in ("_reference_distances", "_pair_distances", "_analytic_distances"):
            m.setattr(PathChooser, name, lambda *a, **k: pytest.fail("a probe ran twice"))
        assert one_at_a_time(imager) == expected
    assert not imager.chooser._ahead
    imager.chooser.probe_ahead(*WINDOW)        # every bin chosen: nothing to make
    assert not imager.chooser._ahead


def test_the_bins_given_by_the_caller_make_the_probes_it_would_find(monkeypatch):
    """The block hands probe_ahead the bins of each track's first and last frames in view (from its keys of every
    frame in view): the same probes as probe_ahead finding those frames and their bins itself, without its keys."""
    zenith, range_m, seen, visible = WINDOW
    found = make_imager()
    found.chooser.probe_ahead(*WINDOW)
    given = make_imager()
    ends = [given.chooser.key(zenith[t, k], range_m[t, k], tuple(seen[t, k])) for t in (0, 1) for k in (0, 1)]
    with monkeypatch.context() as m:
        m.setattr(PathChooser, "keys", lambda *a, **k: pytest.fail("the bins were looked up again"))
        given.chooser.probe_ahead(*WINDOW, ends)
    assert repr(sorted(given.chooser._ahead.items(), key=repr)) == repr(sorted(found.chooser._ahead.items(), key=repr))


def test_a_failing_probe_made_ahead_raises_its_error(monkeypatch):
    imager = make_imager()

    def fail(*args, **kwargs):
        raise ValueError("probe failed")
    monkeypatch.setattr(PathChooser, "_pair_distances", fail)
    with pytest.raises(ValueError, match="probe failed"):
        imager.chooser.probe_ahead(*WINDOW)


def test_the_verdict_is_taken_in_pair_order_however_the_pairs_finish():
    rng = np.random.default_rng(5)
    tolerance = 0.1
    for mean in (0.05, 0.09, 0.1, 0.13):                     # within early, close calls, beyond
        pairs = [list(rng.normal(mean, 0.03, 2)) for _ in range(paths.REFERENCE_PROBE_FRAMES[1] // 2)]
        measured, verdict = [], None
        for pair in pairs:                                     # one pair after another, as the probes were made
            measured += pair
            verdict = pupil_verdict(measured, 0.0, tolerance)
            if verdict is not None:
                break
        orders = [range(len(pairs)), range(len(pairs))[::-1], *(rng.permutation(len(pairs)) for _ in range(30))]
        for order in orders:
            run = _PairRun((0, 0), 0.0, 0.0, 0.0, tolerance)
            for _ in pairs:
                run.take()
            for pair in order:
                run.done(int(pair), pairs[pair])
            assert (run.measured, run.verdict) == (measured, verdict), (mean, order)


def test_a_pair_no_longer_needed_stops_after_its_first_frame_and_keeps_no_screens():
    imager = make_imager()
    chooser, reference = imager.chooser, imager.reference
    calls = []
    field = reference.field

    def counted(*args, **kwargs):
        calls.append(args[0])
        return field(*args, **kwargs)
    reference.field = counted
    assert chooser._pair_distances((2, 18), ZENITH_RAD, RANGE_M, 0, lambda: False) is None
    assert len(calls) == 1 and not reference.screens                 # one frame made, its screens dropped
    distances = chooser._pair_distances((2, 18), ZENITH_RAD, RANGE_M, 0)
    assert len(calls) == 3 and len(distances) == 2 and not reference.screens


def test_a_pair_dropped_while_a_frame_is_made_leaves_the_rest_unmade(monkeypatch):
    # needed() turning False within a frame (before a layer's screen, or before the propagation) ends the pair there:
    # no propagation after it, no stamps, no screens kept; the pair made afterwards has the distances of one never
    # interrupted. A pair asks before each layer and the propagation of each frame, after its first frame and
    # before its stamps: 2 layers + 4 times
    from evsda.blocks.optics import reference_path
    imager = make_imager()
    chooser, reference = imager.chooser, imager.reference
    expected = chooser._pair_distances((2, 18), ZENITH_RAD, RANGE_M, 0)
    layers = len(reference.grid(ZENITH_RAD, RANGE_M)[2])
    assert layers
    propagated = []
    propagate = reference_path.propagate_point_source
    monkeypatch.setattr(reference_path, "propagate_point_source",
                        lambda *args, **kwargs: propagated.append(1) or propagate(*args, **kwargs))
    for asks in range(2 * layers + 4):
        asked = []
        propagated.clear()

        def needed():
            asked.append(1)
            return len(asked) <= asks
        assert chooser._pair_distances((2, 18), ZENITH_RAD, RANGE_M, 0, needed) is None
        assert len(asked) == asks + 1 and not reference.screens
        assert len(propagated) == (asks >= layers + 1) + (asks >= 2 * layers + 3)
    assert chooser._pair_distances((2, 18), ZENITH_RAD, RANGE_M, 0, lambda: True) == expected


def test_a_pair_likely_to_decide_is_waited_for():
    # the one pair being measured would decide were its frames the mean of those done: a thread with nothing else
    # to make waits for it rather than make the next pair, which would be dropped
    run = _PairRun((0, 0), 0.0, 0.0, 0.0, 0.1)
    assert not run.likely_decided()                                # nothing measured, nothing running
    run.take(), run.take()
    assert not run.likely_decided()                                # two running
    run.done(0, [0.05, 0.07])
    assert run.likely_decided()                                    # 4 frames about 0.06: within at 2 SE
    ahead = _PairRun((0, 0), 0.0, 0.0, 0.0, 0.1)
    ahead.take(), ahead.take()
    ahead.done(1, [0.05, 0.07])                                    # the second done first, the first running
    assert ahead.likely_decided() and not ahead.measured
    spread = _PairRun((0, 0), 0.0, 0.0, 0.0, 0.1)
    spread.take(), spread.take()
    spread.done(0, [0.0, 0.2])                                     # too spread to decide on two frames more
    assert not spread.likely_decided()


def test_two_threads_wait_for_the_deciding_pair_instead_of_making_one_to_drop(monkeypatch):
    import time

    monkeypatch.setenv("EVSDA_THREADS", "2")
    made = []

    def pair_distances(self, key, zenith_rad, range_m, pair, needed=lambda: True, rendered=lambda: True):
        made.append(pair)
        time.sleep(0.05 if pair == 0 else 0.3)                    # the first pair ends first
        return [0.05, 0.07]
    monkeypatch.setattr(PathChooser, "_pair_distances", pair_distances)
    imager = make_imager()
    imager.pupil_renderer                                          # made before: the two threads take pairs at once
    run = _PairRun((0, 0), 0.0, 0.0, 0.0, 0.1)
    measured, verdict = imager.chooser._measure([run], [])["reference", (0, 0)]
    assert (measured, verdict[0]) == ([0.05, 0.07, 0.05, 0.07], True)
    assert sorted(made) == [0, 1]                                  # no third pair begun beside the second
