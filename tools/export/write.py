"""`naocal offsets export`: build every file first, then write them atomically, each replaced file kept as NAME.bak,
under a lock on the output directory so that two exports cannot interleave a merge's read and write."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import sys
from pathlib import Path, PurePosixPath

from naocal.solver.errors import DataError, NaocalError
from naocal.tools.export import TEAM_FORMATS
from naocal.tools.export.common import ExportFile, calibrated

BACKUP_SUFFIX = ".bak"


def build(args, offsets) -> list[ExportFile]:
    """The export's files (nothing written yet)."""
    source_name = Path(args.file).name
    if args.format not in TEAM_FORMATS:
        for option in ("merge_from", "head_id", "body_id", "bhuman_release"):
            if getattr(args, option) is not None:
                raise NaocalError(f"--{option.replace('_', '-')} applies to the team formats "
                                  f"({', '.join(TEAM_FORMATS)}), not to {args.format}")
    if args.bhuman_release is not None and args.format != "bhuman":
        raise NaocalError("--bhuman-release applies to --format bhuman only")
    merge_from = None
    if args.merge_from is not None:
        merge_from = Path(args.merge_from)
        if not merge_from.is_dir():
            raise DataError(merge_from, "--merge-from must be a directory (the team's Config or etc/parameters)")
    cal = calibrated(offsets)
    head = args.head_id if args.head_id is not None else cal.robot.get("head_id")
    body = args.body_id if args.body_id is not None else cal.robot.get("body_id")
    if args.format == "bhuman":
        from naocal.tools.export.bhuman import export_bhuman

        return export_bhuman(cal, source_name, head=head, body=body, release=args.bhuman_release,
                             merge_from=merge_from)
    if args.format == "naodevils":
        from naocal.tools.export.naodevils import export_naodevils

        return export_naodevils(cal, source_name, head=head, body=body, merge_from=merge_from)
    if args.format == "hulks":
        from naocal.tools.export.hulks import export_hulks

        return export_hulks(cal, head=head, body=body, merge_from=merge_from)
    from naocal.tools.export import urdf

    if args.format == "urdf":
        nominal = args.nominal_urdf or urdf.NOMINAL_URDF
        return [ExportFile("calibrated.urdf", urdf.export_urdf(offsets, nominal, strip_meshes=args.strip_meshes,
                                                              source_name=source_name))]
    return [ExportFile("offsets.json", urdf.export_json(offsets))]


@contextlib.contextmanager
def locked(directory: Path):
    """An exclusive lock on `directory` (or, while it does not exist, its nearest existing parent), released by the
    OS if naocal dies; a second export into the same place is refused at once."""
    while not directory.exists() and directory != directory.parent:
        directory = directory.parent
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError as err:
        raise DataError(directory, f"cannot open: {err.strerror or err}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise NaocalError(f"{directory}: another naocal export is writing here; try again when it is done") \
                    from None
            raise
        yield
    finally:
        os.close(fd)


def export_target(out: Path, relative: str, single_file: bool) -> Path:
    if single_file:
        if out.is_dir():
            raise DataError(out, "--out is a directory; give a file name")
        return out
    parts = PurePosixPath(relative).parts
    if PurePosixPath(relative).is_absolute() or any(part in ("", ".", "..") for part in parts):
        raise NaocalError(f"refusing to write outside --out: {relative!r}")  # ids are checked: a bug if reached
    target = out.joinpath(*parts)
    for parent in reversed(target.parents):
        if parent.exists() and not parent.is_dir():
            raise DataError(parent, "exists and is not a directory")
    return target


def write_export(target: Path, text: str) -> str:
    from naocal.solver.fileio import atomic_write_text

    previous = None
    if target.exists():
        if not target.is_file():
            raise DataError(target, "exists and is not a regular file")
        previous = target.read_bytes()
        if previous == text.encode("utf-8"):
            return f"unchanged {target}"
    try:
        atomic_write_text(target, text, backup_suffix=BACKUP_SUFFIX if previous is not None else None)
    except OSError as err:
        raise DataError(target, f"cannot write: {err.strerror or err}") from None
    return f"wrote {target}" + ("" if previous is None else f" (previous version kept as {target.name}{BACKUP_SUFFIX})")


def export_inputs(args) -> list:
    """The files an export is made from (an export never replaces them)."""
    from naocal.tools.export import urdf

    return [args.file, args.nominal_urdf or (urdf.NOMINAL_URDF if args.format == "urdf" else None)]


def run_export(args, out) -> int:
    from naocal.solver.fileio import check_not_an_input
    from naocal.solver.offsets import read_offsets

    offsets = read_offsets(args.file)
    team = args.format in TEAM_FORMATS
    if args.out is None:
        files = build(args, offsets)
        for file in files:
            if team:
                out.write(f"// ---- {file.path}\n")
            out.write(file.text)
        _print_notes(files)
        return 0
    target_dir = Path(args.out)
    if team and target_dir.exists() and not target_dir.is_dir():
        raise DataError(target_dir, f"--out must be a directory for the {args.format} format (it gets a layout of "
                                    "files)")
    with locked(target_dir if team else target_dir.parent):
        files = build(args, offsets)  # everything is built before anything is written
        targets = [(export_target(target_dir, file.path, not team), file) for file in files]
        for target, _ in targets:  # a team's files (--merge-from) are merged into on purpose, its sources never
            check_not_an_input(target, export_inputs(args))
        for target, file in targets:
            print(write_export(target, file.text), file=sys.stderr)
            for note in file.notes:
                print(f"  {note}", file=sys.stderr)
    return 0


def _print_notes(files) -> None:
    for file in files:
        for note in file.notes:
            print(f"{file.path}: {note}", file=sys.stderr)
