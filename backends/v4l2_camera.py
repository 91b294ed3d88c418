"""A NAO V6 camera through V4L2 (OpenCV's CAP_V4L2 backend), as SPL team images run it (no ALVideoDevice).

Devices: `/dev/video-bottom` and `/dev/video-top` (udev names on the team images). Format YUYV (YUV 4:2:2),
640 x 480 or 1280 x 960, 30 fps, OpenCV's own conversion off (CAP_PROP_CONVERT_RGB = 0): the raw buffer is
converted here with cv2.cvtColor(..., COLOR_YUV2BGR_YUYV), so a corrupted buffer is seen as it is.

Exposure for calibration is fixed, not automatic (an automatic exposure changes between the images of one
stance): CAP_PROP_AUTO_EXPOSURE = 1 (V4L2 exposure_auto "manual mode" of the UVC driver), CAP_PROP_EXPOSURE =
`exposure` (V4L2 exposure_absolute, in units of 100 us; default 100 = 10 ms, well below the 33 ms frame period
and short enough to keep any residual motion from blurring the boards), CAP_PROP_GAIN = `gain` if given. What the
driver reports back is logged; a resolution it does not accept is an error. Check the controls on the robot with
`v4l2-ctl -d /dev/video-bottom --list-ctrls`.

Time. CAP_PROP_POS_MSEC of CAP_V4L2 is the V4L2 buffer timestamp (OpenCV's cap_v4l.cpp: tv_sec * 1000 +
tv_usec / 1000), on CLOCK_MONOTONIC for the NAO's UVC cameras: the clock the LoLA driver stamps joint readings
with, so no clock mapping is needed on the robot (a stamp further than MAX_STAMP_AGE_S from the monotonic clock is
refused rather than paired with the wrong readings). The cameras have a rolling shutter; row r of h is exposed
at t_buffer - readout_s - stamp_delay_s + readout_s * (r + 0.5) / h (B-Human's CoordinateSystemProvider with its
imageRecordingTime = readout and imageRecordingDelay = stamp delay), so the middle of the frame, which
CameraImage.t_exposure_s reports, is t_buffer - stamp_delay_s - readout_s / 2. The numbers are B-Human's
(coordinateSystemProvider.cfg): readout 0.037 s upper / 0.045 s lower, stamp delay -0.039 / -0.036 s. They are
priors, not measurements of your robot: the agent waits 100 ms after the joints are still before it uses an
image, which covers errors of tens of milliseconds in them.

Robustness (B-Human resets frozen cameras and drops corrupted frames; so does this): a reader thread dequeues
every frame (grab) so the queue never holds stale ones, and converts one only when `capture()` asks. A frame
with the wrong number of bytes or a row of zeros (green after conversion) is dropped, and after 3 in a row the
device is reopened; a timestamp that does not advance for 3 frames, or two retrieved frames with identical
pixels (a live sensor is never noise-free), mean a frozen camera: it is reopened. Every wait has a deadline.

The camera is opened on first use: a bridge whose camera is missing still serves the joints, and `capture()`
raises NaocalError naming the device.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from dataclasses import dataclass

import cv2
import numpy as np

from naocal.backends.base import CameraImage, CameraIntrinsics, nominal_intrinsics
from naocal.backends.errors import RobotTimeout
from naocal.solver.camera import INTRINSICS_KEYS
from naocal.solver.errors import NaocalError

log = logging.getLogger("naocal.v4l2")


@dataclass(frozen=True)
class CameraSpec:
    """Where a NAO V6 camera is and its timing priors (s); see the module docstring."""

    device: str
    readout_s: float
    stamp_delay_s: float


CAMERAS = {
    "bottom": CameraSpec("/dev/video-bottom", readout_s=0.045, stamp_delay_s=-0.036),
    "top": CameraSpec("/dev/video-top", readout_s=0.037, stamp_delay_s=-0.039),
}
RESOLUTIONS = ((640, 480), (1280, 960))
DEFAULT_EXPOSURE = 100  # V4L2 exposure_absolute, 100 us units: 10 ms
MAX_STAMP_AGE_S = 2.0
STALLED_FRAMES = 3
CORRUPT_FRAMES = 3
REOPEN_ATTEMPTS = 5


def device_present(device: str) -> bool:
    """Whether `device` exists (tests replace this with open_v4l2: a test machine has no NAO camera)."""
    return os.path.exists(device)


def open_v4l2(device: str):
    """The capture object for `device` (tests replace this factory: there is no V4L2 device to open there)."""
    return cv2.VideoCapture(device, cv2.CAP_V4L2)


def read_intrinsics(path) -> CameraIntrinsics:
    """Prior intrinsics from a JSON file {width_px, height_px, fx_px, fy_px, cx_px, cy_px[, distortion]} (pixels;
    distortion as OpenCV's k1, k2, p1, p2, k3), checked as every intrinsics are (CameraIntrinsics.from_fields).
    DataError naming the file and field."""
    from naocal.solver import fields
    from naocal.solver.fileio import read_json

    doc = fields.json_object(read_json(path), path, "", INTRINSICS_KEYS, ("distortion", "name"))
    return CameraIntrinsics.from_fields(doc, path)


def yuyv_problem(raw, width: int, height: int) -> str | None:
    """Why a raw YUYV buffer is not a good frame of width x height, or None."""
    if raw is None:
        return "no data"
    raw = np.asarray(raw)
    if raw.dtype != np.uint8 or raw.size != width * height * 2:
        return f"{raw.size} bytes where {width} x {height} YUYV has {width * height * 2}"
    rows = raw.reshape(height, width * 2)
    zero_rows = int(np.count_nonzero(~rows.any(axis=1)))
    if zero_rows:
        return f"{zero_rows} row(s) of zeros (green after conversion)"
    return None


def yuyv_to_bgr(raw, width: int, height: int) -> np.ndarray:
    """(height, width, 3) BGR from a raw YUYV buffer of any shape holding width * height * 2 bytes."""
    return cv2.cvtColor(np.ascontiguousarray(raw, dtype=np.uint8).reshape(height, width, 2), cv2.COLOR_YUV2BGR_YUYV)


class V4L2Camera:
    """One NAO camera (`name` in CAMERAS) through OpenCV's V4L2 backend, opened on first `capture()`.

    device : overrides the camera's udev name. width, height : one of RESOLUTIONS.
    exposure : V4L2 exposure_absolute (100 us units), auto exposure off. gain : V4L2 gain, or None to leave it.
    intrinsics : the camera's prior intrinsics (default: nominal field of view at this resolution).
    open_capture : factory device -> cv2.VideoCapture-like object (default `open_v4l2`).
    frame_timeout_s : deadline of each wait for a frame.
    """

    def __init__(self, name: str = "bottom", *, device: str | None = None, width: int = 640, height: int = 480,
                 fps: int = 30, exposure: int | None = DEFAULT_EXPOSURE, gain: int | None = None,
                 intrinsics: CameraIntrinsics | None = None, open_capture=None, frame_timeout_s: float = 2.0):
        if name not in CAMERAS:
            raise NaocalError(f"unknown camera {name!r}: expected one of {', '.join(CAMERAS)}")
        if (width, height) not in RESOLUTIONS:
            raise NaocalError(f"camera resolution {width} x {height}: expected one of "
                              f"{', '.join(f'{w}x{h}' for w, h in RESOLUTIONS)}")
        self.name = name
        self.spec = CAMERAS[name]
        self.device = device or self.spec.device
        self.width, self.height, self.fps = int(width), int(height), int(fps)
        self.exposure, self.gain = exposure, gain
        self._intrinsics = intrinsics or nominal_intrinsics(self.width, self.height)
        if (self._intrinsics.width_px, self._intrinsics.height_px) != (self.width, self.height):
            raise NaocalError(f"intrinsics for {self._intrinsics.width_px} x {self._intrinsics.height_px} do not "
                              f"match the camera's {self.width} x {self.height}")
        self._open_capture = open_capture
        self.frame_timeout_s = float(frame_timeout_s)
        self._cap = None
        self._thread = None
        self._cond = threading.Condition()
        self._stop = False
        self._error: str | None = None
        self._wanted_since_s: float | None = None  # a capture() waits for a frame dequeued after this time
        self._latest: CameraImage | None = None
        self._latest_seq = 0
        self._previous_raw: bytes | None = None
        self._last_stamp_s = -math.inf
        self.frames_grabbed = 0
        self.frames_dropped = {"corrupted": 0, "frozen": 0, "stalled": 0, "failed": 0}
        self.reopened = 0

    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    # ------------------------------------------------------------------------------------------ device
    def _open(self):
        """Open and configure the device; NaocalError naming it if that fails."""
        factory = self._open_capture or open_v4l2
        cap = factory(self.device)
        if cap is None or not cap.isOpened():
            if cap is not None:
                cap.release()
            if not os.path.exists(self.device):
                raise NaocalError(f"{self.name} camera {self.device}: no such device (is the head's camera "
                                  "connected, and do the udev rules of the team image name it so?)")
            raise NaocalError(f"{self.name} camera {self.device}: cannot open it (does another process, the team's "
                              "framework, hold it?)")
        wanted = {cv2.CAP_PROP_FOURCC: cv2.VideoWriter_fourcc(*"YUYV"), cv2.CAP_PROP_FRAME_WIDTH: self.width,
                  cv2.CAP_PROP_FRAME_HEIGHT: self.height, cv2.CAP_PROP_FPS: self.fps, cv2.CAP_PROP_CONVERT_RGB: 0}
        if self.exposure is not None:
            wanted[cv2.CAP_PROP_AUTO_EXPOSURE] = 1  # UVC "manual mode"
            wanted[cv2.CAP_PROP_EXPOSURE] = int(self.exposure)
        if self.gain is not None:
            wanted[cv2.CAP_PROP_GAIN] = int(self.gain)
        timeout_prop = getattr(cv2, "CAP_PROP_READ_TIMEOUT_MSEC", None)
        if timeout_prop is not None:
            wanted[timeout_prop] = int(self.frame_timeout_s * 1000)
        for prop, value in wanted.items():
            if not cap.set(prop, value):
                log.warning("%s camera %s: the driver did not accept property %d = %s", self.name, self.device, prop,
                            value)
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        if size != (self.width, self.height):
            cap.release()
            raise NaocalError(f"{self.name} camera {self.device}: delivers {size[0]} x {size[1]}, not the "
                              f"{self.width} x {self.height} asked for")
        return cap

    def _ensure_started(self) -> None:
        with self._cond:
            if self._error is not None:
                raise NaocalError(self._error)
            if self._thread is not None:
                return
            if self._stop:
                raise NaocalError(f"{self.name} camera is closed")
            self._cap = self._open()
            self._thread = threading.Thread(target=self._read_frames, name=f"naocal-camera-{self.name}", daemon=True)
            self._thread.start()
            log.info("%s camera %s open: YUYV %d x %d at %d fps, exposure %s", self.name, self.device, self.width,
                     self.height, self.fps, self.exposure)

    def _reopen(self, why: str) -> bool:
        """Close and open the device again; False (and a stored error) if that keeps failing."""
        log.warning("%s camera %s: %s: reopening it", self.name, self.device, why)
        try:
            self._cap.release()
        except Exception as err:  # a wedged device: opening it again is the remedy either way
            log.debug("release: %s", err)
        last = None
        for attempt in range(REOPEN_ATTEMPTS):
            if self._stop:
                return False
            time.sleep(0.2 * (attempt + 1))
            try:
                self._cap = self._open()
                self.reopened += 1
                self._previous_raw, self._last_stamp_s = None, -math.inf
                return True
            except NaocalError as err:
                last = err
        with self._cond:
            self._error = f"{self.name} camera {self.device}: {why}, and reopening failed: {last}"
            self._cond.notify_all()
        return False

    # ------------------------------------------------------------------------------------------ reader thread
    def _read_frames(self) -> None:
        stalled = corrupted = 0
        while not self._stop:
            grabbed = self._cap.grab()
            grabbed_s = time.monotonic()
            if not grabbed:
                self.frames_dropped["failed"] += 1
                if not self._reopen("no frame (grab failed)"):
                    return
                stalled = corrupted = 0
                continue
            stamp_s = float(self._cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
            self.frames_grabbed += 1
            if stamp_s <= self._last_stamp_s:
                stalled += 1
                self.frames_dropped["stalled"] += 1
                if stalled >= STALLED_FRAMES:
                    if not self._reopen(f"timestamp stalled at {stamp_s:.3f} s"):
                        return
                    stalled = corrupted = 0
                continue
            stalled = 0
            self._last_stamp_s = stamp_s
            with self._cond:
                wanted_since_s = self._wanted_since_s
            if wanted_since_s is None or grabbed_s < wanted_since_s:  # nobody waits, or dequeued before the call
                continue
            ok, raw = self._cap.retrieve()
            problem = "retrieve failed" if not ok else yuyv_problem(raw, self.width, self.height)
            if problem is not None:
                corrupted += 1
                self.frames_dropped["corrupted"] += 1
                log.info("%s camera: dropped a corrupted frame: %s", self.name, problem)
                if corrupted >= CORRUPT_FRAMES:
                    if not self._reopen(f"{corrupted} corrupted frames ({problem})"):
                        return
                    stalled = corrupted = 0
                continue
            corrupted = 0
            raw_bytes = np.ascontiguousarray(raw).tobytes()
            if raw_bytes == self._previous_raw:
                self.frames_dropped["frozen"] += 1
                if not self._reopen("frozen: two frames with identical pixels"):
                    return
                stalled = corrupted = 0
                continue
            self._previous_raw = raw_bytes
            image = self._image(raw, stamp_s)
            if image is None:
                continue
            with self._cond:
                self._latest = image
                self._latest_seq += 1
                self._wanted_since_s = None
                self._cond.notify_all()

    def _image(self, raw, stamp_s: float) -> CameraImage | None:
        now_s = time.monotonic()
        if abs(now_s - stamp_s) > MAX_STAMP_AGE_S:
            with self._cond:
                self._error = (f"{self.name} camera {self.device}: buffer timestamp {stamp_s:.3f} s is not on the "
                               f"monotonic clock (now {now_s:.3f} s); cannot pair images with joint readings")
                self._cond.notify_all()
            self._stop = True
            return None
        t_middle_s = stamp_s - self.spec.stamp_delay_s - self.spec.readout_s / 2
        return CameraImage(pixels=yuyv_to_bgr(raw, self.width, self.height), t_exposure_s=min(t_middle_s, now_s),
                           camera=self.name)

    # ------------------------------------------------------------------------------------------ API
    def capture(self) -> CameraImage:
        """The next good frame dequeued after this call (at most a frame period away when the camera runs).

        NaocalError if the device is missing or broken beyond reopening; RobotTimeout if no good frame arrives
        within frame_timeout_s.
        """
        self._ensure_started()
        called_s = time.monotonic()
        deadline = called_s + self.frame_timeout_s
        with self._cond:
            seen = self._latest_seq
            self._wanted_since_s = called_s
            while self._latest_seq == seen:
                if self._error is not None:
                    raise NaocalError(self._error)
                remaining_s = deadline - time.monotonic()
                if remaining_s <= 0:
                    raise RobotTimeout(f"{self.name} camera {self.device}: no good frame within "
                                       f"{self.frame_timeout_s:g} s (dropped so far: {self.frames_dropped})")
                self._cond.wait(remaining_s)
            return self._latest

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
            thread, cap = self._thread, self._cap
        if thread is not None:
            thread.join(self.frame_timeout_s + 1.0)
        if cap is not None:
            cap.release()
