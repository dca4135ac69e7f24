"""Graph files: loading, includes, overrides, and one clear line per problem."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from evsda.graph import GraphError
from evsda.graph.graphfile import load_graph, parse_value

RUN = 'run: {start: "2024-03-01T02:15:00Z", duration_s: 0.05, window_s: 0.01, seed: 7}'


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def good_graph(tmp_path: Path) -> Path:
    return write(tmp_path / "good.yaml", f"""\
        evsda: 1
        name: good
        {RUN}
        blocks:
          ramp: {{type: test_ramp, params: {{slope_per_s: 50}}}}
          spikes: {{type: test_spikes}}
        connections:
          - {{from: ramp.samples, to: spikes.samples}}
        """)


def problems_of(path, overrides=None) -> list[str]:
    with pytest.raises(GraphError) as info:
        load_graph(path, overrides)
    return [str(p) for p in info.value.problems]


def test_good_graph_loads_into_a_digraph(plugin, tmp_path):
    graph = load_graph(good_graph(tmp_path))
    assert set(graph.nodes) == {"ramp", "spikes"}
    assert list(graph.digraph.edges) == [("ramp", "spikes")]
    assert graph.nodes["ramp"].block.params.slope_per_s == 50
    assert graph.run_info().n_windows == 5


def test_set_overrides_a_parameter_with_yaml_scalars(plugin, tmp_path):
    graph = load_graph(good_graph(tmp_path), ["ramp.slope_per_s=1e-3", "spikes.step=2"])
    assert graph.nodes["ramp"].block.params.slope_per_s == pytest.approx(1e-3)
    assert graph.nodes["spikes"].block.params.step == 2
    assert parse_value("[1, 2]") == [1, 2] and parse_value("abc") == "abc"


def test_every_problem_in_a_file_is_reported_together(plugin, tmp_path):
    path = write(tmp_path / "bad.yaml", f"""\
        evsda: 1
        {RUN}
        blocks:
          ramp: {{type: test_ramp, params: {{cadence_s: -1, colour: red}}}}
          spikes: {{type: test_spikes, params: {{step: "many"}}}}
          ghost: {{type: test_rampp}}
          count: {{type: test_counter}}
          lonely: {{type: test_spikes}}
        connections:
          - {{from: ramp.samples, to: spikes.sample}}
          - {{from: ramp.nothing, to: count.events}}
          - {{from: ramp.samples, to: count.events}}
        """)
    lines = problems_of(path)
    text = "\n".join(lines)
    assert all(line.startswith(str(path)) for line in lines)
    assert "block 'ramp' (test_ramp) parameter 'cadence_s': Input should be greater than 0" in text
    assert "parameter 'colour': unknown parameter" in text
    assert "block 'spikes' (test_spikes) parameter 'step'" in text and "'many'" in text
    assert "unknown block type 'test_rampp'; did you mean 'test_ramp'" in text
    assert "has no input port 'sample'; its inputs are ['samples']" in text
    assert "has no output port 'nothing'; its outputs are ['samples']" in text
    assert "port type mismatch: ramp.samples produces Samples [1] but count.events expects Events [event]" in text
    assert "block 'lonely' input 'samples': required input (Samples [1]) is not connected" in text
    assert "block 'spikes' input 'samples': required input (Samples [1]) is not connected" in text
    assert len(lines) == 10


def test_cycle_is_reported(plugin, tmp_path):
    path = write(tmp_path / "cycle.yaml", f"""\
        evsda: 1
        {RUN}
        blocks:
          a: {{type: test_scale}}
          b: {{type: test_scale}}
        connections:
          - {{from: a.samples, to: b.samples}}
          - {{from: b.samples, to: a.samples}}
        """)
    (line,) = problems_of(path)
    assert "the graph has a cycle (a -> b -> a)" in line or "the graph has a cycle (b -> a -> b)" in line


def test_duplicate_names_are_errors_not_silently_merged(plugin, tmp_path):
    path = write(tmp_path / "dup.yaml", f"""\
        evsda: 1
        {RUN}
        blocks:
          ramp: {{type: test_ramp}}
          ramp: {{type: test_ramp}}
        """)
    (line,) = problems_of(path)
    assert "duplicate key 'ramp'" in line and "line 5" in line


def test_yaml_cannot_execute_code(plugin, tmp_path):
    path = write(tmp_path / "evil.yaml", """\
        evsda: 1
        blocks: !!python/object/apply:os.system ["echo pwned"]
        """)
    (line,) = problems_of(path)
    assert "not valid YAML" in line


def test_structure_errors_name_the_key(plugin, tmp_path):
    path = write(tmp_path / "struct.yaml", """\
        evsda: 2
        blocks: {a: {params: {}}}
        conections: []
        run: {start: "yesterday", duration_s: 0}
        """)
    text = "\n".join(problems_of(path))
    assert "'evsda': Input should be 1" in text
    assert "'blocks.a.type': required parameter is missing" in text
    assert "'conections': unknown parameter" in text
    assert "'run.duration_s'" in text and "'run.start'" in text


def test_include_exposes_ports_and_takes_overrides(plugin, tmp_path):
    write(tmp_path / "sensor.yaml", """\
        evsda: 1
        blocks:
          spikes: {type: test_spikes, params: {step: 3}}
        expose:
          inputs: {signal: spikes.samples}
          outputs: {events: spikes.events}
        """)
    main = write(tmp_path / "main.yaml", f"""\
        evsda: 1
        {RUN}
        include:
          - {{file: sensor.yaml, as: cam, set: {{spikes.latency_s: 2.0e-6}}}}
        blocks:
          ramp: {{type: test_ramp}}
          count: {{type: test_counter}}
        connections:
          - {{from: ramp.samples, to: cam.signal}}
          - {{from: cam.events, to: count.events}}
        outputs: [count.metrics]
        """)
    graph = load_graph(main, ["cam/spikes.step=4"])
    block = graph.nodes["cam/spikes"].block
    assert (block.params.step, block.params.latency_s) == (4, 2e-6)
    assert ("ramp", "samples", "cam/spikes", "samples") in graph.connections
    assert graph.outputs == [("count", "metrics")]


def test_include_errors_name_the_include(plugin, tmp_path):
    write(tmp_path / "sensor.yaml", """\
        evsda: 1
        blocks:
          spikes: {type: test_spikes}
        expose:
          inputs: {signal: spikes.samples}
        """)
    main = write(tmp_path / "main.yaml", f"""\
        evsda: 1
        {RUN}
        include:
          - {{file: sensor.yaml, as: cam, set: {{spikez.step: 1}}}}
          - {{file: missing.yaml, as: other}}
        blocks:
          ramp: {{type: test_ramp}}
        connections:
          - {{from: ramp.samples, to: cam.signl}}
        """)
    text = "\n".join(problems_of(main, ["nope.x=1"]))
    assert "include 'cam' set 'cam/spikez.step': no block named 'cam/spikez'; did you mean 'cam/spikes'?" in text
    assert "include 'other': file missing.yaml not found" in text
    assert "include 'cam' exposes no input 'signl'; it exposes ['signal']" in text
    assert "--set 'nope.x': no block named 'nope'" in text


def test_self_include_is_an_error(plugin, tmp_path):
    path = write(tmp_path / "loop.yaml", """\
        evsda: 1
        include: [{file: loop.yaml, as: again}]
        """)
    assert any("includes itself" in line for line in problems_of(path))


def test_missing_file_is_one_clear_error(plugin, tmp_path):
    (line,) = problems_of(tmp_path / "nothing.yaml")
    assert line.endswith("nothing.yaml: graph file not found")


def test_include_swap_replaces_a_block_type(plugin, tmp_path):
    write(tmp_path / "chain.yaml", """\
        evsda: 1
        blocks:
          stage: {type: test_scale, params: {gain: 3.0}}
        expose:
          inputs: {signal: stage.samples}
          outputs: {samples: stage.samples}
        """)
    main = write(tmp_path / "main.yaml", f"""\
        evsda: 1
        {RUN}
        include:
          - {{file: chain.yaml, as: a, swap: {{stage: test_scale}}}}
          - {{file: chain.yaml, as: b, swap: {{stage: test_scale}}, set: {{stage.gain: 5.0}}}}
        blocks:
          ramp: {{type: test_ramp}}
        connections:
          - {{from: ramp.samples, to: a.signal}}
          - {{from: ramp.samples, to: b.signal}}
        """)
    # the swapped block starts from its new type's defaults, then `set` applies
    graph = load_graph(main)
    assert graph.nodes["a/stage"].block.params.gain == 2.0
    assert graph.nodes["b/stage"].block.params.gain == 5.0
    bad = write(tmp_path / "bad.yaml", main.read_text().replace("as: a, swap: {stage:", "as: a, swap: {stge:"))
    assert any("swap 'stge'" in p and "did you mean 'stage'" in p for p in problems_of(bad))


def test_set_overrides_the_run_section(plugin, tmp_path):
    graph = load_graph(good_graph(tmp_path), ["run.duration_s=0.02", "run.seed=3"])
    assert graph.run_info().n_windows == 2 and graph.run_info().seed == 3
    assert any("run.duration_s" in p for p in problems_of(good_graph(tmp_path), ["run.duration_s=-1"]))


def test_a_graph_without_run_section_takes_its_first_includes(plugin, tmp_path):
    good_graph(tmp_path)
    variant = write(tmp_path / "variant.yaml", """\
        evsda: 1
        include:
          - {file: good.yaml, as: scene, set: {ramp.slope_per_s: 7}}
        """)
    graph = load_graph(variant, ["run.seed=9"])
    assert graph.run_info().n_windows == 5 and graph.run_info().seed == 9
    assert graph.nodes["scene/ramp"].block.params.slope_per_s == 7


def test_an_exposed_port_must_exist_even_if_nothing_uses_it(plugin, tmp_path):
    write(tmp_path / "chain.yaml", """\
        evsda: 1
        blocks:
          stage: {type: test_scale}
        expose:
          inputs: {signal: stage.samples}
          outputs: {events: stage.events}
        """)
    main = write(tmp_path / "main.yaml", f"""\
        evsda: 1
        {RUN}
        include:
          - {{file: chain.yaml, as: a}}
        blocks:
          ramp: {{type: test_ramp}}
        connections:
          - {{from: ramp.samples, to: a.signal}}
        """)
    assert any("expose output 'events'" in p and "has no output 'events'" in p and "samples" in p
               for p in problems_of(main))


def test_scientific_notation_is_a_number_everywhere(plugin, tmp_path):
    """YAML 1.1 reads ``1e-5`` (no dot, or no exponent sign) as a string; graph files, --set and list
    elements all read it as a float, as YAML 1.2 does."""
    assert parse_value("1e-5") == 1e-5 and parse_value("[1e-5, 2E3, -1.5e+2, .5e1]") == [1e-5, 2e3, -150.0, 5.0]
    assert parse_value("1e5") == 1e5 and isinstance(parse_value("12"), int) and parse_value("e5") == "e5"
    path = write(tmp_path / "sci.yaml", good_graph(tmp_path).read_text().replace("slope_per_s: 50", "slope_per_s: 5e1"))
    assert load_graph(path).nodes["ramp"].block.params.slope_per_s == 50.0
    assert load_graph(path).to_dict()["blocks"]["ramp"]["params"]["slope_per_s"] == 50.0


def test_libyaml_reads_every_bundled_file_as_pyyamls_own_parser(tmp_path):
    """read_yaml's quick path (libyaml's parser, the same constructor and resolvers) gives the values PyYAML's
    own parser gives, types included, on every bundled graph and library file; a document with an alias, an error
    or a duplicate key goes to PyYAML's parser, which reports it as before."""
    from evsda.graph import reading

    if reading._QuickLoader is None:
        pytest.skip("PyYAML without libyaml")
    root = Path(__file__).parents[2]
    files = [p for folder in ("library", "examples", "benchmarks") for p in (root / folder).rglob("*.yaml")]
    assert len(files) > 20
    for path in files:
        text = path.read_text()
        quick, document = reading._quick_document(text)
        loader = reading._BoundedLoader(text, "graph file")
        try:
            expected = loader.construct_document(loader.get_single_node())
        finally:
            loader.dispose()
        assert quick and repr(document) == repr(expected) and document == expected, path
    assert reading._quick_document("a: &x [1, 2]\nb: *x\n") == (False, None)
    assert reading._quick_document("a: 1\na: 2\n") == (False, None)
    assert reading._quick_document("a: [1, 2\n") == (False, None)
    aliased = write(tmp_path / "aliased.yaml", "a: &x [1e-5, 2]\nb: *x\n")
    assert reading.read_yaml(aliased) == {"a": [1e-5, 2], "b": [1e-5, 2]}
