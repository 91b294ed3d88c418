"""Calibrating a real NAO's camera from real images: MRL-SPL's six 2009 images of a standing NAO V3 and a 4 x 4
board on the floor (tests/data/realdata/mrlspl-nao-2009/, MIT), imported by `naocal import mrlspl`, identified
and diagnosed. The numbers asserted are the ones measured (docs/REALDATA.md); the tolerances are tight enough that
a change in the importer, the detector or the model that moves them shows here."""

import csv
import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from naocal.tools.cli import main

DATA = Path(__file__).parent / "data" / "realdata" / "mrlspl-nao-2009"
CAMERA_ONLY = ["--fix", "joint_offsets", "--fix", "board_mount"]


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    out = tmp_path_factory.mktemp("realdata") / "dataset"
    assert main(["import", "mrlspl", str(DATA), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def dataset(imported):
    from naocal.solver.dataset import read_dataset

    return read_dataset(imported)


def _json_of(capsys, argv) -> dict:
    capsys.readouterr()
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


# ------------------------------------------------------------------------------------------------ the importer

def test_the_importer_gives_six_images_of_nine_corners_with_the_readings_mapped(dataset, imported):
    assert dataset.version == 2 and dataset.n_rows == 54
    images, counts = np.unique(dataset.columns["image"], return_counts=True)
    assert images.tolist() == list(range(6)) and counts.tolist() == [9] * 6
    assert set(dataset.columns["target"]) == {"floor"} and set(dataset.columns["camera"]) == {"bottom"}
    camera = dataset.meta["cameras"]["bottom"]
    assert (camera["width_px"], camera["height_px"]) == (320, 240)
    assert camera["fx_px"] == camera["fy_px"] == pytest.approx(160 / math.tan(1.0641 / 2))
    assert camera["fx_px"] == pytest.approx(271.8, abs=0.05)
    # The readings, from the file's own columns: HeadPitch's sign turned, every other joint as stored.
    with open(DATA / "joints_raw.csv") as f:
        raw = {int(row["image"]): row for row in csv.DictReader(f)}
    first = np.searchsorted(dataset.columns["image"], np.arange(6))
    for image in range(6):
        row = first[image]
        assert dataset.columns["HeadPitch"][row] == -float(raw[image]["HeadPitch_raw_rad"])
        for joint in ("HeadYaw", "LHipRoll", "RHipPitch", "RKneePitch", "RAnkleRoll"):
            assert dataset.columns[joint][row] == float(raw[image][joint + "_raw_rad"])
    # Gravity per image: 9.81 m/s^2, along -z of the right sole (upright torso: mostly -z of the torso).
    g = np.column_stack([dataset.columns[f"gravity_{a}_mps2"] for a in "xyz"])
    assert np.allclose(np.linalg.norm(g, axis=1), 9.81)
    assert np.all(g[:, 2] < -8.5)
    # Provenance and the images with their licence.
    provenance = dataset.meta["provenance"]
    assert provenance["sign_changes"] == {"HeadPitch": -1.0}
    assert "B-Human 2009" in provenance["joint_order"] and "mrlspl" in dataset.meta["source"]
    assert sorted(p.name for p in (imported / "images").iterdir()) == [f"{i:06d}.png" for i in range(6)] + [
        "LICENSE.MIT.txt"]


def test_the_corners_are_in_the_floor_targets_vertex_order(dataset):
    """Checked from the image, not from the prediction that ordered them: vertex col runs along +x of the sole
    (away from the robot: up in the image), row along +y (to the robot's left: left in the image), and the square
    before vertex 0 is orange (the target's first colour; Cr high, blue below 100)."""
    for image in range(6):
        rows = dataset.columns["image"] == image
        order = np.argsort(dataset.columns["vertex"][rows])
        uv = np.column_stack([dataset.columns["u_px"][rows], dataset.columns["v_px"][rows]])[order].reshape(3, 3, 2)
        along_col, along_row = uv[:, 1:] - uv[:, :-1], uv[1:] - uv[:-1]
        assert np.all(along_col[..., 1] < -10)  # col + 1: up in the image
        assert np.all(along_row[..., 0] < -10)  # row + 1: left in the image
        picture = cv2.imread(str(DATA / f"image_{image}.png"))
        x, y = np.round(1.5 * uv[0, 0] - 0.5 * uv[1, 1]).astype(int)  # half a diagonal beyond vertex 0
        assert cv2.cvtColor(picture, cv2.COLOR_BGR2YCrCb)[y, x, 1] > 150


def test_the_nominal_model_misses_by_20_to_35_px(dataset):
    """The solver's own model at zero parameters (the URDF's geometry, the read angles)."""
    from naocal.solver.adapter import model_data_from_dataset
    from naocal.solver.model import Model
    from naocal.solver.registry import Registry

    data = model_data_from_dataset(dataset)
    registry = Registry.for_data(data)
    r = Model(data, registry).residuals(registry.zeros()).reshape(-1, 2)
    per_image = [float(np.sqrt(np.mean(np.sum(r[data.image_of_row == k] ** 2, axis=1)))) for k in range(6)]
    assert per_image == pytest.approx([28.21, 35.08, 20.27, 31.29, 28.94, 28.89], abs=0.05)
    assert float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) == pytest.approx(29.14, abs=0.05)
    # The importer's record agrees with the model.
    recorded = [dataset.meta["provenance"]["images"][str(k)]["nominal_rms_px"] for k in range(6)]
    assert recorded == pytest.approx(per_image, abs=0.01)


# ------------------------------------------------------------------------------------- calibration and diagnosis

def test_the_camera_rotation_brings_it_to_4_6_px_with_the_pitch_determined(imported, capsys):
    report = _json_of(capsys, ["identify", str(imported), *CAMERA_ONLY, "--json"])
    assert report["success"] and report["n_vertices"] == 54 and report["n_images"] == 6
    assert report["rms_px"] == pytest.approx([4.496, 4.713], abs=0.01)
    assert report["cv_rms_px"] == pytest.approx([5.21, 5.90], abs=0.03)
    p = {name: (math.degrees(e["value"]), math.degrees(e["std"]))
         for name, e in report["model_parameters"].items() if name.startswith("camera.bottom.")}
    assert p["camera.bottom.pitch"] == pytest.approx((5.87, 0.41), abs=0.02)  # 14 std from zero
    # not distinguishable from zero (the sandwich of 6 clusters said 0.71; the classic estimate along roll is 1.02)
    assert p["camera.bottom.roll"] == pytest.approx((-0.50, 1.02), abs=0.02)
    assert p["camera.bottom.yaw"] == pytest.approx((0.43, 0.35), abs=0.02)
    # Roll is the weakest direction.
    weakest = report["weak_directions"][0]
    assert weakest["singular_value"] == pytest.approx(0.14, abs=0.01)
    assert abs(weakest["coefficients"]["camera.bottom.roll"]) > 0.95


def test_freeing_the_board_or_the_leg_fits_the_six_images_no_better_out_of_sample(imported, capsys):
    """More parameters lower the fit a little and raise the cross-validated error: with 6 images they fit noise
    (the unconstrained right-leg offsets reach 12.6 deg, inside the 20 deg a worn NAO may show, but they predict
    held-out images worse than the camera rotation alone)."""
    board = _json_of(capsys, ["identify", str(imported), "--fix", "joint_offsets", "--json"])
    assert board["rms_px"] == pytest.approx([4.32, 4.54], abs=0.02)
    assert board["cv_rms_px"][1] > 8.0  # against 5.9 px with the camera rotation alone
    assert board["model_parameters"]["board.floor.trans_x"]["std"] > 0.010  # m: the board's place is not determined
    leg = _json_of(capsys, ["identify", str(imported), "--fix", "board_mount", "--json"])
    assert leg["rms_px"] == pytest.approx([1.57, 2.56], abs=0.02)
    assert leg["cv_rms_px"][1] > 7.0  # against 5.9 px with the camera rotation alone
    assert math.degrees(leg["joint_offsets_c"]["RHipYawPitch"]["c_rad"]) == pytest.approx(12.6, abs=0.1)


def test_the_diagnosis_finds_a_rigid_kinematic_misfit_no_candidate_explains(imported, capsys):
    report = _json_of(capsys, ["diagnose", str(imported), *CAMERA_ONLY, "--json"])
    assert report["rms_total_px"] == pytest.approx(4.606, abs=0.01)
    assert report["noise_px"] == pytest.approx(0.115, abs=0.01)  # the detector's floor: 40 x below the misfit
    assert report["locate"]["rigid_share"] > 0.998
    worst = [w["image"] for w in report["locate"]["worst_images"]]
    assert sorted(worst[:4]) == [1, 2, 3, 4]  # the images where the left foot leans; 0 and 5 below 2 px
    split = {s["image"]: s["rigid_rms_px"] for s in report["locate"]["per_image_split"]}
    assert split[0] < 2.0 and split[5] < 2.0 and min(split[k] for k in (1, 2, 3, 4)) > 4.5
    candidates = {c["effect"]: c for c in report["candidates"]}
    assert not any(c["significant"] for c in candidates.values())
    assert not candidates["elasticity"]["testable"] and "carries the body" in candidates["elasticity"]["reason"]
    assert not candidates["time_lag"]["testable"] and not candidates["backlash"]["testable"]


# ------------------------------------------------------------------------------------------------- bad input

def _copy(tmp_path) -> Path:
    directory = tmp_path / "in"
    shutil.copytree(DATA, directory)
    return directory


def _edit_csv(directory: Path, edit) -> None:
    path = directory / "joints_raw.csv"
    rows = list(csv.reader(path.open()))
    edit(rows)
    with path.open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows(rows)


def _swap_columns(rows):
    for row in rows:
        row[12], row[13] = row[13], row[12]


def _bad_angle(rows):
    rows[3][4] = "0.1.2"


def _beyond_limits(rows):
    rows[2][21] = "3.0"  # RKneePitch


def _short_row(rows):
    rows[4] = rows[4][:10]


@pytest.mark.parametrize("edit, where", [
    (_swap_columns, "joints_raw.csv, line 1, field 'LHipYawPitch_raw_rad'"),
    (_bad_angle, "joints_raw.csv, line 4, field 'LShoulderPitch_raw_rad'"),
    (_beyond_limits, "joints_raw.csv, line 3, field 'RKneePitch_raw_rad'"),
    (_short_row, "joints_raw.csv, line 5"),
])
def test_a_damaged_joints_file_is_one_line_naming_line_and_field_and_nothing_is_written(tmp_path, capsys, edit,
                                                                                          where):
    directory = _copy(tmp_path)
    _edit_csv(directory, edit)
    out = tmp_path / "out"
    capsys.readouterr()
    assert main(["import", "mrlspl", str(directory), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and where in err and "Traceback" not in err
    assert not out.exists()


def test_a_missing_or_wrong_image_is_named(tmp_path, capsys):
    directory = _copy(tmp_path)
    (directory / "image_3.png").unlink()
    assert main(["import", "mrlspl", str(directory), "--out", str(tmp_path / "out")]) == 2
    assert "image_3.png: no such file" in capsys.readouterr().err
    cv2.imwrite(str(directory / "image_3.png"), np.full((240, 320, 3), 90, np.uint8))  # no board in it
    assert main(["import", "mrlspl", str(directory), "--out", str(tmp_path / "out")]) == 2
    assert "image_3.png: no single 4 x 4 board found" in capsys.readouterr().err
    cv2.imwrite(str(directory / "image_3.png"), np.full((240, 320), 90, np.uint8))
    assert main(["import", "mrlspl", str(directory), "--out", str(tmp_path / "out")]) == 2
    assert "image_3.png: a grey image" in capsys.readouterr().err
    cv2.imwrite(str(directory / "image_3.png"), np.full((480, 640, 3), 90, np.uint8))
    assert main(["import", "mrlspl", str(directory), "--out", str(tmp_path / "out")]) == 2
    assert "image_3.png: 640 x 480 pixels: expected 320 x 240" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_with_headpitch_as_stored_the_prediction_cannot_order_the_corners(monkeypatch):
    """The file's HeadPitch has the opposite sign to today's: read as stored, the nominal prediction of image 1
    (its head 25 deg up, read as 25 deg down) is so far off that no labelling of the corners fits it, and the
    import stops, naming the image, rather than guess an order."""
    import naocal.tools.import_mrlspl as importer
    from naocal.solver.errors import DataError

    monkeypatch.setattr(importer, "SIGN", {})
    with pytest.raises(DataError, match="image_1.png: the corners' order cannot be told"):
        importer.build_dataset(DATA)


def test_an_existing_dataset_is_not_overwritten(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "dataset.json").write_text("precious")
    assert main(["import", "mrlspl", str(DATA), "--out", str(out)]) == 2
    assert "not an empty directory" in capsys.readouterr().err
    assert (out / "dataset.json").read_text() == "precious"


def test_a_board_turned_by_a_quarter_turn_is_refused_by_its_colours(dataset):
    """The 180 deg turn is told by the prediction; a board lying turned by 90 deg against the description would
    still be ordered by the prediction, and only the colours can tell: the square before vertex 0 is blue then."""
    from naocal.solver.robot import load_robot
    from naocal.tools.import_mrlspl import board_spec, colour_check

    board = board_spec(load_robot("nao"))
    image = cv2.imread(str(DATA / "image_0.png"))
    rows = dataset.columns["image"] == 0
    uv = np.column_stack([dataset.columns["u_px"][rows], dataset.columns["v_px"][rows]]).reshape(3, 3, 2)
    for channel in ("cr", "cb"):
        assert colour_check(image, channel, uv.reshape(-1, 2), board) is None
        assert colour_check(image, channel, uv[::-1, ::-1].reshape(-1, 2), board) is None  # 180 deg: same colours
        turned = np.swapaxes(uv, 0, 1)[::-1].reshape(-1, 2)  # 90 deg
        assert "not orange" in colour_check(image, channel, turned, board)


def test_seeded_damage_to_the_joints_file_is_refused_as_bad_input_or_read(tmp_path):
    """300 seeded damages (bytes changed, deleted, doubled; lines cut, repeated, swapped; huge numbers, NaN,
    bad UTF-8): every one reads or is a DataError naming joints_raw.csv - never another exception."""
    from naocal.solver.errors import DataError
    from naocal.solver.robot import load_robot
    from naocal.tools.import_mrlspl import check_limits, read_joints

    original = (DATA / "joints_raw.csv").read_bytes()
    robot = load_robot("nao")
    rng = np.random.default_rng(13)
    path = tmp_path / "joints_raw.csv"
    outcomes = {"read": 0, "refused": 0}
    for _ in range(300):
        data = bytearray(original)
        for _ in range(rng.integers(1, 4)):
            kind = rng.integers(0, 6)
            at = int(rng.integers(0, len(data)))
            if kind == 0:
                data[at] = int(rng.integers(0, 256))
            elif kind == 1:
                del data[at:at + int(rng.integers(1, 40))]
            elif kind == 2:
                data[at:at] = data[at:at + int(rng.integers(1, 40))]
            elif kind == 3:
                data[at:at] = rng.choice([b"nan", b"1e308", b"-inf", b"99999999999999999999999", b"\xff\xfe", b","])
            elif kind == 4:
                data = data[:at]
            else:
                lines = bytes(data).split(b"\n")
                i, j = rng.integers(0, len(lines), 2)
                lines[i], lines[j] = lines[j], lines[i]
                data = bytearray(b"\n".join(lines))
        path.write_bytes(bytes(data))
        try:
            check_limits(read_joints(path), robot, path)
            outcomes["read"] += 1
        except DataError as err:
            assert str(err).startswith(str(path)) and "\n" not in str(err)
            outcomes["refused"] += 1
    assert outcomes["refused"] > 200 and outcomes["read"] > 0, outcomes


def test_a_write_that_fails_half_way_leaves_no_half_dataset(tmp_path, monkeypatch, capsys):
    """The disk fills while dataset.json is written: the images already copied are taken back, the output
    directory is left as it was (empty), and the error is one line (exit 3)."""
    import naocal.solver.dataset  # noqa
    from naocal import solver
    from naocal.solver.errors import DiskFullError

    def full(*args, **kwargs):
        raise DiskFullError(tmp_path / "out" / "dataset.json", 0)

    monkeypatch.setattr(solver.dataset, "write_dataset", full)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["import", "mrlspl", str(DATA), "--out", str(out)]) == 3
    assert "no space left" in capsys.readouterr().err
    assert sorted(p.name for p in out.rglob("*")) == []
