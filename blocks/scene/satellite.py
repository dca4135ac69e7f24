"""The satellite as a point source on the focal plane, with its photon flux at the aperture."""

from __future__ import annotations

import dataclasses
import logging
from typing import Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator

from evsda import library
from evsda.blocks.ports import FocalPlane, PointSources, SourceKind
from evsda.blocks.ports.scene import Observer, Orbit, Pointing
from evsda.graph import NS_PER_S, Block, BlockParams, GraphError, Input, Output, ParameterError, Window
from evsda.graph.graphfile import read_yaml
from evsda.graph.params import DataFile, describe_validation_error

from . import facets, radiometry, spectra
from .geometry import consecutive_rows
from .passes import PassReport, find_passes, require_pass
from .pointing import check_sampling, fingerprint
from .reflectors import FacetReflector, attitude_law
from .view import Reflector, SatelliteView, ViewSamples

log = logging.getLogger(__name__)

#: windows whose samples the satellite block takes in one call of its view (:meth:`Satellite._sampled`)
WINDOWS_AHEAD = 5


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

    Shape ``facets`` replaces ``rho A F`` by a facet model's ``sum A f (n.s)(n.o)``
    (:mod:`.facets`: a cylinder or box plus plates, each with a diffuse and a specular
    BRDF), turned by the ``attitude`` law at the light's emission time: ``fixed``
    (nadir-pointing), ``spin`` (uniform rotation about a body axis fixed in inertial
    space) or ``tumble`` (torque-free rigid body). A ``plate`` that spins or tumbles is
    a one-facet model with its normal along body +z.

    At the first window the pass finder scans the whole run; a satellite that is never
    observable in the field is one :class:`~evsda.graph.SceneError` with its closest
    approach (set ``require_pass: false`` to allow it).
    """

    type_name = "satellite"

    class Params(BlockParams):
        cadence_s: float = Field(1e-3, ge=1e-6, le=10, description="Sample spacing of the positions and fluxes "
                                  "(at least 1 us, the events' time resolution) [s]")
        # 10 s: the cubic Hermite error for a LEO orbit is h^4/384 omega^4 r = 0.3 mm (0.4 m at 60 s, which is within
        # the noise floor but saves no measurable CPU): docs/speed.md, "Speed against error"
        knot_step_s: float = Field(10.0, ge=0.1, le=600, description="Spacing of the Skyfield evaluations that "
                                   "are interpolated to the cadence [s]")
        shape: Literal["sphere", "plate", "facets"] = Field("sphere", description="Reflector model: Lambertian "
                                                            "sphere, diffuse flat plate, or a facet model [-]")
        area_m2: float = Field(10.0, gt=0, description="Cross-section of the sphere or area of the plate [m^2]")
        albedo: float = Field(0.2, gt=0, le=1, description="Diffuse reflectivity rho of the surface (Eq. 2) [1]")
        plate_normal: Literal["nadir", "sun", "observer", "bisector"] = Field(
            "nadir", description="Orientation of the plate's normal (shape 'plate', attitude 'fixed') [-]")
        facet_model: facets.FacetModelSpec | None = Field(None, description="Shape 'facets': the body and plates, "
                                                          "inline [-]")
        facet_model_file: DataFile | None = Field(None, description="Shape 'facets': a YAML file holding the "
                                                  "facet model (path or library:shapes/NAME.yaml) [-]")
        attitude: Literal["fixed", "spin", "tumble"] = Field(
            "fixed", description="Attitude law: fixed (plate: plate_normal; facets: body +z to nadir, +x along "
            "the velocity), spin at a constant rate, or tumble (torque-free rigid body) [-]")
        spin_axis_ra_deg: float = Field(0.0, ge=0, lt=360, description="Spin: GCRS right ascension of the spin "
                                        "axis; tumble: of the angular momentum [deg]")
        spin_axis_dec_deg: float = Field(90.0, ge=-90, le=90, description="Spin: GCRS declination of the spin "
                                         "axis; tumble: of the angular momentum [deg]")
        spin_axis_body: tuple[float, float, float] = Field((1.0, 0.0, 0.0), description="Spin: the body axis "
                                                           "that spins (any length, not zero) [1]")
        spin_rate_deg_s: float = Field(0.0, ge=-36000, le=36000, description="Spin: rotation rate about the "
                                       "axis, right-handed (period 360/rate s) [deg/s]")
        spin_phase_deg: float = Field(0.0, ge=-360, le=360, description="Spin and tumble: rotation about the "
                                      "axis at t = 0 [deg]")
        inertia_kg_m2: tuple[float, float, float] | None = Field(None, description="Tumble: principal moments "
                                                                 "of inertia about body x, y, z [kg m^2]")
        angular_velocity_deg_s: tuple[float, float, float] | None = Field(
            None, description="Tumble: body-frame angular velocity at t = 0 [deg/s]")
        band: Literal["V"] = Field("V", description="Photometric band of fluxes and magnitudes [-]")
        require_pass: bool = Field(True, description="Fail before any work if the satellite is never observable "
                                                     "in the field during the run [-]")

        @model_validator(mode="after")
        def _consistent_shape_and_attitude(self):
            inline, file = self.facet_model is not None, self.facet_model_file is not None
            if self.shape == "facets" and inline == file:
                raise ValueError("shape 'facets' needs exactly one of facet_model (inline) and facet_model_file")
            if self.shape != "facets" and (inline or file):
                raise ValueError(f"facet_model and facet_model_file need shape 'facets' (shape is {self.shape!r})")
            if self.shape == "sphere" and self.attitude != "fixed":
                raise ValueError("a Lambertian sphere looks the same in every attitude; spin or tumble a 'plate' or "
                                 "a 'facets' shape")
            if self.shape == "plate" and self.attitude != "fixed" and "plate_normal" in self.model_fields_set:
                raise ValueError("plate_normal is the law of a fixed plate; a spinning or tumbling plate's normal is "
                                 "body +z")
            if not any(self.spin_axis_body) or not all(np.isfinite(self.spin_axis_body)):
                raise ValueError(f"spin_axis_body must be a non-zero direction (got {list(self.spin_axis_body)})")
            if self.attitude == "tumble":
                if self.inertia_kg_m2 is None or self.angular_velocity_deg_s is None:
                    raise ValueError("attitude 'tumble' needs inertia_kg_m2 and angular_velocity_deg_s")
                i1, i2, i3 = self.inertia_kg_m2
                if min(i1, i2, i3) <= 0 or max(i1, i2, i3) > 0.5 * (i1 + i2 + i3) * (1 + 1e-9):
                    raise ValueError(f"inertia_kg_m2 {list(self.inertia_kg_m2)} is not a rigid body's: principal "
                                     f"moments must be positive and each at most the sum of the other two")
            return self

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
        self.reflector = self._reflector()
        self._ahead: tuple[SatelliteView, ViewSamples] | None = None     # samples of the next windows (_sampled)

    def _reflector(self) -> Reflector | FacetReflector:
        """The sphere or fixed plate of Eq. 1-2, or a facet model turned by the attitude law."""
        p = self.params
        if p.shape == "sphere" or (p.shape == "plate" and p.attitude == "fixed"):
            return Reflector(p.shape, p.area_m2, p.albedo, p.plate_normal)
        model = facets.lambertian_plate(p.area_m2, p.albedo) if p.shape == "plate" else facets.build(self._facet_spec())
        law = attitude_law(p.attitude, p.spin_axis_ra_deg, p.spin_axis_dec_deg, p.spin_axis_body, p.spin_rate_deg_s,
                           p.spin_phase_deg, p.inertia_kg_m2, p.angular_velocity_deg_s)
        return FacetReflector(model, law)

    def _facet_spec(self) -> facets.FacetModelSpec:
        p = self.params
        if p.facet_model is not None:
            return p.facet_model
        who = f"{self.label} parameter 'facet_model_file'"
        try:     # bounded like a graph file: a regular UTF-8 file, no alias bomb, nothing of it quoted
            data = read_yaml(library.resolve(p.facet_model_file), what="facet model file")
        except GraphError as exc:
            raise ParameterError(f"{who}: {exc}") from None
        if not isinstance(data, dict) or not set(data) & set(facets.FacetModelSpec.model_fields):
            raise ParameterError(f"{who}: {p.facet_model_file}: not a facet model file (expected a YAML mapping "
                                 f"with a cylinder, a box and/or plates)")
        try:
            return facets.FacetModelSpec.model_validate(data)
        except ValidationError as exc:
            problems = "; ".join(f"{where}: {message}" for where, message in describe_validation_error(exc))
            raise ParameterError(f"{who}: {p.facet_model_file}: {problems}") from None

    @property
    def cadence_ns(self) -> int:
        return max(1, round(self.params.cadence_s * NS_PER_S))

    def view(self, window: Window, orbit: Orbit, observer: Observer, pointing: Pointing,
             focal_plane: FocalPlane) -> SatelliteView:
        """The :class:`SatelliteView` of these inputs (built once; a cache derived from the inputs)."""
        key = (window.epoch, *(fingerprint(v) for v in (orbit, observer, pointing, focal_plane)))
        if key != self._view_key:
            p = self.params
            self._view = SatelliteView(orbit, observer, pointing, focal_plane, window.epoch,
                                       knot_step_ns=round(p.knot_step_s * NS_PER_S),
                                       reflector=self.reflector,
                                       band=radiometry.BANDS[p.band])
            self._view_key = key
            self.passes = None
        return self._view

    def find_passes(self, view: SatelliteView, window: Window) -> PassReport:
        """Passes over the whole run (or this window when the block runs without ``setup``)."""
        start, stop = self.run_span_ns(window)
        return find_passes(view, start, stop, resolution_ns=self.cadence_ns)

    def _sampled(self, view: SatelliteView, window: Window, t_ns: np.ndarray) -> ViewSamples:
        """``view.sample(t_ns)``, the samples of :data:`WINDOWS_AHEAD` windows taken at once and kept for the next.

        Every sample is worked out on its own (elementwise and row by row: the results do not depend on which
        samples are taken together, as a run cut into other windows shows), so the kept rows are the rows a
        window's own call makes; a call costs mostly its ~80 NumPy calls' overhead (one window's 100 samples
        ~1.3 ms, five windows' ~2.2 ms). The scene's other blocks find the pointing frames of these times kept
        (:class:`.geometry.Recent`). A facet model's attitude is sampled window by window as before."""
        kept = self._ahead
        if kept is not None and kept[0] is view and len(t_ns):
            rows = consecutive_rows(kept[1].t_ns, t_ns)
            if rows is not None:
                return _sliced(kept[1], rows)
        if not isinstance(self.reflector, Reflector) or not len(t_ns):
            return view.sample(t_ns)
        stop = min(window.stop_ns + (WINDOWS_AHEAD - 1) * window.duration_ns, self.run_span_ns(window)[1])
        ahead = Window(window.index, window.start_ns, max(stop, window.stop_ns), window.epoch)
        samples = view.sample(ahead.sample_times_ns(self.cadence_ns))
        self._ahead = (view, samples)
        return _sliced(samples, consecutive_rows(samples.t_ns, t_ns))

    def step(self, window: Window, orbit: Orbit, observer: Observer, pointing: Pointing,
             focal_plane: FocalPlane) -> dict:
        view = self.view(window, orbit, observer, pointing, focal_plane)
        if self.passes is None:
            who = self.label
            start, stop = self.run_span_ns(window)
            check_sampling(view.pointing_model, focal_plane, self.cadence_ns, start, stop, who)
            self.passes = self.find_passes(view, window)
            if self.params.require_pass:
                require_pass(self.passes, who, f"{orbit.name} ({orbit.catalog_number})")
            for item in self.passes.passes:
                log.info("%s: %s observable %s", who, orbit.name, item)
        t_ns = window.sample_times_ns(self.cadence_ns)
        s = self._sampled(view, window, t_ns)
        hidden = ~s.observable
        x, y = s.x_px.copy(), s.y_px.copy()
        x[hidden] = np.nan
        y[hidden] = np.nan
        return {"sources": PointSources(
            focal_plane=focal_plane, wavelength_m=spectra.effective_wavelength_m(focal_plane.spectral_response),
            t_ns=t_ns,
            source_id=np.array([orbit.catalog_number]), kind=np.array([SourceKind.SATELLITE], dtype=np.int8),
            x_px=x[:, None], y_px=y[:, None], photon_flux=s.photon_flux[:, None], magnitude=s.magnitude[:, None],
            range_m=s.range_m[:, None], zenith_angle_rad=s.zenith_angle_rad,
            boresight_azimuth_rad=s.boresight_azimuth_rad, field_rotation_rad=s.field_rotation_rad)}


def _sliced(samples: ViewSamples, rows: slice) -> ViewSamples:
    """``samples`` at ``rows``, each array a copy of its own."""
    return ViewSamples(**{f.name: getattr(samples, f.name)[rows].copy() for f in dataclasses.fields(samples)})
