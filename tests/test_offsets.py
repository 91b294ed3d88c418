"""naocal.offsets/2: round trips, validation of damaged files, the sign convention and the apply API.
(Version 1 files: tests/test_formats_v1.py.)"""

import json
import math

import numpy as np
import pytest

from naocal.solver.compensation import compensate_command, correct_reading
from naocal.solver.errors import DataError
from naocal.solver.joints import HEAD_JOINTS, LEG_JOINTS
from naocal.solver.offsets import (
    MAX_BOARD_ROT_Z_RAD, MAX_BOARD_TRANS_M, MAX_CAMERA_ROTATION_RAD, MAX_JOINT_OFFSET_RAD, SCHEMA, Offsets,
    alpha_from_offsets, offsets_from_alpha, offsets_from_parameters, parameter_unit, read_offsets, validate,
    write_offsets,
)

ROBOT = {"id": "nao-17", "body_id": "AL-B-17", "head_id": "AL-H-04"}
FIT = {"rms_px": [0.31, 0.27], "n_vertices": 3456, "n_images": 144}


def make_parameters(seed=0, *, head=False):
    """Registry-named model parameters as the identification would report them (joint offsets are c)."""
    rng = np.random.default_rng(seed)
    params = {}
    for joint in LEG_JOINTS:
        if joint != "RHipYawPitch":  # tied to LHipYawPitch: one motor
            params[f"joint_offset.{joint}"] = {"value": float(rng.normal(0, 0.02)), "std": 1e-3, "unit": "rad"}
    if head:
        for joint in HEAD_JOINTS:
            params[f"head_offset.{joint}"] = {"value": float(rng.normal(0, 0.01)), "std": 2e-3, "unit": "rad"}
    for angle in ("roll", "pitch", "yaw"):
        params[f"camera.bottom.{angle}"] = {"value": float(rng.normal(0, 0.05)), "std": 5e-4, "unit": "rad"}
    for leg in "LR":
        params[f"board.{leg}.rot_z"] = {"value": float(rng.normal(0, 0.01)), "std": 1e-3, "unit": "rad"}
        params[f"board.{leg}.trans_x"] = {"value": float(rng.normal(0, 0.002)), "std": 2e-4, "unit": "m"}
        params[f"board.{leg}.trans_y"] = {"value": float(rng.normal(0, 0.002)), "std": 2e-4, "unit": "m"}
    params["elasticity.LHipPitch"] = {"value": 0.021, "std": 0.004, "unit": "rad/(N m)"}
    params["backlash.LKneePitch"] = {"value": 0.017, "std": 0.002, "unit": "rad"}
    params["link_length.L.thigh"] = {"value": 0.0004, "std": 0.0001, "unit": "m"}
    params["intrinsics.bottom.fx"] = {"value": 10.2, "std": 0.8, "unit": "px"}
    params["distortion.bottom.k1"] = {"value": -0.06, "std": 0.01, "unit": "1"}
    params["time_lag.dt"] = {"value": 0.012, "std": 0.001, "unit": "s"}
    return params


def make_offsets(seed=0, **kwargs) -> Offsets:
    return offsets_from_parameters(make_parameters(seed, **kwargs), robot=ROBOT, fit=FIT,
                                   effects=["joint_offsets", "camera_rotation", "board_mount", "elasticity"],
                                   source={"dataset": "runs/nao-17", "naocal": "0.1.0"},
                                   created="2024-06-01T12:00:00Z")


@pytest.fixture
def offsets_file(tmp_path):
    path = tmp_path / "nao-17.json"
    write_offsets(make_offsets(head=True), path)
    return path


# ------------------------------------------------------------------------------------------ round trips


def test_round_trip_is_exact(tmp_path):
    offsets = make_offsets(head=True)
    write_offsets(offsets, tmp_path / "a.json")
    again = read_offsets(tmp_path / "a.json")
    assert again == offsets
    write_offsets(again, tmp_path / "b.json")
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()


def test_written_file_has_the_documented_layout(offsets_file):
    """Body and head kept apart (heads and bodies get swapped), each fitted effect in its section."""
    doc = json.loads(offsets_file.read_text())
    assert list(doc) == ["schema", "robot", "created", "body", "head", "targets", "model", "fit", "source"]
    assert doc["schema"] == SCHEMA == "naocal.offsets/2"
    assert doc["robot"] == {**ROBOT, "description": "nao"}
    assert list(doc["body"]) == ["joint_offsets_rad", "elasticity_rad_per_nm", "backlash_rad", "link_lengths_m"]
    assert list(doc["body"]["joint_offsets_rad"]) == list(LEG_JOINTS) + list(HEAD_JOINTS)
    assert doc["body"]["elasticity_rad_per_nm"] == {"LHipPitch": 0.021}
    assert doc["body"]["link_lengths_m"] == {"L.thigh": 0.0004}
    assert list(doc["head"]) == ["camera_rotation_rad", "intrinsics_correction_px", "distortion_correction",
                                 "time_lag_s"]
    assert set(doc["head"]["camera_rotation_rad"]["bottom"]) == {"roll", "pitch", "yaw"}
    assert doc["head"]["intrinsics_correction_px"] == {"bottom": {"fx": 10.2}}
    assert set(doc["targets"]["board_mount"]["L"]) == {"rot_z_rad", "trans_x_m", "trans_y_m"}
    assert doc["model"]["parameters"]["elasticity.LHipPitch"] == {"value": 0.021, "std": 0.004, "unit": "rad/(N m)"}


def test_write_keeps_a_backup_and_is_atomic(offsets_file):
    first = offsets_file.read_bytes()
    write_offsets(make_offsets(seed=5), offsets_file)
    assert offsets_file.with_name(offsets_file.name + ".bak").read_bytes() == first
    assert sorted(p.name for p in offsets_file.parent.iterdir()) == ["nao-17.json", "nao-17.json.bak"]
    write_offsets(make_offsets(seed=6), offsets_file.with_name("fresh.json"), backup=False)
    assert not offsets_file.with_name("fresh.json.bak").exists()


def test_invalid_offsets_are_never_written(offsets_file):
    before = offsets_file.read_bytes()
    bad = make_offsets()
    bad.joint_offsets_rad["LHipPitch"] = math.radians(25.0)
    with pytest.raises(DataError, match="body.joint_offsets_rad.LHipPitch"):
        write_offsets(bad, offsets_file)
    assert offsets_file.read_bytes() == before
    assert not offsets_file.with_name(offsets_file.name + ".bak").exists()


# -------------------------------------------------------------------------------------- sign convention


def test_stored_offset_is_the_parameter_c():
    """joint_offset.<J> is c, the stored offset (one name, one meaning); the paper's alpha is -c."""
    params = make_parameters(head=True)
    offsets = make_offsets(head=True)
    for joint in LEG_JOINTS:
        name = f"joint_offset.{joint}" if joint != "RHipYawPitch" else "joint_offset.LHipYawPitch"  # one motor
        assert offsets.joint_offsets_rad[joint] == params[name]["value"]
    for joint in HEAD_JOINTS:
        assert offsets.joint_offsets_rad[joint] == params[f"head_offset.{joint}"]["value"]
    assert offsets.camera_rpy() == tuple(params[f"camera.bottom.{a}"]["value"] for a in ("roll", "pitch", "yaw"))
    assert offsets.board_mount["R"]["trans_y_m"] == params["board.R.trans_y"]["value"]  # corrections as they are
    alpha = alpha_from_offsets(offsets)
    assert alpha["joints"]["LKneePitch"] == -params["joint_offset.LKneePitch"]["value"]
    assert alpha["camera"] == offsets.camera_rpy()


def test_compensation_cancels_a_simulated_joint_error():
    """A joint whose true angle is theta_measured + alpha: commanding requested + c (c = -alpha) reaches requested,
    and measured - c is the true angle."""
    alpha = {"LHipPitch": 0.03, "RKneePitch": -0.02}
    offsets = offsets_from_alpha({**{j: 0.0 for j in LEG_JOINTS}, **alpha}, (0.0, 0.0, 0.0),
                                 {"L": (0, 0, 0), "R": (0, 0, 0)}, robot=ROBOT, fit=FIT)
    requested = {"LHipPitch": -0.4, "RKneePitch": 0.9, "LShoulderPitch": 1.2}
    command = compensate_command(requested, offsets)
    encoder = command  # an ideal servo puts the encoder where it is told
    true_angle = {j: encoder[j] + alpha.get(j, 0.0) for j in encoder}
    assert true_angle == pytest.approx(requested, abs=1e-15)
    assert correct_reading(encoder, offsets) == pytest.approx(true_angle, abs=1e-15)
    assert command["LShoulderPitch"] == 1.2  # no offset: unchanged


def test_apply_forms():
    offsets = make_offsets()
    c = offsets.joint_offsets_rad["LAnklePitch"]
    assert compensate_command(0.5, offsets, joint="LAnklePitch") == 0.5 + c
    assert correct_reading(("LAnklePitch", 0.5), offsets) == 0.5 - c
    assert compensate_command({"LAnklePitch": 0.5}, {"LAnklePitch": 0.01}) == {"LAnklePitch": 0.51}
    assert correct_reading(0.5, offsets, joint="HeadYaw") == 0.5  # no head offsets in this file
    angles = np.array([0.1, 0.2])
    assert np.array_equal(compensate_command(angles, offsets, joint="LAnklePitch"), angles + c)
    with pytest.raises(TypeError):
        compensate_command(0.5, offsets)


def test_offsets_from_alpha_needs_every_leg_joint():
    with pytest.raises(ValueError, match="LHipRoll"):
        offsets_from_alpha({"LHipYawPitch": 0.0}, (0, 0, 0), {"L": (0, 0, 0), "R": (0, 0, 0)}, robot=ROBOT, fit=FIT)


def test_version_1_parameter_names_and_units():
    assert parameter_unit("joint_offset.LHipPitch") == "rad"
    assert parameter_unit("elasticity.RKneePitch") == "rad/(N m)"
    assert parameter_unit("board.L.trans_x") == "m"
    assert parameter_unit("link_length.R.tibia") == "m"
    assert parameter_unit("intrinsics.cy") == "px"
    assert parameter_unit("distortion.k3") == "1"
    assert parameter_unit("time_lag.dt") == "s"
    for bad in ("joint_offset.LHipPtch", "camera.tilt", "board.X.rot_z", "magic.x", "camera", "board.L.rot_x"):
        with pytest.raises(ValueError):
            parameter_unit(bad)


# ------------------------------------------------------------------------------------------- damaged files


def damaged(offsets_file, change):
    doc = json.loads(offsets_file.read_text())
    change(doc)
    offsets_file.write_text(json.dumps(doc))
    with pytest.raises(DataError) as info:
        read_offsets(offsets_file)
    assert "\n" not in str(info.value) and str(offsets_file) in str(info.value)
    return info.value


def set_path(doc, path, value):
    keys = path.split("/")
    for key in keys[:-1]:
        doc = doc[key]
    doc[keys[-1]] = value


def delete_path(doc, path):
    keys = path.split("/")
    for key in keys[:-1]:
        doc = doc[key]
    del doc[keys[-1]]


@pytest.mark.parametrize("path,value,field,problem", [
    ("schema", "naocal.offsets/3", "schema", "wrong schema"),
    ("schema", "naocal.dataset/1", "schema", "wrong schema"),
    ("body/joint_offsets_rad/LHipPitch", float("nan"), "body.joint_offsets_rad.LHipPitch", "non-finite"),
    ("body/joint_offsets_rad/RAnkleRoll", float("inf"), "body.joint_offsets_rad.RAnkleRoll", "non-finite"),
    ("head/camera_rotation_rad/bottom/pitch", float("nan"), "head.camera_rotation_rad.bottom.pitch", "non-finite"),
    ("model/parameters/time_lag.dt/std", float("nan"), "model.parameters.time_lag.dt.std", "non-finite"),
    ("body/joint_offsets_rad/LHipPitch", "0.1", "body.joint_offsets_rad.LHipPitch", "expected a finite number"),
    ("body/joint_offsets_rad/LHipPitch", 0.62, "body.joint_offsets_rad.LHipPitch", "degrees instead of radians"),
    ("body/joint_offsets_rad/LHipPtch", 0.01, "body.joint_offsets_rad.LHipPtch", "unknown joint"),
    ("body/joint_offsets_rad/LFingerX", 0.01, "body.joint_offsets_rad.LFingerX", "unknown joint"),
    ("body/elasticity_rad_per_nm/LKneePitch", 5.0, "body.elasticity_rad_per_nm.LKneePitch", "implausible"),
    ("body/magic", {}, "body.magic", "unknown field"),
    ("body/camera_rotation_rad", {}, "body.camera_rotation_rad", "unknown field"),  # a head result in the body
    ("head/camera_rotation_rad/bottom/yaw", -0.3, "head.camera_rotation_rad.bottom.yaw", "implausible"),
    ("head/camera_rotation_rad/bottom/tilt", 0.01, "head.camera_rotation_rad.bottom.tilt", "unknown field"),
    ("head/camera_rotation_rad/middle", {"roll": 0, "pitch": 0, "yaw": 0}, "head.camera_rotation_rad.middle",
     "unknown name"),
    ("targets/board_mount/L/trans_x_m", 2.0, "targets.board_mount.L.trans_x_m", "mm instead of m"),
    ("targets/board_mount/R/rot_z_rad", 0.5, "targets.board_mount.R.rot_z_rad", "implausible"),
    ("targets/board_mount/L/trans_x_mm", 2.0, "targets.board_mount.L.trans_x_mm", "unknown field"),
    ("targets/board_mount/Q", {"rot_z_rad": 0, "trans_x_m": 0, "trans_y_m": 0}, "targets.board_mount.Q",
     "unknown name"),
    ("model/parameters/camera.bottom.roll/unit", "deg", "model.parameters.camera.bottom.roll.unit", "unknown unit"),
    ("model/parameters/board.L.trans_x/unit", "rad", "model.parameters.board.L.trans_x.unit", "wrong unit"),
    ("model/parameters/elasticity.LHipPitch/unit", "rad/Nm", "model.parameters.elasticity.LHipPitch.unit",
     "unknown unit"),
    ("model/parameters/joint_offset.LHipPtch", {"value": 0, "std": 0, "unit": "rad"},
     "model.parameters.joint_offset.LHipPtch", "unknown model parameter"),
    ("model/parameters/camera.roll", {"value": 0, "std": 0, "unit": "rad"},
     "model.parameters.camera.roll", "unknown model parameter"),  # version 1's name: no camera
    ("model/parameters/camera.bottom.roll/std", -1e-3, "model.parameters.camera.bottom.roll.std", "negative"),
    ("model/effects", "elasticity", "model.effects", "list of effect names"),
    ("model/effects", ["elastic"], "model.effects[0]", "unknown effect"),
    ("fit/rms_px", [0.3], "fit.rms_px", "rms_x, rms_y"),
    ("fit/n_images", -3, "fit.n_images", "must not be negative"),
    ("created", "yesterday", "created", "ISO-8601"),
    ("created", "2024-06-01T14:00:00+02:00", "created", "UTC"),
    ("robot/id", 17, "robot.id", "expected a string"),
    ("robot/head_id", "../../etc/passwd", "robot.head_id", "not a valid id"),  # becomes a file name in exports
    ("robot/body_id", "a\nb", "robot.body_id", "not a valid id"),
    ("model/parameters/camera.bottom.roll/value", 1e300, "model.parameters.camera.bottom.roll.value",
     "implausible size"),
    ("model/parameters/board.L.trans_x/value", 2.0, "model.parameters.board.L.trans_x.value", "mm instead of m"),
    ("robot/description", "../../etc/passwd", "robot.description", "robot description"),
    ("robot/description", "pepper", "robot.description", "unknown robot description"),
    ("extra", 1, "extra", "unknown field"),
    ("robot", [], "robot", "JSON object"),
])
def test_damaged_fields_are_named(offsets_file, path, value, field, problem):
    err = damaged(offsets_file, lambda doc: set_path(doc, path, value))
    assert err.field == field, str(err)
    assert problem in str(err)


@pytest.mark.parametrize("path,field", [
    ("body/joint_offsets_rad", "body.joint_offsets_rad"),
    ("head/camera_rotation_rad", "head.camera_rotation_rad"),
    ("head/camera_rotation_rad/bottom/yaw", "head.camera_rotation_rad.bottom.yaw"),
    ("targets/board_mount/R/trans_y_m", "targets.board_mount.R.trans_y_m"),
    ("fit/n_vertices", "fit.n_vertices"),
    ("model/parameters/camera.bottom.roll/std", "model.parameters.camera.bottom.roll.std"),
    ("robot/description", "robot.description"),
    ("schema", "schema"),
    ("source", "source"),
])
def test_missing_fields_are_named(offsets_file, path, field):
    err = damaged(offsets_file, lambda doc: delete_path(doc, path))
    assert err.field == field and "missing" in str(err)


def test_head_offsets_and_joints_not_calibrated_are_optional(offsets_file):
    doc = json.loads(offsets_file.read_text())
    for joint in HEAD_JOINTS + ("LAnkleRoll",):
        del doc["body"]["joint_offsets_rad"][joint]
        for prefix in ("joint_offset.", "head_offset."):  # not calibrated: in neither copy
            doc["model"]["parameters"].pop(prefix + joint, None)
    validate(doc)


def test_a_joint_left_out_of_one_copy_only_is_refused(offsets_file):
    """model.parameters still holds LAnkleRoll's value: the section's silence would contradict it."""
    doc = json.loads(offsets_file.read_text())
    del doc["body"]["joint_offsets_rad"]["LAnkleRoll"]
    with pytest.raises(DataError, match=r"body.joint_offsets_rad.LAnkleRoll.*missing.*"
                                        r"model.parameters.joint_offset.LAnkleRoll"):
        validate(doc)


@pytest.mark.parametrize("cut", [0, 1, 50, 400, -2])
def test_truncated_file(offsets_file, cut):
    text = offsets_file.read_text()
    offsets_file.write_text(text[:cut] if cut > 0 else ("" if cut == 0 else text[:cut - 1]))
    with pytest.raises(DataError, match="truncated JSON|empty file") as info:
        read_offsets(offsets_file)
    assert str(offsets_file) in str(info.value)


def test_nan_literal_in_the_text(offsets_file):
    text = offsets_file.read_text()
    value = json.loads(text)["body"]["joint_offsets_rad"]["LHipRoll"]
    offsets_file.write_text(text.replace(f'"LHipRoll": {value!r}', '"LHipRoll": NaN', 1))
    with pytest.raises(DataError, match="body.joint_offsets_rad.LHipRoll.*non-finite"):
        read_offsets(offsets_file)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(DataError, match="file not found"):
        read_offsets(tmp_path / "none.json")
    with pytest.raises(DataError, match="is a directory"):
        read_offsets(tmp_path)


def test_limits_are_the_documented_ones():
    assert MAX_JOINT_OFFSET_RAD == pytest.approx(math.radians(20))
    assert MAX_CAMERA_ROTATION_RAD == pytest.approx(math.radians(15))
    assert MAX_BOARD_ROT_Z_RAD == pytest.approx(math.radians(15))
    assert MAX_BOARD_TRANS_M == 0.03


def test_every_registry_parameter_is_accepted_with_its_unit():
    """The offsets file must accept whatever the identification reports, for every camera and target of the robot
    (the effects, solver/effects/, are the source), and write every effect's section."""
    from naocal.solver.effect import Setup
    from naocal.solver.effects import ALL_EFFECTS, EFFECTS
    from naocal.solver.registry import EXTRA_EFFECTS, Registry

    registry = Registry(EXTRA_EFFECTS, setup=Setup.everything())
    assert len(registry.parameters) > 21
    params = {p.name: {"value": 0.0, "std": 0.0, "unit": p.unit} for p in registry.parameters}
    offsets = offsets_from_parameters(params, robot=ROBOT, fit=FIT, effects=registry.extra_effects())
    doc = offsets.to_dict()
    validate(doc)
    for effect in (EFFECTS[name] for name in ALL_EFFECTS):  # the NAO's (an arm's effects are in its own file)
        assert effect.offsets_key in doc[effect.offsets_section], effect.name
    assert set(doc["head"]["camera_rotation_rad"]) == {"bottom", "top"}
    assert set(doc["targets"]["board_mount"]) == {"L", "R", "floor"}


def test_a_fit_the_file_could_not_hold_is_implausible():
    """identify refuses, before writing, what the offsets file would refuse: each term at its own file limit (a
    camera translation is in m, not under the camera rotation's limit in rad)."""
    from naocal.solver.effects import EFFECTS
    from naocal.solver.offsets import MAX_CAMERA_TRANSLATION_M, implausible_parameter

    assert MAX_CAMERA_TRANSLATION_M == EFFECTS["camera_translation"].offsets_limit
    assert "camera.bottom.trans_z" in implausible_parameter("camera.bottom.trans_z", 0.05, 1e-4, "m")
    assert implausible_parameter("camera.bottom.trans_z", 0.02, 1e-4, "m") is None
    assert "deg" in implausible_parameter("camera.bottom.pitch", MAX_CAMERA_ROTATION_RAD * 1.01, 1e-4, "rad")
    assert implausible_parameter("camera.top.yaw", MAX_CAMERA_ROTATION_RAD * 0.99, 1e-4, "rad") is None
    assert "joint_offset.LHipPitch" in implausible_parameter("joint_offset.LHipPitch", MAX_JOINT_OFFSET_RAD * 1.5,
                                                             1e-4, "rad")


def test_a_result_beyond_a_sections_file_limit_is_implausible_not_a_write_error():
    """identify checks a result with implausible_parameter before writing: it must hold the file's own limits (an
    elasticity of 1.47 rad/(N m) passed it, then failed as bad input while being written)."""
    from naocal.solver.offsets import implausible_parameter

    assert "at most 1 rad/(N m)" in implausible_parameter("elasticity.RAnkleRoll", 1.47, 0.1, "rad/(N m)")
    assert implausible_parameter("elasticity.RAnkleRoll", 0.5, 0.1, "rad/(N m)") is None
