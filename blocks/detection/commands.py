"""``evsda limiting-magnitude GRAPH [GRAPH ...] --magnitudes START:STOP:STEP -o DIR``: the limiting-magnitude
study of one or more designs (an event sensor and its frame baseline, say), as one table and one figure.

Each graph is run over the ladder (one run store per point under ``DIR/<graph name>/``; points already
complete are not recomputed, so an interrupted study resumes), P_d against magnitude is fitted
(:func:`.study.fit_logistic`) and set beside the analytic limit of the same design
(:mod:`.analytic`). Writes ``DIR/limiting_magnitude.csv`` (every point), ``DIR/summary.txt`` (the table
printed) and the figure (``--png``, default ``DIR/limiting_magnitude.png``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from evsda.graph import UserError
from evsda.graph.commands import Command


class LimitingMagnitudeCommand(Command):
    name = "limiting-magnitude"
    help = "P_d against magnitude of one or more designs, their 50 %% and 90 %% limits and the analytic cross-check"

    def configure(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("graphs", nargs="+", metavar="GRAPH",
                            help="study graphs: each with a detection_scoring block and injected_sources or a star_field")
        parser.add_argument("--magnitudes", required=True,
                            help="the ladder: START:STOP:STEP (stop included) or a list such as 8,9,10 [V mag]")
        parser.add_argument("-o", "--output", required=True, help="folder for the run stores, table and figure")
        parser.add_argument("--png", help="figure to write (default: OUTPUT/limiting_magnitude.png)")
        parser.add_argument("--set", action="append", default=[], metavar="BLOCK.PARAM=VALUE",
                            help="parameter override applied to every graph (repeatable)")
        parser.add_argument("--repeats", type=int, default=1,
                            help="runs per magnitude with seeds 1..N (star fields: runs of the whole field)")
        parser.add_argument("--jobs", type=int, default=1, help="points run at once (worker processes)")
        parser.add_argument("--frame-exposure", default="auto",
                            help="exposure of frame_sensor designs: 'auto' (the time a source takes to cross one "
                                 "pixel, at most the event detector's look) or seconds")
        parser.add_argument("--no-analytic", action="store_true", help="leave the analytic limits out of the table "
                                                                       "(event designs still get the check that a "
                                                                       "pixel can respond to the motion)")

    def run(self, args: argparse.Namespace) -> int:
        from .study import analytic_limits, check_ladder, check_response, design_limit, frame_overrides, inspect, parse_ladder, \
            plot, run_design, summary_lines, write_table

        magnitudes = parse_ladder(args.magnitudes)
        if args.repeats < 1 or args.jobs < 1:
            raise UserError(f"--repeats and --jobs must be at least 1, got {args.repeats} and {args.jobs}")
        out = Path(args.output)
        if out.exists() and not out.is_dir():
            raise UserError(f"{out} exists and is not a folder")
        out.mkdir(parents=True, exist_ok=True)
        designs = {path: inspect(path, args.set) for path in args.graphs}
        for design in designs.values():
            check_ladder(design, magnitudes)
        kinds = {path: design.kind for path, design in designs.items()}
        event_path = next((p for p, k in kinds.items() if k == "events"), None)
        curves = []
        for path in args.graphs:
            overrides = list(args.set)
            if kinds[path] == "frames":
                overrides = frame_overrides(path, overrides, event_path, args.frame_exposure)
            limit = None
            if kinds[path] == "events" or not args.no_analytic:
                limit = design_limit(path, overrides)
            if kinds[path] == "events":
                check_response(path, limit, min(magnitudes))
            curve = run_design(path, magnitudes, out, overrides, repeats=args.repeats, jobs=args.jobs)
            if not args.no_analytic:
                curve.analytic = analytic_limits(limit)
            curves.append(curve)
        write_table(curves, out / "limiting_magnitude.csv")
        lines = summary_lines(curves)
        (out / "summary.txt").write_text("\n".join(lines) + "\n")
        png = Path(args.png) if args.png else out / "limiting_magnitude.png"
        plot(curves, png)
        print("\n".join(lines))
        print(f"limiting-magnitude: {out / 'limiting_magnitude.csv'}, {out / 'summary.txt'}, {png}")
        return 0


COMMANDS = [LimitingMagnitudeCommand()]
