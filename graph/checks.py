"""Checking a flattened graph: each check is a small function that returns the problems it finds.

The checks run in order (:func:`evsda.graph.graphfile.check_graph`): block types and parameters (which
builds the blocks), connections (ports exist, types match, fan-in), required inputs, exposed ports,
cycles, requested outputs, sizes. A later check skips what an earlier one already reported (a block of an
unknown type, say), so each mistake is one message.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evsda import library
from pydantic import ValidationError

from . import limits as limits_module
from . import registry
from .block import Block
from .errors import ParameterError, Problem, UserError, suggest
from .files import check_regular_file
from .flatten import BlockNode
from .limits import Limits
from .params import params_problems, path_fields
from .ports import port_type_label
from .reading import RunSection
from .wiring import Connection, Declared, Endpoint, Exposure

if TYPE_CHECKING:
    import networkx as nx

Nodes = dict[str, BlockNode]


# -- blocks ------------------------------------------------------------------------------------------
def check_blocks(nodes: Nodes, seed: int) -> list[Problem]:
    """Look up every block's type and build it from its parameters (setting ``node.cls`` and
    ``node.block``); the problems of unknown types and bad parameters."""
    problems: list[Problem] = []
    available = registry.available()
    for name, node in nodes.items():
        node.cls = available.get(node.type)
        if node.cls is None:
            problems.append(Problem(node.file, f"block '{name}'", f"{registry.unknown_block(node.type)}"
                                                                 f"{suggest(node.type, available)} (see `evsda blocks`)"))
            continue
        node.block = build_block(node, node.params, seed, problems)
    return problems


def build_block(node: BlockNode, params: dict[str, Any], seed: int, problems: list[Problem]) -> Block | None:
    """``node``'s block with ``params`` (file parameters resolved), or None with the problems noted."""
    cls, where = node.cls, f"block '{node.name}'"
    params = dict(params)
    unreadable = False
    for key in path_fields(cls.Params):
        if isinstance(params.get(key), str):
            try:
                params[key] = _resolve_path(params[key], Path(node.file).parent)
            except UserError as exc:
                problems.append(Problem(node.file, f"{where} ({node.type}) parameter '{key}'", str(exc)))
                unreadable = True
    if unreadable:
        return None
    try:
        return cls(cls.Params.model_validate(params), name=node.name, seed=seed)
    except ValidationError as exc:
        problems.extend(params_problems(node.file, node.name, node.type, exc))
    except ParameterError as exc:
        problems.append(Problem(node.file, where, str(exc)))
    return None


def _resolve_path(value: str, base: Path) -> str:
    """A file parameter relative to its graph file becomes absolute; ``library:`` stays as is. The file
    must be a regular file (a FIFO or a device would block the block that reads it): checked here,
    by its metadata only, so that ``validate`` reports it."""
    if "\n" in value:
        return value
    path = library.resolve(value, base)
    if path.exists() or path.is_symlink():
        check_regular_file(path, "data file", max_bytes=None)
    return value if value.startswith(library.PREFIX) else str(path)


# -- connections -------------------------------------------------------------------------------------
def check_connections(nodes: Nodes, declared: list[Declared]) -> tuple[list[Connection], list[Problem]]:
    """The declared connections whose ports exist and agree, in order, and the problems of the others
    (a second connection into an input that takes one is refused)."""
    accepted: list[Connection] = []
    problems: list[Problem] = []
    fan_in: Counter[Endpoint] = Counter()
    for conn, file in declared:
        found = _port_problems(nodes, conn, file)
        if found is None:
            continue  # a block of an unknown type, already reported
        if not found:
            fan_in[conn.target] += 1
            found = _fan_in_problems(nodes, conn, file, fan_in[conn.target])
            accepted.extend([] if found else [conn])
        problems.extend(found)
    return accepted, problems


def _port_problems(nodes: Nodes, conn: Connection, file: str) -> list[Problem] | None:
    """The problems of one connection's ports; None if a block's type is unknown (reported already)."""
    src, dst = nodes.get(conn.src), nodes.get(conn.dst)
    if src is None or dst is None:
        return [Problem(file, f"connection {conn}", f"no block named '{conn.src if src is None else conn.dst}'")]
    if src.cls is None or dst.cls is None:
        return None
    messages = [m for m in (_missing_port(conn.src, src, "output", conn.src_port),
                            _missing_port(conn.dst, dst, "input", conn.dst_port)) if m]
    return [Problem(file, f"connection {conn}", m) for m in messages or _type_mismatch(conn, src, dst)]


def _missing_port(name: str, node: BlockNode, kind: str, port: str) -> str | None:
    ports = node.cls.outputs if kind == "output" else node.cls.inputs
    if port in ports:
        return None
    return f"block '{name}' ({node.type}) has no {kind} port '{port}'; its {kind}s are {sorted(ports) or 'none'}"


def _type_mismatch(conn: Connection, src: BlockNode, dst: BlockNode) -> list[str]:
    produced, expected = src.cls.outputs[conn.src_port].type, dst.cls.inputs[conn.dst_port].type
    if produced is expected:
        return []
    return [f"port type mismatch: {conn.source} produces {port_type_label(produced)} but {conn.target} expects "
            f"{port_type_label(expected)}"]


def _fan_in_problems(nodes: Nodes, conn: Connection, file: str, count: int) -> list[Problem]:
    if count > 1 and not nodes[conn.dst].cls.inputs[conn.dst_port].multi:
        return [Problem(file, f"connection {conn}", f"input {conn.target} accepts one connection and already has one")]
    return []


def new_digraph() -> nx.DiGraph:
    """An empty networkx graph. networkx is imported here, where a graph is first checked or made, not with the
    command line: ~0.1 s of CPU that ``evsda --version``, ``blocks``, ``schema`` and ``info`` do without."""
    import networkx

    return networkx.DiGraph()


def dependency_graph(nodes: Nodes, connections: list[Connection]) -> nx.DiGraph:
    """Blocks as nodes, an edge wherever one feeds another (its ``ports``: the (output, input) pairs)."""
    digraph = new_digraph()
    digraph.add_nodes_from(nodes)
    for conn in connections:
        if digraph.has_edge(conn.src, conn.dst):
            digraph[conn.src][conn.dst]["ports"].append((conn.src_port, conn.dst_port))
        else:
            digraph.add_edge(conn.src, conn.dst, ports=[(conn.src_port, conn.dst_port)])
    return digraph


# -- inputs, exposed ports, cycles, outputs ------------------------------------------------------
def check_required_inputs(nodes: Nodes, connections: list[Connection],
                          exposed_inputs: dict[str, Endpoint]) -> list[Problem]:
    """Every required input is connected, or exposed for an including graph to connect."""
    fed = {conn.target for conn in connections} | set(exposed_inputs.values())
    return [Problem(node.file, f"block '{name}' input '{port}'",
                    f"required input ({port_type_label(spec.type)}) is not connected")
            for name, node in nodes.items() if node.cls is not None
            for port, spec in node.cls.inputs.items() if spec.required and (name, port) not in fed]


def check_exposed_ports(nodes: Nodes, exposures: list[Exposure]) -> list[Problem]:
    """Every exposed port is a port of its block."""
    problems = []
    for file, kind, exposed, (name, port) in exposures:
        node = nodes.get(name)
        if node is None or node.cls is None:
            continue
        ports = node.cls.inputs if kind == "input" else node.cls.outputs
        if port not in ports:
            problems.append(Problem(file, f"expose {kind} '{exposed}'", f"block '{name}' ({node.type}) has no "
                                                                       f"{kind} '{port}'; it has {sorted(ports) or 'none'}"))
    return problems


def check_cycles(file: str, digraph: nx.DiGraph) -> list[Problem]:
    """The blocks form a DAG."""
    import networkx

    try:
        cycle = networkx.find_cycle(digraph)
    except networkx.NetworkXNoCycle:
        return []
    chain = " -> ".join([cycle[0][0], *[edge[1] for edge in cycle]])
    return [Problem(file, "connections", f"the graph has a cycle ({chain}); blocks must form a DAG")]


def check_requested_outputs(file: str, nodes: Nodes, requested: list[Endpoint | None]) -> list[Problem]:
    """Every requested output is an output of a block (None: a request already reported)."""
    return [p for item in requested if item is not None for p in _output_problems(file, nodes, item)]


def valid_outputs(file: str, nodes: Nodes, requested: list[Endpoint | None]) -> list[Endpoint]:
    """The requested outputs that :func:`check_requested_outputs` accepts, in order."""
    return [item for item in requested if item is not None and not _output_problems(file, nodes, item)]


def _output_problems(file: str, nodes: Nodes, output: Endpoint) -> list[Problem]:
    node = nodes.get(output.block)
    where = f"output '{output}'"
    if node is None:
        return [Problem(file, where, f"no block named '{output.block}'")]
    if node.cls is not None and output.port not in node.cls.outputs:
        return [Problem(file, where, f"block '{output.block}' has no output '{output.port}'; its outputs are "
                                     f"{sorted(node.cls.outputs) or 'none'}")]
    return []


# -- sizes ---------------------------------------------------------------------------------------------
def check_sizes(file: str, run: RunSection | None, nodes: Nodes, limits: Limits | None) -> list[Problem]:
    """The run's window count, sensor pixels and memory per window are within ``limits``."""
    if run is None:
        return []
    try:
        info = run.run_info()
    except ParameterError:
        return [Problem(file, "run", "duration_s and window_s must each be at least 1 ns")]
    footprints = {name: node.block.footprint(info) for name, node in nodes.items() if node.block is not None}
    return [Problem(file, where, message)
            for where, message in limits_module.check(info.n_windows, footprints, limits or Limits())]
