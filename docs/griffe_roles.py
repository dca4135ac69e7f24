"""Griffe extension: the docstrings' Sphinx roles become checked cross-references.

evsda's docstrings name other objects as Sphinx does (``:class:`Block```, ``:mod:`.paths```,
``:func:`~evsda.graph.checks.run```). Each role is resolved much as Sphinx resolves it: the name
itself, then in the enclosing class, module and package (a leading ``.`` first relative to the
package), then as the unique object of evsda whose path ends with it; ``~`` shows the last
component. A public object becomes an mkdocstrings cross-reference to its path, a private one
(not in the reference) is shown as code. A name of evsda that resolves to nothing is still written
as a cross-reference, so the strict build fails on it; a dotted name outside evsda
(``matplotlib.figure.Figure``) is shown as code. A reST ``::`` before a literal block becomes ``:``
(the indented block is code in Markdown too).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:mod|class|func|meth|attr|data|exc|obj|const):`(~?)([\w.]+)`")
#: a paragraph ending in ``::`` introduces a literal block (reST); Markdown shows the block as code
LITERAL = re.compile(r"::\n\n")


def _objects(obj: griffe.Object) -> dict[str, griffe.Object]:
    """Every object defined in ``obj`` (aliases left out), by path."""
    found = {obj.path: obj}
    for member in obj.members.values():
        if not member.is_alias:
            found.update(_objects(member))
    return found


def _scopes(obj: griffe.Object) -> list[str]:
    """Where a short name is looked for: the object, its parents up to its module, then its package."""
    scopes, current = [], obj
    while current is not None:
        scopes.append(current.path)
        if current.is_module:
            break
        current = current.parent
    module = obj if obj.is_module else obj.module
    if module.parent is not None and not module.is_init_module:
        scopes.append(module.parent.path)
    return scopes


class SphinxRoles(griffe.Extension):
    """Rewrite ``:role:`name``` in every docstring of a loaded package as a cross-reference."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        self.collection = loader.modules_collection
        self.objects = _objects(pkg)
        for obj in list(self.objects.values()):
            if obj.docstring is not None:
                text = ROLE.sub(lambda match: self._reference(obj, match), obj.docstring.value)
                obj.docstring.value = LITERAL.sub(":\n\n", text)

    def _find(self, path: str) -> griffe.Object | None:
        """The object at ``path``, following an import to where it is defined."""
        try:
            found = self.collection.get_member(path)
            return found.final_target if found.is_alias else found
        except (KeyError, ValueError, griffe.AliasResolutionError, griffe.CyclicAliasError):
            return None

    def _resolve(self, obj: griffe.Object, name: str) -> griffe.Object | None:
        module = obj if obj.is_module else obj.module
        package = module if module.is_init_module else module.parent
        exact = [f"{package.path}{name}"] if name.startswith(".") and package is not None else []
        exact += [name, *(f"{scope}.{name}" for scope in _scopes(obj))] if not name.startswith(".") else []
        for candidate in exact:
            if (found := self._find(candidate)) is not None:
                return found
        suffix = name if name.startswith(".") else f".{name}"
        matches = [o for path, o in self.objects.items() if path.endswith(suffix)]
        in_module = [o for o in matches if o.module is module]
        for group in (in_module, matches):
            if len(group) == 1:
                return group[0]
        return None

    def _reference(self, obj: griffe.Object, match: re.Match) -> str:
        short, name = match.group(1) == "~", match.group(2)
        shown = name.rsplit(".", 1)[-1] if short else name.lstrip(".")
        target = self._resolve(obj, name)
        if target is None:
            outside = "." in name and not name.startswith((".", "evsda."))
            return f"`{shown}`" if outside else f"[`{shown}`][{name}]"
        if any(part.startswith("_") and part != "__init__" for part in target.path.split(".")):
            return f"`{shown}`"
        return f"[`{shown}`][{target.path}]"
