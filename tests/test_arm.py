"""The arm model (kinds/arm/model.py), its dataset format, identification and diagnostics on synthetic data, and the
simulated PyBullet arm against naocal's kinematics (docs/ARM.md)."""

import json
import math
import os

import numpy as np
import pytest

from naocal.kinds.arm.model import ArmModel, Observations, Sensor, exp_so3, left_jacobian, log_so3
from naocal.kinds.arm.dataset import read_arm_dataset, resolve_robot, write_arm_dataset
from naocal.kinds.arm.identify import camera_pose_dlt, fit, initialise_sensors
from naocal.solver.effects import ARM_EFFECTS, EFFECTS
from naocal.solver.errors import DataError
from naocal.kinds.arm.scenarios import CAMERA, panda, true_errors  # noqa: F401  (the arm's tests' one home)
from tests.cli_runner import naocal as naocal_in_process, naocal_process

def tool():
    from naocal.kinds.arm.sim import tool_points

    return tool_points()


def synthetic(effects, truth, n_poses=50, seed=0, noise_m=1e-4, noise_px=0.2, pose_error_rad=0.0):
    """A model of the panda with a tracker and a camera, readings at random stances and their measurements
    (the model's own predictions at `truth` plus noise; with `pose_error_rad` the arm stands at each pose off its
    readings by a random error of each joint, shared by that pose's measurements)."""
    urdf, base, tip, chain, names, load = panda()
    rng = np.random.default_rng(seed)
    sensors = [Sensor("tracker", "points", noise=noise_m), Sensor("camera", "camera", dict(CAMERA), noise_px)]
    model = ArmModel(chain, tool(), sensors, effects, load=load, link_names=names)
    lo = np.array([-2.5, -1.5, -2.5, -2.8, -2.5, 0.3, -2.5])
    hi = np.array([2.5, 1.5, 2.5, -0.4, 2.5, 3.4, 2.5])
    theta = rng.uniform(lo, hi, (n_poses, 7))
    rows = [(i, 0, p) for i in range(n_poses) for p in range(3)] + [(i, 1, p) for i in range(n_poses)
                                                                    for p in range(3, 7)]
    obs = Observations(theta[[r[0] for r in rows]], np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                       np.array([r[2] for r in rows]), np.zeros((len(rows), 3)))
    R_cam = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])  # x_cam = -x_base: looks back at the arm
    x = np.array([truth.get(n, 0.0) for n in model.names])
    for i, p in enumerate(model.parameters):
        if p.effect == "sensors" and p.name not in truth:  # axis 0-2: its translation, 3-5: its rotation
            x[i] = {(0, True): (0.4, -0.3, 1.2), (0, False): (1.5, -2.0, 0.3),
                    (1, True): (0.01, 0.02, -0.01), (1, False): (2.5, 0.1, -0.4)}[(p.index, p.axis >= 3)][p.axis % 3]
    model.R0[1] = R_cam
    standing = obs
    if pose_error_rad:
        standing = obs.subset(np.arange(len(obs)))
        standing.theta = obs.theta + rng.normal(0.0, pose_error_rad, (n_poses, 7))[obs.pose]
    pred = model.predict(x, standing)
    noise = np.where(obs.sensor[:, None] == 0, noise_m, noise_px) * rng.normal(size=pred.shape)
    noise[obs.sensor == 1, 2] = 0.0
    obs.measured = pred + noise
    keep = (obs.sensor == 0) | ((pred[:, 0] > 0) & (pred[:, 0] < 1280) & (pred[:, 1] > 0) & (pred[:, 1] < 1024))
    obs = obs.subset(keep)
    model.R0[:] = np.eye(3)  # identification finds the frames itself
    return model, obs, dict(zip(model.names, x)), sensors


# ------------------------------------------------------------------------------------------------ maths


def test_rotation_helpers_round_trip_and_left_jacobian():
    rng = np.random.default_rng(0)
    for phi in list(rng.normal(size=(5, 3))) + [np.array([math.pi - 1e-9, 0.0, 0.0]), np.zeros(3)]:
        assert np.allclose(exp_so3(log_so3(exp_so3(phi))), exp_so3(phi), atol=1e-9)
        e = np.array([1e-7, -2e-7, 3e-7])
        assert np.allclose(exp_so3(phi + e), exp_so3(left_jacobian(phi) @ e) @ exp_so3(phi), atol=1e-12)


def test_jacobian_matches_finite_differences_for_every_effect():
    model, obs, truth, _ = synthetic(ARM_EFFECTS, {}, n_poses=8)
    rng = np.random.default_rng(3)
    model.R0[1] = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    x = np.array([truth[n] for n in model.names]) + rng.normal(0.0, 0.02, len(model.names)) * model.scales * 10
    _, J = model.predict(x, obs, jacobian=True)
    numeric = np.empty_like(J)
    for i in range(len(x)):
        h = 1e-6
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        numeric[:, :, i] = (model.predict(up, obs) - model.predict(down, obs)) / (2 * h)
    scale = np.abs(numeric).max(axis=(0, 1)) + 1e-3  # columns near zero (the hand's tiny torque): absolute
    worst = (np.abs(J - numeric).max(axis=(0, 1)) / scale)
    assert worst.max() < 1e-5, model.names[int(np.argmax(worst))]
    # every effect but marker_scale (one parameter per sheet of printed markers: this tool has none; the dual arm's
    # Jacobian test has them)
    assert {p.effect for p in model.parameters} == set(ARM_EFFECTS) - {"marker_scale"} | {"sensors"}


# ------------------------------------------------------------------------------------------------ identification


def test_identify_recovers_link_lengths_and_joint_offsets_and_fixes_what_is_not_identifiable():
    truth = true_errors()
    model, obs, x_true, _ = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=60)
    result = fit(model, obs, initialise_sensors(model, obs))
    assert result.success
    values = result.model.reported_values(result.x)
    # the first joint turns the whole arm about an axis through the base: a sensor rotation does the same
    assert set(result.fixed_reasons) == {"joint_offset.panda_joint1", "link_length.panda_link0"}
    assert "sensor." in result.fixed_reasons["joint_offset.panda_joint1"]
    for name, free in zip(model.names, result.free):
        if not free or name.startswith("sensor."):
            continue
        tolerance = 1e-4 if name.startswith("link_length.") else math.radians(0.01)
        assert abs(values[name] - truth[name]) < tolerance, name
    assert result.rms()["tracker"] == pytest.approx(1e-4, rel=0.15)


def test_measurement_kinds_give_their_exact_jacobian():
    """Pixels (with lens distortion) and 3-D points: d residual / d y against central differences; the components a
    kind does not measure are 0."""
    from naocal.solver.measurement import MEASUREMENTS, residual

    rng = np.random.default_rng(4)
    y = np.column_stack([rng.uniform(1.0, 3.0, 20), rng.uniform(-0.5, 0.5, 20), rng.uniform(-0.5, 0.5, 20)])
    sensor = Sensor("camera", "camera", dict(CAMERA), 0.2)
    for kind, measurement in MEASUREMENTS.items():
        measured = rng.normal(size=(20, 3)) * 100.0
        r, J = residual(kind, y, measured, sensor)
        numeric = np.empty_like(J)
        for c in range(3):
            h = np.zeros(3)
            h[c] = 1e-6
            numeric[:, :, c] = (residual(kind, y + h, measured, sensor)[0]
                                - residual(kind, y - h, measured, sensor)[0]) / 2e-6
        assert np.abs(J - numeric).max() < 1e-6 * max(np.abs(numeric).max(), 1.0), kind
        unmeasured = ~np.array(measurement.measured)
        assert np.all(r[:, unmeasured] == 0.0) and np.all(J[:, unmeasured] == 0.0)
    assert set(MEASUREMENTS) == {"points", "camera"}


def test_the_arm_s_normal_equations_in_chunks_equal_one_pass_and_its_jacobian():
    """ArmEquations (the arm's side of solver.identify.solve) accumulated over chunks of 7 observations: the same
    normal matrix, gradient, cost and per-observation scores as one pass, and A = Js^T Js of the dense Jacobian."""
    from naocal.kinds.arm.identify import ArmEquations

    model, obs, truth, _ = synthetic(("joint_offsets", "link_lengths", "elasticity"), true_errors(), n_poses=9)
    x = initialise_sensors(model, obs)
    free = np.ones(len(x), bool)
    sigma = np.array([1e-4, 0.2])
    one, chunked = ArmEquations(model, obs, x, free, sigma), ArmEquations(model, obs, x, free, sigma, chunk_rows=7)
    assert len(chunked.chunks) > 5
    weights = np.random.default_rng(2).uniform(0.2, 1.0, len(obs))
    for w in (None, weights):
        a, b = one(x, weights=w), chunked(x, weights=w)
        assert np.allclose(a.A, b.A, rtol=1e-12, atol=1e-9) and np.allclose(a.g, b.g, rtol=1e-12, atol=1e-9)
        assert a.cost == pytest.approx(b.cost, rel=1e-12) and np.allclose(a.image_scores, b.image_scores)
    r, J = chunked.dense(x)
    Js = J * chunked.scales
    assert np.allclose(Js.T @ Js, one(x).A, rtol=1e-10, atol=1e-9) and r.size == model.component_mask(obs).sum()


def test_arm_stds_are_per_pose_and_cover_errors_shared_within_a_pose():
    """An arm that does not return exactly (0.05 deg per joint and pose, shared by the pose's measurements): the
    classic standard deviations (the arm's own, before it used the NAO's identification) claim far more than the
    data hold; the cluster-robust ones, the cluster being the pose, cover the truth."""
    truth = true_errors(seed=1)
    model, obs, _, _ = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=40, seed=1,
                                 pose_error_rad=math.radians(0.05))
    result = fit(model, obs, initialise_sensors(model, obs))
    values = result.model.reported_values(result.x)
    identified = [i for i, n in enumerate(model.names) if result.free[i] and n in truth]
    z = np.array([(values[model.names[i]] - truth[model.names[i]]) / result.std[i] for i in identified])
    assert len(identified) >= 11 and np.abs(z).max() < 3.5, z
    z_classic = np.array([(values[model.names[i]] - truth[model.names[i]]) / result.std_iid[i] for i in identified])
    assert np.abs(z_classic).max() > 4.0, z_classic


def damaged(obs, fraction=0.02, seed=7):
    """A copy of `obs` with `fraction` of its detections wrong (a marker taken for another, a reflection): 3 mm
    off for the tracker, 20 px for the camera, in a random direction; and the rows damaged."""
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(len(obs), size=max(1, round(fraction * len(obs))), replace=False))
    out = obs.subset(np.arange(len(obs)))
    out.measured = obs.measured.copy()
    for k in rows:
        direction = rng.normal(size=3)
        if obs.sensor[k] == 1:
            direction[2] = 0.0
        out.measured[k] += direction / np.linalg.norm(direction) * (3e-3 if obs.sensor[k] == 0 else 20.0)
    return out, rows


@pytest.mark.parametrize("loss", ["linear", "soft_l1", "huber"])
def test_two_percent_wrong_detections_are_set_aside_listed_and_change_nothing(loss):
    """As the NAO's mis-detected corners (solver.fit): each wrong detection is set aside and listed by pose, sensor
    and point, with the linear loss or a robust one; the result covers the truth (linear: the clean data's within
    half its std)."""
    truth = true_errors(seed=3)
    model, obs, _, _ = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=50, seed=3)
    clean = fit(model, obs, initialise_sensors(model, obs))
    bad_obs, rows = damaged(obs)
    result = fit(model, bad_obs, initialise_sensors(model, bad_obs), loss=loss)
    assert result.success and result.loss == loss
    listed = {(o.pose, o.sensor, o.point) for o in result.outliers}
    assert listed == {(int(obs.pose[k]), model.sensors[obs.sensor[k]].name, model.point_names[obs.point[k]])
                      for k in rows}
    assert all(o.size > (2e-3 if o.unit == "m" else 10.0) for o in result.outliers)
    values = result.model.reported_values(result.x)
    for i, name in enumerate(model.names):
        if clean.free[i] and not name.startswith("sensor."):
            assert abs(values[name] - truth[name]) < 3.5 * result.std[i], name
            if loss == "linear":  # the same fit less the wrong detections
                assert abs(result.x[i] - clean.x[i]) < 0.5 * clean.std[i], name
    assert "set aside" in __import__("naocal.kinds.arm.identify", fromlist=["x"]).describe_outliers(result.outliers)


def test_arm_gauges_are_fixed_at_the_nao_s_threshold_and_a_sensor_never_is():
    """One identifiability policy (solver.identify.gauges): 1e-6, the NAO's. A parameter within it of the span of
    those before it in the kind's order is fixed and said so; one that may not be fixed (a sensor frame) stops the
    fit with the NAO's message instead."""
    from naocal.solver.errors import SolveError
    from naocal.solver.identify import UNIDENTIFIABLE_RATIO, gauges

    rng = np.random.default_rng(5)
    J = rng.normal(size=(50, 4))
    J[:, 2] = J[:, 0] - 2 * J[:, 1] + 0.3 * UNIDENTIFIABLE_RATIO * np.linalg.norm(J[:, 0] - 2 * J[:, 1]) * \
        np.linalg.qr(np.column_stack([J[:, :2], rng.normal(size=50)]))[0][:, 2]  # within the threshold: a gauge
    J[:, 3] = J[:, 0] + 30 * UNIDENTIFIABLE_RATIO * np.linalg.norm(J[:, 0]) * \
        np.linalg.qr(np.column_stack([J[:, :2], rng.normal(size=50)]))[0][:, 2]  # beyond it: determined
    found = gauges(J.T @ J, [0, 1, 2, 3], [True] * 4)
    assert set(found) == {2} and set(found[2][0]) == {0, 1}
    assert gauges(J.T @ J, [0, 1, 2, 3], [True, True, False, True]) == {}
    # an arm whose tracker sees one point only, at poses where only the last joint turns: its frame is undetermined
    # a tracker (its pose given) that sees one point in one place: a turn about that point moves nothing
    both, obs, _, _ = synthetic(("joint_offsets",), {}, n_poses=12, seed=4)
    tracker = Sensor("tracker", "points", noise=1e-4, prior_rotation=(0.0, 0.0, 0.0),
                     prior_translation=(0.0, 0.0, 0.0))
    model = ArmModel(both.chain, dict(zip(both.point_names, both.point_xyz)), [tracker], both.effects,
                     both.gravity_mps2, both.load, both.link_names)
    obs = obs.subset((obs.sensor == 0) & (obs.point == 0))
    obs.theta[:] = obs.theta[0]
    obs.measured = model.predict(model.initial_values(), obs)
    with pytest.raises(SolveError, match="cannot determine.*sensor.tracker.rotation"):
        fit(model, obs, initialise_sensors(model, obs))


def test_a_parameter_no_pose_moves_stops_the_fit_naming_it_and_fitting_the_rest_once_it_is_fixed():
    """The flange's elasticity: the hand's centre of mass lies nearly on its axis, so no pose gives it a gravity
    torque (its column is 1e-18 of the largest). The arm fitted it to -1e13 deg/(N m) with std 0; under the one
    policy it stops the fit with the NAO's message naming it, and `--fix` lets the rest be fitted. With the priors
    (the default, docs/ARM.md) its prior holds it at the URDF's 0, its std the prior's, and the report says so."""
    from naocal.solver.errors import SolveError

    model, obs, _, _ = synthetic(("joint_offsets", "link_lengths", "elasticity"), true_errors(), n_poses=40)
    with pytest.raises(SolveError, match=r"cannot determine 1 parameter combination.*elasticity\.panda_joint7"):
        fit(model, obs, initialise_sensors(model, obs), priors=False)
    held = fit(model, obs, initialise_sensors(model, obs))
    i = model.names.index("elasticity.panda_joint7")
    size = EFFECTS["elasticity"].prior_size["rad/(N m)"]
    assert held.success and held.free[i] and "elasticity.panda_joint7" in held.held_by_prior
    assert abs(held.x[i]) < 1e-3 * size and held.std[i] == pytest.approx(size, rel=1e-3)
    result = fit(model, obs, initialise_sensors(model, obs), fixed=("elasticity.panda_joint7",), priors=False)
    assert result.success and not result.free[model.names.index("elasticity.panda_joint7")]
    assert result.condition_number < 1e6


def test_identify_refuses_a_camera_without_enough_observations():
    model, obs, _, _ = synthetic(("joint_offsets",), {}, n_poses=20)
    few = obs.subset((obs.sensor == 0) | (np.arange(len(obs)) < np.flatnonzero(obs.sensor == 1)[3]))
    with pytest.raises(DataError, match="camera camera: needs 6"):
        initialise_sensors(model, few)


# ------------------------------------------------------------------------------------------------ diagnose


def test_diagnose_names_link_lengths_when_missing_and_nothing_when_complete():
    from naocal.kinds.arm.diagnose import diagnose

    truth = true_errors(seed=4)
    complete, obs, _, _ = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=40, seed=5)
    model = ArmModel(complete.chain, dict(zip(complete.point_names, complete.point_xyz)), complete.sensors,
                     ("joint_offsets",), load=complete.load, link_names=complete.link_names)
    d = diagnose(fit(model, obs, initialise_sensors(model, obs)), n_folds=0)
    assert d.best is not None and d.best.label == "link_lengths"
    d = diagnose(fit(complete, obs, initialise_sensors(complete, obs)), n_folds=0)
    assert d.best is None
    assert {c.label for c in d.candidates} == {"link_poses", "points", "elasticity", "tool", "intrinsics"}


def test_diagnose_judges_per_pose_so_correlated_errors_do_not_name_a_candidate():
    """A real arm's errors are correlated within a pose (repeatability, a tracker's drift): here each pose's
    readings share a random 0.3 mm shift (the camera's a 0.6 px one) beyond the stated 0.1 mm / 0.2 px noise, and
    the model is complete. Counted per measurement, the misfit above the noise makes some candidate significant;
    judged per pose (the poses are the independent units), none is. A real missing effect is still named."""
    from naocal.kinds.arm.diagnose import diagnose

    truth = true_errors(seed=12)
    complete, obs, _, _ = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=60, seed=13)
    rng = np.random.default_rng(14)
    shift = rng.normal(0.0, 1.0, (60, 3)) * [3e-4, 3e-4, 3e-4]
    pixel_shift = rng.normal(0.0, 0.6, (60, 3)) * [1.0, 1.0, 0.0]
    obs.measured = obs.measured + np.where(obs.sensor[:, None] == 0, shift[obs.pose], pixel_shift[obs.pose])
    d = diagnose(fit(complete, obs, initialise_sensors(complete, obs)), n_folds=0)
    assert d.fit.rms()["tracker"] > 2.5e-4  # far above the stated noise: a per-measurement test is fooled
    assert d.best is None, [(c.label, c.p_value) for c in d.candidates]
    # the same data with the link lengths left out of the model: still named
    model = ArmModel(complete.chain, dict(zip(complete.point_names, complete.point_xyz)), complete.sensors,
                     ("joint_offsets",), load=complete.load, link_names=complete.link_names)
    d = diagnose(fit(model, obs, initialise_sensors(model, obs)), n_folds=0)
    assert d.best is not None and d.best.label == "link_lengths"


def test_diagnose_says_which_candidates_too_few_poses_cannot_judge():
    """Significance counts poses: 12 poses cannot judge link poses (13 directions) or points (19); they are marked
    n/a and not named, the 5-parameter elasticity is still tested."""
    from naocal.kinds.arm.diagnose import diagnose, format_diagnosis

    model, obs, _, _ = synthetic(("joint_offsets", "link_lengths"), true_errors(seed=3), n_poses=12, seed=4)
    d = diagnose(fit(model, obs, initialise_sensors(model, obs)), n_folds=0)
    testable = {c.label: c.testable for c in d.candidates}
    assert testable == {"link_poses": False, "points": False, "elasticity": True, "tool": True, "intrinsics": True}
    assert d.best is None and "n/a: link_poses, points" in format_diagnosis(d)


def test_diagnose_names_elasticity_under_gravity():
    from naocal.kinds.arm.diagnose import diagnose, format_diagnosis

    truth = true_errors(seed=6)
    truth.update({f"elasticity.panda_joint{k}": 2e-3 for k in (2, 4)})  # 2 mrad per N m
    model, obs, _, _ = synthetic(("joint_offsets", "link_lengths", "elasticity"), truth, n_poses=50, seed=7)
    base = ArmModel(model.chain, dict(zip(model.point_names, model.point_xyz)), model.sensors,
                    ("joint_offsets", "link_lengths"), load=model.load, link_names=model.link_names)
    d = diagnose(fit(base, obs, initialise_sensors(base, obs)), n_folds=2)
    assert d.best is not None and d.best.label == "elasticity"
    # the flange's elasticity no pose moves is fixed with it (the fit would stop on it), here and in the command
    assert d.best.inert == ("elasticity.panda_joint7",) and d.heldout_with
    assert format_diagnosis(d, "arm").splitlines()[-2].endswith(
        "--effects joint_offsets,link_lengths,elasticity --fix elasticity.panda_joint7 --out calibration.json")


# ------------------------------------------------------------------------------------------------ the format


def write(tmp_path, model, obs, sensors, meta_extra=None):
    urdf, base, tip, *_ = panda()
    points = dict(zip(model.point_names, map(tuple, model.point_xyz)))
    meta = {"robot": {"id": "test", "urdf": str(urdf), "base": base, "tip": tip},
            "points": {p: {"xyz_m": list(v)} for p, v in points.items()},
            "sensors": {"tracker": {"kind": "points", "noise_m": 1e-4},
                        "camera": dict({"kind": "camera", "noise_px": 0.2}, **CAMERA)}}
    meta.update(meta_extra or {})
    write_arm_dataset(tmp_path, meta, model.chain.joint_names, obs, sensors, points)
    return tmp_path


def test_dataset_round_trip_and_units_in_column_names(tmp_path):
    model, obs, _, sensors = synthetic(("joint_offsets",), {}, n_poses=12)
    d = read_arm_dataset(write(tmp_path / "rad", model, obs, sensors))
    assert np.array_equal(d.observations.theta, obs.theta)
    assert np.array_equal(d.observations.measured, obs.measured)
    # the same data in degrees and millimetres, columns reordered, no pose column: the same numbers
    text = (tmp_path / "rad" / "observations.csv").read_text().splitlines()
    header = text[0].split(",")
    rows = [line.split(",") for line in text[1:]]
    new_header = [h.replace("_rad", "_deg").replace("_m", "_mm") if (h.endswith("_rad") or h in ("x_m", "y_m", "z_m"))
                  else h for h in header if h != "pose"]
    out = [",".join(reversed(new_header))]
    for r in rows:
        cells = []
        for h, c in zip(header, r):
            if h == "pose":
                continue
            if h.endswith("_rad"):
                c = repr(math.degrees(float(c)))
            elif h in ("x_m", "y_m", "z_m") and c:
                c = repr(float(c) * 1e3)
            cells.append(c)
        out.append(",".join(reversed(cells)))
    (tmp_path / "deg").mkdir()
    (tmp_path / "deg" / "observations.csv").write_text("\n".join(out) + "\n")
    (tmp_path / "deg" / "dataset.json").write_text((tmp_path / "rad" / "dataset.json").read_text())
    e = read_arm_dataset(tmp_path / "deg")
    assert np.allclose(e.observations.theta, obs.theta, atol=1e-12)
    assert np.allclose(e.observations.measured, obs.measured, atol=1e-12)
    assert len(np.unique(e.observations.pose)) == 12  # rows with the same readings are one pose


@pytest.mark.parametrize("change, message", [
    (lambda h, r: (h.replace("panda_joint3_rad", "panda_joint3"), r), "needs its unit"),
    (lambda h, r: (h, r.replace("tracker", "trackr", 1)), "unknown sensor 'trackr'"),
    (lambda h, r: (h, r.replace(",t1,", ",t9,", 1)), "unknown point 't9'"),
    (lambda h, r: (h.replace("x_m", "x_q"), r), "x_m, y_m, z_m"),
    (lambda h, r: (h, r + "\n1,2\n"), "expected"),
])
def test_bad_observations_are_one_line_naming_file_line_and_field(tmp_path, change, message):
    model, obs, _, sensors = synthetic(("joint_offsets",), {}, n_poses=10)
    d = write(tmp_path, model, obs, sensors)
    lines = (d / "observations.csv").read_text().split("\n", 1)
    header, rest = change(lines[0], lines[1])
    (d / "observations.csv").write_text(header + "\n" + rest)
    with pytest.raises(DataError, match=message) as err:
        read_arm_dataset(d)
    assert "observations.csv" in str(err.value) and "\n" not in str(err.value)


def test_bad_number_names_its_line_and_column(tmp_path):
    model, obs, _, sensors = synthetic(("joint_offsets",), {}, n_poses=10)
    d = write(tmp_path, model, obs, sensors)
    lines = (d / "observations.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[4] = "nan"
    lines[3] = ",".join(cells)
    (d / "observations.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"line 4, field 'panda_joint2_rad'"):
        read_arm_dataset(d)


@pytest.mark.parametrize("meta, message", [
    ({"sensors": {"tracker": {"kind": "laser"}}}, "sensors.tracker.kind"),
    ({"sensors": {"camera": {"kind": "camera", "noise_px": 1}}}, "sensors.camera.width_px"),
    ({"points": {"t1": {"xyz_m": [0, 0]}}}, "points.t1.xyz_m"),
    ({"robot": {"urdf": "missing.urdf", "base": "panda_link0", "tip": "panda_hand"}}, "missing.urdf"),
    ({"robot": {"base": "panda_link0", "tip": "nowhere"}}, "robot.urdf"),
])
def test_bad_dataset_json_names_the_field(tmp_path, meta, message):
    model, obs, _, sensors = synthetic(("joint_offsets",), {}, n_poses=10)
    d = write(tmp_path, model, obs, sensors)
    doc = json.loads((d / "dataset.json").read_text())
    doc.update(meta)
    (d / "dataset.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match=message):
        read_arm_dataset(d)


def test_cli_bad_chain_is_one_line_exit_2(tmp_path):
    model, obs, _, sensors = synthetic(("joint_offsets",), {}, n_poses=10)
    d = write(tmp_path, model, obs, sensors)
    for extra, message in ((["--chain", "panda_link0:nowhere"], "no link 'nowhere'"),
                           (["--chain", "panda_link0"], "BASE_LINK:TIP_LINK"),
                           (["--effects", "gravity"], "unknown arm effect")):
        run = naocal_in_process("identify", d, *extra)
        assert run.returncode == 2, run.stderr
        assert message in run.stderr and run.stderr.count("\n") == 1 and "Traceback" not in run.stderr


def naocal(*argv):
    """naocal in a child process: a read that blocks fails the test (TimeoutExpired) instead of hanging it."""
    return naocal_process(*argv, timeout=60)


@pytest.mark.parametrize("name", ["dataset.json", "observations.csv", "robot.urdf"])
def test_a_fifo_in_an_arm_dataset_is_refused_in_one_line_without_blocking(tmp_path, name):
    import shutil

    model, obs, _, sensors = synthetic(("joint_offsets",), {}, n_poses=10)
    d = write(tmp_path / "d", model, obs, sensors)
    doc = json.loads((d / "dataset.json").read_text())
    shutil.copyfile(doc["robot"]["urdf"], d / "robot.urdf")
    doc["robot"]["urdf"] = "robot.urdf"
    (d / "dataset.json").write_text(json.dumps(doc))
    (d / name).unlink()
    os.mkfifo(d / name)
    args = ["--robot", "franka_panda"] if name == "dataset.json" else []  # (without it: not an arm dataset)
    run = naocal("identify", d, *args)
    assert run.returncode == 2 and name in run.stderr and "FIFO" in run.stderr, run.stderr
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr


def test_an_arm_calibration_file_that_is_a_fifo_is_refused_by_offsets_show(tmp_path):
    os.mkfifo(tmp_path / "arm.json")
    run = naocal("offsets", "show", tmp_path / "arm.json")
    assert run.returncode == 2 and "arm.json" in run.stderr and run.stderr.count("\n") == 1, run.stderr


def test_arm_simulate_takes_its_directory_s_lock_and_only_a_new_or_empty_one(tmp_path, capsys):
    from naocal.agent.rundir import RunLock
    from naocal.tools.cli import main

    out = tmp_path / "out"
    with RunLock(out, "naocal simulate (another run)"):
        assert main(["simulate", "--robot", "franka_panda", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "in use by another run" in err and "naocal simulate (another run)" in err, err
    assert not out.exists()  # the lock made it, and a refused run leaves no trace
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["simulate", "--robot", "franka_panda", "--out", str(out)]) == 2
    assert "not an empty directory" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


# ------------------------------------------------------------------------------------------------ the simulated arm


@pytest.mark.parametrize("robot", ["kuka_iiwa", "franka_panda"])
def test_simulated_arm_agrees_with_the_model_at_its_hidden_truth(robot):
    """PyBullet's forward kinematics of the perturbed URDF equals naocal's model at the truth (to 1 um)."""
    from naocal.kinds.arm.sim import SimulatedArm

    urdf, base, tip = resolve_robot(robot, None)
    with SimulatedArm(urdf, base, tip, seed=2) as arm:
        thetas = arm.sample_stances(5)
        limits = np.array(arm.limits())
        assert np.all((thetas > limits[:, 0]) & (thetas < limits[:, 1]))
        obs, sensors = arm.measure(thetas, noise_m=1e-12, noise_px=1e-9)
        assert sum(1 for v in arm.truth if v.startswith("link_length.")) >= 5
        model = ArmModel(arm.chain, arm.points, sensors, ("joint_offsets", "link_lengths"), load=arm.load,
                         link_names=arm.link_names)
        x = np.array([arm.truth.get(n, 0.0) for n in model.names])
        for s, name in enumerate(("tracker", "camera")):
            model.R0[s] = arm.frames[name][0]
            for i, p in model.params("sensors"):
                if p.index == s:
                    x[i] = 0.0 if p.axis >= 3 else arm.frames[name][1][p.axis]
        error = model.predict(x, obs) - obs.measured
        assert np.abs(error[obs.sensor == 0]).max() < 1e-6  # PyBullet rounds to ~5e-8 m
        assert np.abs(error[obs.sensor == 1, :2]).max() < 1e-3


def test_a_camera_pose_is_found_from_points_and_pixels_without_opencv():
    """The solver's starting camera pose (the direct linear transform, no OpenCV): exact on exact pixels, close
    under 0.2 px noise, refused (None) for points in one plane, which it cannot determine."""
    rng = np.random.default_rng(5)
    R, t = exp_so3(np.array([0.3, -0.5, 0.2])), np.array([0.1, -0.2, 1.5])
    K = np.array([[600.0, 0.0, 320.0], [0.0, 610.0, 240.0], [0.0, 0.0, 1.0]])
    points = rng.uniform(-0.3, 0.3, (40, 3))
    homogeneous = (K @ (points @ R.T + t).T).T
    pixels = homogeneous[:, :2] / homogeneous[:, 2:]
    R_found, t_found = camera_pose_dlt(points, pixels, K)
    assert np.allclose(R_found, R, atol=1e-9) and np.allclose(t_found, t, atol=1e-9)
    R_noisy, t_noisy = camera_pose_dlt(points, pixels + rng.normal(0.0, 0.2, pixels.shape), K)
    assert np.degrees(np.linalg.norm(log_so3(R_noisy @ R.T))) < 0.5 and np.linalg.norm(t_noisy - t) < 0.02
    flat = points * [1.0, 1.0, 0.0]
    assert camera_pose_dlt(flat, pixels, K) is None
    assert camera_pose_dlt(points[:5], pixels[:5], K) is None


def test_the_camera_s_starting_pose_takes_memory_linear_in_its_points():
    """The direct linear transform's SVD of its (2 N, 12) system: only its right singular vectors are needed (a full
    SVD made a (2 N, 2 N) matrix: 288 MB for 3000 points, 13 GB for the 10000 poses of benchmarks/bench_arm.py)."""
    import tracemalloc

    rng = np.random.default_rng(6)
    R, t = exp_so3(np.array([0.2, 0.1, -0.3])), np.array([0.0, 0.1, 2.0])
    K = np.array([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])
    points = rng.uniform(-0.3, 0.3, (3000, 3))
    homogeneous = (K @ (points @ R.T + t).T).T
    pixels = homogeneous[:, :2] / homogeneous[:, 2:]
    tracemalloc.start()
    try:
        R_found, _ = camera_pose_dlt(points, pixels, K)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.allclose(R_found, R, atol=1e-9)
    assert peak < 20 * 2 ** 20, f"{peak / 2 ** 20:.0f} MiB"


def test_the_arm_s_effects_are_the_effect_modules_the_nao_s_model_shares():
    """One home for each effect (solver/effects/): the arm's joint_offsets, link_lengths and elasticity are the NAO's
    modules, its own (sensors, tool, points, link_poses) modules beside them; each declares what the arm needs (its
    parameters, prior size per unit, gauge order) and the arm model has no registry of its own."""
    import naocal.kinds.arm.model as arm
    from naocal.solver.effects import ALL_EFFECTS, ARM_MODEL_EFFECTS, parse_effect_names
    from naocal.solver.errors import NaocalError

    for old in ("ArmParameter", "PRIOR_SIZE", "PRIORITY"):
        assert not hasattr(arm, old), old
    assert getattr(arm, "EFFECTS", EFFECTS) is EFFECTS  # the one registry, not a dict of the arm's
    assert set(ARM_EFFECTS) & set(ALL_EFFECTS) == {"joint_offsets", "link_lengths", "elasticity", "intrinsics"}
    assert ARM_MODEL_EFFECTS == ("sensors",) + ARM_EFFECTS
    assert len({EFFECTS[e].gauge_priority for e in ARM_MODEL_EFFECTS}) == len(ARM_MODEL_EFFECTS)
    with pytest.raises(NaocalError, match="unknown effect 'tool'"):
        parse_effect_names("tool")  # an arm's effect is none of the NAO's model
    model, _, _, _ = synthetic(ARM_EFFECTS, {}, n_poses=2)
    assert [p.effect for p in model.parameters] == sorted((p.effect for p in model.parameters),
                                                          key=lambda e: EFFECTS[e].gauge_priority)
    for p in model.parameters:
        effect = EFFECTS[p.effect]
        assert effect.summary and p.scale > 0 and (p.joint or p.index is not None)
        assert (p.effect == "sensors") == (p.unit not in effect.prior_size), p.name  # a sensor frame: no prior
    # the joint terms are the effects' own hook, the NAO model's JointTerm: q = theta - c + C tau
    offset = next(p for p in model.parameters if p.name == "joint_offset.panda_joint2")
    assert offset.joint == "panda_joint2" and offset.unit == "rad"
