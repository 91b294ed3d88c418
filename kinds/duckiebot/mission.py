"""The Duckiebot's calibration mission (issue 23): the seed paper's phases on the agent's state machine
(agent.machine.Machine), every command and frame saved at once in a drive log, resumable, the wheels stopped
however it ends.

    boards -> camera -> face_markers -> marker_drives -> identification -> validation -> leave -> done

- boards: one-wheel steps (a step, stop, settle, grab: sharp frames), turning left, right, left over the semicircle
  of boards, tracking which board is in view (identical boards: by continuity from the one in view at the start);
  recovery when none is: keep turning towards the next board for a bounded number of steps. Started again after
  a resume on the robot: the pass under way goes on from where the replay says the robot turned to (the boards
  tracked on from the replay's last view of them: the robot left where it stopped, or put back so); from the start
  board in view when the replay had seen none.
- camera: the intrinsics from every board view (kinds.duckiebot.identify.fit_intrinsics: lens model by held-out
  error).
- face_markers: spin in steps until floor markers are in view, then one-wheel steps until coaxial with the marker
  line (the markers' yaw, all oriented alike, through the fitted camera and the nominal mount); then on to the
  line's near end until a marker is low in the image and one-wheel steps left and right until it nears either side
  (lens_views: the lens fit's view of the image's lower half), and coaxial again.
- marker_drives: legs out along the line in short stretches (stop, grab) and back, longer each time, some ending with
  one-wheel turns (the joint fit needs turns in view of the markers to tell the baseline from trim), re-aligned at
  the start when the robot came back curved (kinds.duckiebot.render.joint_program's design, closed loop).
- identification: kinds.duckiebot.identify.identify_log on RUN/log (the joint fit); the caller writes the result.
- validation: 2 m straight at 0.3 m/s with the fitted compensation (Duckietown's inverse kinematics), frames while
  moving; the lateral offset from the marker line at rest before and after.
- leave: on along the line with the compensation until no marker has been seen for `max_blind_m`; stop.

Safety: every duty passes `Session.command` (finite, within [-limit, limit], else SafetyError before the robot
hears it); never more than `max_blind_m` (odometry's upper bound) driven without a marker in view; a robot-time
budget (a deadline over every wait); `run_mission`'s finally commands zero duty, also after Ctrl-C, SIGTERM
(tools.cli turns it into KeyboardInterrupt) or any exception.

Resume: the decisions are a function of the frames, so a resumed run replays its log (RUN/log, RUN/validation):
each command must be the one recorded (else refused: another run), each grab returns the saved frame, nothing is
sent to the robot; at the log's end the run goes live (a command in force when it stopped is sent again). No
capture is repeated. That holds where the robot's state is saved with the run (the mock). On the robot
(`restart_phase`) the replay only rebuilds the run: the wheels are commanded stopped first, and at the first live
action the phase the replay ended in starts again from its start conditions where the robot now stands
(RestartedPhase), after a break in the log (Session.new_segment): the joint fit gives each segment its own start
pose (kinds.duckiebot.fit). A log with breaks is replayed in parts: at each break the phase's replay ends and the
phase is replayed again from it (Session.replay_break), so a run resumes any number of times, one break each.
"""

from __future__ import annotations

import bisect
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from naocal.agent.machine import DONE, FAILED, Machine, Outcome, State
from naocal.kinds.duckiebot.detect import detect_boards, detect_markers
from naocal.kinds.duckiebot.drive_log import (MAX_IMAGE_BYTES, SCHEMA, SEGMENTS_FILE, DriveLogAppender, decode_image,
                                              read_drive_log)
from naocal.kinds.duckiebot.fit import PWM_DRIVER, duty_offset, marker_on_floor
from naocal.kinds.duckiebot.identify import Detections, fit_intrinsics, identify_log
from naocal.kinds.duckiebot.kinematics import duty_problem, inverse_kinematics, pwm_drift_bound_m
from naocal.kinds.duckiebot.render import BOARD_INNER_CORNERS, BOARD_SQUARE_M, MARKER_SIZE_M
from naocal.kinds.duckiebot.robot import DEFAULT_K, DEFAULT_LIMIT, duckiebot
from naocal.solver.errors import NaocalError, SafetyError
from naocal.solver.fileio import read_bytes

log = logging.getLogger(__name__)

CALIBRATION_LOG, VALIDATION_LOG = "log", "validation"
# The joint fit's wheel effects on the mission's drives (fit.EFFECTS): the motors' start (two drive duties tell it
# from the slope) and their lags, each wheel's: stop-and-go with lags 5 % apart creeps the robot sideways (the
# realistic mock, seed 1: 2.9 px RMS and the trim 0.004 off without them, 0.48 px and 0.0002 with)
FIT_EFFECTS = ("dead_zone", "wheel_lag", "lag_difference")
# A replayed command may differ from the recorded one by this much: the joint fit is not bit-identical from one
# process to the next (a resumed validation's compensated duties differed by 4e-12)
REPLAY_TOLERANCE = 1e-6

# (state, outcome) -> next state: the mission's whole control flow.
TRANSITIONS = {
    ("boards", "ok"): "camera",
    ("camera", "ok"): "face_markers",
    ("face_markers", "ok"): "marker_drives",
    ("marker_drives", "ok"): "identification",
    ("identification", "ok"): "validation",
    ("identification", "implausible"): FAILED,
    ("validation", "ok"): "leave",
    ("leave", "ok"): DONE,
}


@dataclass(frozen=True)
class MissionSettings:
    n_boards: int = 3  # identical boards on the semicircle, numbered counter-clockwise
    start_board: int = 1  # the one in view at the start (given, as in the paper)
    step_duty: float = 0.25  # one-wheel steps: duty and time (about 12 deg on a nominal robot)
    step_s: float = 0.1
    settle_s: float = 0.4  # stop, then wait this long before grabbing: a 60 ms wheel lag has left 0.1 %
    board_passes: int = 3  # left, right, left
    max_board_steps: int = 30  # per pass
    max_blind_steps: int = 8  # recovery: steps towards the next board with none in view before giving up
    spin_duty: float = 0.3  # turning towards the marker line on the spot
    spin_s: float = 0.1
    max_spin_steps: int = 30
    align_tolerance_rad: float = math.radians(2.0)
    max_align_steps: int = 12
    lens_view_depths: tuple = (0.6, 0.75)  # lens views: drive on until the lowest marker's centre is this far down
    # the image (of its height: 0.6, a marker about 0.16 m ahead of the camera; 0.75, its near edge at the bottom)
    max_approach_steps: int = 10  # stretches of drive_s / 2 at drive_duties[0] (about 3 cm each) towards it
    sweep_margin: float = 0.12  # then turn until the marker's centre is this near (of the width) an image edge
    max_sweep_steps: int = 16  # one-wheel half steps (about 6 deg) each way
    drive_duties: tuple = (0.3, 0.45, 0.3)  # each leg's duty: two duties tell the motors' start (the fit's
    # dead_zone, with the driver's PWM floor) from their slope; they bracket the 0.3 m/s drive's (0.27-0.45 on real
    # robots' gains 0.7-1.3), where the exported gain is the secant (fit.secant_gain)
    drive_s: float = 0.25
    legs: tuple = (2, 3, 4)  # out-and-back legs along the line, in stretches: driving back undoes the heading a
    # wrong trim adds driving out, so the joint fit's start (trim 0) stays close to the drive (one long leg out, then
    # back, curved a large-trim robot off its start values: the fit failed on trim 0.065)
    wiggles: int = 2  # legs ending with one-wheel turns left, right, right, left
    realign_rad: float = math.radians(4.0)  # re-align along the line when curved off by more
    validation_m: float = 2.0
    speed_mps: float = 0.3
    check_every_m: float = 0.1  # validation / leave: a frame while moving this often
    max_blind_m: float = 0.3  # never drive farther than this without a marker in view
    max_leave_m: float = 1.5
    max_fit_rms_px: float = 3.0  # beyond this joint-fit RMS the result is refused (ideal mock, seed 4: 0.55 px)
    max_robot_time_s: float = 600.0  # the deadline over the whole mission's waits
    limit: float = 1.0  # the duty limit (Duckietown's kinematics `limit`)


def log_meta(robot_id: str, source: str) -> dict:
    nominal = duckiebot("DB21")
    return {"schema": SCHEMA, "robot": {"id": robot_id, "model": nominal.model},
            "camera": {"width_px": nominal.camera.width_px, "height_px": nominal.camera.height_px},
            "wheels": {"radius_m": nominal.radius_m, "baseline_m": nominal.baseline_m, "k": DEFAULT_K,
                       "limit": DEFAULT_LIMIT},  # the ROS driver checks its encoder rows with these (its `wheels`)
            "markers": {"family": "tag36h11", "size_m": MARKER_SIZE_M},
            "boards": {"inner_corners": list(BOARD_INNER_CORNERS), "square_m": BOARD_SQUARE_M}, "source": source}


# ------------------------------------------------------------------------------------------------ the session

class ReplayEnded(Exception):
    """A resumed run's replay has reached the log's end inside a phase, on a robot whose state was not saved (the
    real one): the phase starts again from its start conditions (RestartedPhase), never from the old pose. Or it
    has reached a break the log holds (Session._end_of_part): the phase is replayed again from there."""

    def __init__(self, session):
        super().__init__("the replay reached the log's end or a break")
        self.session = session


class Session:
    """The agent's one path to the robot for one drive log: commands, waits, grabs, each saved at once; replays a
    log recorded before (resume) without moving the robot."""

    def __init__(self, robot, log_dir: Path, meta: dict, settings: MissionSettings, t_start_s: float,
                 restart_phase: bool = False):
        self.robot, self.settings = robot, settings
        # the robot's state was not saved with the log: at the replay's end the phase starts again (ReplayEnded)
        self.restart_phase = restart_phase
        self.grabbed = 0  # frames grabbed or replayed: the last one is the log's frame grabbed - 1
        self.log = DriveLogAppender(log_dir, meta)
        self.t_start_s = self.log.wheels[0][0] if self.log.wheels else t_start_s  # the budget runs from the first run
        # at one time a frame came first: a frame is never older than the command before it (grab), but the next
        # command may carry its time (a ROS camera's stamp: the fake peer's frames and commands share a clock tick)
        events = sorted([(t, 1, ("wheels", left, right)) for t, left, right in self.log.wheels]
                        + [(t, 0, ("frame", name)) for t, name in self.log.frames])
        self.replay, self.replay_t_s = [e[2] for e in events], [e[0] for e in events]
        self.cursor = 0
        # the replay in parts, one per break (a resume started the phase again there: new_segment): each part's end
        # ends the phase's replay as the log's end does, and the phase is replayed again from the break (replay_break)
        if self.log.breaks and not restart_phase:
            raise NaocalError(f"{self.log.directory}: the log has breaks (segments.csv: a run resumed on the robot); "
                              "resume it on the robot's backend (nothing was sent to the robot)")
        self.part_ends = [bisect.bisect_left(self.replay_t_s, t) for t in self.log.breaks] + [len(self.replay)]
        for t, start, end in zip(self.log.breaks, self.part_ends, self.part_ends[1:]):
            # each part starts with new_segment's stop at its break, or is empty (new_segment cut short before it)
            if start < end and (self.replay_t_s[start] != t or self.replay[start] != ("wheels", 0.0, 0.0)):
                raise NaocalError(f"{self.log.directory / SEGMENTS_FILE}: the break at {t!r} s is not where a resumed "
                                  "run stopped the wheels (a stop at that time in wheels.csv): not a log this mission "
                                  "wrote (nothing was sent to the robot)")
        self.part = 0  # the part being replayed
        self.duties = (0.0, 0.0)  # the command in force, as logged
        self.resumed = self.live  # a replay has ended and the run gone on live

    @property
    def live(self) -> bool:
        return self.cursor >= len(self.replay)

    def _only_stops_left(self) -> bool:
        """With restart_phase, the log's remaining events are all stops: a run interrupted (Ctrl-C, SIGTERM) logs its
        final stop where the phase would have gone on. The replay ends there: the phase starts again anyway."""
        if not self.restart_phase:
            return False
        end = self.part_ends[self.part]
        if all(e[0] == "wheels" and e[1] == e[2] == 0.0 for e in self.replay[self.cursor:end]):
            self.cursor = end
            return True
        return False

    def _end_of_part(self) -> bool:
        """The replay stands at a break the log holds, not at its end: what follows was logged after the phase was
        started again there, so the phase's replay ends here (ReplayEnded; RestartedPhase calls replay_break)."""
        return not self.live and self.cursor == self.part_ends[self.part]

    def _next_recorded(self, kind: str, duties=None):
        if self.live:
            return None
        if self._end_of_part():
            raise ReplayEnded(self)
        event = self.replay[self.cursor]
        differs = event[0] != kind or (duties is not None and max(abs(event[1] - duties[0]),
                                                                  abs(event[2] - duties[1])) > REPLAY_TOLERANCE)
        if differs and self._only_stops_left():
            if self._end_of_part():
                raise ReplayEnded(self)
            return None
        if event[0] != kind:
            raise NaocalError(f"{self.log.directory}: the recorded run took a {event[0]} where this one takes a {kind} "
                              f"(event {self.cursor + 1}): it was recorded with other options or another robot; "
                              "resume it with the same ones (nothing was sent to the robot)")
        self.cursor += 1
        return event

    def _go_on(self) -> None:
        """At the end of a replay: a command in force when the run stopped is sent again (the robot stopped)."""
        if self.live and not self.resumed and not self.restart_phase:
            self.resumed = True
            if self.duties != (0.0, 0.0):
                self._send(*self.duties)

    def _live(self) -> None:
        """Before anything live: with `restart_phase`, the first live action after a replay ends the phase's replay
        (ReplayEnded), so that a phase the log holds whole is not started again."""
        if not self.resumed:
            raise ReplayEnded(self)

    def new_segment(self) -> None:
        """Go on live where the replay ended, the robot wherever it now stands: the wheels commanded stopped, a break
        in the log (drive_log's segments.csv: the joint fit gives what follows its own start pose), settled. The
        robot-time budget counts the time the robot was driven, not the time it stood dead."""
        self.robot.command(0.0, 0.0)
        self.robot.advance(self.settings.settle_s)  # at rest before the segment starts (and its clock past the log)
        t = self.robot.command(0.0, 0.0)
        last = self.log.last_time_s()
        if not t > last:
            raise NaocalError(f"the robot's clock ({t:.3f} s) is not after the log's last row ({last:.3f} s): it "
                              f"cannot continue {self.log.directory} (nothing was sent but a stop)")
        if self.log.wheels:
            self.t_start_s += t - last
        self.log.add_break(t)
        self.log.add_wheels(t, 0.0, 0.0)
        self.duties, self.resumed = (0.0, 0.0), True
        self.wait(self.settings.settle_s)  # the phase's first row after the stop's, on any robot clock

    def replay_break(self) -> None:
        """Replay a break the log holds (the replay at its part's end: _end_of_part) as new_segment made it: its stop
        row, the budget's dead time left out; nothing is sent. The phase is then replayed again from its start."""
        while self.part_ends[self.part + 1] == self.cursor:
            self.part += 1  # a break with no row of its own (new_segment cut short before its stop): an empty part
        t = self.log.breaks[self.part]  # its stop row at the cursor (checked when the log was opened)
        if self.log.wheels[0][0] < t:  # as new_segment: the time the robot stood dead is not the mission's
            self.t_start_s += t - self.replay_t_s[self.cursor - 1]
        self.cursor += 1
        self.part += 1
        self.duties = (0.0, 0.0)

    def _send(self, left: float, right: float) -> None:
        t = self.robot.command(left, right)
        self.log.add_wheels(t, left, right)

    def command(self, left: float, right: float) -> None:
        limit = self.settings.limit
        for name, duty in (("left", left), ("right", right)):
            problem = duty_problem(name, duty, limit)
            if problem:
                raise SafetyError(f"refused wheel command: {problem}")
        left, right = float(left), float(right)
        recorded = self._next_recorded("wheels", (left, right))
        if recorded is None:
            self._live()
            self._send(left, right)
        elif max(abs(recorded[1] - left), abs(recorded[2] - right)) > REPLAY_TOLERANCE:
            raise NaocalError(f"{self.log.directory}: the recorded run commanded {recorded[1]!r}, {recorded[2]!r} "
                              f"where this one commands {left!r}, {right!r} (event {self.cursor}): resume it with the "
                              "same options and robot (nothing was sent to the robot)")
        else:
            left, right = recorded[1], recorded[2]  # what the robot was sent
        self.duties = (left, right)
        self._go_on()

    def wait(self, duration_s: float) -> None:
        if self._end_of_part():  # as at the log's end (_live): the phase's replay ends at the first action past it
            raise ReplayEnded(self)
        if not self.live:
            return
        self._live()
        if self.robot.now() - self.t_start_s + duration_s > self.settings.max_robot_time_s:
            raise NaocalError(f"the mission's robot-time budget ({self.settings.max_robot_time_s:g} s) is spent: "
                              "stopped")
        self.robot.advance(duration_s)

    def hold(self, left: float, right: float, duration_s: float) -> None:
        """Drive at duties for `duration_s`, then stop and settle (the frame grabbed next is sharp)."""
        self.command(left, right)
        self.wait(duration_s)
        self.command(0.0, 0.0)
        self.wait(self.settings.settle_s)

    def grab(self) -> np.ndarray:
        """A grey frame: the saved one when replaying, else a new one from the robot, saved before it is used."""
        recorded = self._next_recorded("frame")
        if recorded is not None:
            path = self.log.directory / recorded[1]
            image = decode_image(read_bytes(path, max_bytes=MAX_IMAGE_BYTES), path, cv2.IMREAD_GRAYSCALE)
            self.grabbed += 1
            self._go_on()
            return image
        self._live()
        t_command = self.log.wheels[-1][0] if self.log.wheels else -math.inf
        t, image = self.robot.grab()
        if not t > t_command:  # a frame exposed before the last command is stale: never decide on it
            raise NaocalError(f"the camera returned a frame of {t:.3f} s, before the last command ({t_command:.3f} s)")
        self.log.add_frame(t, f"frames/{len(self.log.frames):06d}.png", image)
        self.grabbed += 1  # counted once saved: a grab the replay ended at, or that failed, is no frame
        return image

    def stop(self) -> None:
        """The safe state: wheels at zero duty, logged when live. Never raises for the log (the robot first)."""
        t = self.robot.command(0.0, 0.0)
        if self.live and self.duties != (0.0, 0.0):
            try:
                self.log.add_wheels(max(t, self.log.last_time_s() + 1e-6), 0.0, 0.0)
                self.duties = (0.0, 0.0)
            except Exception:  # the wheels are stopped; a log that cannot take the row must not hide why we stopped
                log.exception("could not log the final stop")


# ------------------------------------------------------------------------------------------------ the context

@dataclass
class MissionContext:
    robot: object
    out_dir: Path
    settings: MissionSettings
    session: Session
    validation_session: Session | None = None
    board_detections: list = field(default_factory=list)  # per frame of the boards phase
    lens: object = None  # LensFit
    lens_fits: object = None
    facing: object = None  # True once coaxial with the marker line
    driven: object = None
    calibration: object = None  # DuckiebotCalibration
    validation: object = None  # dict
    left_area: object = None
    blind_m: float = 0.0  # distance driven (upper bound) since a marker was last in view
    last_seen: object = None  # (distance driven, markers) of the last frame with markers of a compensated drive
    on_calibration: object = None  # callable(calibration): the caller writes it (RUN/offsets.json)
    board_views: dict = field(default_factory=dict)  # {frame index: boards detected}: kept when a phase restarts
    board_passes_done: int = 0  # the boards' passes done: a boards phase started again turns the others only
    board_tracker: object = None  # BoardTracker: a boards phase started again goes on from the replay's last view
    restarted: str | None = None  # the phase started again after a resume (RestartedPhase)

    @property
    def pwm_driver(self) -> bool:
        """The robot's duties pass Duckietown's 8-bit PWM driver (the mock's realistic physics, the ROS bridge): the
        joint fit models it (fit.Drive.pwm_driver). A robot that does not say sends exact duties."""
        return bool(getattr(self.robot, "pwm_driver", False))


def _wrap(angle: float) -> float:
    return math.remainder(angle, 2.0 * math.pi)


def nominal_omega(duty: float, one_wheel: bool) -> float:
    """rad/s of turn for a one-wheel step (or a spin) at duty on a nominal robot (gain 1, k 27)."""
    nominal = duckiebot("DB21")
    wheel = duty * 27.0 * nominal.radius_m
    return wheel / nominal.baseline_m * (1.0 if one_wheel else 2.0)


def nominal_distance_bound(duty: float, duration_s: float) -> float:
    """An upper bound of the distance driven at duty for duration_s on an uncalibrated robot (real robots' speeds
    are 30-40 % off the nominal: 1.5 times)."""
    return 1.5 * abs(duty) * 27.0 * duckiebot("DB21").radius_m * duration_s


def saw_marker(ctx: MissionContext, markers, distance_m: float) -> None:
    """The out-of-area rule: after driving `distance_m` (an upper bound), markers in view reset the count; none for
    more than max_blind_m stops the robot (NaocalError: the run fails with the wheels stopped)."""
    if markers:
        ctx.blind_m = 0.0
        return
    ctx.blind_m += distance_m
    if ctx.blind_m > ctx.settings.max_blind_m:  # run_mission's finally stops the wheels at once
        raise NaocalError(f"no marker seen for {ctx.blind_m:.2f} m (more than {ctx.settings.max_blind_m:g} m): "
                          "stopped before leaving the marked area")


def turn_step(session: Session, settings: MissionSettings, direction: int, step: int, duration_s=None) -> None:
    """A one-wheel step turning left (direction +1, counter-clockwise) or right (-1): alternately the outer wheel
    forward and the inner wheel back, so the robot turns about each wheel in turn and does not creep forward."""
    d, dt = settings.step_duty, settings.step_s if duration_s is None else duration_s
    forward = step % 2 == 0
    if direction > 0:
        session.hold(0.0 if forward else -d, d if forward else 0.0, dt)
    else:
        session.hold(d if forward else 0.0, 0.0 if forward else -d, dt)


# ------------------------------------------------------------------------------------------------ boards

TRACK_PX = 120.0  # a board in this frame within this of where the last frame's was expected is the same board


class BoardTracker:
    """Which of the identical boards are in view: continuity from the previous frame (boards move across the image
    as the robot turns: left turns move them right), the image order (boards numbered counter-clockwise appear
    right to left), and while none is in view, the side a new one enters from."""

    def __init__(self, n_boards: int, start_board: int, width_px: int):
        self.n, self.width = n_boards, width_px
        self.previous = {}  # index -> centre u px in the last frame with boards
        self.shift_px = 0.0  # image motion per step, learnt
        self.start = start_board
        self.last_seen = {}  # index -> u when last seen

    def update(self, centres_u, direction: int) -> dict:
        """{board index: centre u} for this frame's board centres."""
        us = sorted(centres_u)
        if not us:
            return {}
        if not self.last_seen:  # the first view: the board nearest the centre is the start board
            nearest = int(np.argmin([abs(u - self.width / 2) for u in us]))
            leftmost = self.start + nearest
        else:
            leftmost = self._leftmost(us, direction)
        found = {leftmost - i: u for i, u in enumerate(us) if 0 <= leftmost - i < self.n}
        matched = [found[i] - self.previous[i] for i in found if i in self.previous]
        if matched:
            self.shift_px = float(np.median(matched))
        self.previous = found
        self.last_seen.update(found)
        return found

    def _leftmost(self, us, direction: int) -> int:
        guess = self.shift_px if self.shift_px * direction > 0 else direction * 60.0
        if self.previous:
            best = None
            for index, u_before in self.previous.items():
                distances = [abs(u - (u_before + guess)) for u in us]
                rank = int(np.argmin(distances))
                if distances[rank] < TRACK_PX and (best is None or distances[rank] < best[0]):
                    best = (distances[rank], index + rank)
            if best is not None:
                return best[1]
        # none to follow (recovery, or a jump): a board entering while turning left comes in on the left and is the
        # next counter-clockwise; turning right, on the right and the next clockwise
        seen = sorted(self.last_seen)
        if direction > 0:
            edge = us[0] < self.width / 2
            return min(self.n - 1, seen[-1] + 1) if edge else seen[-1] + len(us) - 1
        edge = us[-1] > self.width / 2
        rightmost = max(0, seen[0] - 1) if edge else seen[0]
        return rightmost + len(us) - 1


class Boards(State):
    name = "boards"
    produces = ("board_detections",)

    def run(self, ctx: MissionContext) -> Outcome:
        s, session = ctx.settings, ctx.session
        width = duckiebot("DB21").camera.width_px
        tracker = ctx.board_tracker
        if tracker is None:
            tracker = ctx.board_tracker = BoardTracker(s.n_boards, s.start_board, width)

        def look(direction):
            image = session.grab()
            boards = detect_boards(image, BOARD_INNER_CORNERS, BOARD_SQUARE_M)
            ctx.board_views[session.grabbed - 1] = boards  # the views of a phase restarted are kept
            return tracker.update([float(b.corners_px[..., 0].mean()) for b in boards], direction)

        session.command(0.0, 0.0)  # the safe state first
        # started again after the replay saw boards (check_restart): no step since its last view; else the start board
        look(0 if tracker.previous else +1)
        goals = [(+1, s.n_boards - 1), (-1, 0), (+1, s.start_board)]  # turn until this board passes the centre
        step = 0
        passes = (goals * s.board_passes)[:s.board_passes]
        for index in range(ctx.board_passes_done, len(passes)):  # started again: the pass under way goes on
            direction, goal = passes[index]
            blind = 0
            for _ in range(s.max_board_steps):
                turn_step(session, s, direction, step)
                step += 1
                found = look(direction)
                blind = 0 if found else blind + 1
                if blind > s.max_blind_steps:
                    raise NaocalError(f"no board seen in {blind} steps turning {'left' if direction > 0 else 'right'} "
                                      "(recovery failed): are the boards set up on the semicircle?")
                u = found.get(goal)
                if u is not None and (u - width / 2) * direction >= 0:
                    break
            else:
                raise NaocalError(f"board {goal} did not come into the middle of the view within "
                                  f"{s.max_board_steps} steps")
            ctx.board_passes_done = index + 1
        detections = [ctx.board_views.get(i, []) for i in range(session.grabbed)]
        ctx.board_detections = detections
        n_views = sum(len(d) for d in detections)
        return Outcome("ok", f"{len(detections)} frames, {n_views} board views")


    @staticmethod
    def check_restart(ctx: MissionContext, session: Session) -> None:
        """The start conditions of a boards phase started again (RestartedPhase), checked before its break is logged:
        after the replay saw boards, the robot stands where it stopped, so a board is in view within TRACK_PX of where
        the replay's last view had one (the tracker goes on from it). Else NaocalError naming the board to face,
        nothing logged (the frame looked at is not kept): the robot put back as it stood, the run resumes again."""
        last = ctx.board_tracker.previous if ctx.board_tracker is not None else {}
        if not last:
            return  # the replay saw no board: the start board in view, as when a run starts
        _, image = session.robot.grab()
        us = [float(b.corners_px[..., 0].mean()) for b in detect_boards(image, BOARD_INNER_CORNERS, BOARD_SQUARE_M)]
        if not any(abs(u - u_last) < TRACK_PX for u in us for u_last in last.values()):
            width = duckiebot("DB21").camera.width_px
            facing = min(last, key=lambda i: abs(last[i] - width / 2))
            raise NaocalError(f"the boards are not where the stopped run last saw them (board {facing}, counted "
                              f"counter-clockwise from 0, at u {last[facing]:.0f} px): the robot was moved since; put "
                              "it back as it stood and resume again (nothing was logged, nothing moved)")


class CalibrateCamera(State):
    name = "camera"
    needs = ("board_detections",)
    produces = ("lens",)

    def run(self, ctx: MissionContext) -> Outcome:
        drive_log = read_drive_log(ctx.session.log.directory, check_images=False)
        boards = ctx.board_detections + [[]] * (len(drive_log.frame_files) - len(ctx.board_detections))
        ctx.lens, ctx.lens_fits = fit_intrinsics(drive_log, Detections([[]] * len(boards), boards))
        return Outcome("ok", f"{ctx.lens.camera.model}, held-out {ctx.lens.held_out_rms_px:.3f} px")


# ------------------------------------------------------------------------------------------------ the marker line

def markers_on_floor(image, lens, T_base_camera) -> dict:
    """{id: (x, y, yaw) in the base frame} of the markers in a frame, through a fitted lens and a camera pose."""
    out = {}
    K = lens.camera.K
    for s in detect_markers(image):
        n = lens.camera.normalised(s.corners_px)
        uv = np.column_stack([K[0, 0] * n[:, 0] + K[0, 1] * n[:, 1] + K[0, 2], K[1, 1] * n[:, 1] + K[1, 2]])
        out[s.id] = marker_on_floor(uv, np.arange(4), K, T_base_camera, MARKER_SIZE_M)
    return out


def line_error(markers: dict) -> tuple[float, float]:
    """(heading error rad: turn this much counter-clockwise to face along the line towards its far end (the
    markers' tops point back towards the boards, -x of the robot when coaxial), lateral offset m of the robot from
    the line, left positive), medians over the markers seen."""
    heading = [_wrap(math.pi + pose[2]) for pose in markers.values()]
    lateral = []
    for x, y, yaw in markers.values():
        c, s = math.cos(yaw), math.sin(yaw)
        lateral.append(s * x - c * y)  # the robot's y in the marker's frame: across the line
    return float(np.median(heading)), float(np.median(lateral))


def align(ctx: MissionContext, lens, T_base_camera, session: Session, markers=None) -> dict:
    """One-wheel steps (at most one step_s each: small turns keep the joint fit's start values close) until coaxial
    with the marker line; `markers`: those of the frame just grabbed (else one is grabbed). Returns the last frame's
    markers."""
    s = ctx.settings
    if markers is None:
        markers = markers_on_floor(session.grab(), lens, T_base_camera)
    for step in range(s.max_align_steps):
        if not markers:
            raise NaocalError("lost the marker line while aligning with it")
        error, _ = line_error(markers)
        if abs(error) <= s.align_tolerance_rad:
            return markers
        duration = min(s.step_s, max(0.01, abs(error) / nominal_omega(s.step_duty, True)))
        turn_step(session, s, 1 if error > 0 else -1, step, duration)
        markers = markers_on_floor(session.grab(), lens, T_base_camera)
    raise NaocalError(f"not coaxial with the marker line after {s.max_align_steps} steps")


def marker_centres(image) -> dict:
    """{id: (u, v) px} of the centres of the markers detected in a frame."""
    return {s.id: tuple(s.corners_px.mean(axis=0)) for s in detect_markers(image)}


def lens_views(ctx: MissionContext, session: Session) -> int:
    """Frames of floor markers large in the image's lower half, from one side to the other: the lens fit's view of
    the lower half (the boards are seen only in the upper 40 %, and the marker drives see the markers near the
    image's middle column: realistic mock seed 1, one marker of 30 px or more, in u 202-465, v 255-435 px). From
    coaxial with the line, for each of `lens_view_depths`: on along it in short stretches until the lowest marker's
    centre is that far down the image, then one-wheel half steps left until that marker nears the image's right
    edge (or leaves the view), right until it nears the left edge, and left until it is past the middle again; each
    frame grabbed at rest. Returns the frames grabbed."""
    s = ctx.settings
    width, height = duckiebot("DB21").camera.width_px, duckiebot("DB21").camera.height_px
    duty, duration = s.drive_duties[0], s.drive_s / 2
    frames = 0

    def look(distance_m):
        nonlocal frames
        frames += 1
        centres = marker_centres(session.grab())
        saw_marker(ctx, centres, distance_m)
        return centres

    def lowest(centres):
        return max(centres, key=lambda i: centres[i][1]) if centres else None

    def turn_until(target, direction, stop):
        """Half steps towards `direction` until stop(centre, or None when the target has been missed twice in a row:
        the detector misses a large marker now and then) once the target has been seen (max_sweep_steps at most);
        returns whether it stopped so."""
        seen, missed = False, 0
        for step in range(s.max_sweep_steps):
            turn_step(session, s, direction, step, s.step_s / 2)
            centre = look(nominal_distance_bound(s.step_duty, s.step_s / 2)).get(target)
            seen = seen or centre is not None
            missed = 0 if centre is not None else missed + 1
            if seen and (stop(centre) if centre is not None else missed >= 2 and stop(None)):
                return True
        return False

    edge = (0.5 - s.sweep_margin) * width
    centres = look(0.0)
    for depth in s.lens_view_depths:
        for _ in range(s.max_approach_steps):
            target = lowest(centres)
            if target is None:
                raise NaocalError("lost the marker line while approaching it")
            if centres[target][1] >= depth * height:
                break
            session.hold(duty, duty, duration)
            previous, centres = centres[target], look(nominal_distance_bound(duty, duration))
            if target not in centres and lowest(centres) is not None and centres[lowest(centres)][1] < previous[1]:
                break  # the nearest has left the view at the bottom: sweep with the next
        target = lowest(centres)
        turn_until(target, +1, lambda c: c is None or c[0] - width / 2 >= edge)  # left: the floor moves right
        turn_until(target, -1, lambda c: c is None or width / 2 - c[0] >= edge)
        if not turn_until(target, +1, lambda c: c is not None and c[0] >= width / 2):
            raise NaocalError("lost the marker line turning back to it")
        centres = look(0.0)
    return frames


def acquire_line(ctx: MissionContext, lens, T_base_camera, session: Session) -> dict:
    """Spin on the spot in steps until floor markers are in view, then align with their line (align); returns the
    last frame's markers. From wherever the robot stands: the start of facing the markers, and of a phase started
    again after a resume."""
    s = ctx.settings
    for _ in range(s.max_spin_steps):
        markers = markers_on_floor(session.grab(), lens, T_base_camera)
        if markers:
            return align(ctx, lens, T_base_camera, session, markers)
        session.hold(-s.spin_duty, s.spin_duty, s.spin_s)
    raise NaocalError(f"no floor marker in view after {s.max_spin_steps} turns on the spot")


class FaceMarkers(State):
    name = "face_markers"
    needs = ("lens",)
    produces = ("facing",)

    def run(self, ctx: MissionContext) -> Outcome:
        session = ctx.session
        mount = duckiebot("DB21").T_base_camera  # the nominal mount: its pose is the joint fit's to find
        acquire_line(ctx, ctx.lens, mount, session)
        views = lens_views(ctx, session)
        align(ctx, ctx.lens, mount, session)
        ctx.facing = True
        return Outcome("ok", f"{views} frames of a marker low in the image, left to right")


class MarkerDrives(State):
    name = "marker_drives"
    needs = ("facing",)
    produces = ("driven",)

    def run(self, ctx: MissionContext) -> Outcome:
        s, session = ctx.settings, ctx.session
        mount = duckiebot("DB21").T_base_camera
        if ctx.restarted == self.name:  # resumed wherever the robot stands: the line found again first
            acquire_line(ctx, ctx.lens, mount, session)

        def drive(duty):
            session.hold(duty, duty, s.drive_s)
            markers = markers_on_floor(session.grab(), ctx.lens, mount)
            saw_marker(ctx, markers, nominal_distance_bound(duty, s.drive_s))
            return markers

        for leg, stretches in enumerate(s.legs):
            duty = s.drive_duties[leg % len(s.drive_duties)]
            for _ in range(stretches):
                drive(duty)
            if leg < s.wiggles:  # turns in view of the markers: the baseline, told from trim
                for step, direction in enumerate((+1, -1, -1, +1)):
                    turn_step(session, s, direction, step, s.step_s / 2)
                    markers_on_floor(session.grab(), ctx.lens, mount)
            for _ in range(stretches):
                markers = drive(-duty)
            if markers and abs(line_error(markers)[0]) > s.realign_rad:
                align(ctx, ctx.lens, mount, session, markers)
        ctx.driven = True
        return Outcome("ok", f"{len(session.log.frames)} frames in all")


class IdentifyDrive(State):
    name = "identification"
    needs = ("driven",)
    produces = ("calibration",)

    def run(self, ctx: MissionContext) -> Outcome:
        calibration = identify_log(ctx.session.log.directory, speed_mps=ctx.settings.speed_mps,
                                   effects=FIT_EFFECTS + ((PWM_DRIVER,) if ctx.pwm_driver else ()))
        rms = calibration.drive_fit.rms_px
        if not rms <= ctx.settings.max_fit_rms_px:  # never drive on (nor write) what does not explain the drive
            return Outcome("implausible", f"the joint fit leaves {rms:.2f} px RMS (more than "
                                          f"{ctx.settings.max_fit_rms_px:g}): it does not explain the drive (a wrong "
                                          "start or an unmodelled effect); nothing written")
        ctx.calibration = calibration
        if ctx.on_calibration is not None:
            ctx.on_calibration(ctx.calibration)  # refuses (NaocalError) what no working Duckiebot has
        kin = ctx.calibration.kinematics
        return Outcome("ok", f"gain {kin.gain:.4f}, trim {kin.trim:.4f}, baseline {kin.baseline_m:.4f} m")


def compensated_duties(ctx: MissionContext) -> tuple[float, float]:
    left, right = inverse_kinematics(ctx.settings.speed_mps, 0.0, ctx.calibration.kinematics)
    return float(left), float(right)


def drive_watching(ctx: MissionContext, session: Session, distance_m: float, *, stop_when_blind: bool) -> float:
    """Drive straight with the compensation for `distance_m` (odometry), a frame every check_every_m while moving;
    stops early (returns) when no marker has been seen for max_blind_m if `stop_when_blind`, else fails then.
    Returns the distance driven."""
    s = ctx.settings
    left, right = compensated_duties(ctx)
    chunk_s = s.check_every_m / s.speed_mps
    driven = 0.0
    lens, mount = ctx.calibration.lens, ctx.calibration.T_base_camera
    session.command(left, right)
    while driven < distance_m - 1e-9:
        dt = min(chunk_s, (distance_m - driven) / s.speed_mps)
        session.wait(dt)
        driven += dt * s.speed_mps
        markers = markers_on_floor(session.grab(), lens, mount)
        if markers:
            ctx.last_seen = (driven, markers)
        bound = 1.1 * dt * s.speed_mps  # calibrated: within 10 %
        if stop_when_blind and not markers and ctx.blind_m + bound > s.max_blind_m:
            break
        saw_marker(ctx, markers, bound)
    session.command(0.0, 0.0)
    session.wait(s.settle_s)
    return driven


class Validation(State):
    name = "validation"
    needs = ("calibration",)
    produces = ("validation",)

    def run(self, ctx: MissionContext) -> Outcome:
        s = ctx.settings
        if ctx.validation_session is None:
            ctx.validation_session = Session(ctx.robot, ctx.out_dir / VALIDATION_LOG, ctx.session.log.meta, s,
                                             ctx.session.t_start_s, ctx.session.restart_phase)
        session = ctx.validation_session
        lens, mount = ctx.calibration.lens, ctx.calibration.T_base_camera
        session.command(0.0, 0.0)
        markers = acquire_line(ctx, lens, mount, session)
        heading, before = line_error(markers)
        ctx.blind_m, ctx.last_seen = 0.0, None
        # curving off the marker line (the PWM floor alone may: `pwm_bound_m`) stops the drive where the markers
        # leave the view (max_blind_m), never beyond; the deviation is then measured at the last frame that saw them
        driven = drive_watching(ctx, session, s.validation_m, stop_when_blind=True)
        markers = markers_on_floor(session.grab(), lens, mount)
        measured_m = driven
        if not markers:
            if ctx.last_seen is None:
                raise NaocalError("no marker in view during the validation drive: its deviation cannot be measured")
            measured_m, markers = ctx.last_seen
        heading_end, after = line_error(markers)
        # moving along the line, the offset from it changes by driven sin(heading error) (align leaves up to
        # align_tolerance_rad: 7 cm over 2 m at 2 deg): the drift is what is left, off the start's own heading
        drift = after - before - measured_m * math.sin(heading)
        fit = ctx.calibration.drive_fit
        offset, _ = duty_offset(fit)
        bound = pwm_drift_bound_m(float(np.mean(compensated_duties(ctx))), offset, ctx.calibration.kinematics.baseline_m,
                                  measured_m) if ctx.pwm_driver else 0.0
        ctx.validation = {"driven_m": driven, "measured_at_m": measured_m, "lateral_start_m": before,
                          "lateral_end_m": after, "heading_start_rad": heading, "heading_end_rad": heading_end,
                          "off_line_m": after - before, "deviation_m": drift, "pwm_bound_m": bound}
        stopped = "" if measured_m >= s.validation_m - 1e-6 else \
            f" (stopped: curved off the marker line; measured at {measured_m:.2f} m)"
        return Outcome("ok", f"{driven:.2f} m: {100 * drift:+.1f} cm off its start heading "
                             f"({100 * (after - before):+.1f} cm off the marker line; the PWM floor alone allows "
                             f"+-{100 * bound:.1f} cm){stopped}")


class Leave(State):
    name = "leave"
    needs = ("validation",)
    produces = ("left_area",)

    def run(self, ctx: MissionContext) -> Outcome:
        driven = drive_watching(ctx, ctx.validation_session, ctx.settings.max_leave_m, stop_when_blind=True)
        ctx.left_area = True
        return Outcome("ok", f"{driven:.2f} m on, stopped")


MISSION_STATES = (Boards, CalibrateCamera, FaceMarkers, MarkerDrives, IdentifyDrive, Validation, Leave)


class RestartedPhase(State):
    """A phase that starts again from its start conditions when a resumed run's replay ends inside it (ReplayEnded:
    the robot's state was not saved): the log gets a break (Session.new_segment), the captures before it are kept,
    the out-of-area count starts anew."""

    def __init__(self, phase: State):
        self.phase = phase
        self.name, self.needs, self.produces = phase.name, phase.needs, phase.produces

    def run(self, ctx: MissionContext) -> Outcome:
        while True:  # once per break the log holds, then once live: each pass ends a part of the replay or goes live
            try:
                return self.phase.run(ctx)
            except ReplayEnded as end:
                if end.session.live:
                    log.info("phase %s: the replay ended inside it; starting it again where the robot stands",
                             self.name)
                    check_restart = getattr(self.phase, "check_restart", None)  # the phase's start conditions, if any
                    if check_restart is not None:
                        check_restart(ctx, end.session)
                    end.session.new_segment()
                else:  # an earlier resume started the phase again here: replayed as it went then
                    end.session.replay_break()
                ctx.blind_m, ctx.restarted = 0.0, self.name


def run_mission(robot, out_dir, settings: MissionSettings = MissionSettings(), *, robot_id: str = "duckiebot",
                source: str = "naocal calibrate", on_calibration=None, states=MISSION_STATES,
                transitions=None, start: str = "boards", restart_phase: bool = False):
    """Run the mission on `robot` (DuckiebotMock's interface: now, command, advance, grab), logging to
    out_dir/log and out_dir/validation. Returns (RunResult, MissionContext). The wheels are at zero duty when this
    returns or raises, whatever happened (the finally). `restart_phase`: the robot's state was not saved with a run
    being resumed (the real robot): the phase the replay ends in starts again where the robot stands
    (RestartedPhase); else the run goes on from the log's end (the mock's world is saved with it)."""
    out_dir = Path(out_dir)
    meta = log_meta(robot_id, source)
    t0 = robot.now()
    ctx = MissionContext(robot, out_dir, settings, Session(robot, out_dir / CALIBRATION_LOG, meta, settings, t0,
                                                           restart_phase), on_calibration=on_calibration)
    if restart_phase and not ctx.session.live:  # resumed: the wheels first, a killed run may have left them turning
        robot.command(0.0, 0.0)  # (logged where the phase starts again: Session.new_segment)
    try:
        if (out_dir / VALIDATION_LOG).exists():  # a resumed run that had begun its validation
            ctx.validation_session = Session(robot, out_dir / VALIDATION_LOG, meta, settings, t0, restart_phase)
        phases = [RestartedPhase(cls()) if restart_phase else cls() for cls in states]
        machine = Machine(phases, TRANSITIONS if transitions is None else transitions, start)
        result = machine.run(ctx, clock=robot.now)
    finally:
        for session in (ctx.validation_session, ctx.session):
            if session is not None and session.live:
                session.stop()
        robot.command(0.0, 0.0)  # the safe state whatever the logs could take
    return result, ctx
