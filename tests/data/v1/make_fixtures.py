"""How the naocal.dataset/1 and naocal.offsets/1 fixtures in this directory were made.

They were written by the code of commit 0a4df14 (the last version whose writers wrote version 1), run from a
clean copy of that commit, so that tests/test_formats_v1.py can check that today's readers read the files of that
version and give the same numbers:

    git archive 0a4df14 | tar -x -C /tmp/naocal_v1
    cd tests/data/v1 && PYTHONPATH=/tmp/naocal_v1 python make_fixtures.py

Do not re-run it with a later version: the point of these files is that they are old.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def naocal(*args, stdout=None):
    subprocess.run([sys.executable, "-m", "naocal", *map(str, args)], check=True, stdout=stdout)


def main():
    import naocal.solver as solver
    assert not str(Path(solver.__file__)).startswith(str(HERE.parents[2])), "run with the old version's code"
    from naocal.solver.dataset import write_dataset
    from naocal.solver.offsets import offsets_from_alpha, write_offsets
    from naocal.sim.synthetic import dataset_parts, random_truth, synthesize

    # 1. The mock robot, as `naocal simulate` recorded it (4 stances per leg x 3 head postures + the lag probe).
    naocal("simulate", "--out", HERE / "mock_dataset", "--seed", 5, "--stances-per-leg", 4, "--no-images",
           "--effect", "time_lag=0.03", "--no-progress")
    # 2. A synthetic dataset with quantised readings, a stated pixel noise and a tilted gravity.
    rng = np.random.default_rng(11)
    truth = random_truth(rng)
    data = synthesize(rng, truth, n_stances_per_leg=5, n_head_postures=2, pixel_noise_px=0.05,
                      encoder_resolution_rad=np.radians(0.1))
    data.gravity_torso_mps2 = np.array([-9.7, 0.8, 1.0])
    write_dataset(dataset_parts(data, robot_id="synthetic-11", pixel_noise_px=0.05), HERE / "synthetic_dataset")
    (HERE / "synthetic_dataset" / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    # 3. identify's results and offsets files.
    for name, extra in (("base", []), ("effects", ["--effects", "time_lag,head_offsets", "--tie-hip-yaw-pitch"])):
        with open(HERE / f"identify_{name}.json", "w") as out:
            naocal("identify", HERE / "mock_dataset", *extra, "--cv-folds", 0, "--json", "--out",
                   HERE / f"offsets_{name}.json", stdout=out)
    with open(HERE / "diagnose_synthetic.json", "w") as out:
        naocal("diagnose", HERE / "synthetic_dataset", "--json", stdout=out)
    # 4. An offsets file with the top camera too (the v1 writer's API allowed it).
    joints = {j: 0.001 * (k + 1) for k, j in enumerate(["LHipYawPitch", "LHipRoll", "LHipPitch", "LKneePitch",
                                                        "LAnklePitch", "LAnkleRoll", "RHipRoll", "RHipPitch",
                                                        "RKneePitch", "RAnklePitch", "RAnkleRoll"])}
    joints.update(HeadYaw=-0.004, HeadPitch=0.006)
    offsets = offsets_from_alpha(joints, (0.01, -0.05, 0.02), {"L": (0.01, 0.001, -0.002), "R": (-0.01, 0.0, 0.002)},
                                 robot={"id": "nao-7", "body_id": "body-7", "head_id": "head-7"},
                                 fit={"rms_px": [0.3, 0.4], "n_vertices": 3456, "n_images": 144},
                                 created="2025-01-02T03:04:05Z", top_camera_rpy=(0.002, 0.03, -0.01),
                                 source={"tool": "hand-made with offsets_from_alpha"})
    write_offsets(offsets, HERE / "offsets_top.json", backup=False)


if __name__ == "__main__":
    main()
