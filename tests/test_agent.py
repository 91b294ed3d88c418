"""The agent on a fake robot (no rendering): the state machine, waiting, saving, resuming, compensation."""

import json

import numpy as np
import pytest

from naocal.agent.calibrate import calibrate
from naocal.agent.machine import DONE, FAILED, TRANSITIONS, Machine, Outcome, State
from naocal.agent.planner import PlanSettings, parked_posture
from naocal.agent.progress import ProgressBar
from naocal.agent.robot import Robot, TimingSettings
from naocal.agent.safety import SafetyGuard
from naocal.agent.states import AgentSettings, calibrate_states
from naocal.backends.compensated import CompensatedBackend
from naocal.body.nao_body import CollisionChecker, NaoBody
from naocal.solver.dataset import read_dataset
from naocal.backends.errors import RobotTimeout
from naocal.solver.joints import JOINTS, LEG_JOINTS
from naocal.solver.offsets import read_offsets
from tests.agent_fakes import FakeBackend

SMALL = PlanSettings(stances_per_leg=6)


def small_settings(**kw):
    return AgentSettings(seed=1, plan=SMALL, progress_bar=False, **kw)


@pytest.fixture(scope="module")
def fake_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("fake_run")
    fake = FakeBackend(3, resolution_rad=0.0)  # exact encoders: six stances per leg pin the offsets down
    result, ctx = calibrate(fake, out, small_settings(), detector=fake.detector)
    return fake, out, result, ctx


# --- the state machine ---------------------------------------------------------------------------------------------

def test_transition_table_reaches_done_from_modelling_and_names_known_states():
    names = {s.name for s in calibrate_states()}
    for (state, _), target in TRANSITIONS.items():
        assert state in names
        assert target in names | {DONE, FAILED}
    current, seen = "modelling", []
    while current != DONE:
        seen.append(current)
        current = TRANSITIONS[(current, "ok")]
    assert seen == ["modelling", "measurement", "identification", "compensation", "verification"]


class _Ctx:
    a = None
    b = None


class _Produce(State):
    name = "modelling"
    produces = ("a",)

    def run(self, ctx):
        ctx.a = 1
        return Outcome("ok")


class _Fail(State):
    name = "measurement"
    needs = ("a",)

    def run(self, ctx):
        raise RobotTimeout("the joints never came to rest")


class _Lazy(State):
    name = "modelling"
    produces = ("a",)

    def run(self, ctx):
        return Outcome("ok")


def test_a_naocal_error_ends_in_failed_with_its_reason():
    result = Machine([_Produce(), _Fail()]).run(_Ctx())
    assert result.final == FAILED
    assert result.reason == "measurement: the joints never came to rest"
    assert [h.state for h in result.history] == ["modelling", "measurement"]


class _Interrupted(State):
    name = "measurement"
    needs = ("a",)

    def __init__(self, interrupt):
        self.interrupt = interrupt

    def run(self, ctx):
        raise self.interrupt


@pytest.mark.parametrize("interrupt, cause", [(KeyboardInterrupt(), "Ctrl-C"),  # Python's own, for SIGINT
                                              (KeyboardInterrupt("SIGTERM"), "SIGTERM")])  # tools.cli's handler
def test_an_interrupt_ends_in_interrupted_naming_what_stopped_the_run(interrupt, cause):
    result = Machine([_Produce(), _Interrupted(interrupt)]).run(_Ctx())
    assert result.final == "interrupted"
    assert result.reason == f"measurement: interrupted ({cause})"
    assert (result.history[-1].outcome, result.history[-1].reason) == ("interrupted", cause)


def test_a_state_must_produce_what_it_declares_and_get_what_it_needs():
    with pytest.raises(RuntimeError, match="without producing a"):
        Machine([_Lazy(), _Fail()]).run(_Ctx())
    with pytest.raises(RuntimeError, match="needs a"):
        Machine([_Fail()], start="measurement").run(_Ctx())


# --- a whole run on the fake --------------------------------------------------------------------------------------

def test_fake_run_is_done_and_writes_every_file(fake_run):
    fake, out, result, ctx = fake_run
    assert result.ok, result.reason
    for name in ("plan.json", "progress.json", "offsets.json", "summary.txt", "calibrate.log", "verification.json"):
        assert (out / name).is_file(), name
    summary = (out / "summary.txt").read_text()
    for text in ("naocal calibrate: done", "joint offsets c", "camera rotation", "verification", "robot time"):
        assert text in summary
    assert "state measurement: ok" in (out / "calibrate.log").read_text()


def test_dataset_holds_every_planned_capture_once_with_directions_and_velocities(fake_run):
    fake, out, result, ctx = fake_run
    data = read_dataset(out / "dataset")
    images = data.columns["image"]
    assert sorted(set(images.tolist())) == ctx.plan.image_indices()
    assert len(images) == 24 * ctx.plan.n_images()
    assert data.has_velocities
    direction = data.joint_matrix("dir_")
    assert set(np.unique(direction)) <= {-1.0, 0.0, 1.0} and np.any(direction == -1) and np.any(direction == 1)
    velocity = data.joint_matrix("vel_")
    probe = np.isin(images, [i for s in ctx.plan.sweeps() for i in s.images])
    assert np.all(velocity[~probe] == 0.0)
    assert np.all(np.abs(velocity[probe][:, 2:8]).max(axis=1) > 0.02), "the probe moved while it was exposed"
    assert np.all(data.columns["t_image_s"][~probe] >= data.columns["t_joints_s"][~probe] - 0.2)


def test_images_are_exposed_after_the_robot_was_still(fake_run):
    """Every still capture's image shows the robot at its commanded posture: the fake's sensors at the exposure
    time equal the commanded angles."""
    fake, out, result, ctx = fake_run
    data = read_dataset(out / "dataset")
    cmd = data.joint_matrix("cmd_")
    vel = data.joint_matrix("vel_")
    rows = np.flatnonzero(np.all(vel == 0, axis=1))[::24]
    assert len(rows) == 2 * 6 * 3 + 2 * 2 * 2  # and each leg's two top-camera stances in two head postures
    for row in rows:
        sensors = fake.detected[round(data.columns["t_image_s"][row], 9)]
        np.testing.assert_allclose(sensors, cmd[row], atol=1e-9)


def test_offsets_are_c_minus_alpha_close_to_the_fake_truth(fake_run):
    fake, out, result, ctx = fake_run
    offsets = read_offsets(out / "offsets.json")
    for joint in LEG_JOINTS:
        assert offsets.joint_offset(joint) == pytest.approx(fake.truth[f"joint_offset.{joint}"], abs=np.radians(0.1))
    assert offsets.camera_rpy()[1] == pytest.approx(fake.truth["camera.bottom.pitch"], abs=np.radians(0.05))
    for k, angle in enumerate(("roll", "pitch", "yaw")):  # the top camera from the same run
        assert offsets.camera_rpy("top")[k] == pytest.approx(fake.TOP_ROTATION_RAD[angle], abs=np.radians(0.05))


def test_verification_error_falls_after_compensation(fake_run):
    fake, out, result, ctx = fake_run
    report = json.loads((out / "verification.json").read_text())
    for leg, entry in report["per_leg"].items():
        assert entry["n_stances"] >= 1
        assert entry["after"]["command_rms_px"] < 0.3 * entry["before"]["command_rms_px"], leg
        assert entry["after"]["reading_rms_px"] < 0.3 * entry["before"]["reading_rms_px"], leg


def test_every_command_the_fake_received_was_safe(fake_run):
    fake, out, result, ctx = fake_run
    body = NaoBody()
    try:
        checker = CollisionChecker(body, margin_m=0.003, ground_margin_m=0.003)
        limits = fake.joint_limits()
        posture = dict(zip(JOINTS, fake.start_posture))
        assert len(fake.command_log) >= ctx.plan.n_images()
        for _, targets, speed in fake.command_log:
            assert 0 < speed <= 1
            posture.update(targets)
            for joint, angle in targets.items():
                assert limits[joint][0] <= angle <= limits[joint][1]
            true = np.array([posture[j] for j in JOINTS]) + fake.alpha
            assert checker.is_safe(true)
    finally:
        body.close()


def test_a_second_run_in_the_same_directory_is_refused_without_resume(tmp_path):
    fake = FakeBackend(3)
    with pytest.raises(Crash):
        calibrate(fake, tmp_path, small_settings(), detector=crashing_detector(fake, 3))
    before = (tmp_path / "dataset" / "observations.csv").read_bytes()
    again, _ = calibrate(FakeBackend(3), tmp_path, small_settings(), detector=fake.detector)
    assert again.final == FAILED and "--resume" in again.reason
    assert (tmp_path / "dataset" / "observations.csv").read_bytes() == before


@pytest.mark.parametrize("resume", [False, True])
def test_a_finished_run_is_not_run_again_and_the_robot_not_moved(fake_run, resume):
    """A finished run offered --resume, which re-ran the verification: the robot moved again."""
    from naocal.solver.errors import NaocalError

    _, out, _, _ = fake_run
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    robot = FakeBackend(3)
    with pytest.raises(NaocalError) as refused:
        calibrate(robot, out, small_settings(resume=resume), detector=robot.detector)
    message = str(refused.value)
    assert "finished calibration" in message and "--resume" not in message.replace("nothing to resume", "")
    assert f"naocal verify {out / 'verification' / 'raw'} --offsets {out / 'offsets.json'}" in message
    assert robot.command_log == []
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


# --- crash and resume -----------------------------------------------------------------------------------------------

class Crash(Exception):
    pass


def crashing_detector(fake, after):
    calls = {"n": 0}

    def detect(image, predicted, leg, margin):
        calls["n"] += 1
        if calls["n"] > after:
            raise Crash("power cut")
        return fake.detector(image, predicted, leg, margin)

    return detect


def test_resume_after_a_crash_captures_every_image_exactly_once(tmp_path, fake_run):
    _, _, _, reference_ctx = fake_run
    fake = FakeBackend(3, resolution_rad=0.0)
    with pytest.raises(Crash):
        calibrate(fake, tmp_path, small_settings(), detector=crashing_detector(fake, 17))
    saved = set(read_dataset(tmp_path / "dataset").columns["image"].tolist())
    assert len(saved) == 17
    fresh = FakeBackend(3, resolution_rad=0.0)
    result, ctx = calibrate(fresh, tmp_path, small_settings(resume=True), detector=fresh.detector)
    assert result.ok, result.reason
    images = read_dataset(tmp_path / "dataset").columns["image"]
    counts = np.bincount(images)
    assert np.all(counts[ctx.plan.image_indices()] == 24), "every capture exactly once"
    assert ctx.measurement["sessions"] == 2
    reference = reference_ctx.identification
    for name in reference.registry.names:
        if name.startswith("joint_offset."):
            assert ctx.identification.value(name) == pytest.approx(reference.value(name), abs=np.radians(0.05))


def test_resume_refuses_another_plan_seed(tmp_path):
    fake = FakeBackend(3)
    with pytest.raises(Crash):
        calibrate(fake, tmp_path, small_settings(), detector=crashing_detector(fake, 3))
    settings = small_settings(resume=True)
    settings.seed = 7
    result, _ = calibrate(FakeBackend(3), tmp_path, settings, detector=fake.detector)
    assert result.final == FAILED and "seed" in result.reason


# --- the robot handle ----------------------------------------------------------------------------------------------

@pytest.fixture
def robot():
    fake = FakeBackend(0)
    body = NaoBody()
    guard = SafetyGuard(fake.joint_limits(), CollisionChecker(body, margin_m=0.015, ground_margin_m=0.012),
                        fake.max_speeds())
    yield fake, Robot(fake, guard, parked_posture(), TimingSettings())
    body.close()


def test_waiting_for_still_ends_after_the_motion_and_the_image_after_that(robot):
    fake, r = robot
    target = parked_posture()
    t0 = fake.now()
    rest = r.move(target)
    duration = np.max(np.abs(target - fake.sensor_at(t0)) / (fake.speeds * 0.4))
    assert rest.t_still_s >= t0 + fake.latency_s + duration - 0.011
    image = r.wait_image(rest.t_still_s + 0.025)
    assert image.t_exposure_s >= rest.t_still_s + 0.025
    np.testing.assert_allclose(image.sensor_rad, target, atol=1e-12)


def test_directions_record_the_sign_of_each_joints_last_command_change(robot):
    fake, r = robot
    start = parked_posture()
    r.move(start)
    up = start.copy()
    up[JOINTS.index("LKneePitch")] += 0.2
    r.move(up)
    head = up.copy()
    head[0] -= 0.1
    r.move(head)
    assert r.direction[JOINTS.index("LKneePitch")] == 1.0  # unchanged by the later head-only move
    assert r.direction[0] == -1.0


class Stuck(FakeBackend):
    def command(self, targets_rad, speed_fraction):
        self.command_log.append((self.t, dict(targets_rad), speed_fraction))  # accepted, but nothing moves


class Blind(FakeBackend):
    def capture(self):
        return None


def test_waits_end_in_robot_timeout_at_their_deadline():
    body = NaoBody()
    try:
        for cls in (Stuck, Blind):
            fake = cls(0)
            guard = SafetyGuard(fake.joint_limits(), CollisionChecker(body, margin_m=0.015, ground_margin_m=0.012),
                                fake.max_speeds())
            r = Robot(fake, guard, parked_posture(), TimingSettings(settle_deadline_s=1.0, image_deadline_s=0.5))
            with pytest.raises(RobotTimeout):
                rest = r.move(parked_posture())
                r.wait_image(rest.t_still_s)
            assert fake.now() < 30.0, "the deadline is in robot time and is kept"
    finally:
        body.close()


# --- compensation ---------------------------------------------------------------------------------------------------

def test_compensated_backend_adds_c_to_commands_and_subtracts_it_from_readings():
    fake = FakeBackend(5, resolution_rad=0.0)
    c = {j: fake.truth[f"joint_offset.{j}"] for j in LEG_JOINTS}  # the fake's truth holds c
    comp = CompensatedBackend(fake, c)
    target = parked_posture()
    comp.command(dict(zip(JOINTS, target)), 0.4)
    fake.sleep(3.0)
    np.testing.assert_allclose(fake.true_angles(), target, atol=1e-12)  # the joint stands where asked
    reading = comp.read_joints().angles_rad
    np.testing.assert_allclose([reading[j] for j in JOINTS], fake.true_angles(), atol=1e-12)  # reads the truth
    lo, hi = comp.joint_limits()["LKneePitch"]
    assert lo == pytest.approx(fake.joint_limits()["LKneePitch"][0] - c["LKneePitch"])
    assert hi == pytest.approx(fake.joint_limits()["LKneePitch"][1] - c["LKneePitch"])
    assert comp.joint_limits()["HeadYaw"] == fake.joint_limits()["HeadYaw"]


def test_progress_bar_is_plain_text(capsys):
    import io

    stream = io.StringIO()
    bar = ProgressBar(10, stream=stream)
    for k in range(11):
        bar.update(k, "robot time 1.0 s")
    bar.finish()
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("measuring [") and lines[-1].startswith("measuring [####")
    assert len(lines) == 11 and "10/10" in lines[-1]


def test_bad_settings_and_bad_resume_state_are_naocal_errors(tmp_path):
    (tmp_path / "plan.json").write_text("{")
    (tmp_path / "dataset").mkdir()
    (tmp_path / "dataset" / "observations.csv").write_text("x")
    fake = FakeBackend(0)
    result, _ = calibrate(fake, tmp_path, small_settings(resume=True), detector=fake.detector)
    assert result.final == FAILED and "plan.json" in result.reason


def test_running_estimate_keeps_the_first_leg_when_the_second_begins():
    """The second leg's first capture must not throw away the first leg's offsets (nor make the guard believe the
    second leg's are known)."""
    from naocal.agent.estimate import RunningEstimate
    from naocal.sim.synthetic import DEFAULT_INTRINSICS, random_truth, synthesize

    rng = np.random.default_rng(40)
    truth = random_truth(rng)
    data = synthesize(rng, truth, n_stances_per_leg=18, n_head_postures=1, pixel_noise_px=0.05)
    estimate = RunningEstimate(DEFAULT_INTRINSICS)
    for m in np.flatnonzero(data.leg == "L"):
        estimate.add("L", data.theta[m], data.uv_px[data.image_of_row == m])
    learned = estimate.joint_alpha()
    first_right = int(np.flatnonzero(data.leg == "R")[0])
    estimate.add("R", data.theta[first_right], data.uv_px[data.image_of_row == first_right])
    assert estimate.known_legs == frozenset({"L"}) and not estimate.offsets_known()
    assert estimate.knows("L") and not estimate.knows("R")  # the right board is searched with the wide margin
    alpha = estimate.joint_alpha()
    left = [JOINTS.index(j) for j in LEG_JOINTS if j.startswith("L")]
    right = [JOINTS.index(j) for j in LEG_JOINTS if j.startswith("R")]
    assert np.all(learned[left] != 0.0) and np.all(alpha[right[1:]] == 0.0)
    assert alpha[right[0]] == alpha[left[0]]  # HipYawPitch: one motor, known with the first leg
    assert np.abs(alpha[left] - learned[left]).max() < np.radians(0.05)  # kept, refined at most
    # and it predicts the right board from the left leg's camera at least as well as the nominal model does
    nominal = RunningEstimate(DEFAULT_INTRINSICS)
    second_right = int(np.flatnonzero(data.leg == "R")[1])
    detected = data.uv_px[data.image_of_row == second_right]
    error = lambda e: np.sqrt(np.mean((e.predict("R", data.theta[second_right]) - detected) ** 2))  # noqa: E731
    assert error(estimate) < error(nominal)
    guard_body = NaoBody()
    try:
        guard = SafetyGuard({j: (-3.0, 3.0) for j in JOINTS}, CollisionChecker(guard_body, margin_m=0.015,
                                                                               ground_margin_m=0.012),
                            {j: 5.0 for j in JOINTS})
        guard.set_true_offset(alpha, known=estimate.offsets_known())
        assert (guard.checker.margin_m, guard.checker.ground_margin_m) == (0.015, 0.012)  # still the wide margins
        guard.set_true_offset(alpha, known=True)
        assert guard.checker.margin_m == pytest.approx(0.008)
    finally:
        guard_body.close()


def test_a_resumed_run_reloads_the_top_cameras_rotation_instead_of_relearning_it(tmp_path):
    """The first top capture after a resume is searched with the narrow margin: the rotation learnt from the top
    captures on disk is refitted at the warm start (it was relearnt from the first new top capture, searched wide)."""
    fake = FakeBackend(3, resolution_rad=0.0)
    first_session = []

    def crash_after_two_top_captures(image, predicted, leg, margin):
        if sum(camera == "top" for camera, _ in first_session) == 2:
            raise Crash("power cut")
        first_session.append((image.camera, margin))
        return fake.detector(image, predicted, leg, margin)

    with pytest.raises(Crash):
        calibrate(fake, tmp_path, small_settings(), detector=crash_after_two_top_captures)
    assert [m for c, m in first_session if c == "top"] == [120.0, 40.0]  # wide until its rotation is learnt
    fresh = FakeBackend(3, resolution_rad=0.0)
    resumed = []

    def recording(image, predicted, leg, margin):
        resumed.append((image.camera, margin))
        return fresh.detector(image, predicted, leg, margin)

    result, ctx = calibrate(fresh, tmp_path, small_settings(resume=True), detector=recording)
    assert result.ok, result.reason
    top = [m for c, m in resumed if c == "top"]
    assert top and all(m == 40.0 for m in top), top
