"""The NAO's `naocal diagnose DATASET`: compare the model with the measurements, locate where it fails, name what is
missing (the sections: KIND.diagnose_help, in diagnose's --help)."""

from __future__ import annotations

from naocal.solver.fileio import json_safe


def run(args) -> int:
    import json

    from naocal.agent.rundir import find_dataset
    from naocal.solver.effects import parse_effect_names
    from naocal.solver.fileio import check_output_directory

    effects = parse_effect_names(args.effects)
    if args.report:
        check_output_directory(args.report)
    dataset_path = find_dataset(args.dataset)
    tied = args.tie_hip_yaw_pitch is not False
    dataset, fit, diagnosis = diagnose_dataset(dataset_path, effects, angles=args.angles, fixed=args.fix, tied=tied)
    result = fit.result
    angles_contradicted = angle_check(dataset, fit, effects, args, dataset_path)
    report_path = None
    if args.report:
        report_path = write_diagnosis_report(args.report, diagnosis, dataset, dataset_path, fixed=args.fix,
                                             angles=args.angles, tied=tied)
    if args.json:
        from naocal.kinds.nao.identify import MODEL_PARAMETERS_NOTE, joint_offsets_c

        out = diagnosis.as_dict()
        out.update(fit.as_dict())
        out["joint_offsets_c"] = joint_offsets_c(result)
        out["model_parameters_note"] = MODEL_PARAMETERS_NOTE
        out["model_parameters"] = out.pop("parameters")
        out["report"] = None if report_path is None else str(report_path)
        best = next((x for x in diagnosis.candidates if x.significant and x.plausible), None)
        out["angles_contradicted"] = angles_contradicted  # None: as asked, or chosen by the fit (--angles auto)
        out["verdict"] = {"add": None if best is None or best.assumption else best.effect,  # an effect to add
                          "drop_assumption": best.effect if best is not None and best.assumption else None,
                          "remedy": None if best is None else best.remedy or None,
                          "commands": [] if best is None or best.remedy else list(next_commands(
                              diagnosis, best, dataset_path=dataset_path, fixed=args.fix, angles=args.angles,
                              tied=args.tie_hip_yaw_pitch is not False))}
        print(json.dumps(json_safe(out), indent=1))
    else:
        print(format_text(diagnosis, fit, dataset_path=dataset_path, fixed=args.fix, angles=args.angles,
                          tied=args.tie_hip_yaw_pitch is not False))
        if angles_contradicted:
            print(f"assumption contradicted: {angles_contradicted['text']}: {angles_contradicted['command']}")
        if report_path is not None:
            print(f"\nreport: {report_path}")
    return 0


def diagnose_dataset(dataset_path, effects=(), *, angles="auto", fixed=(), tied=True):
    """(the dataset, the fit, its diagnosis) of the dataset directory `dataset_path` with the model plus `effects`:
    what `naocal diagnose` prints and reports (and `naocal calibrate --report` for its run's dataset)."""
    from naocal.solver.adapter import model_data_from_dataset
    from naocal.solver.dataset import read_dataset
    from naocal.solver.diagnostics import diagnose_result
    from naocal.solver.effects import check_testable
    from naocal.solver.errors import SolveError
    from naocal.solver.fit import identify_dataset

    dataset = read_dataset(dataset_path)
    data = model_data_from_dataset(dataset)
    check_testable(effects, data, dataset_path)
    # naocal identify's routine; the moving captures stay in: they are how the time_lag candidate is tested
    fit = identify_dataset(dataset, effects, angles=angles, moving="all", fixed=fixed, tie_shared_motors=tied)
    result = fit.result
    if not result.success:
        raise SolveError(f"the fit did not converge ({result.message})")
    noise = dataset.meta.get("pixel_noise_px")
    return dataset, fit, diagnose_result(result, pixel_noise_px=noise,
                                         capture_time_s=capture_times(dataset, result))


def write_diagnosis_report(report_dir, diagnosis, dataset, dataset_path, *, fixed=(), angles="auto", tied=True):
    """Write the HTML report of `diagnosis` into `report_dir`; its "after" tables are the fits of the identify
    commands the verdict prints (identify's own options and path). Returns the report's path."""
    from naocal.tools.report import write_report

    def identify_fit(candidate):
        from naocal.kinds.nao.identify import fit_dataset, parse_options

        return fit_dataset(parse_options(identify_options(diagnosis, candidate, fixed=fixed, angles=angles,
                                                          tied=tied)), dataset)

    def identify_command(candidate):
        return next_commands(diagnosis, candidate, dataset_path=dataset_path, fixed=fixed, angles=angles,
                             tied=tied)[0]

    return write_report(report_dir, diagnosis, dataset_path=dataset_path, identify_fit=identify_fit,
                        identify_command=identify_command)


def angle_check(dataset, fit, effects, args, dataset_path) -> dict | None:
    """The angle hypothesis as an assumption: with --angles given (one hypothesis fitted), fit every hypothesis as
    `--angles auto` does; when the data prefer another one (solver.fit's choice, its margin), say which, with the
    RMS of each and the command that lets the data choose. None when the asked one is the data's choice too, or
    with --angles auto (the fit chose already: its evidence is in the COMPARE section)."""
    import shlex

    from naocal.solver.fit import HYPOTHESIS_WORDS, identify_dataset

    if args.angles == "auto":
        return None
    every = identify_dataset(dataset, effects, angles="auto", moving="all", fixed=args.fix,
                             tie_shared_motors=args.tie_hip_yaw_pitch is not False)
    if every.angles == fit.angles:
        return None
    rms = {h.mode: h.rms_px for h in every.hypotheses}
    options = model_options(args)
    return {"assumed": fit.angles, "preferred": every.angles, "rms_px": rms,
            "text": f"the joint angles are {HYPOTHESIS_WORDS[fit.angles]} (--angles {fit.angles}); the data fit "
                    f"{HYPOTHESIS_WORDS[every.angles]} better ({rms[every.angles]:.3f} px against "
                    f"{rms[fit.angles]:.3f} px)",
            "command": shlex.join(["naocal", "diagnose", str(dataset_path), *options, "--angles", "auto"])}


def model_options(args) -> list[str]:
    """The model options of this diagnose run other than --angles (for the command that lets the data choose)."""
    options = ["--effects", args.effects] if args.effects else []
    for name in args.fix:
        options += ["--fix", name]
    if args.tie_hip_yaw_pitch is False:
        options.append("--no-tie-hip-yaw-pitch")
    return options


def capture_times(dataset, result):
    """(M,) t_image_s of each image of the fitted model's data, or None if the column is missing."""
    import numpy as np

    cols = dataset.columns
    if "t_image_s" not in cols:
        return None
    ids, first = np.unique(np.asarray(cols["image"]), return_index=True)
    t = dict(zip(ids.tolist(), np.asarray(cols["t_image_s"], dtype=float)[first].tolist()))
    return np.array([t[int(i)] for i in result.model.data.image_id])


def identify_options(diagnosis, candidate, *, fixed=(), angles="auto", tied=True) -> list[str]:
    """The model options (after DATASET) that add `candidate` to this run's model: its effects plus the candidate,
    its fixed parameters plus the candidate's that these data cannot tell from the model, the same --angles and
    --tie-hip-yaw-pitch. Shared by the commands the verdict prints and the report's fit (the same fit)."""
    res = diagnosis.result
    effects = list(res.registry.extra_effects()) + ([] if candidate.assumption else [candidate.effect])
    options = ["--effects", ",".join(effects)] if effects else []
    for name in list(fixed) + [n for n in candidate.inside_model if n not in fixed]:
        options += ["--fix", name]
    if angles != "auto":
        options += ["--angles", angles]
    if not tied or candidate.effect == "untie_shared_motors":  # the option that drops the tie
        options.append("--no-tie-hip-yaw-pitch")
    return options


# where the suggested identify command stores its result (naocal identify prints, and writes only with --out)
SUGGESTED_OUT = "offsets.json"


def next_commands(diagnosis, candidate, *, dataset_path, fixed=(), angles="auto", tied=True) -> tuple[str, str]:
    """The identify and diagnose commands (shell-quoted, ready to paste) that add `candidate` to this run's model
    (`identify_options`); identify's stores the result with --out."""
    import shlex

    options = identify_options(diagnosis, candidate, fixed=fixed, angles=angles, tied=tied)
    return (shlex.join(["naocal", "identify", str(dataset_path), *options, "--out", SUGGESTED_OUT]),
            shlex.join(["naocal", "diagnose", str(dataset_path), *options]))


def format_text(diagnosis, fit=None, *, dataset_path="DATASET", fixed=(), angles="auto", tied=True) -> str:
    """The human-readable report: compare, locate, names (and, given the DatasetFit, its angle and outlier
    evidence). `dataset_path`, `fixed`, `angles` and `tied` are the run's, for the commands the verdict prints."""
    import math

    from naocal.solver.diagnostics import LOW_UNIQUENESS

    c, loc, res = diagnosis.comparison, diagnosis.location, diagnosis.result
    data = res.model.data
    extra = list(res.registry.extra_effects())
    lines = [f"model: base{''.join(' + ' + e for e in extra)}; {data.n_rows} vertices in {data.n_images} images",
             "", "COMPARE",
             f"  RMS {c.rms_px[0]:.3f} px (x), {c.rms_px[1]:.3f} px (y); {c.rms_total_px:.3f} px overall",
             f"  noise floor {c.noise_px:.3f} px: detector {c.detector_noise_px:.3f} px ("
             + ("stated by the dataset" if c.noise_source == "dataset" else "estimated from the non-rigid residual")
             + (f"), joint readings quantised to {math.degrees(c.encoder_resolution_rad):.3g} deg "
                f"{c.encoder_noise_px:.3f} px" if c.encoder_resolution_rad > 0 else "); joint readings not quantised"),
             f"  the fit is {c.ratio_to_noise:.2f} x the noise floor"
             + (": at the noise level" if c.ratio_to_noise < 1.2 else "")]
    if fit is not None:
        lines[3:3] = ["  " + fit.describe_angles(), "  " + fit.describe_outliers()
                      + (" (mis-detections, not physics, explain them)" if fit.outliers else "")]
        if fit.images_set_aside:
            lines.insert(5, "  " + fit.describe_images())
    lines.append("  per target:       " + ", ".join(
        f"{t} {v['rms_px'][0]:.3f}/{v['rms_px'][1]:.3f} px" for t, v in c.per_target.items()))
    lines.append("  per head posture: " + ", ".join(
        f"{p}: {v['rms_px'][0]:.3f}/{v['rms_px'][1]:.3f} px" for p, v in c.per_head_posture.items()))
    lines.append("  worst stances:    " + ", ".join(
        f"{s['target']}{s['stance']} {s['rms_total_px']:.3f} px" for s in loc.worst_stances[:5]))
    lines += ["", "LOCATE",
              "  worst images:     " + ", ".join(
                  f"{e['image']} ({e['target']}{e['stance']}/{e['head_posture']}) {e['rms_total_px']:.3f} px"
                  for e in loc.worst_images[:5]),
              f"  rigid board motion {loc.rigid_rms_px:.3f} px, non-rigid {loc.nonrigid_rms_px:.3f} px "
              f"({100 * loc.rigid_share:.1f} % of the misfit is rigid: "
              + ("kinematic chain" if loc.rigid_share > 0.5 else "camera model or board") + ")",
              f"  boards: {loc.board_summary}",
              "  misfit explained by a board motion proportional to:"]
    for e in loc.regressors[:6]:
        p = f"p {e['p_value']:.1e}" if math.isfinite(e["p_value"]) else "not testable: too few images carry it"
        lines.append(f"    {e['regressor']:32s} {100 * e['explained_share']:5.1f} %  ({p})")
    w = max([13] + [len(x.effect) for x in diagnosis.candidates])  # the effect column: its longest name
    lines += ["", "NAMES (candidate effects, best first; significant: p < "
              f"{diagnosis.threshold:.1e}, i.e. 0.001 over {sum(1 for x in diagnosis.candidates if x.testable)} tests)",
              "  (explains: share of the misfit it would remove beyond what its parameters fit of pure noise)",
              f"  {'effect':{w}s} {'explains':>8s} {'predicted RMS':>13s} {'p-value':>9s}  {'signif.':7s} "
              f"{'uniqueness':>10s}  note"]
    rss = c.rms_total_px ** 2 * 2 * data.n_rows
    for cand in diagnosis.candidates:
        if not cand.testable:
            lines.append(f"  {cand.effect:{w}s} {'-':>8s} {'-':>13s} {'-':>9s}  {'-':7s} {'-':>10s}  "
                         f"not testable: {cand.reason}")
            continue
        notes = []
        if cand.inside_model:
            notes.append("indistinguishable from the model: " + ", ".join(cand.inside_model[:2]))
        if cand.implausible:
            notes.append("implausible size: " + ", ".join(cand.implausible[:2]))
        if cand.stand_in and cand.significant:
            notes.append("a stand-in: hard to tell apart from the model and explains little of the misfit")
        elif cand.uniqueness < LOW_UNIQUENESS:
            notes.append("its values would correlate with the model's" if cand.significant
                         else "hard to tell apart from the model")
        if cand.significant and not notes:
            notes.append(_top_values(cand, res.registry))
        share = 100 * max(cand.excess_rss_px2, 0.0) / rss if rss > 0 else 0.0
        lines.append(f"  {cand.effect:{w}s} {share:6.1f} % {cand.predicted_rms_px:10.3f} px {cand.p_value:9.1e}  "
                     f"{'yes' if cand.significant else 'no':7s} {cand.uniqueness:10.3f}  {'; '.join(notes)}")
    best = next((x for x in diagnosis.candidates if x.significant and x.plausible), None)
    lines.append("")
    if best is None:
        unnamed = [x.effect for x in diagnosis.candidates if x.significant]
        lines.append(("verdict: no candidate effect is significant; the model explains the data" if not unnamed else
                      f"verdict: no candidate effect explains the misfit ({', '.join(unnamed)} significant but a "
                      "stand-in or of implausible size); the model explains the data")
                     + (" to the noise level." if c.ratio_to_noise < 1.5 else
                        " as far as these candidates go (the remaining misfit is something else)."))
    elif best.remedy:  # an assumption no model can drop: named, with what to do
        lines.append(f"verdict: the data contradict an assumption of the model: {best.assumption} "
                     f"({_top_values(best, res.registry)}; predicted RMS without it {best.predicted_rms_px:.3f} px): "
                     f"{best.remedy}")
    else:
        identify_command, diagnose_command = next_commands(diagnosis, best, dataset_path=dataset_path, fixed=fixed,
                                                           angles=angles, tied=tied)
        if best.assumption:
            lines.append(f"verdict: the data contradict an assumption of the model: {best.assumption} "
                         f"({_top_values(best, res.registry)}; predicted RMS without it {best.predicted_rms_px:.3f} "
                         f"px): {identify_command}")
        else:
            lines.append(f"verdict: add {best.effect} (predicted RMS {best.predicted_rms_px:.3f} px): "
                         f"{identify_command}")
        lines.append(f"  then diagnose again: {diagnose_command}")
    for warning in res.warnings:
        lines.append(f"warning: {warning}")
    return "\n".join(lines)


def _top_values(candidate, registry, count=3) -> str:
    """The candidate's largest predicted values, as its effect shows them (degrees, mm, ms ...); offsets named as c."""
    from naocal.solver.diagnostics import registry_with
    from naocal.solver.offsets import COMPENSATED_PREFIXES, shown_name

    from naocal.solver.effect import shown

    tied_to = {p.name: p.tied_to for p in registry.parameters if p.tied_to}
    registry = registry if candidate.remedy else registry_with(registry, candidate)
    items = sorted(candidate.predicted_values.items(), key=lambda kv: -abs(kv[1]))[:count]
    parts = []
    for name, value in items:
        value, unit = registry.display(name, value) if name in registry.index else shown(value, "m")
        label = shown_name(name) if name.startswith(COMPENSATED_PREFIXES) else name.split(".", 1)[1]
        if candidate.assumption and name in tied_to:  # untied: the step is how far it moves from its partner
            label += " - " + shown_name(tied_to[name])
        parts.append(f"{label} {value:+.3g}{' ' + unit if unit else ''}")
    return "predicted " + ", ".join(parts)
