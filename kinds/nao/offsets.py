"""The NAO's `naocal offsets show | diff | validate | export | apply` of naocal.offsets/2 (and /1) files, and a result
against the simulator's naocal.truth (the verb and its help: tools/cmd_offsets.py)."""

from naocal.tools.columns import number_column as _num, shown_value as _shown  # shared with kinds/arm/offsets.py


# ----------------------------------------------------------------------------------------------- display

# Display units: angles in deg, lengths in mm, time in ms.
_SHOWN_ELSEWHERE = ("joint_offset.", "head_offset.", "board.")  # model names with their own table


def _shown_elsewhere(name: str) -> bool:
    """Whether a model parameter has its own table (joint offsets, camera rotations, board mounts)."""
    parts = name.split(".")
    return name.startswith(_SHOWN_ELSEWHERE) or (parts[0] == "camera" and parts[-1] in ("roll", "pitch", "yaw"))
_BOARD_ROWS = (("rot_z_rad", "rot_z", "rad"), ("trans_x_m", "trans_x", "m"), ("trans_y_m", "trans_y", "m"))


def _unit(unit) -> str:
    from naocal.solver.effect import shown

    return shown(0.0, unit)[1]


def _joint_std(offsets, joint):
    for name in (f"joint_offset.{joint}", f"head_offset.{joint}"):
        if offsets.std(name) is not None:
            return offsets.std(name)
    tied = joint == "RHipYawPitch" and offsets.joint_offset("RHipYawPitch") == offsets.joint_offset("LHipYawPitch")
    return offsets.std("joint_offset.LHipYawPitch") if tied else None  # one motor: R follows L


def parameter_rows(offsets) -> list:
    """(label, unit, value, std) in SI units for everything a file holds, in display order.

    Joint offsets are c (the file's value); the other parameters are the model's values.
    """
    from naocal.solver.offsets import CAMERA_ANGLES, OFFSET_JOINTS

    rows = [(f"c {j}", "rad", offsets.joint_offsets_rad[j], _joint_std(offsets, j))
            for j in OFFSET_JOINTS if j in offsets.joint_offsets_rad]
    for camera, angles in offsets.camera_rotation_rad.items():
        rows += [(f"camera.{camera}.{a}", "rad", angles[a], offsets.std(f"camera.{camera}.{a}"))
                 for a in CAMERA_ANGLES]
    for leg, mount in offsets.board_mount.items():
        rows += [(f"board.{leg}.{short}", unit, mount[key], offsets.std(f"board.{leg}.{short}"))
                 for key, short, unit in _BOARD_ROWS]
    for name, entry in offsets.model["parameters"].items():
        if not _shown_elsewhere(name):
            rows.append((name, entry["unit"], entry["value"], entry["std"]))
    return rows


def format_show(offsets, name: str) -> str:
    from naocal.solver.offsets import CAMERA_ANGLES, OFFSET_JOINTS

    robot, fit = offsets.robot, offsets.fit
    out = [name,
           f"  robot     id {robot.get('id')}, body {robot.get('body_id')}, head {robot.get('head_id')}",
           f"  created   {offsets.created}",
           "  source    " + ("; ".join(f"{k}: {v}" for k, v in offsets.source.items()) or "-"),
           "",
           "joint offsets c (added to commands, subtracted from readings)",
           f"  {'joint':<16}{'c [deg]':>10}{'std [deg]':>11}"]
    for joint in OFFSET_JOINTS:
        if joint in offsets.joint_offsets_rad:
            out.append(f"  {joint:<16}{_num(_shown(offsets.joint_offsets_rad[joint], 'rad'))} "
                       f"{_num(_shown(_joint_std(offsets, joint), 'rad'))}")
    for camera, angles in offsets.camera_rotation_rad.items():
        out += ["", f"camera rotation, {camera} camera (model alpha: T_head_cam = T_nominal @ Rot_y(pitch) "
                    "@ Rot_x(roll) @ Rot_z(yaw))",
                f"  {'angle':<16}{'[deg]':>10}{'std [deg]':>11}"]
        for a in CAMERA_ANGLES:
            std = offsets.std(f"camera.{camera}.{a}")
            out.append(f"  {a:<16}{_num(_shown(angles[a], 'rad'))} {_num(_shown(std, 'rad'))}")
    out += ["", "board mount (model alpha: p = Rot_z(rot_z) Trans_x(trans_x) Trans_y(trans_y) p_sole)",
            f"  {'leg':<6}{'rot_z [deg]':>12}{'trans_x [mm]':>14}{'trans_y [mm]':>14}"]
    for leg, mount in offsets.board_mount.items():
        values = "".join(f"{_num(_shown(mount[key], unit), width)}"
                         for (key, _, unit), width in zip(_BOARD_ROWS, (12, 14, 14)))
        out.append(f"  {leg:<6}{values}")
        stds = [offsets.std(f"board.{leg}.{short}") for _, short, _ in _BOARD_ROWS]
        if any(s is not None for s in stds):
            out.append(f"  {'  std':<6}" + "".join(_num(_shown(s, unit), width) for s, (_, _, unit), width
                                                  in zip(stds, _BOARD_ROWS, (12, 14, 14))))
    effects = offsets.model["effects"]
    out += ["", "model effects: " + (", ".join(effects) if effects else "-")]
    extra = [r for r in parameter_rows(offsets) if r[0] in offsets.model["parameters"] and not _shown_elsewhere(r[0])]
    if extra:
        out.append(f"  {'parameter':<28}{'value':>12}{'std':>12}  unit")
        for label, unit, value, std in extra:
            out.append(f"  {label:<28}{_num(_shown(value, unit), 12, 5)}{_num(_shown(std, unit), 12, 5)}  "
                       f"{_unit(unit)}")
    rms_x, rms_y = fit["rms_px"]
    out += ["", f"fit: rms {rms_x:.3f} px (x), {rms_y:.3f} px (y) over {fit['n_vertices']} vertices "
                f"in {fit['n_images']} images"]
    return "\n".join(out) + "\n"


def format_diff(a, b, name_a: str, name_b: str):
    """(text, number of marked differences): B - A per parameter, '*' where it exceeds the combined std."""
    import math

    rows_a = {label: (unit, value, std) for label, unit, value, std in parameter_rows(a)}
    rows_b = {label: (unit, value, std) for label, unit, value, std in parameter_rows(b)}
    labels = list(rows_a) + [label for label in rows_b if label not in rows_a]
    out = [f"A = {name_a}", f"B = {name_b}"]
    for key in ("id", "body_id", "head_id"):
        if a.robot.get(key) != b.robot.get(key):
            out.append(f"note: robot {key} differs ({a.robot.get(key)} vs {b.robot.get(key)})")
    out.append(f"  {'parameter':<28}{'A':>11}{'B':>11}{'B - A':>11}{'sigma':>10}  unit")
    marked = 0
    for label in labels:
        unit = (rows_a.get(label) or rows_b[label])[0]  # a parameter in one file only (was a KeyError: B lacks it)
        _, value_a, std_a = rows_a.get(label, (unit, None, None))
        _, value_b, std_b = rows_b.get(label, (unit, None, None))
        delta = sigma = None
        mark = ""
        if value_a is not None and value_b is not None:
            delta = value_b - value_a
            sigma = math.hypot(std_a or 0.0, std_b or 0.0)
            if abs(delta) > sigma:
                mark, marked = " *", marked + 1
        else:
            mark = " (only in A)" if value_b is None else " (only in B)"
        out.append(f"  {label:<28}{_num(_shown(value_a, unit), 11)}{_num(_shown(value_b, unit), 11)}"
                   f"{_num(_shown(delta, unit), 11)}{_num(_shown(sigma, unit), 10)}  {_unit(unit)}{mark}")
    out.append(f"{marked} of {len(labels)} parameters differ by more than their combined uncertainty (*)")
    return "\n".join(out) + "\n", marked


# -------------------------------------------------------------------------------------------------- verbs


def run_show(args, out) -> int:
    from naocal.solver.offsets import read_offsets

    out.write(format_show(read_offsets(args.file), args.file))
    return 0


def run_diff(args, out) -> int:
    from naocal.solver.offsets import is_truth_file, read_offsets, read_truth

    truth_a, truth_b = is_truth_file(args.file_a), is_truth_file(args.file_b)
    if truth_a or truth_b:  # a result against the simulator's truth
        from naocal.solver.errors import NaocalError

        if truth_a and truth_b:
            raise NaocalError(f"{args.file_a}, {args.file_b}: both are a simulator's truth; give a result and a truth")
        result_path, truth_path = (args.file_b, args.file_a) if truth_a else (args.file_a, args.file_b)
        truth, notes = read_truth(truth_path)
        text, marked = format_truth_diff(read_offsets(result_path), truth, result_path, truth_path, notes)
    else:
        text, marked = format_diff(read_offsets(args.file_a), read_offsets(args.file_b), args.file_a, args.file_b)
    out.write(text)
    return 1 if (marked and args.fail_on_difference) else 0


TRUTH_Z = 3.0  # an error beyond this many of the result's standard deviations is marked against the truth


def format_truth_diff(result, truth, result_name: str, truth_name: str, notes=()):
    """(text, number marked): each parameter's error (result - truth) and z = error / the result's std, '*' where
    |z| > TRUTH_Z; parameters in one file only listed as such."""
    rows_r = {label: (unit, value, std) for label, unit, value, std in parameter_rows(result)}
    rows_t = {label: (unit, value) for label, unit, value, _ in parameter_rows(truth)}
    out = [f"result = {result_name}", f"truth  = {truth_name} (the simulator's hidden values; joint offsets as c = "
                                      "-alpha)", f"  {'parameter':<28}{'result':>11}{'truth':>11}{'error':>11}"
                                                 f"{'std':>10}{'z':>8}  unit"]
    marked = compared = 0
    for label in list(rows_r) + [label for label in rows_t if label not in rows_r]:
        unit = (rows_r.get(label) or rows_t[label])[0]
        value, std = rows_r[label][1:] if label in rows_r else (None, None)
        true = rows_t[label][1] if label in rows_t else None
        error = z = None
        mark = " (not in the truth)" if true is None else (" (not in the result)" if value is None else "")
        if value is not None and true is not None:
            compared += 1
            error = value - true
            z = error / std if std else None
            if z is not None and abs(z) > TRUTH_Z:
                mark, marked = " *", marked + 1
        z_text = f"{'-':>8}" if z is None else f"{z:>+8.2f}"
        out.append(f"  {label:<28}{_num(_shown(value, unit), 11)}{_num(_shown(true, unit), 11)}"
                   f"{_num(_shown(error, unit), 11)}{_num(_shown(std, unit), 10)}{z_text}  {_unit(unit)}{mark}")
    out.append(f"{marked} of {compared} parameters are off the truth by more than {TRUTH_Z:g} standard deviations "
               "(*)")
    out += [f"note: {n}" for n in notes]
    return "\n".join(out) + "\n", marked


def run_validate(args, out) -> int:
    from naocal.solver.offsets import read_offsets

    read_offsets(args.file)
    out.write("ok\n")
    return 0


def run_export(args, out) -> int:
    from naocal.tools.export.write import run_export as export

    return export(args, out)


def run_apply(args, out) -> int:
    import math

    from naocal.solver.compensation import compensate_command, correct_reading, parse_assignment
    from naocal.solver.offsets import read_offsets

    offsets = read_offsets(args.file)
    posture = dict(parse_assignment(text) for text in args.angles)
    to_rad = 1.0 if args.rad else math.pi / 180.0
    posture_rad = {joint: angle * to_rad for joint, angle in posture.items()}
    apply = compensate_command if args.mode == "command" else correct_reading
    for joint, angle_rad in apply(posture_rad, offsets).items():
        out.write(f"{joint}={angle_rad / to_rad:.10g}\n")
    return 0
