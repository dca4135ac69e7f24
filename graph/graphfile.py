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

YAML is read with a safe loader (a graph file can never execute code) that also
rejects duplicate keys. :func:`load_graph` reports every problem of a file at once as
a :class:`~evsda.graph.errors.GraphError`, one line per problem naming the file, the
block, the port or parameter, and what was expected.
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import networkx as nx
import yaml
from evsda import library
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from . import limits as limits_module
from . import registry
from .block import NS_PER_S, Block, RunInfo, parse_epoch
from .errors import GraphError, ParameterError, Problem, UserError, clip
from .files import FileProblem, check_regular_file, read_text
from .limits import Limits
from .params import describe_validation_error, params_problems, path_fields
from .ports import port_type_label

NAME = r"[A-Za-z_][A-Za-z0-9_]*"
NAME_RE = re.compile(rf"^{NAME}$")
ENDPOINT_RE = re.compile(rf"^({NAME}(?:/{NAME})*)\.({NAME})$")
SEPARATOR = "/"


# -- the file format (pydantic models double as the JSON Schema) ----------------------------------
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)


class RunSection(_Strict):
    """Time range and seed of a run."""

    start: str = Field(description="Run start epoch, ISO 8601 UTC, e.g. 2024-03-01T02:15:00Z [-]")
    duration_s: float = Field(gt=0, description="Simulated duration [s]")
    window_s: float = Field(0.1, gt=0, description="Length of one executor window; state is checkpointed after each [s]")
    seed: int = Field(0, ge=0, description="Seed of every block's random generator [-]")
    store_products: bool | list[str] = Field(
        True, description="Store every block's outputs (true), none (false), or those of the listed blocks, "
                          "so later runs can reuse them [-]")
    store_truth: bool = Field(
        True, description="Store the true state of every source at the optics' render times (the truth group) [-]")

    @field_validator("start", mode="before")
    @classmethod
    def _start_is_instant(cls, value):
        value = value.isoformat() if hasattr(value, "isoformat") else value
        try:
            parse_epoch(value)
        except ParameterError as exc:
            raise ValueError(str(exc)) from None
        return value


class BlockEntry(_Strict):
    type: str = Field(description="Registered block type (see `evsda blocks`) [-]")
    params: dict[str, Any] = Field(default_factory=dict, description="Block parameters [-]")


class ConnectionEntry(_Strict):
    from_: str = Field(alias="from", description="Source port, block.port [-]")
    to: str = Field(description="Destination port, block.port [-]")


class IncludeEntry(_Strict):
    file: str = Field(description="Sub-graph file: a path relative to this file, or library:... [-]")
    as_: str = Field(alias="as", pattern=rf"^{NAME}$", description="Name prefix of the included blocks [-]")
    set: dict[str, Any] = Field(default_factory=dict, description="Parameter overrides, block.param: value [-]")
    swap: dict[str, str] = Field(default_factory=dict,
                                 description="Replace the type of included blocks, block: type; the block starts "
                                             "from the new type's defaults, then set applies [-]")


class ExposeSection(_Strict):
    inputs: dict[str, str] = Field(default_factory=dict, description="Exposed input name -> block.port [-]")
    outputs: dict[str, str] = Field(default_factory=dict, description="Exposed output name -> block.port [-]")


class GraphFile(_Strict):
    """An evsda graph file."""

    evsda: Literal[1] = Field(1, description="Graph file format version [-]")
    name: str | None = Field(None, description="Name of the graph [-]")
    description: str | None = Field(None, description="What the graph simulates [-]")
    run: RunSection | None = Field(None, description="Time range and seed; default: the first include's [-]")
    include: list[IncludeEntry] = Field(default_factory=list)
    blocks: dict[str, BlockEntry] = Field(default_factory=dict)
    connections: list[ConnectionEntry] = Field(default_factory=list)
    expose: ExposeSection | None = None
    outputs: list[str] | None = Field(None, description="Requested outputs, block.port; default: every sink block [-]")
    set: dict[str, Any] = Field(default_factory=dict, description="Parameter overrides, block.param: value [-]")


#: the top-level keys of a graph file (a YAML mapping with none of them is not a graph file)
GRAPH_KEYS = {"evsda", "name", "description", "run", "include", "blocks", "connections", "expose", "outputs", "set"}


# -- safe YAML with duplicate-key detection ------------------------------------------------------
class _DuplicateKey(yaml.YAMLError):
    pass


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate mapping keys instead of silently keeping the last."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise _DuplicateKey(f"line {key_node.start_mark.line + 1}: duplicate key '{key}'")
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


# YAML 1.1 (PyYAML) reads a float only with a dot and a signed exponent: ``1e-5``, ``1E5`` and ``1.0e6``
# would be strings. Every number a user writes in scientific notation is read as a float (as YAML 1.2
# does), in graph files, grid files, --set, --vary and list elements alike.
_EXPONENT_FLOAT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")
_UniqueKeyLoader.yaml_implicit_resolvers = {key: list(resolvers) for key, resolvers
                                            in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_UniqueKeyLoader.add_implicit_resolver("tag:yaml.org,2002:float", _EXPONENT_FLOAT, list("-+0123456789."))


#: a YAML document (graph file, sweep grid) is at most this large [bytes]
MAX_YAML_BYTES = 1 << 20
#: at most this many aliases (``*name``) in one document
MAX_YAML_ALIASES = 1000
#: at most this many values once aliases are expanded (a "billion laughs" document is refused)
MAX_YAML_VALUES = 100_000


class _BoundedLoader(_UniqueKeyLoader):
    """Counts aliases while composing, so an alias bomb stops before it is built."""

    def __init__(self, stream, what: str):
        super().__init__(stream)
        self.aliases, self.what = 0, what

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self.aliases += 1
            if self.aliases > MAX_YAML_ALIASES:
                mark = self.peek_event().start_mark
                raise _Limit(f"line {mark.line + 1}: more than {MAX_YAML_ALIASES} aliases; a {self.what} may "
                             f"not have that many")
        return super().compose_node(parent, index)


class _Limit(yaml.YAMLError):
    pass


def _expanded_size(root: yaml.Node) -> int:
    """How many values ``root`` holds once its aliases are expanded (each shared node counted every time
    it is used), computed without expanding; refuses a node that contains itself."""
    sizes: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    open_nodes: set[int] = set()
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if key in sizes:
            continue
        if isinstance(node, yaml.ScalarNode):
            sizes[key] = 1
            continue
        children = [c for pair in node.value for c in pair] if isinstance(node, yaml.MappingNode) else node.value
        if children_done:
            open_nodes.discard(key)
            sizes[key] = min(1 + sum(sizes[id(c)] for c in children), MAX_YAML_VALUES + 1)
            continue
        if key in open_nodes:
            raise _Limit(f"line {node.start_mark.line + 1}: an alias refers to the value that contains it")
        open_nodes.add(key)
        stack.append((node, True))
        for child in children:
            if id(child) in open_nodes:
                raise _Limit(f"line {child.start_mark.line + 1}: an alias refers to the value that contains it")
            if id(child) not in sizes:
                stack.append((child, False))
    return sizes[id(root)]


def read_yaml(path: Path, what: str = "graph file") -> Any:
    """Parse a YAML file safely; a missing, special, oversized, non-UTF-8 or invalid file, a duplicate
    key, or an alias bomb is a GraphError naming the file and the line, never quoting the file."""
    try:
        text = read_text(path, what, MAX_YAML_BYTES)
    except FileProblem as exc:
        raise GraphError([Problem(str(path), "", exc.reason)]) from None
    loader = _BoundedLoader(text, what)
    try:
        node = loader.get_single_node()
        if node is not None and _expanded_size(node) > MAX_YAML_VALUES:
            raise _Limit(f"its aliases expand to more than {MAX_YAML_VALUES} values; a {what} may not be that large")
        return None if node is None else loader.construct_document(node)
    except _DuplicateKey as exc:
        raise GraphError([Problem(str(path), "", f"{exc}; names must be unique")]) from None
    except _Limit as exc:
        raise GraphError([Problem(str(path), "", str(exc))]) from None
    except RecursionError:
        raise GraphError([Problem(str(path), "", "values are nested too deeply")]) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise GraphError([Problem(str(path), where, f"not valid YAML: {clip(problem)}")]) from None
    finally:
        loader.dispose()


def parse_value(text: str) -> Any:
    """A ``--set`` value: YAML scalar or flow collection, read as graph files are (``1e-3`` is a float)."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError:
        return text


# -- the resolved graph ----------------------------------------------------------------------------
@dataclass
class BlockNode:
    name: str
    type: str
    params: dict[str, Any]
    file: str
    block: Block | None = None
    cls: type[Block] | None = None


@dataclass
class Graph:
    """A checked graph: block instances, connections and run settings."""

    file: str
    name: str
    run: RunSection | None
    nodes: dict[str, BlockNode]
    connections: list[tuple[str, str, str, str]]          # (src block, src port, dst block, dst port)
    outputs: list[tuple[str, str]]                         # requested (block, port)
    exposed_inputs: dict[str, tuple[str, str]] = field(default_factory=dict)
    exposed_outputs: dict[str, tuple[str, str]] = field(default_factory=dict)
    digraph: nx.DiGraph = field(default_factory=nx.DiGraph)

    @property
    def blocks(self) -> dict[str, Block]:
        return {name: node.block for name, node in self.nodes.items()}

    def run_info(self) -> RunInfo:
        if self.run is None:
            raise UserError(f"{self.file}: the graph has no 'run' section (start, duration_s, window_s, seed); "
                            f"a sub-graph cannot be run on its own")
        return RunInfo(
            epoch=parse_epoch(self.run.start),
            duration_ns=round(self.run.duration_s * NS_PER_S),
            window_ns=round(self.run.window_s * NS_PER_S),
            seed=self.run.seed,
        )

    def to_dict(self) -> dict[str, Any]:
        """The fully resolved graph (no includes, every parameter explicit), as stored with a run."""
        return {
            "evsda": 1,
            "name": self.name,
            "run": self.run.model_dump() if self.run else None,
            "blocks": {n: {"type": b.type, "params": b.block.params.model_dump(mode="json")}
                       for n, b in self.nodes.items()},
            "connections": [{"from": f"{a}.{p}", "to": f"{b}.{q}"} for a, p, b, q in self.connections],
            "outputs": [f"{b}.{p}" for b, p in self.outputs],
        }

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()


# -- loading -------------------------------------------------------------------------------------------
@dataclass
class _Flat:
    """A graph file with its includes flattened, before block types are checked."""

    blocks: dict[str, BlockNode] = field(default_factory=dict)
    connections: list[tuple[str, str, str, str, str]] = field(default_factory=list)  # + file
    exposed_inputs: dict[str, tuple[str, str]] = field(default_factory=dict)
    exposed_outputs: dict[str, tuple[str, str]] = field(default_factory=dict)
    requested: list[tuple[str, str] | None] = field(default_factory=list)
    run: RunSection | None = None          # this file's run section, else its first include's
    exposures: list[tuple[str, str, str, str, str]] = field(default_factory=list)  # file, kind, name, block, port


def _split_endpoint(text: str) -> tuple[str, str] | None:
    match = ENDPOINT_RE.match(str(text))
    return (match.group(1), match.group(2)) if match else None


def _set_param(params: dict[str, Any], dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    target = params
    for key in keys[:-1]:
        target = target.setdefault(key, {})
        if not isinstance(target, dict):
            raise KeyError(key)
    target[keys[-1]] = value


def _apply_overrides(flat: _Flat, overrides: dict[str, Any], file: str, origin: str, problems: list[Problem]) -> None:
    for key, value in overrides.items():
        block, sep, param = str(key).partition(".")
        if not sep or not param:
            problems.append(Problem(file, f"{origin} '{key}'", "expected block.param=value"))
            continue
        node = flat.blocks.get(block)
        if node is None:
            problems.append(Problem(file, f"{origin} '{key}'", f"no block named '{block}'{_suggest(block, flat.blocks)}"))
            continue
        try:
            _set_param(node.params, param, value)
        except KeyError:
            problems.append(Problem(file, f"{origin} '{key}'", f"parameter '{param}' is not a mapping"))


def _suggest(name: str, choices) -> str:
    close = difflib.get_close_matches(name, list(choices), n=3)
    return f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""


def _load_flat(path: Path, prefix: str, problems: list[Problem], stack: tuple[Path, ...]) -> tuple[_Flat, GraphFile | None]:
    file = str(path)
    if path.resolve() in stack:
        chain = " -> ".join(str(p) for p in (*stack, path))
        problems.append(Problem(file, "include", f"includes itself ({chain})"))
        return _Flat(), None
    try:
        data = read_yaml(path)
    except GraphError as exc:
        problems.extend(exc.problems)
        return _Flat(), None
    if not isinstance(data, dict) or not (set(map(str, data)) & GRAPH_KEYS):
        # say nothing of what the file holds: it may be any file its user can read
        problems.append(Problem(file, "", f"not an evsda graph file: expected a mapping with some of the keys "
                                          f"{', '.join(sorted(GRAPH_KEYS))}"))
        return _Flat(), None
    try:
        spec = GraphFile.model_validate(data)
    except ValidationError as exc:
        for loc, message in describe_validation_error(exc):
            problems.append(Problem(file, f"'{loc}'", message))
        return _Flat(), None

    def qualified(name: str) -> str:
        return f"{prefix}{SEPARATOR}{name}" if prefix else name

    flat = _Flat(run=spec.run)
    for name, entry in spec.blocks.items():
        if not NAME_RE.match(name):
            problems.append(Problem(file, f"block '{name}'", "block names are letters, digits and _, not starting with a digit"))
            continue
        params = dict(entry.params)
        flat.blocks[qualified(name)] = BlockNode(qualified(name), entry.type, params, file)

    aliases: dict[str, _Flat] = {}
    for include in spec.include:
        if include.as_ in spec.blocks or include.as_ in aliases:
            problems.append(Problem(file, f"include '{include.as_}'", "name already used by a block or another include"))
            continue
        try:
            sub_path = library.resolve(include.file, path.parent)
        except UserError as exc:
            problems.append(Problem(file, f"include '{include.as_}'", str(exc)))
            continue
        if not sub_path.exists():
            problems.append(Problem(file, f"include '{include.as_}'", f"file {clip(include.file)} not found"))
            continue
        sub, _ = _load_flat(sub_path, qualified(include.as_), problems, (*stack, path.resolve()))
        flat.run = flat.run or sub.run
        flat.exposures.extend(sub.exposures)
        for block, block_type in include.swap.items():
            node = sub.blocks.get(f"{qualified(include.as_)}{SEPARATOR}{block}")
            if node is None:
                problems.append(Problem(file, f"include '{include.as_}' swap '{block}'",
                                        f"no block named '{block}' in {include.file}"
                                        f"{_suggest(block, [n.rpartition(SEPARATOR)[2] for n in sub.blocks])}"))
                continue
            node.type, node.params, node.file = block_type, {}, file
        _apply_overrides(sub, {f"{qualified(include.as_)}{SEPARATOR}{k}": v for k, v in include.set.items()},
                         file, f"include '{include.as_}' set", problems)
        aliases[include.as_] = sub
        flat.blocks.update(sub.blocks)
        flat.connections.extend(sub.connections)

    def endpoint(text: str, direction: str, where: str) -> tuple[str, str] | None:
        parts = _split_endpoint(text)
        if parts is None:
            problems.append(Problem(file, where, f"'{text}' is not block.port"))
            return None
        owner, port = parts
        if owner in aliases:  # an include's exposed port
            exposed = aliases[owner].exposed_inputs if direction == "to" else aliases[owner].exposed_outputs
            if port not in exposed:
                kind = "input" if direction == "to" else "output"
                problems.append(Problem(file, where, f"include '{owner}' exposes no {kind} '{port}'; "
                                                     f"it exposes {sorted(exposed) or 'none'}"))
                return None
            return exposed[port]
        if owner not in spec.blocks:
            problems.append(Problem(file, where, f"no block named '{owner}'{_suggest(owner, [*spec.blocks, *aliases])}"))
            return None
        return qualified(owner), port

    for i, conn in enumerate(spec.connections):
        where = f"connection {i + 1} ({conn.from_} -> {conn.to})"
        src = endpoint(conn.from_, "from", where)
        dst = endpoint(conn.to, "to", where)
        if src and dst:
            flat.connections.append((*src, *dst, file))

    if spec.expose:
        for name, target in spec.expose.inputs.items():
            resolved = endpoint(target, "to", f"expose input '{name}'")
            if resolved:
                flat.exposed_inputs[name] = resolved
                flat.exposures.append((file, "input", name, *resolved))
        for name, target in spec.expose.outputs.items():
            resolved = endpoint(target, "from", f"expose output '{name}'")
            if resolved:
                flat.exposed_outputs[name] = resolved
                flat.exposures.append((file, "output", name, *resolved))
    _apply_overrides(flat, {qualified(k): v for k, v in spec.set.items()}, file, "set", problems)
    flat.requested = [endpoint(o, "from", f"output '{o}'") for o in (spec.outputs or [])]
    return flat, spec


def load_graph(path: str | Path, overrides: list[str] | dict[str, Any] | None = None,
               limits: Limits | None = None) -> Graph:
    """Load, flatten and check a graph file; raise GraphError listing every problem.

    ``limits`` (default :class:`Limits`) bounds the window count, sensor pixels and memory per window.
    """
    path = library.resolve(str(path))
    problems: list[Problem] = []
    flat, spec = _load_flat(path, "", problems, ())
    file = str(path)
    if spec is not None and spec.run is None and flat.run is not None:
        spec = spec.model_copy(update={"run": flat.run})
    if isinstance(overrides, dict):
        override_items = dict(overrides)
    else:
        override_items = {}
        for text in overrides or []:
            key, sep, value = text.partition("=")
            if not sep:
                problems.append(Problem(file, f"--set '{text}'", "expected block.param=value"))
                continue
            override_items[key.strip()] = parse_value(value.strip())
    if spec is not None and spec.run is not None and "run" not in flat.blocks:
        spec = _override_run(spec, {k: override_items.pop(k) for k in list(override_items) if k.startswith("run.")},
                             file, problems)
    _apply_overrides(flat, override_items, file, "--set", problems)
    if spec is None:
        raise GraphError(problems)
    graph = _check(file, spec, flat, path.parent, problems, limits)
    if problems:
        raise GraphError(problems)
    return graph


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
    flat = _Flat()
    for name, entry in spec.blocks.items():
        flat.blocks[name] = BlockNode(name, entry.type, dict(entry.params), file)
    for conn in spec.connections:
        src, dst = _split_endpoint(conn.from_), _split_endpoint(conn.to)
        if src is None or dst is None:
            problems.append(Problem(file, f"connection {conn.from_} -> {conn.to}", "expected block.port"))
            continue
        flat.connections.append((*src, *dst, file))
    flat.requested = [_split_endpoint(o) for o in (spec.outputs or [])]
    graph = _check(file, spec, flat, Path.cwd(), problems, limits)
    if problems:
        raise GraphError(problems)
    return graph


def _check(file: str, spec: GraphFile, flat: _Flat, base: Path, problems: list[Problem],
           limits: Limits | None = None) -> Graph:
    seed = spec.run.seed if spec.run else 0
    available = registry.available()
    for name, node in flat.blocks.items():
        cls = available.get(node.type)
        if cls is None:
            problems.append(Problem(node.file, f"block '{name}'", f"{registry.unknown_block(node.type)}"
                                                                 f"{_suggest(node.type, available)} (see `evsda blocks`)"))
            continue
        node.cls = cls
        node.block = _build_block(node, node.params, seed, problems)

    digraph = nx.DiGraph()
    digraph.add_nodes_from(flat.blocks)
    connections = []
    fan_in: dict[tuple[str, str], int] = {}
    for src, sport, dst, dport, cfile in flat.connections:
        where = f"connection {src}.{sport} -> {dst}.{dport}"
        src_node, dst_node = flat.blocks.get(src), flat.blocks.get(dst)
        if src_node is None or dst_node is None:
            problems.append(Problem(cfile, where, f"no block named '{src if src_node is None else dst}'"))
            continue
        if src_node.cls is None or dst_node.cls is None:
            continue  # unknown type, already reported
        out_spec = src_node.cls.outputs.get(sport)
        in_spec = dst_node.cls.inputs.get(dport)
        if out_spec is None:
            problems.append(Problem(cfile, where, f"block '{src}' ({src_node.type}) has no output port '{sport}'; "
                                                  f"its outputs are {sorted(src_node.cls.outputs) or 'none'}"))
        if in_spec is None:
            problems.append(Problem(cfile, where, f"block '{dst}' ({dst_node.type}) has no input port '{dport}'; "
                                                  f"its inputs are {sorted(dst_node.cls.inputs) or 'none'}"))
        if out_spec is None or in_spec is None:
            continue
        if out_spec.type is not in_spec.type:
            problems.append(Problem(cfile, where, f"port type mismatch: {src}.{sport} produces "
                                                  f"{port_type_label(out_spec.type)} but {dst}.{dport} expects "
                                                  f"{port_type_label(in_spec.type)}"))
            continue
        fan_in[(dst, dport)] = fan_in.get((dst, dport), 0) + 1
        if fan_in[(dst, dport)] > 1 and not in_spec.multi:
            problems.append(Problem(cfile, where, f"input {dst}.{dport} accepts one connection and already has one"))
            continue
        connections.append((src, sport, dst, dport))
        if digraph.has_edge(src, dst):
            digraph[src][dst]["ports"].append((sport, dport))
        else:
            digraph.add_edge(src, dst, ports=[(sport, dport)])

    for name, node in flat.blocks.items():
        if node.cls is None:
            continue
        for port, in_spec in node.cls.inputs.items():
            if in_spec.required and (name, port) not in fan_in and (name, port) not in flat.exposed_inputs.values():
                problems.append(Problem(node.file, f"block '{name}' input '{port}'",
                                        f"required input ({port_type_label(in_spec.type)}) is not connected"))

    for exposing_file, kind, exposed, name, port in flat.exposures:
        node = flat.blocks.get(name)
        ports = None if node is None or node.cls is None else (node.cls.inputs if kind == "input" else node.cls.outputs)
        if ports is not None and port not in ports:
            problems.append(Problem(exposing_file, f"expose {kind} '{exposed}'",
                                    f"block '{name}' ({node.type}) has no {kind} '{port}'; it has {sorted(ports) or 'none'}"))

    try:
        cycle = nx.find_cycle(digraph)
        chain = " -> ".join([cycle[0][0], *[edge[1] for edge in cycle]])
        problems.append(Problem(file, "connections", f"the graph has a cycle ({chain}); blocks must form a DAG"))
    except nx.NetworkXNoCycle:
        pass

    requested = []
    for item in flat.requested:
        if item is None:
            continue
        block, port = item
        node = flat.blocks.get(block)
        if node is None:
            problems.append(Problem(file, f"output '{block}.{port}'", f"no block named '{block}'"))
        elif node.cls is not None and port not in node.cls.outputs:
            problems.append(Problem(file, f"output '{block}.{port}'",
                                    f"block '{block}' has no output '{port}'; its outputs are "
                                    f"{sorted(node.cls.outputs) or 'none'}"))
        else:
            requested.append((block, port))

    run = None
    if spec.run is not None:
        try:
            run = RunInfo(epoch=parse_epoch(spec.run.start), duration_ns=round(spec.run.duration_s * NS_PER_S),
                          window_ns=round(spec.run.window_s * NS_PER_S), seed=spec.run.seed)
        except ParameterError:
            problems.append(Problem(file, "run", "duration_s and window_s must each be at least 1 ns"))
    if run is not None:
        footprints = {name: node.block.footprint(run) for name, node in flat.blocks.items() if node.block is not None}
        problems.extend(Problem(file, where, message)
                        for where, message in limits_module.check(run.n_windows, footprints, limits or Limits()))

    return Graph(file=file, name=spec.name or Path(file).stem, run=spec.run, nodes=flat.blocks,
                 connections=connections, outputs=requested, exposed_inputs=flat.exposed_inputs,
                 exposed_outputs=flat.exposed_outputs, digraph=digraph)


def _build_block(node: BlockNode, params: dict[str, Any], seed: int, problems: list[Problem]) -> Block | None:
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


def check_override(graph: Graph, key: str, value: Any) -> list[Problem]:
    """The problems of setting ``key`` (``block.param`` or ``run.field``) to ``value`` in ``graph``, checked on
    that block's parameters (or the run section) alone: a sweep checks each distinct value once this way
    instead of loading every point's whole graph. Checks that need the whole graph (sizes) run with the point."""
    problems: list[Problem] = []
    if key.startswith("run."):
        if graph.run is None:
            return [Problem(graph.file, f"'{key}'", "the graph has no run section")]
        data = graph.run.model_dump()
        data[key.removeprefix("run.")] = value
        try:
            RunSection.model_validate(data)
        except ValidationError as exc:
            problems.extend(Problem(graph.file, f"'run.{loc}'", message) for loc, message in describe_validation_error(exc))
        return problems
    block, sep, param = key.partition(".")
    node = graph.nodes.get(block)
    if not sep or not param:
        return [Problem(graph.file, f"'{key}'", "expected block.param")]
    if node is None:
        return [Problem(graph.file, f"'{key}'", f"no block named '{block}'{_suggest(block, graph.nodes)}")]
    params = copy.deepcopy(node.params)
    try:
        _set_param(params, param, value)
    except KeyError:
        return [Problem(graph.file, f"'{key}'", f"parameter '{param}' is not a mapping")]
    _build_block(node, params, graph.run.seed if graph.run else 0, problems)
    return problems


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
