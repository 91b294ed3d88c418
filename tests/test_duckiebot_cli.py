"""The Duckiebot through the command line (issues 22, 23): `naocal identify LOG --out CAL.json`, `naocal offsets
show|validate|diff|export CAL`, `naocal verify LOG [--offsets CAL|DIR]`, bad logs refused in one line (exit 2, nothing
written). Independent data: a small log made by kinds/duckiebot/render.py (OpenCV, not PyBullet)."""

import json
import re
import shutil
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from naocal.kinds.duckiebot.calibration import read_calibration_file, write_calibration_file
from naocal.kinds.duckiebot.calibration_files import read_calibration
from naocal.kinds.duckiebot.intrinsics import LensCamera
from naocal.kinds.duckiebot.render import joint_program, render_drive_log
from naocal.solver.errors import SolveError
from tests.cli_runner import naocal

LOG_K = 27.0  # the rendered log's k: the fit's gain and trim are in it


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A small rendered log (28 frames: boards while turning, the marker line with turns; ~7 s CPU to render) and
    its calibration by `naocal identify LOG --out CAL.json` (~13 s CPU)."""
    root = tmp_path_factory.mktemp("duckiebot")
    rendered = render_drive_log(root / "LOG", seed=1, steps=joint_program(board_steps=2, marker_drives=4, returns=1))
    result = naocal("identify", root / "LOG", "--out", root / "CAL.json")
    assert result.returncode == 0, result.stderr
    return SimpleNamespace(root=root, log=root / "LOG", cal=root / "CAL.json", rendered=rendered, identify=result)


def one_line_error(result, *names):
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    line = result.stderr.strip()
    assert "\n" not in line and "Traceback" not in line, line
    for name in names:
        assert str(name) in line, (name, line)
    return line


def test_identify_calibrates_a_rendered_log(calibrated):
    """The hidden robot's trim within 0.002 and gain within 1 % (in the log's k), the summary printed."""
    robot = calibrated.rendered.robot.kinematics
    cal = read_calibration_file(calibrated.cal)
    assert abs(cal.kinematics.trim - robot.trim * LOG_K / robot.k) < 0.002
    assert abs(cal.kinematics.gain / (robot.gain * LOG_K / robot.k) - 1.0) < 0.01
    assert cal.std("trim") > 0 and cal.fit["converged"] and cal.lens_model in cal.lenses
    for text in ("kinematics: gain", "trim", "camera on the body", "lens:", "held-out RMS", "fit: RMS"):
        assert text in calibrated.identify.stdout, text


def test_identify_says_which_part_of_each_std_is_statistical_and_which_a_considered_model_error(calibrated):
    """The file keeps each std's parts (the fit's cluster-robust one, the lens's, the detector's corner error over
    its window: kinds.duckiebot.identify's considered nuisances), their root sum of squares the std; the printout
    shows them in one line."""
    cal = read_calibration_file(calibrated.cal)
    for name in ("gain", "trim", "camera.z_m"):
        parts = cal.parameters[name]["std_parts"]
        assert set(parts) == {"fit", "lens", "corner_window"} and parts["corner_window"] > 0, parts
        assert np.isclose(np.sqrt(sum(v ** 2 for v in parts.values())), cal.std(name), rtol=1e-6)
    line = next(line for line in calibrated.identify.stdout.splitlines() if line.startswith("std parts:"))
    assert "statistical / lens / detector's corner error" in line and "trim" in line and "camera z mm" in line


def test_the_calibration_exports_duckietowns_three_files(calibrated, tmp_path):
    out = tmp_path / "calibrations"
    result = naocal("offsets", "export", calibrated.cal, "--format", "duckietown", "--out", out)
    assert result.returncode == 0, result.stderr
    cal = read_calibration_file(calibrated.cal)
    files, findings = read_calibration(out, "rendered")
    assert not [f for f in findings if f.level == "refuse"]
    assert files.kinematics.trim == pytest.approx(cal.kinematics.trim, abs=1e-12)
    assert np.allclose(files.camera.K, cal.lenses["plumb_bob"].K)
    assert "replaced" not in result.stderr
    again = naocal("offsets", "export", calibrated.cal, "--format", "duckietown", "--out", out)
    assert again.returncode == 0 and again.stderr.count("replaced the previous") == 3, again.stderr  # never silently
    for action in ("show", "validate"):
        assert naocal("offsets", action, calibrated.cal).returncode == 0
    diff = naocal("offsets", "diff", calibrated.cal, calibrated.cal, "--fail-on-difference")
    assert diff.returncode == 0 and "trim" in diff.stdout
    exported = naocal("offsets", "export", calibrated.cal, "--format", "json")
    assert json.loads(exported.stdout)["schema"] == "naocal.duckiebot_calibration/1"


def test_verify_says_whether_the_robot_still_drives_straight(calibrated, tmp_path):
    """On its own log the calibration is still good (0 +- a few mm over 2 m); a calibration whose trim is 0.05 off
    would send it about 0.3 m aside: drifted, exit 1."""
    good = naocal("verify", calibrated.log, "--offsets", calibrated.cal)
    assert good.returncode == 0 and "verdict: still good" in good.stdout, good.stdout + good.stderr
    doc = json.loads(calibrated.cal.read_text())
    for section in (doc["kinematics"], doc["parameters"]["trim"]):
        key = "trim" if "trim" in section else "value"
        section[key] += 0.05
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps(doc))
    drifted = naocal("verify", calibrated.log, "--offsets", wrong, "--json")
    report = json.loads(drifted.stdout)
    assert drifted.returncode == 1 and report["verdict"] == "drifted"
    assert abs(report["lateral_deviation_m"]) > 0.1 and report["lateral_deviation_std_m"] < 0.05
    # the trim's std carries the detector's corner error as identify's does (the whole log shares it)
    parts = report["now"]["trim"]["std_parts"]
    assert set(parts) == {"fit", "corner_window"} and parts["corner_window"] > 0, parts
    assert np.isclose(np.hypot(parts["fit"], parts["corner_window"]), report["now"]["trim"]["std"], rtol=1e-6)


def _verify_json(*argv):
    result = naocal("verify", *argv, "--json")
    assert result.returncode in (0, 1), result.stdout + result.stderr
    return json.loads(result.stdout)


def test_verify_gives_no_verdict_from_a_handful_of_marker_frames(calibrated, tmp_path):
    log = tmp_path / "LOG"
    shutil.copytree(calibrated.log, log)
    rows = (log / "frames.csv").read_text().splitlines()
    (log / "frames.csv").write_text("\n".join(rows[:1] + rows[-3:]) + "\n")  # the last 3 frames: markers in view
    result = naocal("verify", log, "--offsets", calibrated.cal)
    assert result.returncode == 3, (result.stdout, result.stderr)
    assert "3 frames with a marker in view, at least 8" in result.stderr and "verdict" not in result.stdout


def test_verify_reads_duckietowns_calibration_files_as_it_reads_the_calibration(calibrated, tmp_path, monkeypatch):
    """`verify LOG --offsets DIR` on the files `offsets export --format duckietown` wrote judges as `--offsets
    CAL.json` does (the camera's pose recovered from the homography), and so does a bare `verify LOG` with them in
    the default directory; a broken directory is one line naming the file and field, exit 2."""
    out = tmp_path / "calibrations"
    assert naocal("offsets", "export", calibrated.cal, "--format", "duckietown", "--out", out).returncode == 0
    reference = _verify_json(calibrated.log, "--offsets", calibrated.cal)
    from_files = _verify_json(calibrated.log, "--offsets", out)
    monkeypatch.setenv("NAOCAL_DUCKIETOWN_CALIBRATIONS", str(out))
    bare = _verify_json(calibrated.log)
    for report in (from_files, bare):
        assert report["calibration_source"] == "duckietown" and str(out) in report["calibration"]
        assert report["verdict"] == reference["verdict"]
        for key in ("lateral_deviation_m", "lateral_deviation_std_m", "predicted_speed_mps"):
            assert report[key] == pytest.approx(reference[key], abs=1e-7), key
        for name in ("gain", "trim"):
            assert report["now"][name]["value"] == pytest.approx(reference["now"][name]["value"], abs=1e-8)
    assert reference["calibration_source"] == "naocal" and from_files["calibration_rms_px"] is None
    # the robot's name, checked before it becomes a file name; a missing file; a bad value
    one_line_error(naocal("verify", calibrated.log, "--offsets", out, "--robot-name", "../etc"), "--robot-name")
    one_line_error(naocal("verify", calibrated.log, "--offsets", out, "--robot-name", "other"),
                   out / "kinematics" / "other.yaml", "not found")
    kinematics = out / "kinematics" / "rendered.yaml"
    good = kinematics.read_text()
    kinematics.write_text(good.replace("trim: ", "trim: x"))
    one_line_error(naocal("verify", calibrated.log, "--offsets", out), kinematics, "trim")
    kinematics.write_text(good)
    (out / "camera_extrinsic" / "rendered.yaml").unlink()
    one_line_error(naocal("verify", calibrated.log, "--offsets", out), out / "camera_extrinsic" / "rendered.yaml")


def _shown(text: str, label: str) -> float:
    """The number after `label ` in `offsets show`'s output."""
    return float(re.search(rf"(?:^|[ (]){re.escape(label)} ([-+0-9.e]+)", text, re.M).group(1))


def test_offsets_show_reads_duckietowns_calibrations_directory(calibrated, tmp_path):
    """`offsets show DIR` on the files `offsets export --format duckietown` wrote says what CAL.json says: the
    kinematics, the lens, and the camera's pose on the body recovered from the homography (to the printed digits);
    validate says ok; with several robots' files, --robot-name picks one and without it one line names them."""
    out = tmp_path / "calibrations"
    assert naocal("offsets", "export", calibrated.cal, "--format", "duckietown", "--out", out).returncode == 0
    cal = read_calibration_file(calibrated.cal)
    shown = naocal("offsets", "show", out)
    assert shown.returncode == 0, shown.stderr
    text = shown.stdout
    assert "robot rendered" in text and "recovered from the homography" in text
    kin = cal.kinematics
    for label, value, unit in (("gain", kin.gain, 1e-4), ("trim", kin.trim, 1e-5), ("baseline", kin.baseline_m * 1e3,
                               0.01), ("radius", kin.radius_m * 1e3, 1e-3), ("k", kin.k, 1e-3),
                               ("limit", kin.limit, 1e-3)):
        assert _shown(text, label) == pytest.approx(value, abs=unit), label
    for axis in "xyz":
        assert _shown(text, axis) == pytest.approx(cal.value(f"camera.{axis}_m") * 1e3, abs=0.051), axis
    for angle in ("roll", "pitch", "yaw"):
        assert _shown(text, angle) == pytest.approx(np.degrees(cal.value(f"camera.{angle}_rad")), abs=0.0051), angle
    K = cal.lenses["plumb_bob"].K
    for label, value in (("fx", K[0, 0]), ("fy", K[1, 1]), ("cx", K[0, 2]), ("cy", K[1, 2])):
        assert _shown(text, label) == pytest.approx(value, abs=0.0051), label
    assert naocal("offsets", "validate", out).stdout == "ok\n"
    # several robots: one line naming them; --robot-name picks one; a file is not a directory
    shutil.copy(out / "kinematics" / "rendered.yaml", out / "kinematics" / "autobot07.yaml")
    one_line_error(naocal("offsets", "show", out), "rendered", "autobot07", "--robot-name")
    assert _shown(naocal("offsets", "show", out, "--robot-name", "rendered").stdout, "trim") == \
        pytest.approx(kin.trim, abs=1e-5)
    one_line_error(naocal("offsets", "show", out, "--robot-name", "autobot07"),
                   out / "camera_intrinsic" / "autobot07.yaml")
    one_line_error(naocal("offsets", "show", calibrated.cal, "--robot-name", "rendered"), "is a file")
    (tmp_path / "empty" / "kinematics").mkdir(parents=True)
    one_line_error(naocal("offsets", "show", tmp_path / "empty"), "no robot's calibration files")


BAD_FILES = {  # a broken file of a calibrations DIR: (its folder, the edit, what the one line names)
    "missing key": ("kinematics", lambda t: t.replace("gain:", "gains:"), "gain"),
    "yaml error": ("camera_intrinsic", lambda t: t.replace("rows: 3", "rows: [3", 1), "line"),
    "nan": ("kinematics", lambda t: t.replace("trim: ", "trim: .nan #"), "trim"),
    "nan in the homography": ("camera_extrinsic", lambda t: t.replace("homography: [", "homography: [.nan, "
                              ).replace(", 1.0]", "]"), "homography"),
    "impossible homography": ("camera_extrinsic", lambda t: "homography: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, "
                                                            "1.0]\n", "homography"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_offsets_show_names_a_broken_calibrations_file(tmp_path, case):
    from tests.test_duckiebot_calibration_files import calibration
    from naocal.kinds.duckiebot.calibration_files import write_calibration

    write_calibration(tmp_path, calibration("autobot01"))
    assert naocal("offsets", "show", tmp_path).returncode == 0
    folder, edit, field = BAD_FILES[case]
    path = tmp_path / folder / "autobot01.yaml"
    path.write_text(edit(path.read_text()))
    one_line_error(naocal("offsets", "show", tmp_path), path, field)
    one_line_error(naocal("offsets", "validate", tmp_path), path, field)


def test_bare_verify_judges_the_logs_own_camera_under_duckietowns_defaults(calibrated, tmp_path, monkeypatch):
    """Without --offsets and without the robot's files (an empty default directory), a log with board views is
    judged by its own camera under Duckietown's default kinematics (gain 1, trim 0): the rendered robot (trim 0.052
    in its k) then curves about 1.3 m off over 2 m, drifted, exit 1; the deviation is the 2 m drive of the robot
    identify found, commanded with the defaults."""
    from naocal.kinds.duckiebot.robot import Kinematics
    from naocal.kinds.duckiebot.verbs import straight_drive

    monkeypatch.setenv("NAOCAL_DUCKIETOWN_CALIBRATIONS", str(tmp_path))
    result = naocal("verify", calibrated.log)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Duckietown's default kinematics" in result.stdout and "verdict: drifted" in result.stdout
    assert f"naocal identify {calibrated.log}" in result.stdout
    cal = read_calibration_file(calibrated.cal)
    robot = Kinematics(baseline_m=cal.value("baseline_m"), gain=cal.value("gain"), trim=cal.value("trim"), k=LOG_K)
    lateral, _ = straight_drive(Kinematics(), robot)
    assert abs(lateral) > 0.5
    shown = float(result.stdout.split("lateral deviation ")[1].split(" +-")[0]) / 100
    assert shown == pytest.approx(lateral, abs=0.002)


def test_bare_verify_with_no_calibration_and_no_boards_is_one_line(tmp_path, monkeypatch):
    """A lane pass (no board in view) and no files of its robot: one line naming what is needed, exit 2; another
    kind's data without --offsets: one line, exit 2."""
    from naocal.kinds.duckiebot.render import DriveStep

    steps = [DriveStep(0.0, -0.3, 0.3, grab=False, face_rad=np.pi)] + [DriveStep(0.25, 0.2, 0.2, settle_s=0.0)] * 3
    render_drive_log(tmp_path / "LANE", seed=1, steps=steps)
    monkeypatch.setenv("NAOCAL_DUCKIETOWN_CALIBRATIONS", str(tmp_path / "none"))
    one_line_error(naocal("verify", tmp_path / "LANE"), "--offsets CAL.json", "--offsets DIR",
                   tmp_path / "none" / "kinematics" / "rendered.yaml", "board views")
    (tmp_path / "nao").mkdir()
    one_line_error(naocal("verify", tmp_path / "nao"), "--offsets FILE is required")


def test_bare_verify_of_a_log_without_boards_searches_a_sample_only(tmp_path, monkeypatch):
    """A log with no board in view and no calibration: the board search runs on board_sample_frames only (about one
    searched frame in MIN_BOARD_VIEWS), not on every frame board_search_frames picks, before the one-line refusal;
    the sample is a subset of those frames and any MIN_BOARD_VIEWS consecutive ones hold a sampled frame."""
    import naocal.kinds.duckiebot.identify as identify
    from naocal.kinds.duckiebot.drive_log import SCHEMA, write_drive_log, write_frame

    rng = np.random.default_rng(3)
    for frame_t_s in (np.arange(45) / 15.0, np.cumsum(rng.uniform(0.01, 0.6, 400))):  # a camera; any timing
        searched, sampled = identify.board_search_frames(frame_t_s), identify.board_sample_frames(frame_t_s)
        assert sampled.any() and not (sampled & ~searched).any()
        runs = np.convolve(sampled[searched].astype(int), np.ones(identify.MIN_BOARD_VIEWS, int), "valid")
        assert runs.min() >= 1
    log = tmp_path / "LANE"
    times = np.arange(45) / 15.0  # 3 s at 15 fps, nothing but noise in view
    names = [f"frames/{i:03d}.png" for i in range(len(times))]
    for name in names:
        write_frame(log, name, rng.integers(0, 255, (120, 160), dtype=np.uint8))
    meta = {"schema": SCHEMA, "robot": {"id": "lane01", "model": "DB21"}, "camera": {"width_px": 160, "height_px": 120},
            "wheels": {"radius_m": 0.0318, "baseline_m": 0.1, "k": 27.0, "limit": 1.0},
            "markers": {"family": "tag36h11", "size_m": 0.065}, "boards": {"inner_corners": [7, 5], "square_m": 0.031},
            "source": "test"}
    write_drive_log(log, meta, ([0.0, 3.0], [0.2, 0.0], [0.2, 0.0]), (times, names))
    searches = []
    detect_boards = identify.detect_boards
    monkeypatch.setattr(identify, "detect_boards", lambda *a, **k: searches.append(1) or detect_boards(*a, **k))
    monkeypatch.setenv("NAOCAL_DUCKIETOWN_CALIBRATIONS", str(tmp_path / "none"))
    one_line_error(naocal("verify", log), "board views", "none in 2 frames sampled")
    assert len(searches) == identify.board_sample_frames(times).sum() == 2 < identify.board_search_frames(times).sum()


def test_verify_takes_the_robots_kinematics_file_when_it_has_no_camera_files(tmp_path):
    """With only kinematics/<robot>.yaml in the default directory, the log's own camera is judged under that file
    (what the robot runs), not under Duckietown's defaults."""
    from naocal.kinds.duckiebot.calibration_files import kinematics_yaml
    from naocal.kinds.duckiebot.robot import Kinematics
    from naocal.kinds.duckiebot.verbs import robot_kinematics

    log = SimpleNamespace(model="DB21")
    assert robot_kinematics(log, "rendered", None)[0] == Kinematics()
    path = tmp_path / "rendered.yaml"
    path.write_text(kinematics_yaml(Kinematics(gain=1.25, trim=0.05), "2026-11-28-05-00-00"))
    kinematics, label = robot_kinematics(log, "rendered", path)
    assert (kinematics.gain, kinematics.trim) == (1.25, 0.05) and str(path) in label


def _blank(path):
    cv2.imwrite(str(path), np.full((480, 640), 128, np.uint8))


def _edit_csv(path, row, column, value):
    lines = path.read_text().splitlines()
    cells = lines[row].split(",")
    cells[column] = value
    lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def _swap_rows(path):
    lines = path.read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    path.write_text("\n".join(lines) + "\n")


BAD_LOGS = {  # what is broken -> (how, the file the one line names)
    "missing wheels.csv": (lambda log, _: (log / "wheels.csv").unlink(), "wheels.csv"),
    "missing log.json": (lambda log, _: (log / "log.json").unlink(), "log.json"),
    "another schema": (lambda log, _: (log / "log.json").write_text(
        (log / "log.json").read_text().replace("naocal.drive_log/1", "naocal.drive_log/9")), "schema"),
    "times not increasing": (lambda log, _: _swap_rows(log / "wheels.csv"), "wheels.csv"),
    "NaN duty": (lambda log, _: _edit_csv(log / "wheels.csv", 3, 1, "nan"), "wheels.csv"),
    "a frame not an image": (lambda log, _: (log / "frames" / "000002.png").write_text("not a png"), "000002.png"),
    "no marker ever seen": (lambda log, _: [_blank(p) for p in (log / "frames").iterdir()], "frames.csv"),
    "too few board views": (lambda log, rendered: [_blank(log / "frames" / f"{i:06d}.png")
                                                   for i, boards in enumerate(rendered.board_px) if boards], "LOG"),
}


@pytest.mark.parametrize("problem", sorted(BAD_LOGS))
def test_a_bad_log_is_refused_in_one_line_and_nothing_written(calibrated, tmp_path, problem):
    log = tmp_path / "LOG"
    shutil.copytree(calibrated.log, log)
    damage, named = BAD_LOGS[problem]
    damage(log, calibrated.rendered)
    out = tmp_path / "CAL.json"
    one_line_error(naocal("identify", log, "--out", out), named)
    assert not out.exists()


def test_identify_never_writes_over_its_input(calibrated, tmp_path):
    log = tmp_path / "LOG"
    shutil.copytree(calibrated.log, log)
    before = (log / "wheels.csv").read_bytes()
    one_line_error(naocal("identify", log, "--out", log / "wheels.csv"), "wheels.csv")
    assert (log / "wheels.csv").read_bytes() == before
    files = sorted(log.rglob("*"))
    for out in (log / "CAL.json", log / "frames" / "CAL.json"):  # nothing written into the log, not even beside it
        one_line_error(naocal("identify", log, "--out", out), out, "inside the drive log")
        one_line_error(naocal("identify", log, "--refine", calibrated.cal, "--out", out), "inside the drive log")
    assert sorted(log.rglob("*")) == files


@pytest.mark.parametrize("where, value, field", [
    (("camera", "lenses", "plumb_bob", "K", 0, 0), 11454.0, "camera.lenses.plumb_bob.K"),  # a real broken file's fx
    (("camera", "lenses", "plumb_bob", "distortion", 0), -5.4, "camera.lenses.plumb_bob.distortion"),
    (("parameters", "trim", "std"), float("nan"), "parameters.trim.std"),
    (("kinematics", "gain"), 2.0, "kinematics.gain"),  # disagrees with parameters.gain
    (("robot", "id"), "no/such robot", "robot.id"),
    (("fit", "extra"), 1, "fit.extra"),
    (("fit", "pwm_driver"), "yes", "fit.pwm_driver"),
    (("parameters", "trim", "std_parts", "corner_window"), 1.0, "parameters.trim.std_parts"),  # not the std's
    (("parameters", "trim", "std_parts", "seen"), 0.0, "parameters.trim.std_parts.seen"),
])
def test_a_bad_calibration_file_is_refused_naming_its_field(calibrated, tmp_path, where, value, field):
    doc = json.loads(calibrated.cal.read_text())
    node = doc
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    one_line_error(naocal("offsets", "validate", bad), bad, field)
    out = tmp_path / "dt"
    one_line_error(naocal("offsets", "export", bad, "--format", "duckietown", "--out", out), bad, field)
    assert not out.exists()


def test_a_calibration_from_a_log_in_segments_reads_with_each_segments_anchor(calibrated, tmp_path):
    """A log in segments (segments.csv) is fitted with one anchor per segment, `anchor<s>.*` after a break: the
    calibration file holds them and reads; a misspelt one is still refused."""
    doc = json.loads(calibrated.cal.read_text())
    for axis in ("x_m", "y_m", "theta_rad"):
        doc["parameters"][f"anchor1.{axis}"] = {"value": 0.1, "std": 0.01, "fixed": False}
    good = tmp_path / "segments.json"
    good.write_text(json.dumps(doc))
    assert naocal("offsets", "validate", good).returncode == 0
    doc["parameters"]["anchor0x.x_m"] = doc["parameters"].pop("anchor1.x_m")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    one_line_error(naocal("offsets", "validate", bad), bad, "parameters.anchor0x.x_m")


def test_an_implausible_calibration_is_never_written(calibrated, tmp_path):
    """The writer checks the document with the reader first: a trim beyond any working Duckiebot (0.6) is refused
    (exit 3, the fit's fault) and the file already there is kept."""
    cal = read_calibration_file(calibrated.cal)
    names = list(cal.parameters)
    x = np.array([cal.value(n) for n in names])
    x[names.index("trim")] = 0.6
    kinematics = SimpleNamespace(**{**cal.kinematics.__dict__, "trim": 0.6})
    lens_fits = {m: SimpleNamespace(camera=LensCamera(m, c.K, c.distortion), n_views=e["views"], train_rms_px=0.1,
                                    held_out_rms_px=e["held_out_rms_px"])
                 for (m, c), e in zip(cal.lenses.items(), cal.lens_errors.values())}
    fit = SimpleNamespace(names=names, x=x, std=np.full(len(x), 1e-3), free=np.ones(len(x), bool), rms_px=0.3,
                          sightings=SimpleNamespace(frame=np.zeros(8)), outliers=SimpleNamespace(frame=np.zeros(0)),
                          reference_marker=0, success=True, warnings=[], pwm_driver=False, considered={})
    fake = SimpleNamespace(robot_id="rendered", kinematics=kinematics, lens=lens_fits[cal.lens_model],
                           lens_fits=lens_fits, drive_fit=fit)
    target = tmp_path / "CAL.json"
    target.write_text("kept")
    with pytest.raises(SolveError, match=r"trim.*beyond any working Duckiebot") as caught:
        write_calibration_file(target, fake)
    assert caught.value.exit_code == 3 and "\n" not in str(caught.value)
    assert target.read_text() == "kept"
    fit.x[names.index("trim")] = kinematics.trim = cal.kinematics.trim  # plausible again: written
    assert write_calibration_file(target, fake) == []
    assert read_calibration_file(target).kinematics.trim == cal.kinematics.trim


def test_other_kinds_options_and_formats_are_refused(calibrated, tmp_path, monkeypatch):
    import naocal.kinds.duckiebot as duckiebot

    one_line_error(naocal("verify", calibrated.log, "--offsets", calibrated.cal, "--angles", "measured"), "--angles")
    one_line_error(naocal("offsets", "export", calibrated.cal, "--format", "bhuman"), "duckietown")
    one_line_error(naocal("offsets", "apply", calibrated.cal, "--command", "x=1"), "inverse kinematics")
    nao = tmp_path / "offsets.json"
    nao.write_text(json.dumps({"schema": "naocal.offsets/2"}))
    one_line_error(naocal("offsets", "export", nao, "--format", "duckietown"), "a NAO's offsets file exports to")
    one_line_error(naocal("calibrate", "--robot", "duckiebot", "--backend", "mock", "--out", tmp_path / "run",
                          "--plan", "optimal"), "--plan")
    monkeypatch.setitem(duckiebot.VERB_MODULES, "calibrate", ("no_such_module", "run"))
    one_line_error(naocal("calibrate", "--robot", "duckiebot", "--backend", "mock", "--out", tmp_path / "run"),
                   "not in this version")
    assert not (tmp_path / "run").exists()


def test_identify_adds_the_wheel_effects_diagnose_names(calibrated, tmp_path):
    """`naocal identify LOG --effects dead_zone --out CAL.json` (what diagnose's loop leads to) fits the effect and
    writes it; the strict reader takes it back; an unknown effect is one line, exit 2, nothing written."""
    out = tmp_path / "CAL.json"
    result = naocal("identify", calibrated.log, "--effects", "dead_zone", "--out", out)
    assert result.returncode == 0, result.stderr
    cal = read_calibration_file(out)
    assert "dead_zone" in cal.parameters and cal.std("dead_zone") > 0
    assert not cal.pwm_driver and not read_calibration_file(calibrated.cal).pwm_driver
    # Duckietown's wheel driver, named like an effect (a log does not say which driver sent its duties): recorded
    # in the file, and verify refits through it
    driven = tmp_path / "PWM.json"
    result = naocal("identify", calibrated.log, "--effects", "pwm_driver,dead_zone", "--out", driven)
    assert result.returncode == 0, result.stderr
    assert read_calibration_file(driven).pwm_driver and json.loads(driven.read_text())["fit"]["pwm_driver"] is True
    verified = naocal("verify", calibrated.log, "--offsets", driven, "--json")
    assert verified.returncode in (0, 1), verified.stderr
    bad = naocal("identify", calibrated.log, "--effects", "wobble", "--out", tmp_path / "BAD.json")
    one_line_error(bad, "wobble")
    assert not (tmp_path / "BAD.json").exists()


def test_a_drive_logs_file_named_for_its_folder_is_one_line_naming_the_folder(calibrated, tmp_path):
    for verb, name in (("identify", "log.json"), ("diagnose", "wheels.csv"), ("verify", "frames.csv")):
        extra = ("--out", tmp_path / "CAL.json") if verb == "identify" else ()
        result = naocal(verb, calibrated.log / name, *extra)
        assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
        assert result.stderr.count("\n") == 1 and f"name its folder, {calibrated.log}" in result.stderr, result.stderr
    assert not (tmp_path / "CAL.json").exists()
