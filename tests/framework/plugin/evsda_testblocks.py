"""A tiny third-party block package used by the framework tests.

It is installed into a temporary folder with a ``.dist-info`` declaring the
``evsda.blocks`` entry point, exactly as a real plugin would be, so the tests
exercise discovery through entry points. The blocks do no physics: they only
exercise state, randomness, windows and ports.
"""

from __future__ import annotations

import logging
import os
import signal
import time
from dataclasses import dataclass

import numpy as np
from pydantic import Field

from evsda.blocks.ports import Events, FocalPlane, Metrics
from evsda.graph import Block, BlockParams, Input, Output, ParameterError, PortValue, SceneError, Window

GEOMETRY = FocalPlane(width_px=32, height_px=16, pixel_pitch_m=5e-6, focal_length_m=1.0)


@dataclass(frozen=True, eq=False)
class Samples(PortValue):
    """A sampled scalar signal."""

    unit = "1"
    t_ns: np.ndarray
    value: np.ndarray


class RampSource(Block):
    """A noisy ramp sampled on the run's global grid."""

    type_name = "test_ramp"

    class Params(BlockParams):
        cadence_s: float = Field(1e-3, gt=0, description="Sampling interval [s]")
        slope_per_s: float = Field(100.0, description="Ramp slope [1/s]")
        noise: float = Field(0.1, ge=0, description="Standard deviation of the added noise [1]")
        fail_at_s: float | None = Field(None, description="Raise a SceneError in the window holding this time [s]")

    outputs = {"samples": Output(Samples, "the ramp")}

    def step(self, window: Window) -> dict:
        fail = self.params.fail_at_s
        if fail is not None and window.start_ns <= fail * 1e9 < window.stop_ns:
            raise SceneError(f"ramp '{self.name}' cannot continue past {fail} s")
        t = window.sample_times_ns(round(self.params.cadence_s * 1e9))
        value = self.params.slope_per_s * t * 1e-9 + self.params.noise * self.rng.standard_normal(t.size)
        return {"samples": Samples(t, value)}


class Scale(Block):
    """Multiplies a signal by a gain."""

    type_name = "test_scale"

    class Params(BlockParams):
        gain: float = Field(2.0, description="Gain [1]")

    inputs = {"samples": Input(Samples, "signal")}
    outputs = {"samples": Output(Samples, "scaled signal")}

    def step(self, window: Window, samples: Samples) -> dict:
        return {"samples": Samples(samples.t_ns, self.params.gain * samples.value)}


class NoisyGain(Block):
    """Multiplies a signal by a gain and adds noise, in a worker process of its own (``worth_a_process``): it
    keeps state, draws random numbers, logs, and can fail in a chosen window, or kill its own process in the window
    ``EVSDA_TEST_DIE_AT_WINDOW`` names (read from the environment, so that the same graph then resumes)."""

    type_name = "test_noisy_gain"
    worth_a_process = True

    class Params(BlockParams):
        gain: float = Field(2.0, description="Gain [1]")
        noise: float = Field(0.5, ge=0, description="Standard deviation of the added noise [1]")
        fail_at_window: int | None = Field(None, description="Raise a SceneError in this window")
        fail_in_setup: bool = Field(False, description="Raise a ParameterError in setup()")
        sleep_s: float = Field(0.0, ge=0, description="Wall-clock pause per window, to test interruption [s]")

    inputs = {"samples": Input(Samples, "signal")}
    outputs = {"samples": Output(Samples, "scaled, noisy signal")}
    state = ("steps",)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.steps = 0

    def setup(self, run) -> None:
        super().setup(run)
        if self.params.fail_in_setup:
            raise ParameterError(f"{self.label} cannot be set up")

    def step(self, window: Window, samples: Samples) -> dict:
        time.sleep(self.params.sleep_s)
        if window.index == self.params.fail_at_window:
            raise SceneError(f"{self.label} fails in window {window.index}")
        if str(window.index) == os.environ.get("EVSDA_TEST_DIE_AT_WINDOW"):
            os.kill(os.getpid(), signal.SIGKILL)
        self.steps += 1
        logging.getLogger("evsda_testblocks").info("%s stepped window %d in process %d", self.label, window.index,
                                                   os.getpid())
        noise = self.params.noise * self.rng.standard_normal(samples.value.size)
        return {"samples": Samples(samples.t_ns, self.params.gain * samples.value + noise)}


class SpikeEncoder(Block):
    """Emits an event at a random pixel each time the running sum of its input grows by ``step``."""

    type_name = "test_spikes"
    is_sink = True

    class Params(BlockParams):
        step: float = Field(5.0, gt=0, description="Increment of the running sum per event [1]")
        latency_s: float = Field(1e-6, ge=0, description="Readout latency [s]")
        sleep_s: float = Field(0.0, ge=0, description="Wall-clock pause per window, to test interruption [s]")

    inputs = {"samples": Input(Samples, "signal to encode")}
    outputs = {"events": Output(Events, "encoded events")}
    state = ("total", "emitted")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.total = 0.0
        self.emitted = 0

    def step(self, window: Window, samples: Samples) -> dict:
        time.sleep(self.params.sleep_s)
        running = self.total + np.cumsum(np.abs(samples.value))
        levels = np.floor(running / self.params.step).astype(np.int64)
        crossings = np.maximum(np.diff(levels, prepend=self.emitted), 0)
        t = np.repeat(samples.t_ns, crossings)
        if running.size:
            self.total = float(running[-1])
            self.emitted = int(levels[-1])
        n = t.size
        x = self.rng.integers(0, GEOMETRY.width_px, n).astype(np.uint16)
        y = self.rng.integers(0, GEOMETRY.height_px, n).astype(np.uint16)
        p = np.where(self.rng.random(n) < 0.5, 1, -1).astype(np.int8)
        return {"events": Events(GEOMETRY, t, t + round(self.params.latency_s * 1e9), x, y, p,
                                 np.zeros(n, np.uint8))}


class EventCounter(Block):
    """Counts events and reports the total at the end of the run."""

    type_name = "test_counter"
    is_sink = True
    inputs = {"events": Input(Events, "events to count", multi=True)}
    outputs = {"metrics": Output(Metrics, "event count")}
    state = ("count",)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.count = 0

    def step(self, window: Window, events: list) -> dict:
        self.count += sum(len(e) for e in events)
        return {"metrics": Metrics({"events_counted": self.count}, {"events_counted": "event"})}


BLOCKS = [RampSource, Scale, NoisyGain, SpikeEncoder, EventCounter]
