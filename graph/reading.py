"""Reading graph files: safe YAML, and the file format as pydantic models (which double as the JSON Schema).

YAML is read with a safe loader (a graph file can never execute code) that rejects duplicate keys,
bounds the document's size and its aliases (an alias bomb stops before it is built), and reads every
number in scientific notation as a float (as YAML 1.2 does). :func:`read_graph_file` turns one file
into a validated :class:`GraphFile`, or notes its problems.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from .block import NS_PER_S, RunInfo, parse_epoch
from .errors import GraphError, ParameterError, Problem, clip
from .files import FileProblem, read_text
from .params import describe_validation_error

NAME = r"[A-Za-z_][A-Za-z0-9_]*"
NAME_RE = re.compile(rf"^{NAME}$")
ENDPOINT_RE = re.compile(rf"^({NAME}(?:/{NAME})*)\.({NAME})$")
#: joins an include's name and the names of its blocks (``sensor/pixel``)
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

    def run_info(self) -> RunInfo:
        """The run these settings describe; ParameterError if the duration or the window is below 1 ns."""
        return RunInfo(epoch=parse_epoch(self.start), duration_ns=round(self.duration_s * NS_PER_S),
                       window_ns=round(self.window_s * NS_PER_S), seed=self.seed)


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


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [child for pair in node.value for child in pair]
    return node.value if isinstance(node, yaml.SequenceNode) else []


def _refuse_cycle(node: yaml.Node, open_nodes: set[int]) -> None:
    if id(node) in open_nodes:
        raise _Limit(f"line {node.start_mark.line + 1}: an alias refers to the value that contains it")


def _expanded_size(root: yaml.Node) -> int:
    """How many values ``root`` holds once its aliases are expanded (each shared node counted every time
    it is used), computed without expanding; refuses a node that contains itself."""
    sizes: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    open_nodes: set[int] = set()
    while stack:
        node, children_done = stack.pop()
        if id(node) in sizes:
            continue
        children = _children(node)
        if children_done:
            open_nodes.discard(id(node))
            sizes[id(node)] = min(1 + sum(sizes[id(c)] for c in children), MAX_YAML_VALUES + 1)
            continue
        _refuse_cycle(node, open_nodes)
        open_nodes.add(id(node))
        stack.append((node, True))
        for child in children:
            _refuse_cycle(child, open_nodes)
            stack.extend([(child, False)] if id(child) not in sizes else [])
    return sizes[id(root)]


if yaml.__with_libyaml__:
    class _QuickLoader(yaml.cyaml.CParser, _UniqueKeyLoader):
        """``_UniqueKeyLoader``'s constructor and resolvers (the same values, duplicate keys refused) over
        libyaml's parser, ~10x quicker than PyYAML's own reader, scanner and parser (``_quick_document``)."""

        def __init__(self, stream):
            yaml.cyaml.CParser.__init__(self, stream)
            yaml.constructor.SafeConstructor.__init__(self)
            yaml.resolver.Resolver.__init__(self)
else:                # PyYAML built without libyaml: its own parser reads every document
    _QuickLoader = None


def _plain_tree(root: yaml.Node) -> bool:
    """Whether ``root`` holds no node twice (no alias) and fewer than ``MAX_YAML_VALUES`` values."""
    seen: set[int] = set()
    stack = [root]
    while stack:
        node = stack.pop()
        if id(node) in seen or len(seen) >= MAX_YAML_VALUES:
            return False
        seen.add(id(node))
        stack.extend(_children(node))
    return True


def _quick_document(text: str) -> tuple[bool, Any]:
    """``(True, document)`` for a document that libyaml reads without an error, an alias or too many values,
    else ``(False, None)``: ``read_yaml`` then reads it with PyYAML's own parser, whose errors and limits
    (counted while composing) it reports. The tracked pass's graph file and library files (~13 kB) take ~5 ms
    so instead of ~35 ms of CPU (a loaded host) on the start's one-core stretch (docs/speed.md)."""
    if _QuickLoader is None:
        return False, None
    loader = _QuickLoader(text)
    try:
        node = loader.get_single_node()
        if node is None or not _plain_tree(node):
            return False, None
        return True, loader.construct_document(node)
    except (yaml.YAMLError, RecursionError):
        return False, None
    finally:
        loader.dispose()


def read_yaml(path: Path, what: str = "graph file") -> Any:
    """Parse a YAML file safely; a missing, special, oversized, non-UTF-8 or invalid file, a duplicate
    key, or an alias bomb is a GraphError naming the file and the line, never quoting the file."""
    try:
        text = read_text(path, what, MAX_YAML_BYTES)
    except FileProblem as exc:
        raise GraphError([Problem(str(path), "", exc.reason)]) from None
    quick, document = _quick_document(text)
    if quick:
        return document
    loader = _BoundedLoader(text, what)
    try:
        node = loader.get_single_node()
        if node is not None and _expanded_size(node) > MAX_YAML_VALUES:
            raise _Limit(f"its aliases expand to more than {MAX_YAML_VALUES} values; a {what} may not be that large")
        return None if node is None else loader.construct_document(node)
    except (yaml.YAMLError, RecursionError) as exc:
        raise GraphError([Problem(str(path), *_yaml_problem(exc))]) from None
    finally:
        loader.dispose()


def _yaml_problem(exc: yaml.YAMLError | RecursionError) -> tuple[str, str]:
    """(where, what) of a YAML document that cannot be read."""
    if isinstance(exc, _DuplicateKey):
        return "", f"{exc}; names must be unique"
    if isinstance(exc, _Limit):
        return "", str(exc)
    if isinstance(exc, RecursionError):
        return "", "values are nested too deeply"
    mark = getattr(exc, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
    return where, f"not valid YAML: {clip(getattr(exc, 'problem', None) or type(exc).__name__)}"


def parse_value(text: str) -> Any:
    """A ``--set`` value: YAML scalar or flow collection, read as graph files are (``1e-3`` is a float)."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError:
        return text


def read_graph_file(path: Path, problems: list[Problem]) -> GraphFile | None:
    """The graph file at ``path``, validated; None with its problems noted when it cannot be read as one."""
    file = str(path)
    try:
        data = read_yaml(path)
    except GraphError as exc:
        problems.extend(exc.problems)
        return None
    if not isinstance(data, dict) or not (set(map(str, data)) & GRAPH_KEYS):
        # say nothing of what the file holds: it may be any file its user can read
        problems.append(Problem(file, "", f"not an evsda graph file: expected a mapping with some of the keys "
                                          f"{', '.join(sorted(GRAPH_KEYS))}"))
        return None
    try:
        return GraphFile.model_validate(data)
    except ValidationError as exc:
        problems.extend(Problem(file, f"'{loc}'", message) for loc, message in describe_validation_error(exc))
        return None
