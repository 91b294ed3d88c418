"""The V4L2 camera class against frame sources with cv2.VideoCapture's contract (tests/lola_fakes.py)."""

import json
import math
import time

import cv2
import numpy as np
import pytest

from naocal.backends.lola_driver import LolaBackend
from naocal.backends.base import nominal_intrinsics
from naocal.backends.v4l2_camera import CAMERAS, V4L2Camera, read_intrinsics, yuyv_problem, yuyv_to_bgr
from naocal.backends.errors import RobotTimeout
from naocal.solver.errors import DataError, NaocalError
from tests.lola_fakes import FakeLola, SyntheticCapture, bgr_to_yuyv


def camera_with(**capture_kwargs):
    """A bottom camera on a SyntheticCapture; returns (camera, the list of captures it opened)."""
    opened = []

    def open_capture(device):
        opened.append(SyntheticCapture(device, **capture_kwargs))
        return opened[-1]

    return V4L2Camera("bottom", open_capture=open_capture, frame_timeout_s=1.5), opened


def test_yuyv_converts_to_bgr_as_v4l2_delivers_it():
    bgr = np.zeros((480, 640, 3), dtype=np.uint8)
    bgr[:, :320] = (40, 120, 200)  # a colour on the left, grey on the right
    bgr[:, 320:] = 128
    yuyv = bgr_to_yuyv(bgr)
    assert yuyv.shape == (480, 640, 2)
    back = yuyv_to_bgr(yuyv, 640, 480)
    assert np.abs(back.astype(int) - bgr).max() <= 3
    flat = yuyv_to_bgr(yuyv.reshape(1, -1), 640, 480)  # OpenCV's raw mode may hand a single row of bytes
    assert np.array_equal(flat, back)
    assert yuyv_problem(yuyv, 640, 480) is None
    assert "bytes" in yuyv_problem(yuyv[:-1], 640, 480)
    zeros = yuyv.copy()
    zeros[10] = 0
    assert "row(s) of zeros" in yuyv_problem(zeros, 640, 480)
    green = yuyv_to_bgr(np.zeros((2, 2, 2), np.uint8), 2, 2)
    assert green[0, 0, 1] > 100 and green[0, 0, 0] == 0  # why zero rows are "green rows"


def test_the_camera_opens_on_first_capture_with_fixed_exposure_yuyv_and_its_resolution():
    camera, opened = camera_with()
    assert opened == []  # nothing opened by the constructor
    assert camera.intrinsics() == nominal_intrinsics(640, 480)
    try:
        image = camera.capture()
    finally:
        camera.close()
    assert len(opened) == 1 and opened[0].released
    settings = opened[0].settings
    assert settings[cv2.CAP_PROP_FOURCC] == cv2.VideoWriter_fourcc(*"YUYV")
    assert settings[cv2.CAP_PROP_CONVERT_RGB] == 0
    assert settings[cv2.CAP_PROP_AUTO_EXPOSURE] == 1 and settings[cv2.CAP_PROP_EXPOSURE] == 100
    assert (settings[cv2.CAP_PROP_FRAME_WIDTH], settings[cv2.CAP_PROP_FRAME_HEIGHT]) == (640, 480)
    assert image.pixels.shape == (480, 640, 3) and image.pixels.dtype == np.uint8 and image.camera == "bottom"


def test_the_exposure_time_is_the_buffer_timestamp_moved_by_the_rolling_shutter_priors():
    camera, opened = camera_with(stamp_lag_s=0.05)  # buffers stamped 50 ms before they are dequeued
    try:
        image = camera.capture()
    finally:
        camera.close()
    # Middle row: t_buffer - stamp_delay - readout / 2 = t_buffer + 0.036 - 0.0225 (B-Human's priors, bottom).
    # The synthetic buffers are stamped k / 30 s - 0.05 s: recover k.
    k = (image.t_exposure_s - 0.0135 + 0.05) * 30.0
    assert k == pytest.approx(round(k), abs=1e-6)
    assert (CAMERAS["bottom"].readout_s, CAMERAS["bottom"].stamp_delay_s) == (0.045, -0.036)
    assert (CAMERAS["top"].readout_s, CAMERAS["top"].stamp_delay_s) == (0.037, -0.039)
    camera, _ = camera_with(stamp_lag_s=0.0)  # a prior that would put the exposure after the frame arrived
    try:
        t_before = time.monotonic()
        image = camera.capture()
        assert t_before <= image.t_exposure_s <= time.monotonic()  # never later than it was received
    finally:
        camera.close()


class SlowReader(SyntheticCapture):
    """A frame source whose reader is held up after each grab (a loaded robot): the frame in hand when capture() is
    called was dequeued before the call."""

    def get(self, prop):
        if prop == cv2.CAP_PROP_POS_MSEC:
            time.sleep(0.05)
        return super().get(prop)


def test_a_frame_dequeued_before_the_call_is_never_returned():
    camera = V4L2Camera("bottom", open_capture=lambda device: SlowReader(device, stamp_lag_s=0.0), frame_timeout_s=2.0)
    try:
        camera.capture()
        for _ in range(6):
            time.sleep(0.02)
            t_before = time.monotonic()
            assert camera.capture().t_exposure_s >= t_before
    finally:
        camera.close()


def test_capture_returns_a_new_frame_each_time():
    camera, _ = camera_with()
    try:
        stamps = [camera.capture().t_exposure_s for _ in range(4)]
    finally:
        camera.close()
    # each a later frame of the 30 fps stream (a loaded machine may miss a frame between two captures: two
    # periods apart, never less than one, never off the frame grid)
    periods = np.diff(stamps) * 30
    assert np.all(periods > 0.5) and np.allclose(periods, np.round(periods), atol=0.3), periods


@pytest.mark.parametrize("fault, dropped", [("freeze_frames", "frozen"), ("stall_frames", "stalled")])
def test_a_frozen_camera_is_reopened(fault, dropped):
    camera, opened = camera_with(faults={fault: 6})
    try:
        camera.capture()  # the first frame is good; then the fault begins
        for _ in range(3):
            image = camera.capture()
    finally:
        camera.close()
    assert camera.frames_dropped[dropped] >= 1
    assert camera.reopened >= 1 and len(opened) >= 2 and opened[0].released
    assert image.pixels.shape == (480, 640, 3)


@pytest.mark.parametrize("fault", ["wrong_size_frames", "zero_row_frames"])
def test_corrupted_frames_are_dropped_and_repeated_ones_reopen_the_camera(fault):
    camera, opened = camera_with(faults={fault: 2})
    try:
        image = camera.capture()  # the corrupted frames are dropped, the next good one returned
        assert camera.frames_dropped["corrupted"] == 2 and camera.reopened == 0
        assert yuyv_problem(bgr_to_yuyv(image.pixels), 640, 480) is None
    finally:
        camera.close()
    camera, opened = camera_with(faults={fault: 4})
    try:
        camera.capture()
    finally:
        camera.close()
    assert camera.reopened == 1 and len(opened) == 2


def test_a_missing_device_is_named_and_does_not_stop_the_joints(tmp_path):
    camera, _ = camera_with(missing=True)
    with pytest.raises(NaocalError, match="bottom camera /dev/video-bottom: no such device"):
        camera.capture()
    path = str(tmp_path / "robocup")
    with FakeLola(path):
        backend = LolaBackend(path, camera=camera_with(missing=True)[0])
        try:
            assert backend.read_joints().angles_rad["HeadYaw"] == 0.0  # joints are served ...
            assert backend.intrinsics().width_px == 640
            with pytest.raises(NaocalError, match="/dev/video-bottom: no such device"):  # ... the camera says what
                backend.capture()
        finally:
            backend.close()


def test_a_camera_that_cannot_be_reopened_and_one_off_the_monotonic_clock_are_errors():
    attempts = []

    def flaky(device):
        attempts.append(SyntheticCapture(device, missing=len(attempts) > 0, faults={"freeze_frames": 10}))
        return attempts[-1]

    camera = V4L2Camera("bottom", open_capture=flaky, frame_timeout_s=10.0)
    try:
        camera.capture()
        t0 = time.monotonic()
        with pytest.raises(NaocalError, match="frozen.*reopening failed"):
            camera.capture()
        assert time.monotonic() - t0 < 6.0
    finally:
        camera.close()
    camera, _ = camera_with(stamp_lag_s=-100.0)  # stamps 100 s in the future: another clock
    with pytest.raises(NaocalError, match="not on the monotonic clock"):
        camera.capture()
    camera.close()


def test_no_frame_within_the_deadline_is_a_timeout():
    class Silent(SyntheticCapture):
        def grab(self):
            time.sleep(0.05)
            self._stamp_ms += 1.0
            return True

        def retrieve(self, *args):
            return False, None  # every frame broken, but the device keeps answering

    camera = V4L2Camera("bottom", open_capture=lambda d: Silent(d), frame_timeout_s=0.5)
    try:
        t0 = time.monotonic()
        with pytest.raises((RobotTimeout, NaocalError)):
            camera.capture()
        assert time.monotonic() - t0 < 3.0
    finally:
        camera.close()


def test_bad_settings_and_bad_intrinsics_files_are_refused(tmp_path):
    with pytest.raises(NaocalError, match="resolution 800 x 600"):
        V4L2Camera("bottom", width=800, height=600)
    with pytest.raises(NaocalError, match="unknown camera"):
        V4L2Camera("left")

    class WrongSize(SyntheticCapture):
        def get(self, prop):
            return 320.0 if prop == cv2.CAP_PROP_FRAME_WIDTH else super().get(prop)

    camera = V4L2Camera("bottom", open_capture=lambda d: WrongSize(d))
    with pytest.raises(NaocalError, match="delivers 320 x 480"):
        camera.capture()
    camera.close()
    good = {"width_px": 640, "height_px": 480, "fx_px": 600.0, "fy_px": 601.0, "cx_px": 320.5, "cy_px": 240.0}
    path = tmp_path / "intrinsics.json"
    path.write_text(json.dumps(good))
    assert read_intrinsics(path).fy_px == 601.0
    for bad, field in [({**good, "fx_px": -1}, "fx_px"), ({**good, "width_px": 640.5}, "width_px"),
                       ({**good, "distortion": [0, 0]}, "distortion"), ({**good, "fx": 600}, "fx"),
                       ({**good, "cy_px": math.inf}, "cy_px")]:
        path.write_text(json.dumps(bad).replace("Infinity", "1e999"))
        with pytest.raises(DataError, match=f"intrinsics.json, field '{field}'"):
            read_intrinsics(path)
    path.write_text("{not json")
    with pytest.raises(DataError, match="invalid JSON"):
        read_intrinsics(path)
