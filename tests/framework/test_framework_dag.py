"""The blocks' dependency graph (graph/dag.py): Kahn's topological order, reach, cycles."""

import itertools
import random

import pytest

from evsda.graph.dag import Dag


def diamond() -> Dag:
    # source -> (left, right) -> sink, plus a lone block; nodes added in a scrambled order
    dag = Dag(["sink", "lone", "right", "source", "left"])
    for a, b in [("source", "right"), ("source", "left"), ("left", "sink"), ("right", "sink")]:
        dag.add_edge(a, b, ("out", "in"))
    return dag


def test_order_is_kahns_generations_in_insertion_order():
    # Kahn 1962: the blocks without inputs in the order they were added, then each generation's children in the
    # order their edges were added
    assert list(diamond().topological_order()) == ["lone", "source", "right", "left", "sink"]


def test_every_edge_points_forward_in_random_dags():
    for seed in range(200):
        rng = random.Random(seed)
        names = [f"b{i}" for i in range(rng.randint(1, 10))]
        edges = [(a, b) for a, b in itertools.combinations(names, 2) if rng.random() < 0.3]
        rng.shuffle(names)
        dag = Dag(names)
        for a, b in edges:
            dag.add_edge(a, b, ("out", "in"))
        order = {name: k for k, name in enumerate(dag.topological_order())}
        assert sorted(order) == sorted(names)
        assert all(order[a] < order[b] for a, b in edges)
        assert dag.find_cycle() is None


def test_reach_ports_and_degrees():
    dag = diamond()
    dag.add_edge("source", "left", ("other", "in2"))
    assert dag.ancestors("sink") == {"source", "left", "right"} and dag.ancestors("source") == set()
    assert dag.descendants("source") == {"left", "right", "sink"} and dag.descendants("lone") == set()
    assert dag.ports("source", "left") == [("out", "in"), ("other", "in2")]
    assert dag.predecessors("sink") == ["left", "right"] and dag.out_degree("sink") == 0
    assert dag.edges == [("right", "sink"), ("source", "right"), ("source", "left"), ("left", "sink")]


def test_a_cycle_is_found_and_refused():
    dag = diamond()
    dag.add_edge("sink", "source", ("out", "in"))
    cycle = dag.find_cycle()
    assert cycle[0] == cycle[-1] and len(cycle) == 4
    assert all(b in dag.successors(a) for a, b in zip(cycle, cycle[1:]))
    with pytest.raises(ValueError, match="cycle"):
        list(dag.topological_order())
