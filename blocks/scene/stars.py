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

from . import projection, radiometry, spectra
from .catalog import StarCatalog, load_hipparcos
from .ephemeris import timescale
from .geometry import KnotGrid, unit
from .pointing import check_sampling, fingerprint, shared_models
from .starcounts import draw_magnitudes, integrated_counts_per_deg2
from .visibility import EARTH_RADIUS_M

log = logging.getLogger(__name__)

ABERRATION_MARGIN_RAD = np.radians(30.0 / 3600.0)   # apparent minus catalogue place, at most ~21 arcsec
MAX_SYNTHETIC_STARS = 2_000_000
CHUNK = 1000                                        # samples projected together


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
    changes by <1e-4 arcsec/s). Photon flux at the aperture: ``N0 10**(-0.4 V)`` (V band)
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
        cadence_s: float = Field(1e-3, ge=1e-6, le=10, description="Sample spacing of the positions (at least 1 "
                              "us, the events' time resolution) [s]")
        knot_step_s: float = Field(10.0, ge=0.1, le=600, description="Spacing of the Skyfield apparent-place "
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
        self._photometry_cache: dict[int, tuple] = {}
        self._interval_kept: tuple[int, np.ndarray, np.ndarray] | None = None    # (k, places at k, change to k + 1)

    @property
    def cadence_ns(self) -> int:
        return max(1, round(self.params.cadence_s * NS_PER_S))

    # -- the stars of this run ------------------------------------------------------------------
    def _prepare(self, window: Window, observer: Observer, pointing: Pointing, focal_plane: FocalPlane):
        key = (window.epoch, *(fingerprint(v) for v in (observer, pointing, focal_plane)))
        if key == self._key:
            return
        knot_ns = round(self.params.knot_step_s * NS_PER_S)
        self._observer, self._pointing = shared_models(observer, pointing, window.epoch, knot_ns)
        self._focal_plane = focal_plane
        start, stop = self.run_span_ns(window)
        check_sampling(self._pointing, focal_plane, self.cadence_ns, start, stop, self.label)
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
        self._photometry_cache = {}
        self._interval_kept = None
        self._key = key
        log.info("%s '%s': %d stars swept by the field (%d from the catalogue)", self.type_name, self.name,
                 len(self._stars), int(np.sum(near[: len(bright)])))

    def _swept(self, start_ns: int, stop_ns: int, focal_plane: FocalPlane):
        """Boresights sampled over the run and the angular reach around them that the field covers.

        Between two samples ``dt`` apart the boresight stays within half the gap of one of
        them, or, for a scan, raster or slew (whose path may turn), within half of
        ``dt`` times the frame's largest angular rate.
        """
        n = max(2, int((stop_ns - start_ns) // NS_PER_S) + 2)
        t = np.linspace(start_ns, stop_ns, n)
        boresights, _, _ = self._pointing.frame(t)
        gaps = np.arccos(np.clip(np.sum(boresights[1:] * boresights[:-1], axis=-1), -1, 1))
        turning = self._pointing.moving_rate_bound_rad_s() * (t[1] - t[0]) / NS_PER_S
        margin = self.params.margin_px * focal_plane.pixel_scale_rad
        reach = (projection.radius_rad(focal_plane) + margin + ABERRATION_MARGIN_RAD
                 + max(float(gaps.max(initial=0)), turning) / 2)
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
            raise ParameterError(f"{self.label}: the field sweeps {area_deg2:.0f} deg^2 during "
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
        x, y = self.project(t_ns)
        stars = self._stars
        k, w = self._knot_weights(t_ns)
        flux, mag = (self._between_knots(k, w, self._knot_photometry, m) for m in (1, 2))
        margin = self.params.margin_px
        with np.errstate(invalid="ignore"):
            on_detector = (x >= -0.5 - margin) & (x < focal_plane.width_px - 0.5 + margin)
            on_detector &= y >= -0.5 - margin
            on_detector &= y < focal_plane.height_px - 0.5 + margin
        knots = _distinct(k)
        for k0 in knots:
            # above the horizon (or clear of the Earth) at both knots around these samples
            visible = (self._knot_photometry(k0)[0] > 0) & (self._knot_photometry(k0 + 1)[0] > 0)
            if len(knots) == 1:         # every sample (the usual window): no mask of rows
                on_detector &= visible
            else:
                on_detector[k == k0] &= visible
        np.putmask(x, ~on_detector, np.nan)
        np.putmask(y, ~on_detector, np.nan)
        zenith, azimuth, rotation = (angle.copy() for angle in self._pointing.boresight_angles(t_ns))
        n = len(stars)
        return {"sources": PointSources(
            focal_plane=focal_plane, wavelength_m=spectra.effective_wavelength_m(focal_plane.spectral_response),
            t_ns=t_ns, source_id=stars.name,
            kind=np.full(n, SourceKind.STAR, dtype=np.int8), x_px=x, y_px=y, photon_flux=flux, magnitude=mag,
            range_m=np.full((len(t_ns), n), np.inf), zenith_angle_rad=zenith,
            boresight_azimuth_rad=azimuth, field_rotation_rad=rotation)}

    def _knot_weights(self, t_ns) -> tuple[np.ndarray, np.ndarray]:
        step = self._places.step_ns
        t = np.asarray(t_ns, dtype=np.float64)
        k = np.floor(t / step).astype(np.int64)
        return k, (t - k * step) / step

    def _between_knots(self, k, w, knot_values, member: int) -> np.ndarray:
        """``[n_t, n_stars]`` linear interpolation between knots of a per-star quantity."""
        knots = _distinct(k)
        if len(knots) == 1:         # one knot interval (the usual window): every row
            v0, v1 = knot_values(knots[0])[member], knot_values(knots[0] + 1)[member]
            return v0 + w[:, None] * (v1 - v0)
        out = np.empty((len(k), len(self._stars)))
        for k0 in knots:
            rows = np.flatnonzero(k == k0)
            v0, v1 = knot_values(k0)[member], knot_values(k0 + 1)[member]
            out[rows] = v0 + w[rows, None] * (v1 - v0)
        return out

    def _knot_photometry(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Visibility (1/0), photon flux and magnitude of every star at knot ``k``.

        The flux at the aperture is ``N0 10**(-0.4 V)`` times the transmission at the
        star's own airmass (ground), in the detector's response: times the band factor of
        the star's B - V (:func:`.spectra.star_band_factor`; synthetic stars and catalogue
        stars without a colour take :data:`.spectra.FIELD_STAR_B_V`); the magnitude stays V.
        Between knots, 10 s apart by default, it is interpolated linearly: a star's airmass
        changes by ~1e-3 in that time.
        """
        cached = self._photometry_cache.get(k)
        if cached is not None:
            return cached
        t = np.array([k * self._places.step_ns], dtype=np.float64)
        (places,) = self._places.values(np.array([k]))
        band, stars = radiometry.V_BAND, self._stars
        flux = radiometry.photon_flux_of_magnitude(stars.vmag, band)
        kappa = spectra.star_band_factor(self._focal_plane.spectral_response, stars.colour)
        observer = self._observer.observer
        if observer.is_ground:
            _, _, up = self._observer.enu(t)
            sin_elevation = places[0] @ up[0]
            visible = (sin_elevation > 0).astype(float)
            transmission = np.nan_to_num(radiometry.transmission(observer.extinction_mag_per_airmass,
                                                                 np.arccos(np.clip(sin_elevation, -1, 1))))
            flux = flux * transmission
        else:
            r_obs, _ = self._observer.state(t)
            distance = np.linalg.norm(r_obs[0])
            limb = np.arcsin(min(1.0, (EARTH_RADIUS_M + observer.min_grazing_altitude_m) / distance))
            visible = (np.arccos(np.clip(places[0] @ (-r_obs[0] / distance), -1, 1)) > limb).astype(float)
        result = (visible, flux * kappa, radiometry.magnitude(flux, band))
        self._photometry_cache[k] = result
        return result

    def project(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates ``[n_t, n_stars]`` of the stars near the detector (NaN elsewhere).

        Apparent places are linear between knots, so their dot products with the sensor
        axes are too: two matrix products per knot interval. Samples go in chunks of
        ``CHUNK`` (1 s at 1 ms); a star is projected at every sample of a chunk only if,
        at the chunk's first, middle or last sample, it lies within the detector plus
        ``margin_px`` plus twice the field's drift over the chunk (for a scan, raster or
        slew at least the frame's largest angular rate times the chunk's duration, as the
        path may turn inside the chunk), so stars that stay far from the detector cost
        three samples, not a thousand.
        """
        t = np.asarray(t_ns, dtype=np.float64)
        n_t, n_s = len(t), len(self._stars)
        x, y = np.full((n_t, n_s), np.nan), np.full((n_t, n_s), np.nan)
        axes = np.stack(self._pointing.frame(t))                  # [3, n_t, 3]: b, r, u
        k, w = self._knot_weights(t_ns)
        fp = self._focal_plane
        half_w, half_h = projection.half_extent_rad(fp)
        margin = (self.params.margin_px + 1.0) * fp.pixel_scale_rad
        turning_rate = self._pointing.moving_rate_bound_rad_s()
        for k0 in _distinct(k):
            in_interval = np.flatnonzero(k == k0)
            s0, ds = self._interval(k0)
            for first in range(0, len(in_interval), CHUNK):
                rows = in_interval[first:first + CHUNK]
                probe = rows[[0, len(rows) // 2, -1]]
                xi, eta = self._tangent(axes[:, probe], w[probe], s0, ds)
                with np.errstate(invalid="ignore"):
                    drift = np.nanmax(np.hypot(xi[-1] - xi[0], eta[-1] - eta[0]), initial=0.0)
                    drift = max(drift, turning_rate * (t[rows[-1]] - t[rows[0]]) / NS_PER_S)
                    near = ((np.abs(xi) <= half_w + margin + 2 * drift)
                            & (np.abs(eta) <= half_h + margin + 2 * drift)).any(axis=0)
                cols = np.flatnonzero(near)
                if cols.size:
                    xs, ys = projection.to_pixels(*self._tangent(axes[:, rows], w[rows], s0[cols], ds[cols]), fp)
                    x[rows[:, None], cols] = xs
                    y[rows[:, None], cols] = ys
        return x, y

    def _interval(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The stars' apparent places at knot ``k`` and their change to knot ``k + 1``, ``[n_stars, 3]``, kept for
        the last interval asked (a window's samples lie in one knot interval, the next windows' mostly in the same:
        100 windows of 0.1 s at the default 10 s knots). The kept arrays are the ones made at its first ask, layout
        included (the places are kept transposed, and the layout chooses BLAS's kernel in :meth:`_tangent`)."""
        kept = self._interval_kept
        if kept is None or kept[0] != k:
            s0 = self._places.values(np.array([k]))[0][0]
            ds = self._places.values(np.array([k + 1]))[0][0] - s0
            for array in (s0, ds):
                array.flags.writeable = False
            kept = self._interval_kept = (k, s0, ds)
        return kept[1], kept[2]

    @staticmethod
    def _tangent(axes, w, s0, ds):
        """Tangent-plane coordinates of places ``s0 + w ds`` in frames ``axes`` ``[3, m, 3]``."""
        dots = axes @ s0.T + w[:, None] * (axes @ ds.T)
        return projection.tangent_plane(dots[0], dots[1], dots[2])


def _distinct(k: np.ndarray) -> list[int]:
    """The distinct knot indices in ``k``, ascending (one, without a sort, where all are the same: the usual
    window)."""
    if k.size and k.min() == k.max():
        return [int(k.flat[0])]
    return [int(k0) for k0 in np.unique(k)]


def _catalog_of(drawn: dict) -> StarCatalog:
    n = len(drawn["vmag"])
    zeros = np.zeros(n)
    return StarCatalog(np.array([f"BS {i:06d}" for i in range(n)], dtype=str), np.asarray(drawn["vmag"]),
                       np.asarray(drawn["ra_deg"]), np.asarray(drawn["dec_deg"]), zeros, zeros, zeros)


def _concatenate(a: StarCatalog, b: StarCatalog) -> StarCatalog:
    return StarCatalog(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in
                         ("name", "vmag", "ra_deg", "dec_deg", "pm_ra_mas_yr", "pm_dec_mas_yr", "parallax_mas")),
                       epoch_jyear=a.epoch_jyear, b_v=np.concatenate([a.colour, b.colour]))


def _near_track(vectors: np.ndarray, boresights: np.ndarray, reach: float) -> np.ndarray:
    """Whether each unit vector comes within ``reach`` of any sampled boresight."""
    if len(vectors) == 0:
        return np.zeros(0, dtype=bool)
    cos_reach = np.cos(reach)
    near = np.zeros(len(vectors), dtype=bool)
    for chunk in range(0, len(boresights), 256):
        near |= (vectors @ boresights[chunk:chunk + 256].T >= cos_reach).any(axis=1)
    return near
