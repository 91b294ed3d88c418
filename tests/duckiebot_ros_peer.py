"""A fake peer of Duckietown's ROS interfaces for kinds/duckiebot/ros_driver.py: fake `rospy`, `duckietown_msgs.msg`
and `sensor_msgs.msg` modules (put into sys.modules by the test) over a simulated ROS graph on the robot:

- a wheels driver node on /<veh>/wheels_driver_node/wheels_cmd that hands every command to a hidden robot (the
  PyBullet DuckiebotMock: its physics integrates the duties), records what it received and reports each command it
  executed on ~wheels_cmd_executed, stamped when executed (as dt-duckiebot-interface's wheels_driver_node does);
- with `queued=True`, publishing as rospy does with a queue_size: a message goes out from a sender thread a moment
  later, and one still queued when its publisher unregisters is dropped (rospy.impl.tcpros_pubsub.QueuedConnection:
  its thread ends when the connection is done, whatever is queued);
- a camera node publishing, every 1/30 s of robot time, a JPEG of kinds.duckiebot.render's Renderer at the hidden
  robot's pose (rendered and encoded only when a subscriber reads msg.data: most frames are never looked at);
- two encoder nodes publishing cumulative ticks (135 per revolution) of the hidden wheels' angles (the right one
  `right_tick_lag_steps` physics steps after the left: each node has its own timer).

Robot time is simulated (ROS sim time): rospy.sleep(d) steps the hidden robot by d and delivers the messages that
fell due, outside the graph's lock (rospy's callbacks run on other threads: the driver's locks must not nest in the
graph's). Hooks let a test damage what the peers publish.
"""

from __future__ import annotations

import math
import threading
import time
import types
from dataclasses import dataclass, field

import cv2
import numpy as np

from naocal.kinds.duckiebot.mock import PHYSICS_DT_S, DuckiebotMock

STEPS_PER_FRAME = 16  # 480 Hz physics: 30 Hz camera
STEPS_PER_TICK = 16  # encoders at 30 Hz


@dataclass
class Header:
    stamp: object = None
    seq: int = 0
    frame_id: str = ""


@dataclass
class WheelsCmdStamped:
    header: Header = field(default_factory=Header)
    vel_left: float = 0.0
    vel_right: float = 0.0


@dataclass
class WheelEncoderStamped:
    header: Header = field(default_factory=Header)
    data: int = 0
    resolution: int = 135
    type: int = 0


@dataclass
class CompressedImage:
    header: Header = field(default_factory=Header)
    format: str = "jpeg"
    data: object = b""


class LazyJpeg:
    """A frame's JPEG bytes, rendered on first use (bytes(x))."""

    def __init__(self, render):
        self._render, self._data = render, None

    def __bytes__(self):
        if self._data is None:
            ok, data = cv2.imencode(".jpg", self._render(), [cv2.IMWRITE_JPEG_QUALITY, 95])
            self._data = data.tobytes()
        return self._data


class FakeRosGraph:
    def __init__(self, vehicle="db21", seed=4, realism="ideal", *, encoders=True, wheels_node=True,
                 start_pose=(0, 0, 0), scene=None, queued=False, send_delay_s=0.02, right_tick_lag_steps=0):
        self.vehicle = vehicle
        self.queued, self.send_delay_s = queued, send_delay_s
        self.right_tick_lag_steps = right_tick_lag_steps  # the two encoder nodes' timers out of phase (real ones are)
        self.robot = DuckiebotMock(seed, realism, supersample=1, start_pose=start_pose, scene=scene)
        self.lock = threading.RLock()
        self.subscribers = {}  # topic -> [Subscriber]
        self.received = []  # (t, vel_left, vel_right) of every wheels command the wheels node received
        self.refused = []  # wheels commands the hidden robot refused (out of range): must stay empty
        self.angles = np.zeros(2)  # the hidden wheels' angles, rad
        self.steps = 0
        self.encoders, self.camera_on, self.clock_running = encoders, True, True
        self.frame_hook = None  # callable(msg) -> msg: damage a frame before it is published
        self.tick_hook = None  # callable(side, msg) -> msg
        self.sleep_hook = None  # callable(): called as each rospy.sleep begins (a signal mid-wait)
        self.shutdown_hooks = []
        self.node = None
        if wheels_node:
            self._subscribe(f"/{vehicle}/wheels_driver_node/wheels_cmd", self._on_wheels)
        self.modules = self._modules()

    # ------------------------------------------------------------------------------------------ the graph
    def _subscribe(self, topic, callback, args=None):
        sub = types.SimpleNamespace(topic=topic, callback=callback, args=args)
        sub.unregister = lambda: self.subscribers[topic].remove(sub)
        self.subscribers.setdefault(topic, []).append(sub)
        return sub

    def _deliver(self, topic, msg):
        for sub in list(self.subscribers.get(topic, ())):
            sub.callback(msg) if sub.args is None else sub.callback(msg, sub.args)

    def _on_wheels(self, msg):
        with self.lock:
            left, right = msg.vel_left, msg.vel_right
            self.received.append((self.robot.t_s, left, right))
            try:
                self.robot.command(left, right)
            except Exception as exc:  # a real wheels driver would clip or misbehave: the test fails on it
                self.refused.append(str(exc))
            executed = WheelsCmdStamped(Header(self.Time(self.robot.t_s)), left, right)
        self._deliver(f"/{self.vehicle}/wheels_driver_node/wheels_cmd_executed", executed)

    def time(self) -> float:
        return self.robot.t_s

    def sleep(self, duration_s: float):
        if self.sleep_hook:
            self.sleep_hook()
        if not self.clock_running:
            return
        for _ in range(max(1, int(round(duration_s / PHYSICS_DT_S)))):
            due = []
            with self.lock:
                self.robot.advance(PHYSICS_DT_S)
                self.angles += self.robot.wheel_w * PHYSICS_DT_S
                self.steps += 1
                t = self.robot.t_s
                if self.camera_on and self.steps % STEPS_PER_FRAME == 0:
                    due.append((f"/{self.vehicle}/camera_node/image/compressed", self._frame(t)))
                if self.encoders:
                    for i, side in enumerate(("left", "right")):
                        if self.steps % STEPS_PER_TICK != (self.right_tick_lag_steps if i else 0):
                            continue
                        msg = WheelEncoderStamped(Header(self.Time(t)), int(math.floor(
                            self.angles[i] / (2 * math.pi) * 135)), 135)
                        msg = self.tick_hook(side, msg) if self.tick_hook else msg
                        due.append((f"/{self.vehicle}/{side}_wheel_encoder_node/tick", msg))
            for topic, msg in due:
                self._deliver(topic, msg)

    def _frame(self, t):
        pose = self.robot.pose()
        renderer = self.robot.renderer
        msg = CompressedImage(Header(self.Time(t)), "jpeg", LazyJpeg(lambda: renderer.render(pose, noise_grey=0.0)))
        return self.frame_hook(msg) if self.frame_hook else msg

    # ------------------------------------------------------------------------------------------ the modules
    def _modules(self) -> dict:
        graph = self

        class Time:
            def __init__(self, secs=0.0):
                self.secs = float(secs)

            def to_sec(self):
                return self.secs

            @staticmethod
            def now():
                return Time(graph.time())

        self.Time = Time

        class Publisher:
            def __init__(self, topic, msg_type, queue_size=None):
                self.topic, self.msg_type, self.registered = topic, msg_type, True
                self.queue, self.cond = [], threading.Condition()
                if graph.queued:
                    threading.Thread(target=self._send, daemon=True).start()

            def publish(self, msg):
                assert isinstance(msg, self.msg_type) and self.registered
                if not graph.queued:
                    graph._deliver(self.topic, msg)
                    return
                with self.cond:
                    self.queue.append(msg)
                    self.cond.notify()

            def _send(self):  # rospy's sender thread: out a moment later, unless unregistered meanwhile
                while True:
                    with self.cond:
                        while not self.queue and self.registered:
                            self.cond.wait()
                        if not self.registered:
                            return
                    time.sleep(graph.send_delay_s)
                    with self.cond:
                        if not self.registered:
                            return
                        queue, self.queue = self.queue, []
                    for msg in queue:
                        graph._deliver(self.topic, msg)

            def get_num_connections(self):
                return len(graph.subscribers.get(self.topic, ()))

            def unregister(self):
                with self.cond:
                    self.registered = False
                    self.cond.notify()

        def Subscriber(topic, msg_type, callback, callback_args=None, queue_size=None, buff_size=None):
            return graph._subscribe(topic, callback, callback_args)

        def init_node(name, anonymous=False, disable_signals=False):
            assert disable_signals, "naocal's own SIGTERM handler must stop the wheels: rospy must not take it"
            graph.node = name

        rospy = types.ModuleType("rospy")
        rospy.Time, rospy.Publisher, rospy.Subscriber, rospy.init_node = Time, Publisher, Subscriber, init_node
        rospy.get_time = lambda: graph.time()
        rospy.sleep = graph.sleep
        rospy.on_shutdown = graph.shutdown_hooks.append
        duckietown_msgs, sensor_msgs = types.ModuleType("duckietown_msgs"), types.ModuleType("sensor_msgs")
        duckietown_msgs.msg = types.ModuleType("duckietown_msgs.msg")
        duckietown_msgs.msg.WheelsCmdStamped, duckietown_msgs.msg.WheelEncoderStamped = WheelsCmdStamped, \
            WheelEncoderStamped
        sensor_msgs.msg = types.ModuleType("sensor_msgs.msg")
        sensor_msgs.msg.CompressedImage = CompressedImage
        return {"rospy": rospy, "duckietown_msgs": duckietown_msgs, "duckietown_msgs.msg": duckietown_msgs.msg,
                "sensor_msgs": sensor_msgs, "sensor_msgs.msg": sensor_msgs.msg}

    def install(self, monkeypatch):
        for name, module in self.modules.items():
            monkeypatch.setitem(__import__("sys").modules, name, module)
        return self

    def close(self):
        self.robot.close()


def check_resumed_again(log_dir, before, frames: dict, received: list) -> None:
    """A run resumed a second time (tests of --resume on the robot and over the bridge): `before` the log after the
    first resume (one break), `frames` its frames' bytes, `received` the wheel commands (t, left, right) the robot
    got during the second resume. Two breaks, only stops before the second, which is a stop row; every frame kept
    byte for byte, not redone; frames after it."""
    from naocal.kinds.duckiebot.drive_log import read_drive_log

    resumed = read_drive_log(log_dir)
    assert resumed.segment_t_s[0] == before.segment_t_s[0] and len(resumed.segment_t_s) == 2
    t_second = resumed.segment_t_s[1]
    assert t_second > max(before.wheel_t_s[-1], before.frame_t_s[-1])
    assert all((left, right) == (0.0, 0.0) for t, left, right in received if t <= t_second)  # only stops
    at_break = np.searchsorted(resumed.wheel_t_s, t_second)
    assert (resumed.left_duty[at_break], resumed.right_duty[at_break]) == (0.0, 0.0)
    assert resumed.frame_files[:len(before.frame_files)] == before.frame_files
    assert all((log_dir / name).read_bytes() == data for name, data in frames.items())  # kept, not redone
    assert np.sum(resumed.frame_t_s > t_second) >= 3
