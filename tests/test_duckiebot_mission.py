"""The Duckiebot's PyBullet mock and its calibration mission (kinds/duckiebot/mock.py, mission.py, calibrate.py):
the ideal mock's hidden truth recovered by a short mission, the wheels stopped on an exception and on SIGTERM, a
killed run resumed without repeating a capture, the out-of-area stop, no duty outside [-1, 1]."""

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from naocal.agent.machine import DONE, INTERRUPTED
from naocal.kinds.duckiebot.drive_log import read_drive_log
from naocal.kinds.duckiebot.fit import CAMERA, pose_parameters
from naocal.kinds.duckiebot.identify import calibrate, detect_log
from naocal.kinds.duckiebot.intrinsics import LensCamera
from naocal.kinds.duckiebot.mission import (Boards, CalibrateCamera, FaceMarkers, IdentifyDrive, MarkerDrives,
                                            MissionContext, MissionSettings, ReplayEnded, Session, Validation,
                                            drive_watching, log_meta, run_mission)
from naocal.kinds.duckiebot.mock import DuckiebotMock
from naocal.solver.errors import NaocalError, SafetyError

ROOT = Path(__file__).resolve().parents[1]
# A short mission: one pass over the boards each way, two legs along the marker line.
SHORT = MissionSettings(board_passes=2, legs=(2, 3), wiggles=1)
UP_TO_IDENTIFICATION = {("boards", "ok"): "camera", ("camera", "ok"): "face_markers",
                        ("face_markers", "ok"): "marker_drives", ("marker_drives", "ok"): "identification",
                        ("identification", "ok"): DONE}
BOARDS_ONLY = {("boards", "ok"): DONE}


def short_mock(seed=4, realism="ideal", **kw):
    return DuckiebotMock(seed, realism, supersample=1, **kw)


@pytest.fixture(scope="module")
def ideal_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ideal")
    robot = short_mock()
    result, ctx = run_mission(robot, out, SHORT, transitions=UP_TO_IDENTIFICATION,
                              states=(Boards, CalibrateCamera, FaceMarkers, MarkerDrives, IdentifyDrive))
    yield robot, result, ctx, out
    robot.close()


def test_ideal_mock_truth_recovered_by_a_short_mission(ideal_run):
    robot, result, ctx, _ = ideal_run
    assert result.final == DONE, result.reason
    truth = robot.truth.kinematics()
    kin, fit = ctx.calibration.kinematics, ctx.calibration.drive_fit
    assert abs(kin.trim - truth.trim) < 0.001
    assert abs(kin.gain / truth.gain - 1) < 0.01
    assert abs(kin.baseline_m - truth.baseline_m) < 0.002
    true_pose = pose_parameters(robot.truth.T_base_camera)
    for name, value in zip(CAMERA, true_pose):
        limit = 0.003 if name.endswith("_m") else math.radians(0.5)
        assert abs(fit.value(name) - value) < limit, name
    K = ctx.calibration.lens.camera.K
    assert abs(K[0, 0] / robot.truth.camera.fx_px - 1) < 0.01


def test_every_duty_within_limits_and_logged_as_sent(ideal_run):
    robot, _, ctx, out = ideal_run
    sent = np.array([(left, right) for _, left, right in robot.received])
    assert np.all(np.abs(sent) <= 1.0) and len(sent) > 20
    log = read_drive_log(out / "log")
    logged = np.column_stack([log.left_duty, log.right_duty])
    assert np.array_equal(logged, sent[:len(logged)])  # every command logged, in order
    assert not sent[len(logged):].any() and not logged[-1].any()  # then only the final stops (the safe state)


def test_a_duty_outside_the_limits_is_refused_before_the_robot(tmp_path):
    robot = short_mock()
    try:
        session = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0)
        for left, right in ((1.5, 0.0), (0.0, -1.01), (float("nan"), 0.0), (0.0, float("inf"))):
            with pytest.raises(SafetyError):
                session.command(left, right)
        with pytest.raises(SafetyError):
            robot.command(2.0, 0.0)
        assert robot.received == []
    finally:
        robot.close()


class Failing:
    """A robot whose grab fails (or is interrupted) after `after` frames, mid-mission."""

    def __init__(self, robot, after, exc):
        self.robot, self.after, self.exc, self.frames = robot, after, exc, 0

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def advance(self, duration_s, poses=None):
        if self.frames >= self.after and self.robot.duties.any():  # while the wheels turn
            self.exc()
        self.robot.advance(duration_s, poses)

    def grab(self):
        self.frames += 1
        return self.robot.grab()


def test_wheels_stopped_when_the_mission_raises(tmp_path):
    robot = short_mock()

    def bug():
        raise RuntimeError("a bug")

    try:
        with pytest.raises(RuntimeError):
            run_mission(Failing(robot, 3, bug), tmp_path, SHORT)
        assert robot.duties.tolist() == [0.0, 0.0] and robot.received[-1][1:] == (0.0, 0.0)
        log = read_drive_log(tmp_path / "log", check_images=False)
        assert (log.left_duty[-2], log.right_duty[-2]) != (0.0, 0.0)  # it was driving when it failed
        assert (log.left_duty[-1], log.right_duty[-1]) == (0.0, 0.0)
    finally:
        robot.close()


def test_sigterm_stops_the_wheels_and_interrupts_the_run(tmp_path):
    from naocal.tools.cli import _terminate_like_ctrl_c

    robot = short_mock()
    previous = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _terminate_like_ctrl_c()  # what `naocal calibrate` installs: SIGTERM raises KeyboardInterrupt("SIGTERM")
    try:
        result, _ = run_mission(Failing(robot, 2, lambda: os.kill(os.getpid(), signal.SIGTERM)), tmp_path, SHORT)
        assert result.final == INTERRUPTED and "SIGTERM" in result.reason
        assert robot.duties.tolist() == [0.0, 0.0]
        log = read_drive_log(tmp_path / "log", check_images=False)
        assert (log.left_duty[-2], log.right_duty[-2]) != (0.0, 0.0)
        assert (log.left_duty[-1], log.right_duty[-1]) == (0.0, 0.0)
    finally:
        signal.signal(signal.SIGTERM, previous)
        robot.close()


KILLED_RUN = textwrap.dedent("""
    import os, signal, sys
    sys.path.insert(0, {root!r})
    import naocal
    from naocal.agent.machine import DONE
    from naocal.kinds.duckiebot.mission import Boards, MissionSettings, run_mission
    from naocal.kinds.duckiebot.mock import DuckiebotMock

    class Killed:
        def __init__(self, robot):
            self.robot, self.frames = robot, 0
        def __getattr__(self, name):
            return getattr(self.robot, name)
        def advance(self, duration_s, poses=None):
            if self.frames >= 3 and self.robot.duties.any():
                os.kill(os.getpid(), signal.SIGKILL)  # mid-drive: no finally, no stop
            self.robot.advance(duration_s, poses)
        def grab(self):
            self.frames += 1
            return self.robot.grab()

    out = {out!r}
    robot = DuckiebotMock(4, "ideal", supersample=1, state_path=out + "/mock_state.json")
    run_mission(Killed(robot), out, MissionSettings(board_passes=1), states=(Boards,),
                transitions={{("boards", "ok"): DONE}})
""")


def test_a_killed_run_resumes_without_repeating_a_capture(tmp_path):
    killed = tmp_path / "killed"
    killed.mkdir()
    proc = subprocess.run([sys.executable, "-c", KILLED_RUN.format(root=str(ROOT.parent), out=str(killed))],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    before = read_drive_log(killed / "log")
    assert len(before.frame_files) == 3 and before.left_duty[-1] + before.right_duty[-1] != 0  # killed driving
    first = {name: (killed / "log" / name).read_bytes() for name in before.frame_files}

    settings = MissionSettings(board_passes=1)
    robot = short_mock(state_path=killed / "mock_state.json")
    try:
        result, _ = run_mission(robot, killed, settings, states=(Boards,), transitions=BOARDS_ONLY)
        assert result.final == DONE, result.reason
        resumed_commands = len(robot.received)
    finally:
        robot.close()
    after = read_drive_log(killed / "log")
    assert after.frame_files[:3] == before.frame_files and np.array_equal(after.frame_t_s[:3], before.frame_t_s)
    assert all((killed / "log" / n).read_bytes() == data for n, data in first.items())  # not grabbed again
    # the same mission uninterrupted: as many frames (none repeated, none missing)
    reference = short_mock()
    try:
        result, _ = run_mission(reference, tmp_path / "whole", settings, states=(Boards,), transitions=BOARDS_ONLY)
        assert result.final == DONE
    finally:
        reference.close()
    whole = read_drive_log(tmp_path / "whole" / "log", check_images=False)
    assert len(after.frame_files) == len(whole.frame_files)
    assert resumed_commands < len(whole.wheel_t_s)  # the replayed part was not sent again


class StoppedMidDrive:
    """The mock stopped (KeyboardInterrupt: what Ctrl-C and SIGTERM raise) as it is to drive straight at `duty` for
    the `at`-th time."""

    def __init__(self, robot, duty, at):
        self.robot, self.duty, self.at, self.seen = robot, duty, at, 0

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def advance(self, duration_s, poses=None):
        if np.allclose(self.robot.duties, self.duty):
            self.seen += 1
            if self.seen >= self.at:
                raise KeyboardInterrupt("stopped by the test")
        self.robot.advance(duration_s, poses)


class StoppedMidTurn:
    """The mock stopped (KeyboardInterrupt) as it is to turn one-wheel step `at` (counting from 1)."""

    def __init__(self, robot, at):
        self.robot, self.at, self.seen = robot, at, 0

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def advance(self, duration_s, poses=None):
        if self.robot.duties.any():
            self.seen += 1
            if self.seen >= self.at:
                raise KeyboardInterrupt("stopped by the test")
        self.robot.advance(duration_s, poses)


def test_a_boards_phase_stopped_mid_pass_goes_on_with_that_pass_where_the_replay_left_it(tmp_path):
    """Resumed as on the robot (restart_phase), the robot left where it stopped, in the second pass (turning right,
    one step after the first pass ended facing the last board): the boards are tracked on from the replay's last view
    of them and the pass goes on to its board. It was started again as from the start board, which was not in view:
    the boards were misnamed and the pass ended one board early. The views before are kept."""
    robot = short_mock()
    try:
        result, _ = run_mission(robot, tmp_path / "whole", SHORT, states=(Boards,), transitions=BOARDS_ONLY)
        assert result.final == DONE, result.reason
        heading_rad = robot.pose()[2]
    finally:
        robot.close()
    whole = read_drive_log(tmp_path / "whole" / "log", check_images=False)
    robot = short_mock()
    try:
        result, _ = run_mission(StoppedMidTurn(robot, 6), tmp_path / "run", SHORT, states=(Boards,),
                                transitions=BOARDS_ONLY)
        assert result.final == INTERRUPTED
        before = read_drive_log(tmp_path / "run" / "log", check_images=False)
        assert 0 < np.sum(before.left_duty > 0) < np.sum(whole.left_duty > 0)  # the second pass under way
        result, ctx = run_mission(robot, tmp_path / "run", SHORT, states=(Boards,), transitions=BOARDS_ONLY,
                                  restart_phase=True)
        resumed_heading_rad = robot.pose()[2]
    finally:
        robot.close()
    assert result.final == DONE and ctx.restarted == "boards", result.reason
    after = read_drive_log(tmp_path / "run" / "log", check_images=False)
    (t_break,) = after.segment_t_s
    assert after.frame_files[:len(before.frame_files)] == before.frame_files
    segment = after.wheel_t_s > t_break  # right turns only: the second pass went on
    assert np.all((after.left_duty[segment] >= 0) & (after.right_duty[segment] <= 0))
    # it ended where the uninterrupted run's did (a step is about 12 deg), with its views and one at the restart
    assert abs(math.remainder(resumed_heading_rad - heading_rad, 2 * math.pi)) < math.radians(6.0)
    assert len(whole.frame_files) <= len(after.frame_files) <= len(whole.frame_files) + 1


UP_TO_DRIVES = {("boards", "ok"): "camera", ("camera", "ok"): "face_markers", ("face_markers", "ok"): "marker_drives",
                ("marker_drives", "ok"): DONE}


def test_a_run_stopped_mid_drive_and_carried_resumes_where_the_robot_stands(tmp_path):
    """Resumed as on the real robot (restart_phase: the mock's saved pose is not used): stopped in the marker drives'
    second leg, the robot carried 3 cm and turned 5.7 deg by hand, the run goes on: the captures kept, a break in
    the log with the wheels stopped there, the marker line found again (a frame before any drive), the drives done.
    The joint fit on such a log: tests/test_duckiebot_fit.py; the calibration against an uninterrupted run's:
    benchmarks/bench_duckiebot_resume.py."""
    states = (Boards, CalibrateCamera, FaceMarkers, MarkerDrives)
    state = tmp_path / "mock_state.json"
    robot = short_mock(state_path=state)
    try:
        result, _ = run_mission(StoppedMidDrive(robot, SHORT.drive_duties[1], 2), tmp_path, SHORT, states=states,
                                transitions=UP_TO_DRIVES)
    finally:
        robot.close()
    assert result.final == INTERRUPTED and result.history[-1].state == "marker_drives", result.reason
    before = read_drive_log(tmp_path / "log")
    kept = {name: (tmp_path / "log" / name).read_bytes() for name in before.frame_files}
    robot = short_mock(state_path=state)
    try:
        robot.carry(-0.03, 0.02, 0.1)
        result, ctx = run_mission(robot, tmp_path, SHORT, states=states, transitions=UP_TO_DRIVES,
                                  restart_phase=True)
    finally:
        robot.close()
    assert result.final == DONE, result.reason
    assert ctx.restarted == "marker_drives" and ctx.driven
    after = read_drive_log(tmp_path / "log")
    (t_break,) = after.segment_t_s
    assert t_break > max(before.wheel_t_s[-1], before.frame_t_s[-1])
    assert after.frame_files[:len(before.frame_files)] == before.frame_files
    assert all((tmp_path / "log" / name).read_bytes() == data for name, data in kept.items())
    first = np.searchsorted(after.wheel_t_s, t_break)
    assert after.wheel_t_s[first] == t_break and (after.left_duty[first], after.right_duty[first]) == (0.0, 0.0)
    # the line found again before any drive: a frame at rest after the stop, before the segment's next command
    assert np.any((after.frame_t_s > t_break) & (after.frame_t_s < after.wheel_t_s[first + 1]))
    # every leg driven after the break: both duties, out and back
    segment = after.wheel_t_s >= t_break
    for duty in SHORT.drive_duties[:2]:
        assert np.any(np.isclose(after.left_duty[segment], duty) & np.isclose(after.right_duty[segment], duty))
        assert np.any(np.isclose(after.left_duty[segment], -duty) & np.isclose(after.right_duty[segment], -duty))


def test_a_run_resumed_twice_as_on_the_robot_goes_on_at_each_break_and_still_identifies(tmp_path):
    """Resumed as on the real robot (restart_phase), stopped in the marker drives, resumed (the robot carried), stopped
    again inside the phase that resume started again, resumed again: the replay restarts the phase at the log's
    break as the first resume did (it refused the run as recorded with other options: the phase's own next action
    is not the break's stop), nothing sent but the stop before the second break, every capture kept byte for byte,
    two breaks, and the joint fit identifies the ideal robot from the log's three segments (through the run's own
    lens: identify_log would search the frames for boards again, tens of CPU seconds more)."""
    states = (Boards, CalibrateCamera, FaceMarkers, MarkerDrives)
    state = tmp_path / "mock_state.json"
    robot = short_mock(state_path=state)
    try:
        result, _ = run_mission(StoppedMidDrive(robot, SHORT.drive_duties[1], 2), tmp_path, SHORT, states=states,
                                transitions=UP_TO_DRIVES)
        assert result.final == INTERRUPTED and result.history[-1].state == "marker_drives", result.reason
        robot.carry(-0.03, 0.02, 0.1)
        # killed again in the phase started again: its second stretch out at the first leg's duty
        result, ctx = run_mission(StoppedMidDrive(robot, SHORT.drive_duties[0], 2), tmp_path, SHORT, states=states,
                                  transitions=UP_TO_DRIVES, restart_phase=True)
        assert result.final == INTERRUPTED and ctx.restarted == "marker_drives", result.reason
        before = read_drive_log(tmp_path / "log")
        assert len(before.segment_t_s) == 1 and before.frame_t_s[-1] > before.segment_t_s[0]
        kept = {name: (tmp_path / "log" / name).read_bytes() for name in before.frame_files}
        robot.carry(0.02, -0.01, -0.05)
        sent = len(robot.received)
        result, ctx = run_mission(robot, tmp_path, SHORT, states=states, transitions=UP_TO_DRIVES,
                                  restart_phase=True)
        truth = robot.truth.kinematics()
    finally:
        robot.close()
    assert result.final == DONE and ctx.restarted == "marker_drives" and ctx.driven, result.reason
    after = read_drive_log(tmp_path / "log")
    assert after.segment_t_s[0] == before.segment_t_s[0] and len(after.segment_t_s) == 2
    t_break = after.segment_t_s[1]
    assert t_break > max(before.wheel_t_s[-1], before.frame_t_s[-1])
    assert all((l, r) == (0.0, 0.0) for t, l, r in robot.received[sent:] if t <= t_break)  # the replay sent nothing
    assert after.frame_files[:len(before.frame_files)] == before.frame_files
    assert all((tmp_path / "log" / name).read_bytes() == data for name, data in kept.items())
    first = np.searchsorted(after.wheel_t_s, t_break)
    assert after.wheel_t_s[first] == t_break and (after.left_duty[first], after.right_duty[first]) == (0.0, 0.0)
    segment = after.wheel_t_s >= t_break  # the drives done again after the second break: both duties, out and back
    for duty in SHORT.drive_duties[:2]:
        assert np.any(np.isclose(after.left_duty[segment], duty) & np.isclose(after.right_duty[segment], duty))
        assert np.any(np.isclose(after.left_duty[segment], -duty) & np.isclose(after.right_duty[segment], -duty))
    calibration = calibrate(after, detect_log(after, boards=False), ctx.lens, ctx.lens_fits)
    fit, kin = calibration.drive_fit, calibration.kinematics
    assert {"anchor1.x_m", "anchor2.x_m"} <= set(fit.names) and fit.rms_px < 1.0  # a start pose for each segment after a break
    assert abs(kin.trim - truth.trim) < 0.001 and abs(kin.gain / truth.gain - 1) < 0.01
    assert abs(kin.baseline_m - truth.baseline_m) < 0.002


def test_resumed_as_on_the_robot_the_replay_ends_at_the_first_live_action_or_at_a_final_stop(tmp_path):
    """restart_phase: nothing is sent while the log replays; the first action past it ends the phase's replay
    (ReplayEnded), as does a stop an interrupted run logged where the phase goes on otherwise (a grab here), which
    the mock's own resume refuses as another run's."""
    robot = short_mock()
    try:
        first = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0)
        first.command(0.3, 0.3)
        robot.advance(0.1)
        first.stop()  # Ctrl-C during the wait: run_mission's finally logs the stop
        sent = len(robot.received)
        for restart in (True, False):
            again = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0, restart_phase=restart)
            again.command(0.3, 0.3)
            with pytest.raises(ReplayEnded if restart else NaocalError):
                again.grab()
        again = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0, restart_phase=True)
        again.command(0.3, 0.3)
        again.command(0.0, 0.0)  # the logged stop, replayed
        with pytest.raises(ReplayEnded):
            again.wait(0.1)
        assert len(robot.received) == sent
        again.new_segment()
        assert robot.received[sent][1:] == (0.0, 0.0) and again.live
        assert again.log.breaks == [again.log.wheels[-1][0]] and again.log.wheels[-1][1:] == (0.0, 0.0)
    finally:
        robot.close()


def test_a_break_the_log_holds_ends_the_phases_replay_and_is_replayed_as_it_was_made(tmp_path):
    """restart_phase on a log with a break (a run resumed once, then stopped again): the replay ends at the break at
    the first action past it, as at the log's end (it refused the phase's next action as another run's), nothing
    sent; replay_break replays the break's stop and leaves the robot-time budget where new_segment had it; at the
    log's end the next break follows. A break with no row of its own (new_segment cut short) is an empty part; one
    not at a stop is refused naming segments.csv, as is a log with breaks resumed as on the mock."""
    robot = short_mock()
    meta = log_meta("t", "test")

    def session():
        return Session(robot, tmp_path / "log", meta, SHORT, 0.0, restart_phase=True)

    try:
        first = Session(robot, tmp_path / "log", meta, SHORT, 0.0)
        first.command(0.3, 0.3)
        robot.advance(0.1)
        first.stop()
        once = session()
        once.command(0.3, 0.3)
        once.command(0.0, 0.0)
        with pytest.raises(ReplayEnded):
            once.wait(0.1)
        robot.advance(5.0)  # the robot stood dead before the resume
        once.new_segment()
        budget_s = once.t_start_s
        once.command(0.2, -0.2)
        robot.advance(0.1)
        once.stop()
        sent = len(robot.received)
        twice = session()
        twice.command(0.3, 0.3)
        twice.command(0.0, 0.0)
        with pytest.raises(ReplayEnded):
            twice.wait(0.1)  # the break: the first resume's phase started again here
        assert not twice.live
        twice.replay_break()
        assert twice.t_start_s == budget_s and twice.duties == (0.0, 0.0)
        twice.wait(SHORT.settle_s)
        twice.command(0.2, -0.2)  # the phase as it went after the break, replayed
        with pytest.raises(ReplayEnded):
            twice.grab()  # the final stop left, then the log's end
        assert twice.live and len(robot.received) == sent
        twice.new_segment()
        assert len(twice.log.breaks) == 2 and all(r[1:] == (0.0, 0.0) for r in robot.received[sent:])
        breaks = tmp_path / "log" / "segments.csv"
        # new_segment cut short after a break was saved, before its stop: its part is empty
        text = breaks.read_text()
        t_empty = (once.log.breaks[0] + once.log.wheels[np.searchsorted([w[0] for w in once.log.wheels],
                                                                       once.log.breaks[0]) - 1][0]) / 2
        breaks.write_text(text.split("\n", 1)[0] + f"\n{t_empty!r}\n" + text.split("\n", 1)[1])
        again = session()
        again.command(0.3, 0.3)
        again.command(0.0, 0.0)
        with pytest.raises(ReplayEnded):
            again.command(0.3, 0.3)
        again.replay_break()
        assert again.part == 2 and again.t_start_s == budget_s
        breaks.write_text(text.replace(repr(once.log.breaks[0]), repr(once.log.breaks[0] - 1e-3)))
        with pytest.raises(NaocalError, match="segments.csv: the break at .* is not where a resumed run stopped"):
            session()
        with pytest.raises(NaocalError, match="the log has breaks"):
            Session(robot, tmp_path / "log", meta, SHORT, 0.0)
        assert len(robot.received) == sent + 2  # new_segment's stops only
    finally:
        robot.close()


class CameraNotUp:
    """The mock whose camera gives no frame the first time it is asked (a camera node not started yet: the grab's
    deadline fails the run)."""

    def __init__(self, robot):
        self.robot, self.asked = robot, False

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def grab(self):
        if not self.asked:
            self.asked = True
            raise NaocalError("no camera frame within 2 s")
        return self.robot.grab()


def test_a_run_whose_first_grab_failed_resumes_with_each_board_view_on_its_frame(tmp_path):
    """The first frame never came (the run failed there, its log a stop and no frame), then `--resume` as on the
    robot: the grab the replay ended at is not counted as a frame, so the boards phase's views stay on the frames
    they were seen in (they were one frame off, one view more than frames) and the camera is fitted from them."""
    settings = MissionSettings(board_passes=1)
    to_camera = {("boards", "ok"): "camera", ("camera", "ok"): DONE}
    robot = short_mock()
    try:
        result, _ = run_mission(CameraNotUp(robot), tmp_path, settings, states=(Boards, CalibrateCamera),
                                transitions=to_camera)
        assert result.final == "failed" and "no camera frame" in result.reason
        assert not (tmp_path / "log" / "frames.csv").exists()
        result, ctx = run_mission(robot, tmp_path, settings, states=(Boards, CalibrateCamera), transitions=to_camera,
                                  restart_phase=True)
    finally:
        robot.close()
    assert result.final == DONE, result.reason
    frames = read_drive_log(tmp_path / "log", check_images=False).frame_files
    assert len(ctx.board_detections) == len(frames) and set(ctx.board_views) == set(range(len(frames)))
    assert [bool(views) for views in ctx.board_detections][:2] == [True, True]  # the start board, from the first


def test_no_marker_in_view_stops_within_the_bound(tmp_path):
    """Driving where no marker lies (facing the boards, away from the line), the robot stops once it has driven
    max_blind_m without seeing one: never farther than that and one check."""
    robot = short_mock()
    try:
        settings = MissionSettings(max_blind_m=0.3, check_every_m=0.1)
        session = Session(robot, tmp_path / "log", log_meta("t", "test"), settings, 0.0)
        lens = SimpleNamespace(camera=LensCamera.from_intrinsics(robot.truth.camera))
        calibration = SimpleNamespace(kinematics=robot.truth.kinematics(), lens=lens,
                                      T_base_camera=robot.truth.T_base_camera)
        ctx = MissionContext(robot, tmp_path, settings, session, calibration=calibration)
        start = robot.pose()
        with pytest.raises(NaocalError, match="no marker seen"):
            drive_watching(ctx, session, 2.0, stop_when_blind=False)
        travelled = np.linalg.norm(robot.pose()[:2] - start[:2])
        assert 0.25 < travelled <= settings.max_blind_m + settings.check_every_m + 0.01
    finally:
        robot.close()


def test_a_validation_curving_off_the_line_stops_and_is_measured_not_failed(tmp_path):
    """A compensation that curves the robot off the marker line (the PWM floor alone may, 20-34 cm over 2 m on the
    realistic mock): the drive stops where the markers leave the view (never farther than max_blind_m and a check
    beyond them) and the validation reports the drift measured at the last frame that saw them, with the bound the
    PWM floor allows, instead of failing."""
    robot = short_mock(realism="realistic", start_pose=(0.0, 0.0, math.pi))  # facing along the marker line
    try:
        settings = MissionSettings(max_blind_m=0.3, check_every_m=0.1)
        session = Session(robot, tmp_path / "log", log_meta("t", "test"), settings, 0.0)
        lens = SimpleNamespace(camera=LensCamera.from_intrinsics(robot.truth.camera))
        true = robot.truth.kinematics_at(settings.speed_mps)
        calibration = SimpleNamespace(kinematics=replace(true, trim=true.trim + 0.04), lens=lens,
                                      T_base_camera=robot.truth.T_base_camera,
                                      drive_fit=SimpleNamespace(names=[], pwm_driver=True))  # fitted through it
        ctx = MissionContext(robot, tmp_path, settings, session, calibration=calibration)
        outcome = Validation().run(ctx)
        v = ctx.validation
        assert outcome.name == "ok" and "stopped: curved off the marker line" in outcome.reason
        assert 0.2 < v["measured_at_m"] < v["driven_m"] < settings.validation_m
        assert abs(v["deviation_m"]) > 0.02 and 0.0 < v["pwm_bound_m"] < 0.4  # the bound over the distance measured
    finally:
        robot.close()


def test_calibrate_refuses_other_options_on_resume_and_bad_backends(tmp_path, capsys):
    from naocal.kinds.duckiebot.calibrate import _record, check_out_dir

    args = SimpleNamespace(backend="mock", seed=3, mock=None, out=str(tmp_path), resume=True,
                           effect=[], report=None, endpoint=None)
    record = _record(args)
    (tmp_path / "run.json").write_text(json.dumps({**record, "mock_seed": 4}))
    (tmp_path / "log").mkdir()
    with pytest.raises(NaocalError, match="other options.*mock_seed 3 .the run: 4"):
        check_out_dir(tmp_path, record, resume=True)
    with pytest.raises(NaocalError, match="already holds a Duckiebot calibration run: continue it with --resume"):
        check_out_dir(tmp_path, record, resume=False)
    for change, message in (({"backend": "naoqi"}, "runs on --backend mock or ros or bridge"),
                            ({"backend": "bridge"}, "needs --endpoint"), ({"seed": -1}, "--seed"),
                            ({"backend": "bridge", "endpoint": "tcp://db21.local:7790", "mock": "ideal"},
                             "--mock is the server's option"),
                            ({"effect": ["x=1"]}, "--effect")):
        with pytest.raises(NaocalError, match=message):
            _record(SimpleNamespace(**{**vars(args), **change}))
    # --resume over the bridge: as with --backend ros (tests/test_duckiebot_bridge.py resumes a killed run)
    assert _record(SimpleNamespace(**{**vars(args), "backend": "bridge", "endpoint": "tcp://db21.local:7790"}))[
        "endpoint"] == "tcp://db21.local:7790"


def test_calibrate_cli_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys):
    from naocal.tools.cli import main

    out = tmp_path / "run"
    for extra in (["--backend", "bridge"], ["--backend", "mock", "--seed", "-1"],
                  ["--backend", "mock", "--effect", "x=1"]):
        assert main(["calibrate", "--robot", "duckiebot", *extra, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "naocal calibrate: error:" in err
        assert not out.exists()


def test_a_fit_that_does_not_explain_the_drive_is_refused_and_not_written(tmp_path, monkeypatch):
    import naocal.kinds.duckiebot.mission as mission

    robot = short_mock()
    try:
        session = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0)
        written = []
        ctx = MissionContext(robot, tmp_path, SHORT, session, driven=True, on_calibration=written.append)
        bad = SimpleNamespace(drive_fit=SimpleNamespace(rms_px=26.5))  # realistic seed 1's local minimum
        monkeypatch.setattr(mission, "identify_log", lambda _, **options: bad)
        outcome = IdentifyDrive().run(ctx)
        assert outcome.name == "implausible" and "26.50 px" in outcome.reason
        assert written == [] and ctx.calibration is None
    finally:
        robot.close()


def test_a_replayed_command_matches_within_rounding_and_is_refused_beyond(tmp_path):
    """A resumed validation's compensated duties came out of a new process's joint fit 4e-12 off the recorded ones:
    the same command (what the robot was sent is kept); another command is refused, nothing sent."""
    robot = short_mock()
    try:
        live = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0)
        live.command(0.0, 0.0)
        robot.advance(0.1)
        live.command(0.31363786007679184, 0.3478764646158086)
        robot.advance(0.1)
        live.command(0.0, 0.0)
        sent = len(robot.received)
        replay = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0)
        replay.command(0.0, 0.0)
        replay.command(0.31363786007293204, 0.34787646461676885)
        assert replay.duties == (0.31363786007679184, 0.3478764646158086) and len(robot.received) == sent
        with pytest.raises(NaocalError, match="recorded run commanded"):
            Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0).command(0.1, 0.0)
        assert len(robot.received) == sent
    finally:
        robot.close()


def test_facing_the_markers_sees_one_large_low_in_the_image_on_both_sides(tmp_path):
    """The lens fit sees the image's lower half only through the floor markers (the boards stand in its upper 40 %):
    facing the line, the mission sees a marker large (usable by the lens fit), low in the image, near its left and
    its right side (realistic seed 1 before lens_views: one usable marker, its corners within u 202-465 px), and
    ends coaxial with the line again."""
    from naocal.kinds.duckiebot.detect import detect_markers
    from naocal.kinds.duckiebot.intrinsics import FLOOR_MIN_SIDE_PX

    robot = short_mock(seed=1, realism="realistic", start_pose=(0.0, 0.0, math.pi))  # facing along the marker line
    try:
        session = Session(robot, tmp_path / "log", log_meta("t", "test"), SHORT, 0.0)
        lens = SimpleNamespace(camera=LensCamera.from_intrinsics(robot.truth.camera))
        ctx = MissionContext(robot, tmp_path, SHORT, session, lens=lens)
        session.command(0.0, 0.0)  # the safe state first, as the mission's first state does
        assert FaceMarkers().run(ctx).name == "ok"
        log = read_drive_log(tmp_path / "log")
        low = []  # centres of the markers usable by the lens fit, below the image's middle
        for i in range(len(log.frame_files)):
            for s in detect_markers(log.load_frame(i)):
                side = np.linalg.norm(np.roll(s.corners_px, -1, axis=0) - s.corners_px, axis=1).min()
                centre = s.corners_px.mean(axis=0)
                if side >= FLOOR_MIN_SIDE_PX and centre[1] >= 0.55 * 480:
                    low.append(centre)
        u = np.array(low)[:, 0]
        assert u.min() < 0.25 * 640 and u.max() > 0.75 * 640, u
        # coaxial again: within the alignment tolerance and the camera mount's yaw (the nominal mount steers)
        assert abs(math.remainder(robot.pose()[2] - math.pi, 2 * math.pi)) < math.radians(5.0)
    finally:
        robot.close()
