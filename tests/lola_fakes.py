"""Test doubles for the LoLA driver and the V4L2 cameras: a fake LoLA on a real Unix socket, and frame sources with
the contract of cv2.VideoCapture.

`FakeLola` speaks the published layout (backends.lola_driver module docstring): every 12 ms of the monotonic clock
it sends one msgpack map with Accelerometer, Angles, Battery, Current, FSR, Gyroscope, Position, Sonar, Stiffness,
Temperature, Touch, Status (LoLA's 25-joint order) and RobotConfig, 32-bit floats as LoLA packs them, and reads
the client's answers ({"Position": [25], "Stiffness": [25]}). It records every cycle (`records`: what it sent
and the newest answer applied) so that tests can check that answers come every cycle, that motion is gradual
and within limits, and what the robot was told after the agent died. Like LoLA it serves one client: a second
one is accepted and never sent anything ("silent"), or refused ("refuse").

When its client disconnects, the fake keeps applying the last command it received. What real LoLA does then is
not documented in any source we found (docs/DEPLOY.md): tests only check what the client sent before it left.

Physics behind it: `SimpleServos` (each stiff joint goes to its command at its maximum speed; fast, for unit
tests) or `MockPhysics` (backends.mock.MockBackend driven in real time: its clock follows the monotonic clock,
every new command becomes a MockBackend.command at full speed, so its collision check sees every step; its camera
renders the frames `CameraServer` hands out).

Cameras: `SyntheticCapture` makes YUYV frames in process, with injectable faults (frozen, stalled timestamps,
wrong size, zero rows, missing device); `RemoteCapture` fetches the mock's rendered frames from `CameraServer`
in the fake robot's process. Both behave as cv2.VideoCapture(device, cv2.CAP_V4L2) with CONVERT_RGB off:
grab(), retrieve() -> (ok, YUYV (h, w, 2) uint8), read(), get(CAP_PROP_POS_MSEC) = the buffer timestamp on the
monotonic clock in ms, isOpened(), set(), release().

Run as a program (the end-to-end tests): `python -m tests.lola_fakes robot ...` runs FakeLola with MockPhysics
and a CameraServer; `python -m tests.lola_fakes bridge --camera-socket P -- <naocal arguments>` runs `naocal`
with backends.v4l2_camera.open_v4l2 replaced by RemoteCapture (there is no V4L2 device to open on a test machine).
"""

from __future__ import annotations

import argparse
import math
import os
import socket
import sys
import threading
import time

import cv2
import msgpack
import numpy as np

from naocal.backends.lola_driver import CYCLE_S, LOLA_INDEX, LOLA_JOINTS, MOTOR_OF, N_LOLA
from naocal.solver import limits
from naocal.solver.joints import JOINTS

BODY_ID, HEAD_ID = "P0000074A05S94700111", "P0000073A07S93Z00046"  # 20 characters, like LoLA's
ROBOT_CONFIG = [BODY_ID, "6.0.0.0", HEAD_ID, "6.0.0.0"]
ARM_POSTURE = {"LShoulderPitch": 1.4, "LShoulderRoll": 0.2, "LElbowYaw": -1.2, "LElbowRoll": -0.5, "LWristYaw": 0.0,
               "RShoulderPitch": 1.4, "RShoulderRoll": -0.2, "RElbowYaw": 1.2, "RElbowRoll": 0.5, "RWristYaw": 0.0,
               "LHand": 0.2, "RHand": 0.2}


def lola_speeds() -> np.ndarray:
    """Maximum speed (rad/s) of each LoLA joint; arms and hands at a plausible 5 rad/s (never commanded here)."""
    speeds = limits.max_speeds()
    return np.array([speeds.get(name, 5.0) for name in LOLA_JOINTS])


def to_lola(angles: dict) -> np.ndarray:
    """naocal's {joint: angle} (plus arms) -> LoLA's 25 positions (RHipYawPitch dropped: one motor)."""
    out = np.array([ARM_POSTURE.get(name, 0.0) for name in LOLA_JOINTS])
    for name, angle in angles.items():
        if name in LOLA_INDEX:
            out[LOLA_INDEX[name]] = angle
    return out


def sensor_map(position, stiffness, temperature, status, current=None) -> dict:
    """One LoLA sensor message before packing."""
    return {
        "Accelerometer": [-9.81, 0.0, 0.0], "Angles": [0.0, -1.5708], "Battery": [0.9, -32768.0, -1.0, 30.0],
        "Current": [float(c) for c in (current if current is not None else np.full(N_LOLA, 0.05))],
        "FSR": [0.0] * 8, "Gyroscope": [0.0, 0.0, 0.0],
        "Position": [float(p) for p in position], "Sonar": [2.55, 2.55],
        "Stiffness": [float(s) for s in stiffness], "Temperature": [float(t) for t in temperature],
        "Touch": [0.0] * 14, "Status": [int(s) for s in status], "RobotConfig": list(ROBOT_CONFIG),
    }


def sensor_message(position, stiffness, temperature, status, current=None) -> bytes:
    """One LoLA sensor message, packed as LoLA packs it (32-bit floats, Status as ints)."""
    return msgpack.packb(sensor_map(position, stiffness, temperature, status, current), use_single_float=True)


# ---------------------------------------------------------------------------------------------- physics
class SimpleServos:
    """Each joint with stiffness > 0 moves toward its command at its maximum speed; a limp joint stays put."""

    def __init__(self, posture: dict | None = None):
        from naocal.backends.mock import DEFAULT_POSTURE

        self.q = to_lola({**DEFAULT_POSTURE, **(posture or {})})
        self.command = self.q.copy()
        self.stiffness = np.zeros(N_LOLA)
        self.speeds = lola_speeds()
        self._t = None
        self.violations: list[str] = []

    def advance(self, now_s: float) -> None:
        dt = 0.0 if self._t is None else max(0.0, now_s - self._t)
        self._t = now_s
        stiff = self.stiffness > 0
        step = np.clip(self.command - self.q, -self.speeds * dt, self.speeds * dt)
        self.q[stiff] += step[stiff]

    def positions(self) -> np.ndarray:
        return self.q.copy()

    def apply(self, position, stiffness) -> None:
        self.command = np.asarray(position, dtype=float)
        self.stiffness = np.asarray(stiffness, dtype=float)


class MockPhysics:
    """naocal.backends.mock.MockBackend in real time: mock time = START_TIME_S + (monotonic - start)."""

    def __init__(self, mock, start_mono_s: float):
        from naocal.backends.mock import START_TIME_S

        self.mock = mock
        self.offset_s = START_TIME_S - start_mono_s  # mock time minus monotonic time
        self.lock = threading.Lock()  # MockBackend is not thread-safe (the camera server renders with it)
        self.violations: list[str] = []
        self._applied = None
        self._stiffness = np.zeros(N_LOLA)
        with self.lock:
            mock.set_stiffness(list(JOINTS), 0.0)  # LoLA starts with the joints limp

    def to_mono(self, mock_t: float) -> float:
        return mock_t - self.offset_s

    def advance(self, now_s: float) -> None:
        with self.lock:
            self._advance_locked(now_s)

    def _advance_locked(self, now_s: float) -> None:
        ahead = now_s + self.offset_s - self.mock.now()
        if ahead > 0:
            self.mock.sleep(ahead)

    def positions(self) -> np.ndarray:
        with self.lock:
            return to_lola(self.mock.read_joints().angles_rad)

    def apply(self, position, stiffness) -> None:
        from naocal.solver.errors import SafetyError

        position, stiffness = np.asarray(position, dtype=float), np.asarray(stiffness, dtype=float)
        with self.lock:
            stiff = {name: stiffness[MOTOR_OF[name]] > 0 for name in JOINTS}
            for name in JOINTS:  # the mock ignores commands to a joint at stiffness 0, as a limp motor does
                if stiff[name] != (self._stiffness[MOTOR_OF[name]] > 0):
                    self.mock.set_stiffness([name], 1.0 if stiff[name] else 0.0)
            self._stiffness = stiffness.copy()
            targets = {name: float(position[MOTOR_OF[name]]) for name in JOINTS if stiff[name]}
            targets.pop("RHipYawPitch", None)  # one motor: LHipYawPitch's command drives it
            if not targets or targets == self._applied:
                return
            try:
                self.mock.command(targets, 1.0)
            except SafetyError as err:
                self.violations.append(str(err))
            self._applied = targets


# ---------------------------------------------------------------------------------------------- LoLA
class FakeLola:
    """A LoLA on a Unix socket at `path`, 12 ms cycles of the monotonic clock, one client at a time.

    physics : SimpleServos or MockPhysics.
    second_client : 'silent' (accepted, never served: what LoLA does with a second connection as far as teams
        report) or 'refuse' (the listening socket is closed while a client is served).
    record_path : also append every record to this file (msgpack), for a fake in another process.
    cycle_s : the cycle period (LoLA's is 12 ms).
    hostile : None, or a function {sensor map} -> what to send instead: a map (packed as LoLA packs it, values of
        any type), None (send nothing: a frozen LoLA) or "close" (close the connection). Settable while running.
    """

    def __init__(self, path, physics=None, *, second_client: str = "silent", record_path=None, cycle_s=CYCLE_S):
        self.path = os.fspath(path)
        self.cycle_s = cycle_s  # longer than 12 ms: a robot whose LoLA runs slow (a loaded or throttled head)
        self.physics = physics or SimpleServos()
        self.second_client = second_client
        self.temperature = np.full(N_LOLA, 35.0)
        self.status = np.zeros(N_LOLA, dtype=int)
        self.records: list[dict] = []  # per cycle: t, sent position, the answer applied (or None), n answers
        self.events: list[tuple[float, str]] = []
        self.answers_received = 0
        self.messages_sent = 0
        self.late_cycles = 0
        self._record_file = open(record_path, "ab") if record_path else None
        self._stop = threading.Event()
        self._listener = None
        self._client = None
        self._parked: list[socket.socket] = []
        self._unpacker = None
        self._last_answer = None  # (position, stiffness)
        self._thread = None
        self.lock = threading.Lock()
        self.hostile = None
        self.hostile_sent = 0  # messages the hostile function changed

    # lifecycle
    def start(self) -> "FakeLola":
        if os.path.exists(self.path):
            os.unlink(self.path)
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._listener.bind(self.path)
        self._listener.listen(4)
        self._listener.setblocking(False)
        self._thread = threading.Thread(target=self._run, name="fake-lola", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        for sock in [self._client, self._listener, *self._parked]:
            if sock is not None:
                sock.close()
        if self._record_file is not None:
            self._record_file.close()
        if os.path.exists(self.path):
            os.unlink(self.path)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False

    @property
    def connected(self) -> bool:
        return self._client is not None

    def wait_for(self, predicate, timeout_s: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if predicate(self):
                    return True
            time.sleep(0.005)
        return False

    # the 12 ms loop
    def _run(self) -> None:
        t0 = time.monotonic()
        k = 0
        while not self._stop.is_set():
            k += 1
            tick = t0 + k * self.cycle_s
            delay = tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -self.cycle_s:  # late (a busy machine, or the mock rendering): skip the missed ticks
                self.late_cycles += 1
                k += int(-delay / self.cycle_s)
            self._accept()
            now = time.monotonic()
            answers = self._drain()
            with self.lock:
                if answers:
                    self._last_answer = answers[-1]
                    self.answers_received += len(answers)
                if self._last_answer is not None:
                    self.physics.apply(*self._last_answer)
                self.physics.advance(now)
                position = self.physics.positions()
                stiffness = self._last_answer[1] if self._last_answer is not None else np.zeros(N_LOLA)
                every = [[[float(p) for p in pos], [float(s) for s in stiff]] for pos, stiff in answers]
                record = {"t": now, "k": k, "sent": [float(p) for p in position], "n_answers": len(answers),
                          "answers": every, "position": every[-1][0] if every else None,
                          "stiffness": every[-1][1] if every else None, "client": self._client is not None}
                self.records.append(record)
                if self._record_file is not None:
                    self._record_file.write(msgpack.packb(record))
                    self._record_file.flush()
            if self._client is not None:
                message = sensor_map(position, stiffness, self.temperature, self.status)
                hostile = self.hostile
                if hostile is not None:
                    message = hostile(message)
                    self.hostile_sent += 1
                    if message is None:
                        continue
                    if message == "close":
                        self._drop_client("hostile close")
                        continue
                try:
                    self._client.sendall(msgpack.packb(message, use_single_float=True))
                    self.messages_sent += 1
                except OSError:
                    self._drop_client("send failed")

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self._listener.accept()
            except (BlockingIOError, OSError):
                return
            if self._client is None:
                conn.setblocking(False)
                self._client = conn
                self._unpacker = msgpack.Unpacker(raw=False, max_buffer_size=1 << 20)
                self.events.append((time.monotonic(), "connect"))
                if self.second_client == "refuse":
                    self._listener.close()  # nobody else gets in: a connect() is refused
                    self._listener = _Closed()
            else:
                self._parked.append(conn)  # accepted, never served
                self.events.append((time.monotonic(), "second client parked"))

    def _drain(self) -> list:
        if self._client is None:
            return []
        answers = []
        while True:
            try:
                data = self._client.recv(1 << 16)
            except BlockingIOError:
                break
            except OSError:
                self._drop_client("receive failed")
                break
            if not data:
                self._drop_client("client disconnected")
                break
            self._unpacker.feed(data)
            for message in self._unpacker:
                if isinstance(message, dict) and len(message.get("Position", ())) == N_LOLA \
                        and len(message.get("Stiffness", ())) == N_LOLA:
                    answers.append((np.array(message["Position"], dtype=float),
                                    np.array(message["Stiffness"], dtype=float)))
                else:
                    self.events.append((time.monotonic(), f"malformed answer {str(message)[:80]}"))
        return answers

    def _drop_client(self, why: str) -> None:
        self.events.append((time.monotonic(), why))
        if self._record_file is not None:
            self._record_file.write(msgpack.packb({"event": why, "t": time.monotonic()}))
        self._client.close()
        self._client = None


class _Closed:
    def accept(self):
        raise OSError("closed")

    def close(self):
        pass


def answer_series(records, since_t=-math.inf):
    """(times, positions (n, 25), stiffnesses (n, 25)) of every answer in `records` received after `since_t`, in
    order (an answer is timed by the cycle that received it; two may arrive in one cycle on a busy machine)."""
    rows = [(r["t"], pos, stiff) for r in records if r["t"] >= since_t for pos, stiff in r.get("answers", ())]
    if not rows:
        return np.zeros(0), np.zeros((0, N_LOLA)), np.zeros((0, N_LOLA))
    t, position, stiffness = zip(*rows)
    return np.array(t), np.array(position), np.array(stiffness)


def read_records(path) -> tuple[list, list]:
    """(cycle records, events) from a record file written by FakeLola(record_path=...)."""
    records, events = [], []
    with open(path, "rb") as file:
        unpacker = msgpack.Unpacker(file, raw=False)
        try:
            for item in unpacker:
                (events if "event" in item else records).append(item)
        except (msgpack.OutOfData, ValueError):
            pass  # the writer was killed mid-record
    return records, events


# ---------------------------------------------------------------------------------------------- cameras
def bgr_to_yuyv(bgr: np.ndarray) -> np.ndarray:
    """(h, w, 3) BGR -> (h, w, 2) YUYV as a V4L2 buffer holds it ([Y0 U0 Y1 V0] per pixel pair): the inverse of
    OpenCV's COLOR_YUV2BGR_YUYV, which reads BT.601 video range (Y 16..235)."""
    b, g, r = (bgr[..., k].astype(float) for k in range(3))
    y = 16.0 + 0.257 * r + 0.504 * g + 0.098 * b
    u = 128.0 - 0.148 * r - 0.291 * g + 0.439 * b
    v = 128.0 + 0.439 * r - 0.368 * g - 0.071 * b
    out = np.empty(bgr.shape[:2] + (2,), dtype=np.uint8)
    out[..., 0] = np.clip(np.rint(y), 0, 255)
    out[:, 0::2, 1] = np.clip(np.rint((u[:, 0::2] + u[:, 1::2]) / 2), 0, 255)
    out[:, 1::2, 1] = np.clip(np.rint((v[:, 0::2] + v[:, 1::2]) / 2), 0, 255)
    return out


class SyntheticCapture:
    """cv2.VideoCapture's contract over synthetic YUYV frames at 30 fps of the monotonic clock (in process).

    Each frame is noise plus a moving square; frame k's buffer timestamp is its arrival time minus `stamp_lag_s`.
    Faults for tests, each the number of frames it lasts from now: freeze_frames (identical pixels, new stamps),
    stall_frames (the same timestamp again), wrong_size_frames, zero_row_frames (rows of zeros, green in BGR);
    missing=True: the device does not exist (isOpened() False).
    """

    opened: list = []  # every instance, to count reopenings

    def __init__(self, device="/dev/video-bottom", api=None, *, width=640, height=480, fps=30.0, missing=False,
                 stamp_lag_s=0.02, faults=None):
        self.device, self.api = device, api
        self.width, self.height, self.period_s = width, height, 1.0 / fps
        self.missing = missing
        self.stamp_lag_s = stamp_lag_s
        self.faults = faults if faults is not None else {}
        self.settings: dict = {}
        self.released = False
        self._k = None
        self._stamp_ms = 0.0
        self._rng = np.random.default_rng(len(SyntheticCapture.opened))
        self._frozen = None
        SyntheticCapture.opened.append(self)

    def isOpened(self) -> bool:
        return not self.missing and not self.released

    def set(self, prop, value) -> bool:
        self.settings[prop] = value
        return True

    def get(self, prop) -> float:
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self._stamp_ms
        return {cv2.CAP_PROP_FRAME_WIDTH: self.width, cv2.CAP_PROP_FRAME_HEIGHT: self.height}.get(
            prop, self.settings.get(prop, -1.0))

    def _fault(self, name) -> bool:
        left = self.faults.get(name, 0)
        if left > 0:
            self.faults[name] = left - 1
            return True
        return False

    def grab(self) -> bool:
        if not self.isOpened():
            return False
        now = time.monotonic()
        k = math.floor(now / self.period_s)
        if self._k is not None and k <= self._k:
            k = self._k + 1
            time.sleep(max(0.0, k * self.period_s - now))  # block until the next frame, as V4L2 does
        self._k = k
        if not (self._stamp_ms and self._fault("stall_frames")):  # a stalled stamp repeats the last one
            self._stamp_ms = (k * self.period_s - self.stamp_lag_s) * 1000.0
        return True

    def retrieve(self, *args):
        if self._k is None:
            return False, None
        if self._fault("wrong_size_frames"):
            return True, np.zeros((1, self.width * self.height * 2 - 100), dtype=np.uint8)
        if self._fault("freeze_frames") and self._frozen is not None:
            return True, self._frozen.copy()
        grey = self._rng.integers(90, 110, (self.height, self.width), dtype=np.uint8)
        x = (self._k * 7) % (self.width - 40)
        grey[100:140, x:x + 40] = 230
        frame = bgr_to_yuyv(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
        if self._fault("zero_row_frames"):
            frame[self.height // 2:self.height // 2 + 8] = 0
        self._frozen = frame
        return True, frame.copy()

    def read(self):
        return (self.retrieve() if self.grab() else (False, None))

    def release(self) -> None:
        self.released = True


class CameraServer:
    """Serves the mock's bottom camera to RemoteCapture over a Unix socket, in the fake robot's process.

    Frame k is exposed at the mock's FRAME_PHASE_S + k / 30 s (its middle) and delivered camera_delay_s later (the
    mock's). Its buffer timestamp is placed where naocal's prior expects it, off by `stamp_error_s` (the priors
    are only priors): t_buffer = t_middle + V4L2 stamp delay + readout / 2 + stamp_error_s.
    """

    def __init__(self, path, physics: MockPhysics, *, stamp_error_s: float = 0.004, missing: bool = False):
        from naocal.backends.v4l2_camera import CAMERAS

        self.path = os.fspath(path)
        self.physics = physics
        # per camera: its V4L2 prior, each off by stamp_error_s
        self.stamp_shift_s = {name: prior.stamp_delay_s + prior.readout_s / 2 + stamp_error_s
                              for name, prior in CAMERAS.items()}
        self.missing = missing
        self._stop = threading.Event()

    def start(self) -> "CameraServer":
        if os.path.exists(self.path):
            os.unlink(self.path)
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._listener.bind(self.path)
        self._listener.listen(4)
        threading.Thread(target=self._accept_loop, name="fake-camera", daemon=True).start()
        return self

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            conn, _ = self._listener.accept()
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn) -> None:
        from naocal.backends.mock import FRAME_PERIOD_S, FRAME_PHASE_S

        mock = self.physics.mock
        unpacker = msgpack.Unpacker(raw=False)
        image, last_k, camera = None, None, "bottom"
        with conn:
            while True:
                data = conn.recv(4096)
                if not data:
                    return
                unpacker.feed(data)
                for request in unpacker:
                    op = request.get("op")
                    if op == "open":  # the device names the camera, as the NAO's udev rules do
                        camera = "top" if "top" in str(request.get("device", "")) else "bottom"
                        reply = {"ok": not self.missing}
                    elif op == "grab":
                        # The next frame after the last one served: wait for its arrival, as V4L2's DQBUF does.
                        now_mock = time.monotonic() + self.physics.offset_s
                        newest = math.floor((now_mock - mock.camera_delay_s - FRAME_PHASE_S) / FRAME_PERIOD_S)
                        k = newest + 1 if last_k is None else max(last_k + 1, newest - 2)
                        arrival = self.physics.to_mono(FRAME_PHASE_S + k * FRAME_PERIOD_S + mock.camera_delay_s)
                        time.sleep(max(0.0, arrival - time.monotonic()))
                        with self.physics.lock:
                            self.physics._advance_locked(time.monotonic())
                            image = mock.capture(camera)
                        k = last_k = int(round((mock.exposure_time(image) - FRAME_PHASE_S) / FRAME_PERIOD_S))
                        stamp_s = self.physics.to_mono(image.t_exposure_s) + self.stamp_shift_s[camera]
                        reply = {"ok": True, "k": k, "stamp_ms": stamp_s * 1000.0}
                    elif op == "retrieve" and image is not None:
                        with self.physics.lock:
                            pixels = image.pixels  # rendered here, on first use
                        reply = {"ok": True, "yuyv": bgr_to_yuyv(np.ascontiguousarray(pixels)).tobytes(),
                                 "shape": [pixels.shape[0], pixels.shape[1], 2]}
                    else:
                        reply = {"ok": False}
                    conn.sendall(msgpack.packb(reply, use_bin_type=True))


class RemoteCapture:
    """cv2.VideoCapture's contract over a CameraServer (the bridge's side of the fake camera)."""

    def __init__(self, device, api=None, *, camera_socket):
        self.device, self.api = device, api
        self.settings: dict = {}
        self._stamp_ms = 0.0
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._sock.settimeout(10.0)
        self._sock.connect(os.fspath(camera_socket))
        self._unpacker = msgpack.Unpacker(raw=False, max_buffer_size=64 << 20)
        self._open = bool(self._call({"op": "open", "device": str(device)})["ok"])

    def _call(self, request) -> dict:
        self._sock.sendall(msgpack.packb(request))
        while True:
            for reply in self._unpacker:
                return reply
            data = self._sock.recv(1 << 20)
            if not data:
                raise OSError("camera server gone")
            self._unpacker.feed(data)

    def isOpened(self) -> bool:
        return self._open

    def set(self, prop, value) -> bool:
        self.settings[prop] = value
        return True

    def get(self, prop) -> float:
        return self._stamp_ms if prop == cv2.CAP_PROP_POS_MSEC else self.settings.get(prop, -1.0)

    def grab(self) -> bool:
        reply = self._call({"op": "grab"})
        if reply.get("ok"):
            self._stamp_ms = float(reply["stamp_ms"])
        return bool(reply.get("ok"))

    def retrieve(self, *args):
        reply = self._call({"op": "retrieve"})
        if not reply.get("ok"):
            return False, None
        return True, np.frombuffer(reply["yuyv"], dtype=np.uint8).reshape(reply["shape"])

    def read(self):
        return self.retrieve() if self.grab() else (False, None)

    def release(self) -> None:
        self._open = False
        self._sock.close()


# ---------------------------------------------------------------------------------------------- programs
def _robot_main(args) -> int:
    """The fake robot: FakeLola with MockPhysics and a CameraServer, until SIGTERM."""
    import signal

    from naocal.backends.mock import MockBackend

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    # An ideal encoder: LoLA's readings are 32-bit floats, which hide the mock's 0.1 deg grid from naocal's
    # quantisation detection (solver.adapter.encoder_resolution); with the grid the fit would use the readings and
    # their quantisation error (0.1-0.2 deg on the knees) would swamp what this test checks.
    mock = MockBackend(args.seed, encoder_resolution_deg=0.0, camera_delay_s=0.04, sensor_period_s=CYCLE_S,
                       sensor_lag_cycles=1, command_delay_s=CYCLE_S)
    physics = MockPhysics(mock, time.monotonic())
    camera = CameraServer(args.camera_socket, physics).start()
    lola = FakeLola(args.lola_socket, physics, record_path=args.record).start()
    print("fake robot: ready", flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        lola.stop()
        camera._stop.set()
        print(f"fake robot: stopped; violations {len(physics.violations)}; late cycles {lola.late_cycles}",
              flush=True)
        for violation in physics.violations[:20]:
            print(f"violation: {violation}", flush=True)
    return 0


def _bridge_main(camera_socket, naocal_argv) -> int:
    """`naocal` with the V4L2 device replaced by the fake robot's camera."""
    import naocal.backends.v4l2_camera as v4l2_camera
    from naocal.tools import cli

    v4l2_camera.open_v4l2 = lambda device: RemoteCapture(device, cv2.CAP_V4L2, camera_socket=camera_socket)
    v4l2_camera.device_present = lambda device: True  # the fake robot serves both cameras
    return cli.main(naocal_argv)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["bridge"]:
        rest = argv[1:]
        if len(rest) < 3 or rest[0] != "--camera-socket" or rest[2] != "--":
            print("usage: python -m tests.lola_fakes bridge --camera-socket PATH -- NAOCAL_ARGS...", file=sys.stderr)
            return 2
        return _bridge_main(rest[1], rest[3:])
    parser = argparse.ArgumentParser(prog="python -m tests.lola_fakes")
    sub = parser.add_subparsers(dest="program", required=True)
    robot = sub.add_parser("robot", help="fake LoLA + mock physics + camera server")
    robot.add_argument("--lola-socket", required=True)
    robot.add_argument("--camera-socket", required=True)
    robot.add_argument("--record", required=True)
    robot.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    return _robot_main(args)


if __name__ == "__main__":
    sys.exit(main())
