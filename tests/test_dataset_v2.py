"""naocal.dataset/2: a camera and a target per image, any joints of the robot description, per-image gravity;
every bad input named by file, line and field. (Version 1: tests/test_dataset.py and tests/test_formats_v1.py.)"""

import json

import numpy as np
import pytest

from naocal.solver.dataset import (GRAVITY_COLUMNS, META_FILE, OBSERVATIONS_FILE, SCHEMA_V2, DatasetAppender,
                            read_dataset, upgrade_v1, write_dataset)
from naocal.solver.errors import DataError

JOINTS = ("HeadYaw", "HeadPitch", "RHipYawPitch", "RHipRoll", "RHipPitch", "RKneePitch", "RAnklePitch", "RAnkleRoll")


def make_meta(**changes):
    meta = {
        "schema": SCHEMA_V2,
        "robot": {"id": "nao-17", "model": "H25 V6", "description": "nao"},
        "cameras": {"bottom": {"width_px": 640, "height_px": 480, "fx_px": 608.5, "fy_px": 609.25, "cx_px": 320.1,
                               "cy_px": 239.7},
                    "top": {"width_px": 1280, "height_px": 960, "fx_px": 1217.0, "fy_px": 1217.0, "cx_px": 640.0,
                            "cy_px": 480.0, "distortion": [0.01, 0.0, 0.0, 0.0, 0.0]}},
        "targets": {"floor": {"columns": 4, "rows": 4, "square_m": 0.1, "mass_kg": 0.0},
                    "R": {"columns": 7, "rows": 5, "square_m": 0.025, "mass_kg": 0.1, "centre_m": [0.17, 0, 0]}},
        "joints": list(JOINTS),
        "source": "test",
    }
    meta.update(changes)
    return meta


def make_columns(seed=0, gravity=False):
    """Four images: the floor board (9 vertices) in both cameras, the right sandal (24) in both."""
    rng = np.random.default_rng(seed)
    images = [(0, "bottom", "floor", 9), (1, "top", "floor", 9), (2, "bottom", "R", 24), (3, "top", "R", 24)]
    rows = [(i, cam, tgt, v) for i, cam, tgt, n in images for v in range(n)]
    image = np.array([r[0] for r in rows])
    columns = {"image": image, "camera": np.array([r[1] for r in rows]), "target": np.array([r[2] for r in rows]),
               "stance": image // 2, "head_posture": image % 2, "vertex": np.array([r[3] for r in rows])}
    for name in ("u_px", "v_px"):
        columns[name] = rng.normal(size=image.size)
    for name in ("x_mount_m", "y_mount_m", "z_mount_m"):  # within a metre of the target's frame (plausible)
        columns[name] = rng.normal(scale=0.1, size=image.size)
    columns["t_image_s"] = columns["t_joints_s"] = image * 1.5
    for prefix in ("", "cmd_", "dir_"):
        values = rng.integers(-1, 2, (4, len(JOINTS))) if prefix == "dir_" else rng.uniform(-0.05, 0.2, (4, len(JOINTS)))
        for j, joint in enumerate(JOINTS):
            columns[prefix + joint] = values[image, j].astype(float)
    if gravity:
        g = rng.normal(size=(4, 3)) + [0, 0, -9.81]
        for k, name in enumerate(GRAVITY_COLUMNS):
            columns[name] = g[image, k]
    return columns


def test_round_trip_with_two_cameras_two_targets_a_joint_subset_and_gravity(tmp_path):
    written = write_dataset((make_meta(), make_columns(gravity=True)), tmp_path / "ds")
    read = read_dataset(tmp_path / "ds")
    assert read.version == 2 and read.joints == JOINTS
    assert read.meta["gravity_mps2"] == [-9.81, 0.0, 0.0]  # the robot description's default, filled in
    assert set(read.columns["camera"]) == {"bottom", "top"} and set(read.columns["target"]) == {"floor", "R"}
    header = (tmp_path / "ds" / OBSERVATIONS_FILE).read_text().splitlines()[0].split(",")
    assert header[:6] == ["image", "camera", "target", "stance", "head_posture", "vertex"]
    assert header[-3:] == list(GRAVITY_COLUMNS)
    for name, values in written.columns.items():
        assert np.array_equal(values, read.columns[name]), name
    assert read.joint_matrix("cmd_").shape == (read.n_rows, len(JOINTS))
    assert read.as_v2() is read


def test_the_model_sees_both_cameras_the_targets_and_per_image_gravity(tmp_path):
    from naocal.solver.adapter import model_data_from_dataset

    write_dataset((make_meta(), make_columns(gravity=True)), tmp_path / "ds")
    data = model_data_from_dataset(read_dataset(tmp_path / "ds"))
    assert list(data.target) == ["R", "R", "floor", "floor"]  # the description's target order
    assert list(data.camera) == ["bottom", "top", "bottom", "top"]
    assert data.setup.cameras == ("bottom", "top") and data.setup.targets == ("R", "floor")
    assert data.cameras["top"]["width_px"] == 1280 and data.cameras["top"]["distortion"][0] == 0.01
    assert data.gravity_mps2.shape == (4, 3) and len({tuple(g) for g in data.gravity_mps2}) == 4
    assert data.loads["R"][0] == 0.1 and data.loads["floor"][0] == 0.0
    assert np.all(data.tau[data.target == "floor"] == 0.0)  # a supporting chain: no hanging load modelled
    assert np.any(data.tau[data.target == "R"] != 0.0)


def corrupt_meta(tmp_path, change):
    meta = make_meta()
    change(meta)
    path = tmp_path / "ds"
    write_dataset((make_meta(), make_columns()), path)
    (path / META_FILE).write_text(json.dumps(meta))
    with pytest.raises(DataError) as info:
        read_dataset(path)
    assert str(path / META_FILE) in str(info.value) and "\n" not in str(info.value)
    return info.value


@pytest.mark.parametrize("change,field,problem", [
    (lambda m: m["cameras"].update(side=m["cameras"]["bottom"]), "cameras.side", "not one of the robot's"),
    (lambda m: m["cameras"]["top"].update(fx_px=0), "cameras.top.fx_px", "must be positive"),
    (lambda m: m["cameras"].clear(), "cameras", "at least one camera"),
    (lambda m: m["targets"].update(hand={"columns": 3, "rows": 3, "square_m": 0.01, "mass_kg": 0}), "targets.hand",
     "not one of the robot's"),
    (lambda m: m["targets"]["R"].update(rows=1), "targets.R.rows", "must be at least 2"),
    (lambda m: m["targets"]["R"].pop("mass_kg"), "targets.R.mass_kg", "missing required field"),
    (lambda m: m["targets"]["R"].update(centre_m=[0.1, 0]), "targets.R.centre_m", "list of 3"),
    (lambda m: m.update(joints=["HeadYaw", "LFinger"]), "joints[1]", "not one of the robot's"),
    (lambda m: m.update(joints=["HeadYaw", "HeadYaw"]), "joints", "listed twice"),
    (lambda m: m["joints"].remove("RAnkleRoll"), "joints", "lacks joint 'RAnkleRoll', which moves target 'R'"),
    (lambda m: m["joints"].remove("HeadPitch"), "joints", "lacks joint 'HeadPitch', which moves camera 'bottom'"),
    (lambda m: m["robot"].update(description="../nao"), "robot.description", "name of a robot description"),
    (lambda m: m["robot"].update(description="pepper"), "robot.description", "unknown robot description"),
    (lambda m: m.update(gravity_mps2=[0, 0]), "gravity_mps2", "list of 3"),
    (lambda m: m.update(schema="naocal.dataset/9"), "schema", "wrong schema"),
])
def test_bad_meta_names_the_field(tmp_path, change, field, problem):
    err = corrupt_meta(tmp_path, change)
    assert err.field == field, str(err)
    assert problem in str(err)


def corrupt_rows(tmp_path, change, **kwargs):
    columns = make_columns(**kwargs)
    change(columns)
    with pytest.raises(DataError) as info:
        write_dataset((make_meta(), columns), tmp_path / "ds")
    return info.value


@pytest.mark.parametrize("change,field,line,problem", [
    (lambda c: c["camera"].__setitem__(3, "side"), "camera", 5, "unknown camera 'side'"),
    (lambda c: c["target"].__setitem__(0, "L"), "target", 2, "unknown target 'L'"),  # not in dataset.json
    (lambda c: c["vertex"].__setitem__(8, 9), "vertex", 10, "its target's vertex range"),  # the floor board has 9
    (lambda c: c["target"].__setitem__(20, "floor"), "target", 22, "differs within image 2"),
    (lambda c: c["RKneePitch"].__setitem__(30, 0.5), "RKneePitch", 32, "differs within image 2"),
    (lambda c: c.pop("cmd_RAnkleRoll"), "cmd_RAnkleRoll", 1, "missing required column"),
    (lambda c: c.pop("gravity_y_mps2"), "gravity_y_mps2", 1, "must be given together"),
    (lambda c: c["gravity_z_mps2"].__setitem__(0, np.nan), "gravity_z_mps2", 2, "expected a finite number"),
    # plausible values: pixels of each row's own camera, the robot description's joint limits, gravity's size
    (lambda c: c["u_px"].__setitem__(3, 1500.0), "u_px", 5, "the 640 x 480 image with a margin"),
    (lambda c: c["RKneePitch"].__setitem__(slice(18, 42), 3.0), "RKneePitch", 20, "the joint's limits"),
    (lambda c: c["x_mount_m"].__setitem__(5, 50.0), "x_mount_m", 7, "implausible value"),
    (lambda c: [c[n].__setitem__(slice(0, 9), 0.0) for n in GRAVITY_COLUMNS], "gravity_x_mps2", 2,
     "implausible gravity"),
])
def test_bad_rows_name_line_and_column(tmp_path, change, field, line, problem):
    columns = make_columns(gravity=True)
    columns = {k: (v.astype(object) if k in ("camera", "target") else v) for k, v in columns.items()}
    change(columns)
    with pytest.raises(DataError) as info:
        write_dataset((make_meta(), columns), tmp_path / "ds")
    err = info.value
    assert (err.field, err.line) == (field, line), str(err)
    assert problem in str(err)
    assert not (tmp_path / "ds").exists()  # nothing written that could not be read back


def test_a_version_1_dataset_upgrades_to_the_same_numbers():
    from pathlib import Path

    v1 = read_dataset(Path(__file__).parent / "data" / "v1" / "mock_dataset")
    assert v1.version == 1 and "leg" in v1.columns
    v2 = v1.as_v2()
    assert v2.version == 2 and v2.meta["targets"]["L"]["centre_m"] == [0.17, 0.0, 0.0]
    assert v2.meta["cameras"]["bottom"]["fx_px"] == 600.0 and "name" not in v2.meta["cameras"]["bottom"]
    assert np.array_equal(v2.columns["target"], v1.columns["leg"])
    assert set(v2.columns["camera"]) == {"bottom"}
    assert np.array_equal(v2.columns["x_mount_m"], v1.columns["x_sole_m"])
    assert np.array_equal(v2.joint_matrix(), v1.joint_matrix())
    meta, columns = upgrade_v1(v1.meta, v1.columns)
    assert meta == v2.meta


def test_appender_writes_version_2_and_refuses_to_mix_versions(tmp_path):
    columns = make_columns()
    appender = DatasetAppender(tmp_path / "ds", make_meta())
    for image in range(4):
        rows = columns["image"] == image
        appender.append({k: v[rows] for k, v in columns.items()})
    assert read_dataset(tmp_path / "ds").n_rows == 66
    from pathlib import Path

    old = Path(__file__).parent / "data" / "v1" / "mock_dataset"
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / META_FILE).write_text((old / META_FILE).read_text())
    with pytest.raises(DataError, match="existing dataset is naocal.dataset/1"):
        DatasetAppender(tmp_path / "old", make_meta())


def test_pixels_are_bounded_by_their_own_cameras_image(tmp_path):
    columns = make_columns()
    columns["u_px"][9:18] = 1500.0  # image 1: the top camera, 1280 px wide (the bottom one is 640)
    assert read_dataset(write_dataset((make_meta(), columns), tmp_path / "ds").path).n_rows == len(columns["u_px"])
