"""pyproject.toml: `pip install '.[test]'` works on any machine Python and the dependencies install on."""

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_test_extra_does_not_pull_qi():
    """qi has wheels for x86_64 Linux only: with it in the test extra, the README's test command failed elsewhere.
    Its tests skip without it (tests/test_naoqi_driver.py); the naoqi extra installs it."""
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    names = {requirement.split(">")[0].split("=")[0].split("[")[0].strip().lower() for requirement in extras["test"]}
    assert "qi" not in names and {"pytest", "hypothesis"} <= names
    assert any(r.startswith("qi") for r in extras["naoqi"])


def test_an_install_is_one_import_package_naocal(tmp_path):
    """Issue 22: `pip install .` put six generic top-level packages (agent, backends, body, sim, solver, tools) into
    site-packages, colliding with any other project's `tools` or `agent`. Installed, naocal is one package."""
    import subprocess
    import sys

    import shutil

    # Built from a copy: setuptools builds in the source tree (build/), whose stale files would reach a later install.
    source = tmp_path / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".git", "build", "dist", "*.egg-info", "__pycache__", ".venv", "tests", "benchmarks", "docs", ".pytest_cache"))
    target = tmp_path / "site"
    run = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--quiet",
                          "--target", str(target), str(source)], capture_output=True, text=True, timeout=600)
    if run.returncode != 0:  # no (recent enough) setuptools or wheel beside this Python: build it apart
        run = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", "--target",
                              str(target), str(source)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    imported = sorted(p.name for p in target.iterdir() if p.suffix != ".dist-info" and p.name not in ("bin",)
                      and not p.name.endswith(".dist-info") and not p.name.startswith(("_", ".")))
    assert imported == ["naocal"], imported
    installed = target / "naocal"
    for package in ("agent", "backends", "body", "kinds", "sim", "solver", "tools"):
        assert (installed / package / "__init__.py").is_file(), package
    assert (installed / "solver" / "data" / "nao.json").is_file()  # the robot description travels with it
    # Every module and data file of the checkout's folders is installed (found, not listed: a new kind's folder or
    # a simulator's URDF was missing from an installed copy when the package list was written by hand).
    for folder in ("agent", "backends", "body", "kinds", "sim", "solver", "tools"):
        files = [p.relative_to(ROOT) for p in (ROOT / folder).rglob("*")
                 if p.is_file() and "__pycache__" not in p.parts and (p.suffix == ".py" or "data" in p.parts)]
        missing = [str(f) for f in files if not (installed / f).is_file()]
        assert not missing, f"not installed: {missing[:5]}"
    # the installed copy runs on its own, from anywhere: no checkout on the path
    probe = subprocess.run([sys.executable, "-c", "import naocal.tools.cli as c, naocal.solver.robot as r; "
                            "print(c.__file__); print(r.load_robot('nao').name)"],
                           capture_output=True, text=True, cwd=tmp_path, env={"PYTHONPATH": str(target)}, timeout=120)
    assert probe.returncode == 0, probe.stderr[-2000:]
    assert probe.stdout.splitlines()[0].startswith(str(installed))
