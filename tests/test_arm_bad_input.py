"""An arm's files, bad numbers (issue 21): every numeric field of naocal.arm_calibration/1 is checked where it is
read, named in one line (exit 2) by every verb that reads the file; an arm URDF's non-finite or degenerate
attributes are refused when it is read; identify --out never replaces the dataset it reads."""

import json

import pytest

from tests import fuzz_inputs as fz
from test_arm import synthetic, true_errors, write


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    """(dataset directory, calibration file) of a simulated Franka Panda."""
    from naocal.tools.cli import main

    root = tmp_path_factory.mktemp("arm")
    model, obs, _, sensors = synthetic(("joint_offsets", "link_lengths"), true_errors(seed=8), n_poses=30, seed=9)
    dataset = write(root / "d", model, obs, sensors)
    assert main(["identify", str(dataset), "--out", str(root / "cal.json")]) == 0
    return dataset, root / "cal.json"


def one_line_error(outcome, verb):
    assert outcome.returncode == 2, fz.describe(outcome)
    lines = outcome.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"naocal {verb}: error: ") and "Traceback" not in outcome.stderr
    return lines[0]


def set_field(doc, dotted, value):
    """doc's field at 'a.b.c' or 'a.b[1]' set to value."""
    *parents, last = dotted.split(".")
    for key in parents:
        doc = doc[key]
    if "[" in last:
        key, index = last[:-1].split("[")
        doc[key][int(index)] = value
    else:
        doc[last] = value


BAD_FIELDS = [
    ("sensors.tracker.rotation_rad[0]", 1e308, "implausible size"),
    ("sensors.camera.translation_m[2]", -1e308, "implausible size"),
    ("sensors.tracker.translation_m[1]", 0.5, "disagrees with model.parameters.sensor.tracker.translation.y"),
    ("fit.rms.tracker.value", 1e308, "implausible size"),
    ("fit.heldout.camera.calibrated", 1e308, "implausible size"),
    ("fit.n_observations", -1, "expected a whole number at least 0"),
]


@pytest.mark.parametrize("field, value, problem", BAD_FIELDS)
@pytest.mark.parametrize("verb", ["show", "validate", "diff", "export", "apply", "verify"])
def test_an_implausible_number_anywhere_in_an_arm_calibration_is_named_by_every_verb(arm, tmp_path, field, value,
                                                                                    problem, verb):
    dataset, good = arm
    doc = json.loads(good.read_text())
    set_field(doc, field, value)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    argv = {"show": ["offsets", "show", str(bad)], "validate": ["offsets", "validate", str(bad)],
            "diff": ["offsets", "diff", str(good), str(bad)],
            "export": ["offsets", "export", str(bad), "--format", "json"],
            "apply": ["offsets", "apply", str(bad), "--command", "panda_joint2=10"],
            "verify": ["verify", str(dataset), "--offsets", str(bad)]}[verb]
    line = one_line_error(fz.run_forked(argv, deadline_s=60), argv[0])
    assert f"field '{field}'" in line and problem in line and str(bad) in line, line


def test_an_implausible_compliance_is_refused(arm, tmp_path):
    from naocal.kinds.arm.calibration import read_arm_calibration
    from naocal.solver.errors import DataError

    doc = json.loads(arm[1].read_text())
    doc["model"]["parameters"]["elasticity.panda_joint2"] = {"value": 1e308, "std": 0.0, "unit": "rad/(N m)",
                                                            "fixed": False}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(DataError, match=r"elasticity.panda_joint2.value'.*implausible size"):
        read_arm_calibration(bad)


def test_arm_identify_out_onto_its_dataset_is_refused(arm):
    dataset = arm[0]
    meta = dataset / "dataset.json"
    before = meta.read_bytes()
    line = one_line_error(fz.run_forked(["identify", str(dataset), "--out", str(meta)], deadline_s=60), "identify")
    assert "is an input of this command" in line and meta.read_bytes() == before


URDF_DAMAGE = [  # (what is replaced in panda_joint3 or panda_link4, by what, the words of the refusal)
    ('xyz="0 -0.316 0"', 'xyz="nan -0.316 0"',
     "'joints.panda_joint3.origin.xyz[0]': expected a finite number, got 'nan'"),
    ('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>', "joint 'panda_joint3': axis xyz '0 0 0': no direction"),
    ('rpy="1.57079632679 0 0" xyz="0 -0.316 0"', 'rpy="inf 0 0" xyz="0 -0.316 0"',
     "'joints.panda_joint3.origin.rpy[0]': expected a finite number, got 'inf'"),
    ('effort="87" lower="-2.9671" upper="2.9671"', 'effort="87" lower="nan" upper="2.9671"',
     "'joints.panda_joint3.limit.lower': expected a finite number, got 'nan'"),
    ('xyz="0 -0.316 0"', 'xyz="0 -316 0"', "'joints.panda_joint3.origin.xyz[1]': implausible size -316 m"),
    ('<mass value="2.08"/>', '<mass value="-2.08"/>',
     "'links.panda_link4.inertial.mass.value': must be within [0, 10000], got -2.08"),
]


@pytest.mark.parametrize("old, new, words", URDF_DAMAGE)
def test_an_arm_urdf_with_a_non_finite_or_degenerate_attribute_is_refused_when_read(arm, tmp_path, old, new, words):
    from naocal.kinds.arm.dataset import read_arm_dataset

    text = read_arm_dataset(arm[0]).urdf_path.read_text()
    start = text.index('<link name="panda_link4">' if "mass" in old else '<joint name="panda_joint3"')
    end = text.index("</link>" if "mass" in old else "</joint>", start)
    assert text[start:end].count(old) == 1
    bad = tmp_path / "panda.urdf"
    bad.write_text(text[:start] + text[start:end].replace(old, new) + text[end:])
    outcome = fz.run_forked(["identify", str(arm[0]), "--robot", str(bad)], deadline_s=20)
    line = one_line_error(outcome, "identify")
    assert str(bad) in line and words in line, line
