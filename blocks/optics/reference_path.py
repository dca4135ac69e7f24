"""The ``reference`` path: paper Eq. 3-4, split-step Fresnel propagation from the source
through every layer's screen to the aperture (:mod:`.propagation`, grids from :mod:`.sampling`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import erf

from .layer_screen import LayerScreen
from .propagation import propagate_point_source
from .sampling import PropagationGeometry, PropagationGrid, check_grid, choose_grid, planes_for
from .screen_kernels import MARGIN

if TYPE_CHECKING:
    from .imaging import Imager

#: a source farther than this is propagated from this range (its wavefront curvature over any
#: aperture, Fresnel number D^2 / (lambda R) < 1e-3, is negligible) [m]
FAR_RANGE_M = 1e9


class ReferencePath:
    """Fresnel propagation (Eq. 3-4) with each source's own screens; sizing and sampling come from ``imager``."""

    def __init__(self, imager: Imager, grid_size: int | None):
        self.imager, self.grid_size = imager, grid_size
        self.screens: dict[str, dict[int, LayerScreen]] = {}

    def grid(self, zenith_rad: float, range_m: float) -> tuple[PropagationGeometry, PropagationGrid, dict]:
        """The propagation grid for a source at ``range_m`` and the plane index of each layer."""
        g = self.imager.geometry
        distance = min(range_m, FAR_RANGE_M)
        layers = self.imager.atmosphere.layers if self.imager.turbulent(zenith_rad) else ()
        slant = {i: layer.altitude_m / np.cos(zenith_rad) for i, layer in enumerate(layers) if layer.cn2_dh > 0}
        slant = {i: s for i, s in slant.items() if s < distance}
        geometry = PropagationGeometry(self.imager.wavelength, distance, self.imager.telescope.diameter_m,
                                       r0_m=self.imager.r0(zenith_rad),
                                       turbulence_length_m=max(slant.values(), default=0.0))
        layer_planes = {i: distance - s for i, s in slant.items()}
        if self.grid_size is None:
            grid = choose_grid(geometry, g.delta_m, tuple(layer_planes.values()))
        else:
            free = choose_grid(geometry, g.delta_m, tuple(layer_planes.values()))
            grid = PropagationGrid(int(self.grid_size), free.delta1_m, g.delta_m,
                                   planes_for(geometry, int(self.grid_size), free.delta1_m, g.delta_m,
                                           tuple(layer_planes.values())))
            check_grid(geometry, grid, f"{self.imager.label} parameter 'grid_size'")
        index = {i: grid.planes_m.index(z) + 1 for i, z in layer_planes.items()}
        return geometry, grid, index

    def field(self, source: str, t_s: float, sight: np.ndarray, zenith_rad: float, range_m: float,
              slack: float = 1.3, keep_twin: bool = False, aperture: bool = True,
              needed: Callable[[], bool] | None = None) -> np.ndarray | None:
        """Pupil field (n, n) of paper Eq. 3-4 for one instant, normalised to the vacuum amplitude (``sight`` (2,):
        where the line of sight crosses the layers, :meth:`.Imager.sight`).

        New screens are ``slack`` times the grid wide and keep their twins with ``keep_twin`` (:meth:`_screens`).
        Without ``aperture``, the field that reaches the aperture (times ``imager.pupil_amplitude`` it is the
        field, the same numbers): made without the pupil renderer (the path probes make it on one thread while
        another makes the renderer). ``needed`` is asked before each layer's screen and before the propagation: once
        it says False, the field is left unmade and None returned (a path probe's pair that a verdict dropped)."""
        g = self.imager.geometry
        geometry, grid, index = self.grid(zenith_rad, range_m)
        distance = geometry.distance_m
        spacing = grid.spacings_m
        screens = {}
        if index:
            per_layer = self._screens(source, grid, index, slack, keep_twin)
            k2 = (2 * np.pi / self.imager.wavelength) ** 2
            for i, plane in index.items():
                if needed is not None and not needed():
                    return None
                layer, screen = self.imager.atmosphere.layers[i], per_layer[i]
                centre, _ = self.imager.footprints(layer, np.array([t_s]), np.reshape(sight, (1, 2)),
                                                   np.array([zenith_rad]), np.array([np.inf]))
                axis = (np.arange(grid.n) - grid.n // 2) * spacing[plane]
                rows = ((centre[0, 1] + axis) / screen.delta)[None]
                cols = ((centre[0, 0] + axis) / screen.delta)[None]
                screen.cover(np.array([rows[0, 0], cols[0, 0]]), np.array([rows[0, -1], cols[0, -1]]),
                             int(self.imager.epochs_of(np.array([t_s]))[0]))
                weight = np.sqrt(0.423 * k2 / np.cos(zenith_rad) * layer.cn2_dh)
                screens[plane] = weight * screen.sample(rows, cols)[0]
        if needed is not None and not needed():
            return None
        # the FFTs on the calling thread: sources, and the path probes' frames, are rendered on every core; only the
        # pupil's centred n_pupil x n_pupil of the observation plane is made
        pupil = propagate_point_source(grid.n, grid.delta1_m, grid.deltan_m, self.imager.wavelength, distance,
                                       geometry.roi_m, grid.planes_m, screens,
                                       collimate=distance if self.imager.focus == "source" else np.inf, workers=1,
                                       window=g.n_pupil)
        # divide by the vacuum field on axis, erf(2 pi)^2 / (i lambda Z) (propagation.point_source_vacuum_field)
        pupil = pupil * (1j * self.imager.wavelength * distance / erf(2 * np.pi) ** 2)
        return pupil * self.imager.pupil_amplitude if aperture else pupil

    def pupil_phase(self, source: str, t_s: float, sight: np.ndarray, zenith_rad: float,
                              range_m: float) -> np.ndarray:
        """The pupil path's phase (n, n) [rad] for the screens the reference path used at this instant.

        Each layer's screen is read where the straight line from the source to each pupil
        point crosses it (``(1 - L/R)`` of the pupil coordinate): the geometric-optics
        projection that the pupil path makes, so that the two paths can be compared frame
        by frame (:mod:`.paths`, benchmarks/optics_paths.py). Call after :meth:`field`.
        """
        g = self.imager.geometry
        phase = self.imager.defocus(np.array([range_m]))[0] * np.ones((g.n_pupil, g.n_pupil))
        if not self.imager.turbulent(zenith_rad):
            return phase
        geometry, grid, index = self.grid(zenith_rad, range_m)
        per_layer = self.screens[source]
        k2 = (2 * np.pi / self.imager.wavelength) ** 2
        xp = (np.arange(g.n_pupil) - g.n_pupil // 2) * g.delta_m
        for i in index:
            layer, screen = self.imager.atmosphere.layers[i], per_layer[i]
            centre, scale = self.imager.footprints(layer, np.array([t_s]), np.reshape(sight, (1, 2)),
                                                   np.array([zenith_rad]), np.array([geometry.distance_m]))
            rows = ((centre[0, 1] + scale[0] * xp) / screen.delta)[None]
            cols = ((centre[0, 0] + scale[0] * xp) / screen.delta)[None]
            weight = np.sqrt(0.423 * k2 / np.cos(zenith_rad) * layer.cn2_dh)
            phase = phase + weight * screen.sample(rows, cols)[0]
        return phase

    def _screens(self, source: str, grid: PropagationGrid, index: dict,
                           slack: float = 1.3, keep_twin: bool = False) -> dict[int, LayerScreen]:
        """Each layer's screen for the reference grid: ``slack`` times the grid and its margins wide
        (room to move before an extension; path probes, which read one frame, take 1); ``keep_twin``:
        new screens keep the other half of their FFT draw (:meth:`.LayerScreen.twin`)."""
        spacing = grid.spacings_m
        screens = self.screens.setdefault(source, {})
        for i, plane in index.items():
            step = screens[i].delta if i in screens else float(spacing[plane])
            needed = grid.n * spacing[plane] / step + 2 * MARGIN + 4
            if i not in screens or screens[i].n < needed:
                n = int(np.ceil(slack * (grid.n + 2 * MARGIN + 4)))
                n += n % 2
                L0 = self.imager.outer_scale_m
                screens[i] = LayerScreen(n, float(spacing[plane]), (*self.imager.source_seed(source, 1), i), L0=L0,
                                         update="extend" if np.isfinite(L0) else "regenerate", keep_twin=keep_twin)
        return screens

    def probe_pair(self, names: tuple[str, str], zenith_rad: float, range_m: float,
                   needed: Callable[[], bool] | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Pupil field before the aperture (:meth:`field` without ``aperture``) and pupil-path phase
        (:meth:`pupil_phase`) of two independent frames of the path chooser's probe, at ``t = 0`` on the
        boresight, on screens just wide enough (``slack`` 1) named ``names``, dropped after use. The second
        frame's screens are the imaginary halves of the first's FFT draws (:meth:`.LayerScreen.twin`; screens cut
        from FFT screens, wider than :data:`.layer_screen.SELF_START_SAMPLES`; narrower ones are drawn for each
        frame): two frames for one frame's draws and transforms. The frames come one at a time: a probe that
        needs no second frame closes the iterator after the first; one whose ``needed`` says False while a frame is
        made (:meth:`field`) ends without that frame."""
        sight = np.zeros(2)
        first, second = names
        try:
            field = self.field(first, 0.0, sight, zenith_rad, range_m, slack=1.0, keep_twin=True, aperture=False,
                               needed=needed)
            if field is None:
                return
            yield field, self.pupil_phase(first, 0.0, sight, zenith_rad, range_m)
            twins = {i: screen.twin((*self.imager.source_seed(second, 1), i))
                     for i, screen in self.screens.pop(first, {}).items()}
            self.screens[second] = {i: twin for i, twin in twins.items() if twin is not None}
            field = self.field(second, 0.0, sight, zenith_rad, range_m, slack=1.0, aperture=False, needed=needed)
            if field is None:
                return
            yield field, self.pupil_phase(second, 0.0, sight, zenith_rad, range_m)
        finally:
            self.screens.pop(first, None)
            self.screens.pop(second, None)

    def render(self, source, t_s, sight, zenith_rad, range_m, offset) -> np.ndarray:
        out = np.empty((len(t_s), self.imager.geometry.stamp_size, self.imager.geometry.stamp_size))
        for f in range(len(t_s)):
            field = self.field(source, t_s[f], sight[f], zenith_rad[f], range_m[f])
            out[f] = self.imager.pupil_renderer.stamps_from_field(field[None], offset[f:f + 1])[0]
        return out

    # -- checkpoint -------------------------------------------------------------------------------
    def state(self) -> dict:
        return {key: {str(i): s.state() | {"n": s.n, "delta": s.delta} for i, s in screens.items()}
                for key, screens in self.screens.items()}

    def set_state(self, state: dict) -> None:
        L0 = self.imager.outer_scale_m
        self.screens = {}
        for key, per_layer in state.items():
            screens = {}
            for i, s in per_layer.items():
                screen = LayerScreen(int(s["n"]), float(s["delta"]), (*self.imager.source_seed(key, 1), int(i)),
                                     L0=L0, update="extend" if np.isfinite(L0) else "regenerate")
                screen.set_state(s)
                screens[int(i)] = screen
            self.screens[key] = screens
