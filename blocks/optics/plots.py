"""The paper's Fig. 3 (a point source's power through turbulent phase screens) and Fig. 4 (Zernike
modes and the Kolmogorov phase screen they build) as PNG files.

Each figure has a function that computes its arrays (usable and testable without matplotlib)
and one that returns a :class:`matplotlib.figure.Figure` (built without pyplot: no backend is
selected, nothing stays open; given a path, it is also saved there). Also the PSF stamp the
optics block renders for one source of a graph (:func:`psf_stamp`, :func:`plot_psf_stamp`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atmosphere import Atmosphere
from .fft_screens import fft_phase_screens
from .karhunen_loeve import KarhunenLoeve, zernike_phase_screen
from .propagation import grid_coordinates, point_source_field, propagate
from .psf import psf_fft
from .sampling import PropagationGeometry, PropagationGrid, choose_grid
from .telescope import Telescope
from .zernike import noll_to_nm, zernike_basis


# -- Fig. 4: Zernike modes and a Karhunen-Loeve screen ------------------------------------------------
@dataclass(frozen=True)
class ZernikeScreen:
    """Modes shown (Noll ``j``), their maps [1], the screen's coefficients [rad] and the screen [rad]."""

    shown: tuple[int, ...]
    modes: np.ndarray              # (len(shown), n, n), NaN outside the pupil
    coefficients: np.ndarray       # a_j for j = 2 .. n_modes + 1 [rad]
    screen: np.ndarray             # (n, n) [rad], NaN outside the pupil
    aperture_m: float
    d_over_r0: float


def zernike_screen(aperture_m: float, r0_m: float, n_modes: int, shown=(2, 4, 5, 7, 11), samples: int = 256,
                   seed: int = 0) -> ZernikeScreen:
    """Noll modes ``shown`` (paper Eq. 5-6) and one screen of ``n_modes`` modes from tilt (paper Eq. 7-11).

    The coefficients are Karhunen-Loeve draws with Noll's covariance for ``D/r0`` (paper
    Eq. 8-11, :class:`.KarhunenLoeve`); ``r0_m`` is at the wavelength the phase is wanted for.
    """
    x = (np.arange(samples) + 0.5 - samples / 2) * aperture_m / samples
    xx, yy = np.meshgrid(x, x)
    outside = np.hypot(xx, yy) > aperture_m / 2
    radius = aperture_m / 2
    modes = np.stack([zernike_basis(1, xx, yy, radius, first=j)[0] for j in shown])
    d_over_r0 = aperture_m / r0_m
    coefficients = KarhunenLoeve.of(n_modes).sample_coefficients(np.random.default_rng(seed), d_over_r0)
    screen = zernike_phase_screen(coefficients, xx, yy, radius)
    modes[:, outside] = np.nan
    screen[outside] = np.nan
    return ZernikeScreen(tuple(shown), modes, coefficients, screen, aperture_m, d_over_r0)


def plot_zernike_screen(result: ZernikeScreen, path: str | Path | None = None):
    """The paper's Fig. 4: each shown mode, then the screen (rms over the pupil in the title)."""
    panels = len(result.shown) + 1
    columns = min(3, panels)
    rows = int(np.ceil(panels / columns))
    fig = _figure(4.2 * columns, 3.5 * rows)
    axes = fig.subplots(rows, columns, squeeze=False)
    extent = np.array([-1, 1, -1, 1]) * result.aperture_m / 2
    for ax, j, mode in zip(axes.flat, result.shown, result.modes):
        n, m = noll_to_nm(j)
        a_j = result.coefficients[j - 2] if j - 2 < len(result.coefficients) else np.nan
        image = ax.imshow(mode, origin="lower", extent=extent, cmap="RdBu_r", vmin=-np.nanmax(np.abs(mode)),
                          vmax=np.nanmax(np.abs(mode)))
        ax.set_title(f"Noll j = {j} (n = {n}, m = {m})" + (f"\na_j = {a_j:+.2f} rad" if np.isfinite(a_j) else ""),
                     fontsize=9)
        fig.colorbar(image, ax=ax, shrink=0.8, label="Z_j [1]")
    ax = axes.flat[panels - 1]
    limit = np.nanmax(np.abs(result.screen))
    image = ax.imshow(result.screen, origin="lower", extent=extent, cmap="RdBu_r", vmin=-limit, vmax=limit)
    rms = float(np.sqrt(np.nanmean(result.screen**2)))
    ax.set_title(f"screen: {len(result.coefficients)} modes, D/r0 = {result.d_over_r0:.3g}\n"
                 f"rms {rms:.2f} rad", fontsize=9)
    fig.colorbar(image, ax=ax, shrink=0.8, label="phase [rad]")
    for ax in axes.flat[panels:]:
        ax.axis("off")
    for ax in axes.flat[:panels]:
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    fig.tight_layout()
    return _saved(fig, path)


# -- Fig. 3: a point source's power through turbulent phase screens --------------------------------
@dataclass(frozen=True)
class PropagationDemo:
    """Arrays of the paper's Fig. 3, each with its sample spacing."""

    grid: PropagationGrid
    geometry: PropagationGeometry
    source_power: np.ndarray       # (N, N) power per source-plane cell [W]
    screen: np.ndarray             # (N, N) phase of the strongest layer [rad]
    screen_plane: int              # its plane index (1-based)
    screen_altitude_m: float
    observed_power: np.ndarray     # (N, N) power per observation-plane cell [W]
    focal_power: np.ndarray        # power per focal-plane sample [W]
    focal_step_rad: float
    vacuum_focal_power: np.ndarray # the same telescope without screens [W]
    aperture_power_w: float
    r0_m: float


def propagation_demo(aperture_m: float = 0.3, distance_m: float = 400e3, wavelength_m: float = 550e-9,
                     r0_500nm_m: float = 0.05, n_layers: int = 3, zenith_deg: float = 0.0, power_w: float = 1.0,
                     seed: int = 0, pupil_samples: int = 64, max_grid: int = 8192) -> PropagationDemo:
    """A point source (paper Eq. 3) propagated through Hufnagel-Valley layers to a telescope (paper Eq. 4).

    The HV5/7 profile is lumped into ``n_layers`` layers and scaled to ``r0_500nm_m`` at
    zenith and 500 nm (:class:`.Atmosphere`); each layer is one FFT screen on its plane's
    grid (:func:`.fft_phase_screens`). The grid is the smallest that satisfies Schmidt's
    sampling constraints (:func:`.choose_grid`) with ``pupil_samples`` across the aperture.
    The source plane carries ``power_w`` [W]; energy is conserved up to what the absorbing
    boundary removes. The focal-plane image is the Fraunhofer pattern of the collimated
    field on the aperture (:func:`.psf_fft`). Raises ``ValueError`` when no grid of at most
    ``max_grid`` points satisfies the constraints.
    """
    zenith = np.deg2rad(zenith_deg)
    atmosphere = Atmosphere.hufnagel_valley(n_layers).scaled_to_r0(r0_500nm_m)
    slant = {i: layer.altitude_m / np.cos(zenith) for i, layer in enumerate(atmosphere.layers)}
    slant = {i: s for i, s in slant.items() if s < distance_m}
    r0 = atmosphere.r0(wavelength_m, zenith)
    geometry = PropagationGeometry(wavelength_m, distance_m, aperture_m, r0_m=r0,
                                   turbulence_length_m=max(slant.values(), default=0.0))
    grid = choose_grid(geometry, aperture_m / pupil_samples, tuple(distance_m - s for s in slant.values()))
    if grid.n > max_grid:
        raise ValueError(f"the geometry needs a {grid.n}-point grid, more than {max_grid}")
    spacing = grid.spacings_m
    plane_of = {i: grid.planes_m.index(distance_m - s) + 1 for i, s in slant.items()}
    rng = np.random.default_rng(seed)
    layer_r0 = atmosphere.layer_r0(wavelength_m, zenith)
    screens = {plane: fft_phase_screens(rng, grid.n, spacing[plane], layer_r0[i], atmosphere.L0)[0]
               for i, plane in plane_of.items()}
    strongest = int(np.argmin(layer_r0))
    source = point_source_field(grid.n, grid.delta1_m, wavelength_m, distance_m, geometry.roi_m, curvature=False)
    source *= np.sqrt(power_w / (np.sum(np.abs(source) ** 2) * grid.delta1_m**2))      # [sqrt(W) / m]
    kwargs = dict(source_curvature=-distance_m, collimate=distance_m)
    field = propagate(source, wavelength_m, grid.delta1_m, grid.deltan_m, grid.planes_m, screens, **kwargs)
    vacuum = propagate(source, wavelength_m, grid.delta1_m, grid.deltan_m, grid.planes_m, **kwargs)

    telescope = Telescope(aperture_m)
    n_pupil = pupil_samples + 2
    start = grid.n // 2 - n_pupil // 2
    crop = slice(start, start + n_pupil)
    amplitude = telescope.pupil(n_pupil, grid.deltan_m)
    n_fft = 4 * n_pupil
    focal, step = psf_fft(field[crop, crop] * amplitude, grid.deltan_m, wavelength_m, n_fft)
    focal_vacuum, _ = psf_fft(vacuum[crop, crop] * amplitude, grid.deltan_m, wavelength_m, n_fft)
    return PropagationDemo(
        grid, geometry, np.abs(source) ** 2 * grid.delta1_m**2,
        screens.get(plane_of.get(strongest, -1), np.zeros((grid.n, grid.n))), plane_of.get(strongest, 0),
        atmosphere.layers[strongest].altitude_m, np.abs(field) ** 2 * grid.deltan_m**2, focal * step**2, step,
        focal_vacuum * step**2, float(np.sum(np.abs(field[crop, crop] * amplitude) ** 2) * grid.deltan_m**2), r0)


def plot_propagation(demo: PropagationDemo, path: str | Path | None = None):
    """The paper's Fig. 3: source plane, the strongest screen, the aperture plane and the focal plane."""
    from matplotlib.patches import Circle

    g, geometry = demo.grid, demo.geometry
    fig = _figure(10, 8.6)
    axes = fig.subplots(2, 2)

    def show(ax, values, delta, half_width, title, label, cmap="inferno", symmetric=False):
        x = grid_coordinates(values.shape[0], delta)
        keep = np.abs(x) <= half_width
        sub = values[np.ix_(keep, keep)]
        extent = [x[keep][0] - delta / 2, x[keep][-1] + delta / 2] * 2
        limit = np.abs(sub).max() if symmetric else None
        image = ax.imshow(sub, origin="lower", extent=extent, cmap=cmap,
                          vmin=-limit if symmetric else None, vmax=limit)
        ax.set_title(title, fontsize=9)
        fig.colorbar(image, ax=ax, shrink=0.85, label=label, format="%.3g")
        return ax

    lobe = geometry.source_lobe_m
    ax = show(axes[0, 0], demo.source_power, g.delta1_m, max(8 * lobe, 8 * g.delta1_m),
              f"source plane (Eq. 3): {demo.source_power.sum():.3g} W\nsinc lobe {lobe:.3g} m",
              "power per cell [W]")
    ax.set_xlabel("x1 [m]"), ax.set_ylabel("y1 [m]")
    spacing = g.spacings_m[demo.screen_plane]
    ax = show(axes[0, 1], demo.screen, spacing, g.n * spacing / 2,
              f"phase screen of the strongest layer\n(altitude {demo.screen_altitude_m / 1e3:.3g} km)", "phase [rad]",
              cmap="RdBu_r", symmetric=True)
    ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]")
    ax = show(axes[1, 0], demo.observed_power, g.deltan_m, geometry.roi_m / 2 * 1.2,
              f"aperture plane (Eq. 4, {len(g.planes_m)} steps, N = {g.n})\n"
              f"{demo.aperture_power_w:.3g} W in the aperture (circle)", "power per cell [W]")
    ax.add_patch(Circle((0, 0), geometry.aperture_m / 2, fill=False, color="cyan", lw=1))
    ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]")
    arcsec = np.rad2deg(1) * 3600
    half = max(4 * geometry.wavelength_m / geometry.aperture_m, 2.5 * geometry.wavelength_m / demo.r0_m)
    ax = show(axes[1, 1], demo.focal_power, demo.focal_step_rad * arcsec, half * arcsec,
              f"focal plane: D/r0 = {geometry.aperture_m / demo.r0_m:.3g}\n"
              f"peak {demo.focal_power.max() / demo.vacuum_focal_power.max():.2f} of the vacuum peak",
              "power per sample [W]")
    ax.set_xlabel("x [arcsec]"), ax.set_ylabel("y [arcsec]")
    fig.suptitle(f"point source at {geometry.distance_m / 1e3:.4g} km, lambda = {geometry.wavelength_m * 1e9:.0f} nm,"
                 f" D = {geometry.aperture_m:g} m, r0 = {demo.r0_m * 100:.3g} cm", fontsize=10)
    fig.tight_layout()
    return _saved(fig, path)


def _figure(width_in: float, height_in: float, dpi: float = 110):
    """A Figure made without pyplot (no backend selected, no global registry to close)."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=dpi)


def _saved(fig, path: str | Path | None):
    if path is not None:
        fig.savefig(path, dpi=fig.dpi)
    return fig


# -- the PSF stamp the optics block renders ------------------------------------------------------------
@dataclass(frozen=True)
class PsfStamp:
    """One source's stamp as the optics block renders it at one render time."""

    source_id: str
    t_ns: int                      # render time [ns since the run's start]
    image: np.ndarray              # (h, w) photon flux the source adds per pixel [photon s^-1 pixel^-1]
    origin: tuple[int, int]        # (x0 column, y0 row) of the stamp's first pixel
    x_px: float                    # the source's true position [pixel]
    y_px: float
    magnitude: float               # its apparent magnitude [mag]
    collected_photon_rate: float   # its flux times the collecting area and throughput [photon s^-1]
    pixel_scale_arcsec: float
    path: str                      # the PSF path and why it was chosen

    @property
    def centroid(self) -> tuple[float, float]:
        """Flux-weighted (x, y) of the stamp [pixel]."""
        h, w = self.image.shape
        total = self.image.sum()
        return (float((self.image.sum(axis=0) * (self.origin[0] + np.arange(w))).sum() / total),
                float((self.image.sum(axis=1) * (self.origin[1] + np.arange(h))).sum() / total))


def psf_stamp(graph, optics: str | None = None, time_s: float = 0.0, source_id: str | None = None) -> PsfStamp:
    """The stamp the graph's optics block (``optics``, default the first) renders for one source at the
    render time at or before ``time_s`` after the run's start: ``source_id``, or by default the brightest
    satellite on the detector then (else the brightest star). The blocks upstream run for that window."""
    from evsda.blocks.ports import PointSources, SourceKind
    from evsda.blocks.scene.commands import upstream_values
    from evsda.graph import UserError, Window

    from .block import PointSourceOptics

    names = [n for n, node in graph.nodes.items() if isinstance(node.block, PointSourceOptics)]
    if optics is not None and optics not in names:
        raise UserError(f"{graph.file}: no optics block named '{optics}'; it has {names or 'none'}")
    if not names:
        raise UserError(f"{graph.file}: the graph has no optics block")
    name = optics or names[0]
    block: PointSourceOptics = graph.nodes[name].block
    run = graph.run_info()
    t_ns = round(time_s * 1e9)
    if not 0 <= t_ns < run.duration_ns:
        raise UserError(f"the stamp's time must be within the run, 0 to {run.duration_ns / 1e9:g} s; got {time_s}")
    index = t_ns // run.window_ns
    window = Window(index, index * run.window_ns, min((index + 1) * run.window_ns, run.duration_ns), run.epoch)
    cadence = max(1, round(1e9 / block.params.render_rate_hz))
    t_ns = max(window.start_ns, (t_ns // cadence) * cadence)
    candidates = []          # (kind rank, magnitude, PointSources, column)
    for src in upstream_values(graph, name, window).get("sources", []):
        k = max(int(np.searchsorted(src.t_ns, t_ns, side="right")) - 1, 0)
        for j, sid in enumerate(np.asarray(src.source_id).astype(str)):
            if source_id is not None and sid != str(source_id):
                continue
            if np.isfinite(src.x_px[k, j]) and np.isfinite(src.y_px[k, j]) and src.photon_flux[k, j] > 0:
                candidates.append((int(src.kind[j] != SourceKind.SATELLITE), float(src.magnitude[k, j]), src, j))
    if not candidates:
        what = f"source '{source_id}'" if source_id is not None else "source"
        raise UserError(f"no {what} is on the detector at {t_ns / 1e9:g} s; choose another time or source")
    _, magnitude, src, j = min(candidates, key=lambda c: c[:2])
    one = PointSources(src.focal_plane, src.wavelength_m, src.t_ns, src.source_id[[j]], src.kind[[j]],
                       src.x_px[:, [j]], src.y_px[:, [j]], src.photon_flux[:, [j]], src.magnitude[:, [j]],
                       src.range_m[:, [j]], src.zenith_angle_rad, src.boresight_azimuth_rad, src.field_rotation_rad)
    block.setup(run)
    out = block.step(Window(index, t_ns, t_ns + cadence, run.epoch), sources=[one])
    irradiance, truth = out["irradiance"], out["truth"]
    k = max(int(np.searchsorted(src.t_ns, t_ns, side="right")) - 1, 0)
    zenith, range_m = float(src.zenith_angle_rad[k]), float(src.range_m[k, j])
    imager = getattr(block, "_imager", None)
    path = imager.chooser.choose(zenith, range_m).reason if imager is not None else block.params.psf_path
    collected = float(src.photon_flux[k, j]) * block.telescope.collecting_area_m2 * block.params.throughput
    return PsfStamp(str(src.source_id[j]), int(t_ns), irradiance.stamp_flux[0, 0].copy(),
                    tuple(int(v) for v in irradiance.stamp_origin[0, 0]), float(truth.x_px[0]), float(truth.y_px[0]),
                    magnitude, collected, float(np.degrees(src.focal_plane.pixel_scale_rad) * 3600), path)


def plot_psf_stamp(stamp: PsfStamp, path: str | Path | None = None, dpi: float = 110):
    """The stamp in detector pixels (photon flux per pixel), the true position (+) and the centroid (x)."""
    fig = _figure(7.2, 6.2, dpi)
    ax = fig.add_subplot()
    h, w = stamp.image.shape
    x0, y0 = stamp.origin
    image = ax.imshow(stamp.image, origin="upper", interpolation="nearest", cmap="magma",
                      extent=(x0 - 0.5, x0 + w - 0.5, y0 + h - 0.5, y0 - 0.5))
    fig.colorbar(image, ax=ax, shrink=0.85, label="photon flux [photon s^-1 pixel^-1]", format="%.3g")
    cx, cy = stamp.centroid
    ax.plot(stamp.x_px, stamp.y_px, "+", color="cyan", ms=14, mew=1.5, label="true position")
    ax.plot(cx, cy, "x", color="lime", ms=9, mew=1.5, label="stamp centroid")
    ax.set_xlabel(f"column x [pixel] ({stamp.pixel_scale_arcsec:.3g} arcsec per pixel)")
    ax.set_ylabel("row y [pixel]")
    ax.legend(fontsize=8, loc="upper right")
    fraction = stamp.image.sum() / stamp.collected_photon_rate if stamp.collected_photon_rate > 0 else np.nan
    reason = "\n(".join(stamp.path.split(" (", 1))      # the path, then its conditions on their own line
    ax.set_title(f"{stamp.source_id} at {stamp.t_ns / 1e9:.6g} s, {stamp.magnitude:.2f} mag: {h}x{w} stamp holds "
                 f"{fraction:.1%} of {stamp.collected_photon_rate:.3g} photon/s; centroid - truth = "
                 f"({cx - stamp.x_px:+.2f}, {cy - stamp.y_px:+.2f}) px\n{reason}", fontsize=7.5)
    fig.tight_layout()
    return _saved(fig, path)
