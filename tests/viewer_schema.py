"""What a Foxglove-family viewer's JSON Schema parser (Foxglove Studio's and Lichtblick's
``parseJsonSchema`` in ``packages/mcap-support``) takes of a channel's schema, checked without
one: the root an object with ``properties``; each property ONE ``type`` name (``boolean``,
``string``, ``number``, ``integer``, ``object`` with its own ``properties``, ``array`` of one
of those), or Studio's ``oneOf`` of numeric ``const`` alternatives; a list of types, ``null``,
an ``anyOf`` or a field with no ``type`` makes it refuse, and drop, the whole channel. Keywords
beside ``properties`` (``required``, a root ``oneOf`` of ``required`` lists, ranges, patterns)
are not read by it."""

from __future__ import annotations

from typing import Any

_FIELD_TYPES = {"boolean", "string", "number", "integer", "object", "array"}


def viewer_refuses(schema: dict[str, Any], path: str = "") -> list[str]:
    """Why the viewers' parser (mcap-support's parseJsonSchema) would refuse ``schema``."""
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{path or 'root'}: an object schema needs type object and properties"]
    why: list[str] = []
    for name, field in schema["properties"].items():
        where = f"{path}.{name}" if path else name
        kind = field.get("type")
        kind = kind if isinstance(kind, str) else repr(kind)  # a list of names: refused
        if isinstance(field.get("oneOf"), list):
            if not all(isinstance(a.get("const"), int | float) for a in field["oneOf"]):
                why.append(f"{where}: oneOf of non-numbers")
        elif kind not in _FIELD_TYPES:
            why.append(f"{where}: type {kind!r}")
        elif kind == "object":
            why += viewer_refuses(field, where)
        elif kind == "array":
            item = field.get("items", {})
            if item.get("type") == "object":
                why += viewer_refuses(item, where)
            elif str(item.get("type")) not in _FIELD_TYPES - {"array", "object"}:
                why.append(f"{where}[]: type {item.get('type')!r}")
    return why
