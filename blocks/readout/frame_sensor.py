"""A conventional (CMOS/CCD) frame sensor fed the same irradiance as the event sensor.

The baseline of a trade study: the paper cites event sensors reaching 1-1.8 magnitudes
brighter than a CMOS camera on the same scene (Sec. 1, [15]); this block gives the
frames to measure that on one scene (see :mod:`.photometry`).

Frame ``k`` is exposed over ``[t_k, t_k + t_exp)`` with ``t_k = k / frame_rate`` on one
global grid from the run epoch. Per pixel, with the photon flux ``Φ(t)`` of the
:class:`Irradiance` (sample and hold) [photon s^-1 pixel^-1]:

* signal electrons ``S = QE * ∫ Φ dt`` over the exposure,
* dark electrons ``D = i_dark(T) * t_exp`` with the dark current of a silicon pixel
  versus temperature (Janesick, *Scientific Charge-Coupled Devices*, SPIE 2001, Sec. 7;
  the form ESA's Pyxel uses)::

      i_dark(T) = D_FM A_pix / q * (T / 300 K)**1.5 * exp(E_g(300 K) / (2 k 300 K) - E_g(T) / (2 k T))

  with ``D_FM`` the dark-current figure of merit at 300 K [nA cm^-2], ``A_pix`` the pixel
  area and the silicon band gap of Varshni's law with Janesick's coefficients
  ``E_g(T) = 1.1557 eV - 7.021e-4 eV/K * T**2 / (1108 K + T)``,
* collected electrons ``N ~ Poisson(S + D)`` (shot noise), clipped at the full well,
* read noise: ``N + Normal(0, σ_read)``,
* digital number ``DN = round(N / gain + bias)`` clipped to ``[0, 2**bits - 1]``.

Before the first irradiance sample of the run the first sample holds; a frame is
emitted in the window where its exposure ends.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from evsda.blocks.ports import FocalPlane, Frame, Irradiance, add_stamp
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, Window

ELEMENTARY_CHARGE_C = 1.602176634e-19      # q [C]
BOLTZMANN_EV_PER_K = 8.617333262e-5        # k [eV K^-1]
CM2_PER_M2 = 1e4
A_PER_NA = 1e-9


def silicon_band_gap_eV(temperature_K):
    """Band gap of silicon [eV]: Varshni's law with Janesick's coefficients (Scientific CCDs, 2001)."""
    t = np.asarray(temperature_K, dtype=float)
    return 1.1557 - 7.021e-4 * t**2 / (1108.0 + t)


def dark_current_e_per_s(figure_of_merit_nA_cm2: float, pixel_area_m2: float, temperature_K):
    """Dark current of one pixel [electron s^-1] (Janesick's model, normalised at 300 K)."""
    t = np.asarray(temperature_K, dtype=float)
    at_300 = figure_of_merit_nA_cm2 * A_PER_NA / ELEMENTARY_CHARGE_C * pixel_area_m2 * CM2_PER_M2
    activation = silicon_band_gap_eV(300.0) / (2 * BOLTZMANN_EV_PER_K * 300.0) \
        - silicon_band_gap_eV(t) / (2 * BOLTZMANN_EV_PER_K * t)
    return at_300 * (t / 300.0) ** 1.5 * np.exp(activation)


class FrameSensor(Block):
    """CMOS/CCD frames from photon flux: QE, shot noise, dark current vs temperature, read noise, full well, ADC."""

    type_name = "frame_sensor"

    class Params(BlockParams):
        frame_rate_hz: float = Field(10.0, gt=0, description="Frames per second [Hz]")
        exposure_s: float = Field(0.05, gt=0, description="Exposure time of each frame, at most 1 / frame_rate_hz [s]")
        quantum_efficiency: float = Field(0.6, gt=0, le=1, description="Electrons per incident photon [1]")
        read_noise_e: float = Field(2.0, ge=0, description="Read noise, rms [electron]")
        dark_current_nA_cm2: float = Field(0.1, ge=0, description="Dark-current figure of merit at 300 K "
                                                                  "(Janesick's D_FM) [nA cm^-2]")
        temperature_K: float = Field(293.15, gt=0, le=400, description="Sensor temperature [K]")
        full_well_e: float = Field(20_000, gt=0, description="Full-well capacity [electron]")
        adc_bits: int = Field(12, ge=1, le=16, description="Bits of the analogue-to-digital converter [bit]")
        gain_e_per_dn: float = Field(1.0, gt=0, description="Electrons per digital number [electron DN^-1]")
        bias_dn: float = Field(100.0, ge=0, description="Offset added before digitisation [DN]")

        @model_validator(mode="after")
        def _exposure_fits(self):
            if self.exposure_s * self.frame_rate_hz > 1 + 1e-12:
                raise ValueError(f"exposure_s ({self.exposure_s}) must not exceed the frame period "
                                 f"1 / frame_rate_hz ({1 / self.frame_rate_hz:g} s)")
            return self

    inputs = {"irradiance": Input(Irradiance, "photon flux on the pixels (the event sensor's input)")}
    outputs = {"frames": Output(Frame, "frames whose exposure ended in this window [DN]")}
    state = ("exposure", "frame_index", "held")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.exposure = []         # the frame in progress: one entry per irradiance sample it has seen
        self.frame_index = -1      # the frame in progress (-1: none)
        self.held = None           # the last irradiance sample, holding into the next window

    def frame_start_ns(self, k) -> np.ndarray:
        """Start of the exposure of frame ``k`` [ns]: ``round(k / frame_rate)``, one grid from the run epoch."""
        return np.round(np.asarray(k, np.float64) * NS_PER_S / self.params.frame_rate_hz).astype(np.int64)

    @property
    def exposure_ns(self) -> int:
        return round(self.params.exposure_s * NS_PER_S)

    def dark_e_per_s(self, fp: FocalPlane) -> float:
        """Dark current of one pixel at the sensor's temperature [electron s^-1]."""
        return float(dark_current_e_per_s(self.params.dark_current_nA_cm2, fp.pixel_area_m2, self.params.temperature_K))

    def step(self, window: Window, irradiance: Irradiance) -> dict:
        fp = irradiance.focal_plane
        pieces = self._pieces(window, irradiance)
        period_ns = NS_PER_S / self.params.frame_rate_hz
        starts, images = [], []
        for k in range(max(0, int(window.start_ns // period_ns) - 1), int(window.stop_ns // period_ns) + 2):
            t0 = int(self.frame_start_ns(k))
            t1 = t0 + self.exposure_ns
            if t1 <= window.start_ns or t0 >= window.stop_ns:
                continue
            if k != self.frame_index:
                self.frame_index, self.exposure = k, []
            self._collect(pieces, max(t0, window.start_ns), min(t1, window.stop_ns))
            if t1 <= window.stop_ns:
                starts.append(t0)
                images.append(self._read_out(fp))
                self.frame_index, self.exposure = -1, []
        image = np.stack(images) if images else np.zeros((0, *fp.shape), np.uint16)
        return {"frames": Frame(fp, np.asarray(starts, np.int64), self.exposure_ns, image)}

    def _pieces(self, window: Window, irr: Irradiance) -> list[tuple[int, int, dict]]:
        """``(from_ns, to_ns, sample)``: stretches of constant flux covering the window (sample and hold)."""
        t = np.asarray(irr.t_ns, np.int64)
        samples = [{"t_ns": int(t[j]), "background": float(irr.background[j]),
                    "origin": np.asarray(irr.stamp_origin[j]), "flux": np.asarray(irr.stamp_flux[j])}
                   for j in range(t.size)]
        pieces = []
        first = int(t[0]) if t.size else window.stop_ns
        if first > window.start_ns:
            before = self.held if self.held is not None else (samples[0] if samples else None)
            if before is not None:
                pieces.append((window.start_ns, first, before))
        for j, sample in enumerate(samples):
            end = int(t[j + 1]) if j + 1 < t.size else window.stop_ns
            pieces.append((max(sample["t_ns"], window.start_ns), end, sample))
        if samples:
            self.held = samples[-1]
        return pieces

    def _collect(self, pieces, t0: int, t1: int) -> None:
        """Record how long each sample lit the frame in progress within ``[t0, t1)`` (integer ns, so
        a frame straddling windows sums exactly what one window would)."""
        for a, b, sample in pieces:
            ns = min(b, t1) - max(a, t0)
            if ns <= 0:
                continue
            if self.exposure and self.exposure[-1]["t_ns"] == sample["t_ns"]:
                self.exposure[-1]["ns"] += ns
            else:
                self.exposure.append({**sample, "ns": ns})

    def _read_out(self, fp: FocalPlane) -> np.ndarray:
        p = self.params
        photons = np.zeros(fp.shape)
        background = 0.0
        for entry in self.exposure:                  # photons = sum of flux x time [photon pixel^-1]
            dt_s = entry["ns"] / NS_PER_S
            background += entry["background"] * dt_s
            for s in range(entry["flux"].shape[0]):
                add_stamp(photons, entry["flux"][s] * dt_s, int(entry["origin"][s][0]), int(entry["origin"][s][1]))
        mean_e = p.quantum_efficiency * (photons + background) + self.dark_e_per_s(fp) * p.exposure_s
        electrons = np.minimum(self.rng.poisson(mean_e).astype(np.float64), p.full_well_e)
        if p.read_noise_e > 0:
            electrons += self.rng.normal(0.0, p.read_noise_e, fp.shape)
        dn = np.rint(electrons / p.gain_e_per_dn + p.bias_dn)
        return np.clip(dn, 0, 2**p.adc_bits - 1).astype(np.uint16)
