"""Config injection (issue 11): robot, body and head ids are validated where offsets files are read, and refused again
by every writer that puts them into another program's config or a file name (defence in depth)."""

import json

import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from naocal.solver.errors import DataError
from naocal.solver.offsets import read_offsets, write_offsets
from tests.test_offsets import make_offsets

BAD_IDS = {
    "newline": "nao-17\noffsets = { lHipPitch = 90deg; };",
    "parent directory": "..",
    "path separator": "a/b",
    "backslash": "a\\b",
    "leading dot": ".hidden",
    "space": "nao 17",
    "comment end": "x*/",
    "empty": "",
    "too long": "n" * 65,
    "non-ASCII": "naö",
}
GOOD_IDS = ["P0000073A19S31T00003", "AL-B-17", "mock-body-1", "Dante", "nao.17_b", "n" * 64]


def write_with_robot(tmp_path, **robot):
    path = tmp_path / "offsets.json"
    write_offsets(make_offsets(head=True), path)
    doc = json.loads(path.read_text())
    doc["robot"].update(robot)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("key", ["id", "body_id", "head_id"])
@pytest.mark.parametrize("name", BAD_IDS)
def test_reader_refuses_unsafe_ids_naming_the_field(tmp_path, key, name):
    path = write_with_robot(tmp_path, **{key: BAD_IDS[name]})
    with pytest.raises(DataError) as info:
        read_offsets(path)
    message = str(info.value)
    assert f"field 'robot.{key}'" in message and "\n" not in message, message


@pytest.mark.parametrize("value", GOOD_IDS + [None])
def test_reader_accepts_real_ids(tmp_path, value):
    assert read_offsets(write_with_robot(tmp_path, body_id=value)).robot["body_id"] == value


def test_validate_verb_says_which_field_in_one_line(tmp_path, capsys):
    path = write_with_robot(tmp_path, id=BAD_IDS["newline"])
    code = tools.cli.main(["offsets", "validate", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "robot.id" in err and "Traceback" not in err


# ------------------------------------------------------------------------------------------------ writers


def unchecked_offsets(**robot):
    """An Offsets built without the reader (as a future caller might): the writers must still refuse bad ids."""
    offsets = make_offsets(head=True)
    offsets.robot.update(robot)
    return offsets


@pytest.mark.parametrize("key", ["id", "body_id", "head_id"])
def test_every_writer_refuses_an_unsafe_id(key):
    from naocal.solver.errors import NaocalError
    from naocal.tools.export.bhuman import export_bhuman
    from naocal.tools.export.common import calibrated
    from naocal.tools.export.hulks import export_hulks
    from naocal.tools.export.naodevils import export_naodevils
    from naocal.tools.export.urdf import export_urdf

    offsets = unchecked_offsets(**{key: BAD_IDS["newline"]})
    cal = calibrated(offsets)
    head, body = cal.robot["head_id"], cal.robot["body_id"]
    writers = [lambda: export_bhuman(cal, "f.json", head=head, body=body),
               lambda: export_naodevils(cal, "f.json", head=head, body=body),
               lambda: export_urdf(offsets)]
    if key != "id":  # HULKs writes no comment, only file names
        writers.append(lambda: export_hulks(cal, head=head, body=body))
    for write in writers:
        with pytest.raises(NaocalError, match="not a valid id"):
            write()


def test_a_file_name_with_a_newline_stays_inside_the_comment(tmp_path, capsys):
    from tests.cfg_reader import parse_cfg

    path = tmp_path / "nao-17\noffsets = { lHipPitch = 90deg; };\n--> <x/>.json"
    write_offsets(make_offsets(head=True), path)
    for fmt in ("bhuman", "naodevils", "urdf"):
        assert tools.cli.main(["offsets", "export", str(path), "--format", fmt]) == 0
        out = capsys.readouterr().out
        assert "\noffsets = { lHipPitch = 90deg; };" not in out and "--> <x/>" not in out
        if fmt == "bhuman":
            joint_file = out.split("// ---- ")[1].split("\n", 1)[1]
            assert list(parse_cfg(joint_file)) == ["offsets"]
            assert parse_cfg(joint_file)["offsets"]["lHipPitch"] != "90deg"
        if fmt == "urdf":
            import xml.etree.ElementTree as ET

            ET.fromstring(out.split("\n", 1)[1])  # still well-formed XML
