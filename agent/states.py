"""The agent's states and the context (blackboard) they share.

    modelling -> measurement -> identification -> compensation -> verification -> done   (agent.machine.TRANSITIONS)

Each state names the context fields it needs and produces. Files, all under the output directory DIR:
plan.json (modelling), dataset/ + progress.json (measurement), offsets.json (+ .bak; compensation),
verification/ and verification.json (verification).
"""

from __future__ import annotations

import json
import logging
import math
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from naocal.agent.estimate import FULL, RunningEstimate
from naocal.agent.machine import Outcome, State
from naocal.agent.measure import Measurement, MeasureSettings, opencv_detector
from naocal.agent.plan import read_plan, write_plan
from naocal.agent.planner import PlanSettings, Planner
from naocal.agent.progress import ProgressBar
from naocal.agent.record import CaptureStore
from naocal.agent.robot import Robot, TimingSettings
from naocal.agent.safety import KNOWN_OFFSET_MARGIN_M, SafetyGuard
from naocal.agent.verify import identified_intrinsics, verify
from naocal.backends.compensated import CompensatedBackend
from naocal.body.nao_body import CollisionChecker, NaoBody
from naocal.solver.adapter import model_data_from_dataset
from naocal.solver.dataset import read_dataset
from naocal.solver.errors import SafetyError
from naocal.solver.errors import NaocalError
from naocal.solver.fileio import atomic_write_text
from naocal.solver.fit import identify_dataset
from naocal.solver.joints import JOINTS, LEGS
from naocal.solver.offsets import (MAX_BOARD_ROT_Z_RAD, MAX_BOARD_TRANS_M, MAX_CAMERA_ROTATION_RAD, MAX_JOINT_OFFSET_RAD,
                            offsets_from_result, write_offsets)

log = logging.getLogger(__name__)

# The verification state's last write, so the mark of a finished run: a DIR holding it has nothing left to do.
VERIFICATION_NAME = "verification.json"


def run_finished(out_dir: Path) -> bool:
    """Did the run in `out_dir` end done? (Every state before verification leaves files a resume continues from;
    verification.json is written last, once everything else is.)"""
    return (Path(out_dir) / VERIFICATION_NAME).is_file()


@dataclass(frozen=True)
class Thresholds:
    """When an identification is plausible enough to compensate with (beyond a max_: refused), and when it is
    unusual enough to say so (beyond a warn_: a warning, and the offsets are used). Real robots: HipYawPitch offsets
    up to 11.5 deg (HULKs), camera pitch corrections -6..+2 deg with outliers of 7-14 deg (docs/MOCK.md)."""

    max_rms_px: float = 5.0  # the paper's real robot kept ~3 px; far more means a wrong model or bad data
    max_joint_offset_rad: float = MAX_JOINT_OFFSET_RAD  # 20 deg, the offsets file's own limit
    warn_joint_offset_rad: float = math.radians(8.0)
    max_camera_rotation_rad: float = MAX_CAMERA_ROTATION_RAD  # 15 deg
    warn_camera_rotation_rad: float = math.radians(7.0)
    max_board_trans_m: float = MAX_BOARD_TRANS_M
    max_board_rot_z_rad: float = MAX_BOARD_ROT_Z_RAD
    max_joint_offset_std_rad: float = math.radians(0.5)  # an offset known worse than this is no calibration


@dataclass
class AgentSettings:
    seed: int = 0
    plan: PlanSettings = field(default_factory=PlanSettings)
    measure: MeasureSettings = field(default_factory=MeasureSettings)
    timing: TimingSettings = field(default_factory=TimingSettings)
    thresholds: Thresholds = field(default_factory=Thresholds)
    speed_fraction: float = 0.4
    command_margin_rad: float = 0.02  # the agent's own margin to the joint limits for every command
    collision_margin_m: float = 0.015  # the agent's own collision check of every command
    ground_margin_m: float = 0.012
    known_offset_margin_m: float = KNOWN_OFFSET_MARGIN_M  # once the joint offsets are estimated
    resume: bool = False
    save_images: bool = True
    progress_bar: bool = True
    tie_hip_yaw_pitch: bool = True  # one motor, one sensor on the robot: one offset
    # Quantised readings (servos anywhere in their step): fit by GLS (solver.gls), intrinsics free. On the realistic
    # mock (paper plan, seed 1) the worst joint-offset error fell from 0.22 to 0.07 deg (docs/AGENT.md).
    gls: bool = True
    source: str = "naocal calibrate"
    mock_seed: int | None = None  # the mock's hidden truth (recorded in offsets.json), None for a real robot
    resume_command: str | None = None  # the command that continues this run (for summary.txt)


@dataclass
class Context:
    """Everything the states share. None = not produced yet."""

    backend: object
    settings: AgentSettings
    out_dir: Path
    dataset_dir: Path
    progress_path: Path | None
    plan_path: Path | None
    detector: object = opencv_detector
    # produced by the states:
    plan: object = None
    robot: Robot | None = None
    estimate: RunningEstimate | None = None
    meta: dict | None = None
    measurement: dict | None = None
    identification: object = None
    angle_choice: object = None  # the fit's evidence: angles chosen, outliers (solver.fit.DatasetFit)
    offsets: object = None
    compensated: CompensatedBackend | None = None
    verification: object = None
    store: CaptureStore | None = None  # the captures being saved (what an interrupted measurement got)
    summary: str | None = None  # summary.txt's text (set by agent.calibrate.calibrate)
    summary_error: str | None = None  # why summary.txt could not be written (a full disk)
    # owned resources (closed by close())
    _bodies: list = field(default_factory=list)
    _guards: list = field(default_factory=list)

    def close(self) -> None:
        if self.robot is not None:
            self.robot.guard.close()
        for guard in self._guards:
            guard.close()
        for body in self._bodies:
            body.close()
        self._bodies.clear()


def dataset_meta(backend, source: str) -> dict:
    """dataset.json (naocal.dataset/2) of a run: the robot's identity, its camera's prior intrinsics, the sandals
    as the robot description has them, its gravity."""
    from naocal.solver.robot import nao

    identity = backend.robot_identity()
    camera = backend.intrinsics().to_dict()
    name = camera.pop("name", "bottom")
    sandals = {leg: nao().target(leg) for leg in LEGS}
    return {
        "schema": "naocal.dataset/2",
        "robot": {"id": str(identity.get("id", "unknown")), "model": str(identity.get("model", "NAO")),
                  "body_id": str(identity.get("body_id", identity.get("id", "unknown"))),
                  "head_id": str(identity.get("head_id", identity.get("id", "unknown"))), "description": "nao"},
        "cameras": {name: camera, "top": dict(camera)},  # the backend states one prior: both NAO cameras' lens
        "targets": {leg: {"columns": t.board.columns, "rows": t.board.rows, "square_m": t.board.square_m,
                          "mass_kg": t.board.mass_kg, "centre_m": [float(x) for x in t.centre]}
                    for leg, t in sandals.items()},
        "joints": list(JOINTS),
        "source": source,
        "gravity_mps2": [float(g) for g in backend.gravity_torso_mps2()],
    }


def make_guard(backend, settings: AgentSettings, body: NaoBody) -> SafetyGuard:
    checker = CollisionChecker(body, margin_m=settings.collision_margin_m, ground_margin_m=settings.ground_margin_m)
    return SafetyGuard(backend.joint_limits(), checker, backend.max_speeds(), margin_rad=settings.command_margin_rad,
                       known_offset_margin_m=settings.known_offset_margin_m)


class Modelling(State):
    """Load the model, the camera's prior intrinsics and the robot's identity; plan (or reload the plan)."""

    name = "modelling"
    needs = ("backend", "settings")
    produces = ("plan", "robot", "estimate", "meta")

    def run(self, ctx: Context) -> Outcome:
        s = ctx.settings
        backend = ctx.backend
        intrinsics = backend.intrinsics()
        ctx.meta = dataset_meta(backend, s.source)
        existing = (ctx.dataset_dir / "observations.csv").exists()
        if existing and not s.resume:
            raise NaocalError(f"{ctx.dataset_dir} already holds captures: continue it with --resume, or choose "
                              "another output directory (nothing was changed)")
        plan_settings = replace(s.plan, speed_fraction=s.speed_fraction, intrinsics={
            "fx_px": intrinsics.fx_px, "fy_px": intrinsics.fy_px, "cx_px": intrinsics.cx_px,
            "cy_px": intrinsics.cy_px, "width_px": intrinsics.width_px, "height_px": intrinsics.height_px,
            "distortion": [float(d) for d in intrinsics.distortion]})
        if s.resume and ctx.plan_path and ctx.plan_path.exists():
            plan = read_plan(ctx.plan_path)
            if plan.seed != s.seed:
                raise NaocalError(f"{ctx.plan_path}: this run was planned with --seed {plan.seed}, not {s.seed}; "
                                  "resume with the same seed")
            log.info("resuming with the stored plan %s (%d images)", ctx.plan_path, plan.n_images())
        else:
            if "top" not in backend.cameras:  # e.g. a LoLA bridge started with the bottom camera's V4L2 device
                log.info("the backend offers no top camera: the plan has bottom-camera stances only")
                plan_settings = replace(plan_settings, top_stances_per_leg=0)
            planner = Planner(plan_settings, limits=backend.joint_limits(), speeds=backend.max_speeds())
            try:
                plan = planner.make_plan(s.seed)
            finally:
                planner.close()
            if ctx.plan_path:
                write_plan(plan, ctx.plan_path)
            log.info("planned %d images (%s plan, seed %d): %d stances per leg, estimated robot time %.0f s",
                     plan.n_images(), plan.kind, plan.seed, plan.stats["n_stances"]["L"],
                     plan.stats["estimated_robot_time_s"])
        body = NaoBody()
        ctx._bodies.append(body)
        backend.set_stiffness(list(backend.joint_names()), 1.0)
        ctx.robot = Robot(backend, make_guard(backend, s, body), plan.parked(), s.timing, s.speed_fraction)
        stored = PlanSettings.from_dict(plan.settings)
        ctx.estimate = RunningEstimate(stored.intrinsics, camera_prior=stored.camera_prior_rad,
                                       max_joint_offset_rad=s.thresholds.max_joint_offset_rad)
        ctx.plan = plan
        return Outcome("ok")


class Measure(State):
    """Capture every planned image that is not in the dataset yet; `dataset_only` ends the run there."""

    name = "measurement"
    needs = ("plan", "robot", "estimate", "meta")
    produces = ("measurement",)

    def __init__(self, dataset_only: bool = False):
        self.dataset_only = dataset_only

    def run(self, ctx: Context) -> Outcome:
        s = ctx.settings
        store = CaptureStore(ctx.dataset_dir, ctx.meta, progress_path=ctx.progress_path, save_images=s.save_images)
        ctx.store = store
        if store.repair:
            log.warning(store.repair)
        progress = ProgressBar(ctx.plan.n_images(), enabled=s.progress_bar)
        measurement = Measurement(ctx.robot, ctx.plan, store, ctx.estimate, ctx.detector, s.measure, progress)
        self._warm_start(ctx, store, measurement.other_cameras)
        measurement.run()
        saved = store.saved_images() & set(ctx.plan.image_indices())
        ctx.measurement = {
            "robot_time_s": measurement.robot_time_s(),
            "n_planned": ctx.plan.n_images(),
            "n_saved": len(saved),
            "n_skipped": len(store.skipped_images()),
            "skipped": store.skipped_images(),
            "sessions": store.progress["sessions"],
        }
        log.info("measurement: %d of %d images saved, %d skipped, %.1f s of robot time", len(saved),
                 ctx.plan.n_images(), len(store.skipped_images()), measurement.robot_time_s())
        if not saved:
            raise NaocalError("no capture succeeded: nothing to identify")
        return Outcome("dataset_only" if self.dataset_only else "ok")

    @staticmethod
    def _warm_start(ctx: Context, store: CaptureStore, other_cameras: dict) -> None:
        """On resume, the running estimate learns from the bottom camera's captures already on disk, and each
        other camera's estimate (the top camera's rotation) from its own, held at the estimate's offsets: the
        first top capture after a resume is aimed and searched with the rotation learnt before, not relearnt."""
        if not store.saved_images():
            return
        dataset = read_dataset(ctx.dataset_dir)
        data = model_data_from_dataset(dataset)
        still = _still_images(data)
        others = []
        for m in still:
            rows = data.image_of_row == m
            if rows.sum() != data.robot.target(data.target[m]).board.n_vertices:
                continue  # only complete boards
            if data.camera[m] == "bottom":
                ctx.estimate.preload(str(data.leg[m]), data.theta[m], data.uv_px[rows])
            elif data.camera[m] in other_cameras:
                others.append((other_cameras[data.camera[m]], m, rows))
        ctx.estimate.refit()
        for camera_estimate, m, rows in others:
            camera_estimate.preload(str(data.leg[m]), data.theta[m], data.uv_px[rows])
        for camera_estimate in {id(c): c for c, _, _ in others}.values():
            camera_estimate.refit(ctx.estimate)


def _still_images(data) -> np.ndarray:
    """Indices of the images taken at rest (no vel_ columns, or all velocities zero)."""
    if data.velocity is None:
        return np.arange(data.n_images)
    return np.flatnonzero(np.all(data.velocity == 0.0, axis=1))


def _identification_setup(data_setup):
    """The robot's default cameras and targets plus those the data use, in the description's order."""
    from naocal.solver.effect import Setup

    default = Setup.default(data_setup.robot)
    cameras, targets = set(default.cameras + data_setup.cameras), set(default.targets + data_setup.targets)
    return Setup(data_setup.robot, tuple(c for c in data_setup.robot.cameras if c in cameras),
                 tuple(t for t in data_setup.robot.targets if t in targets))


class Identification(State):
    """Fit the paper's 21 parameters (HipYawPitch tied: one motor) to the still captures with `naocal identify`'s
    routine (solver.fit.identify_dataset, its defaults), so both give the same offsets from the same dataset;
    `implausible` if the fit cannot be trusted."""

    name = "identification"
    needs = ("measurement",)
    produces = ("identification",)

    def run(self, ctx: Context) -> Outcome:
        s = ctx.settings
        dataset = read_dataset(ctx.dataset_dir)
        # Every camera the data use and both sandals: a sandal without captures keeps its nominal mount (the
        # summary, offsets and guard name all its parameters).
        fit = identify_dataset(dataset, tie_shared_motors=s.tie_hip_yaw_pitch, gls=s.gls,
                               setup=_identification_setup(model_data_from_dataset(dataset).setup))
        if fit.n_moving_set_aside:
            log.info("identification uses the still captures (the %d moving ones of the lag probe are for the "
                     "diagnostics' time_lag effect)", fit.n_moving_set_aside)
        ctx.angle_choice = fit
        log.info("%s", fit.describe_angles())
        log.info("%s", fit.describe_outliers())
        if fit.images_set_aside:
            log.info("%s", fit.describe_images())
        result = fit.result
        ctx.identification = result
        why = implausible(result, s.thresholds)
        if why:
            return Outcome("implausible", why)
        for warning in unusual(result, s.thresholds):
            log.warning("%s", warning)
        return Outcome("ok")


def unusual(result, t: Thresholds) -> list[str]:
    """Plausible but unusually large results, worth a look before the offsets are trusted."""
    warn = {"joint_offset": t.warn_joint_offset_rad, "camera": t.warn_camera_rotation_rad}
    out = []
    for name in result.registry.names:
        group = name.split(".")[0]
        if group in warn and abs(result.value(name)) > warn[group]:
            out.append(f"{name} = {math.degrees(result.value(name)):.2f} deg is unusually large (more than "
                       f"{math.degrees(warn[group]):g} deg): check the robot (a loose joint, a replaced part, a "
                       "head from another robot)")
    return out


def implausible(result, t: Thresholds) -> str | None:
    """Why an identification result must not be used for compensation, or None."""
    if not result.success:
        return f"the solve did not converge ({result.message})"
    if max(result.rms_px) > t.max_rms_px:
        return (f"the fit's RMS ({result.rms_px[0]:.2f}, {result.rms_px[1]:.2f}) px exceeds {t.max_rms_px} px: "
                "the model does not explain the data (run naocal diagnose on the dataset)")
    limits = {"joint_offset": t.max_joint_offset_rad, "camera": t.max_camera_rotation_rad}
    for name in result.registry.names:
        value = result.value(name)
        group = name.split(".")[0]
        if group in limits and abs(value) > limits[group]:
            return f"{name} = {math.degrees(value):.2f} deg is implausibly large"
        if group == "board":
            limit = t.max_board_rot_z_rad if name.endswith("rot_z") else t.max_board_trans_m
            if abs(value) > limit:
                return f"{name} = {value:.4g} is implausibly large"
        if group == "joint_offset":
            std = float(result.std[result.registry.index[name]])
            if not std <= t.max_joint_offset_std_rad:
                return f"{name} is not determined by the data (std {math.degrees(std):.2f} deg)"
    return None


class Compensation(State):
    """Write offsets.json (atomic; the previous one kept as offsets.json.bak) and wrap the backend."""

    name = "compensation"
    needs = ("identification", "meta")
    produces = ("offsets", "compensated")

    def run(self, ctx: Context) -> Outcome:
        result = ctx.identification
        offsets = offsets_from_result(result, robot=ctx.meta["robot"], source=offsets_source(ctx))
        write_offsets(offsets, ctx.out_dir / "offsets.json")
        ctx.offsets = offsets
        ctx.compensated = CompensatedBackend(ctx.backend, offsets)
        return Outcome("ok")


def offsets_source(ctx: Context) -> dict:
    """offsets.json's `source`: the tool, the dataset and both seeds, named (the mock's, if any, and the plan's)."""
    s = ctx.settings
    source = {"tool": s.source, "dataset": str(ctx.dataset_dir)}
    if s.mock_seed is not None:
        source["mock_seed"] = s.mock_seed
    source.update(plan_seed=s.seed, plan=ctx.plan.kind if ctx.plan else None)
    return source


class Verification(State):
    """Re-measure held-out stances raw and compensated; report the errors before and after."""

    name = "verification"
    needs = ("offsets", "compensated", "identification", "plan", "robot")
    produces = ("verification",)

    def run(self, ctx: Context) -> Outcome:
        s = ctx.settings
        body = NaoBody()
        ctx._bodies.append(body)
        raw = ctx.robot
        raw.guard.set_true_offset(-_offset_vector(ctx.offsets))  # alpha = -c: where the raw joints truly go
        mounts = {leg: tuple(ctx.identification.value(f"board.{leg}.{k}") for k in ("rot_z", "trans_x", "trans_y"))
                  for leg in ("L", "R")}
        raw.guard.set_board_mounts(mounts)
        compensated = Robot(ctx.compensated, make_guard(ctx.compensated, s, body), ctx.plan.parked(), s.timing,
                            s.speed_fraction)
        # Through the compensation the joints go where commanded: the offsets are known, and they are zero.
        compensated.guard.checker.margin_m = compensated.guard.checker.ground_margin_m = s.known_offset_margin_m
        compensated.guard.set_board_mounts(mounts)
        ctx._guards += [raw.guard, compensated.guard]
        compensated.image_delay_s = raw.image_delay_s
        values = FULL.from_dict({n: ctx.identification.value(n) for n in ctx.identification.registry.names})
        folder = ctx.out_dir / "verification"
        if folder.exists():  # from an earlier attempt of this run: keep it, one generation back
            shutil.rmtree(folder.with_name("verification.prev"), ignore_errors=True)
            folder.rename(folder.with_name("verification.prev"))
        stores = {name: CaptureStore(folder / name, ctx.meta, save_images=s.save_images)
                  for name in ("raw", "compensated")}
        compensated.commanded = raw.commanded - _offset_vector(ctx.offsets)
        report = verify(raw, compensated, ctx.plan.verification, values,
                        identified_intrinsics(ctx.estimate.intrinsics, ctx.identification), ctx.detector,
                        _offset_vector(ctx.offsets), stores=stores)
        try:
            compensated.move(ctx.plan.parked())
        except SafetyError as err:
            log.warning("could not park the robot after verification: %s", err)
        raw.commanded = compensated.commanded + _offset_vector(ctx.offsets)  # the raw robot's view of where it is
        atomic_write_text(ctx.out_dir / VERIFICATION_NAME, json.dumps(report.to_dict(), indent=1) + "\n")
        ctx.verification = report
        return Outcome("ok")


def _offset_vector(offsets) -> np.ndarray:
    from naocal.solver.joints import JOINTS

    return np.array([offsets.joint_offset(j) for j in JOINTS])


def calibrate_states():
    return [Modelling(), Measure(), Identification(), Compensation(), Verification()]


def simulate_states():
    return [Modelling(), Measure(dataset_only=True)]
