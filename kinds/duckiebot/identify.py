"""A drive log to a Duckiebot's calibration (issue 23): read, detect, fit the camera's intrinsics, then the joint fit
(kinds.duckiebot.fit). `identify_log(LOG)` is what `naocal identify LOG --out CAL.json` will call once the CLI's
dispatch is redesigned (issue 22); it writes nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from naocal.kinds.duckiebot.calibration_files import DuckietownCalibration, duckietown_calibration
from naocal.kinds.duckiebot.detect import detect_boards, detect_markers_and_repeats, refinement_window_px
from naocal.kinds.duckiebot.drive_log import DriveLog, read_drive_log
from naocal.kinds.duckiebot.fit import (CORNER_WINDOW, LENS, PWM_DRIVER, Drive, DriveEquations, DriveFit, Sightings,
                                        fit_drive, secant_gain)
from naocal.kinds.duckiebot.intrinsics import FloorMarkers, LensCamera, LensFit, board_points, choose_lens
from naocal.kinds.duckiebot.robot import Kinematics, nominal_for
from naocal.solver.camera import CameraIntrinsics
from naocal.solver.errors import DataError, NaocalError, SolveError
from naocal.solver.fields import fail

# A marker corner's detection noise grows fast as the marker shrinks in the image: measured on a rendered log (seed
# 1, detected vs true corners, after their common inward bias) 0.04 px sd for sides of 30-100 px, 0.32 px at 20-30,
# 0.34 px at 15-20, 0.64 px below 15: about (UNIT_NOISE_SIDE_PX / side)^2 px, never below MIN_NOISE_PX.
UNIT_NOISE_SIDE_PX = 10.0
MIN_NOISE_PX = 0.15
SPEED_MPS = 0.3  # the speed the exported gain is the secant at (the validation drive; Duckietown's lanes)
HELD_OUT_GROUPS = 3  # board views split into this many runs of consecutive views, each held out in turn
MIN_BOARD_VIEWS = 6  # two per group at least, so that each fit without one group still has 4 views
# Boards are searched for in frames at least this far apart on the log's clock: a board search costs about 0.35 s
# CPU per 640 x 480 frame (kinds.duckiebot.detect), a camera streaming at 15-30 fps while the robot turns gives
# near-identical views 33-67 ms apart (0.35 rad/s: 0.7 deg), which add cost, not information, and whose errors are
# not independent as the lens fit's view clusters assume. The mission's logs (frames grabbed standing still, 0.5 s
# or more apart) are searched in full.
BOARD_SEARCH_INTERVAL_S = 0.25
# The detector's corners lie inside the true ones by about b0 + c / w px, w cornerSubPix's window half-width
# (detect.refinement_window_px: half a marker cell, 1-4 px), c depending on the image's blur, which a log does not
# state. The joint fit fits one constant shift (fit.BIAS, b0's) and keeps c at 0; c's effect is considered
# (add_corner_covariance) with this std: the root mean square about 0 of c fitted to the outward error by window
# (2-4 px, weighted by corners) in benchmarks/bench_duckiebot_corners.py's four blur / noise conditions (seeds 1-3,
# 40 poses each): -1.41 (blur 0.5 px, noise 1.5: the mock's), -1.63 (sharp), -1.66 (blur 0.5, no noise), -0.12
# (blur 1.0, noise 1.5). The fit's c = 0 is biased by their mean (-1.2), so the std covers the mean and the spread
# (sd 0.73) together: the considered covariance is then the estimate's mean squared error, not its variance.
CORNER_WINDOW_STD_PX2 = 1.36


@dataclass(frozen=True)
class Detections:
    """Per frame: the markers (kinds.duckiebot.detect.MarkerSighting) and boards (BoardSighting) found."""

    markers: list
    boards: list


def detect_log(log: DriveLog, *, boards: bool = True, searched: dict | None = None) -> Detections:
    """Markers in every frame and (unless `boards` is False: a drive with none, e.g. kinds.duckiebot.refine's lane
    pass) boards where search_boards looks; `searched`: {frame: its boards} of frames already searched
    (sample_boards'), not searched again."""
    markers = []
    for i in range(len(log.frame_files)):
        sightings, repeated = detect_markers_and_repeats(log.load_frame(i, cv2.IMREAD_GRAYSCALE), log.marker_family)
        if repeated:
            # the fit tells the floor's markers apart by id alone: markers sharing one would be one marker seen in
            # several places (detect_markers drops them, so a log of identical markers looked markerless)
            fail(log.frame_path(i), f"marker id {repeated[0]} is on several markers in this frame: naocal tells "
                 "the floor markers apart by their ids, which must differ")
        markers.append(sightings)
    found = search_boards(log, searched) if boards else {}
    return Detections(markers, [found.get(i, []) for i in range(len(log.frame_files))])


def search_boards(log: DriveLog, searched: dict | None = None) -> dict:
    """{frame: its boards} of the frames searched: the coarse sample first (sample_boards, or `searched`: its
    result), then every board_search_frames frame between a sampled frame that holds a board and the sampled frames
    either side of it. A search costs about 0.4 s CPU a frame, a marker's 0.02; on the realistic mock's missions
    (seeds 1-5, 8) this finds every board view the full search does (23-37 a log) in 44-59 frames of 100-133."""
    found = dict(searched) if searched is not None else sample_boards(log)
    candidates = np.flatnonzero(board_search_frames(log.frame_t_s))
    sampled = sorted(found)
    for k, frame in enumerate(sampled):
        if not found[frame]:
            continue
        low = sampled[k - 1] if k > 0 else -1
        high = sampled[k + 1] if k + 1 < len(sampled) else len(log.frame_files)
        for i in candidates[(candidates > low) & (candidates < high)]:
            if int(i) not in found:
                found[int(i)] = detect_boards(log.load_frame(int(i), cv2.IMREAD_GRAYSCALE), log.board_inner_corners,
                                              log.board_square_m)
    return found


def board_sample_frames(frame_t_s) -> np.ndarray:
    """A coarse first board search (bool per frame): of the frames board_search_frames picks, those its rule picks
    again at MIN_BOARD_VIEWS times the interval. At most MIN_BOARD_VIEWS - 1 searched frames lie between two sampled
    ones (searched frames are at least the interval apart), so any MIN_BOARD_VIEWS consecutive searched frames hold
    a sampled one: a log whose boards stay in view that long is found at about 1 / MIN_BOARD_VIEWS of the cost."""
    search = np.flatnonzero(board_search_frames(frame_t_s))
    chosen = np.zeros(len(frame_t_s), bool)
    chosen[search[board_search_frames(np.asarray(frame_t_s)[search],
                                      BOARD_SEARCH_INTERVAL_S * MIN_BOARD_VIEWS)]] = True
    return chosen


def sample_boards(log: DriveLog) -> dict:
    """{frame: its boards} of the board_sample_frames of `log` (detect_log's `searched`): whether a full board
    search can find anything, for a fraction of its cost."""
    return {int(i): detect_boards(log.load_frame(int(i), cv2.IMREAD_GRAYSCALE), log.board_inner_corners,
                                  log.board_square_m)
            for i in np.flatnonzero(board_sample_frames(log.frame_t_s))}


def board_search_frames(frame_t_s, interval_s: float = BOARD_SEARCH_INTERVAL_S) -> np.ndarray:
    """Which frames to search for boards (bool per frame): the first, then each at least `interval_s` after the last
    one searched."""
    chosen = np.zeros(len(frame_t_s), bool)
    last = -math.inf
    for i, t in enumerate(frame_t_s):
        if t - last >= interval_s:
            chosen[i], last = True, t
    return chosen


def fit_intrinsics(log: DriveLog, detections: Detections) -> tuple[LensFit, dict]:
    """(chosen LensFit, {model: LensFit}) from every board view and the floor markers seen (the image's lower half:
    kinds.duckiebot.intrinsics.FloorMarkers), the lens model by held-out error (choose_lens). A board seen is not
    told from the others (they are identical), so the held-out groups are runs of consecutive views: the robot turns
    in steps, so a run is one stretch of the turn."""
    obj = board_points(log.board_inner_corners, log.board_square_m)
    views = [sighting.corners_px.reshape(-1, 2) for boards in detections.boards for sighting in boards]
    if len(views) < MIN_BOARD_VIEWS:
        raise NaocalError(f"{log.path}: {len(views)} board views found, at least {MIN_BOARD_VIEWS} are needed to "
                          "fit the camera's intrinsics")
    groups = np.arange(len(views)) * HELD_OUT_GROUPS // len(views)
    nominal = nominal_for(log.model)
    prior = nominal.camera
    K_guess = [[prior.fx_px, 0.0, prior.cx_px], [0.0, prior.fy_px, prior.cy_px], [0.0, 0.0, 1.0]]
    floor = FloorMarkers(marker_sightings(detections), log.marker_size_m, nominal.T_base_camera).usable()
    return choose_lens([obj] * len(views), views, (log.width_px, log.height_px), groups, K_guess=K_guess,
                       floor=floor)


def marker_sightings(detections: Detections) -> Sightings:
    """Every detected marker corner (raw pixels) with its expected noise from the marker's smallest side in the
    image ((UNIT_NOISE_SIDE_PX / side)^2 px, at least MIN_NOISE_PX)."""
    frame, marker, corner, uv, noise = [], [], [], [], []
    for f, sightings in enumerate(detections.markers):
        for s in sightings:
            frame += [f] * 4
            marker += [s.id] * 4
            corner += [0, 1, 2, 3]
            uv.append(s.corners_px)
            side = np.linalg.norm(np.roll(s.corners_px, -1, axis=0) - s.corners_px, axis=1).min()
            noise += [max(MIN_NOISE_PX, (UNIT_NOISE_SIDE_PX / max(side, 1.0)) ** 2)] * 4
    if not uv:
        return Sightings(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), np.zeros(0))
    return Sightings(np.array(frame), np.array(marker), np.array(corner), np.concatenate(uv).astype(float),
                     np.array(noise))


def rectified_sightings(detections: Detections, camera: LensCamera) -> Sightings:
    """Every detected marker corner, undistorted with `camera` and re-projected with its K (rectified pixels), with
    its expected noise (marker_sightings)."""
    return rectify(marker_sightings(detections), camera)


def rectify(raw: Sightings, camera: LensCamera) -> Sightings:
    """Raw corners (marker_sightings') undistorted with `camera` and re-projected with its K, their noise kept."""
    if not len(raw.frame):
        return Sightings(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)))
    normalised = camera.normalised(raw.uv_px)
    K = camera.K
    rect = np.column_stack([K[0, 0] * normalised[:, 0] + K[0, 1] * normalised[:, 1] + K[0, 2],
                            K[1, 1] * normalised[:, 1] + K[1, 2]])
    return Sightings(raw.frame, raw.marker, raw.corner, rect, raw.noise_px)


def considered_effect(fit: DriveFit, drive: Drive, marker_size_m: float, observed, p0, steps) -> np.ndarray:
    """S (free parameters x nuisances) = d x_hat / d p: how far the joint fit's estimate moves per unit of a nuisance
    p the fit takes as known at p0 (Schmidt's "consider" parameters). `observed(p)`: (every corner as rectified
    Sightings, the camera matrix K) were the nuisance p. One Gauss-Newton step from the solution per nuisance, each
    moved by its `steps` entry: the fit's gradient at x_hat is 0 with p0, so the step is the refit's first-order
    response to the nuisance."""
    keys = {(f, m, c): i for i, (f, m, c) in enumerate(zip(fit.sightings.frame, fit.sightings.marker,
                                                           fit.sightings.corner))}

    def step_of(p):
        everything, K = observed(p)
        rows = np.full(len(keys), -1)
        for i, key in enumerate(zip(everything.frame, everything.marker, everything.corner)):
            if key in keys:
                rows[keys[key]] = i
        equations = DriveEquations(drive, everything.subset(rows), K, marker_size_m, fit.reference_marker, fit.names,
                                   fit.x, fit.free)
        normal = equations(fit.x[equations.index])
        return normal.A, normal.g, equations.scales

    p0 = np.asarray(p0, dtype=float)
    A, g0, scales = step_of(p0)
    S = np.zeros((int(fit.free.sum()), len(p0)))
    for j, h in enumerate(steps):
        p = p0.copy()
        p[j] += h
        _, g, _ = step_of(p)
        S[:, j] = -np.linalg.solve(A, g - g0) * scales / h
    return S


def add_considered(fit: DriveFit, nuisance: str, S: np.ndarray, covariance) -> None:
    """Add a considered nuisance's S cov S^T (considered_effect's S) to the joint fit's covariance and stds (in
    place); fit.considered[nuisance]: the std it alone adds to each parameter (names' order), so the statistical
    part stays known (DriveFit.std_parts)."""
    if fit.covariance is None:
        return
    added = S @ np.atleast_2d(covariance) @ S.T
    fit.covariance[np.ix_(fit.free, fit.free)] += added
    fit.std[fit.free] = np.sqrt(np.clip(np.diag(fit.covariance)[fit.free], 0.0, None))
    part = np.zeros(len(fit.x))
    part[fit.free] = np.sqrt(np.clip(np.diag(added), 0.0, None))
    fit.considered[nuisance] = part


def add_lens_covariance(fit: DriveFit, drive: Drive, detections: Detections, lens: LensFit,
                        marker_size_m: float) -> None:
    """Carry the lens's uncertainty into the joint fit's covariance and stds (in place): the joint fit takes the
    intrinsics as known, but they are estimated (lens.covariance, clustered by board view, independent of the
    drive), and every rectified corner moves with them: considered_effect of the lens's parameters (each moved by a
    small step), S cov(lens) S^T added. Without it the stds left the realistic mock's gain 3-26 stds off (seeds
    1-5)."""
    if lens.covariance is None or fit.covariance is None:
        return
    raw = marker_sightings(detections)
    model = type(lens.camera)

    def observed(p):
        camera = model.of_parameters(lens.camera.model, p)
        return rectify(raw, camera), camera.K

    p0 = lens.camera.parameters
    S = considered_effect(fit, drive, marker_size_m, observed, p0, 1e-4 * np.maximum(np.abs(p0), 1e-2))
    add_considered(fit, LENS, S, lens.covariance)


def corner_window_shifts(detections: Detections) -> np.ndarray:
    """(N, 2), marker_sightings' rows: each corner's outward unit diagonal (from its quad's centre) over its
    cornerSubPix window half-width (detect.refinement_window_px): the corner's move per px^2 of CORNER_WINDOW."""
    shifts = []
    for sightings in detections.markers:
        for s in sightings:
            out = s.corners_px - s.corners_px.mean(axis=0)
            shifts.append(out / np.linalg.norm(out, axis=1)[:, None] / refinement_window_px(s.corners_px))
    return np.concatenate(shifts) if shifts else np.zeros((0, 2))


def add_corner_covariance(fit: DriveFit, drive: Drive, detections: Detections, camera: LensCamera,
                          marker_size_m: float, std_px2: float = CORNER_WINDOW_STD_PX2) -> None:
    """Carry the detector's size-dependent corner error into the joint fit's covariance and stds (in place), as a
    considered nuisance (considered_effect): every raw corner moved outward along its diagonal by c / w (w its
    cornerSubPix window half-width), c kept at 0 by the fit (its one corner_bias_px takes a constant shift), of std
    `std_px2` (CORNER_WINDOW_STD_PX2). An error shared by every frame of a log: no cluster-robust std sees it."""
    if fit.covariance is None:
        return
    raw = marker_sightings(detections)
    shifts = corner_window_shifts(detections)

    def observed(p):
        return rectify(replace(raw, uv_px=raw.uv_px + p[0] * shifts), camera), camera.K

    S = considered_effect(fit, drive, marker_size_m, observed, np.zeros(1), np.array([std_px2]))
    add_considered(fit, CORNER_WINDOW, S, np.array([[std_px2 ** 2]]))


@dataclass
class DuckiebotCalibration:
    """A Duckiebot calibrated from a drive log: kinematics (Duckietown's parameters, k and radius the log's), the
    camera (the chosen lens; its plumb_bob fit for Duckietown's files), the camera's pose on the body, the floor
    markers, with the joint fit's stds: cluster-robust, the considered model errors carried in (drive_fit.std_parts():
    the lens's, the detector's corner error's; the lens's own stds: `lens.std`, clusters the board views)."""

    robot_id: str
    kinematics: Kinematics
    lens: LensFit  # chosen by held-out error
    lens_fits: dict  # {model: LensFit}
    drive_fit: DriveFit

    @property
    def T_base_camera(self) -> np.ndarray:
        return self.drive_fit.T_base_camera

    def plumb_bob_camera(self, width_px: int, height_px: int) -> CameraIntrinsics:
        """The camera as Duckietown's camera_intrinsic file holds it (plumb_bob only)."""
        fit = self.lens_fits["plumb_bob"].camera
        K = fit.K
        return CameraIntrinsics(width_px, height_px, K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                                tuple(float(d) for d in fit.distortion[:5]))

    def duckietown(self, width_px: int = 640, height_px: int = 480,
                   calibration_time: str = "") -> DuckietownCalibration:
        """Duckietown's three files' content (kinds.duckiebot.calibration_files.write_calibration writes them): the
        homography follows from the fitted camera pose and the plumb_bob camera's K."""
        return duckietown_calibration(self.robot_id, self.kinematics, self.plumb_bob_camera(width_px, height_px),
                                      self.T_base_camera, calibration_time)

    def to_dict(self) -> dict:
        fit = self.drive_fit
        return {"robot": self.robot_id,
                "kinematics": {"gain": self.kinematics.gain, "trim": self.kinematics.trim,
                               "baseline_m": self.kinematics.baseline_m, "k": self.kinematics.k,
                               "radius_m": self.kinematics.radius_m, "limit": self.kinematics.limit},
                "lens": {"model": self.lens.camera.model, "K": self.lens.camera.K.tolist(),
                         "distortion": self.lens.camera.distortion.tolist(),
                         "std": dict(zip(self.lens.names, self.lens.std.tolist())),
                         "whole_image_std_px": self.lens.whole_image_std_px,
                         "held_out_rms_px": {m: f.held_out_rms_px for m, f in self.lens_fits.items()}},
                "T_base_camera": self.T_base_camera.tolist(),
                "parameters": fit.parameters_dict(), "reference_marker": fit.reference_marker,
                "rms_px": fit.rms_px, "corners": int(len(fit.sightings.frame)),
                "outliers": int(len(fit.outliers.frame)), "warnings": list(fit.warnings)}


def calibrate(log: DriveLog, detections: Detections, lens: LensFit, lens_fits: dict, *, speed_mps: float = SPEED_MPS,
              **fit_options):
    """The joint fit of a log's detections through a fitted lens, as a DuckiebotCalibration (fit_options: fit_drive's;
    effects with fit.PWM_DRIVER: the log's duties went through Duckietown's wheel driver). The kinematics' gain is
    the secant at `speed_mps` (fit.secant_gain: the fitted dead zone and the driver's PWM floor folded in, what Duckietown's
    inverse kinematics needs to drive that fast); the trim is the fit's."""
    sightings = rectified_sightings(detections, lens.camera)
    drive = Drive.of_log(log, pwm_driver=PWM_DRIVER in fit_options.get("effects", ()))
    drive_fit = fit_drive(drive, sightings, lens.camera.K, log.marker_size_m,
                          nominal_for(log.model).T_base_camera, **fit_options)
    add_lens_covariance(drive_fit, drive, detections, lens, log.marker_size_m)
    add_corner_covariance(drive_fit, drive, detections, lens.camera, log.marker_size_m)
    gain, _ = secant_gain(drive, drive_fit, speed_mps)
    try:
        kin = Kinematics(baseline_m=drive_fit.value("baseline_m"), radius_m=log.wheels.radius_m,
                         gain=gain, trim=drive_fit.value("trim"), k=log.wheels.k, limit=log.wheels.limit)
    except DataError as err:  # the fit's values, not the log's: a fit gone astray (exit 3), not a bad input (2)
        raise SolveError(f"the joint fit of {log.path} ended at impossible kinematics ({err.field} {err.problem}): nothing "
                         "calibrated") from None
    return DuckiebotCalibration(log.robot_id, kin, lens, lens_fits, drive_fit)


def identify_log(log_dir, **fit_options) -> DuckiebotCalibration:
    """Read the drive log at `log_dir`, detect markers and boards in every frame, fit the intrinsics (lens model by
    held-out error), then the joint fit. DataError for a bad log, NaocalError / SolveError when the data cannot
    calibrate (too few board views, no marker seen, something undetermined)."""
    log = read_drive_log(log_dir)
    detections = detect_log(log)
    lens, fits = fit_intrinsics(log, detections)
    return calibrate(log, detections, lens, fits, **fit_options)
