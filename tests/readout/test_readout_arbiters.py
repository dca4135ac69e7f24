"""Arbiters: hand-computed scan orders and delays, saturation counts, conservation, windowing.

References: delays worked out by hand from the clock rate; an independent tick-by-tick
simulation of the scanner, FIFO and bus (written from the model's description, not
from the vectorised code); and exact conservation triggered = recorded + dropped.
"""

import bisect
from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evsda.blocks.ports import Events, FocalPlane, TriggeredEvents
from evsda.blocks.readout import ColumnBurstArbiter, IdealReadout, RowScanArbiter
from evsda.blocks.readout.clock import ceil_tick, tick_ns
from evsda.blocks.readout.output_fifo import NEVER, run_fifo
from evsda.graph import NS_PER_S, ParameterError, RunInfo, Window


def triggered(fp, t, x, y, p=None, cause=None):
    t, x, y = (np.asarray(a, np.int64) for a in (t, x, y))
    order = np.lexsort((x, y, t))
    n = t.size
    p = np.ones(n, np.int8) if p is None else np.asarray(p, np.int8)
    cause = np.zeros(n, np.uint8) if cause is None else np.asarray(cause, np.uint8)
    return TriggeredEvents(fp, t[order], x[order].astype(np.uint16), y[order].astype(np.uint16),
                           p[order], cause[order])


def run_windows(block, events: TriggeredEvents, edges_ns, duration_ns=None):
    """Feed ``events`` window by window; return the concatenated Events fields and total drops."""
    duration_ns = duration_ns or edges_ns[-1]
    block.setup(RunInfo(duration_ns=duration_ns, window_ns=duration_ns))
    outs, dropped = [], 0
    for i, (a, b) in enumerate(zip(edges_ns[:-1], edges_ns[1:])):
        sel = (events.t_ns >= a) & (events.t_ns < b)
        piece = TriggeredEvents(events.focal_plane, *(f[sel] for f in (events.t_ns, events.x, events.y,
                                                                         events.p, events.cause)))
        out = block.step(Window(i, a, b), events=piece)["events"]
        assert np.all(np.diff(out.t_readout_ns) >= 0), "events must be sorted by readout time"
        assert np.all((out.t_readout_ns >= a) & ((out.t_readout_ns < b) | (b == duration_ns)))
        outs.append(out)
        dropped += out.n_dropped
    cat = {name: np.concatenate([getattr(o, name) for o in outs])
           for name in ("t_trigger_ns", "t_readout_ns", "x", "y", "p", "cause")}
    return cat, dropped


# -- scan order and delays, computed by hand -------------------------------------------------------
def test_row_scan_reads_a_burst_row_then_column_with_clock_delays():
    """100 MHz clock (10 ns ticks), 2 ticks per row, bus 25 Mevent/s (one event per 4 ticks).

    Scanner: row r is visited at tick 2r of each 16-tick pass (8 rows). Events at t = 0:
    (5,0) latched at tick 0, bus free -> tick 0 = 0 ns; row 2 latched at tick 4: (0,2) at
    tick 4 = 40 ns, (3,2) waits for the bus until tick 8 = 80 ns; (5,5) latched at tick 10,
    bus free at 12 -> 120 ns; (15,7) latched at 14, bus free at 16 -> 160 ns. (9,0)
    triggers at 15 ns, after row 0's visit: next visit of row 0 at tick 16, bus free at 20
    -> 200 ns.
    """
    fp = FocalPlane(16, 8, 10e-6, 1.0)
    ev = triggered(fp, [0, 0, 0, 0, 0, 15], [3, 0, 15, 5, 5, 9], [2, 2, 7, 0, 5, 0])
    arb = RowScanArbiter(clock_hz=100e6, row_cycles=2, bus_throughput_eps=25e6, queue_depth=8)
    out = arb.step(Window(0, 0, 1000), events=ev)["events"]
    assert list(zip(out.x.tolist(), out.y.tolist())) == [(5, 0), (0, 2), (3, 2), (5, 5), (15, 7), (9, 0)]
    assert out.t_readout_ns.tolist() == [0, 40, 80, 120, 160, 200]
    assert out.t_trigger_ns.tolist() == [0, 0, 0, 0, 0, 15]
    assert out.n_dropped == 0 and arb.n_pending == 0


def test_column_burst_stamps_a_group_with_its_grant():
    """Groups of 2 columns, 1 tick per group at 100 MHz, bus 50 Mevent/s (2 ticks/event).

    Group 0 (columns 0-1) at tick 0 holds (0,5) and (1,0): granted ticks 0 and 2, both
    stamped 0 ns. Group 1 at tick 1: (2,3) waits for the bus until tick 4 = 40 ns.
    Group 2 at tick 2: (5,0) at tick 6 = 60 ns. Group 3 at tick 3: (7,3) at 80 ns.
    """
    fp = FocalPlane(8, 6, 10e-6, 1.0)
    ev = triggered(fp, [0] * 5, [1, 5, 2, 7, 0], [0, 0, 3, 3, 5])
    arb = ColumnBurstArbiter(clock_hz=100e6, bus_throughput_eps=50e6, queue_depth=64, group_width_px=2)
    out = arb.step(Window(0, 0, 1000), events=ev)["events"]
    assert list(zip(out.x.tolist(), out.y.tolist())) == [(0, 5), (1, 0), (2, 3), (5, 0), (7, 3)]
    assert out.t_readout_ns.tolist() == [0, 0, 40, 60, 80]


def test_ideal_readout_records_at_trigger_time():
    fp = FocalPlane(4, 4, 10e-6, 1.0)
    ev = triggered(fp, [5, 1, 9], [0, 3, 2], [1, 3, 0], p=[1, -1, 1], cause=[0, 3, 1])
    out = IdealReadout().step(Window(0, 0, 100), events=ev)["events"]
    assert isinstance(out, Events) and out.n_dropped == 0
    np.testing.assert_array_equal(out.t_readout_ns, out.t_trigger_ns)
    np.testing.assert_array_equal(out.t_trigger_ns, ev.t_ns)
    np.testing.assert_array_equal(out.cause, ev.cause)


# -- saturation -----------------------------------------------------------------------------------
def test_flood_in_one_grant_keeps_queue_depth_plus_one():
    """10 000 events in one microsecond on one row, latched by one visit (1 row, 200 ticks per
    visit at 100 MHz = 2 µs). One event goes straight onto the free bus, queue_depth wait;
    the rest find the FIFO full."""
    fp = FocalPlane(4096, 1, 10e-6, 1.0)
    rng = np.random.default_rng(1)
    n = 4000
    t = np.sort(rng.integers(1, 1000, n))
    x = rng.permutation(4096)[:n]
    ev = triggered(fp, t, x, np.zeros(n))
    for depth in (1, 16):
        arb = RowScanArbiter(clock_hz=100e6, row_cycles=200, bus_throughput_eps=50e6, queue_depth=depth)
        out = arb.step(Window(0, 0, 10_000), events=ev)["events"]
        assert len(out) == depth + 1
        assert out.n_dropped == n - depth - 1
        assert out.t_readout_ns.tolist() == [2000 + 20 * k for k in range(depth + 1)]
        np.testing.assert_array_equal(out.x, np.sort(x)[: depth + 1])   # column order


@pytest.mark.parametrize("depth", [1, 3, 10])
def test_sustained_flood_above_bus_throughput_drops_the_excess(depth):
    """One event per tick (100 Mevent/s) into a bus of 50 Mevent/s (2 ticks per event), for
    T = 1000 ticks on a one-row sensor scanned every tick. The bus never idles once the FIFO
    is full, and the last accepted event (arriving at the last even tick, 998) waits for the
    `depth` events before it: its grant is 998 + 2*depth, so exactly 998/2 + depth + 1 events
    are recorded and the rest are dropped."""
    fp = FocalPlane(1000, 1, 10e-6, 1.0)
    ticks = np.arange(1000)
    ev = triggered(fp, ticks * 10, ticks, np.zeros(1000))
    arb = RowScanArbiter(clock_hz=100e6, bus_throughput_eps=50e6, queue_depth=depth)
    cat, dropped = run_windows(arb, ev, [0, 3_333, 7_001, 30_000])
    assert len(cat["x"]) == 998 // 2 + depth + 1
    assert len(cat["x"]) + dropped == 1000
    grants = cat["t_readout_ns"] // 10
    np.testing.assert_array_equal(np.diff(grants), 2)          # a busy bus, one event per slot


# -- an independent tick-by-tick reference -------------------------------------------------------------
def reference_row_scan(fp, t_ns, x, y, clock_hz, row_cycles, bus_cycles, depth):
    """Step the scanner, FIFO and bus one clock tick at a time (slow, obviously correct)."""
    period_ns = 1e9 / clock_hz
    trig = np.ceil(np.asarray(t_ns) / period_ns - 1e-9).astype(int)
    requests = {}                      # pixel -> list of (trigger tick, event index), oldest first
    for i in np.argsort(trig, kind="stable"):
        requests.setdefault((int(y[i]), int(x[i])), []).append((int(trig[i]), int(i)))
    queue, bus_free, out, dropped = deque(), -(10**9), {}, 0
    k, left = 0, len(trig)
    while left or queue:
        if queue and k >= bus_free:                   # the bus takes the head of the FIFO
            out[queue.popleft()] = k
            bus_free = k + bus_cycles
        if k % row_cycles == 0:                      # the scanner visits a row and latches it
            row = (k // row_cycles) % fp.height_px
            for col in range(fp.width_px):
                reqs = requests.get((row, col), [])
                due = [r for r in reqs if r[0] <= k]
                if not due:
                    continue
                requests[(row, col)] = [r for r in reqs if r[0] > k]
                dropped += len(due) - 1             # one request per pixel per visit
                left -= len(due)
                if len(queue) >= depth:
                    dropped += 1
                    continue
                queue.append(due[0][1])
                if k >= bus_free:
                    out[queue.popleft()] = k
                    bus_free = k + bus_cycles
        k += 1
    return {i: int(np.floor(g * period_ns + 1e-6)) for i, g in out.items()}, dropped


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), depth=st.integers(1, 5), row_cycles=st.integers(1, 3),
       bus_cycles=st.integers(1, 4))
def test_row_scan_matches_tick_by_tick_reference(seed, depth, row_cycles, bus_cycles):
    rng = np.random.default_rng(seed)
    fp = FocalPlane(5, 4, 10e-6, 1.0)
    n = 60
    t = np.sort(rng.integers(0, 3000, n))
    x, y = rng.integers(0, 5, n), rng.integers(0, 4, n)
    clock = 100e6
    ref, ref_dropped = reference_row_scan(fp, t, x, y, clock, row_cycles, bus_cycles, depth)
    ev = triggered(fp, t, x, y)
    arb = RowScanArbiter(clock_hz=clock, row_cycles=row_cycles, bus_throughput_eps=clock / bus_cycles,
                         queue_depth=depth)
    cat, dropped = run_windows(arb, ev, [0, 777, 1500, 100_000])
    assert dropped == ref_dropped
    # match recorded events by (trigger time, pixel): the reference is keyed by input index
    order = np.lexsort((x, y, t))
    got = sorted(zip(cat["t_trigger_ns"].tolist(), cat["x"].tolist(), cat["y"].tolist(), cat["t_readout_ns"].tolist()))
    want = sorted((int(t[i]), int(x[i]), int(y[i]), ref[i]) for i in order if i in ref)
    assert got == want


# -- the clock's conversions against Python's integers -------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(start=st.integers(-3 * 10**9, 10**12), span=st.sampled_from([0, 1, 10**8, 10**9, 3 * 10**9]),
       n=st.integers(1, 50), clock=st.sampled_from([1_066_000_000, 100_000_000, 999_999_937, 5_000_000_000]),
       seed=st.integers(0, 1000))
def test_clock_conversions_match_python_integers(start, span, n, clock, seed):
    """Times within one second (one quotient for all: clock._quotient) and across seconds give the exact ticks."""
    t = np.sort(start + np.random.default_rng(seed).integers(0, span + 1, n))
    ticks = ceil_tick(t, clock)
    assert ticks.tolist() == [-(-v * clock // NS_PER_S) for v in t.tolist()]
    assert tick_ns(ticks, clock).tolist() == [k * NS_PER_S // clock for k in ticks.tolist()]
    assert int(ceil_tick(t[0], clock)) == -(-int(t[0]) * clock // NS_PER_S)        # a scalar


# -- the FIFO against a plain event-by-event queue ---------------------------------------------------
def reference_fifo(arrival, service, depth):
    grants, accepted, last = [], [], NEVER
    for a in arrival:
        waiting = len(grants) - bisect.bisect_right(grants, a)      # grants are increasing
        if waiting >= depth:
            accepted.append(False)
            continue
        last = max(a, last + service)
        grants.append(last)
        accepted.append(True)
    return np.array(accepted, bool), np.array(grants, np.int64)


@settings(max_examples=60, deadline=None)
@given(arrivals=st.lists(st.integers(0, 200), min_size=0, max_size=120), service=st.integers(1, 6),
       depth=st.integers(1, 6), cut=st.floats(0, 1))
def test_fifo_matches_reference_also_when_cut_in_two(arrivals, service, depth, cut):
    a = np.sort(np.array(arrivals, np.int64))
    want_acc, want_grant = reference_fifo(a.tolist(), service, depth)
    whole = run_fifo(a, service, depth, np.zeros(0, np.int64), int(NEVER))
    np.testing.assert_array_equal(whole.accepted, want_acc)
    np.testing.assert_array_equal(whole.grant[whole.accepted], want_grant)
    # in two pieces, the second starting at tick h, carrying the grants still waiting at h
    h = int(cut * 200)
    m = int(np.searchsorted(a, h))
    first = run_fifo(a[:m], service, depth, np.zeros(0, np.int64), int(NEVER))
    g1 = first.grant[first.accepted]
    second = run_fifo(a[m:], service, depth, g1[g1 >= h], first.last_grant)
    np.testing.assert_array_equal(np.concatenate([first.accepted, second.accepted]), want_acc)


@pytest.mark.parametrize("seed", range(2))
def test_fifo_through_long_floods_matches_reference(seed):
    """Tens of thousands of arrivals in bursts far above the bus rate: long busy periods."""
    rng = np.random.default_rng(seed)
    bursts = rng.integers(0, 200_000, 40)
    a = np.sort(np.concatenate([b + rng.integers(0, rng.integers(1, 3000), 500) for b in bursts]))
    for service, depth in [(3, 1), (2, 16), (7, 5)]:
        want_acc, want_grant = reference_fifo(a.tolist(), service, depth)
        got = run_fifo(a, service, depth, np.zeros(0, np.int64), int(NEVER))
        np.testing.assert_array_equal(got.accepted, want_acc)
        np.testing.assert_array_equal(got.grant[got.accepted], want_grant)
        assert 0 < want_acc.sum() < a.size


# -- conservation, windowing, resume ---------------------------------------------------------------------
def noisy_scene(seed=0, n=30_000, duration_ns=2_000_000):
    """Background noise plus a dense burst, on a 64 x 48 sensor."""
    rng = np.random.default_rng(seed)
    fp = FocalPlane(64, 48, 10e-6, 1.0)
    t = np.concatenate([rng.integers(0, duration_ns, n), rng.integers(1_000_000, 1_001_000, n // 3)])
    x, y = rng.integers(0, 64, t.size), rng.integers(0, 48, t.size)
    p = rng.choice(np.array([-1, 1], np.int8), t.size)
    return triggered(fp, t, x, y, p=p, cause=rng.integers(0, 4, t.size)), duration_ns


ARBITERS = [
    lambda: RowScanArbiter(clock_hz=200e6, row_cycles=3, bus_throughput_eps=20e6, queue_depth=16),
    lambda: ColumnBurstArbiter(clock_hz=200e6, group_width_px=4, group_cycles=2, bus_throughput_eps=40e6,
                               queue_depth=8),
    lambda: IdealReadout(),
]


@pytest.mark.parametrize("make", ARBITERS)
def test_conservation_and_window_independence(make):
    ev, duration = noisy_scene()
    whole, d_whole = run_windows(make(), ev, [0, duration])
    edges = [0, 1, 250_000, 999_999, 1_000_500, 1_000_501, 1_700_000, duration]
    cut, d_cut = run_windows(make(), ev, edges)
    assert len(whole["x"]) + d_whole == len(ev)          # triggered = recorded + dropped, exactly
    for name in whole:
        np.testing.assert_array_equal(whole[name], cut[name])
    assert d_whole == d_cut
    assert np.all(whole["t_readout_ns"] >= whole["t_trigger_ns"])


@pytest.mark.parametrize("make", ARBITERS[:2])
def test_killed_and_resumed_run_is_identical(make):
    ev, duration = noisy_scene(seed=4)
    edges = [0, 400_000, 1_000_300, 1_500_000, duration]
    whole, _ = run_windows(make(), ev, edges)
    # run the first two windows, checkpoint, and continue in a fresh block
    first = make()
    first.setup(RunInfo(duration_ns=duration, window_ns=duration))
    outs = []
    for i in range(2):
        sel = (ev.t_ns >= edges[i]) & (ev.t_ns < edges[i + 1])
        outs.append(first.step(Window(i, edges[i], edges[i + 1]), events=piece(ev, sel))["events"])
    state = {k: (dict(v) if isinstance(v, dict) else v) for k, v in first.get_state().items()}
    second = make()
    second.setup(RunInfo(duration_ns=duration, window_ns=duration))
    second.set_state(state)
    for i in range(2, len(edges) - 1):
        sel = (ev.t_ns >= edges[i]) & (ev.t_ns < edges[i + 1])
        outs.append(second.step(Window(i, edges[i], edges[i + 1]), events=piece(ev, sel))["events"])
    np.testing.assert_array_equal(np.concatenate([o.t_readout_ns for o in outs]), whole["t_readout_ns"])
    np.testing.assert_array_equal(np.concatenate([o.x for o in outs]), whole["x"])


def piece(ev, sel):
    return TriggeredEvents(ev.focal_plane, ev.t_ns[sel], ev.x[sel], ev.y[sel], ev.p[sel], ev.cause[sel])


def test_pending_events_are_carried_and_flushed_or_dropped_at_the_end():
    fp = FocalPlane(8, 1000, 10e-6, 1.0)          # a slow scan: 1000 rows x 10 ticks = 100 µs per pass
    ev = triggered(fp, [0, 0, 0], [0, 1, 2], [999, 999, 500])
    for flush in (True, False):
        arb = RowScanArbiter(clock_hz=100e6, row_cycles=10, bus_throughput_eps=100e6, flush_at_end=flush)
        arb.setup(RunInfo(duration_ns=20_000, window_ns=10_000))
        a = arb.step(Window(0, 0, 10_000), events=ev)["events"]
        assert len(a) == 0 and a.n_dropped == 0 and arb.n_pending == 3
        b = arb.step(Window(1, 10_000, 20_000), events=TriggeredEvents.empty(fp))["events"]
        assert arb.n_pending == 0
        if flush:      # row 500 at 50 µs, row 999 at 99.9 µs (columns 0 then 1, 10 ns apart)
            assert b.t_readout_ns.tolist() == [50_000, 99_900, 99_910] and b.n_dropped == 0
        else:
            assert len(b) == 0 and b.n_dropped == 3


# -- hard cases --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("make", ARBITERS)
def test_empty_run(make):
    fp = FocalPlane(32, 16, 10e-6, 1.0)
    arb = make()
    arb.setup(RunInfo(duration_ns=2000, window_ns=1000))
    for i in range(2):
        out = arb.step(Window(i, 1000 * i, 1000 * (i + 1)), events=TriggeredEvents.empty(fp))["events"]
        assert len(out) == 0 and out.n_dropped == 0


def test_last_row_and_column():
    """Pixel (W-1, H-1) of a 1280 x 720 sensor: row 719 is visited at tick 719 (7.19 µs at
    100 MHz) of the first pass; an event just after that visit waits a whole pass (720 ticks)."""
    fp = FocalPlane(1280, 720, 10e-6, 1.0)
    ev = triggered(fp, [0, 7_191, 0], [1279, 1279, 0], [719, 719, 719])
    arb = RowScanArbiter(clock_hz=100e6, bus_throughput_eps=100e6)
    out = arb.step(Window(0, 0, 100_000), events=ev)["events"]
    assert out.x.tolist() == [0, 1279, 1279]
    assert out.t_readout_ns.tolist() == [7_190, 7_200, 7_190 + 7_200]
    burst = ColumnBurstArbiter(clock_hz=100e6, bus_throughput_eps=100e6, group_width_px=7)
    out = burst.step(Window(0, 0, 100_000), events=ev)["events"]
    # 183 groups of 7 columns; column 1279 is in group 182, visited at ticks 182 + 183 m:
    # the event of 7.191 µs (tick 720) waits for the visit at tick 731
    assert out.t_readout_ns.tolist() == [0, 1_820, 7_310]


def test_clock_must_be_a_multiple_of_the_bus_rate():
    with pytest.raises(ParameterError, match="bus_throughput_eps"):
        RowScanArbiter(clock_hz=100e6, bus_throughput_eps=30e6)
    with pytest.raises(ParameterError, match="queue_depth"):
        RowScanArbiter(queue_depth=0)
    with pytest.raises(ParameterError, match="clock_hz"):
        RowScanArbiter(clock_hz=100.5)


@pytest.mark.parametrize("block", [IdealReadout, RowScanArbiter, ColumnBurstArbiter])
def test_every_parameter_states_its_unit(block):
    for name, info in block.Params.model_fields.items():
        assert info.description and info.description.rstrip().endswith("]"), name
