"""Diagnostics (issue 7) on synthetic data with known hidden effects: compare, locate, names, the loop.

Every dataset here is the model's own prediction at a known truth plus 0.1 px Gaussian pixel noise (the noise
floor), 24 stances per leg x 3 head postures, with about 30 % of the images taken while the joints move (so a
time lag is visible). Effect sizes are realistic (see `effect_truth`).
"""

import functools
import itertools

import numpy as np
import pytest

from naocal.solver.crossval import grouped_cv_rms, stance_folds
from naocal.solver.diagnostics import (
    apparent_errors, candidate_effects, compare, diagnose_result, forward_selection, locate, partial_residuals,
    rank_candidates,
)
from naocal.solver.noisefloor import RigidSplit, noise_floor_estimate, reading_resolution
from naocal.solver.scoretest import effective_clusters, score_test, stance_clusters
from naocal.solver.identify import identify
from naocal.solver.joints import HEAD_JOINTS, LEG_JOINTS
from naocal.solver.model import Model
from naocal.solver.registry import EXTRA_EFFECTS, Registry
from naocal.sim.synthetic import random_truth, synthesize

DEG = np.pi / 180
NOISE_PX = 0.1


def effect_truth(rng, effect) -> dict:
    """Hidden values of realistic size for one effect."""
    sign = lambda: rng.choice([-1.0, 1.0])  # noqa: E731
    if effect == "elasticity":  # 0.02-0.05 rad/(N m): 1-3 deg per N m
        return {f"elasticity.{j}": rng.uniform(0.02, 0.05) for j in LEG_JOINTS}
    if effect == "backlash":  # half play 0.5-1 deg
        return {f"backlash.{j}": rng.uniform(0.5, 1.0) * DEG for j in LEG_JOINTS}
    if effect == "link_lengths":  # 2-3 mm
        return {f"link_length.{leg}.{link}": sign() * rng.uniform(0.002, 0.003)
                for leg in "LR" for link in ("thigh", "tibia")}
    if effect == "head_offsets":  # about 1 deg
        return {f"head_offset.{j}": sign() * rng.uniform(0.7, 1.2) * DEG for j in HEAD_JOINTS}
    if effect == "intrinsics":  # about 10 px
        return {f"intrinsics.bottom.{k}": sign() * rng.uniform(7.0, 12.0) for k in ("fx", "fy", "cx", "cy")}
    if effect == "distortion":
        return {"distortion.bottom.k1": rng.uniform(0.05, 0.1)}
    if effect == "time_lag":  # 30-50 ms
        return {"time_lag.dt": rng.uniform(0.03, 0.05)}
    raise AssertionError(effect)


# The paper's candidates, each tested here; an effect added later brings its own tests (e.g.
# tests/test_effect_camera_translation.py).
HIDDEN = ("elasticity", "backlash", "link_lengths", "head_offsets", "intrinsics", "distortion", "time_lag")


def moving_velocities(rng, n_images, fraction=0.3):
    """(M, 14) rad/s: 0.2-0.5 rad/s of random sign on about `fraction` of the images, zero on the others."""
    velocity = np.zeros((n_images, 14))
    moving = rng.random(n_images) < fraction
    velocity[moving] = rng.choice([-1.0, 1.0], size=(moving.sum(), 14)) * rng.uniform(0.2, 0.5, (moving.sum(), 14))
    return velocity


@functools.lru_cache(maxsize=None)
def make(seed, hidden=(), encoder_resolution_deg=0.0):
    """(data, truth) with the effects `hidden` injected; cached: several tests share one dataset."""
    rng = np.random.default_rng(seed)
    truth = random_truth(rng)
    for effect in hidden:
        truth.update(effect_truth(rng, effect))
    data = synthesize(rng, truth, effects=hidden, velocity=moving_velocities(rng, 144), pixel_noise_px=NOISE_PX,
                      encoder_resolution_rad=encoder_resolution_deg * DEG)
    return data, truth


@functools.lru_cache(maxsize=None)
def base_fit(seed, hidden=(), encoder_resolution_deg=0.0):
    data, _ = make(seed, hidden, encoder_resolution_deg)
    result = identify(data, Registry())
    assert result.success, result.message
    return result


def total_rms(xy):
    return float(np.sqrt((xy[0] ** 2 + xy[1] ** 2) / 2))


# ------------------------------------------------------------------------------------------------------- names


@pytest.mark.parametrize("effect", HIDDEN)
def test_hidden_effect_is_ranked_first_significant_and_fitting_it_reaches_the_noise(effect):
    data, _ = make(11, (effect,))
    ranking = rank_candidates(base_fit(11, (effect,)))
    assert ranking[0].effect == effect, [(c.effect, c.predicted_rms_px) for c in ranking]
    assert ranking[0].significant and ranking[0].plausible
    # It explains most of the misfit (one linearised step; the refit below goes the rest of the way).
    assert ranking[0].predicted_rms_px < 0.2 * total_rms(base_fit(11, (effect,)).rms_px)
    assert ranking[0].predicted_rms_px < 0.5 * min(c.predicted_rms_px for c in ranking[1:] if c.testable)
    fitted = identify(data, Registry((effect,)))
    assert fitted.success
    assert total_rms(fitted.rms_px) < 1.2 * NOISE_PX
    assert total_rms(grouped_cv_rms(data, fitted.registry)) < 1.2 * NOISE_PX
    # ... and with it in the model, nothing else is significant.
    assert not any(c.significant for c in rank_candidates(fitted))


@pytest.mark.parametrize("effect", ["elasticity", "backlash", "link_lengths", "time_lag"])
def test_predicted_values_match_the_hidden_ones(effect):
    _, truth = make(11, (effect,))
    top = rank_candidates(base_fit(11, (effect,)))[0]
    hidden = np.array([truth[n] for n in top.predicted_values])
    predicted = np.array(list(top.predicted_values.values()))
    # One linearised step: most parameters within a few %; weakly excited ones (AnkleRoll feels little gravity
    # torque) further off, which the refit settles.
    assert np.median(np.abs(predicted - hidden) / np.abs(hidden)) < 0.1, (predicted, hidden)


def test_score_test_predicts_the_refit():
    """Small effect (linear regime): predicted RMS and values agree with actually adding the effect."""
    rng = np.random.default_rng(3)
    truth = random_truth(rng)
    truth.update({f"elasticity.{j}": rng.uniform(-0.005, 0.005) for j in LEG_JOINTS})
    data = synthesize(rng, truth, effects=("elasticity",), pixel_noise_px=NOISE_PX)
    top = next(c for c in rank_candidates(identify(data, Registry())) if c.effect == "elasticity")
    refit = identify(data, Registry(("elasticity",)))
    assert top.predicted_rms_px == pytest.approx(total_rms(refit.rms_px), rel=0.01)
    for name, value in top.predicted_values.items():
        assert value == pytest.approx(refit.value(name), abs=0.05 * 0.005)


def test_no_hidden_effect_no_candidate_is_significant():
    """False positives, counted honestly: no candidate significant in any of 8 datasets (4 with 0.1 deg encoder
    quantisation, whose error is shared by the images of a stance), and the p-values look uniform."""
    p_values = []
    for seed, quantisation in [(s, 0.0) for s in range(300, 304)] + [(s, 0.1) for s in range(310, 314)]:
        ranking = rank_candidates(base_fit(seed, (), quantisation))
        assert not any(c.significant for c in ranking), [(c.effect, c.p_value) for c in ranking]
        p_values += [c.p_value for c in ranking if c.testable]
    assert 0.3 < np.mean(p_values) < 0.7, np.mean(p_values)
    assert np.mean(np.array(p_values) < 0.05) < 0.2


def test_stance_clustering_is_needed_with_quantised_encoders():
    """Images of one stance share its encoder error: treating every pixel as independent (the classic chi-square
    test with the fitted sigma) rejects a correct model; the clustered test does not."""
    result = base_fit(310, (), 0.1)
    ext_ranking = rank_candidates(result)
    assert not any(c.significant for c in ext_ranking)
    from naocal.solver.diagnostics import _Extension  # the same projection, classic statistic
    from naocal.solver.scoretest import project_off

    ext = _Extension(result, candidate_effects(result.registry))
    J_tilde = project_off(ext.Q, ext.J[:, ext.columns["elasticity"]])
    test = score_test(J_tilde, ext.residual, ext.clusters, Q=ext.Q)
    classic = test.delta_rss / NOISE_PX ** 2  # chi-square(12) if the pixels were independent with sigma 0.1
    assert classic > 100  # hopelessly "significant"
    assert test.p_value > 1e-3


def test_a_regressor_carried_by_few_clusters_is_not_overconfident():
    """Pure noise, a candidate that lives in 6 of 72 clusters: its p-values must stay uniform (no 1e-11)."""
    rng = np.random.default_rng(31)
    rows_per_cluster, n_clusters = 48, 72
    clusters = list(np.arange(rows_per_cluster * n_clusters).reshape(n_clusters, rows_per_cluster))
    carried = np.zeros(rows_per_cluster * n_clusters)
    carried[: 6 * rows_per_cluster] = rng.normal(size=6 * rows_per_cluster)
    assert effective_clusters(carried[:, None] / np.linalg.norm(carried), clusters) < 6.5
    block6 = np.zeros((len(carried), 6))
    for c in range(6):  # six directions, each in its own cluster: untestable
        block6[clusters[c], c] = 1.0
    assert np.isnan(score_test(block6, rng.normal(size=len(carried)), clusters).p_value)
    p_values = []
    for _ in range(1000):
        cluster_shift = np.repeat(rng.normal(0, 0.5, n_clusters), rows_per_cluster)  # errors shared in a cluster
        p_values.append(score_test(carried[:, None], cluster_shift + rng.normal(size=len(carried)), clusters).p_value)
    p_values = np.array(p_values)
    # Counting all 72 clusters gave 12 % below 0.05, 5 % below 0.01 and a minimum of 5e-13 on these data.
    assert np.mean(p_values < 0.05) < 0.08 and np.mean(p_values < 0.01) < 0.02 and np.min(p_values) > 1e-5


@pytest.mark.parametrize("pair, seed", [(("elasticity", "backlash"), 21), (("link_lengths", "distortion"), 21),
                                        (("head_offsets", "time_lag"), 21), (("elasticity", "intrinsics"), 21)])
def test_two_hidden_effects_adding_the_top_one_names_the_second(pair, seed):
    data, _ = make(seed, pair)
    first = rank_candidates(base_fit(seed, pair))[0]
    assert first.significant and first.effect in pair
    second = rank_candidates(identify(data, Registry((first.effect,))))[0]
    assert second.significant and {first.effect, second.effect} == set(pair)
    final = identify(data, Registry(pair))
    assert total_rms(final.rms_px) < 1.2 * NOISE_PX
    assert not any(c.significant for c in rank_candidates(final))


def test_two_hidden_effects_near_tie_for_raw_drss():
    """Hidden link lengths + intrinsics: by raw dRSS, 12 elasticity parameters would come first (0.950 px against
    0.955 px for link lengths); net of what they fit of noise they do not, and the loop finds both."""
    data, _ = make(21, ("link_lengths", "intrinsics"))
    ranking = rank_candidates(base_fit(21, ("link_lengths", "intrinsics")))
    raw = min((c for c in ranking if c.testable), key=lambda c: c.predicted_rms_px)
    assert raw.effect == "elasticity" and ranking[0].effect == "link_lengths"
    steps = forward_selection(data)
    assert set(steps[-1].effects) == {"link_lengths", "intrinsics"}
    assert total_rms(steps[-1].result.rms_px) < 1.2 * NOISE_PX
    assert total_rms(steps[-1].cv_rms_px) < 1.2 * NOISE_PX
    cv = [total_rms(step.cv_rms_px) for step in steps]
    assert all(b < a for a, b in zip(cv, cv[1:])), cv


def test_stepwise_selection_drops_a_stand_in(monkeypatch):
    """If a stand-in gets in first (here forced: elasticity for hidden link lengths + intrinsics), it is dropped
    once the true effects are in, because it no longer explains anything significant."""
    import naocal.solver.diagnostics as diagnostics
    data, _ = make(21, ("link_lengths", "intrinsics"))
    real = diagnostics.rank_candidates
    calls = []

    def elasticity_first(result, *args, **kwargs):
        ranking = real(result, *args, **kwargs)
        calls.append(1)
        if len(calls) == 1:
            ranking.sort(key=lambda c: c.effect != "elasticity")
            # (a stand-in compliance comes out negative on some joint, so it is implausible now that effects say
            # their sign (issue 21) and would never get in: forced plausible, to test how it is dropped)
            ranking[0].plausible, ranking[0].significant = True, True
        return ranking

    monkeypatch.setattr(diagnostics, "rank_candidates", elasticity_first)
    steps = diagnostics.forward_selection(data, cv_folds=0)
    assert steps[1].added == "elasticity"
    assert set(steps[-1].effects) == {"link_lengths", "intrinsics"}
    assert any("dropped elasticity" in note for step in steps for note in step.notes)
    assert total_rms(steps[-1].result.rms_px) < 1.2 * NOISE_PX


def test_forward_selection_stops_at_once_without_hidden_effects():
    data, _ = make(300)
    steps = forward_selection(data, cv_folds=0)
    assert len(steps) == 1 and steps[0].effects == ()
    assert "no significant" in steps[0].notes[-1]


def test_untestable_candidates_are_listed_with_the_reason():
    data, _ = make(11, ("elasticity",))
    still = make(11, ("elasticity",))[0].subset(np.arange(data.n_images))
    still.velocity = None
    ranking = rank_candidates(identify(still, Registry()))
    lag = next(c for c in ranking if c.effect == "time_lag")
    assert not lag.testable and "vel_" in lag.reason
    assert ranking[-1] is lag and {c.effect for c in ranking} == set(EXTRA_EFFECTS) | {"rigid_board"}  # (and
    # the default model's assumptions: Registry() does not tie the HipYawPitch pair; the boards are always assumed)
    # Velocities recorded but all zero: testable in principle, no signal.
    still.velocity = np.zeros((still.n_images, 14))
    lag = next(c for c in rank_candidates(identify(still, Registry())) if c.effect == "time_lag")
    assert not lag.testable and "still" in lag.reason


def test_uniqueness_shows_what_the_data_cannot_separate():
    """Head offsets are nearly camera rotation (HeadPitch rotates the camera about a parallel axis 5 cm away):
    uniqueness below 1 % (identifiable here only because 0.1 px noise is tiny against 1 deg offsets)."""
    head = next(c for c in rank_candidates(base_fit(11, ("head_offsets",))) if c.effect == "head_offsets")
    assert head.uniqueness < 0.01
    data, _ = make(11, ("head_offsets",))
    no_camera = identify(data, Registry(fixed=["camera_rotation"]))
    head_alone = next(c for c in rank_candidates(no_camera) if c.effect == "head_offsets")
    assert head_alone.uniqueness > 10 * head.uniqueness  # still low: the leg offsets absorb most of the rest
    backlash = next(c for c in rank_candidates(base_fit(11, ("head_offsets",))) if c.effect == "backlash")
    assert backlash.uniqueness > 0.8  # random approach directions: nothing in the base model looks like play


# ----------------------------------------------------------------------------------------------- compare, locate


def test_rigid_split_kinematics_rigid_camera_terms_not():
    data, _ = make(300)
    registry = Registry(("elasticity", "link_lengths", "intrinsics", "distortion"))
    model = Model(data, registry)
    values = registry.zeros()
    split = RigidSplit(model, values)
    J = model.evaluate(values)[1]
    for name in ("joint_offset.LKneePitch", "camera.bottom.yaw", "board.R.trans_x", "elasticity.RHipPitch",
                 "link_length.L.tibia"):
        column = J[:, :, registry.index[name]]
        assert np.max(np.abs(split(column)[1])) < 1e-6 * np.max(np.abs(column)), name
    for name in ("intrinsics.bottom.fx", "distortion.bottom.k1"):
        column = J[:, :, registry.index[name]]
        assert np.sqrt(np.mean(split(column)[1] ** 2)) > 0.01 * np.sqrt(np.mean(column ** 2)), name


@pytest.mark.parametrize("effect", ["elasticity", "distortion", "intrinsics"])
def test_noise_floor_estimate_sees_through_kinematic_and_camera_errors(effect):
    result = base_fit(11, (effect,))
    assert total_rms(result.rms_px) > 3 * NOISE_PX
    estimate = noise_floor_estimate(result.model, result.values, result.residuals_px)
    assert estimate == pytest.approx(NOISE_PX, rel=0.1)


def test_reading_resolution_is_found_in_the_data():
    np.testing.assert_allclose(reading_resolution(make(300, (), 0.1)[0].theta), 0.1 * DEG, rtol=1e-6)
    assert not np.any(reading_resolution(make(300)[0].theta))
    rng = np.random.default_rng(0)
    theta = np.round(rng.uniform(-1, 1, (50, 14)) / 0.0015) * 0.0015 + 0.3  # a grid that does not pass through 0
    theta[:, 0] = rng.uniform(-1, 1, 50)  # one joint read without quantisation
    theta[3:, 5] = theta[0, 5]  # one joint with only three distinct readings, on the grid
    theta[1, 5] += 0.003
    theta[2, 5] += 0.0075
    resolution = reading_resolution(theta)
    assert resolution[0] == 0
    np.testing.assert_allclose(resolution[1:], 0.0015, rtol=1e-6)


def test_noise_floor_includes_quantised_joint_readings():
    """0.1 deg encoder steps move whole boards by about 0.37 px: a correct model cannot fit below that, and the
    non-rigid estimate cannot see it; the floor combines both."""
    c = compare(base_fit(310, (), 0.1), pixel_noise_px=NOISE_PX)
    assert c.encoder_resolution_rad == pytest.approx(0.1 * DEG)
    assert c.encoder_noise_px > 2 * NOISE_PX
    assert c.noise_px == pytest.approx(np.hypot(NOISE_PX, c.encoder_noise_px))
    assert c.ratio_to_noise == pytest.approx(1.0, abs=0.1)
    assert compare(base_fit(310, (), 0.1)).detector_noise_px == pytest.approx(NOISE_PX, rel=0.1)


def test_compare_groups_and_noise_source():
    result = base_fit(11, ("elasticity",))
    c = compare(result, pixel_noise_px=0.1)
    assert c.noise_source == "dataset" and c.noise_px == 0.1
    assert c.ratio_to_noise > 10
    assert compare(result).noise_source == "estimated"
    n = np.array([v["n_images"] for v in c.per_target.values()])
    ms = np.array([np.mean(np.square(v["rms_px"])) for v in c.per_target.values()])
    assert np.sum(n * ms) / np.sum(n) == pytest.approx(c.rms_total_px ** 2)  # 24 vertices in every image
    assert len(c.per_stance) == 48 and len(c.per_image) == 144 and set(c.per_head_posture) == {0, 1, 2}


@pytest.mark.parametrize("effect, regressor", [("elasticity", "gravity torque"), ("backlash", "approach direction"),
                                               ("time_lag", "velocity")])
def test_locate_points_at_the_right_regressor(effect, regressor):
    location = locate(base_fit(11, (effect,)))
    assert location.regressors[0]["regressor"].startswith(regressor), location.regressors[:3]
    assert location.rigid_share > 0.99  # kinematic effects move the boards rigidly


def test_locate_camera_effect_is_non_rigid_and_common_to_both_boards():
    location = locate(base_fit(11, ("distortion",)))
    # Over one small board radial distortion is mostly a shift and a scale (rigid), but it leaves a clear
    # non-rigid part, which kinematic errors never do.
    assert location.nonrigid_rms_px > 1.5 * NOISE_PX
    assert locate(base_fit(11, ("elasticity",))).nonrigid_rms_px < 1.05 * NOISE_PX
    assert location.regressors[0]["regressor"] == "image radius"
    assert "alike" in location.board_summary


def test_locate_one_bad_leg():
    rng = np.random.default_rng(8)
    truth = random_truth(rng)
    truth.update({"link_length.L.thigh": 0.003, "link_length.L.tibia": -0.003})
    data = synthesize(rng, truth, effects=("link_lengths",), pixel_noise_px=NOISE_PX)
    location = locate(identify(data, Registry()))
    assert "L board fits worse" in location.board_summary
    assert location.worst_images[0]["target"] == "L"


def test_apparent_and_partial_residuals_show_the_fitted_term():
    data, truth = make(11, ("elasticity",))
    fit = identify(data, Registry(("elasticity",)))
    joint = "RKneePitch"
    error = apparent_errors(fit, [f"joint_offset.{joint}"], partial_residuals(fit, [f"elasticity.{joint}"]))[:, 0]
    ok = np.isfinite(error)
    assert np.all(data.leg[ok] == "R")
    from naocal.solver.joints import JOINT_INDEX

    slope = np.polyfit(data.tau[ok, JOINT_INDEX[joint]], error[ok], 1)[0]
    # the sag C tau, switched off, reads as an offset c = -C tau (q = theta - c)
    assert slope == pytest.approx(-truth[f"elasticity.{joint}"], rel=0.05)


def test_diagnosis_as_dict_has_the_issue_keys():
    out = diagnose_result(base_fit(11, ("backlash",)), pixel_noise_px=0.1).as_dict()
    assert set(out) >= {"rms_px", "noise_px", "candidates"}
    assert len(out["rms_px"]) == 2
    for c in out["candidates"]:
        assert set(c) >= {"effect", "predicted_rms_px", "p_value", "significant", "uniqueness"}
    assert out["candidates"][0]["effect"] == "backlash"
    excess = [c["excess_rss_px2"] for c in out["candidates"] if c["testable"]]
    assert excess == sorted(excess, reverse=True)


# ------------------------------------------------------------------------------------------- cross-validation


def test_stance_folds_partition_whole_stances_with_both_legs():
    data, _ = make(300)
    folds = stance_folds(data, 5, seed=1)
    assert sorted(np.concatenate(folds).tolist()) == list(range(data.n_images))
    keys = [(data.leg[m], data.stance[m]) for m in range(data.n_images)]
    owner = {}
    for k, fold in enumerate(folds):
        assert set(data.leg[fold]) == {"L", "R"}
        for m in fold:
            assert owner.setdefault(keys[m], k) == k  # a stance never spans two folds
    assert len(stance_folds(data.subset(np.flatnonzero(data.stance < 2)), 5)) == 4  # fewer stances than folds


def test_cv_rms_reveals_a_missing_effect_and_matches_the_noise_with_it():
    data, _ = make(11, ("backlash",))
    base = grouped_cv_rms(data, Registry())
    full = grouped_cv_rms(data, Registry(("backlash",)))
    assert total_rms(full) < 1.1 * NOISE_PX < total_rms(base) / 10
    assert grouped_cv_rms(data, Registry(("backlash",)), seed=0) == full  # deterministic


def test_cv_rms_is_above_the_fit_rms_for_an_overfitting_model():
    data, _ = make(300)
    fit = identify(data, Registry(("elasticity", "backlash")))
    assert total_rms(grouped_cv_rms(data, fit.registry)) > total_rms(fit.rms_px)


def test_clusters_are_stances_and_sweep_captures():
    data, _ = make(300)
    clusters = stance_clusters(data)
    assert len(clusters) == 48  # moving or not, the images of a stance share its leg readings: one cluster
    assert sorted(np.concatenate(clusters).tolist()) == list(range(2 * data.n_rows))
    # Captures along a sweep (the agent's lag probe: one stance label, angles that change) are separate clusters.
    sweep = data.subset(np.arange(data.n_images))
    probe = np.flatnonzero((sweep.leg == "L") & (sweep.stance == 0))
    sweep.theta[probe, 4] += np.arange(len(probe)) * 0.01
    sweep.velocity = np.zeros((sweep.n_images, 14))
    sweep.velocity[probe, 4] = 0.1
    assert len(stance_clusters(sweep)) == 48 - 1 + len(probe)


def test_candidates_are_those_not_in_the_model():
    assert candidate_effects(Registry(("backlash",))) == tuple(e for e in EXTRA_EFFECTS if e != "backlash")
    assert set(itertools.chain(candidate_effects(Registry()))) == set(EXTRA_EFFECTS)
