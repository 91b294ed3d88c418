"""`naocal detect IMAGE...`: find a checkerboard's inner corners in images, to check a board and a camera.

    naocal detect IMAGE... [--board WxH] [--size WxH] [--channel auto|grey|cr|cb] [--json] [--overlay OUT]

--board WxH counts squares, not inner corners (default 7x5, the NAO sandal): a board of W x H squares has
(W-1) x (H-1) inner corners (7x5: 6 x 4; 9x6: 8 x 5; 4x4: 3 x 3). OpenCV's patternSize counts inner corners:
--board is that plus one each way. When no board of the size is found but one of a square more each way is
there (the inner-corner count passed), the line says so.

The board may be of any two colours, either polarity, in grey or in colour: --channel auto tries grey (black and
white) and the chroma channels Cr and Cb of YCrCb (colours of similar brightness, e.g. an orange/blue board on
green carpet) and keeps the detection whose squares differ most for their noise.

Images: PNG, JPEG, BMP, PPM, PGM, PBM, PAM, colour or grey, 8 or 16 bit, up to 16.8 Mpx (4096 x 4096; the size
in the file's header is checked before anything is decoded: docs/CONVENTIONS.md); and raw YUYV
frames (YUV 4:2:2, the NAO camera's V4L2 format: Y0 U Y1 V per pair of pixels, 2 bytes per pixel, no header)
named *.yuv, *.yuyv or *.raw: --size WxH gives their size, else it is told by the file's length among 160x120,
320x240, 640x480 and 1280x960. Pixel (0, 0) is the centre of the top-left pixel (OpenCV's).

Corner order (plain and --json): row by row, each row holding W - 1 corners. Of the grid's labellings (turns
and mirror images) the one whose rows run most nearly left to right and follow each other most nearly downwards:
for a board seen roughly upright, row 0 is the row nearest the top of the image and each row runs left to right.
That is an order in the image, not on the board: a board that looks the same turned (7 x 5, 4 x 4) cannot show
which of its corners is which, and the detail says so. With several boards of the size in view (both sandals),
the largest in the image is reported and the detail says how many there are.

Output: one line per image (found or not, with the reason; the corner count; the refinement quality: how far the
corners lie from straight lines through each row and column, RMS, and the edge width); --json prints one
document (schema naocal.detect/1):
  {"schema": "naocal.detect/1",
   "board": {"columns": W, "rows": H, "inner_corners": [W-1, H-1]},    squares, and inner corners per row, column
   "images": [{"path": str, "found": bool,
               "reason": null | "missing" | "cut_off" | "blurred",       why not found (null when found)
               "detail": str,                                            what was found, in words
               "width_px": int, "height_px": int,
               "channel": null | "grey" | "cr" | "cb",                   where the corners were found
               "line_rms_px": float | null, "edge_width_px": float | null,
               "corners_px": [[[u, v], ... W-1 per row], ... H-1 rows] | null}]}   in the corner order above
--overlay OUT draws each image's corners with their order (row 0 in red, index labels, corner 0 circled): OUT is
a file (.png, .jpg) for one image, or a directory (one IMAGE.corners.png per image); images narrower than 640 px
are drawn enlarged. An overlay never replaces an input image (by any name or link): that is refused.

Exit codes: 0 when the board was found in every image, 1 when it was not in some (listed on stderr), 2 for bad
input (an unreadable image, a bad --board) - then nothing is detected.
"""

from __future__ import annotations

import argparse

YUYV_SIZES = ((160, 120), (320, 240), (640, 480), (1280, 960))
RAW_SUFFIXES = (".yuv", ".yuyv", ".raw")
OVERLAY_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


def register(subparsers):
    p = subparsers.add_parser(
        "detect", help="find a checkerboard's inner corners in images (any board size, colours, polarity)",
        description=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", nargs="+", metavar="IMAGE",
                   help="image files (PNG, JPEG, BMP, PPM, PGM; raw YUYV frames *.yuv, *.yuyv, *.raw)")
    p.add_argument("--board", default="7x5", metavar="WxH",
                   help="the board in squares, not inner corners: W x H squares have (W-1) x (H-1) inner corners "
                        "(default 7x5, the sandal: 6 x 4 inner corners)")
    p.add_argument("--size", metavar="WxH", help="the pixel size of raw YUYV frames (default: told by the file's "
                                                 "length among 160x120, 320x240, 640x480, 1280x960)")
    p.add_argument("--channel", default="auto", choices=("auto", "grey", "cr", "cb"),
                   help="image channel to search (default auto: those that separate the squares, the best kept)")
    p.add_argument("--json", action="store_true", help="print one JSON document instead of lines")
    p.add_argument("--overlay", metavar="OUT", help="draw the corners: a file for one image, else a directory")
    p.set_defaults(run=run)


def run(args) -> int:
    import json
    import sys

    from naocal.agent.board_detect import parse_board
    from naocal.solver.errors import DataError, NaocalError
    from naocal.solver.fileio import check_output_file

    try:
        board = parse_board(args.board)
    except ValueError as err:
        raise NaocalError(f"--board: {err}") from None
    raw_size = parse_size(args.size) if args.size else None
    overlay = _overlay_paths(args.overlay, args.images) if args.overlay else None
    for out in (overlay or {}).values():  # before any work; never over an image (by any name or link)
        check_output_file(out, inputs=args.images)
    for path in args.images:  # every image checked first (and let go: memory): bad input detects nothing
        if read_image(path, raw_size).ndim == 2 and args.channel in ("cr", "cb"):
            raise DataError(path, f"a grey image has no {args.channel} channel (use --channel auto or grey)")

    reports, missing = [], []
    for path in args.images:
        image = read_image(path, raw_size)
        report = detect_one(path, image, board, args.channel)
        reports.append(report)
        if not report["found"]:
            missing.append(path)
        if overlay:
            _write_overlay(overlay[path], image, report)
        if not args.json:
            print(_line(report, board), flush=True)
    if args.json:
        print(json.dumps({"schema": "naocal.detect/1", "board": {"columns": board.columns, "rows": board.rows,
                                                                 "inner_corners": list(board.shape[::-1])},
                          "images": reports}))
    if missing:
        print(f"naocal detect: no {board_words(board)} found in {len(missing)} of {len(args.images)} images: "
              + ", ".join(missing), file=sys.stderr)
        return 1
    return 0


def board_words(board) -> str:
    """'7x5-square board (6x4 inner corners)': both counts, since OpenCV's users count inner corners."""
    rows, columns = board.shape
    return f"{board.columns}x{board.rows}-square board ({columns}x{rows} inner corners)"


def parse_size(text: str) -> tuple[int, int]:
    """--size 'WxH' -> (width, height) of a raw YUYV frame; NaocalError when malformed."""
    from naocal.solver.errors import NaocalError

    parts = text.lower().replace(" ", "").split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise NaocalError(f"--size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 640x480")
    from naocal.solver.fileio import MAX_IMAGE_PIXELS

    width, height = (int(p) for p in parts)
    if not (2 <= width <= 8192 and 2 <= height <= 8192) or width % 2:
        raise NaocalError(f"--size {text!r}: expected an even width of 2-8192 px and a height of 2-8192 px "
                          "(YUYV holds pixels in pairs)")
    if width * height > MAX_IMAGE_PIXELS:
        raise NaocalError(f"--size {text!r}: at most {MAX_IMAGE_PIXELS / 1e6:.1f} Mpx are read (4096 x 4096; "
                          "docs/CONVENTIONS.md)")
    return width, height


def read_image(path: str, raw_size: tuple[int, int] | None = None):
    """An 8-bit (h, w, 3) BGR or (h, w) grey image from a file (raw YUYV of `raw_size` (w, h), else told by its
    length); DataError naming the file when it cannot be."""
    from pathlib import Path

    import cv2
    import numpy as np

    from naocal.solver.errors import DataError
    from naocal.solver.fileio import native_stderr_held, read_bytes, read_image_bytes

    file = Path(path)
    if not file.exists():
        raise DataError(path, "no such file")
    if file.suffix.lower() in RAW_SUFFIXES:
        data = read_bytes(file)  # a regular file of at most 64 MiB (a FIFO or directory is refused unread)
        for width, height in [raw_size] if raw_size else YUYV_SIZES:
            if len(data) == 2 * width * height:
                yuyv = np.frombuffer(data, np.uint8).reshape(height, width, 2)
                return cv2.cvtColor(yuyv, cv2.COLOR_YUV2BGR_YUYV)
        if raw_size:
            raise DataError(path, f"raw YUYV of {len(data)} bytes: --size {raw_size[0]}x{raw_size[1]} needs "
                                  f"{2 * raw_size[0] * raw_size[1]} (2 bytes per pixel)")
        sizes = ", ".join(f"{w}x{h}" for w, h in YUYV_SIZES)
        raise DataError(path, f"raw YUYV of {len(data)} bytes: expected 2 bytes per pixel at {sizes} "
                              "(or give --size WxH)")
    data, _ = read_image_bytes(file)  # its header's size within the pixel budget before anything is decoded
    said = []  # what libpng, libjpeg ... printed: a damaged file is our one line, with their words in it
    log = cv2.utils.logging
    previous = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)  # OpenCV's own log lines say what the None below says
    try:
        with native_stderr_held(said):
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as err:  # a header OpenCV refuses after ours passed it
        raise DataError(path, f"not an image OpenCV can read: {str(err).strip().splitlines()[-1][:200]}") from None
    finally:
        log.setLogLevel(previous)
    if image is None or image.size == 0:
        why = " ".join(said[0].split())[:160] if said and said[0].strip() else ""
        raise DataError(path, "not an image OpenCV can read" + (f" ({why})" if why else " (PNG, JPEG, BMP, PPM, PGM; "
                                                                         "raw YUYV as *.yuv, *.yuyv, *.raw)"))
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.dtype != np.uint8:
        raise DataError(path, f"{image.dtype} pixels: expected 8 or 16 bit")
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise DataError(path, f"{image.shape} pixels: expected grey or colour")
    return np.ascontiguousarray(image)


def detect_one(path: str, image, board, channel: str) -> dict:
    """One image's JSON report (module docstring)."""
    import numpy as np

    from naocal.agent.board_detect import BoardSpec, detect_board

    found = detect_board(image, board, channel=channel)
    corners = found.image_order_px
    located = corners is not None and found.reason in (None, "ambiguous")
    rows, columns = board.shape
    detail = found.detail
    if not located and found.reason == "missing" and max(board.columns, board.rows) < 40:
        # --board given as OpenCV's inner-corner count? Then the board one square larger each way is there.
        larger = BoardSpec(board.columns + 1, board.rows + 1)
        bigger = detect_board(image, larger, channel=channel)
        if bigger.image_order_px is not None and bigger.reason in (None, "ambiguous"):
            detail += (f"; a {board_words(larger)} is there: --board counts squares, not inner corners "
                       f"(--board {larger.columns}x{larger.rows})")
    return {
        "path": path,
        "found": bool(located),
        "reason": None if located else found.reason,
        "detail": detail,
        "width_px": int(image.shape[1]),
        "height_px": int(image.shape[0]),
        "channel": found.channel or None,
        "line_rms_px": _number(found.line_rms_px),
        "edge_width_px": _number(found.edge_width_px),
        "corners_px": np.round(corners.reshape(rows, columns, 2), 3).tolist() if located else None,
    }


def _number(value: float):
    import math

    return None if value is None or not math.isfinite(value) else round(float(value), 3)


def _line(report: dict, board) -> str:
    if not report["found"]:
        return f"{report['path']}: not found ({report['reason']}): no {board_words(board)}: {report['detail']}"
    rows, columns = len(report["corners_px"]), len(report["corners_px"][0])
    text = (f"{report['path']}: found {rows * columns} corners ({rows} rows of {columns}) in {report['channel']}, "
            f"line fit {report['line_rms_px']:.2f} px RMS, edges {report['edge_width_px']:.1f} px wide")
    if "boards" in report["detail"]:
        text += "; " + report["detail"].split(" (")[0] + ": the largest reported"
    if "orientation cannot be told" in report["detail"]:
        text += "; the board looks the same turned: corners in image order"
    return text


def _overlay_paths(out: str, images: list) -> dict:
    """{image path: overlay file}. OUT is a file for one image (unless it is a directory), else a directory."""
    from pathlib import Path

    from naocal.solver.errors import NaocalError

    target = Path(out)
    if len(images) == 1 and not target.is_dir():
        if target.suffix.lower() not in OVERLAY_SUFFIXES:
            raise NaocalError(f"--overlay {out}: expected a file ending in {', '.join(OVERLAY_SUFFIXES)} "
                              "(or a directory)")
        return {images[0]: target}
    if target.exists() and not target.is_dir():
        raise NaocalError(f"--overlay {out}: not a directory (several images need one)")
    paths, used = {}, set()
    for path in images:
        name = Path(path).stem + ".corners.png"
        k = 1
        while name in used:
            k += 1
            name = f"{Path(path).stem}-{k}.corners.png"
        used.add(name)
        paths[path] = target / name
    return paths


ROW_COLOURS = ((0, 0, 255), (0, 255, 255), (255, 0, 255), (255, 255, 0), (255, 128, 0), (255, 255, 255))  # BGR


def _label(canvas, text: str, origin, size: float, colour) -> None:
    """Text on a dark box, readable on any background."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    (w, h), base = cv2.getTextSize(text, font, size, 1)
    x, y = int(origin[0]), int(origin[1])
    cv2.rectangle(canvas, (x - 2, y - h - 2), (x + w + 2, y + base), (0, 0, 0), -1)
    cv2.putText(canvas, text, (x, y), font, size, colour, 1, cv2.LINE_AA)


def _write_overlay(out, image, report: dict) -> None:
    import cv2
    import numpy as np

    from naocal.solver.errors import NaocalError
    from naocal.solver.fileio import atomic_write_bytes

    canvas = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    scale = 1
    while canvas.shape[1] * scale < 640:
        scale += 1
    canvas = cv2.resize(canvas, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    size = 0.4
    if report["found"]:
        grid = (np.asarray(report["corners_px"]) + 0.5) * scale - 0.5
        rows, columns = grid.shape[:2]
        shift = 4  # fixed-point bits for sub-pixel drawing
        pts = np.round(grid * (1 << shift)).astype(np.int32)
        for r in range(rows):
            colour = ROW_COLOURS[r % len(ROW_COLOURS)]
            cv2.polylines(canvas, [pts[r]], False, colour, 2, cv2.LINE_AA, shift)
            for c in range(columns):
                cv2.circle(canvas, tuple(pts[r, c]), 3 << shift, colour, 1, cv2.LINE_AA, shift)
                _label(canvas, str(r * columns + c), np.round(grid[r, c] + [5, -5]).astype(int), size, colour)
        cv2.circle(canvas, tuple(pts[0, 0]), 8 << shift, ROW_COLOURS[0], 2, cv2.LINE_AA, shift)
        text = f"{rows * columns} corners in {report['channel']}, row 0 red, corner 0 circled"
    else:
        text = f"not found ({report['reason']})"
    _label(canvas, text, (6, 18), 0.5, (255, 255, 255))
    ok, encoded = cv2.imencode(out.suffix if out.suffix.lower() in OVERLAY_SUFFIXES else ".png", canvas)
    if not ok:
        raise NaocalError(f"--overlay {out}: could not encode the image")
    atomic_write_bytes(out, encoded.tobytes())
