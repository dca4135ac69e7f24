"""The DVS pixel array as a block: irradiance in, triggered events out."""

from __future__ import annotations

import numpy as np

from evsda.blocks.ports import FocalPlane, Irradiance, TriggeredEvents
from evsda.graph import Block, Footprint, InputError, Input, Output, RunInfo, Window, compile_ahead

from . import jitter, reference, warm_up
from .eventdriven import EventDrivenPixels
from .eventlog import EventLog
from .model import PixelModel
from .params import DvsPixelParams
from .sampling import (DENSE_FRACTION, dense_block_rows, dense_frames, dense_stamps, has_stamps, live_stamps,
                       sample_steps, stamp_coverage, stamp_pixels, window_steps)

#: memory the pixel block holds per sensor pixel, for the limits checked before a run [byte]
STATE_BYTES_PER_PIXEL = 400


class DvsPixel(Block):
    """Dynamic-vision-sensor pixels: photon flux to triggered ON/OFF events (paper Sec. 2.3-2.5, Eq. 12-21).

    Each pixel converts its photon flux to a photocurrent (Eq. 12-13), adds the
    temperature-dependent dark current (Eq. 15, Arrhenius form), takes the lin-log
    response (Eq. 14) through an intensity-dependent low-pass filter (Eq. 16) and compares
    it with its memorised value against per-pixel ON/OFF thresholds (Eq. 17), one event
    per pixel per step. Junction leak (Eq. 18), parasitic photocurrent (Eq. 19) and shot
    noise (Eq. 20) add noise events; a refractory period (Eq. 21) follows every event;
    ``timing_jitter_s`` delays each event's time stamp at random (:mod:`.jitter`).
    Every event carries its cause (signal, leak, parasitic, shot) and each window reports
    ``n_loss``: the events the pixels could not emit -- Eq. 17's owed events that the input
    took back before the pixel could compare again, and shot-noise events that arrived
    while a pixel was blind (see :mod:`.comparator`).

    ``implementation='reference'`` steps every pixel at every ``time_step_s`` exactly as
    the paper writes it; ``'fast'`` (default) computes the same process event by event
    (closed-form first-crossing steps, exact geometric shot-noise waiting times), at a
    cost proportional to the events and input changes, so a full 1280x720 sensor runs
    faster than real time. Results do not depend on the window length.

    Currents enter Eqs. 14, 16 and 20 normalised by ``reference_current_A`` (the
    paper's digital-number scale made explicit); thresholds are in ln of current.

    Example::

        pixel = DvsPixel(temperature_K=280, seed=3)
        out = pixel.step(Window.from_seconds(0, 0.1), irradiance=irr)["events"]
    """

    type_name = "dvs_pixel"
    Params = DvsPixelParams
    inputs = {"irradiance": Input(Irradiance, "photon flux on every pixel: background plus stamps [photon s^-1 pixel^-1]")}
    outputs = {"events": Output(TriggeredEvents, "events as the pixels trigger them, with cause and N_loss")}
    state = ("pixels", "held_background", "sensor", "late", "jitter_key")
    _ahead = None           # (set in __init__) a class default too: blocks pickled before it still step

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.pixels: dict | None = None          # per-pixel state (see reference.new_state / EventDrivenPixels.new_state)
        self.held_background: float | None = None
        self.sensor: dict | None = None          # geometry and band the state belongs to
        self.late: dict | None = None            # events delayed past the last window's end (timing jitter)
        self.jitter_key: int | None = None       # counter-RNG key of the timing jitter
        self._model: PixelModel | None = None
        self._engine: EventDrivenPixels | None = None
        #: input path of the fast implementation: 'auto' (from the input), 'sparse' or 'dense' (tests, benchmarks)
        self.input_path = "auto"
        self._ahead: compile_ahead.Ahead | None = None      # the compiled loops being built in a second process

    def setup(self, run: RunInfo) -> None:
        super().setup(run)
        if self.params.implementation == "fast":    # with an empty Numba cache: compiled while the optics compile
            self._ahead = compile_ahead.start(warm_up.TASKS, warm_up.MODULES)

    def set_state(self, state) -> None:
        super().set_state(state)
        self._model = self._engine = None

    # -- one window ----------------------------------------------------------------------------
    def step(self, window: Window, irradiance: Irradiance) -> dict:
        self.check_inputs({"irradiance": irradiance})
        if self._ahead is not None:
            self._ahead.wait()
            self._ahead = None
        model = self._model_for(irradiance)
        fp = irradiance.focal_plane
        dt_ns = model.dt_ns
        n_start, n_end = window_steps(window.start_ns, window.stop_ns, dt_ns)
        samples, steps = sample_steps(irradiance, dt_ns, n_start, n_end)
        log = EventLog()
        if self.pixels is None:
            self._start(model, irradiance, samples, n_start)
        if self.params.implementation == "reference":
            reference.run(model, self.pixels, n_start, n_end, steps, dense_frames(irradiance, samples),
                          self.rng, log)
        else:
            self._run_fast(model, irradiance, samples, steps, n_end, log)
        if samples.size:
            self.held_background = float(irradiance.background[samples[-1]])
        events = log.to_port(fp, dt_ns)
        if self.params.timing_jitter_s > 0:
            events, self.late = jitter.jittered(events, self.late, window.stop_ns, self.jitter_key,
                                                self.params.timing_jitter_s, dt_ns)
        return {"events": events}

    def footprint(self, run: RunInfo) -> Footprint:
        """Memory per sensor pixel: the event-driven state (12 floats and 7 integers per pixel, a 4-byte wake code) and its
        start-up temporaries peak at 360 B/pixel (tracemalloc, 400 x 400 sensor); 400 B/pixel stated."""
        return Footprint(bytes_per_pixel=STATE_BYTES_PER_PIXEL)

    def pixel_field(self, name: str) -> np.ndarray:
        """A copy of one per-pixel state field, as a flat array in row-major pixel order.

        Names: ``flux`` [photon s^-1], ``filtered`` (L) and ``memorised`` (M) [1],
        ``theta_on``, ``theta_off`` [1], ``ready`` (first step the pixel may fire again).
        """
        if self.pixels is None:
            raise RuntimeError(f"{self.label} has no pixel state before its first step")
        if self.params.implementation == "reference":
            return np.array(self.pixels[name], copy=True)
        if self._engine is not None:
            self._engine.take_pending()
        return EventDrivenPixels.field(self.pixels, name)

    # -- helpers -------------------------------------------------------------------------------
    def _model_for(self, irradiance: Irradiance) -> PixelModel:
        fp = irradiance.focal_plane
        sensor = {"width_px": int(fp.width_px), "height_px": int(fp.height_px),
                  "pixel_pitch_m": float(fp.pixel_pitch_m), "wavelength_m": float(irradiance.wavelength_m)}
        if self.sensor is not None and self.sensor != sensor:
            raise InputError(f"{self.label} input 'irradiance' changed focal plane or band during the run "
                             f"(was {self.sensor}, now {sensor}); a pixel array cannot change its geometry")
        if not (sensor["pixel_pitch_m"] > 0 and sensor["wavelength_m"] > 0):
            raise InputError(f"{self.label} input 'irradiance' needs a positive pixel pitch and wavelength, "
                             f"got {sensor['pixel_pitch_m']} m and {sensor['wavelength_m']} m")
        self.sensor = sensor
        if self._model is None:
            self._model = PixelModel(self.params, fp.pixel_area_m2, sensor["wavelength_m"])
        return self._model

    def _start(self, model: PixelModel, irradiance: Irradiance, samples: np.ndarray, n_start: int) -> None:
        if len(irradiance.t_ns) == 0:
            raise InputError(f"{self.label} input 'irradiance' has no samples in its first window; "
                             f"the pixels need an initial photon flux")
        first = samples[:1] if samples.size else np.array([0])
        flux = dense_frames(irradiance, first)[0]
        if not np.all(np.isfinite(flux)) or np.any(flux < 0):
            raise InputError(f"{self.label} input 'irradiance' has negative or non-finite photon flux")
        if self.params.implementation == "reference":
            self.pixels = reference.new_state(model, flux, self.rng)
        else:
            self.pixels = EventDrivenPixels.new_state(model, flux, self.rng, n_start,
                                                      float(irradiance.background[first[0]]))
        self.held_background = float(irradiance.background[first[0]])
        if self.params.timing_jitter_s > 0:
            self.jitter_key = int(self.rng.integers(0, 2**63 - 1))

    def _run_fast(self, model, irradiance, samples, steps, n_end, log) -> None:
        if self._engine is None or self._engine.s is not self.pixels:
            self._engine = EventDrivenPixels(model, self.pixels)
        background = np.asarray(irradiance.background, dtype=float)[samples]
        # the live stamps, found once for both the path choice and the sparse path
        live = live_stamps(irradiance, samples) if has_stamps(irradiance, samples) else None
        if self._dense(irradiance, samples, live):
            height, width = irradiance.focal_plane.shape
            self._engine.run_dense_window(background, steps, lambda r0, r1: dense_stamps(irradiance, samples, r0, r1),
                                          dense_block_rows(irradiance, samples), n_end, log, height, width)
        else:
            self._engine.run_window(self.held_background, background, steps, stamp_pixels(irradiance, samples, live),
                                    n_end, log)

    def _dense(self, irradiance: Irradiance, samples: np.ndarray, live) -> bool:
        """Whether this window's input takes the dense path (``input_path``, or ``auto``: stamps covering
        at least ``DENSE_FRACTION`` of the sensor per sample); both paths give identical events."""
        path = self.input_path
        if path == "auto":
            return samples.size > 1 and live is not None and stamp_coverage(irradiance, samples, live) >= DENSE_FRACTION
        return path == "dense" and samples.size > 0
