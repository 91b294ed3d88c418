"""The body of `naocal diagnose LOG [--effects E1,E2] [--lens MODEL] [--json]` on a Duckiebot drive log: the
mission's loop (kinds.duckiebot.drive_diagnostics: compare, locate, name the missing effect, add it). Imported to
build the command line: argparse only at import; the engine is imported by the body.
"""

from __future__ import annotations

# kinds.duckiebot.intrinsics.LENS_MODELS (not imported here: it imports cv2; a test keeps them alike)
LENS_CHOICES = ("plumb_bob", "rational", "fisheye")


def add_options(parser) -> None:
    """`naocal diagnose`'s Duckiebot options (LOG, --effects and --json are the verb's own)."""
    parser.add_argument("--lens", choices=LENS_CHOICES, default="plumb_bob",
                        help="Duckiebot: the lens model the marker corners are rectified with (default plumb_bob, "
                             "what Duckietown's files hold)")


def parse_effects(text) -> tuple:
    """'dead_zone,slip' -> the wheel effects (the registry's differential-drive effects, solver/effects/ with
    drive_parameters: fit.ALL_EFFECTS, in the registry's order; pwm_driver, Duckietown's wheel driver, a choice of
    model); NaocalError naming an unknown one."""
    from naocal.kinds.duckiebot.fit import ALL_EFFECTS
    from naocal.solver.effects import comma_list
    from naocal.solver.errors import NaocalError

    if not text:
        return ()
    names = comma_list(text, "--effects")
    for name in names:
        if name not in ALL_EFFECTS:
            raise NaocalError(f"--effects: unknown Duckiebot effect {name!r} (expected {', '.join(ALL_EFFECTS)})")
    return tuple(e for e in ALL_EFFECTS if e in names)


def run_diagnose(args) -> int:
    import json

    from naocal.kinds.duckiebot.drive_diagnostics import diagnose_log, format_diagnosis
    from naocal.solver.fileio import json_safe

    effects = parse_effects(getattr(args, "effects", ""))
    diagnosis = diagnose_log(args.dataset, effects, getattr(args, "lens", "plumb_bob"))
    if getattr(args, "json", False):
        print(json.dumps(json_safe(diagnosis.as_dict()), indent=1))
    else:
        print(format_diagnosis(diagnosis, args.dataset))
    return 0
