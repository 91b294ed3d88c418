"""naocal.arm_dataset/1 as real exports write it (docs/FORMATS.md): comment lines, CRLF, a byte order mark, padded
headers, ';' with decimal commas or tabs, tracker-only and camera-only data, markers not seen, one sensor or point
without their columns, pose labels; readings in the wrong unit refused; an arm without hidden errors reported
honestly. On synthetic data of the Franka Panda (tests/test_arm.py)."""

import json
import math
import re

import numpy as np
import pytest

from naocal.kinds.arm.dataset import read_arm_dataset
from naocal.solver.errors import DataError
from test_arm import synthetic, true_errors, write
from naocal.tools.cli import main


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """A dataset as naocal writes it, with hidden joint offsets and link lengths, and its truth."""
    truth = true_errors(seed=21)
    model, obs, _, sensors = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=40, seed=22)
    directory = write(tmp_path_factory.mktemp("arm") / "plain", model, obs, sensors)
    return directory, truth


def copy(plain, target, csv_text=None, edit_meta=None):
    target.mkdir()
    meta = json.loads((plain / "dataset.json").read_text())
    if edit_meta:
        edit_meta(meta)
    (target / "dataset.json").write_text(json.dumps(meta))
    (target / "observations.csv").write_bytes((csv_text if csv_text is not None else
                                               (plain / "observations.csv").read_text()).encode("utf-8"))
    return target


def table(plain):
    lines = (plain / "observations.csv").read_text().splitlines()
    return lines[0].split(","), [line.split(",") for line in lines[1:]]


def identify(capsys, directory, *extra):
    code = main(["identify", str(directory), "--json", *map(str, extra)])
    out = capsys.readouterr()
    return code, (json.loads(out.out) if code == 0 else None), out.err


def assert_recovered(report, truth, angle_deg=0.01, length_m=1e-4):
    """Every free arm parameter within 4 of its standard deviations of the truth, and those within the
    tolerance (40 poses: the must-show's 0.01 deg and 0.1 mm are for 60, tests/test_arm_sim.py)."""
    checked = 0
    for name, entry in report["parameters"].items():
        if entry["fixed"] or name.startswith("sensor."):
            continue
        tolerance = length_m if name.startswith("link_length.") else math.radians(angle_deg)
        assert abs(entry["value"] - truth.get(name, 0.0)) < 4 * entry["std"] and entry["std"] < tolerance, name
        checked += 1
    assert checked >= 10


def test_a_spreadsheet_export_reads_as_the_plain_file(plain, tmp_path):
    """Byte order mark, comment lines before and inside the table, CRLF, padded header cells, ';' as the
    delimiter with decimal commas; and the same with tabs: the same observations."""
    directory, _ = plain
    reference = read_arm_dataset(directory).observations
    header, rows = table(directory)
    semicolon = ("\ufeff# exported by the cell controller\r\n# units: rad, m, px\r\n"
                 + ";".join(f" {h} " for h in header) + "\r\n"
                 + "".join(("# a comment between rows\r\n" if i == 5 else "") + ";".join(c.replace(".", ",")
                                                                                       for c in r) + "\r\n"
                           for i, r in enumerate(rows)))
    tabs = "\t".join(header) + "\n" + "".join("\t".join(r) + "\n" for r in rows)
    for name, text in (("semicolon", semicolon), ("tabs", tabs)):
        obs = read_arm_dataset(copy(directory, tmp_path / name, text)).observations
        assert np.array_equal(obs.theta, reference.theta) and np.array_equal(obs.measured, reference.measured)
        assert np.array_equal(obs.pose, reference.pose) and np.array_equal(obs.sensor, reference.sensor)


def test_tracker_only_data_without_camera_columns_recover_the_truth(plain, tmp_path, capsys):
    directory, truth = plain
    header, rows = table(directory)
    keep = [i for i, h in enumerate(header) if h not in ("u_px", "v_px")]
    text = "\n".join(",".join(r[i] for i in keep) for r in [header] + [r for r in rows if r[1] == "tracker"])
    tracker_only = copy(directory, tmp_path / "tracker", text, lambda m: m["sensors"].pop("camera"))
    code, report, err = identify(capsys, tracker_only)
    assert code == 0, err
    assert set(report["rms"]) == {"tracker"}
    assert_recovered(report, truth)
    # dataset.json still naming the camera, which has no rows (nor columns): left out, and said so
    named = copy(directory, tmp_path / "named", text)
    code, report, err = identify(capsys, named)
    assert code == 0 and set(report["rms"]) == {"tracker"}, err
    assert "note:" in err and "camera" in err and "left out" in err


def test_camera_only_data_are_identified(plain, tmp_path, capsys):
    directory, truth = plain
    header, rows = table(directory)
    keep = [i for i, h in enumerate(header) if h not in ("x_m", "y_m", "z_m")]
    text = "\n".join(",".join(r[i] for i in keep) for r in [header] + [r for r in rows if r[1] == "camera"])
    camera_only = copy(directory, tmp_path / "camera", text, lambda m: m["sensors"].pop("tracker"))
    code, report, err = identify(capsys, camera_only)
    assert code == 0, err
    assert set(report["rms"]) == {"camera"} and report["rms"]["camera"]["value"] == pytest.approx(0.2, rel=0.25)
    # one camera of 0.2 px at 2.5 m sees less than the tracker (joint 6: std 0.04 deg): its own uncertainty
    assert_recovered(report, truth, angle_deg=0.1, length_m=1e-3)


def test_markers_not_seen_are_left_out_and_partial_readings_refused(plain, tmp_path, capsys):
    directory, _ = plain
    header, rows = table(directory)
    u, v, x = header.index("u_px"), header.index("v_px"), header.index("x_m")
    camera_rows = [i for i, r in enumerate(rows) if r[1] == "camera"]
    unseen = [list(r) for r in rows]
    for i in camera_rows[:3]:
        unseen[i][u] = unseen[i][v] = ""
    unseen[camera_rows[3]][u] = unseen[camera_rows[3]][v] = "nan"
    d = copy(directory, tmp_path / "unseen", "\n".join(",".join(r) for r in [header] + unseen))
    data = read_arm_dataset(d)
    assert len(data.observations) == len(rows) - 4 and "4 row(s) without a measurement" in data.notes[0]
    partial = [list(r) for r in rows]
    tracker_row = next(i for i, r in enumerate(rows) if r[1] == "tracker")
    partial[tracker_row][x] = ""
    d = copy(directory, tmp_path / "partial", "\n".join(",".join(r) for r in [header] + partial))
    with pytest.raises(DataError, match=rf"line {tracker_row + 2}, field 'x_m'"):
        read_arm_dataset(d)


def test_one_sensor_and_one_point_need_no_columns_and_poses_may_be_labels(plain, tmp_path):
    directory, _ = plain
    header, rows = table(directory)
    drop = {header.index(h) for h in ("sensor", "point", "u_px", "v_px")}
    pose = header.index("pose")
    rows = [r for r in rows if r[1] == "tracker" and r[2] == "t1"]
    text = "\n".join(",".join(("P-" + c if i == pose and n else c) for i, c in enumerate(r) if i not in drop)
                     for n, r in enumerate([header] + rows))

    def one(meta):
        meta["sensors"].pop("camera")
        meta["points"] = {"t1": meta["points"]["t1"]}

    data = read_arm_dataset(copy(directory, tmp_path / "one", text, one))
    assert len(data.observations) == len(rows) and set(data.observations.sensor.tolist()) == {0}
    assert len(np.unique(data.observations.pose)) == len(rows)
    # two sensors named in dataset.json: the sensor column is needed
    with pytest.raises(DataError, match="field 'sensor'"):
        read_arm_dataset(copy(directory, tmp_path / "two", text, lambda m: m.update(points={"t1": m["points"]["t1"]})))


@pytest.mark.parametrize("column, factor, message", [
    ("panda_joint2_rad", 180 / math.pi, "degrees in a _rad column"),
    ("y_m", 1000.0, "millimetres in an _m column"),
    ("u_px", 100.0, "beyond one image size"),
])
def test_readings_in_the_wrong_unit_are_refused_naming_line_and_column(plain, tmp_path, column, factor, message):
    directory, _ = plain
    header, rows = table(directory)
    c = header.index(column)
    rows = [list(r) for r in rows]
    row = next(i for i, r in enumerate(rows) if r[c])
    rows[row][c] = repr(float(rows[row][c]) * factor + (1000.0 if column == "u_px" else 0.0))
    d = copy(directory, tmp_path / "wrong", "\n".join(",".join(r) for r in [header] + rows))
    with pytest.raises(DataError, match=rf"line {row + 2}, field '{column}'.*{message}"):
        read_arm_dataset(d)


def test_identify_takes_a_robust_loss_and_lists_wrong_detections_by_line(plain, tmp_path, capsys):
    """`--loss` is the NAO's for an arm too (it was refused); a tracker reading 5 mm off and a marker 30 px off are
    set aside and listed with their pose, sensor, point and line, in the table and in --json."""
    directory, truth = plain
    header, rows = table(directory)
    tracker = next(k for k, r in enumerate(rows) if r[1] == "tracker" and int(r[0]) == 7)
    camera = next(k for k, r in enumerate(rows) if r[1] == "camera" and int(r[0]) == 12)
    rows[tracker][header.index("x_m")] = repr(float(rows[tracker][header.index("x_m")]) + 5e-3)
    rows[camera][header.index("u_px")] = repr(float(rows[camera][header.index("u_px")]) + 30.0)
    damaged = copy(directory, tmp_path / "damaged", "\n".join([",".join(header)] + [",".join(r) for r in rows]))
    for loss in ("linear", "soft_l1"):
        code, report, err = identify(capsys, damaged, "--loss", loss)
        assert code == 0, err
        assert report["loss"] == loss
        assert {(o["pose"], o["sensor"], o["point"], o["line"]) for o in report["outliers"]} == {
            (7, "tracker", rows[tracker][2], tracker + 2), (12, "camera", rows[camera][2], camera + 2)}
        assert_recovered(report, truth, angle_deg=0.02, length_m=2e-4)
    assert main(["identify", str(damaged), "--loss", "huber"]) == 0
    out = capsys.readouterr().out
    assert f"outliers: 2 detections in 2 poses set aside" in out and f"(line {tracker + 2})" in out
    assert main(["identify", str(damaged), "--loss-scale-px", "3"]) == 2
    assert "--loss-scale-px is the NAO's" in capsys.readouterr().err


def test_an_arm_without_hidden_errors_is_reported_honestly(tmp_path, capsys):
    """No error to find: identify succeeds with values within their uncertainty of zero and names its weakest
    directions; diagnose finds nothing missing. (40 poses, as assert_recovered's tolerances are for: with 30 the
    per-pose clustered std of the sixth joint's offset is 0.0103 deg, its classic one 0.0082 deg.)"""
    model, obs, _, sensors = synthetic(("joint_offsets", "link_lengths"), {}, n_poses=40, seed=23)
    d = write(tmp_path / "exact", model, obs, sensors)
    code, report, err = identify(capsys, d)
    assert code == 0, err
    assert_recovered(report, {})
    for name, entry in report["parameters"].items():
        if not entry["fixed"] and not name.startswith("sensor."):
            assert abs(entry["value"]) < 5 * entry["std"], name
    assert report["weak_directions"] and all(w["coefficients"] for w in report["weak_directions"])
    assert main(["diagnose", str(d), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["verdict"] is None


def test_the_examples_in_formats_md_read_as_documented(tmp_path, capsys):
    """docs/FORMATS.md's dataset.json and observations.csv examples, as they are there."""
    import re
    import shutil
    from pathlib import Path

    from naocal.kinds.arm.dataset import resolve_robot

    text = (Path(__file__).resolve().parents[1] / "docs" / "FORMATS.md").read_text()
    section = text[text.index("## `naocal.arm_dataset/1`"):]
    meta = re.search(r"```json\n(.*?)```", section, re.S).group(1)
    rows = re.search(r"```\n(# exported.*?)```", section, re.S).group(1)
    (tmp_path / "dataset.json").write_text(meta)
    (tmp_path / "observations.csv").write_text(rows)
    shutil.copyfile(resolve_robot("franka_panda", None)[0], tmp_path / "panda.urdf")
    data = read_arm_dataset(tmp_path)
    obs = data.observations
    assert len(obs) == 3 and "1 row(s) without a measurement" in data.notes[0]
    assert np.allclose(obs.theta[0], np.radians([12.5, -30.0, 5.0, -120.0, 10.0, 95.0, 45.0]))
    assert np.allclose(obs.measured[0], [1.532114, -2.010527, 0.312880])  # mm -> m
    assert np.allclose(obs.measured[1, :2], [702.31, 488.90]) and obs.pose.tolist() == [0, 0, 1]
    assert [s.name for s in data.sensors] == ["tracker", "camera"] and data.sensors[0].noise == 2e-5


@pytest.mark.parametrize("edit, field", [
    (lambda m: m["sensors"]["camera"].update(fx_px=1e308), "sensors.camera.fx_px"),  # once an SVD failure
    (lambda m: m["sensors"]["camera"].update(distortion=[1e300, 0, 0, 0, 0]), "sensors.camera.distortion[0]"),
    (lambda m: m["sensors"]["camera"].update(width_px=640.5), "sensors.camera.width_px"),  # the intrinsics' one check
    (lambda m: m["sensors"]["camera"].update(cx_px=-5.0), "sensors.camera.cx_px"),
    (lambda m: m["sensors"]["tracker"].update(noise_m=5.0), "sensors.tracker.noise_m"),
    (lambda m: m["sensors"]["tracker"].update(pose={"rotation_rad": [1e300, 0, 0], "translation_m": [0, 0, 0]}),
     "sensors.tracker.pose.rotation_rad[0]"),
    (lambda m: m.update(gravity_mps2=[0.0, 0.0, -9810.0]), "gravity_mps2[2]"),
    (lambda m: m.update(gravity_mps2=[0.0, 0.0, 0.0]), "gravity_mps2"),
])
def test_implausible_dataset_json_numbers_are_refused_naming_the_field(plain, tmp_path, edit, field):
    directory, _ = plain
    with pytest.raises(DataError, match=rf"field '{re.escape(field)}'"):
        read_arm_dataset(copy(directory, tmp_path / "bad", edit_meta=edit))


def test_an_arm_dataset_is_recognised_wherever_its_schema_key_stands(plain, tmp_path, capsys):
    """A real export may write `schema` last, after kilobytes of points and sensors."""
    directory, _ = plain

    def schema_last(meta):
        meta.pop("schema")
        meta["about"] = "x" * 5000
        meta["schema"] = "naocal.arm_dataset/1"

    d = copy(directory, tmp_path / "last", edit_meta=schema_last)
    assert main(["identify", str(d), "--cv-folds", "0", "--out", str(tmp_path / "cal.json")]) == 0, \
        capsys.readouterr().err
    doc = json.loads((tmp_path / "cal.json").read_text())
    doc["about"] = "y" * 5000
    doc["schema"] = doc.pop("schema")
    (tmp_path / "cal.json").write_text(json.dumps(doc))
    assert main(["offsets", "validate", str(tmp_path / "cal.json")]) == 0
