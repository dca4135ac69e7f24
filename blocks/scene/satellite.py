"""The satellite as a point source on the focal plane, with its photon flux at the aperture."""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
from pydantic import Field

from evsda.blocks.ports import FocalPlane, PointSources, SourceKind
from evsda.blocks.ports.scene import Observer, Orbit, Pointing
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, Window

from . import radiometry
from .passes import PassReport, find_passes, require_pass
from .pointing import check_sampling
from .view import Reflector, SatelliteView

log = logging.getLogger(__name__)


class Satellite(Block):
    """A satellite's focal-plane position and brightness versus time (paper Sec. 2.1, Eq. 1-2).

    Positions: the apparent place (light time, aberration) from Skyfield's SGP4 at
    ``knot_step_s`` knots, Hermite-interpolated to the ``cadence_s`` grid, projected
    gnomonically in the sensor frame. They are NaN while the satellite is not
    observable: outside the detector, in the Earth's shadow, below the horizon limit
    (behind the Earth from space) or while the observer's Sun is too high.

    Brightness: ``N = N_sun rho A F(phi) / R^2 * 10**(-0.4 k X) * nu`` [photon s^-1 m^-2]
    in the V band: Eq. 2's radiance ``rho E / pi`` over the projected area, with the
    phase function F of a Lambertian sphere (cross-section A) or a flat plate (area A),
    range R, extinction k over airmass X at the satellite's elevation, and the lit
    fraction nu of the solar disc (penumbra). Flux and magnitude are given at every
    sample, observable or not.

    At the first window the pass finder scans the whole run; a satellite that is never
    observable in the field is one :class:`~evsda.graph.SceneError` with its closest
    approach (set ``require_pass: false`` to allow it).
    """

    type_name = "satellite"

    class Params(BlockParams):
        cadence_s: float = Field(1e-3, gt=0, le=10, description="Sample spacing of the positions and fluxes [s]")
        knot_step_s: float = Field(10.0, gt=0, le=600, description="Spacing of the Skyfield evaluations that "
                                   "are interpolated to the cadence [s]")
        shape: Literal["sphere", "plate"] = Field("sphere", description="Reflector model: Lambertian sphere "
                                                  "or diffuse flat plate [-]")
        area_m2: float = Field(10.0, gt=0, description="Cross-section of the sphere or area of the plate [m^2]")
        albedo: float = Field(0.2, gt=0, le=1, description="Diffuse reflectivity rho of the surface (Eq. 2) [1]")
        plate_normal: Literal["nadir", "sun", "observer", "bisector"] = Field(
            "nadir", description="Orientation of the plate's normal (shape 'plate') [-]")
        band: Literal["V"] = Field("V", description="Photometric band of fluxes and magnitudes [-]")
        require_pass: bool = Field(True, description="Fail before any work if the satellite is never observable "
                                                     "in the field during the run [-]")

    inputs = {
        "orbit": Input(Orbit, "the satellite's element set"),
        "observer": Input(Observer, "where the sensor is"),
        "pointing": Input(Pointing, "where the sensor looks"),
        "focal_plane": Input(FocalPlane, "the detector geometry"),
    }
    outputs = {"sources": Output(PointSources, "the satellite on the focal plane")}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._view: SatelliteView | None = None
        self._view_key = None
        self.passes: PassReport | None = None

    @property
    def cadence_ns(self) -> int:
        return max(1, round(self.params.cadence_s * NS_PER_S))

    def view(self, window: Window, orbit: Orbit, observer: Observer, pointing: Pointing,
             focal_plane: FocalPlane) -> SatelliteView:
        """The :class:`SatelliteView` of these inputs (built once; a cache derived from the inputs)."""
        key = (window.epoch, *(repr(v.to_arrays()) for v in (orbit, observer, pointing, focal_plane)))
        if key != self._view_key:
            p = self.params
            self._view = SatelliteView(orbit, observer, pointing, focal_plane, window.epoch,
                                       knot_step_ns=round(p.knot_step_s * NS_PER_S),
                                       reflector=Reflector(p.shape, p.area_m2, p.albedo, p.plate_normal),
                                       band=radiometry.BANDS[p.band])
            self._view_key = key
            self.passes = None
        return self._view

    def find_passes(self, view: SatelliteView, window: Window) -> PassReport:
        """Passes over the whole run (or this window when the block runs without ``setup``)."""
        start, stop = (0, self._run.duration_ns) if self._run is not None else (window.start_ns, window.stop_ns)
        return find_passes(view, start, stop, resolution_ns=self.cadence_ns)

    def step(self, window: Window, orbit: Orbit, observer: Observer, pointing: Pointing,
             focal_plane: FocalPlane) -> dict:
        view = self.view(window, orbit, observer, pointing, focal_plane)
        if self.passes is None:
            who = f"{self.type_name} '{self.name}'"
            start, stop = (0, self._run.duration_ns) if self._run is not None else (window.start_ns, window.stop_ns)
            check_sampling(view.pointing_model, focal_plane, self.cadence_ns, start, stop, who)
            self.passes = self.find_passes(view, window)
            if self.params.require_pass:
                require_pass(self.passes, who, f"{orbit.name} ({orbit.catalog_number})")
            for item in self.passes.passes:
                log.info("%s: %s observable %s", who, orbit.name, item)
        t_ns = window.sample_times_ns(self.cadence_ns)
        s = view.sample(t_ns)
        hidden = ~s.observable
        x, y = s.x_px.copy(), s.y_px.copy()
        x[hidden] = np.nan
        y[hidden] = np.nan
        return {"sources": PointSources(
            focal_plane=focal_plane, wavelength_m=view.band.effective_wavelength_m, t_ns=t_ns,
            source_id=np.array([orbit.catalog_number]), kind=np.array([SourceKind.SATELLITE], dtype=np.int8),
            x_px=x[:, None], y_px=y[:, None], photon_flux=s.photon_flux[:, None], magnitude=s.magnitude[:, None],
            range_m=s.range_m[:, None], zenith_angle_rad=s.zenith_angle_rad)}
