"""End to end on LoLA: `naocal calibrate --backend bridge` against `naocal bridge serve --driver lola`, which talks
to a fake LoLA over a Unix socket with the PyBullet mock behind it and reads the mock's rendered camera through a
V4L2-like frame source (tests/lola_fakes.py; there is no V4L2 device here, so the bridge runs with
backends.v4l2_camera.open_v4l2 replaced, and nothing else). Then the agent is killed in the middle of a motion and
the test reads what the robot was told afterwards."""

import json
import os
import selectors
import signal
import subprocess
import sys
import time

import msgpack
import numpy as np
import pytest

from naocal.backends.base import Backend, JointReading
from naocal.backends.lola_driver import CYCLE_S, LOLA_INDEX
from naocal.solver import limits
from naocal.solver.joints import JOINTS, LEG_JOINTS
from tests.lola_fakes import answer_series, read_records

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED = 3
LEASE_S, HOLD_S, RAMP_S = 3.0, 2.0, 2.0
SPEED = 0.4  # the agent's default


class TwelveMsRobot(Backend):
    """Still joints sampled every 12 ms (LoLA's cycle) on a simulated clock: nothing else."""

    def __init__(self):
        self.t = 100.0

    def read_joints(self):
        t_sample = np.floor(self.t / CYCLE_S) * CYCLE_S
        return JointReading({j: 0.1 for j in JOINTS}, t_sample)

    def sleep(self, duration_s):
        self.t += duration_s

    def now(self):
        return self.t

    def max_speeds(self):
        return limits.max_speeds()

    robot_identity = joint_names = joint_limits = command = set_stiffness = capture = intrinsics = None


def test_the_agent_sees_still_joints_sampled_every_12_ms():
    """Samples that do not divide the agent's 0.1 s still window (LoLA's 12 ms) must still make a still window."""
    from naocal.agent.robot import Robot

    robot = Robot(TwelveMsRobot(), guard=None, parked14=np.zeros(len(JOINTS)))
    still = robot.wait_still(np.full(len(JOINTS), 0.1), expected_s=0.0, t_command=100.0)
    assert still.t_reading_s - still.t_still_s == pytest.approx(0.108, abs=1e-9)  # 9 cycles: the shortest >= 0.1 s
    assert still.t_reading_s < 100.0 + 0.2


def start(argv, ready, timeout_s=120.0):
    """Start a process and wait for the line starting with `ready` on its stdout; returns (process, line)."""
    process = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    selector = selectors.DefaultSelector()
    selector.register(process.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    while True:
        if not selector.select(timeout=max(0.0, deadline - time.monotonic())):
            process.kill()
            pytest.fail(f"{argv[2:5]} did not start within {timeout_s} s")
        line = process.stdout.readline()
        if not line:
            pytest.fail(f"{argv[2:5]} exited with {process.wait()}: {process.stderr.read()[-2000:]}")
        if line.startswith(ready):
            return process, line


def stop(process, timeout_s=60.0):
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def calibrate(endpoint, out, *extra):
    return [sys.executable, "-m", "naocal", "calibrate", "--backend", "bridge", "--endpoint", endpoint, "--out",
            str(out), "--stances-per-leg", "6", "--no-probe", "--no-progress", *extra]


@pytest.mark.slow
def test_calibrating_through_lola_and_v4l2_recovers_the_mock_truth_and_a_killed_agent_leaves_a_safe_robot(tmp_path):
    from naocal.backends.mock import draw_truth

    record = tmp_path / "lola.record"
    intrinsics = tmp_path / "intrinsics.json"  # the mock's camera prior (a team passes its own)
    intrinsics.write_text(json.dumps({"width_px": 640, "height_px": 480, "fx_px": 600.0, "fy_px": 600.0,
                                      "cx_px": 320.0, "cy_px": 240.0}))
    robot, _ = start([sys.executable, "-m", "tests.lola_fakes", "robot", "--lola-socket", str(tmp_path / "robocup"),
                      "--camera-socket", str(tmp_path / "camera"), "--record", str(record), "--seed", str(SEED)],
                     "fake robot: ready")
    bridge = None
    try:
        bridge, line = start([sys.executable, "-m", "tests.lola_fakes", "bridge", "--camera-socket",
                              str(tmp_path / "camera"), "--", "bridge", "serve", "--driver", "lola", "--lola-socket",
                              str(tmp_path / "robocup"), "--bind", "tcp://127.0.0.1:0", "--intrinsics",
                              str(intrinsics), "--lease-timeout-s", str(LEASE_S), "--hold-s", str(HOLD_S),
                              "--ramp-s", str(RAMP_S), "--lola-timeout-s", "5"], "naocal bridge: serving lola")
        endpoint = line.split(" on ")[1].strip()

        # 1. A whole calibration.
        run = subprocess.run(calibrate(endpoint, tmp_path / "run"), cwd=ROOT, capture_output=True, text=True,
                             timeout=900)
        assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
        stored = json.loads((tmp_path / "run" / "offsets.json").read_text())
        truth = draw_truth(SEED)
        for joint in LEG_JOINTS:
            error_deg = np.degrees(-stored["body"]["joint_offsets_rad"][joint] - truth.alpha_rad[joint])  # c = -alpha
            assert abs(error_deg) < 0.1, (joint, error_deg)
        # Both V4L2 devices (/dev/video-bottom, /dev/video-top) served: one run calibrates both cameras.
        assert set(stored["head"]["camera_rotation_rad"]) == {"bottom", "top"}
        for name, true in truth.camera_rotations().items():
            for angle in ("roll", "pitch", "yaw"):
                error_deg = np.degrees(stored["head"]["camera_rotation_rad"][name][angle] - true[angle])
                assert abs(error_deg) < 0.1, (name, angle, error_deg)
        assert stored["robot"]["body_id"] == "P0000074A05S94700111"

        # 2. Another run, killed while a leg is moving.
        agent = subprocess.Popen(calibrate(endpoint, tmp_path / "killed"), cwd=ROOT, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
        observations = tmp_path / "killed" / "dataset" / "observations.csv"
        deadline = time.monotonic() + 300.0
        while not (observations.exists() and observations.read_text().count("\n") > 24 * 3):
            assert agent.poll() is None and time.monotonic() < deadline, "the second run did not get going"
            time.sleep(0.1)
        legs = [LOLA_INDEX[j] for j in LEG_JOINTS if j != "RHipYawPitch"]
        tail = msgpack.Unpacker(raw=False)
        previous = None
        with open(record, "rb") as file:
            while True:  # a leg joint's command changes from one cycle to the next: mid-motion
                tail.feed(file.read())
                moved = False
                for item in tail:
                    for position, _ in item.get("answers", ()):
                        position = np.array(position)
                        moved = previous is not None and np.abs(position[legs] - previous[legs]).max() > 1e-4
                        previous = position
                if moved:
                    break
                assert agent.poll() is None and time.monotonic() < deadline, "no motion seen"
                time.sleep(0.002)
        t_kill = time.monotonic()
        agent.kill()
        agent.wait()
        time.sleep(LEASE_S + HOLD_S + RAMP_S + 2.0)
    finally:
        if bridge is not None:
            stop(bridge)
        stop(robot)
    assert "violations 0" in robot.stdout.read()  # the mock's own collision check never refused a step

    records, events = read_records(record)
    t, position, stiffness = answer_series(records, t_kill)
    t = t - t_kill
    assert len(t) > (LEASE_S + HOLD_S + RAMP_S) / CYCLE_S * 0.9, "the bridge kept answering LoLA every cycle"
    steps = np.abs(np.diff(position, axis=0))
    max_step = np.array([SPEED * limits.max_speeds().get(name, 0.0) * CYCLE_S for name in
                         sorted(LOLA_INDEX, key=LOLA_INDEX.get)])
    assert np.all(steps <= max_step * (1 + 1e-5) + 1e-7), "never a jump"
    moving = t[1:][steps.max(axis=1) > 1e-7]
    assert len(moving) > 3, "killed mid-motion"
    assert moving.max() < LEASE_S, "the motion under way finishes; then the joints hold"
    stiff = stiffness.max(axis=1)
    first_drop = t[1:][np.diff(stiff) < -1e-9].min()
    assert first_drop == pytest.approx(LEASE_S + HOLD_S, abs=0.5), "held for hold_s after the lease expired"
    assert stiff[t < first_drop - 0.05].min() == pytest.approx(1.0)
    assert -np.diff(stiffness, axis=0).max() <= CYCLE_S / RAMP_S + 1e-6, "stiffness falls no faster than the ramp"
    limp_at = t[np.flatnonzero(stiff == 0.0)[0]]
    assert limp_at == pytest.approx(first_drop + RAMP_S, abs=0.2)
