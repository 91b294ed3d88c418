"""A small fake robot for the agent's unit tests: simulated clock, moving joints, biased quantised encoders,
late images, and a "detector" that projects the board exactly from the fake's hidden truth (no rendering).

Physics kept: each servo drives its own biased sensor to the command at speed_fraction x max speed after a
command latency (true angle = sensor + alpha); encoders are sampled at 100 Hz and quantised; images are exposed
at 30 Hz and arrive `image_delay_s` later, showing the robot as it was at their exposure.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from naocal.backends.base import Backend, CameraImage, CameraIntrinsics, JointReading
from naocal.solver.errors import SafetyError
from naocal.solver.joints import JOINTS, LEG_JOINTS
from naocal.solver.limits import joint_limits, max_speeds
from naocal.solver.model import Model
from naocal.solver.registry import Registry
from naocal.sim.synthetic import DEFAULT_INTRINSICS, make_model_data

FULL = Registry()
_BLANK = np.zeros((480, 640, 3), dtype=np.uint8)


@dataclass(frozen=True)
class FakeImage(CameraImage):
    sensor_rad: tuple = ()  # the servo sensors (not the readings) at the exposure time


@dataclass
class FakeDetection:
    vertices_px: np.ndarray | None
    reason: str | None = None
    detail: str = ""

    @property
    def ok(self):
        return self.vertices_px is not None


def random_truth(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    truth = {f"joint_offset.{j}": rng.uniform(-0.03, 0.03) for j in LEG_JOINTS}
    truth["joint_offset.RHipYawPitch"] = truth["joint_offset.LHipYawPitch"]  # one motor, as on the robot
    truth.update({"camera.bottom.roll": rng.uniform(-0.03, 0.03), "camera.bottom.pitch": rng.uniform(-0.06, 0.0),
                  "camera.bottom.yaw": rng.uniform(-0.03, 0.03)})
    for leg in "LR":
        truth[f"board.{leg}.rot_z"] = rng.uniform(-0.02, 0.02)
        truth[f"board.{leg}.trans_x"] = rng.uniform(-0.002, 0.002)
        truth[f"board.{leg}.trans_y"] = rng.uniform(-0.002, 0.002)
    return truth


class FakeBackend(Backend):
    name = "fake"

    def __init__(self, seed: int = 0, *, truth: dict | None = None, image_delay_s: float = 0.06,
                 latency_s: float = 0.03, resolution_rad: float = np.radians(0.1), pixel_noise_px: float = 0.05,
                 start=None):
        self.truth = random_truth(seed) if truth is None else dict(truth)
        self.values = FULL.from_dict(self.truth)
        self.alpha = -np.array([self.truth.get(f"joint_offset.{j}", 0.0) for j in JOINTS])  # the truth holds c
        self.rng = np.random.default_rng(seed + 1000)
        self.t = 0.0
        self.image_delay_s = image_delay_s
        self.latency_s = latency_s
        self.resolution_rad = resolution_rad
        self.pixel_noise_px = pixel_noise_px
        self.limits = joint_limits()
        self.speeds = np.array([max_speeds()[j] for j in JOINTS])
        q0 = np.zeros(len(JOINTS)) if start is None else np.asarray(start, dtype=float)
        q0[1] = 0.42  # head up off the ground
        self.start_posture = q0.copy()
        self._segments = [(-1.0, q0.copy(), q0.copy(), np.ones(len(JOINTS)))]  # (t_start, from, to, speed)
        self.command_log = []  # (t, {joint: target}, speed_fraction)
        self.detected = {}  # exposure time -> the sensors (14,) the detected image showed
        self.n_captures = 0

    # --- motion --------------------------------------------------------------------------------------------
    def sensor_at(self, t: float) -> np.ndarray:
        started = [s for s in self._segments if s[0] <= t] or self._segments[:1]
        t_start, q_from, q_to, speed = max(started, key=lambda s: s[0])
        delta = q_to - q_from
        moved = np.minimum(np.abs(delta), speed * (t - t_start))
        return q_from + np.sign(delta) * moved

    def true_angles(self) -> np.ndarray:
        return self.sensor_at(self.t) + self.alpha

    # --- Backend -------------------------------------------------------------------------------------------
    def robot_identity(self):
        return {"id": "fake", "model": "NAO H25 V5 (fake)", "body_id": "fake-body", "head_id": "fake-head"}

    def joint_names(self):
        return JOINTS

    def joint_limits(self):
        return {j: self.limits[j] for j in JOINTS}

    def max_speeds(self):
        return dict(zip(JOINTS, self.speeds))

    def command(self, targets_rad, speed_fraction):
        for name, value in targets_rad.items():
            if name not in JOINTS:
                raise SafetyError(f"unknown joint {name}")
            lo, hi = self.limits[name]
            if not (np.isfinite(value) and lo <= value <= hi):
                raise SafetyError(f"{name} target {value} outside [{lo}, {hi}]")
        self.command_log.append((self.t, dict(targets_rad), speed_fraction))
        t_start = self.t + self.latency_s
        q_from = self.sensor_at(t_start)
        q_to = q_from.copy()
        for name, value in targets_rad.items():
            q_to[JOINTS.index(name)] = value
        self._segments = [s for s in self._segments if s[0] < t_start][-4:]
        self._segments.append((t_start, q_from, q_to, self.speeds * speed_fraction))

    def read_joints(self):
        t_sample = np.floor(self.t / 0.01 + 1e-9) * 0.01
        q = self.sensor_at(t_sample)
        if self.resolution_rad > 0:
            q = np.round(q / self.resolution_rad) * self.resolution_rad
        return JointReading(dict(zip(JOINTS, q)), float(t_sample))

    def set_stiffness(self, names, stiffness):
        pass

    def capture(self, camera="bottom"):
        k = int(np.floor((self.t - self.image_delay_s) * 30.0 + 1e-9))
        if k < 0:
            return None
        t_exposure = k / 30.0
        self.n_captures += 1
        return FakeImage(_BLANK, float(t_exposure), camera, tuple(self.sensor_at(t_exposure)))

    def intrinsics(self):
        d = DEFAULT_INTRINSICS
        return CameraIntrinsics(640, 480, d["fx_px"], d["fy_px"], d["cx_px"], d["cy_px"])

    def now(self):
        return self.t

    def sleep(self, duration_s):
        self.t += max(float(duration_s), 0.0)

    # --- the fake detector ---------------------------------------------------------------------------------
    # The top camera's hidden rotation (the bottom camera's is in `values`).
    TOP_ROTATION_RAD = {"roll": 0.02, "pitch": -0.06, "yaw": -0.03}

    def project(self, leg, sensor14, camera="bottom") -> np.ndarray:
        data = make_model_data(np.asarray(sensor14)[None], np.array([leg]), np.array([0]), np.array([0]))
        if camera == "bottom":
            return Model(data, FULL).residuals(self.values)
        data = replace(data, camera=np.array([camera]), cameras={camera: data.cameras["bottom"]})
        registry = Registry.for_data(data)
        known = {**dict(zip(FULL.names, self.values)),
                 **{f"camera.{camera}.{a}": v for a, v in self.TOP_ROTATION_RAD.items()}}
        values = np.array([known.get(name, 0.0) for name in registry.names])
        return Model(data, registry).residuals(values)

    def detector(self, image, predicted_px, leg, search_margin_px):
        self.detected[round(image.t_exposure_s, 9)] = np.array(image.sensor_rad)
        uv = self.project(leg, image.sensor_rad, image.camera) + self.rng.normal(0.0, self.pixel_noise_px, (24, 2))
        if np.any(uv < 6) or np.any(uv[:, 0] > 633) or np.any(uv[:, 1] > 473):
            return FakeDetection(None, "cut_off", "a vertex near the image edge")
        shift = np.linalg.norm(uv.mean(axis=0) - np.asarray(predicted_px).mean(axis=0))
        if shift > search_margin_px + 12:
            return FakeDetection(None, "missing", f"board {shift:.0f} px from the prediction")
        return FakeDetection(uv)
