"""Effects as units (solver/effect.py, solver/effects/): discovered, complete, exactly differentiated in any setup,
written to and read from the offsets file by themselves, and the model's pipeline over their hooks."""

import functools
import math

import numpy as np
import pytest

from naocal.solver.effect import ALLOWED_UNITS, Effect, Setup
from naocal.solver.effects import ALL_EFFECTS, BASE_EFFECTS, EFFECTS, EXTRA_EFFECTS, owner_of, parse_effect_names
from naocal.solver.errors import NaocalError
from naocal.solver.identify import identify
from naocal.solver.model import Model
from naocal.solver.registry import Registry
from naocal.solver.robot import nao
from naocal.sim.synthetic import random_truth, synthesize_views

# Two cameras and three targets: the sandals on hanging legs and a floor board under a supporting leg; irregular
# vertex counts (24 and 9). Views beyond the joint limits are fine for the mathematics.
WIDE = Setup(nao(), ("bottom", "top"), ("L", "R", "floor"))


@functools.lru_cache(maxsize=None)
def wide_data(seed=0, velocity=0.3):
    rng = np.random.default_rng(seed)
    return synthesize_views(rng, random_truth(rng, setup=WIDE), WIDE, n_stances=4, n_postures=1,
                            velocity_rad_s=velocity, within_limits=False)


def test_every_module_is_discovered_in_order():
    assert BASE_EFFECTS == ("joint_offsets", "camera_rotation", "board_mount")
    assert EXTRA_EFFECTS[:7] == ("elasticity", "backlash", "link_lengths", "head_offsets", "intrinsics",
                                 "distortion", "time_lag")
    assert ALL_EFFECTS == BASE_EFFECTS + EXTRA_EFFECTS
    for name, effect in EFFECTS.items():
        assert isinstance(effect, Effect) and effect.name == name


def test_the_wheel_effects_are_modules_of_the_registry():
    """Issue 22: a differential drive's effects are modules of solver/effects/ with the drive_parameters hook (the
    Duckiebot's fit takes them from there: their parameters, units, scales and starts); pwm_driver is a choice of
    model without a parameter; none is a term of the NAO's model or an arm's."""
    from naocal.kinds.duckiebot import fit
    from naocal.solver.effects import ARM_MODEL_EFFECTS, DRIVE_EFFECTS

    assert DRIVE_EFFECTS == ("dead_zone", "slip", "wheel_lag", "speed_trim", "lag_difference", "pwm_driver")
    assert not set(DRIVE_EFFECTS) & set(ALL_EFFECTS + ARM_MODEL_EFFECTS)
    assert fit.ALL_EFFECTS == DRIVE_EFFECTS and fit.LAG_EFFECTS == ("wheel_lag", "lag_difference")
    for name in DRIVE_EFFECTS:
        effect = EFFECTS[name]
        assert effect.summary and not effect.parameters(Setup.everything())
        for p in effect.drive_parameters():
            assert p.effect == name and p.unit in ALLOWED_UNITS and p.scale > 0 and p.component == p.name
            assert fit.SCALES[p.name] == p.scale and fit.EFFECT_START.get(p.name, 0.0) == p.start
    assert {n: names for n, names in fit.EFFECTS.items()} == {
        "dead_zone": ("dead_zone",), "slip": ("slip_s_per_m",), "wheel_lag": ("wheel_lag_s",),
        "speed_trim": ("speed_trim",), "lag_difference": ("wheel_lag_difference_s",)}
    assert EFFECTS["pwm_driver"].drive_parameters() == [] and fit.EFFECT_START == {"wheel_lag_s": 0.06}


@pytest.mark.parametrize("name", ALL_EFFECTS)
def test_each_effect_is_complete(name):
    """Parameters with units and scales, a summary, a plausible size, a section of the offsets file, a display."""
    effect = EFFECTS[name]
    parameters = effect.parameters(Setup.everything())
    assert parameters and effect.summary
    for p in parameters:
        assert p.effect == name and p.unit in ("rad", "m", "px", "s", "rad/(N m)", "1") and p.scale > 0
        value, unit = effect.display(p, p.scale)
        assert math.isfinite(value) and isinstance(unit, str)
    assert effect.plausible_limit > 0
    assert effect.offsets_section in ("body", "head", "targets") and effect.offsets_key
    if effect.mock_size_unit is None:  # the base model's terms: the mock draws them as its base truth
        with pytest.raises(NotImplementedError):
            effect.mock_perturbation(np.random.default_rng(0), 1.0, Setup.everything())
    else:  # its mock injection: a plain description, drawn from the stream it is given, zero at size 0
        import json

        from naocal.solver.effect import MockPerturbation

        first = effect.mock_perturbation(np.random.default_rng(7), 1e-3, Setup.everything())
        again = effect.mock_perturbation(np.random.default_rng(7), 1e-3, Setup.everything())
        assert isinstance(first, MockPerturbation) and first.record
        assert json.loads(json.dumps(first.record)) == first.record == again.record
        assert first != MockPerturbation(record=first.record)  # it perturbs something
        zero = effect.mock_perturbation(np.random.default_rng(7), 0.0, Setup.everything())
        assert all(not np.any(np.asarray(v, dtype=float)) for d in (zero.alpha_rad, zero.compliance_rad_per_nm,
                   zero.half_play_rad, zero.link_deltas_m, zero.intrinsics_px, zero.distortion,
                   zero.camera_translation_m) for v in d.values()) and zero.image_stamp_late_s == 0.0


@pytest.mark.parametrize("name", ALL_EFFECTS)
def test_each_effect_writes_and_checks_its_section(name):
    from naocal.solver.errors import DataError

    effect = EFFECTS[name]
    setup = Setup.everything()
    values = {p.name: 0.5 * p.scale for p in effect.parameters(setup)}
    content = effect.write_offsets(values, setup)
    assert content
    effect.read_offsets(content, "f.json", "section", nao())  # accepted as written
    damaged = _damage_first_number(content, 1e6)
    with pytest.raises(DataError, match="implausible size") as info:
        effect.read_offsets(damaged, "f.json", "section", nao())
    assert info.value.field.startswith("section.")


def _damage_first_number(content, value):
    if isinstance(content, dict):
        key = next(iter(content))
        return {**content, key: _damage_first_number(content[key], value)}
    return value


@pytest.mark.parametrize("name", ALL_EFFECTS)
def test_each_effect_gradient_in_a_wide_setup(name):
    """d residual / d parameter against central differences, for every parameter of the effect, with two cameras,
    three targets, irregular boards and moving joints; the other parameters away from zero."""
    data = wide_data()
    registry = Registry(ALL_EFFECTS, setup=WIDE)
    model = Model(data, registry)
    rng = np.random.default_rng(1)
    x = registry.scales * rng.uniform(-1.0, 1.0, len(registry))
    for p in registry.parameters:
        if p.effect == "elasticity":
            x[registry.index[p.name]] = abs(x[registry.index[p.name]])
    _, J = model.evaluate(x)
    for i, p in enumerate(registry.parameters):
        if p.effect != name:
            continue
        h = 1e-4 * p.scale
        step = np.zeros(len(x))
        step[i] = h
        fd = (model.residuals(x + step) - model.residuals(x - step)) / (2 * h)
        scale = max(np.abs(J[:, :, i]).max(), 1e-9)
        assert np.abs(fd - J[:, :, i]).max() / scale < 1e-5, p.name


def test_identification_recovers_both_cameras_and_every_target_mount():
    rng = np.random.default_rng(2)
    truth = random_truth(rng, setup=WIDE)
    data = synthesize_views(rng, truth, WIDE, n_stances=8, n_postures=2, within_limits=False)
    result = identify(data, Registry.for_data(data))
    assert result.success
    assert result.registry.setup == WIDE
    for name, value in truth.items():
        std = result.std[result.registry.index[name]]
        assert abs(result.value(name) - value) < 5 * std + 1e-9, name


def test_the_model_refuses_data_its_registry_was_not_made_for():
    with pytest.raises(NaocalError, match="Registry.for_data"):
        Model(wide_data(), Registry())


def test_names_and_owners():
    assert parse_effect_names("elasticity, time_lag,elasticity") == ("elasticity", "time_lag")
    with pytest.raises(NaocalError, match="part of the base model"):
        parse_effect_names("board_mount")
    with pytest.raises(NaocalError, match="unknown effect 'sag'"):
        parse_effect_names("sag")
    setup = Setup.default()
    assert owner_of("joint_offset.LKneePitch", setup).name == "joint_offsets"
    assert owner_of("camera.bottom.pitch", setup).name == "camera_rotation"
    assert owner_of("camera.top.pitch", setup) is None  # not in this setup
    assert owner_of("link_length.R.tibia", setup).name == "link_lengths"


def test_registry_layout_of_the_paper_model():
    registry = Registry(tie_hip_yaw_pitch=True)
    assert len(registry) == 21 and len(registry.free_names) == 20
    assert registry.names[12:15] == ("camera.bottom.roll", "camera.bottom.pitch", "camera.bottom.yaw")
    assert registry.parameter("joint_offset.RHipYawPitch").tied_to == "joint_offset.LHipYawPitch"
    floor = Registry(setup=Setup(nao(), ("bottom",), ("floor",)))
    assert [p.joint for p in floor.parameters if p.effect == "joint_offsets"] == [
        "RHipYawPitch", "RHipRoll", "RHipPitch", "RKneePitch", "RAnklePitch", "RAnkleRoll"]  # the support leg


def test_joint_offset_is_c_the_offset_robot_code_stores():
    """q_true = theta - c: a positive c of a joint moves the board as a negative change of its reading does."""
    data = wide_data(velocity=0.0)
    registry = Registry(setup=WIDE)
    model = Model(data, registry)
    c = registry.zeros()
    c[registry.index["joint_offset.RKneePitch"]] = 0.01
    moved = model.data
    theta = moved.theta.copy()
    moved.theta = theta.copy()
    moved.theta[:, moved.column("RKneePitch")] -= 0.01
    try:
        by_reading = Model(moved, registry).residuals(registry.zeros())
    finally:
        moved.theta = theta
    np.testing.assert_allclose(model.residuals(c), by_reading, atol=1e-9)


def test_elasticity_follows_the_datasets_board_mass_and_per_image_gravity():
    """Not the NAO's sandal constant: the dataset's board mass and each image's gravity load the joints."""
    data = wide_data(velocity=0.0)
    registry = Registry(("elasticity",), setup=WIDE)
    x = registry.zeros()
    for p in registry.parameters:
        if p.effect == "elasticity":
            x[registry.index[p.name]] = 0.05
    q0 = Model(data, registry).joint_angles(x)
    heavy = data.subset(np.arange(data.n_images))
    heavy.loads = {t: (m * 3 + 0.2, c) for t, (m, c) in data.loads.items()}
    tilted = data.subset(np.arange(data.n_images))
    tilted.gravity_mps2 = tilted.gravity_mps2[:, [1, 0, 2]]
    for changed in (heavy, tilted):
        q = Model(changed, registry).joint_angles(x)
        hanging = np.isin(changed.target, ("L", "R"))
        assert np.abs(q - q0)[hanging].max() > 1e-4
        assert np.abs(q - q0)[~hanging].max() == 0.0  # the floor board's leg carries the body: not modelled


class _Shift(Effect):
    """A test effect: a camera moved along its parent link's x axis (a camera term beside camera_rotation's)."""

    name, order = "test_shift", 999
    summary = "test"

    def parameters(self, setup):
        from naocal.solver.effect import Parameter

        return [Parameter(f"shift.{c}", self.name, "m", 0.002, camera=c) for c in setup.cameras]

    def camera_terms(self, layout, values):
        from naocal.solver.effect import CameraTerm

        return [CameraTerm(p.camera, translation=np.array([values[i], 0.0, 0.0]),
                           translation_params=[(i, np.array([1.0, 0.0, 0.0]))])
                for i, p in layout.params(self.name) if p.camera in layout.cameras]


def test_camera_terms_of_two_effects_combine(monkeypatch):
    """A second effect may move a camera that camera_rotation turns: the translation and the rotation compose, and
    the Jacobian stays exact."""
    import naocal.solver.effects  # noqa
    from naocal import solver
    monkeypatch.setitem(solver.effects.EFFECTS, "test_shift", _Shift())
    data = wide_data(velocity=0.0)
    registry = Registry(("test_shift",), setup=WIDE)
    model = Model(data, registry)
    x = registry.scales * np.random.default_rng(3).uniform(-1, 1, len(registry))
    _, J = model.evaluate(x)
    for name in ("shift.bottom", "shift.top", "camera.top.pitch"):
        i = registry.index[name]
        step = np.zeros(len(x))
        step[i] = 1e-7
        fd = (model.residuals(x + step) - model.residuals(x - step)) / 2e-7
        assert np.abs(fd - J[:, :, i]).max() < 1e-5 * np.abs(J[:, :, i]).max(), name
    moved = x.copy()
    moved[registry.index["shift.bottom"]] += 0.005
    changed = np.abs(model.residuals(moved) - model.residuals(x)).max(axis=1) > 0
    assert np.array_equal(changed, (model.data.camera == "bottom")[model.data.image_of_row])


@pytest.mark.parametrize("name", EXTRA_EFFECTS)
def test_each_effects_report_picture_is_well_formed(name):
    """partial_residual_panels of a fit with the effect: points and the fitted line, finite, one group per point."""
    from naocal.sim.synthetic import synthesize

    rng = np.random.default_rng(6)
    velocity = np.zeros((48, 14))
    velocity[::4] = rng.uniform(-0.4, 0.4, (12, 14))
    data = synthesize(rng, random_truth(rng), n_stances_per_leg=8, velocity=velocity)
    fit = identify(data, Registry((name,)))
    for x, y, xlabel, ylabel, groups, (line_x, line_y) in EFFECTS[name].partial_residual_panels(fit):
        assert len(x) == len(y) == len(groups) > 0 and len(line_x) == len(line_y)
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(y)) and np.all(np.isfinite(line_y))
        assert xlabel and ylabel and set(groups) <= {"L", "R"}


def test_docs_effects_table_has_a_row_for_every_module():
    """docs/EFFECTS.md's one table names every module of the registry, whatever kind's model takes it."""
    from conftest import ROOT

    rows = {line.split("|")[1].strip() for line in (ROOT / "docs" / "EFFECTS.md").read_text().splitlines()
            if line.startswith("| ")}
    assert set(EFFECTS) <= rows, sorted(set(EFFECTS) - rows)
