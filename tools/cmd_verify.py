"""`naocal verify DATASET --offsets FILE`: is a calibration still good on new data? (its values are not refitted)"""

EXIT_GOOD, EXIT_DRIFTED = 0, 1


def register(subparsers):
    p = subparsers.add_parser(
        "verify",
        help="the residuals of new data under a fixed calibration: still good, or drifted (and what moved)",
        description=(
            "Evaluate a naocal.dataset/2 (or /1) under the calibration of a naocal.offsets/2 (or /1) file without "
            "refitting it, after setting aside what identify sets aside (moving captures, mis-detected corners and "
            "images): RMS, median, 95th percentile and maximum pixel error overall, per camera, per target and per "
            "image, against the calibration's own RMS and the data's noise floor. Verdict 'still good' or 'drifted' "
            "(the RMS beyond 1.5 x both, or a calibrated value moved by 5 standard deviations), naming the joints, "
            "cameras or boards whose calibrated values the new data say have moved. Exit 0 still good, 1 drifted, "
            "2 bad input (docs/DIAGNOSTICS.md). An arm's naocal.arm_dataset/1 under its naocal.arm_calibration/1: "
            "per sensor and pose, drifted on the RMS (docs/ARM.md)."
        ),
    )
    p.add_argument("dataset", metavar="DATASET",
                   help="naocal.dataset/2 (or /1) directory of new captures, or a `naocal calibrate --out` run")
    p.add_argument("--offsets", required=True, metavar="FILE",
                   help="the calibration: naocal.offsets/2 (or /1); an arm's naocal.arm_calibration/1")
    p.add_argument("--json", action="store_true", help="print one JSON object (docs/DIAGNOSTICS.md) instead of text")
    from tools.cmd_identify import add_angles_option

    add_angles_option(p)
    from tools.arm_cli import add_arm_options

    add_arm_options(p)  # an arm (docs/ARM.md): DATASET a naocal.arm_dataset/1, FILE a naocal.arm_calibration/1
    p.set_defaults(run=run)


def run(args) -> int:
    import json

    from solver.arm_calibration import is_arm_calibration
    from tools.arm_cli import run_verify, wants_arm

    if wants_arm(args) or is_arm_calibration(args.offsets):
        return run_verify(args)

    from agent.rundir import find_dataset
    from solver.dataset import read_dataset
    from solver.offsets import read_offsets
    from solver.robot import load_robot
    from solver.verify import check_same_robot, verify_dataset

    offsets = read_offsets(args.offsets)
    dataset = read_dataset(find_dataset(args.dataset))  # (both read through solver.fileio: regular files, capped)
    check_same_robot(offsets, args.offsets, dataset.meta,
                     load_robot(dataset.as_v2().meta["robot"].get("description", "nao")))
    result = verify_dataset(dataset, offsets, angles=args.angles, pixel_noise_px=dataset.meta.get("pixel_noise_px"))
    if args.json:
        print(json.dumps({"dataset": str(args.dataset), "offsets": str(args.offsets), **result.as_dict()}, indent=1))
    else:
        print(format_text(result))
    return EXIT_GOOD if result.good else EXIT_DRIFTED


def format_text(result) -> str:
    from solver.verify import moved_text

    def stats(s):
        return (f"RMS {s['rms_px']:.3f} px, median {s['median_px']:.3f}, p95 {s['p95_px']:.3f}, "
                f"max {s['max_px']:.3f} px ({s['n_vertices']} vertices)")

    lines = [f"overall: {stats(result.overall)}"]
    if result.outliers or result.images_set_aside or result.n_moving_set_aside:
        lines.append(f"before anything was set aside: {stats(result.all_corners)}")
    if result.calibration_rms_px is not None:
        lines.append(f"the calibration's own fit: RMS {result.calibration_rms_px:.3f} px")
    lines.append(f"noise floor of these data: {result.noise_floor_px:.3f} px ({result.noise_source})")
    lines += [f"camera {c}: {stats(s)}" for c, s in result.per_camera.items()]
    lines += [f"target {t}: {stats(s)}" for t, s in result.per_target.items()]
    if result.worst_images:
        lines.append("worst images: " + ", ".join(f"{e['image']} ({e['target']}, {e['rms_px']:.2f} px)"
                                                  for e in result.worst_images))
    lines += [moved_text(e) for e in result.moved]
    if result.board_summary:
        lines.append(result.board_summary)
    lines += [f"warning: {w}" for w in result.warnings]
    if result.angles:
        lines.append(result.angles)
    from solver.fit import describe_outliers
    from solver.image_check import describe_set_aside

    lines.append(describe_outliers(result.outliers, result.robust_scale_px) + " (as identify sets them aside)")
    if result.images_set_aside:
        lines.append(describe_set_aside(result.images_set_aside))
    if result.n_moving_set_aside:
        lines.append(f"{result.n_moving_set_aside} captures taken while moving set aside (the calibration has no "
                     "time_lag: as identify)")
    lines.append(result.verdict)
    return "\n".join(lines)
