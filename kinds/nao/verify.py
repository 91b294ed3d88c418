"""The NAO's `naocal verify DATASET --offsets FILE` (the verb: tools/cmd_verify.py): is a calibration still good on
new data? (its values are not refitted)"""

EXIT_GOOD, EXIT_DRIFTED = 0, 1


def run(args) -> int:
    import json

    from naocal.agent.rundir import find_dataset
    from naocal.solver.dataset import read_dataset
    from naocal.solver.offsets import read_offsets
    from naocal.solver.robot import load_robot
    from naocal.solver.verify import check_same_robot, verify_dataset

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
    from naocal.solver.verify import moved_text

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
    from naocal.solver.fit import describe_outliers
    from naocal.solver.image_check import describe_set_aside

    lines.append(describe_outliers(result.outliers, result.robust_scale_px) + " (as identify sets them aside)")
    if result.images_set_aside:
        lines.append(describe_set_aside(result.images_set_aside))
    if result.n_moving_set_aside:
        lines.append(f"{result.n_moving_set_aside} captures taken while moving set aside (the calibration has no "
                     "time_lag: as identify)")
    lines.append(result.verdict)
    return "\n".join(lines)
