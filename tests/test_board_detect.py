"""agent.board_detect on synthetic boards with exact corners: sizes, colours, polarity, orientation, refusals."""

import cv2
import numpy as np
import pytest

from naocal.agent import board_detect
from naocal.agent.board_detect import (SANDAL, BoardSpec, channels_to_try, detect_board, image_order, labellings,
                                line_rms_px, parse_board, polarity)
from tests.synthetic_boards import board_homography, inner_corners, render


def _scene(columns, rows, colours=("black", "white"), **pose):
    look = {k: pose.pop(k) for k in ("blur_px", "noise", "margin_squares", "background", "supersample") if k in pose}
    look.setdefault("blur_px", 0.6)
    look.setdefault("noise", 2.0)
    look.setdefault("margin_squares", 0.5)
    if "size" in pose:
        look["size"] = pose["size"]
    return render(columns, rows, board_homography(columns, rows, **pose), colours=colours, **look)


def _as_labelled(found, truth):
    """The detection's image-ordered corners in the labelling closest to the truth (rows, cols, 2)."""
    grid = found.image_order_px.reshape(-1, truth.shape[1], 2) if found.image_order_px is not None else None
    options = [g for _, g in labellings(grid.reshape(truth.shape)) if g.shape == truth.shape]
    return min(options, key=lambda g: np.abs(g - truth).max())


@pytest.mark.parametrize("columns, rows, colours, pose", [
    (8, 5, ("black", "white"), dict(tilt_x=-0.4, turn=0.2)),
    (8, 5, ("white", "black"), dict(tilt_x=-0.4, turn=0.2)),  # the other polarity: the same board turned
    (8, 5, ("black", "white"), dict(tilt_y=0.5, turn=2.6)),
    (10, 7, ("white", "black"), dict(turn=-1.3, square_px=30.0)),
    (9, 6, ("black", "white"), dict(turn=3.0, tilt_x=0.7, square_px=25.0)),
])
def test_a_board_whose_colours_fix_its_orientation_is_found_in_board_order(columns, rows, colours, pose):
    """columns + rows odd: a half turn swaps the colours, and the camera sees the printed face (never its mirror
    image), so with known colours the board order follows from the image alone, in either polarity."""
    scene = _scene(columns, rows, colours, **pose)
    found = detect_board(scene.image, BoardSpec(columns, rows, colours=colours))
    assert found.ok, found.detail
    error = found.vertices_px - scene.corners_px.reshape(-1, 2)
    assert np.abs(error).max() < 0.12 and np.sqrt(np.mean(error ** 2)) < 0.05, np.abs(error).max()
    assert found.channel == "grey"
    # Told the wrong polarity, the detector puts vertex 0 where that colour is: the board turned by 180 deg.
    swapped = detect_board(scene.image, BoardSpec(columns, rows, colours=colours[::-1]))
    assert swapped.ok
    np.testing.assert_allclose(swapped.vertices_px, found.vertices_px[::-1], atol=1e-9)


@pytest.mark.parametrize("columns, rows, colours, pose, orientations", [
    (7, 5, ("black", "white"), dict(tilt_x=0.5, turn=0.3), 2),  # the sandal: the same after a half turn
    (7, 5, ("white", "black"), dict(tilt_y=0.6, turn=-0.4), 2),
    (4, 4, ("black", "white"), dict(), 2),  # quarter turns swap its colours, the half turn does not
    (5, 5, ("black", "white"), dict(turn=0.78), 4),  # every quarter turn keeps its colours
    (4, 4, ("orange", "blue"), dict(tilt_x=0.7, turn=0.1, background="green", margin_squares=0.0), 2),
])
def test_a_symmetric_board_is_found_but_its_orientation_is_reported_ambiguous(columns, rows, colours, pose,
                                                                              orientations):
    scene = _scene(columns, rows, colours, **pose)
    found = detect_board(scene.image, BoardSpec(columns, rows, colours=colours))
    assert not found.ok and found.reason == "ambiguous", found.detail
    assert f"{orientations} orientations fit" in found.detail
    error = _as_labelled(found, scene.corners_px) - scene.corners_px
    assert np.abs(error).max() < 0.12 and np.sqrt(np.mean(error ** 2)) < 0.05
    if "orange" in colours:
        assert found.channel in ("cr", "cb")  # grey barely separates orange from blue


def test_unknown_colours_and_either_polarity():
    """Without colours every channel is tried; black-on-white and white-on-black boards are found alike."""
    for colours in (("black", "white"), ("white", "black")):
        scene = _scene(8, 5, colours, tilt_x=0.3, turn=0.5)
        found = detect_board(scene.image, BoardSpec(8, 5))
        assert found.reason == "ambiguous" and "polarity" in found.detail  # the colours would have told
        error = _as_labelled(found, scene.corners_px) - scene.corners_px
        assert np.abs(error).max() < 0.12
    assert channels_to_try(scene.image, BoardSpec(8, 5)) == ("grey", "cr", "cb")
    assert channels_to_try(scene.image, SANDAL) == ("grey",)
    assert channels_to_try(scene.image[..., 0], BoardSpec(8, 5)) == ("grey",)
    orange_blue = channels_to_try(scene.image, BoardSpec(4, 4, colours=("orange", "blue")))
    assert {"cr", "cb"} <= set(orange_blue[:2])  # the best separating first
    assert polarity(SANDAL, "grey") == -1 and polarity(BoardSpec(4, 4), "grey") == 0


def test_image_order_runs_left_to_right_and_top_to_bottom():
    """Whatever labelling a grid comes in, image_order returns the same one: row 0 at the top, each row left to
    right, for a board seen upright and for one turned by 30 deg."""
    for turn in (0.0, 0.5, -0.5, np.pi):
        truth = inner_corners(7, 5, board_homography(7, 5, tilt_x=0.3, turn=turn))
        orders = [image_order(g, (4, 6)) for _, g in labellings(truth) if g.shape == truth.shape]
        for order in orders:
            np.testing.assert_array_equal(order, orders[0])
        along_row = orders[0][:, -1] - orders[0][:, 0]
        down = orders[0][-1] - orders[0][0]
        assert np.all(along_row[:, 0] > 0) and np.all(down[:, 1] > 0)


def test_noise_blur_and_dim_light_keep_the_corners_accurate():
    truth_scene = _scene(8, 6, tilt_x=0.4, turn=0.2, square_px=35.0)
    board = BoardSpec(8, 6, colours=("black", "white"))
    for look, limit in ((dict(noise=8.0), 0.25), (dict(blur_px=2.0), 0.1), (dict(noise=4.0, blur_px=1.5), 0.2)):
        scene = _scene(8, 6, tilt_x=0.4, turn=0.2, square_px=35.0, **look)
        found = detect_board(scene.image, board)
        error = _as_labelled(found, truth_scene.corners_px) - truth_scene.corners_px
        assert np.abs(error).max() < limit, (look, np.abs(error).max())
    dim = (truth_scene.image * 0.15).astype(np.uint8)  # contrast of about 30 grey levels
    found = detect_board(dim, board)
    assert np.abs(_as_labelled(found, truth_scene.corners_px) - truth_scene.corners_px).max() < 0.25


def test_small_and_large_images():
    for size, square_px in (((160, 120), 12.0), ((1280, 960), 110.0)):
        scene = _scene(6, 5, size=size, square_px=square_px, tilt_x=0.3, turn=0.3, blur_px=0.8 * square_px / 40,
                       supersample=2 if size[0] > 640 else 4)
        found = detect_board(scene.image, BoardSpec(6, 5, colours=("black", "white")))
        assert found.image_order_px is not None, (size, found.detail)
        error = _as_labelled(found, scene.corners_px) - scene.corners_px
        assert np.abs(error).max() < 0.02 * square_px + 0.1, (size, np.abs(error).max())


def test_wrong_board_size_is_refused_never_cut_down():
    scene = _scene(8, 6, tilt_x=0.3, turn=0.2)
    bigger = detect_board(scene.image, BoardSpec(5, 4))
    assert bigger.reason == "missing" and bigger.image_order_px is None
    assert "8 x 6 squares" in bigger.detail, bigger.detail
    smaller = detect_board(scene.image, BoardSpec(9, 6))
    assert smaller.reason == "missing" and "complete 7 x 5 grid" in smaller.detail, smaller.detail
    transposed = detect_board(scene.image, BoardSpec(6, 8))  # the same board, rows and columns swapped: found
    assert transposed.image_order_px is not None


def test_images_without_a_board_are_refused():
    rng = np.random.default_rng(3)
    noise = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    blank = np.full((240, 320), 128, np.uint8)
    ramp = np.tile(np.linspace(0, 255, 320).astype(np.uint8), (240, 1))
    stripes = np.tile(((np.arange(320) // 12) % 2 * 200 + 20).astype(np.uint8), (240, 1))
    dots = np.full((240, 320), 30, np.uint8)
    for x in range(20, 300, 25):
        for y in range(20, 220, 25):
            cv2.circle(dots, (x, y), 6, 220, -1)
    for image in (noise, blank, ramp, stripes, cv2.GaussianBlur(noise, (0, 0), 3), dots):
        found = detect_board(image, BoardSpec(4, 4))
        assert found.reason == "missing" and found.image_order_px is None, found.detail


def test_a_board_cut_off_by_the_image_edge():
    scene = _scene(8, 6, tilt_x=0.3, turn=0.1, shift_px=(-250.0, 0.0))
    assert scene.corners_px[..., 0].min() < 0 < scene.corners_px[..., 0].max()  # some corners outside
    found = detect_board(scene.image, BoardSpec(8, 6))
    assert found.reason == "cut_off", found.detail


def test_two_boards_in_view_are_ambiguous_and_the_largest_is_given():
    left = _scene(6, 5, square_px=20.0, shift_px=(-150.0, 0.0))
    right = _scene(6, 5, square_px=24.0, shift_px=(150.0, 0.0))
    both = np.where(np.arange(640)[None, :, None] < 320, left.image, right.image).astype(np.uint8)
    found = detect_board(both, BoardSpec(6, 5))
    assert found.reason == "ambiguous" and "2 boards" in found.detail, found.detail
    error = _as_labelled(found, right.corners_px) - right.corners_px
    assert np.abs(error).max() < 0.12


def test_blur_limit_and_quality_numbers():
    scene = _scene(8, 5, tilt_x=0.3, blur_px=2.5)
    found = detect_board(scene.image, BoardSpec(8, 5, colours=("black", "white")))
    assert found.ok and found.edge_width_px > 3.0 and found.line_rms_px < 0.05
    refused = detect_board(scene.image, BoardSpec(8, 5, colours=("black", "white")), max_edge_width_px=3.0)
    assert refused.reason == "blurred" and refused.image_order_px is not None
    assert line_rms_px(scene.corners_px) < 1e-9  # straight lines through exact corners


def test_board_specs_and_bad_arguments():
    assert parse_board("4x4") == BoardSpec(4, 4) and parse_board("7X5") == BoardSpec(7, 5)
    assert SANDAL.shape == (4, 6) and SANDAL.n_corners == 24 and SANDAL.colours == ("black", "white")
    for text in ("4", "4x", "x4", "4x4x4", "-4x4", "2x5", "4.5x4", "41x4", ""):
        with pytest.raises(ValueError):
            parse_board(text)
    with pytest.raises(ValueError):
        BoardSpec(4, 4, colours=("black", "black"))
    with pytest.raises(ValueError):
        BoardSpec(4, 4, colours=("black", "purple"))
    image = np.zeros((240, 320, 3), np.uint8)
    with pytest.raises(ValueError):
        detect_board(image.astype(np.float32), BoardSpec(4, 4))
    with pytest.raises(ValueError):
        detect_board(np.zeros((240, 320, 4), np.uint8), BoardSpec(4, 4))
    with pytest.raises(ValueError):
        detect_board(image, BoardSpec(4, 4), channel="red")
    with pytest.raises(ValueError):
        detect_board(image[..., 0], BoardSpec(4, 4), channel="cr")


# --- small, blurred, JPEG-compressed boards: OpenCV's detectors as a second opinion ---------------------------------
def _small_jpeg_board(seed, columns=10, rows=7, square=40):
    """A black/white board of 7-12 px squares in perspective on a mottled background, lit unevenly, blurred, noisy,
    JPEG 70: (BGR image, true inner corners (n, 2) in board order)."""
    rng = np.random.default_rng(seed)
    board = np.zeros((rows * square, columns * square), np.uint8)
    for r in range(rows):
        for c in range(columns):
            if (r + c) % 2 == 0:
                board[r * square:(r + 1) * square, c * square:(c + 1) * square] = 255
    board = cv2.copyMakeBorder(board, square, square, square, square, cv2.BORDER_CONSTANT, value=255)
    h, w = board.shape
    scale = rng.uniform(0.25, 0.45)
    cx, cy = 320 + rng.uniform(-80, 80), 240 + rng.uniform(-60, 60)
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = np.float32([[cx - w * scale / 2, cy - h * scale / 2], [cx + w * scale / 2, cy - h * scale / 2],
                      [cx + w * scale / 2, cy + h * scale / 2], [cx - w * scale / 2, cy + h * scale / 2]])
    M = cv2.getPerspectiveTransform(src, dst + rng.uniform(-40, 40, dst.shape).astype(np.float32))
    background = cv2.resize(rng.uniform(60, 200, (60, 80)).astype(np.uint8), (640, 480))
    img = cv2.warpPerspective(board, M, (640, 480), dst=background, borderMode=cv2.BORDER_TRANSPARENT)
    img = img * np.linspace(0.6, 1.1, 640)[None, :] * rng.uniform(0.5, 1.0) + rng.uniform(0, 40)
    img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.5, 1.5)) + rng.normal(0, 4, img.shape)
    ok, jpeg = cv2.imencode(".jpg", np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 70])
    grey = cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE)
    corners = np.array([[square * (i + 2), square * (j + 2)] for j in range(rows - 1) for i in range(columns - 1)],
                       np.float32) - 0.5  # between two pixels: pixel centres at integer coordinates
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), cv2.perspectiveTransform(corners[None], M)[0]


@pytest.mark.parametrize("seed", [102, 112, 129])  # boards the X-corner checks refuse (of seeds 100-129: 11, of
# which OpenCV's second opinion finds 7)
def test_small_blurred_compressed_boards_are_found_with_opencvs_second_opinion(seed):
    image, truth = _small_jpeg_board(seed)
    own = board_detect._own_lattices(board_detect.channel_image(image, "grey"), "grey", BoardSpec(10, 7))
    assert own.grid is None  # the case this covers
    found = detect_board(image, BoardSpec(10, 7))  # no colours: found, the orientation ambiguous
    assert found.image_order_px is not None, found.detail
    error = np.linalg.norm(found.image_order_px[:, None] - truth[None], axis=-1).min(axis=1)
    assert error.max() < 1.2 and np.sqrt(np.mean(error ** 2)) < 0.5


def test_opencvs_second_opinion_does_not_cut_a_bigger_board_down_to_size():
    """OpenCV finds a board of the size asked for inside a bigger one; the check beyond its outer squares refuses
    that (here on exact corners of a 10 x 7 board: a 6 x 5 window in it, and the whole board)."""
    square = 40
    board = np.zeros((7 * square, 10 * square), np.uint8)
    for r in range(7):
        for c in range(10):
            board[r * square:(r + 1) * square, c * square:(c + 1) * square] = 255 * ((r + c) % 2 == 0)
    img = cv2.copyMakeBorder(board, 60, 480 - 60 - 7 * square, 60, 640 - 60 - 10 * square,
                             cv2.BORDER_CONSTANT, value=255)
    img = cv2.copyMakeBorder(img[20:-20, 20:-20], 20, 20, 20, 20, cv2.BORDER_CONSTANT, value=120)

    def window(x0, y0, columns, rows):  # exact inner corners of a window of the board
        xs, ys = np.meshgrid(np.arange(columns), np.arange(rows))
        cells = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
        return cells, 60 - 0.5 + square * (cells + [x0 + 1, y0 + 1])

    for (x0, y0, columns, rows), bigger in (((2, 1, 5, 4), True), ((0, 0, 9, 6), False)):
        cells, points = window(x0, y0, columns, rows)
        ok, contrast, _ = board_detect.alternation(img, cells, points)
        assert ok
        assert board_detect._continues_beyond(img, cells, points, contrast, rows, columns) == bigger
