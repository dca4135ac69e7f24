"""Block parameters: frozen pydantic models with units.

Every field states its unit in square brackets at the end of its description
(``"Die temperature [K]"``, ``"Quantum efficiency [1]"`` for dimensionless) and,
where the unit is ambiguous, in its name (``aperture_m``). Physical ranges are
enforced with pydantic constraints (``gt=0``) or validators, so a non-physical
value is rejected before any work.
"""

from __future__ import annotations

import typing
from typing import Annotated

from pydantic import BaseModel, ConfigDict, ValidationError

from .errors import Problem, excerpt


class _FileMarker:
    """Marks a parameter that names a file (see :data:`DataFile`)."""

    def __repr__(self) -> str:
        return "DataFile"


_FILE = _FileMarker()

#: A parameter naming a data file: a ``library:...`` reference to bundled data or a
#: path, which graph files resolve relative to their own folder.
DataFile = Annotated[str, _FILE]


def path_fields(params_class: type[BaseModel]) -> list[str]:
    """Names of the parameters of ``params_class`` declared as :data:`DataFile`."""

    def is_file(annotation) -> bool:
        if typing.get_origin(annotation) is Annotated:
            return any(m is _FILE for m in annotation.__metadata__) or is_file(typing.get_args(annotation)[0])
        return any(is_file(arg) for arg in typing.get_args(annotation))

    return [name for name, info in params_class.model_fields.items()
            if any(m is _FILE for m in info.metadata) or is_file(info.annotation)]


class BlockParams(BaseModel):
    """Base of every block's ``Params``: frozen, unknown keys rejected, and no infinite or NaN number
    (every physical quantity is finite; "no limit" is spelled ``None`` where a block allows it)."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True, allow_inf_nan=False)


def describe_validation_error(error: ValidationError) -> list[tuple[str, str]]:
    """Turn a pydantic error into ``(parameter, what was expected)`` pairs."""
    out = []
    for item in error.errors():
        loc = ".".join(str(part) for part in item["loc"]) or "(params)"
        kind = item["type"]
        if kind == "extra_forbidden":
            message = "unknown parameter"
        elif kind == "missing":
            message = "required parameter is missing"
        else:
            message = item["msg"]
            if "input" in item and kind not in ("missing",):
                message += f" (got {excerpt(item['input'])})"
        out.append((loc, message))
    return out


def params_problems(file: str, block: str, type_name: str, error: ValidationError) -> list[Problem]:
    """Problems for a block whose params failed validation, one per bad parameter."""
    return [
        Problem(file, f"block '{block}' ({type_name}) parameter '{loc}'", message)
        for loc, message in describe_validation_error(error)
    ]
