"""Named types of a graph's wiring: port endpoints, connections and exposed ports.

Each is a NamedTuple, so code that unpacks them as plain tuples (``for src, sport, dst, dport in
graph.connections``) keeps working, while new code reads the fields by name.
"""

from __future__ import annotations

from typing import Literal, NamedTuple


class Endpoint(NamedTuple):
    """One port of one block: ``block.port``."""

    block: str
    port: str

    def __str__(self) -> str:
        return f"{self.block}.{self.port}"


class Connection(NamedTuple):
    """An output port feeding an input port: ``src.src_port -> dst.dst_port``."""

    src: str
    src_port: str
    dst: str
    dst_port: str

    @classmethod
    def between(cls, source: Endpoint, target: Endpoint) -> "Connection":
        return cls(source.block, source.port, target.block, target.port)

    @property
    def source(self) -> Endpoint:
        return Endpoint(self.src, self.src_port)

    @property
    def target(self) -> Endpoint:
        return Endpoint(self.dst, self.dst_port)

    def __str__(self) -> str:
        return f"{self.source} -> {self.target}"


class Declared(NamedTuple):
    """A connection as a graph file declares it, before its ports are checked."""

    connection: Connection
    file: str


class Exposure(NamedTuple):
    """A port of an included graph's block that the graph exposes under its own name."""

    file: str
    kind: Literal["input", "output"]
    name: str
    target: Endpoint
