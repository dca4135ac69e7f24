"""Synthetic point sources of one magnitude moving at one apparent rate: the rungs of a limiting-magnitude ladder.

``n_sources`` sources of V magnitude ``magnitude`` are spread over the detector on a regular
grid (one per cell, at a random sub-pixel phase drawn with the block's generator) and move
together at ``rate_arcsec_s`` in the direction ``direction_deg`` (from +x towards +y). A
source leaving the inner area (``margin_px`` from the edges) re-enters on the opposite side:
its position is NaN at the sample where it wraps, so its path breaks there as a source leaving
the field and another entering. The photon flux at the aperture is the V zero point of
:data:`evsda.blocks.scene.radiometry.V_BAND` times ``10^(-0.4 (V + extinction_mag))``
(Pogson), in the detector's response: times the band factor of a star of colour ``b_minus_v``
(:func:`evsda.blocks.scene.spectra.star_band_factor`, 1 for a V-band detector); the magnitude
reported is ``V`` (above the atmosphere, as a catalogue gives it).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from evsda.blocks.ports import FocalPlane, PointSources, SourceKind
from evsda.blocks.scene import spectra
from evsda.blocks.scene.radiometry import V_BAND, photon_flux_of_magnitude
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, ParameterError, Window

ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0
MAX_STEP_PX = 1.0          # largest jump of a sampled source between samples [pixel] (as the scene blocks)
MIN_SPACING_PX = 12.0      # closest two injected sources may be [pixel]


class InjectedSources(Block):
    """A grid of point sources of one V magnitude moving at one apparent rate (a limiting-magnitude rung)."""

    type_name = "injected_sources"

    class Params(BlockParams):
        magnitude: float = Field(10.0, ge=-5, le=30, description="V magnitude of every source, above the "
                                                                 "atmosphere [mag]")
        n_sources: int = Field(16, ge=1, le=10_000, description="Number of sources on the detector [1]")
        rate_arcsec_s: float = Field(0.0, ge=0, description="Apparent rate of motion on the sky [arcsec s^-1]")
        direction_deg: float = Field(30.0, description="Direction of motion from +x towards +y [deg]")
        extinction_mag: float = Field(0.0, ge=0, le=10, description="Extinction between the source and the "
                                                                    "aperture [mag]")
        b_minus_v: float = Field(spectra.FIELD_STAR_B_V, ge=-0.4, le=2.4, description="Colour of the sources: "
                                 "blackbodies at the temperature of this B - V (default: the mean field star's, "
                                 "near the Sun's 0.65); sets their photons outside the V band [mag]")
        zenith_angle_deg: float | None = Field(0.0, ge=0, lt=90, description="Zenith angle of the line of sight "
                                               "for the optics' turbulence; null for an observer in space [deg]")
        margin_px: float = Field(8.0, ge=0, description="Sources stay this far inside the detector's edges [pixel]")
        cadence_s: float = Field(1e-3, gt=0, le=10, description="Sample spacing of the positions [s]")

    inputs = {"focal_plane": Input(FocalPlane, "the detector the sources are placed on")}
    outputs = {"sources": Output(PointSources, "the injected sources on the focal plane")}
    state = ("start_xy",)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.start_xy: np.ndarray | None = None      # [n_src, 2] positions at t = 0, drawn once per run

    @property
    def cadence_ns(self) -> int:
        return max(1, round(self.params.cadence_s * NS_PER_S))

    def velocity_px_s(self, focal_plane: FocalPlane) -> np.ndarray:
        """Apparent velocity ``(vx, vy)`` on the detector [pixel s^-1]."""
        rate = self.params.rate_arcsec_s / (focal_plane.pixel_scale_rad * ARCSEC_PER_RAD)
        angle = math.radians(self.params.direction_deg)
        return np.array([rate * math.cos(angle), rate * math.sin(angle)])

    def _inner(self, focal_plane: FocalPlane) -> tuple[float, float, float, float]:
        m = self.params.margin_px
        return m, m, focal_plane.width_px - 1 - 2 * m, focal_plane.height_px - 1 - 2 * m

    def _place(self, focal_plane: FocalPlane) -> np.ndarray:
        who = self.label
        x0, y0, width, height = self._inner(focal_plane)
        n = self.params.n_sources
        if width <= 0 or height <= 0:
            raise ParameterError(f"{who}: margin_px = {self.params.margin_px} leaves no room on a "
                                 f"{focal_plane.width_px} x {focal_plane.height_px} detector")
        cols = max(1, math.ceil(math.sqrt(n * width / height)))
        rows = math.ceil(n / cols)
        spacing = min(width / cols, height / rows)
        if spacing < MIN_SPACING_PX:
            raise ParameterError(f"{who}: {n} sources on a {focal_plane.width_px} x {focal_plane.height_px} detector "
                                 f"would be {spacing:.1f} pixels apart, closer than {MIN_SPACING_PX:g}: their images "
                                 f"and events would mix; use fewer sources or a larger detector")
        step = MAX_STEP_PX / max(np.abs(self.velocity_px_s(focal_plane)).max(), 1e-300)
        if self.cadence_ns / NS_PER_S > step:
            raise ParameterError(f"{who}: at {self.params.rate_arcsec_s:g} arcsec/s the sources move "
                                 f"{self.cadence_ns / NS_PER_S / step:.3g} pixels between samples "
                                 f"{self.params.cadence_s:g} s apart, more than the {MAX_STEP_PX:g} pixel a sampled "
                                 f"source may jump; sample every {step:.3g} s or faster (cadence_s here, and the "
                                 f"optics' render_rate_hz)")
        index = np.arange(n)
        cell = np.stack([(index % cols + 0.5) * width / cols, (index // cols + 0.5) * height / rows], axis=-1)
        phase = self.rng.uniform(-0.5, 0.5, size=(n, 2))
        return cell + phase + np.array([x0, y0])

    def step(self, window: Window, focal_plane: FocalPlane) -> dict:
        if self.start_xy is None:
            self.start_xy = self._place(focal_plane)
        t = window.sample_times_ns(self.cadence_ns)
        x0, y0, width, height = self._inner(focal_plane)
        v = self.velocity_px_s(focal_plane)
        seconds = t.astype(np.float64) / NS_PER_S
        travelled = seconds[:, None, None] * v[None, None, :]                    # [n_t, 1, 2]
        offset = self.start_xy[None, :, :] - np.array([x0, y0]) + travelled        # [n_t, n_src, 2]
        size = np.array([width, height])
        laps = np.floor(offset / size)
        xy = offset - laps * size + np.array([x0, y0])
        # the sample where a source wraps (its lap count changed since the previous sample) is NaN
        previous = (self.start_xy[None, :, :] - np.array([x0, y0])
                    + (seconds - self.cadence_ns / NS_PER_S)[:, None, None] * v[None, None, :])
        wrapped = (np.floor(previous / size) != laps).any(axis=-1)
        xy[wrapped] = np.nan
        n_t, n = t.size, self.params.n_sources
        response = focal_plane.spectral_response
        flux = float(photon_flux_of_magnitude(self.params.magnitude + self.params.extinction_mag, V_BAND)
                     * spectra.star_band_factor(response, self.params.b_minus_v))
        zenith = np.nan if self.params.zenith_angle_deg is None else math.radians(self.params.zenith_angle_deg)
        sources = PointSources(
            focal_plane, spectra.effective_wavelength_m(response), t, np.array([f"INJ{i:04d}" for i in range(n)]),
            np.full(n, SourceKind.SATELLITE, np.int8), xy[..., 0], xy[..., 1], np.full((n_t, n), flux),
            np.full((n_t, n), self.params.magnitude), np.full((n_t, n), np.inf), np.full(n_t, zenith))
        return {"sources": sources}
