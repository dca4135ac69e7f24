"""Graph files: YAML descriptions of a simulation, loaded and checked before any work.

A graph file names blocks (``type`` + ``params``), the connections between their
ports, sub-graphs it includes, and the run's time range and seed::

    evsda: 1
    name: leo_pass
    run: {start: "2024-03-01T02:15:00Z", duration_s: 10, window_s: 0.1, seed: 1}
    include:
      - {file: "library:sensors/prophesee_gen4.yaml", as: sensor, set: {pixel.temperature_K: 280}}
    blocks:
      iss: {type: tle_source, params: {tle_file: "library:tle/iss.tle"}}
    connections:
      - {from: optics.irradiance, to: sensor.irradiance}
    outputs: [sensor.events]

Loading is a pipeline of three steps, each its own module: reading (:mod:`~evsda.graph.reading`: safe
YAML, the file format), flattening (:mod:`~evsda.graph.flatten`: includes, swap, set, expose) and
checking (:mod:`~evsda.graph.checks`: one small function per check). :func:`load_graph` reports every
problem of a file at once as a :class:`~evsda.graph.errors.GraphError`, one line per problem naming the
file, the block, the port or parameter, and what was expected.
"""

from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evsda import library
from pydantic import ValidationError

from . import checks
from .block import Block, RunInfo
from .errors import GraphError, Problem, UserError, suggest
from .flatten import BlockNode, FlatGraph, apply_overrides, flatten, flatten_resolved, set_param
from .limits import Limits
from .params import describe_validation_error
from .reading import GRAPH_KEYS, GraphFile, RunSection, parse_value, read_yaml
from .wiring import Connection, Endpoint

if TYPE_CHECKING:
    import networkx as nx

__all__ = ["GRAPH_KEYS", "BlockNode", "Graph", "GraphFile", "RunSection", "check_override", "graph_from_dict",
           "load_graph", "parse_value", "read_yaml"]


@dataclass
class Graph:
    """A checked graph: block instances, connections and run settings."""

    file: str
    name: str
    run: RunSection | None
    nodes: dict[str, BlockNode]
    connections: list[Connection]
    outputs: list[Endpoint]                                # requested outputs
    exposed_inputs: dict[str, Endpoint] = field(default_factory=dict)
    exposed_outputs: dict[str, Endpoint] = field(default_factory=dict)
    digraph: nx.DiGraph = field(default_factory=checks.new_digraph)

    @property
    def blocks(self) -> dict[str, Block]:
        return {name: node.block for name, node in self.nodes.items()}

    def run_info(self) -> RunInfo:
        if self.run is None:
            raise UserError(f"{self.file}: the graph has no 'run' section (start, duration_s, window_s, seed); "
                            f"a sub-graph cannot be run on its own")
        return self.run.run_info()

    def to_dict(self) -> dict[str, Any]:
        """The fully resolved graph (no includes, every parameter explicit), as stored with a run."""
        return {
            "evsda": 1,
            "name": self.name,
            "run": self.run.model_dump() if self.run else None,
            "blocks": {n: {"type": b.type, "params": b.block.params.model_dump(mode="json")}
                       for n, b in self.nodes.items()},
            "connections": [{"from": str(c.source), "to": str(c.target)} for c in self.connections],
            "outputs": [str(output) for output in self.outputs],
        }

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()


# -- loading -------------------------------------------------------------------------------------------
def load_graph(path: str | Path, overrides: list[str] | dict[str, Any] | None = None,
               limits: Limits | None = None) -> Graph:
    """Load, flatten and check a graph file; raise GraphError listing every problem.

    ``overrides``: ``block.param`` (or ``run.field``) values, as a dict or as ``--set`` texts ``key=value``.
    ``limits`` (default :class:`Limits`) bounds the window count, sensor pixels and memory per window.
    """
    path = library.resolve(str(path))
    file = str(path)
    problems: list[Problem] = []
    flat, spec = flatten(path, problems)
    override_items = _override_items(overrides, file, problems)
    if spec is None:
        apply_overrides(flat.blocks, override_items, file, "--set", problems)
        raise GraphError(problems)
    if spec.run is None and flat.run is not None:   # the first include's run section
        spec = spec.model_copy(update={"run": flat.run})
    if spec.run is not None and "run" not in flat.blocks:
        run_items = {k: override_items.pop(k) for k in list(override_items) if k.startswith("run.")}
        spec = _override_run(spec, run_items, file, problems)
    apply_overrides(flat.blocks, override_items, file, "--set", problems)
    graph = check_graph(file, spec, flat, problems, limits)
    if problems:
        raise GraphError(problems)
    return graph


def _override_items(overrides: list[str] | dict[str, Any] | None, file: str, problems: list[Problem]) -> dict:
    """``overrides`` as a dict; ``--set`` texts are ``key=value`` with the value read as YAML."""
    if isinstance(overrides, dict):
        return dict(overrides)
    items = {}
    for text in overrides or []:
        key, sep, value = text.partition("=")
        if not sep:
            problems.append(Problem(file, f"--set '{text}'", "expected block.param=value"))
            continue
        items[key.strip()] = parse_value(value.strip())
    return items


def _override_run(spec: GraphFile, overrides: dict[str, Any], file: str, problems: list[Problem]) -> GraphFile:
    """``--set run.duration_s=2``: the run section's fields can be overridden like parameters."""
    if not overrides:
        return spec
    data = spec.run.model_dump()
    data.update({key.removeprefix("run."): value for key, value in overrides.items()})
    try:
        run = RunSection.model_validate(data)
    except ValidationError as exc:
        problems.extend(Problem(file, f"--set 'run.{loc}'", message) for loc, message in describe_validation_error(exc))
        return spec
    return spec.model_copy(update={"run": run})


def graph_from_dict(data: dict[str, Any], file: str = "<graph>", limits: Limits | None = None) -> Graph:
    """Check a resolved graph given as a dict (e.g. one stored with a run)."""
    problems: list[Problem] = []
    try:
        spec = GraphFile.model_validate(data)
    except ValidationError as exc:
        raise GraphError([Problem(file, f"'{loc}'", m) for loc, m in describe_validation_error(exc)]) from None
    graph = check_graph(file, spec, flatten_resolved(spec, file, problems), problems, limits)
    if problems:
        raise GraphError(problems)
    return graph


def check_graph(file: str, spec: GraphFile, flat: FlatGraph, problems: list[Problem],
                limits: Limits | None = None) -> Graph:
    """Run every check of :mod:`~evsda.graph.checks` on ``flat`` in order, noting their problems in
    ``problems``; the graph of what passed (blocks built, connections accepted)."""
    problems += checks.check_blocks(flat.blocks, spec.run.seed if spec.run else 0)
    connections, found = checks.check_connections(flat.blocks, flat.connections)
    problems += found
    digraph = checks.dependency_graph(flat.blocks, connections)
    problems += checks.check_required_inputs(flat.blocks, connections, flat.exposed_inputs)
    problems += checks.check_exposed_ports(flat.blocks, flat.exposures)
    problems += checks.check_cycles(file, digraph)
    problems += checks.check_requested_outputs(file, flat.blocks, flat.requested)
    problems += checks.check_sizes(file, spec.run, flat.blocks, limits)
    return Graph(file=file, name=spec.name or Path(file).stem, run=spec.run, nodes=flat.blocks,
                 connections=connections, outputs=checks.valid_outputs(file, flat.blocks, flat.requested),
                 exposed_inputs=flat.exposed_inputs, exposed_outputs=flat.exposed_outputs, digraph=digraph)


def check_override(graph: Graph, key: str, value: Any) -> list[Problem]:
    """The problems of setting ``key`` (``block.param`` or ``run.field``) to ``value`` in ``graph``, checked on
    that block's parameters (or the run section) alone: a sweep checks each distinct value once this way
    instead of loading every point's whole graph. Checks that need the whole graph (sizes) run with the point."""
    if key.startswith("run."):
        return _run_override_problems(graph, key, value)
    block, sep, param = key.partition(".")
    node = graph.nodes.get(block)
    if not sep or not param:
        return [Problem(graph.file, f"'{key}'", "expected block.param")]
    if node is None:
        return [Problem(graph.file, f"'{key}'", f"no block named '{block}'{suggest(block, graph.nodes)}")]
    params = copy.deepcopy(node.params)
    try:
        set_param(params, param, value)
    except KeyError:
        return [Problem(graph.file, f"'{key}'", f"parameter '{param}' is not a mapping")]
    problems: list[Problem] = []
    checks.build_block(node, params, graph.run.seed if graph.run else 0, problems)
    return problems


def _run_override_problems(graph: Graph, key: str, value: Any) -> list[Problem]:
    if graph.run is None:
        return [Problem(graph.file, f"'{key}'", "the graph has no run section")]
    data = graph.run.model_dump()
    data[key.removeprefix("run.")] = value
    try:
        RunSection.model_validate(data)
    except ValidationError as exc:
        return [Problem(graph.file, f"'run.{loc}'", message) for loc, message in describe_validation_error(exc)]
    return []
