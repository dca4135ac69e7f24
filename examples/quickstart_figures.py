"""The quick start's figures, from a run of the main job: prints them, and writes them into the README.

Runs ``examples/iss_pass.yaml`` (or reads a store of it already made with ``--store``) and
prints the metrics the README's quick start quotes, in the README's form. With
``--write-readme`` it replaces the block between ``<!-- quickstart-figures -->`` and
``<!-- /quickstart-figures -->`` in README.md, so the figures there are always those of a run
of the code as it is.

    python examples/quickstart_figures.py [--store iss_pass.zarr] [--write-readme]
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from pathlib import Path

from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

ROOT = Path(__file__).resolve().parents[1]
MAIN_JOB = ROOT / "examples" / "iss_pass.yaml"
README = ROOT / "README.md"
BEGIN, END = "<!-- quickstart-figures -->", "<!-- /quickstart-figures -->"

#: the metrics the quick start shows: (name, how the README explains it)
SHOWN = (
    ("events_triggered", "every event the pixels fired"),
    ("events_recorded", "read out by the arbiter (+ dropped + pending = triggered)"),
    ("events_lost_pixel", "events the pixels could not emit (Eq. 17's owed events taken back, noise while blind)"),
    ("ratio_recorded_to_expected", "recorded / (triggered + lost in the pixels)"),
    ("out_of_order_fraction", "read out in another order than triggered"),
    ("events_triggered_signal", "by cause: signal, leak, parasitic, shot noise"),
    ("events_triggered_leak", ""),
    ("events_triggered_shot", ""),
    ("background_rate_hz_per_pixel", "in pixels away from the track (leak + shot noise)"),
    ("track_snr", "track events over the background expected there"),
    ("readout_delay_p99_s", "trigger-to-readout delay percentiles"),
)
UNITS = {"event": "event", "Hz pixel^-1": "Hz", "s": "s", "1": ""}


def metrics_of(store_path: Path | None) -> tuple[dict, dict]:
    """Metrics and units of a finished run of the main job (run now into a temporary store if none is given)."""
    if store_path is not None and (store_path / "zarr.json").exists():
        store = RunStore.open(store_path)
        return store.metrics, store.metric_units
    with tempfile.TemporaryDirectory() as tmp:
        out = store_path or Path(tmp) / "iss_pass.zarr"
        result = run_graph(load_graph(MAIN_JOB), out, progress=False)
        return dict(result.metrics), dict(result.metric_units)


def figures_block(metrics: dict, units: dict) -> str:
    """The README's text block of the quick-start metrics (a fenced ``text`` block)."""
    lines = ["```text"]
    for name, note in SHOWN:
        value = metrics[name]
        unit = UNITS.get(units.get(name, ""), units.get(name, ""))
        shown = f"{value:.3g}" if isinstance(value, float) and not name.startswith("ratio") else (
            f"{value:.6f}" if isinstance(value, float) else f"{value}")
        lines.append(f"{name:<29}{shown:>10} {unit:<6} {note}".rstrip())
    lines.append("```")
    return "\n".join(lines)


def replace_block(text: str, block: str) -> str:
    """``text`` with the part between the quick-start markers replaced by ``block``."""
    pattern = re.compile(re.escape(BEGIN) + r"\n.*?\n" + re.escape(END), re.S)
    if not pattern.search(text):
        raise ValueError(f"README has no {BEGIN} ... {END} block")
    return pattern.sub(lambda _: f"{BEGIN}\n{block}\n{END}", text, count=1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", type=Path, help="a run store of examples/iss_pass.yaml (made if missing)")
    parser.add_argument("--write-readme", action="store_true", help="write the figures into README.md")
    args = parser.parse_args()
    block = figures_block(*metrics_of(args.store))
    print(block)
    if args.write_readme:
        README.write_text(replace_block(README.read_text(encoding="utf-8"), block), encoding="utf-8")
        print(f"wrote the figures into {README}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
