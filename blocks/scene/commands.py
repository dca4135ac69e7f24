"""Command-line sub-commands contributed by the scene stage (see evsda.graph.commands)."""

from __future__ import annotations

import argparse

from evsda.graph import NS_PER_S, UserError, Window
from evsda.graph.commands import Command, add_figure_options
from evsda.graph.files import check_figure_output, save_figure


def upstream_values(graph, block_name: str, window: Window) -> dict:
    """The inputs of ``block_name`` for one window, by running the blocks upstream of it once."""
    run = graph.run_info()
    values: dict[tuple[str, str], object] = {}

    def evaluate(name: str) -> None:
        node = graph.nodes[name].block
        kwargs = {}
        for src, sport, dst, dport in graph.connections:
            if dst == name:
                if (src, sport) not in values:
                    evaluate(src)
                kwargs[dport] = values[(src, sport)]
        node.setup(run)
        for port, value in node.step(window, **kwargs).items():
            values[(name, port)] = value

    inputs = {}
    specs = type(graph.nodes[block_name].block).inputs
    for src, sport, dst, dport in graph.connections:
        if dst == block_name:
            evaluate(src)
            if specs[dport].multi:          # a port taking several connections gets them all, as a list
                inputs.setdefault(dport, []).append(values[(src, sport)])
            else:
                inputs[dport] = values[(src, sport)]
    return inputs


class PlotPass(Command):
    name = "plot-pass"
    help = "plot a satellite's track through the field of view (the paper's Fig. 2)"

    def configure(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("graph", help="graph file with a satellite block")
        add_figure_options(parser, dpi=110.0, aliases=("--png",))
        parser.add_argument("--satellite", default=None, help="name of the satellite block (default: the first)")
        parser.add_argument("--pad", type=float, default=30.0, help="seconds of track shown before and after the run")
        parser.add_argument("--set", action="append", default=[], metavar="BLOCK.PARAM=VALUE",
                            help="override a parameter, as for `evsda run`")

    def run(self, args: argparse.Namespace) -> int:
        from evsda.graph.graphfile import load_graph

        from .passes import find_passes      # here, not at the top: `evsda` starts without the scene's modules
        from .satellite import Satellite

        check_figure_output(args.output, args.overwrite, args.dpi)
        graph = load_graph(args.graph, args.set)
        run = graph.run_info()
        satellites = [n for n, node in graph.nodes.items() if isinstance(node.block, Satellite)]
        if args.satellite is not None and args.satellite not in satellites:
            raise UserError(f"{args.graph}: no satellite block named '{args.satellite}'; it has {satellites or 'none'}")
        if not satellites:
            raise UserError(f"{args.graph}: the graph has no satellite block to plot")
        name = args.satellite or satellites[0]
        block = graph.nodes[name].block
        window = Window(0, 0, min(run.window_ns, run.duration_ns), run.epoch)
        inputs = upstream_values(graph, name, window)
        view = block.view(window, **inputs)
        pad = round(args.pad * NS_PER_S)
        report = find_passes(view, 0, run.duration_ns, resolution_ns=block.cadence_ns)
        from .plot import plot_pass

        save_figure(plot_pass(view, report, -pad, run.duration_ns + pad), args.output, args.overwrite, args.dpi)
        if not getattr(args, "quiet", False):
            print(f"{args.output}: {inputs['orbit'].name}; " + ("; ".join(str(p) for p in report.passes)
                                                            or "no observable pass during the run"))
        return 0


COMMANDS: list = [PlotPass()]
