"""naocal's output is its own: nothing from the libraries it uses (pybullet's build-time banner)."""

import subprocess
import sys

from conftest import ROOT


def test_loading_and_connecting_pybullet_prints_nothing():
    code = ("import agent.visibility, agent.planner, backends.mock_render\n"
            "from body.nao_body import NaoBody\n"
            "NaoBody().close(); NaoBody().close(); print('ok')\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "ok\n" and done.stderr == ""


def test_the_simulated_arm_prints_nothing_of_pybullet(tmp_path):
    code = ("from kinds.arm.sim import SimulatedArm\n"
            "from kinds.arm.dataset import resolve_robot\n"
            "with SimulatedArm(*resolve_robot('franka_panda', None)) as arm:\n"
            "    arm.measure(arm.sample_stances(2), 1e-4, 0.2)\n"
            "print('ok')\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "ok\n" and done.stderr == ""
