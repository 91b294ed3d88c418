"""End to end on the simulated PyBullet arm, through the command line (docs/ARM.md): simulate, identify against
the hidden truth, diagnose's loop, offsets show."""

import json
import math
import subprocess
import sys

import pytest


def naocal(*args):
    run = subprocess.run([sys.executable, "-m", "tools", *args], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    return run.stdout


@pytest.mark.slow
def test_simulated_panda_identified_to_the_truth_and_diagnosed(tmp_path):
    data = tmp_path / "panda"
    naocal("simulate", "--robot", "franka_panda", "--seed", "5", "--poses", "80", "--out", str(data))
    truth = json.loads((data / "truth.json").read_text())["parameters"]
    out = naocal("identify", str(data), "--json", "--out", str(tmp_path / "cal.json"))
    report = json.loads(out[out.index("{"):])
    params = report["parameters"]
    assert set(truth) <= set(params)  # truth.json uses identify's names
    checked = 0
    for name, entry in params.items():
        if entry["fixed"] or name.startswith("sensor."):
            continue
        tolerance = 1e-4 if name.startswith("link_length.") else math.radians(0.01)
        assert abs(entry["value"] - truth[name]) < tolerance, name
        checked += 1
    assert checked >= 11 and set(report["fixed"]) == {"joint_offset.panda_joint1", "link_length.panda_link0"}
    held = report["heldout"]
    assert held["tracker"]["nominal"] > 10 * 1e-4 and held["tracker"]["calibrated"] < 1.15e-4
    assert held["camera"]["nominal"] > 3 * 0.2 and held["camera"]["calibrated"] < 1.15 * 0.2
    assert "panda_joint2" in naocal("offsets", "show", str(tmp_path / "cal.json"))
    # the diagnose loop: link lengths named when the model lacks them, nothing when it has them
    out = naocal("diagnose", str(data), "--effects", "joint_offsets", "--json")
    assert json.loads(out[out.index("{"):])["verdict"] == "link_lengths"
    out = naocal("diagnose", str(data), "--json")
    assert json.loads(out[out.index("{"):])["verdict"] is None
