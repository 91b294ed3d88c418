"""Can the top camera see the sandals with the robot on its back? Counts over random leg stances.

    python benchmarks/top_camera_views.py [--stances 20000] [--seed 0] [--render 0]

For each leg: `--stances` leg stances drawn uniformly within the joint limits (0.05 rad margin), each seen from a
grid of head postures over the whole documented HeadPitch-vs-HeadYaw range (41 yaws x 12 pitches). A stance
counts at each stage it passes with at least one head posture:
  any corner    some inner corner of the sandal projects into the 640 x 480 image, the board facing the camera
  24 corners    all 24 inner corners do
  view rules    the planner's: every corner 50 px inside the image, tilt <= 60 deg, squares >= 12 px
  stance rules  the planner's: joint margins, HeadPitch >= 0.34 rad (the back of the head clear of the ground),
                20 mm between body parts, 15 mm to the ground, the feet 35 mm apart
  unoccluded    no ray from the camera to the board's grid (padded by a quarter square) hits the body
  robust        the stance keeps 10 mm with the offsets still unknown (3 sigma of the planner's prior)
The same counts for the bottom camera are printed beside them. `--render N` renders N of the top camera's
accepted views on the ideal mock (backends.mock) and detects the board in them (agent.measure.opencv_detector).
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.planner import Planner, PlanSettings, with_leg  # noqa: E402
from naocal.agent.visibility import ViewRules, view_matrix  # noqa: E402
from naocal.solver.robot import default_intrinsics  # noqa: E402
from naocal.solver.joints import JOINTS, LEGS, leg_joints  # noqa: E402
from naocal.solver.limits import head_pitch_limits  # noqa: E402
from naocal.solver.joints import HEAD_COLUMNS  # noqa: E402

STAGES = ("any corner", "24 corners", "view rules", "stance rules", "unoccluded", "robust")


def head_grid(n_yaw=41, n_pitch=12) -> np.ndarray:
    heads = []
    for yaw in np.linspace(-2.0, 2.0, n_yaw):
        lo, hi = head_pitch_limits(yaw)
        heads += [(yaw, p) for p in np.linspace(lo, hi, n_pitch)]
    return np.array(heads)


def count(planner: Planner, leg: str, camera: str, Q: np.ndarray, heads: np.ndarray, accepted: list) -> dict:
    K = default_intrinsics(camera)
    s = planner.settings
    loose = ViewRules(margin_px=-1e6, max_tilt_deg=80.0, min_square_px=0.0)  # in front and facing
    n_any = 0
    seen = np.zeros((len(Q), len(heads)), dtype=bool)
    for chunk in np.array_split(np.arange(len(Q)), max(len(Q) // 2000, 1)):
        # 'any corner': project and count corners inside the image for boards in front and facing the camera
        from naocal.solver.kinematics import camera_fk, leg_fk, project_sole_points
        from naocal.solver.nao_model import board_vertices_sole

        T_sole = leg_fk(Q[chunk], leg)
        facing = view_matrix(Q[chunk], leg, heads, K, loose, camera=camera)
        for h, T_cam in enumerate(camera_fk(heads, camera)):
            uv, depth = project_sole_points(np.repeat(T_cam[None], len(chunk), 0), T_sole, board_vertices_sole(), K)
            inside = (depth > 0.05) & (uv[..., 0] >= 0) & (uv[..., 0] <= K["width_px"] - 1) & (uv[..., 1] >= 0) & (
                uv[..., 1] <= K["height_px"] - 1)
            seen[chunk, h] = facing[:, h] & inside.any(axis=1)
        n_any += int(seen[chunk].any(axis=1).sum())
    all24 = view_matrix(Q, leg, heads, K, ViewRules(margin_px=0.0, max_tilt_deg=80.0, min_square_px=0.0),
                        camera=camera)
    rules = view_matrix(Q, leg, heads, K, s.view_rules(), camera=camera)
    counts = dict.fromkeys(STAGES, 0)
    counts["any corner"], counts["24 corners"], counts["view rules"] = (
        n_any, int(all24.any(axis=1).sum()), int(rules.any(axis=1).sum()))
    for i in np.flatnonzero(rules.any(axis=1)):
        passed = [False] * 3
        for h in np.flatnonzero(rules[i]):
            q14 = with_leg(planner.parked, leg, Q[i])
            q14[HEAD_COLUMNS] = heads[h]
            if not planner.stance_ok(q14):
                continue
            passed[0] = True
            if not planner.occlusion.is_visible(q14, leg, camera):
                continue
            passed[1] = True
            if not planner.robust_ok(q14):
                continue
            passed[2] = True
            accepted.append(q14)
            break
        for stage, ok in zip(STAGES[3:], passed):
            counts[stage] += int(ok)
    return counts


def render_check(views: list, n: int) -> None:
    """Render `n` accepted top-camera views on the ideal mock (no offsets known to the planner: the mock's own
    truth moves the board by its offsets) and detect the board."""
    from naocal.agent.measure import opencv_detector
    from naocal.backends.mock import MockBackend
    from naocal.solver.joints import JOINTS

    found = []
    for leg, q14 in views[:n]:
        with MockBackend(seed=1, posture={j: float(a) for j, a in zip(JOINTS, q14)}) as mock:
            mock.sleep(0.5)
            image = mock.capture(camera="top")
            truth = mock.true_vertex_pixels(image)[leg]
            visible = int(truth[1].sum())
            detection = opencv_detector(image, truth[0], leg, 60.0)
            found.append((visible, len(detection.vertices_px) if detection.ok else 0))
    print(f"rendered on the ideal mock (seed 1): {len(found)} views; truly visible corners "
          f"{[v for v, _ in found]}, detected {[d for _, d in found]}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stances", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--render", type=int, default=0)
    args = ap.parse_args(argv)
    planner = Planner(PlanSettings())
    heads = head_grid()
    rng = np.random.default_rng(args.seed)
    views = []
    try:
        print(f"{args.stances} random stances per leg, {len(heads)} head postures each; stances passing each stage")
        print(f"{'leg':>3} {'camera':>6} " + " ".join(f"{s:>12}" for s in STAGES) + "   seconds")
        for leg in LEGS:
            names = leg_joints(leg)
            lo = np.array([planner.limits[j][0] for j in names]) + 0.05
            hi = np.array([planner.limits[j][1] for j in names]) - 0.05
            Q = rng.uniform(lo, hi, size=(args.stances, 6))
            for camera in ("top", "bottom"):
                t0 = time.perf_counter()
                accepted, yaw = [], []
                c = count(planner, leg, camera, Q, heads, accepted)
                if camera == "top":
                    views += [(leg, q) for q in accepted]
                    yaw = np.array([q[HEAD_COLUMNS][0] for q in accepted])
                    pitch = np.array([q[HEAD_COLUMNS][1] for q in accepted])
                print(f"{leg:>3} {camera:>6} " + " ".join(f"{c[s]:>12d}" for s in STAGES)
                      + f"   {time.perf_counter() - t0:.0f}")
            if len(yaw):
                hip = np.array([q[JOINTS.index(leg + "HipPitch")] for q in accepted])
                print(f"    top camera's accepted views: |HeadYaw| {np.abs(yaw).min():.2f}-{np.abs(yaw).max():.2f} "
                      f"rad, HeadPitch {pitch.min():.2f}-{pitch.max():.2f} rad, {leg}HipPitch {hip.min():.2f} to "
                      f"{hip.max():.2f} rad")
        if args.render:
            render_check(views, args.render)
    finally:
        planner.close()


if __name__ == "__main__":
    main()
