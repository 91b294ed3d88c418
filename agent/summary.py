"""summary.txt: what a calibration run did and found, readable by a person."""

from __future__ import annotations

import math

import numpy as np

from naocal.solver.joints import LEG_JOINTS, LEGS

PAPER_ROBOT_TIME_S = 590.0  # Kastner, Roefer, Laue: the real robot's measurement phase


def _deg(x) -> float:
    return math.degrees(float(x))


def describe_direction(direction, top=4) -> str:
    """A weak direction in the words of the tables: offsets named as c (the parameters are c)."""
    from naocal.solver.offsets import shown_name

    terms = sorted(direction.coefficients.items(), key=lambda kv: -abs(kv[1]))[:top]
    return " ".join(f"{c:+.2f} {shown_name(n)}" for n, c in terms)


def resumable(result) -> bool:
    """Would `--resume` get further? Yes after an error or Ctrl-C in any state (captures are kept, the rest is
    redone); not after an implausible identification (the same data give the same fit)."""
    return not result.ok and bool(result.history) and result.history[-1].outcome in ("error", "interrupted")


def summary_text(ctx, result, *, backend_label: str, truth: dict | None = None) -> str:
    lines = [f"naocal calibrate: {result.final}" + (f" - {result.reason}" if result.reason else ""), ""]
    if resumable(result):
        how = ctx.settings.resume_command or "the same command with --resume"
        lines += [f"to continue (captures already saved are kept, not repeated): {how}", ""]
    meta = ctx.meta or {}
    robot = meta.get("robot", {})
    lines.append(f"robot: {robot.get('id', '?')} ({robot.get('model', '?')}), backend {backend_label}")
    if ctx.plan is not None:
        st = ctx.plan.stats
        n_st = st.get("n_stances", {})
        lines.append(f"plan: {ctx.plan.kind}, seed {ctx.plan.seed}: {ctx.plan.n_images()} images "
                     f"({st.get('n_still_images', '?')} still, {st.get('n_probe_images', 0)} in the lag probe), "
                     f"stances L {n_st.get('L', '?')}, R {n_st.get('R', '?')}")
        design = st.get("design")
        if design:
            if design.get("target_worst_std_deg") is not None:
                lines.append(f"  D-optimal: {design['selected_stances']} stances from a pool of {design['pool_stances']}"
                             f", until the predicted worst joint-offset std reaches "
                             f"{design['target_worst_std_deg']:g} deg (the paper plan: {design['paper_stances']})")
            else:
                lines.append(f"  D-optimal: {design['selected_stances']} stances reach the precision of the paper "
                             f"plan's {design['paper_stances']} (from a pool of {design['pool_stances']})")
    m = ctx.measurement
    if m:
        lines.append(f"measurement: {m['n_saved']} of {m['n_planned']} images saved, {m['n_skipped']} skipped, "
                     f"robot time {m['robot_time_s']:.1f} s (the paper's robot: {PAPER_ROBOT_TIME_S:.0f} s), "
                     f"{m['sessions']} session(s)")
        for image, reason in sorted(m["skipped"].items()):
            lines.append(f"  skipped image {image}: {reason}")
    elif getattr(ctx, "store", None) is not None and ctx.plan is not None:  # stopped during the measurement
        store = ctx.store
        saved = store.saved_images() & set(ctx.plan.image_indices())
        lines.append(f"measurement (not finished): {len(saved)} of {ctx.plan.n_images()} images saved in "
                     f"{ctx.dataset_dir}, {len(store.skipped_images())} skipped")
    res = ctx.identification
    if res is not None:
        lines += ["", f"fit: RMS {res.rms_px[0]:.3f} px (x), {res.rms_px[1]:.3f} px (y) over {res.model.data.n_rows} "
                      f"vertices in {res.model.data.n_images} still images; {res.iterations} iterations, "
                      f"{res.solve_time_s * 1e3:.0f} ms; condition number {res.condition_number:.3g}"]
        choice = getattr(ctx, "angle_choice", None)
        if choice is not None:
            lines.append(f"  {choice.describe()}")
        std = {n: float(s) for n, s in zip(res.registry.names, res.std)}
        weakest_joint = max(LEG_JOINTS, key=lambda j: std[f"joint_offset.{j}"])
        robot_s = f", in {m['robot_time_s']:.1f} s of robot time" if m else ""
        lines.append(f"precision: worst joint-offset std {_deg(std[f'joint_offset.{weakest_joint}']):.4f} deg "
                     f"({weakest_joint}){robot_s}")
        lines.append("joint offsets c (stored; ADDED to commands, SUBTRACTED from readings; c = -alpha):")
        for j in LEG_JOINTS:
            name = f"joint_offset.{j}"  # the parameter is c
            lines.append(f"  {j:14s} c = {_deg(res.value(name)):+8.4f} deg   std {_deg(std[name]):.4f} deg")
        for camera in res.registry.setup.cameras:  # every camera the data use (the NAO: bottom, and top)
            lines.append(f"{camera} camera rotation (alpha of Eq. 3):")
            for a in ("roll", "pitch", "yaw"):
                name = f"camera.{camera}.{a}"
                lines.append(f"  {a:14s} {_deg(res.value(name)):+8.4f} deg   std {_deg(std[name]):.4f} deg")
        lines.append("board mount (alpha of Eq. 4):")
        for leg in LEGS:
            rz, x, y = (f"board.{leg}.{k}" for k in ("rot_z", "trans_x", "trans_y"))
            lines.append(f"  {leg}: rot_z {_deg(res.value(rz)):+.3f} deg (std {_deg(std[rz]):.3f}), "
                         f"x {res.value(x) * 1e3:+.2f} mm (std {std[x] * 1e3:.2f}), "
                         f"y {res.value(y) * 1e3:+.2f} mm (std {std[y] * 1e3:.2f})")
        weakest = min(res.weak_directions, key=lambda w: w.singular_value) if res.weak_directions else None
        if weakest is not None:
            lines.append(f"weakest direction (relative singular value {weakest.singular_value:.2e}): "
                         f"{describe_direction(weakest)}")
        for warning in res.warnings:
            lines.append(f"warning: {warning}")
    v = ctx.verification
    if v is not None:
        lines += [""] + verification_lines(v, res)
    if truth and res is not None:
        lines += ["", "against the mock's hidden truth (truth.json):"]
        lines += truth_comparison(res, truth)
    if result.history:
        lines += ["", "states: " + ", ".join(f"{h.state} {h.outcome} ({h.wall_s:.1f} s wall"
                                             + (f", {h.robot_s:.1f} s robot" if np.isfinite(h.robot_s) else "") + ")"
                                             for h in result.history)]
    return "\n".join(lines) + "\n"


def verification_lines(v, fit=None) -> list[str]:
    """The verification's numbers (agent.verify.VerificationReport) and what they are: held-out captures, errors
    before and after compensation without the mis-detections identify sets aside (and with them), and why the error
    after compensation is not the fit's RMS."""
    lines = ["verification: the robot re-measured stances the fit did not use (held out), each twice: raw, then "
             "through the offsets (compensated). Held-out error = RMS over both coordinates (as the fit's) of the "
             "detected board corners against the identified camera and boards with nominal joints, at the joint "
             "readings (corrected by the offsets after compensation) and at the commanded angles:"]
    for leg, entry in v.per_leg.items():
        b, a = entry["before"], entry["after"]
        n = entry["n_stances"]
        lines.append(f"  leg {leg} ({n} stance{'s' if n != 1 else ''}): at the joint readings "
                     f"{b['reading_rms_px']:.2f} -> {a['reading_rms_px']:.2f} px; at the commanded angles "
                     f"{b['command_rms_px']:.2f} -> {a['command_rms_px']:.2f} px (before -> after compensation)")
    for phase, aside in v.set_aside.items():
        if aside["n_corners"]:
            with_them = ", ".join(f"leg {leg} {e[phase]['all_reading_rms_px']:.2f} / "
                                  f"{e[phase]['all_command_rms_px']:.2f}" for leg, e in v.per_leg.items())
            lines.append(f"  set aside as mis-detections ({'raw' if phase == 'before' else 'compensated'} captures), "
                         f"as identify sets them aside: {aside['n_corners']} of {aside['of_corners']} corners; with "
                         f"them the errors at the readings / commands would be {with_them} px")
    for s in v.skipped:
        lines.append(f"  skipped {s['leg']} stance {s['stance']} ({s['phase']}): {s['reason']}")
    if fit is not None:
        rms = math.sqrt((fit.rms_px[0] ** 2 + fit.rms_px[1] ** 2) / 2)
        lines.append(f"  the fit's own RMS, {rms:.3f} px (both coordinates), is minimised on its own "
                     f"{fit.model.data.n_images} captures; after compensation the held-out error at the readings "
                     "is comparable to it once mis-detections are set aside (in both, a reading is off by up to "
                     "half its encoder step, which moves the whole board); at the commanded angles it is larger: "
                     "a servo rests anywhere in its step and sags under load")
    return lines


def truth_errors(result, truth: dict) -> dict:
    """Identified minus true model values: {"joint_offset_deg": {joint: e}, "camera_deg": {camera: {a: e}},
    "board": {leg: {"rot_z_deg", "trans_x_mm", "trans_y_mm"}}} for the cameras the fit has. `truth` is
    naocal.truth/2 (camera_rotation_rad keyed by camera) or /1 (one {roll, pitch, yaw}: the bottom camera's)."""
    alpha = truth.get("alpha_rad", {})
    out = {"joint_offset_deg": {}, "camera_deg": {}, "board": {}}
    for j in LEG_JOINTS:
        if j in alpha:  # the parameter is c = -alpha
            out["joint_offset_deg"][j] = _deg(-result.value(f"joint_offset.{j}") - alpha[j])
    cams = truth.get("camera_rotation_rad", {})
    if "pitch" in cams:  # naocal.truth/1
        cams = {"bottom": cams}
    for camera in result.registry.setup.cameras:
        cam = cams.get(camera, {})
        errors = {a: _deg(result.value(f"camera.{camera}.{a}") - cam[a]) for a in ("roll", "pitch", "yaw") if a in cam}
        if errors:
            out["camera_deg"][camera] = errors
    for leg in LEGS:
        mount = truth.get("board_mount", {}).get(leg)
        if mount:
            out["board"][leg] = {
                "rot_z_deg": _deg(result.value(f"board.{leg}.rot_z") - mount["rot_z_rad"]),
                "trans_x_mm": (result.value(f"board.{leg}.trans_x") - mount["trans_x_m"]) * 1e3,
                "trans_y_mm": (result.value(f"board.{leg}.trans_y") - mount["trans_y_m"]) * 1e3,
            }
    return out


def truth_comparison(result, truth: dict) -> list[str]:
    err = truth_errors(result, truth)
    lines = []
    joints = err["joint_offset_deg"]
    if joints:
        worst = max(joints, key=lambda j: abs(joints[j]))
        lines.append(f"  joint offsets: largest error {joints[worst]:+.4f} deg ({worst}), RMS "
                     f"{math.sqrt(np.mean(np.square(list(joints.values())))):.4f} deg")
        z = {j: abs(e) / math.degrees(result.std[result.registry.index[f"joint_offset.{j}"]]) for j, e in joints.items()
             if result.std[result.registry.index[f"joint_offset.{j}"]] > 0}
        if z:
            most = max(z, key=z.get)
            lines.append(f"  joint offsets: largest error in standard deviations {z[most]:.2f} ({most})")
    for camera, errors in err["camera_deg"].items():
        lines.append(f"  {camera} camera rotation error: " + ", ".join(f"{a} {e:+.4f} deg" for a, e in errors.items()))
    for leg, e in err["board"].items():
        lines.append(f"  board {leg} error: rot_z {e['rot_z_deg']:+.3f} deg, x {e['trans_x_mm']:+.3f} mm, "
                     f"y {e['trans_y_mm']:+.3f} mm")
    effects = truth.get("effects") or {}
    if effects:
        lines.append("  injected effects (not in the paper's model): "
                     + ", ".join(f"{k}={v}" for k, v in effects.items()))
    return lines
