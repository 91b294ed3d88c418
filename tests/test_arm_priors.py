"""Priors (soft bounds) in the one fit (solver.identify.Prior) and the arm's use of them (issue 24): the posterior of
a linear problem is Bayes' exact one, a robust loss never bends a prior's row, and the arm reports which parameters
its priors held."""

import numpy as np
import pytest

from naocal.solver.identify import Normal, Prior, last_pass_cached, solve


class LinearEquations:
    """r = J x - y, one row per observation (each its own cluster), in the shape solver.identify.solve wants."""

    def __init__(self, J, y, scales):
        self.J, self.y, self.scales = J, y, np.asarray(scales, dtype=float)

    def __call__(self, free, *, weights=None, jacobian=True):
        r = self.J @ free - self.y
        rw = r if weights is None else r * np.sqrt(weights)
        Js = self.J * self.scales
        return Normal(Js.T @ Js, Js.T @ rw, 0.5 * float(rw @ rw), r[:, None], Js * rw[:, None])

    def dense(self, free):
        return self.J @ free - self.y, self.J


def _problem(seed=0):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(40, 3))
    J[:, 2] = J[:, 1] + 1e-3 * rng.normal(size=40)  # x1 and x2 nearly the same direction: the prior decides
    y = J @ np.array([1.0, 0.3, -0.2]) + rng.normal(size=40)
    return J, y


def test_a_prior_gives_the_exact_gaussian_posterior_and_is_counted_in_the_covariance():
    J, y = _problem()
    equations = LinearEquations(J, y, [1.0, 0.1, 0.1])
    prior = Prior(np.array([1, 2]), np.array([0.0, 0.1]), np.array([0.5, 0.2]))
    solution = solve(equations, last_pass_cached(equations), np.zeros(3), prior=prior)
    P = np.diag([0.0, 1 / 0.5 ** 2, 1 / 0.2 ** 2])
    mean = np.linalg.solve(J.T @ J + P, J.T @ y + P @ np.array([0.0, 0.0, 0.1]))
    assert np.allclose(solution.free, mean, atol=1e-8)
    spread = solution.spread(np.arange(40), ["a", "b", "c"])
    s2 = 2 * solution.final.cost / (40 + 2 - 3)
    bread = np.linalg.inv(J.T @ J + P)  # the residuals' variance scales the data's information, not the prior's
    assert np.allclose(spread.covariance_iid, bread @ (J.T @ J * s2 + P) @ bread, rtol=1e-6)
    # the data alone barely separate b from c: their posterior stds are near the priors', not the data's 1e3
    std = np.sqrt(np.diag(spread.covariance))
    assert std[1] < 0.5 and std[2] < 0.2
    # without the prior, the same solve is the plain least squares
    plain = solve(equations, last_pass_cached(equations), np.zeros(3))
    assert np.allclose(plain.free, np.linalg.lstsq(J, y, rcond=None)[0], atol=1e-6)


@pytest.mark.parametrize("loss", ["soft_l1", "huber", "cauchy"])
def test_a_robust_loss_bends_the_data_but_never_the_prior(loss):
    """A prior 20 of its stds from the data's answer: a robust loss applied to its row would all but drop it (x0
    back at the data's 1.0); kept quadratic, the answer is Bayes' exact one (the data's rows stay inside the bend)."""
    rng = np.random.default_rng(1)
    J = rng.normal(size=(2000, 2))
    y = J @ np.array([1.0, 2.0]) + 0.05 * rng.normal(size=2000)
    equations = LinearEquations(J, y, [1.0, 1.0])
    prior = Prior(np.array([0]), np.array([0.9]), np.array([0.005]))
    solution = solve(equations, last_pass_cached(equations), np.zeros(2), loss=loss, loss_scale=1.0, prior=prior)
    P = np.diag([1 / 0.005 ** 2, 0.0])
    exact = np.linalg.solve(J.T @ J + P, J.T @ y + P @ np.array([0.9, 0.0]))
    data_only = np.linalg.lstsq(J, y, rcond=None)[0]
    assert solution.success
    assert data_only[0] - exact[0] > 3e-3  # the prior moves it measurably
    assert abs(solution.free[0] - exact[0]) < 2e-4


# ------------------------------------------------------------------------------------------------ the arm


from naocal.solver.effects import EFFECTS  # noqa: E402
from naocal.kinds.arm.identify import RUNOFF_FACTOR, fit, initialise_sensors, prior_sizes, ran_off  # noqa: E402
from naocal.kinds.arm.scenarios import CAMERA, panda, scenario, true_errors  # noqa: E402,F401



@pytest.mark.parametrize("case", ["a", "b", "c"])
def test_a_near_flat_direction_stays_plausible_with_priors_and_stops_naming_it_without(case):
    model, obs, truth, flat = scenario(case)
    with_priors = fit(model, obs, initialise_sensors(model, obs))
    assert with_priors.success and ran_off(with_priors) is None
    size = prior_sizes(model)
    physical = size > 0
    assert np.all(np.abs(with_priors.x[physical]) <= RUNOFF_FACTOR * size[physical])
    # the posterior of what the data determine is the data's: the well-seen parameters are at their truth
    for name in ("joint_offset.panda_joint2", "joint_offset.panda_joint3"):
        i = model.names.index(name)
        assert abs(with_priors.x[i] - truth[name]) < 4 * with_priors.std[i] < 1e-3
    alone = fit(model, obs, initialise_sensors(model, obs), priors=False)
    message = ran_off(alone)
    assert message is not None and " ran off " in message and "relative singular value" in message
    weak = message.split("at the solution): ")[1].split(";")[0]
    assert all(name in weak for name in flat), message  # the direction, by its parameters
    assert any(f"--fix {name}=0" in message for name in flat) and "priors on" in message and "\n" not in message


def test_the_report_says_which_parameters_the_prior_held():
    model, obs, _, _ = scenario("b")
    result = fit(model, obs, initialise_sensors(model, obs))
    held = set(result.held_by_prior)
    # the wrist's link lengths along the flat direction: the prior, not the data; the shoulder's: the data
    assert {"link_length.panda_link4", "link_length.panda_link6"} <= held
    assert "link_length.panda_link2" not in held and "joint_offset.panda_joint2" not in held
    entries = result.parameters_dict()
    assert entries["link_length.panda_link4"]["prior_std"] == EFFECTS["link_lengths"].prior_size["m"]
    assert entries["sensor.tracker.translation.x"]["prior_std"] is None  # a sensor may be anywhere
    i = model.names.index("link_length.panda_link4")
    assert 0.5 * EFFECTS["link_lengths"].prior_size["m"] < result.std[i] <= EFFECTS["link_lengths"].prior_size["m"]
    assert fit(model, obs, initialise_sensors(model, obs), priors=False).held_by_prior == []


def write_scenario(directory, case):
    from naocal.kinds.arm.dataset import write_arm_dataset

    model, obs, truth, flat = scenario(case)
    urdf, base, tip, *_ = panda()
    points = dict(zip(model.point_names, map(tuple, model.point_xyz)))
    sensor = model.sensors[0]
    entry = {"kind": "points", "noise_m": 1e-4} if sensor.kind == "points" else dict(
        {"kind": "camera", "noise_px": 0.2}, **CAMERA)
    meta = {"robot": {"id": "test", "urdf": str(urdf), "base": base, "tip": tip},
            "points": {p: {"xyz_m": list(v)} for p, v in points.items()}, "sensors": {sensor.name: entry}}
    write_arm_dataset(directory, meta, model.chain.joint_names, obs, model.sensors, points)
    return directory, truth, flat


def test_identify_stops_on_a_run_off_fit_writing_nothing_and_fits_it_with_priors_fix_and_start(tmp_path):
    import json

    from tests.cli_runner import naocal

    data, truth, flat = write_scenario(tmp_path / "wrist", "b")
    out = tmp_path / "cal.json"
    alone = naocal("identify", data, "--no-priors", "--out", out)
    assert alone.returncode == 3 and not out.exists()
    assert len(alone.stderr.strip().splitlines()) == 1 and " ran off " in alone.stderr and "--fix" in alone.stderr
    # the --fix it names, at a value in the units the table shows (mm), holds the direction: the rest converges
    fixed = naocal("identify", data, "--no-priors", "--fix", "link_length.panda_link6=-0.5", "--json")
    assert fixed.returncode == 0, fixed.stderr
    entry = json.loads(fixed.stdout)["parameters"]["link_length.panda_link6"]
    assert entry["fixed"] and entry["value"] == pytest.approx(-0.5e-3) and entry["prior_std"] is None
    # the priors on (the default): it converges, writes, and says which parameters its prior held
    ok = naocal("identify", data, "--out", out)
    assert ok.returncode == 0, ok.stderr
    assert "(held by its prior)" in ok.stdout and "priors: " in ok.stdout and "link_length.panda_link6" in ok.stdout
    written = json.loads(out.read_text())
    assert written["model"]["priors"] and "link_length.panda_link6" in written["model"]["held_by_prior"]
    # --start from that file: the same solution (the priors stay about the URDF, not the start)
    again = naocal("identify", data, "--start", out, "--json")
    assert again.returncode == 0, again.stderr
    started = json.loads(again.stdout)["parameters"]
    for name, e in written["model"]["parameters"].items():
        if not name.startswith("sensor."):
            assert started[name]["value"] == pytest.approx(e["value"], abs=1e-3 * max(e["std"], 1e-9) + 1e-9), name


@pytest.mark.parametrize("option, problem", [
    (["--fix", "link_length.nowhere=1"], "is not a parameter of the model"),
    (["--fix", "link_length.panda_link6=abc"], "finite value in mm"),
    (["--fix", "joint_offset.panda_joint2=45"], "within 20 deg"),
    (["--fix", "sensor.tracker.translation.x=3"], "dataset.json"),
    (["--fix", "wobble"], "not a parameter of the model nor an effect"),
    (["--start", "missing.json"], "missing.json"),
])
def test_bad_fix_and_start_are_one_line_and_exit_2(tmp_path, option, problem):
    from tests.cli_runner import naocal

    data, _, _ = write_scenario(tmp_path / "wrist", "b")
    result = naocal("identify", data, *[str(tmp_path / o) if o.endswith(".json") else o for o in option])
    assert result.returncode == 2 and problem in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr


def test_start_refuses_a_calibration_of_a_parameter_the_model_lacks(tmp_path):
    import json

    from tests.cli_runner import naocal

    data, _, _ = write_scenario(tmp_path / "wrist", "c")
    cal = tmp_path / "cal.json"
    assert naocal("identify", data, "--effects", "joint_offsets,link_lengths,points", "--out", cal).returncode == 0
    result = naocal("identify", data, "--effects", "joint_offsets,link_lengths", "--start", cal)
    assert result.returncode == 2 and "model.parameters.point.t1." in result.stderr and "--effects" in result.stderr
    assert json.loads(cal.read_text())["schema"] == "naocal.arm_calibration/1"


# ------------------------------------------------------------------------------------------------ verify on the tracker


def one_sensor_dataset(directory, model, obs, sensors, name, noise_px=0.2):
    """The observations of sensor `name` only, as a dataset whose dataset.json states that sensor alone (its frame
    not given: found from the data)."""
    from naocal.kinds.arm.dataset import write_arm_dataset

    urdf, base, tip, *_ = panda()
    s = [x.name for x in sensors].index(name)
    points = dict(zip(model.point_names, map(tuple, model.point_xyz)))
    entry = {"kind": "points", "noise_m": 1e-4} if name == "tracker" else dict(
        {"kind": "camera", "noise_px": noise_px}, **CAMERA)
    meta = {"robot": {"id": "test", "urdf": str(urdf), "base": base, "tip": tip},
            "points": {p: {"xyz_m": list(v)} for p, v in points.items()}, "sensors": {name: entry}}
    write_arm_dataset(directory, meta, model.chain.joint_names, obs.subset(obs.sensor == s), sensors, points)
    return directory


def camera_calibration_and_tracker(tmp_path):
    """(calibration file from a camera alone, another session's tracker dataset, its reflectors' true positions)."""
    from tests.cli_runner import naocal
    from tests.test_arm import synthetic

    rng = np.random.default_rng(11)
    truth = true_errors()
    reflectors = {f"point.{t}.{a}": rng.uniform(1e-3, 2e-3) * rng.choice((-1, 1)) for t in ("t1", "t2", "t3")
                  for a in "xyz"}
    effects = ("joint_offsets", "link_lengths", "points")
    # the markers where the file says; a camera as precise as the tracker (0.05 px at 2.5 m is some 0.1 mm)
    model, obs, _, sensors = synthetic(effects, truth, n_poses=100, seed=3, noise_px=0.05)
    cameras = one_sensor_dataset(tmp_path / "cameras", model, obs, sensors, "camera", noise_px=0.05)
    model, obs, _, sensors = synthetic(effects, dict(truth, **reflectors), n_poses=40, seed=4)
    tracker = one_sensor_dataset(tmp_path / "tracker", model, obs, sensors, "tracker")
    cal = tmp_path / "from_cameras.json"
    assert naocal("identify", cameras, "--out", cal).returncode == 0
    return cal, tracker, reflectors


def test_a_camera_made_calibration_is_checked_on_a_tracker_whose_frame_and_reflectors_are_unknown(tmp_path):
    """Calibrated from a camera alone; the tracker's data (another session: other poses, its frame unknown, its
    reflectors 1-2 mm off where dataset.json puts them) judged with the arm held: with the reflectors refitted
    (--refit sensors,points) the calibration is still good at the tracker's noise; without, the misplaced reflectors
    look like drift; and the URDF (no calibration) is drifted even with the reflectors refitted."""
    import json

    from tests.cli_runner import naocal

    cal, tracker, reflectors = camera_calibration_and_tracker(tmp_path)
    refitted = naocal("verify", tracker, "--offsets", cal, "--refit", "sensors,points", "--json")
    assert refitted.returncode == 0, refitted.stdout + refitted.stderr
    verdict = json.loads(refitted.stdout)
    assert verdict["good"] and verdict["per_sensor"]["tracker"]["ratio"] < 1.3
    assert verdict["absorbed"]["chi2"] < verdict["absorbed"]["bound"] and not verdict["absorbed"]["beyond"]
    found = {e["parameter"]: e["value"] for e in verdict["refitted"]}
    for name, value in reflectors.items():  # where the reflectors really are, from the tracker with the arm held
        assert abs(found[name] - value) < 3e-4, name
    assert naocal("verify", tracker, "--offsets", cal, "--refit", "sensors,points").stdout.count(
        "refitted with the arm held: point.t1.x") == 1

    as_filed = naocal("verify", tracker, "--offsets", cal, "--json")  # the reflectors taken as dataset.json says
    assert as_filed.returncode == 1 and json.loads(as_filed.stdout)["per_sensor"]["tracker"]["ratio"] > 3

    nominal = json.loads(cal.read_text())
    for name, entry in nominal["model"]["parameters"].items():
        if not name.startswith("sensor."):
            entry["value"] = 0.0
    nominal["joint_offsets_rad"] = {k: 0.0 for k in nominal["joint_offsets_rad"]}
    nominal["link_lengths_m"] = {k: 0.0 for k in nominal["link_lengths_m"]}
    urdf_only = tmp_path / "urdf.json"
    urdf_only.write_text(json.dumps(nominal))
    refuted = naocal("verify", tracker, "--offsets", urdf_only, "--refit", "sensors,points", "--json")
    assert refuted.returncode == 1 and json.loads(refuted.stdout)["per_sensor"]["tracker"]["ratio"] > 3


def test_verify_refit_points_cannot_hide_a_wrong_calibration_in_the_reflectors(tmp_path):
    """The flange's offset 10 deg wrong: the three reflectors 0.1 m around its axis turn by 17 mm, all in the tool's
    frame, which refitting where they sit absorbs whole: the tracker's residual stays at its noise and verify said
    "still good". What the refit absorbed is now judged against the reflectors' prior (3 mm): beyond it, drifted."""
    import json
    import math

    from tests.cli_runner import naocal

    cal, tracker, _ = camera_calibration_and_tracker(tmp_path)
    wrong = json.loads(cal.read_text())
    wrong["model"]["parameters"]["joint_offset.panda_joint7"]["value"] += math.radians(10.0)
    wrong["joint_offsets_rad"]["panda_joint7"] += math.radians(10.0)
    wrong_path = tmp_path / "wrong.json"
    wrong_path.write_text(json.dumps(wrong))
    run = naocal("verify", tracker, "--offsets", wrong_path, "--refit", "sensors,points", "--json")
    verdict = json.loads(run.stdout)
    assert verdict["per_sensor"]["tracker"]["ratio"] < 1.3  # the residual alone is fooled
    assert run.returncode == 1 and not verdict["good"] and verdict["absorbed"]["beyond"]
    assert verdict["absorbed"]["chi2"] > 3 * verdict["absorbed"]["bound"]
    text = naocal("verify", tracker, "--offsets", wrong_path, "--refit", "sensors,points").stdout
    assert "BEYOND what the prior allows" in text and "an arm error can hide there" in text.splitlines()[-1]


@pytest.mark.parametrize("option, problem", [
    (["--refit", "sensors,link_lengths"], "not refitted by verify"),
    (["--refit", "sensors,,points"], "empty name"),
    (["--fix", "joint_offset.panda_joint2=0.1"], "verify holds the calibration's arm"),
])
def test_verify_refit_bad_options_are_one_line_exit_2(tmp_path, option, problem):
    from tests.cli_runner import naocal

    data, _, _ = write_scenario(tmp_path / "wrist", "b")
    cal = tmp_path / "cal.json"
    assert naocal("identify", data, "--out", cal).returncode == 0
    result = naocal("verify", data, "--offsets", cal, *option)
    assert result.returncode == 2 and problem in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_diagnose_takes_fix_values_start_and_no_priors_and_stops_on_a_run_off_fit(tmp_path):
    from tests.cli_runner import naocal

    data, _, _ = write_scenario(tmp_path / "wrist", "b")
    alone = naocal("diagnose", data, "--no-priors")
    assert alone.returncode == 3 and " ran off " in alone.stderr and len(alone.stderr.strip().splitlines()) == 1
    held = naocal("diagnose", data, "--no-priors", "--fix", "joint_offset.panda_joint7=0.25", "--effects",
                  "joint_offsets")
    assert held.returncode == 0, held.stderr
    # the command it suggests holds what this fit held, as it held it
    assert "--fix joint_offset.panda_joint7=0.25 --no-priors --out calibration.json" in held.stdout
    cal = tmp_path / "cal.json"
    assert naocal("identify", data, "--out", cal).returncode == 0
    assert naocal("diagnose", data, "--start", cal).returncode == 0


def test_a_value_the_data_insist_on_is_not_called_a_run_off_and_no_fix_is_suggested():
    """A joint whose readings are 25 deg off the URDF's zero: the data determine it well, so the stop asks about the
    URDF and the zeros, and suggests no --fix (holding it would write a wrong calibration)."""
    import math

    from tests.test_arm import synthetic

    truth = dict(true_errors(seed=8), **{"joint_offset.panda_joint4": math.radians(25.0)})
    model, obs, _, _ = synthetic(("joint_offsets", "link_lengths"), truth, n_poses=30, seed=9)
    message = ran_off(fit(model, obs, initialise_sensors(model, obs)))
    assert message.startswith("joint_offset.panda_joint4 = 25 deg is beyond a calibration")
    assert "the data determine it" in message and "zeros" in message and "--fix" not in message


def test_the_arm_s_options_on_a_nao_dataset_are_refused_not_ignored(tmp_path):
    from tests.cli_runner import naocal

    nao = tmp_path / "nao"  # what a NAO's dataset says it is (the arm's options refuse it before reading on)
    nao.mkdir()
    (nao / "dataset.json").write_text('{"schema": "naocal.dataset/2"}')
    for argv in (["identify", nao, "--no-priors"], ["diagnose", nao, "--start", tmp_path / "x.json"]):
        result = naocal(*argv)
        assert result.returncode == 2 and "an arm's options" in result.stderr, result.stderr
