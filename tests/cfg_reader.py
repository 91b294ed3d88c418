"""A small reader of B-Human's configuration syntax for the export tests, written from the format (records
`key = value;` and `key = { ... };`, `//` and `/* */` comments), independent of tools/export/cfgtext.py."""

import math
import re


def parse_cfg(text: str) -> dict:
    text = re.sub(r"//[^\n]*|/\*.*?\*/", " ", text, flags=re.S)
    tokens = re.findall(r"[{}=;]|[^\s{}=;]+", text)
    position = 0

    def record(closing):
        nonlocal position
        fields = {}
        while tokens[position] != closing:
            key, equals = tokens[position], tokens[position + 1]
            assert equals == "=" and key not in fields, (key, equals)
            position += 2
            if tokens[position] == "{":
                position += 1
                fields[key] = record("}")  # consumes the closing brace
            else:
                fields[key] = tokens[position]
                position += 1
            if tokens[position] == ";":
                position += 1
            else:
                assert tokens[position] == closing, tokens[position]
        position += 1
        return fields

    tokens.append("<end>")
    return record("<end>")


def rad(literal: str) -> float:
    """An angle literal in rad: '-3.5deg' (degrees) or a plain number (radians), as B-Human reads them."""
    if literal.endswith("deg"):
        return math.radians(float(literal[:-3]))
    return float(literal)
