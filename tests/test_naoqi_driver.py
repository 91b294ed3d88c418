"""The NAOqi driver against fake NAOqi services hosted in a real qi session on loopback."""

import math
import time

import numpy as np
import pytest

pytest.importorskip("qi", reason="the NAOqi driver's tests need qi (libqi-python, wheels for x86_64 Linux only): "
                                  "pip install '.[naoqi]'")

from naocal.backends.bridge import BridgeBackend  # noqa: E402
from naocal.backends.bridge_server import BridgeServer  # noqa: E402
from naocal.backends.naoqi_driver import FRAME_PERIOD_S, NaoqiBackend  # noqa: E402
from naocal.backends.errors import RobotFault, RobotTimeout  # noqa: E402
from naocal.solver.errors import SafetyError
from naocal.solver.errors import NaocalError  # noqa: E402
from tests.backend_contract import check_backend_contract  # noqa: E402
from tests.naoqi_fakes import DCM_EPOCH_S, FakeRobot, TextImageVideoDevice, fake_naoqi  # noqa: E402


@pytest.fixture
def naoqi():
    with fake_naoqi() as (url, robot):
        yield url, robot


def test_the_naoqi_driver_passes_the_backend_contract(naoqi):
    url, robot = naoqi
    check_backend_contract(NaoqiBackend(url), settle_s=0.3)
    assert robot.calls[0] == ("subscribeCamera", "naocal", 1, 2, 13, 30)  # bottom camera, VGA, BGR, 30 fps
    assert robot.calls[-1] == ("unsubscribe", "naocal_0")
    assert not robot.subscribers


def test_the_naoqi_driver_over_the_bridge_passes_the_backend_contract(naoqi):
    url, robot = naoqi
    driver = NaoqiBackend(url)
    server = BridgeServer(driver, "tcp://127.0.0.1:0", driver="naoqi", clock="wall").start_thread()
    try:
        check_backend_contract(BridgeBackend(server.endpoint, timeout_s=2.0), settle_s=0.3)
    finally:
        server.stop()
        driver.close()
    assert len(robot.motion_commands()) == 2


@pytest.mark.parametrize("targets, speed, problem", [
    ({"LKneePitch": 2.5}, 0.1, "LKneePitch"),
    ({"RKneePitch": -0.2}, 0.1, "RKneePitch"),
    ({"LKneePitch": math.nan}, 0.1, "LKneePitch"),
    ({"LKneePitch": math.inf}, 0.1, "LKneePitch"),
    ({"LShoulderPitch": 0.0}, 0.1, "unknown joint"),
    ({"HeadYaw": 0.1}, 0.0, "speed_fraction"),
    ({"HeadYaw": 0.1}, 1.5, "speed_fraction"),
    ({"HeadYaw": 0.1}, math.nan, "speed_fraction"),
    ({"HeadYaw": 1.5, "HeadPitch": 0.4}, 0.1, "HeadPitch-vs-HeadYaw"),  # box allows it, the table does not
    ({"HeadYaw": -2.0, "HeadPitch": -0.6}, 0.1, "HeadPitch-vs-HeadYaw"),
])
def test_unsafe_commands_raise_and_send_nothing(naoqi, targets, speed, problem):
    url, robot = naoqi
    backend = NaoqiBackend(url)
    before = len(robot.motion_commands())
    with pytest.raises(SafetyError, match=problem):
        backend.command(targets, speed)
    assert len(robot.motion_commands()) == before
    backend.close()


def test_a_head_move_is_checked_against_where_the_other_head_joint_is(naoqi):
    url, robot = naoqi
    backend = NaoqiBackend(url)
    backend.command({"HeadPitch": 0.45}, 1.0)  # fine at yaw 0 (limit 0.515)
    backend.sleep(0.4)
    with pytest.raises(SafetyError, match="HeadYaw 1.5"):
        backend.command({"HeadYaw": 1.5}, 0.1)  # would put pitch 0.45 beyond the 0.2 allowed there
    backend.command({"HeadYaw": 1.5, "HeadPitch": 0.1}, 0.5)
    assert robot.motion_commands()[-1][1:3] == (["HeadYaw", "HeadPitch"], pytest.approx([1.5, 0.1]))
    backend.close()


def test_limits_are_the_tighter_of_naoqi_and_the_model(naoqi):
    url, robot = naoqi
    robot.limits = {**robot.limits, "LAnkleRoll": (-0.2, 0.3)}  # a robot reporting narrower limits
    backend = NaoqiBackend(url)
    assert backend.joint_limits()["LAnkleRoll"] == pytest.approx((-0.2, 0.3))
    assert backend.joint_limits()["RKneePitch"][0] >= -0.103083
    with pytest.raises(SafetyError):
        backend.command({"LAnkleRoll": 0.35}, 0.1)
    backend.close()


def test_images_arrive_as_exact_bytes_with_their_exposure_on_the_dcm_clock(naoqi):
    url, robot = naoqi
    backend = NaoqiBackend(url)
    image = backend.capture()
    now_s = backend.now()
    assert image.pixels.shape == (480, 640, 3) and image.pixels.dtype == np.uint8
    assert np.array_equal(image.pixels, robot.image_pattern)
    # The fake stamps frames on the monotonic clock; the DCM clock is that plus DCM_EPOCH_S.
    age_s = now_s - image.t_exposure_s
    assert FRAME_PERIOD_S - 0.02 <= age_s <= 2 * FRAME_PERIOD_S + 0.2
    reading = backend.read_joints()
    assert abs(reading.t_s - backend.now()) < 0.05
    assert reading.t_s > DCM_EPOCH_S
    backend.close()


@pytest.mark.parametrize("image_clock", ["monotonic", "realtime", "dcm"])
def test_the_image_clock_is_detected(image_clock):
    with fake_naoqi(FakeRobot(image_clock=image_clock)) as (url, _):
        for told in ("auto", image_clock):
            backend = NaoqiBackend(url, image_clock=told)
            image = backend.capture()
            assert FRAME_PERIOD_S - 0.02 <= backend.now() - image.t_exposure_s <= 2 * FRAME_PERIOD_S + 0.2
            backend.close()


def test_image_stamps_on_an_unknown_clock_are_refused_not_guessed(naoqi, monkeypatch):
    url, robot = naoqi
    monkeypatch.setattr(robot, "image_stamp", lambda: 1000.0)
    backend = NaoqiBackend(url)
    with pytest.raises(NaocalError, match="none of the clocks"):
        backend.capture()
    backend.close()


def test_image_bytes_that_arrive_as_text_are_reported():
    with fake_naoqi(video_class=TextImageVideoDevice) as (url, _):
        backend = NaoqiBackend(url)
        with pytest.raises(NaocalError, match="as text"):
            backend.capture()
        backend.close()


@pytest.mark.parametrize("index, value, message", [
    (0, 640.5, "field 'width': expected a whole number from 1 to 65536, got 640.5"),
    (2, True, "field 'layers': expected a whole number at least 0, got True"),
    (4, -3, "field 'seconds': expected a whole number at least 0, got -3"),
])
def test_an_image_header_naoqi_sends_is_checked_before_use_naming_the_field(index, value, message):
    """getImageRemote's size, layers and stamp, as NAOqi's dynamic values may carry any type (they were int()-ed:
    640.5 became 640, True a layer)."""
    class OddHeader(TextImageVideoDevice):
        def getImageRemote(self, handle):
            header = [640, 480, 3, 13, 0, 0]
            header[index] = value
            return header + [b"pixels"]

    with fake_naoqi(video_class=OddHeader) as (url, _):
        backend = NaoqiBackend(url)
        with pytest.raises(NaocalError) as refused:
            backend.capture()
        assert "ALVideoDevice.getImageRemote, " + message in str(refused.value), str(refused.value)
        backend.close()


def test_every_naoqi_call_has_a_deadline(naoqi):
    url, robot = naoqi
    backend = NaoqiBackend(url, call_timeout_s=0.2)
    robot.block_get_angles_s = 0.5
    with pytest.raises(RobotTimeout, match="getAngles"):
        backend.read_joints()
    robot.block_get_angles_s = 0.0
    backend.close()


def test_connection_failures_are_one_line_errors():
    with pytest.raises(NaocalError, match="127.0.0.1:1"):
        NaoqiBackend("tcp://127.0.0.1:1", call_timeout_s=1.0)


def test_stiffness_is_checked_and_sent(naoqi):
    url, robot = naoqi
    backend = NaoqiBackend(url)
    backend.set_stiffness(["HeadYaw", "HeadPitch"], 0.8)
    assert robot.calls[-1] == ("setStiffnesses", ["HeadYaw", "HeadPitch"], pytest.approx([0.8, 0.8]))
    for names, value in ((["HeadYaw"], 1.5), (["HeadYaw"], math.nan), (["LElbowRoll"], 0.5)):
        with pytest.raises(SafetyError):
            backend.set_stiffness(names, value)
    assert robot.calls[-1][0] == "setStiffnesses" and len([c for c in robot.calls if c[0] == "setStiffnesses"]) == 1
    identity = backend.robot_identity()
    assert identity == {"id": "FAKEBODY0001", "model": "NAO V5", "body_id": "FAKEBODY0001", "head_id": "FAKEHEAD0001"}
    backend.close()


def test_bridge_serve_drives_naoqi_and_stops_cleanly_on_sigterm(naoqi):
    import os
    import selectors
    import signal
    import subprocess
    import sys

    from tests.bridge_fakes import CLI, ROOT

    url, robot = naoqi
    server = subprocess.Popen(
        [sys.executable, "-c", CLI, "bridge", "serve", "--driver", "naoqi", "--naoqi", url,
         "--bind", "tcp://127.0.0.1:0"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        selector = selectors.DefaultSelector()
        selector.register(server.stdout, selectors.EVENT_READ)
        line, deadline = "", time.monotonic() + 20.0
        while not line.startswith("naocal bridge: serving"):  # qi prints its own notes on stdout too
            assert selector.select(timeout=max(0.0, deadline - time.monotonic())), "server not up within 20 s"
            line = server.stdout.readline()
            assert line, f"the server exited: {server.stderr.read()}"
        assert line.startswith("naocal bridge: serving naoqi on tcp://127.0.0.1:"), line
        endpoint = line.split(" on ")[1].strip()
        bridge = BridgeBackend(endpoint, timeout_s=2.0)
        assert bridge.server_info()["driver"] == "naoqi" and bridge.server_info()["clock"] == "wall"
        assert bridge.robot_identity()["body_id"] == "FAKEBODY0001"
        bridge.command({"HeadYaw": 0.2}, 0.5)
        with pytest.raises(SafetyError):
            bridge.command({"HeadYaw": 3.0}, 0.5)
        bridge.close()
        server.send_signal(signal.SIGTERM)
        out, err = server.communicate(timeout=20)
    finally:
        if server.poll() is None:
            os.kill(server.pid, signal.SIGKILL)
            server.wait()
    assert server.returncode == 0, err
    assert "stopped" in out
    assert robot.calls[-1][0] == "unsubscribe"  # the driver was closed
    assert [call[1:3] for call in robot.motion_commands()] == [(["HeadYaw"], pytest.approx([0.2]))]


def test_a_head_joint_still_on_its_way_is_checked_at_its_target(naoqi):
    url, robot = naoqi
    backend = NaoqiBackend(url)
    backend.command({"HeadPitch": 0.45}, 0.01)  # fine at yaw 0, and slow: it reads near 0 for a while
    with pytest.raises(SafetyError, match="HeadPitch 0.45"):
        backend.command({"HeadYaw": 1.5}, 1.0)  # pitch will be 0.45 where 0.2 is the limit
    backend.close()


@pytest.mark.parametrize("kind, value", [("nan", math.nan), ("inf", math.inf), ("string", "0.5"), ("bool", True),
                                         ("out-of-limit", 2.5), ("huge", 1e30)])
def test_a_reading_naoqi_cannot_be_trusted_is_a_fault_never_served_and_motion_stops(naoqi, kind, value):
    """As for LoLA (tests/test_lola_driver.py): refused at once, reported by status, every motion call refused."""
    url, robot = naoqi
    backend = NaoqiBackend(url)
    try:
        backend.set_stiffness(["HeadYaw"], 1.0)
        with robot.lock:
            robot.sensor_override["LKneePitch"] = value
        with pytest.raises(RobotFault, match="LKneePitch"):
            backend.read_joints()
        assert "LKneePitch" in backend.status()["robot"]["fault"]
        with robot.lock:
            robot.sensor_override.clear()  # even if it reads well again: restart the bridge once the robot is checked
        sent = len(robot.calls)
        for motion in (lambda: backend.command({"HeadYaw": 0.1}, 0.1), lambda: backend.set_stiffness(["HeadYaw"], 1.0),
                       lambda: backend.sleep(0.01), backend.read_joints):
            with pytest.raises(RobotFault):
                motion()
        assert len(robot.calls) == sent  # nothing reached NAOqi
    finally:
        backend.close()


@pytest.mark.parametrize("value", ["12:03:04", math.nan, -5, True, None])
def test_a_dcm_time_that_is_no_time_refuses_the_connection_in_one_line(value):
    """DCM/Time is read at connect to put images and readings on the robot's clock: a string, NaN, a negative or a
    bool is refused naming DCM/Time (it was float()-ed: a traceback or a clock in the wrong place)."""
    robot = FakeRobot()
    robot.memory_override["DCM/Time"] = value
    with fake_naoqi(robot) as (url, _):
        with pytest.raises(NaocalError, match="DCM/Time"):
            NaoqiBackend(url)
