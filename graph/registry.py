"""The block registry: built-in blocks and third-party blocks from entry points.

Blocks are found through the entry-point group ``evsda.blocks``. An entry point
names either one :class:`~evsda.graph.block.Block` subclass or a collection
(list, tuple or dict values) of them. evsda registers its own blocks the same
way (``builtin = "evsda.blocks.catalog:BLOCKS"``), so a third-party package adds
blocks by declaring, in its pyproject.toml::

    [project.entry-points."evsda.blocks"]
    my_arbiter = "mypackage.arbiter:MyArbiter"

A plugin that fails to import hides none of the others: its failure is kept (:func:`broken`)
and shown where its blocks would be asked for (:func:`unknown_block`, ``evsda blocks``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from importlib.metadata import entry_points

from .block import Block
from .errors import UserError

ENTRY_POINT_GROUP = "evsda.blocks"

_registered: dict[str, type[Block]] = {}
_origin: dict[str, str] = {}
_broken: dict[str, str] = {}   # entry-point name -> why it failed to import
_loaded = False


def register(block_class: type[Block], origin: str = "python") -> type[Block]:
    """Register a block class under its ``type_name`` (usable as a decorator)."""
    if not (isinstance(block_class, type) and issubclass(block_class, Block)):
        raise TypeError(f"{block_class!r} is not a Block subclass")
    name = block_class.type_name
    if not name:
        raise TypeError(f"{block_class.__name__} has no type_name")
    existing = _registered.get(name)
    if existing is not None and existing is not block_class:
        raise UserError(f"block type '{name}' from {origin} clashes with the one from {_origin[name]}")
    _registered[name] = block_class
    _origin[name] = origin
    return block_class


def unregister(name: str) -> None:
    """Remove a block type (for tests and plugin reloading)."""
    _registered.pop(name, None)
    _origin.pop(name, None)


def _as_classes(obj) -> Iterable[type[Block]]:
    if isinstance(obj, type):
        return [obj]
    if isinstance(obj, Mapping):
        return list(obj.values())
    return list(obj)


def load_entry_points() -> None:
    """Import every block advertised in the ``evsda.blocks`` entry-point group (once)."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    _broken.clear()
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
        except Exception as exc:  # kept, not raised: a broken plugin must not hide the others
            why = " ".join(str(exc).split()) or type(exc).__name__
            _broken[ep.name] = f"block plugin '{ep.name}' ({ep.value}) failed to import: {why}"
            continue
        dist = getattr(ep, "dist", None)
        origin = f"entry point '{ep.name}'" + (f" of {dist.name}" if dist is not None else "")
        for block_class in _as_classes(obj):
            register(block_class, origin)


def refresh() -> None:
    """Look for entry points again (after installing a plugin into a running process)."""
    global _loaded
    _loaded = False
    load_entry_points()


def available() -> dict[str, type[Block]]:
    """All registered block types, by name."""
    load_entry_points()
    return dict(sorted(_registered.items()))


def broken() -> list[str]:
    """One line per block plugin that failed to import (its blocks are missing from :func:`available`)."""
    load_entry_points()
    return list(_broken.values())


def unknown_block(name: str) -> str:
    """The message for a block type nobody registered, naming the plugins that failed to import."""
    failures = broken()
    return f"unknown block type '{name}'" + (f" ({'; '.join(failures)})" if failures else "")


def origin(name: str) -> str:
    load_entry_points()
    return _origin.get(name, "")


def get(name: str) -> type[Block] | None:
    load_entry_points()
    return _registered.get(name)


def is_builtin(name: str) -> bool:
    cls = get(name)
    return cls is not None and cls.__module__.startswith("evsda.")
