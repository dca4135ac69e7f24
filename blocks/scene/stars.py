"""Stars in the field: Hipparcos down to a magnitude limit, fainter ones drawn from star counts."""

from __future__ import annotations

import logging

import numpy as np
from pydantic import Field, model_validator
from skyfield.api import Star
from skyfield.framelib import galactic_frame

from evsda import library
from evsda.blocks.ports import FocalPlane, PointSources, SourceKind
from evsda.blocks.ports.scene import Observer, Pointing
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, ParameterError, Window
from evsda.graph.params import DataFile

from . import projection, radiometry
from .catalog import StarCatalog, load_hipparcos
from .ephemeris import timescale
from .geometry import KnotGrid, ObserverModel, unit
from .pointing import PointingModel
from .starcounts import draw_magnitudes, integrated_counts_per_deg2
from .visibility import EARTH_RADIUS_M

log = logging.getLogger(__name__)

ABERRATION_MARGIN_RAD = np.radians(30.0 / 3600.0)   # apparent minus catalogue place, at most ~21 arcsec
MAX_SYNTHETIC_STARS = 2_000_000


class StarField(Block):
    """Stars crossing the field: positions (apparent places, gnomonic projection) and photon fluxes.

    Bright stars come from the Hipparcos catalogue (ESA 1997) down to
    ``catalog_limit_mag``, with proper motion to the run's epoch; fainter stars down to
    ``faint_limit_mag`` are drawn with ``self.rng`` at random positions with magnitudes
    following the Bahcall & Soneira (1980) counts at the field's galactic position
    (:mod:`evsda.blocks.scene.starcounts`). Only stars that the field sweeps over during
    the run are kept; in a staring field they drift with the sky.

    Apparent places come from Skyfield (proper motion, parallax, aberration,
    deflection) on ``knot_step_s`` knots, linearly interpolated in between (aberration
    changes by <1e-4 arcsec/s). Photon flux in V at the aperture: ``N0 10**(-0.4 V)``
    times the transmission at each star's own airmass. Positions are NaN outside the
    detector (plus ``margin_px``) and below the horizon or behind the Earth.
    """

    type_name = "star_field"

    class Params(BlockParams):
        catalog: DataFile = Field("library:stars/hip_main.dat.gz", description="Hipparcos main catalogue file "
                                  "(hip_main.dat format) [-]")
        catalog_limit_mag: float = Field(6.5, le=13, description="Faintest star taken from the catalogue (the "
                                         "bundled excerpt is complete to V 6.5) [mag]")
        faint_limit_mag: float = Field(12.0, le=22, description="Faintest synthetic star drawn from the star "
                                       "counts; at or below catalog_limit_mag for none [mag]")
        cadence_s: float = Field(1e-3, gt=0, le=10, description="Sample spacing of the positions [s]")
        knot_step_s: float = Field(10.0, gt=0, le=600, description="Spacing of the Skyfield apparent-place "
                                   "evaluations [s]")
        margin_px: float = Field(0.0, ge=0, description="Keep positions of stars this far outside the detector "
                                 "(their image can spill in) [pixel]")

        @model_validator(mode="after")
        def _limits(self):
            if self.faint_limit_mag > self.catalog_limit_mag + 12:
                raise ValueError("faint_limit_mag more than 12 mag below catalog_limit_mag would draw "
                                 "millions of stars")
            return self

    inputs = {
        "observer": Input(Observer, "where the sensor is"),
        "pointing": Input(Pointing, "where the sensor looks"),
        "focal_plane": Input(FocalPlane, "the detector geometry"),
    }
    outputs = {"sources": Output(PointSources, "the stars on the focal plane")}
    state = ("faint_stars",)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.faint_stars: dict | None = None       # drawn once per run with self.rng; checkpointed
        self._key = None
        self._stars: StarCatalog | None = None

    @property
    def cadence_ns(self) -> int:
        return max(1, round(self.params.cadence_s * NS_PER_S))

    # -- the stars of this run ------------------------------------------------------------------
    def _prepare(self, window: Window, observer: Observer, pointing: Pointing, focal_plane: FocalPlane):
        key = (window.epoch, *(repr(v.to_arrays()) for v in (observer, pointing, focal_plane)))
        if key == self._key:
            return
        knot_ns = round(self.params.knot_step_s * NS_PER_S)
        self._observer = ObserverModel(observer, window.epoch, knot_ns)
        self._pointing = PointingModel(pointing, self._observer, window.epoch, knot_ns)
        self._focal_plane = focal_plane
        start, stop = (0, self._run.duration_ns) if self._run is not None else (window.start_ns, window.stop_ns)
        boresights, reach = self._swept(start, stop, focal_plane)
        catalog = load_hipparcos(str(library.resolve(self.params.catalog)))
        bright = catalog.select(catalog.vmag <= self.params.catalog_limit_mag)
        if self.faint_stars is None:
            self.faint_stars = self._draw_faint(boresights, reach)
        stars = _concatenate(bright, _catalog_of(self.faint_stars))
        near = _near_track(stars.unit_vectors(), boresights, reach)
        self._stars = stars.select(near)
        sky_observer = self._observer.skyfield_observer()
        catalog_epoch = timescale().J(stars.epoch_jyear)
        star = Star(ra_hours=self._stars.ra_deg / 15.0, dec_degrees=self._stars.dec_deg,
                    ra_mas_per_year=self._stars.pm_ra_mas_yr, dec_mas_per_year=self._stars.pm_dec_mas_yr,
                    parallax_mas=self._stars.parallax_mas, epoch=catalog_epoch)
        self._places = KnotGrid(window.epoch, knot_ns, lambda t: (np.stack(
            [unit(sky_observer.at(t[i]).observe(star).apparent().xyz.m.T) for i in range(len(t))]),))
        self._key = key
        log.info("%s '%s': %d stars swept by the field (%d from the catalogue)", self.type_name, self.name,
                 len(self._stars), int(np.sum(near[: len(bright)])))

    def _swept(self, start_ns: int, stop_ns: int, focal_plane: FocalPlane):
        """Boresights sampled over the run and the angular reach around them that the field covers."""
        n = max(2, int((stop_ns - start_ns) // NS_PER_S) + 2)
        t = np.linspace(start_ns, stop_ns, n)
        boresights, _, _ = self._pointing.frame(t)
        gaps = np.arccos(np.clip(np.sum(boresights[1:] * boresights[:-1], axis=-1), -1, 1))
        margin = self.params.margin_px * focal_plane.pixel_scale_rad
        reach = projection.radius_rad(focal_plane) + margin + ABERRATION_MARGIN_RAD + float(gaps.max(initial=0)) / 2
        return boresights, reach

    def _draw_faint(self, boresights: np.ndarray, reach: float) -> dict:
        """Synthetic stars fainter than the catalogue in a cap around the swept track (Bahcall & Soneira)."""
        p = self.params
        empty = {"vmag": np.zeros(0), "ra_deg": np.zeros(0), "dec_deg": np.zeros(0)}
        if p.faint_limit_mag <= p.catalog_limit_mag:
            return empty
        centre = unit(boresights.mean(axis=0))
        radius = min(np.pi, float(np.arccos(np.clip(boresights @ centre, -1, 1)).max()) + reach)
        galactic = galactic_frame.rotation_at(None) @ centre
        l_deg = float(np.degrees(np.arctan2(galactic[1], galactic[0])))
        b_deg = float(np.degrees(np.arcsin(galactic[2])))
        area_deg2 = 2 * np.pi * (1 - np.cos(radius)) * np.degrees(1) ** 2
        density = float(integrated_counts_per_deg2(p.faint_limit_mag, l_deg, b_deg)
                        - integrated_counts_per_deg2(p.catalog_limit_mag, l_deg, b_deg))
        expected = density * area_deg2
        if expected > MAX_SYNTHETIC_STARS:
            raise ParameterError(f"{self.type_name} '{self.name}': the field sweeps {area_deg2:.0f} deg^2 during "
                                 f"the run, {expected:.0f} stars down to faint_limit_mag={p.faint_limit_mag:g}; "
                                 f"lower faint_limit_mag or shorten the run")
        n = int(self.rng.poisson(expected))
        cos_theta = self.rng.uniform(np.cos(radius), 1.0, n)
        phi = self.rng.uniform(0.0, 2 * np.pi, n)
        vmag = draw_magnitudes(self.rng, n, p.catalog_limit_mag, p.faint_limit_mag, l_deg, b_deg)
        sin_theta = np.sqrt(1 - cos_theta**2)
        e1 = unit(np.cross(centre, [0.0, 0.0, 1.0] if abs(centre[2]) < 0.9 else [1.0, 0.0, 0.0]))
        e2 = np.cross(centre, e1)
        v = (cos_theta[:, None] * centre + (sin_theta * np.cos(phi))[:, None] * e1
             + (sin_theta * np.sin(phi))[:, None] * e2)
        return {"vmag": vmag, "ra_deg": np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360.0,
                "dec_deg": np.degrees(np.arcsin(np.clip(v[:, 2], -1, 1)))}

    # -- one window -------------------------------------------------------------------------------
    def step(self, window: Window, observer: Observer, pointing: Pointing, focal_plane: FocalPlane) -> dict:
        self._prepare(window, observer, pointing, focal_plane)
        t_ns = window.sample_times_ns(self.cadence_ns)
        x, y, up_dot = self.project(t_ns)
        stars = self._stars
        band = radiometry.V_BAND
        flux = radiometry.photon_flux_of_magnitude(stars.vmag, band)[None, :] * np.ones((len(t_ns), 1))
        visible = np.ones_like(x, dtype=bool)
        if observer.is_ground:
            visible = up_dot > 0
            flux = flux * np.nan_to_num(radiometry.transmission(observer.extinction_mag_per_airmass,
                                                                np.arccos(np.clip(up_dot, -1, 1))))
        else:
            visible = self._clear_of_earth(t_ns, x.shape)
        margin = self.params.margin_px
        on_detector = (x >= -0.5 - margin) & (x < focal_plane.width_px - 0.5 + margin) \
            & (y >= -0.5 - margin) & (y < focal_plane.height_px - 0.5 + margin)
        hidden = ~(on_detector & visible)
        x[hidden] = np.nan
        y[hidden] = np.nan
        b, _, _ = self._pointing.frame(t_ns)
        n = len(stars)
        return {"sources": PointSources(
            focal_plane=focal_plane, wavelength_m=band.effective_wavelength_m, t_ns=t_ns, source_id=stars.name,
            kind=np.full(n, SourceKind.STAR, dtype=np.int8), x_px=x, y_px=y, photon_flux=flux,
            magnitude=radiometry.magnitude(flux, band), range_m=np.full((len(t_ns), n), np.inf),
            zenith_angle_rad=self._pointing.zenith_angle(t_ns, b))}

    def project(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel coordinates ``[n_t, n_stars]`` (NaN behind the sensor) and each star's ``s . up``."""
        t = np.asarray(t_ns, dtype=np.float64)
        b, r, u = self._pointing.frame(t)
        _, _, up = self._observer.enu(t)
        axes = np.stack([b, r, u, up], axis=1)                      # [n_t, 4, 3]
        step = self._places.step_ns
        k = np.floor(t / step).astype(np.int64)
        w = (t - k * step) / step
        n_t, n_s = len(t), len(self._stars)
        dots = np.empty((4, n_t, n_s))
        for k0 in np.unique(k):
            rows = np.flatnonzero(k == k0)
            (s0,) = self._places.values(np.array([k0]))
            (s1,) = self._places.values(np.array([k0 + 1]))
            a = axes[rows]                                        # [m, 4, 3]
            d0 = np.einsum("mac,sc->ams", a, s0[0])
            d1 = np.einsum("mac,sc->ams", a, s1[0])
            wr = w[rows][None, :, None]
            dots[:, rows] = (1 - wr) * d0 + wr * d1
        x, y = projection.to_pixels(*projection.tangent_plane(dots[0], dots[1], dots[2]), self._focal_plane)
        return x, y, dots[3]

    def _clear_of_earth(self, t_ns, shape) -> np.ndarray:
        """Space observer: whether each star's line of sight clears the Earth plus the grazing height."""
        r_obs, _ = self._observer.state(np.asarray(t_ns, dtype=np.float64))
        distance = np.linalg.norm(r_obs, axis=-1)
        limb = np.arcsin(np.clip((EARTH_RADIUS_M + self._observer.observer.min_grazing_altitude_m) / distance, 0, 1))
        (s0,) = self._places.values(np.floor(np.asarray(t_ns) / self._places.step_ns).astype(np.int64))
        nadir = -r_obs / distance[:, None]
        angle_from_nadir = np.arccos(np.clip(np.einsum("tsc,tc->ts", s0, nadir), -1, 1))
        return np.broadcast_to(angle_from_nadir > limb[:, None], shape)


def _catalog_of(drawn: dict) -> StarCatalog:
    n = len(drawn["vmag"])
    zeros = np.zeros(n)
    return StarCatalog(np.array([f"BS {i:06d}" for i in range(n)], dtype=str), np.asarray(drawn["vmag"]),
                       np.asarray(drawn["ra_deg"]), np.asarray(drawn["dec_deg"]), zeros, zeros, zeros)


def _concatenate(a: StarCatalog, b: StarCatalog) -> StarCatalog:
    return StarCatalog(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in
                         ("name", "vmag", "ra_deg", "dec_deg", "pm_ra_mas_yr", "pm_dec_mas_yr", "parallax_mas")),
                       epoch_jyear=a.epoch_jyear)


def _near_track(vectors: np.ndarray, boresights: np.ndarray, reach: float) -> np.ndarray:
    """Whether each unit vector comes within ``reach`` of any sampled boresight."""
    if len(vectors) == 0:
        return np.zeros(0, dtype=bool)
    cos_reach = np.cos(reach)
    near = np.zeros(len(vectors), dtype=bool)
    for chunk in range(0, len(boresights), 256):
        near |= (vectors @ boresights[chunk:chunk + 256].T >= cos_reach).any(axis=1)
    return near
