"""B-Human's configuration syntax (also Nao Devils'), parsed with the position of every value so that a merge can
replace single values in the team's text and leave every other byte (comments, layout, number formats) alone.

Syntax (B-Human's `InMapFile`): a file is a list of fields `key = value;`; a value is a literal (`0.62deg`,
`true`, `"a string"`), a record `{ key = value; ... }` or an array `[ value, value ]`; `//` and `/* */` are comments.
The `;` after a record or an array is optional here, as it is in B-Human's files.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from naocal.solver.errors import DataError

_TOKEN = re.compile(r"""
    (?P<space>\s+|//[^\n]*|/\*.*?\*/)
  | (?P<punct>[{}\[\]=;,])
  | (?P<string>"(?:[^"\\\n]|\\.)*")
  | (?P<word>(?:[^\s{}\[\]=;,"/]|/(?![/*]))+)
""", re.VERBOSE | re.DOTALL)


@dataclass
class CfgValue:
    """A value and its span text[start:end]. kind: 'literal', 'record' (fields) or 'array' (items)."""

    kind: str
    start: int
    end: int
    text: str = ""
    fields: dict[str, CfgValue] = field(default_factory=dict)
    items: list[CfgValue] = field(default_factory=list)


def _line(text: str, position: int) -> int:
    return text.count("\n", 0, position) + 1


def _tokens(text: str, path):
    position = 0
    while position < len(text):
        match = _TOKEN.match(text, position)
        if match is None:
            what = "unterminated comment" if text.startswith("/*", position) else \
                "unterminated string" if text[position] == '"' else f"unexpected character {text[position]!r}"
            raise DataError(path, what, line=_line(text, position))
        if match.lastgroup != "space":
            yield match.lastgroup, match.group(), match.start()
        position = match.end()


def parse_cfg(text: str, path) -> CfgValue:
    """The file as a record (kind 'record', span the whole text); DataError naming the line for bad syntax."""
    tokens = list(_tokens(text, path))
    tokens.append(("end", "", len(text)))
    position = 0

    def fail(problem, at):
        raise DataError(path, problem, line=_line(text, tokens[at][2]) if at < len(tokens) else None)

    def value():
        nonlocal position
        kind, token, start = tokens[position]
        if token == "{":
            position += 1
            fields = record_fields("}")
            end = tokens[position][2] + 1
            position += 1
            return CfgValue("record", start, end, fields=fields)
        if token == "[":
            position += 1
            items = []
            while tokens[position][1] != "]":
                if tokens[position][0] == "end":
                    fail("unterminated array: missing ']'", position)
                items.append(value())
                if tokens[position][1] == ",":
                    position += 1
                elif tokens[position][1] != "]":
                    fail(f"expected ',' or ']', got {tokens[position][1]!r}", position)
            end = tokens[position][2] + 1
            position += 1
            return CfgValue("array", start, end, items=items)
        if kind in ("word", "string"):
            position += 1
            return CfgValue("literal", start, start + len(token), text=token)
        fail(f"expected a value, got {token or 'the end of the file'!r}", position)

    def at_close(closing):
        kind, token, _ = tokens[position]
        return kind == "end" if closing == "" else (kind == "punct" and token == closing)

    def record_fields(closing):
        nonlocal position
        fields = {}
        while not at_close(closing):
            kind, key, _ = tokens[position]
            if kind == "end":
                fail("unterminated record: missing '}'", position)
            if kind != "word":
                fail(f"expected a key, got {key!r}", position)
            if key in fields:
                fail(f"key {key!r} appears twice", position)
            if tokens[position + 1][1] != "=":
                fail(f"expected '=' after {key!r}", position + 1)
            position += 2
            fields[key] = value()
            if tokens[position][1] == ";":
                position += 1
            elif fields[key].kind == "literal" and not at_close(closing):  # named at the value, not the next line
                raise DataError(path, f"expected ';' after the value of {key!r}", line=_line(text, fields[key].end))
        return fields

    fields = record_fields("")
    return CfgValue("record", 0, len(text), fields=fields)


def lookup(root: CfgValue, keys) -> CfgValue | None:
    """The value at the key path (e.g. ('offsets', 'lHipPitch')), or None where a key is absent."""
    node = root
    for key in keys:
        if node.kind != "record" or key not in node.fields:
            return None
        node = node.fields[key]
    return node


def literals(node: CfgValue, prefix=()) -> dict[tuple, str]:
    """{key path: literal text} of every literal below `node` (array items by index)."""
    if node.kind == "literal":
        return {prefix: node.text}
    children = node.fields.items() if node.kind == "record" else enumerate(node.items)
    flat = {}
    for key, child in children:
        flat.update(literals(child, prefix + (key,)))
    return flat


def replace_literals(text: str, root: CfgValue, new_values: dict[tuple, str], path) -> str:
    """`text` with the literals at the given key paths replaced, every other byte kept.

    The result is parsed again and must differ from the original in exactly those literals (a check of this
    editor, not of the input)."""
    edits = []
    for keys, literal in new_values.items():
        node = lookup(root, keys)
        if node is None or node.kind != "literal":
            raise DataError(path, "missing value (naocal replaces values, it does not add keys)",
                            field=".".join(map(str, keys)))
        edits.append((node.start, node.end, literal))
    for start, end, literal in sorted(edits, reverse=True):
        text = text[:start] + literal + text[end:]
    before, after = literals(root), literals(parse_cfg(text, path))
    expected = {**before, **new_values}
    if after != expected:
        raise AssertionError(f"{path}: the merge changed more than the calibrated values")
    return text
