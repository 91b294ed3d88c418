"""The NAO's `naocal identify DATASET`: fit the model to a dataset and print (or save) the parameters."""

from __future__ import annotations

import argparse


def run(args) -> int:
    import json

    from naocal.agent.rundir import dataset_files, find_dataset
    from naocal.solver.adapter import model_data_from_dataset
    from naocal.solver.dataset import read_dataset
    from naocal.solver.effects import check_testable, parse_effect_names
    from naocal.solver.errors import NaocalError, SolveError
    from naocal.solver.fileio import check_output_file
    from naocal.solver.offsets import implausible_parameters

    if not 0 < args.loss_scale_px < float("inf"):  # (also refuses nan)
        raise NaocalError(f"--loss-scale-px must be a positive number, got {args.loss_scale_px}")
    effects = parse_effect_names(args.effects)
    dataset_path = find_dataset(args.dataset)
    if args.out:
        check_output_file(args.out, inputs=dataset_files(dataset_path))
    dataset = read_dataset(dataset_path)
    data = model_data_from_dataset(dataset)
    check_testable(effects, data, dataset_path)
    fit = fit_dataset(args, dataset)
    result, data = fit.result, fit.data
    if not result.success:
        raise SolveError(f"the solve did not converge ({result.message}); nothing written")
    why = implausible_parameters(result.parameters_dict())
    if why:
        raise SolveError(f"implausible result: {why}; nothing written")

    cv_rms = None
    if args.cv_folds and args.cv_folds > 1:
        from naocal.solver.crossval import grouped_cv_rms

        cv_rms = grouped_cv_rms(data, result.registry, n_folds=args.cv_folds)

    if args.out:
        write_offsets_file(args.out, result, dataset, dataset_path)

    if args.json:
        report = result_json(result, effects, cv_rms)
        report.update(fit.as_dict(), angles=fit.describe_angles(), angle_choice=fit.as_dict()["angles"])
        print(json.dumps(report, indent=1))
    else:
        print(fit.describe_angles())
        print(fit.describe_outliers())
        if fit.images_set_aside:
            print(fit.describe_images())
        if fit.n_moving_set_aside:
            print(f"{fit.n_moving_set_aside} captures taken while moving set aside (only --effects time_lag models "
                  "them)")
        print(format_table(result, cv_rms, args.out))
    return 0


def fit_dataset(args, dataset):
    """The fit `naocal identify` makes of a read dataset with these options (solver.fit.DatasetFit): the one place
    that turns identify's options into a fit (run, and diagnose's report for the command it suggests)."""
    from naocal.solver.effects import parse_effect_names
    from naocal.solver.fit import identify_dataset

    return identify_dataset(dataset, parse_effect_names(args.effects), angles=args.angles,
                            robust=not args.keep_outliers, fixed=args.fix,
                            tie_shared_motors=args.tie_hip_yaw_pitch is not False, solver=args.solver, loss=args.loss,
                            loss_scale_px=args.loss_scale_px, gls=args.gls and args.loss == "linear")


def parse_options(options) -> argparse.Namespace:
    """identify's options (the words after DATASET, e.g. of a command diagnose suggests) as `run` would see them."""
    from naocal.kinds.nao.options import add_options
    from naocal.tools.verb_options import add_identify_options

    parser = argparse.ArgumentParser(prog="naocal identify")
    add_identify_options(parser)
    add_options(parser, "identify")
    return parser.parse_args(["DATASET", *options])


def result_json(result, effects, cv_rms) -> dict:
    import numpy as np

    free = list(result.registry.free_names)
    return {
        "success": result.success,
        "message": result.message,
        "rms_px": list(result.rms_px),
        "cv_rms_px": None if cv_rms is None else [float(v) for v in cv_rms],
        "solve_time_s": result.solve_time_s,
        "iterations": result.iterations,
        "function_evaluations": result.function_evaluations,
        "effects": list(effects),
        "n_vertices": int(result.model.data.n_rows),
        "n_images": int(result.model.data.n_images),
        "joint_offsets_c": joint_offsets_c(result),
        "model_parameters_note": MODEL_PARAMETERS_NOTE,
        "model_parameters": result.parameters_dict(),
        "condition_number": result.condition_number,
        "weak_directions": [
            {"singular_value": w.singular_value, "coefficients": w.coefficients} for w in result.weak_directions
        ],
        "correlation": {"names": free, "matrix": np.round(np.nan_to_num(result.correlation), 4).tolist()},
        "downweighted_images": result.downweighted_images,
        "warnings": result.warnings,
    }


MODEL_PARAMETERS_NOTE = ("model values: joint_offset.<J> and head_offset.<J> are the stored offset c "
                         "(q_true = theta - c), as in joint_offsets_c")


def joint_offsets_c(result) -> dict:
    """{joint: {"c_rad", "std_rad", "fixed"}}: the compensation offsets c, as offsets.json stores them (the
    parameters joint_offset.<J> and head_offset.<J> are c)."""
    from naocal.solver.offsets import COMPENSATED_PREFIXES

    out = {}
    for name, entry in result.parameters_dict().items():
        if name.startswith(COMPENSATED_PREFIXES):
            out[name.split(".", 1)[1]] = {"c_rad": entry["value"], "std_rad": entry["std"],
                                          "fixed": name in result.registry.fixed}
    return out


def format_offsets_c(result, out=None) -> list[str]:
    """The joint offsets as the table every naocal command prints: c, labelled, in degrees; `out` the file they
    were stored in (None: not stored, and the table says how to)."""
    import math

    stored = f"stored in {out}" if out else "not stored: --out FILE writes them"
    lines = [f"joint offsets c ({stored}; ADDED to commands, SUBTRACTED from readings; q_true = theta - c):"]
    for joint, entry in joint_offsets_c(result).items():
        fixed = "  (fixed)" if entry["fixed"] else ""
        lines.append(f"  {joint:14s} c = {math.degrees(entry['c_rad']):+8.4f} deg   "
                     f"std {math.degrees(entry['std_rad']):.4f} deg{fixed}")
    return lines


def format_table(result, cv_rms, out=None) -> str:
    from naocal.agent.summary import describe_direction
    from naocal.solver.diagnostics import implausibility
    from naocal.solver.offsets import COMPENSATED_PREFIXES

    lines = [
        f"fit: RMS {result.rms_px[0]:.3f} px (x), {result.rms_px[1]:.3f} px (y) over "
        f"{result.model.data.n_rows} vertices in {result.model.data.n_images} images; "
        f"{result.iterations} iterations, {result.solve_time_s * 1e3:.1f} ms",
    ]
    if cv_rms is not None:
        lines.append(f"cross-validated (whole stances held out): RMS {cv_rms[0]:.3f} px (x), {cv_rms[1]:.3f} px (y)")
    lines.append("")
    lines += format_offsets_c(result, out)
    lines.append("")
    lines.append("other parameters (model values: camera rotation and board mount corrections of Eq. 3-4, effects):")
    lines.append(f"{'parameter':30s} {'value':>12s} {'std':>10s}  unit")
    for name, entry in result.parameters_dict().items():
        if name.startswith(COMPENSATED_PREFIXES):  # an offset: in the c table above
            continue
        value, unit = result.registry.display(name, entry["value"])
        std, _ = result.registry.display(name, entry["std"])
        fixed = "  (fixed)" if name in result.registry.fixed else ""
        why = implausibility(result, name)
        lines.append(f"{name:30s} {value:12.4f} {std:10.4f}  {unit}{fixed}" + (f"  {why}" if why else ""))
    lines.append("")
    lines.append(f"condition number (scaled Jacobian): {result.condition_number:.3g}")
    lines.append("weakest directions (what the data determine least; why repeated runs can differ):")
    for w in result.weak_directions:
        lines.append(f"  relative singular value {w.singular_value:.2e}: {describe_direction(w)}")
    strong = strongest_correlations(result)
    if strong:
        lines.append("strongest correlations:")
        lines.extend(f"  {a} ~ {b}: {c:+.3f}" for a, b, c in strong)
    if result.downweighted_images:
        lines.append(f"down-weighted by the robust loss: images {result.downweighted_images}")
    for warning in result.warnings:
        lines.append(f"warning: {warning}")
    return "\n".join(lines)


def strongest_correlations(result, count=5, threshold=0.8):
    """The strongest correlations between free parameters, offsets named as c (as the tables show them)."""
    import numpy as np

    from naocal.solver.offsets import shown_name

    C = np.nan_to_num(result.correlation)
    names = [shown_name(n) for n in result.registry.free_names]
    pairs = [(abs(C[i, j]), names[i], names[j], C[i, j]) for i in range(len(names)) for j in range(i)]
    pairs.sort(reverse=True)
    return [(a, b, c) for m, a, b, c in pairs[:count] if m >= threshold]


def write_offsets_file(path, result, dataset, dataset_path):
    from naocal.solver.offsets import offsets_from_result, write_offsets

    robot_meta = dataset.meta.get("robot", {})
    robot = {key: str(robot_meta.get(key, robot_meta.get("id", "unknown"))) for key in ("id", "body_id", "head_id")}
    offsets = offsets_from_result(result, robot=robot, source={
        "tool": "naocal identify", "dataset": str(dataset_path), "dataset_source": dataset.meta.get("source")})
    write_offsets(offsets, path)
