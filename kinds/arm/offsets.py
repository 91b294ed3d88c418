"""`naocal offsets diff | validate | export | apply` of an arm's calibration file (naocal.arm_calibration/1,
docs/ARM.md): the arm kind's `offsets` bodies."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from naocal.solver.errors import DataError, NaocalError
from naocal.tools.columns import number_column as _num, shown_value as _shown  # the NAO's diff table's columns

ARM_EXPORT_FORMATS = ("urdf", "json")



def format_arm_diff(a, b, name_a: str, name_b: str):
    """(text, number of marked differences): B - A per parameter in display units (deg, mm), '*' where it exceeds
    the combined std. The sensors' frames (the setup, not the arm) are listed apart and never marked."""
    from naocal.solver.effect import shown

    out = [f"A = {name_a}", f"B = {name_b}"]
    for key in ("id", "base", "tip"):
        if a.robot.get(key) != b.robot.get(key):
            out.append(f"note: robot {key} differs ({a.robot.get(key)} vs {b.robot.get(key)})")
    if a.effects != b.effects:
        out.append(f"note: models differ (A: {', '.join(a.effects)}; B: {', '.join(b.effects)})")
    names = list(a.parameters) + [n for n in b.parameters if n not in a.parameters]
    arm = [n for n in names if not n.startswith("sensor.")]
    setup = [n for n in names if n.startswith("sensor.")]
    marked = 0
    header = f"  {'parameter':<44}{'A':>11}{'B':>11}{'B - A':>11}{'sigma':>10}  unit"
    for title, group in (("the arm", arm), ("the sensors' frames (the setup: differ whenever a sensor is set up "
                                             "again; not marked)", setup)):
        if not group:
            continue
        out += ["", title, header]
        for name in group:
            ea, eb = a.parameters.get(name), b.parameters.get(name)
            unit = (ea or eb)["unit"]
            va = None if ea is None else ea["value"]
            vb = None if eb is None else eb["value"]
            delta = sigma = None
            mark = ""
            if ea is not None and eb is not None:
                delta = vb - va
                sigma = math.hypot(ea["std"], eb["std"])
                if group is arm and abs(delta) > sigma and not (ea["fixed"] and eb["fixed"]):
                    mark, marked = " *", marked + 1
            else:
                mark = " (only in A)" if eb is None else " (only in B)"
            out.append(f"  {name:<44}{_num(_shown(va, unit), 11)}{_num(_shown(vb, unit), 11)}"
                       f"{_num(_shown(delta, unit), 11)}"
                       f"{_num(_shown(sigma, unit), 10)}  {shown(0.0, unit)[1]}{mark}")
    out.append(f"{marked} of {len(arm)} arm parameters differ by more than their combined uncertainty (*)")
    return "\n".join(out) + "\n", marked


def _arm_pair(path_a, path_b):
    from naocal.kinds.arm.calibration import is_arm_calibration, read_arm_calibration

    arm_a, arm_b = is_arm_calibration(path_a), is_arm_calibration(path_b)
    if arm_a != arm_b:
        arm, nao = (path_a, path_b) if arm_a else (path_b, path_a)
        raise DataError(nao, f"not an arm calibration ({arm} is naocal.arm_calibration/1): an arm's and a NAO's "
                             "calibration cannot be compared")
    return read_arm_calibration(path_a), read_arm_calibration(path_b)


def run_diff(args, out) -> int:
    a, b = _arm_pair(args.file_a, args.file_b)
    text, marked = format_arm_diff(a, b, args.file_a, args.file_b)
    out.write(text)
    return 1 if (marked and args.fail_on_difference) else 0


def run_validate(args, out) -> int:
    from naocal.kinds.arm.calibration import read_arm_calibration

    read_arm_calibration(args.file)
    out.write("ok\n")
    return 0


def _urdf_of(cal, args) -> Path:
    given = args.nominal_urdf or cal.robot.get("urdf")
    if not given:
        raise DataError(cal.path, "no URDF: the file names none; give --nominal-urdf URDF", field="robot.urdf")
    path = Path(given)
    if not path.is_absolute() and not path.exists():  # as written by identify: relative to where it ran
        beside = Path(cal.path).parent / path
        path = beside if beside.exists() else path
    if not path.is_file():
        raise DataError(path, "the arm's URDF is not there; give --nominal-urdf URDF",
                        field=None if args.nominal_urdf else "robot.urdf")
    return path


def build_export(args):
    """(file name, text, the files it was made from) of an arm's export; NaocalError for what an arm's file cannot
    be exported to."""
    import json

    from naocal.kinds.arm.calibration import read_arm_calibration

    if args.format not in ARM_EXPORT_FORMATS:
        raise NaocalError(f"--format {args.format}: an arm's calibration exports to {' or '.join(ARM_EXPORT_FORMATS)} "
                          "(the team formats are the NAO's)")
    for option in ("merge_from", "head_id", "body_id", "bhuman_release"):
        if getattr(args, option, None) is not None:
            raise NaocalError(f"--{option.replace('_', '-')} is the NAO's team formats' option")
    cal = read_arm_calibration(args.file)
    if args.format == "json":
        from naocal.solver.fileio import read_json

        return "calibration.json", json.dumps(read_json(args.file), indent=1, allow_nan=False) + "\n", [args.file]
    from naocal.kinds.arm.urdf_export import export_arm_urdf

    urdf = _urdf_of(cal, args)
    return "calibrated.urdf", export_arm_urdf(cal, urdf, source_name=Path(args.file).name,
                                              strip_meshes=args.strip_meshes), [args.file, urdf]


def run_export(args, out) -> int:
    from naocal.tools.export.write import export_target, locked, write_export

    if args.out is None:
        out.write(build_export(args)[1])
        return 0
    from naocal.solver.fileio import check_not_an_input

    target = Path(args.out)
    with locked(target.parent):
        _, text, inputs = build_export(args)  # built before anything is written
        check_not_an_input(target, inputs)
        print(write_export(export_target(target, "", True), text), file=sys.stderr)
    return 0


def run_apply(args, out) -> int:
    """Compensated commands (requested + c) or corrected readings (measured - c) of the arm's joints."""
    from naocal.kinds.arm.calibration import read_arm_calibration

    cal = read_arm_calibration(args.file)
    offsets = {n.split(".", 1)[1]: e["value"] for n, e in cal.parameters.items() if n.startswith("joint_offset.")}
    to_rad = 1.0 if args.rad else math.pi / 180.0
    sign = 1.0 if args.mode == "command" else -1.0
    for text in args.angles:
        joint, sep, value = text.partition("=")
        joint = joint.strip()
        try:
            angle = float(value) if sep and joint else math.nan
        except ValueError:
            angle = math.nan
        if not math.isfinite(angle):
            raise NaocalError(f"expected JOINT=ANGLE with a finite angle, got {text[:60]!r}")
        if joint not in offsets:
            raise NaocalError(f"unknown joint {joint[:60]!r} (the calibration's: {', '.join(offsets)})")
        out.write(f"{joint}={(angle * to_rad + sign * offsets[joint]) / to_rad:.10g}\n")
    return 0
