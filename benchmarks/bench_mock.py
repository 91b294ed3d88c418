"""The mock's camera: rendering plus corner detection, in images per second and pixel accuracy, against the
straightforward implementation (every black square of both boards a thin PyBullet box on a white one, one
640 x 480 TinyRenderer image, findChessboardCornersSB with CALIB_CB_ACCURACY | CALIB_CB_EXHAUSTIVE, scored against
the squares' own top faces); and the collision checker in stances per second.

    python benchmarks/bench_mock.py [--images 40]

Then the same pipeline on the realistic mock (`realism="realistic"`: rolling shutter, YUYV capture, noise,
defocus; docs/MOCK.md), on stances its own (true) robot sees, in images per second and against the ideal mock.

Both pipelines see the same random visible stances of the same simulated robot and are scored against the same
exact projections (true kinematics, true camera). naocal's pipeline: the body by TinyRenderer, the boards drawn
from their exact homography with 4 x 4 area sampling, detection guided by a prediction (the truth shifted by a few
pixels, as a fitted model would give it).
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pybullet

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.corners import detect_board_vertices, find_grid, order_like_prediction  # noqa: E402
from naocal.backends.mock import MockBackend  # noqa: E402
from naocal.backends.mock_render import BLACK, WHITE  # noqa: E402
from naocal.body.nao_body import BOARD_HALF_X_M, BOARD_HALF_Y_M, CollisionChecker  # noqa: E402
from naocal.solver.joints import JOINTS, LEGS  # noqa: E402
from naocal.solver.nao_model import BOARD_COLUMNS, BOARD_ROWS, BOARD_SQUARE_M  # noqa: E402
from naocal.solver.transforms import make_transform  # noqa: E402
from tests.mock_stances import move_and_settle, visible_stances  # noqa: E402
from naocal.backends.mock import DEFAULT_POSTURE  # noqa: E402

SHEET_TOP_M = 0.0004  # the straightforward boards: a white sheet on the plate, black squares on the sheet
SQUARES_TOP_M = 0.0006


class BoxBoards:
    """The straightforward renderer: each board as 35 thin box squares on a white box, drawn by TinyRenderer
    at 640 x 480 into the mock's own scene (same body, same camera matrices)."""

    def __init__(self, mock: MockBackend):
        self.mock = mock
        cid = mock.body.client
        self.bodies = {}
        white = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=[BOARD_HALF_X_M, BOARD_HALF_Y_M, 0.0002],
                                           rgbaColor=[WHITE, WHITE, WHITE, 1], physicsClientId=cid)
        black = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=[BOARD_SQUARE_M / 2] * 2 + [0.0002],
                                           rgbaColor=[BLACK, BLACK, BLACK, 1], physicsClientId=cid)
        for leg in LEGS:
            parts = [pybullet.createMultiBody(0, -1, white, [0, 0, -10], physicsClientId=cid)]
            offsets = []
            for i in range(BOARD_COLUMNS):
                for j in range(BOARD_ROWS):
                    if (i + j) % 2 == 0:
                        offsets.append(((i - (BOARD_COLUMNS - 1) / 2) * BOARD_SQUARE_M,
                                        (j - (BOARD_ROWS - 1) / 2) * BOARD_SQUARE_M))
                        parts.append(pybullet.createMultiBody(0, -1, black, [0, 0, -10], physicsClientId=cid))
            self.bodies[leg] = (parts, offsets)

    def render(self, q_true):
        mock = self.mock
        cid = mock.body.client
        for leg in LEGS:
            T_world_board = mock._T_world_board(q_true, leg)
            parts, offsets = self.bodies[leg]
            self._place(parts[0], T_world_board @ make_transform(np.eye(3), [0, 0, SHEET_TOP_M - 0.0002]), cid)
            for part, (x, y) in zip(parts[1:], offsets):
                self._place(part, T_world_board @ make_transform(np.eye(3), [x, y, SQUARES_TOP_M - 0.0002]), cid)
        grey, _ = mock.renderer.render_body(q_true, mock._T_world_cam(q_true))
        return np.clip(np.rint(grey * 255), 0, 255).astype(np.uint8)

    @staticmethod
    def _place(body, T, cid):
        from scipy.spatial.transform import Rotation

        pybullet.resetBasePositionAndOrientation(body, T[:3, 3].tolist(), Rotation.from_matrix(T[:3, :3]).as_quat(),
                                                 physicsClientId=cid)

    def hide(self):
        for parts, _ in self.bodies.values():
            for part in parts:
                pybullet.resetBasePositionAndOrientation(part, [0, 0, -10], [0, 0, 0, 1],
                                                         physicsClientId=self.mock.body.client)


def summarise(name, errors, failures, seconds, n):
    if errors:
        e = np.concatenate(errors)
        rms = np.sqrt(np.mean(e ** 2, axis=0))
        mean = e.mean(axis=0)
        text = (f"RMS ({rms[0]:.3f}, {rms[1]:.3f}) px, mean ({mean[0]:+.3f}, {mean[1]:+.3f}) px, "
                f"max {np.abs(e).max():.2f} px")
    else:
        text = "no detections"
    print(f"{name:34s} {n / seconds:6.1f} images/s ({1000 * seconds / n:5.0f} ms each)  {len(errors):3d}/{n} boards "
          f"found  {text}  failures: {failures or '-'}")
    return n / seconds


def capture_and_detect(mock, n, rng):
    """(errors, failures, seconds) of capture (rendered on demand) + guided detection on n visible stances."""
    errors, failures, elapsed = [], {}, 0.0
    for command, leg in visible_stances(mock, n, seed=1):
        move_and_settle(mock, DEFAULT_POSTURE)  # as visible_stances checked the way
        move_and_settle(mock, command)
        mock.sleep(mock.camera_delay_s + 0.3)  # the realistic servo settles for a while
        before = time.perf_counter()
        image = mock.capture()
        truth, _ = mock.true_vertex_pixels(image)[leg]
        found = detect_board_vertices(image.pixels, truth + rng.normal(0, 5, 2))
        elapsed += time.perf_counter() - before
        if found.ok:
            errors.append(found.vertices_px - truth)
        else:
            failures[found.reason] = failures.get(found.reason, 0) + 1
    mock.close()
    return errors, failures, elapsed


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=40)
    args = parser.parse_args()

    mock = MockBackend(seed=0)
    stances = visible_stances(mock, args.images, seed=1)
    rng = np.random.default_rng(0)

    # naocal: capture (render on demand) + guided detection.
    errors, failures, elapsed = [], {}, 0.0
    for command, leg in stances:
        move_and_settle(mock, DEFAULT_POSTURE)
        move_and_settle(mock, command)
        mock.sleep(mock.camera_delay_s + 0.1)
        before = time.perf_counter()
        image = mock.capture()  # rendered here, on demand
        truth, _ = mock.true_vertex_pixels(image)[leg]
        predicted = truth + rng.normal(0, 5, 2)
        found = detect_board_vertices(image.pixels, predicted)
        elapsed += time.perf_counter() - before
        if found.ok:
            errors.append(found.vertices_px - truth)
        else:
            failures[found.reason] = failures.get(found.reason, 0) + 1
    ours = summarise("homography boards + guided detection", errors, failures, elapsed, len(stances))
    realistic = capture_and_detect(MockBackend(seed=0, realism="realistic"), args.images, rng)
    summarise("realistic mock (YUYV, noise, defocus)", *realistic, args.images)
    print(f"realistic / ideal time per image: {realistic[2] / elapsed:.2f}")

    # Straightforward: box squares in TinyRenderer + findChessboardCornersSB.
    boxes = BoxBoards(mock)
    errors, failures, elapsed = [], {}, 0.0
    for command, leg in stances:
        q_true = mock._true_static(np.array([command[j] for j in JOINTS]))
        # Its corners are those of the squares' top faces, 0.6 mm above the board plane.
        T_cam_board = np.linalg.inv(mock._T_world_cam(q_true)) @ mock._T_world_board(q_true, leg)
        corners = mock._vertices_board + [0.0, 0.0, SQUARES_TOP_M]
        truth = mock.truth.camera.project(corners @ T_cam_board[:3, :3].T + T_cam_board[:3, 3])
        before = time.perf_counter()
        pixels = boxes.render(q_true)
        grid = find_grid(pixels, "sb")
        ordered = order_like_prediction(grid, truth)[0] if grid is not None else None
        elapsed += time.perf_counter() - before
        if ordered is not None and np.abs(ordered - truth).max() < 3.0:
            errors.append(ordered - truth)
        else:
            failures["not found"] = failures.get("not found", 0) + 1
    boxes.hide()
    plain = summarise("box boards + findChessboardCornersSB", errors, failures, elapsed, len(stances))
    print(f"speed ratio (naocal / straightforward): {ours / plain:.2f}")

    # Collision checks, as the planner makes them (nominal body).
    checker = CollisionChecker(margin_m=0.01, ground_margin_m=0.01)
    limits = mock.joint_limits()
    lower = np.array([limits[j][0] for j in JOINTS])
    upper = np.array([limits[j][1] for j in JOINTS])
    candidates = rng.uniform(lower, upper, size=(3000, len(JOINTS)))
    before = time.perf_counter()
    safe = checker.safe_mask(candidates)
    quick = len(candidates) / (time.perf_counter() - before)
    safe_ones = np.array([command_row for command_row in (np.array([c[j] for j in JOINTS]) for c, _ in stances)])
    before = time.perf_counter()
    for _ in range(10):
        checker.safe_mask(safe_ones)
    full = 10 * len(safe_ones) / (time.perf_counter() - before)
    print(f"collision checks: {quick:.0f} random stances/s ({100 * safe.mean():.0f} % safe, most exit early), "
          f"{full:.0f} safe stances/s (every pair checked)")
    checker.close()
    mock.close()


if __name__ == "__main__":
    main()
