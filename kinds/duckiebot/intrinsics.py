"""The camera's intrinsics from chessboard views by naocal's own LM, the lens model chosen by held-out reprojection
error.

Lens models (LENS_PARAMETERS): `plumb_bob` (OpenCV's k1, k2, p1, p2 with k3 = 0: what Duckietown's files hold, and
what ROS's camera calibrator fits by default; every real robot's file has k3 = 0), `rational` (k1..k6, p1, p2:
OpenCV's rational model), `fisheye` (Kannala-Brandt k1..k4). Each is fitted by `solver.identify.solve` (the core's
one path) on `LensEquations`: the board corners' residuals with their exact Jacobian (OpenCV's projectPoints
derivatives), one 6-DoF pose per view, with cluster-robust stds (cluster: a view: its corners share its pose's and
its detection's errors). OpenCV's calibrateCamera / fisheye.calibrate only give the start values.

Why k3 is not fitted in plumb_bob: the set-up's boards stand at the camera's height while the camera looks 19 deg
down, so every board view lies in the image's upper 40 % (rendered logs, seeds 1-5: v < 192 px); a fifth radial
term then bends the lower corners freely (seed 5: 0.53 px off over the whole image with k3, 0.18 without). The
lower half is seen through the floor markers (FloorMarkers: fitted with the boards when given).

A low training reprojection error proves nothing (the reference: 0.07-0.09 px while the camera is 5-12 px wrong over
the whole image), so each model is judged on views it was not fitted to: views are split into groups, each group
held out in turn, the camera fitted to the others, and each held-out view's pose found by PnP with that camera.
`choose_lens` takes the simplest model not significantly worse than the best (a paired test over the held-out
views): on seed 1 rational's held-out RMS was 0.1 % below plumb_bob's, noise, and it was 0.84 px off over the whole
image against plumb_bob's 0.58. `camera_difference_px` compares two cameras over the whole image;
`LensFit.whole_image_std_px` is the std of that difference from the fit's covariance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from naocal.kinds.duckiebot.fit import (BIAS, Sightings, camera_transform, chain_floor, marker_offsets,
                                       marker_on_floor, pose_parameters)
from naocal.solver.errors import NaocalError
from naocal.solver.identify import (MAD_TO_SIGMA, OUTLIER_SCALES, Normal, check_identifiable, last_pass_cached, solve,
                                    trimmed)
from naocal.solver.transforms import d_rot_x, d_rot_y, rot_rpy, rot_x, rot_y

LENS_MODELS = ("plumb_bob", "rational", "fisheye")
INTRINSIC_NAMES = ("fx_px", "fy_px", "cx_px", "cy_px")
# The fitted distortion coefficients of each model, in OpenCV's order (LensCamera.distortion holds OpenCV's full
# vector: plumb_bob's k3 = 0 after p2).
LENS_PARAMETERS = {"plumb_bob": ("k1", "k2", "p1", "p2"),
                   "rational": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
                   "fisheye": ("k1", "k2", "k3", "k4")}
_OPENCV_LENGTH = {"plumb_bob": 5, "rational": 8, "fisheye": 4}
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
# LM's variable scales (about the prior uncertainty of each): px, distortion, rad, m
_SCALES = {"px": 5.0, "distortion": 0.01, "rotation": 0.05, "translation": 0.02}
MAX_ITERATIONS = 100
# choose_lens: a model is better than a simpler one only if its held-out views' mean squared errors are lower, by the
# mean log ratio over the views, by more than this many standard errors
CHOICE_SE = 2.0
# choose_lens: a model whose whole-image std (LensFit.whole_image_std_px) is more than this many times the best
# determined model's is left out of the choice (its extra terms extrapolate where no view was)
MAX_WHOLE_IMAGE_STD_RATIO = 10.0


@dataclass(frozen=True)
class LensCamera:
    """A fitted camera: lens model, K (3, 3), distortion coefficients in OpenCV's order for the model."""

    model: str
    K: np.ndarray
    distortion: np.ndarray

    @classmethod
    def from_intrinsics(cls, camera) -> "LensCamera":
        """A naocal camera (solver.camera.CameraIntrinsics: OpenCV's pixel convention and plumb_bob)."""
        K = np.array([[camera.fx_px, 0.0, camera.cx_px], [0.0, camera.fy_px, camera.cy_px], [0.0, 0.0, 1.0]])
        return cls("plumb_bob", K, np.asarray(camera.distortion, dtype=float))

    @property
    def parameters(self) -> np.ndarray:
        """The fitted values, in the order of `parameter_names(model)`."""
        K = self.K
        return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
                               self.distortion[:len(LENS_PARAMETERS[self.model])]])

    @classmethod
    def of_parameters(cls, model: str, p) -> "LensCamera":
        p = np.asarray(p, dtype=float)
        K = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
        distortion = np.zeros(_OPENCV_LENGTH[model])
        distortion[:len(p) - 4] = p[4:]
        return cls(model, K, distortion)

    def project(self, object_points, rvec, tvec) -> np.ndarray:
        """(n, 2) pixels of board points (n, 3) at pose (rvec, tvec) (OpenCV's camera frame)."""
        return self.project_with_jacobian(object_points, rvec, tvec, jacobian=False)[0]

    def project_with_jacobian(self, object_points, rvec, tvec, jacobian: bool = True):
        """((n, 2) pixels, d pixels / d parameters (n, 2, 4 + distortion) or None, d pixels / d (rvec, tvec)
        (n, 2, 6) or None): OpenCV's exact derivatives."""
        obj = np.asarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
        rvec, tvec = np.asarray(rvec, np.float64).reshape(3), np.asarray(tvec, np.float64).reshape(3)
        n, q = len(obj), 4 + len(LENS_PARAMETERS[self.model])
        if self.model == "fisheye":
            uv, J = cv2.fisheye.projectPoints(obj.reshape(1, -1, 3), rvec, tvec, self.K, self.distortion)
            uv = uv.reshape(-1, 2)
            if not jacobian:
                return uv, None, None
            J = J.reshape(n, 2, 15)  # f (2), c (2), k (4), rvec, tvec, skew
            return uv, J[:, :, :8], J[:, :, 8:14]
        uv, J = cv2.projectPoints(obj, rvec, tvec, self.K, self.distortion)
        uv = uv.reshape(-1, 2)
        if not jacobian:
            return uv, None, None
        J = J.reshape(n, 2, -1)  # rvec, tvec, f (2), c (2), distortion
        return uv, J[:, :, 6:6 + q], J[:, :, :6]

    def normalised(self, uv_px) -> np.ndarray:
        """(n, 2) undistorted normalised coordinates (x right, y down) of pixels."""
        uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
        if self.model == "fisheye":
            out = cv2.fisheye.undistortPoints(uv, self.K, self.distortion)
        else:
            out = cv2.undistortPoints(uv, self.K, self.distortion, None, None, criteria=_CRITERIA)
        return out.reshape(-1, 2)

    def pose(self, object_points, image_points):
        """(rvec, tvec) of a board view with this camera (PnP on undistorted points)."""
        ok, rvec, tvec = cv2.solvePnP(np.asarray(object_points, np.float64), self.normalised(image_points),
                                      np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise NaocalError("a board view's pose cannot be found")
        return rvec, tvec


def parameter_names(model: str) -> tuple:
    return INTRINSIC_NAMES + LENS_PARAMETERS[model]


@dataclass(frozen=True)
class LensFit:
    camera: LensCamera
    train_rms_px: float  # all views, fitted to all: RMS per corner (the 2-D distance), as OpenCV's
    held_out_rms_px: float  # each group held out in turn (RMS over both coordinates)
    n_views: int
    std: np.ndarray = field(default=None, repr=False)  # cluster-robust (cluster: a view), parameter_names order
    covariance: np.ndarray = field(default=None, repr=False)  # of camera.parameters
    whole_image_std_px: float = float("nan")  # std of camera_difference_px against the truth, from `covariance`
    held_out_view_ms_px2: np.ndarray = field(default=None, repr=False)  # each held-out view's mean squared error

    @property
    def names(self) -> tuple:
        return parameter_names(self.camera.model)

    def stdev(self, name: str) -> float:
        return float(self.std[self.names.index(name)])


def board_points(inner_corners: tuple[int, int], square_m: float) -> np.ndarray:
    """(rows * columns, 3) inner corners of a board in its plane, in image order (row-major, rows of columns)."""
    columns, rows = inner_corners
    r, c = np.mgrid[0:rows, 0:columns]
    return np.column_stack([c.ravel() * square_m, r.ravel() * square_m, np.zeros(r.size)])


def opencv_start(object_points, image_points, size, model: str, K_guess=None):
    """(camera, rvecs, tvecs): OpenCV's calibration of `model`, the LM's start values."""
    w, h = size
    K0 = np.array(K_guess if K_guess is not None else [[w / 2, 0, w / 2], [0, w / 2, h / 2], [0, 0, 1]], float)
    if model == "fisheye":
        obj = [np.asarray(o, np.float64).reshape(1, -1, 3) for o in object_points]  # (n, 1, 3): refused in 5.0
        img = [np.asarray(i, np.float64).reshape(1, -1, 2) for i in image_points]
        # OpenCV 5 keeps the fisheye flags in cv2 itself; 4.x (Python 3.8's) in cv2.fisheye, with their own values
        ns = cv2.fisheye if hasattr(cv2.fisheye, "CALIB_FIX_SKEW") else cv2
        flags = ns.CALIB_RECOMPUTE_EXTRINSIC | ns.CALIB_FIX_SKEW | ns.CALIB_USE_INTRINSIC_GUESS
        _, K, D, rvecs, tvecs = cv2.fisheye.calibrate(obj, img, (w, h), K0.copy(), np.zeros(4), flags=flags,
                                                      criteria=_CRITERIA)
    else:
        obj = [np.asarray(o, np.float32) for o in object_points]
        img = [np.asarray(i, np.float32) for i in image_points]
        flags = cv2.CALIB_USE_INTRINSIC_GUESS | (cv2.CALIB_RATIONAL_MODEL if model == "rational" else
                                                 cv2.CALIB_FIX_K3)
        _, K, D, rvecs, tvecs = cv2.calibrateCamera(obj, img, (w, h), K0.copy(), None, flags=flags,
                                                    criteria=_CRITERIA)
    n = len(LENS_PARAMETERS[model])
    camera = LensCamera.of_parameters(model, np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
                                                              np.asarray(D, float).ravel()[:n]]))
    return camera, [np.ravel(r) for r in rvecs], [np.ravel(t) for t in tvecs]


# ------------------------------------------------------------------------------------------------ the floor markers

# The floor markers as lens observations: the boards are seen only in the image's upper 40 % (they stand at the
# camera's height while it looks 19 deg down), the markers lie on the floor, in its lower half. Each marker alone is
# a weak view (4 corners, 6 pose unknowns), so they are fitted as what they are: all on one floor, each at one pose
# (x, y, yaw) shared by every frame that sees it, the camera at one height and attitude over the floor in every frame
# (the robot stands on it: frames are grabbed at rest), each frame a planar pose (x, y, theta). The detector's
# corners lie inside the true ones (kinds.duckiebot.fit's BIAS, fitted here as there: one bias along each marker's
# image diagonal); a marker whose smallest side is under FLOOR_MIN_SIDE_PX is left out: the bias is about constant for
# sides of 30-100 px (0.20 px) and grows below (0.36-0.41 at 15-30, 0.70 under 15); with sides down to 20 px the one
# fitted bias came out -0.83 px and the lens 2.0 px off over the image (mock seed 5; 0.15 px with 30).
FLOOR_MIN_SIDE_PX = 30.0
FLOOR_MOUNT = ("floor.camera.z_m", "floor.camera.roll_rad", "floor.camera.pitch_rad")
FLOOR_BIAS = "floor." + BIAS
_FLOOR_SCALES = {"mount": (0.005, 0.02, 0.03), "frame": (0.05, 0.05, 0.05), "marker": (0.05, 0.05, 0.05),
                 "bias": 0.1}
# naocal's camera frame (x along the optical axis, y left, z up) to OpenCV's (x right, y down, z along the axis)
_NAOCAL_TO_OPENCV = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
# The floor block's board noise: the rows' residuals are divided by their expected noise, the boards' by this (their
# corners are 0.031-0.039 px RMS from the truth on rendered logs), the markers' by identify's noise model
BOARD_NOISE_PX = 0.04


@dataclass(frozen=True)
class FloorMarkers:
    """Detected floor-marker corners for the lens fit: kinds.duckiebot.fit.Sightings of RAW (distorted) pixels, the
    markers' side (m) and a camera pose on the body to start from (T_base_camera: its height, roll and pitch)."""

    sightings: Sightings
    size_m: float
    T_base_camera_start: np.ndarray

    def usable(self) -> "FloorMarkers":
        """The sightings whose marker is large enough (FLOOR_MIN_SIDE_PX), seen in two frames or more, in the
        largest group of frames and markers tied to each other."""
        s = self.sightings
        keep = np.zeros(len(s.frame), bool)
        for f, m in set(zip(s.frame.tolist(), s.marker.tolist())):
            rows = np.flatnonzero((s.frame == f) & (s.marker == m))
            if len(rows) == 4 and _smallest_side(s.uv_px[rows[np.argsort(s.corner[rows])]]) >= FLOOR_MIN_SIDE_PX:
                keep[rows] = True
        s = s.subset(np.flatnonzero(keep))
        pairs = set(zip(s.frame.tolist(), s.marker.tolist()))
        seen = np.bincount([m for _, m in pairs], minlength=int(s.marker.max(initial=0)) + 1)
        s = s.subset(np.flatnonzero(seen[s.marker] >= 2))  # a marker seen once fixes nothing of the lens
        # one floor: the frames and markers linked (a frame seeing a marker) to the most corners; another group's
        # poses could not be tied to it
        group = {}

        def root(node):
            while group.get(node, node) != node:
                node = group[node]
            return node
        for f, m in zip(s.frame.tolist(), s.marker.tolist()):
            a, b = root(("frame", f)), root(("marker", m))
            if a != b:
                group[a] = b
        roots = [root(("marker", m)) for m in s.marker.tolist()]
        if roots:  # the most corners; ties: the group of the smallest marker id (a function of the data alone)
            size = {r: (roots.count(r), -min(m for m, q in zip(s.marker.tolist(), roots) if q == r)) for r in roots}
            largest = max(size, key=size.get)
            s = s.subset(np.flatnonzero([r == largest for r in roots]))
        return FloorMarkers(s, self.size_m, self.T_base_camera_start)


def _smallest_side(corners_px) -> float:
    return float(np.linalg.norm(np.roll(corners_px, -1, axis=0) - corners_px, axis=1).min())


class FloorBlock:
    """The floor markers' part of LensEquations: parameters (after the lens's and the boards' poses) the camera's
    height, roll and pitch over the floor, each frame's planar pose, each marker's but the reference's (the gauge:
    the floor's frame) pose, the corner bias; residuals (predicted - detected) / the corner's expected noise."""

    def __init__(self, floor: FloorMarkers, first_column: int, reference: int | None = None):
        s = floor.sightings
        self.obs, self.size_m, self.T_start = s, floor.size_m, np.asarray(floor.T_base_camera_start, dtype=float)
        self.offsets = marker_offsets(floor.size_m)[s.corner]
        self.frames = np.unique(s.frame)
        self.row_frame = np.searchsorted(self.frames, s.frame)
        counts = {m: len(set(s.frame[s.marker == m].tolist())) for m in np.unique(s.marker).tolist()}
        # the gauge: the marker seen in the most frames (ties: smallest id), unless given (another block's)
        self.reference = min(counts, key=lambda m: (-counts[m], m)) if reference is None else reference
        self.markers = [m for m in sorted(counts) if m != self.reference]
        self.names = list(FLOOR_MOUNT) + [f"floor.frame{f}.{a}" for f in self.frames.tolist()
                                          for a in ("x_m", "y_m", "theta_rad")]
        self.names += [f"floor.marker{m}.{a}" for m in self.markers for a in ("x_m", "y_m", "yaw_rad")] + [FLOOR_BIAS]
        self.scales = np.array(list(_FLOOR_SCALES["mount"]) + list(_FLOOR_SCALES["frame"]) * len(self.frames) +
                               list(_FLOOR_SCALES["marker"]) * len(self.markers) + [_FLOOR_SCALES["bias"]])
        c0 = first_column
        self.mount_cols = c0 + np.arange(3)
        self.frame_cols = c0 + 3 + 3 * self.row_frame[:, None] + np.arange(3)  # (N, 3)
        marker_index = {m: i for i, m in enumerate(self.markers)}
        at = c0 + 3 + 3 * len(self.frames)
        self.marker_cols = np.array([[-1] * 3 if m == self.reference else at + 3 * marker_index[m] + np.arange(3)
                                     for m in s.marker.tolist()]).reshape(-1, 3)
        self.bias_col = c0 + len(self.names) - 1
        self.weight = BOARD_NOISE_PX / s.sigma_px  # in the boards' units: their rows are in px
        self.cluster_rows = [np.flatnonzero(self.row_frame == i) for i in range(len(self.frames))]

    def _points(self, x, o):
        """(OpenCV camera-frame points (N, 3), d points / d x (N, 3, P)) of the offsets o (N, 2) in each row's
        marker frame."""
        N, P = len(o), len(x)
        others = self.marker_cols[:, 0] >= 0
        m = np.zeros((N, 3))
        m[others] = x[self.marker_cols[others]]
        cy, sy = np.cos(m[:, 2]), np.sin(m[:, 2])
        world = m[:, :2] + np.stack([cy * o[:, 0] - sy * o[:, 1], sy * o[:, 0] + cy * o[:, 1]], axis=1)
        pose = x[self.frame_cols]
        ct, st = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        rel = world - pose[:, :2]
        base = np.stack([ct * rel[:, 0] + st * rel[:, 1], -st * rel[:, 0] + ct * rel[:, 1], np.zeros(N)], axis=1)
        h, roll, pitch = x[self.mount_cols]
        R = rot_rpy(roll, pitch, 0.0)
        d = base - np.array([0.0, 0.0, h])
        points = (d @ R) @ _NAOCAL_TO_OPENCV.T  # R^T d per row, then OpenCV's axes
        J = np.zeros((N, 3, P))
        CRt = _NAOCAL_TO_OPENCV @ R.T  # d points / d base
        J[:, :, self.mount_cols[0]] = -CRt[:, 2]
        for col, D in ((self.mount_cols[1], rot_y(pitch) @ d_rot_x(roll)),
                       (self.mount_cols[2], d_rot_y(pitch) @ rot_x(roll))):
            J[:, :, col] = (d @ D) @ _NAOCAL_TO_OPENCV.T
        B = CRt[:, :2]  # d points / d base xy (3, 2)
        RT = np.stack([np.stack([ct, st], -1), np.stack([-st, ct], -1)], axis=1)  # (N, 2, 2): R(theta)^T
        dRT = np.stack([np.stack([-st, ct], -1), np.stack([-ct, -st], -1)], axis=1)
        rows = np.arange(N)
        d_frame = np.concatenate([-RT, np.einsum("nij,nj->ni", dRT, rel)[:, :, None]], axis=2)  # d base xy / d pose
        J[rows[:, None], :, self.frame_cols] = np.einsum("ij,njk->nki", B, d_frame)
        BR = np.einsum("ij,njk->nik", B, RT)  # d points / d world xy (N, 3, 2)
        d_world_d_yaw = np.stack([-sy * o[:, 0] - cy * o[:, 1], cy * o[:, 0] - sy * o[:, 1]], axis=1)
        r = np.flatnonzero(others)
        J[r, :, self.marker_cols[r, 0]] = BR[r, :, 0]
        J[r, :, self.marker_cols[r, 1]] = BR[r, :, 1]
        J[r, :, self.marker_cols[r, 2]] = np.einsum("nij,nj->ni", BR[r], d_world_d_yaw[r])
        return points, J

    def predict(self, camera: "LensCamera", x, q: int, jacobian: bool = True):
        """(pixels (N, 2), d pixels / d x (N, 2, P) or None): each corner's projection moved outward along its
        marker's image diagonal by the bias (as kinds.duckiebot.fit.DriveEquations.predict)."""
        N = len(self.obs.frame)
        corners, d_corners = self._points(x, self.offsets)
        centres, d_centres = self._points(x, np.zeros((N, 2)))
        both, dboth = np.concatenate([corners, centres]), np.concatenate([d_corners, d_centres])
        uv, J_lens, J_pose = camera.project_with_jacobian(both, np.zeros(3), np.zeros(3), jacobian)
        corner_uv, centre_uv = uv[:N], uv[N:]
        d = corner_uv - centre_uv
        L = np.linalg.norm(d, axis=1)
        b = x[self.bias_col]
        out = corner_uv + b * d / L[:, None]
        if not jacobian:
            return out, None
        Jall = np.einsum("nij,njp->nip", J_pose[:, :, 3:6], dboth)  # at the identity pose, d/d tvec = d/d point
        Jall[:, :, :q] += J_lens
        corner_J, centre_J = Jall[:N], Jall[N:]
        M = np.eye(2)[None] / L[:, None, None] - d[:, :, None] * d[:, None, :] / (L ** 3)[:, None, None]
        J = corner_J + b * M @ (corner_J - centre_J)
        J[:, :, self.bias_col] = d / L[:, None]
        return out, J

    def start(self, camera: "LensCamera") -> np.ndarray:
        """Start values: the mount's height, roll and pitch as given; each marker's pose in a frame from its corners'
        floor points (kinds.duckiebot.fit.marker_on_floor) under the camera's footprint, chained from the reference
        marker through the frames (breadth first); bias 0."""
        s = self.obs
        z, roll, pitch = pose_parameters(self.T_start)[[2, 3, 4]]
        footprint = camera_transform([0.0, 0.0, z, roll, pitch, 0.0])
        rect = camera.normalised(s.uv_px) @ camera.K[:2, :2].T + camera.K[:2, 2]
        local = {}
        for f, m in set(zip(s.frame.tolist(), s.marker.tolist())):
            rows = np.flatnonzero((s.frame == f) & (s.marker == m))
            local[f, m] = marker_on_floor(rect[rows], s.corner[rows], camera.K, footprint, self.size_m)
        frames, markers = chain_floor(local, self.reference)
        if len(frames) < len(self.frames) or len(markers) < len(self.markers) + 1:
            raise NaocalError("the floor markers do not chain into one floor")
        return np.concatenate([[z, roll, pitch], *[frames[f] for f in self.frames.tolist()],
                               *[markers[m] for m in self.markers], [0.0]])


class LensEquations:
    """The intrinsics' normal equations for solver.identify.solve (as kinds.duckiebot.fit.DriveEquations are the
    joint fit's): unknowns the lens's `parameter_names(model)`, then each view's pose (`view<i>.rx .ry .rz`: OpenCV's
    rotation vector, `.tx_m .ty_m .tz_m`); residuals (projected - detected) px, one row per corner; each view's
    score for the cluster-robust covariance (its cluster: the view)."""

    def __init__(self, model: str, object_points, image_points, camera: LensCamera, rvecs, tvecs,
                 floor: FloorMarkers | None = None):
        self.model = model
        self.obj = [np.asarray(o, dtype=float).reshape(-1, 3) for o in object_points]
        self.img = [np.asarray(i, dtype=float).reshape(-1, 2) for i in image_points]
        self.q = len(parameter_names(model))
        self.names = list(parameter_names(model)) + [f"view{i}.{a}" for i in range(len(self.obj))
                                                     for a in ("rx", "ry", "rz", "tx_m", "ty_m", "tz_m")]
        pose_scales = [_SCALES["rotation"]] * 3 + [_SCALES["translation"]] * 3
        self.scales = np.array([_SCALES["px"]] * 4 + [_SCALES["distortion"]] * (self.q - 4) +
                               pose_scales * len(self.obj))
        self.start = np.concatenate([camera.parameters] + [np.concatenate([r, t]) for r, t in zip(rvecs, tvecs)])
        self.first_row = np.concatenate([[0], np.cumsum([len(o) for o in self.obj])])
        # the floor markers (optional): their parameters after the views' poses, a cluster per frame after the views'
        self.floor = None if floor is None or not len(floor.sightings.frame) else FloorBlock(floor, len(self.names))
        if self.floor is not None:
            self.names += self.floor.names
            self.scales = np.concatenate([self.scales, self.floor.scales])
            self.start = np.concatenate([self.start, self.floor.start(camera)])

    def camera(self, free) -> LensCamera:
        return LensCamera.of_parameters(self.model, free[:self.q])

    def _views(self, free, jacobian):
        """Per view: (its columns, residuals (n, 2), Jacobian (n, 2, q + 6) or None)."""
        camera = self.camera(free)
        for m, (obj, img) in enumerate(zip(self.obj, self.img)):
            at = self.q + 6 * m
            uv, J_lens, J_pose = camera.project_with_jacobian(obj, free[at:at + 3], free[at + 3:at + 6], jacobian)
            columns = np.r_[0:self.q, at:at + 6]
            yield columns, uv - img, None if J_lens is None else np.concatenate([J_lens, J_pose], axis=2)

    def _floor(self, free, jacobian):
        """(residuals (N, 2), Jacobian (N, 2, P) or None) of the floor markers, each divided by its expected noise
        and multiplied by BOARD_NOISE_PX: in the boards' units."""
        uv, J = self.floor.predict(self.camera(free), free, self.q, jacobian)
        w = self.floor.weight[:, None]
        return (uv - self.floor.obs.uv_px) * w, None if J is None else J * w[:, :, None]

    def __call__(self, free, *, weights=None, jacobian: bool = True) -> Normal:
        P, M = len(free), len(self.obj)
        clusters = M + (0 if self.floor is None else len(self.floor.frames))
        A, g, scores, rss, residuals = np.zeros((P, P)), np.zeros(P), np.zeros((clusters, P)), 0.0, []
        for m, (columns, r, J) in enumerate(self._views(free, jacobian)):
            residuals.append(r)
            rw = r if weights is None else r * np.sqrt(weights[self.first_row[m]:self.first_row[m + 1]])[:, None]
            rss += float(np.sum(rw ** 2))
            if jacobian:
                Js = J.reshape(-1, len(columns)) * self.scales[columns]
                A[np.ix_(columns, columns)] += Js.T @ Js
                scores[m, columns] = Js.T @ rw.reshape(-1)
                g[columns] += scores[m, columns]
        if self.floor is not None:
            r, J = self._floor(free, jacobian)
            residuals.append(r)
            rw = r if weights is None else r * np.sqrt(weights[self.first_row[-1]:])[:, None]
            rss += float(np.sum(rw ** 2))
            if jacobian:
                Js = J * self.scales
                flat = Js.reshape(-1, P)
                A += flat.T @ flat
                per_row = np.einsum("ncp,nc->np", Js, rw)
                for k, rows in enumerate(self.floor.cluster_rows):
                    scores[M + k] = per_row[rows].sum(axis=0)
                g += per_row.sum(axis=0)
        return Normal(A, g, 0.5 * rss, np.concatenate(residuals), scores)

    def dense(self, free):
        """(r, J) flattened, unscaled: for scipy's solvers (robust losses)."""
        rs, Js = [], []
        for columns, r, J in self._views(free, True):
            full = np.zeros((r.size, len(free)))
            full[:, columns] = J.reshape(r.size, -1)
            rs.append(r.reshape(-1))
            Js.append(full)
        if self.floor is not None:
            r, J = self._floor(free, True)
            rs.append(r.reshape(-1))
            Js.append(J.reshape(r.size, -1))
        return np.concatenate(rs), np.concatenate(Js)


def fit_camera(object_points, image_points, size, model: str, K_guess=None, *, with_covariance: bool = False,
               floor: FloorMarkers | None = None, trim_floor: bool = True):
    """(camera, training RMS px per board corner[, covariance of camera.parameters, the floor markers fitted (None
    without)]) of one lens model fitted to board views (lists of (n, 3) and (n, 2)) and the floor markers if given,
    their mis-detected sightings set aside (unless not `trim_floor`: _floor_outliers_trimmed); `size` (w, h).
    OpenCV's calibration of the boards gives the start; naocal's LM (solver.identify.solve) the fit; the covariance
    is cluster-robust with a view, and a floor frame, per cluster."""
    if model not in LENS_MODELS:
        raise NaocalError(f"unknown lens model {model!r}: expected one of {', '.join(LENS_MODELS)}")
    if len(object_points) < 3:
        raise NaocalError(f"{len(object_points)} board views: at least 3 are needed to fit a camera")
    camera, rvecs, tvecs = opencv_start(object_points, image_points, size, model, K_guess)

    def fit(floor_kept):
        equations = LensEquations(model, object_points, image_points, camera, rvecs, tvecs, floor_kept)
        normal_at = last_pass_cached(equations)
        check_identifiable(normal_at(equations.start).A, equations.names)
        solution = solve(equations, normal_at, equations.start, max_iterations=MAX_ITERATIONS)
        if not solution.success:
            raise NaocalError(f"the {model} lens fit did not converge ({solution.message})")
        return equations, solution

    equations, solution = fit(floor)
    if equations.floor is not None and trim_floor:
        equations, solution = _floor_outliers_trimmed(fit, floor, (equations, solution))
    camera = equations.camera(solution.free)
    boards = solution.final.residuals[:equations.first_row[-1]]
    train = float(np.sqrt(np.mean(np.sum(boards ** 2, axis=1))))
    if not with_covariance:
        return camera, train
    spread = solution.spread(np.arange(len(solution.final.image_scores)), equations.names)
    fitted = None if equations.floor is None else FloorMarkers(equations.floor.obs, floor.size_m,
                                                                floor.T_base_camera_start)
    return camera, train, spread.covariance[:equations.q, :equations.q], fitted


def _floor_outliers_trimmed(fit, floor: FloorMarkers, result):
    """(equations, solution) of `fit(floor markers)` with the floor's mis-detected sightings set aside by the outlier
    rule of every kind (solver.identify.trimmed: a sighting's RMS whitened corner distance beyond OUTLIER_SCALES
    robust scales of the kept corners', the worst of a frame each round, those the final fit explains taken back).
    A marker's corners are judged together (its pose comes from its four alone). On the realistic mock's seed 8 two
    sightings 5.4 and 15 times their expected noise (RMS; the other 64 0.1-1.5) took the lens from 0.16 px off the
    true camera over the whole image to 1.9 (fx, fy 1.9 stds off)."""
    s = floor.sightings
    pairs = np.column_stack([s.frame, s.marker])
    keys, row_sighting = np.unique(pairs, axis=0, return_inverse=True)
    row_sighting = row_sighting.ravel()

    def kept_floor(kept):
        return FloorMarkers(s.subset(np.flatnonzero(kept[row_sighting])), floor.size_m,
                            floor.T_base_camera_start).usable()

    def judge(result, kept):
        equations, solution = result
        size = np.full(len(keys), np.inf)  # a sighting the kept fit has no frame or marker pose for: not judged back
        block = equations.floor
        if block is None:  # every marker set aside: none left to judge by
            return np.where(kept, 0.0, np.inf), OUTLIER_SCALES
        known = np.isin(s.frame, block.frames) & np.isin(s.marker, block.markers + [block.reference])
        every = FloorBlock(FloorMarkers(s.subset(np.flatnonzero(known)), floor.size_m, floor.T_base_camera_start),
                           equations.q, block.reference)  # the kept fit's frames and markers: its parameters
        x = np.concatenate([solution.free[:equations.q], solution.free[block.mount_cols[0]:]])
        uv, _ = every.predict(equations.camera(solution.free), x, equations.q, jacobian=False)
        whitened = (uv - every.obs.uv_px) / every.obs.sigma_px[:, None]
        scale = MAD_TO_SIGMA * float(np.median(np.abs(whitened[kept[row_sighting[known]]])))
        corner = np.linalg.norm(whitened, axis=1) / max(scale, 1e-12)
        rows = row_sighting[known]
        size[np.unique(rows)] = np.sqrt(np.bincount(rows, corner ** 2)[np.unique(rows)] / 4.0)
        return size, OUTLIER_SCALES

    result, _, _ = trimmed(result, lambda kept, _: fit(kept_floor(kept)), judge, keys[:, 0],
                           np.ones(len(keys), bool))
    return result


def whole_image_std_px(camera: LensCamera, covariance, size, step_px: float = 8.0) -> float:
    """The std of camera_difference_px(truth, camera) that the parameters' covariance implies: the RMS over the
    image grid of each pixel's expected squared displacement (trace of J C J^T, J: the pixel's derivative with
    respect to the parameters at its fixed ray)."""
    _, rays = _grid_rays(camera, size, step_px)
    _, J, _ = camera.project_with_jacobian(rays, np.zeros(3), np.zeros(3))
    variance = np.einsum("nij,jk,nik->n", J, np.asarray(covariance), J)
    return float(np.sqrt(np.mean(np.clip(variance, 0.0, None))))


def _grid_rays(camera: LensCamera, size, step_px: float) -> np.ndarray:
    """((n, 2) a grid of pixels over the whole image, (n, 3) the camera's rays of them (z = 1, OpenCV's frame))."""
    w, h = size
    u, v = np.meshgrid(np.arange(0.0, w, step_px), np.arange(0.0, h, step_px))
    uv = np.column_stack([u.ravel(), v.ravel()])
    return uv, np.column_stack([camera.normalised(uv), np.ones(len(uv))])


def view_rms_px(camera: LensCamera, object_points, image_points) -> float:
    """RMS (over both coordinates) of one view's corners about their projection at the view's PnP pose."""
    rvec, tvec = camera.pose(object_points, image_points)
    residual = camera.project(object_points, rvec, tvec) - np.asarray(image_points, float)
    return float(np.sqrt(np.mean(residual ** 2)))


def fit_lens(object_points, image_points, size, model: str, groups, K_guess=None, floor=None) -> LensFit:
    """One lens model: fitted to all views (with its stds), and held out group by group (`groups`: a label per
    board view, at least two different ones); the floor markers (optional) are in every fit, none held out (a
    marker's four corners give no pose of their own to judge it by): those the fit to all views kept (its outlier
    trimming not repeated per group: the same sightings, and each round is a fit)."""
    labels = _group_labels(groups)
    groups = np.asarray(groups)
    camera, train, covariance, floor = fit_camera(object_points, image_points, size, model, K_guess,
                                                  with_covariance=True, floor=floor)
    squares = np.full(len(object_points), np.inf)
    for label in labels:
        train_idx, test_idx = np.flatnonzero(groups != label), np.flatnonzero(groups == label)
        try:
            held, _ = fit_camera([object_points[i] for i in train_idx], [image_points[i] for i in train_idx], size,
                                 model, K_guess, floor=floor, trim_floor=False)
            squares[test_idx] = [view_rms_px(held, object_points[i], image_points[i]) ** 2 for i in test_idx]
        except (cv2.error, NaocalError):  # too few views left, or the fit diverged: the model cannot be judged
            pass
    return LensFit(camera, train, float(np.sqrt(np.mean(squares))), len(object_points),
                   np.sqrt(np.clip(np.diag(covariance), 0.0, None)), covariance,
                   whole_image_std_px(camera, covariance, size), squares)


def _group_labels(groups) -> np.ndarray:
    labels = np.unique(np.asarray(groups))
    if len(labels) < 2:
        raise NaocalError("held-out errors need the views in at least two groups")
    return labels


def significantly_worse(a: LensFit, b: LensFit) -> bool:
    """Whether a's held-out views are worse than b's by more than CHOICE_SE standard errors (paired over the views
    of both: the log ratio of their mean squared errors)."""
    fa, fb = np.isfinite(a.held_out_view_ms_px2), np.isfinite(b.held_out_view_ms_px2)
    if np.any(fb & ~fa):  # a view b predicts and a cannot
        return True
    # the log ratio: views' errors differ by factors (a view at the image's edge has ten times the error of one in
    # the middle), so their differences are heavy-tailed and a mean of them tells little
    d = np.log(a.held_out_view_ms_px2[fa & fb] / np.maximum(b.held_out_view_ms_px2[fa & fb], 1e-300))
    if len(d) < 2:
        return bool(d.mean() > 0)
    return bool(d.mean() > CHOICE_SE * d.std(ddof=1) / np.sqrt(len(d)))


def choose_lens(object_points, image_points, size, groups, models=LENS_MODELS, K_guess=None, floor=None):
    """(chosen LensFit, {model: LensFit}): the simplest model (fewest parameters; ties: the order of `models`) whose
    held-out error is not significantly worse than the smallest one's (significantly_worse), among the models the
    views determine over the whole image (whole-image std within MAX_WHOLE_IMAGE_STD_RATIO of the best determined
    one's). `floor`: the floor markers (FloorMarkers) fitted with the boards."""
    _group_labels(groups)
    fits = {}
    for model in models:
        try:
            fits[model] = fit_lens(object_points, image_points, size, model, groups, K_guess, floor)
        except (cv2.error, NaocalError):
            continue  # refused on these views (e.g. OpenCV's fisheye ill-conditioned check, an undetermined term)
    if not fits:
        raise NaocalError("no lens model could be fitted to the board views")
    # held-out views judge a model only where the boards were seen; one the views leave undetermined elsewhere in the
    # image is not a candidate (realistic mock, seed 8: rational held out 3 % below plumb_bob, yet 144 px off the true
    # camera over the whole image, its whole-image std 1.3e5 px against plumb_bob's 0.97)
    stds = [f.whole_image_std_px for f in fits.values() if np.isfinite(f.whole_image_std_px)]
    candidates = [f for f in fits.values() if not stds
                  or f.whole_image_std_px <= MAX_WHOLE_IMAGE_STD_RATIO * min(stds)]
    best = min(candidates, key=lambda f: f.held_out_rms_px)
    for fit in sorted(candidates, key=lambda f: len(f.names)):
        if fit is best or not significantly_worse(fit, best):
            return fit, fits
    return best, fits


def camera_difference_px(a: LensCamera, b: LensCamera, size, step_px: float = 8.0) -> float:
    """RMS pixel distance over the whole image between where two cameras see the same rays: a grid of a's pixels,
    their rays by a, projected by b."""
    uv, rays = _grid_rays(a, size, step_px)
    back = b.project(rays, np.zeros(3), np.zeros(3))
    return float(np.sqrt(np.mean(np.sum((back - uv) ** 2, axis=1))))
