"""Frame-sensor baseline and photometry: Janesick's dark current against its published
form and Pyxel's band gap, photon-transfer statistics of blank frames, clipping, timing,
window independence, and per-source SNR against the CCD equation (Howell 2006)."""

import numpy as np
import pytest

from evsda.blocks.ports import FocalPlane, Irradiance, PointSources, SourceKind
from evsda.blocks.readout import FramePhotometry, FrameSensor
from evsda.blocks.readout.frame_sensor import ELEMENTARY_CHARGE_C, dark_current_e_per_s, silicon_band_gap_eV
from evsda.graph import ParameterError, Window

FP = FocalPlane(96, 80, 10e-6, 1.0)
K_EV = 8.617333262e-5


def test_band_gap_at_300_K_is_pyxels_value():
    # ESA Pyxel's band_gap_silicon(300) = 1.1108214488636363 eV (Janesick's Varshni coefficients)
    assert silicon_band_gap_eV(300.0) == pytest.approx(1.1108214488636363, rel=1e-12)


def test_dark_current_follows_janesicks_formula():
    """Janesick (Scientific CCDs, 2001): D = 2.55e15 P_S D_FM T^1.5 exp(-E_g / 2kT) e-/s/pixel with
    P_S in cm^2 and D_FM in nA/cm^2. The temperature dependence is the same to rounding, and
    the rounded constant 2.55e15 agrees with the exact normalisation at 300 K to 1 %."""
    area_m2, fom = (10e-6) ** 2, 0.5
    temperatures = np.array([233.0, 263.0, 293.0, 300.0, 320.0])
    published = 2.55e15 * area_m2 * 1e4 * fom * temperatures**1.5 * np.exp(
        -silicon_band_gap_eV(temperatures) / (2 * K_EV * temperatures))
    ratio = dark_current_e_per_s(fom, area_m2, temperatures) / published
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-12)
    assert ratio[0] == pytest.approx(1.0, abs=0.01)


def test_dark_current_at_300_K_is_the_figure_of_merit():
    assert dark_current_e_per_s(1.0, 1e-4, 300.0) == pytest.approx(1e-9 / ELEMENTARY_CHARGE_C, rel=1e-12)
    # near room temperature silicon dark current doubles every ~8 K (here: 280 to 300 K)
    doubling_K = 20 * np.log(2) / np.log(dark_current_e_per_s(1.0, 1e-4, 300.0) / dark_current_e_per_s(1.0, 1e-4, 280.0))
    assert 6.0 < doubling_K < 9.0


def irradiance(fp, t_ns, background, origin=None, flux=None):
    n = len(t_ns)
    origin = np.zeros((n, 0, 2), np.int32) if origin is None else np.asarray(origin, np.int32)
    flux = np.zeros((n, 0, 1, 1)) if flux is None else np.asarray(flux, float)
    return Irradiance(fp, 550e-9, np.asarray(t_ns, np.int64), np.broadcast_to(np.asarray(background, float), (n,)).copy(),
                      origin, flux)


def test_blank_frames_follow_the_photon_transfer_relations():
    """Uniform flux b: mean DN = bias + (QE b t + i_d t) / g; variance = (QE b t + i_d t + σ_r²) / g²
    + 1/12 (shot noise, read noise, quantisation; Janesick's photon transfer)."""
    fp = FocalPlane(256, 256, 10e-6, 1.0)
    sensor = FrameSensor(frame_rate_hz=10, exposure_s=0.05, quantum_efficiency=0.5, read_noise_e=5.0,
                         dark_current_nA_cm2=2.0, temperature_K=300.0, gain_e_per_dn=2.0, bias_dn=100,
                         full_well_e=1e6, adc_bits=16, seed=3)
    out = sensor.step(Window(0, 0, 100_000_000), irradiance=irradiance(fp, [0], 2000.0))["frames"]
    assert out.image.shape == (1, 256, 256) and out.t_start_ns.tolist() == [0] and out.exposure_ns == 50_000_000
    dark_e = dark_current_e_per_s(2.0, fp.pixel_area_m2, 300.0) * 0.05
    mean_e = 0.5 * 2000 * 0.05 + dark_e
    dn = out.image[0].astype(float)
    variance = (mean_e + 25.0) / 4.0 + 1 / 12
    assert abs(dn.mean() - (100 + mean_e / 2)) < 5 * np.sqrt(variance / dn.size)
    assert dn.var() == pytest.approx(variance, rel=0.03)


def test_full_well_and_adc_clip():
    sensor = FrameSensor(full_well_e=1000, gain_e_per_dn=0.5, bias_dn=10, adc_bits=12, read_noise_e=0)
    out = sensor.step(Window(0, 0, 100_000_000), irradiance=irradiance(FP, [0], 1e7))["frames"]
    assert np.all(out.image == 2010)                 # 1000 e- / 0.5 + 10
    sensor = FrameSensor(full_well_e=1e6, gain_e_per_dn=0.5, adc_bits=8, read_noise_e=0)
    out = sensor.step(Window(0, 0, 100_000_000), irradiance=irradiance(FP, [0], 1e7))["frames"]
    assert np.all(out.image == 255)


def test_exposure_longer_than_the_frame_period_is_refused():
    with pytest.raises(ParameterError, match="exposure_s"):
        FrameSensor(frame_rate_hz=30, exposure_s=0.05)


def moving_scene(t_ns, x0=10.0, vx_px_s=400.0, y=40.0, flux=5e5):
    """A point source crossing the sensor: a 1-pixel stamp at its rounded position per 1 ms sample."""
    x = x0 + vx_px_s * t_ns / 1e9
    origin = np.stack([np.round(x), np.full_like(x, round(y))], axis=-1)[:, None, :]
    stamps = np.full((len(t_ns), 1, 1, 1), flux)
    return x, origin, stamps


def run_frames(edges, seed=1):
    sensor = FrameSensor(frame_rate_hz=20, exposure_s=0.03, seed=seed)
    grid = np.arange(0, edges[-1], 1_000_000)
    x, origin, stamps = moving_scene(grid)
    frames = []
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        sel = (grid >= lo) & (grid < hi)
        out = sensor.step(Window(i, lo, hi), irradiance=irradiance(FP, grid[sel], 50.0, origin[sel], stamps[sel]))
        frames.append(out["frames"])
    return frames


def test_frames_do_not_depend_on_the_windows():
    whole = run_frames([0, 200_000_000])
    cut = run_frames([0, 17_000_000, 51_000_000, 51_500_000, 130_000_000, 200_000_000])
    starts = np.concatenate([f.t_start_ns for f in cut])
    np.testing.assert_array_equal(starts, [0, 50_000_000, 100_000_000, 150_000_000])
    np.testing.assert_array_equal(whole[0].t_start_ns, starts)
    np.testing.assert_array_equal(np.concatenate([f.image for f in cut]), whole[0].image)


def sources_for(t_ns, x, y, magnitude=8.0, kind=SourceKind.STAR):
    n = len(t_ns)
    return PointSources(FP, 550e-9, np.asarray(t_ns, np.int64), np.array(["S1"]), np.array([kind], np.int8),
                        np.asarray(x, float).reshape(n, 1), np.asarray(y, float).reshape(n, 1), np.ones((n, 1)),
                        np.full((n, 1), magnitude), np.full((n, 1), np.inf), np.full(n, np.nan))


def test_star_snr_follows_the_ccd_equation():
    """A static star of F = 2e4 photon/s in one pixel on a sky of b = 400 photon/s/pixel: the
    measured mean SNR over 40 frames matches Howell's CCD equation with the known noise."""
    qe, t_exp, gain, read, F, b = 0.6, 0.02, 1.5, 4.0, 2e4, 400.0
    sensor = FrameSensor(frame_rate_hz=25, exposure_s=t_exp, quantum_efficiency=qe, read_noise_e=read,
                         dark_current_nA_cm2=0.05, temperature_K=293.15, gain_e_per_dn=gain, bias_dn=200,
                         full_well_e=1e6, adc_bits=16, seed=11)
    phot = FramePhotometry(aperture_radius_px=2.0, annulus_inner_px=5.0, annulus_outer_px=9.0,
                           gain_e_per_dn=gain, snr_threshold=5.0)
    grid = np.arange(0, 1_600_000_000, 10_000_000)
    origin = np.tile([[[47, 40]]], (grid.size, 1, 1))
    flux = np.full((grid.size, 1, 1, 1), F)
    for i, lo in enumerate(range(0, 1_600_000_000, 200_000_000)):
        sel = (grid >= lo) & (grid < lo + 200_000_000)
        window = Window(i, lo, lo + 200_000_000)
        frames = sensor.step(window, irradiance=irradiance(FP, grid[sel], b, origin[sel], flux[sel]))["frames"]
        phot.step(window, frames=frames, sources=sources_for(grid[sel], np.full(sel.sum(), 47.0), np.full(sel.sum(), 40.0)))
    v = phot.finish()["metrics"].values
    assert v["frame_measurements_S1"] == 40
    d = np.hypot(*np.mgrid[-10:11, -10:11])
    n_pix, n_b = int((d <= 2).sum()), int(((d > 5) & (d <= 9)).sum())
    assert (n_pix, n_b) == (13, 172)            # Gauss's circle problem: N(2) = 13, N(9) - N(5) = 253 - 81
    dark_e = dark_current_e_per_s(0.05, FP.pixel_area_m2, 293.15) * t_exp
    sigma2 = qe * b * t_exp + dark_e + read**2 + gain**2 / 12
    n_star = qe * F * t_exp
    snr = n_star / np.sqrt(n_star + n_pix * (1 + n_pix / n_b) * sigma2)
    assert v["frame_snr_S1"] == pytest.approx(snr, rel=0.05)
    assert v["frame_detected_fraction_S1"] == 1.0
    s2 = 25.0
    n_lim = (s2 + np.sqrt(s2**2 + 4 * s2 * n_pix * (1 + n_pix / n_b) * sigma2)) / 2
    assert v["frame_limiting_mag_S1"] == pytest.approx(8.0 + 2.5 * np.log10(n_star / n_lim), abs=0.1)
    assert v["frame_limiting_magnitude"] == v["frame_limiting_mag_S1"]


def test_trailed_satellite_is_measured_along_its_path():
    """A satellite crossing 12 pixels during a 30 ms exposure: the capsule aperture holds its
    whole trail, so the measured electrons are QE F t within shot noise."""
    sensor = FrameSensor(frame_rate_hz=20, exposure_s=0.03, read_noise_e=1.0, dark_current_nA_cm2=0.0,
                         gain_e_per_dn=1.0, full_well_e=1e6, adc_bits=16, seed=5)
    phot = FramePhotometry(aperture_radius_px=2.0, annulus_inner_px=4.0, annulus_outer_px=7.0)
    grid = np.arange(0, 200_000_000, 1_000_000)
    x, origin, stamps = moving_scene(grid, x0=8.0, flux=5e5)
    window = Window(0, 0, 200_000_000)
    frames = sensor.step(window, irradiance=irradiance(FP, grid, 50.0, origin, stamps))["frames"]
    srcs = sources_for(grid, x, np.full(grid.size, 40.0), kind=SourceKind.SATELLITE)
    signals = []
    for k in range(frames.image.shape[0]):
        t0 = int(frames.t_start_ns[k])
        path = np.stack([8.0 + 400.0 * np.array([t0, t0 + 30_000_000]) / 1e9, [40.0, 40.0]], axis=1)
        from evsda.blocks.readout.metrics import densify
        signal, snr, _ = phot.measure(frames.image[k].astype(float), densify(path))
        signals.append(signal)
    expected = 0.6 * 5e5 * 0.03
    assert np.mean(signals) == pytest.approx(expected, rel=4 * np.sqrt(expected) / expected / np.sqrt(len(signals)) + 0.01)
    v = phot.step(window, frames=frames, sources=srcs)["metrics"].values
    assert v["frame_measurements_S1"] == 4 and v["frame_snr_S1"] > 20


def test_frame_sensor_state_survives_a_zarr_checkpoint(tmp_path):
    """Stop mid-exposure, checkpoint through the run store, resume in a fresh block: same frames."""
    from evsda.graph.store import RunStore

    grid = np.arange(0, 200_000_000, 1_000_000)
    x, origin, stamps = moving_scene(grid)
    edges = [0, 61_000_000, 200_000_000]

    def step(sensor, i):
        sel = (grid >= edges[i]) & (grid < edges[i + 1])
        return sensor.step(Window(i, edges[i], edges[i + 1]),
                           irradiance=irradiance(FP, grid[sel], 50.0, origin[sel], stamps[sel]))["frames"]

    whole = FrameSensor(frame_rate_hz=20, exposure_s=0.03, seed=2)
    want = [step(whole, 0), step(whole, 1)]
    first = FrameSensor(frame_rate_hz=20, exposure_s=0.03, seed=2)
    got = [step(first, 0)]
    assert first.frame_index == 1 and first.exposure          # frame 1 (50-80 ms) is in progress
    store = RunStore.create(tmp_path / "ckpt.zarr")
    store.commit(windows=1, checkpoint=store.write_checkpoint(0, {"camera": first.get_state()}))
    second = FrameSensor(frame_rate_hz=20, exposure_s=0.03, seed=2)
    second.set_state(RunStore.open(tmp_path / "ckpt.zarr").read_checkpoint()["camera"])
    got.append(step(second, 1))
    for a, b in zip(want, got):
        np.testing.assert_array_equal(a.t_start_ns, b.t_start_ns)
        np.testing.assert_array_equal(a.image, b.image)
