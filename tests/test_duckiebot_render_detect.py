"""Marker and board detection (kinds/duckiebot/detect.py) on images of the independent OpenCV renderer
(kinds/duckiebot/render.py), whose drive log must read (issue 23)."""

import cv2
import numpy as np
import pytest

from naocal.kinds.duckiebot.calibration_files import (apply_homography, duckietown_calibration, read_calibration,
                                               write_calibration)
from naocal.kinds.duckiebot.detect import detect_boards, detect_markers
from naocal.kinds.duckiebot.drive_log import read_drive_log
from naocal.kinds.duckiebot.intrinsics import LensCamera, board_points, camera_difference_px, choose_lens
from naocal.kinds.duckiebot.kinematics import wheel_speeds
from naocal.kinds.duckiebot.render import (Renderer, calibration_scene, hidden_robot, paper_program, render_drive_log,
                                    undistort_exact)
from naocal.solver.camera import project_points
from naocal.solver.transforms import invert_transform, make_transform, rot_z, transform_points

MIN_MARKER_SIDE_PX = 20.0  # markers whose every side is at least this long are held to the sub-pixel bound


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    directory = tmp_path_factory.mktemp("render") / "LOG"
    return render_drive_log(directory, seed=3, steps=paper_program(board_steps=2, marker_drives=3))


def test_the_opencv_class_api_exists():
    assert hasattr(cv2.aruco, "ArucoDetector") and hasattr(cv2.aruco, "DICT_APRILTAG_36h11")


def test_a_printed_marker_is_found_at_its_corners():
    """Independent of the renderer: a marker drawn 10 px per cell at a known place; its black square's outer
    corners lie on pixel boundaries, half a pixel from the pixel centres (OpenCV's convention)."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    image = np.full((240, 320), 230, np.uint8)
    image[60:140, 100:180] = cv2.aruco.generateImageMarker(dictionary, 7, 80, borderBits=1)
    image = cv2.GaussianBlur(image, (0, 0), 0.7)
    sightings = detect_markers(np.dstack([image] * 3))
    assert [s.id for s in sightings] == [7]
    expected = np.array([[99.5, 59.5], [179.5, 59.5], [179.5, 139.5], [99.5, 139.5]])
    np.testing.assert_allclose(sightings[0].corners_px, expected, atol=0.3)
    assert detect_markers(np.full((100, 100), 128, np.uint8)) == []


def test_exact_undistortion_inverts_the_projection_in_the_corners():
    camera = hidden_robot(1).camera
    uv = np.array([[-0.5, -0.5], [639.5, 479.5], [0.0, 240.0], [320.0, 0.0], [321.3, 233.7]])
    xn = undistort_exact(uv, camera.intrinsics())
    back, _ = project_points(np.stack([np.ones(len(uv)), -xn[:, 0], -xn[:, 1]], axis=1), camera.intrinsics())
    np.testing.assert_allclose(back, uv, atol=1e-6)


def test_the_rendered_log_reads_and_holds_the_drive(rendered):
    log = read_drive_log(rendered.log.path)
    assert log.meta() == rendered.log.meta() and log.frame_files == rendered.log.frame_files
    assert log.model == "DB21" and log.wheels.k == 27.0  # the nominal description, not the hidden truth
    assert np.abs(np.concatenate([log.left_duty, log.right_duty])).max() <= 1.0
    # encoders count the true wheel angles: 135 ticks per revolution, over the whole drive
    truth = rendered.robot.kinematics
    durations = np.diff(log.wheel_t_s)
    w_left, w_right = wheel_speeds(log.left_duty[:-1], log.right_duty[:-1], truth)
    turns = np.array([w_left @ durations, w_right @ durations]) / (2 * np.pi)
    np.testing.assert_allclose([log.left_ticks[-1], log.right_ticks[-1]], turns * 135, atol=1.0)
    # the robot faced the marker line after its spin; frames are grabbed standing still
    assert rendered.drive.frame_poses[-1][2] == pytest.approx(np.pi, abs=1e-9)
    left, right = log.duties_at(log.frame_t_s)
    assert not left.any() and not right.any()


def test_markers_are_detected_at_their_true_pixels(rendered):
    errors, seen = [], set()
    for i in range(len(rendered.log.frame_files)):
        truth = rendered.marker_px[i]
        for sighting in detect_markers(rendered.log.load_frame(i)):
            assert sighting.id in truth, f"frame {i}: marker {sighting.id} is not in view"
            true = truth[sighting.id]
            sides = np.linalg.norm(true - np.roll(true, 1, axis=0), axis=1)
            if sides.min() >= MIN_MARKER_SIDE_PX:
                errors.append(np.linalg.norm(sighting.corners_px - true, axis=1))
                seen.add(sighting.id)
    errors = np.concatenate(errors)
    assert len(seen) >= 2 and len(errors) >= 20
    # ArUco's sub-pixel refinement of an L-shaped corner lands about 0.15-0.3 px off (docs/DUCKIEBOT.md)
    assert errors.max() < 0.6 and np.sqrt(np.mean(errors ** 2)) < 0.4


def test_boards_are_detected_at_their_true_pixels(rendered):
    found = 0
    for i in range(len(rendered.log.frame_files)):
        truth = rendered.board_px[i]
        sightings = detect_boards(rendered.log.load_frame(i), rendered.log.board_inner_corners)
        assert len(sightings) == len(truth), f"frame {i}"
        for sighting in sightings:
            error = min(np.abs(sighting.corners_px - true).max() for true in truth.values())
            assert error < 0.25, f"frame {i}: board corners {error:.2f} px off"
            found += 1
    assert found >= 5


def test_rendering_is_deterministic_and_geometric():
    scene = calibration_scene()
    robot = hidden_robot(2)
    renderer = Renderer(scene, robot.camera, robot.T_base_camera)
    a = renderer.render((0.0, 0.0, 0.0), np.random.default_rng(5))
    b = renderer.render((0.0, 0.0, 0.0), np.random.default_rng(5))
    assert a.shape == (480, 640) and np.array_equal(a, b)
    # facing away from boards and markers (towards +y): floor and wall only, the floor below the horizon
    empty = renderer.render((0.0, 0.0, np.pi / 2), noise_grey=0.0, blur_px=0.0)
    assert detect_markers(empty) == [] and abs(int(empty[-1, 320]) - 70) <= 1


def test_intrinsics_from_the_rendered_boards(rendered):
    """The boards seen while turning on the spot: the lens model chosen by held-out error (boards held out one at
    a time) is the truth's, plumb_bob; the camera is judged against the truth over the whole image."""
    O, I, groups = [], [], []
    obj = board_points(rendered.log.board_inner_corners, rendered.log.board_square_m)
    for i in range(len(rendered.log.frame_files)):
        for sighting in detect_boards(rendered.log.load_frame(i), rendered.log.board_inner_corners):
            truth = rendered.board_px[i]
            board = min(truth, key=lambda b: np.abs(sighting.corners_px - truth[b]).max())
            O.append(obj)
            I.append(sighting.corners_px.reshape(-1, 2))
            groups.append(board)
    best, fits = choose_lens(O, I, (640, 480), groups)
    assert best.camera.model == "plumb_bob" and best.train_rms_px < 0.1
    assert fits["fisheye"].held_out_rms_px > best.held_out_rms_px
    assert camera_difference_px(LensCamera.from_intrinsics(rendered.robot.camera), best.camera, (640, 480)) < 1.5


def test_the_exported_homography_puts_detected_markers_where_they_lie(rendered, tmp_path):
    """Duckietown's files written from the hidden robot's truth: a detected marker corner, rectified with the
    intrinsic file's camera (undistorted onto its projection_matrix) and mapped by the extrinsic file's homography,
    lands on the floor where the marker lies, in the robot's frame (x forward from the axle, y left)."""
    robot = rendered.robot
    write_calibration(tmp_path, duckietown_calibration("rendered", robot.kinematics, robot.camera,
                                                       robot.T_base_camera, "2026-11-27-12-00-00"))
    cal, findings = read_calibration(tmp_path, "rendered")
    assert not [f for f in findings if f.level == "refuse"]
    errors = []
    for i in range(len(rendered.log.frame_files)):
        x, y, theta = rendered.drive.frame_poses[i]
        T_base_world = invert_transform(make_transform(rot_z(theta), (x, y, 0.0)))
        for sighting in detect_markers(rendered.log.load_frame(i)):
            rectified = cv2.undistortPoints(sighting.corners_px.reshape(-1, 1, 2), cal.camera.K,
                                            cal.camera.distortion, None, cal.camera.projection()[:, :3])
            ground = apply_homography(cal.homography, rectified.reshape(-1, 2))
            true = transform_points(T_base_world, rendered.scene.marker_corners()[sighting.id])[:, :2]
            if np.linalg.norm(true, axis=1).max() < 0.35:  # the near floor, where Duckietown's lane is read
                errors.append(np.linalg.norm(ground - true, axis=1))
    errors = np.concatenate(errors)
    assert len(errors) >= 8 and errors.max() < 0.002  # m (seeds 1, 3: 0.7, 1.3 mm): the corners' 0.1-0.6 px
