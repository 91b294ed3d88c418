"""camera_translation (solver/effects/camera_translation.py): recovered from synthetic data, named by the
diagnostics when it is the hidden error, written to the head's section of the offsets file. (Its gradient, file
section and completeness are checked with every other effect in tests/test_effects.py.)"""

import functools
import json

import numpy as np
import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from naocal.solver.crossval import grouped_cv_rms
from naocal.solver.dataset import write_dataset
from naocal.solver.diagnostics import rank_candidates
from naocal.solver.errors import DataError
from naocal.solver.identify import identify
from naocal.solver.offsets import read_offsets
from naocal.solver.registry import Registry
from naocal.sim.synthetic import dataset_parts, random_truth, synthesize

NOISE_PX = 0.1
SHIFT = ("camera.bottom.trans_x", "camera.bottom.trans_y", "camera.bottom.trans_z")


@functools.lru_cache(maxsize=None)
def hidden(seed=11):
    """A NAO whose bottom camera sits 3-5 mm off its nominal place on each axis (the paper's plan, 0.1 px)."""
    rng = np.random.default_rng(seed)
    truth = random_truth(rng)
    truth.update({name: rng.choice([-1.0, 1.0]) * rng.uniform(0.003, 0.005) for name in SHIFT})
    return synthesize(rng, truth, effects=("camera_translation",), pixel_noise_px=NOISE_PX), truth


def test_identification_recovers_the_camera_position():
    data, truth = hidden()
    fit = identify(data, Registry(("camera_translation",)))
    assert fit.success
    for name in SHIFT:
        std = fit.std[fit.registry.index[name]]
        assert abs(fit.value(name) - truth[name]) < max(4 * std, 5e-5), (name, fit.value(name), truth[name], std)
    assert max(fit.rms_px) < 1.1 * NOISE_PX
    assert max(grouped_cv_rms(data, fit.registry)) < 1.1 * NOISE_PX  # on stances the fit did not see


def test_diagnose_names_it_when_it_is_the_hidden_error():
    data, _ = hidden()
    base = identify(data, Registry())
    assert min(base.rms_px) > 5 * NOISE_PX  # the paper's model cannot absorb it
    ranking = rank_candidates(base)
    top = ranking[0]
    assert top.effect == "camera_translation" and top.significant and top.plausible, [
        (c.effect, c.predicted_rms_px) for c in ranking]
    assert top.predicted_rms_px < 1.1 * NOISE_PX
    assert top.predicted_rms_px < 0.5 * min(c.predicted_rms_px for c in ranking[1:] if c.testable)
    after = rank_candidates(identify(data, Registry(("camera_translation",))))
    assert not any(c.significant for c in after)


def test_not_named_when_absent():
    rng = np.random.default_rng(5)
    data = synthesize(rng, random_truth(rng), pixel_noise_px=NOISE_PX)
    candidate = next(c for c in rank_candidates(identify(data, Registry())) if c.effect == "camera_translation")
    assert not candidate.significant


def test_identify_writes_it_to_the_heads_section(tmp_path, capsys):
    data, truth = hidden()
    write_dataset(dataset_parts(data, pixel_noise_px=NOISE_PX), tmp_path / "ds")
    out = tmp_path / "offsets.json"
    code = tools.cli.main(["identify", str(tmp_path / "ds"), "--effects", "camera_translation", "--cv-folds", "0",
                           "--out", str(out)])
    assert code == 0
    assert "camera.bottom.trans_x" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    section = doc["head"]["camera_translation_m"]["bottom"]
    for name in SHIFT:
        assert section[name.rsplit(".", 1)[1]] == pytest.approx(truth[name], abs=1e-4)
    assert doc["model"]["effects"] == ["camera_translation"]
    offsets = read_offsets(out)
    assert offsets.head["camera_translation_m"] == doc["head"]["camera_translation_m"]
    doc["head"]["camera_translation_m"]["bottom"]["trans_z"] = 4.5  # mm written as m
    out.write_text(json.dumps(doc))
    with pytest.raises(DataError, match="mm instead of m") as info:
        read_offsets(out)
    assert info.value.field == "head.camera_translation_m.bottom.trans_z"


def test_offsets_show_lists_it(tmp_path, capsys):
    """`naocal offsets show` shows every fitted parameter that has no table of its own (the camera's rotation has)."""
    from naocal.solver.offsets import offsets_from_parameters, write_offsets

    params = {f"camera.bottom.{a}": {"value": -0.05, "std": 1e-4, "unit": "rad"} for a in ("roll", "pitch", "yaw")}
    params.update({f"camera.bottom.trans_{a}": {"value": v, "std": 1e-5, "unit": "m"}
                   for a, v in (("x", 0.001), ("y", -0.002), ("z", 0.0042))})
    write_offsets(offsets_from_parameters(params, robot={"id": "nao"}, fit={"rms_px": [0.1, 0.1], "n_vertices": 1,
                                                                             "n_images": 1},
                                          effects=["camera_translation"]), tmp_path / "o.json")
    assert tools.cli.main(["offsets", "show", str(tmp_path / "o.json")]) == 0
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if "camera.bottom.trans_z" in line)
    assert "4.20000" in line and "mm" in line
    assert not any("camera.bottom.pitch" in line for line in out.splitlines())  # in the rotation table instead


def test_the_mock_simulates_it_from_its_own_module(tmp_path):
    """Its mock injection is its module's `mock_perturbation`: the mock moves each camera's mount in the head frame
    by what it drew, renders the boards there, and says so in its truth; nothing else names the effect."""
    from naocal.agent.corners import detect_board_vertices
    from naocal.backends.mock import EFFECTS, MockBackend, parse_effect_sizes
    from naocal.body.nao_body import T_WORLD_TORSO
    from naocal.solver.effects import EFFECTS as MODEL_EFFECTS
    from naocal.solver.kinematics import chain_frames
    from naocal.solver.nao_model import head_chain
    from tests.mock_stances import settle_and_capture, visible_stances

    assert "camera_translation" in EFFECTS
    assert parse_effect_sizes(["camera_translation=0.004"]) == {"camera_translation": 0.004}
    moved, nominal = MockBackend(seed=21, effects={"camera_translation": 0.004}), MockBackend(seed=21)
    try:
        drawn = moved.effect_values_dict()["effects"]["camera_translation"]["camera_translation_m"]
        assert set(drawn) == {"bottom", "top"}
        for shift in drawn.values():
            assert all(0.002 <= abs(shift[a]) <= 0.004 for a in ("trans_x", "trans_y", "trans_z"))
        assert moved.truth_dict()["effects"] == {"camera_translation": 0.004}
        assert moved.truth.alpha_rad == nominal.truth.alpha_rad  # the base truth stays what it was
        # The true camera sits where the head frame says: its origin moved by R_torso_head @ t, its axes kept.
        q = np.array(list(moved.true_angles().values()))
        head = q[:2][None]
        for cam, shift in drawn.items():
            t = np.array([shift["trans_x"], shift["trans_y"], shift["trans_z"]])
            R_torso_head = chain_frames(head_chain(cam), head)[0][0, -1, :3, :3]
            T_moved, T_nominal = moved._T_world_cam(q, cam), nominal._T_world_cam(q, cam)
            np.testing.assert_allclose(T_moved[:3, :3], T_nominal[:3, :3], atol=1e-12)
            np.testing.assert_allclose(T_moved[:3, 3] - T_nominal[:3, 3], T_WORLD_TORSO[:3, :3] @ R_torso_head @ t,
                                       atol=1e-12)
        # The rendered image shows the boards where the moved camera sees them (a few pixels from the nominal's).
        command, leg = visible_stances(moved, 1, seed=3)[0]
        image, reference = settle_and_capture(moved, command), settle_and_capture(nominal, command)
        pixels, visible = moved.true_vertex_pixels(image)[leg]
        assert visible.all()
        assert np.max(np.linalg.norm(pixels - nominal.true_vertex_pixels(reference)[leg][0], axis=1)) > 1.0
        found = detect_board_vertices(image.pixels, pixels + 3.0)
        assert found.ok, found.detail
        assert np.sqrt(np.mean((found.vertices_px - pixels) ** 2)) < 0.1
    finally:
        moved.close()
        nominal.close()
    assert MODEL_EFFECTS["camera_translation"].mock_size_unit == "m"
