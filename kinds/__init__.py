"""Robot kinds as plug-ins (issue 22): each kind (the NAO, a serial arm) brings its own options and the bodies of the
verbs it supports; the verbs in tools/cmd_*.py find the kind once and run its body (docs/ARCHITECTURE.md).

    kind = kinds.for_args(args, args.dataset)   # --robot, else the data, else the default kind
    return kind.identify(args)

A kind is a module `kinds/<name>/__init__.py` whose KIND satisfies `Kind`, listed in KINDS below. Other robot
kinds (kinds/duckiebot, issue 23) live here too before they are wired into the command line.
"""

from __future__ import annotations

from typing import Protocol

from naocal.kinds import arm, nao


class Kind(Protocol):
    """A robot kind. The per-verb bodies take the parsed arguments and return the exit code; a kind has the bodies of
    the verbs it supports: identify(args), diagnose(args), verify(args), simulate(args), and offsets(args, action,
    out) for `naocal offsets ACTION` (show, diff, validate, export, apply), writing to the text stream `out`."""

    name: str

    def claims(self, source) -> bool:
        """Whether `source` is this kind's: a path (a dataset directory, a calibration file), decided from the data
        (dataset.json's schema, the file's schema), or parsed arguments, decided from options only this kind has
        (an arm's --robot). Never raises: anything unreadable is not claimed."""

    def add_options(self, parser, verb: str) -> None:
        """Add this kind's options of `verb` to its argparse parser (argparse only: `naocal --help` stays instant).
        Every kind adds its options before parsing; the chosen kind refuses another kind's options it was given."""


# The order of asking: the arm first, so that a pair of an arm's file and a NAO's reaches the arm's reader, which
# names the mismatch. DEFAULT reads what no kind claims (its readers name what is wrong with it); its options come
# first in --help.
KINDS: tuple[Kind, ...] = (arm.KIND, nao.KIND)
DEFAULT: Kind = nao.KIND


def add_options(parser, verb: str) -> None:
    """Every kind's options of `verb`, the default kind's first."""
    for kind in (DEFAULT, *(k for k in KINDS if k is not DEFAULT)):
        kind.add_options(parser, verb)


def for_data(*paths) -> Kind:
    """The kind of the data at `paths` (the first kind claiming any of them), else DEFAULT."""
    for kind in KINDS:
        if any(kind.claims(str(path)) for path in paths if path is not None):
            return kind
    return DEFAULT


def for_args(args, *paths) -> Kind:
    """The kind the options in `args` ask for (an arm's --robot), else that of the data at `paths` (`for_data`)."""
    for kind in KINDS:
        if kind.claims(args):
            return kind
    return for_data(*paths)
