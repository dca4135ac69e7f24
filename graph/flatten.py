"""Flattening graph files: includes, swaps, ``set`` overrides and exposed ports resolved into one list of
blocks and connections, before any block type is looked up (:mod:`evsda.graph.checks` does that).

An included file's blocks are renamed ``<as>/<block>``; a connection to an include names one of the ports
its file exposes. Every problem found is noted and flattening goes on, so a file's problems are reported
together.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsda import library

from .block import Block
from .errors import Problem, UserError, clip, suggest
from .reading import ENDPOINT_RE, NAME_RE, SEPARATOR, GraphFile, IncludeEntry, RunSection, read_graph_file
from .wiring import Connection, Declared, Endpoint, Exposure


@dataclass
class BlockNode:
    """One block of a graph: its name, type, parameters as written and the file that declares it;
    ``cls`` and ``block`` are set once its type is found and its parameters check."""

    name: str
    type: str
    params: dict[str, Any]
    file: str
    block: Block | None = None
    cls: type[Block] | None = None


@dataclass
class FlatGraph:
    """A graph file with its includes flattened, before block types are checked."""

    blocks: dict[str, BlockNode] = field(default_factory=dict)
    connections: list[Declared] = field(default_factory=list)
    exposed_inputs: dict[str, Endpoint] = field(default_factory=dict)
    exposed_outputs: dict[str, Endpoint] = field(default_factory=dict)
    requested: list[Endpoint | None] = field(default_factory=list)   # None: already reported
    run: RunSection | None = None          # this file's run section, else its first include's
    exposures: list[Exposure] = field(default_factory=list)


def split_endpoint(text: str) -> Endpoint | None:
    """``block.port`` (block names may hold ``/``) as an Endpoint; None if it is not one."""
    match = ENDPOINT_RE.match(str(text))
    return Endpoint(match.group(1), match.group(2)) if match else None


def set_param(params: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``params[a][b] = value`` for ``dotted`` = ``a.b``; KeyError names a part that is not a mapping."""
    keys = dotted.split(".")
    target = params
    for key in keys[:-1]:
        target = target.setdefault(key, {})
        if not isinstance(target, dict):
            raise KeyError(key)
    target[keys[-1]] = value


def apply_overrides(blocks: dict[str, BlockNode], overrides: dict[str, Any], file: str, origin: str,
                    problems: list[Problem]) -> None:
    """Set ``block.param: value`` overrides on ``blocks``; ``origin`` says where they come from in messages."""
    for key, value in overrides.items():
        block, sep, param = str(key).partition(".")
        where = f"{origin} '{key}'"
        if not sep or not param:
            problems.append(Problem(file, where, "expected block.param=value"))
        elif block not in blocks:
            problems.append(Problem(file, where, f"no block named '{block}'{suggest(block, blocks)}"))
        else:
            try:
                set_param(blocks[block].params, param, value)
            except KeyError:
                problems.append(Problem(file, where, f"parameter '{param}' is not a mapping"))


@dataclass(frozen=True)
class _Scope:
    """The file being flattened and the prefix its block names get (empty for the top file)."""

    path: Path
    prefix: str

    @property
    def file(self) -> str:
        return str(self.path)

    def qualified(self, name: str) -> str:
        return f"{self.prefix}{SEPARATOR}{name}" if self.prefix else name


def flatten(path: Path, problems: list[Problem], prefix: str = "",
            stack: tuple[Path, ...] = ()) -> tuple[FlatGraph, GraphFile | None]:
    """The graph file at ``path`` flattened (its blocks named ``<prefix>/<block>``) and its validated
    contents; an empty graph and None where the file cannot be read. ``stack``: the including files."""
    if path.resolve() in stack:
        chain = " -> ".join(str(p) for p in (*stack, path))
        problems.append(Problem(str(path), "include", f"includes itself ({chain})"))
        return FlatGraph(), None
    spec = read_graph_file(path, problems)
    if spec is None:
        return FlatGraph(), None
    scope = _Scope(path, prefix)
    flat = FlatGraph(run=spec.run)
    _add_blocks(flat, spec, scope, problems)
    aliases = _add_includes(flat, spec, scope, problems, stack)
    ports = _Ports(scope, spec, aliases, problems)
    for i, conn in enumerate(spec.connections):
        where = f"connection {i + 1} ({conn.from_} -> {conn.to})"
        src, dst = ports.resolve(conn.from_, "from", where), ports.resolve(conn.to, "to", where)
        if src and dst:
            flat.connections.append(Declared(Connection.between(src, dst), scope.file))
    _add_exposures(flat, spec, ports)
    apply_overrides(flat.blocks, {scope.qualified(k): v for k, v in spec.set.items()}, scope.file, "set", problems)
    flat.requested = [ports.resolve(o, "from", f"output '{o}'") for o in (spec.outputs or [])]
    return flat, spec


def _add_blocks(flat: FlatGraph, spec: GraphFile, scope: _Scope, problems: list[Problem]) -> None:
    for name, entry in spec.blocks.items():
        if not NAME_RE.match(name):
            problems.append(Problem(scope.file, f"block '{name}'",
                                    "block names are letters, digits and _, not starting with a digit"))
            continue
        flat.blocks[scope.qualified(name)] = BlockNode(scope.qualified(name), entry.type, dict(entry.params),
                                                       scope.file)


def _add_includes(flat: FlatGraph, spec: GraphFile, scope: _Scope, problems: list[Problem],
                  stack: tuple[Path, ...]) -> dict[str, FlatGraph]:
    """Flatten each include into ``flat`` (swap first, then set); returns the includes by name."""
    aliases: dict[str, FlatGraph] = {}
    for include in spec.include:
        sub = _read_include(include, spec, aliases, scope, problems, stack)
        if sub is None:
            continue
        flat.run = flat.run or sub.run
        flat.exposures.extend(sub.exposures)
        _swap(sub, include, scope, problems)
        apply_overrides(sub.blocks, {f"{scope.qualified(include.as_)}{SEPARATOR}{k}": v for k, v in include.set.items()},
                        scope.file, f"include '{include.as_}' set", problems)
        aliases[include.as_] = sub
        flat.blocks.update(sub.blocks)
        flat.connections.extend(sub.connections)
    return aliases


def _read_include(include: IncludeEntry, spec: GraphFile, aliases: dict[str, FlatGraph], scope: _Scope,
                  problems: list[Problem], stack: tuple[Path, ...]) -> FlatGraph | None:
    """The included file flattened (empty if it cannot be read), or None where the include itself is wrong."""
    where = f"include '{include.as_}'"
    if include.as_ in spec.blocks or include.as_ in aliases:
        problems.append(Problem(scope.file, where, "name already used by a block or another include"))
        return None
    try:
        sub_path = library.resolve(include.file, scope.path.parent)
    except UserError as exc:
        problems.append(Problem(scope.file, where, str(exc)))
        return None
    if not sub_path.exists():
        problems.append(Problem(scope.file, where, f"file {clip(include.file)} not found"))
        return None
    return flatten(sub_path, problems, scope.qualified(include.as_), (*stack, scope.path.resolve()))[0]


def _swap(sub: FlatGraph, include: IncludeEntry, scope: _Scope, problems: list[Problem]) -> None:
    """``swap: {block: type}``: the included block gets the new type and starts from its defaults."""
    for block, block_type in include.swap.items():
        node = sub.blocks.get(f"{scope.qualified(include.as_)}{SEPARATOR}{block}")
        if node is None:
            names = [n.rpartition(SEPARATOR)[2] for n in sub.blocks]
            problems.append(Problem(scope.file, f"include '{include.as_}' swap '{block}'",
                                    f"no block named '{block}' in {include.file}{suggest(block, names)}"))
            continue
        node.type, node.params, node.file = block_type, {}, scope.file


def _add_exposures(flat: FlatGraph, spec: GraphFile, ports: "_Ports") -> None:
    if not spec.expose:
        return
    for kind, direction, targets, exposed in (("input", "to", spec.expose.inputs, flat.exposed_inputs),
                                              ("output", "from", spec.expose.outputs, flat.exposed_outputs)):
        for name, target in targets.items():
            resolved = ports.resolve(target, direction, f"expose {kind} '{name}'")
            if resolved:
                exposed[name] = resolved
                flat.exposures.append(Exposure(ports.scope.file, kind, name, resolved))


class _Ports:
    """Resolves the ``block.port`` texts of one file: its own blocks, or the ports its includes expose."""

    def __init__(self, scope: _Scope, spec: GraphFile, aliases: dict[str, FlatGraph], problems: list[Problem]):
        self.scope, self.blocks, self.aliases, self.problems = scope, spec.blocks, aliases, problems

    def resolve(self, text: str, direction: str, where: str) -> Endpoint | None:
        """The endpoint ``text`` names (``direction``: "from" an output, "to" an input); None if it names none."""
        parts = split_endpoint(text)
        if parts is None:
            return self._refuse(where, f"'{text}' is not block.port")
        owner, port = parts
        if owner in self.aliases:
            return self._exposed(owner, port, direction, where)
        if owner not in self.blocks:
            return self._refuse(where, f"no block named '{owner}'{suggest(owner, [*self.blocks, *self.aliases])}")
        return Endpoint(self.scope.qualified(owner), port)

    def _exposed(self, include: str, port: str, direction: str, where: str) -> Endpoint | None:
        sub = self.aliases[include]
        exposed = sub.exposed_inputs if direction == "to" else sub.exposed_outputs
        if port not in exposed:
            kind = "input" if direction == "to" else "output"
            return self._refuse(where, f"include '{include}' exposes no {kind} '{port}'; "
                                       f"it exposes {sorted(exposed) or 'none'}")
        return exposed[port]

    def _refuse(self, where: str, message: str) -> None:
        self.problems.append(Problem(self.scope.file, where, message))
        return None


def flatten_resolved(spec: GraphFile, file: str, problems: list[Problem]) -> FlatGraph:
    """A resolved graph (no includes, as stored with a run) as a FlatGraph."""
    flat = FlatGraph()
    for name, entry in spec.blocks.items():
        flat.blocks[name] = BlockNode(name, entry.type, dict(entry.params), file)
    for conn in spec.connections:
        src, dst = split_endpoint(conn.from_), split_endpoint(conn.to)
        if src is None or dst is None:
            problems.append(Problem(file, f"connection {conn.from_} -> {conn.to}", "expected block.port"))
            continue
        flat.connections.append(Declared(Connection.between(src, dst), file))
    flat.requested = [split_endpoint(o) for o in (spec.outputs or [])]
    return flat
