"""JSON Schemas for graph files and block parameters, generated from the pydantic models.

``schema/graph.schema.json`` validates a whole graph file, with each block's
``params`` checked against its type's schema; ``schema/blocks/<type>.schema.json``
holds each built-in block's parameters on its own. Editors that speak JSON Schema
(e.g. VS Code's YAML extension) use them for completion and checking::

    # yaml-language-server: $schema=../schema/graph.schema.json
"""

from __future__ import annotations

import json
from pathlib import Path

from . import registry
from .reading import GraphFile

GRAPH_SCHEMA = "graph.schema.json"
BLOCKS_DIR = "blocks"
SCHEMA_ID = "https://evsda.invalid/schema/"


def block_schema(name: str) -> dict:
    """The JSON Schema of one block type's parameters."""
    cls = registry.get(name)
    schema = cls.Params.model_json_schema()
    schema["title"] = f"{name} parameters"
    schema["description"] = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else name
    return schema


def graph_schema(block_names: list[str]) -> dict:
    """The JSON Schema of a graph file whose blocks are of the given types."""
    schema = GraphFile.model_json_schema(by_alias=True)
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = SCHEMA_ID + GRAPH_SCHEMA
    defs = schema.setdefault("$defs", {})
    entry = defs["BlockEntry"]
    entry["properties"]["type"]["enum"] = list(block_names)
    rules = []
    for name in block_names:
        params = block_schema(name)
        for key, value in params.pop("$defs", {}).items():
            defs[f"{name}__{key}"] = value
        text = json.dumps(params).replace('"#/$defs/', f'"#/$defs/{name}__')
        defs[f"params__{name}"] = json.loads(text)
        rules.append({
            "if": {"properties": {"type": {"const": name}}, "required": ["type"]},
            "then": {"properties": {"params": {"$ref": f"#/$defs/params__{name}"}}},
        })
    entry["allOf"] = rules
    return schema


def render_all() -> dict[str, str]:
    """Every schema file (relative path -> text) for the built-in blocks."""
    names = [n for n in registry.available() if registry.is_builtin(n)]
    files = {GRAPH_SCHEMA: graph_schema(names)}
    for name in names:
        files[f"{BLOCKS_DIR}/{name}.schema.json"] = block_schema(name)
    return {path: json.dumps(doc, indent=2, sort_keys=True) + "\n" for path, doc in files.items()}


def write(directory: Path) -> list[str]:
    """Regenerate ``directory``; returns the files written."""
    files = render_all()
    (directory / BLOCKS_DIR).mkdir(parents=True, exist_ok=True)
    for stale in (directory / BLOCKS_DIR).glob("*.schema.json"):
        if f"{BLOCKS_DIR}/{stale.name}" not in files:
            stale.unlink()
    for path, text in files.items():
        (directory / path).write_text(text)
    return sorted(files)


def stale(directory: Path) -> list[str]:
    """Files in ``directory`` that differ from what :func:`write` would produce."""
    files = render_all()
    problems = []
    for path, text in files.items():
        target = directory / path
        if not target.exists():
            problems.append(f"{target} is missing")
        elif target.read_text() != text:
            problems.append(f"{target} is out of date")
    for extra in sorted((directory / BLOCKS_DIR).glob("*.schema.json")):
        if f"{BLOCKS_DIR}/{extra.name}" not in files:
            problems.append(f"{extra} belongs to no block")
    return problems
