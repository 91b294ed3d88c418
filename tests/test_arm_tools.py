"""An arm's calibration file through the command line (docs/ARM.md): naocal verify of new data under it, naocal
offsets show / diff / validate / export of it, on synthetic data of the Franka Panda with a hidden truth."""

import json
import math

import numpy as np
import pytest

from test_arm import synthetic, true_errors, write
from naocal.tools.cli import main


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory):
    """Two datasets of one arm with hidden link lengths and joint offsets (even and odd poses of one simulation),
    and the calibration identified from the first."""
    root = tmp_path_factory.mktemp("arm")
    model, obs, _, sensors = synthetic(("joint_offsets", "link_lengths"), true_errors(seed=8), n_poses=60, seed=9)
    first = write(root / "first", model, obs.subset(obs.pose % 2 == 0), sensors)
    second = write(root / "second", model, obs.subset(obs.pose % 2 == 1), sensors)
    assert main(["identify", str(first), "--out", str(root / "cal.json"), "--json"]) == 0
    return root, first, second, root / "cal.json"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def edited(path, out, edit):
    doc = json.loads(path.read_text())
    edit(doc)
    out.write_text(json.dumps(doc))
    return out


def shift(doc, name, delta):
    doc["model"]["parameters"][name]["value"] += delta
    section, key = name.split(".", 1)
    table = {"joint_offset": "joint_offsets_rad", "link_length": "link_lengths_m"}[section]
    doc[table][key] += delta


# ------------------------------------------------------------------------------------------------ verify


def test_verify_new_data_of_the_same_arm_is_still_good(two_sessions, capsys):
    root, _, second, cal = two_sessions
    code, out, err = run(capsys, "verify", second, "--offsets", cal, "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["good"] and report["ratio"] < 1.3 and not report["moved"]
    assert set(report["per_sensor"]) == {"tracker", "camera"}
    assert report["per_sensor"]["tracker"]["unit"] == "m" and report["per_sensor"]["camera"]["unit"] == "px"
    assert report["per_sensor"]["tracker"]["rms"] == pytest.approx(1e-4, rel=0.2)
    code, out, _ = run(capsys, "verify", second, "--offsets", cal)
    assert code == 0 and out.strip().splitlines()[-1].startswith("still good")


@pytest.mark.parametrize("name, delta, unit", [("joint_offset.panda_joint4", math.radians(0.3), "deg"),
                                               ("link_length.panda_link4", 1e-3, "mm")])
def test_verify_names_what_moved_when_the_arm_drifted(two_sessions, capsys, tmp_path, name, delta, unit):
    root, _, second, cal = two_sessions
    drifted = edited(cal, tmp_path / "drifted.json", lambda doc: shift(doc, name, delta))
    code, out, err = run(capsys, "verify", second, "--offsets", drifted, "--json")
    assert code == 1, err
    report = json.loads(out)
    assert not report["good"] and report["ratio"] > 3
    assert report["moved"][0]["parameter"] == name
    # the data say the calibrated value is `delta` too large
    assert report["moved"][0]["change"] == pytest.approx(-delta, rel=0.05)
    assert report["moved"][0]["display"][1] == unit and report["verdict"].startswith("drifted")


def test_verify_and_diagnose_name_poses_by_the_file_s_labels(two_sessions, capsys, tmp_path):
    """Poses labelled with text in the file (a lab's 'home', 'P-17') are reported by those labels, not by the
    numbers the reader gave them."""
    root, _, second, cal = two_sessions
    labelled = tmp_path / "labelled"
    labelled.mkdir()
    (labelled / "dataset.json").write_text((second / "dataset.json").read_text())
    lines = (second / "observations.csv").read_text().splitlines()
    pose = lines[0].split(",").index("pose")
    rows = [line.split(",") for line in lines[1:]]
    for r in rows:
        r[pose] = f"P-{r[pose]}"
    (labelled / "observations.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    drifted = edited(cal, tmp_path / "drifted.json", lambda doc: shift(doc, "joint_offset.panda_joint4", 0.005))
    code, out, err = run(capsys, "verify", labelled, "--offsets", drifted, "--json")
    assert code == 1, err
    report = json.loads(out)
    labels = {r[pose] for r in rows}
    assert {e["pose"] for e in report["per_pose"]} == labels
    assert report["worst_poses"] and all(e["pose"] in labels for e in report["worst_poses"])
    code, out, err = run(capsys, "diagnose", labelled, "--json")
    assert code == 0, err
    assert all(e["pose"] in labels for e in json.loads(out)["worst_poses"])


def test_verify_without_stated_noise_takes_a_refit_as_the_noise_floor(two_sessions, capsys, tmp_path):
    root, _, second, cal = two_sessions
    import shutil

    quiet = tmp_path / "quiet"
    shutil.copytree(second, quiet)
    edited(quiet / "dataset.json", quiet / "dataset.json",
           lambda doc: [s.pop("noise_m", None) or s.pop("noise_px", None) for s in doc["sensors"].values()])
    code, out, err = run(capsys, "verify", quiet, "--offsets", cal, "--json")
    assert code == 0, err
    tracker = json.loads(out)["per_sensor"]["tracker"]
    assert tracker["noise_source"] == "refit" and tracker["noise_floor"] == pytest.approx(1e-4, rel=0.25)


def test_verify_bad_input_is_one_line_exit_2(two_sessions, capsys, tmp_path):
    root, first, second, cal = two_sessions
    nao = tmp_path / "nao.json"
    nao.write_text(json.dumps({"schema": "naocal.offsets/2"}))
    other_tip = edited(cal, tmp_path / "tip.json", lambda doc: doc["robot"].update(tip="panda_link7"))
    other_arm = edited(cal, tmp_path / "id.json", lambda doc: doc["robot"].update(id="another"))
    damaged = edited(cal, tmp_path / "bad.json",
                     lambda doc: doc["model"]["parameters"]["joint_offset.panda_joint2"].update(value="x"))
    unit = edited(cal, tmp_path / "unit.json",
                  lambda doc: doc["model"]["parameters"]["link_length.panda_link3"].update(unit="mm"))
    for offsets, message in ((nao, "naocal.arm_calibration/1"), (other_tip, "robot.tip"), (other_arm, "robot.id"),
                             (damaged, "model.parameters.joint_offset.panda_joint2.value"),
                             (unit, "model.parameters.link_length.panda_link3.unit"),
                             (tmp_path / "missing.json", "missing.json")):
        code, out, err = run(capsys, "verify", second, "--offsets", offsets)
        assert code == 2 and message in err and err.count("\n") == 1, (offsets, err)
    code, _, err = run(capsys, "verify", tmp_path / "nowhere", "--offsets", cal)
    assert code == 2 and "nowhere" in err


# ------------------------------------------------------------------------------------------------ offsets


def test_offsets_diff_of_two_arm_calibrations_per_parameter_with_units(two_sessions, capsys, tmp_path):
    root, first, second, cal = two_sessions
    assert main(["identify", str(second), "--out", str(tmp_path / "b.json")]) == 0
    capsys.readouterr()
    code, out, err = run(capsys, "offsets", "diff", cal, tmp_path / "b.json")
    assert code == 0, err
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith("  joint_offset.")
            or line.startswith("  link_length.") or line.startswith("  sensor.")}
    assert rows["joint_offset.panda_joint4"].split()[-1] in ("deg", "*") and "mm" in rows["link_length.panda_link4"]
    moved = edited(tmp_path / "b.json", tmp_path / "moved.json",
                   lambda doc: shift(doc, "link_length.panda_link4", 2e-3))
    code, out, _ = run(capsys, "offsets", "diff", cal, moved, "--fail-on-difference")
    assert code == 1
    line = next(line for line in out.splitlines() if line.startswith("  link_length.panda_link4"))
    assert line.endswith("mm *") and float(line.split()[3]) == pytest.approx(2.0, abs=0.1)  # B - A in mm
    nao = tmp_path / "nao.json"
    nao.write_text(json.dumps({"schema": "naocal.offsets/2"}))
    code, _, err = run(capsys, "offsets", "diff", cal, nao)
    assert code == 2 and "nao.json" in err and err.count("\n") == 1


def test_offsets_validate_show_and_apply_an_arm_calibration(two_sessions, capsys, tmp_path):
    root, first, second, cal = two_sessions
    assert run(capsys, "offsets", "validate", cal)[:2] == (0, "ok\n")
    code, out, _ = run(capsys, "offsets", "show", cal)
    assert code == 0 and "link_length.panda_link4" in out and "fit: tracker RMS" in out
    c = json.loads(cal.read_text())["joint_offsets_rad"]["panda_joint2"]
    code, out, _ = run(capsys, "offsets", "apply", cal, "--command", "panda_joint2=10")
    assert code == 0 and float(out.split("=")[1]) == pytest.approx(10 + math.degrees(c))
    code, out, _ = run(capsys, "offsets", "apply", cal, "--reading", "--rad", "panda_joint2=0.5")
    assert float(out.split("=")[1]) == pytest.approx(0.5 - c)
    damaged = edited(cal, tmp_path / "bad.json", lambda doc: doc["joint_offsets_rad"].update(panda_joint2=1.0))
    for argv, message in ((["validate", damaged], "joint_offsets_rad.panda_joint2"),
                          (["show", damaged], "joint_offsets_rad.panda_joint2"),
                          (["apply", cal, "--command", "LHipPitch=3"], "unknown joint"),
                          (["export", cal, "--format", "hulks"], "urdf or json")):
        code, _, err = run(capsys, "offsets", *argv)
        assert code == 2 and message in err and err.count("\n") == 1, err


def _calibration_file(path, values, urdf):
    """A naocal.arm_calibration/1 with these parameter values (SI) of the panda."""
    from naocal.kinds.arm.calibration import SCHEMA

    params = {n: {"value": v, "std": 0.0, "unit": "m" if n.startswith("link_length.") or n.split(".")[-1] in "xyz"
                  else "rad", "fixed": False} for n, v in values.items()}
    doc = {"schema": SCHEMA, "created": "2026-01-02T03:04:05Z",
           "robot": {"urdf": str(urdf), "base": "panda_link0", "tip": "panda_hand", "id": "arm<-->7"},
           "model": {"effects": ["joint_offsets", "link_lengths", "link_poses"], "parameters": params}}
    path.write_text(json.dumps(doc))
    return path


def test_offsets_export_urdf_gives_the_calibrated_arm_to_pybullet(tmp_path, capsys):
    """The exported URDF loaded into PyBullet (an independent forward kinematics) at the joint readings puts the
    hand where naocal's model of the calibration does, for joint offsets, link lengths and full link poses."""
    from naocal.body.pybullet_quiet import pybullet
    from naocal.kinds.arm.model import ArmModel, Observations
    from test_arm import panda

    urdf, base, tip, chain, names, load = panda()
    rng = np.random.default_rng(11)
    model = ArmModel(chain, {"o": (0.0, 0.0, 0.0), "x": (0.1, 0.0, 0.0), "y": (0.0, 0.1, 0.0)}, [],
                     ("joint_offsets", "link_lengths", "link_poses"), load=load, link_names=names)
    values = {p.name: float(rng.normal(0.0, 3e-3 if p.unit == "m" else 0.01)) for p in model.parameters}
    cal = _calibration_file(tmp_path / "cal.json", values, urdf)
    code, _, err = run(capsys, "offsets", "export", cal, "--format", "urdf", "--strip-meshes", "--out",
                       tmp_path / "calibrated.urdf")
    assert code == 0, err
    text = (tmp_path / "calibrated.urdf").read_text()
    assert "arm<-\\u002d>7" in text  # the file's strings are escaped in the header comment
    theta = rng.uniform(-1.0, 1.0, (5, 7))
    obs = Observations(np.repeat(theta, 3, axis=0), np.repeat(np.arange(5), 3), np.zeros(15, int),
                       np.tile(np.arange(3), 5), np.zeros((15, 3)))
    expected = model.base_points(np.array([values[n] for n in model.names]), obs).reshape(5, 3, 3)
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(tmp_path / "calibrated.urdf"), useFixedBase=True, physicsClientId=client)
        info = [pybullet.getJointInfo(body, i, physicsClientId=client)
                for i in range(pybullet.getNumJoints(body, physicsClientId=client))]
        joint_index = {i[1].decode(): i[0] for i in info}
        hand = {i[12].decode(): i[0] for i in info}[tip]
        for row, angles in enumerate(theta):
            for joint, angle in zip(chain.joint_names, angles):
                pybullet.resetJointState(body, joint_index[joint], angle, physicsClientId=client)
            state = pybullet.getLinkState(body, hand, computeForwardKinematics=True, physicsClientId=client)
            R = np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3)
            found = np.array([R @ p + np.array(state[4]) for p in model.point_xyz])
            assert np.abs(found - expected[row]).max() < 1e-6  # PyBullet keeps ~1e-7 m
    finally:
        pybullet.disconnect(client)
    # and the nominal URDF is not where the calibration puts the hand (the test can fail)
    zero = model.base_points(np.zeros(len(model.names)), obs).reshape(5, 3, 3)
    assert np.abs(zero - expected).max() > 1e-3


def test_identify_refuses_a_fit_beyond_what_a_calibration_file_may_hold(tmp_path, capsys):
    """A joint whose readings are 25 deg off the URDF's zero (another zero convention): exit 3 and no file, not a
    calibration file every reader then refuses."""
    truth = dict(true_errors(seed=8), **{"joint_offset.panda_joint4": math.radians(25.0)})
    model, obs, _, sensors = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=30, seed=9)
    d = write(tmp_path / "d", model, obs, sensors)
    code, _, err = run(capsys, "identify", d, "--out", tmp_path / "cal.json")
    assert code == 3 and "joint_offset.panda_joint4" in err and "nothing written" in err, err
    assert not (tmp_path / "cal.json").exists()
