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
