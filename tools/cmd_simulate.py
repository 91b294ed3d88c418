"""`naocal simulate`: record a dataset of the simulated NAO, with its hidden truth beside it.

    naocal simulate --out DIR [--seed N] [--effect NAME=SIZE ...] [--mock ideal|realistic]
    naocal simulate --robot kuka_iiwa|franka_panda|URDF [--chain BASE:TIP] --out DIR [--seed N] [--poses N]
        a simulated arm instead (docs/ARM.md): naocal.arm_dataset/1 and its hidden truth in DIR/truth.json

Runs the agent's modelling and measurement (the standard plan: 24 stances per leg x 3 head postures, plus the lag
probe) on the PyBullet mock and writes the naocal.dataset/2 directory DIR (dataset.json, observations.csv,
images/) and DIR/truth.json (naocal.truth/2: the mock's alpha, camera rotations, board mounts and effects; with
--effect also DIR/truth_effects.json: what each effect drew, e.g. camera_translation's shift of each camera).
Exit 0 on success, 2 on bad input, 3 if the measurement failed.
"""

import argparse

import naocal.kinds as kinds
def register(subparsers):
    p = subparsers.add_parser(
        "simulate", help="record a dataset of the simulated NAO (with its hidden truth in truth.json)",
        description=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, metavar="DIR", help="the dataset directory to create")
    p.add_argument("--seed", type=int, default=0, help="seed of the mock's hidden truth and of the plan (default 0)")
    kinds.add_options(p, "simulate")  # the NAO's (mock, plan ...) and an arm's (--robot, --poses ...)
    p.set_defaults(run=run)


def run(args) -> int:
    return kinds.for_args(args).simulate(args)
