"""The cores a pipelined run gets (graph/core_share.py): its CPU against the wall over its last windows, and the
choice it drives, pipelined or one step at a time."""

import pytest

from evsda.graph import core_share
from evsda.graph.core_share import CoreShare, SoloPolicy, adapt_enabled
from evsda.graph.errors import UserError


class Clocks:
    """A wall clock and a CPU clock that advance by what the test says each step took."""

    def __init__(self):
        self.wall, self.cpu = 0.0, 0.0

    def step(self, wall_s: float, cores: float) -> None:
        self.wall += wall_s
        self.cpu += wall_s * cores


def policy_and_clocks(span_s: float = 0.4, solo_s: float = 1.0) -> tuple[SoloPolicy, Clocks]:
    clocks = Clocks()
    share = CoreShare(span_s, wall=lambda: clocks.wall, cpu=lambda: clocks.cpu)
    return SoloPolicy(share, low=0.85, below=1.25, above=1.2, solo_s=solo_s), clocks


def test_the_share_is_cpu_over_wall_since_the_newest_mark_a_span_old():
    clocks = Clocks()
    share = CoreShare(0.4, wall=lambda: clocks.wall, cpu=lambda: clocks.cpu)
    readings = []
    for wall_s, cores in ((0.0, 0.0), (0.1, 2.0), (0.3, 1.0), (0.05, 1.5), (0.1, 1.0)):
        clocks.step(wall_s, cores)                                       # marks at 0, 0.1, 0.4, 0.45, 0.55 s
        readings.append(share.mark())
    assert readings[:2] == [None, None]                                  # under a span yet
    assert readings[2] == pytest.approx((0.2 + 0.3) / 0.4)
    assert readings[3] == pytest.approx((0.2 + 0.3 + 0.075) / 0.45)     # the mark at 0.1 s is not 0.4 s old yet
    assert readings[4] == pytest.approx((0.3 + 0.075 + 0.1) / 0.45)     # it is: the span starts there
    share.restart()
    assert share.mark() is None


def test_pipelined_while_two_cores_then_one_step_at_a_time_on_one():
    policy, clocks = policy_and_clocks()
    modes = []
    for cores in [1.6] * 10 + [1.0] * 6:
        clocks.step(0.1, cores)
        modes.append(policy.update())
    assert not any(modes[:10])
    assert modes[10:] == [False] * 2 + [True] * 4       # solo once the last 0.4 s read under 1.25 cores


def test_one_step_at_a_time_ends_when_the_loops_find_a_second_core_or_after_a_while():
    policy, clocks = policy_and_clocks(solo_s=1.0)
    for _ in range(5):
        clocks.step(0.1, 1.0)
        policy.update()
    assert policy.solo
    # the host stays busy: pipelined again after solo_s all the same, to read it anew
    modes = []
    for _ in range(10):
        clocks.step(0.1, 1.0)
        modes.append(policy.update())
    assert modes == [True] * 9 + [False]
    for _ in range(5):
        clocks.step(0.1, 1.0)
        policy.update()
    assert policy.solo
    # a core comes free: the blocks' loops read 1.4 one step at a time, and the pipeline is back once a span says so
    modes = []
    for _ in range(5):
        clocks.step(0.1, 1.4)
        modes.append(policy.update())
    assert modes == [True] * 2 + [False] * 3            # (0.1 s at 1.0 + 0.3 s at 1.4) / 0.4 s = 1.3 cores


def test_the_pipeline_stays_on_a_host_busy_on_both_cores_and_returns_when_it_grows_busier():
    policy, clocks = policy_and_clocks(solo_s=1.0)
    modes = []
    for cores in [0.6] * 10 + [1.0] * 6 + [0.5] * 6 + [1.0] * 10:
        clocks.step(0.1, cores)
        modes.append(policy.update())
    # under 0.85 cores pipelined: the run competes on both cores' queues, where its second thread earns a share
    assert not any(modes[:10])
    assert modes[10:16] == [False] * 2 + [True] * 4
    assert modes[16:22] == [True] + [False] * 5         # one step at a time reads 0.75 (under 0.85): pipelined
    # and it stays pipelined for solo_s (1 s) before it tries one step at a time again
    assert modes[22:] == [False] * 5 + [True] * 5


def test_the_switch(monkeypatch):
    monkeypatch.delenv("EVSDA_PIPELINE_ADAPT", raising=False)
    assert not adapt_enabled()
    monkeypatch.setenv("EVSDA_PIPELINE_ADAPT", "on")
    assert adapt_enabled()
    monkeypatch.setenv("EVSDA_PIPELINE_ADAPT", "maybe")
    with pytest.raises(UserError, match="EVSDA_PIPELINE_ADAPT must be off"):
        adapt_enabled()
    assert core_share.SOLO_BELOW_CORES > core_share.PIPELINE_ABOVE_CORES > 1.0 > core_share.SOLO_ABOVE_CORES
