"""The camera model: projection of points in the NAO camera frame to pixels, OpenCV lens distortion, and their
exact derivatives. The only place naocal projects a point (the paper's Eq. 1, docs/CONVENTIONS.md):

    (xn, yn) = (-y / x, -z / x)                  normalised coordinates: OpenCV's (x right, y down)
    (xd, yd) = distort(xn, yn; k1, k2, p1, p2, k3)      OpenCV's radial-tangential model
    (u, v)   = (cx + fx * xd, cy + fy * yd)      pixel (0, 0) is the centre of the top-left pixel (OpenCV)

for a point (x, y, z) in the NAO camera frame (x along the optical axis, y left, z up). Intrinsics are a dict
{"fx_px", "fy_px", "cx_px", "cy_px", "distortion": [k1, k2, p1, p2, k3], "width_px", "height_px"}; the prior of
each camera is in the robot description (solver.robot.default_intrinsics). Every function is pure and vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from naocal.solver import fields

# The intrinsic components, in the order of `Projection.intrinsic_jacobian` columns.
COMPONENTS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
NO_DISTORTION = (0.0, 0.0, 0.0, 0.0, 0.0)


INTRINSICS_KEYS = ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")
# Beyond these a value is damaged or a unit mix-up, not a camera.
MAX_IMAGE_SIDE_PX = 10_000
MAX_FOCAL_LENGTH_PX = 100_000.0
MAX_DISTORTION = 100.0  # OpenCV's coefficients; a NAO's or a Duckiebot's lens needs |k| < 1, a fisheye's a few


@dataclass(frozen=True)
class CameraIntrinsics:
    """A camera's intrinsics: image size, pinhole (fx, fy, cx, cy) and OpenCV distortion (k1, k2, p1, p2, k3), in
    the conventions above. The one intrinsics type: the robot description's cameras (solver.robot.Camera) are these
    with a name, a frame and a readout; the backends report them (backends.base.CameraIntrinsics is this)."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    distortion: tuple = NO_DISTORTION

    def intrinsics(self) -> dict:
        """The intrinsics dict the camera model, the datasets and the agent use."""
        return {"width_px": int(self.width_px), "height_px": int(self.height_px), "fx_px": float(self.fx_px),
                "fy_px": float(self.fy_px), "cx_px": float(self.cx_px), "cy_px": float(self.cy_px),
                "distortion": [float(d) for d in self.distortion]}

    def to_dict(self) -> dict:
        """As the bridge protocol sends it: the dict with the camera's name (a backend's intrinsics() are its
        bottom camera's)."""
        return {"name": getattr(self, "name", "bottom"), **self.intrinsics()}

    @classmethod
    def from_fields(cls, doc: dict, path, where: str = "") -> "CameraIntrinsics":
        """The intrinsics in a JSON object's fields (INTRINSICS_KEYS, distortion optional), each checked
        (solver.fields; DataError naming `path` and the field under `where`): the one check of a camera's intrinsics
        however they arrive (a dataset, a prior file, the bridge, an arm's sensor). Whole positive image sides, positive
        focal lengths, the principal point inside the image, plausible sizes."""
        def name(key):
            return f"{where}.{key}" if where else key

        for key in INTRINSICS_KEYS:
            if key not in doc:
                fields.fail(path, "missing required field", name(key))
        width, height = (int(fields.number(doc[key], path, name(key), positive=True, integer=True,
                                           limit=MAX_IMAGE_SIDE_PX)) for key in ("width_px", "height_px"))
        fx, fy = (fields.number(doc[key], path, name(key), positive=True, limit=MAX_FOCAL_LENGTH_PX)
                  for key in ("fx_px", "fy_px"))
        cx, cy = (fields.number(doc[key], path, name(key)) for key in ("cx_px", "cy_px"))
        for key, value, side in (("cx_px", cx, width), ("cy_px", cy, height)):
            if not 0 <= value <= side:
                fields.fail(path, f"principal point outside the {width} x {height} image, got {value!r}", name(key))
        distortion = fields.vector(doc.get("distortion", list(NO_DISTORTION)), 5, path, name("distortion"),
                                   limit=MAX_DISTORTION)
        return cls(width_px=width, height_px=height, fx_px=fx, fy_px=fy, cx_px=cx, cy_px=cy,
                   distortion=tuple(distortion))

    def project(self, p_cam) -> np.ndarray:
        """Pixels (..., 2) of points (..., 3) in the camera frame (`project_points`; depth > 0 in front)."""
        return project_points(p_cam, self.intrinsics())[0]

    def undistort_px(self, uv_px) -> np.ndarray:
        """Undistorted pixels (..., 2) of distorted ones (`undistort_points`)."""
        return undistort_points(uv_px, self.intrinsics())


def distortion_of(intrinsics) -> np.ndarray:
    """(5,) OpenCV coefficients (k1, k2, p1, p2, k3) of an intrinsics dict (zeros when it has none)."""
    k = list(intrinsics.get("distortion") or NO_DISTORTION) + [0.0] * 5
    return np.array(k[:5], dtype=float)


def distort(xn, yn, k):
    """OpenCV distortion of normalised coordinates: (xd, yd, r2, D), D (..., 2, 2) = d(xd, yd) / d(xn, yn).

    k = (k1, k2, p1, p2, k3), each a scalar or an array broadcasting with xn.
    """
    k1, k2, p1, p2, k3 = k
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    g = 2.0 * k1 + r2 * (4.0 * k2 + 6.0 * k3 * r2)  # d radial / d r2, times 2
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    D = np.empty(np.shape(xn) + (2, 2))
    D[..., 0, 0] = radial + g * xn * xn + 2.0 * p1 * yn + 6.0 * p2 * xn
    D[..., 0, 1] = g * xn * yn + 2.0 * p1 * xn + 2.0 * p2 * yn
    D[..., 1, 0] = D[..., 0, 1]
    D[..., 1, 1] = radial + g * yn * yn + 6.0 * p1 * yn + 2.0 * p2 * xn
    return xd, yd, r2, D


@dataclass
class Projection:
    """Pixels of N points and what their derivatives need. Built by `project`.

    uv_px (N, 2); inv_x (N,) = 1 / depth; xn, yn normalised, xd, yd distorted coordinates, r2 = xn^2 + yn^2;
    D (N, 2, 2) = d(xd, yd) / d(xn, yn); f (N, 2) = (fx, fy) of each point's camera.
    """

    uv_px: np.ndarray
    p_cam: np.ndarray
    inv_x: np.ndarray
    xn: np.ndarray
    yn: np.ndarray
    xd: np.ndarray
    yd: np.ndarray
    r2: np.ndarray
    D: np.ndarray
    f: np.ndarray

    def point_jacobian(self) -> np.ndarray:
        """(N, 2, 3): d(u, v) / d(x, y, z) of the point in the camera frame."""
        # d(xn, yn) / d(x, y, z) = [[-xn, -1, 0], [-yn, 0, -1]] / x
        A = np.empty(self.xn.shape + (2, 3))
        for row in (0, 1):
            d_xn, d_yn = self.D[:, row, 0], self.D[:, row, 1]
            scale = self.f[:, row] * self.inv_x
            A[:, row, 0] = -(d_xn * self.xn + d_yn * self.yn) * scale
            A[:, row, 1] = -d_xn * scale
            A[:, row, 2] = -d_yn * scale
        return A

    def twist_jacobian(self) -> np.ndarray:
        """(N, 2, 6): d(u, v) / d twist (v, w) of the point in the camera frame, dp = v + w x p (v in m, w in rad).

        The interaction matrix [A, p x a_i]: every rigid motion of a point relative to the camera enters so.
        """
        A = self.point_jacobian()
        x, y, z = self.p_cam[:, 0], self.p_cam[:, 1], self.p_cam[:, 2]
        L = np.empty(self.xn.shape + (2, 6))
        L[:, :, :3] = A
        a0, a1, a2 = A[:, :, 0], A[:, :, 1], A[:, :, 2]
        L[:, :, 3] = y[:, None] * a2 - z[:, None] * a1  # (p x a): d/dw of a . (w x p)
        L[:, :, 4] = z[:, None] * a0 - x[:, None] * a2
        L[:, :, 5] = x[:, None] * a1 - y[:, None] * a0
        return L

    def intrinsic_jacobian(self, component: str) -> np.ndarray:
        """(N, 2): d(u, v) / d of one intrinsic component ('fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'p1', 'p2', 'k3')."""
        out = np.zeros(self.xn.shape + (2,))
        xn, yn, r2, f = self.xn, self.yn, self.r2, self.f
        if component == "fx":
            out[:, 0] = self.xd
        elif component == "fy":
            out[:, 1] = self.yd
        elif component == "cx":
            out[:, 0] = 1.0
        elif component == "cy":
            out[:, 1] = 1.0
        elif component in ("k1", "k2", "k3"):
            rp = r2 ** {"k1": 1, "k2": 2, "k3": 3}[component]
            out[:, 0], out[:, 1] = f[:, 0] * xn * rp, f[:, 1] * yn * rp
        elif component == "p1":
            out[:, 0], out[:, 1] = f[:, 0] * 2.0 * xn * yn, f[:, 1] * (r2 + 2.0 * yn * yn)
        elif component == "p2":
            out[:, 0], out[:, 1] = f[:, 0] * (r2 + 2.0 * xn * xn), f[:, 1] * 2.0 * xn * yn
        else:
            raise ValueError(f"unknown intrinsic component {component!r} (expected one of {', '.join(COMPONENTS)})")
        return out


def project(p_cam, fx, fy, cx, cy, k=NO_DISTORTION) -> Projection:
    """Project points p_cam (N, 3) in the camera frame; the intrinsics are scalars or (N,) arrays (one per point).

    k = (k1, k2, p1, p2, k3), scalars or (N,) arrays. Points at or behind the camera give non-finite pixels.
    """
    p_cam = np.asarray(p_cam, dtype=float)
    x, y, z = p_cam[:, 0], p_cam[:, 1], p_cam[:, 2]
    inv_x = 1.0 / x
    xn, yn = -y * inv_x, -z * inv_x
    xd, yd, r2, D = distort(xn, yn, k)
    uv = np.stack([cx + fx * xd, cy + fy * yd], axis=1)
    f = np.empty((len(x), 2))
    f[:, 0], f[:, 1] = fx, fy
    return Projection(uv, p_cam, inv_x, xn, yn, xd, yd, r2, D, f)


def project_points(p_cam, intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (..., 2) and depths (...) of points (..., 3) in the camera frame, for one camera's intrinsics dict.

    Points at or behind the camera (depth <= 0) give non-finite or meaningless pixels: check the depth.
    """
    p_cam = np.asarray(p_cam, dtype=float)
    depth = p_cam[..., 0]
    k = distortion_of(intrinsics)
    with np.errstate(divide="ignore", invalid="ignore"):
        xn, yn = -p_cam[..., 1] / depth, -p_cam[..., 2] / depth
        if np.any(k):
            xn, yn, _, _ = distort(xn, yn, k)
        uv = np.stack([intrinsics["cx_px"] + intrinsics["fx_px"] * xn,
                       intrinsics["cy_px"] + intrinsics["fy_px"] * yn], axis=-1)
    return uv, depth


def undistort_points(uv_px, intrinsics, iterations: int = 50) -> np.ndarray:
    """Undistorted pixels (..., 2) of distorted ones: the inverse of `distort` by fixed-point iteration on the
    normalised coordinates (as OpenCV's undistortPoints), exact to ~1e-12 px for the NAO's mild distortions."""
    uv_px = np.asarray(uv_px, dtype=float)
    fx, fy, cx, cy = (intrinsics[k] for k in ("fx_px", "fy_px", "cx_px", "cy_px"))
    xd, yd = (uv_px[..., 0] - cx) / fx, (uv_px[..., 1] - cy) / fy
    xn, yn = xd.copy(), yd.copy()
    k1, k2, p1, p2, k3 = distortion_of(intrinsics)
    if any((k1, k2, p1, p2, k3)):
        for _ in range(iterations):
            r2 = xn * xn + yn * yn
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xn = (xd - (2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn))) / radial
            yn = (yd - (p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn)) / radial
    return np.stack([cx + fx * xn, cy + fy * yn], axis=-1)


def plane_homography(T_cam_plane, intrinsics) -> np.ndarray:
    """H (3, 3): points (x, y, 1) of the plane z = 0 of a frame at T_cam_plane -> undistorted pixels (u, v, 1).

    The pinhole part of the projection above as a matrix: (u, v, 1) ~ K @ p_cam with K mapping the NAO camera
    frame (x optical axis, y left, z up) to pixels."""
    K = np.array([[intrinsics["cx_px"], -intrinsics["fx_px"], 0.0], [intrinsics["cy_px"], 0.0, -intrinsics["fy_px"]],
                  [1.0, 0.0, 0.0]])
    return K @ np.column_stack([T_cam_plane[:3, 0], T_cam_plane[:3, 1], T_cam_plane[:3, 3]])


def transform_to_camera(T_base_cam, p_base) -> np.ndarray:
    """Points (..., K, 3) in the base frame -> camera frame, for camera poses T_base_cam (..., 4, 4)."""
    R, t = T_base_cam[..., :3, :3], T_base_cam[..., :3, 3]
    return np.einsum("...ji,...kj->...ki", R, p_base - t[..., None, :])
