"""The paper's Fig. 2: the satellite's track, the field-of-view outline, in-field and eclipsed segments."""

from __future__ import annotations

from datetime import timedelta

import numpy as np

from . import projection
from .geometry import NS_PER_S, apparent_position, unit
from .passes import PassReport, iso
from .pointing import azel_from_enu
from .view import SatelliteView


def _sky(view: SatelliteView, t_ns: np.ndarray, directions: np.ndarray):
    """Azimuth/elevation (ground observer) or right ascension/declination (space) [deg] of directions."""
    if view.observer.is_ground:
        east, north, up = view.observer_model.enu(t_ns.astype(np.float64))
        lon, lat = azel_from_enu(*(np.einsum("...j,...j->...", directions, axis) for axis in (east, north, up)))
    else:
        lon = np.mod(np.arctan2(directions[..., 1], directions[..., 0]), 2 * np.pi)
        lat = np.arcsin(np.clip(directions[..., 2], -1, 1))
    return np.degrees(lon), np.degrees(lat)


def plot_pass(view: SatelliteView, report: PassReport, start_ns: int, stop_ns: int, path=None, title: str = ""):
    """The pass as a Figure (saved to ``path`` if given; built without pyplot, so no backend is selected and
    nothing stays open): sky track with the field outline, the track on the detector, and the angle from
    the boresight versus time.

    Track colours: observable in the field (green), in the field but not observable
    (orange), sunlit outside the field (blue), in the Earth's shadow (grey). The field
    outline is the detector's border at the start, middle and end of the run.
    """
    n = int(min(20001, max(2001, (stop_ns - start_ns) // 10_000_000)))
    t_ns = np.linspace(start_ns, stop_ns, n).astype(np.int64)
    s = view.sample(t_ns)
    b, r, u = view.pointing_model.frame(t_ns.astype(np.float64))
    lon_0 = float(_sky(view, t_ns[:1], b[:1])[0][0])
    from matplotlib.figure import Figure

    fig = Figure(figsize=(18, 5.4), dpi=110)
    sky, det, ax_t = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.1, 1.1, 1]})
    seconds = (t_ns - report.start_ns) / NS_PER_S
    lon, lat = _sky(view, t_ns, unit(apparent_position(view.track, view.observer_model, t_ns.astype(np.float64))))
    x_sky, y_sky = (lon - lon_0 + 180.0) % 360.0 - 180.0, lat
    labels = (f"azimuth - {lon_0:.2f} [deg]", "elevation [deg]") if view.observer.is_ground else \
        (f"right ascension - {lon_0:.2f} [deg]", "declination [deg]")
    categories = [
        (s.observable, "observable in the field", "tab:green"),
        (s.in_fov & ~s.observable, "in the field, not observable", "tab:orange"),
        (~s.in_fov & s.sunlit, "sunlit, outside the field", "tab:blue"),
        (~s.sunlit, "in the Earth's shadow", "0.6"),
    ]
    for mask, label, colour in categories:
        for ax, xs, ys in ((sky, x_sky, y_sky), (det, s.x_px, s.y_px),
                           (ax_t, seconds, np.degrees(s.boresight_angle_rad))):
            ax.plot(np.where(mask, xs, np.nan), np.where(mask, ys, np.nan), color=colour, lw=2.2,
                    label=label if ax is sky else None)

    fp = view.focal_plane
    w, h = fp.width_px, fp.height_px
    edge = np.concatenate([np.stack([np.linspace(-0.5, w - 0.5, 50), np.full(50, -0.5)], 1),
                           np.stack([np.full(50, w - 0.5), np.linspace(-0.5, h - 0.5, 50)], 1),
                           np.stack([np.linspace(w - 0.5, -0.5, 50), np.full(50, h - 0.5)], 1),
                           np.stack([np.full(50, -0.5), np.linspace(h - 0.5, -0.5, 50)], 1)])
    for j, style in ((0, "-"), (n // 2, "--"), (n - 1, ":")):
        dirs = projection.deproject(edge[:, 0], edge[:, 1], b[j], r[j], u[j], fp)
        lon_e, lat_e = _sky(view, np.full(len(dirs), t_ns[j]), dirs)
        sky.plot((lon_e - lon_0 + 180.0) % 360.0 - 180.0, lat_e, "k", ls=style, lw=1,
                 label=f"field at {seconds[j]:+.1f} s")
    det.plot(edge[:, 0], edge[:, 1], "k", lw=1)
    det.set_xlim(-0.25 * w, 1.25 * w)
    det.set_ylim(1.25 * h, -0.25 * h)
    det.set_aspect("equal")
    det.set_xlabel("column [pixel]")
    det.set_ylabel("row [pixel]")
    det.set_title(f"on the {w}x{h} detector ({np.degrees(fp.pixel_scale_rad) * 3600:.2f} arcsec/pixel)")
    radius = np.degrees(projection.radius_rad(fp))
    ax_t.axhline(radius, color="k", lw=1, ls="--", label="field corner radius")
    for p in report.passes:
        ax_t.axvspan((p.start_ns - report.start_ns) / NS_PER_S, (p.stop_ns - report.start_ns) / NS_PER_S,
                     color="tab:green", alpha=0.15)
    sky.set_xlabel(labels[0])
    sky.set_ylabel(labels[1])
    sky.set_aspect("equal", adjustable="datalim")
    sky.legend(fontsize=8, loc="best")
    sky.set_title(title or f"{view.orbit.name} ({view.orbit.catalog_number}) from {view.observer.name}")
    ax_t.set_yscale("log")
    ax_t.set_xlabel(f"time after {iso(view.epoch + timedelta(microseconds=report.start_ns / 1000))} [s]")
    ax_t.set_ylabel("angle from the boresight [deg]")
    ax_t.legend(fontsize=8, loc="best")
    passes = "\n".join(str(p) for p in report.passes[:4]) or "no observable pass"
    ax_t.set_title(passes, fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig
