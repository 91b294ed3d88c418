"""The Duckiebot through naocal's bridge (kinds/duckiebot/bridge.py, docs/PROTOCOL.md "Duckiebot commands"): the same
server, protocol and lease as the NAO's, the mock served behind it on ipc://, the mission's client in front."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from bridge_fakes import FakeBackend, RawClient, serving
from duckiebot_ros_peer import check_resumed_again
from naocal.agent.machine import DONE
from naocal.backends import protocol
from naocal.backends.bridge import BridgeBackend
from naocal.backends.errors import BridgeError, RobotFault
from naocal.kinds.duckiebot.bridge import DuckiebotBridge, ServedDuckiebot
from naocal.kinds.duckiebot.drive_log import read_drive_log
from naocal.kinds.duckiebot.mission import Boards, MissionSettings, run_mission
from naocal.kinds.duckiebot.mock import DuckiebotMock
from naocal.solver.errors import SafetyError

ROOT = Path(__file__).resolve().parents[1]
SHORT = MissionSettings(board_passes=2, legs=(2, 3), wiggles=1)
BOARDS_ONLY = {("boards", "ok"): DONE}


def ipc(tmp_path) -> str:
    return f"ipc://{tmp_path}/duckiebot.sock"


@pytest.fixture
def mock():
    robot = DuckiebotMock(4, "ideal", supersample=1)
    yield robot
    robot.close()


@pytest.fixture
def served(mock):
    robot = ServedDuckiebot(mock, robot_id="mock4", watchdog_s=0.3)
    yield robot
    robot.close()


def test_the_boards_phase_over_the_bridge_drives_the_mock_as_a_direct_run_does(tmp_path):
    direct = DuckiebotMock(4, "ideal", supersample=1)
    try:
        run_mission(direct, tmp_path / "direct", SHORT, transitions=BOARDS_ONLY, states=(Boards,))
    finally:
        direct.close()
    mock = DuckiebotMock(4, "ideal", supersample=1)
    served = ServedDuckiebot(mock, robot_id="mock4")
    try:
        with serving(served, ipc(tmp_path), driver="mock") as server:
            robot = DuckiebotBridge(server.endpoint)
            try:
                result, ctx = run_mission(robot, tmp_path / "bridged", SHORT, robot_id=robot.robot_id,
                                          transitions=BOARDS_ONLY, states=(Boards,))
            finally:
                robot.close()
        assert result.final == DONE, result.reason
        assert ctx.session.log.frames and mock.duties.tolist() == [0.0, 0.0]
        # the robot received the same duties at the same times as without the bridge; then only stops (the client's
        # close, the server's end of control)
        n = len(direct.received)
        assert mock.received[:n] == direct.received and all(tuple(d) == (0.0, 0.0) for _, *d in mock.received[n:])
        bridged, alone = read_drive_log(tmp_path / "bridged" / "log"), read_drive_log(tmp_path / "direct" / "log")
        assert np.array_equal(bridged.wheel_t_s, alone.wheel_t_s) and np.array_equal(bridged.frame_t_s, alone.frame_t_s)
        assert bridged.robot_id == "mock4" and bridged.frame_files == alone.frame_files
        last = len(alone.frame_files) - 1  # PNG over the wire: the mission saw exactly what the robot saw
        assert np.array_equal(bridged.load_frame(last), alone.load_frame(last))
    finally:
        served.close()


def test_a_bad_duty_is_refused_on_the_server_before_the_robot(tmp_path, served, mock):
    with serving(served, ipc(tmp_path)) as server:
        raw = RawClient(server.endpoint)
        token = raw.request("raw:1", "acquire", {"nonce": "n" * 22})["result"]["token"]
        for seq, (left, right) in enumerate([(math.nan, 0.0), (0.2, 1.5), (-math.inf, 0.0), (1.0000001, 0.0)], 2):
            reply = raw.request(f"raw:{seq}", "wheels", {"left_duty": left, "right_duty": right}, token=token)
            assert reply["ok"] is False and reply["error"]["type"] == "SafetyError", reply
        assert mock.received == []  # the driver never heard them
        reply = raw.request("raw:9", "wheels", {"left_duty": "0.5", "right_duty": 0.0}, token=token)
        assert reply["error"]["type"] == "ProtocolError"
        assert raw.request("raw:10", "release", token=token)["ok"] is True
        raw.close()
        client = DuckiebotBridge(server.endpoint)
        with pytest.raises(SafetyError, match="right duty 2.0"):
            client.command(0.1, 2.0)
        assert all((l, r) == (0.0, 0.0) for _, l, r in mock.received)  # only the stop of the raw client's release
        client.close()


def test_without_the_lease_nothing_moves_and_reads_still_work(tmp_path, served, mock):
    with serving(served, ipc(tmp_path)) as server:
        controller = DuckiebotBridge(server.endpoint)
        controller.command(0.2, 0.2)
        stranger = RawClient(server.endpoint)
        for seq, (cmd, args) in enumerate([("wheels", {"left_duty": 0.9, "right_duty": -0.9}),
                                           ("grab", {}), ("sleep", {"duration_s": 1.0})], 1):
            reply = stranger.request(f"s:{seq}", cmd, args, token="t" * 22)
            assert reply["error"]["type"] == "ControlError", reply
        assert stranger.request("s:9", "now")["ok"] is True
        assert [(l, r) for _, l, r in mock.received] == [(0.2, 0.2)] and mock.t_s == 0.0
        stranger.close()
        controller.close()


def test_any_client_stops_the_wheels_without_the_lease_and_the_controller_is_told_once(tmp_path, served, mock,
                                                                                      capsys):
    """The emergency stop: a second client, which never asked for the lease, stops the wheels the controller set
    turning; it moves nothing else, takes no control, and the controller hears of it at its next motion request."""
    from naocal.tools import cli

    with serving(served, ipc(tmp_path)) as server:
        controller = DuckiebotBridge(server.endpoint)
        controller.command(0.3, 0.3)
        observer = DuckiebotBridge(server.endpoint)
        assert observer.stop()["t_s"] >= 0.0 and mock.duties.tolist() == [0.0, 0.0]
        assert observer._token is None and observer.server_info()["controlled"] is True  # no control taken
        with pytest.raises(BridgeError, match="another client controls the robot"):
            observer.command(0.2, 0.2)  # stopping gives no right to drive
        with pytest.raises(RobotFault, match="another client stopped the robot.*wheels not executed"):
            controller.command(0.4, 0.4)
        assert mock.duties.tolist() == [0.0, 0.0]
        controller.command(0.4, 0.4)  # told once: it may drive again
        assert mock.duties.tolist() == [0.4, 0.4]
        # the command line's stop, from a third client
        assert cli.main(["bridge", "stop", "--endpoint", server.endpoint]) == 0
        assert "stopped the duckiebot mock4" in capsys.readouterr().out and mock.duties.tolist() == [0.0, 0.0]
        with pytest.raises(RobotFault, match="another client stopped the robot"):
            controller.advance(0.1)
        observer.stop()  # a stop of a standing robot: duties 0 again, nothing else; the controller is told all the same
        controller.command(0.0, 0.0)  # its own stop is never refused (nor does it use up the notice)
        with pytest.raises(RobotFault, match="another client stopped the robot"):
            controller.command(0.1, 0.1)
        controller.command(0.1, 0.1)
        assert {tuple(d) for _, *d in mock.received} == {(0.0, 0.0), (0.3, 0.3), (0.4, 0.4), (0.1, 0.1)}
        observer.close()
        controller.close()


def test_a_dead_client_has_its_wheels_stopped_within_the_watchdog(tmp_path, served, mock):
    """A client process killed (SIGKILL: no stop, no release) while the wheels turn."""
    with serving(served, ipc(tmp_path)) as server:
        script = textwrap.dedent(f"""
            import sys, time
            sys.path.insert(0, {str(ROOT.parent)!r})
            sys.path.insert(0, {str(ROOT)!r})
            from naocal.kinds.duckiebot.bridge import DuckiebotBridge
            robot = DuckiebotBridge({server.endpoint!r})
            robot.command(0.5, 0.4)
            print("driving", flush=True)
            time.sleep(60)
        """)
        child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
        try:
            assert child.stdout.readline().strip() == "driving"
            assert mock.duties.tolist() == [0.5, 0.4]
            child.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            while mock.duties.tolist() != [0.0, 0.0] and time.monotonic() - killed < 5.0:
                time.sleep(0.01)
            stopped_after_s = time.monotonic() - killed
        finally:
            child.kill()
            child.wait()
        assert mock.duties.tolist() == [0.0, 0.0] and stopped_after_s < 0.3 + 0.5, stopped_after_s
        # a controller silent too long (hung, not dead) is told once that the server stopped its wheels
        hung = DuckiebotBridge(server.endpoint)
        with pytest.raises(BridgeError, match="acquire: another client controls the robot"):
            hung.command(0.3, 0.3)  # the dead client's lease has not lapsed (120 s): nobody else drives
    with serving(served, ipc(tmp_path)) as server:
        hung = DuckiebotBridge(server.endpoint)
        hung.command(0.3, 0.3)
        time.sleep(0.6)
        assert mock.duties.tolist() == [0.0, 0.0]
        with pytest.raises(RobotFault, match="no request from the controlling client for 0.[3-6]"):
            hung.advance(0.1)
        hung.command(0.2, 0.2)  # told once: it may drive again
        assert mock.duties.tolist() == [0.2, 0.2]
        hung.close()
        assert mock.duties.tolist() == [0.0, 0.0]


def test_the_lease_lapsing_and_the_shutdown_stop_the_wheels(tmp_path, mock):
    served = ServedDuckiebot(mock, robot_id="mock4", watchdog_s=10.0)  # the lease's deadline comes first here
    try:
        with serving(served, ipc(tmp_path), lease_timeout_s=0.3) as server:
            client = DuckiebotBridge(server.endpoint)
            client.command(0.3, -0.3)
            deadline = time.monotonic() + 3.0
            while mock.duties.tolist() != [0.0, 0.0] and time.monotonic() < deadline:
                time.sleep(0.02)
            assert mock.duties.tolist() == [0.0, 0.0]
            with pytest.raises(RobotFault, match="control ended"):
                client.command(0.25, 0.25)  # its holder comes back: told once
            time.sleep(0.4)  # its lease lapses again
            newcomer = DuckiebotBridge(server.endpoint)
            newcomer.command(0.25, 0.25)  # the lapsed lease passes on; the stop was not the newcomer's to hear of
            assert mock.duties.tolist() == [0.25, 0.25]
            newcomer._drop_socket()  # gone without a word
        served.close()  # what `naocal bridge serve` does on SIGINT / SIGTERM
        assert mock.duties.tolist() == [0.0, 0.0]
    finally:
        served.close()


class BadFrames:
    """The mock, but its camera returns a frame of the wrong size; encoders that count, then jump back in time."""

    ticks_per_revolution = 135

    def __init__(self, robot):
        self.robot, self.rows = robot, [(0.1, 0, 0), (0.2, 3, 4), (0.3, 6, 8)]

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def grab(self):
        t, image = self.robot.grab()
        return t, image[:, :320]

    def encoder_ticks(self, t_from_s, t_to_s):
        return [r for r in self.rows if t_from_s <= r[0] <= t_to_s]


def test_frames_and_encoder_rows_are_checked_before_they_are_echoed(tmp_path, mock):
    served = ServedDuckiebot(BadFrames(mock), robot_id="mock4")
    try:
        with serving(served, ipc(tmp_path)) as server:
            client = DuckiebotBridge(server.endpoint)
            assert client.facts()["ticks_per_revolution"] == 135
            assert client.encoder_ticks(0.0, 0.25) == [[0.1, 0, 0], [0.2, 3, 4]]
            client.command(0.2, 0.2)
            with pytest.raises(RobotFault, match="shape \\(480, 320\\).*the wheels were stopped"):
                client.grab()
            assert mock.duties.tolist() == [0.0, 0.0]
            served.driver.rows.append((0.25, 9, 9))  # back in time
            with pytest.raises(RobotFault, match="row 4: t_s 0.25 is not after"):
                client.encoder_ticks(0.0, 1.0)
            client.close()
    finally:
        served.close()


def test_encoder_rows_that_jump_are_not_written_into_the_drive_log(tmp_path, mock):
    """The laptop writes the robot's ticks into LOG/encoders.csv (save_encoders): with the reader's jump check
    (drive_log.impossible_tick_step), so a log it writes is one the reader takes; the line is named, nothing written."""
    from naocal.kinds.duckiebot.drive_log import DriveLogAppender
    from naocal.kinds.duckiebot.mission import log_meta
    from naocal.solver.errors import DataError

    bad = BadFrames(mock)
    bad.rows = [(0.1, 0, 0), (0.2, 3, 4), (0.3, 6, 8), (0.4, 6 + 900, 12)]  # 900 ticks in 0.1 s: 195 at most
    served = ServedDuckiebot(bad, robot_id="mock4")
    DriveLogAppender(tmp_path / "log", log_meta("mock4", "a test"))
    try:
        with serving(served, ipc(tmp_path)) as server:
            client = DuckiebotBridge(server.endpoint)
            with pytest.raises(DataError, match=r"encoders.csv, line 5, field 'left_ticks': \+900 ticks since the "
                                                r"previous row .*more than the wheel can turn"):
                client.save_encoders(tmp_path / "log", 0.0, 1.0)
            assert not (tmp_path / "log" / "encoders.csv").exists()
            assert client.save_encoders(tmp_path / "log", 0.0, 0.35) == 3
            client.close()
    finally:
        served.close()


def test_kinds_are_told_apart_and_the_nao_client_is_unchanged(tmp_path, served):
    with serving(served, ipc(tmp_path)) as server:
        hello = BridgeBackend(server.endpoint).server_info  # a NAO client meets a Duckiebot server
        with pytest.raises(BridgeError, match="serves a duckiebot, not a nao"):
            hello()
        raw = RawClient(server.endpoint)
        reply = raw.request("old:1", "read_joints")  # a revision-1 request: framing unchanged, command not this kind's
        assert reply["v"] == 1 and reply["error"]["type"] == "UnknownCommand"
        assert "a nao command, and this server serves a duckiebot" in reply["error"]["message"]
        raw.close()
    with serving(FakeBackend(), ipc(tmp_path)) as server:
        with pytest.raises(BridgeError, match="serves a nao, not a duckiebot"):
            DuckiebotBridge(server.endpoint).now()
        raw = RawClient(server.endpoint)
        hello = raw.request("old:1", "hello")["result"]
        assert hello["protocol"] == 1 and hello["kind"] == "nao" and hello["revision"] == protocol.PROTOCOL_REVISION
        assert raw.request("old:2", "wheels", {"left_duty": 0.1, "right_duty": 0.1})["error"]["type"] == \
            "UnknownCommand"
        raw.close()


def test_calibrate_over_the_bridge_needs_an_endpoint_one_line_exit_2(tmp_path):
    run = subprocess.run([sys.executable, "-m", "naocal", "calibrate", "--robot", "duckiebot", "--backend", "bridge",
                          "--out", str(tmp_path / "run")], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 2 and "--backend bridge needs --endpoint URL" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


@pytest.fixture
def ros_served(monkeypatch):
    """RosDuckiebot over Duckietown's topics (the fake peer of tests/duckiebot_ros_peer.py), ready to be served:
    (the fake ROS graph, the served robot); both closed after the test."""
    sys.path.insert(0, str(ROOT / "tests"))
    from duckiebot_ros_peer import FakeRosGraph
    from naocal.kinds.duckiebot.ros_driver import RosDuckiebot

    graph = FakeRosGraph("db21", seed=4).install(monkeypatch)
    served = ServedDuckiebot(RosDuckiebot("db21", watchdog_s=30.0), robot_id="db21", watchdog_s=10.0)
    try:
        yield graph, served
    finally:
        served.close()
        graph.close()


def test_the_ros_driver_served_against_a_fake_ros_peer(tmp_path, ros_served):
    """`naocal bridge serve --robot duckiebot --driver ros` as on a DB21: RosDuckiebot over Duckietown's topics (the
    fake peer of tests/duckiebot_ros_peer.py) behind the server; the client drives, grabs and reads the encoders."""
    graph, served = ros_served
    with serving(served, ipc(tmp_path), driver="ros", clock="wall") as server:
        client = DuckiebotBridge(server.endpoint)
        assert client.facts()["ticks_per_revolution"] == 135 and client.robot_id == "db21"
        t_start = client.command(0.4, 0.4)
        client.advance(1.5)
        client.command(0.0, 0.0)
        t, image = client.grab()
        assert t > t_start and image.shape == (480, 640) and image.dtype == np.uint8
        rows = client.encoder_ticks(t_start, t)
        assert len(rows) > 20 and rows[-1][1] - rows[0][1] > 50  # 1.5 s at about 0.4 x 27 rad/s
        assert rows == [[r[0], r[1], r[2]] for r in served.driver.encoder_ticks(t_start, t)]
        client.close()
    assert graph.received[-1][1:] == (0.0, 0.0) and graph.refused == []


@pytest.mark.parametrize("damage, message", [
    (lambda msg: setattr(msg, "data", b"\xff\xd8 not a jpeg"), "does not decode as an image \\(13 bytes\\)"),
    (lambda msg: setattr(msg, "data", bytes(cv2.imencode(".jpg", np.zeros((240, 320), np.uint8))[1])),
     "is 320 x 240, expected 640 x 480"),
])
def test_a_bad_camera_frame_from_ros_is_never_echoed_the_client_hears_why_and_the_server_goes_on(
        tmp_path, ros_served, damage, message):
    """The camera node's JPEG is decoded and its size checked on the robot before anything of it crosses the bridge:
    a frame that fails is answered with one error naming the topic, the wheels stopped, the server still serving."""
    graph, served = ros_served
    with serving(served, ipc(tmp_path), driver="ros", clock="wall") as server:
        client = DuckiebotBridge(server.endpoint)
        client.command(0.2, 0.2)

        def damaged(msg):
            damage(msg)
            return msg

        graph.frame_hook = damaged
        with pytest.raises(BridgeError, match=f"/db21/camera_node/image/compressed: the frame stamped .* {message}"
                                              ".*the wheels were stopped") as refused:
            client.grab()
        assert "\n" not in str(refused.value) and graph.robot.duties.tolist() == [0.0, 0.0]
        assert client.now() > 0.0  # the server goes on
        client.close()


def test_with_curve_clients_an_unknown_key_moves_nothing_and_an_admitted_one_drives(tmp_path, served, mock):
    from naocal.backends.bridge_server import write_curve_keys

    server_public, server_secret = write_curve_keys(tmp_path / "server", "server")
    write_curve_keys(tmp_path / "clients", "laptop")
    _, stranger_secret = write_curve_keys(tmp_path / "others", "stranger")
    with serving(served, ipc(tmp_path), curve_secret_key_file=server_secret,
                 curve_clients_dir=tmp_path / "clients") as server:
        for kwargs in ({}, {"curve_server_key": server_public, "curve_client_key": stranger_secret}):
            stranger = DuckiebotBridge(server.endpoint, timeout_s=1.0, retries=0, **kwargs)
            for attempt in (lambda: stranger.command(0.5, 0.5), stranger.stop):
                with pytest.raises(BridgeError, match="requires CURVE keys|does not admit this client"):
                    attempt()
            stranger.close()
        assert mock.received == []
        laptop = DuckiebotBridge(server.endpoint, curve_server_key=server_public,
                                 curve_client_key=tmp_path / "clients" / "laptop.key_secret")
        laptop.command(0.5, 0.5)
        assert mock.duties.tolist() == [0.5, 0.5]
        stranger = DuckiebotBridge(server.endpoint, timeout_s=1.0, retries=0, curve_server_key=server_public,
                                   curve_client_key=stranger_secret)
        with pytest.raises(BridgeError, match="does not admit this client"):
            stranger.stop()  # the stop needs no lease, but CURVE's credentials still
        stranger.close()
        assert mock.duties.tolist() == [0.5, 0.5]
        observer = DuckiebotBridge(server.endpoint, curve_server_key=server_public,
                                   curve_client_key=tmp_path / "clients" / "laptop.key_secret")
        observer.stop()  # an admitted key without the lease
        assert mock.duties.tolist() == [0.0, 0.0]
        observer.close()
        laptop.close()
        assert mock.duties.tolist() == [0.0, 0.0]


@pytest.mark.parametrize("argv, message", [
    (["--robot", "duckiebot", "--driver", "naoqi"], "--driver naoqi drives a NAO"),
    (["--driver", "ros"], "--driver ros and --watchdog-s are for --robot duckiebot"),
    (["--robot", "duckiebot", "--driver", "mock", "--watchdog-s", "0"], "--watchdog-s must be within"),
])
def test_bridge_serve_bad_robot_options_are_one_line_exit_2(argv, message, capsys):
    from naocal.tools import cli

    code = cli.main(["bridge", "serve", *argv])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message in err, err


SERVE_RECORDING = textwrap.dedent("""
    import os, sys
    sys.path.insert(0, {parent!r})
    sys.path.insert(0, {root!r})
    from naocal.backends.bridge_server import BridgeServer
    from naocal.kinds.duckiebot.mock import DuckiebotMock
    from naocal.tools import cli

    duties_file, crash_file = sys.argv[1], sys.argv[2]
    command = DuckiebotMock.command

    def recorded(self, left, right):  # every duty the mock's wheels received, as they received it
        t = command(self, left, right)
        with open(duties_file, "a") as file:
            file.write(f"{{left}} {{right}}\\n")
        return t

    DuckiebotMock.command = recorded
    expire = BridgeServer._expire_idle_lease

    def crash_on_request(self):  # the serving loop ends on an exception when the test asks
        if os.path.exists(crash_file):
            raise RuntimeError("a bug in the serving loop")
        return expire(self)

    BridgeServer._expire_idle_lease = crash_on_request
    sys.exit(cli.main(["bridge", "serve", "--robot", "duckiebot", "--driver", "mock", "--mock", "ideal", "--seed",
                       "4", "--watchdog-s", "10", "--bind", "tcp://127.0.0.1:0"]))
""")


@pytest.mark.parametrize("ending", ["SIGTERM", "SIGINT", "SIGHUP", "exception"])
def test_every_end_of_bridge_serve_leaves_the_wheels_stopped(tmp_path, ending):
    """`naocal bridge serve --robot duckiebot` in its own process, the wheels turning (the watchdog far off), ended by a
    signal or by an exception in its loop: the last duties its driver received are 0, 0."""
    duties, crash = tmp_path / "duties.txt", tmp_path / "crash"
    script = SERVE_RECORDING.format(parent=str(ROOT.parent), root=str(ROOT))
    server = subprocess.Popen([sys.executable, "-c", script, str(duties), str(crash)], cwd=ROOT, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        line = server.stdout.readline()
        assert " on tcp://" in line, (line, server.stderr.read() if server.poll() is not None else "")
        client = DuckiebotBridge(line.split(" on ")[1].strip(), timeout_s=5.0, retries=0)
        client.command(0.3, 0.25)
        client._drop_socket()  # the client is gone without a word: only the server can stop the wheels now
        assert duties.read_text().splitlines()[-1] == "0.3 0.25"
        if ending == "exception":
            crash.touch()
        else:
            server.send_signal(getattr(signal, ending))
        code = server.wait(timeout=20)
    finally:
        server.kill()
        server.wait()
    stderr = server.stderr.read()
    assert duties.read_text().splitlines()[-1] == "0.0 0.0", (duties.read_text(), stderr)
    if ending == "exception":
        assert code != 0 and "a bug in the serving loop" in stderr
    else:
        assert code == 0 and "Traceback" not in stderr and "naocal bridge: stopped" in server.stdout.read(), stderr


@pytest.mark.parametrize("ending", ["the server SIGKILLed", "the wrapper SIGTERMed"])
def test_the_deploy_wrapper_publishes_zero_duties_however_the_server_ended(tmp_path, ending):
    """docs/DEPLOY.md's wrapper around `naocal bridge serve --robot duckiebot`, run as written with stand-ins for naocal
    (a server that stops on SIGTERM) and rostopic (records what it would publish)."""
    import re

    wrapper = re.search(r"```\n(#!/bin/sh\n# /data/naocal/serve-duckiebot.*?)```", (ROOT / "docs" / "DEPLOY.md")
                        .read_text(), re.S).group(1)
    (tmp_path / "serve").write_text(wrapper)
    bin_dir, calls = tmp_path / "bin", tmp_path / "calls"
    bin_dir.mkdir()
    (bin_dir / "naocal").write_text(f"#!/bin/sh\necho \"naocal $*\" >> {calls}\necho $$ > {tmp_path}/pid\n"
                                    f"trap 'echo stopped >> {calls}; exit 0' TERM\nwhile true; do sleep 0.02; done\n")
    (bin_dir / "rostopic").write_text(f"#!/bin/sh\necho \"rostopic $*\" >> {calls}\n")
    for stand_in in bin_dir.iterdir():
        stand_in.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "VEHICLE_NAME": "db21"}
    wrapper_process = subprocess.Popen(["sh", str(tmp_path / "serve"), "--bind", "tcp://127.0.0.1:7790"], env=env)
    try:
        deadline = time.monotonic() + 10.0
        while not (tmp_path / "pid").exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.1)  # the server's trap is set
        if ending == "the server SIGKILLed":
            os.kill(int((tmp_path / "pid").read_text()), signal.SIGKILL)
        else:
            wrapper_process.send_signal(signal.SIGTERM)
        assert wrapper_process.wait(timeout=10) == 0
    finally:
        wrapper_process.kill()
    lines = calls.read_text().splitlines()
    assert lines[0] == "naocal bridge serve --robot duckiebot --driver ros --bind tcp://127.0.0.1:7790"
    assert lines[-1] == ("rostopic pub -1 /db21/wheels_driver_node/wheels_cmd duckietown_msgs/WheelsCmdStamped "
                         "{header: auto, vel_left: 0.0, vel_right: 0.0}")
    assert ("stopped" in lines) == (ending == "the wrapper SIGTERMed")  # a signal reaches the server: its own stop


# --------------------------------------------------------------------------------- --resume over the bridge

class Killed(BaseException):
    """The laptop's process dies (SIGKILL, a flat battery): from now on it sends nothing, not even a stop."""


def killed_mid_turn(monkeypatch, argv, steps: int = 4) -> None:
    """`naocal calibrate argv` (the boards phase) killed once its `steps`-th one-wheel step's duties are in force
    (counting those sent to the robot: stops go as "stop", a resume's replay sends nothing)."""
    from naocal.tools.cli import main

    call, dead, turns = DuckiebotBridge._call, [], []

    def dies_mid_turn(self, cmd, args=None, **kw):
        if dead:
            raise Killed()
        result = call(self, cmd, args, **kw)
        if cmd == "wheels" and len(turns) < steps:
            turns.append(args)
            dead.extend([True] * (len(turns) == steps))
        return result

    monkeypatch.setattr(DuckiebotBridge, "_call", dies_mid_turn)
    with pytest.raises(Killed):
        main(argv)
    monkeypatch.setattr(DuckiebotBridge, "_call", call)


def boards_only(monkeypatch, board_passes=2) -> None:
    import naocal.kinds.duckiebot.mission as mission

    whole = mission.run_mission
    monkeypatch.setattr(mission, "run_mission", lambda robot_, out_, settings, **kw: whole(
        robot_, out_, MissionSettings(board_passes=board_passes), **kw, states=(Boards,), transitions=BOARDS_ONLY))


@pytest.mark.parametrize("driver, server_restarts", [("mock", False), ("ros", False), ("ros", True)])
def test_a_run_killed_mid_phase_resumes_over_the_bridge(tmp_path, monkeypatch, capsys, driver, server_restarts):
    """`calibrate --backend bridge` killed mid-turn (the wheels left turning until the server's watchdog; the lease
    still held), the robot left where it stopped, then `--resume` (the server restarted meanwhile, or not):
    the wheels are stopped before anything else reaches the robot, the lease taken back, the replay rebuilds the run,
    the phase starts again after one break in the log, the captures are kept, the run ends done."""
    from naocal.tools.cli import main

    if driver == "ros":
        sys.path.insert(0, str(ROOT / "tests"))
        from duckiebot_ros_peer import FakeRosGraph
        from naocal.kinds.duckiebot.ros_driver import RosDuckiebot

        graph = FakeRosGraph("db21", seed=4).install(monkeypatch)
        robot, clock = graph.robot, "wall"

        def new_served():
            return ServedDuckiebot(RosDuckiebot("db21", watchdog_s=30.0), robot_id="db21", watchdog_s=0.3)
    else:
        robot, clock = DuckiebotMock(4, "ideal", supersample=1), "simulated"

        def new_served():
            return ServedDuckiebot(robot, robot_id="mock4", watchdog_s=0.3)
    boards_only(monkeypatch)
    out = tmp_path / "run"
    served = new_served()
    servers = [served]
    try:
        server = serving(served, ipc(tmp_path), driver=driver, clock=clock)
        endpoint = server.__enter__().endpoint
        argv = ["calibrate", "--robot", "duckiebot", "--backend", "bridge", "--endpoint", endpoint, "--out", str(out)]
        killed_mid_turn(monkeypatch, argv)
        assert (out / "bridge.token").stat().st_mode & 0o777 == 0o600  # the lease's secret, kept for the resume
        deadline = time.monotonic() + 5.0
        while robot.duties.any() and time.monotonic() < deadline:  # the server's watchdog stops them
            time.sleep(0.02)
        assert not robot.duties.any()
        log = read_drive_log(out / "log")
        assert log.left_duty.any() and len(log.frame_files) >= 3 and not (out / "mission.json").exists()
        frames = {name: (out / "log" / name).read_bytes() for name in log.frame_files}
        if server_restarts:  # the bridge died (its wheels stopped with it) and came back: a new lease, same clock
            server.__exit__(None, None, None)
            served.close()
            served = new_served()
            servers.append(served)
            server = serving(served, ipc(tmp_path), driver=driver, clock=clock)
            server.__enter__()

        # the robot left where it stopped: the boards phase goes on from where the replay says it turned to
        reached = []  # every command that reached the robot's end of the server, in order
        dispatch = served.dispatch
        monkeypatch.setattr(served, "dispatch", lambda cmd, args: reached.append(cmd) or dispatch(cmd, args))
        capsys.readouterr()
        assert main(argv + ["--resume"]) == 0, capsys.readouterr().err
        moving = [i for i, cmd in enumerate(reached) if cmd in ("wheels", "sleep", "grab")]
        assert "stop" in reached[:moving[0]] and reached.index("wheels") > reached.index("sleep")  # stopped, settled
        resumed = read_drive_log(out / "log")
        assert len(resumed.segment_t_s) == 1 and resumed.segment_t_s[0] > max(log.wheel_t_s[-1], log.frame_t_s[-1])
        at_break = np.searchsorted(resumed.wheel_t_s, resumed.segment_t_s[0])
        assert (resumed.left_duty[at_break], resumed.right_duty[at_break]) == (0.0, 0.0)
        assert resumed.frame_files[:len(log.frame_files)] == log.frame_files
        assert all((out / "log" / name).read_bytes() == data for name, data in frames.items())  # kept, not redone
        assert np.sum(resumed.frame_t_s > resumed.segment_t_s[0]) >= 3 and (out / "mission.json").exists()
        assert not robot.duties.any() and not (out / "bridge.token").exists()  # stopped, the lease released
        server.__exit__(None, None, None)
    finally:
        for each in servers:
            each.close()
        if driver == "ros":
            graph.close()
        else:
            robot.close()


def test_a_run_killed_again_in_the_phase_its_resume_started_again_resumes_again_over_the_bridge(
        tmp_path, monkeypatch, capsys, mock):
    """`calibrate --backend bridge` killed mid-turn, resumed, killed again mid-turn inside the phase that resume
    started again (the wheels left to the server's watchdog each time), resumed again: the replay starts the phase
    again at the log's break as the first resume did (it refused the run as recorded with other options), nothing
    but stops reaches the robot before the second break, every capture kept byte for byte, two breaks, done."""
    from naocal.tools.cli import main

    boards_only(monkeypatch)
    out = tmp_path / "run"
    served = ServedDuckiebot(mock, robot_id="mock4", watchdog_s=0.3)
    try:
        with serving(served, ipc(tmp_path), driver="mock", clock="simulated") as server:
            argv = ["calibrate", "--robot", "duckiebot", "--backend", "bridge", "--endpoint", server.endpoint,
                    "--out", str(out)]

            def killed_and_stopped(argv, steps):
                killed_mid_turn(monkeypatch, argv, steps)
                deadline = time.monotonic() + 5.0
                while mock.duties.any() and time.monotonic() < deadline:  # the server's watchdog stops them
                    time.sleep(0.02)
                assert not mock.duties.any()

            killed_and_stopped(argv, 4)
            killed_and_stopped(argv + ["--resume"], 2)
            log = read_drive_log(out / "log")
            (t_first,) = log.segment_t_s
            assert np.sum(log.frame_t_s > t_first) >= 1 and np.any((log.left_duty != 0) | (log.right_duty != 0), where=log.wheel_t_s > t_first)
            frames = {name: (out / "log" / name).read_bytes() for name in log.frame_files}
            sent = len(mock.received)
            capsys.readouterr()
            assert main(argv + ["--resume"]) == 0, capsys.readouterr().err
        check_resumed_again(out / "log", log, frames, mock.received[sent:])
        assert (out / "mission.json").exists()
        assert not mock.duties.any() and not (out / "bridge.token").exists()
    finally:
        served.close()


class Outlives:
    """The robot outlives its server (a real one does): closing the server leaves it there."""

    def __init__(self, robot):
        self.robot = robot

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def close(self):
        pass


def test_a_server_that_restarted_under_a_run_ends_it_even_when_the_robot_keeps_its_state(tmp_path, mock):
    """The server stops the wheels when it ends: a client that reconnects to a new server (its `state_persists`, as
    the ROS driver's) must not go on as if the duties it set were still in force (its log would not be what
    happened); it ends with one line saying --resume continues, nothing executed."""
    served = ServedDuckiebot(Outlives(mock), robot_id="mock4", watchdog_s=10.0)
    try:
        with serving(served, ipc(tmp_path), state_persists=True) as server:
            client = DuckiebotBridge(server.endpoint, timeout_s=0.5, retries=2)
            client.command(0.2, 0.2)
        served.close()  # what `naocal bridge serve` does on SIGTERM: the wheels stopped
        assert not mock.duties.any()
        served = ServedDuckiebot(Outlives(mock), robot_id="mock4", watchdog_s=10.0)
        t_s = mock.t_s
        with serving(served, ipc(tmp_path), state_persists=True):
            with pytest.raises(BridgeError, match="server restarted during 'sleep'.*continue it with --resume"):
                client.advance(0.2)
            assert not mock.duties.any() and mock.t_s == t_s  # nothing executed
            client.close()
    finally:
        served.close()


def test_a_resume_on_a_mock_server_whose_clock_restarted_moves_nothing_and_says_why(tmp_path, monkeypatch, capsys):
    """`--driver mock` restarted: a new simulated world whose clock starts again at 0, before the run's log. The
    resumed run stops the wheels, reads the clock back and ends there (exit 3, one line): nothing but stops sent."""
    from naocal.tools.cli import main

    boards_only(monkeypatch)
    first, out = DuckiebotMock(4, "ideal", supersample=1), tmp_path / "run"
    argv = ["calibrate", "--robot", "duckiebot", "--backend", "bridge", "--endpoint", ipc(tmp_path), "--out", str(out)]
    served = ServedDuckiebot(first, robot_id="mock4", watchdog_s=0.3)
    try:
        with serving(served, ipc(tmp_path), driver="mock"):
            killed_mid_turn(monkeypatch, argv)
    finally:
        served.close()
    second = DuckiebotMock(4, "ideal", supersample=1)
    served = ServedDuckiebot(second, robot_id="mock4", watchdog_s=0.3)
    try:
        with serving(served, ipc(tmp_path), driver="mock"):
            capsys.readouterr()
            assert main(argv + ["--resume"]) == 3
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "is not after the log's last row" in err, err
            assert second.received and not any(l or r for _, l, r in second.received)
    finally:
        served.close()
    assert len(read_drive_log(out / "log").segment_t_s) == 0
