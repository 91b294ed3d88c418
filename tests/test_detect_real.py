"""Detection on real NAO pixels: six bottom-camera images of a 4 x 4 orange/blue board on green carpet (MRL-SPL,
2009, MIT licence: tests/data/realdata/mrlspl-nao-2009/). No truth comes with them, so every check is independent
of the detector: the corners lie on straight lines; a homography (a planar board) explains them; each is a real
X-corner; and each agrees with the intersection of straight lines fitted to the board's own edges, located in 1-D
profiles across them (no corner refinement involved)."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from naocal.agent.board_detect import BoardSpec, channel_image, corner_asymmetry, detect_board, labellings
from naocal.agent.corners import detect_board_vertices

DATA = Path(__file__).parent / "data" / "realdata" / "mrlspl-nao-2009"
BOARD = BoardSpec(4, 4, square_m=0.1, colours=("orange", "blue"))


@pytest.fixture(scope="module")
def images():
    return [cv2.imread(str(DATA / f"image_{i}.png")) for i in range(6)]


@pytest.fixture(scope="module")
def found(images):
    """Each image's detection without colours (as `naocal detect --board 4x4` runs it), and in each channel."""
    return [(detect_board(image, BoardSpec(4, 4)), {c: detect_board(image, BoardSpec(4, 4), channel=c)
                                                   for c in ("cr", "cb")}) for image in images]


def _grid(detection) -> np.ndarray:
    return detection.image_order_px.reshape(3, 3, 2)


def _edge_point(channel: np.ndarray, point, normal, half_px: float) -> float | None:
    """Signed offset (px) along `normal` of the mid-level crossing of the channel's profile across an edge."""
    t = np.linspace(-half_px, half_px, int(8 * half_px) + 1)
    xy = (point[None] + t[:, None] * normal[None]).astype(np.float32)
    profile = cv2.remap(channel.astype(np.float32), xy[:, 0:1], xy[:, 1:2], cv2.INTER_LINEAR)[:, 0]
    k = max(2, len(t) // 6)
    low, high = profile[:k].mean(), profile[-k:].mean()
    if abs(high - low) < 20:
        return None
    level = 0.5 * (low + high)
    s = np.sign(profile - level) * np.sign(high - low)
    crossings = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
    if len(crossings) != 1:
        return None
    i = crossings[0]
    return float(t[i] + (level - profile[i]) / (profile[i + 1] - profile[i]) * (t[i + 1] - t[i]))


def _edge_lines(channel: np.ndarray, grid: np.ndarray):
    """Lines (point, unit direction) fitted to the edge points along each row and column of corners, over the
    segments between corners and one square beyond (the outer squares' edges), keeping 3 px from every corner."""
    lines = {}
    for name, lines_of_corners in (("row", grid), ("column", np.swapaxes(grid, 0, 1))):
        fitted = []
        for corners in lines_of_corners:
            direction = corners[-1] - corners[0]
            direction /= np.linalg.norm(direction)
            normal = np.array([-direction[1], direction[0]])
            ends = np.concatenate([[2 * corners[0] - corners[1]], corners, [2 * corners[-1] - corners[-2]]])
            points = []
            for a, b in zip(ends[:-1], ends[1:]):
                length = np.linalg.norm(b - a)
                for f in np.linspace(0, 1, 12)[1:-1]:
                    p = a + f * (b - a)
                    if min(f, 1 - f) * length < 3.0:
                        continue
                    offset = _edge_point(channel, p, normal, 0.3 * length)
                    if offset is not None:
                        points.append(p + offset * normal)
            points = np.array(points)
            centre = points.mean(axis=0)
            u = np.linalg.svd(points - centre)[2][0]
            residual = (points - centre) @ np.array([-u[1], u[0]])
            fitted.append((centre, u, len(points), float(np.sqrt(np.mean(residual ** 2)))))
        lines[name] = fitted
    return lines


def _intersect(a, b) -> np.ndarray:
    (p, u), (q, v) = a[:2], b[:2]
    s = np.linalg.solve(np.column_stack([u, -v]), q - p)
    return p + s[0] * u


def test_all_nine_corners_on_all_six_real_images(images, found):
    for image, (auto, _) in zip(images, found):
        assert auto.reason == "ambiguous" and "orientation cannot be told" in auto.detail, auto.detail
        assert auto.channel in ("cr", "cb")  # grey hardly separates orange from blue
        grid = _grid(auto)
        # Straight rows and columns (the lens bends them by far less than 0.01 px over two squares).
        assert auto.line_rms_px < 0.15
        # A planar board: one homography explains all nine corners.
        H, _ = cv2.findHomography(np.argwhere(np.ones((3, 3)))[:, ::-1].astype(float), grid.reshape(-1, 2), 0)
        mapped = cv2.perspectiveTransform(np.argwhere(np.ones((3, 3)))[None, :, ::-1].astype(float), H)[0]
        assert np.sqrt(np.mean((mapped - grid.reshape(-1, 2)) ** 2)) < 0.15
        # Real X-corners: their neighbourhoods are point symmetric (an L-corner gives 0.5, an edge 1).
        channel = channel_image(image, auto.channel)
        assert corner_asymmetry(channel, grid.reshape(-1, 2), 5).max() < 0.2
        # The spacing is a board's: neighbouring squares differ by less than perspective allows (< 20 %).
        steps = np.linalg.norm(np.diff(grid, axis=1), axis=-1)
        assert np.all(steps.max(axis=1) / steps.min(axis=1) < 1.2)


def test_corners_agree_with_the_intersections_of_the_boards_own_edges(images, found):
    """In each chroma channel, straight lines through sub-pixel edge points found in 1-D profiles across the
    board's edges intersect where the detector put the corners."""
    differences = []
    for image, (_, by_channel) in zip(images, found):
        for name, detection in by_channel.items():
            assert detection.image_order_px is not None, (name, detection.detail)
            grid = _grid(detection)
            lines = _edge_lines(channel_image(image, name), grid)
            for line in lines["row"] + lines["column"]:
                assert line[2] >= 20 and line[3] < 0.35  # enough edge points, and on a straight line
            crossing = np.array([[_intersect(r, c) for c in lines["column"]] for r in lines["row"]])
            differences.append(crossing - grid)
    differences = np.concatenate(differences).reshape(-1, 2)
    rms, largest = np.sqrt(np.mean(differences ** 2)), np.abs(differences).max()
    print(f"\ncorners vs edge-line intersections: RMS {rms:.2f} px, largest {largest:.2f} px")
    # The edge lines' own scatter is 0.1-0.25 px per edge point; the largest differences are the top row's, where a
    # band of different brightness crosses the board 10 px below it.
    assert rms < 0.2 and largest < 0.6


def yuv422_round_trip(image: np.ndarray) -> np.ndarray:
    """The NAO camera's YUV 4:2:2: each horizontal pair of pixels shares one chroma sample."""
    ycc = cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb).astype(float)
    shared = 0.5 * (ycc[:, 0::2, 1:] + ycc[:, 1::2, 1:])
    ycc[:, 0::2, 1:], ycc[:, 1::2, 1:] = shared, shared
    return cv2.cvtColor(np.clip(np.round(ycc), 0, 255).astype(np.uint8), cv2.COLOR_YCrCb2BGR)


DEGRADATIONS = {  # name: (degrade, scale of the result, largest corner change in the same channel, its px)
    "noise": (lambda im, rng: np.clip(im + rng.normal(0, 8, im.shape), 0, 255).astype(np.uint8), 1.0, 0.3),
    "blur": (lambda im, rng: cv2.GaussianBlur(im, (0, 0), 1.5), 1.0, 0.45),
    "half size": (lambda im, rng: cv2.resize(im, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA), 0.5, 0.3),
    "yuv422": (lambda im, rng: yuv422_round_trip(im), 1.0, 0.35),
    "gamma 0.5": (lambda im, rng: (255 * (im / 255.0) ** 0.5).astype(np.uint8), 1.0, 0.2),
    "gamma 2": (lambda im, rng: (255 * (im / 255.0) ** 2).astype(np.uint8), 1.0, 0.2),
    "jpeg 90": (lambda im, rng: cv2.imdecode(cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, 90])[1], 1),
                1.0, 0.9),
}


@pytest.mark.parametrize("name", list(DEGRADATIONS))
def test_degraded_real_images_are_still_detected(images, found, name):
    """Found in every image, with corners where the undegraded image has them in the same channel (Cr and Cb
    disagree by up to 0.7 px on these images, their chroma siting; and when the degradation makes another
    channel the best, it is compared with Cr within 1 px)."""
    degrade, scale, limit = DEGRADATIONS[name]
    rng = np.random.default_rng(5)
    for image, (auto, by_channel) in zip(images, found):
        worse = degrade(image, rng)
        again = detect_board(worse, BoardSpec(4, 4))
        assert again.image_order_px is not None and again.reason == "ambiguous", (name, again.detail)
        assert again.line_rms_px < 0.3
        reference = by_channel.get(again.channel)
        if reference is None:
            reference, limit = by_channel["cr"], 1.0
        expected = (reference.image_order_px + 0.5) * scale - 0.5  # pixel centres at integer coordinates
        assert np.abs(again.image_order_px - expected).max() < limit, (name, again.channel)


def test_wrong_board_sizes_are_refused_on_real_images(images):
    for columns, rows, hint in ((7, 5, "3 x 3 grid"), (5, 4, "3 x 3 grid"), (3, 3, "4 x 4 squares")):
        for image in images[:3]:
            result = detect_board(image, BoardSpec(columns, rows))
            assert result.reason == "missing" and result.image_order_px is None, result.detail
            assert hint in result.detail, result.detail


def test_a_non_board_region_of_a_real_image_is_refused(images):
    """The carpet, the table edge and the room behind, without the board: its stripes make X-like points in the
    chroma channels, which must not pass for a board."""
    for image in images:
        without = image.copy()
        without[30:150, 70:260] = image[120:240, 70:260]  # carpet from below the board, over the board
        result = detect_board(without, BoardSpec(4, 4))
        assert result.reason == "missing", result.detail


def test_a_prediction_orders_the_corners_on_the_board(images, found):
    """With a predicted projection (as a calibration model gives it: here the corners turned, scaled and shifted
    a little), the board's vertices come back in the prediction's order, on the same pixels. Of the grid's 8
    labellings, the 4 that put orange on square (0, 0) are found (2 of them are mirror images, which no camera
    model predicts); the others are refused because the squares' colours contradict them."""
    rng = np.random.default_rng(2)
    for image, (auto, _) in zip(images, found):
        grid = _grid(auto)
        accepted = 0
        for _, labelled in labellings(grid):
            truth = labelled.reshape(-1, 2)
            centre = truth.mean(axis=0)
            a = np.radians(rng.uniform(-4, 4))
            R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) * rng.uniform(0.96, 1.04)
            predicted = centre + (truth - centre) @ R.T + rng.uniform(-8, 8, 2)
            result = detect_board_vertices(image, predicted, board=BOARD, max_edge_width_px=10.0)
            if result.ok:
                accepted += 1
                assert np.abs(result.vertices_px - truth).max() < 0.8
                ycrcb = cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb)
                square_00 = np.round(1.5 * truth[0] - 0.5 * truth[4]).astype(int)  # half a diagonal beyond vertex 0
                assert ycrcb[square_00[1], square_00[0], 1] > 150  # orange: high Cr (blue is below 100)
            else:
                assert result.reason in ("missing", "ambiguous"), result.detail
        assert accepted == 4
