"""The planner: every capture of the paper plan meets the rules, plans are deterministic, the design maths is right,
and the D-optimal plan reaches the paper plan's precision with fewer stances."""

import json

import numpy as np
import pytest

from naocal.agent.design import _gls_information, greedy_d_optimal, load_error_moment, log_det, stance_information
from naocal.agent.plan import Plan, Still, Sweep, read_plan, write_plan
from naocal.agent.planner import PlanSettings, Planner, make_plan, parked_posture
from naocal.agent.safety import SafetyGuard, prior_covariance
from naocal.agent.visibility import OcclusionChecker, views_ok
from naocal.body.nao_body import CollisionChecker, NaoBody
from naocal.solver.errors import SafetyError
from naocal.solver.errors import DataError
from naocal.solver.joints import JOINT_INDEX, JOINTS, LEG_JOINTS, LEGS
from naocal.solver.kinematics import camera_fk, leg_fk
from naocal.solver.limits import head_pitch_limits, joint_limits
from naocal.solver.joints import HEAD_COLUMNS, LEG_COLUMNS
from naocal.sim.synthetic import DEFAULT_INTRINSICS


@pytest.fixture(scope="module")
def paper_plan():
    return make_plan(0)


@pytest.fixture(scope="module")
def body():
    b = NaoBody()
    yield b
    b.close()


def test_paper_plan_has_24_stances_per_leg_times_3_head_postures_and_a_lag_probe(paper_plan):
    stills = [s for s in paper_plan.stills() if s.camera == "bottom"]
    assert len(stills) == 2 * 24 * 3
    for leg in LEGS:
        mine = [s for s in stills if s.leg == leg]
        assert sorted({s.stance for s in mine}) == list(range(24))
        for stance in range(24):
            shots = [s for s in mine if s.stance == stance]
            assert sorted(s.head_posture for s in shots) == [0, 1, 2]
            legs = np.array([s.angles()[LEG_COLUMNS[leg]] for s in shots])
            assert np.all(legs == legs[0]), "the leg stays put while the head changes posture"
            heads = np.array([s.angles()[HEAD_COLUMNS] for s in shots])
            assert np.min(np.linalg.norm(heads[:, None] - heads[None], axis=2) + np.eye(3)) >= PlanSettings().min_head_spread_rad
    sweeps = paper_plan.sweeps()
    assert [s.leg for s in sweeps] == ["L", "R"]
    assert paper_plan.image_indices() == list(range(paper_plan.n_images()))


def test_paper_plan_ends_with_top_camera_stances_that_pull_the_thigh_up(paper_plan):
    s = PlanSettings()
    top = [st for st in paper_plan.stills() if st.camera == "top"]
    per_leg = s.top_stances_per_leg * s.top_head_postures
    assert [st.leg for st in top] == ["L"] * per_leg + ["R"] * per_leg
    assert paper_plan.steps[-len(top):] == top  # after the bottom camera's: the offsets are known by then
    for st in top:
        hip = st.angles()[JOINT_INDEX[f"{st.leg}HipPitch"]]
        assert s.top_hip_pitch_min_rad <= hip <= s.top_hip_pitch_max_rad
    # the bottom camera's plan of a seed is what it was without them
    bottom_only = make_plan(0, PlanSettings(top_stances_per_leg=0))
    assert [st for st in paper_plan.steps if not (isinstance(st, Still) and st.camera == "top")] == bottom_only.steps
    assert Plan.from_dict(paper_plan.to_dict()).stills()[-1].camera == "top"  # plan.json keeps the camera


def test_every_capture_meets_the_rules_on_the_nominal_model(paper_plan, body):
    s = PlanSettings()
    limits = joint_limits()
    collisions = CollisionChecker(body, margin_m=s.collision_margin_m, ground_margin_m=s.ground_margin_m)
    occlusion = OcclusionChecker(body)
    for still in paper_plan.stills():
        q = still.angles()
        for j, name in enumerate(JOINTS):
            lo, hi = limits[name]
            assert lo + s.joint_margin_rad <= q[j] <= hi - s.joint_margin_rad, (still.image, name)
        lo, hi = head_pitch_limits(q[JOINT_INDEX["HeadYaw"]])
        assert lo + s.head_pitch_margin_rad <= q[JOINT_INDEX["HeadPitch"]] <= hi - s.head_pitch_margin_rad
        assert q[JOINT_INDEX["LHipYawPitch"]] == q[JOINT_INDEX["RHipYawPitch"]], "one motor drives both"
        assert collisions.is_safe(q), still.image
        assert occlusion.is_visible(q, still.leg, still.camera), still.image
        T_cam = camera_fk(q[HEAD_COLUMNS][None], still.camera)
        T_sole = leg_fk(q[LEG_COLUMNS[still.leg]][None], still.leg)
        assert views_ok(T_cam, T_sole, DEFAULT_INTRINSICS, s.view_rules(), s.camera_offset())[0], still.image


def test_views_ok_rejects_a_board_outside_the_image_or_seen_from_behind(paper_plan):
    q = paper_plan.stills()[0].angles()
    leg = paper_plan.stills()[0].leg
    T_cam = camera_fk(q[HEAD_COLUMNS][None])
    T_cam[0, :3, :3] = T_cam[0, :3, :3] @ PlanSettings().camera_offset()  # the prior camera rotation
    T_sole = leg_fk(q[LEG_COLUMNS[leg]][None], leg)
    assert views_ok(T_cam, T_sole, DEFAULT_INTRINSICS)[0]
    turned = T_cam.copy()
    turned[0, :3, :3] = turned[0, :3, :3] @ np.diag([-1.0, -1.0, 1.0])  # camera looking the other way
    assert not views_ok(turned, T_sole, DEFAULT_INTRINSICS)[0]
    flipped = T_sole.copy()
    flipped[0, :3, :3] = flipped[0, :3, :3] @ np.diag([1.0, -1.0, -1.0])  # printed face turned away
    assert not views_ok(T_cam, flipped, DEFAULT_INTRINSICS)[0]


def test_the_lag_probe_keeps_the_board_in_view_along_the_whole_sweep(paper_plan, body):
    s = PlanSettings()
    occlusion = OcclusionChecker(body)
    for sweep in paper_plan.sweeps():
        assert len(sweep.images) == s.probe_images_per_leg
        delta = sweep.end() - sweep.start()
        moving = np.abs(delta[LEG_COLUMNS[sweep.leg]])
        assert np.all(moving > 0.05), "every leg joint moves, so the lag shows in all of them"
        for t in np.linspace(0.0, 1.0, 7):
            q = sweep.start() + t * delta
            T_cam = camera_fk(q[HEAD_COLUMNS][None])
            T_sole = leg_fk(q[LEG_COLUMNS[sweep.leg]][None], sweep.leg)
            assert views_ok(T_cam, T_sole, DEFAULT_INTRINSICS, s.view_rules(), s.camera_offset())[0]
            assert occlusion.is_visible(q, sweep.leg)


def test_approach_directions_are_balanced_and_gravity_torques_vary(paper_plan):
    stats = paper_plan.stats
    assert set(stats["approach_direction_mean"]) == set(LEG_JOINTS)
    for joint, mean in stats["approach_direction_mean"].items():
        assert abs(mean) <= 0.5, f"{joint} is approached from one side {mean:+.2f} of the time"
    for joint in ("LHipPitch", "RHipPitch", "LKneePitch", "RKneePitch"):
        lo, hi = stats["gravity_torque_range_nm"][joint]
        assert hi - lo > 0.2, joint


def test_same_seed_same_plan_other_seed_other_plan(paper_plan):
    again = make_plan(0)
    assert json.dumps(again.to_dict()) == json.dumps(paper_plan.to_dict())
    other = make_plan(1, PlanSettings(stances_per_leg=4, probe=False))
    assert other.stills()[0].angles_rad != paper_plan.stills()[0].angles_rad


def test_plan_file_round_trip_and_bad_files(tmp_path, paper_plan):
    path = tmp_path / "plan.json"
    write_plan(paper_plan, path)
    back = read_plan(path)
    assert back.to_dict() == paper_plan.to_dict()
    assert any(isinstance(st, Sweep) for st in back.steps) and isinstance(back.steps[0], Still)
    doc = json.loads(path.read_text())
    doc["steps"][-1]["camera"] = "middle"
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError, match="camera"):
        read_plan(path)
    doc["steps"][-1]["camera"] = "top"
    doc["schema"] = "naocal.plan/0"
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError, match="schema"):
        read_plan(path)
    doc["schema"] = "naocal.plan/1"
    doc["steps"][3]["angles_rad"] = [0.0] * 13
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError, match=r"steps\[3\]"):
        read_plan(path)
    path.write_text(path.read_text()[:100])
    with pytest.raises(DataError, match="truncated"):
        read_plan(path)


def test_information_by_woodbury_equals_the_dense_inverse():
    rng = np.random.default_rng(3)
    J, G = rng.normal(size=(40, 5)), rng.normal(size=(40, 3))
    sigma_px, sigma_q = 0.1, 0.02
    S = sigma_px ** 2 * np.eye(40) + sigma_q ** 2 * G @ G.T
    np.testing.assert_allclose(_gls_information(J, G, sigma_px, sigma_q), J.T @ np.linalg.solve(S, J), rtol=1e-9)
    per_column = np.array([0.02, 0.0, 0.05])  # one variance per shared error; a zero one shares nothing
    S = sigma_px ** 2 * np.eye(40) + G @ np.diag(per_column ** 2) @ G.T
    np.testing.assert_allclose(_gls_information(J, G, sigma_px, per_column), J.T @ np.linalg.solve(S, J), rtol=1e-9)


def test_the_load_error_moment_is_that_of_a_servo_pulled_to_one_side_of_its_step():
    """A servo resting anywhere in its step cell, pulled `a` steps towards one edge and stopped there: the second
    moment of its error about the cell's centre (the reading) by Monte Carlo, 1/12 unloaded, 1/4 at the edge."""
    u = np.random.default_rng(0).uniform(-0.5, 0.5, 400_000)
    for a in (0.0, 0.3, -0.7, 1.0, 2.5):
        assert load_error_moment(a) == pytest.approx(np.mean(np.clip(u + a, -0.5, 0.5) ** 2), abs=1e-3)
    assert load_error_moment(0.0) == pytest.approx(1 / 12) and load_error_moment(3.0) == pytest.approx(0.25)


def test_a_loaded_stance_tells_less_than_the_unloaded_model_says(paper_plan):
    """The design's load model (servo_stiffness_nm_per_rad): the gravity load pulls each leg joint towards one side
    of its step, a larger error the stance's images share; the information of every stance is at most what the
    load-free model gives, and smaller where the load is large."""
    stills = [s for s in paper_plan.stills() if s.camera == "bottom"][:12]
    theta = np.array([s.angles() for s in stills])
    leg, stance = np.array([s.leg for s in stills]), np.array([s.stance for s in stills])
    free = stance_information(theta, leg, stance, encoder_resolution_rad=np.radians(360 / 4096))
    loaded = stance_information(theta, leg, stance, encoder_resolution_rad=np.radians(360 / 4096),
                                servo_stiffness_nm_per_rad=1300.0)
    stiff = stance_information(theta, leg, stance, encoder_resolution_rad=np.radians(360 / 4096),
                               servo_stiffness_nm_per_rad=1e9)
    np.testing.assert_allclose(stiff, free, rtol=1e-6, atol=1e-9)  # no sag: the old model
    for a, b in zip(free, loaded):
        assert np.min(np.linalg.eigvalsh(a - b)) > -1e-6 * np.max(np.linalg.eigvalsh(a))
        assert np.trace(b) < np.trace(a)


def test_shared_leg_reading_error_limits_what_more_head_postures_add(paper_plan):
    """Three head postures of one stance share the leg's reading error: they add less than three separate stances
    would, and the design must know it."""
    stills = paper_plan.stills()[:6]  # two stances of the left leg, three postures each
    theta = np.array([s.angles() for s in stills])
    leg = np.array([s.leg for s in stills])
    shared = stance_information(theta, leg, np.array([s.stance for s in stills]))
    separate = stance_information(theta, leg, np.arange(6))
    assert log_det(separate.sum(axis=0) + 1e-9 * np.eye(21)) > log_det(shared.sum(axis=0) + 1e-9 * np.eye(21))
    exact = stance_information(theta, leg, np.array([s.stance for s in stills]), encoder_resolution_rad=0.0)
    assert np.trace(exact.sum(axis=0)) > np.trace(shared.sum(axis=0))


def test_the_optimal_plan_stops_where_the_predicted_worst_joint_offset_std_reaches_its_target():
    """reaching_count: the first prefix of the greedy order whose predicted worst joint-offset std is within the
    target, never a prefix that leaves a parameter undetermined (its pseudo-inverse would call it known)."""
    from naocal.agent.design import BASE_REGISTRY, joint_offset_indices, predicted_std, reaching_count

    P = len(BASE_REGISTRY)
    rng = np.random.default_rng(5)
    mask = np.r_[np.ones(P // 2), np.zeros(P - P // 2)]  # each stance sees half the parameters
    infos = np.array([np.diag(mask if k % 2 == 0 else 1.0 - mask) * 4e4 for k in range(12)])
    infos *= rng.uniform(0.5, 1.5, 12)[:, None, None]
    order = list(range(12))
    worst = [np.degrees(np.max(predicted_std(infos[:n].sum(axis=0))[joint_offset_indices()])) for n in range(2, 13)]
    target = worst[4]  # reached with 6 stances, not before
    assert all(w > target for w in worst[:4])
    assert reaching_count(infos, order, target) == 6
    assert reaching_count(infos, order, 1e-9) is None and reaching_count(infos, order, None) is None
    assert reaching_count(infos, order, 1e9) == 2  # not 1: one stance leaves half the parameters undetermined


def test_greedy_d_optimal_takes_the_most_informative_first():
    rng = np.random.default_rng(0)
    infos = np.array([np.diag(rng.uniform(0.1, 1.0, 4)) for _ in range(6)])
    infos[4] = 5.0 * np.eye(4)
    order = greedy_d_optimal(infos, 3)
    assert order[0] == 4 and len(set(order)) == 3


@pytest.mark.slow
def test_d_optimal_plan_reaches_the_paper_precision_with_fewer_stances():
    plan = make_plan(0, PlanSettings(kind="optimal", pool_per_leg=80, probe=False, target_worst_std_deg=None))
    design = plan.stats["design"]
    assert design["selected_stances"] < design["paper_stances"]
    assert design["selected_log_det"] >= design["paper_log_det"]
    paper_worst = max(design["paper_predicted_std"][f"joint_offset.{j}"] for j in LEG_JOINTS)
    assert np.radians(plan.stats["predicted_worst_joint_offset_std_deg"]) <= paper_worst + 1e-12
    assert plan.n_images() == 3 * design["selected_stances"] + plan.stats["n_top_camera_images"]


def test_safety_guard_refuses_limits_head_table_and_collisions(body):
    limits = joint_limits()
    speeds = {j: 5.0 for j in JOINTS}
    guard = SafetyGuard(limits, CollisionChecker(body, margin_m=0.015, ground_margin_m=0.012), speeds)
    parked = parked_posture()
    guard.check(parked)
    too_far = parked.copy()
    too_far[JOINT_INDEX["LKneePitch"]] = limits["LKneePitch"][1] - 0.001
    with pytest.raises(SafetyError, match="LKneePitch"):
        guard.check(too_far)
    head = parked.copy()
    head[JOINT_INDEX["HeadYaw"]], head[JOINT_INDEX["HeadPitch"]] = 0.68, 0.5
    with pytest.raises(SafetyError, match="HeadPitch"):
        guard.check(head)
    head[JOINT_INDEX["HeadYaw"]], head[JOINT_INDEX["HeadPitch"]] = 1.2, 0.2  # beyond the command range
    with pytest.raises(SafetyError, match="HeadYaw"):
        guard.check(head)
    crossed = parked.copy()
    crossed[JOINT_INDEX["LHipRoll"]], crossed[JOINT_INDEX["RHipRoll"]] = -0.3, 0.3  # legs into each other
    with pytest.raises(SafetyError, match="collision"):
        guard.check(crossed)
    nan = parked.copy()
    nan[0] = np.nan
    with pytest.raises(SafetyError):
        guard.check(nan)


def test_a_gap_inside_the_margin_is_called_a_margin_violation_not_a_collision(body):
    guard = SafetyGuard(joint_limits(), CollisionChecker(body, margin_m=0.015, ground_margin_m=0.012),
                        {j: 5.0 for j in JOINTS})
    close = parked_posture()
    close[JOINT_INDEX["LHipRoll"]], close[JOINT_INDEX["RHipRoll"]] = 0.12, -0.12  # sandals a few millimetres apart
    problem = guard.problem(close)
    assert problem.startswith("LSandal and RSandal closer than the 15 mm margin (") and "collision" not in problem
    gap_mm = float(problem.rsplit("(", 1)[1].split(" mm")[0])
    assert 0 < gap_mm < 15
    crossed = parked_posture()
    crossed[JOINT_INDEX["LHipRoll"]], crossed[JOINT_INDEX["RHipRoll"]] = 0.06, -0.06
    assert guard.problem(crossed).startswith("collision: LSandal and RSandal overlap by ")


def test_safety_guard_detours_around_a_blocked_path(paper_plan, body):
    """Find a transition between plan stances whose direct path is blocked; the guard's way round is clear."""
    guard = SafetyGuard(joint_limits(), CollisionChecker(body, margin_m=0.015, ground_margin_m=0.012),
                        {j: 5.0 for j in JOINTS})
    stills = [s for s in paper_plan.stills() if s.head_posture == 0]
    found = 0
    for a in stills[:24]:
        for b in stills[24:]:
            if guard.path_clear(a.angles(), b.angles(), 0.4):
                continue
            way = guard.waypoints(a.angles(), b.angles(), 0.4, parked_posture())
            assert len(way) >= 2 and np.array_equal(way[-1], b.angles())
            legs = [a.angles()] + way
            assert all(guard.path_clear(p, q, 0.4) for p, q in zip(legs, legs[1:]))
            found += 1
            if found == 3:
                return
    pytest.skip("no blocked transition among the sampled pairs")


def test_planner_rejects_unknown_plan_kind():
    planner = Planner(PlanSettings(kind="best"))
    try:
        with pytest.raises(ValueError, match="plan kind"):
            planner.make_plan(0)
    finally:
        planner.close()


def test_the_robot_time_estimate_counts_each_capture_s_settling_and_guard():
    """Motion at the plan's speed plus `capture_overhead_s` per capture (the servo settling, the still window, the
    image guard: 0.37 s measured on the realistic mock, against 0.21 s assumed before)."""
    parked = parked_posture()
    bent = parked.copy()
    bent[JOINT_INDEX["LKneePitch"]] += 0.5
    stills = [Still(0, "L", 0, 0, tuple(bent)), Still(1, "L", 0, 1, tuple(bent))]
    plan = Plan(0, "paper", {}, stills, [], tuple(parked))
    planner = Planner(PlanSettings())
    try:
        motion = planner.move_time_s(parked, bent)
        assert planner.estimate_robot_time_s(plan) == pytest.approx(motion + 2 * 0.37)
        assert planner.estimate_robot_time_s(plan, 0.0) == pytest.approx(motion)
    finally:
        planner.close()


def test_head_yaw_range_is_one_constant_of_the_robot_description(body):
    """The planner drew top-camera head postures up to |HeadYaw| 0.7 rad while the measurement's head moves
    clamped to 0.6 (re-aiming a planned posture moved the head away from it): both, and the guard, now take the
    robot description's command range."""
    from types import SimpleNamespace

    from naocal.agent.measure import Measurement
    from naocal.agent.planner import PlanSettings
    from naocal.solver.limits import command_limits
    from naocal.solver.robot import nao

    assert nao().command_limits == {"HeadYaw": (-0.7, 0.7)}
    assert command_limits()["HeadYaw"] == (-0.7, 0.7) and command_limits()["HeadPitch"] == joint_limits()["HeadPitch"]
    assert PlanSettings().top_head_yaw_max_rad == 0.7
    guard = SafetyGuard(joint_limits(), CollisionChecker(body, margin_m=0.015, ground_margin_m=0.012),
                        {j: 5.0 for j in JOINTS})
    yaw = JOINT_INDEX["HeadYaw"]
    assert (guard.lower[yaw], guard.upper[yaw]) == (-0.7, 0.7)
    q = parked_posture()
    q[yaw], q[JOINT_INDEX["HeadPitch"]] = 0.68, 0.35
    assert guard.problem(q) is None
    measurement = SimpleNamespace(robot=SimpleNamespace(guard=guard), _head_ok=lambda p: guard.problem(p) is None)
    assert Measurement.feasible_head(measurement, q)[yaw] == 0.68  # kept where the planner put it (was 0.6)
    q[yaw] = 0.75
    assert "HeadYaw" in guard.problem(q)
    assert Measurement.feasible_head(measurement, q)[yaw] == 0.7


def _guards_of_realistic_robots(body, seeds=(1, 2, 3, 4)):
    """The agent's guard (its own margins) as it stands on the realistic mock's robots `seeds`: before anything is
    known (offsets 0, the plausible offsets as 3 standard deviations) and once the offsets and sandal mounts are
    known (the hidden truth: the verification's and the top camera's state)."""
    from naocal.agent.states import AgentSettings
    from naocal.backends.mock import draw_truth

    s = AgentSettings()
    planned = PlanSettings()
    prior = prior_covariance(np.radians(planned.hip_yaw_pitch_offset_prior_deg),
                             np.radians(planned.leg_offset_prior_deg))

    def guard():
        checker = CollisionChecker(body, margin_m=s.collision_margin_m, ground_margin_m=s.ground_margin_m)
        return SafetyGuard(joint_limits(), checker, {j: 5.0 for j in JOINTS}, margin_rad=s.command_margin_rad,
                           known_offset_margin_m=s.known_offset_margin_m)

    unknown = guard()
    unknown.set_true_offset(np.zeros(len(JOINTS)), known=False, covariance14=prior)
    yield "nothing known", unknown
    for seed in seeds:
        truth = draw_truth(seed, realism="realistic")
        known = guard()
        known.set_true_offset(np.array([truth.alpha_rad[j] for j in JOINTS]), known=True)
        known.set_board_mounts({leg: (m.rot_z_rad, m.trans_x_m, m.trans_y_m) for leg, m in truth.board_mount.items()})
        yield f"realistic seed {seed}", known
        known.close()


def assert_every_stance_passes_the_guard(plan, body):
    postures = [(f"{st.camera} capture {st.image}", st.angles()) for st in plan.stills()]
    postures += [(f"verification {st.leg} stance {st.stance}", st.angles()) for st in plan.verification]
    for state, guard in _guards_of_realistic_robots(body):
        refused = [(what, guard.problem(np.asarray(q))) for what, q in postures]
        refused = [r for r in refused if r[1] is not None]
        assert not refused, (state, refused[:3], len(refused))


def test_every_planned_stance_passes_the_agents_guard_on_realistic_robots(paper_plan, body):
    """The agent commands the planned angles raw: the joints stand at plan + offset (HipYawPitch up to 12 deg on a
    real robot). Every calibration, top-camera and verification stance must pass the guard whatever the robot's
    offsets (before, checked at the nominal offsets: the run's plan put realistic seed 1's verification stance R 1
    with LSandal 11.8 mm into the ground; this plan had 16 captures refused before anything is known, and 18
    captures and a verification stance once seed 1's offsets are)."""
    assert plan_has_top_and_verification(paper_plan)
    assert_every_stance_passes_the_guard(paper_plan, body)


def plan_has_top_and_verification(plan) -> bool:
    return any(st.camera == "top" for st in plan.stills()) and len(plan.verification) == 4


@pytest.mark.slow
def test_every_stance_of_the_realistic_mocks_plans_passes_the_guard(body):
    """As above, for the plans the realistic mock's runs use (its prior intrinsics, fx = 618 px): paper and
    optimal; and the guard, knowing each robot's offsets, finds a clear way for every move of the plan (before: on
    realistic seed 1 the optimal plan's right-leg stances had none and were left out)."""
    from naocal.backends.mock import default_intrinsics

    prior = default_intrinsics("realistic").to_dict()
    intrinsics = {k: prior[k] for k in ("fx_px", "fy_px", "cx_px", "cy_px", "width_px", "height_px")}
    for kind in ("paper", "optimal"):
        plan = make_plan(0, PlanSettings(kind=kind, intrinsics=dict(intrinsics, distortion=[0.0] * 5)))
        assert plan_has_top_and_verification(plan)
        assert_every_stance_passes_the_guard(plan, body)
        for state, guard in _guards_of_realistic_robots(body):
            if state != "nothing known":
                assert not blocked_moves(plan, guard), (kind, state, blocked_moves(plan, guard)[:3])


def blocked_moves(plan, guard, speed_fraction=0.4):
    """The plan's moves, in the order the agent makes them (calibration, top camera, verification; each sweep
    from its start to its end), for which `guard` finds no clear way, direct or through detours."""
    from naocal.agent.plan import Sweep

    targets = []
    for step in plan.steps:
        targets += [("sweep", step.start(), step.speed_fraction), ("sweep", step.end(), step.speed_fraction)] if (
            isinstance(step, Sweep)) else [(f"{step.camera} capture {step.image}", step.angles(), speed_fraction)]
    targets += [(f"verification {st.leg} {st.stance}", st.angles(), speed_fraction) for st in plan.verification]
    position, blocked = np.asarray(plan.parked()), []
    for what, target, fraction in targets:
        try:
            guard.waypoints(position, np.asarray(target), fraction, np.asarray(plan.parked()))
        except SafetyError as err:
            blocked.append((what, str(err)))
            continue
        position = np.asarray(target)
    return blocked


def test_the_guard_finds_a_way_for_every_move_of_the_plan_on_a_robot_with_a_large_hip_yaw_pitch_offset(
        paper_plan, body):
    """Realistic seed 1 carries an 11.2 deg HipYawPitch offset, the one motor both legs turn with: once it is
    known, the agent's guard must find a clear way (direct or a detour) for every move of the plan."""
    for state, guard in _guards_of_realistic_robots(body, seeds=(1,)):
        if state == "realistic seed 1":
            assert not blocked_moves(paper_plan, guard)
