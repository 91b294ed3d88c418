"""The Duckiebot's ROS driver (kinds/duckiebot/ros_driver.py) against a fake peer of Duckietown's interfaces
(tests/duckiebot_ros_peer.py: fake rospy and message modules, a wheels node driving a hidden PyBullet robot, a camera
node publishing rendered JPEGs, encoder nodes): a short mission calibrates through it end to end, and each safety
rule (duties in range, watchdog, stop on close / SIGTERM / refused reading, deadlines, checked readings)."""

import cv2
import math
import os
import signal
import sys
import time

import numpy as np
import pytest

from naocal.agent.machine import DONE, INTERRUPTED
from naocal.kinds.duckiebot.drive_log import read_drive_log, read_encoders
from naocal.kinds.duckiebot.mission import (Boards, CalibrateCamera, FaceMarkers, IdentifyDrive, MarkerDrives,
                                            MissionSettings, run_mission)
from naocal.solver.errors import NaocalError, SafetyError

sys.path.insert(0, os.path.dirname(__file__))
from duckiebot_ros_peer import FakeRosGraph, check_resumed_again  # noqa: E402

VEHICLE = "db21"
CAMERA_TOPIC = f"/{VEHICLE}/camera_node/image/compressed"
LEFT_TICKS = f"/{VEHICLE}/left_wheel_encoder_node/tick"
SHORT = MissionSettings(board_passes=2, legs=(2, 3), wiggles=1)


@pytest.fixture
def graph(monkeypatch):
    graph = FakeRosGraph(VEHICLE).install(monkeypatch)
    yield graph
    graph.close()


def driver_named(vehicle, **kw):
    from naocal.kinds.duckiebot.ros_driver import RosDuckiebot

    return RosDuckiebot(vehicle, **kw)


def driver(**kw):
    return driver_named(VEHICLE, **kw)


def stopped(graph) -> bool:
    return graph.received[-1][1:] == (0.0, 0.0) and not graph.robot.duties.any()


def test_without_rospy_one_line_error_and_the_module_imports(monkeypatch):
    from naocal.kinds.duckiebot import ros_driver  # importable anywhere: rospy only in the constructor

    monkeypatch.setitem(sys.modules, "rospy", None)
    with pytest.raises(NaocalError) as err:
        ros_driver.RosDuckiebot(VEHICLE)
    assert "dt-ros-commons" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.slow
def test_a_short_mission_calibrates_through_the_driver(tmp_path, monkeypatch):
    graph = FakeRosGraph(VEHICLE, seed=4).install(monkeypatch)
    robot = driver(watchdog_s=30.0)  # the test machine's pauses are not a hung agent
    try:
        result, ctx = run_mission(robot, tmp_path, SHORT, states=(Boards, CalibrateCamera, FaceMarkers, MarkerDrives,
                                                                  IdentifyDrive),
                                  transitions={("boards", "ok"): "camera", ("camera", "ok"): "face_markers",
                                               ("face_markers", "ok"): "marker_drives",
                                               ("marker_drives", "ok"): "identification",
                                               ("identification", "ok"): DONE})
        assert result.final == DONE, result.reason
        truth, kin, fit = graph.robot.truth.kinematics(), ctx.calibration.kinematics, ctx.calibration.drive_fit
        assert abs(kin.trim - truth.trim) < 0.001
        # gain: this short mission through the driver is 0.85 % off (1.9 of its std): within its std's cover
        assert abs(kin.gain - truth.gain) < 3 * fit.stdev("gain") and abs(kin.gain / truth.gain - 1) < 0.02
        assert abs(kin.baseline_m - truth.baseline_m) < 0.002
        # every duty the wheels node received was within range and is the log's, in order; then the final stop
        assert graph.refused == [] and stopped(graph)
        received = np.array([(l, r) for _, l, r in graph.received[1:]])  # after the constructor's stop
        log = read_drive_log(tmp_path / "log", check_images=False)
        assert np.array_equal(np.column_stack([log.left_duty, log.right_duty]), received[:len(log.wheel_t_s)])
        # the encoders recorded into the drive log: the ticks are the turns the logged duties drove the hidden
        # wheels (ideal motors: w = gain duty), on the same clock
        written = robot.save_encoders(tmp_path / "log", log.wheel_t_s[0], log.frame_t_s[-1])
        log = read_drive_log(tmp_path / "log", check_images=False)
        assert written > 100 and len(log.encoder_t_s) == written
        t = np.linspace(log.encoder_t_s[0], log.encoder_t_s[-1], 200001)
        duties = np.column_stack(log.duties_at(t))
        gains = np.array([graph.robot.truth.motor_left_radps, graph.robot.truth.motor_right_radps])
        driven_rad = np.abs(duties * gains).sum(axis=0) * (t[1] - t[0])
        counted = np.abs(np.diff(np.column_stack([log.left_ticks, log.right_ticks]), axis=0)).sum(axis=0)
        assert np.allclose(counted * 2 * np.pi / 135, driven_rad, rtol=0.03), (counted, driven_rad)
    finally:
        robot.close()
        graph.close()


def test_duties_outside_the_range_are_never_published(graph):
    robot = driver()
    sent = len(graph.received)
    for left, right in ((1.01, 0.0), (0.0, -1.5), (math.nan, 0.0), (0.0, math.inf), (True, 0.0), ("0.3", 0.0)):
        with pytest.raises(SafetyError):
            robot.command(left, right)
    assert len(graph.received) == sent and graph.refused == []
    robot.command(1.0, -1.0)  # the limits themselves are fine
    assert graph.received[-1][1:] == (1.0, -1.0)
    robot.close()
    assert stopped(graph)


def test_watchdog_stops_the_wheels_when_the_agent_goes_silent(graph):
    robot = driver(watchdog_s=0.2)
    robot.command(0.3, 0.3)
    robot.advance(1.5)  # inside the driver the agent is alive: no stop, however long the wait
    assert graph.received[-1][1:] == (0.3, 0.3)
    time.sleep(0.6)  # the agent hangs with the wheels turning
    assert stopped(graph)
    with pytest.raises(NaocalError, match="watchdog"):
        robot.advance(0.1)
    robot.close()


def test_after_a_fault_the_stop_and_the_clock_still_work_moving_does_not(graph):
    robot = driver()
    graph.frame_hook = lambda msg: setattr(msg.header, "stamp", type(msg.header.stamp)(0.0)) or msg
    graph.sleep(0.2)  # a frame stamped back in time arrives while the robot stands
    assert robot.now() > 0.1 and robot.command(0.0, 0.0) > 0.1  # the agent's unwinding: its clock, its stop
    for move in (lambda: robot.command(0.2, 0.2), lambda: robot.advance(0.1), robot.grab):
        with pytest.raises(NaocalError, match=f"{CAMERA_TOPIC}: a frame stamped"):
            move()
    assert stopped(graph)
    robot.close()


def test_stopped_on_close_and_on_ros_shutdown(graph):
    robot = driver()
    robot.command(0.4, 0.2)
    for hook in graph.shutdown_hooks:  # rospy shutting down (the container stopping)
        hook()
    assert stopped(graph)
    robot.command(0.4, 0.2)
    robot.close()
    robot.close()
    assert stopped(graph)


def test_close_sends_the_stop_before_it_leaves_the_topic_as_rospy_queues_it(monkeypatch, caplog):
    """rospy publishes from a queue thread: a stop published just before the publisher unregisters would be dropped.
    close() waits until the wheels driver reports the stop executed; if it never does, it says so within its
    deadline."""
    from naocal.kinds.duckiebot.ros_driver import STOP_CONFIRM_S

    graph = FakeRosGraph(VEHICLE, queued=True).install(monkeypatch)
    try:
        def drive(left, right):
            robot.command(left, right)
            deadline = time.monotonic() + 5.0
            while graph.robot.duties.tolist() != [left, right] and time.monotonic() < deadline:
                time.sleep(0.005)
            assert graph.robot.duties.tolist() == [left, right]

        robot = driver()
        drive(0.4, 0.2)
        robot.close()
        assert stopped(graph), graph.received[-3:]
        robot = driver()
        drive(0.3, 0.3)
        graph.send_delay_s = 30.0  # the next message takes longer than close() waits
        started = time.monotonic()
        robot.close()
        assert time.monotonic() - started < STOP_CONFIRM_S + 1.0
        assert "did not report the stop executed within 0.5 s" in caplog.text
    finally:
        graph.close()


def test_sigterm_mid_drive_stops_the_wheels(graph, tmp_path):
    from naocal.tools.cli import _terminate_like_ctrl_c

    robot = driver()
    previous = signal.getsignal(signal.SIGTERM)
    _terminate_like_ctrl_c()  # what `naocal calibrate` installs: SIGTERM raises KeyboardInterrupt("SIGTERM")

    def kill_while_driving():
        if graph.robot.duties.any():
            graph.sleep_hook = None
            os.kill(os.getpid(), signal.SIGTERM)

    graph.sleep_hook = kill_while_driving
    try:
        result, _ = run_mission(robot, tmp_path, SHORT, states=(Boards,), transitions={("boards", "ok"): DONE})
        assert result.final == INTERRUPTED and "SIGTERM" in result.reason
        assert stopped(graph)
        assert any(l or r for _, l, r in graph.received)  # it was driving
    finally:
        signal.signal(signal.SIGTERM, previous)
        robot.close()


def test_no_frame_within_the_deadline_stops_the_wheels(graph):
    robot = driver(image_timeout_s=0.3)
    robot.command(0.2, 0.2)
    graph.camera_on = False
    start = time.monotonic()
    with pytest.raises(NaocalError, match=f"{CAMERA_TOPIC}: no frame within 0.3 s of asking at"):
        robot.grab()
    assert time.monotonic() - start < 5 and stopped(graph)
    robot.close()


def test_a_frame_stamped_on_another_clock_is_refused(graph):
    robot = driver()
    robot.command(0.2, 0.2)

    def ahead(msg):
        msg.header.stamp = graph.Time(msg.header.stamp.to_sec() + 3600.0)
        return msg

    graph.frame_hook = ahead
    with pytest.raises(NaocalError, match=f"{CAMERA_TOPIC}: a frame stamped .* 3600.0 s ahead of the robot's clock"):
        robot.grab()
    assert stopped(graph)
    robot.close()


def test_a_clock_that_stands_still_is_a_deadline_missed(graph):
    robot = driver(clock_slack_s=0.2)
    robot.command(0.2, 0.2)
    graph.clock_running = False
    with pytest.raises(NaocalError, match="clock did not reach"):
        robot.advance(0.1)
    assert stopped(graph)
    robot.close()


def test_no_wheels_driver_listening_is_refused(monkeypatch):
    graph = FakeRosGraph(VEHICLE, wheels_node=False).install(monkeypatch)
    try:
        with pytest.raises(NaocalError, match=f"/{VEHICLE}/wheels_driver_node/wheels_cmd: no wheels driver"):
            driver(connect_timeout_s=0.2)
    finally:
        graph.close()


def _jpeg(image):
    return cv2.imencode(".jpg", image)[1].tobytes()


@pytest.mark.parametrize("damage, message", [
    (lambda msg: setattr(msg, "data", b"not a jpeg"), "does not decode as an image"),
    (lambda msg: setattr(msg, "data", _jpeg(np.zeros((240, 320), np.uint8))), "is 320 x 240, expected 640 x 480"),
])
def test_a_frame_that_is_not_a_camera_image_is_refused(graph, damage, message):
    robot = driver()
    robot.command(0.2, -0.2)
    graph.frame_hook = lambda msg: damage(msg) or msg
    with pytest.raises(NaocalError, match=f"{CAMERA_TOPIC}: .*{message}"):
        robot.grab()
    assert stopped(graph)
    robot.close()


def test_a_frame_stamped_back_in_time_is_refused(graph):
    robot = driver()
    robot.grab()
    robot.command(0.2, 0.2)

    def back(msg):
        msg.header.stamp = graph.Time(msg.header.stamp.to_sec() - 1.0)
        return msg

    graph.frame_hook = back
    with pytest.raises(NaocalError, match=f"{CAMERA_TOPIC}: a frame stamped .* not after the previous one"):
        robot.advance(0.2)
    assert stopped(graph)
    robot.close()


def left_damaged_after(n, change):
    """An encoder hook: the left count's messages after the n-th changed by `change(msg)`."""
    seen = [0]

    def hook(side, msg):
        if side == "left":
            seen[0] += 1
            if seen[0] > n:
                change(msg)
        return msg

    return hook


@pytest.mark.parametrize("change, message", [
    (lambda msg: setattr(msg, "data", msg.data + 500), "encoder row \\d+, field 'left_ticks': \\+5\\d\\d ticks since the "
                                                        "previous row .* more than the wheel can turn"),
    (lambda msg: setattr(msg, "data", math.nan), "tick count nan is not a whole number"),
    (lambda msg: setattr(msg, "data", 12.5), "tick count 12.5 is not a whole number"),
    (lambda msg: setattr(msg, "resolution", 100), "resolution 100 ticks per revolution, expected 135"),
    (lambda msg: setattr(msg.header, "stamp", type(msg.header.stamp)(0.0)), "not after the previous one"),
])
def test_an_encoder_reading_that_cannot_be_is_refused(graph, change, message):
    robot = driver()
    robot.command(0.3, 0.3)
    graph.tick_hook = left_damaged_after(2, change)
    with pytest.raises(NaocalError, match=f"{LEFT_TICKS}: .*{message}"):
        robot.advance(0.5)
    assert stopped(graph)
    robot.close()


def rows_as_the_reader_reads_them(robot):
    """The driver's encoder rows through encoders.csv's reader with the drive log's wheels (its jump check)."""
    import dataclasses

    from naocal.kinds.duckiebot.drive_log import ENCODERS_HEADER, csv_text, parse_meta
    from naocal.kinds.duckiebot.mission import log_meta

    wheels = dataclasses.replace(parse_meta(log_meta(VEHICLE, "a test"), "log.json")["wheels"], ticks_per_revolution=135)
    text = csv_text(ENCODERS_HEADER, ([repr(t), str(a), str(b)] for t, a, b in robot.encoder_rows))
    return read_encoders("encoders.csv", text, wheels=wheels)


def test_encoder_rows_from_two_nodes_out_of_phase_are_rows_the_reader_takes(monkeypatch):
    """Each encoder node has its own timer: the right count 2 ms after the left. A row at each message, the other
    side's count held, put a whole interval's ticks 2 ms after the row before: the mission ran, and its log was then
    refused by the reader as a jump. A row once both have counted steps as the wheels turned."""
    graph = FakeRosGraph(VEHICLE, right_tick_lag_steps=1).install(monkeypatch)
    robot = driver()
    try:
        robot.command(0.6, 0.6)
        robot.advance(1.0)
        robot.command(0.0, 0.0)
        t, left, right = rows_as_the_reader_reads_them(robot)
        assert len(t) > 25 and right[-1] - right[0] > 300 and np.all(np.diff(t) > 0.03)
    finally:
        robot.close()
        graph.close()


def test_an_int32_counter_wrapping_mid_drive_is_undone_as_the_reader_does(graph):
    """Duckietown's tick counts are int32 since boot: past 2^31 - 1 they go on from -2^31. The reader undoes it
    (drive_log.unwrap_int32); the driver refused it as a jump of -2^32 and stopped the mission."""
    def near_the_top(side, msg):
        msg.data = (msg.data + 2 ** 31 - 60 + 2 ** 31) % 2 ** 32 - 2 ** 31
        return msg

    graph.tick_hook = near_the_top
    robot = driver()
    robot.command(0.4, 0.4)
    robot.advance(1.0)
    robot.command(0.0, 0.0)
    t, left, right = rows_as_the_reader_reads_them(robot)
    assert left[0] < 2 ** 31 < left[-1] and np.all(np.diff(left) >= 0) and np.all(np.diff(left) < 20)
    assert stopped(graph)
    robot.close()


def test_a_db18_without_encoders_writes_no_encoders_file(monkeypatch, tmp_path):
    graph = FakeRosGraph(VEHICLE, encoders=False).install(monkeypatch)
    robot = driver()
    try:
        robot.command(0.3, 0.3)
        robot.advance(0.3)
        assert robot.save_encoders(tmp_path, 0.0, robot.now()) == 0 and not (tmp_path / "encoders.csv").exists()
    finally:
        robot.close()
        graph.close()


def test_a_bad_robot_name_is_one_line(graph):
    with pytest.raises(NaocalError, match="robot name '../x'"):
        driver_named("../x")


# --------------------------------------------------------------------------------- naocal calibrate --backend ros

def test_calibrate_ros_bad_setups_are_one_line_exit_2_nothing_written(tmp_path, monkeypatch, capsys):
    from naocal.tools.cli import main

    out = tmp_path / "run"
    monkeypatch.delenv("VEHICLE_NAME", raising=False)
    cases = [(["--robot", "duckiebot"], "VEHICLE_NAME is not set"),
             (["--robot", "nao"], "another robot kind's (--robot duckiebot)")]
    for robot, message in cases:
        assert main(["calibrate", *robot, "--backend", "ros", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and not out.exists()
    monkeypatch.setenv("VEHICLE_NAME", VEHICLE)
    monkeypatch.setitem(sys.modules, "rospy", None)  # not on the robot
    for extra, message in (([], "dt-ros-commons"), (["--resume"], "dt-ros-commons"),
                           (["--mock", "ideal"], "--mock chooses")):
        assert main(["calibrate", "--robot", "duckiebot", "--backend", "ros", *extra, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and not out.exists()


def test_calibrate_ros_runs_the_mission_on_the_robot_and_records_its_encoders(tmp_path, monkeypatch, capsys):
    import naocal.kinds.duckiebot.mission as mission
    from naocal.tools.cli import main

    graph = FakeRosGraph(VEHICLE).install(monkeypatch)
    monkeypatch.setenv("VEHICLE_NAME", VEHICLE)
    whole = mission.run_mission

    def boards_only(robot, out, settings, **kw):  # the first phase only: the CLI's wiring, not the mission again
        return whole(robot, out, MissionSettings(board_passes=1, max_blind_m=settings.max_blind_m), **kw,
                     states=(Boards,), transitions={("boards", "ok"): DONE})

    monkeypatch.setattr(mission, "run_mission", boards_only)
    out = tmp_path / "run"
    try:
        assert main(["calibrate", "--robot", "duckiebot", "--backend", "ros", "--out", str(out)]) == 0, \
            capsys.readouterr().err
        assert stopped(graph) and graph.refused == []
        assert not (out / "truth.json").exists() and (out / "mission.json").exists()
        log = read_drive_log(out / "log")
        assert log.robot_id == VEHICLE and log.wheels.ticks_per_revolution == 135
        assert len(log.frame_files) > 3 and len(log.encoder_t_s) > 10
        assert log.encoder_t_s[0] >= log.wheel_t_s[0] and log.encoder_t_s[-1] <= max(log.frame_t_s[-1],
                                                                                      log.wheel_t_s[-1])
        assert log.left_ticks[-1] != log.left_ticks[0]  # the one-wheel steps turned the left wheel
        # the run's journal holds every row the log got, saved as they came
        journal = list(zip(*(a.tolist() for a in read_encoders(out / "encoders.csv"))))
        assert set(zip(log.encoder_t_s.tolist(), log.left_ticks.tolist(), log.right_ticks.tolist())) <= set(journal)
    finally:
        graph.close()


def test_calibrate_ros_a_refused_reading_mid_run_is_exit_3_with_its_summary(tmp_path, monkeypatch, capsys):
    import naocal.kinds.duckiebot.mission as mission
    from naocal.tools.cli import main

    graph = FakeRosGraph(VEHICLE).install(monkeypatch)
    monkeypatch.setenv("VEHICLE_NAME", VEHICLE)
    whole = mission.run_mission
    monkeypatch.setattr(mission, "run_mission", lambda robot, out, settings, **kw: whole(
        robot, out, MissionSettings(board_passes=1), **kw, states=(Boards,), transitions={("boards", "ok"): DONE}))
    frames = [0]

    def stamped_back_after_1_5_s(msg):  # mid-run the camera's stamps go back (refused in its subscriber)
        frames[0] += 1
        if frames[0] > 45:
            msg.header.stamp = type(msg.header.stamp)(0.0)
        return msg

    graph.frame_hook = stamped_back_after_1_5_s
    out = tmp_path / "run"
    try:
        assert main(["calibrate", "--robot", "duckiebot", "--backend", "ros", "--out", str(out)]) == 3
        err = capsys.readouterr().err
        assert f"{CAMERA_TOPIC}: a frame stamped 0.0 s, not after the previous one" in err and err.count("\n") == 1
        assert "not after the previous one" in (out / "summary.txt").read_text()
        assert stopped(graph) and not (out / "mission.json").exists()
    finally:
        graph.close()


# --------------------------------------------------------------------------------- the encoders, saved as they come

def journal_rows(path):
    return list(zip(*(a.tolist() for a in read_encoders(path))))


def test_the_ticks_are_saved_as_they_come_and_a_restarted_driver_keeps_them(graph, tmp_path, monkeypatch):
    import naocal.kinds.duckiebot.ros_driver as ros_driver

    monkeypatch.setattr(ros_driver, "ENCODER_SAVE_S", 0.0)  # every row at once: the file is the memory, exactly
    path = tmp_path / "encoders.csv"
    first = driver()
    assert first.keep_encoders(path) == 0
    first.command(0.3, 0.1)
    first.advance(0.5)
    first.command(0.0, 0.0)
    saved = journal_rows(path)  # no close, no save_encoders: what a crash now would leave
    assert len(saved) > 10 and saved == first.encoder_rows and saved[-1][1] > saved[0][1]
    for subscriber in first._subscribers:  # the first process is gone (a crash): its subscribers with it
        subscriber.unregister()
    first._closed = True
    with open(path, "a") as f:
        f.write(f"{saved[-1][0] + 1.0!r},9")  # a crash cut the last append short
    second = driver()
    try:
        assert second.keep_encoders(path) == len(saved)  # the earlier run's rows, the torn one cut off
        second.command(0.1, 0.3)
        second.advance(0.3)
        second.command(0.0, 0.0)
    finally:
        second.close()
    rows = journal_rows(path)
    assert rows[:len(saved)] == saved and len(rows) > len(saved) + 5 and rows == second.encoder_rows
    assert path.read_text().endswith("\n")


def test_a_damaged_journal_is_one_line_naming_it(graph, tmp_path):
    path = tmp_path / "encoders.csv"
    path.write_text("t_s,left_ticks,right_ticks\n0.1,3,4\n0.2,x,5\n")
    robot = driver()
    try:
        with pytest.raises(NaocalError, match=r"encoders.csv, line 3, field 'left_ticks': expected a whole number"):
            robot.keep_encoders(path)
    finally:
        robot.close()
    assert path.read_text().endswith("0.2,x,5\n")  # not changed


class Crash(Exception):
    """A bug that kills the process (the CLI keeps its traceback)."""


def test_calibrate_ros_a_crash_keeps_the_ticks_and_a_resumed_run_starts_the_phase_again_where_it_stands(
        tmp_path, monkeypatch, capsys):
    """A run on the fake peer dies (the ticks kept), and `--resume` goes on where the robot stands: refused while hands
    have moved it (the boards not where the run left them: nothing moved, nothing logged), then, put back, the wheels
    stopped first, the captures kept, a break in the log where the phase started again, the ticks appended."""
    import naocal.kinds.duckiebot.mission as mission
    from naocal.tools.cli import main

    graph = FakeRosGraph(VEHICLE).install(monkeypatch)
    monkeypatch.setenv("VEHICLE_NAME", VEHICLE)
    whole = mission.run_mission

    def crash_after_the_boards(robot, out, settings, **kw):
        whole(robot, out, MissionSettings(board_passes=1), **kw, states=(Boards,), transitions={("boards", "ok"): DONE})
        raise Crash("the process dies here")  # before the logs get their encoders.csv

    monkeypatch.setattr(mission, "run_mission", crash_after_the_boards)
    out = tmp_path / "run"
    try:
        with pytest.raises(Crash):
            main(["calibrate", "--robot", "duckiebot", "--backend", "ros", "--out", str(out)])
        log = read_drive_log(out / "log")
        assert log.encoder_t_s is None  # the end of the run never came
        rows = journal_rows(out / "encoders.csv")
        assert len(rows) > 10 and rows[0][0] <= log.wheel_t_s[-1] and rows[-1][1] != rows[0][1]
        before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
        capsys.readouterr()
        assert main(["calibrate", "--robot", "duckiebot", "--backend", "ros", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "continue it with --resume" in err, err
        assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before
        frames = {name: (out / "log" / name).read_bytes() for name in log.frame_files}

        def boards_twice(robot, out, settings, **kw):  # the resumed run goes on past the crashed one's end
            return whole(robot, out, MissionSettings(board_passes=2), **kw, states=(Boards,),
                         transitions={("boards", "ok"): DONE})

        monkeypatch.setattr(mission, "run_mission", boards_twice)
        resume = ["calibrate", "--robot", "duckiebot", "--backend", "ros", "--resume", "--out", str(out)]
        # hands moved it (turned 22 deg): the boards are not where the run left them; nothing moves, nothing logged
        graph.robot.carry(0.0, 0.0, 0.38)
        def captures():  # the commands and frames logged (log.json and encoders.csv get the ticks as a run ends)
            return {p: p.read_bytes() for p in (out / "log").rglob("*")
                    if p.is_file() and p.name not in ("log.json", "encoders.csv")}

        sent, logged = len(graph.received), captures()
        capsys.readouterr()
        assert main(resume) == 3
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "boards are not where the stopped run last saw them (board 2" in err, err
        assert graph.received[sent:] and all((l, r) == (0.0, 0.0) for _, l, r in graph.received[sent:])
        assert captures() == logged and not (out / "log" / "segments.csv").exists()
        # put back as it stood: the boards phase goes on from where the replay says it turned to
        graph.robot.carry(0.0, 0.0, -0.38)
        sent = len(graph.received)
        assert main(resume) == 0
        resumed = read_drive_log(out / "log")
        assert graph.received[sent][1:] == (0.0, 0.0)  # the wheels stopped before anything else was sent
        assert len(resumed.segment_t_s) == 1 and resumed.segment_t_s[0] > log.wheel_t_s[-1]
        at_break = np.searchsorted(resumed.wheel_t_s, resumed.segment_t_s[0])
        assert resumed.wheel_t_s[at_break] == resumed.segment_t_s[0]
        assert (resumed.left_duty[at_break], resumed.right_duty[at_break]) == (0.0, 0.0)
        assert resumed.frame_files[:len(log.frame_files)] == log.frame_files
        assert all((out / "log" / name).read_bytes() == data for name, data in frames.items())  # kept, not redone
        # the phase went on with the pass not yet done only (right, to board 0: every step after the break turns
        # right), the first pass's views kept
        after = resumed.wheel_t_s > resumed.segment_t_s[0]
        left, right = resumed.left_duty[after], resumed.right_duty[after]
        assert np.sum(resumed.frame_t_s > resumed.segment_t_s[0]) >= 3 and np.any(left > 0)
        assert np.all((left >= 0) & (right <= 0))
        assert resumed.encoder_t_s is not None and journal_rows(out / "encoders.csv")[:len(rows)] == rows
        assert stopped(graph)
    finally:
        graph.close()


class StoppedAtStep:
    """The robot as the run is stopped (KeyboardInterrupt: Ctrl-C, SIGTERM) when it is to turn its `at`-th one-wheel
    step, counting what it drives only (a resumed run's replay drives nothing)."""

    def __init__(self, robot, at):
        self.robot, self.at, self.steps, self.duties = robot, at, 0, (0.0, 0.0)

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def command(self, left, right):
        self.duties = (left, right)
        return self.robot.command(left, right)

    def advance(self, duration_s):
        if self.duties != (0.0, 0.0):
            self.steps += 1
            if self.steps >= self.at:
                raise KeyboardInterrupt()
        self.robot.advance(duration_s)


def test_calibrate_ros_a_run_stopped_again_in_the_phase_its_resume_started_again_resumes_again(
        tmp_path, monkeypatch, capsys):
    """Ctrl-C in the boards phase, `--resume`, Ctrl-C again inside the phase that resume started again, `--resume`
    again: the replay starts the phase again at the log's break as the first resume did (it refused the run as
    recorded with other options: the phase's own next step is not the break's stop), the wheels stopped before
    anything else, nothing else sent during the replay, every capture kept byte for byte, two breaks, done."""
    import naocal.kinds.duckiebot.mission as mission
    from naocal.tools.cli import main

    graph = FakeRosGraph(VEHICLE).install(monkeypatch)
    monkeypatch.setenv("VEHICLE_NAME", VEHICLE)
    whole, stop_at = mission.run_mission, [3, 2, None]  # each run's step stopped at (live steps only)

    def boards_stopped(robot, out, settings, **kw):
        at = stop_at.pop(0)
        return whole(robot if at is None else StoppedAtStep(robot, at), out, SHORT, **kw, states=(Boards,),
                     transitions={("boards", "ok"): DONE})

    monkeypatch.setattr(mission, "run_mission", boards_stopped)
    out = tmp_path / "run"
    argv = ["calibrate", "--robot", "duckiebot", "--backend", "ros", "--out", str(out)]
    try:
        assert main(argv) == 130
        assert main(argv + ["--resume"]) == 130
        log = read_drive_log(out / "log")
        (t_first,) = log.segment_t_s
        assert np.sum(log.frame_t_s > t_first) >= 1 and np.any((log.left_duty != 0) | (log.right_duty != 0), where=log.wheel_t_s > t_first)  # turned again
        frames = {name: (out / "log" / name).read_bytes() for name in log.frame_files}
        sent = len(graph.received)
        capsys.readouterr()
        assert main(argv + ["--resume"]) == 0, capsys.readouterr().err
        check_resumed_again(out / "log", log, frames, graph.received[sent:])
        assert (out / "mission.json").exists() and stopped(graph)
    finally:
        graph.close()
