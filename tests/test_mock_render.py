"""The mock's body, collision checker and renderer: conventions and exactness."""

import math

import numpy as np
import pybullet
import pytest

from naocal.backends.mock_render import SceneRenderer, board_outline_board_m, projection_matrix_gl, view_matrix_gl
from naocal.solver.camera import CameraIntrinsics, plane_homography
from naocal.body.nao_body import (
    BOARD_HALF_X_M, BOARD_HALF_Y_M, T_WORLD_TORSO, BoardMount, BodyGeometry, CollisionChecker, NaoBody,
    T_sole_board,
)
from naocal.backends.mock import DEFAULT_POSTURE
from naocal.solver.joints import JOINTS, LEGS, leg_joints
from naocal.solver.kinematics import camera_fk, chain_frames, gravity_torques, leg_fk
from naocal.solver.limits import joint_limits
from naocal.solver.nao_model import head_chain


@pytest.fixture(scope="module")
def body():
    geometry = BodyGeometry(thigh_delta_m={"L": 0.003, "R": -0.002}, tibia_delta_m={"L": -0.001, "R": 0.004},
                            board_mount={"L": BoardMount(0.01, 0.002, -0.001), "R": BoardMount(-0.02, 0.0, 0.003)})
    nao = NaoBody(geometry)
    yield nao
    nao.close()


def _random_stances(n, seed=0):
    limits = joint_limits()
    lower = np.array([limits[j][0] for j in JOINTS])
    upper = np.array([limits[j][1] for j in JOINTS])
    return np.random.default_rng(seed).uniform(lower, upper, size=(n, len(JOINTS)))


def test_body_links_sit_where_the_kinematics_put_them(body):
    geometry = body.geometry
    for q in _random_stances(20):
        body.set_angles(q)
        for leg in LEGS:
            q_leg = q[[JOINTS.index(j) for j in leg_joints(leg)]][None]
            T_sole = leg_fk(q_leg, leg, thigh_delta_m=geometry.thigh_delta_m[leg],
                            tibia_delta_m=geometry.tibia_delta_m[leg])[0]
            expected = T_WORLD_TORSO @ T_sole @ T_sole_board(geometry.board_mount[leg])
            np.testing.assert_allclose(body.link_pose_world(f"{leg}Sandal"), expected, atol=1e-6)
        frames, _ = chain_frames(head_chain(), q[None, :2])
        np.testing.assert_allclose(body.link_pose_world("Head"), T_WORLD_TORSO @ frames[0, 1], atol=1e-6)


def test_gravity_torques_of_the_simulated_masses_match_the_model(body):
    for q in _random_stances(10, seed=1):
        tau = body.gravity_torques(q)
        for leg in LEGS:
            idx = [JOINTS.index(j) for j in leg_joints(leg)]
            mount = body.geometry.board_mount[leg]
            expected = gravity_torques(q[idx][None], leg, sandal_com_sole_m=T_sole_board(mount)[:3, 3])[0]
            if body.geometry.thigh_delta_m[leg] or body.geometry.tibia_delta_m[leg]:
                continue  # the model's torques use the nominal lengths; see test below for the nominal body
            np.testing.assert_allclose(tau[idx], expected, atol=1e-12)
    nominal = NaoBody()
    for q in _random_stances(10, seed=2):
        tau = nominal.gravity_torques(q)
        for leg in LEGS:
            idx = [JOINTS.index(j) for j in leg_joints(leg)]
            np.testing.assert_allclose(tau[idx], gravity_torques(q[idx][None], leg)[0], atol=1e-12)
    nominal.close()


def test_collision_checker_on_known_stances():
    checker = CollisionChecker()
    posture = np.array([DEFAULT_POSTURE[j] for j in JOINTS])
    assert checker.is_safe(posture) and checker.contacts(posture) == []
    crossed = posture.copy()
    crossed[JOINTS.index("LHipRoll")], crossed[JOINTS.index("RHipRoll")] = -0.2, 0.2
    assert not checker.is_safe(crossed)
    assert any({c.link_a, c.link_b} == {"LSandal", "RSandal"} for c in checker.contacts(crossed))
    down = posture.copy()
    down[JOINTS.index("RHipPitch")], down[JOINTS.index("RKneePitch")] = 0.4, 0.0
    assert ("RSandal", "ground") in {(c.link_a, c.link_b) for c in checker.contacts(down)}
    assert checker.safe_mask(np.stack([posture, crossed, down])).tolist() == [True, False, False]
    as_dict = dict(zip(JOINTS, posture))
    assert checker.is_safe(as_dict)
    with pytest.raises(ValueError):
        checker.is_safe(posture[:5])
    checker.close()


def test_ray_occlusion(body):
    q = np.array([DEFAULT_POSTURE[j] for j in JOINTS])
    body.set_angles(q)
    torso = body.link_pose_world("torso")[:3, 3]  # inside the torso's box, 6 cm above the ground
    above = torso + [0.0, 0.0, 1.0]
    on_chest = torso + [0.0, 0.0, 0.05]  # the torso's front (its top, lying on the back) is at +0.05
    assert body.hidden(q, above, [on_chest, above + [0.1, 0.0, 0.0]]).tolist() == [False, False]
    assert body.hidden(q, above, [torso, torso - [0.0, 0.0, 0.2]]).tolist() == [True, True]


def _edge_scene(edge_u_px=None, edge_v_px=None, depth_m=1.0):
    """A PyBullet client with one large thin box whose near face, at `depth_m` in front of a NAO camera at the
    world origin (looking along world +x), starts at pixel column u (covering larger u) or row v."""
    client = pybullet.connect(pybullet.DIRECT)
    cam = CameraIntrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    half = 0.2
    shape = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=[0.001, half, half], physicsClientId=client)
    # u = cx - fx * y / x  ->  the edge at u is at y = (cx - u) * x / fx; the box covers y below it.
    y = 0.0 if edge_u_px is None else (cam.cx_px - edge_u_px) * depth_m / cam.fx_px - half
    z = 0.0 if edge_v_px is None else (cam.cy_px - edge_v_px) * depth_m / cam.fy_px - half
    pybullet.createMultiBody(0, -1, shape, [depth_m + 0.001, y, z], physicsClientId=client)
    _, _, _, _, seg = pybullet.getCameraImage(
        cam.width_px, cam.height_px, view_matrix_gl(np.eye(4)).T.ravel().tolist(),
        projection_matrix_gl(cam).T.ravel().tolist(), renderer=pybullet.ER_TINY_RENDERER, shadow=0,
        physicsClientId=client)
    pybullet.disconnect(client)
    return np.asarray(seg).reshape(cam.height_px, cam.width_px) >= 0


@pytest.mark.parametrize("edge", [200.2, 200.8, 333.5, 417.3])
def test_tinyrenderer_samples_pixel_centres_with_the_opencv_convention(edge):
    """Pixel (k, r) covers (u, v) = (k, r): an edge at u = e first covers column ceil(e), likewise rows."""
    covered = _edge_scene(edge_u_px=edge)
    assert np.argmax(covered[240]) == math.ceil(edge)
    covered = _edge_scene(edge_v_px=edge * 0.8)
    assert np.argmax(covered[:, 320]) == math.ceil(edge * 0.8)


def test_board_coverage_is_the_exact_projected_area(body):
    """Area sampling: the board's drawn coverage sums to the area of its exact projection (shoelace)."""
    cam = CameraIntrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    renderer = SceneRenderer(body, cam, supersample=4)
    rng = np.random.default_rng(4)
    for _ in range(5):
        from naocal.solver.transforms import make_transform, rot_rpy

        R = rot_rpy(*rng.uniform(-0.4, 0.4, 3)) @ np.array([[0, 0, -1.0], [0, 1, 0], [1, 0, 0]])
        T_cam_board = make_transform(R, [rng.uniform(0.45, 0.6), rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03)])
        corners = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * [BOARD_HALF_X_M, BOARD_HALF_Y_M, 0]
        uv = cam.project(corners @ T_cam_board[:3, :3].T + T_cam_board[:3, 3])
        area = 0.5 * abs(np.dot(uv[:, 0], np.roll(uv[:, 1], 1)) - np.dot(uv[:, 1], np.roll(uv[:, 0], 1)))
        bbox = renderer._bbox([T_cam_board])
        assert bbox is not None and bbox[0] > 0 and bbox[2] < 639 and bbox[1] > 0 and bbox[3] < 479
        coverage = renderer._warp_board(T_cam_board, bbox)[..., 1]
        assert coverage.sum() == pytest.approx(area, rel=2e-4)
        # The homography used to draw maps the board plane exactly as the camera model projects it.
        H = plane_homography(T_cam_board, cam.intrinsics())
        outline = board_outline_board_m()
        mapped = (H @ np.column_stack([outline[:, :2], np.ones(len(outline))]).T).T
        np.testing.assert_allclose(mapped[:, :2] / mapped[:, 2:], cam.project(outline @ T_cam_board[:3, :3].T
                                                                               + T_cam_board[:3, 3]), atol=1e-9)


def test_camera_model_distortion_round_trip():
    cam = CameraIntrinsics(640, 480, 600.0, 600.0, 320.0, 240.0, distortion=(-0.1, 0.0, 0.0, 0.0, 0.0))
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [639, 479], size=(200, 2))
    undistorted = cam.undistort_px(uv)
    rays = np.column_stack([np.ones(200), -(undistorted[:, 0] - cam.cx_px) / cam.fx_px,
                            -(undistorted[:, 1] - cam.cy_px) / cam.fy_px])
    np.testing.assert_allclose(cam.project(rays), uv, atol=1e-9)


def test_view_matrix_looks_along_the_nao_optical_axis():
    T_world_cam = T_WORLD_TORSO @ camera_fk(np.array([[0.2, 0.3]]))[0]
    V = view_matrix_gl(T_world_cam)
    ahead = T_world_cam[:3, 3] + T_world_cam[:3, 0]  # 1 m along the optical axis
    p_gl = V @ np.append(ahead, 1.0)
    np.testing.assert_allclose(p_gl[:3], [0.0, 0.0, -1.0], atol=1e-12)  # OpenGL cameras look along -z


def test_rendered_images_are_pinned_to_the_bit():
    """A capture of seed 21 with a distorted lens and shifted intrinsics, pinned by its SHA-256 (taken before the
    renderer's camera became solver.camera.CameraIntrinsics): the renderer's camera type,
    projection, undistortion map and homography may change in form, not in a single pixel. The pin holds for the
    library versions it was taken with (a newer OpenCV or PyBullet may round a pixel differently): skipped with
    others."""
    import hashlib
    import importlib.metadata

    import cv2

    versions = (cv2.__version__, np.__version__, importlib.metadata.version("pybullet"))
    if versions != ("5.0.0", "2.4.6", "3.2.7"):
        pytest.skip(f"pinned with OpenCV 5.0.0, numpy 2.4.6, pybullet 3.2.7; these are {versions}")

    from naocal.backends.mock import MockBackend
    from tests.mock_stances import settle_and_capture, visible_stances

    mock = MockBackend(seed=21, effects={"distortion": -0.08, "intrinsics": 5.0})
    command, _ = visible_stances(mock, 1, seed=5, margin_px=10.0)[0]
    pixels = np.ascontiguousarray(settle_and_capture(mock, command).pixels)
    assert pixels.shape == (480, 640, 3)
    assert hashlib.sha256(pixels.tobytes()).hexdigest() == \
        "ff0b4fc3c88fcbd78c53c8f3629e77e56c041ed624872d31f5c5556330e5202a"
