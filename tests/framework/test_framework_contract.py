"""Every built-in block honours the block contract (documentation, units, ports, parameters)."""

from __future__ import annotations

import inspect

import pytest

from evsda.graph import Block, Input, Output, registry
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


def step_problems(cls: type[Block]) -> list[str]:
    """Where ``cls.step``'s parameters disagree with ``cls.inputs`` (issue 16.5: inputs are declared
    twice, and this is what keeps the two declarations one): the same names, a required input without
    a default and an optional one defaulting to ``None``, no catch-all ``**inputs`` or ``*args``."""
    parameters = list(inspect.signature(inspect.unwrap(cls.step)).parameters.values())[2:]
    problems = [f"step() takes *{p.name}/**{p.name}" for p in parameters
                if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    named = {p.name: p for p in parameters if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
    if set(named) != set(cls.inputs):
        problems.append(f"step() parameters {sorted(named)} != inputs {sorted(cls.inputs)}")
    for port, spec in cls.inputs.items():
        parameter = named.get(port)
        if parameter is None:
            continue
        has_default = parameter.default is not inspect.Parameter.empty
        if spec.required and has_default:
            problems.append(f"required input '{port}' has a default in step()")
        if not spec.required and (not has_default or parameter.default is not None):
            problems.append(f"optional input '{port}' must default to None in step()")
    return problems


@pytest.mark.parametrize("name", BUILTIN)
def test_step_parameters_are_the_declared_inputs(name):
    assert step_problems(registry.get(name)) == []


def test_the_step_check_sees_a_disagreement():
    port_type = registry.get("dvs_pixel").inputs["irradiance"].type

    class Drifted(Block):
        type_name = "drifted"
        inputs = {"frames": Input(port_type), "extra": Input(port_type, required=False)}
        outputs = {"out": Output(port_type)}

        def step(self, window, frames=None, extras=None):
            return {}

    assert step_problems(Drifted) == [
        "step() parameters ['extras', 'frames'] != inputs ['extra', 'frames']",
        "required input 'frames' has a default in step()",
    ]
