"""Every built-in block honours the block contract (documentation, units, ports, parameters)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from evsda.graph import Block, Input, Output, registry
from evsda.graph.block import step_signature_problems
from evsda.graph.ports import PORT_TYPES
from evsda.graph.report import describe_block, split_unit

BUILTIN = [name for name in registry.available() if registry.is_builtin(name)]


def test_there_are_builtin_blocks():
    assert BUILTIN, "no built-in block is registered through the evsda.blocks entry point"


@pytest.mark.parametrize("name", BUILTIN)
def test_block_contract(name):
    cls = registry.get(name)
    assert issubclass(cls, Block) and cls.type_name == name
    assert cls.__doc__ and cls.__doc__.strip(), f"{name} has no docstring"
    for port, spec in {**cls.inputs, **cls.outputs}.items():
        assert spec.type.type_name() in PORT_TYPES, f"{name}.{port} uses an unregistered port type"
        assert spec.type.unit, f"port type {spec.type.type_name()} declares no unit"
    config = cls.Params.model_config
    assert config.get("frozen") and config.get("extra") == "forbid"
    for field, info in cls.Params.model_fields.items():
        text, unit = split_unit(info.description)
        assert text and unit, f"{name}.{field}: description must end with its unit in brackets, e.g. '[K]'"
    for attribute in cls.state:
        assert isinstance(attribute, str)
    assert name in describe_block(name, cls)


@pytest.mark.parametrize("name", BUILTIN)
def test_step_parameters_are_the_declared_inputs(name):
    assert step_signature_problems(registry.get(name)) == []


def test_the_step_check_sees_a_disagreement():
    port_type = registry.get("dvs_pixel").inputs["irradiance"].type

    class Drifted(Block):
        type_name = "drifted"
        inputs = {"frames": Input(port_type), "extra": Input(port_type, required=False)}
        outputs = {"out": Output(port_type)}

        def step(self, window, frames=None, extras=None):
            return {}

    assert step_signature_problems(Drifted) == [
        "step() parameters ['extras', 'frames'] != inputs ['extra', 'frames']",
        "required input 'frames' has a default in step()",
    ]


def test_registering_a_block_whose_step_disagrees_is_refused():
    """The rule is the framework's, not only this test's: a plugin's block breaking it is not registered."""
    port_type = registry.get("dvs_pixel").inputs["irradiance"].type

    class Drifted(Block):
        """A block whose step() renamed its input."""
        type_name = "drifted_contract"
        inputs = {"frames": Input(port_type)}
        outputs = {"out": Output(port_type)}

        def step(self, window, frame):
            return {}

    with pytest.raises(TypeError, match=r"block 'drifted_contract' \(.*Drifted\): its step\(\) must take exactly "
                                        r"its declared inputs by name: step\(\) parameters \['frame'\] != "
                                        r"inputs \['frames'\]"):
        registry.register(Drifted)
    assert registry.get("drifted_contract") is None


DRIFTED_PLUGIN = '''
from evsda.graph import Block, Input, Output, registry
PORT = registry.get("dvs_pixel").inputs["irradiance"].type

class Drifted(Block):
    """A plugin block whose step() takes an input it never declared."""
    type_name = "drifted_plugin"
    inputs = {"frames": Input(PORT)}
    outputs = {"out": Output(PORT)}

    def step(self, window, frames, extra=None):
        return {}
'''


def test_a_plugin_whose_step_disagrees_is_reported_and_hides_no_other_block(tmp_path):
    (tmp_path / "evsda_drifted.py").write_text(DRIFTED_PLUGIN)
    dist = tmp_path / "evsda_drifted-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: evsda-drifted\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[evsda.blocks]\ndrifted = evsda_drifted:Drifted\n")
    proc = subprocess.run([sys.executable, "-m", "evsda.graph.cli", "blocks"], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr
    assert "dvs_pixel" in proc.stdout and "drifted_plugin" not in proc.stdout
    assert ("block plugin 'drifted' (evsda_drifted:Drifted): block 'drifted_plugin' (evsda_drifted:Drifted): "
            "its step() must take exactly its declared inputs by name: "
            "step() parameters ['extra', 'frames'] != inputs ['frames']") in proc.stderr
    assert "Traceback" not in proc.stderr
