"""The robot-kind registry (kinds/__init__.py, docs/ARCHITECTURE.md): which kind a verb's data and options choose."""

import argparse
import json

import naocal.kinds as kinds
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
    assert len({k.name for k in kinds.KINDS}) == len(kinds.KINDS)
    # a pair with an arm's file goes to the arm, whose reader names the mismatch
    assert kinds.for_data(offsets, arm_calibration).name == "arm"
    # what no kind claims (missing, of another schema, damaged) goes to the default kind, whose reader names it
    _write(tmp_path / "bad" / "dataset.json", {"schema": "something/9"})
    (tmp_path / "damaged.json").write_text("{")
    for path in (tmp_path / "missing", tmp_path / "bad", tmp_path / "damaged.json"):
        assert not any(k.claims(str(path)) for k in kinds.KINDS)
        assert kinds.for_data(path) is kinds.DEFAULT


def test_options_choose_the_kind_before_the_data(tmp_path):
    nao_dataset = _write(tmp_path / "nao" / "dataset.json", {"schema": "naocal.dataset/2"}).parent
    parser = argparse.ArgumentParser()
    parser.add_argument("dataset")
    kinds.add_options(parser, "identify")
    assert kinds.for_args(parser.parse_args([str(nao_dataset)]), nao_dataset).name == "nao"
    assert kinds.for_args(parser.parse_args([str(nao_dataset), "--robot", "kuka_iiwa"]), nao_dataset).name == "arm"
    assert kinds.for_args(parser.parse_args([str(nao_dataset), "--chain", "a:b"])).name == "arm"


def test_every_kind_has_the_protocol():
    for kind in kinds.KINDS:
        assert isinstance(kind.name, str) and callable(kind.claims) and callable(kind.add_options)
        for verb in ("identify", "diagnose", "verify", "simulate", "offsets"):
            assert callable(getattr(kind, verb)), (kind.name, verb)
