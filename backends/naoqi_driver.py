"""`NaoqiBackend`: a real NAO through NAOqi, with libqi-python (`qi`). Meant to run on the robot, beside NAOqi.

Services used: ALMotion (getAngles with sensors, setAngles non-blocking, setStiffnesses, getLimits),
ALVideoDevice (subscribeCamera bottom/VGA/BGR/30 fps, getImageRemote, releaseImage, unsubscribe) and
ALMemory ('DCM/Time' and the robot's ids).

Safety: every target is checked before anything is sent: known joint, finite, inside the joint's limits (the
tighter of naocal's model limits, solver.limits, and what ALMotion.getLimits reports), and HeadPitch inside the
documented HeadPitch-vs-HeadYaw table for the HeadYaw the head will have. A refused command raises SafetyError
and sends nothing. There is no collision model here: the agent plans collision-free stances. LHipYawPitch and
RHipYawPitch are one motor on a NAO: both targets are passed on and NAOqi follows LHipYawPitch's.

Clocks. The robot clock of this backend is the DCM clock ('DCM/Time', ms, the clock the joint sensors are
sampled on), in s. `read_joints` stamps each sample with 'DCM/Time' read just before it. `now()` is the local
monotonic clock plus an offset to the DCM clock measured at connection (the sample with the shortest round
trip; error below one DCM cycle when the driver runs on the robot). Images carry their own timestamp
(getImageRemote fields 4 and 5, s and us) on a clock that depends on the NAOqi version: the V4L2 buffer time
(CLOCK_MONOTONIC on current kernels), the system time, or the DCM time. With `image_clock='auto'` the first image
decides: its stamp is mapped through each candidate clock and the one that puts the exposure within the last
`MAX_IMAGE_AGE_S` of robot time is used; none or two disagreeing candidates raise NaocalError instead of a guess.
The monotonic and system clocks are this machine's, so run the driver on the robot (docs/DEPLOY.md). The stamp
is shifted by `image_stamp_offset_s` (default one frame earlier): whether NAOqi stamps the start or the end of the
readout is not documented, and reporting an exposure too early only makes the agent wait one frame longer,
while too late would let it use an image taken while the robot still moved.

Every call to NAOqi has a deadline (`call_timeout_s`); a call past it raises RobotTimeout.

Readings: every joint angle ALMotion.getAngles returns, and DCM/Time, is checked before it is served
(backends.base.checked_reading: a finite number within the joint's limits plus limits.READING_MARGIN_RAD). One
that cannot be trusted is a fault: RobotFault now and on every later command, set_stiffness and sleep (the agent
stops; NAOqi keeps its last targets, docs/DEPLOY.md); restart the bridge once the robot is checked.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np

from naocal.backends.base import Backend, JointTables, CameraImage, CameraIntrinsics, JointReading, checked_reading, nominal_intrinsics
from naocal.solver import fields, limits
from naocal.backends.errors import RobotFault, RobotTimeout
from naocal.solver.errors import NaocalError, SafetyError
from naocal.solver.joints import HEAD_JOINTS, JOINTS

log = logging.getLogger("naocal.naoqi")

BOTTOM_CAMERA, VGA, BGR_COLORSPACE, FPS = 1, 2, 13, 30
CAMERA_INDEX = {"top": 0, "bottom": BOTTOM_CAMERA}  # ALVideoDevice's camera indices
FRAME_PERIOD_S = 1.0 / FPS
DCM_CYCLE_S = 0.010
MAX_IMAGE_AGE_S = 2.0
NOMINAL_INTRINSICS = nominal_intrinsics(640, 480)
IMAGE_CLOCKS = ("auto", "dcm", "monotonic", "realtime")

# qi 3.1.5 sometimes aborts the interpreter at exit ("terminate called without an active exception") if a
# qi.Session object was destroyed earlier; closed sessions are parked here so they live until the end.
_CLOSED_SESSIONS: list = []


class NaoqiBackend(JointTables, Backend):
    """A NAO reached through NAOqi at `url` (on the robot: tcp://127.0.0.1:9559).

    Parameters
    ----------
    url : NAOqi's address.
    image_clock : 'auto', or the clock the image timestamps are on: 'dcm', 'monotonic', 'realtime'.
    image_stamp_offset_s : added to every image timestamp to get the exposure time (see the module doc).
    intrinsics : the camera's prior intrinsics (default: nominal, from the field of view).
    call_timeout_s : deadline of each NAOqi call.
    """

    name = "naoqi"
    keeps_commands_on_close = True  # close() only unsubscribes the cameras: NAOqi keeps the last targets and stiffness

    def __init__(
        self,
        url: str = "tcp://127.0.0.1:9559",
        *,
        image_clock: str = "auto",
        image_stamp_offset_s: float = -FRAME_PERIOD_S,
        intrinsics: CameraIntrinsics | None = None,
        call_timeout_s: float = 5.0,
        camera_subscriber: str = "naocal",
    ):
        if image_clock not in IMAGE_CLOCKS:
            raise ValueError(f"image_clock must be one of {IMAGE_CLOCKS}, got {image_clock!r}")
        import qi  # the NAOqi client library is only needed for a real robot

        self.url = url
        self.image_clock = image_clock
        self.image_stamp_offset_s = float(image_stamp_offset_s)
        self.call_timeout_s = float(call_timeout_s)
        self._intrinsics = intrinsics or NOMINAL_INTRINSICS
        self._lock = threading.Lock()  # NAOqi calls from one thread at a time
        self._closed = False
        self._camera_handle = None
        self._camera_subscriber = camera_subscriber
        self._top_camera_handle = None  # subscribed when the top camera is first asked for
        self._image_clock_offset_s = None
        self._head_targets: dict[str, float] = {}  # last commanded head angles
        self._fault: str | None = None  # why motion is refused: a reading that could not be trusted
        self._session = qi.Session()
        try:
            self._wait(self._session.connect(url, _async=True), f"connect to NAOqi at {url}")
            self._motion = self._wait(self._session.service("ALMotion", _async=True), "find ALMotion")
            self._video = self._wait(self._session.service("ALVideoDevice", _async=True), "find ALVideoDevice")
            self._memory = self._wait(self._session.service("ALMemory", _async=True), "find ALMemory")
            self._limits, self._speeds = self._read_limits()
            self._clock_offset_s = self._measure_clock_offset()
            self._camera_handle = str(self._call(self._video, "subscribeCamera", camera_subscriber,
                                                 BOTTOM_CAMERA, VGA, BGR_COLORSPACE, FPS))
        except BaseException:
            self._closed = True
            self._session.close()
            _CLOSED_SESSIONS.append(self._session)
            raise
        log.info("connected to NAOqi at %s; camera subscriber %s", url, self._camera_handle)

    # ------------------------------------------------------------------------------------------ NAOqi calls
    def _wait(self, future, what: str):
        try:
            return future.value(int(self.call_timeout_s * 1000))
        except RuntimeError as err:
            if "timeout" in str(err).lower():
                raise RobotTimeout(f"NAOqi at {self.url}: {what}: no answer within {self.call_timeout_s:g} s") from None
            raise NaocalError(f"NAOqi at {self.url}: {what} failed: {' '.join(str(err).split())[:300]}") from None

    def _call(self, service, method: str, *args):
        if self._closed:
            raise NaocalError(f"NAOqi backend for {self.url} is closed ({method})")
        with self._lock:
            return self._wait(getattr(service, method)(*args, _async=True), method)

    def _number(self, value, what: str, low: float = -math.inf) -> float:
        """A number NAOqi reported, checked before use (solver.fields.number): a string, a bool, NaN or a value below
        `low` is refused with one line naming what was asked (NAOqi's dynamic values carry any type)."""
        return fields.number(value, f"NAOqi at {self.url}", what, low=low)

    def _read_limits(self):
        model_limits, model_speeds = limits.joint_limits(), limits.max_speeds()
        joint_limits, speeds = {}, {}
        for name in JOINTS:
            reported = self._call(self._motion, "getLimits", name)
            lower_rad, upper_rad, speed_rad_per_s = (self._number(v, f"getLimits({name})") for v in reported[0][:3])
            lower = max(lower_rad, model_limits[name][0])
            upper = min(upper_rad, model_limits[name][1])
            if not lower < upper:
                raise NaocalError(f"{name}: ALMotion limits [{lower_rad}, {upper_rad}] do not overlap naocal's "
                                  f"{model_limits[name]}")
            joint_limits[name] = (lower, upper)
            speeds[name] = min(speed_rad_per_s, model_speeds[name]) if speed_rad_per_s > 0 else model_speeds[name]
        return joint_limits, speeds

    def _dcm_time_s(self) -> float:
        return self._number(self._call(self._memory, "getData", "DCM/Time"), "DCM/Time (ms)", low=0.0) * 1e-3

    def _measure_clock_offset(self, samples: int = 7) -> float:
        """DCM time minus local monotonic time, from the read with the shortest round trip."""
        best = None
        for _ in range(samples):
            before = time.monotonic()
            dcm_s = self._dcm_time_s()
            after = time.monotonic()
            if best is None or after - before < best[0]:
                # DCM/Time is the start of the current cycle: on average half a cycle old.
                best = (after - before, dcm_s + DCM_CYCLE_S / 2 - (before + after) / 2)
        return best[1]

    # ------------------------------------------------------------------------------------------ Backend
    def robot_identity(self) -> dict:
        def memory_value(key):
            try:
                return str(self._call(self._memory, "getData", key))
            except NaocalError:
                return "unknown"

        body_id = memory_value("Device/DeviceList/ChestBoard/BodyId")
        head_id = memory_value("RobotConfig/Head/FullHeadId")
        model = f"NAO {memory_value('RobotConfig/Body/BaseVersion')}"
        return {"id": body_id, "model": model, "body_id": body_id, "head_id": head_id}

    def _refuse_if_faulted(self) -> None:
        if self._fault is not None:
            raise RobotFault(self._fault)

    def command(self, targets_rad: dict[str, float], speed_fraction: float) -> None:
        self._refuse_if_faulted()
        speed_fraction = limits.check_speed_fraction(speed_fraction)
        head_angles = None
        if len(set(HEAD_JOINTS) & set(targets_rad)) == 1:
            # The head joint not commanded now may stand where it reads or still be on its way to its last target.
            current = self.read_joints().angles_rad
            head_angles = {name: [current[name]] + ([self._head_targets[name]] if name in self._head_targets else [])
                           for name in HEAD_JOINTS}
        targets = limits.check_targets(targets_rad, self._limits, head_angles=head_angles)
        if targets:
            self._call(self._motion, "setAngles", list(targets), list(targets.values()), speed_fraction)
            self._head_targets.update({name: targets[name] for name in HEAD_JOINTS if name in targets})

    def read_joints(self) -> JointReading:
        self._refuse_if_faulted()
        dcm_ms = self._call(self._memory, "getData", "DCM/Time")
        angles = self._call(self._motion, "getAngles", list(JOINTS), True)
        if len(angles) != len(JOINTS):
            raise NaocalError(f"ALMotion.getAngles returned {len(angles)} angles for {len(JOINTS)} joints")
        try:
            reading = checked_reading(dict(zip(JOINTS, angles)), dcm_ms, self._limits)
        except RobotFault as err:
            self._fault = f"NAOqi at {self.url}: {err}; motion refused from now on (restart the bridge)"
            log.error("%s", self._fault)
            raise RobotFault(self._fault) from None
        return JointReading(angles_rad=reading.angles_rad, t_s=min(reading.t_s * 1e-3, self.now()))

    def set_stiffness(self, names, stiffness: float) -> None:
        names = [names] if isinstance(names, str) else list(names)
        unknown = [name for name in names if name not in self._limits]
        if unknown:
            raise SafetyError(f"unknown joint(s) {unknown}: naocal sets the stiffness of {', '.join(JOINTS)} only")
        stiffness = float(stiffness)
        if not 0.0 <= stiffness <= 1.0:
            raise SafetyError(f"stiffness must be in [0, 1], got {stiffness}")
        self._refuse_if_faulted()
        self._call(self._motion, "setStiffnesses", names, [stiffness] * len(names))

    def capture(self, camera: str = "bottom") -> CameraImage | None:
        if camera not in CAMERA_INDEX:
            raise NaocalError(f"unknown camera {camera!r}: expected one of {', '.join(CAMERA_INDEX)}")
        handle = self._camera_handle
        if camera == "top":
            if self._top_camera_handle is None:
                self._top_camera_handle = str(self._call(self._video, "subscribeCamera",
                                                         f"{self._camera_subscriber}_top", CAMERA_INDEX["top"], VGA,
                                                         BGR_COLORSPACE, FPS))
            handle = self._top_camera_handle
        try:
            raw = self._call(self._video, "getImageRemote", handle)
        finally:
            try:
                self._call(self._video, "releaseImage", handle)
            except NaocalError as err:
                log.debug("releaseImage: %s", err)
        if not raw or len(raw) < 7:
            return None
        width, height, layers, colorspace, seconds, microseconds, data = raw[:7]
        source = f"NAOqi at {self.url}: ALVideoDevice.getImageRemote"  # each value checked before use
        width, height = (fields.count(n, source, name, 1, 1 << 16)
                         for n, name in ((width, "width"), (height, "height")))
        layers, colorspace = fields.count(layers, source, "layers"), fields.count(colorspace, source, "colorspace")
        seconds, microseconds = fields.count(seconds, source, "seconds"), fields.count(microseconds, source,
                                                                                         "microseconds", 0, 10 ** 6)
        if isinstance(data, str):
            raise NaocalError("ALVideoDevice.getImageRemote delivered the pixels as text, not bytes (the qi bytes "
                              "problem: the service must declare a raw-buffer field)")
        if (layers, colorspace) != (3, BGR_COLORSPACE):
            raise NaocalError(f"camera image has {layers} layers in colour space {colorspace}; expected 3, BGR (13)")
        pixels = np.frombuffer(bytes(data), dtype=np.uint8)
        if pixels.size != width * height * 3:
            raise NaocalError(f"camera image of {width} x {height} x 3 arrived with {pixels.size} bytes")
        stamp_s = seconds + microseconds * 1e-6
        t_exposure_s = self._image_stamp_to_robot_s(stamp_s) + self.image_stamp_offset_s
        return CameraImage(pixels=pixels.reshape(height, width, 3).copy(),
                           t_exposure_s=min(t_exposure_s, self.now()), camera=camera)

    def _image_stamp_to_robot_s(self, stamp_s: float) -> float:
        if self._image_clock_offset_s is None:
            self._image_clock_offset_s = self._image_clock_offset(stamp_s)
        return stamp_s + self._image_clock_offset_s

    def _image_clock_offset(self, stamp_s: float) -> float:
        """Offset from the image clock to the DCM clock, for `self.image_clock` or detected from one stamp."""
        candidates = {
            "dcm": 0.0,
            "monotonic": self._clock_offset_s,
            "realtime": self._clock_offset_s - (time.time() - time.monotonic()),
        }
        if self.image_clock != "auto":
            return candidates[self.image_clock]
        now_s = self.now()
        plausible = {name: offset for name, offset in candidates.items()
                     if now_s - MAX_IMAGE_AGE_S <= stamp_s + offset <= now_s + 2 * DCM_CYCLE_S}
        if not plausible:
            raise NaocalError(
                f"image timestamp {stamp_s:.3f} s is on none of the clocks {sorted(candidates)} (DCM time now "
                f"{now_s:.3f} s); run the driver on the robot, or pass image_clock="
            )
        if max(plausible.values()) - min(plausible.values()) > 2 * DCM_CYCLE_S:
            raise NaocalError(f"image timestamp {stamp_s:.3f} s fits several clocks ({sorted(plausible)}); "
                              "pass image_clock= explicitly")
        name = next(iter(plausible))
        log.info("camera timestamps are on the %s clock", name)
        return plausible[name]

    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    def now(self) -> float:
        return time.monotonic() + self._clock_offset_s

    def sleep(self, duration_s: float) -> None:
        duration_s = float(duration_s)
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"sleep: duration_s must be finite and >= 0, got {duration_s}")
        self._refuse_if_faulted()
        deadline = time.monotonic() + duration_s
        while (remaining_s := deadline - time.monotonic()) > 0:
            time.sleep(remaining_s)

    def close(self) -> None:
        if self._closed:
            return
        try:
            for handle in (self._top_camera_handle, self._camera_handle):
                if handle is not None:
                    self._call(self._video, "unsubscribe", handle)
        except NaocalError as err:
            log.warning("could not unsubscribe the camera: %s", err)
        finally:
            self._closed = True
            self._session.close()
            _CLOSED_SESSIONS.append(self._session)
