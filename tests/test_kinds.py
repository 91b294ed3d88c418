"""The robot-kind registry (kinds/__init__.py, docs/ARCHITECTURE.md): which kind a verb's data and options choose."""

import argparse
import json
import sys

import pytest

import naocal.kinds as kinds
from conftest import ROOT
from tests.cli_runner import naocal


def _write(path, doc):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


def test_the_data_choose_the_kind(tmp_path):
    nao_dataset = _write(tmp_path / "nao" / "dataset.json", {"schema": "naocal.dataset/2"}).parent
    nao_run = _write(tmp_path / "run" / "dataset" / "dataset.json", {"schema": "naocal.dataset/1"}).parent.parent
    arm_dataset = _write(tmp_path / "arm" / "dataset.json", {"schema": "naocal.arm_dataset/1"}).parent
    offsets = _write(tmp_path / "offsets.json", {"schema": "naocal.offsets/2"})
    arm_calibration = _write(tmp_path / "arm.json", {"schema": "naocal.arm_calibration/1"})
    assert [kinds.for_data(p).name for p in (nao_dataset, nao_run, offsets)] == ["nao"] * 3
    assert [kinds.for_data(p).name for p in (arm_dataset, arm_calibration)] == ["arm"] * 2
    assert len({k.name for k in kinds.registered()}) == len(kinds.registered())
    # a pair with an arm's file goes to the arm, whose reader names the mismatch
    assert kinds.for_data(offsets, arm_calibration).name == "arm"
    # what no kind claims (missing, of another schema, damaged) goes to the default kind, whose reader names it
    _write(tmp_path / "bad" / "dataset.json", {"schema": "something/9"})
    (tmp_path / "damaged.json").write_text("{")
    for path in (tmp_path / "missing", tmp_path / "bad", tmp_path / "damaged.json"):
        assert not any(k.claims(str(path)) for k in kinds.registered())
        assert kinds.for_data(path) is kinds.default()


def test_options_choose_the_kind_before_the_data(tmp_path):
    nao_dataset = _write(tmp_path / "nao" / "dataset.json", {"schema": "naocal.dataset/2"}).parent
    parser = argparse.ArgumentParser()
    parser.add_argument("dataset")
    kinds.add_options(parser, "identify")
    assert kinds.for_args(parser.parse_args([str(nao_dataset)]), nao_dataset).name == "nao"
    assert kinds.for_args(parser.parse_args([str(nao_dataset), "--robot", "kuka_iiwa"]), nao_dataset).name == "arm"
    assert kinds.for_args(parser.parse_args([str(nao_dataset), "--chain", "a:b"])).name == "arm"


def test_every_kind_has_the_protocol():
    for kind in kinds.registered():
        assert isinstance(kind.name, str) and callable(kind.claims) and callable(kind.add_options)
        for verb in ("identify", "diagnose", "verify", "simulate", "offsets"):
            assert callable(getattr(kind, verb)), (kind.name, verb)


def test_kinds_are_discovered_in_their_order_of_asking():
    """Issue 22: the registry lists no kind; it finds every subpackage with a KIND, asked by rank, the NAO (the
    default) last, the Duckiebot before the arm (whose --robot takes any name)."""
    assert [k.name for k in kinds.registered()] == ["duckiebot", "arm", "nao"]
    assert kinds.default().name == "nao"
    assert [k.name for k in kinds.capable("calibrate")] == ["duckiebot", "nao"]
    source = (ROOT / "kinds" / "__init__.py").read_text()
    assert "import arm" not in source and "nao.KIND" not in source


def test_the_verbs_help_names_every_kinds_data():
    """Issue 22: identify, diagnose and verify are every kind's verbs. Their --help says, for each registered kind
    that has the verb, what its data (DATASET) are, and identify's and verify's what its calibration file (identify
    --out, verify --offsets) is, identify's what its model is: none describes the NAO's data alone."""
    from naocal.tools.cli import build_parser

    verbs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    said = {"identify": ("data_help", "calibration_help", "model_help"), "diagnose": ("data_help",),
            "verify": ("data_help", "calibration_help")}
    for verb, attributes in said.items():
        text = "".join(verbs[verb].format_help().split())  # argparse wraps lines: compare without white space
        for kind in kinds.registered():
            assert callable(getattr(kind, verb, None)), (kind.name, verb)
            for attribute in attributes:
                what = getattr(kind, attribute, "")
                assert what and f"{kind.name}:{''.join(what.split())}" in text, (verb, kind.name, attribute)


def test_the_effects_and_diagnose_help_come_from_every_kind():
    """Issue 22: identify's and diagnose's --effects list each kind's effects of the one registry under its name
    (the Duckiebot's wheel effects too), and diagnose's epilog and --json describe every kind's output."""
    from naocal.solver.effects import ARM_EFFECTS, DRIVE_EFFECTS, EXTRA_EFFECTS
    from naocal.tools.cli import build_parser

    verbs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    said = {"identify": ("effects_help",), "diagnose": ("effects_help", "diagnose_json_help", "diagnose_help")}
    for verb, attributes in said.items():
        text = "".join(verbs[verb].format_help().split())
        for kind in kinds.registered():
            for attribute in attributes:
                what = getattr(kind, attribute, "")
                assert what and f"{kind.name}:{''.join(what.split())}" in text, (verb, kind.name, attribute)
        for effect in EXTRA_EFFECTS + ARM_EFFECTS + DRIVE_EFFECTS:
            assert effect in text, (verb, effect)
    assert "duckiebot:dead_zone,slip,wheel_lag,speed_trim,lag_difference,pwm_driver" in text


KIND_SOURCE = """
import argparse


class ToyKind:
    name = "toy"
    rank = 5

    def claims(self, source):
        if isinstance(source, argparse.Namespace):
            return getattr(source, "robot", None) == "toy"
        return str(source).endswith(".toy")

    def add_options(self, parser, verb):
        if verb == "identify":
            parser.add_argument("--toy-level", type=int, default=1)

    def identify(self, args):
        print(f"toy identify {args.dataset} level {args.toy_level}")
        return 7

    def calibrate(self, args):
        print(f"toy calibrate {args.out}")
        return 0


KIND = ToyKind()
"""


def test_a_kind_is_a_folder_found_and_dispatched_to(tmp_path, monkeypatch):
    """A throw-away kind package on naocal.kinds' search path: found, its options in the verb's parser, its data and
    its --robot dispatched to it, with no other file touched."""
    package = tmp_path / "toy"
    package.mkdir()
    (package / "__init__.py").write_text(KIND_SOURCE)
    monkeypatch.setattr(kinds, "__path__", [*kinds.__path__, str(tmp_path)])
    try:
        assert [k.name for k in kinds.registered()][0] == "toy"
        result = naocal("identify", tmp_path / "data.toy", "--toy-level", "3")
        assert result.returncode == 7 and "toy identify" in result.stdout and "level 3" in result.stdout
        result = naocal("calibrate", "--robot", "toy", "--backend", "mock", "--out", tmp_path / "run")
        assert result.returncode == 0 and "toy calibrate" in result.stdout, result.stderr
    finally:
        sys.modules.pop("naocal.kinds.toy", None)
        monkeypatch.undo()
    assert "toy" not in [k.name for k in kinds.registered()]


def test_robot_duckiebot_reaches_the_duckiebot_not_the_arm(tmp_path):
    """The arm claims any --robot (a URDF path); `--robot duckiebot` is the Duckiebot's, whatever the verb."""
    for verb in ("identify", "diagnose", "verify", "simulate"):
        parser = argparse.ArgumentParser()
        if verb != "simulate":
            parser.add_argument("dataset")
        kinds.add_options(parser, verb)
        argv = ([] if verb == "simulate" else [str(tmp_path)]) + ["--robot", "duckiebot"]
        assert kinds.for_args(parser.parse_args(argv)).name == "duckiebot", verb
        argv = ([] if verb == "simulate" else [str(tmp_path)]) + ["--robot", "kuka_iiwa"]
        assert kinds.for_args(parser.parse_args(argv)).name == "arm", verb


def test_the_duckiebots_data_choose_it(tmp_path):
    log = _write(tmp_path / "LOG" / "log.json", {"schema": "naocal.drive_log/1"}).parent
    cal = _write(tmp_path / "cal.json", {"schema": "naocal.duckiebot_calibration/1"})
    assert kinds.for_data(log).name == "duckiebot" and kinds.for_data(cal).name == "duckiebot"
    offsets = _write(tmp_path / "offsets.json", {"schema": "naocal.offsets/2"})
    assert kinds.for_data(offsets).name == "nao"
    # a broken log is still the Duckiebot's (its reader names what is wrong); a NAO dataset never is
    (log / "log.json").unlink()
    (log / "wheels.csv").write_text("t_s,left_duty,right_duty\n")
    assert kinds.for_data(log).name == "duckiebot"
    _write(log / "dataset.json", {"schema": "naocal.dataset/2"})
    assert kinds.for_data(log).name == "nao"


def test_building_the_command_line_imports_no_kind_body():
    """`naocal --help` stays instant: every kind's __init__ (and the option modules it calls at registration) is
    argparse only; OpenCV, SciPy and PyBullet are imported by the bodies."""
    import subprocess

    probe = ("import sys; from naocal.tools.cli import build_parser; build_parser(); "
             "print(sorted(m for m in ('cv2', 'scipy', 'pybullet') if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "[]", run.stdout + run.stderr


def test_a_backend_of_another_kind_is_refused_by_the_nao_in_one_line(tmp_path):
    """--backend offers every kind's backends; the NAO refuses the Duckiebot's `ros` without naming another kind in
    its code (its own calibrate_backends decide), exit 2, nothing written."""
    from tests.cli_runner import naocal

    result = naocal("calibrate", "--backend", "ros", "--out", tmp_path / "run")
    assert result.returncode == 2 and "--backend ros is another robot kind's (--robot duckiebot)" in result.stderr, \
        result.stderr
    assert "\n" not in result.stderr.strip() and not (tmp_path / "run").exists()


@pytest.mark.parametrize("option", [["--camera-error"], ["--print-scale-error", "0"], ["--poses", "20"], ["--noise-px", "0.5"]])
def test_the_nao_simulate_refuses_another_kinds_option_instead_of_ignoring_it(tmp_path, option):
    done = naocal("simulate", *option, "--out", tmp_path / "sim")
    assert done.returncode == 2 and f"{option[0]} is not an option of the NAO's simulate" in done.stderr, done.stderr
    assert not (tmp_path / "sim").exists()
