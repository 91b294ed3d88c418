"""A real Duckiebot (DB21) driven over Duckietown's own ROS interfaces: the robot interface of the mission
(kinds.duckiebot.mission: now, command, advance, grab; the mock's, kinds.duckiebot.mock.DuckiebotMock).

Runs ON the robot, inside Duckietown's dt-ros-commons container (docs/DEPLOY.md "Duckiebot (DB21)"): rospy and the
message modules exist only there, so they are imported in the constructor, never at module import (as `qi` for the
NAO). The topics (dt-duckiebot-interface, Duckietown's robot-side stack; `<veh>` the robot's name, $VEHICLE_NAME):

    /<veh>/wheels_driver_node/wheels_cmd           duckietown_msgs/WheelsCmdStamped     published: vel_left,
                                                                                        vel_right duties in [-1, 1]
    /<veh>/wheels_driver_node/wheels_cmd_executed  duckietown_msgs/WheelsCmdStamped     subscribed: each command the
                                                                                        wheels driver executed
    /<veh>/camera_node/image/compressed            sensor_msgs/CompressedImage          subscribed: JPEG, header.stamp
    /<veh>/left_wheel_encoder_node/tick, right_... duckietown_msgs/WheelEncoderStamped  subscribed: data = cumulative
                                                                                        ticks, resolution 135 / rev

Safety (the safe state = both duties 0):
- a duty is published only when finite and within [-1, 1] (else SafetyError, nothing sent);
- a watchdog thread publishes zero duties when the wheels turn and the agent has not called the driver for
  `watchdog_s` (wall time): a hung agent never leaves the robot driving; the next call then fails (the drive's log
  would not be what happened);
- zero duties on close(), on any refused reading, on every deadline missed, and from rospy's shutdown hook;
  close() waits (STOP_CONFIRM_S) until the wheels driver reports the zero executed before it leaves the topic:
  rospy sends from a queue thread, and a message still queued when its publisher unregisters is dropped;
  the node is started with disable_signals=True so that Ctrl-C / SIGTERM reach naocal's own handler (tools.cli),
  whose unwinding stops the wheels through this driver (rospy's would shut the node down first: no publisher left);
- every wait has a deadline: the wheels driver listening (connect_timeout_s), a frame after the request
  (image_timeout_s), the robot's clock advancing (advance: duration + clock_slack_s of wall time);
- every reading is checked before use: a frame that does not decode, is not 640 x 480, or whose stamp does not
  follow the previous one; an encoder count that is not a whole number, of another resolution, with a stamp going
  back, or a row of counts (both sides) that steps more than the wheels can turn (drive_log.impossible_tick_step,
  the drive log reader's own check, int32 wrap-arounds undone as it does): refused (RobotError naming the topic and
  the row's line), wheels stopped.

Times are the robot's ROS clock (rospy.get_time(), the messages' header.stamp): one clock for commands, frames and
ticks, as the drive log wants. A frame's stamp is taken as its mid-exposure time (the camera node stamps each frame
when it is captured; its exposure is a few ms at the calibration area's light).
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np

from naocal.kinds.duckiebot.drive_log import (EncoderJournal, Wheels, impossible_tick_step, unwrap_int32,
                                             write_encoders)
from naocal.kinds.duckiebot.kinematics import duty_problem
from naocal.kinds.duckiebot.robot import (DB21_TICKS_PER_REVOLUTION, DEFAULT_K, DEFAULT_LIMIT, IMAGE_HEIGHT_PX,
                                         IMAGE_WIDTH_PX, decoded_frame, duckiebot, robot_name_problem)
from naocal.solver.errors import NaocalError, SafetyError

log = logging.getLogger(__name__)

MAX_ADVANCE_S = 60.0  # one advance() longer than this is a caller's bug (the mission waits at most seconds)
ENCODER_SAVE_S = 0.2  # the ticks are appended to the journal (keep_encoders) at least this often (wall time)
STOP_CONFIRM_S = 0.5  # close(): how long (wall time) to wait for the wheels driver to report the stop executed


def topics(vehicle: str) -> dict:
    """Duckietown's topic names for robot `vehicle` (dt-duckiebot-interface)."""
    return {"wheels": f"/{vehicle}/wheels_driver_node/wheels_cmd",
            "executed": f"/{vehicle}/wheels_driver_node/wheels_cmd_executed",
            "camera": f"/{vehicle}/camera_node/image/compressed",
            "left_ticks": f"/{vehicle}/left_wheel_encoder_node/tick",
            "right_ticks": f"/{vehicle}/right_wheel_encoder_node/tick"}


class RobotError(NaocalError):
    """A reading from the robot refused, or a deadline missed: the wheels were stopped."""


class RosDuckiebot:
    """The mission's robot over Duckietown's ROS topics. `vehicle`: the robot's name (its topics' namespace)."""

    pwm_driver = True  # its wheel commands go through Duckietown's wheel driver (kinematics.duty_to_pwm)

    def __init__(self, vehicle: str, *, watchdog_s: float = 1.0, image_timeout_s: float = 2.0,
                 connect_timeout_s: float = 10.0, clock_slack_s: float = 2.0,
                 ticks_per_revolution: int = DB21_TICKS_PER_REVOLUTION, node_name: str = "naocal"):
        try:
            import rospy
            from duckietown_msgs.msg import WheelEncoderStamped, WheelsCmdStamped
            from sensor_msgs.msg import CompressedImage
        except ImportError as exc:
            raise NaocalError(f"--backend ros runs on the Duckiebot inside Duckietown's dt-ros-commons container "
                              f"(rospy and duckietown_msgs are not importable here: {exc}); docs/DEPLOY.md") from None
        problem = robot_name_problem(vehicle)  # it names the topics, the drive logs and the calibration files
        if problem:
            raise NaocalError(f"{problem} ($VEHICLE_NAME, the robot's name)")
        self._rospy, self._WheelsCmdStamped = rospy, WheelsCmdStamped
        self.vehicle, self.topics = vehicle, topics(vehicle)
        self.watchdog_s, self.image_timeout_s, self.clock_slack_s = watchdog_s, image_timeout_s, clock_slack_s
        self.ticks_per_revolution = int(ticks_per_revolution)
        nominal = duckiebot("DB21")  # the drive log's wheels (mission.log_meta): its reader's jump check, run on each row
        self.wheels = Wheels(nominal.radius_m, nominal.baseline_m, DEFAULT_K, DEFAULT_LIMIT, self.ticks_per_revolution)
        self._lock = threading.RLock()
        self._fault = None  # the first refused reading / watchdog stop: raised at the agent's next call
        self._duties = (0.0, 0.0)  # as last published
        self._last_call = time.monotonic()
        self._last_now = -math.inf
        self._frame = None  # (stamp s, message) of the newest frame: decoded only when grabbed (30 Hz on a Pi)
        self._ticks = {"left": None, "right": None}  # side -> (stamp s, count as sent, count unwrapped) newest
        self.encoder_rows = []  # (t_s, left_ticks, right_ticks): each time both sides have counted since the last
        self._journal = None  # EncoderJournal (keep_encoders): encoder_rows saved as they come
        self._unsaved = []  # encoder_rows not yet in the journal
        self._journal_lock = threading.Lock()  # one append at a time, in order (taken before self._lock)
        self._saved_at = time.monotonic()
        self._closed = False
        self._executed = None  # (stamp s, vel_left, vel_right): the wheels driver's newest executed command
        self._executed_changed = threading.Condition()
        rospy.init_node(node_name, anonymous=True, disable_signals=True)
        self._wheels = rospy.Publisher(self.topics["wheels"], WheelsCmdStamped, queue_size=1)
        self._subscribers = [
            rospy.Subscriber(self.topics["camera"], CompressedImage, self._on_frame, queue_size=1, buff_size=2 ** 22),
            rospy.Subscriber(self.topics["left_ticks"], WheelEncoderStamped, self._on_ticks, callback_args="left"),
            rospy.Subscriber(self.topics["right_ticks"], WheelEncoderStamped, self._on_ticks, callback_args="right"),
            rospy.Subscriber(self.topics["executed"], WheelsCmdStamped, self._on_executed, queue_size=1)]
        rospy.on_shutdown(self._stop_quietly)
        deadline = time.monotonic() + connect_timeout_s
        while self._wheels.get_num_connections() < 1:
            if time.monotonic() > deadline:
                self.close()
                raise RobotError(f"{self.topics['wheels']}: no wheels driver listening within {connect_timeout_s:g} s "
                                 "(is dt-duckiebot-interface running on this robot, and is the name right?)")
            time.sleep(0.05)
        self._publish(0.0, 0.0)  # start from the safe state
        self._watchdog = threading.Thread(target=self._watch, name="naocal-wheels-watchdog", daemon=True)
        self._watchdog.start()

    # ------------------------------------------------------------------------------------------ safety
    def _publish(self, left: float, right: float) -> float:
        for name, duty in (("left", left), ("right", right)):
            problem = duty_problem(name, duty)
            if problem:
                raise SafetyError(f"refused wheel command: {problem}")
        msg = self._WheelsCmdStamped()
        stamp = self._rospy.Time.now()
        msg.header.stamp = stamp
        msg.vel_left, msg.vel_right = float(left), float(right)
        with self._lock:
            self._wheels.publish(msg)
            self._duties = (float(left), float(right))
        return stamp.to_sec()

    def _stop_quietly(self) -> float | None:
        """The safe state, from any thread; never raises (the stop must not hide why we stopped). The stop's stamp,
        None if it could not be published (after close(): its stop was confirmed or warned about then)."""
        if self._closed:
            return None
        try:
            return self._publish(0.0, 0.0)
        except Exception:  # a node already shut down: the wheels driver's own shutdown stops the motors
            log.exception("could not publish the stop")
            return None

    def _on_executed(self, msg) -> None:
        with self._executed_changed:
            self._executed = (msg.header.stamp.to_sec(), msg.vel_left, msg.vel_right)
            self._executed_changed.notify_all()

    def _stop_confirmed(self, timeout_s: float) -> bool:
        """Publish the stop and wait, at most `timeout_s` of wall time, until the wheels driver reports (0, 0)
        executed at or after it."""
        t_stop = self._stop_quietly()
        if t_stop is None:
            return False
        deadline = time.monotonic() + timeout_s
        with self._executed_changed:
            while not (self._executed is not None and self._executed[0] >= t_stop
                       and self._executed[1:] == (0.0, 0.0)):
                remaining_s = deadline - time.monotonic()
                if remaining_s <= 0:
                    return False
                self._executed_changed.wait(remaining_s)
        return True

    def _refuse(self, problem: str) -> None:
        """A reading refused (from a subscriber's thread): stop now, fail the agent's next call."""
        with self._lock:
            if self._fault is None:
                self._fault = problem
        self._stop_quietly()

    def _enter(self, *, moving: bool = True) -> None:
        """Every call of the agent: it is alive (the watchdog's clock); a fault since its last call is raised by
        every call that would move the robot or use a reading (`moving`), never by the clock or the stop: the
        agent's unwinding (the stop, its summary's robot time) must not fail on the fault it is reporting."""
        with self._lock:
            self._last_call = time.monotonic()
            fault = self._fault
        if fault is not None and moving:
            self._stop_quietly()
            raise RobotError(f"{fault} (the wheels were stopped)")

    def _watch(self) -> None:
        while not self._closed:
            time.sleep(min(0.05, self.watchdog_s / 4))
            with self._lock:
                silent = time.monotonic() - self._last_call
                if self._duties != (0.0, 0.0) and silent > self.watchdog_s and not self._closed:
                    self._refuse(f"watchdog: no call from the agent for {silent:.2f} s while the wheels turned "
                                 f"(more than {self.watchdog_s:g} s)")

    def _fail(self, problem: str):
        self._stop_quietly()
        raise RobotError(f"{problem} (the wheels were stopped)")

    # ------------------------------------------------------------------------------------------ readings
    def _on_frame(self, msg) -> None:
        topic = self.topics["camera"]
        stamp = msg.header.stamp.to_sec()
        with self._lock:
            previous = self._frame[0] if self._frame is not None else -math.inf
            if not math.isfinite(stamp) or stamp <= previous:
                self._refuse(f"{topic}: a frame stamped {stamp!r} s, not after the previous one ({previous!r} s)")
                return
            self._frame = (stamp, msg)

    def _on_ticks(self, msg, side: str) -> None:
        topic = self.topics[f"{side}_ticks"]
        stamp, ticks = msg.header.stamp.to_sec(), msg.data
        with self._lock:
            if isinstance(ticks, bool) or not isinstance(ticks, (int, np.integer)):
                return self._refuse(f"{topic}: tick count {ticks!r} is not a whole number")
            if msg.resolution != self.ticks_per_revolution:
                return self._refuse(f"{topic}: resolution {msg.resolution!r} ticks per revolution, expected "
                                    f"{self.ticks_per_revolution} (another encoder?)")
            if not math.isfinite(stamp):
                return self._refuse(f"{topic}: stamp {stamp!r} s is not a time")
            previous, count = self._ticks[side], int(ticks)
            if previous is not None:
                if stamp <= previous[0]:
                    return self._refuse(f"{topic}: a count stamped {stamp!r} s, not after the previous one "
                                        f"({previous[0]!r} s)")
                # Duckietown's int32 counter wrapping, undone as the reader does (drive_log.unwrap_int32)
                count = previous[2] + int(np.diff(unwrap_int32(np.array([previous[1], count], np.int64)))[0])
            self._ticks[side] = (stamp, int(ticks), count)
            left, right = self._ticks["left"], self._ticks["right"]
            last_t = self.encoder_rows[-1][0] if self.encoder_rows else -math.inf
            # a row once both sides have counted since the last one, at the later stamp: each column's step then
            # spans about the rows' spacing (the other side's count held in a row right after its own would show a
            # whole interval's ticks within a millisecond, which the reader refuses as a jump)
            if left is not None and right is not None and min(left[0], right[0]) > last_t:
                row = (max(left[0], right[0]), left[2], right[2])
                if self.encoder_rows:  # the reader's jump check (drive_log.impossible_tick_step), at once
                    t_s = np.array([last_t, row[0]])
                    for name, column in (("left_ticks", 1), ("right_ticks", 2)):
                        found = impossible_tick_step(t_s, [self.encoder_rows[-1][column], row[column]], self.wheels,
                                                     counts_held=False)
                        if found:
                            n = len(self.encoder_rows) + 1  # the journal holds every row, after its header
                            where = f"{self._journal.path}, line {n + 1}" if self._journal is not None else \
                                f"encoder row {n}"
                            return self._refuse(f"{self.topics[name]}: {where}, field '{name}': {found[1]}: a reset "
                                                "or a glitch")
                self.encoder_rows.append(row)
                self._unsaved.append(row)
        if self._journal is not None and time.monotonic() - self._saved_at >= ENCODER_SAVE_S:
            self._save_ticks()

    # ------------------------------------------------------------------------------------------ the encoders' journal
    def keep_encoders(self, path) -> int:
        """Save every encoder row, from now on as it comes (at least every ENCODER_SAVE_S), to the journal `path`
        (drive_log.EncoderJournal: encoders.csv's format, appended and fsync'd): a crash loses at most the last
        fraction of a second. A journal that holds rows (an earlier run's) is continued: its rows come first in
        encoder_rows (save_encoders writes them into their logs). Returns the rows it held. DataError for a journal
        the reader refuses."""
        with self._journal_lock:
            journal = EncoderJournal(path)
            with self._lock:
                last = journal.rows[-1][0] if journal.rows else -math.inf
                new = [row for row in self.encoder_rows if row[0] > last]  # ticks since this driver started
                self.encoder_rows = list(journal.rows) + new
                self._unsaved = new
                self._journal = journal
        self._save_ticks()
        return len(journal.rows) - len(new)

    def _save_ticks(self) -> None:
        """Append the rows not yet saved to the journal; a failure (disk full) is a fault: the wheels stop (a run
        whose readings are not saved must not go on)."""
        with self._journal_lock:
            with self._lock:
                rows, self._unsaved = self._unsaved, []
                self._saved_at = time.monotonic()
            try:
                self._journal.append(rows)
            except (OSError, ValueError, NaocalError) as err:
                self._refuse(f"the encoders' ticks could not be saved to {self._journal.path} ({err})")

    # ------------------------------------------------------------------------------------------ the interface
    def now(self) -> float:
        """The robot's ROS clock, s; refused when it goes back."""
        self._enter(moving=False)
        t = self._rospy.get_time()
        if not math.isfinite(t) or t < self._last_now:
            self._fail(f"the robot's clock went back ({t!r} s after {self._last_now!r} s)")
        self._last_now = t
        return t

    def command(self, left: float, right: float) -> float:
        """Publish the duties (held until the next command); returns the robot time they were sent. The stop (0, 0)
        is always sent, also after a fault."""
        self._enter(moving=(left, right) != (0.0, 0.0))
        return self._publish(left, right)

    def advance(self, duration_s: float) -> None:
        """Wait `duration_s` on the robot's clock (the wheels keep the duties in force); a deadline of duration +
        clock_slack_s of wall time (a clock that stands still: stop, fail)."""
        if not (isinstance(duration_s, (int, float)) and 0.0 <= duration_s <= MAX_ADVANCE_S):
            raise SafetyError(f"advance: duration {duration_s!r} s is not within [0, {MAX_ADVANCE_S:g}] s")
        self._enter()
        target = self.now() + duration_s
        deadline = time.monotonic() + duration_s + self.clock_slack_s
        while True:
            self._enter()
            remaining = target - self.now()
            if remaining <= 0:
                return
            if time.monotonic() > deadline:
                self._fail(f"the robot's clock did not reach {target:.3f} s within {duration_s + self.clock_slack_s:g}"
                           " s of wall time (is ROS time running?)")
            self._rospy.sleep(min(remaining, 0.02))

    def grab(self) -> tuple[float, np.ndarray]:
        """(stamp s, grey image) of the first frame exposed after this call (never one from before the last
        command); no such frame within image_timeout_s: stop, fail."""
        topic = self.topics["camera"]
        self._enter()
        t_request = self.now()
        deadline = time.monotonic() + self.image_timeout_s
        while True:
            with self._lock:
                frame = self._frame
            if frame is not None and frame[0] > t_request:
                break
            if time.monotonic() > deadline:
                newest = "none" if frame is None else f"the newest stamped {frame[0]:.3f} s"
                self._fail(f"{topic}: no frame within {self.image_timeout_s:g} s of asking at {t_request:.3f} s "
                           f"({newest}: is the camera node running, on the robot's clock?)")
            self._rospy.sleep(0.005)
            self._enter()
        stamp, data = frame[0], bytes(frame[1].data)
        now = self.now()
        if stamp > now + self.clock_slack_s:  # another clock: its frames would pass for fresh ones forever
            self._fail(f"{topic}: a frame stamped {stamp:.3f} s, {stamp - now:.1f} s ahead of the robot's clock")
        image, problem = decoded_frame(data, IMAGE_WIDTH_PX, IMAGE_HEIGHT_PX)  # the camera node's resolution
        if problem:
            self._fail(f"{topic}: the frame stamped {stamp:.3f} s {problem}")
        return stamp, image

    def encoder_ticks(self, t_from_s: float, t_to_s: float) -> list:
        """The rows (t_s, left_ticks, right_ticks) counted within [t_from_s, t_to_s], checked as they came in."""
        with self._lock:
            return [r for r in self.encoder_rows if t_from_s <= r[0] <= t_to_s]

    def save_encoders(self, log_dir, t_from_s: float, t_to_s: float) -> int:
        """The ticks counted within [t_from_s, t_to_s] into the drive log (drive_log.write_encoders); the rows written
        (0, nothing written, on a robot without encoders: the DB18)."""
        if self._journal is not None:
            self._save_ticks()
        return write_encoders(log_dir, self.encoder_ticks(t_from_s, t_to_s), self.ticks_per_revolution)

    def close(self) -> None:
        """Wheels stopped (the wheels driver's report awaited: STOP_CONFIRM_S), watchdog ended, topics left. Safe to
        call twice."""
        if self._closed:
            return
        if not self._stop_confirmed(STOP_CONFIRM_S):
            log.warning("%s: the wheels driver did not report the stop executed within %g s (is "
                        "dt-duckiebot-interface running?): the wheels may still turn; docs/DEPLOY.md says how to stop "
                        "them", self.topics["executed"], STOP_CONFIRM_S)
        self._closed = True
        for subscriber in self._subscribers:
            subscriber.unregister()
        self._wheels.unregister()
        if self._journal is not None:  # the last ticks (no more come)
            self._save_ticks()
