"""A simulated Duckiebot with hidden truth (issue 23): PyBullet physics (DIRECT, headless) for the motion, the OpenCV
renderer (kinds.duckiebot.render) for the camera, in the seed paper's set-up.

The body: a chassis on two driven wheels (spheres of the hidden radii on revolute joints about the axle, their
contact points the hidden baseline apart: a sphere's contact point stays below its centre whatever the roll) and a
frictionless ball caster at the back; the floor a plane with friction. Each wheel is velocity-controlled with a
bounded torque.

A duty u in [-1, 1] per wheel reaches the motor as Duckietown's wheel driver sends it (kinematics.duty_to_pwm: no
PWM for |u| <= 0.01, then floor(|u| 195 + 60) of 255). The motor turns the wheel at w = sign(u) m (pwm - pwm_dead) /
195 (0 below pwm_dead) rad/s: `m` the hidden per-wheel motor gain, `pwm_dead` the hidden PWM at which the motor
starts to turn (the driver assumes 60: a dead zone and a speed offset when it is not), reached through a first-order
lag of the hidden time constant; the body moves at the wheels' ground speeds less each tyre's hidden slip
(`DuckiebotMock._roll` says why the body is not left to PyBullet's friction). The ideal mock (`realism="ideal"`, for
teaching) turns the wheel at exactly w = m u: no PWM, no dead zone, no lag, no slip, no image noise or motion
blur.

Hidden (`DuckiebotTruth`, drawn per seed; docs/DUCKIEBOT.md "The mock and the agent" lists the ranges): per-wheel radius
and motor gain (what Duckietown's trim and gain express), the baseline, the PWM dead zone, each wheel's lag, the
tyres' slip, the camera's intrinsics and plumb_bob distortion, and its pose on the body. `truth_document`
writes them in the calibration file's names and units (in the log's k, as the fit's gain and trim are).

Frames: the renderer at the body's planar pose from PyBullet; an exposure of `exposure_s` during which the robot
keeps moving, rendered as the mean of poses over it (motion blur from the speed), then noise.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from naocal.kinds.duckiebot.kinematics import PWM_MAX, PWM_MIN, duty_problem, duty_to_pwm
from naocal.kinds.duckiebot.render import HiddenRobot, Renderer, calibration_scene
from naocal.kinds.duckiebot.robot import BASELINE_M, WHEEL_RADIUS_M, Kinematics
from naocal.solver.camera import CameraIntrinsics
from naocal.solver.errors import NaocalError, SafetyError
from naocal.solver.fileio import atomic_write_text, read_json
from naocal.solver.transforms import rot_z

REALISMS = ("ideal", "realistic")
LOG_K = 27.0  # Duckietown's nominal k: the log's, in which the truth's gain and trim are expressed
PHYSICS_DT_S = 1.0 / 480.0
CHASSIS_MASS_KG, WHEEL_MASS_KG, CASTER_MASS_KG = 1.0, 0.05, 0.02
CASTER_RADIUS_M, CASTER_BEHIND_M = 0.015, 0.10
WHEEL_TORQUE_NM = 2.0  # the wheels follow their speeds at once (their lag is the motor's, modelled before)
N_MARKERS = 20  # the marker line: 0.3-3.2 m behind the start, so a 2 m validation drive stays over it
COM_IN_BASE_M = np.array([-0.03, 0.0, 0.02])  # the chassis' centre of mass, behind the axle: the caster carries some
# PyBullet reports a body's pose at its centre of mass and places links relative to it: both shifted by this
WHEEL_FRICTION = 1.0
TRUTH_SPEED_MPS = 0.3  # truth.json's kinematics: what drives the robot straight this fast (the drive)
RESTORE_GAP_S = 1e-3  # a restored mock resumes this long after its saved time, wheels stopped (the driver's watchdog)


@dataclass(frozen=True)
class DuckiebotTruth:
    """The hidden robot. Motor gains in rad/s of wheel speed per unit duty; the dead zone in PWM steps (0..255)."""

    radius_left_m: float
    radius_right_m: float
    motor_left_radps: float
    motor_right_radps: float
    baseline_m: float
    pwm_dead: float  # the PWM at which the motors start to turn (the driver assumes PWM_MIN = 60)
    lag_left_s: float  # first-order time constants of the wheel speeds
    lag_right_s: float
    slip_left: float  # the fraction of each wheel's rolling speed lost to tyre slip
    slip_right: float
    camera: CameraIntrinsics
    T_base_camera: np.ndarray
    pwm_driver: bool = True  # the duties pass kinematics.duty_to_pwm (realistic); ideal: the motor gets the duty

    def kinematics(self) -> Kinematics:
        """Duckietown's parameters that describe this robot (in the log's k = 27, the nominal radius): its forward
        map u -> wheel ground speed r_side m_side u is r (u k / (gain -+ trim))."""
        a_left = WHEEL_RADIUS_M * LOG_K / (self.radius_left_m * self.motor_left_radps * (1.0 - self.slip_left))
        a_right = WHEEL_RADIUS_M * LOG_K / (self.radius_right_m * self.motor_right_radps * (1.0 - self.slip_right))
        return Kinematics(baseline_m=self.baseline_m, radius_m=WHEEL_RADIUS_M, gain=(a_left + a_right) / 2.0,
                          trim=(a_right - a_left) / 2.0, k=LOG_K)

    def duty_offset(self) -> float:
        """The duty a wheel loses before it turns, on average over the duties near any one: (pwm_dead - 60) / 195
        (the motor's start against the driver's floor), plus half a PWM step the driver's floor drops on average
        (realistic only: `pwm_driver`); the same for both wheels, as fit.duty_offset models it."""
        if self.pwm_driver:
            return (self.pwm_dead - PWM_MIN + 0.5) / (PWM_MAX - PWM_MIN)
        return (self.pwm_dead - PWM_MIN) / (PWM_MAX - PWM_MIN)

    def kinematics_at(self, speed_mps: float) -> Kinematics:
        """What a user needs: the parameters with which Duckietown's inverse kinematics (no dead zone) drives this
        robot at `speed_mps` straight, on average over the PWM steps near it. A wheel turning at w needs the duty
        c + a w / k (c: duty_offset, the same on both wheels; a = gain -+ trim of `kinematics()`, the motor's
        slope): the secant gain + c k r / v, the slope's trim (fit.secant_gain is the fit's)."""
        slope = self.kinematics()
        return replace(slope, gain=slope.gain + self.duty_offset() * slope.k * slope.radius_m / speed_mps)

    def hidden_robot(self) -> HiddenRobot:
        """The renderer's HiddenRobot of this truth (for methods written against it, e.g. the paper's)."""
        return HiddenRobot(self.kinematics(), self.camera, self.T_base_camera)


def draw_truth(seed: int, realism: str = "realistic") -> DuckiebotTruth:
    """A hidden DB21 for `seed`. The camera and the mount as kinds.duckiebot.render.hidden_robot draws them (the real
    robots' ranges); the wheels: motor gains 27 rad/s x U(0.7, 1.3) with a left/right asymmetry N(0, 0.05) clipped
    to +-0.12 (the real robots' trim), radii 0.0318 m +- 0.3 mm each (tyre wear), baseline 0.1 m +- 3 mm; realistic
    only: the motors start at PWM U(55, 65), lags U(0.02, 0.06) s (each wheel within +-5 % of the
    other's), tyre slip U(0, 2 %) of each wheel's
    rolling speed (ideal: 60, 0, 0)."""
    if realism not in REALISMS:
        raise NaocalError(f"unknown mock realism {realism!r}: expected one of {', '.join(REALISMS)}")
    from naocal.kinds.duckiebot.render import hidden_robot

    camera_truth = hidden_robot(seed)  # the camera and its mount: the renderer's draw, one home for those ranges
    rng = np.random.default_rng([seed, 23])
    motor = LOG_K * rng.uniform(0.7, 1.3)
    asymmetry = float(np.clip(rng.normal(0.0, 0.05), -0.12, 0.12))
    radii = WHEEL_RADIUS_M + rng.uniform(-0.0003, 0.0003, 2)
    baseline = BASELINE_M + rng.uniform(-0.003, 0.003)
    realistic = realism == "realistic"
    pwm_dead = rng.uniform(55.0, 65.0) if realistic else float(PWM_MIN)
    # one time constant for both motors, each within +-5 % of it: wheels whose lags differ more (20 vs 58 ms, an
    # earlier draw) creep sideways about 5 mm per stop-and-go stretch, which the joint fit (no lag in its model)
    # cannot explain: it failed at 26 px RMS (docs/DUCKIEBOT.md); what `naocal diagnose` is to name
    lags = rng.uniform(0.02, 0.06) * rng.uniform(0.95, 1.05, 2) if realistic else np.zeros(2)
    slips = rng.uniform(0.0, 0.02, 2) if realistic else np.zeros(2)
    return DuckiebotTruth(float(radii[0]), float(radii[1]), motor * (1.0 - asymmetry), motor * (1.0 + asymmetry),
                     float(baseline), float(pwm_dead), float(lags[0]), float(lags[1]), float(slips[0]),
                     float(slips[1]), camera_truth.camera, camera_truth.T_base_camera, realistic)


def truth_document(truth: DuckiebotTruth, seed: int, realism: str) -> dict:
    """RUN/truth.json: the hidden robot in the calibration file's names and units (kinematics in the log's k;
    `parameters` the joint fit's camera.* names), with the mock's own hidden effects beside them."""
    from naocal.kinds.duckiebot.fit import CAMERA, pose_parameters

    kin, at_speed = truth.kinematics(), truth.kinematics_at(TRUTH_SPEED_MPS)
    camera = truth.camera
    K = [[camera.fx_px, 0.0, camera.cx_px], [0.0, camera.fy_px, camera.cy_px], [0.0, 0.0, 1.0]]
    # the joint fit's names: the motors' slope (gain, trim) and start (dead_zone: with the driver's floor modelled)
    parameters = {"gain": kin.gain, "trim": kin.trim, "baseline_m": kin.baseline_m,
                  "dead_zone": (truth.pwm_dead - PWM_MIN) / (PWM_MAX - PWM_MIN)}
    parameters.update(zip(CAMERA, (float(v) for v in pose_parameters(truth.T_base_camera))))
    return {"schema": "naocal.duckiebot_truth/1", "mock": {"seed": int(seed), "realism": realism},
            "camera": {"width_px": camera.width_px, "height_px": camera.height_px, "lens_model": "plumb_bob",
                       "lenses": {"plumb_bob": {"K": K, "distortion": [float(d) for d in camera.distortion]}}},
            # what Duckietown's files need to drive TRUTH_SPEED_MPS straight (DuckiebotTruth.kinematics_at), and
            # the motors' slope (the same trim: the start PWM is both wheels')
            "kinematics": {"gain": at_speed.gain, "trim": at_speed.trim, "baseline_m": kin.baseline_m,
                           "k": kin.k, "radius_m": kin.radius_m, "limit": kin.limit, "speed_mps": TRUTH_SPEED_MPS},
            "kinematics_slope": {"gain": kin.gain, "trim": kin.trim},
            "parameters": {n: {"value": float(v)} for n, v in parameters.items()},
            "T_base_camera": np.asarray(truth.T_base_camera).tolist(),
            "hidden": {"radius_left_m": truth.radius_left_m, "radius_right_m": truth.radius_right_m,
                       "motor_left_radps": truth.motor_left_radps, "motor_right_radps": truth.motor_right_radps,
                       "pwm_dead": truth.pwm_dead, "lag_left_s": truth.lag_left_s, "lag_right_s": truth.lag_right_s,
                       "slip_left": truth.slip_left, "slip_right": truth.slip_right}}


def mock_scene():
    return calibration_scene(n_markers=N_MARKERS)


class DuckiebotMock:
    """The simulated robot: `command(left, right)` duties, `advance(dt)` lets time pass, `grab()` a frame.

    `state_path`: the mock's world (pose, clock, command, noise stream) is saved there after every action and
    restored from it when present: a killed run's robot stays where it was (wheels stopped by the driver's
    watchdog, RESTORE_GAP_S later)."""

    def __init__(self, seed: int, realism: str = "realistic", *, state_path=None, supersample: int = 2,
                 start_pose=(0.0, 0.0, 0.0), scene=None):
        import pybullet

        self.seed, self.realism = int(seed), realism
        self.truth = draw_truth(seed, realism)
        self.ideal = realism == "ideal"
        self.pwm_driver = not self.ideal  # its duties pass kinematics.duty_to_pwm (the mission's fit models it)
        self.exposure_s = 0.02  # the ideal mock too: a frame takes time (but renders its mid-exposure pose, sharp)
        self.noise_grey = 0.0 if self.ideal else 1.5
        self.scene = scene or mock_scene()
        self.renderer = Renderer(self.scene, self.truth.camera, self.truth.T_base_camera, supersample)
        self.state_path = Path(state_path) if state_path is not None else None
        self.t_s = 0.0
        self.duties = np.zeros(2)  # as last received (left, right)
        self.wheel_w = np.zeros(2)  # the lagged wheel speed targets, rad/s
        self.received = []  # (t, left, right) of every command received: what the robot was asked
        self.frames = 0
        self._p = pybullet
        self._client = pybullet.connect(pybullet.DIRECT)
        self._build(start_pose)
        if self.state_path is not None and self.state_path.exists():
            self._restore()

    # ------------------------------------------------------------------------------------------ the body
    def _build(self, pose):
        p, c, truth = self._p, self._client, self.truth
        p.setGravity(0, 0, -9.81, physicsClientId=c)
        p.setTimeStep(PHYSICS_DT_S, physicsClientId=c)
        floor = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c)
        self._floor = p.createMultiBody(0, floor, physicsClientId=c)
        p.changeDynamics(self._floor, -1, lateralFriction=1.0, physicsClientId=c)
        r_mean = (truth.radius_left_m + truth.radius_right_m) / 2.0
        com = COM_IN_BASE_M
        chassis = p.createCollisionShape(p.GEOM_BOX, halfExtents=(0.09, 0.06, 0.02),
                                         collisionFramePosition=tuple(np.array([-0.04, 0.0, 0.035]) - com),
                                         physicsClientId=c)
        wheels = [p.createCollisionShape(p.GEOM_SPHERE, radius=r, physicsClientId=c)
                  for r in (truth.radius_left_m, truth.radius_right_m)]
        caster = p.createCollisionShape(p.GEOM_SPHERE, radius=CASTER_RADIUS_M, physicsClientId=c)
        self._body = p.createMultiBody(
            CHASSIS_MASS_KG, chassis, -1, basePosition=(pose[0], pose[1], r_mean + com[2]),
            baseOrientation=p.getQuaternionFromEuler((0, 0, pose[2])),
            linkMasses=[WHEEL_MASS_KG, WHEEL_MASS_KG, CASTER_MASS_KG], linkCollisionShapeIndices=wheels + [caster],
            linkVisualShapeIndices=[-1, -1, -1],
            linkPositions=[tuple(np.array(xyz) - com) for xyz in (
                (0, truth.baseline_m / 2, truth.radius_left_m - r_mean),
                (0, -truth.baseline_m / 2, truth.radius_right_m - r_mean),
                (-CASTER_BEHIND_M, 0, CASTER_RADIUS_M - r_mean))],
            linkOrientations=[(0, 0, 0, 1)] * 3, linkInertialFramePositions=[(0, 0, 0)] * 3,
            linkInertialFrameOrientations=[(0, 0, 0, 1)] * 3, linkParentIndices=[0, 0, 0],
            linkJointTypes=[p.JOINT_REVOLUTE, p.JOINT_REVOLUTE, p.JOINT_FIXED],
            linkJointAxis=[(0, 1, 0), (0, 1, 0), (0, 0, 1)], physicsClientId=c)
        for link in (0, 1):
            p.changeDynamics(self._body, link, lateralFriction=WHEEL_FRICTION, rollingFriction=0.0,
                             spinningFriction=0.0, physicsClientId=c)
            p.setJointMotorControl2(self._body, link, p.VELOCITY_CONTROL, targetVelocity=0.0,
                                    force=WHEEL_TORQUE_NM, physicsClientId=c)
        p.changeDynamics(self._body, 2, lateralFriction=0.0, rollingFriction=0.0, spinningFriction=0.0,
                         physicsClientId=c)  # a ball caster: no resistance in any direction
        p.changeDynamics(self._body, -1, lateralFriction=0.0, physicsClientId=c)
        for _ in range(int(0.2 / PHYSICS_DT_S)):  # settle on the floor before the clock starts
            p.stepSimulation(physicsClientId=c)
        self._place(pose)

    def _place(self, pose):
        """Put the body at rest at planar `pose` (on the floor as settled)."""
        p, c = self._p, self._client
        position, _ = p.getBasePositionAndOrientation(self._body, physicsClientId=c)
        com = rot_z(pose[2]) @ COM_IN_BASE_M
        p.resetBasePositionAndOrientation(self._body, (pose[0] + com[0], pose[1] + com[1], position[2]),
                                          p.getQuaternionFromEuler((0, 0, pose[2])), physicsClientId=c)
        p.resetBaseVelocity(self._body, (0, 0, 0), (0, 0, 0), physicsClientId=c)
        for link in (0, 1):
            p.resetJointState(self._body, link, 0.0, 0.0, physicsClientId=c)

    def pose(self) -> np.ndarray:
        """The true planar pose (x, y, theta) of the base frame (tests and benchmarks only: hidden from the agent)."""
        position, orientation = self._p.getBasePositionAndOrientation(self._body, physicsClientId=self._client)
        R = np.array(self._p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        axle = np.asarray(position) - R @ COM_IN_BASE_M
        return np.array([axle[0], axle[1], math.atan2(R[1, 0], R[0, 0])])

    def carry(self, forward_m: float, left_m: float, turn_rad: float) -> None:
        """Pick the robot up and set it down elsewhere, at rest (what hands do between a stopped run and its resume;
        tests only): moved by (forward, left) in its own frame and turned counter-clockwise by turn_rad."""
        x, y, theta = self.pose()
        c, s = math.cos(theta), math.sin(theta)
        self._place((x + c * forward_m - s * left_m, y + s * forward_m + c * left_m, theta + turn_rad))
        self.duties, self.wheel_w = np.zeros(2), np.zeros(2)
        self._save()

    # ------------------------------------------------------------------------------------------ the motors
    def motor_speeds(self, duties) -> np.ndarray:
        """Steady wheel speeds (rad/s, left, right) the motors reach for duties."""
        duties = np.asarray(duties, dtype=float)
        gains = np.array([self.truth.motor_left_radps, self.truth.motor_right_radps])
        if self.ideal:
            return gains * duties
        pwm = duty_to_pwm(duties)
        return np.sign(duties) * gains * np.maximum(pwm - self.truth.pwm_dead, 0.0) * (pwm > 0) / (PWM_MAX - PWM_MIN)

    def now(self) -> float:
        return self.t_s

    def command(self, left: float, right: float) -> float:
        """Set the duties (held until the next command); returns the robot time they took effect. A duty that is not
        a finite number within [-1, 1] is refused (SafetyError), never clipped: the caller has a bug."""
        for name, duty in (("left", left), ("right", right)):
            problem = duty_problem(name, duty)
            if problem:
                raise SafetyError(f"refused wheel command: {problem}")
        self.duties = np.array([float(left), float(right)])
        self.received.append((self.t_s, float(left), float(right)))
        self._save()
        return self.t_s

    def advance(self, duration_s: float, poses: list | None = None) -> None:
        """Let `duration_s` of robot time pass under the current duties; `poses` collects the pose every step."""
        p, c = self._p, self._client
        target = self.motor_speeds(self.duties)
        lags = np.array([self.truth.lag_left_s, self.truth.lag_right_s])
        for _ in range(max(0, int(round(duration_s / PHYSICS_DT_S)))):
            if self.ideal:
                self.wheel_w = target
            else:
                self.wheel_w = self.wheel_w + (target - self.wheel_w) * (1.0 - np.exp(-PHYSICS_DT_S / lags))
            rolling = self.wheel_w * (1.0 - np.array([self.truth.slip_left, self.truth.slip_right]))
            for link in (0, 1):  # the wheels turn as the body moves over the floor: friction has nothing to fight
                p.setJointMotorControl2(self._body, link, p.VELOCITY_CONTROL, targetVelocity=float(rolling[link]),
                                        force=WHEEL_TORQUE_NM, physicsClientId=c)
            self._roll()
            p.stepSimulation(physicsClientId=c)
            self.t_s += PHYSICS_DT_S
            if poses is not None:
                poses.append(self.pose())
        self._save()

    def _roll(self) -> None:
        """The body follows its wheels' ground speeds (each wheel's rolling speed less its tyre slip) at every physics
        step; the contacts keep it on the floor. Left to PyBullet's friction alone, the body lagged its wheels by
        10-15 % of every 0.1 s one-wheel step, losing more starting than it made up stopping (25-45 mrad of a
        240 mrad step, at any friction 1-5 and motor torque 0.06-2 N m), and the joint fit, whose model holds each
        command from its row, failed on it (docs/DUCKIEBOT.md)."""
        p, c, truth = self._p, self._client, self.truth
        v_left, v_right = self.wheel_w * (truth.radius_left_m * (1.0 - truth.slip_left),
                                          truth.radius_right_m * (1.0 - truth.slip_right))
        v, omega = (v_left + v_right) / 2.0, (v_right - v_left) / truth.baseline_m
        theta = self.pose()[2]
        com = rot_z(theta) @ COM_IN_BASE_M
        linear = np.array([v * math.cos(theta) - omega * com[1], v * math.sin(theta) + omega * com[0], 0.0])
        p.resetBaseVelocity(self._body, linear.tolist(), (0.0, 0.0, omega), physicsClientId=c)

    # ------------------------------------------------------------------------------------------ the camera
    def grab(self) -> tuple[float, np.ndarray]:
        """(mid-exposure robot time, grey image): the robot keeps moving through the exposure."""
        rng = np.random.default_rng([self.seed, 1000 + self.frames])
        poses = [self.pose()]
        t0 = self.t_s
        if self.exposure_s > 0:
            self.advance(self.exposure_s, poses)
        self.frames += 1
        self._save()
        poses = np.array(poses)
        # sub-poses enough that the image moves at most about a pixel between them (fx ~ 340 px: a radian of
        # turn is 340 px, a metre of travel at 0.3 m about 1100 px)
        moved_px = 340.0 * abs(poses[-1, 2] - poses[0, 2]) + 1100.0 * np.linalg.norm(poses[-1, :2] - poses[0, :2])
        n = 1 if self.ideal else int(min(8, 1 + math.ceil(moved_px)))
        if n == 1:
            image = self.renderer.render(poses[len(poses) // 2], rng, noise_grey=self.noise_grey)
        else:
            picks = poses[np.linspace(0, len(poses) - 1, n).round().astype(int)]
            mean = np.mean([self.renderer.render(q, noise_grey=0.0).astype(np.float32) for q in picks], axis=0)
            image = np.clip(np.rint(mean + rng.normal(0.0, self.noise_grey, mean.shape)), 0, 255).astype(np.uint8)
        return t0 + self.exposure_s / 2.0, image

    # ------------------------------------------------------------------------------------------ persistence
    def _save(self) -> None:
        if self.state_path is None:
            return
        doc = {"seed": self.seed, "realism": self.realism, "t_s": self.t_s, "pose": self.pose().tolist(),
               "duties": self.duties.tolist(), "frames": self.frames}
        atomic_write_text(self.state_path, json.dumps(doc) + "\n")

    def _restore(self) -> None:
        doc = read_json(self.state_path)
        if doc.get("seed") != self.seed or doc.get("realism") != self.realism:
            raise NaocalError(f"{self.state_path}: the mock saved there is seed {doc.get('seed')!r} "
                              f"({doc.get('realism')!r}), not seed {self.seed} ({self.realism}) (nothing was changed)")
        self._place(doc["pose"])
        self.t_s = float(doc["t_s"]) + RESTORE_GAP_S
        self.frames = int(doc["frames"])
        self.duties = np.zeros(2)  # the driver's watchdog stopped the wheels while nobody commanded them

    def close(self) -> None:
        if self._client is not None:
            self._p.disconnect(physicsClientId=self._client)
            self._client = None
