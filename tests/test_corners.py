"""Corner detection on the mock's images, against the exact projections of the rendered scene."""

import cv2
import numpy as np
import pytest

from naocal.agent.corners import REASONS, detect_board_vertices, order_like_prediction
from naocal.backends.mock import MockBackend
from tests.mock_stances import capture_at, visible_stances

N_STANCES = 100


def _model_error(pixels, rng, shift_px=10.0, angle_rad=0.03, scale=0.02):
    """A prediction as an uncalibrated model makes it: the truth shifted, turned and scaled a little."""
    centre = pixels.mean(axis=0)
    c, s = np.cos(angle_rad * rng.standard_normal()), np.sin(angle_rad * rng.standard_normal())
    R = np.array([[c, -s], [s, c]]) * (1 + scale * rng.standard_normal())
    return centre + (pixels - centre) @ R.T + rng.normal(0, shift_px, 2)


def _capture(n, seed, both=False):
    """(image, leg, true pixels (24, 2), visible (24,), the other board's (pixels, visible)) for random stances
    in which the camera sees the board of `leg` (or both boards) whole."""
    mock = MockBackend(seed=seed)
    out = []
    for command, leg in visible_stances(mock, n, seed=2, both=both):
        image = capture_at(mock, command)
        truth = mock.true_vertex_pixels(image)
        other = "R" if leg == "L" else "L"
        out.append((image.pixels, leg, truth[leg][0], truth[leg][1], truth[other]))
    mock.close()
    return out


@pytest.fixture(scope="module")
def many():
    return _capture(N_STANCES, seed=31)


@pytest.fixture(scope="module")
def captures():
    return _capture(8, seed=32)


@pytest.mark.slow
def test_detected_vertices_match_the_true_projection(many):
    rng = np.random.default_rng(0)
    errors, failures = [], []
    # The sampler keeps a 5 mm ring around each vertex in sight; seen in the image, the toe's raised edge may
    # still come within the 4 px that true_vertex_pixels asks for. Those few are left out.
    clear = [c for c in many if c[3].all()]
    assert len(clear) >= N_STANCES - 3
    for pixels, leg, truth, _, _ in clear:
        found = detect_board_vertices(pixels, _model_error(truth, rng))
        if not found.ok:
            failures.append(found.reason)
            continue
        error = found.vertices_px - truth
        # No vertex-order error: every vertex lies on its own true position (a neighbour is ~a square away).
        assert np.max(np.linalg.norm(error, axis=1)) < 0.5
        errors.append(error)
    assert len(failures) <= 2, failures  # a vertex too close to the toe may be refused, never guessed
    errors = np.concatenate(errors)
    rms = np.sqrt(np.mean(errors ** 2, axis=0))
    print(f"\n{len(clear) - len(failures)} boards: RMS error {rms} px, mean {errors.mean(axis=0)} px")
    assert np.all(rms <= 0.1)
    assert np.all(np.abs(errors.mean(axis=0)) < 0.02)  # no bias from a pixel-convention slip


def test_without_a_prediction_the_order_is_not_guessed(captures):
    pixels, _, truth, _, _ = captures[0]
    found = detect_board_vertices(pixels)
    assert not found.ok and found.reason == "ambiguous" and found.vertices_px is None
    grid = found.image_order_px.reshape(4, 6, 2)
    labellings = [grid, grid[::-1], grid[:, ::-1], grid[::-1, ::-1]]
    assert min(np.abs(g.reshape(-1, 2) - truth).max() for g in labellings) < 0.5


def test_rendered_boards_are_found_without_a_prediction(captures):
    """agent.board_detect on the mock's images: every board whose vertices are all in sight, in image order, on
    its true vertices (in one of the sandal's two orientations: it looks the same turned)."""
    for pixels, _, truth, visible, (other, other_visible) in captures:
        if not visible.all():
            continue
        found = detect_board_vertices(pixels)
        assert found.reason == "ambiguous" and found.image_order_px is not None, found.detail
        grid = found.image_order_px.reshape(4, 6, 2)
        boards = [truth] + ([other] if "2 boards" in found.detail else [])  # then the larger one is given
        error = min(np.abs(g - board.reshape(4, 6, 2)).max() for board in boards
                    for g in (grid, grid[::-1, ::-1], grid[::-1], grid[:, ::-1]))
        assert error < 0.15


def test_the_prediction_resolves_the_180_degree_turn(captures):
    pixels, _, truth, _, _ = captures[1]
    found = detect_board_vertices(pixels, truth + [6.0, -4.0])
    assert found.ok, found.detail
    assert np.abs(found.vertices_px - truth).max() < 0.5
    # The labelling follows the prediction: predicted turned by 180 degrees, the result turns with it.
    turned = detect_board_vertices(pixels, truth[::-1] + [6.0, -4.0])
    np.testing.assert_array_equal(turned.vertices_px, found.vertices_px[::-1])
    # order_like_prediction takes each labelling of a grid back to the prediction's order.
    grid = truth.reshape(4, 6, 2)
    for relabelled in (grid[::-1, ::-1], grid[::-1], grid[:, ::-1]):
        ordered, _ = order_like_prediction(relabelled.reshape(-1, 2), truth + 5.0)
        np.testing.assert_array_equal(ordered, truth)
    # A prediction that fits no labelling well is not trusted.
    ordered, detail = order_like_prediction(truth, np.roll(truth, 3, axis=0))
    assert ordered is None


def test_a_large_prediction_error_within_the_search_margin(captures):
    pixels, _, truth, _, _ = captures[2]
    found = detect_board_vertices(pixels, truth + [55.0, -35.0], search_margin_px=100.0)
    assert found.ok, found.detail
    assert np.abs(found.vertices_px - truth).max() < 0.5


def _turned(truth, angle_deg, scale, shift_squares):
    """The truth turned about its centre, scaled, and shifted by (along the rows, along the columns) squares."""
    centre, a = truth.mean(axis=0), np.radians(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) * scale
    grid = truth.reshape(4, 6, 2)
    along_row = np.median(np.diff(grid, axis=1).reshape(-1, 2), axis=0)
    along_column = np.median(np.diff(grid, axis=0).reshape(-1, 2), axis=0)
    return centre + (truth - centre) @ R.T + shift_squares[0] * along_row + shift_squares[1] * along_column


def test_a_prediction_turned_and_scaled_like_an_unseen_legs(captures):
    """Before the estimate has fitted a leg (or with an effect the model lacks), its prediction of that leg's
    board is turned in the image by 4-6 deg and scaled by a few per cent (mock seed 7 with backlash or elasticity):
    10-20 px at the board's far end, more than a shift alone can match. The board is still found, exactly, even
    half a square off; with a vertex partly hidden it is still refused."""
    for pixels, _, truth, visible, _ in captures:
        if not visible.all():
            continue
        for angle, scale, shift in ((5.0, 0.95, (0.0, 0.0)), (-6.0, 1.05, (0.3, 0.3)), (4.5, 0.96, (0.5, 0.0)),
                                    (-5.0, 0.95, (0.0, -0.5)), (6.0, 1.04, (-0.5, 0.5))):
            found = detect_board_vertices(pixels, _turned(truth, angle, scale, shift), search_margin_px=40.0)
            assert found.ok, (angle, scale, shift, found.reason, found.detail)
            assert np.abs(found.vertices_px - truth).max() < 0.5
    pixels, _, truth, _, _ = captures[5]
    hidden = pixels.copy()
    u, v = np.round(truth[9]).astype(int)
    hidden[v + 1:v + 12, u + 1:u + 12] = 120
    found = detect_board_vertices(hidden, _turned(truth, 5.0, 0.95, (0.3, 0.3)), search_margin_px=40.0)
    assert not found.ok and found.reason == "missing", found.detail


def test_both_boards_in_view_are_told_apart():
    for pixels, leg, truth, _, (other_truth, _) in _capture(2, seed=33, both=True):
        for expected in (truth, other_truth):
            found = detect_board_vertices(pixels, expected + 8.0)
            assert found.ok, found.detail
            assert np.abs(found.vertices_px - expected).max() < 0.5


@pytest.mark.parametrize("edge_px", [3.0, 1.0, -6.0, -30.0])
def test_a_board_reaching_out_of_the_image_is_cut_off(captures, edge_px):
    """The leftmost vertex moved to `edge_px` from the left image edge (negative: outside); at 10 px it is found."""
    pixels, _, truth, _, _ = captures[3]
    shift = int(np.floor(truth[:, 0].min() - edge_px))
    moved = np.full_like(pixels, 140)
    moved[:, : pixels.shape[1] - shift] = pixels[:, shift:]
    for offset in ([0.0, 0.0], [-25.0, 10.0], [25.0, -10.0]):
        found = detect_board_vertices(moved, truth - [shift, 0] + offset, search_margin_px=50.0)
        assert not found.ok and found.reason == "cut_off", (offset, found.reason, found.detail)
    shift = int(np.floor(truth[:, 0].min() - 10.0))
    moved = np.full_like(pixels, 140)
    moved[:, : pixels.shape[1] - shift] = pixels[:, shift:]
    found = detect_board_vertices(moved, truth - [shift, 0])
    assert found.ok and np.abs(found.vertices_px - (truth - [shift, 0])).max() < 0.5


def test_a_blurred_board_is_refused(captures):
    pixels, _, truth, _, _ = captures[4]
    blurred = cv2.GaussianBlur(pixels, (0, 0), 2.5)
    found = detect_board_vertices(blurred, truth)
    assert not found.ok and found.reason == "blurred", found.detail
    assert found.edge_width_px > 3.0
    assert detect_board_vertices(pixels, truth).edge_width_px < 2.5


def test_a_missing_or_partly_hidden_board_is_reported(captures):
    pixels, _, truth, _, _ = captures[5]
    blank = np.full_like(pixels, 140)
    found = detect_board_vertices(blank, truth)
    assert not found.ok and found.reason == "missing"
    hidden = pixels.copy()
    u, v = np.round(truth[9]).astype(int)
    hidden[v + 1:v + 12, u + 1:u + 12] = 120  # something covers part of a quadrant of vertex 9
    found = detect_board_vertices(hidden, truth)
    assert not found.ok and found.reason == "missing", found.detail
    assert set(REASONS) == {"missing", "cut_off", "blurred", "ambiguous"}


def test_bad_arguments():
    image = np.zeros((480, 640, 3), np.uint8)
    with pytest.raises(ValueError):
        detect_board_vertices(image, np.zeros((23, 2)))
    with pytest.raises(ValueError):
        detect_board_vertices(image, np.full((24, 2), np.nan))
    with pytest.raises(ValueError):
        detect_board_vertices(np.zeros((480, 640, 4), np.uint8))
    with pytest.raises(ValueError):
        detect_board_vertices(image, method="guided")


def test_a_prediction_far_outside_the_image_is_cut_off(captures):
    """A board predicted wholly outside the image, whose searched region's bounding box still reaches into it
    (it used to raise IndexError on the empty region), is `cut_off`."""
    pixels, _, truth, _, _ = captures[0]
    for scale, centre in ((1.0, [-300.0, 560.0]), (2.0, [-450.0, 700.0])):  # left of and below the 640 x 480 image
        predicted = (truth - truth.mean(axis=0)) * scale + centre
        found = detect_board_vertices(pixels, predicted, search_margin_px=120.0)
        assert not found.ok and found.reason == "cut_off", (found.reason, found.detail)
