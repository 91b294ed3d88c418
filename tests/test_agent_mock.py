"""The agent on the PyBullet mock: one full calibration shared by the tests (tests/conftest.py's mock_run), checked
against the mock's hidden truth; a run that does not wait out the image delay; the command log."""

import json
import math

import numpy as np
import pytest

pytest.importorskip("naocal.backends.mock")

from naocal.agent.planner import PlanSettings  # noqa: E402
from naocal.agent.robot import TimingSettings  # noqa: E402
from naocal.backends.compensated import CompensatedBackend  # noqa: E402
from naocal.backends.mock import SHARED_MOTOR, MockBackend  # noqa: E402
from naocal.body.nao_body import CollisionChecker, NaoBody  # noqa: E402
from naocal.solver.dataset import read_dataset  # noqa: E402
from naocal.solver.joints import JOINT_INDEX, JOINTS, LEG_JOINTS  # noqa: E402
from naocal.solver.limits import head_pitch_limits  # noqa: E402
from naocal.solver.offsets import read_offsets  # noqa: E402
from naocal.solver.registry import Registry  # noqa: E402
from naocal.solver.model import Model  # noqa: E402
from naocal.sim.synthetic import make_model_data  # noqa: E402
from naocal.agent.planner import make_plan  # noqa: E402
from naocal.agent.robot import Robot  # noqa: E402
from naocal.agent.safety import SafetyGuard  # noqa: E402

pytestmark = pytest.mark.slow
SEED = 5
DEG = math.radians(1.0)


def test_calibration_finds_the_hidden_offsets(mock_run):
    mock, out, result, ctx, _ = mock_run
    assert result.ok, result.reason
    truth = mock.truth_dict()
    offsets = read_offsets(out / "offsets.json")
    for joint in LEG_JOINTS:
        # stored c = -alpha: ADDED to commands, SUBTRACTED from readings
        assert offsets.joint_offset(joint) == pytest.approx(-truth["alpha_rad"][joint], abs=0.1 * DEG), joint
    for camera in ("bottom", "top"):  # one run calibrates both cameras
        for k, angle in enumerate(("roll", "pitch", "yaw")):
            assert offsets.camera_rpy(camera)[k] == pytest.approx(truth["camera_rotation_rad"][camera][angle],
                                                                  abs=0.05 * DEG), (camera, angle)
    assert sum(step.camera == "top" for step in ctx.plan.stills()) >= 2
    assert ctx.measurement["n_saved"] == ctx.plan.n_images() and ctx.measurement["n_skipped"] == 0
    assert ctx.measurement["robot_time_s"] < 590.0, "faster than the paper's robot"


def test_after_compensation_commands_reach_their_angle_and_readings_tell_the_truth(mock_run):
    mock, out, result, ctx, _ = mock_run
    offsets = read_offsets(out / "offsets.json")
    compensated = CompensatedBackend(mock, offsets)
    wrong_sign = CompensatedBackend(mock, {j: -c for j, c in offsets.joint_offsets_rad.items()})
    for stance in ctx.plan.verification:
        target = dict(zip(JOINTS, stance.angles()))
        for backend, good in ((compensated, True), (wrong_sign, False), (mock, False)):
            backend.command(target, 0.4)
            mock.sleep(3.0)
            true = mock.true_angles()
            reading = backend.read_joints().angles_rad
            error = max(abs(true[j] - target[j]) for j in LEG_JOINTS)
            told = max(abs(reading[j] - true[j]) for j in LEG_JOINTS)
            if good:
                assert error < 0.1 * DEG, f"a joint stands {error / DEG:.3f} deg from where it was sent"
                assert told < 0.1 * DEG, f"a corrected reading is {told / DEG:.3f} deg off the true angle"
            else:
                assert error > 0.3 * DEG and told > 0.3 * DEG  # uncompensated or wrong sign: visibly off
    mock.command(dict(zip(JOINTS, ctx.plan.parked())), 0.4)
    mock.sleep(3.0)


def test_no_command_the_mock_received_was_unsafe(mock_run):
    mock, out, result, ctx, n_commands = mock_run
    log = mock.command_log[:n_commands]
    assert all(record.accepted for record in log), [r.reason for r in log if not r.accepted][:3]
    limits = mock.joint_limits()
    body = NaoBody(mock.truth.geometry())
    try:
        checker = CollisionChecker(body, margin_m=0.003, ground_margin_m=0.003)
        servo = dict(mock.servo_angles(0.0))  # the starting posture
        alpha = np.array([mock.truth.alpha_rad[j] for j in JOINTS])
        for record in log:
            for joint, angle in record.targets_rad.items():
                lo, hi = limits[joint]
                assert lo <= angle <= hi, (joint, angle)
            servo.update(record.targets_rad)
            servo[SHARED_MOTOR[1]] = servo[SHARED_MOTOR[0]]  # one motor: the left command wins
            q = np.array([servo[j] for j in JOINTS])
            lo, hi = head_pitch_limits(q[JOINT_INDEX["HeadYaw"]])
            assert lo <= q[JOINT_INDEX["HeadPitch"]] <= hi
            assert checker.is_safe(q + alpha), f"commanded stance at t = {record.t_s:.2f} s collides"
    finally:
        body.close()


def test_dataset_and_summary(mock_run):
    mock, out, result, ctx, _ = mock_run
    data = read_dataset(out / "dataset")
    images = np.unique(data.columns["image"])
    assert images.tolist() == ctx.plan.image_indices()
    assert len(list((out / "dataset" / "images").glob("*.png"))) == len(images)
    probe = [i for s in ctx.plan.sweeps() for i in s.images]
    assert len(probe) == 6
    moving = np.isin(data.columns["image"], probe)
    assert np.all(np.abs(data.joint_matrix("vel_")[moving]).max(axis=1) > 0.02)
    assert np.all(data.joint_matrix("vel_")[~moving] == 0.0)
    summary = (out / "summary.txt").read_text()
    assert "naocal calibrate: done" in summary and "against the mock's hidden truth" in summary
    report = json.loads((out / "verification.json").read_text())
    for entry in report["per_leg"].values():
        assert entry["after"]["command_rms_px"] < 0.2 * entry["before"]["command_rms_px"]
    assert json.loads((out / "offsets.json").read_text())["schema"] == "naocal.offsets/2"


def _true_model_pixels(mock, leg, theta14):
    """Where the mock's true model puts `leg`'s vertices for joint readings theta14 (what a dataset row claims)."""
    truth = mock.truth_dict()
    registry = Registry()
    values = {f"joint_offset.{j}": -truth["alpha_rad"][j] for j in LEG_JOINTS}  # the parameter is c = -alpha
    values.update({f"camera.bottom.{k}": v for k, v in truth["camera_rotation_rad"]["bottom"].items()})
    for side, mount in truth["board_mount"].items():
        values.update({f"board.{side}.rot_z": mount["rot_z_rad"], f"board.{side}.trans_x": mount["trans_x_m"],
                       f"board.{side}.trans_y": mount["trans_y_m"]})
    data = make_model_data(np.asarray(theta14)[None], np.array([leg]), np.array([0]), np.array([0]))
    return Model(data, registry).residuals(registry.from_dict(values))


def test_capturing_without_waiting_out_the_image_delay_pairs_readings_with_an_older_image():
    """Images arrive 0.1 s after their exposure. Taking the newest image as soon as the joints read their target
    pairs the readings with an image of the leg still on its way: the board in the image lies tens of pixels from
    where the readings put it. Waiting for an image exposed after the robot was still leaves only the encoder
    quantisation (about a pixel at most). Measured against the mock's truth, no detection involved."""
    plan = make_plan(0, PlanSettings(stances_per_leg=3, probe=False))
    errors = {}
    for name, timing in (("naive", TimingSettings(still_window_s=0.0, reach_tolerance_rad=0.002)),
                         ("careful", TimingSettings())):
        mock = MockBackend(SEED)
        body = NaoBody()
        try:
            guard = SafetyGuard(mock.joint_limits(), CollisionChecker(body, margin_m=0.015, ground_margin_m=0.012),
                                mock.max_speeds())
            robot = Robot(mock, guard, plan.parked(), timing)
            worst = []
            for still in [st for st in plan.stills() if st.camera == "bottom"][::3]:  # seen by the bottom camera
                rest = robot.move(still.angles())
                image = robot.newest_image() if name == "naive" else robot.wait_image(rest.t_still_s + 0.025)
                _, theta = robot.read()
                seen = mock.vertex_pixels_at(mock.exposure_time(image))[still.leg]
                worst.append(np.max(np.linalg.norm(_true_model_pixels(mock, still.leg, theta) - seen, axis=1)))
            errors[name] = worst
        finally:
            body.close()
            mock.close()
    assert max(errors["careful"]) < 2.0, errors  # a 0.1 deg encoder step moves a board by up to about a pixel
    assert min(errors["naive"]) > 10.0, errors
