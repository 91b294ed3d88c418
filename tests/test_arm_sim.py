"""End to end on the simulated PyBullet arm, through the command line (docs/ARM.md): simulate, identify against
the hidden truth, diagnose's loop, offsets show."""

import json
import math
import subprocess
import sys

import pytest

from tests import cli_runner


def naocal(*args):
    run = cli_runner.naocal(*args)
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


TWO_LINKS_WITHOUT_INERTIA = """<robot name="two">
 <link name="base"/> <link name="l1"/> <link name="l2"/> <link name="tip"/>
 <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.3"/>
  <axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
 <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4"/>
  <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
 <joint name="j3" type="fixed"><parent link="l2"/><child link="tip"/><origin xyz="0.3 0 0"/></joint>
</robot>
"""


def test_a_user_urdf_without_inertial_data_leaves_naocal_s_output_clean(tmp_path):
    """PyBullet warns from C, on stdout, for each link without <inertial>: not in naocal's output."""
    urdf = tmp_path / "two.urdf"
    urdf.write_text(TWO_LINKS_WITHOUT_INERTIA)
    run = subprocess.run([sys.executable, "-m", "naocal", "simulate", "--robot", str(urdf), "--chain", "base:tip",
                          "--seed", "1", "--poses", "12", "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "b3Warning" not in run.stdout + run.stderr and "inertial" not in run.stdout + run.stderr
    assert run.stdout.startswith("naocal simulate: wrote") and run.stderr == ""
