"""solver/fields.py: the one home of a file field's checks (issue 22), and the readers that use it."""

import json
import math
import shutil

import pytest

from naocal.solver import fields
from naocal.solver.errors import DataError
from naocal.solver.robot import DATA_DIR, load_robot


def refused(check, *args, **kwargs) -> DataError:
    with pytest.raises(DataError) as info:
        check(*args, **kwargs)
    return info.value


@pytest.mark.parametrize("value,limits,problem", [
    ("600", {}, "expected a finite number, got '600'"),
    (True, {}, "expected a finite number, got True"),
    (math.nan, {}, "expected a finite number, got nan"),
    (math.inf, {}, "expected a finite number, got inf"),
    (0, {"positive": True}, "must be positive, got 0"),
    (-1e-9, {"non_negative": True}, "must not be negative, got -1e-09"),
    (0.0, {"high": 1.0, "positive": True}, "must be within (0, 1], got 0.0"),
    (1.5, {"low": -1, "high": 1}, "must be within [-1, 1], got 1.5"),
    (1, {"low": 2}, "must be at least 2, got 1"),
    (640.5, {"integer": True}, "expected a whole number, got 640.5"),
    (0.5, {"limit": math.radians(20), "unit": "rad"}, "is it in degrees instead of radians?"),
    (2.0, {"limit": 0.1, "unit": "m"}, "is it in mm instead of m?"),
])
def test_a_refused_number_names_the_file_the_field_and_what_it_must_be(value, limits, problem):
    err = refused(fields.number, value, "cal.json", "cameras.bottom.fx_px", **limits)
    assert str(err).startswith("cal.json, field 'cameras.bottom.fx_px': ") and problem in str(err), str(err)
    assert err.field == "cameras.bottom.fx_px"


def test_an_accepted_number_comes_back_as_float():
    assert fields.number(3, "f", "x", positive=True, integer=True, high=3) == 3.0
    assert type(fields.number(3, "f", "x")) is float


def test_text_cells_are_read_as_numbers_naming_the_line():
    assert fields.number_text("-0.25", "wheels.csv", "left_duty", line=4, low=-1, high=1) == -0.25
    for text in ("abc", "", "nan", "inf", "1" * 200, None, ["1"]):
        err = refused(fields.number_text, text, "wheels.csv", "left_duty", line=4)
        assert str(err).startswith("wheels.csv, line 4, field 'left_duty': expected a finite number"), str(err)
    assert fields.count_text("640", "cam.yaml", "image_width", 16, 10000) == 640
    for text in ("6.4e2", "-640", "99999", ""):
        assert "expected a whole number from 16 to 10000" in str(refused(fields.count_text, text, "cam.yaml",
                                                                           "image_width", 16, 10000))


def test_counts_vectors_names_and_text():
    assert fields.count(7, "f", "n") == 7
    for value in (7.0, True, -1, "7"):
        assert "expected a whole number at least 0" in str(refused(fields.count, value, "f", "n"))
    assert fields.vector([1, 2, 3], 3, "f", "xyz") == (1.0, 2.0, 3.0)
    assert fields.vector(["1", "2"], (2, 4), "f", "d", from_text=True) == (1.0, 2.0)
    assert "expected a list of 3 numbers" in str(refused(fields.vector, [1, 2], 3, "f", "xyz"))
    assert refused(fields.vector, [1, "x", 3], 3, "f", "xyz").field == "xyz[1]"
    assert fields.names(["a", "b"], "f", "joints") == ("a", "b")
    assert "'a' is listed twice" in str(refused(fields.names, ["a", "b", "a"], "f", "joints"))
    assert "at least one" in str(refused(fields.names, [], "f", "joints", non_empty=True))
    assert fields.text("DB21", "f", "robot.model", max_chars=40) == "DB21"
    for value in ("a\nb", "x" * 41, 7):  # a line break would split a line of another program's config file
        assert "expected a single line of printable text" in str(refused(fields.text, value, "f", "robot.model",
                                                                           max_chars=40))


def test_json_objects_name_the_unknown_or_missing_field():
    assert fields.json_object({"a": 1}, "f", "robot", ("a",), ("b",)) == {"a": 1}
    err = refused(fields.json_object, {"a": 1, "c": 2}, "f", "robot", ("a",), ("b",))
    assert err.field == "robot.c" and "unknown field (allowed: a, b)" in str(err)
    err = refused(fields.json_object, {}, "f", "", ("schema",))
    assert err.field == "schema" and "missing required field" in str(err)
    err = refused(fields.json_object, [], "f", "robot")
    assert err.field == "robot" and "expected a JSON object, got []" in str(err)
    err = refused(fields.json_object, {"LHipPtch": 0}, "f", "body.x", optional=("LHipPitch",), keys="joint")
    assert "unknown joint (allowed: LHipPitch)" in str(err)


def robot_file(tmp_path, change):
    """A copy of the NAO's robot description (and its URDF beside it) with `change` applied to its document."""
    doc = json.loads((DATA_DIR / "nao.json").read_text())
    shutil.copy(DATA_DIR / doc["urdf"], tmp_path / doc["urdf"])
    change(doc)
    path = tmp_path / "robot.json"
    path.write_text(json.dumps(doc))
    return path


def test_the_robot_description_names_a_missing_top_level_field_as_itself(tmp_path):
    """It named it '.name' (its own key check wrote the document's field as '' + '.' + key)."""
    err = refused(load_robot, robot_file(tmp_path, lambda doc: doc.pop("name")))
    assert err.field == "name" and "missing required field" in str(err)


def test_the_robot_description_is_read_by_the_strict_json_reader(tmp_path):
    """A key twice was read silently (the last won): the description now goes through solver.fileio.read_json as
    every other file does."""
    path = robot_file(tmp_path, lambda doc: None)
    path.write_text(path.read_text().replace('"name":', '"name": "x", "name":', 1))
    err = refused(load_robot, path)
    assert err.field == "name" and "the same key twice" in str(err)


def test_the_robot_description_refuses_a_fractional_image_size(tmp_path):
    """width_px 640.5 was truncated to 640 without a word."""
    err = refused(load_robot, robot_file(tmp_path, lambda doc: doc["cameras"]["bottom"].update(width_px=640.5)))
    assert err.field == "cameras.bottom.width_px" and "expected a whole number" in str(err)
