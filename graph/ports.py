"""Typed ports: the values that flow between blocks.

A port type is a frozen dataclass deriving from :class:`PortValue` whose fields are
numpy arrays, plain scalars/strings, or other port values. It declares the unit of
its main quantity in ``unit``. Every port type serialises itself to flat numpy
arrays plus JSON attributes, which is how the executor stores outputs and
checkpoints without knowing what they mean.

The vocabulary of concrete port types lives in :mod:`evsda.blocks.ports`; this
module only holds the mechanism.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

PORT_TYPES: dict[str, type["PortValue"]] = {}

# How a run store records a port type's values (:attr:`PortValue.record`):
#: each window's value under ``products/<block>/<port>/`` (when the run stores products or asks for it)
PRODUCT = "product"
#: the run's event stream: its columns (:attr:`PortValue.stream_columns`) appended under ``events/``
EVENT_STREAM = "events"
#: named figures with units (:meth:`PortValue.figures`) merged into ``metrics/``
METRICS = "metrics"
#: rows of ground truth (``table()``) appended under ``truth/``
TRUTH = "truth"


class PortValue:
    """Base class of all port types (use as a frozen dataclass).

    A port type says how a run store records its values (:attr:`record`), so the framework names no
    port type and no field of one.
    """

    unit: ClassVar[str] = ""
    #: how a run store records values of this type: PRODUCT, EVENT_STREAM, METRICS or TRUTH
    record: ClassVar[str] = PRODUCT
    #: EVENT_STREAM types: each column's field name -> (dtype, CF attributes: units, long_name, flags)
    stream_columns: ClassVar[dict[str, tuple[np.dtype, dict[str, Any]]]] = {}
    #: EVENT_STREAM types: the field holding the geometry the events lie on (recorded once, as attributes)
    stream_geometry: ClassVar[str | None] = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        PORT_TYPES[cls.__name__] = cls

    @classmethod
    def type_name(cls) -> str:
        return cls.__name__

    # -- recording ---------------------------------------------------------------------------
    def stream(self) -> tuple[dict[str, np.ndarray], "PortValue | None"]:
        """EVENT_STREAM types: ``(columns, geometry)``, the arrays of :attr:`stream_columns` and the value of
        :attr:`stream_geometry`."""
        geometry = getattr(self, self.stream_geometry) if self.stream_geometry else None
        return {name: getattr(self, name) for name in self.stream_columns}, geometry

    @classmethod
    def geometry_type(cls) -> type["PortValue"] | None:
        """EVENT_STREAM types: the port type of :attr:`stream_geometry`."""
        return typing.get_type_hints(cls).get(cls.stream_geometry) if cls.stream_geometry else None

    def figures(self) -> tuple[dict[str, Any], dict[str, str]]:
        """METRICS types: ``(values, units)``, each by the figure's name."""
        raise NotImplementedError(f"{self.type_name()} records no metrics")

    # -- serialisation -------------------------------------------------------------
    def to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Flatten into ``({name: ndarray}, {name: json-able})``; nested values use ``a.b`` names."""
        arrays: dict[str, np.ndarray] = {}
        attrs: dict[str, Any] = {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, PortValue):
                sub_arrays, sub_attrs = value.to_arrays()
                arrays.update({f"{field.name}.{k}": v for k, v in sub_arrays.items()})
                attrs.update({f"{field.name}.{k}": v for k, v in sub_attrs.items()})
            elif isinstance(value, np.ndarray):
                arrays[field.name] = value
            else:
                attrs[field.name] = jsonable(value, mark_nonfinite=False)
        return arrays, attrs

    def fingerprint(self) -> str:
        """A SHA-256 of every field (each array's dtype, shape and bytes; the other fields as JSON), for cache
        keys: equal values have equal fingerprints, whatever the size of their arrays."""
        arrays, attrs = self.to_arrays()
        digest = hashlib.sha256(json.dumps(attrs, sort_keys=True, default=repr).encode())
        for name in sorted(arrays):
            data = np.ascontiguousarray(arrays[name])
            digest.update(f"\0{name} {data.dtype.str} {data.shape}\0".encode())
            digest.update(repr(data.tolist()).encode() if data.dtype.kind == "O" else data.tobytes())
        return digest.hexdigest()

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], attrs: dict[str, Any]):
        """Inverse of :meth:`to_arrays`."""
        hints = typing.get_type_hints(cls)
        kwargs = {}
        for field in dataclasses.fields(cls):
            hint = hints.get(field.name)
            if isinstance(hint, type) and issubclass(hint, PortValue):
                kwargs[field.name] = hint.from_arrays(*(_under(field.name, d) for d in (arrays, attrs)))
            elif field.name in arrays:
                kwargs[field.name] = np.asarray(arrays[field.name])
            elif field.name in attrs:
                value = attrs[field.name]
                kwargs[field.name] = tuple(value) if isinstance(value, list) else value
        return cls(**kwargs)


def _under(name: str, values: dict[str, Any]) -> dict[str, Any]:
    """The entries of a nested value ``name`` (keys ``name.x``), by their inner names."""
    prefix = name + "."
    return {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}


def jsonable(value: Any, mark_nonfinite: bool = True) -> Any:
    """``value`` as JSON can hold it: numpy scalars as numbers, tuples as lists, arrays as lists (string
    arrays marked), dict keys as strings; with ``mark_nonfinite``, inf and NaN marked too (strict JSON has
    neither). :func:`from_json` restores the marked values."""
    if isinstance(value, dict):
        return {str(k): jsonable(v, mark_nonfinite) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v, mark_nonfinite) for v in value]
    value = _plain(value)
    if mark_nonfinite and isinstance(value, float) and not np.isfinite(value):
        return {"__float__": repr(value)}
    return value


def _plain(value: Any) -> Any:
    """numpy scalars as Python numbers, arrays as lists (string arrays marked); anything else as it is."""
    if isinstance(value, np.ndarray):
        return {"__strarray__": value.tolist()} if value.dtype.kind in "USO" else value.tolist()
    if isinstance(value, (np.integer, np.floating, np.bool_)):
        return value.item()
    return value


def from_json(value: Any) -> Any:
    """Inverse of :func:`jsonable` for the values it marks."""
    if isinstance(value, dict):
        if "__strarray__" in value:
            return np.asarray(value["__strarray__"], dtype=str)
        if "__float__" in value:
            return float(value["__float__"])
        return {k: from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [from_json(v) for v in value]
    return value


@dataclass(frozen=True)
class Input:
    """An input port: the type it accepts and what it means.

    ``multi=True`` accepts any number of connections; the block then receives a list.
    ``required=False`` lets the port stay unconnected; the block then receives ``None``
    (or an empty list for ``multi``).
    """

    type: type[PortValue]
    description: str = ""
    required: bool = True
    multi: bool = False


@dataclass(frozen=True)
class Output:
    """An output port: the type it produces and what it means."""

    type: type[PortValue]
    description: str = ""


def port_type_label(port_type: type[PortValue]) -> str:
    """``Irradiance [photon s^-1 pixel^-1]`` — the name and unit shown in messages."""
    unit = f" [{port_type.unit}]" if port_type.unit else ""
    return f"{port_type.type_name()}{unit}"
