"""`naocal detect`: plain and JSON output, corner order, overlays, image formats, exit codes and bad input."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from naocal.agent.board_detect import image_order
from conftest import ROOT
from tests.synthetic_boards import board_homography, render
from naocal.tools.cli import main

DATA = Path(__file__).parent / "data" / "realdata" / "mrlspl-nao-2009"
REAL = [str(DATA / f"image_{i}.png") for i in range(6)]


def test_json_for_the_six_real_images(capsys):
    assert main(["detect", *REAL, "--board", "4x4", "--json"]) == 0
    out = capsys.readouterr()
    report = json.loads(out.out)
    assert out.err == ""
    assert report["schema"] == "naocal.detect/1"
    assert report["board"] == {"columns": 4, "rows": 4, "inner_corners": [3, 3]}
    assert [r["path"] for r in report["images"]] == REAL
    for r in report["images"]:
        assert r["found"] is True and r["reason"] is None and r["channel"] in ("cr", "cb")
        assert (r["width_px"], r["height_px"]) == (320, 240)
        assert r["line_rms_px"] < 0.15 and r["edge_width_px"] > 0
        corners = np.array(r["corners_px"])
        assert corners.shape == (3, 3, 2)
        # Image order: rows follow each other downwards, each row runs left to right.
        assert np.all(np.diff(corners[..., 1].mean(axis=1)) > 0)
        assert np.all(np.diff(corners[..., 0], axis=1) > 0)
        assert "orientation cannot be told" in r["detail"]


def test_plain_lines_and_exit_code_one_naming_the_images_without_a_board(tmp_path, capsys):
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((240, 320, 3), 90, np.uint8))
    assert main(["detect", REAL[0], str(blank), "--board", "4x4"]) == 1
    out = capsys.readouterr()
    lines = out.out.splitlines()
    assert len(lines) == 2
    assert lines[0].startswith(f"{REAL[0]}: found 9 corners (3 rows of 3) in c") and "line fit" in lines[0]
    assert lines[1].startswith(f"{blank}: not found (missing): no 4x4-square board (3x3 inner corners)")
    assert out.err.strip() == (f"naocal detect: no 4x4-square board (3x3 inner corners) found in 1 of 2 images: "
                               f"{blank}")


def test_default_board_is_the_sandal_and_other_sizes(tmp_path, capsys):
    sandal = render(7, 5, board_homography(7, 5, tilt_x=0.4, turn=0.2), margin_squares=0.5, blur_px=0.6)
    path = tmp_path / "sandal.png"
    cv2.imwrite(str(path), sandal.image)
    assert main(["detect", str(path), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)["images"][0]
    assert r["found"] and np.array(r["corners_px"]).shape == (4, 6, 2)
    truth = sandal.corners_px  # board order; the image order is one of the grid's four labellings
    corners = np.array(r["corners_px"])
    assert min(np.abs(g - corners).max() for g in (truth, truth[::-1], truth[:, ::-1], truth[::-1, ::-1])) < 0.1
    # The same image is no 4 x 4 board, nor a 6 x 4 (the corners form a bigger grid): exit 1.
    for wrong in ("4x4", "6x4"):
        assert main(["detect", str(path), "--board", wrong]) == 1
        assert "not found (missing)" in capsys.readouterr().out


def test_overlays_for_one_image_and_for_several(tmp_path, capsys):
    one = tmp_path / "one.png"
    assert main(["detect", REAL[3], "--board", "4x4", "--overlay", str(one)]) == 0
    drawn = cv2.imread(str(one))
    assert drawn.shape == (480, 640, 3)  # 320 x 240 drawn at twice the size
    original = cv2.resize(cv2.imread(REAL[3]), (640, 480), interpolation=cv2.INTER_NEAREST)
    assert np.mean(np.any(drawn != original, axis=2)) > 0.005  # something was drawn
    folder = tmp_path / "overlays"
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((240, 320), 90, np.uint8))
    assert main(["detect", REAL[0], REAL[1], str(blank), "--board", "4x4", "--overlay", str(folder)]) == 1
    assert sorted(p.name for p in folder.iterdir()) == ["blank.corners.png", "image_0.corners.png",
                                                        "image_1.corners.png"]
    capsys.readouterr()


def test_grey_16_bit_and_raw_yuyv_images(tmp_path, capsys):
    image = cv2.imread(REAL[5])
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    sixteen = tmp_path / "sixteen.png"
    cv2.imwrite(str(sixteen), image.astype(np.uint16) * 257)
    yuv = cv2.cvtColor(image, cv2.COLOR_BGR2YUV).astype(float)
    yuyv = np.empty((240, 320, 2))
    yuyv[..., 0] = yuv[..., 0]
    yuyv[:, 0::2, 1] = 0.5 * (yuv[:, 0::2, 1] + yuv[:, 1::2, 1])  # U, shared by each pair of pixels
    yuyv[:, 1::2, 1] = 0.5 * (yuv[:, 0::2, 2] + yuv[:, 1::2, 2])  # V
    raw = tmp_path / "frame.yuv"
    raw.write_bytes(np.clip(np.round(yuyv), 0, 255).astype(np.uint8).tobytes())
    assert main(["detect", str(sixteen), str(raw), "--board", "4x4", "--json"]) == 0
    images = json.loads(capsys.readouterr().out)["images"]
    assert all(r["found"] for r in images)
    # Grey hardly separates orange from blue: this image's board is found in grey, not promised for others.
    main(["detect", str(grey), "--board", "4x4", "--json"])
    assert json.loads(capsys.readouterr().out)["images"][0]["channel"] in ("grey", None)


@pytest.mark.parametrize("arguments, message", [
    (["--board", "4by4"], "--board"),
    (["--board", "2x5"], "--board"),
    (["--overlay", "out.txt"], "--overlay"),
])
def test_bad_options_are_one_line_and_exit_two(arguments, message, tmp_path, capsys):
    assert main(["detect", REAL[0], *[a if a != "out.txt" else str(tmp_path / a) for a in arguments]]) == 2
    out = capsys.readouterr()
    assert out.out == "" and len(out.err.strip().splitlines()) == 1 and message in out.err


def test_unreadable_or_missing_images_detect_nothing(tmp_path, capsys):
    text = tmp_path / "notes.png"
    text.write_text("not an image")
    odd = tmp_path / "frame.yuv"
    odd.write_bytes(b"\0" * 1000)
    for bad in (text, odd, tmp_path / "missing.png"):
        assert main(["detect", REAL[0], str(bad), "--board", "4x4", "--json"]) == 2
        out = capsys.readouterr()
        assert out.out == ""  # nothing detected, nothing printed
        assert out.err.startswith(f"naocal detect: error: {bad}: ") and len(out.err.strip().splitlines()) == 1


def test_a_chroma_channel_of_a_grey_image_is_bad_input(tmp_path, capsys):
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), cv2.cvtColor(cv2.imread(REAL[0]), cv2.COLOR_BGR2GRAY))
    assert main(["detect", REAL[0], str(grey), "--board", "4x4", "--channel", "cr"]) == 2
    out = capsys.readouterr()
    assert out.out == "" and out.err.strip() == (f"naocal detect: error: {grey}: a grey image has no cr channel "
                                                 "(use --channel auto or grey)")


def test_no_traceback_from_the_installed_command(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG garbage")
    run = subprocess.run([sys.executable, "-m", "naocal", "detect", str(bad)], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 2 and "Traceback" not in run.stderr and run.stdout == ""


def test_two_boards_in_view_report_the_largest(tmp_path, capsys):
    """Both sandals in one image: the board is found (exit 0), the largest one's corners are given, and the line
    says there are two."""
    small = render(7, 5, board_homography(7, 5, square_px=18.0, shift_px=(-160.0, 0.0)), margin_squares=0.5)
    large = render(7, 5, board_homography(7, 5, square_px=24.0, shift_px=(150.0, 0.0)), margin_squares=0.5)
    path = tmp_path / "two.png"
    cv2.imwrite(str(path), np.where(np.arange(640)[None, :, None] < 300, small.image, large.image).astype(np.uint8))
    assert main(["detect", str(path)]) == 0
    line = capsys.readouterr().out
    assert "found 24 corners" in line and "2 boards of 7 x 5 squares in view: the largest reported" in line
    assert main(["detect", str(path), "--json"]) == 0
    corners = np.array(json.loads(capsys.readouterr().out)["images"][0]["corners_px"])
    assert corners[..., 0].min() > 300  # the right-hand, larger board


def test_ppm_pgm_and_raw_yuyv_of_a_size_given_by_size(tmp_path, capsys):
    """PPM and PGM (netpbm) read; a raw YUYV frame of a size not among the NAO's is read with --size WxH."""
    scene = render(7, 5, board_homography(7, 5, size=(400, 300), square_px=30.0, tilt_x=0.3), size=(400, 300),
                   margin_squares=0.5)
    ppm, pgm, raw = tmp_path / "board.ppm", tmp_path / "board.pgm", tmp_path / "frame.raw"
    cv2.imwrite(str(ppm), scene.image)
    cv2.imwrite(str(pgm), cv2.cvtColor(scene.image, cv2.COLOR_BGR2GRAY))
    from tests.stress_boards import to_yuyv
    raw.write_bytes(to_yuyv(scene.image).tobytes())
    assert main(["detect", str(ppm), str(pgm), str(raw), "--size", "400x300", "--json"]) == 0
    images = json.loads(capsys.readouterr().out)["images"]
    for r in images:
        assert r["found"] and (r["width_px"], r["height_px"]) == (400, 300)
        corners = np.array(r["corners_px"])
        assert np.abs(image_order(scene.corners_px, (4, 6)) - corners).max() < 0.3
    # Without --size the length fits none of the NAO's sizes; with a wrong one it does not fit either.
    for extra, message in (([], "or give --size WxH"), (["--size", "320x240"], "--size 320x240 needs 153600")):
        assert main(["detect", str(raw), *extra]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"naocal detect: error: {raw}: ") and message in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("size", ["640", "641x480", "0x10", "axb"])
def test_a_bad_size_is_one_line_and_exit_two(size, capsys):
    assert main(["detect", REAL[0], "--size", size]) == 2
    out = capsys.readouterr()
    assert out.out == "" and out.err.startswith("naocal detect: error: --size") and len(out.err.splitlines()) == 1


def test_a_directory_or_fifo_as_an_image_is_one_line_naming_it(tmp_path, capsys):
    import os

    fifo = tmp_path / "pipe.png"
    os.mkfifo(fifo)  # read, it would block for ever
    for bad in (tmp_path, fifo):
        assert main(["detect", str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"naocal detect: error: {bad}: ") and len(err.splitlines()) == 1


def test_the_inner_corner_count_passed_as_board_is_named(tmp_path, capsys):
    """OpenCV counts inner corners: --board 6x4 for the 7 x 5 sandal finds no board of 6 x 4 squares; the line
    says what was tried and that a 7x5-square board is there."""
    scene = render(7, 5, board_homography(7, 5, square_px=40.0, tilt_x=0.3, turn=0.2), margin_squares=0.5)
    path = tmp_path / "sandal.png"
    cv2.imwrite(str(path), scene.image)
    assert main(["detect", str(path), "--board", "6x4"]) == 1
    out = capsys.readouterr()
    assert "no 6x4-square board (5x3 inner corners)" in out.out
    assert "a 7x5-square board (6x4 inner corners) is there: --board counts squares, not inner corners" in out.out
    assert main(["detect", str(path), "--board", "7x5"]) == 0
    capsys.readouterr()
