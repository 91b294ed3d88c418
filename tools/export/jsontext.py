"""JSON parsed with the position of every value, so that a merge sets single values in a team's file and keeps every
other byte (key order, indentation, number formats) as it was. HULKs' parameter files are plain JSON (serde_json).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

from naocal.solver import fields
from naocal.solver.errors import DataError

_NUMBER = re.compile(r"-?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?")
_STRING = re.compile(r'"(?:[^"\\\x00-\x1f]|\\(?:["\\/bfnrt]|u[0-9a-fA-F]{4}))*"')
_SPACE = re.compile(r"[ \t\r\n]*")
MAX_DEPTH = 64  # parameter files nest a handful of levels; deeper is damage, and must not exhaust the stack


@dataclass
class JsonNode:
    """A value and its span text[start:end]. kind: 'object' (members, key -> node), 'array' or 'scalar'."""

    kind: str
    start: int
    end: int
    members: dict[str, JsonNode] = field(default_factory=dict)
    key_starts: dict[str, int] = field(default_factory=dict)


def _line(text: str, position: int) -> int:
    return text.count("\n", 0, position) + 1


def parse_json(text: str, path) -> tuple[JsonNode, object]:
    """(span tree, the parsed document); DataError naming the line for invalid JSON or a repeated key."""
    position = 0

    def fail(problem):
        if position >= len(text):
            problem = "unexpected end of file (truncated?)"
        raise DataError(path, f"invalid JSON: {problem}", line=_line(text, position))

    def skip():
        nonlocal position
        position = _SPACE.match(text, position).end()

    def value(depth):
        nonlocal position
        if depth > MAX_DEPTH:
            fail(f"nested deeper than {MAX_DEPTH} levels")
        skip()
        start = position
        char = text[position:position + 1]
        if char == "{":
            position += 1
            node = JsonNode("object", start, start)
            skip()
            if text[position:position + 1] == "}":
                position += 1
            else:
                while True:
                    skip()
                    match = _STRING.match(text, position)
                    if match is None:
                        fail("expected a string key")
                    key = json.loads(match.group())
                    if key in node.members:
                        fail(f"key {key!r} appears twice")
                    node.key_starts[key] = position
                    position = match.end()
                    skip()
                    if text[position:position + 1] != ":":
                        fail("expected ':'")
                    position += 1
                    node.members[key] = value(depth + 1)
                    skip()
                    char = text[position:position + 1]
                    position += 1
                    if char == "}":
                        break
                    if char != ",":
                        position -= 1
                        fail("expected ',' or '}'")
            node.end = position
            return node
        if char == "[":
            position += 1
            skip()
            if text[position:position + 1] == "]":
                position += 1
            else:
                while True:
                    value(depth + 1)
                    skip()
                    char = text[position:position + 1]
                    position += 1
                    if char == "]":
                        break
                    if char != ",":
                        position -= 1
                        fail("expected ',' or ']'")
            return JsonNode("array", start, position)
        for pattern in (_STRING, _NUMBER):
            match = pattern.match(text, position)
            if match:
                position = match.end()
                return JsonNode("scalar", start, position)
        for word in ("true", "false", "null"):
            if text.startswith(word, position):
                position += len(word)
                return JsonNode("scalar", start, position)
        fail("unexpected end of file" if position >= len(text) else f"unexpected character {char!r}")

    root = value(0)
    skip()
    if position != len(text):
        fail("text after the document")
    try:
        document = json.loads(text)
    except ValueError as err:  # e.g. an integer beyond Python's digit limit
        raise DataError(path, f"invalid JSON: {err}") from None
    return root, fields.json_object(document, path, "")


def _indent_of(text: str, position: int) -> str:
    line_start = text.rfind("\n", 0, position) + 1
    return re.match(r"[ \t]*", text[line_start:]).group()


def _nested(value, indent: str) -> str:
    """JSON text of `value` for a position whose line is indented by `indent` (two more spaces per level)."""
    return json.dumps(value, indent=2, allow_nan=False).replace("\n", "\n" + indent)


def set_values(text: str, new_values: dict[tuple, object], path) -> str:
    """`text` with the values at the key paths set (members added where absent), every other byte kept.

    The result must parse to the original document with exactly these values set (a check of this editor)."""
    root, expected = parse_json(text, path)
    for keys, value in new_values.items():
        node, where = root, []
        for depth, key in enumerate(keys):
            if node.kind != "object":
                fields.json_object(json.loads(text[node.start:node.end]), path, ".".join(where))  # refuses it
            if key not in node.members:
                text = _insert_member(text, node, keys[depth:], value)
                break
            node, where = node.members[key], where + [key]
        else:  # a value laid out over several lines stays so, indented like its key
            multi_line = "\n" in text[node.start:node.end]
            new = _nested(value, _indent_of(text, node.start)) if multi_line else json.dumps(value, allow_nan=False)
            text = text[:node.start] + new + text[node.end:]
        root, _ = parse_json(text, path)
        target = expected
        for key in keys[:-1]:
            target = target.setdefault(key, {})
        target[keys[-1]] = value
    if json.loads(text) != expected:
        raise AssertionError(f"{path}: the merge changed more than the calibrated values")
    return text


def _insert_member(text: str, node: JsonNode, keys: tuple, value) -> str:
    """Add "keys[0]": {keys[1]: ... value} to the object `node`, indented like its other members."""
    for key in reversed(keys[1:]):
        value = {key: value}
    if node.members:
        last_key = list(node.members)[-1]
        last = node.members[last_key]
        key_start = node.key_starts[last_key]
        if "\n" in text[node.start:key_start]:
            indent = _indent_of(text, key_start)
            member = f",\n{indent}{json.dumps(keys[0])}: {_nested(value, indent)}"
        else:
            member = f", {json.dumps(keys[0])}: {json.dumps(value, allow_nan=False)}"
        return text[:last.end] + member + text[last.end:]
    outer = _indent_of(text, node.start)
    indent = outer + "  "
    body = f"{{\n{indent}{json.dumps(keys[0])}: {_nested(value, indent)}\n{outer}}}"
    return text[:node.start] + body + text[node.end:]
