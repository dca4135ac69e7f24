"""Trade study on one scene: event sensor versus frame sensor as a satellite gets fainter.

The same irradiance (a satellite crossing a 128 x 96 sensor on a uniform sky) feeds
* the event chain ``dvs_pixel -> row_scan_arbiter -> event_metrics`` (track SNR: events
  on the satellite's path above the background expected there), and
* the frame chain ``frame_sensor -> frame_photometry`` (CCD-equation SNR per frame),
for a range of magnitudes; the magnitude where each SNR falls to 5 is each sensor's
limiting magnitude on this scene (the paper, Sec. 1, cites event sensors 1-1.8 mag
brighter than a CMOS camera). The photon zero point and sensor settings are
illustrative, not a calibrated instrument.

    python examples/readout_frame_vs_event.py
"""

from __future__ import annotations

import numpy as np

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import FocalPlane, Irradiance, PointSources, SourceKind
from evsda.blocks.readout import EventMetrics, FramePhotometry, FrameSensor, RowScanArbiter
from evsda.graph import RunInfo

FP = FocalPlane(128, 96, 15e-6, 0.5)
ZERO_POINT = 1.6e8               # photons s^-1 on the detector from a magnitude-0 source (illustrative)
SKY = 40.0                       # photons s^-1 pixel^-1
DURATION_NS, WINDOW_NS, CADENCE_NS = 500_000_000, 100_000_000, 1_000_000
SPEED = (150.0, 40.0)            # pixel s^-1


def psf_stamp(dx: float, dy: float, sigma: float = 0.8) -> np.ndarray:
    """A 5 x 5 Gaussian PSF centred at (2 + dx, 2 + dy), normalised to 1."""
    yy, xx = np.mgrid[0:5, 0:5]
    g = np.exp(-((xx - 2 - dx) ** 2 + (yy - 2 - dy) ** 2) / (2 * sigma**2))
    return g / g.sum()


def scene(magnitude: float, window):
    t = window.sample_times_ns(CADENCE_NS)
    x = 20 + SPEED[0] * t / 1e9
    y = 30 + SPEED[1] * t / 1e9
    flux = ZERO_POINT * 10 ** (-0.4 * magnitude)
    origin = np.stack([np.round(x) - 2, np.round(y) - 2], -1)[:, None, :].astype(np.int32)
    stamps = np.stack([psf_stamp(a - round(a), b - round(b)) * flux for a, b in zip(x, y)])[:, None]
    irradiance = Irradiance(FP, 550e-9, t, np.full(t.size, SKY), origin, stamps)
    n = t.size
    sources = PointSources(FP, 550e-9, t, np.array(["SAT"]), np.array([SourceKind.SATELLITE], np.int8),
                           x[:, None], y[:, None], np.ones((n, 1)), np.full((n, 1), magnitude),
                           np.full((n, 1), 1e6), np.full(n, 0.5))
    return irradiance, sources


def run(magnitude: float) -> tuple[float, float]:
    run_info = RunInfo(duration_ns=DURATION_NS, window_ns=WINDOW_NS, seed=1)
    pixel = DvsPixel(seed=1, name="pixel")
    arbiter = RowScanArbiter(clock_hz=50e6, bus_throughput_eps=10e6)
    events = EventMetrics(track_radius_px=2.5)
    camera = FrameSensor(frame_rate_hz=10, exposure_s=0.1, quantum_efficiency=0.6, read_noise_e=3.0,
                         gain_e_per_dn=1.0, seed=1, name="camera")
    photometry = FramePhotometry(aperture_radius_px=2.5, annulus_inner_px=5, annulus_outer_px=9)
    for block in (pixel, arbiter, events, camera, photometry):
        block.setup(run_info)
    for window in run_info.windows():
        irradiance, sources = scene(magnitude, window)
        triggered = pixel.step(window, irradiance=irradiance)["events"]
        recorded = arbiter.step(window, events=triggered)["events"]
        events.step(window, triggered=triggered, events=recorded, sources=sources)
        frames = camera.step(window, irradiance=irradiance)["frames"]
        photometry.step(window, frames=frames, sources=sources)
    return (events.finish()["metrics"].values.get("track_snr", 0.0),
            photometry.finish()["metrics"].values.get("frame_snr_SAT", 0.0))


def crossing(magnitudes, snr, level=5.0) -> float:
    """The magnitude where ``snr`` falls through ``level`` (linear in log SNR), or nan."""
    for i in range(len(snr) - 1):
        if snr[i] >= level > snr[i + 1] and snr[i + 1] > 0:
            f = np.log(snr[i] / level) / np.log(snr[i] / snr[i + 1])
            return magnitudes[i] + f * (magnitudes[i + 1] - magnitudes[i])
    return float("nan")


def main() -> None:
    magnitudes = np.arange(4.0, 14.1, 1.0)
    print(f"{'magnitude':>10s} {'event track SNR':>16s} {'frame SNR':>10s}")
    event_snr, frame_snr = [], []
    for m in magnitudes:
        e, f = run(m)
        event_snr.append(e)
        frame_snr.append(f)
        print(f"{m:10.1f} {e:16.1f} {f:10.1f}")
    print(f"limiting magnitude (SNR 5): events {crossing(magnitudes, event_snr):.1f}, "
          f"frames {crossing(magnitudes, frame_snr):.1f}")


if __name__ == "__main__":
    main()
