"""Joint names and their order. This order is the column order of every (..., 14) joint-angle array in naocal."""

HEAD_JOINTS = ("HeadYaw", "HeadPitch")
LEG_JOINT_SUFFIXES = ("HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")
LEFT_LEG_JOINTS = tuple("L" + s for s in LEG_JOINT_SUFFIXES)
RIGHT_LEG_JOINTS = tuple("R" + s for s in LEG_JOINT_SUFFIXES)
LEG_JOINTS = LEFT_LEG_JOINTS + RIGHT_LEG_JOINTS
JOINTS = HEAD_JOINTS + LEG_JOINTS  # the dataset's 14 joints, in the dataset's order
JOINT_INDEX = {name: i for i, name in enumerate(JOINTS)}
LEGS = ("L", "R")


def leg_joints(leg: str) -> tuple[str, ...]:
    """The six joints of leg 'L' or 'R', hip to ankle."""
    if leg == "L":
        return LEFT_LEG_JOINTS
    if leg == "R":
        return RIGHT_LEG_JOINTS
    raise ValueError(f"unknown leg {leg!r}: expected 'L' or 'R'")
