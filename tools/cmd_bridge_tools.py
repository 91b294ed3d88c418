"""`naocal bridge status` and `naocal bridge move`: check a calibration on the robot through a running bridge.

  naocal bridge status --endpoint URL [--offsets FILE] [--json]
  naocal bridge move --endpoint URL [--offsets FILE] [--speed F] JOINT=DEG ...

An offsets file of another body or head than the robot's (what `naocal verify` refuses) is warned about.
`status` prints the robot's ids and, per joint, the raw reading, the reading corrected by the offsets file
(reading - c), stiffness, temperature and temperature status. `--json` prints one JSON object (schema in
docs/DEPLOY.md): a key per joint name with raw_rad, corrected_rad, stiffness, temperature_c, status (null where
the robot does not report it), and the key "robot" with body_id, head_id, their versions and the driver.
Exit 0 when the robot is fine, 3 when it reports a fault (the readings shown are then the last trusted ones), so
that a script checking the robot stops there.

`move` moves the named joints to the given angles in degrees, through the offsets (the command sent is
target + c, so the joint truly stands at the target), at a safe default speed (10 % of each joint's maximum),
after checking every target against the robot's limits and the HeadPitch-vs-HeadYaw table (an unsafe target
exits with code 2 before anything moves). It stiffens only the named joints, waits on the robot's clock (the
mock's moves only when asked) until they read their targets (deadline: three times the motion time plus
--timeout-s), then releases control: the LoLA driver then holds the
joints for its hold time and ramps their stiffness to 0 (docs/DEPLOY.md). It has no collision model: move one
joint at a time, in small steps, with the robot where it cannot hurt itself.
"""

DEFAULT_MOVE_SPEED = 0.1
MAX_MOVE_TIMEOUT_S = 600.0
MAX_TOLERANCE_DEG = 10.0
MOVE_POLL_S = 0.05


def register(actions) -> None:
    """Add `status` and `move` to the `naocal bridge` actions."""
    status = actions.add_parser("status", help="the robot's ids and every joint's reading, stiffness, temperature")
    status.add_argument("--endpoint", required=True, metavar="URL", help="e.g. tcp://127.0.0.1:7790")
    status.add_argument("--offsets", metavar="FILE", help="naocal offsets.json: also print readings - c")
    status.add_argument("--json", action="store_true", help="one JSON object (schema in docs/DEPLOY.md)")
    status.add_argument("--timeout-s", type=float, default=3.0, help="give up after this long (default 3)")

    move = actions.add_parser("move", help="move named joints to angles (deg) through the offsets, then release")
    move.add_argument("--endpoint", required=True, metavar="URL", help="e.g. tcp://127.0.0.1:7790")
    move.add_argument("--offsets", metavar="FILE", help="naocal offsets.json: command target + c")
    move.add_argument("--speed", type=float, default=DEFAULT_MOVE_SPEED, metavar="F",
                      help=f"fraction of each joint's maximum speed, in (0, 0.5] (default {DEFAULT_MOVE_SPEED})")
    move.add_argument("--timeout-s", type=float, default=5.0,
                      help="wait for the joints three times the expected motion time plus this, in robot time "
                           f"(default 5, at most {MAX_MOVE_TIMEOUT_S:g})")
    move.add_argument("--tolerance-deg", type=float, default=1.0,
                      help="a joint has arrived when it reads within this of its target "
                           f"(default 1, at most {MAX_TOLERANCE_DEG:g})")
    move.add_argument("angles", nargs="+", metavar="JOINT=DEG", help="e.g. HeadYaw=20 LKneePitch=45.5")


def _read_offsets(path):
    """The offsets file (None without --offsets), read before anything connects: a bad file stops here."""
    from naocal.solver.offsets import read_offsets

    return read_offsets(path) if path else None


def _offsets_for(robot, offsets, path) -> dict:
    """{joint: c} of `offsets` for the robot behind `robot` ({} without a file). Warns, as `verify` refuses, when the
    file names another body or head than the robot reports (solver.verify.check_same_robot)."""
    import sys

    from naocal.solver.errors import DataError
    from naocal.solver.robot import nao
    from naocal.solver.verify import check_same_robot

    if offsets is None:
        return {}
    try:
        check_same_robot(offsets, path, {"robot": robot.robot_identity()}, nao())
    except DataError as err:
        print(f"naocal bridge: WARNING: {err}; its offsets do not describe this robot", file=sys.stderr)
    return offsets.joint_offsets_rad


def _identity_text(robot: dict, driver) -> str:
    """'body ID (VERSION), head ID (VERSION)'; a driver that reports no versions (the mock, NAOqi) says so once
    rather than print '?'."""
    ids = f"body {robot.get('body_id', 'unknown')}", f"head {robot.get('head_id', 'unknown')}"
    versions = robot.get("body_version"), robot.get("head_version")
    if all(versions):
        return ", ".join(f"{part} ({version})" for part, version in zip(ids, versions))
    return f"{ids[0]}, {ids[1]} (the {driver} driver reports no versions)"


def run_status(args) -> int:
    import json
    import math

    from naocal.backends.bridge import BridgeBackend
    from naocal.solver.compensation import correct_reading

    offsets_file = _read_offsets(args.offsets)
    bridge = BridgeBackend(args.endpoint, timeout_s=args.timeout_s, retries=1)
    try:
        offsets = _offsets_for(bridge, offsets_file, args.offsets)
        report = bridge.status()
        driver = bridge.server_info().get("driver")
    finally:
        bridge.close()
    joints = report["joints"]
    corrected = correct_reading({name: entry["raw_rad"] for name, entry in joints.items()}, offsets)
    robot = dict(report["robot"])
    robot.update(driver=driver, offsets_file=args.offsets, t_s=report.get("t_s"))
    out = {"robot": robot}
    for name, entry in joints.items():
        out[name] = {"raw_rad": entry["raw_rad"], "corrected_rad": corrected[name], "stiffness": entry.get("stiffness"),
                     "temperature_c": entry.get("temperature_c"), "status": entry.get("status")}
        if entry.get("current_a") is not None:
            out[name]["current_a"] = entry["current_a"]
    # A fault is not an answer to "is the robot fine": a script must see it in the exit code, not parse the text.
    code = 3 if robot.get("fault") else 0
    if args.json:
        print(json.dumps(out, indent=1))
        return code

    def number(value, fmt):
        return "-" if value is None else format(value, fmt)

    print(f"robot: {_identity_text(robot, driver)}, driver {driver}"
          + (f", control {robot['control']}" if robot.get("control") else "")
          + (f", PAUSED: {robot['paused']}" if robot.get("paused") else "")
          + (f", FAULT: {robot['fault']}" if robot.get("fault") else ""))
    print(f"{'joint':<16}{'raw_deg':>10}{'corrected_deg':>15}{'stiffness':>11}{'temp_C':>8}{'status':>8}")
    for name, entry in out.items():
        if name == "robot":
            continue
        print(f"{name:<16}{math.degrees(entry['raw_rad']):>10.2f}{math.degrees(entry['corrected_rad']):>15.2f}"
              f"{number(entry['stiffness'], '.2f'):>11}{number(entry['temperature_c'], '.0f'):>8}"
              f"{number(entry['status'], 'd'):>8}")
    if not offsets:
        print("(no --offsets: corrected = raw)")
    return code


def run_move(args) -> int:
    import math

    from naocal.backends.bridge import BridgeBackend
    from naocal.backends.compensated import CompensatedBackend
    from naocal.solver import limits
    from naocal.solver.compensation import parse_assignment
    from naocal.backends.errors import RobotTimeout
    from naocal.solver.errors import NaocalError, SafetyError

    if not 0.0 < args.speed <= 0.5:
        raise NaocalError(f"--speed must be within (0, 0.5], got {args.speed}")
    if not 0.0 < args.timeout_s <= MAX_MOVE_TIMEOUT_S:  # every wait has a deadline
        raise NaocalError(f"--timeout-s must be within (0, {MAX_MOVE_TIMEOUT_S:g}] s, got {args.timeout_s}")
    if not 0.0 < args.tolerance_deg <= MAX_TOLERANCE_DEG:
        raise NaocalError(f"--tolerance-deg must be within (0, {MAX_TOLERANCE_DEG:g}], got {args.tolerance_deg}")
    targets = {}
    for text in args.angles:
        joint, angle_deg = parse_assignment(text)
        if joint in targets:
            raise NaocalError(f"{joint} given twice")
        targets[joint] = math.radians(angle_deg)
    offsets_file = _read_offsets(args.offsets)

    bridge = BridgeBackend(args.endpoint, timeout_s=3.0, retries=1)
    try:
        offsets = _offsets_for(bridge, offsets_file, args.offsets)
        robot = CompensatedBackend(bridge, offsets) if offsets else bridge
        movable = set(robot.joint_names())
        fixed = [joint for joint in targets if joint not in movable]
        if fixed:
            raise NaocalError(f"this robot's driver moves only {', '.join(sorted(movable))}; not {', '.join(fixed)} "
                              "(nothing was moved)")
        start = robot.read_joints().angles_rad
        try:
            limits.check_targets(targets, robot.joint_limits(),
                                 head_angles={name: [start[name]] for name in ("HeadYaw", "HeadPitch")})
        except SafetyError as err:
            raise SafetyError(f"refusing to move: {err} (nothing was moved)") from None
        speeds = robot.max_speeds()
        expected_s = max(abs(targets[j] - start[j]) / (args.speed * speeds[j]) for j in targets)
        robot.set_stiffness(list(targets), 1.0)
        robot.command(targets, args.speed)
        # Waits on the robot's clock (now/sleep): a simulated one (the mock) moves only when asked to sleep.
        done_s = robot.now() + expected_s  # releasing earlier would stop the motion short of its target
        # The driver moves one step per LoLA message: allow for a robot slower than its nominal cycle.
        allowed_s = 3.0 * expected_s + args.timeout_s
        deadline_s = robot.now() + allowed_s
        tolerance = math.radians(args.tolerance_deg)
        while True:
            reading = robot.read_joints().angles_rad
            away = {j: reading[j] for j in targets if abs(reading[j] - targets[j]) > tolerance}
            # A driver that interpolates itself (LoLA) says when its motion has ended: on a slow cycle that is
            # later than the nominal motion time, and releasing earlier freezes the joint short of its target.
            if not away and robot.now() >= done_s and not bridge.status()["robot"].get("moving", False):
                break
            if robot.now() > deadline_s:
                raise RobotTimeout(f"not there within {allowed_s:.1f} s: " + ", ".join(
                    f"{j} reads {math.degrees(a):.2f} deg, target {math.degrees(targets[j]):.2f} deg"
                    for j, a in away.items()))
            robot.sleep(MOVE_POLL_S)
    finally:
        bridge.close()  # releases control: the driver holds, then ramps stiffness down
    for joint, target in targets.items():
        c = offsets.get(joint, 0.0)
        print(f"{joint}: target {math.degrees(target):.2f} deg, commanded {math.degrees(target + c):.2f} deg raw, "
              f"reads {math.degrees(reading[joint]):.2f} deg" + (" corrected" if offsets else ""))
    return 0
