"""The checks every file reader makes of one field: one home, one message style (docs/FORMATS.md).

A reader parses its file (solver.fileio: JSON, CSV, text) and checks each field with these. A refusal is one
DataError naming the file, the line where the format has lines, and the field:

    FILE[, line N], field 'FIELD': expected <what it must be>, got <what it is>     (the wrong kind of value)
    FILE[, line N], field 'FIELD': must be <range>, got <value>                     (a value out of its range)

`field` is the field's path in the document (`cameras.bottom.fx_px`, `joints[3]`; "" or None: the document
itself), or a CSV column's name. Each check returns the value checked (a number as float), so a reader reads
`fx = fields.number(cam["fx_px"], path, "cameras.bottom.fx_px", positive=True)`.
"""

from __future__ import annotations

import math

from naocal.solver.errors import DataError

MAX_COUNT = 2 ** 53  # the largest integer a JSON reader (a double) holds exactly


def fail(path, problem, field=None, line=None):
    """Raise the DataError of a refused field (see the module docstring)."""
    raise DataError(path, problem, field=field or None, line=line)


def shown(value, max_chars: int = 40) -> str:
    """`value` as a message quotes it: its repr, cut to `max_chars` (a field may hold a megabyte)."""
    text = repr(value)
    return text if len(text) <= max_chars else text[:max_chars - 3] + "..."


def _interval(low, high, open_low) -> str:
    if high == math.inf:
        return "be positive" if low == 0 and open_low else "not be negative" if low == 0 else \
            f"be {'above' if open_low else 'at least'} {low:g}"
    if low == -math.inf:
        return f"be at most {high:g}"
    return f"be within {'(' if open_low else '['}{low:g}, {high:g}]"


def number(value, path, field, *, low=-math.inf, high=math.inf, open_low=False, positive=False,
           non_negative=False, integer=False, limit=None, unit="1", line=None) -> float:
    """A finite JSON number (not a boolean), as float; refused unless within [low, high] (`open_low`: (low, high];
    `positive`: (0, inf); `non_negative`: [0, inf)), a whole number when `integer` (3.0 is one), and at most `limit`
    in size. `limit` is the bound of a plausible value in `unit`: the message then says which mix-up is likely
    (degrees for radians, mm for m)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(path, f"expected a finite number, got {shown(value)}", field, line)
    if positive or non_negative:
        low, open_low = max(low, 0.0), open_low or positive
    if value < low or (open_low and value == low) or value > high:
        fail(path, f"must {_interval(low, high, open_low)}, got {value!r}", field, line)
    if integer and value != int(value):
        fail(path, f"expected a whole number, got {value!r}", field, line)
    if limit is not None and abs(value) > limit:
        fail(path, implausible(value, limit, unit), field, line)
    return float(value)


def implausible(value: float, limit: float, unit: str) -> str:
    """What is wrong with a value of `unit` beyond the plausible `limit`, and the likely unit mix-up."""
    if unit == "rad":
        return (f"implausible size {math.degrees(value):.3f} deg (limit +-{math.degrees(limit):g} deg); is it in "
                "degrees instead of radians?")
    if unit == "m":
        return f"implausible size {value:g} m (limit +-{limit:g} m); is it in mm instead of m?"
    return f"implausible size {value:g}{'' if unit == '1' else ' ' + unit} (limit +-{limit:g})"


def count(value, path, field, low: int = 0, high: int = MAX_COUNT, *, line=None) -> int:
    """A JSON integer (not a boolean, not 3.0) from `low` to `high`."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        span = f"at least {low}" if high == MAX_COUNT else f"from {low} to {high}"
        fail(path, f"expected a whole number {span}, got {shown(value)}", field, line)
    return value


def number_text(text, path, field, *, line=None, **limits) -> float:
    """The finite number a text holds (a CSV cell, a YAML scalar), checked as `number` with `limits`."""
    # Python's float() also reads '1_000' and other scripts' digits ('\u0663'): no file writes those as numbers
    plain = isinstance(text, str) and len(text) <= 100 and text.isascii() and "_" not in text
    try:
        value = float(text) if plain else None
    except ValueError:
        value = None
    if value is None or not math.isfinite(value):
        fail(path, f"expected a finite number, got {shown(text)}", field, line)
    return number(value, path, field, line=line, **limits)


def count_text(text, path, field, low: int = 0, high: int = MAX_COUNT, *, line=None) -> int:
    """The whole number a text holds in decimal digits (a CSV cell, a YAML scalar), from `low` to `high`."""
    if (not isinstance(text, str) or not (text.isascii() and text.isdigit()) or len(text) > 20
            or not low <= int(text) <= high):
        span = f"at least {low}" if high == MAX_COUNT else f"from {low} to {high}"
        fail(path, f"expected a whole number {span}, got {shown(text)}", field, line)
    return int(text)


def vector(value, n, path, field, *, from_text: bool = False, **limits) -> tuple:
    """A list of `n` numbers (`n` a tuple: any of those lengths), each checked as `number` with `limits`
    (`from_text`: each a text holding a number, as number_text: a YAML list)."""
    lengths = n if isinstance(n, tuple) else (n,)
    if not isinstance(value, list) or len(value) not in lengths:
        fail(path, f"expected a list of {' or '.join(map(str, lengths))} numbers, got {shown(value)}", field)
    check = number_text if from_text else number
    return tuple(check(v, path, f"{field}[{i}]", **limits) for i, v in enumerate(value))


def names(value, path, field, *, what: str = "names", non_empty: bool = False) -> tuple:
    """A list of distinct non-empty strings (at least one when `non_empty`)."""
    if not isinstance(value, list) or (non_empty and not value) or not all(isinstance(v, str) and v for v in value):
        fail(path, f"expected a list of {what}{' (at least one)' if non_empty else ''}, got {shown(value)}", field)
    if len(set(value)) != len(value):
        twice = next(v for i, v in enumerate(value) if v in value[:i])
        fail(path, f"expected a list of {what}, each once; {shown(twice)} is listed twice", field)
    return tuple(value)


def text(value, path, field, *, max_chars: int | None = None, non_empty: bool = False,
         one_line: bool = True) -> str:
    """A string of at most `max_chars` characters; `one_line`: printable, no line break or control character (text
    that another program's config file or a one-line message will hold); `non_empty`: not ""."""
    if not isinstance(value, str) or (max_chars is not None and len(value) > max_chars) \
            or (non_empty and not value) or (one_line and not value.isprintable()):
        kind = {(True, False): "a single line of printable text", (True, True): "a non-empty single line of printable "
                "text", (False, False): "text", (False, True): "non-empty text"}[(one_line, non_empty)]
        most = "" if max_chars is None else f" (at most {max_chars} characters)"
        fail(path, f"expected {kind}{most}, got {shown(value)}", field)
    return value


def json_object(value, path, field, required=(), optional=None, *, keys: str = "field") -> dict:
    """A JSON object with every `required` key and no key outside `required` + `optional` (None: any key); `keys`
    says what its keys are (a joint, a camera) in the message naming one that is not allowed."""
    def inner(key):
        return f"{field}.{key}" if field else key

    if not isinstance(value, dict):
        fail(path, f"expected a JSON object, got {shown(value)}", field)
    if optional is not None:
        allowed = tuple(dict.fromkeys((*required, *optional)))
        for key in value:
            if key not in allowed:
                fail(path, f"unknown {keys} (allowed: {', '.join(allowed)})", inner(key))
    for key in required:
        if key not in value:
            fail(path, "missing required field", inner(key))
    return value


def flag(value, path, field) -> bool:
    """A JSON true or false."""
    if not isinstance(value, bool):
        fail(path, f"expected true or false, got {shown(value)}", field)
    return value


def choice(value, choices, path, field) -> str:
    """One of the names `choices`."""
    if not isinstance(value, str) or value not in choices:
        fail(path, f"expected one of {', '.join(choices)}, got {shown(value)}", field)
    return value
