"""The body of `naocal simulate --robot duckiebot --seed N --out LOG [--hidden-effects dead_zone=0.08,slip=...]`: a log
(naocal.drive_log/1) of a hidden Duckiebot rendered by the independent OpenCV renderer (kinds.duckiebot.render), its
truth in LOG/truth.json; for the mission's loop (`naocal diagnose LOG`, kinds.duckiebot.diagnose).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

# A hidden effect's value when --hidden-effects names it without one (the parameter of fit.EFFECTS, SI units; for
# wide_lens any value: render.hidden_robot's fisheye; pwm_driver: on above 0, Duckietown's wheel driver): each well above what the joint fit resolves, well inside what
# a worn Duckiebot shows. Here, not in render.py: this module is imported to build the command line (argparse only).
HIDDEN_DEFAULTS = {"dead_zone": 0.08, "slip": 0.5, "wheel_lag": 0.08, "speed_trim": 0.08, "pwm_driver": 1.0,
                   "wide_lens": 1.0}


def add_options(parser) -> None:
    """--hidden-effects (argparse only). Not `--hidden`: the arm's kind adds that one to the same parser (with its own
    default), and a Duckiebot's verb refuses another kind's options."""
    parser.add_argument("--hidden-effects", default="", metavar="NAME[=VALUE],...",
                        help="Duckiebot: hidden effects, e.g. dead_zone=0.08,slip=0.5 ("
                             + ", ".join(f"{k} default {v:g}" for k, v in HIDDEN_DEFAULTS.items()) + ")")


def parse_hidden(text) -> dict:
    """'dead_zone=0.08,slip' -> {'dead_zone': 0.08, 'slip': HIDDEN_DEFAULTS['slip']}; NaocalError naming what is
    wrong."""
    import math

    from naocal.solver.effects import comma_list
    from naocal.solver.errors import NaocalError

    hidden = {}
    for item in comma_list(text, "--hidden-effects") if text else ():
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in HIDDEN_DEFAULTS:
            raise NaocalError(f"--hidden-effects: unknown Duckiebot effect {name!r} "
                              f"(expected {', '.join(HIDDEN_DEFAULTS)})")
        try:
            number = float(value) if value.strip() else HIDDEN_DEFAULTS[name]
        except ValueError:
            raise NaocalError(f"--hidden-effects: {name}={value!r} is not a number") from None
        if not math.isfinite(number) or number < 0:
            raise NaocalError(f"--hidden-effects: {name}={value} must be a finite number >= 0")
        if name == "dead_zone" and number >= 0.2:  # the program's one-wheel steps (duty 0.25) must still move
            raise NaocalError(f"--hidden-effects: dead_zone={value} must be below 0.2 (the drive's smallest duty "
                              "is 0.25)")
        hidden[name] = number
    return hidden


def run_simulate(args) -> int:
    """Render the drive log of hidden robot `args.seed` with `args.hidden_effects` into the new or empty `args.out`, and
    its truth (kinematics, lens, camera pose, hidden effects) into LOG/truth.json."""
    from naocal.agent.rundir import RunLock, entries
    from naocal.kinds.duckiebot.render import diagnose_program, hidden_robot, render_drive_log
    from naocal.solver.errors import NaocalError
    from naocal.solver.fileio import atomic_write_text

    hidden = parse_hidden(args.hidden_effects)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise NaocalError(f"{out}: already exists and is not a directory (nothing was changed)")
    with RunLock(out, f"naocal simulate --robot duckiebot --seed {args.seed} --out {out}"):
        if entries(out):
            raise NaocalError(f"{out}: already exists and is not an empty directory (nothing was changed)")
        rendered = render_drive_log(out, seed=args.seed, steps=diagnose_program(), robot_id=f"hidden{args.seed}",
                                    hidden=hidden)
        truth = {"schema": "naocal.duckiebot_truth/1", "seed": args.seed, "hidden": hidden,
                 **hidden_robot(args.seed, hidden).truth()}
        atomic_write_text(out / "truth.json", json.dumps(truth, indent=1) + "\n")
    print(f"naocal simulate: wrote {out}: a drive log of {len(rendered.log.frame_files)} frames of hidden Duckiebot "
          f"seed {args.seed}" + (f" with {', '.join(f'{k}={v:g}' for k, v in hidden.items())}" if hidden else "")
          + f"; hidden truth in {out / 'truth.json'}", file=sys.stdout)
    return 0
