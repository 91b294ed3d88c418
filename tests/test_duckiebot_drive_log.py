"""The drive log reader (kinds/duckiebot/drive_log.py, issue 23): the exact format, and every bad log refused in one
line naming the file and the line or field, nothing written."""

import json
import os

import cv2
import numpy as np
import pytest

from naocal.kinds.duckiebot.drive_log import (SCHEMA, DriveLogAppender, read_drive_log, write_drive_log,
                                              write_frame)
from naocal.solver.errors import DataError

W, H = 64, 48  # small frames keep the tests fast; the reader takes the size from log.json


def meta(**changes):
    doc = {"schema": SCHEMA, "robot": {"id": "autobot01", "model": "DB21"},
           "camera": {"width_px": W, "height_px": H},
           "wheels": {"radius_m": 0.0318, "baseline_m": 0.1, "k": 27.0, "limit": 1.0, "ticks_per_revolution": 135},
           "markers": {"family": "tag36h11", "size_m": 0.065}, "boards": {"inner_corners": [7, 5], "square_m": 0.031},
           "source": "test"}
    doc.update(changes)
    return doc


@pytest.fixture
def log(tmp_path):
    directory = tmp_path / "LOG"
    directory.mkdir()
    rng = np.random.default_rng(1)
    for i in range(3):
        write_frame(directory, f"frames/{i:04d}.png" if i < 2 else "frames/0002.jpg",
                    rng.integers(0, 255, (H, W, 3), dtype=np.uint8))
    write_drive_log(directory, meta(), ([0.0, 0.5, 1.0], [0.0, 0.3, -0.2], [0.0, 0.31, 0.2]),
                    ([0.1, 0.6, 0.9], ["frames/0000.png", "frames/0001.png", "frames/0002.jpg"]),
                    ([0.0, 0.5, 1.0], [0, 40, -3], [0, 41, 30]))
    return directory


def snapshot(directory):
    return {p: p.stat().st_mtime_ns for p in directory.rglob("*")}


def test_a_good_log_reads_exactly(log):
    drive = read_drive_log(log)
    assert drive.robot_id == "autobot01" and drive.model == "DB21" and (drive.width_px, drive.height_px) == (W, H)
    assert drive.wheels.ticks_per_revolution == 135 and drive.board_inner_corners == (7, 5)
    np.testing.assert_array_equal(drive.wheel_t_s, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(drive.left_duty, [0.0, 0.3, -0.2])
    np.testing.assert_array_equal(drive.right_ticks, [0, 41, 30])
    assert drive.frame_files == ("frames/0000.png", "frames/0001.png", "frames/0002.jpg")
    assert drive.load_frame(0).shape == (H, W, 3)
    assert drive.meta() == meta()
    # each command holds until the next one; nothing is commanded before the first
    left, right = drive.duties_at([-1.0, 0.0, 0.49, 0.5, 0.7, 5.0])
    np.testing.assert_array_equal(left, [0.0, 0.0, 0.0, 0.3, 0.3, -0.2])
    np.testing.assert_array_equal(right, [0.0, 0.0, 0.0, 0.31, 0.31, 0.2])


def test_encoders_are_optional(log):
    (log / "encoders.csv").unlink()
    doc = meta()
    del doc["wheels"]["ticks_per_revolution"]
    (log / "log.json").write_text(json.dumps(doc))
    drive = read_drive_log(log)
    assert drive.encoder_t_s is None and drive.wheels.ticks_per_revolution is None
    doc["wheels"]["ticks_per_revolution"] = None  # an exporter's way of leaving it out
    (log / "log.json").write_text(json.dumps(doc))
    assert read_drive_log(log).wheels.ticks_per_revolution is None


def test_a_log_in_segments_reads_its_breaks_and_one_without_has_none(log):
    assert read_drive_log(log).segment_t_s.shape == (0,)  # no segments.csv: one drive, as before
    (log / "segments.csv").write_text("t_s\n0.55\n0.55\n0.8\n")  # a break written twice is one break
    np.testing.assert_array_equal(read_drive_log(log).segment_t_s, [0.55, 0.8])


def test_the_appender_records_a_break_after_every_row_and_keeps_it(tmp_path):
    appender = DriveLogAppender(tmp_path / "LOG", meta())
    appender.add_wheels(1.0, 0.3, 0.3)
    appender.add_frame(1.5, "frames/000000.png", np.zeros((H, W), np.uint8))
    with pytest.raises(ValueError, match="does not follow the log's last row"):
        appender.add_break(1.5)  # a break belongs between rows: the frame at 1.5 s was before it
    appender.add_break(2.0)
    appender.add_wheels(2.0, 0.0, 0.0)
    again = DriveLogAppender(tmp_path / "LOG", meta())
    assert again.breaks == [2.0] and len(again.wheels) == 2
    np.testing.assert_array_equal(read_drive_log(tmp_path / "LOG").segment_t_s, [2.0])


def refused(log, match):
    before = snapshot(log.parent)
    with pytest.raises(DataError, match=match) as err:
        read_drive_log(log)
    assert "\n" not in str(err.value)
    assert snapshot(log.parent) == before  # nothing written
    return str(err.value)


@pytest.mark.parametrize("name", ["log.json", "wheels.csv", "frames.csv"])
def test_missing_files(log, name):
    (log / name).unlink()
    message = refused(log, "file not found")
    assert message.startswith(str(log / name))


def test_encoders_without_ticks_per_revolution(log):
    # optional in the format: a DB21's encoders count 135 a revolution (a log exported without it was refused)
    doc = meta()
    del doc["wheels"]["ticks_per_revolution"]
    (log / "log.json").write_text(json.dumps(doc))
    drive = read_drive_log(log)
    assert drive.wheels.ticks_per_revolution == 135 and drive.meta()["wheels"]["ticks_per_revolution"] == 135
    # a model whose encoders naocal does not know: the ticks cannot be read as angles
    for model in ("DB18", "DB99-lab"):
        doc["robot"]["model"] = model
        (log / "log.json").write_text(json.dumps(doc))
        refused(log, r"log.json, field 'wheels.ticks_per_revolution': encoders.csv is present.*nor known for the "
                     "model")


def test_encoder_counters_wrapping_around_int32_are_unwrapped(log):
    """Duckietown's counters are int32 since boot: 2147483600 -> -2147483626 is 70 ticks forward (and back for the
    other wheel), read on from the first count; counts written as floats ('12.0') are whole numbers."""
    (log / "encoders.csv").write_text("t_s,left_ticks,right_ticks\n0,2147483600,-2147483600\n"
                                      "0.5,-2147483626,2147483626.0\n1.0,-2147483600,2147483600\n")
    drive = read_drive_log(log)
    np.testing.assert_array_equal(drive.left_ticks, [2147483600, 2147483670, 2147483696])
    np.testing.assert_array_equal(drive.right_ticks, [-2147483600, -2147483670, -2147483696])
    assert drive.left_ticks.dtype == np.int64


def test_an_encoder_step_beyond_what_the_wheel_can_turn_is_refused(log):
    """At the limit duty 1, k 27 and gain 0.3 (the lowest real robots have) a wheel turns 90 rad/s: 0.5 s is
    at most 967 ticks of 135 a revolution (+2 for rounding); 1000 is refused naming its line, 960 is read."""
    (log / "encoders.csv").write_text("t_s,left_ticks,right_ticks\n0,0,0\n0.5,960,-960\n1.0,960,-900\n")
    np.testing.assert_array_equal(read_drive_log(log).right_ticks, [0, -960, -900])
    (log / "encoders.csv").write_text("t_s,left_ticks,right_ticks\n0,0,0\n0.5,40,41\n1.0,40,1041\n")
    message = refused(log, r"encoders.csv, line 4, field 'right_ticks': \+1000 ticks since the previous row")
    assert "969 ticks at most" in message


def test_a_row_per_encoder_message_export_reads_and_a_spike_is_still_refused(log):
    """A ROS bag export writing one row per encoder message (Duckietown's two nodes at 30 Hz, 2 ms apart), the other
    wheel's count held: at 1 m/s (31 rad/s, 22 ticks a period) a wheel's ticks of a whole period land 2 ms after the
    row before. The wheel turned them since its count last changed (33 ms), not in 2 ms: read. A spike of 200 ticks
    in a period stays impossible (66 at most)."""
    def export(spike_at=None):
        rows, left, right = ["t_s,left_ticks,right_ticks"], 0, 0
        for i in range(30):
            t = i / 30.0
            left += 22
            rows.append(f"{t:.4f},{left},{right}")
            right += 200 if i == spike_at else 22
            rows.append(f"{t + 0.002:.4f},{left},{right}")
        (log / "encoders.csv").write_text("\n".join(rows) + "\n")

    export()
    drive = read_drive_log(log)
    assert drive.left_ticks[-1] == drive.right_ticks[-1] == 660
    export(spike_at=12)
    refused(log, r"encoders.csv, line 27, field 'right_ticks': \+200 ticks since the previous row \(0.002 s before; "
                 r"the count last changed 0.0333 s before\): more than the wheel can turn \(66 ticks at most")


def test_windows_and_ros_bag_exports_read_as_written(log):
    # CRLF line endings, a UTF-8 byte order mark, a trailing blank line; Unix-epoch times (a ROS bag's), each file
    # starting at its own time
    t0 = 1780000000.0
    lines = {"wheels.csv": ["t_s,left_duty,right_duty", f"{t0 + 0.25:.6f},0,0", f"{t0 + 0.5:.6f},0.3,0.31",
                            f"{t0 + 0.500001:.6f},-0.2,0.2"],
             "frames.csv": ["t_s,file", f"{t0:.6f},frames/0000.png", f"{t0 + 0.5:.6f},frames/0001.png",
                            f"{t0 + 0.9:.6f},frames/0002.jpg"],
             "encoders.csv": ["t_s,left_ticks,right_ticks", f"{t0 + 0.3:.6f},2147483600,-2147483600",
                              f"{t0 + 0.6:.6f},2147483647,-2147483648"]}
    for name, rows in lines.items():
        (log / name).write_bytes(b"\xef\xbb\xbf" + ("\r\n".join(rows) + "\r\n\r\n").encode())
    (log / "log.json").write_bytes(b"\xef\xbb\xbf" + json.dumps(meta()).replace("\n", "\r\n").encode())
    drive = read_drive_log(log)
    assert drive.wheel_t_s.dtype == np.float64 and drive.wheel_t_s[0] == t0 + 0.25
    # microseconds kept at 1.78e9 s (a double's step there: 2.4e-7 s; a float32's: 128 s)
    np.testing.assert_allclose(np.diff(drive.wheel_t_s), [0.25, 0.000001], rtol=0, atol=2.5e-7)
    np.testing.assert_array_equal(drive.frame_t_s, [t0, t0 + 0.5, t0 + 0.9])
    np.testing.assert_array_equal(drive.left_ticks, [2147483600, 2147483647])
    left, _ = drive.duties_at([t0, t0 + 0.5, t0 + 0.5000005, t0 + 0.9])  # a command at a frame's time holds there
    np.testing.assert_array_equal(left, [0.0, 0.3, 0.3, -0.2])


def test_a_row_written_twice_is_read_once(log):
    # a recorder or export writing one message twice (the same time and values): read once; the same time with
    # other values is refused (test_bad_csv_files)
    (log / "wheels.csv").write_text("t_s,left_duty,right_duty\n0,0,0\n0.5,0.3,0.31\n0.5,0.3,0.31\n1,-0.2,0.2\n"
                                    "1,-0.2,0.2\n")
    (log / "frames.csv").write_text("t_s,file\n0.1,frames/0000.png\n0.1,frames/0000.png\n0.6,frames/0001.png\n"
                                    "0.9,frames/0002.jpg\n")
    (log / "encoders.csv").write_text("t_s,left_ticks,right_ticks\n0,0,0\n0,0,0\n0.5,40,41\n")
    drive = read_drive_log(log)
    np.testing.assert_array_equal(drive.wheel_t_s, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(drive.right_duty, [0.0, 0.31, 0.2])
    assert drive.frame_files == ("frames/0000.png", "frames/0001.png", "frames/0002.jpg")
    np.testing.assert_array_equal(drive.encoder_t_s, [0.0, 0.5])
    np.testing.assert_array_equal(drive.left_ticks, [0, 40])


def test_log_json_keys_the_format_does_not_define_are_ignored_with_a_warning(log, caplog):
    # an exporter's own notes (a bag's name, the camera's rate) made the log unreadable: "unknown field"
    doc = meta(recorded_by="rosbag2csv 0.3")
    doc["camera"]["fps"] = 15
    (log / "log.json").write_text(json.dumps(doc))
    with caplog.at_level("WARNING"):
        drive = read_drive_log(log)
    assert drive.meta() == meta()
    assert "log.json: ignored the fields the drive log format does not define: 'recorded_by', 'camera.fps'" in \
        caplog.text


@pytest.mark.parametrize("name, text, match", [
    ("wheels.csv", "t_s,left_duty,right_duty\n0,0,0\n1,0.2,0.2\n0.5,0,0\n", r"wheels.csv, line 4, field 't_s': "
                                                                             r"time 0.5 s is before the previous row's "
                                                                             r"1.0 s \(times must increase\)"),
    ("wheels.csv", "t_s,left_duty,right_duty\n0,0,0\n0,0.2,0.2\n", r"wheels.csv, line 3, field 't_s': time 0.0 s "
                                                                    "is also the previous row's, with other values"),
    ("frames.csv", "t_s,file\n0.1,frames/0000.png\n0.1,frames/0001.png\n", r"frames.csv, line 3, field 't_s'"),
    ("encoders.csv", "t_s,left_ticks,right_ticks\n1,0,0\n1,0,1\n", r"encoders.csv, line 3, field 't_s'"),
    ("wheels.csv", "\ufefft_s,left_duty,right_duty,stamp\r\n0,0,0,0\r\n", r"wheels.csv, line 1: expected the header"),
    ("frames.csv", "t_s,file\n0.6,frames/0001.png\n0.1,frames/0000.png\n", r"frames.csv, line 3, field 't_s'"),
    ("encoders.csv", "t_s,left_ticks,right_ticks\n1,0,0\n0,1,1\n", r"encoders.csv, line 3, field 't_s'"),
    ("wheels.csv", "t_s,left_duty,right_duty\n0,nan,0\n", r"wheels.csv, line 2, field 'left_duty'.*finite"),
    ("wheels.csv", "t_s,left_duty,right_duty\n0,0,1.01\n", r"wheels.csv, line 2, field 'right_duty'.*must be within"),
    ("wheels.csv", "t_s,left_duty,right_duty\n0,-inf,0\n", r"line 2, field 'left_duty'"),
    ("wheels.csv", "t_s,left_duty,right_duty\n0,0\n", r"wheels.csv, line 2: expected 3 cells"),
    ("wheels.csv", "t_s,right_duty,left_duty\n0,0,0\n", r"wheels.csv, line 1: expected the header"),
    ("wheels.csv", "t_s,left_duty,right_duty\n", r"wheels.csv.*no data rows"),
    ("wheels.csv", "", r"wheels.csv, line 1: empty file"),
    ("encoders.csv", "t_s,left_ticks,right_ticks\n0,1.5,0\n", r"encoders.csv, line 2, field 'left_ticks'"),
    ("frames.csv", "t_s,file\n0.1,../outside.png\n", r"frames.csv, line 2, field 'file'.*leaves the log"),
    ("frames.csv", "t_s,file\n0.1,/etc/passwd.png\n", r"line 2, field 'file'.*leaves the log"),
    ("frames.csv", "t_s,file\n0.1,frames/0000.bmp\n", r"line 2, field 'file'.*not a PNG or JPEG"),
    ("frames.csv", "t_s,file\n0.1,frames/0000.png\n0.2,frames/./0000.png\n", r"line 3, field 'file'.*already"),
    ("frames.csv", "t_s,file\n0.1,frames/absent.png\n", r"absent.png: file not found"),
    ("segments.csv", "t_s\n0.7\n0.4\n", r"segments.csv, line 3, field 't_s'.*before the previous"),
    ("segments.csv", "t_s\nnan\n", r"segments.csv, line 2, field 't_s'.*finite"),
    ("segments.csv", "t_s,reason\n0.7,crash\n", r"segments.csv, line 1: expected the header t_s"),
    ("segments.csv", "t_s\n", r"segments.csv.*no data rows"),
    # what Python's int() / float() read but no exporter writes as a number (the first one escaped as a ValueError)
    ("encoders.csv", "t_s,left_ticks,right_ticks\n0,+-5,0\n", r"encoders.csv, line 2, field 'left_ticks'"),
    ("encoders.csv", "t_s,left_ticks,right_ticks\n0,0,\u0663\n", r"encoders.csv, line 2, field 'right_ticks'"),
    ("wheels.csv", "t_s,left_duty,right_duty\n0,0,0\n1_0,0,0\n", r"wheels.csv, line 3, field 't_s'.*'1_0'"),
])
def test_bad_csv_files(log, name, text, match):
    (log / name).write_text(text)
    refused(log, match)


def test_frames_that_are_not_images(log):
    (log / "frames" / "0001.png").write_text("not an image at all")
    refused(log, r"0001.png: not a PNG image")
    png = cv2.imencode(".png", np.zeros((H, W), np.uint8))[1].tobytes()
    (log / "frames" / "0001.png").write_bytes(png[:40])  # truncated
    refused(log, r"0001.png: not a readable image")
    (log / "frames" / "0001.png").write_bytes(cv2.imencode(".png", np.zeros((H + 1, W), np.uint8))[1].tobytes())
    refused(log, r"0001.png: image is 64 x 49 px, log.json's camera is 64 x 48")
    (log / "frames" / "0001.png").unlink()
    os.mkfifo(log / "frames" / "0001.png")  # would block a naive reader
    refused(log, r"0001.png: is a FIFO")


def test_a_damaged_frame_is_one_line_with_the_decoders_words_and_nothing_on_native_stderr(log, capfd):
    jpeg = (log / "frames" / "0002.jpg").read_bytes()
    # its second half lost, the end marker kept: libjpeg decodes it, grey below, with a 'Corrupt JPEG data' warning
    (log / "frames" / "0002.jpg").write_bytes(jpeg[:len(jpeg) // 2] + jpeg[-2:])
    refused(log, r"0002.jpg: a damaged image \(the decoder said: Corrupt JPEG data")
    png = bytearray((log / "frames" / "0001.png").read_bytes())
    png[len(png) // 2:len(png) // 2 + 16] = bytes(16)
    (log / "frames" / "0001.png").write_bytes(bytes(png))
    refused(log, r"0001.png: not a readable image \(the decoder refused it: damaged or truncated: libpng error")
    assert capfd.readouterr().err == ""  # libpng's and libjpeg's own lines are in the one line, not beside it


def test_a_symbolic_link_out_of_the_log_is_refused(log, tmp_path):
    outside = tmp_path / "outside.png"
    outside.write_bytes((log / "frames" / "0000.png").read_bytes())
    (log / "frames" / "0000.png").unlink()
    (log / "frames" / "0000.png").symlink_to(outside)
    refused(log, r"frames.csv, line 2, field 'file'.*outside the log directory")
    (log / "frames" / "0000.png").unlink()
    (log / "frames" / "0000.png").write_bytes(outside.read_bytes())
    (tmp_path / "wheels.csv").write_bytes((log / "wheels.csv").read_bytes())  # a CSV is read from LOG only, too
    (log / "wheels.csv").unlink()
    (log / "wheels.csv").symlink_to(tmp_path / "wheels.csv")
    refused(log, r"wheels.csv: a symbolic link leading outside the log directory")


@pytest.mark.parametrize("change, match", [
    (dict(schema="naocal.drive_log/2"), r"field 'schema'"),
    (dict(wheels={"radius_m": 0.03, "baseline_m": 0.1, "k": 27}), r"field 'wheels.limit': missing required"),
    (dict(boards={"inner_corners": [7, 5], "square": 0.031}), r"field 'boards.square_m': missing required"),
    (dict(robot={"id": "../evil", "model": "DB21"}), r"field 'robot.id': robot name"),
    (dict(robot={"id": "autobot01"}), r"field 'robot.model': missing"),
    (dict(camera={"width_px": 64.5, "height_px": 48}), r"field 'camera.width_px'"),
    (dict(wheels={"radius_m": float("nan"), "baseline_m": 0.1, "k": 27, "limit": 1}), r"field 'wheels.radius_m'"),
    (dict(wheels={"radius_m": 0.03, "baseline_m": 0.1, "k": 27, "limit": 1.5}),
     r"field 'wheels.limit'.*must be within"),
    (dict(markers={"family": "tag25h9", "size_m": 0.065}), r"field 'markers.family'"),
    (dict(boards={"inner_corners": [7], "square_m": 0.031}), r"field 'boards.inner_corners'"),
    (dict(boards={"inner_corners": [7, 1], "square_m": 0.031}), r"field 'boards.inner_corners\[1\]'"),
    (dict(source=""), r"field 'source'"),
])
def test_bad_log_json(log, change, match):
    (log / "log.json").write_text(json.dumps(meta(**change)))
    refused(log, r"log.json, " + match)


def test_not_a_directory(tmp_path):
    with pytest.raises(DataError, match="not a directory"):
        read_drive_log(tmp_path / "nothing")


def test_the_writer_checks_everything_before_writing(tmp_path):
    directory = tmp_path / "LOG"
    write_frame(directory, "f.png", np.zeros((H, W, 3), np.uint8))
    good = (([0.0, 1.0], [0.0, 0.5], [0.0, 0.5]), ([0.5], ["f.png"]))
    for wheels, frames, match in [(([0.0, 1.0], [0.0, float("nan")], [0.0, 0.5]), good[1], "wheels.csv, line 3"),
                                  (good[0], ([0.5], ["../f.png"]), "frames.csv, line 2"),
                                  (good[0], ([0.5], ["g.png"]), "g.png: file not found")]:
        with pytest.raises(DataError, match=match):
            write_drive_log(directory, meta(), wheels, frames)
        assert sorted(p.name for p in directory.iterdir()) == ["f.png"]
    with pytest.raises(DataError, match="encoders.csv, line 3"):
        write_drive_log(directory, meta(), *good, ([0.0, 0.0], [0, 1], [0, 1]))
    assert write_drive_log(directory, meta(), *good).frame_files == ("f.png",)


def with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """`jpeg` with an APP1 Exif segment whose one tag is the orientation (6: shown turned 90 deg clockwise), as
    phones and some exporters write it."""
    import struct

    tiff = b"II*\x00" + struct.pack("<IH", 8, 1) + struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0) + b"\0" * 4
    app1 = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:]


def test_a_jpeg_frame_is_read_as_the_sensor_gave_it_whatever_its_exif_orientation(log):
    # OpenCV turns a JPEG by its EXIF orientation unless told not to: a 64 x 48 frame read as 48 x 64 (refused, or a
    # turned camera); the size check, which decodes it unchanged, passed it
    pixels = np.zeros((H, W), np.uint8)
    pixels[:8, :16] = 255
    ok, jpeg = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, 100])
    (log / "frames" / "0002.jpg").write_bytes(with_exif_orientation(jpeg.tobytes(), 6))
    drive = read_drive_log(log)
    grey = drive.load_frame(2, cv2.IMREAD_GRAYSCALE)
    assert grey.shape == (H, W) and grey[:8, :16].mean() > 200 and grey[8:, 16:].mean() < 50
    assert drive.load_frame(2).shape == (H, W, 3)
    from naocal.kinds.duckiebot.robot import decoded_frame

    image, why = decoded_frame((log / "frames" / "0002.jpg").read_bytes(), W, H)
    assert why is None and image.shape == (H, W)
