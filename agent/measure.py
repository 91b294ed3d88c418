"""Measurement: execute a plan on the robot, capture, detect, and save every capture at once.

A still capture: command the stance (checked), wait until the joints are still, take the first image exposed after
that (images arrive later than joint readings: wait it out), read the joints, detect the board with the running
estimate's predicted projection, and append the capture to the dataset (fsync) with its image. A missed detection
is retried with a small head move; after `detection_tries` the capture is skipped with a logged reason.

A sweep (the lag probe): from rest at its start, move slowly to its end while sampling the joints at their full
rate and taking images on the way; each image's joint angles are interpolated to its exposure time and its joint
velocities recorded (vel_<Joint> columns), so that a lag between the image and joint clocks becomes measurable.
A sweep comes when every joint offset is known well enough for the plain safety check (at the end, if not before).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from naocal.agent.camera_estimate import CameraEstimate
from naocal.agent.corners import detect_board_vertices
from naocal.agent.estimate import RunningEstimate
from naocal.agent.plan import Plan, Still, Sweep
from naocal.agent.planner import PlanSettings
from naocal.agent.progress import ProgressBar
from naocal.agent.record import CaptureRecord, CaptureStore
from naocal.agent.robot import Robot
from naocal.agent.safety import prior_covariance
from naocal.agent.visibility import OcclusionChecker, view_margin_px
from naocal.solver.errors import SafetyError
from naocal.solver.joints import HEAD_COLUMNS, JOINTS, LEG_COLUMNS
from naocal.solver.limits import head_pitch_limits

log = logging.getLogger(__name__)

# detector(image, predicted_px (24, 2), leg, search_margin_px) -> object with .ok, .vertices_px, .reason, .detail
Detector = Callable


def opencv_detector(image, predicted_px, leg, search_margin_px):
    """naocal.agent.corners' guided detection; if the prediction's shape is too far off for it (a leg whose offsets the
    estimate does not know yet, an effect the model lacks), OpenCV's whole-board detector finds the board, and the
    guided detection runs again from what it found (so its checks - hidden vertices, square pattern - still apply)."""
    first = detect_board_vertices(image.pixels, predicted_px, search_margin_px=search_margin_px)
    if first.ok or first.reason == "cut_off":
        return first
    rough = detect_board_vertices(image.pixels, predicted_px, search_margin_px=search_margin_px, method="sb")
    if not rough.ok:
        return first
    again = detect_board_vertices(image.pixels, rough.vertices_px, search_margin_px=10.0)
    return again if again.ok else first


@dataclass(frozen=True)
class MeasureSettings:
    detection_tries: int = 3
    retry_head_step_rad: float = 0.04
    aim_margin_px: float = 15.0  # re-aim the head before a capture whose board the estimate puts this near the edge
    search_margin_px_nominal: float = 120.0  # before the first fit the camera may be off by degrees
    search_margin_px_fitted: float = 40.0
    known_fit_rms_px: float = 2.0  # the estimate predicts a leg's board well enough for the narrow margin
    wait_for_still_image: bool = True  # False pairs still joints with an older image: only to show the error
    sweep_fit_halfwidth_s: float = 0.05  # joint samples within this of an exposure give its angle and velocity


class Measurement:
    """Runs the plan's steps that are not done yet (resume: those in the dataset or skipped are done)."""

    def __init__(self, robot: Robot, plan: Plan, store: CaptureStore, estimate: RunningEstimate,
                 detector: Detector = opencv_detector, settings: MeasureSettings = MeasureSettings(),
                 progress: ProgressBar | None = None):
        self.robot = robot
        self.plan = plan
        self.store = store
        self.estimate = estimate
        self.detector = detector
        self.settings = settings
        self.progress = progress
        self.intrinsics = estimate.intrinsics
        stored = PlanSettings.from_dict(plan.settings)  # the plausible offsets the plan was made for
        self.offset_prior = prior_covariance(np.radians(stored.hip_yaw_pitch_offset_prior_deg),
                                             np.radians(stored.leg_offset_prior_deg))
        self.session_start_s = robot.now()
        self.n_saved = 0
        self.n_skipped = 0
        self._substitutes: dict = {}  # (leg, stance) -> leg angles (6,) replacing a stance unsafe on this robot
        # Cameras other than the running estimate's (the top camera): their rotation learnt from their captures.
        self.other_cameras = {"top": CameraEstimate("top", self.intrinsics, stored.camera_prior_rad)}

    # --- bookkeeping -------------------------------------------------------------------------------------------
    def session_time_s(self) -> float:
        return self.robot.now() - self.session_start_s

    def robot_time_s(self) -> float:
        """Robot time spent measuring, over all sessions of this run."""
        return self.store.robot_time_s(self.session_time_s())

    def _done(self) -> int:
        return len(self.store.done_images() & set(self.plan.image_indices()))

    def _tick(self) -> None:
        if self.progress:
            self.progress.update(self._done(), f"robot time {self.robot_time_s():6.1f} s, skipped "
                                               f"{len(self.store.skipped_images())}")

    def _save(self, record: CaptureRecord, pixels) -> None:
        self.store.save(record, pixels, self.session_time_s())
        self.n_saved += 1

    def _skip(self, image: int, reason: str) -> None:
        self.store.skip(image, reason, self.session_time_s())
        self.n_skipped += 1

    # --- the run -----------------------------------------------------------------------------------------------
    def _update_guard(self) -> None:
        """Let the safety check use what the estimate knows: joints truly stand at command + alpha, sandals sit
        where they are mounted."""
        self.robot.guard.set_true_offset(self.estimate.joint_alpha(), known=self.estimate.offsets_known(),
                                         covariance14=self.estimate.joint_covariance(self.offset_prior))
        if self.robot.guard.set_board_mounts(self.estimate.board_mounts()):
            log.info("safety check updated with the estimated sandal mounts")

    def run(self) -> None:
        self._update_guard()
        done = self.store.done_images()
        if done:
            log.info("resuming: %d of %d captures already done", len(done & set(self.plan.image_indices())),
                     self.plan.n_images())
        self._tick()
        deferred: list[Still] = []  # refused while the leg's offsets were too uncertain: tried again later
        sweeps: list[Sweep] = []  # lag probes put off until the offsets are known
        steps = list(self.plan.steps)
        for k, step in enumerate(steps):
            if all(i in done for i in step.images):
                continue
            if isinstance(step, Still):
                if self.still(step, may_defer=True) == "deferred":
                    deferred.append(step)
            elif self.robot.guard.uncertain():  # a slow sweep needs clear ways: once every offset is known
                sweeps.append(step)
            else:
                self.sweep(step, done)
            done = self.store.done_images()
            following = steps[k + 1] if k + 1 < len(steps) else None
            if deferred and (following is None or following.leg != step.leg or not isinstance(following, Still)):
                self.estimate.refit()  # the leg's other stances have taught the estimate where it truly is
                self._update_guard()
                for again in deferred:
                    self.still(again)
                    done = self.store.done_images()
                    self._tick()
                deferred = []
            self._tick()
        for step in sweeps:
            self.sweep(step, self.store.done_images())
            self._tick()
        try:
            self.robot.move(self.robot.parked)  # leave the robot in a safe posture
        except SafetyError as err:
            log.warning("could not park the robot after measuring: %s", err)
        if self.progress:
            self.progress.finish(f"robot time {self.robot_time_s():6.1f} s")

    def _search_margin(self, leg: str, attempt: int = 0) -> float:
        """How far the board may lie from the prediction: wide until the estimate has seen this leg and fits it
        to a pixel or two, and wider with every retry (up to three times the wide margin while it has not: real
        offsets move an unseen board by a hundred pixels and more)."""
        s = self.settings
        known = self.estimate.knows(leg) and max(self.estimate.rms_px) < s.known_fit_rms_px
        base = s.search_margin_px_fitted if known else s.search_margin_px_nominal
        return min(base * (1 + attempt), s.search_margin_px_nominal * (1 if known else 3))

    def _detect(self, image, leg, theta14, attempt: int = 0, camera: str = "bottom"):
        if camera == "bottom":
            predicted = self.estimate.predict(leg, theta14)
            margin = self._search_margin(leg, attempt)
        else:  # its rotation is known once it has a capture; the wide margin until then
            other = self.other_cameras[camera]
            predicted = other.predict(self.estimate, leg, theta14)
            s = self.settings
            known = other.fitted and max(other.rms_px) < s.known_fit_rms_px
            margin = (s.search_margin_px_fitted if known else s.search_margin_px_nominal) * (1 + attempt)
        return self.detector(image, predicted, leg, margin), predicted

    # --- still captures ----------------------------------------------------------------------------------------
    def still(self, step: Still, *, may_defer: bool = False) -> str:
        """Capture one planned still image; 'saved', 'skipped', or 'deferred' (`may_defer`: the move was refused
        only because the joint offsets are not known well enough yet). A stance that is unsafe on this robot (its
        offsets move the legs by centimetres from the nominal model the plan was made on) is replaced by a nearby
        one the estimate says is safe and sees the board (`substitute`), the same for all its head postures."""
        planned = self._substituted(step)
        bottom = step.camera == "bottom"  # the running estimate substitutes and learns from bottom images
        target = self.aim(planned, step.leg, step.camera)  # the top camera: once its rotation is learnt
        reasons = []
        for attempt in range(self.settings.detection_tries):
            try:
                rest = self.robot.move(target)
            except SafetyError as err:
                if may_defer and attempt == 0 and self.robot.guard.uncertain():
                    log.info("capture %d deferred until the offsets are better known: %s", step.image, err)
                    return "deferred"
                replacement = (self.substitute(step) if bottom and attempt == 0 and step.leg in self.estimate.known_legs
                               else None)
                if replacement is not None:
                    log.info("capture %d: the planned stance is unsafe on this robot (%s); a nearby one instead",
                             step.image, err)
                    target = self.aim(replacement, step.leg)
                    try:
                        rest = self.robot.move(target)
                    except SafetyError as again:
                        reasons.append(f"{err}; the substitute too: {again}")
                        break
                else:
                    reasons.append(str(err))
                    break
            if self.settings.wait_for_still_image:
                image = self.robot.wait_image(rest.t_still_s + self.robot.timing.exposure_guard_s, step.camera)
            else:
                image = self.robot.newest_image(step.camera)
            t_joints, theta = self.robot.read()
            detection, _ = self._detect(image, step.leg, theta, attempt, step.camera)
            if detection.ok:
                record = CaptureRecord(step.image, step.leg, step.stance, step.head_posture,
                                       np.asarray(detection.vertices_px, dtype=float), theta, self.robot.commanded.copy(),
                                       self.robot.direction.copy(), np.zeros(len(JOINTS)), float(image.t_exposure_s),
                                       float(t_joints), step.camera)
                self._save(record, image.pixels)
                if bottom:
                    self.estimate.add(step.leg, theta, record.vertices_px)
                    self._update_guard()
                else:
                    self.other_cameras[step.camera].add(self.estimate, step.leg, theta, record.vertices_px)
                return "saved"
            reasons.append(f"try {attempt + 1}: {detection.reason} ({detection.detail})")
            log.info("capture %d: detection failed (%s: %s); retrying with a small head move", step.image,
                     detection.reason, detection.detail)
            target = self.retry_target(target, step.leg, attempt, camera=step.camera)
            if target is None:
                reasons.append("no safe head move left to retry with")
                break
        self._skip(step.image, "; ".join(reasons))
        return "skipped"

    def _substituted(self, step: Still) -> np.ndarray:
        """The step's posture, with its stance's substitute leg angles if it has one."""
        q = np.asarray(step.angles(), dtype=float)
        legs = self._substitutes.get((step.leg, step.stance))
        if legs is not None:
            q = q.copy()
            q[LEG_COLUMNS[step.leg]] = legs
            q[[JOINTS.index("LHipYawPitch"), JOINTS.index("RHipYawPitch")]] = legs[0]  # one motor
        return q

    def substitute(self, step: Still, *, tries_per_scale: int = 25) -> np.ndarray | None:
        """A posture near the step's that the guard accepts (at the estimated offsets, with their uncertainty) and
        in which the estimate sees the whole board (all vertices 30 px inside the image, squares of 12 px, nothing
        of the robot in between), or None. Deterministic from the image index; remembered for the whole stance."""
        base = np.asarray(step.angles(), dtype=float)
        cols = LEG_COLUMNS[step.leg]
        guard = self.robot.guard
        rng = np.random.default_rng([step.image, 6007])
        hyp = [JOINTS.index("LHipYawPitch"), JOINTS.index("RHipYawPitch")]
        occlusion = OcclusionChecker(guard.checker.body)
        alpha = self.estimate.joint_alpha()
        ways_tried = 0
        for scale in (0.08, 0.16, 0.3):
            for _ in range(tries_per_scale):
                if ways_tried == 4:  # finding a way is the costly part: a few candidates only
                    return None
                q = base.copy()
                q[cols] = np.clip(q[cols] + rng.normal(0.0, scale, len(cols)), guard.lower[cols] + 0.03,
                                  guard.upper[cols] - 0.03)
                q[hyp] = q[cols[0]]
                if not self._board_in_view(q, step.leg) or guard.problem(q) is not None:
                    continue
                if occlusion.hidden_points(q + alpha, step.leg):
                    continue
                ways_tried += 1
                try:  # and there is a way to it
                    guard.waypoints(self.robot.commanded, q, self.robot.speed_fraction, self.robot.parked)
                except SafetyError:
                    continue
                self._substitutes[(step.leg, step.stance)] = q[cols].copy()
                return q
        return None

    def _board_in_view(self, q14, leg, margin_px: float = 30.0, min_square_px: float = 12.0) -> bool:
        uv = self.estimate.predict(leg, q14)
        if not np.all(np.isfinite(uv)):
            return False
        if view_margin_px(uv[None], self.intrinsics["width_px"], self.intrinsics["height_px"])[0] < margin_px:
            return False
        grid = uv.reshape(4, 6, 2)
        return min(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(),
                   np.linalg.norm(np.diff(grid, axis=1), axis=-1).min()) >= min_square_px

    def _head_ok(self, q14) -> bool:
        return self.robot.guard.problem(q14) is None

    def feasible_head(self, q14) -> np.ndarray | None:
        """q14 with the head moved to the nearest posture the guard accepts (HeadYaw within the guard's limits:
        the robot description's command range, +-0.7 rad, as the planner's; HeadPitch inside the HeadYaw table,
        raised in small steps if the head comes too near the ground), or None."""
        q = np.array(q14, dtype=float)
        yaw_col, pitch_col = HEAD_COLUMNS
        guard = self.robot.guard
        q[yaw_col] = np.clip(q[yaw_col], guard.lower[yaw_col], guard.upper[yaw_col])
        lo, hi = head_pitch_limits(q[yaw_col])
        m = self.robot.guard.head_pitch_margin_rad + 0.005
        q[pitch_col] = np.clip(q[pitch_col], lo + m, hi - m)
        while q[pitch_col] <= hi - m + 1e-12:
            if self._head_ok(q):
                return q
            q[pitch_col] += 0.02
        return None

    def _predict(self, leg, q14, camera: str = "bottom") -> np.ndarray:
        """Where the estimate puts `leg`'s board vertices (24, 2) in `camera` at angles q14."""
        if camera == "bottom":
            return self.estimate.predict(leg, q14)
        return self.other_cameras[camera].predict(self.estimate, leg, q14)

    def recentred(self, target14, leg, camera: str = "bottom") -> np.ndarray:
        """target14 with the head turned so that the estimate puts the board's centre at the image centre
        (at most 0.15 rad of head motion)."""
        def centre(q):
            return self._predict(leg, q, camera).mean(axis=0)

        c0 = centre(target14)
        goal = np.array([self.intrinsics["cx_px"], self.intrinsics["cy_px"]])
        J = np.empty((2, 2))
        for k, col in enumerate(HEAD_COLUMNS):
            q = target14.copy()
            q[col] += 1e-3
            J[:, k] = (centre(q) - c0) / 1e-3
        step = -np.linalg.lstsq(J, c0 - goal, rcond=None)[0]
        norm = np.linalg.norm(step)
        if norm > 0.15:
            step *= 0.15 / norm
        out = target14.copy()
        out[HEAD_COLUMNS] += step
        return out

    def aim(self, target14, leg, camera: str = "bottom") -> np.ndarray:
        """The planned posture, or with the head re-aimed if the estimate puts the board near the image edge."""
        predicted = self._predict(leg, target14, camera)
        margin = view_margin_px(predicted[None], self.intrinsics["width_px"], self.intrinsics["height_px"])[0]
        if margin >= self.settings.aim_margin_px:
            return target14
        moved = self.feasible_head(self.recentred(target14, leg, camera))
        if moved is None:
            return target14
        new_margin = view_margin_px(self._predict(leg, moved, camera)[None], self.intrinsics["width_px"],
                                    self.intrinsics["height_px"])[0]
        if new_margin <= margin:
            return target14
        log.info("re-aiming the head: the estimate puts the board %.0f px from the image edge (%.0f px after)",
                 margin, new_margin)
        return moved

    def retry_target(self, target14, leg, attempt, *, camera: str = "bottom") -> np.ndarray | None:
        """A small head move for another try: re-centre the board, then a step in one of four directions."""
        s = self.settings.retry_head_step_rad
        pattern = [(s, 0.0), (-s, 0.0), (0.0, -s), (0.0, s)]
        base = self.recentred(target14, leg, camera)
        for k in range(len(pattern)):
            dyaw, dpitch = pattern[(attempt + k) % len(pattern)]
            q = base.copy()
            q[HEAD_COLUMNS] += (dyaw, dpitch)
            q = self.feasible_head(q)
            if q is not None and np.max(np.abs(q - target14)) > 1e-3:
                return q
        return None

    # --- the lag probe -----------------------------------------------------------------------------------------
    def sweep(self, step: Sweep, done: set) -> None:
        wanted = [k for k, i in enumerate(step.images) if i not in done]
        start, end = step.start(), step.end()
        for shrink in (1.0, 0.5):  # the true robot may sit closer to itself than planned: then a shorter sweep
            middle = (start + end) / 2.0
            a, b = middle + shrink * (start - middle), middle + shrink * (end - middle)
            try:
                self.robot.guard.check(b)
                if not self.robot.guard.path_clear(a, b, step.speed_fraction):
                    raise SafetyError("the sweep's way is not clear")
                self.robot.move(a)
                break
            except SafetyError as err:
                reason = err
                log.info("lag probe of leg %s at %.0f %% length refused: %s", step.leg, 100 * shrink, err)
        else:
            for k in wanted:
                self._skip(step.images[k], f"lag probe: {reason}")
            return
        end = b
        samples = []  # (t, angles14)
        t_command = self.robot.now()
        duration = self.robot.command(end, step.speed_fraction)
        exposures = [t_command + f * duration for f in step.exposure_fractions]
        images = {}
        frame_s = 1.0 / 30.0
        tm = self.robot.timing
        k = 0
        while self.robot.now() < t_command + duration:  # a deadline: the robot clock always advances
            t, q = self.robot.read()
            if not samples or t > samples[-1][0]:
                samples.append((t, q))
            if k < len(exposures) and self.robot.now() >= exposures[k] + self.robot.image_delay_s:
                image = self.robot.backend.capture()
                if image is not None and image.t_exposure_s >= exposures[k] - frame_s / 2:
                    images[k] = image
                    k += 1
            self.robot.backend.sleep(tm.sample_period_s)
        self.robot.wait_still(end, 0.0, self.robot.now())
        times = np.array([s[0] for s in samples])
        angles = np.array([s[1] for s in samples])
        for k in wanted:
            index = step.images[k]
            image = images.get(k)
            if image is None:
                self._skip(index, "lag probe: no image arrived during the sweep")
                continue
            fit = self._angles_at(times, angles, image.t_exposure_s)
            if fit is None:
                self._skip(index, "lag probe: too few joint samples around the exposure")
                continue
            theta, velocity = fit
            detection, _ = self._detect(image, step.leg, theta)
            if not detection.ok:
                self._skip(index, f"lag probe: {detection.reason} ({detection.detail})")
                continue
            record = CaptureRecord(index, step.leg, step.stance, 0, np.asarray(detection.vertices_px, dtype=float),
                                   theta, end, self.robot.direction.copy(), velocity,
                                   float(image.t_exposure_s), float(image.t_exposure_s))
            self._save(record, image.pixels)

    def _angles_at(self, times, angles, t):
        """Angles (14,) and velocities (14,) at time t from a local straight-line fit to the joint samples within
        sweep_fit_halfwidth_s of t (both sides needed); None if the samples do not surround t."""
        h = self.settings.sweep_fit_halfwidth_s
        near = np.abs(times - t) <= h
        if near.sum() < 4 or not (times[near].min() < t < times[near].max()):
            return None
        dt = times[near] - t
        A = np.column_stack([np.ones_like(dt), dt])
        coef, *_ = np.linalg.lstsq(A, angles[near], rcond=None)
        return coef[0], coef[1]
