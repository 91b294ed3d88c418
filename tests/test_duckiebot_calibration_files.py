"""Duckietown's three calibration files (kinds/duckiebot/calibration_files.py, issue 23): exact keys, round trip,
a strict reader, and broken calibrations refused before anything is written."""

import re

import numpy as np
import pytest

from naocal.kinds.duckiebot.calibration_files import (CameraCalibration, DuckietownCalibration, apply_homography,
                                               camera_pose_from_homography,
                                               check_calibration, ground_homography, parse_simple_yaml,
                                               read_calibration, read_extrinsic, read_intrinsic, read_kinematics,
                                               write_calibration, yaml_float)
from naocal.kinds.duckiebot.robot import Kinematics, camera_mount, duckiebot
from naocal.solver.errors import DataError, NaocalError

# The YAML 1.1 float pattern (yaml.org/type/float.html), which PyYAML (Duckietown's reader) resolves floats by:
# without a '.', '1e-05' is a string to it.
YAML11_FLOAT = re.compile(r"[-+]?([0-9][0-9_]*)?\.[0-9.]*([eE][-+][0-9]+)?")
# The key layout of docs/DUCKIEBOT.md ("Duckietown's files").
KINEMATICS_KEYS = {"baseline", "calibration_time", "gain", "k", "limit", "radius", "trim", "v_max", "omega_max"}
INTRINSIC_KEYS = ["image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                  "distortion_coefficients", "rectification_matrix", "projection_matrix"]
STAMP = "2026-11-27-10-00-00"


def calibration(robot="autobot01", **changes):
    K = np.array([[338.25, 0.0, 318.5], [0.0, 336.0, 231.75], [0.0, 0.0, 1.0]])
    P = np.array([[250.5, 0.0, 320.0, 0.0], [0.0, 251.25, 240.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    camera = CameraCalibration(640, 480, K, np.array([-0.29, 0.061, 0.0012, -1e-05, 0.0]), P=P)
    parts = dict(robot=robot, kinematics=Kinematics(gain=1.05, trim=-0.0315, k=27.0),
                 camera=camera, homography=ground_homography(camera_mount(pitch_down_rad=0.34), P),
                 calibration_time=STAMP)
    parts.update(changes)
    return DuckietownCalibration(**parts)


def test_yaml_floats_read_as_floats_by_yaml11():
    for value in (1e-05, -2.17e-4, 0.1, 27.0, 1e20, -0.0, 336.5, 1.0 / 3.0):
        text = yaml_float(value)
        assert YAML11_FLOAT.fullmatch(text), text
        assert float(text) == value
    with pytest.raises(ValueError):
        yaml_float(float("nan"))


def test_files_have_duckietowns_exact_key_layout(tmp_path):
    assert write_calibration(tmp_path, calibration()) == []
    kin_text = (tmp_path / "kinematics" / "autobot01.yaml").read_text()
    top = [line.split(":")[0] for line in kin_text.splitlines()]
    assert set(top) == KINEMATICS_KEYS and top == sorted(top)
    assert f"calibration_time: {STAMP}\n" in kin_text and "trim: -0.0315\n" in kin_text
    intr = (tmp_path / "camera_intrinsic" / "autobot01.yaml").read_text()
    assert [line.split(":")[0] for line in intr.splitlines() if not line.startswith(" ")] == INTRINSIC_KEYS
    assert "camera_name: /autobot01/camera_node\n" in intr and "distortion_model: plumb_bob\n" in intr
    assert "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [338.25, 0.0, 318.5, 0.0, 336.0, 231.75, 0.0, 0.0, 1.0]\n" \
        in intr
    assert "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.29, 0.061, 0.0012, -1.0e-05, 0.0]\n" in intr
    assert "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]\n" \
        in intr
    assert "projection_matrix:\n  rows: 3\n  cols: 4\n  data: [250.5, 0.0, 320.0, 0.0, 0.0, 251.25, 240.0" in intr
    extr = (tmp_path / "camera_extrinsic" / "autobot01.yaml").read_text().splitlines()
    assert extr[0].startswith("homography: [") and len(extr[0].split(",")) == 9
    assert extr[1] == f"# Calibrated on {STAMP} by naocal"


def test_round_trip_is_exact(tmp_path):
    cal = calibration()
    write_calibration(tmp_path, cal)
    back, findings = read_calibration(tmp_path, "autobot01")
    assert findings == [] and back.kinematics == cal.kinematics and back.calibration_time == STAMP
    for name in ("K", "distortion", "R"):
        np.testing.assert_array_equal(getattr(back.camera, name), getattr(cal.camera, name))
    np.testing.assert_array_equal(back.camera.P, cal.camera.P)
    np.testing.assert_array_equal(back.homography, cal.homography)


def test_homography_maps_rectified_pixels_to_the_ground_like_real_robots():
    """The nominal DB21 (camera 0.108 m up, 0.066 m ahead, 19 deg down) and the prior camera give a homography
    within 3 cm of the real robots' median one (docs/DUCKIEBOT.md) where the floor is seen; x ahead, y left."""
    robot = duckiebot()
    c = robot.camera
    H = ground_homography(robot.T_base_camera, [[c.fx_px, 0, c.cx_px], [0, c.fy_px, c.cy_px], [0, 0, 1]])
    assert H[2, 2] == 1.0 and H[1, 2] < 0
    median = np.array([[-6e-6, -2.17e-4, -0.2267], [9.93e-4, -2e-6, -0.3224], [4e-6, -7.6e-3, 1]])
    uv = np.array([[320, 479], [100, 400], [540, 300], [320, 250], [10, 470]])
    np.testing.assert_allclose(apply_homography(H, uv), apply_homography(median, uv), atol=0.03)
    # the principal point's ray meets the floor at height / tan(pitch) ahead of the camera
    assert apply_homography(H, [c.cx_px, c.cy_px]) == pytest.approx((0.066 + 0.108 / np.tan(np.radians(19)), 0.0))


def test_the_camera_pose_comes_back_from_its_homography():
    """camera_pose_from_homography inverts ground_homography: the pose to rounding, whatever H's scale and sign,
    for a rectified camera other than K; a homography no camera gives is refused."""
    P = np.array([[250.5, 0.0, 320.0, 0.0], [0.0, 251.25, 240.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    for T in (camera_mount(), camera_mount(ahead_m=0.05, height_m=0.12, pitch_down_rad=0.34, lateral_m=0.012,
                                           roll_rad=0.02, yaw_rad=-0.03)):
        H = ground_homography(T, P)
        for scale in (1.0, -3.0, 1e-3):
            np.testing.assert_allclose(camera_pose_from_homography(scale * H, P), T, atol=1e-12)
        np.testing.assert_allclose(ground_homography(camera_pose_from_homography(H, P), P), H, atol=1e-12)
    with pytest.raises(ValueError, match="no camera gives it"):
        camera_pose_from_homography(np.diag([1.0, 2.0, 1.0]) @ H, P)


@pytest.mark.parametrize("change, match", [
    (lambda c: dict(camera=CameraCalibration(640, 480, np.diag([11454.0, 11454.0, 1.0]) + [[0, 0, 320], [0, 0, 240],
                                                                                            [0, 0, 0]],
                                             c.camera.distortion, P=c.camera.P)), r"camera_matrix.fx: 11454"),
    (lambda c: dict(camera=CameraCalibration(640, 480, c.camera.K, np.array([-5.4, 0.06, 0, 0, 0]), P=c.camera.P)),
     r"distortion_coefficients.k1: -5.4"),
    (lambda c: dict(homography=c.homography * [[1, 1, 1], [1, 1, -1], [1, 1, 1]]), r"homography\[5\]: H\[1\]\[2\]"),
    (lambda c: dict(kinematics=Kinematics(gain=0.5, trim=0.6)), r"kinematics.trim"),
    (lambda c: dict(robot="../etc/passwd"), r"robot name '../etc/passwd'"),
    (lambda c: dict(robot="bad name"), r"robot name"),
    (lambda c: dict(calibration_time="yesterday"), r"calibration time"),
])
def test_broken_calibrations_are_refused_and_nothing_written(tmp_path, change, match):
    cal = calibration()
    with pytest.raises(NaocalError, match=match) as err:
        write_calibration(tmp_path / "out", calibration(**change(cal)))
    assert "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()


def test_unusual_values_are_written_with_warnings(tmp_path):
    warnings = write_calibration(tmp_path, calibration(kinematics=Kinematics(gain=1.0, trim=0.3)))
    assert [w.field for w in warnings] == ["kinematics.trim"] and "unusual" in warnings[0].message
    _, findings = read_calibration(tmp_path, "autobot01")
    assert [f.field for f in findings] == ["kinematics.trim"]
    assert check_calibration(calibration(kinematics=Kinematics(gain=-1.0)))[0].level == "warn"


def test_a_directory_in_the_way_is_refused_before_anything_is_written(tmp_path):
    (tmp_path / "camera_extrinsic" / "autobot01.yaml").mkdir(parents=True)
    with pytest.raises(DataError, match="is a directory"):
        write_calibration(tmp_path, calibration())
    assert not (tmp_path / "kinematics").exists()


def test_the_reader_takes_pyyaml_style_files(tmp_path):
    """Files as PyYAML or ROS write them: block lists, a flow list wrapped over lines, other key orders, comments,
    no v_max/omega_max (older saves), a quoted camera name. Values are the real robots' medians."""
    (tmp_path / "k.yaml").write_text("---\n# old save\nbaseline: 0.1\ncalibration_time: 2017-10-06-11-09-49\n"
                                     "gain: 1.0\nk: 27.0\nlimit: 1.0\nradius: 0.0318\ntrim: 0.0  # never calibrated\n")
    kin, stamp, findings = read_kinematics(tmp_path / "k.yaml")
    assert kin == Kinematics() and stamp == "2017-10-06-11-09-49" and findings == []
    (tmp_path / "i.yaml").write_text(
        "camera_matrix:\n  cols: 3\n  data:\n  - 336.5\n  - 0\n  - 316\n  - 0\n  - 336.5\n  - 233\n  - 0\n  - 0\n"
        "  - 1\n  rows: 3\ncamera_name: '/x/camera_node'\ndistortion_coefficients:\n  cols: 5\n"
        "  data: [-0.283, 0.058,\n    0.0, 0.0, 0]\n  rows: 1\ndistortion_model: plumb_bob\nimage_height: 480\n"
        "image_width: 640\nprojection_matrix:\n  cols: 4\n"
        "  data: [230.0, 0, 320.0, 0, 0, 230.0, 240.0, 0, 0, 0, 1, 0]\n"
        "  rows: 3\nrectification_matrix:\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n  rows: 3\n")
    camera, name, findings = read_intrinsic(tmp_path / "i.yaml")
    assert name == "/x/camera_node" and camera.K[0, 0] == 336.5 and camera.distortion[1] == 0.058
    assert findings == []
    (tmp_path / "e.yaml").write_text("homography: [-6.0e-06, -0.000217, -0.2267, 0.000993, -2.0e-06, -0.3224,\n"
                                     "  4.0e-06, -0.0076, 1.0]\n# Calibrated on 2018-01-01\n")
    H, findings = read_extrinsic(tmp_path / "e.yaml")
    assert H[1, 2] == -0.3224 and findings == []


@pytest.mark.parametrize("text, match", [
    ("homography: [1, 2]\n", r"field 'homography': expected a list of 9"),
    ("homography: [1, 2, 3, 4, 5, 6, 7, 8, 9]\nextra: 1\n", r"field 'extra': unknown field"),
    ("homography: [1, 2, 3\n", r"line 1: a list '\[' never closed"),
    ("homography: &a [1]\n", r"line 1: unsupported YAML"),
    ("homography: !!python/object [1]\n", r"line 1: unsupported YAML"),
    ("homography: [1]\nhomography: [2]\n", r"line 2, field 'homography': the same key twice"),
    ("\thomography: [1]\n", r"line 1: a tab"),
    ("homography: [nan, 0, 0, 0, 1, 0, 0, 0, 1]\n", r"field 'homography\[0\]': expected a finite"),
    ("", r"empty file"),
    ("homography: [-6e-6, -2.17e-4, -0.2267, 9.93e-4, -2e-6, 0.3224, 4e-6, -7.6e-3, 1]\n",
     r"field 'homography\[5\]': implausible"),
])
def test_the_extrinsic_reader_is_strict(tmp_path, text, match):
    (tmp_path / "e.yaml").write_text(text)
    with pytest.raises(DataError, match=match):
        read_extrinsic(tmp_path / "e.yaml")


def test_the_reader_names_implausible_real_files_and_can_report_them(tmp_path):
    text = ("image_width: 640\nimage_height: 480\ncamera_name: /x/camera_node\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
            "  data: [11454.0, 0, 316, 0, 11454.0, 233, 0, 0, 1]\ndistortion_model: plumb_bob\n"
            "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.283, 0.058, 0, 0, 0]\n"
            "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
            "projection_matrix:\n  rows: 3\n  cols: 4\n  data: [230, 0, 320, 0, 0, 230, 240, 0, 0, 0, 1, 0]\n")
    (tmp_path / "i.yaml").write_text(text)
    with pytest.raises(DataError, match=r"i.yaml, field 'camera_matrix.fx': implausible calibration: 11454"):
        read_intrinsic(tmp_path / "i.yaml")
    _, _, findings = read_intrinsic(tmp_path / "i.yaml", strict=False)
    assert [f.level for f in findings if f.field == "camera_matrix.fx"] == ["refuse"]
    (tmp_path / "i.yaml").write_text(text.replace("distortion_model: plumb_bob", "distortion_model: equidistant"))
    with pytest.raises(DataError, match="field 'distortion_model'"):
        read_intrinsic(tmp_path / "i.yaml")


def test_parse_simple_yaml_refuses_deeper_nesting():
    with pytest.raises(DataError, match="line 3: nested deeper"):
        parse_simple_yaml("a:\n  b:\n    c: 1\n", "x.yaml")
