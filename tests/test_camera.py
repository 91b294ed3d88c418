"""The camera model (solver/camera.py) against OpenCV, and its derivatives against finite differences."""

import cv2
import numpy as np
import pytest

from naocal.solver import camera

K = (-0.08, 0.03, 0.002, -0.001, 0.01)
INTR = {"fx_px": 610.0, "fy_px": 605.0, "cx_px": 318.0, "cy_px": 243.0, "distortion": list(K),
        "width_px": 640, "height_px": 480}


def points(rng, n=200):
    x = rng.uniform(0.2, 1.0, n)
    return np.column_stack([x, rng.uniform(-0.4, 0.4, n) * x, rng.uniform(-0.3, 0.3, n) * x])


def test_projection_is_opencvs_with_the_nao_camera_frame():
    """OpenCV's camera frame is (x right, y down, z forward) = (-y, -z, x) of the NAO camera frame."""
    p = points(np.random.default_rng(0))
    uv = camera.project(p, INTR["fx_px"], INTR["fy_px"], INTR["cx_px"], INTR["cy_px"], K).uv_px
    K_cv = np.array([[INTR["fx_px"], 0, INTR["cx_px"]], [0, INTR["fy_px"], INTR["cy_px"]], [0, 0, 1.0]])
    p_cv = np.column_stack([-p[:, 1], -p[:, 2], p[:, 0]])
    uv_cv = cv2.projectPoints(p_cv, np.zeros(3), np.zeros(3), K_cv, np.array(K))[0][:, 0]
    np.testing.assert_allclose(uv, uv_cv, atol=1e-9)
    np.testing.assert_allclose(camera.project_points(p, INTR)[0], uv, atol=1e-12)


def test_optical_axis_hits_the_principal_point_and_left_is_left():
    uv = camera.project(np.array([[1.0, 0, 0], [1.0, 0.1, 0], [1.0, 0, 0.1]]), 600.0, 600.0, 320.0, 240.0).uv_px
    assert uv[0] == pytest.approx([320.0, 240.0])
    assert uv[1, 0] < 320.0 and uv[2, 1] < 240.0  # a point to the left is left in the image, up is up


def fd(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


def test_point_and_twist_jacobians_against_finite_differences():
    rng = np.random.default_rng(1)
    p = points(rng, 50)
    proj = camera.project(p, 610.0, 605.0, 318.0, 243.0, K)
    A, L = proj.point_jacobian(), proj.twist_jacobian()
    uv = lambda q: camera.project(q, 610.0, 605.0, 318.0, 243.0, K).uv_px  # noqa: E731
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1e-6
        np.testing.assert_allclose(A[:, :, i], (uv(p + e) - uv(p - e)) / 2e-6, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(L[:, :, i], A[:, :, i])
        # a rotation about axis i: dp = e_i x p
        w = np.zeros(3)
        w[i] = 1e-6
        np.testing.assert_allclose(L[:, :, 3 + i], (uv(p + np.cross(w, p)) - uv(p - np.cross(w, p))) / 2e-6,
                                   rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("component", camera.COMPONENTS)
def test_intrinsic_jacobian_against_finite_differences(component):
    p = points(np.random.default_rng(2), 50)
    values = dict(fx=610.0, fy=605.0, cx=318.0, cy=243.0, k1=K[0], k2=K[1], p1=K[2], p2=K[3], k3=K[4])

    def uv(delta):
        v = dict(values)
        v[component] += delta
        return camera.project(p, v["fx"], v["fy"], v["cx"], v["cy"], (v["k1"], v["k2"], v["p1"], v["p2"],
                                                                       v["k3"])).uv_px

    h = 1e-3 if component in ("fx", "fy", "cx", "cy") else 1e-6
    expected = (uv(h) - uv(-h)) / (2 * h)
    got = camera.project(p, 610.0, 605.0, 318.0, 243.0, K).intrinsic_jacobian(component)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-6)


def test_per_point_intrinsics_equal_per_camera_projections():
    rng = np.random.default_rng(3)
    p = points(rng, 20)
    fx = np.r_[np.full(10, 600.0), np.full(10, 620.0)]
    both = camera.project(p, fx, 600.0, 320.0, 240.0).uv_px
    np.testing.assert_allclose(both[:10], camera.project(p[:10], 600.0, 600.0, 320.0, 240.0).uv_px)
    np.testing.assert_allclose(both[10:], camera.project(p[10:], 620.0, 600.0, 320.0, 240.0).uv_px)


def test_unknown_component_is_refused():
    with pytest.raises(ValueError, match="unknown intrinsic component"):
        camera.project(np.array([[1.0, 0, 0]]), 1.0, 1.0, 0.0, 0.0).intrinsic_jacobian("skew")


def test_default_intrinsics_come_from_the_robot_description():
    from naocal.solver.robot import default_intrinsics, nao

    assert default_intrinsics() == nao().camera("bottom").intrinsics()
    assert default_intrinsics("top")["height_px"] == 480


def test_undistortion_inverts_the_projection_and_agrees_with_opencv():
    """undistort_points: distorted pixels back to the pinhole pixels of the same rays (every OpenCV coefficient),
    as cv2.undistortPoints finds them."""
    intrinsics = {"fx_px": 560.0, "fy_px": 575.0, "cx_px": 318.0, "cy_px": 243.0,
                  "distortion": (-0.12, 0.05, 0.002, -0.001, -0.01)}
    rng = np.random.default_rng(3)
    p_cam = np.column_stack([np.ones(300), rng.uniform(-0.5, 0.5, 300), rng.uniform(-0.4, 0.4, 300)])
    distorted, _ = camera.project_points(p_cam, intrinsics)
    pinhole, _ = camera.project_points(p_cam, {**intrinsics, "distortion": None})
    np.testing.assert_allclose(camera.undistort_points(distorted, intrinsics), pinhole, atol=1e-8)
    K = np.array([[560.0, 0, 318.0], [0, 575.0, 243.0], [0, 0, 1]])
    opencv = cv2.undistortPoints(distorted[:, None, :], K, np.array(intrinsics["distortion"]), P=K,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))[:, 0]
    np.testing.assert_allclose(camera.undistort_points(distorted, intrinsics), opencv, atol=1e-3)
    np.testing.assert_array_equal(camera.undistort_points(distorted, {**intrinsics, "distortion": None}), distorted)


def test_plane_homography_maps_a_plane_as_the_projection_does():
    from naocal.solver.transforms import make_transform, rot_rpy

    intrinsics = {"fx_px": 600.0, "fy_px": 610.0, "cx_px": 320.0, "cy_px": 240.0}
    T_cam_plane = make_transform(rot_rpy(0.2, -0.3, 0.1) @ np.array([[0, 0, -1.0], [0, 1, 0], [1, 0, 0]]),
                                 [0.5, 0.02, -0.03])
    xy = np.random.default_rng(1).uniform(-0.1, 0.1, (50, 2))
    H = camera.plane_homography(T_cam_plane, intrinsics)
    mapped = np.column_stack([xy, np.ones(50)]) @ H.T
    p_cam = np.column_stack([xy, np.zeros(50)]) @ T_cam_plane[:3, :3].T + T_cam_plane[:3, 3]
    np.testing.assert_allclose(mapped[:, :2] / mapped[:, 2:], camera.project_points(p_cam, intrinsics)[0], atol=1e-9)
