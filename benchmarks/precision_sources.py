"""Where the realistic mock's joint-offset error comes from: each error source alone, measured on one run.

    python benchmarks/precision_sources.py [--seed 1] [--plan paper|optimal] [--out DIR]

Runs one `naocal calibrate --backend mock` (realistic) and keeps the mock, so that for every saved image it knows
what the agent could not: the servos' true sensor positions and the board vertices' exact pixels at the image's
true exposure time. It then refits the same images with one error source at a time put back:

- exact: true sensor positions, exact pixels, true intrinsics (a check of this script: errors ~0)
- intrinsics: the prior intrinsics (618 px) instead of the true ones
- servo in cell (commands): the commands as joint angles (the servo stands somewhere in the commanded step)
- quantisation (readings): the readings as joint angles
- detection: the detected corners (YUYV, noise, defocus, mis-detections set aside as identify_dataset does)
- ordinary least squares: solver.fit.identify_dataset without GLS (the agent before issue 12's deliver 3)
- agent: what the agent's identification does (identify_dataset with GLS: solver/gls.py)

and prints, per leg joint, the error against the truth (deg). docs/AGENT.md quotes it.
"""

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.calibrate import calibrate  # noqa: E402
from naocal.agent.measure import opencv_detector  # noqa: E402
from naocal.agent.planner import PlanSettings  # noqa: E402
from naocal.agent.states import AgentSettings  # noqa: E402
from naocal.backends.mock import MockBackend  # noqa: E402
from naocal.solver.adapter import model_data_from_dataset  # noqa: E402
from naocal.solver.dataset import read_dataset  # noqa: E402
from naocal.solver.fit import identify_dataset  # noqa: E402
from naocal.solver.identify import identify  # noqa: E402
from naocal.solver.joints import JOINTS, LEG_JOINTS  # noqa: E402
from naocal.solver.registry import Registry  # noqa: E402


def truth_of_images(mock: MockBackend, dataset, data):
    """(servo sensor angles (M, 14), exact pixels (N, 2)) of the fitted data's images at their true exposure."""
    cols = dataset.as_v2().columns
    image = np.asarray(cols["image"], dtype=np.int64)
    stamp = {int(i): float(t) for i, t in zip(image, cols["t_image_s"])}
    offset = mock.truth.time_lag_s + mock.realism.stamp_offset_s()
    servo = np.empty((data.n_images, len(JOINTS)))
    uv = np.empty((data.n_rows, 2))
    for m, image_id in enumerate(data.image_id):
        t = stamp[int(image_id)] - offset
        s = mock.servo_angles(t)
        servo[m] = [s[j] for j in JOINTS]
        pixels = mock._vertex_pixels(mock._true_q(t), str(data.camera[m]))[str(data.target[m])][0]
        rows = np.flatnonzero(data.image_of_row == m)
        uv[rows] = pixels[data.vertex[rows]]
    return servo, uv


def joint_errors_deg(result, truth_alpha) -> np.ndarray:
    return np.degrees([result.value(f"joint_offset.{j}") + truth_alpha[j] for j in LEG_JOINTS])


def joint_stds_deg(result) -> np.ndarray:
    return np.degrees([result.std[result.registry.index[f"joint_offset.{j}"]] for j in LEG_JOINTS])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--plan", default="paper", choices=("paper", "optimal"))
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="naocal_sources_"))
    mock = MockBackend(args.seed, realism="realistic")
    try:
        settings = AgentSettings(seed=0, progress_bar=False, plan=PlanSettings(kind=args.plan))
        result, ctx = calibrate(mock, out, settings, detector=mock.faulty(opencv_detector), truth=mock.truth_dict())
        dataset = read_dataset(out / "dataset")
        agent_fit = identify_dataset(dataset, gls=False)
        data = agent_fit.data  # the still captures the agent fits, mis-detections set aside
        servo, uv_exact = truth_of_images(mock, dataset, data)
        true_cameras = {name: dict(cam, fx_px=mock.truth.camera.fx_px, fy_px=mock.truth.camera.fy_px,
                                   cx_px=mock.truth.camera.cx_px, cy_px=mock.truth.camera.cy_px)
                        for name, cam in data.cameras.items()}
        alpha = mock.truth.alpha_rad
        np.savez(out / "truth_of_images.npz", image_id=data.image_id, servo=servo, uv_exact=uv_exact,
                 vertex=data.vertex, image_of_row=data.image_of_row,
                 true_intrinsics=[mock.truth.camera.fx_px, mock.truth.camera.fy_px, mock.truth.camera.cx_px,
                                  mock.truth.camera.cy_px])
    finally:
        mock.close()
    registry = agent_fit.result.registry
    measured = model_data_from_dataset(dataset, angles="measured")
    commanded = model_data_from_dataset(dataset, angles="commanded")
    index = {int(i): m for m, i in enumerate(measured.image_id)}
    pick = np.array([index[int(i)] for i in data.image_id])

    def variant(theta=None, uv=None, cameras=None):
        d = replace(data, theta=data.theta if theta is None else theta, uv_px=data.uv_px if uv is None else uv,
                    cameras=cameras or data.cameras, tau=None)
        return identify(d, Registry((), setup=registry.setup, tie_shared_motors=True),
                        reading_step_rad=np.full(len(JOINTS), agent_fit.reading_step_rad))

    cases = [
        ("exact", variant(servo, uv_exact, true_cameras)),
        ("intrinsics (prior 618 px)", variant(servo, uv_exact)),
        ("servo in cell (commands)", variant(commanded.theta[pick], uv_exact, true_cameras)),
        ("quantisation (readings)", variant(measured.theta[pick], uv_exact, true_cameras)),
        ("detection", variant(servo, None, true_cameras)),
        (f"ordinary least squares ({agent_fit.angles})", agent_fit.result),
        ("agent (GLS, intrinsics free)", identify_dataset(dataset, gls=True).result),
    ]
    print(f"seed {args.seed}, {args.plan} plan: {data.n_images} still images, robot time "
          f"{ctx.measurement['robot_time_s']:.1f} s; run in {out}")
    print("| case | " + " | ".join(LEG_JOINTS) + " | worst | worst std |")
    print("|---" * (len(LEG_JOINTS) + 3) + "|")
    for name, res in cases:
        e = joint_errors_deg(res, alpha)
        s = joint_stds_deg(res)
        print(f"| {name} | " + " | ".join(f"{x:+.3f}" for x in e) + f" | {np.max(np.abs(e)):.3f} | {np.max(s):.3f} |")


if __name__ == "__main__":
    main()
