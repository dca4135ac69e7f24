"""The ``pupil_fft`` path: the far-field image of the aperture times ``exp(i phase)``.

The turbulent phase is the sum of every layer's screen along the straight line of sight
(near-field / geometric-optics approximation, :mod:`.paths`): FFT screens with
subharmonics (:mod:`.layer_screen`) or Karhunen-Loeve Zernike modes (:mod:`.modal_screen`),
read on each layer's footprint under frozen flow (:mod:`.imaging`). Where the renderer's frame path holds, a walk
and its stamps are one compiled call (:func:`walk_and_stamp`): each source's frames are stamped as soon as its last
layer has read them, while its phases are still in cache, with no interpreter between.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from .layer_screen import LayerScreen, accumulate_layers
from .modal_screen import ModalScreen, pupil_modes
from .render import _stamp_frames
from .screen_kernels import layer_grids, layer_grids_drifting, walk_segments

if TYPE_CHECKING:
    from .imaging import Imager


def layer_columns(layers) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The layers' altitudes (L, 1) [m], winds (L, 1, 2) [m/s] and ``Cn^2 dh`` (L, 1) [m^(1/3)], as
    :meth:`.Imager.footprints_at` and the screens' weights take them."""
    return (np.array([layer.altitude_m for layer in layers])[:, None],
            np.array([layer.wind_m_s for layer in layers])[:, None, :],
            np.array([layer.cn2_dh for layer in layers])[:, None])


class PupilPath:
    """Pupil-plane phase screens of each source and the stamps they give; sizing and sampling come from ``imager``."""

    def __init__(self, imager: Imager, screen_method: str, screen_update: str, n_zernike_modes: int):
        self.imager = imager
        self.screen_method, self.screen_update, self.n_zernike_modes = screen_method, screen_update, n_zernike_modes
        self.screens: dict[str, list[LayerScreen]] = {}
        self.modal_screens: dict[str, list[ModalScreen]] = {}
        self._modes: np.ndarray | None = None
        self._layers: tuple | None = None          # :meth:`_layer_set`

    def _layer_screens(self, source: str) -> list[LayerScreen]:
        if source not in self.screens:
            g = self.imager.geometry
            self.screens[source] = [
                LayerScreen(n, step, (*self.imager.source_seed(source, 0), i), L0=self.imager.outer_scale_m,
                            update=self.screen_update)
                for i, (n, step) in enumerate(zip(g.layer_n, g.layer_delta_m))]
        return self.screens[source]

    def _modal_screens(self, source: str) -> list[ModalScreen]:
        if source not in self.modal_screens:
            self.modal_screens[source] = [
                ModalScreen((*self.imager.source_seed(source, 0), i), self.imager.telescope.diameter_m,
                            self.n_zernike_modes)
                for i in range(len(self.imager.atmosphere.layers))]
        return self.modal_screens[source]

    @property
    def pupil_modes(self) -> np.ndarray:
        """Zernike modes of modal screens on the pupil grid, flattened ``(n_modes, n_pupil^2)`` [1]."""
        if self._modes is None:
            g = self.imager.geometry
            modes = pupil_modes(self.n_zernike_modes, g.n_pupil, g.delta_m, self.imager.telescope.diameter_m)
            self._modes = modes.reshape(self.n_zernike_modes, -1)
        return self._modes

    def turbulent_phase(self, source: str, t_s, sight, zenith_rad, range_m) -> np.ndarray:
        """Phase [rad] over the pupil grid (F, n, n): the sum of every layer's screen along the line of sight
        (``sight`` (F, 2): :meth:`.Imager.sight`); FFT screens give a transposed view (the stamps read it as it is)."""
        g = self.imager.geometry
        frames = len(t_s)
        shape = (frames, g.n_pupil, g.n_pupil)          # the phase transposed: (F, x, y), see LayerScreen.accumulate
        if not self.imager.atmosphere:
            return np.zeros(shape)
        epochs = self.imager.epochs_of(t_s)
        if self.screen_method == "zernike":
            return self._modal_phase(source, t_s, sight, zenith_rad, range_m, epochs)
        if not self._layer_set()[0]:
            return np.zeros(shape).transpose(0, 2, 1)
        return self._phases([source], t_s, epochs, np.asarray(sight)[None], np.asarray(zenith_rad)[None],
                            np.asarray(range_m)[None])[0]

    def _layer_set(self) -> tuple:
        """The turbulent layers' indices, altitudes (L,) [m], winds (L, 2) [m/s], ``Cn^2 dh`` (L,) [m^(1/3)], the
        pupil's sample positions [m] and the screens' spacings (L,) [m]: the same for every source and window (made at
        the first render, once the geometry is fixed)."""
        if self._layers is None:
            g = self.imager.geometry
            chosen = [i for i, layer in enumerate(self.imager.atmosphere.layers) if layer.cn2_dh > 0]
            self._layers = (chosen, *(np.ascontiguousarray(c[:, 0]) for c in layer_columns(
                                [self.imager.atmosphere.layers[i] for i in chosen])),
                            (np.arange(g.n_pupil) - g.n_pupil // 2) * g.delta_m,
                            np.array([float(g.layer_delta_m[i]) for i in chosen]))
        return self._layers

    def _phases(self, sources: list[str], t_s, epochs, sight, zenith_rad, range_m, stamping: tuple | None = None):
        """:meth:`turbulent_phase` of several sources at the same times ``t_s`` (F,) (``epochs``: their screen
        epochs), ``sight`` (S, F, 2), ``zenith_rad`` and ``range_m`` (S, F): (S, F, n, n), transposed views; every
        source's layers in one walk (:func:`.accumulate_layers` with an output a source), each phase the same
        numbers as the source's alone. With ``stamping`` (:meth:`.PupilRenderer.frame_arguments` of the S F frames,
        source by source), the walk stamps them too (:func:`walk_and_stamp`); returns the phases and whether it
        did."""
        g = self.imager.geometry
        chosen, altitude, wind, cn2, xp, spacing = self._layer_set()
        count, frames, layers = len(sources), len(t_s), len(chosen)
        k2 = (2 * np.pi / self.imager.wavelength) ** 2
        t_s = np.ascontiguousarray(t_s, dtype=float)
        screens = []
        # every layer's footprint grids [samples] (S L, F, n) and weights r0^(-5/6) (S L, F), a source's in one
        # compiled pass, the footprints as :meth:`.Imager.footprints_at` makes them (the screens are drawn for r0 = 1 m)
        rows, cols = np.empty((2, count * layers, frames, g.n_pupil))
        weight = np.empty((count * layers, frames))
        # every source's lines of sight, cosines and ranges at once (element by element: each source's numbers)
        sight, range_m = np.ascontiguousarray(sight, dtype=float), np.ascontiguousarray(range_m, dtype=float)
        turbulent = np.isfinite(zenith_rad)
        cosine = np.cos(np.where(turbulent, zenith_rad, 0.0))
        for k, source in enumerate(sources):
            every = self._layer_screens(source)
            screens += [every[i] for i in chosen]
            part = slice(k * layers, (k + 1) * layers)
            flow = self.imager.source_flow(source, t_s, sight[k])      # equivalent layers: the source's own winds
            if flow is not None and flow[1] is None:                    # follow_sight_rate: its footprints' drifts
                layer_grids_drifting(altitude, np.ascontiguousarray(flow[0][chosen]), cn2, spacing, sight[k],
                                     cosine[k], range_m[k], turbulent[k], xp, k2, rows[part], cols[part], weight[part])
                continue
            winds, times = (wind, t_s) if flow is None else (np.ascontiguousarray(flow[0][chosen]), flow[1])
            layer_grids(altitude, winds, cn2, spacing, times, sight[k], cosine[k], range_m[k], turbulent[k], xp, k2,
                        rows[part], cols[part], weight[part])
        phase_t = np.empty((count, frames, g.n_pupil, g.n_pupil))   # written by each first layer's reads: no zeroing
        stamped = accumulate_layers(screens, rows, cols, epochs, weight, phase_t, fresh=True,     # one walk
                                    outputs=np.repeat(np.arange(count, dtype=np.int64), layers),
                                    then=None if stamping is None else (walk_and_stamp, stamping))
        phase = phase_t.transpose(0, 1, 3, 2)
        return phase if stamping is None else (phase, stamped is True)

    def _modal_phase(self, source, t_s, sight, zenith_rad, range_m, epochs) -> np.ndarray:
        """Phase [rad] (F, n, n) from modal screens (:mod:`.modal_screen`): Zernike modes over each footprint."""
        g = self.imager.geometry
        turbulent = np.isfinite(zenith_rad)
        zenith = np.where(turbulent, zenith_rad, 0.0)
        k2 = (2 * np.pi / self.imager.wavelength) ** 2
        coefficients = np.zeros((len(t_s), self.n_zernike_modes))
        for layer, screen in zip(self.imager.atmosphere.layers, self._modal_screens(source)):
            if layer.cn2_dh <= 0:
                continue
            centre, scale = self.imager.footprints(layer, t_s, sight, zenith, range_m)
            # r0^(-5/6) of this layer times (footprint diameter s D)^(5/6): Noll's covariance for s D / r0
            weight = (np.sqrt(0.423 * k2 / np.cos(zenith) * layer.cn2_dh)
                      * (scale * self.imager.telescope.diameter_m) ** (5 / 6))
            coefficients += np.where(turbulent, weight, 0.0)[:, None] * screen.coefficients(centre, epochs)
        return (coefficients @ self.pupil_modes).reshape(len(t_s), g.n_pupil, g.n_pupil)

    def render(self, source, t_s, sight, zenith_rad, range_m, offset) -> np.ndarray:
        if self.batches():                  # a walk and its stamps in one call (the same numbers as below)
            return self.render_many([source], t_s, np.asarray(sight)[None], np.asarray(zenith_rad)[None],
                                    np.asarray(range_m)[None], np.asarray(offset)[None])[0]
        phase = self.turbulent_phase(source, t_s, sight, zenith_rad, range_m)
        return self.imager.pupil_renderer.stamps(self.imager.pupil_amplitude, phase, offset,
                                                 self.imager.defocus_curvature(range_m))

    def batches(self) -> bool:
        """Whether :meth:`render_many` can take sources together: FFT screens in a turbulent atmosphere."""
        return self.screen_method == "fft" and bool(self.imager.atmosphere) and bool(self._layer_set()[0])

    def render_many(self, sources: list[str], t_s, sight, zenith_rad, range_m, offset) -> np.ndarray:
        """:meth:`render` of several sources at the same times ``t_s`` (F,) (``sight``, ``offset`` (S, F, 2),
        ``zenith_rad``, ``range_m`` (S, F)): stamps (S, F, M, M), each source's those of its own call, in one walk of
        every source's screens and one :meth:`.PupilRenderer.stamps` call (:meth:`batches` must hold), both in one
        compiled call where the renderer's frame path holds (:func:`walk_and_stamp`)."""
        count, frames = zenith_rad.shape
        g, renderer = self.imager.geometry, self.imager.pupil_renderer
        size = renderer.sampler.size
        amplitude, offset = self.imager.pupil_amplitude, offset.reshape(count * frames, 2)
        curvature = self.imager.defocus_curvature(range_m.reshape(-1))
        stamps = np.empty((count * frames, size, size))
        stamping = renderer.frame_arguments(amplitude, offset, curvature, stamps)
        phase = self._phases(sources, t_s, self.imager.epochs_of(t_s), sight, zenith_rad, range_m, stamping)
        if stamping is not None:
            phase, stamped = phase
            if stamped:
                return stamps.reshape(count, frames, size, size)
        stamps = renderer.stamps(amplitude, phase.reshape(count * frames, g.n_pupil, g.n_pupil), offset, curvature)
        return stamps.reshape(count, frames, *stamps.shape[1:])

    # -- checkpoint -------------------------------------------------------------------------------
    def state(self) -> dict:
        return {key: [s.state() for s in screens] for key, screens in self.screens.items()}

    def set_state(self, state: dict) -> None:
        """Restore the layer screens (call once the coordinator's geometry is set)."""
        self._modes = self._layers = None
        self.screens = {}
        for key, states in state.items():
            screens = self._layer_screens(key)
            for screen, s in zip(screens, states):
                screen.set_state(s)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def walk_and_stamp(layout, windows, origins, sides, before, edges, noise, states, draw, unscaled, ki, wi, fi, a, b,
                   stencil_rows, stencil_back, operator_at, frame_ops, rows, cols, weight, out_t, layer_out, assign,
                   low, amplitudes, frequencies, mode_at, stride, phasors, slots, curvature, r2, ky, kx, x, amplitude_t,
                   b_psf, b_t, factor, area, stamps, cosine, sine, grid, psf, half, image, scratch, twr, twi):
    """:func:`.screen_kernels.walk_segments` (its arguments first: the phases ``out_t`` (S, F, nx, ny), one output a
    source) and :func:`.render._stamp_frames` of every output's F frames (the rest:
    :meth:`.PupilRenderer.frame_arguments` of the S F frames, output by output, into ``stamps`` (S F, M, M)) in one
    call: each output stamped as soon as its
    last segment is walked (a layer's segments are consecutive and all of one output), so its phases are still in
    cache; outputs no segment reads (their zeros) at the end. The same walk and the same stamps, frame by frame, as the
    two calls one after the other. Returns the first segment that read outside its canvas (-1: none; then nothing
    more is made) and whether every frame was stamped (False once a frame's tilted phase is beyond the compiled sine's
    range: the caller then takes :meth:`.PupilRenderer.stamps`)."""
    outputs, frames = out_t.shape[0], out_t.shape[1]
    last = np.full(outputs, -1, np.int64)
    for s in range(layout.shape[0]):
        last[layer_out[layout[s, 0]]] = s
    stamped, s0 = True, 0
    for s in range(layout.shape[0]):
        k = layer_out[layout[s, 0]]
        if last[k] != s:
            continue
        bad = walk_segments(layout[s0:s + 1], windows, origins[s0:s + 1], sides, before, edges, noise,
                            states[s0:s + 1], draw, unscaled, ki, wi, fi, a, b, stencil_rows, stencil_back, operator_at,
                            frame_ops, rows, cols, weight, out_t, layer_out, assign, low, amplitudes, frequencies,
                            mode_at, stride, phasors, slots)
        if bad >= 0:
            return s0 + bad, False
        s0 = s + 1
        stamped = stamped and _stamp_output(k, frames, out_t, curvature, r2, ky, kx, x, amplitude_t, b_psf, b_t,
                                            factor, area, stamps, cosine, sine, grid, psf, half, image, scratch, twr,
                                            twi)
    for k in range(outputs):
        if last[k] < 0:
            stamped = stamped and _stamp_output(k, frames, out_t, curvature, r2, ky, kx, x, amplitude_t, b_psf, b_t,
                                                factor, area, stamps, cosine, sine, grid, psf, half, image, scratch,
                                                twr, twi)
    return -1, stamped


@numba.njit(error_model="numpy", nogil=True)
def _stamp_output(k, frames, out_t, curvature, r2, ky, kx, x, amplitude_t, b_psf, b_t, factor, area, stamps, cosine,
                  sine, grid, psf, half, image, scratch, twr, twi):
    """:func:`.render._stamp_frames` of output ``k``'s ``frames`` frames (:func:`walk_and_stamp`'s arguments)."""
    f = slice(k * frames, (k + 1) * frames)
    return _stamp_frames(out_t[k], curvature[f], r2, ky[f], kx[f], x, amplitude_t, b_psf, b_t, factor, area,
                         stamps[f], cosine, sine, grid, psf, half, image, scratch, twr, twi)
