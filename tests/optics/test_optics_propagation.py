"""Point-source field (paper Eq. 3), multi-plane angular-spectrum propagation (Eq. 4) and Schmidt's sampling rules."""

import numpy as np
import pytest

from evsda.blocks.optics.fft_screens import fft_phase_screens
from evsda.blocks.optics.propagation import (
    grid_coordinates, plane_spacings, point_source_field, point_source_vacuum_field, propagate,
    square_aperture_vacuum_field)
from evsda.blocks.optics.sampling import (
    PropagationGeometry, PropagationGrid, check_grid, choose_grid, planes_for, violations)
from evsda.graph import ParameterError

LAMBDA = 0.5e-6
APERTURE = 0.3


def _vacuum_error(geometry, grid):
    source = point_source_field(grid.n, grid.delta1_m, LAMBDA, geometry.distance_m, geometry.roi_m, curvature=False)
    field = propagate(source, LAMBDA, grid.delta1_m, grid.deltan_m, grid.planes_m,
                      source_curvature=-geometry.distance_m)
    x = grid_coordinates(grid.n, grid.deltan_m)
    exact = point_source_vacuum_field(x[None, :], x[:, None], LAMBDA, geometry.distance_m, geometry.roi_m)
    inside = np.abs(x) <= APERTURE / 2
    amplitude = np.abs(field - exact)[np.ix_(inside, inside)].max() / np.abs(exact).max()
    phase = np.abs(np.angle(field / exact)[np.ix_(inside, inside)]).max()
    return amplitude, phase


@pytest.mark.parametrize("distance", [400e3, 36_000e3])          # LEO and GEO
def test_vacuum_point_source_matches_the_analytic_fresnel_field(distance):
    geometry = PropagationGeometry(LAMBDA, distance, APERTURE)
    grid = choose_grid(geometry, APERTURE / 48)
    assert violations(geometry, grid) == []
    amplitude, phase = _vacuum_error(geometry, grid)
    # float64 quadratic phases: at GEO the source-plane chirp spans ~1e5 rad, yet the result keeps 1e-9 rad
    assert amplitude < 1e-6
    assert phase < 1e-8


def test_collimation_removes_the_spherical_wave():
    distance = 400e3
    geometry = PropagationGeometry(LAMBDA, distance, APERTURE)
    grid = choose_grid(geometry, APERTURE / 48)
    source = point_source_field(grid.n, grid.delta1_m, LAMBDA, distance, geometry.roi_m)   # chirp included
    field = propagate(source, LAMBDA, grid.delta1_m, grid.deltan_m, grid.planes_m, collimate=distance)
    x = grid_coordinates(grid.n, grid.deltan_m)
    exact = point_source_vacuum_field(x[None, :], x[:, None], LAMBDA, distance, geometry.roi_m, collimated=True)
    inside = np.abs(x) <= APERTURE / 2
    np.testing.assert_allclose(field[np.ix_(inside, inside)], exact[np.ix_(inside, inside)], rtol=1e-6, atol=0)


def test_off_axis_source_arrives_tilted_with_its_footprint_on_axis():
    distance = 400e3
    geometry = PropagationGeometry(LAMBDA, distance, APERTURE)
    grid = choose_grid(geometry, APERTURE / 48)
    xc, yc = 3 * grid.delta1_m, -2 * grid.delta1_m
    source = point_source_field(grid.n, grid.delta1_m, LAMBDA, distance, geometry.roi_m, centre=(xc, yc),
                                curvature=False)
    field = propagate(source, LAMBDA, grid.delta1_m, grid.deltan_m, grid.planes_m, source_curvature=-distance)
    x = grid_coordinates(grid.n, grid.deltan_m)
    on_axis = point_source_vacuum_field(x[None, :], x[:, None], LAMBDA, distance, geometry.roi_m)
    tilt = np.exp(-2j * np.pi * (xc * x[None, :] + yc * x[:, None]) / (LAMBDA * distance))
    inside = np.abs(x) <= APERTURE / 2
    np.testing.assert_allclose(field[np.ix_(inside, inside)], (on_axis * tilt)[np.ix_(inside, inside)],
                               rtol=0, atol=1e-5 * np.abs(on_axis).max())


def test_square_aperture_matches_the_fresnel_integrals():
    # Goodman 2005 Eq. 4-53 / Schmidt 2010 Eq. 1.60: Fresnel number (w/2)^2 / (lambda z) = 5
    n, wavelength, width = 1024, 1e-6, 0.02
    distance = (width / 2) ** 2 / (wavelength * 5)
    delta = width / 128
    x = grid_coordinates(n, delta)
    edge = np.where(np.isclose(np.abs(x), width / 2), 0.5, (np.abs(x) < width / 2).astype(float))
    field = propagate(np.outer(edge, edge).astype(complex), wavelength, delta, delta, [distance], absorber=False)
    exact = square_aperture_vacuum_field(x[None, :], x[:, None], width, wavelength, distance)
    inside = np.abs(x) < width
    error = np.abs(field - exact)[np.ix_(inside, inside)]
    assert np.sqrt(np.mean(error**2)) < 0.01 * np.abs(exact).max()


def test_energy_is_conserved_through_every_step_and_screen():
    # Parseval: a compact beam through three phase screens with scaling steps keeps sum |U|^2 delta^2
    n, wavelength = 256, 1e-6
    delta1, deltan = 2e-3, 3e-3
    planes = [200.0, 500.0, 1000.0]
    x = grid_coordinates(n, delta1)
    beam = np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / (0.05) ** 2).astype(complex)
    rng = np.random.default_rng(0)
    spacing = plane_spacings(delta1, deltan, planes)
    screens = {i: fft_phase_screens(rng, n, spacing[i], 0.05)[0] for i in (1, 2)}
    energy_in = np.sum(np.abs(beam) ** 2) * delta1**2
    for last in range(1, 4):
        out = propagate(beam, wavelength, delta1, plane_spacings(delta1, deltan, planes)[last], planes[:last],
                        {k: v for k, v in screens.items() if k < last}, absorber=False)
        energy_out = np.sum(np.abs(out) ** 2) * spacing[last] ** 2
        assert energy_out == pytest.approx(energy_in, rel=1e-10)


def test_a_grid_at_the_aliasing_limit_is_accepted_and_accurate():
    geometry = PropagationGeometry(LAMBDA, 400e3, APERTURE, r0_m=0.1, turbulence_length_m=20e3)
    free = choose_grid(geometry, APERTURE / 48)
    lz = LAMBDA * geometry.distance_m
    d1p, d2p = geometry.widened
    needed = d1p / (2 * free.delta1_m) + d2p / (2 * free.deltan_m) + lz / (2 * free.delta1_m * free.deltan_m)
    n = int(np.ceil(needed))
    at_limit = PropagationGrid(n, free.delta1_m, free.deltan_m, planes_for(geometry, n, free.delta1_m, free.deltan_m))
    assert violations(geometry, at_limit) == []
    check_grid(geometry, at_limit, "test")
    assert _vacuum_error(geometry, at_limit)[0] < 1e-6
    # constraint 1 exactly at its bound is valid too, a hair beyond it is not
    limit = (lz - d2p * free.delta1_m) / d1p
    edge = PropagationGrid(free.n, free.delta1_m, limit, free.planes_m)
    assert not any("constraint 1" in v for v in violations(geometry, edge))
    beyond = PropagationGrid(free.n, free.delta1_m, limit * 1.001, free.planes_m)
    assert any("constraint 1" in v for v in violations(geometry, beyond))


def test_an_aliasing_grid_is_one_clear_error_with_a_valid_suggestion():
    geometry = PropagationGeometry(LAMBDA, 400e3, APERTURE, r0_m=0.1, turbulence_length_m=20e3)
    free = choose_grid(geometry, APERTURE / 48)
    small = PropagationGrid(free.n // 2, free.delta1_m, free.deltan_m, free.planes_m)
    with pytest.raises(ParameterError) as info:
        check_grid(geometry, small, "block 'optics' parameter 'grid_size'")
    message = str(info.value)
    assert "constraint 2" in message and f"a valid grid is N = {free.n}" in message
    assert "\n" not in message
    # the undersized grid really does alias: the vacuum field goes wrong
    coarse = PropagationGrid(int(0.4 * free.n) // 2 * 2, free.delta1_m, free.deltan_m, free.planes_m)
    assert _vacuum_error(geometry, coarse)[0] > 0.1


def test_long_steps_get_vacuum_planes_for_constraint_four():
    geometry = PropagationGeometry(LAMBDA, 400e3, APERTURE, r0_m=0.1, turbulence_length_m=20e3)
    grid = choose_grid(geometry, APERTURE / 48, layer_planes_m=(400e3 - 20e3, 400e3 - 5e3))
    spacing = grid.spacings_m
    steps = np.diff(np.r_[0.0, grid.planes_m])
    assert np.all(steps <= grid.n * spacing[:-1] * spacing[1:] / LAMBDA * (1 + 1e-9))
    assert {380e3, 395e3, 400e3} <= set(grid.planes_m)


@pytest.mark.parametrize("r0_500nm, distance", [(0.1, 400e3), (0.05, 400e3), (0.1, 36_000e3)])
def test_reference_scintillation_matches_the_weak_fluctuation_rytov_variance(r0_500nm, distance):
    # a point source through HV5/7-shaped layers: in weak fluctuations the intensity variance on the aperture
    # plane is the spherical-wave Rytov variance 2.25 k^(7/6) sum_i Cn2dh_i [z_i (1 - z_i/R)]^(5/6) (Tatarskii
    # 1971; for a homogeneous path it integrates to Andrews & Phillips 2005's 0.5 Cn2 k^(7/6) L^(11/6), and for
    # R -> inf it is their plane-wave Eq. 12.38): the reference path's scintillation, from its own diffraction
    from evsda.blocks.optics.plots import propagation_demo
    wavelength = 550e-9
    k = 2 * np.pi / wavelength
    measured = []
    for seed in range(3):
        demo = propagation_demo(aperture_m=0.3, distance_m=distance, wavelength_m=wavelength, r0_500nm_m=r0_500nm,
                                n_layers=3, seed=seed, pupil_samples=48)
        x = grid_coordinates(demo.grid.n, demo.grid.deltan_m)
        inside = np.abs(x) <= 0.3                            # well inside the illuminated 1.2 m region
        intensity = demo.observed_power[np.ix_(inside, inside)]
        measured.append(intensity.var() / intensity.mean() ** 2)
    from evsda.blocks.optics.atmosphere import Atmosphere
    layers = Atmosphere.hufnagel_valley(3).scaled_to_r0(r0_500nm).layers
    rytov = 2.25 * k ** (7 / 6) * sum(layer.cn2_dh * (layer.altitude_m * (1 - layer.altitude_m / distance)) ** (5 / 6)
                                      for layer in layers)
    assert rytov < 0.3
    assert np.mean(measured) == pytest.approx(rytov, rel=0.15)


def test_kept_transfer_functions_give_the_field_made_afresh(monkeypatch):
    # the reference probes' frames share their grid, so the steps' transfer functions are kept between calls: the
    # same field as with every transfer function made afresh, and a kept plan is not changed by its use
    from evsda.blocks.optics import propagation
    n, wavelength, delta1, deltan = 128, 0.5e-6, 2e-3, 3e-3
    planes = [200.0, 500.0, 1000.0]
    x = grid_coordinates(n, delta1)
    beam = np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / 0.05**2).astype(complex)
    spacing = plane_spacings(delta1, deltan, planes)
    rng = np.random.default_rng(1)
    screens = {i: fft_phase_screens(rng, n, spacing[i], 0.05)[0] for i in (0, 1, 2)}
    kept = [propagate(beam, wavelength, delta1, deltan, planes, screens) for _ in range(2)]
    monkeypatch.setattr(propagation, "TRANSFER_CACHE_BYTES", 0)
    afresh = propagate(beam, wavelength, delta1, deltan, planes, screens)
    np.testing.assert_array_equal(kept[0], afresh)
    np.testing.assert_array_equal(kept[1], afresh)
    assert np.abs(afresh).max() > 0


@pytest.mark.parametrize("screened", [(1, 3), (3, 4), (4,), (), (0, 2)])
def test_a_point_source_from_its_kept_vacuum_steps_is_the_whole_propagation(screened, monkeypatch):
    # the steps before the first screen read only the grid: kept, and gone on from, they give the whole
    # propagation's field bit for bit, first made and when taken from the cache, and are not changed by their use
    from evsda.blocks.optics import propagation
    n, distance, roi = 128, 4e5, 0.4
    planes = [1e5, 2e5, 3e5, 3.5e5, distance]
    delta1, deltan = LAMBDA * distance / roi / 8, 2e-3
    spacing = plane_spacings(delta1, deltan, planes)
    rng = np.random.default_rng(2)
    source = point_source_field(n, delta1, LAMBDA, distance, roi, curvature=False)
    propagation._vacuum_head.cache_clear()
    for collimate in (np.inf, distance):
        screens = {i: fft_phase_screens(rng, n, spacing[i], 0.05)[0] for i in screened}
        whole = propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance,
                          collimate=collimate, workers=1)
        for _ in range(2):
            kept = propagation.propagate_point_source(n, delta1, deltan, LAMBDA, distance, roi, planes, screens,
                                                      collimate=collimate, workers=1)
            np.testing.assert_array_equal(kept, whole)
        if min(screened, default=0) > 2:                           # from an unscreened plane (its absorber next)
            head = propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance,
                             workers=1, stop=2)
            head.setflags(write=False)
            np.testing.assert_array_equal(propagate(source, LAMBDA, delta1, deltan, planes, screens,
                                                    source_curvature=-distance, collimate=collimate, workers=1,
                                                    start=(2, head)), whole)
    assert propagation._vacuum_head.cache_info().currsize == (1 if screened and min(screened) > 0 else 0)
    monkeypatch.setattr(propagation, "TRANSFER_CACHE_BYTES", 0)      # too large a grid to keep: made every time
    np.testing.assert_array_equal(
        propagation.propagate_point_source(n, delta1, deltan, LAMBDA, distance, roi, planes, screens,
                                           collimate=distance, workers=1), whole)


@pytest.mark.parametrize("n", [128, 127])
def test_fused_steps_give_the_field_of_numpys_steps(n, monkeypatch):
    # a step's division, screen phasor and absorber made in one compiled pass (propagation._step) give the field
    # NumPy's steps give, bit for bit, through every plane, from a kept start, and on the way to a stop
    from evsda.blocks.optics import propagation
    if not propagation.fused_steps_agree():
        pytest.skip("NumPy's complex product rounds otherwise here: propagate makes its steps with NumPy")
    distance, roi = 4e5, 0.4
    planes = [1e5, 2e5, 3e5, 3.5e5, distance]
    delta1, deltan = LAMBDA * distance / roi / 8, 2e-3
    spacing = plane_spacings(delta1, deltan, planes)
    rng = np.random.default_rng(n)
    screens = {i: fft_phase_screens(rng, n, spacing[i], 0.05)[0] * 20 for i in (2, 3, 5)}
    screens[3] = np.asfortranarray(screens[3])                    # the reference path's screens are read transposed
    source = point_source_field(n, delta1, LAMBDA, distance, roi, curvature=False)

    def fields():
        head = propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance, stop=2)
        head.setflags(write=False)
        return [propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance,
                          collimate=distance, start=start) for start in (None, (2, head))] + [head]

    fused = fields()
    assert len(propagation._step.signatures) == 1                  # one compile, whatever the screens' layout
    monkeypatch.setattr(propagation, "fused_steps_agree", lambda: False)
    for a, b in zip(fused, fields(), strict=True):
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64))
    assert np.array_equal(fused[0], fused[1])


@pytest.mark.parametrize("n", [256, 255, 64])
def test_compiled_phasors_are_numpys_and_in_the_ffts_order(n):
    """The screens' phasors (one compiled pass after numpy's float32 sine and cosine) against the same steps in
    numpy: unit modulus taken in double precision, bit for bit, and ``shifted`` is ``ifftshift``'s order."""
    import scipy.fft as sfft

    from evsda.blocks.optics.propagation import _phasor

    phase = np.random.default_rng(n).normal(0.0, 30.0, (n, n))
    rounded = phase.astype(np.float32)
    cos, sin = np.cos(rounded).astype(float), np.sin(rounded).astype(float)
    modulus = np.sqrt(np.square(cos) + np.square(sin))
    expected = (cos / modulus) + 1j * (sin / modulus)
    assert np.array_equal(_phasor(phase), expected)
    assert np.array_equal(_phasor(phase, shifted=True), sfft.ifftshift(expected))
    assert np.allclose(np.abs(_phasor(phase)), 1.0, rtol=0, atol=1e-15)


def _screened_path(n: int, screened: tuple[int, ...]):
    """A 400 km path of five planes on an ``n``-point grid, strong screens (seeded by ``n``) at the planes
    ``screened``: ``(distance, roi, planes, delta1, deltan, screens, source)`` for :func:`propagate`."""
    distance, roi = 4e5, 0.4
    planes = [1e5, 2e5, 3e5, 3.5e5, distance]
    delta1, deltan = LAMBDA * distance / roi / 8, 2e-3
    spacing = plane_spacings(delta1, deltan, planes)
    rng = np.random.default_rng(n)
    screens = {i: fft_phase_screens(rng, n, spacing[i], 0.05)[0] * 20 for i in screened}
    source = point_source_field(n, delta1, LAMBDA, distance, roi, curvature=False)
    return distance, roi, planes, delta1, deltan, screens, source


@pytest.mark.parametrize("n", [128, 126, 135])
@pytest.mark.parametrize("fused", [True, False])
def test_an_observed_window_is_that_part_of_the_whole_field(n, fused, monkeypatch):
    # propagate(window=w) makes the last step's second inverse transform, division, absorber and chirp on the centred
    # w x w only (propagation._observed_window): bit for bit that part of the whole field, with or without the kept
    # vacuum steps and the collimation, for odd and even sizes (pocketfft's 1 / n^2 scale, not a power of 2 here)
    from evsda.blocks.optics import propagation
    if not fused:
        monkeypatch.setattr(propagation, "fused_steps_agree", lambda: False)
    distance, roi, planes, delta1, deltan, screens, source = _screened_path(n, (1, 3))
    for collimate in (np.inf, distance):
        whole = propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance,
                          collimate=collimate, workers=1)
        for window in (40, 41, 1, n):
            corner = n // 2 - window // 2
            part = whole[corner:corner + window, corner:corner + window]
            for made in (propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance,
                                   collimate=collimate, workers=1, window=window),
                         propagation.propagate_point_source(n, delta1, deltan, LAMBDA, distance, roi, planes,
                                                            screens, collimate=collimate, workers=1,
                                                            window=window)):
                assert made.shape == (window, window)
                assert np.array_equal(made.view(np.uint64), part.view(np.uint64))


@pytest.mark.parametrize("n", [256, 129])
def test_fields_in_padded_rows_are_those_in_contiguous_rows(n, monkeypatch):
    # propagate keeps its field in rows ROW_PADDING samples longer (propagation._padded: a 256-point field's rows 4 KiB
    # apart made the columns' transforms slow): bit for bit the field of contiguous rows and NumPy's steps (the
    # reference), whole, windowed, from a kept start and to a stop
    from evsda.blocks.optics import propagation
    distance, _, planes, delta1, deltan, screens, source = _screened_path(n, (2, 4))

    def fields():
        head = propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance, stop=2)
        head.setflags(write=False)
        made = [propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance,
                          collimate=distance, start=start, window=window)
                for start in (None, (2, head)) for window in (None, 40)]
        return made + [head]

    padded = fields()
    assert propagation.ROW_PADDING > 0
    monkeypatch.setattr(propagation, "ROW_PADDING", 0)
    monkeypatch.setattr(propagation, "fused_steps_agree", lambda: False)
    for a, b in zip(padded, fields(), strict=True):
        assert a.flags.c_contiguous
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64))


def test_transfer_products_over_whole_padded_rows_are_those_over_the_fields_columns(monkeypatch):
    # propagate multiplies each step's spectrum by its transfer function over the padded rows whole (one contiguous
    # product, propagation._times_rows) where NumPy gives the views' product bit for bit: the same fields as the
    # product over the views
    from evsda.blocks.optics import propagation
    assert propagation.whole_rows_agree()
    distance, _, planes, delta1, deltan, screens, source = _screened_path(256, (2, 4))

    def field():
        return propagate(source, LAMBDA, delta1, deltan, planes, screens, source_curvature=-distance,
                         collimate=distance, window=40)

    calls = []
    monkeypatch.setattr(propagation, "whole_rows_agree", lambda: calls.append(True) or True)
    whole = field()
    assert calls                                   # the whole rows were multiplied
    monkeypatch.setattr(propagation, "whole_rows_agree", lambda: False)
    assert np.array_equal(whole.view(np.uint64), field().view(np.uint64))
