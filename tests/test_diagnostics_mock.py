"""Diagnostics end to end on the mock robot: `naocal simulate` hides effects, `naocal diagnose` names them.

Slow (each simulated dataset takes about 40 CPU seconds): two datasets (elasticity, backlash + distortion) are
made once per session and shared; NAOCAL_MOCK_ALL_EFFECTS=1 adds every effect alone. Without a hidden effect, the
dataset is that of the ideal mock's calibration the session shares (tests/conftest.py's mock_run). The standard
plan is used (24 stances per leg): with 12 the 20 % margin on the cross-validated RMS is too tight even for a
correct model (quantised joint readings, shared by the 3 images of a stance, and about 20 parameters per leg).
"""

import contextlib
import importlib.util
import io
import json
import os

import pytest

pytestmark = pytest.mark.slow

if importlib.util.find_spec("naocal.tools.cmd_simulate") is None:
    pytest.skip("naocal simulate is not available yet", allow_module_level=True)

from naocal.tools.cli import main  # noqa: E402

SEED = 7
# Realistic sizes, in the mock's units (see backends/mock.py).
EFFECT_SIZES = {"elasticity": 0.03, "backlash": 0.012, "link_lengths": 0.0025, "head_offsets": 0.017,
                "intrinsics": 10.0, "distortion": 0.08, "time_lag": 0.04}
FLOOR_MARGIN = 1.2  # "within 20 % of the noise floor"


EFFECTS = tuple(EFFECT_SIZES) if os.environ.get("NAOCAL_MOCK_ALL_EFFECTS") == "1" else ("elasticity",)


@pytest.fixture(scope="session")
def simulated(tmp_path_factory):
    """simulated(('elasticity',)) -> dataset directory; each combination simulated once per session."""
    cache = {}

    def make(effects=()):
        key = tuple(effects)
        if key not in cache:
            out = tmp_path_factory.mktemp("mock_" + ("_".join(key) or "none"))
            args = ["simulate", "--out", str(out), "--seed", str(SEED), "--no-progress", "--mock", "ideal"]
            for effect in key:
                args += ["--effect", f"{effect}={EFFECT_SIZES[effect]}"]
            with contextlib.redirect_stdout(io.StringIO()):
                assert main(args) == 0, args
            images = {leg: len(set(_images_of_leg(out, leg))) for leg in "LR"}
            assert min(images.values()) >= 24, f"naocal simulate recorded too few images per leg: {images}"
            cache[key] = out
        return cache[key]

    return make


def _images_of_leg(dataset, leg):
    from naocal.solver.dataset import read_dataset

    columns = read_dataset(dataset).as_v2().columns
    return [int(i) for i, g in zip(columns["image"], columns["target"]) if g == leg]


def total(xy):
    """RMS over both coordinates, comparable with noise_px."""
    return (0.5 * (xy[0] ** 2 + xy[1] ** 2)) ** 0.5


def run_json(capsys, *args):
    capsys.readouterr()
    assert main([*map(str, args), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("effect", EFFECTS)
def test_diagnose_names_the_hidden_effect_and_adding_it_reaches_the_noise(simulated, capsys, effect):
    dataset = simulated((effect,))
    diagnosis = run_json(capsys, "diagnose", dataset)
    top = diagnosis["candidates"][0]
    assert top["effect"] == effect and top["significant"], diagnosis["candidates"][:3]
    floor = diagnosis["noise_px"]
    assert total(diagnosis["rms_px"]) > FLOOR_MARGIN * floor  # the effect is visible at all

    fit = run_json(capsys, "identify", dataset, "--effects", effect)
    assert total(fit["rms_px"]) < FLOOR_MARGIN * floor, (fit["rms_px"], floor)
    assert total(fit["cv_rms_px"]) < FLOOR_MARGIN * floor, (fit["cv_rms_px"], floor)
    quiet = run_json(capsys, "diagnose", dataset, "--effects", effect)
    assert not any(c["significant"] for c in quiet["candidates"]), quiet["candidates"][:2]


def test_no_hidden_effect_nothing_significant(mock_run, capsys):
    diagnosis = run_json(capsys, "diagnose", mock_run[1])  # a calibration run's directory: its dataset
    assert not any(c["significant"] for c in diagnosis["candidates"]), diagnosis["candidates"][:2]
    assert total(diagnosis["rms_px"]) < FLOOR_MARGIN * diagnosis["noise_px"]


def test_two_hidden_effects_second_named_after_adding_the_first(simulated, capsys):
    pair = ("backlash", "distortion")
    dataset = simulated(pair)
    first = run_json(capsys, "diagnose", dataset)["candidates"][0]
    assert first["significant"] and first["effect"] in pair
    second = run_json(capsys, "diagnose", dataset, "--effects", first["effect"])["candidates"][0]
    assert second["significant"] and {first["effect"], second["effect"]} == set(pair)
    both = run_json(capsys, "diagnose", dataset, "--effects", ",".join(pair))
    assert not any(c["significant"] for c in both["candidates"])
    assert total(both["rms_px"]) < FLOOR_MARGIN * both["noise_px"]
