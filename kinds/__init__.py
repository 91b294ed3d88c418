"""Robot kinds as plug-ins (issue 22): each kind (the NAO, a serial arm, the Duckiebot) brings its own options and
the bodies of the verbs it supports; the verbs in tools/cmd_*.py find the kind once and run its body
(docs/ARCHITECTURE.md).

    kind = kinds.for_args(args, args.dataset)   # --robot, else the data, else the default kind
    return kind.identify(args)

A kind is a subpackage `kinds/<name>/` whose `__init__.py` defines KIND (satisfying `Kind`): the registry finds
every such subpackage of this package (`registered()`), so adding a kind is adding a folder. A kind's __init__ is
imported while the command line is built: argparse only there, heavy imports inside the verb bodies.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Protocol

# The verbs whose bodies a kind may have (a kind has those it supports; `capable` lists the kinds with one).
VERBS = ("calibrate", "identify", "diagnose", "verify", "simulate", "offsets")


class Kind(Protocol):
    """A robot kind. The per-verb bodies take the parsed arguments and return the exit code; a kind has the bodies of
    the verbs it supports: calibrate(args), identify(args), diagnose(args), verify(args), simulate(args), and
    offsets(args, action, out) for `naocal offsets ACTION` (show, diff, validate, export, apply), writing to the
    text stream `out`."""

    name: str
    rank: int  # the order of asking: lower first; the highest rank is the default kind (the NAO)
    # What the verbs' common --help says of this kind (help_by_kind): its data (identify's, diagnose's and verify's
    # DATASET), its calibration file (identify --out, verify --offsets) and what identify fits by default.
    data_help: str
    calibration_help: str
    model_help: str
    # Optional: True when its verify finds the calibration without --offsets (the Duckiebot's, in Duckietown's
    # calibrations directory); without it, `naocal verify` without --offsets is a usage error (tools/cmd_verify.py).
    # verify_finds_calibration: bool, and verify_help: str (what its verify does, for `naocal verify --help`);
    # offsets_help: str (its files in `naocal offsets --help`, when they are not the default kind's)
    # What the effect registry (solver/effects/) has for its model, for identify's and diagnose's --effects (a
    # property: it reads the registry when --help is built); what diagnose's --help says of its output: the sections
    # it prints (help_blocks_by_kind) and its --json object.
    effects_help: str
    diagnose_help: str
    diagnose_json_help: str

    def claims(self, source) -> bool:
        """Whether `source` is this kind's: a path (a dataset directory, a calibration file), decided from the data
        (dataset.json's schema, the file's schema), or parsed arguments, decided from options only this kind has
        (an arm's --robot). Never raises: anything unreadable is not claimed."""

    def add_options(self, parser, verb: str) -> None:
        """Add this kind's options of `verb` to its argparse parser (argparse only: `naocal --help` stays instant).
        Every kind adds its options before parsing; the chosen kind refuses another kind's options it was given."""


_FOUND: dict[tuple, tuple] = {}  # this package's __path__ -> the kinds found on it


def registered() -> tuple[Kind, ...]:
    """Every kind, in the order of asking (by rank, then name). Found once per __path__ (a directory listing; each
    kind's __init__ is imported once): a kind put on this package's __path__ is found, and a process that may no
    longer list the checkout (a verb run after dropping privileges) keeps the kinds it found."""
    key = tuple(__path__)
    if key not in _FOUND:
        found = {}
        for info in pkgutil.iter_modules(__path__, __name__ + "."):
            if info.ispkg:
                kind = getattr(importlib.import_module(info.name), "KIND", None)
                if kind is not None:
                    found.setdefault(kind.name, kind)  # the first on __path__ of a name wins, as for any import
        _FOUND[key] = tuple(sorted(found.values(), key=lambda k: (k.rank, k.name)))
    return _FOUND[key]


def default() -> Kind:
    """The kind that reads what no kind claims (its readers name what is wrong with it): the last asked."""
    return registered()[-1]


def capable(verb: str) -> tuple[Kind, ...]:
    """The kinds that have a body for `verb`, in the order of asking."""
    return tuple(k for k in registered() if callable(getattr(k, verb, None)))


def named(name: str) -> Kind:
    """The kind called `name` (KeyError if none is)."""
    for kind in registered():
        if kind.name == name:
            return kind
    raise KeyError(name)


def _helping(attribute: str, verb: str) -> list:
    """[(kind, its text)] of the kinds with a body for `verb` that say something in `attribute`, the default first."""
    kinds = capable(verb)
    ordered = [k for k in kinds if k is default()] + [k for k in kinds if k is not default()]
    return [(k, getattr(k, attribute, "")) for k in ordered if getattr(k, attribute, "")]


def help_by_kind(attribute: str, verb: str) -> str:
    """For a verb's --help: what each kind with a body for `verb` says in `attribute` (data_help, calibration_help,
    model_help, effects_help, diagnose_json_help), the default kind first: 'nao: ...; arm: ...'."""
    return "; ".join(f"{k.name}: {text}" for k, text in _helping(attribute, verb))


def help_blocks_by_kind(attribute: str, verb: str) -> str:
    """For a verb's --help epilog: each kind's text of several lines (diagnose_help) under its name, indented."""
    return "\n".join(f"{k.name}:\n" + "\n".join("  " + line if line else line for line in text.splitlines())
                     for k, text in _helping(attribute, verb))


def export_formats() -> tuple[str, ...]:
    """Every format `naocal offsets export --format` takes: each kind's `export_formats`, the default kind's first.
    The kind of the file exported refuses the formats that are not its own."""
    kinds = registered()
    formats = [f for kind in (kinds[-1], *kinds[:-1]) for f in getattr(kind, "export_formats", ())]
    return tuple(dict.fromkeys(formats))


def add_options(parser, verb: str) -> None:
    """Every kind's options of `verb`, the default kind's first (its options come first in --help). Which options
    each kind added is kept in the parsed arguments (`kind_options`) for `foreign_options`."""
    kinds = registered()
    owners = {}
    for kind in (kinds[-1], *kinds[:-1]):
        before = {a.dest for a in parser._actions}
        kind.add_options(parser, verb)
        owners[kind.name] = {a.dest: (a.option_strings[0] if a.option_strings else a.dest, a.default)
                             for a in parser._actions if a.dest not in before}
    parser.set_defaults(kind_options=owners)


def foreign_options(args, kind: Kind) -> list[str]:
    """The options of other kinds given in `args` (their value not the default), as written on the command line:
    what `kind` must refuse."""
    given = []
    for owner, options in getattr(args, "kind_options", {}).items():
        if owner != kind.name:
            given += [flag for dest, (flag, default) in options.items() if getattr(args, dest, default) != default]
    return given


def json_schema(path):
    """The "schema" of the JSON file `path`, None if it is not a readable JSON object (for a kind's `claims`: never
    raises)."""
    from naocal.solver.errors import DataError
    from naocal.solver.fileio import read_json

    try:  # read_json: regular files only (a FIFO must not block the check), size capped
        doc = read_json(path)
    except DataError:
        return None
    return doc.get("schema") if isinstance(doc, dict) else None


def for_data(*paths) -> Kind:
    """The kind of the data at `paths` (the first kind claiming any of them), else the default kind."""
    kinds = registered()
    for kind in kinds:
        if any(kind.claims(str(path)) for path in paths if path is not None):
            return kind
    return kinds[-1]


def for_args(args, *paths) -> Kind:
    """The kind the options in `args` ask for (an arm's --robot, `--robot duckiebot`), else that of the data at
    `paths` (`for_data`)."""
    for kind in registered():
        if kind.claims(args):
            return kind
    return for_data(*paths)
