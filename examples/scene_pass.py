"""The scene quick-start pass (docs/scene.md): the ISS crossing a staring 0.5 m telescope's field over Graz.

Builds the scene blocks from Python (no graph file), finds the pass with the pass
finder, and prints a few samples of the satellite's PointSources.

    python examples/scene_pass.py
"""

from datetime import datetime, timezone

import numpy as np

from evsda.blocks.scene import Camera, GroundSite, PointingLaw, Satellite, StarField, TleSource
from evsda.graph import RunInfo, Window

START = datetime(2023, 3, 20, 19, 19, 57, tzinfo=timezone.utc)
run = RunInfo(epoch=START, duration_ns=10 * 10**9, window_ns=10**8, seed=1)

iss = TleSource(tle_file="library:tle/iss.tle")
site = GroundSite(name="Graz", latitude_deg=47.0671, longitude_deg=15.4934, altitude_m=493)
camera = Camera(width_px=1280, height_px=720, pixel_pitch_m=4.86e-6, focal_length_m=1.0)  # 0.5 m f/2, Gen4
pointing = PointingLaw(mode="stare", azimuth_deg=343.75, elevation_deg=40.57)
satellite = Satellite(shape="sphere", area_m2=2500, albedo=0.3, name="sat")
stars = StarField(faint_limit_mag=13, name="stars", seed=1)
for block in (iss, site, camera, pointing, satellite, stars):
    block.setup(run)

first = Window(0, 0, run.window_ns, START)
scene = {"orbit": iss.step(first)["orbit"], "observer": site.step(first)["observer"],
         "pointing": pointing.step(first)["pointing"], "focal_plane": camera.step(first)["focal_plane"]}
print(f"TLE: {scene['orbit'].name} epoch {scene['orbit'].epoch_utc}, {iss.tle_age_days:.2f} days before the start")

windows = [satellite.step(window, **scene)["sources"] for window in run.windows()]
for p in satellite.passes.passes:
    print("pass:", p)
t_ns = np.concatenate([w.t_ns for w in windows])
columns = {name: np.concatenate([getattr(w, name)[:, 0] for w in windows])
           for name in ("x_px", "y_px", "magnitude", "photon_flux", "range_m")}
zenith = np.concatenate([w.zenith_angle_rad for w in windows])
seen = np.flatnonzero(np.isfinite(columns["x_px"]))
for k in seen[np.linspace(0, len(seen) - 1, 6).astype(int)]:
    print(f"  t = {t_ns[k] / 1e9:6.3f} s  x = {columns['x_px'][k]:7.1f}  y = {columns['y_px'][k]:6.1f}  "
          f"V = {columns['magnitude'][k]:5.2f}  flux = {columns['photon_flux'][k]:.3e} photon/s/m^2  "
          f"range = {columns['range_m'][k] / 1e3:6.1f} km  boresight zenith angle = {np.degrees(zenith[k]):.2f} deg")

field = stars.step(Window(0, 0, 10**6, START), scene["observer"], scene["pointing"], scene["focal_plane"])["sources"]
on = np.isfinite(field.x_px[0])
print(f"stars on the detector at the start: {on.sum()} (brightest V = {np.nanmin(field.magnitude[0, on]):.2f})")
