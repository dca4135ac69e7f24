"""Every built-in block honours the block contract (documentation, units, ports, parameters)."""

from __future__ import annotations

import pytest

from evsda.graph import Block, registry
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
