"""The paper's Fig. 3 and Fig. 4 from the command line: valid PNGs whose numbers mean what they say."""

import argparse

import numpy as np
import pytest

from evsda.blocks.optics.commands import COMMANDS, PlotPropagation, PlotScreen
from evsda.blocks.optics.plots import propagation_demo, zernike_screen
from evsda.blocks.optics.propagation import grid_coordinates, point_source_field, point_source_vacuum_field
from evsda.blocks.optics.telescope import Telescope

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def invoke(command, argv):
    parser = argparse.ArgumentParser(prog=f"evsda {command.name}")
    command.configure(parser)
    return command.run(parser.parse_args(argv))


def png_size(path):
    """(width, height) from the IHDR chunk of a PNG file."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def test_commands_are_registered():
    assert {c.name for c in COMMANDS} == {"plot-screen", "plot-propagation", "plot-psf"}


def test_plot_screen_writes_a_png(tmp_path, capsys):
    png = tmp_path / "fig4.png"
    assert invoke(PlotScreen(), ["-o", str(png), "--modes", "15", "--samples", "64", "--show", "2,4,7"]) == 0
    width, height = png_size(png)
    assert width > 600 and height > 300 and png.stat().st_size > 20_000
    assert "D/r0 = 6" in capsys.readouterr().out


def test_plot_screen_rejects_bad_noll_indices(tmp_path):
    with pytest.raises(SystemExit):
        invoke(PlotScreen(), ["-o", str(tmp_path / "x.png"), "--show", "0,2"])


def test_screen_is_the_sum_of_its_modes_and_the_modes_are_noll_s():
    result = zernike_screen(0.3, 0.05, 10, shown=tuple(range(2, 12)), samples=33, seed=4)
    inside = np.isfinite(result.screen)
    np.testing.assert_allclose(np.tensordot(result.coefficients, result.modes, axes=(0, 0))[inside],
                               result.screen[inside], atol=1e-12)
    centre = result.modes[:, 16, 16]                    # r = 0: only m = 0 modes are non-zero
    assert centre[4 - 2] == pytest.approx(-np.sqrt(3))  # defocus sqrt(3)(2 r^2 - 1), Noll 1976 Table I
    assert centre[11 - 2] == pytest.approx(np.sqrt(5))  # spherical sqrt(5)(6 r^4 - 6 r^2 + 1)


def test_plot_propagation_writes_a_png(tmp_path, capsys):
    png = tmp_path / "fig3.png"
    argv = ["-o", str(png), "--aperture", "0.1", "--distance", "2e5", "--layers", "2", "--pupil-samples", "32"]
    assert invoke(PlotPropagation(), argv) == 0
    width, height = png_size(png)
    assert width > 600 and height > 600 and png.stat().st_size > 50_000
    assert "W in the aperture" in capsys.readouterr().out


def test_plot_propagation_reports_an_impossible_grid(tmp_path):
    from evsda.graph import UserError
    with pytest.raises(UserError, match="grid"):
        invoke(PlotPropagation(), ["-o", str(tmp_path / "x.png"), "--distance", "3.6e7", "--pupil-samples", "4000"])


def test_propagation_figure_powers_are_watts():
    # vacuum: the power in the aperture is the analytic Fresnel field's (Goodman 2005 Eq. 4-17) times the
    # source power over the source's own energy; the focal plane holds exactly that power (Parseval)
    demo = propagation_demo(aperture_m=0.1, distance_m=2e5, r0_500nm_m=1e4, n_layers=1, power_w=2.5,
                            pupil_samples=32)
    g, geometry = demo.grid, demo.geometry
    source = point_source_field(g.n, g.delta1_m, 550e-9, 2e5, geometry.roi_m)
    source_energy = np.sum(np.abs(source) ** 2) * g.delta1_m**2
    x = grid_coordinates(34, g.deltan_m)
    aperture = Telescope(0.1).pupil(34, g.deltan_m)
    analytic = np.abs(point_source_vacuum_field(x[None, :], x[:, None], 550e-9, 2e5, geometry.roi_m)) ** 2
    expected = 2.5 * np.sum(analytic * aperture**2) * g.deltan_m**2 / source_energy
    assert demo.source_power.sum() == pytest.approx(2.5)
    assert demo.vacuum_focal_power.sum() == pytest.approx(expected, rel=0.01)
    assert demo.aperture_power_w == pytest.approx(expected, rel=0.01)       # r0 = 10 km: no turbulence
    assert demo.focal_power.sum() == pytest.approx(demo.aperture_power_w, rel=1e-9)
    assert demo.observed_power.sum() <= 2.5
