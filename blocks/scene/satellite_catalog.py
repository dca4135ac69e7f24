"""Many satellites from one catalogue: screened cheaply, propagated finely only where they cross the field."""

from __future__ import annotations

import fnmatch
import logging
import math
import warnings
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Literal

import numpy as np
from pydantic import Field

from evsda import library
from evsda.blocks.ports import FocalPlane, PointSources, SourceKind
from evsda.blocks.ports.scene import Observer, Orbit, Pointing
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, ParameterError, RunInfo, SceneError, Window
from evsda.graph.params import DataFile

from . import radiometry, spectra
from .element_sets import (Catalog, CatalogObject, apply_properties, epoch_jd, epoch_utc, guess_format, read_catalog,
                           read_text)
from .geometry import satrec_track
from .passes import Pass, find_passes, iso
from .pointing import check_sampling, fingerprint
from .screening import Screen, ScreenResult
from .view import Reflector, SatelliteView, SharedGeometry

log = logging.getLogger(__name__)


class CatalogEntryWarning(UserWarning):
    """Malformed catalogue entries were skipped (``on_bad_entry: skip``)."""


class CatalogAgeWarning(UserWarning):
    """Some element sets are further than ``max_tle_age_days`` from the simulated time."""


@dataclass
class Crossing:
    """A catalogued object observable in the field during the run: its view and its passes."""

    obj: CatalogObject
    view: SatelliteView
    passes: list[Pass]


class SatelliteCatalog(Block):
    """Every object of a catalogue (TLE file or OMM CSV/JSON/XML) that crosses the field, as point sources.

    At the first window the whole catalogue is screened over the run
    (:mod:`evsda.blocks.scene.screening`: all objects on a 10 s grid with ``sgp4``'s
    vectorised propagator, then the candidates on a 0.5 s grid); each remaining
    candidate's crossings are found with the pass finder of the ``satellite`` block, and
    only the objects observable in the field are output, sampled at ``cadence_s`` only
    during their crossings. Positions, visibility and brightness are those of the
    ``satellite`` block (paper Eq. 1-2; Lambertian sphere or flat plate), with each
    object's ``AREA_M2`` and ``ALBEDO`` from the catalogue's columns or the
    ``properties_file`` (a CSV keyed by ``NORAD_CAT_ID``), else the defaults here.

    ``source_id`` is the NORAD catalogue number (5 digits, as in a TLE), so truth and
    metrics are per object. Positions, fluxes and magnitudes are NaN outside an
    object's crossings (they are never computed there).
    """

    type_name = "satellite_catalog"

    class Params(BlockParams):
        catalog_file: DataFile = Field(description="Catalogue of mean elements: a TLE file (two- or three-line "
                                       "entries) or an OMM file (.csv, .json, .xml); .gz allowed [-]")
        format: Literal["auto", "tle", "omm_csv", "omm_json", "omm_xml"] = Field(
            "auto", description="Catalogue format; auto goes by the file name (.csv, .json, .xml, else TLE) [-]")
        on_bad_entry: Literal["error", "skip"] = Field(
            "error", description="A malformed entry stops the run before any work (error, naming its line) or is "
                                 "left out with a warning naming each line (skip) [-]")
        properties_file: DataFile | None = Field(
            None, description="CSV with NORAD_CAT_ID and AREA_M2 and/or ALBEDO per object (overrides the "
                              "catalogue's own columns) [-]")
        names: str = Field("*", description="Keep only objects whose name matches this pattern (shell-style, "
                                            "case-insensitive, e.g. 'STARLINK-*') [-]")
        shape: Literal["sphere", "plate"] = Field("sphere", description="Reflector model of every object: "
                                                  "Lambertian sphere or diffuse flat plate [-]")
        area_m2: float = Field(10.0, gt=0, description="Cross-section (sphere) or area (plate) of objects "
                                                        "without an AREA_M2 column [m^2]")
        albedo: float = Field(0.2, gt=0, le=1, description="Diffuse reflectivity of objects without an ALBEDO "
                                                           "column (Eq. 2) [1]")
        plate_normal: Literal["nadir", "sun", "observer", "bisector"] = Field(
            "nadir", description="Orientation of the plates' normals (shape 'plate') [-]")
        band: Literal["V"] = Field("V", description="Photometric band of fluxes and magnitudes [-]")
        cadence_s: float = Field(1e-3, ge=1e-6, le=10, description="Sample spacing of positions and fluxes "
                                  "(at least 1 us, the events' time resolution) [s]")
        knot_step_s: float = Field(10.0, ge=0.1, le=600, description="Spacing of the Skyfield evaluations that "
                                   "are interpolated to the cadence [s]")
        screen_step_s: float = Field(10.0, ge=0.1, le=600, description="Coarse step of the screen over the whole "
                                     "catalogue [s]")
        screen_fine_step_s: float = Field(0.5, ge=0.01, le=60, description="Step at which the screen's candidates "
                                          "are screened again [s]")
        max_tle_age_days: float = Field(14.0, gt=0, description="Warn (once, with a count) about element sets "
                                        "further than this from the simulated time [d]")
        max_objects: int = Field(1000, ge=1, description="Refuse a run in which more objects than this cross the "
                                 "field (narrow it with 'names', the field or the duration) [1]")
        require_crossing: bool = Field(True, description="Fail before any work if no object of the catalogue is "
                                       "observable in the field during the run [-]")

    inputs = {
        "observer": Input(Observer, "where the sensor is"),
        "pointing": Input(Pointing, "where the sensor looks"),
        "focal_plane": Input(FocalPlane, "the detector geometry"),
    }
    outputs = {"sources": Output(PointSources, "the objects crossing the field, one source per object")}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.catalog = self._load()
        self.screen: ScreenResult | None = None
        self.crossings: list[Crossing] | None = None
        self._key = None

    # -- the catalogue --------------------------------------------------------------------------------
    def _load(self) -> Catalog:
        p = self.params
        path = library.resolve(p.catalog_file)
        source = f"{self.label} catalog_file {p.catalog_file}"
        fmt = guess_format(path) if p.format == "auto" else p.format
        catalog = read_catalog(read_text(path, self.label), fmt, source, skip_bad=p.on_bad_entry == "skip")
        if catalog.skipped:
            listed = "; ".join(f"line {line}: {reason}" for line, reason in catalog.skipped[:20])
            more = f"; and {len(catalog.skipped) - 20} more" if len(catalog.skipped) > 20 else ""
            warnings.warn(f"{source}: skipped {len(catalog.skipped)} malformed entries ({listed}{more})",
                          CatalogEntryWarning, stacklevel=2)
        if p.names != "*":
            pattern = p.names.upper()
            catalog.objects = [o for o in catalog.objects if fnmatch.fnmatchcase(o.name.upper(), pattern)]
            if not catalog.objects:
                raise ParameterError(f"{self.label} parameter 'names': no object of {p.catalog_file} matches "
                                     f"{p.names!r}")
        if p.properties_file is not None:
            props = library.resolve(p.properties_file)
            matched = apply_properties(catalog, read_text(props, self.label),
                                       f"{self.label} properties_file {p.properties_file}")
            log.info("%s: properties for %d objects from %s", self.label, matched, p.properties_file)
        log.info("%s: %d objects from %s", self.label, len(catalog), p.catalog_file)
        return catalog

    def setup(self, run: RunInfo) -> None:
        super().setup(run)
        jd_run = run.epoch.timestamp() / 86400.0 + 2440587.5
        age = jd_run - epoch_jd(self.catalog.objects)
        end_age = age + run.duration_ns / 86400e9
        stale = np.maximum(np.abs(age), np.abs(end_age)) > self.params.max_tle_age_days
        if stale.any():
            worst = int(np.argmax(np.abs(age)))
            o = self.catalog.objects[worst]
            warnings.warn(f"{self.label}: {int(stale.sum())} of {len(self.catalog)} element sets are more than "
                          f"max_tle_age_days={self.params.max_tle_age_days:g} days from the simulated time (e.g. "
                          f"{o.name} ({o.object_id}), {age[worst]:.1f} days); their positions may be off by "
                          f"kilometres", CatalogAgeWarning, stacklevel=2)

    # -- screening and crossings ------------------------------------------------------------------------
    @property
    def cadence_ns(self) -> int:
        return max(1, round(self.params.cadence_s * NS_PER_S))

    def _reflector(self, obj: CatalogObject) -> Reflector:
        p = self.params
        area = obj.area_m2 if math.isfinite(obj.area_m2) else p.area_m2
        albedo = obj.albedo if math.isfinite(obj.albedo) else p.albedo
        return Reflector(p.shape, area, albedo, p.plate_normal)

    def prepare(self, window: Window, observer: Observer, pointing: Pointing, focal_plane: FocalPlane) -> None:
        """Screen the catalogue and find every crossing over the run (once per set of inputs)."""
        key = (window.epoch, *(fingerprint(v) for v in (observer, pointing, focal_plane)))
        if key == self._key:
            return
        p = self.params
        knot_ns = round(p.knot_step_s * NS_PER_S)
        start, stop = self.run_span_ns(window)
        shared = SharedGeometry(observer, pointing, window.epoch, knot_ns)
        check_sampling(shared.pointing_model, focal_plane, self.cadence_ns, start, stop, self.label)
        objects = self.catalog.objects
        self.screen = Screen([o.satrec for o in objects], shared.pointing_model, focal_plane, window.epoch, start,
                             stop, coarse_step_ns=round(p.screen_step_s * NS_PER_S),
                             fine_step_ns=round(p.screen_fine_step_s * NS_PER_S)).run()
        crossings, blocked = [], 0
        fine_ns = round(p.screen_fine_step_s * NS_PER_S)
        for index, intervals in self.screen.intervals.items():
            obj = objects[index]
            orbit = Orbit(name=obj.name, catalog_number=obj.object_id, line1="", line2="",
                          epoch_utc=epoch_utc(obj))
            view = SatelliteView(orbit, observer, pointing, focal_plane, window.epoch, knot_ns,
                                 reflector=self._reflector(obj), band=radiometry.BANDS[p.band], shared=shared,
                                 track=satrec_track(window.epoch, knot_ns, obj.satrec))
            passes, in_fov = [], False
            for a, b in intervals:
                report = find_passes(view, max(start, a - fine_ns), min(stop, b + fine_ns),
                                     resolution_ns=self.cadence_ns)
                passes += report.passes
                in_fov |= bool(report.in_fov)
            if passes:
                crossings.append(Crossing(obj, view, passes))
            elif in_fov:
                blocked += 1
        crossings.sort(key=lambda c: (c.passes[0].start_ns, c.obj.object_id))
        log.info("%s: screened %d objects in %.2f s (%d coarse candidates, %d after the fine screen%s); %d cross "
                 "the field observably, %d more cross it unobservable (shadow, horizon, daylight)", self.label,
                 len(objects), self.screen.seconds, self.screen.n_coarse_candidates, len(self.screen.intervals),
                 f", {len(self.screen.failed)} not propagated (SGP4 errors)" if self.screen.failed else "",
                 len(crossings), blocked)
        for c in crossings:
            log.info("%s: %s (%s) observable %s", self.label, c.obj.name, c.obj.object_id,
                     "; ".join(str(x) for x in c.passes))
        if len(crossings) > p.max_objects:
            raise SceneError(f"{self.label}: {len(crossings)} objects cross the field during the run, more than "
                             f"max_objects={p.max_objects}; narrow the catalogue ('names'), the field or the run")
        if not crossings and p.require_crossing:
            when = f"between {iso(at(window.epoch, start))} and {iso(at(window.epoch, stop))}"
            extra = f"; {blocked} cross it but are never observable (Earth's shadow, horizon or daylight)" \
                if blocked else ""
            raise SceneError(f"{self.label}: none of the {len(objects)} objects of {p.catalog_file} is observable in "
                             f"the field of view {when}{extra}; change the pointing, the time or the duration, or "
                             f"set require_crossing: false")
        self.crossings = crossings
        self._pointing_model = shared.pointing_model
        self._key = key

    # -- one window ---------------------------------------------------------------------------------------
    def step(self, window: Window, observer: Observer, pointing: Pointing, focal_plane: FocalPlane) -> dict:
        self.prepare(window, observer, pointing, focal_plane)
        t_ns = window.sample_times_ns(self.cadence_ns)
        n_t, n_src = len(t_ns), len(self.crossings)
        x, y = np.full((n_t, n_src), np.nan), np.full((n_t, n_src), np.nan)
        flux, magnitude, range_m = (np.full((n_t, n_src), np.nan) for _ in range(3))
        pad = self.cadence_ns
        for j, crossing in enumerate(self.crossings):
            during = np.zeros(n_t, bool)
            for item in crossing.passes:
                during |= (t_ns >= item.start_ns - pad) & (t_ns <= item.stop_ns + pad)
            if not during.any():
                continue
            s = crossing.view.sample(t_ns[during])
            seen = s.observable
            rows = np.flatnonzero(during)
            x[rows[seen], j], y[rows[seen], j] = s.x_px[seen], s.y_px[seen]
            flux[rows, j], magnitude[rows, j], range_m[rows, j] = s.photon_flux, s.magnitude, s.range_m
        t = t_ns.astype(np.float64)
        b, _, u = self._pointing_model.frame(t) if n_t else (np.zeros((0, 3)),) * 3
        zenith = self._pointing_model.zenith_angle(t, b) if n_t else np.zeros(0)
        azimuth, rotation = self._pointing_model.horizon(t, b, u) if n_t else (np.zeros(0), np.zeros(0))
        return {"sources": PointSources(
            focal_plane=focal_plane, wavelength_m=spectra.effective_wavelength_m(focal_plane.spectral_response),
            t_ns=t_ns,
            source_id=np.array([c.obj.object_id for c in self.crossings], dtype=str),
            kind=np.full(n_src, SourceKind.SATELLITE, dtype=np.int8), x_px=x, y_px=y, photon_flux=flux,
            magnitude=magnitude, range_m=range_m, zenith_angle_rad=zenith, boresight_azimuth_rad=azimuth,
            field_rotation_rad=rotation)}


def at(epoch: datetime, t_ns: int) -> datetime:
    return epoch + timedelta(microseconds=t_ns / 1000)
