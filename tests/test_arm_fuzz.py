"""Fuzz an arm's inputs: seeded damage of a valid naocal.arm_dataset/1 and naocal.arm_calibration/1, fed to every
verb that reads them (identify, diagnose, verify, offsets ...), with the NAO's harness (tests/fuzz_inputs.py).

Each damaged input must end in exit 0 or 2 (1: verify's drifted; 3: a failed identification), and on failure in
exactly one line on stderr, `naocal VERB: error: ...`, naming the damaged file; never a traceback or a hang.
"""

import os
import random
import shutil

import pytest

from tests import fuzz_inputs as fz
from test_arm import synthetic, true_errors, write

DEADLINE_S = 20.0
ARM_COLUMNS = ("pose", "sensor", "point", "panda_joint1_rad", "panda_joint4_rad", "panda_joint7_rad", "x_m", "z_m",
               "u_px", "v_px")
CALIBRATION = "calibration.json"


@pytest.fixture(scope="module")
def work():
    with fz.work_directory("naocal-arm-fuzz-") as path:  # the permission-denied cases run as nobody
        yield path


@pytest.fixture(scope="module")
def valid(work):
    """(dataset directory with robot.urdf inside, directory holding the calibration and a reference copy)."""
    import json

    from naocal.tools.cli import main

    model, obs, _, sensors = synthetic(("joint_offsets", "link_lengths"), true_errors(seed=31), n_poses=14, seed=32)
    dataset = write(work / "valid" / "dataset", model, obs, sensors)
    doc = json.loads((dataset / "dataset.json").read_text())
    shutil.copyfile(doc["robot"]["urdf"], dataset / "robot.urdf")
    doc["robot"]["urdf"] = "robot.urdf"
    (dataset / "dataset.json").write_text(json.dumps(doc, indent=1))
    calibration = work / "valid" / "calibration"
    calibration.mkdir()
    assert main(["identify", str(dataset), "--cv-folds", "0", "--out", str(calibration / CALIBRATION)]) == 0
    shutil.copy(calibration / CALIBRATION, calibration / "reference.json")
    for path in (work / "valid", dataset, calibration):
        os.chmod(path, 0o755)
    for path in list(dataset.iterdir()) + list(calibration.iterdir()):
        os.chmod(path, 0o644)
    return dataset, calibration


def arm_csv_damages(rng, text, n):
    """n seeded damages of an arm's observations.csv: one cell, a whole column, or the header."""
    lines = text.split("\n")
    header = lines[0].split(",")
    rows = [i for i in range(1, len(lines)) if lines[i]]
    out = []
    for _ in range(n):
        column = rng.choice([c for c in ARM_COLUMNS if c in header])
        j = header.index(column)
        value = rng.choice(fz.NASTY_CELLS)
        changed = list(lines)
        kind = rng.random()
        if kind < 0.85:
            picked = [rng.choice(rows)] if kind < 0.6 else rows
            for i in picked:
                cells = changed[i].split(",")
                cells[j] = value
                changed[i] = ",".join(cells)
            label = f"{column} on {'line ' + str(picked[0] + 1) if len(picked) == 1 else 'every line'} = {value[:24]!r}"
        else:
            new_header = list(header)
            new_header[j] = value or "renamed"
            changed[0] = ",".join(new_header)
            label = f"header: {column} renamed {value[:24]!r}"
        data = "\n".join(changed).encode("utf-8")
        out.append((label, fz._edit_bytes(lambda _b, d=data: d), False))
    return out


def dataset_cases(valid_dir, seed, n_json, n_csv):
    import json

    rng = random.Random(seed)
    meta = json.loads((valid_dir / fz.META).read_text())
    csv_text = (valid_dir / fz.OBSERVATIONS).read_text()
    cases = []
    for target in (fz.META, fz.OBSERVATIONS, "robot.urdf"):
        for label, damage, nobody in rng.sample(fz.file_damages(rng, 30), 5):
            cases.append(fz.Case(f"{target}: {label}", target, fz._on(target, damage), nobody))
    cases += [fz.Case(f"{fz.META}: {label}", fz.META, fz._on(fz.META, damage), nobody)
              for label, damage, nobody in fz.json_damages(rng, meta, n_json)]
    cases += [fz.Case(f"{fz.OBSERVATIONS}: {label}", fz.OBSERVATIONS, fz._on(fz.OBSERVATIONS, damage), nobody)
              for label, damage, nobody in arm_csv_damages(rng, csv_text, n_csv)]
    return cases


def dataset_verbs(calibration):
    def verbs(dataset, out_dir):
        return [["identify", str(dataset), "--cv-folds", "0"],
                ["identify", str(dataset), "--json", "--cv-folds", "2", "--out", str(out_dir / "identified.json")],
                ["diagnose", str(dataset), "--json"],
                ["verify", str(dataset), "--offsets", str(calibration)]]
    return verbs


def calibration_verbs(calibration, reference):
    return [["offsets", "show", str(calibration)],
            ["offsets", "validate", str(calibration)],
            ["offsets", "diff", str(calibration), str(reference)],
            ["offsets", "diff", str(reference), str(calibration)],
            ["offsets", "export", str(calibration), "--format", "json"],
            ["offsets", "export", str(calibration), "--format", "urdf", "--strip-meshes"],
            ["offsets", "apply", str(calibration), "--command", "panda_joint2=10"]]


def run(cases, valid_dir, work, verbs_of):
    """fz.run_cases with the arm's targets (verify's drifted, 1, is a verdict for fz.problems too)."""
    runs, failures = 0, []
    work.mkdir(parents=True, exist_ok=True)
    os.chmod(work, 0o755)
    out_dir = work / "out"
    out_dir.mkdir(exist_ok=True)
    for k, case in enumerate(cases):
        case_dir = fz.prepare(case, valid_dir, work)
        verbs = verbs_of(case_dir, out_dir)
        argv = verbs[k % len(verbs)]
        if case.as_nobody and "--out" in argv:
            argv = verbs[0]
        outcome = fz.run_forked(argv, deadline_s=DEADLINE_S, as_nobody=case.as_nobody)
        runs += 1
        target = str(case_dir / case.target) if case.target not in (fz.META, "robot.urdf") else str(case_dir)
        found = fz.problems(outcome, argv[0], target, allow_failed_fit=argv[0] in ("identify", "diagnose", "verify"))
        if found:
            failures.append(fz.Failure(case.name, argv, found, outcome))
    return runs, failures


def report(runs, failures):
    return f"{len(failures)} of {runs} runs failed:\n" + "\n".join(str(f) for f in failures[:15])


def test_valid_arm_inputs_pass_every_verb_silently(valid, work):
    dataset, calibration = valid
    argvs = dataset_verbs(calibration / CALIBRATION)(dataset, work) + calibration_verbs(
        calibration / CALIBRATION, calibration / "reference.json")
    for argv in argvs:
        outcome = fz.run_forked(argv, deadline_s=DEADLINE_S)
        assert outcome.returncode == 0, (argv, fz.describe(outcome))
        assert not fz.problems(outcome, argv[0], "", allow_failed_fit=False), (argv, fz.describe(outcome))


def test_damaged_arm_datasets_fail_cleanly(valid, work):
    dataset, calibration = valid
    cases = dataset_cases(dataset, seed=0, n_json=15, n_csv=15)  # (benchmarks/fuzz_inputs.py-sized: seed and n up)
    runs, failures = run(cases, dataset, work / "datasets", lambda d, out: dataset_verbs(
        calibration / CALIBRATION)(d, out))
    assert runs == len(cases) and not failures, report(runs, failures)


def test_damaged_arm_calibrations_fail_cleanly(valid, work):
    import json

    dataset, calibration = valid
    rng = random.Random(0)
    doc = json.loads((calibration / CALIBRATION).read_text())
    cases = [fz.Case(f"{CALIBRATION}: {label}", CALIBRATION, fz._on(CALIBRATION, damage), nobody)
             for label, damage, nobody in rng.sample(fz.file_damages(rng, 40), 6) + fz.json_damages(rng, doc, 24)]
    reference = calibration / "reference.json"
    runs, failures = run(cases, calibration, work / "calibrations", lambda d, out: calibration_verbs(
        d / CALIBRATION, reference) + [["verify", str(dataset), "--offsets", str(d / CALIBRATION)]])
    assert runs == len(cases) and not failures, report(runs, failures)
