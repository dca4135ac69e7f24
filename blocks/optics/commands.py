"""Command-line sub-commands contributed by the optics stage (see evsda.graph.commands).

* ``evsda plot-screen`` -- the paper's Fig. 4: Zernike modes and the Karhunen-Loeve screen they build;
* ``evsda plot-propagation`` -- the paper's Fig. 3: a point source's power through turbulent layers;
* ``evsda plot-psf`` -- the PSF stamp the optics block of a graph renders for one source.
"""

from __future__ import annotations

import argparse

from evsda.graph import UserError
from evsda.graph.commands import Command, add_figure_options, check_seconds
from evsda.graph.files import check_figure_output, save_figure

from .zernike import noll_to_nm


def _positive(kind):
    def parse(text: str):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
        return value
    return parse


def _noll_list(text: str) -> tuple[int, ...]:
    try:
        modes = tuple(int(item) for item in text.split(",") if item.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated Noll indices such as 2,4,5,7,11, got {text}")
    if not modes or min(modes) < 1:
        raise argparse.ArgumentTypeError(f"Noll indices start at 1, got {text}")
    return modes


class PlotScreen(Command):
    name = "plot-screen"
    help = "plot Zernike modes and the Kolmogorov phase screen they build (the paper's Fig. 4) as a PNG"

    def configure(self, parser: argparse.ArgumentParser) -> None:
        add_figure_options(parser, dpi=110.0)
        parser.add_argument("--aperture", type=_positive(float), default=0.3, help="aperture diameter D [m]")
        parser.add_argument("--r0", type=_positive(float), default=0.05,
                            help="Fried parameter at the wavelength of the phase [m]")
        parser.add_argument("--modes", type=_positive(int), default=20,
                            help="Zernike modes in the screen, from tilt (Noll j = 2 ...)")
        parser.add_argument("--show", type=_noll_list, default=(2, 4, 5, 7, 11),
                            help="Noll indices of the modes drawn, comma-separated")
        parser.add_argument("--samples", type=_positive(int), default=256, help="samples across the aperture")
        parser.add_argument("--seed", type=int, default=0, help="seed of the Karhunen-Loeve draw")

    def run(self, args: argparse.Namespace) -> int:
        from .plots import plot_zernike_screen, zernike_screen

        if args.modes > 1000:
            raise UserError(f"plot-screen: --modes {args.modes} is more than the 1000 modes supported")
        check_figure_output(args.output, args.overwrite, args.dpi)
        result = zernike_screen(args.aperture, args.r0, args.modes, args.show, args.samples, args.seed)
        save_figure(plot_zernike_screen(result), args.output, args.overwrite, args.dpi)
        shown = ", ".join(f"j={j} (n={noll_to_nm(j)[0]}, m={noll_to_nm(j)[1]})" for j in args.show)
        if not getattr(args, "quiet", False):
            print(f"{args.output}: modes {shown}; screen of {args.modes} modes, D/r0 = {result.d_over_r0:.3g}")
        return 0


class PlotPropagation(Command):
    name = "plot-propagation"
    help = "plot a point source's power through turbulent phase screens to the focal plane (the paper's Fig. 3)"

    def configure(self, parser: argparse.ArgumentParser) -> None:
        add_figure_options(parser, dpi=110.0)
        parser.add_argument("--aperture", type=_positive(float), default=0.3, help="aperture diameter D [m]")
        parser.add_argument("--distance", type=_positive(float), default=400e3, help="source range [m]")
        parser.add_argument("--wavelength", type=_positive(float), default=550e-9, help="wavelength [m]")
        parser.add_argument("--r0", type=_positive(float), default=0.05,
                            help="Fried parameter at zenith and 500 nm that the Hufnagel-Valley 5/7 profile is "
                                 "scaled to [m]")
        parser.add_argument("--layers", type=_positive(int), default=3, help="turbulent layers (phase screens)")
        parser.add_argument("--zenith", type=float, default=0.0, help="zenith angle [deg]")
        parser.add_argument("--power", type=_positive(float), default=1.0, help="power of the source plane [W]")
        parser.add_argument("--pupil-samples", type=_positive(int), default=64,
                            help="grid samples across the aperture")
        parser.add_argument("--seed", type=int, default=0, help="seed of the phase screens")

    def run(self, args: argparse.Namespace) -> int:
        from .plots import plot_propagation, propagation_demo

        if not 0 <= args.zenith < 90:
            raise UserError(f"plot-propagation: --zenith must be in [0, 90) degrees, got {args.zenith}")
        check_figure_output(args.output, args.overwrite, args.dpi)
        if args.layers > 32:
            raise UserError(f"plot-propagation: --layers {args.layers} is more than the 32 supported")
        try:
            demo = propagation_demo(args.aperture, args.distance, args.wavelength, args.r0, args.layers, args.zenith,
                                    args.power, args.seed, args.pupil_samples)
        except ValueError as exc:
            raise UserError(f"plot-propagation: no valid propagation grid for this geometry: {exc}; "
                            f"try fewer --pupil-samples or a shorter --distance") from None
        save_figure(plot_propagation(demo), args.output, args.overwrite, args.dpi)
        if not getattr(args, "quiet", False):
            print(f"{args.output}: grid {demo.grid.describe()}; {demo.aperture_power_w:.3g} W of {args.power:g} W "
                  f"in the aperture; r0 = {demo.r0_m:.3g} m at {args.wavelength * 1e9:.0f} nm")
        return 0


class PlotPsf(Command):
    name = "plot-psf"
    help = "plot the PSF stamp a graph's optics block renders for one source at one time"

    def configure(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("graph", help="graph file with an optics block")
        add_figure_options(parser, dpi=110.0)
        parser.add_argument("--optics", default=None, help="name of the optics block (default: the first)")
        parser.add_argument("--time-s", type=float, default=0.0, help="time after the run's start [s]")
        parser.add_argument("--source", default=None,
                            help="source id (default: the brightest satellite on the detector, else star)")
        parser.add_argument("--set", action="append", default=[], metavar="BLOCK.PARAM=VALUE",
                            help="override a parameter, as for `evsda run`")

    def run(self, args: argparse.Namespace) -> int:
        from evsda.graph.graphfile import load_graph

        from .plots import plot_psf_stamp, psf_stamp

        check_figure_output(args.output, args.overwrite, args.dpi)
        check_seconds("--time-s", args.time_s)
        stamp = psf_stamp(load_graph(args.graph, args.set), args.optics, args.time_s, args.source)
        save_figure(plot_psf_stamp(stamp, dpi=args.dpi), args.output, args.overwrite, args.dpi)
        cx, cy = stamp.centroid
        height, width = stamp.image.shape
        if not getattr(args, "quiet", False):
            print(f"{args.output}: {stamp.source_id} at {stamp.t_ns / 1e9:g} s, {height}x{width} "
                  f"stamp with {stamp.image.sum() / stamp.collected_photon_rate:.1%} of its flux, centroid "
                  f"({cx:.2f}, {cy:.2f}) vs true ({stamp.x_px:.2f}, {stamp.y_px:.2f}); {stamp.path}")
        return 0


COMMANDS: list = [PlotScreen(), PlotPropagation(), PlotPsf()]
