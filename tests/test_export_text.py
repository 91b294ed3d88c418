"""The text editors behind merges: single values replaced or added, every other byte kept, bad syntax refused with
the file and line (tools/export/cfgtext.py, tools/export/jsontext.py)."""

import json

import pytest

from naocal.solver.errors import DataError
from tests.cfg_reader import parse_cfg as read_cfg
from naocal.tools.export import cfgtext, jsontext

CFG = """// team comment: keep me
offsets = {
  headYaw = 0.4deg;   // trailing comment
  /* block
     comment */ headPitch = -1.2deg;
  lHipPitch = 1.30deg;
};
names = ["a", "b;c"];
poses = [{x = 1; y = 2;}, {x = 3; y = 4;}];
upper = {x = 0.85deg; y = -3.25deg; z = 1.1deg;};
"""


def test_cfg_replace_keeps_every_other_byte():
    root = cfgtext.parse_cfg(CFG, "t.cfg")
    new = cfgtext.replace_literals(CFG, root, {("offsets", "lHipPitch"): "-0.5deg", ("upper", "y"): "2deg"}, "t.cfg")
    assert new == CFG.replace("lHipPitch = 1.30deg", "lHipPitch = -0.5deg").replace("y = -3.25deg", "y = 2deg")
    offsets_only = new[new.index("offsets"):new.index("names")]
    assert read_cfg(offsets_only)["offsets"] == {"headYaw": "0.4deg", "headPitch": "-1.2deg", "lHipPitch": "-0.5deg"}


def test_cfg_lookup_and_literals():
    root = cfgtext.parse_cfg(CFG, "t.cfg")
    assert cfgtext.lookup(root, ("poses",)).kind == "array"
    assert cfgtext.lookup(root, ("offsets", "missing")) is None
    flat = cfgtext.literals(root)
    assert flat[("names", 1)] == '"b;c"' and flat[("poses", 1, "y")] == "4"


def test_cfg_replace_refuses_a_missing_key():
    root = cfgtext.parse_cfg(CFG, "t.cfg")
    with pytest.raises(DataError, match="field 'offsets.lKneePitch'"):
        cfgtext.replace_literals(CFG, root, {("offsets", "lKneePitch"): "1deg"}, "t.cfg")


@pytest.mark.parametrize("text,line,problem", [
    ("a = {\n  x = 1;\n  y = 2\n  z = 3;\n};\n", 3, "expected ';'"),
    ("a = {\n  x = 1;\n", 3, "unterminated record"),
    ("a = 1;\na = 2;\n", 2, "appears twice"),
    ("a = 1;\n/* open\n", 2, "unterminated comment"),
    ('a = "open\n', 1, "unterminated string"),
    ("a = [1, 2;\n", 1, "expected ',' or ']'"),
    ("= 1;\n", 1, "expected a key"),
    ("a = ;\n", 1, "expected a value"),
])
def test_cfg_syntax_errors_name_the_line(text, line, problem):
    with pytest.raises(DataError) as info:
        cfgtext.parse_cfg(text, "bad.cfg")
    assert f"bad.cfg, line {line}" in str(info.value) and problem in str(info.value), str(info.value)


JSON = """{
  "joint_calibration_offsets": {
    "left_leg": {
      "hip_yaw_pitch": -0.2
    },
    "right_leg": {}
  },
  "step_planner": {"forward": 0.04, "inward_rotation": 0.45},
  "calibration": {
    "correction_in_camera_bottom": [
      -0.0145,
      -0.0136,
      0.0045
    ]
  }
}
"""


def test_json_set_replaces_adds_and_keeps_the_rest():
    new = jsontext.set_values(JSON, {
        ("joint_calibration_offsets", "left_leg", "hip_yaw_pitch"): 0.01,
        ("joint_calibration_offsets", "left_leg", "hip_roll"): -0.02,
        ("joint_calibration_offsets", "right_leg", "knee_pitch"): 0.03,
        ("joint_calibration_offsets", "head", "yaw"): 0.04,
        ("calibration", "correction_in_camera_bottom"): [0.1, 0.2, 0.3],
        ("camera", "calibration", "correction_in_camera_top"): [0.4, 0.5, 0.6],
    }, "t.json")
    doc = json.loads(new)
    assert doc["joint_calibration_offsets"] == {"left_leg": {"hip_yaw_pitch": 0.01, "hip_roll": -0.02},
                                                "right_leg": {"knee_pitch": 0.03}, "head": {"yaw": 0.04}}
    assert doc["calibration"]["correction_in_camera_bottom"] == [0.1, 0.2, 0.3]
    assert doc["camera"] == {"calibration": {"correction_in_camera_top": [0.4, 0.5, 0.6]}}
    assert '  "step_planner": {"forward": 0.04, "inward_rotation": 0.45},\n' in new  # untouched line, byte for byte
    assert '      "hip_yaw_pitch": 0.01,\n      "hip_roll": -0.02\n' in new  # indented like its sibling
    assert '    "correction_in_camera_bottom": [\n      0.1,\n      0.2,\n      0.3\n    ]\n' in new  # stays multi-line
    assert '    "right_leg": {\n      "knee_pitch": 0.03\n    },\n' in new


def test_json_set_on_an_empty_document():
    assert json.loads(jsontext.set_values("{}", {("a", "b"): 1.5}, "t.json")) == {"a": {"b": 1.5}}


@pytest.mark.parametrize("text,problem", [
    ('{"a": 1, "a": 2}', "appears twice"),
    ('{"a": 1,}', "expected a string key"),
    ('{"a": NaN}', "unexpected character"),
    ('{"a": [1, 2}', "expected ',' or ']'"),
    ('{"a": 1} x', "text after the document"),
    ('[1, 2]', "expected a JSON object"),
    ('{"a": ' + "[" * 1000 + "]" * 1000 + "}", "nested deeper"),
    ('{"a": ' + "9" * 5000 + "}", "invalid JSON"),
    ('{"a": 1', "unexpected end of file"),
])
def test_json_errors_are_data_errors(text, problem):
    with pytest.raises(DataError) as info:
        jsontext.set_values(text, {("a",): 1}, "bad.json")
    assert "bad.json" in str(info.value) and problem in str(info.value), str(info.value)


def test_json_refuses_to_set_below_a_non_object():
    with pytest.raises(DataError) as refused:
        jsontext.set_values('{"a": [1]}', {("a", "b"): 1}, "t.json")
    assert str(refused.value) == "t.json, field 'a': expected a JSON object, got [1]"  # solver.fields' style
    with pytest.raises(DataError) as refused:
        jsontext.set_values('[1, 2]', {("a",): 1}, "t.json")
    assert str(refused.value) == "t.json: expected a JSON object, got [1, 2]"
