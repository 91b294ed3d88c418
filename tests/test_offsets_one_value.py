"""One value, one place (issue 21): an offsets file whose two copies of a value disagree is refused by every verb.

A file holds each fitted value in model.parameters (with its std) and in the people's sections (body, head,
targets). show, export and apply read the sections, verify the parameters: an edited file that contradicts itself
would give two calibrations. Every verb reads it through solver.offsets.read_offsets, which refuses it naming
both fields (one line, exit 2).
"""

import json
import math

import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from naocal.solver.offsets import read_offsets, write_offsets
from tests.test_offsets import make_offsets

DATASET = tools.cli.__file__.rsplit("/tools/", 1)[0] + "/tests/data/v1/synthetic_dataset"
EDITS = {
    "the section": (lambda doc: doc["body"]["joint_offsets_rad"], "LKneePitch",
                    "body.joint_offsets_rad.LKneePitch"),
    "model.parameters": (lambda doc: doc["model"]["parameters"]["joint_offset.LKneePitch"], "value",
                         "body.joint_offsets_rad.LKneePitch"),
    "a camera's rotation": (lambda doc: doc["head"]["camera_rotation_rad"]["bottom"], "pitch",
                            "head.camera_rotation_rad.bottom.pitch"),
    "an effect's section": (lambda doc: doc["body"]["elasticity_rad_per_nm"], "LHipPitch",
                            "body.elasticity_rad_per_nm.LHipPitch"),
}
VERBS = {
    "show": lambda f: ["offsets", "show", f],
    "validate": lambda f: ["offsets", "validate", f],
    "export": lambda f: ["offsets", "export", f, "--format", "json"],
    "apply": lambda f: ["offsets", "apply", f, "--command", "LKneePitch=20"],
    "diff A": lambda f: ["offsets", "diff", f, f + ".good"],
    "diff B": lambda f: ["offsets", "diff", f + ".good", f],
    "verify": lambda f: ["verify", DATASET, "--offsets", f],
}
PARAMETER_OF = {"body.joint_offsets_rad.LKneePitch": "model.parameters.joint_offset.LKneePitch",
                "head.camera_rotation_rad.bottom.pitch": "model.parameters.camera.bottom.pitch",
                "body.elasticity_rad_per_nm.LHipPitch": "model.parameters.elasticity.LHipPitch"}


def contradicting(tmp_path, edit):
    good = tmp_path / "nao.json.good"
    offsets = make_offsets(head=True)
    offsets.robot.update(id="synthetic-11", body_id="synthetic-11", head_id="synthetic-11")  # DATASET's robot
    write_offsets(offsets, good)
    doc = json.loads(good.read_text())
    table, key, _ = EDITS[edit]
    table(doc)[key] += math.radians(1.0)  # the edit: LKneePitch moved +1 deg in one copy only
    path = tmp_path / "nao.json"
    path.write_text(json.dumps(doc, indent=1))
    return path


@pytest.mark.parametrize("edit", list(EDITS))
@pytest.mark.parametrize("verb", list(VERBS))
def test_every_verb_refuses_a_file_whose_two_copies_disagree(tmp_path, capsys, edit, verb):
    path = contradicting(tmp_path, edit)
    code = tools.cli.main(VERBS[verb](str(path)))
    out, err = capsys.readouterr()
    field = EDITS[edit][2]
    assert code == 2, (out, err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert str(path) + "," in err and field in err and PARAMETER_OF[field] in err, err  # both fields named
    assert "contradicts itself" in err


def test_the_consistent_file_is_read_by_every_verb(tmp_path, capsys):
    path = contradicting(tmp_path, "the section")
    path.write_bytes((tmp_path / "nao.json.good").read_bytes())
    for verb, argv in VERBS.items():
        code = tools.cli.main(argv(str(path)))
        _, err = capsys.readouterr()
        assert code in ((0, 1) if verb == "verify" else (0,)), (verb, err)  # verify: still good or drifted


def test_an_offsets_object_edited_in_one_copy_is_not_written(tmp_path):
    offsets = make_offsets()
    offsets.joint_offsets_rad["LKneePitch"] += 0.01
    with pytest.raises(Exception, match="body.joint_offsets_rad.LKneePitch.*model.parameters.joint_offset"):
        write_offsets(offsets, tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()


def test_version_1_files_are_checked_too(tmp_path, capsys):
    """A version 1 file's copies: joint_offsets_rad (c) and model.parameters.joint_offset (alpha = -c)."""
    v1 = tools.cli.__file__.rsplit("/tools/", 1)[0] + "/tests/data/v1/offsets_base.json"
    doc = json.loads(open(v1).read())
    doc["joint_offsets_rad"]["LKneePitch"] += 0.01
    (tmp_path / "v1.json").write_text(json.dumps(doc))
    code = tools.cli.main(["offsets", "validate", str(tmp_path / "v1.json")])
    err = capsys.readouterr().err
    assert code == 2 and "field 'joint_offsets_rad.LKneePitch'" in err
    assert "model.parameters.joint_offset.LKneePitch" in err
    assert read_offsets(v1)  # the file as written reads
