"""Fuzz: seeded damage of a valid dataset and a valid offsets file, fed to every verb that reads them.

Each damaged input must end in exit 0 or 2 (3: a failed identification), and on failure in exactly one line on
stderr, `naocal VERB: error: ...`, naming the damaged file; never a traceback, a warning, or a hang. The cases and
the runner are in tests/fuzz_inputs.py; benchmarks/fuzz_inputs.py runs many more (every verb on every case).
"""

import os
from pathlib import Path

import pytest

from tests import fuzz_inputs as fz

DEADLINE_S = 30.0  # a hang is for ever; identify on a loaded 2-core CI machine takes up to ~12 s


@pytest.fixture(scope="module")
def work():
    with fz.work_directory("naocal-fuzz-") as path:  # the permission-denied cases run as nobody
        yield path


@pytest.fixture(scope="module")
def valid(work):
    return fz.make_valid_inputs(work / "valid")


def report(runs, failures):
    lines = [str(f) for f in failures[:15]]
    return f"{len(failures)} of {runs} runs failed:\n" + "\n".join(lines)


def test_valid_inputs_pass_every_verb_silently(valid, work):
    dataset, offsets = valid
    argvs = fz.dataset_verbs(dataset, work, offsets / fz.OFFSETS) + fz.offsets_verbs(offsets / fz.OFFSETS,
                                                                                      offsets / "reference.json")
    for argv in argvs:
        outcome = fz.run_forked(argv, deadline_s=DEADLINE_S)
        assert outcome.returncode == 0, (argv, fz.describe(outcome))
        assert not fz.problems(outcome, argv[0], "", allow_failed_fit=False), (argv, fz.describe(outcome))


def test_damaged_datasets_fail_cleanly(valid, work):
    dataset, offsets = valid
    cases = fz.dataset_cases(dataset, seed=0, n_json=40, n_csv=80)
    runs, failures = fz.run_cases(cases, dataset, work / "datasets",
                                  lambda d, out: fz.dataset_verbs(d, out, offsets / fz.OFFSETS), every_verb=False,
                                  deadline_s=DEADLINE_S)
    assert runs >= len(cases) - 3  # (permission-denied cases skip the verb that writes)
    assert not failures, report(runs, failures)


def test_damaged_offsets_files_fail_cleanly(valid, work):
    _, offsets = valid
    reference = offsets / "reference.json"
    cases = fz.offsets_cases(offsets / fz.OFFSETS, seed=0, n_json=60)
    runs, failures = fz.run_cases(cases, offsets, work / "offsets",
                                  lambda d, out: fz.offsets_verbs(d / fz.OFFSETS, reference), every_verb=False,
                                  deadline_s=DEADLINE_S)
    assert runs == len(cases)
    assert not failures, report(runs, failures)



def test_a_joint_list_without_a_joint_the_data_need_is_named_by_every_verb(valid, work):
    """The fuzz harness found `joints` with one entry deleted refused in a line that named neither file nor field
    (the model's 'the data have no angles of joint ...'): the reader now names dataset.json's `joints`."""
    import json
    import shutil

    dataset, offsets = valid
    copy = work / "no_joint"
    shutil.copytree(dataset, copy)
    meta = json.loads((copy / fz.META).read_text())
    meta["joints"].remove("LAnkleRoll")
    (copy / fz.META).write_text(json.dumps(meta))
    argvs = fz.dataset_verbs(copy, work, offsets / fz.OFFSETS)
    for argv in argvs:
        outcome = fz.run_forked(argv, deadline_s=DEADLINE_S)
        assert outcome.returncode == 2, (argv, fz.describe(outcome))
        assert not fz.problems(outcome, argv[0], str(copy / fz.META), allow_failed_fit=True), fz.describe(outcome)
        assert "field 'joints'" in outcome.stderr and "LAnkleRoll" in outcome.stderr


V1 = Path(__file__).parent / "data" / "v1"  # files of naocal.dataset/1 and naocal.offsets/1 (still read)


@pytest.fixture(scope="module")
def valid_v1(work):
    import shutil

    dataset, offsets = work / "valid_v1" / "dataset", work / "valid_v1" / "offsets"
    shutil.copytree(V1 / "synthetic_dataset", dataset)
    (dataset / "truth.json").unlink()
    offsets.mkdir()
    shutil.copy(V1 / "offsets_base.json", offsets / fz.OFFSETS)
    shutil.copy(V1 / "offsets_base.json", offsets / "reference.json")
    for path in (work / "valid_v1", dataset, offsets):
        os.chmod(path, 0o755)
    for path in list(dataset.iterdir()) + list(offsets.iterdir()):
        os.chmod(path, 0o644)
    return dataset, offsets


def test_damaged_version_1_files_fail_cleanly(valid_v1, work):
    """A version 1 seed too: its own reader's checks (a few seeded mutations of each file; the file-level damages
    are the same code path as version 2's)."""
    dataset, offsets = valid_v1
    cases = fz.dataset_cases(dataset, seed=1, n_json=6, n_csv=10)[-16:]
    runs, failures = fz.run_cases(cases, dataset, work / "datasets_v1", fz.dataset_verbs, every_verb=False,
                                  deadline_s=DEADLINE_S)
    assert not failures, report(runs, failures)
    reference = offsets / "reference.json"
    cases = fz.offsets_cases(offsets / fz.OFFSETS, seed=1, n_json=10)[-10:]
    runs, failures = fz.run_cases(cases, offsets, work / "offsets_v1",
                                  lambda d, out: fz.offsets_verbs(d / fz.OFFSETS, reference), every_verb=False,
                                  deadline_s=DEADLINE_S)
    assert runs == len(cases) and not failures, report(runs, failures)
