"""The blocks' dependency graph: a small directed graph with the few queries the framework makes.

Nodes and edges keep the order they were added in, and :meth:`Dag.topological_order` is Kahn's algorithm
taken generation by generation in that order (the order networkx's ``topological_sort`` gives, which this
module replaced: importing networkx cost every run ~0.15 s).
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Iterator


class Dag:
    """Directed graph of hashable nodes; each edge holds its ``ports``, the (output, input) pairs it carries."""

    def __init__(self, nodes: Iterable[Hashable] = ()):
        self._successors: dict[Hashable, dict[Hashable, list]] = {}
        self._predecessors: dict[Hashable, dict[Hashable, None]] = {}
        for node in nodes:
            self.add_node(node)

    def add_node(self, node: Hashable) -> None:
        self._successors.setdefault(node, {})
        self._predecessors.setdefault(node, {})

    def add_edge(self, source: Hashable, target: Hashable, ports: tuple[str, str]) -> None:
        """An edge ``source -> target`` carrying ``ports`` (added to the edge's list if it exists)."""
        self.add_node(source)
        self.add_node(target)
        self._successors[source].setdefault(target, []).append(ports)
        self._predecessors[target][source] = None

    @property
    def nodes(self) -> list[Hashable]:
        return list(self._successors)

    @property
    def edges(self) -> list[tuple[Hashable, Hashable]]:
        return [(s, t) for s, targets in self._successors.items() for t in targets]

    def ports(self, source: Hashable, target: Hashable) -> list[tuple[str, str]]:
        return self._successors[source][target]

    def successors(self, node: Hashable) -> list[Hashable]:
        return list(self._successors[node])

    def predecessors(self, node: Hashable) -> list[Hashable]:
        return list(self._predecessors[node])

    def out_degree(self, node: Hashable) -> int:
        return len(self._successors[node])

    def ancestors(self, node: Hashable) -> set[Hashable]:
        """Every node with a path to ``node`` (not ``node`` itself)."""
        return self._reach(node, self._predecessors)

    def descendants(self, node: Hashable) -> set[Hashable]:
        """Every node ``node`` has a path to (not ``node`` itself)."""
        return self._reach(node, self._successors)

    @staticmethod
    def _reach(node: Hashable, links: dict) -> set[Hashable]:
        seen, todo = set(), list(links[node])
        while todo:
            other = todo.pop()
            if other not in seen:
                seen.add(other)
                todo.extend(links[other])
        seen.discard(node)
        return seen

    def topological_order(self) -> Iterator[Hashable]:
        """The nodes, each after all its predecessors (Kahn 1962, Commun. ACM 5, 558): the nodes without
        predecessors in the order they were added, then generation by generation each node's successors in the
        order their edges were added. Raises ``ValueError`` on a cycle."""
        waiting = {node: len(sources) for node, sources in self._predecessors.items() if sources}
        generation = [node for node, sources in self._predecessors.items() if not sources]
        emitted = 0
        while generation:
            following = []
            for node in generation:
                for child in self._successors[node]:
                    waiting[child] -= 1
                    if not waiting[child]:
                        following.append(child)
                        del waiting[child]
            yield from generation
            emitted += len(generation)
            generation = following
        if emitted < len(self._successors):
            raise ValueError("the graph has a cycle")

    def find_cycle(self) -> list[Hashable] | None:
        """The nodes of one cycle, first node repeated at the end (``[a, b, a]``), or None when there is none
        (depth-first search, nodes in the order they were added)."""
        done: set[Hashable] = set()
        for start in self._successors:
            if start in done:
                continue
            path, on_path = [start], {start}
            branches = [iter(self._successors[start])]
            while branches:
                child = next(branches[-1], None)
                if child is None:
                    branches.pop()
                    done.add(path[-1])
                    on_path.discard(path.pop())
                elif child in on_path:
                    return path[path.index(child):] + [child]
                elif child not in done:
                    path.append(child)
                    on_path.add(child)
                    branches.append(iter(self._successors[child]))
        return None
