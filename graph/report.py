"""Text shown to users: block listings, block descriptions, end-of-run summaries."""

from __future__ import annotations

import re
import textwrap

import numpy as np
from pydantic_core import PydanticUndefined

from .block import NS_PER_S, Block
from .errors import StoreError
from .ports import port_type_label

UNIT_RE = re.compile(r"\s*\[([^\[\]]*)\]\s*$")


def split_unit(description: str | None) -> tuple[str, str]:
    """``"Die temperature [K]"`` -> ``("Die temperature", "K")``."""
    description = description or ""
    match = UNIT_RE.search(description)
    if not match:
        return description, ""
    return description[: match.start()], match.group(1)


def _type_name(annotation) -> str:
    text = getattr(annotation, "__name__", None) or str(annotation)
    return text.replace("typing.", "").replace("NoneType", "None")


def _constraints(info) -> str:
    parts = []
    for item in info.metadata:
        for attr, symbol in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            value = getattr(item, attr, None)
            if value is not None:
                parts.append(f"{symbol} {value}")
    return ", ".join(parts)


def _block_summary(cls: type[Block]) -> str:
    """The first line of a block's docstring, or ``""``."""
    return (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""


def _input_short(port: str, spec) -> str:
    """``"scene: Scene[]?"``: ``[]`` when it takes many, ``?`` when optional."""
    return f"{port}: {spec.type.type_name()}{'[]' if spec.multi else ''}{'' if spec.required else '?'}"


def _block_paragraph(name: str, cls: type[Block]) -> list[str]:
    ins = ", ".join(_input_short(p, s) for p, s in cls.inputs.items())
    outs = ", ".join(f"{p}: {s.type.type_name()}" for p, s in cls.outputs.items())
    params = ", ".join(cls.Params.model_fields)
    return [f"{name}  —  {_block_summary(cls)}", f"    in:  {ins or '-'}", f"    out: {outs or '-'}",
            textwrap.fill(f"params: {params or '-'}", width=100, initial_indent="    ",
                          subsequent_indent="            ")]


def list_blocks(blocks: dict[str, type[Block]]) -> str:
    """One paragraph per block: summary, ports and parameter names."""
    return "\n".join(line for name, cls in blocks.items() for line in _block_paragraph(name, cls))


def _input_lines(inputs: dict) -> list[str]:
    lines = []
    for port, spec in inputs.items() or {}:
        flags = [f for f, on in (("many", spec.multi), ("optional", not spec.required)) if on]
        lines.append(f"  {port}: {port_type_label(spec.type)}{' (' + ', '.join(flags) + ')' if flags else ''}"
                     f"  {spec.description}")
    return lines or ["  (none)"]


def _output_lines(outputs: dict) -> list[str]:
    lines = [f"  {port}: {port_type_label(spec.type)}  {spec.description}" for port, spec in outputs.items()]
    return lines or ["  (none)"]


def _default_text(info) -> str:
    """``"required"`` or ``"default <value>"`` for one Params field."""
    if info.default is PydanticUndefined and info.default_factory is None:
        return "required"
    return f"default {info.default_factory() if info.default_factory else info.default!r}"


def _parameter_lines(field_name: str, info) -> list[str]:
    text, unit = split_unit(info.description)
    limits = _constraints(info)
    unit_text = f" [{unit}]" if unit else ""
    lines = [f"  {field_name}{unit_text}: {_type_name(info.annotation)}, {_default_text(info)}"
             f"{', ' + limits if limits else ''}"]
    if text:
        lines.append(textwrap.fill(text, width=100, initial_indent="      ", subsequent_indent="      "))
    return lines


def describe_block(name: str, cls: type[Block]) -> str:
    """Everything about one block type: docstring, ports with units, parameters with units and defaults."""
    doc = textwrap.dedent(cls.__doc__ or "").strip()
    lines = [name, "=" * len(name), doc, "", "Inputs:", *_input_lines(cls.inputs),
             "Outputs:", *_output_lines(cls.outputs), "Parameters:"]
    for field_name, info in cls.Params.model_fields.items():
        lines.extend(_parameter_lines(field_name, info))
    return "\n".join(lines)


def run_summary(graph, result) -> str:
    """End-of-run summary: windows, events, metrics, reuse and time per block."""
    lines = []
    store = result.store
    if store is not None:
        size = store.disk_bytes()
        per_event = f", {size / store.n_events:.1f} bytes per event" if store.n_events else ""
        lines.append(f"{store.path}: {store.committed_windows} of {graph.run_info().n_windows} windows, "
                     f"{store.n_events} events recorded; {size / 1e6:.1f} MB on disk{per_event}")
    for block, source in result.reused.items():
        lines.append(f"reused {block} from {source}")
    if result.metrics:
        lines.append("metrics:")
        for key, value in result.metrics.items():
            unit = result.metric_units.get(key, "")
            shown = f"{value:.6g}" if isinstance(value, float) else str(value)
            lines.append(f"  {key:<40} {shown} {unit}".rstrip())
    total = sum(result.timing_s.values()) or 1.0
    simulated = graph.run_info().duration_ns / NS_PER_S
    lines.append(f"time per block (wall clock, {simulated:g} s simulated):")
    for block, seconds in sorted(result.timing_s.items(), key=lambda kv: -kv[1]):
        lines.append(f"  {block:<40} {seconds:9.3f} s  {100 * seconds / total:5.1f} %")
    return "\n".join(lines)


def _seconds(attrs, key: str) -> float | None:
    """A duration kept in nanoseconds under ``key``, in seconds; None when absent."""
    return attrs.get(key, 0) / NS_PER_S if key in attrs else None


def _store_info_base(store, status) -> dict:
    attrs = store.attrs
    graph = attrs.get("graph") or {}
    return {
        "store": str(store.path),
        "status": status.describe(),
        "complete": status.complete,
        "resumable": status.resumable,
        "graph": graph.get("name"),
        "description": graph.get("description"),
        "evsda_version": attrs.get("evsda_version"),
        "seed": attrs.get("seed"),
        "start_epoch": attrs.get("start_epoch"),
        "duration_s": _seconds(attrs, "duration_ns"),
        "window_s": _seconds(attrs, "window_ns"),
        "windows": status.windows,
        "n_windows": status.n_windows,
        "events": store.n_events,
        "events_by_cause": {},
        "metrics": {name: {"value": value, "unit": store.metric_units.get(name, "")}
                    for name, value in store.metrics.items()},
        "products": {},
        "tables": {},
        "checkpoint": status.has_checkpoint,
        "disk_bytes": store.disk_bytes(),
        "reused": attrs.get("reused", {}),
    }


def _count_causes(store, info: dict) -> None:
    """Fill ``info["events_by_cause"]``, or mark the store damaged when a chunk cannot be read."""
    labels = store.group["events/cause"].attrs.get("flag_meanings", "").split()
    counts = np.zeros(256, np.int64)
    try:
        for chunk in store.iter_events():
            counts += np.bincount(chunk["cause"], minlength=256)
    except StoreError as exc:       # a damaged chunk: say so, and show the rest of what the store holds
        info.update(status=f"damaged: {str(exc).removeprefix(f'{store.path}: ')}", complete=False,
                    resumable=False)
    else:
        info["events_by_cause"] = {(labels[code] if code < len(labels) else f"cause_{code}"): int(counts[code])
                                   for code in np.flatnonzero(counts)}


def _add_products_and_tables(store, info: dict) -> None:
    """Rows committed per product (``products/<block>/<port>/_attrs``) and per table column."""
    lengths = store._committed().get("lengths", {})
    for key, length in sorted(lengths.items()):
        parts = key.split("/")
        if parts[0] == "products" and parts[-1] == "_attrs":
            info["products"]["/".join(parts[1:-2]) + "." + parts[-2]] = int(length)
        elif parts[0] not in ("products", "events", "checkpoint", "metrics") and len(parts) == 2:
            info["tables"].setdefault(parts[0], {})[parts[1]] = int(length)


def store_info(store) -> dict:
    """What a run store holds, as plain data (``evsda info``): its graph, seed, epoch, duration, events by
    cause, metrics with units, products, tables, and whether it is complete or resumable."""
    status = store.status()
    info = _store_info_base(store, status)
    if store.n_events and not status.problems:
        _count_causes(store, info)
    _add_products_and_tables(store, info)
    return info


def _table_line(name: str, columns: dict[str, int]) -> str:
    """``"table        stars: 12 rows of ra, dec; 3 rows of id"``: columns grouped by row count."""
    by_rows: dict[int, list[str]] = {}
    for column, rows in columns.items():
        by_rows.setdefault(rows, []).append(column)
    return f"table        {name}: " + "; ".join(f"{rows} rows of {', '.join(names)}"
                                             for rows, names in sorted(by_rows.items(), reverse=True))


def _metric_lines(metrics: dict) -> list[str]:
    if not metrics:
        return []
    lines = ["metrics:"]
    for key, entry in metrics.items():
        value = entry["value"]
        shown = f"{value:.6g}" if isinstance(value, float) else str(value)
        lines.append(f"  {key:<40} {shown} {entry['unit']}".rstrip())
    return lines


def _store_header_lines(info: dict) -> list[str]:
    lines = [f"{info['store']}: {info['status']}"]
    if info["graph"]:
        lines.append(f"graph        {info['graph']}" + (f" — {info['description']}" if info["description"] else ""))
    lines.append(f"seed         {info['seed']}")
    lines.append(f"start epoch  {info['start_epoch']}")
    if info["duration_s"] is not None:
        lines.append(f"duration     {info['duration_s']:g} s in {info['n_windows']} windows of {info['window_s']:g} s")
    by_cause = ", ".join(f"{k} {v}" for k, v in info["events_by_cause"].items())
    lines.append(f"events       {info['events']}" + (f" ({by_cause})" if by_cause else ""))
    return lines


def describe_store(info: dict) -> str:
    """``evsda info``'s text from :func:`store_info`'s data."""
    lines = _store_header_lines(info)
    lines.extend(f"product      {name}: {rows} windows" for name, rows in info["products"].items())
    lines.extend(_table_line(name, columns) for name, columns in info["tables"].items())
    lines.append(f"checkpoint   {'kept' if info['checkpoint'] else 'none'}; "
                 f"{info['disk_bytes'] / 1e6:.1f} MB on disk; evsda {info['evsda_version']}")
    lines.extend(f"reused       {block} from {source}" for block, source in info["reused"].items())
    lines.extend(_metric_lines(info["metrics"]))
    return "\n".join(lines)
