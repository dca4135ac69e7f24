"""Block parameters: frozen pydantic models with units.

Every field states its unit in square brackets at the end of its description
(``"Die temperature [K]"``, ``"Quantum efficiency [1]"`` for dimensionless) and,
where the unit is ambiguous, in its name (``aperture_m``). Physical ranges are
enforced with pydantic constraints (``gt=0``) or validators, so a non-physical
value is rejected before any work.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, ValidationError

from .errors import Problem


class BlockParams(BaseModel):
    """Base of every block's ``Params``: frozen, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)


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
                message += f" (got {item['input']!r})"
        out.append((loc, message))
    return out


def params_problems(file: str, block: str, type_name: str, error: ValidationError) -> list[Problem]:
    """Problems for a block whose params failed validation, one per bad parameter."""
    return [
        Problem(file, f"block '{block}' ({type_name}) parameter '{loc}'", message)
        for loc, message in describe_validation_error(error)
    ]
