"""The layering (docs/CONVENTIONS.md): solver <- body, sim, backends <- agent <- tools. What each package may import,
one class per name, and the old names of moved modules still importing for one release (issue 13)."""

import ast
import importlib
from collections import defaultdict

import pytest

from conftest import ROOT

PACKAGES = ("solver", "body", "sim", "backends", "agent", "tools")
# What each package must never import (module-level or inside functions).
FORBIDDEN = {
    "solver": ("backends", "agent", "tools", "body", "sim", "pybullet", "zmq", "cv2"),
    "body": ("backends", "agent", "tools", "sim"),
    "sim": ("backends", "agent", "tools"),
    "agent": ("backends.pybullet_body", "backends.mock", "backends.mock_render", "body.nao_body.NaoBody_",
              "sim", "solver.synthetic", "tools"),
}
# Compatibility re-exports of moved names (one release), the only allowed exceptions.
COMPATIBILITY = {("solver/errors.py", "backends")}


def imports_of(path):
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module


def python_files(package):
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_packages_import_only_what_their_layer_may(package):
    bad = []
    for path in python_files(package):
        relative = str(path.relative_to(ROOT))
        for name in imports_of(path):
            for forbidden in FORBIDDEN[package]:
                if (name == forbidden or name.startswith(forbidden + ".")) and \
                        (relative, forbidden) not in COMPATIBILITY:
                    bad.append(f"{relative} imports {name}")
    assert not bad, bad


def test_robot_errors_live_with_the_backends_and_old_names_still_import():
    from backends import errors
    from solver import errors as solver_errors

    source = (ROOT / "solver" / "errors.py").read_text()
    for name in ("SafetyError", "RobotTimeout", "BridgeError"):
        assert f"class {name}" not in source
        assert getattr(solver_errors, name) is getattr(errors, name)
        assert issubclass(getattr(errors, name), solver_errors.NaocalError)


def test_moved_modules_import_under_their_old_names():
    assert importlib.import_module("backends.pybullet_body") is importlib.import_module("body.nao_body")
    assert importlib.import_module("solver.synthetic") is importlib.import_module("sim.synthetic")
    from solver.adapter import make_model_data
    from solver.synthetic import make_model_data as old

    assert old is make_model_data
    assert not (ROOT / "solver" / "synthetic.py").exists() and not (ROOT / "backends" / "pybullet_body.py").exists()


def test_one_class_per_name():
    """Two classes of one name with different meanings (the robot at rest and a plan's image were both `Still`; a
    feasible stance and a candidate effect both `Candidate`) are traps: one name, one concept."""
    homes = defaultdict(list)
    for package in PACKAGES:
        for path in python_files(package):
            for node in ast.parse(path.read_text()).body:
                if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                    homes[node.name].append(str(path.relative_to(ROOT)))
    twice = {name: files for name, files in homes.items() if len(files) > 1}
    assert not twice, twice
