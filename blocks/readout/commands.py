"""Command-line sub-commands contributed by the readout stage (see evsda.graph.commands):

* ``evsda export STORE [--format aedat4|evt2|evt3|hdf5|npy] -o FILE [--time readout|trigger] [--truth [csv|hdf5]]
  [--overwrite] [--partial]``
* ``evsda render STORE [--png F] [--gif F] [--truth] [--scale S] [--dpi D] [--start-s S] [--stop-s S] [--frames N]
  [--fps F] [--overwrite]``
* ``evsda plot-lightcurve | plot-rate | plot-spacetime STORE -o FILE [...]`` (see :mod:`.plots`)

Both read the recorded events of a run store in chunks, so memory stays flat. Outputs are checked
before any work (folder exists and is writable, no existing file unless ``--overwrite``), written
under a temporary name and renamed when complete. An unfinished run is exported only with
``--partial``; ``render`` draws it with a note.
"""

from __future__ import annotations

import argparse
import sys

from evsda.blocks.ports import EventCause
from evsda.graph import NS_PER_S, UserError
from evsda.graph.commands import Command, add_figure_options, check_seconds
from evsda.graph.files import (atomic_output, check_figure_output, check_free_space, check_output_path,
                               save_figure)

from .exporters import BYTES_PER_EVENT, WRITERS, export_events, extension_warning, infer_format
from .render import render_gif, render_png
from .truth_export import FORMATS as TRUTH_FORMATS
from .truth_export import truth_path, write_truth_csv, write_truth_hdf5

#: the most frames ``render --gif`` draws (1000 s of animation at 10 frames per second)
MAX_FRAMES = 10_000


def _open(path: str):
    from evsda.graph.store import RunStore

    store = RunStore.open(path)
    fp = store.focal_plane
    if fp is None:
        raise UserError(f"{path} holds no recorded events (no focal-plane geometry); run a graph whose "
                        f"outputs include an arbiter's events")
    return store, fp


def _incomplete(store) -> str | None:
    """Why the store is not a finished run (its status line), or None if it is."""
    status = store.status()
    store.check_readable()
    return None if status.complete else status.describe()


def _progress(chunks, total: int, what: str):
    from tqdm import tqdm

    with tqdm(total=total, unit="event", desc=what, disable=None, leave=False) as bar:
        for chunk in chunks:
            yield chunk
            bar.update(len(chunk["x"]))


def _max_time_us(store) -> int | None:
    """The latest time any event of the run can carry [µs since the start epoch]: its duration."""
    duration_ns = store.attrs.get("duration_ns")
    return None if duration_ns is None else -(-int(duration_ns) // 1000)


class ExportCommand(Command):
    name = "export"
    help = "write a run's recorded events to an event-camera file format"

    def configure(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("store", help="run store (.zarr) written by `evsda run`")
        parser.add_argument("--format", choices=sorted(WRITERS), default=None,
                            help="aedat4 (iniVation), evt2/evt3 (Prophesee raw), hdf5 (v2e layout, integer µs, "
                                 "gzip), npy (tonic's x, y, t, p); default: from the extension of OUTPUT "
                                 "(.aedat4, .raw = evt3, .h5/.hdf5, .npy)")
        parser.add_argument("-o", "--output", required=True, help="file to write")
        parser.add_argument("--time", choices=("readout", "trigger"), default="readout",
                            help="which time of the Eq. 22 record to write (trigger: hdf5 and npy only)")
        parser.add_argument("--chunk-size", type=int, default=1 << 20, help="events read at a time")
        parser.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it exists")
        parser.add_argument("--partial", action="store_true",
                            help="export the committed part of an unfinished run (refused otherwise)")
        parser.add_argument("--truth", nargs="?", const="csv", choices=sorted(TRUTH_FORMATS), default=None,
                            help="also write the ground truth (every source's time, x, y, magnitude, flux, range, "
                                 "kind, id at the optics render rate) beside OUTPUT as NAME.truth.csv (default) "
                                 "or NAME.truth.h5")

    def run(self, args: argparse.Namespace) -> int:
        if args.chunk_size < 1:
            raise UserError(f"--chunk-size must be at least 1, got {args.chunk_size}")
        if args.format is None:
            args.format = infer_format(args.output)
        output = check_output_path(args.output, args.overwrite, "export")
        truth_output = None
        if args.truth:
            truth_output = check_output_path(truth_path(output, args.truth), args.overwrite, "truth")
        store, fp = _open(args.store)
        if truth_output is not None and not store.has_truth:
            raise UserError(f"{args.store} holds no ground truth (run with run.store_truth: false, or by an evsda "
                            f"older than the truth group); export without --truth")
        unfinished = _incomplete(store)
        if unfinished and not args.partial:
            raise UserError(f"{args.store} is not a finished run ({unfinished}); pass --partial to export "
                            f"the events it has committed")
        check_free_space(output, store.n_events * BYTES_PER_EVENT.get(args.format, 64) + (1 << 20), "export")
        warning = extension_warning(args.output, args.format)
        if warning:
            print(f"evsda: warning: {warning}", file=sys.stderr)
        epoch = store.attrs.get("start_epoch")
        chunks = _progress(store.iter_events(args.chunk_size), store.n_events, "export")
        with atomic_output(output, args.overwrite, "export") as temporary:
            n = export_events(chunks, temporary, args.format, fp.width_px, fp.height_px, time=args.time, epoch=epoch,
                              max_time_us=_max_time_us(store))
        note = f"; partial run: {unfinished}" if unfinished else ""
        if not getattr(args, "quiet", False):
            print(f"wrote {n} events to {args.output} ({args.format}, {args.time} times in µs since "
                  f"{epoch or 'the run start'}{note})")
        if truth_output is not None:
            rows = store.read_truth()
            with atomic_output(truth_output, args.overwrite, "truth") as temporary:
                if args.truth == "csv":
                    k = write_truth_csv(rows, temporary)
                else:
                    k = write_truth_hdf5(rows, temporary, store.truth_attrs(), epoch, fp.width_px, fp.height_px)
            if not getattr(args, "quiet", False):
                print(f"wrote {k} truth rows ({len(set(rows['source_id'].tolist()))} sources) to {truth_output}")
        return 0


class RenderCommand(Command):
    name = "render"
    help = "draw a run's events: accumulated image (ON green, OFF red) and animation"

    def configure(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("store", help="run store (.zarr) written by `evsda run`")
        parser.add_argument("--png", help="accumulated event image to write (paper Fig. 6)")
        parser.add_argument("--gif", help="animation of the events over time to write")
        parser.add_argument("--start-s", type=float, default=None, help="first readout time shown [s]")
        parser.add_argument("--stop-s", type=float, default=None, help="readout time where the images stop [s]")
        parser.add_argument("--frames", type=int, default=100, help="frames of the animation")
        parser.add_argument("--fps", type=float, default=10.0, help="frames per second of the animation")
        parser.add_argument("--chunk-size", type=int, default=1 << 20, help="events read at a time")
        parser.add_argument("--overwrite", action="store_true", help="replace the image files if they exist")
        parser.add_argument("--truth", action="store_true", help="draw the true paths of the sources on the PNG")
        parser.add_argument("--scale", type=float, default=None,
                            help="PNG pixels per sensor pixel (1: native resolution; default: an 8-inch figure)")
        parser.add_argument("--dpi", type=float, default=100.0, help="resolution of the PNG [dots per inch]")

    def run(self, args: argparse.Namespace) -> int:
        if args.scale is not None and not 0 < args.scale <= 64:
            raise UserError(f"--scale must be in (0, 64] PNG pixels per sensor pixel, got {args.scale}")
        _check_dpi(args.dpi)
        if not args.png and not args.gif:
            raise UserError("evsda render needs --png FILE and/or --gif FILE")
        if args.frames < 1 or not 0 < args.fps < float("inf"):
            raise UserError(f"--frames must be at least 1 and --fps positive, got {args.frames} and {args.fps}")
        if args.chunk_size < 1:
            raise UserError(f"--chunk-size must be at least 1, got {args.chunk_size}")
        if args.gif and args.frames > MAX_FRAMES:
            raise UserError(f"--frames must be at most {MAX_FRAMES}, got {args.frames}")
        check_seconds("--start-s", args.start_s)
        check_seconds("--stop-s", args.stop_s)
        for output in filter(None, (args.png, args.gif)):
            check_output_path(output, args.overwrite, "image")
        store, fp = _open(args.store)
        unfinished = _incomplete(store)
        if unfinished:
            print(f"evsda: note: {args.store} is not a finished run ({unfinished}); drawing the events it has "
                  f"committed", file=sys.stderr)
        start = None if args.start_s is None else round(args.start_s * NS_PER_S)
        stop = None if args.stop_s is None else round(args.stop_s * NS_PER_S)
        if start is not None and stop is not None and stop <= start:
            raise UserError(f"--stop-s ({args.stop_s}) must be after --start-s ({args.start_s})")
        if args.png:
            truth = _truth_of(store) if args.truth else None
            with atomic_output(args.png, args.overwrite, "image", suffix=".png") as temporary:
                on, off = render_png(store.iter_events(args.chunk_size), temporary, fp.width_px, fp.height_px,
                                     start, stop, truth=truth, scale=args.scale, dpi=args.dpi)
            if not getattr(args, "quiet", False):
                print(f"wrote {args.png}: {on} ON and {off} OFF events")
        if args.gif:
            lo = 0 if start is None else start
            hi = stop if stop is not None else _end_ns(store)
            if hi <= lo:
                raise UserError(f"{args.store} has no events after {lo / NS_PER_S} s to animate; pass --stop-s")
            with atomic_output(args.gif, args.overwrite, "animation", suffix=".gif") as temporary:
                n = render_gif(store.iter_events(args.chunk_size), temporary, fp.width_px, fp.height_px, lo, hi,
                               n_frames=args.frames, fps=args.fps)
            if not getattr(args, "quiet", False):
                print(f"wrote {args.gif}: {n} frames from {lo / NS_PER_S} s to {hi / NS_PER_S} s")
        return 0


def _truth_of(store) -> dict:
    truth = store.read_truth()
    if not truth:
        raise UserError(f"{store.path} holds no ground truth (run with run.store_truth: false, or by an evsda older "
                        f"than the truth group); draw it without --truth")
    return truth


def _check_dpi(dpi: float) -> None:
    if not 10 <= dpi <= 2400:
        raise UserError(f"--dpi must be between 10 and 2400, got {dpi}")


class _StorePlot(Command):
    """A figure of a run store saved to ``-o FILE`` (format from the extension: png, pdf, svg...)."""

    def configure(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("store", help="run store (.zarr) written by `evsda run`")
        add_figure_options(parser, dpi=100.0)
        self.options(parser)

    def options(self, parser: argparse.ArgumentParser) -> None:
        """This plot's own arguments."""

    def check(self, args: argparse.Namespace) -> None:
        """Refuse this plot's own bad arguments before any work."""

    def figure(self, store, args: argparse.Namespace):
        """The Figure, and one line saying what it shows."""
        raise NotImplementedError

    def run(self, args: argparse.Namespace) -> int:
        from evsda.graph.store import RunStore

        check_figure_output(args.output, args.overwrite, args.dpi)
        self.check(args)
        store = RunStore.open(args.store)
        if store.focal_plane is None:
            raise UserError(f"{args.store} holds no recorded events (no focal-plane geometry)")
        unfinished = _incomplete(store)
        if unfinished:
            print(f"evsda: note: {args.store} is not a finished run ({unfinished}); drawing what it has committed",
                  file=sys.stderr)
        fig, summary = self.figure(store, args)
        save_figure(fig, args.output, args.overwrite, args.dpi)
        if not getattr(args, "quiet", False):
            print(f"wrote {args.output}: {summary}")
        return 0


def _bin(parser: argparse.ArgumentParser, default: float) -> None:
    parser.add_argument("--bin-s", type=float, default=default, help=f"time bin [s] (default {default:g})")


class PlotLightCurve(_StorePlot):
    name = "plot-lightcurve"
    help = "plot a source's light curve: ON/OFF events per time bin along its true path, and its magnitude"

    def options(self, parser):
        parser.add_argument("--source", default=None, help="source id (default: the satellite longest in the field)")
        _bin(parser, 0.01)
        parser.add_argument("--radius-px", type=float, default=3.0, help="track radius [pixel] (as object_metrics)")
        parser.add_argument("--latency-s", type=float, default=1.0,
                            help="how long after the source passed a pixel its events count [s] (as object_metrics)")

    def figure(self, store, args):
        from .plots import light_curve, plot_light_curve

        if not args.radius_px >= 0 or not 0 <= args.latency_s <= 10:
            raise UserError(f"--radius-px must be >= 0 and --latency-s in [0, 10], got {args.radius_px} and "
                            f"{args.latency_s}")
        curve = light_curve(store, args.source, args.bin_s, args.radius_px, args.latency_s)
        return plot_light_curve(curve, args.dpi), (f"light curve of {curve.source_id}: {int(curve.on.sum())} ON and "
                                                   f"{int(curve.off.sum())} OFF events along its path")


class PlotRate(_StorePlot):
    name = "plot-rate"
    help = "plot the event rate against time, by cause (signal, leak, parasitic, shot)"

    def options(self, parser):
        _bin(parser, 0.01)
        parser.add_argument("--time", choices=("readout", "trigger"), default="readout",
                            help="bin events by readout time t_a (default) or trigger time t_t")

    def figure(self, store, args):
        from .plots import event_rate, plot_event_rate

        rate = event_rate(store, args.bin_s, args.time)
        counts = ", ".join(f"{c.name.lower()} {int(n)}" for c, n in zip(EventCause, rate.counts.sum(axis=1)))
        return plot_event_rate(rate, args.dpi), f"event rate by cause ({counts})"


class PlotSpaceTime(_StorePlot):
    name = "plot-spacetime"
    help = "plot events' x (or y) against time with the true tracks: a moving source is a line of its rate"

    def options(self, parser):
        parser.add_argument("--axis", choices=("x", "y"), default="x", help="column x (default) or row y")
        parser.add_argument("--start-s", type=float, default=None, help="first trigger time shown [s]")
        parser.add_argument("--stop-s", type=float, default=None, help="trigger time where the plot stops [s]")
        parser.add_argument("--stars", action="store_true", help="draw the stars' true tracks too")
        parser.add_argument("--max-events", type=int, default=200_000, help="events drawn at most (every k-th)")

    def check(self, args):
        if args.max_events < 1:
            raise UserError(f"--max-events must be at least 1, got {args.max_events}")
        check_seconds("--start-s", args.start_s)
        check_seconds("--stop-s", args.stop_s)

    def figure(self, store, args):
        from .plots import plot_space_time

        fig = plot_space_time(store, args.axis, args.start_s, args.stop_s, args.stars, args.max_events, dpi=args.dpi)
        return fig, f"{args.axis}-t space-time plot"


def _end_ns(store) -> int:
    """The end of the run (or just after its last recorded event) [ns]."""
    duration = store.attrs.get("duration_ns")
    last = 0
    if store.n_events:
        last = int(next(store.iter_events(1, start=store.n_events - 1))["t_readout_ns"][-1]) + 1
    return max(int(duration or 0), last)


COMMANDS: list = [ExportCommand(), RenderCommand(), PlotLightCurve(), PlotRate(), PlotSpaceTime()]
