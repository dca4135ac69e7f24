"""The block registry: built-in blocks and third-party blocks from entry points.

Blocks are found through the entry-point group ``evsda.blocks``. An entry point
names either one :class:`~evsda.graph.block.Block` subclass, a collection
(list, tuple or dict values) of them, or a mapping of type names to
``"module:Class"`` strings, whose modules are imported only when a block of theirs
is asked for (:func:`get`). evsda registers its own blocks that last way
(``builtin = "evsda.blocks.catalog:BLOCKS"``), so that loading a graph imports only
the block packages it names; a third-party package adds blocks by declaring, in its
pyproject.toml::

    [project.entry-points."evsda.blocks"]
    my_arbiter = "mypackage.arbiter:MyArbiter"

A plugin that fails to import, whose block type clashes with one already registered, or whose
block's ``step()`` parameters are not its declared inputs (:func:`~evsda.graph.block.step_signature_problems`)
hides none of the others: its failure is kept (:func:`broken`) and shown where its blocks would be
asked for (:func:`unknown_block`, ``evsda blocks``). :func:`register` called directly raises on
either.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from importlib import import_module
from importlib.metadata import entry_points

from .block import Block, step_signature_problems
from .errors import UserError

ENTRY_POINT_GROUP = "evsda.blocks"

_registered: dict[str, type[Block]] = {}
_origin: dict[str, str] = {}
_lazy: dict[str, str] = {}     # type name -> "module:Class", not imported yet (its origin is in _origin)
_broken: dict[str, str] = {}   # entry-point name (or lazy type name) -> why it failed to import
_scanned = False               # the entry points have been read
_loaded = False                # every lazily declared block has been imported


def _spec(block_class: type[Block]) -> str:
    return f"{block_class.__module__}:{block_class.__qualname__}"


def _clash(name: str, origin: str) -> UserError:
    return UserError(f"block type '{name}' from {origin} clashes with the one from {_origin[name]}")


def register(block_class: type[Block], origin: str = "python") -> type[Block]:
    """Register a block class under its ``type_name`` (usable as a decorator)."""
    if not (isinstance(block_class, type) and issubclass(block_class, Block)):
        raise TypeError(f"{block_class!r} is not a Block subclass")
    name = block_class.type_name
    if not name:
        raise TypeError(f"{block_class.__name__} has no type_name")
    problems = step_signature_problems(block_class)
    if problems:
        raise TypeError(f"block '{name}' ({_spec(block_class)}): its step() must take exactly its declared "
                        f"inputs by name: {'; '.join(problems)}")
    existing = _registered.get(name)
    if (existing is not None and existing is not block_class) or _lazy.get(name, _spec(block_class)) != _spec(block_class):
        raise _clash(name, origin)
    _lazy.pop(name, None)
    _registered[name] = block_class
    _origin.setdefault(name, origin)
    return block_class


def _declare(name: str, spec: str, origin: str) -> None:
    """Register type ``name`` as ``"module:Class"``, to be imported when first asked for."""
    if name in _registered:
        if _spec(_registered[name]) != spec:
            raise _clash(name, origin)
        return
    if _lazy.get(name, spec) != spec:
        raise _clash(name, origin)
    _lazy[name], _origin[name] = spec, origin


def unregister(name: str) -> None:
    """Remove a block type (for tests and plugin reloading)."""
    _registered.pop(name, None)
    _lazy.pop(name, None)
    _origin.pop(name, None)


def _as_classes(obj) -> Iterable[type[Block]]:
    if isinstance(obj, type):
        return [obj]
    if isinstance(obj, Mapping):
        return list(obj.values())
    return list(obj)


def _why(exc: Exception) -> str:
    """An import failure's message on one line (its type when it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def _register_entry_point(ep, obj) -> None:
    """Register what one loaded entry point names: classes, or a mapping of type names to "module:Class"."""
    dist = getattr(ep, "dist", None)
    origin = f"entry point '{ep.name}'" + (f" of {dist.name}" if dist is not None else "")
    lazy = isinstance(obj, Mapping) and obj and all(isinstance(v, str) for v in obj.values())
    for item in (obj.items() if lazy else _as_classes(obj)):
        try:
            if lazy:
                _declare(*item, origin)
            else:
                register(item, origin)
        except (UserError, TypeError) as exc:   # kept, not raised, like an import failure
            _broken[f"{ep.name}:{item[0] if lazy else getattr(item, '__name__', item)}"] = (
                f"block plugin '{ep.name}' ({ep.value}): {exc}")


def _scan() -> None:
    """Read the ``evsda.blocks`` entry points (once): import plugins that name classes, note the lazy ones."""
    global _scanned
    if _scanned:
        return
    _scanned = True
    _broken.clear()
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
        except Exception as exc:  # kept, not raised: a broken plugin must not hide the others
            _broken[ep.name] = f"block plugin '{ep.name}' ({ep.value}) failed to import: {_why(exc)}"
            continue
        _register_entry_point(ep, obj)


def _resolve(name: str) -> type[Block] | None:
    """Import a lazily declared block; a failure is kept like a broken plugin's (None returned)."""
    spec = _lazy[name]
    module, _, attr = spec.partition(":")
    try:
        block_class = getattr(import_module(module), attr)
    except Exception as exc:  # kept, not raised, as for a plugin that fails to import
        _lazy.pop(name)
        _broken[name] = f"block '{name}' ({spec}, {_origin[name]}) failed to import: {_why(exc)}"
        return None
    if not (isinstance(block_class, type) and issubclass(block_class, Block)) or block_class.type_name != name:
        _lazy.pop(name)
        _broken[name] = f"block '{name}' ({spec}, {_origin[name]}) is not a Block subclass of that type"
        return None
    try:
        return register(block_class, _origin[name])
    except TypeError as exc:  # kept, not raised, as for a plugin whose block breaks the contract
        _lazy.pop(name)
        _broken[name] = f"{exc} ({_origin[name]})"
        return None


def load_entry_points() -> None:
    """Import every block advertised in the ``evsda.blocks`` entry-point group (once)."""
    global _loaded
    _scan()
    if _loaded:
        return
    _loaded = True
    for name in list(_lazy):
        if name in _lazy:
            _resolve(name)


def refresh() -> None:
    """Look for entry points again (after installing a plugin into a running process)."""
    global _scanned, _loaded
    _scanned = _loaded = False
    _lazy.clear()
    load_entry_points()


class _Available(Mapping):
    """Every block type by name; a lazily declared block is imported when its class is looked up."""

    def __init__(self, names: list[str]):
        self._names = names

    def __getitem__(self, name: str) -> type[Block]:
        block_class = get(name) if name in self._names else None
        if block_class is None:
            raise KeyError(name)
        return block_class

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name) -> bool:
        return name in self._names

    def items(self) -> list[tuple[str, type[Block]]]:
        """Every block type and its class (importing them all); one that fails to import is left out
        (and kept in :func:`broken`)."""
        found = ((name, get(name)) for name in self._names)
        return [(name, block_class) for name, block_class in found if block_class is not None]

    def values(self) -> list[type[Block]]:
        return [block_class for _, block_class in self.items()]


def available() -> Mapping[str, type[Block]]:
    """All registered block types, by name (sorted); only the classes looked up are imported."""
    _scan()
    return _Available(sorted({*_registered, *_lazy}))


def broken() -> list[str]:
    """One line per block plugin that failed to import (its blocks are missing from :func:`available`)."""
    _scan()
    return list(_broken.values())


def unknown_block(name: str) -> str:
    """The message for a block type nobody registered, naming the plugins that failed to import."""
    failures = broken()
    return f"unknown block type '{name}'" + (f" ({'; '.join(failures)})" if failures else "")


def origin(name: str) -> str:
    _scan()
    return _origin.get(name, "")


def get(name: str) -> type[Block] | None:
    """The block class of type ``name`` (importing its module if it was declared lazily), or None."""
    _scan()
    if name in _lazy:
        return _resolve(name)
    return _registered.get(name)


def is_builtin(name: str) -> bool:
    cls = get(name)
    return cls is not None and cls.__module__.startswith("evsda.")
