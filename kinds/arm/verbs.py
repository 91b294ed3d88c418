"""The arm's bodies of `naocal identify`, `diagnose`, `verify` and `simulate`, and `offsets show` (docs/ARM.md); the
kind (kinds/arm/__init__.py) claims --robot / --chain, a naocal.arm_dataset/1 directory or a
naocal.arm_calibration/1 file."""

from __future__ import annotations

import json
import math
import sys

from naocal.solver.fileio import json_safe


def add_arm_options(parser, *, simulate=False, verb="") -> None:
    """--robot and --chain; for identify, diagnose and verify the priors, start values and (verify) the nuisance
    parameters refitted (argparse only)."""
    parser.add_argument("--robot", metavar="URDF",
                        help="an arm: its URDF file, or kuka_iiwa / franka_panda (pybullet_data); simulate also "
                             "knows dualarm (two arms on a torso); "
                             + ("simulates that arm" if simulate else "default: the dataset's robot.urdf"))
    parser.add_argument("--chain", metavar="BASE_LINK:TIP_LINK",
                        help="the arm's serial chain by its URDF base and tip links (default: the dataset's, or "
                             "the named arm's flange / hand)")
    if verb not in ("identify", "diagnose", "verify"):
        return
    parser.add_argument("--no-priors", action="store_true",
                        help="arm: fit from the data alone (default: every physical parameter has a Gaussian prior "
                             "about the URDF's value of its effect's plausible size, docs/ARM.md)")
    parser.add_argument("--start", metavar="CAL_JSON",
                        help="arm: start from the arm's parameters of this naocal.arm_calibration/1 (the priors "
                             "stay about the URDF)")
    if verb == "verify":
        parser.add_argument("--refit", default="sensors", metavar="sensors[,points][,intrinsics]",
                            help="arm: what the new data refit with the calibration's arm held (default: sensors, the "
                                 "sensors' frames; points: also where the reflectors / markers sit on the tool, "
                                 "e.g. a tracker's reflector; what a tool's markers move together is judged as its mount moving; intrinsics: the cameras' fx, fy, cx, cy and lens "
                                 "distortion k1, k2, p1, p2, k3 of the new session)")
        parser.add_argument("--fix", action="append", default=[], metavar="NAME[=VALUE]",
                            help="arm: hold a refitted parameter (repeatable), at VALUE in the units the report "
                                 "shows (deg, mm)")


def parse_arm_effects(text: str):
    from naocal.kinds.arm.model import DEFAULT_EFFECTS
    from naocal.solver.effects import ARM_EFFECTS, comma_list
    from naocal.solver.errors import NaocalError

    if not text:
        return DEFAULT_EFFECTS
    names = comma_list(text, "--effects")
    for name in names:
        if name not in ARM_EFFECTS:
            raise NaocalError(f"--effects: unknown arm effect {name!r} (expected {', '.join(ARM_EFFECTS)})")
    return tuple(names)


def _check_nao_only(args) -> None:
    from naocal.solver.errors import NaocalError

    if getattr(args, "loss_scale_px", 1.0) != 1.0:
        raise NaocalError("--loss-scale-px is the NAO's: an arm's robust loss bends at its sensors' noise (1 std)")
    if getattr(args, "tie_hip_yaw_pitch", False):
        raise NaocalError("--tie-hip-yaw-pitch is the NAO's")


def fixed_and_start(args, dataset, effects):
    """(names or effects held, {name: SI start value}) from --start CAL.json and --fix NAME[=VALUE] (VALUE in the
    units the report shows: deg, mm; a bare NAME is held at its start value, the URDF's unless --start gives one).
    NaocalError naming the option, DataError naming the file's field."""
    from naocal.kinds.arm.calibration import LIMITS
    from naocal.kinds.arm.identify import model_for
    from naocal.solver.effect import DISPLAY_UNITS
    from naocal.solver.effects import ARM_EFFECTS
    from naocal.solver.errors import DataError, NaocalError

    model = model_for(dataset, effects)
    start = {}
    if getattr(args, "start", None):
        from naocal.kinds.arm.calibration import read_arm_calibration
        from naocal.kinds.arm.verify import check_same_arm

        cal = read_arm_calibration(args.start)
        check_same_arm(cal, dataset)
        for name, entry in cal.arm_parameters.items():
            if name not in model.names:
                raise DataError(cal.path, f"{name} is not a parameter of the model being fitted (effects "
                                          f"{', '.join(model.effects)}): add its effect with --effects",
                                field=f"model.parameters.{name}")
            start[name] = entry["value"]
    fixed = []
    for text in getattr(args, "fix", None) or ():
        name, sep, value = (part.strip() for part in text.partition("="))
        if not sep:
            if name not in ARM_EFFECTS and name not in model.names:
                raise NaocalError(f"--fix {text[:60]!r}: not a parameter of the model nor an effect")
            fixed.append(name)
            continue
        if name not in model.names:
            raise NaocalError(f"--fix {text[:60]!r}: {name[:60]!r} is not a parameter of the model (NAME=VALUE "
                              "needs one parameter)")
        unit = model.parameters[model.names.index(name)].unit
        if name.startswith("sensor."):
            raise NaocalError(f"--fix {text[:60]!r}: a sensor's frame is found from the data; give its pose in "
                              "dataset.json instead")
        try:
            shown_value = float(value)
        except ValueError:
            shown_value = float("nan")
        label, factor = DISPLAY_UNITS.get(unit, (unit, 1.0))
        if not math.isfinite(shown_value) or abs(shown_value / factor) > LIMITS.get(unit, math.inf):
            raise NaocalError(f"--fix {text[:60]!r}: expected NAME=VALUE with a finite value in {label} within "
                              f"{LIMITS.get(unit, math.inf) * factor:.4g} {label}")
        start[name] = shown_value / factor
        fixed.append(name)
    return tuple(fixed), start


def _load(args):
    from naocal.kinds.arm.dataset import is_arm_dataset, read_arm_dataset

    if not (args.robot or args.chain) and not is_arm_dataset(args.dataset):  # claimed by an arm-only option
        from naocal.solver.errors import NaocalError

        raise NaocalError(f"{args.dataset}: not an arm's dataset (naocal.arm_dataset/1): --no-priors, --start, "
                          "--refit and verify's --fix are an arm's options")

    dataset = read_arm_dataset(args.dataset, robot=args.robot, chain=args.chain)
    for note in dataset.notes or ():
        print(f"naocal {args.verb}: note: {note}", file=sys.stderr)
    return dataset


def _unit_of(kind):
    return "m" if kind == "points" else "px"


def result_json(fit, dataset, heldout) -> dict:
    sensors = {s.name: s.kind for s in fit.model.sensors}
    return {
        "success": fit.success, "message": fit.message,
        "robot": {"urdf": str(dataset.urdf_path), "base": dataset.base, "tip": dataset.tip},
        "effects": list(fit.model.effects),
        "n_observations": len(fit.obs), "n_poses": int(len(set(fit.obs.pose.tolist()))),
        "rms": {s: {"value": v, "unit": _unit_of(sensors[s])} for s, v in fit.rms().items()},
        "noise": {s.name: {"value": float(fit.sigma[i]), "unit": _unit_of(s.kind), "stated": bool(fit.noise_known[i])}
                  for i, s in enumerate(fit.model.sensors)},
        "heldout": None if heldout is None else {
            s: dict(v, unit=_unit_of(sensors[s])) for s, v in heldout.items()},
        "parameters": fit.parameters_dict(),
        "fixed": fit.fixed_reasons,
        "priors": fit.priors,
        "held_by_prior": fit.held_by_prior,
        "loss": fit.loss,
        "outliers": [o.as_dict() for o in fit.outliers],
        "condition_number": fit.condition_number,
        "weak_directions": [{"singular_value": w.singular_value, "coefficients": w.coefficients}
                            for w in fit.weak_directions],
        "iterations": fit.iterations, "solve_time_s": fit.solve_time_s,
    }


def _shown(value, unit):
    from naocal.solver.effect import shown

    return shown(value, unit)


def format_table(report: dict) -> str:
    from naocal.kinds.arm.identify import shown_rms
    from naocal.kinds.arm.identify import PRIOR_HELD

    kind = {s: ("points" if v["unit"] == "m" else "camera") for s, v in report["rms"].items()}
    lines = ["fit: " + "; ".join(f"{s} RMS {shown_rms(v['value'], kind[s])} per axis" for s, v in
                                  report["rms"].items())
             + f" over {report['n_observations']} observations in {report['n_poses']} poses; "
               f"{report['iterations']} evaluations, {report['solve_time_s'] * 1e3:.0f} ms"]
    if report["heldout"]:
        lines.append("held-out poses: " + "; ".join(
            f"{s} nominal {shown_rms(v['nominal'], kind[s])} -> calibrated {shown_rms(v['calibrated'], kind[s])}"
            for s, v in report["heldout"].items()))
    held = set(report["held_by_prior"])
    lines += ["", f"{'parameter':45s} {'value':>12s} {'std':>10s} {'prior':>8s}  unit"]
    for name, e in report["parameters"].items():
        value, unit = _shown(e["value"], e["unit"])
        std, _ = _shown(e["std"], e["unit"])
        prior = f"{_shown(e['prior_std'], e['unit'])[0]:8.3g}" if e.get("prior_std") else f"{'-':>8s}"
        mark = "  (fixed)" if e["fixed"] else "  (held by its prior)" if name in held else ""
        lines.append(f"{name:45s} {value:12.4f} {std:10.4f} {prior}  {unit}{mark}")
    lines.append("")
    for name, reason in report["fixed"].items():
        lines.append(f"fixed: {name}: {reason}")
    if report["priors"]:
        lines.append("priors: each physical parameter ~ N(URDF, its plausible size: the 'prior' column); "
                     + (f"{len(held)} held by their prior (posterior std above {PRIOR_HELD:g} x the prior's: the "
                        f"data did not inform them): {', '.join(sorted(held))}" if held else
                        "the data informed every one (posterior std below "
                        f"{PRIOR_HELD:g} x the prior's)"))
    else:
        lines.append("priors: off (--no-priors): the data alone")
    from naocal.kinds.arm.identify import ArmOutlier, describe_outliers

    lines.append(describe_outliers([ArmOutlier(**o) for o in report["outliers"]]))
    lines.append(f"condition number (scaled Jacobian): {report['condition_number']:.3g}")
    lines.append("weakest directions at the solution (what the data determine least):")
    for w in report["weak_directions"]:
        lines.append(f"  relative singular value {w['singular_value']:.2e}: "
                     + " ".join(f"{c:+.2f}*{n}" for n, c in w["coefficients"].items()))
    return "\n".join(lines)


def run_identify(args) -> int:
    from naocal.kinds.arm.identify import heldout_rms, identify_dataset
    from naocal.solver.errors import SolveError

    _check_nao_only(args)
    effects = parse_arm_effects(args.effects)
    dataset = _load(args)
    if args.out:
        from naocal.agent.rundir import dataset_files
        from naocal.solver.fileio import check_output_file

        check_output_file(args.out, inputs=[*dataset_files(args.dataset), dataset.urdf_path])  # before the fit
    fixed, start = fixed_and_start(args, dataset, effects)
    fit = identify_dataset(dataset, effects, fixed=fixed, start=start, loss=args.loss, robust=not args.keep_outliers,
                           priors=not args.no_priors)
    from naocal.kinds.arm.identify import ran_off

    runoff = ran_off(fit)  # first: a fit that ran off often does not converge either, and this says why
    if runoff:
        raise SolveError(runoff)
    if not fit.success:
        raise SolveError(f"the solve did not converge ({fit.message}); nothing written")
    heldout = heldout_rms(fit, args.cv_folds) if args.cv_folds and args.cv_folds > 1 else None
    report = result_json(fit, dataset, heldout)
    if args.out:
        write_calibration(args.out, report, dataset, args.dataset)
    print(json.dumps(json_safe(report), indent=1) if args.json else format_table(report))
    return 0


def write_calibration(path, report, dataset, dataset_path) -> None:
    """naocal.arm_calibration/1: per section as identify --json names them, plus the fit and its source."""
    from pathlib import Path

    from naocal.kinds.arm.calibration import SCHEMA
    from naocal.solver.fileio import atomic_write_text
    from naocal.solver.offsets import utc_now_iso

    params = report["parameters"]
    sections = {"joint_offsets_rad": {}, "link_lengths_m": {}, "sensors": {}}
    for name, e in params.items():
        if name.startswith("joint_offset."):
            sections["joint_offsets_rad"][name.split(".", 1)[1]] = e["value"]
        elif name.startswith("link_length."):
            sections["link_lengths_m"][name.split(".", 1)[1]] = e["value"]
    for s in dataset.sensors:
        sections["sensors"][s.name] = {
            "rotation_rad": [params[f"sensor.{s.name}.rotation.{a}"]["value"] for a in "xyz"],
            "translation_m": [params[f"sensor.{s.name}.translation.{a}"]["value"] for a in "xyz"]}
    doc = {"schema": SCHEMA, "created": utc_now_iso(),
           "robot": dict(report["robot"], urdf=str(Path(dataset.urdf_path).resolve()),
                         id=str(dataset.meta.get("robot", {}).get("id", "unknown"))),
           **sections,
           **({"chains": {ac.name: {"base": ac.chain.base, "tip": ac.chain.tip} for ac in dataset.chain}}
              if isinstance(dataset.chain, tuple) else {}),  # several chains: the names tool.<chain> uses
           "model": {"effects": report["effects"], "parameters": params, "fixed": report["fixed"],
                     "priors": report["priors"], "held_by_prior": report["held_by_prior"]},
           "fit": {"rms": report["rms"], "noise": report["noise"], "heldout": report["heldout"],
                   "n_observations": report["n_observations"]},
           "source": {"tool": "naocal identify", "dataset": str(dataset_path)}}
    atomic_write_text(path, json.dumps(json_safe(doc), indent=1, allow_nan=False) + "\n", backup_suffix=".bak")


def format_calibration(path) -> str:
    """`naocal offsets show` of an arm calibration file; DataError naming the field when it is damaged."""
    from naocal.kinds.arm.calibration import read_arm_calibration

    cal = read_arm_calibration(path)
    robot = cal.robot
    lines = [f"{path}: arm calibration of {robot.get('id', '?')} ({robot['base']} -> {robot['tip']}), "
             f"created {cal.created}", "  model: sensor frames + " + (" + ".join(cal.effects) or "nothing"), ""]
    lines.append(f"{'parameter':45s} {'value':>12s} {'std':>10s}  unit")
    for name, e in cal.parameters.items():
        value, unit = _shown(e["value"], e["unit"])
        std, _ = _shown(e["std"], e["unit"])
        lines.append(f"{name:45s} {value:12.4f} {std:10.4f}  {unit}{'  (fixed)' if e['fixed'] else ''}")
    for name, reason in cal.fixed_reasons.items():
        lines.append(f"fixed: {name}: {reason}")
    if cal.rms:
        from naocal.kinds.arm.identify import shown_rms

        lines += ["", "fit: " + "; ".join(f"{s} RMS {shown_rms(v, 'points' if u == 'm' else 'camera')} per axis"
                                          for s, (v, u) in cal.rms.items())]
    return "\n".join(lines) + "\n"


def run_verify(args) -> int:
    """`naocal verify` of an arm dataset under an arm calibration: exit 0 still good, 1 drifted."""
    from naocal.kinds.arm.calibration import read_arm_calibration
    from naocal.kinds.arm.identify import model_for
    from naocal.kinds.arm.verify import format_arm_verdict, verify_arm

    from naocal.solver.errors import NaocalError

    if getattr(args, "angles", "auto") != "auto":
        raise NaocalError("--angles is the NAO's: an arm's dataset has one reading per joint")
    cal = read_arm_calibration(args.offsets)
    dataset = _load(args)
    refit = parse_refit(args.refit)
    held, start = fixed_and_start(args, dataset, tuple(cal.effects) + tuple(e for e in refit if e not in cal.effects))
    refitted = {p.name for p in model_for(dataset, refit).parameters if p.effect in refit}
    for name in held:
        if name not in refitted and name not in refit:
            raise NaocalError(f"--fix {name}: verify holds the calibration's arm; only what --refit names "
                              f"({', '.join(('sensors',) + refit)}) is fitted")
    # a --start file may be a whole calibration (of this setup): only what verify refits is taken from it
    start = {name: value for name, value in start.items() if name in refitted}
    verdict = verify_arm(dataset, cal, refit_effects=refit, priors=not args.no_priors, held=held, start=start)
    if args.json:
        print(json.dumps(json_safe({"dataset": str(args.dataset), "offsets": str(args.offsets), **verdict.as_dict()}),
                         indent=1))
    else:
        print(format_arm_verdict(verdict))
    return 0 if verdict.good else 1


def parse_refit(text: str) -> tuple:
    """--refit sensors[,points][,intrinsics]: the nuisance effects beyond the sensors' frames (always refitted)."""
    from naocal.kinds.arm.verify import NUISANCE_EFFECTS
    from naocal.solver.effects import comma_list
    from naocal.solver.errors import NaocalError

    names = comma_list(text or "sensors", "--refit")
    for name in names:
        if name != "sensors" and name not in NUISANCE_EFFECTS:
            raise NaocalError(f"--refit: {name[:40]!r} is not refitted by verify (expected sensors, "
                              f"{', '.join(NUISANCE_EFFECTS)}): the arm's parameters are the calibration's")
    return tuple(n for n in dict.fromkeys(names) if n != "sensors")


def run_diagnose(args) -> int:
    from naocal.kinds.arm.diagnose import diagnose, format_diagnosis
    from naocal.kinds.arm.identify import identify_dataset
    from naocal.solver.errors import SolveError

    effects = parse_arm_effects(args.effects)
    dataset = _load(args)
    fixed, start = fixed_and_start(args, dataset, effects)
    fit = identify_dataset(dataset, effects, fixed=fixed, start=start, priors=not args.no_priors)
    from naocal.kinds.arm.identify import ran_off

    runoff = ran_off(fit)
    if runoff:  # the diagnosis of a fit that ran off would name effects for the wrong reason
        raise SolveError(runoff.replace("; nothing written", ""))
    if not fit.success:
        raise SolveError(f"the fit did not converge ({fit.message})")
    d = diagnose(fit)
    if args.json:
        print(json.dumps(json_safe(d.as_dict()), indent=1))
    else:
        print(format_diagnosis(d, args.dataset))
    return 0


def run_simulate(args) -> int:
    import shlex
    from pathlib import Path

    from naocal.agent.rundir import RunLock, entries
    from naocal.kinds.arm.sim import simulate_arm
    from naocal.kinds.arm.dataset import PYBULLET_ARMS, resolve_robot
    from naocal.solver.errors import NaocalError

    from naocal.solver.effects import comma_list

    hidden = tuple(comma_list(args.hidden, "--hidden")) if args.hidden else ()
    for h in hidden:
        if h not in ("joint_offsets", "link_lengths"):
            raise NaocalError(f"--hidden: unknown error {h!r} (expected joint_offsets, link_lengths)")
    if args.poses < 10:
        raise NaocalError("--poses: at least 10")
    if not (args.noise_m > 0 and args.noise_px > 0):
        raise NaocalError("--noise-m and --noise-px must be positive")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise NaocalError(f"{out}: already exists and is not a directory (nothing was changed)")
    if args.robot == DUALARM:
        return run_simulate_dualarm(args, out)
    dual_only = [o for o, given in (("--camera-error", args.camera_error), ("--print-scale-error",
                 args.print_scale_error is not None), ("--stance-seed", args.stance_seed is not None)) if given]
    if dual_only:
        raise NaocalError(f"{dual_only[0]}: only with --robot dualarm")
    if args.robot is None:
        raise NaocalError("--robot kuka_iiwa|franka_panda|URDF is needed with --chain")
    urdf, base, tip = resolve_robot(args.robot, args.chain)
    if base is None or tip is None:
        raise NaocalError("--chain BASE_LINK:TIP_LINK is needed for a URDF file")
    name = args.robot if args.robot in PYBULLET_ARMS else Path(args.robot).stem
    # as the NAO's simulate: one run per DIR (its lock), into a new or empty directory only
    command = shlex.join(["naocal", "simulate", "--robot", str(args.robot), "--chain", f"{base}:{tip}", "--out",
                          str(out), "--seed", str(args.seed), "--poses", str(args.poses)])
    with RunLock(out, command):
        if entries(out):
            raise NaocalError(f"{out}: already exists and is not an empty directory (nothing was changed)")
        info = simulate_arm(out, urdf, base, tip, seed=args.seed, n_poses=args.poses, noise_m=args.noise_m,
                            noise_px=args.noise_px, hidden=hidden, name=name)
    print(f"naocal simulate: wrote {out}: {info['n_observations']} observations in {info['n_poses']} poses of "
          f"{name}; hidden truth in {out / 'truth.json'}", file=sys.stdout)
    return 0


MAX_PRINT_SCALE_ERROR = 0.05  # 5 %: beyond it a print is not a misprint but the wrong size typed
DUALARM = "dualarm"  # --robot dualarm: naocal's two arms on a torso (kinds/arm/sim.py simulate_dualarm)


def run_simulate_dualarm(args, out) -> int:
    """`naocal simulate --robot dualarm`: its cameras, tracker and markers; every error it has hidden."""
    import shlex

    from naocal.agent.rundir import RunLock, entries
    from naocal.kinds.arm.sim import CAMERA_FILING_ERROR, PRINT_SCALE_ERROR, simulate_dualarm
    from naocal.solver.errors import NaocalError

    if args.chain is not None:
        raise NaocalError("--chain: the dual-arm robot's chains are its own (left, right)")
    if args.hidden != "joint_offsets,link_lengths":
        raise NaocalError("--hidden: the dual-arm robot hides joint offsets, link lengths, tool mounts and marker "
                          "positions (not chosen)")
    if args.stance_seed is not None and args.stance_seed < 0:
        raise NaocalError(f"--stance-seed: a seed, 0 or more, got {args.stance_seed}")
    print_scale_error = PRINT_SCALE_ERROR if args.print_scale_error is None else args.print_scale_error
    if not 0.0 <= print_scale_error <= MAX_PRINT_SCALE_ERROR:  # NaN refused too
        raise NaocalError(f"--print-scale-error: a relative spread in [0, {MAX_PRINT_SCALE_ERROR:g}], got "
                          f"{args.print_scale_error}")
    command = shlex.join(["naocal", "simulate", "--robot", DUALARM, "--out", str(out), "--seed", str(args.seed),
                          "--poses", str(args.poses)] + (["--camera-error"] if args.camera_error else [])
                         + ["--print-scale-error", f"{print_scale_error:g}"]
                         + (["--stance-seed", str(args.stance_seed)] if args.stance_seed is not None else []))
    with RunLock(out, command):
        if entries(out):
            raise NaocalError(f"{out}: already exists and is not an empty directory (nothing was changed)")
        info = simulate_dualarm(out, seed=args.seed, n_poses=args.poses, noise_m=args.noise_m,
                                noise_px=args.noise_px,
                                camera_error=dict(CAMERA_FILING_ERROR) if args.camera_error else None,
                                print_scale_error=print_scale_error, stance_seed=args.stance_seed)
    print(f"naocal simulate: wrote {out}: {len(info['observations'])} observations in {info['n_poses']} poses of "
          f"the dual-arm robot (chains left, right; cameras cam_left, cam_right on its torso; tracker); "
          f"{info['refused_colliding']} drawn stances refused as colliding (arms, tools, torso); hidden truth in "
          f"{out / 'truth.json'}", file=sys.stdout)
    return 0
