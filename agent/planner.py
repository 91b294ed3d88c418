"""Modelling: plan the stances the robot takes, deterministically from a seed.

Every capture of a plan satisfies, on the nominal model:
- all 24 vertices inside the image with a margin (`ViewRules.margin_px`), the board facing the camera (tilt at most
  `max_tilt_deg`), squares large enough to detect;
- joints inside their limits with a margin, HeadPitch inside the HeadPitch-vs-HeadYaw table with a margin and high
  enough that the head stays clear of the ground (the robot lies on its back);
- no self-collision or ground contact (body.nao_body.CollisionChecker with margins larger than the
  robot's own refusal check, because the true robot differs from the nominal one by its offsets), and the two
  legs' feet and shins kept `legs_apart_m` apart (the other leg's offsets are unknown while one is measured);
- the agent's own worst-case check passes whatever offsets the robot carries (agent.safety.worst_case_clearance
  at the guard's margin, with `robust_extra_margin_m` more): the agent commands the planned angles raw, so the
  joints stand at plan + offset, and the plan is made before any offset is known (the one HipYawPitch motor's
  12 deg moves both feet by centimetres; a plan checked at the nominal offsets put a verification stance's
  sandal 11.8 mm into the ground on realistic seed 1);
- no part of the robot (the other leg, the own foot, the head) between the camera and the board (ray tests).

Plans:
- "paper": the paper's plan, `stances_per_leg` random feasible stances per leg x `head_postures` head postures.
- "optimal": a pool of feasible candidates (`pool_per_leg` per leg) and greedy D-optimal selection on the
  information about the paper's 21 parameters (agent.design); as many stances as it takes to reach the precision
  of the paper plan drawn from the same pool (or `stances_total` if given).

Both orders the stances of each leg to keep the motion short while every leg joint is approached from both sides
about equally often (backlash is only identifiable if approach directions vary), and end each leg with the lag
probe (a slow sweep, see `Sweep`), unless `probe` is off.

Why the probe is in the standard plan: a time lag between the image clock and the joint clock shifts every moving
capture by velocity x lag but leaves still captures untouched, so it cannot be seen in still data at all; six
images (about 4 % of the plan, a few seconds of robot time) make it measurable. The agent's own identification
uses only the still captures, so the probe never biases the paper's 21 parameters.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field

import numpy as np

from naocal.agent.design import greedy_d_optimal, log_det, matching_count, predicted_std, reaching_count, stance_information
from naocal.agent.plan import Plan, Still, Sweep
from naocal.agent.safety import KNOWN_OFFSET_MARGIN_M, SafetyGuard, prior_covariance, worst_case_clearance
from naocal.agent.visibility import OcclusionChecker, ViewRules, view_matrix, views_ok
from naocal.body.nao_body import CollisionChecker, NaoBody
from naocal.body.pybullet_quiet import pybullet
from naocal.solver.joints import HEAD_COLUMNS, JOINT_INDEX, JOINTS, LEG_COLUMNS, LEG_JOINTS, LEGS, leg_joints
from naocal.solver.kinematics import camera_fk, gravity_torques, leg_fk
from naocal.solver.errors import SafetyError
from naocal.solver.robot import default_intrinsics
from naocal.solver.limits import command_limits, head_pitch_limits, joint_limits, max_speeds
from naocal.solver.registry import Registry
from naocal.solver.transforms import rot_x, rot_y, rot_z

log = logging.getLogger(__name__)

LEG_END_PARTS = ("Sandal", "Foot", "Tibia")

# Both legs out of the camera's way, spread wide with the soles turned outwards and lifted off the ground; head
# resting. Wide, because a HipYawPitch offset of 12 deg (real robots carry that) turns both feet towards each other:
# the sandals keep their margins for any such offset (agent.safety.worst_case_clearance).
PARKED = {"LHipRoll": 0.6, "LHipPitch": -0.3, "LAnkleRoll": 0.2, "RHipRoll": -0.6, "RHipPitch": -0.3,
          "RAnkleRoll": -0.2, "HeadYaw": 0.0, "HeadPitch": 0.42}


@dataclass(frozen=True)
class PlanSettings:
    """Everything that defines a plan besides the seed (stored in plan.json)."""

    kind: str = "paper"  # "paper" or "optimal"
    stances_per_leg: int = 24  # paper plan (and the reference precision of the optimal plan)
    stances_total: int | None = None  # optimal plan: a fixed count instead of "match the paper plan"
    head_postures: int = 3
    pool_per_leg: int = 150  # optimal plan: candidate stances per leg
    probe: bool = True
    probe_images_per_leg: int = 3
    probe_speed_fraction: float = 0.016  # fastest leg joint at about 0.1 rad/s: little motion blur
    probe_duration_s: float = 1.5
    verification_per_leg: int = 2
    # The top camera (docs/AGENT.md): it sees a sandal only with the thigh pulled up to the chest; stances for it are
    # drawn from that region, after the bottom camera's captures (the joint offsets are known by then).
    top_stances_per_leg: int = 2
    top_head_postures: int = 2
    top_hip_pitch_min_rad: float = -1.50
    top_hip_pitch_max_rad: float = -1.15
    top_head_yaw_max_rad: float = field(default_factory=lambda: command_limits()["HeadYaw"][1])  # nao.json
    joint_margin_rad: float = 0.05
    head_pitch_margin_rad: float = 0.03
    head_yaw_max_rad: float = 0.5
    head_pitch_min_rad: float = 0.34  # below this the back of the head nears the ground
    min_head_spread_rad: float = 0.05  # head postures of one stance at least this far apart (yaw, pitch)
    collision_margin_m: float = 0.02
    ground_margin_m: float = 0.015
    legs_apart_m: float = 0.035  # the two legs' feet and shins at least this far apart: while one leg is measured,
    # the other's offsets and sandal mount are still unknown (up to ~2 deg per joint: centimetres at the foot)
    path_collision_margin_m: float = 0.015  # transitions between stances: the agent's own command check margins
    path_ground_margin_m: float = 0.012
    view_margin_px: float = 50.0  # around the projection through the prior camera rotation: room for +-3 deg
    # Real heads' bottom cameras are rotated: published corrections pitch -3..-8.5 deg, roll and yaw 1-3 deg
    # (B-Human cameraCalibration.cfg, HULKs head.<id>.json; docs/MOCK.md). Boards are planned where the camera sees them with the typical rotation.
    camera_prior_rad: dict = field(default_factory=lambda: {"roll": 0.0, "pitch": -0.1, "yaw": 0.0})
    max_tilt_deg: float = 60.0
    min_square_px: float = 12.0
    # The offsets a real robot may carry before they are measured (the agent's worst-case safety check): HipYawPitch
    # up to about 12 deg (HULKs' bodies: -0.07 and -0.2 rad), the other leg joints a few degrees.
    hip_yaw_pitch_offset_prior_deg: float = 12.0
    leg_offset_prior_deg: float = 3.0
    # Every stance keeps the guard's margin for those offsets (agent.safety.KNOWN_OFFSET_MARGIN_M) and this much
    # more: the sandals' mounts (up to about 1 deg and 3 mm, unknown when planning) move their far ends by some mm.
    robust_extra_margin_m: float = 0.004
    speed_fraction: float = 0.4  # what the measurement will use: for ordering and the time estimate
    # The design's information model (agent.design): the fit the agent makes (GLS with the intrinsics free, on
    # readings in encoder steps shared by the images of one command, each servo pulled towards one side of its step
    # by its load). sigma_px is the effective pixel noise: the detector's 0.03 px plus what the model still lacks
    # (detection biases). Chosen so that the predicted worst joint-offset std matches the fit's jackknife std on the
    # realistic mock: whole runs of seeds 1-4, paper and optimal plans, realised / predicted 0.70-1.33 with 0.05 px,
    # mean 0.98 (with 0.1 px: 0.47-0.85; benchmarks/bench_precision.py, docs/AGENT.md).
    sigma_px: float = 0.05
    encoder_resolution_deg: float = 360.0 / 4096  # 12-bit encoders (docs/MOCK.md)
    # The load pulling a servo to one side of its step (agent.design.load_error_moment): tau / K. Not published for
    # the NAO; the realistic mock's (docs/MOCK.md: the largest lying-leg load, 1.4 N m, pulls ~0.7 step). None: the
    # servo rests anywhere in its step whatever the load.
    servo_stiffness_nm_per_rad: float | None = 1300.0
    design_effects: str = "intrinsics"  # comma-separated, besides the paper's parameters
    # optimal plan: stances in greedy order until the predicted worst joint-offset std reaches this (None: until the
    # paper plan's precision is matched); half of issue 12's goal of 0.05 deg, for the realised / predicted spread.
    target_worst_std_deg: float | None = 0.025
    # robot time per capture besides the motion: the servo settling, the still window, the image guard. Measured,
    # paper plan seed 0 (motion 22.3 s at speed_fraction 0.4, 158 images): 63.0 s on the ideal mock (0.26 s), 81.3 s
    # on the realistic one (0.37 s: its servo settles like a damped second-order system, LoLA's 12 ms cycle).
    capture_overhead_s: float = 0.37
    intrinsics: dict = field(default_factory=default_intrinsics)

    def view_rules(self) -> ViewRules:
        return ViewRules(self.view_margin_px, self.max_tilt_deg, self.min_square_px)

    def camera_offset(self) -> np.ndarray:
        """Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw) of the prior camera rotation (Eq. 3)."""
        c = self.camera_prior_rad
        return rot_y(c["pitch"]) @ rot_x(c["roll"]) @ rot_z(c["yaw"])

    @classmethod
    def from_dict(cls, d: dict) -> "PlanSettings":
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclass
class FeasibleStance:
    """A feasible stance: leg angles (6,) and its head postures (H, 2), nominal-model checked and safe for any
    plausible offsets (Planner.robust_ok)."""

    leg: str
    q_leg: np.ndarray
    heads: np.ndarray
    camera: str = "bottom"

    def stances(self, parked: np.ndarray) -> np.ndarray:
        """(H, 14) full postures, one per head posture."""
        out = np.repeat(with_leg(parked, self.leg, self.q_leg)[None], len(self.heads), axis=0)
        out[:, HEAD_COLUMNS] = self.heads
        return out


def with_leg(q14, leg: str, q_leg) -> np.ndarray:
    """q14 with `leg`'s six angles set to q_leg. Both HipYawPitch joints take q_leg's: they are one motor on the
    robot (NAOqi and the mock move RHipYawPitch with LHipYawPitch), so the other leg turns with it."""
    out = np.array(q14, dtype=float)
    out[LEG_COLUMNS[leg]] = q_leg
    out[[JOINT_INDEX["LHipYawPitch"], JOINT_INDEX["RHipYawPitch"]]] = q_leg[0]
    return out


def parked_posture() -> np.ndarray:
    q = np.zeros(len(JOINTS))
    for name, angle in PARKED.items():
        q[JOINT_INDEX[name]] = angle
    return q


class Planner:
    """Makes plans; owns a nominal PyBullet body for collision and occlusion checks (close() it)."""

    def __init__(self, settings: PlanSettings = PlanSettings(), *, limits=None, speeds=None):
        self.settings = settings
        self.limits = dict(joint_limits() if limits is None else limits)
        self.speeds = dict(max_speeds() if speeds is None else speeds)
        self.body = NaoBody()
        self.collisions = CollisionChecker(self.body, margin_m=settings.collision_margin_m,
                                           ground_margin_m=settings.ground_margin_m)
        self.occlusion = OcclusionChecker(self.body)
        self.paths = SafetyGuard(self.limits, CollisionChecker(self.body, margin_m=settings.path_collision_margin_m,
                                                               ground_margin_m=settings.path_ground_margin_m),
                                 self.speeds)
        # the guard's worst case over the offsets, at the guard's margins (SafetyGuard.worst_case)
        self.robust = CollisionChecker(self.body, margin_m=KNOWN_OFFSET_MARGIN_M, ground_margin_m=KNOWN_OFFSET_MARGIN_M)
        self.offsets_prior = prior_covariance(np.radians(settings.hip_yaw_pitch_offset_prior_deg),
                                              np.radians(settings.leg_offset_prior_deg))
        self.parked = parked_posture()
        self.design_registry = Registry(tuple(e for e in settings.design_effects.split(",") if e))
        if not self.stance_ok(self.parked):
            raise AssertionError("the parked posture is not safe: fix agent.planner.PARKED")

    def close(self) -> None:
        self.body.close()

    # --- constraints ----------------------------------------------------------------------------------------
    def within_limits(self, q14) -> bool:
        m = self.settings.joint_margin_rad
        for name, angle in zip(JOINTS, q14):
            lo, hi = self.limits[name]
            if not (lo + m <= angle <= hi - m):
                return False
        yaw, pitch = q14[JOINT_INDEX["HeadYaw"]], q14[JOINT_INDEX["HeadPitch"]]
        lo, hi = head_pitch_limits(yaw)
        mh = self.settings.head_pitch_margin_rad
        return lo + mh <= pitch <= hi - mh and pitch >= self.settings.head_pitch_min_rad

    def stance_ok(self, q14) -> bool:
        return self.within_limits(q14) and self.collisions.is_safe(q14) and self.legs_apart(q14)

    def legs_apart(self, q14) -> bool:
        """No sandal, foot or shin of one leg within legs_apart_m of those of the other (collisions.is_safe has
        just posed the body at q14, or this call does)."""
        self.body.set_angles(q14)
        index = self.body.link_index
        for a in LEG_END_PARTS:
            for b in LEG_END_PARTS:
                if pybullet.getClosestPoints(self.body.robot, self.body.robot, self.settings.legs_apart_m,
                                             linkIndexA=index["L" + a], linkIndexB=index["R" + b],
                                             physicsClientId=self.body.client):
                    return False
        return True

    def robust_ok(self, Q14) -> bool:
        """Every posture of Q14 (k, 14) passes the guard's worst-case check for any plausible offsets (3 standard
        deviations of `offsets_prior`) with robust_extra_margin_m to spare (agent.safety.worst_case_clearance).
        Whatever the first leg's fit teaches, the agent commands raw angles: a known offset still moves the joint
        from where the plan put it, so every stance is checked against every offset, not only the unknown ones."""
        return all(worst_case_clearance(self.robust, q, self.offsets_prior)[0] >= self.settings.robust_extra_margin_m
                   for q in np.atleast_2d(Q14))

    def views_ok(self, Q14, leg, camera: str = "bottom") -> np.ndarray:
        """(N,) the view rules for postures Q14 (N, 14) looking at `leg`'s board through `camera` (nominal
        model)."""
        Q14 = np.atleast_2d(np.asarray(Q14, dtype=float))
        return views_ok(camera_fk(Q14[:, HEAD_COLUMNS], camera), leg_fk(Q14[:, LEG_COLUMNS[leg]], leg),
                        self.settings.intrinsics, self.settings.view_rules(), self.settings.camera_offset())

    def capture_ok(self, q14, leg, *, view_checked=False, camera: str = "bottom") -> bool:
        """A still capture of `leg`'s board at posture q14 through `camera` meets every rule (`view_checked`: the
        view rules are known to hold already)."""
        q14 = np.asarray(q14, dtype=float)
        if not self.stance_ok(q14):
            return False
        if not view_checked and not self.views_ok(q14, leg, camera)[0]:
            return False
        return self.occlusion.is_visible(q14, leg, camera)

    # --- candidates -----------------------------------------------------------------------------------------
    def _head_samples(self, rng, n=48) -> np.ndarray:
        s = self.settings
        yaw = rng.uniform(-s.head_yaw_max_rad, s.head_yaw_max_rad, n)
        bounds = np.array([head_pitch_limits(y) for y in yaw])
        lo = np.maximum(bounds[:, 0] + s.head_pitch_margin_rad, s.head_pitch_min_rad)
        hi = bounds[:, 1] - s.head_pitch_margin_rad
        keep = hi > lo
        return np.column_stack([yaw[keep], rng.uniform(lo[keep], hi[keep])])

    def _spread_heads(self, leg, q_leg, heads, visible, rng, camera: str = "bottom") -> np.ndarray | None:
        """`head_postures` (top camera: `top_head_postures`) valid head postures, far apart from each other
        (farthest-point order)."""
        k = self.settings.head_postures if camera == "bottom" else self.settings.top_head_postures
        remaining = list(rng.permutation(np.flatnonzero(visible)))
        chosen = []
        while remaining and len(chosen) < k:
            if chosen:
                d = np.min(np.linalg.norm(heads[remaining][:, None] - heads[chosen][None], axis=2), axis=1)
                if d.max() < self.settings.min_head_spread_rad:
                    break
                pick = remaining.pop(int(np.argmax(d)))
            else:
                pick = remaining.pop(0)
            q14 = with_leg(self.parked, leg, q_leg)
            q14[HEAD_COLUMNS] = heads[pick]
            if self.capture_ok(q14, leg, view_checked=True, camera=camera):
                chosen.append(pick)
        if len(chosen) < k:
            return None
        return heads[chosen]

    def candidates(self, leg: str, rng, n_wanted: int, *, max_batches=400, batch=256) -> list[FeasibleStance]:
        """`n_wanted` feasible stances of `leg` in random order (deterministic from rng), each safe for any
        plausible offsets (robust_ok): any of them may open the leg's measurement or verify the result."""
        s = self.settings
        names = leg_joints(leg)
        lo = np.array([self.limits[j][0] for j in names]) + s.joint_margin_rad
        hi = np.array([self.limits[j][1] for j in names]) - s.joint_margin_rad
        found: list[FeasibleStance] = []
        for _ in range(max_batches):
            q = rng.uniform(lo, hi, size=(batch, 6))
            heads = self._head_samples(rng)
            visible = view_matrix(q, leg, heads, s.intrinsics, s.view_rules(), s.camera_offset())
            for i in np.flatnonzero(visible.sum(axis=1) >= s.head_postures):
                if not self.stance_ok(with_leg(self.parked, leg, q[i])):
                    continue
                chosen = self._spread_heads(leg, q[i], heads, visible[i], rng)
                if chosen is None:
                    continue
                cand = FeasibleStance(leg, q[i].copy(), chosen)
                if not self.robust_ok(cand.stances(self.parked)):
                    continue
                found.append(cand)
                if len(found) == n_wanted:
                    return found
        raise RuntimeError(f"found only {len(found)} of {n_wanted} feasible stances for leg {leg}: "
                           "are the view rules or margins too strict?")

    def top_candidates(self, leg: str, rng, n_wanted: int, *, max_batches=200, batch=256) -> list[FeasibleStance]:
        """`n_wanted` stances in which the top camera sees `leg`'s sandal, each with `top_head_postures` head
        postures: HipPitch within top_hip_pitch_min_rad..top_hip_pitch_max_rad (the thigh towards the chest, where alone the top camera sees
        the board), the other joints anywhere within their margins, HeadYaw within +-top_head_yaw_max_rad. Taken
        after both legs' offsets are known, but commanded raw as every stance: safe for any plausible offsets
        (robust_ok)."""
        s = self.settings
        names = leg_joints(leg)
        lo = np.array([self.limits[j][0] for j in names]) + s.joint_margin_rad
        hi = np.array([self.limits[j][1] for j in names]) - s.joint_margin_rad
        pitch = names.index(f"{leg}HipPitch")
        lo[pitch], hi[pitch] = max(lo[pitch], s.top_hip_pitch_min_rad), min(hi[pitch], s.top_hip_pitch_max_rad)
        found: list[FeasibleStance] = []
        for _ in range(max_batches):
            q = rng.uniform(lo, hi, size=(batch, 6))
            yaw = rng.uniform(-s.top_head_yaw_max_rad, s.top_head_yaw_max_rad, 48)
            bounds = np.array([head_pitch_limits(y) for y in yaw])
            p_lo = np.maximum(bounds[:, 0] + s.head_pitch_margin_rad, s.head_pitch_min_rad)
            p_hi = bounds[:, 1] - s.head_pitch_margin_rad
            keep = p_hi > p_lo
            heads = np.column_stack([yaw[keep], rng.uniform(p_lo[keep], p_hi[keep])])
            visible = view_matrix(q, leg, heads, s.intrinsics, s.view_rules(), s.camera_offset(), camera="top")
            for i in np.flatnonzero(visible.sum(axis=1) >= s.top_head_postures):
                if not self.stance_ok(with_leg(self.parked, leg, q[i])):
                    continue
                chosen = self._spread_heads(leg, q[i], heads, visible[i], rng, camera="top")
                if chosen is None:
                    continue
                cand = FeasibleStance(leg, q[i].copy(), chosen, camera="top")
                if not self.robust_ok(cand.stances(self.parked)):
                    continue
                found.append(cand)
                if len(found) == n_wanted:
                    return found
        log.warning("found only %d of %d top-camera stances for leg %s", len(found), n_wanted, leg)
        return found

    # --- ordering -------------------------------------------------------------------------------------------
    def move_time_s(self, a14, b14, speed_fraction=None) -> float:
        """Time (s) to move from posture a to b, each joint at speed_fraction of its maximum speed."""
        f = self.settings.speed_fraction if speed_fraction is None else speed_fraction
        v = np.array([self.speeds[j] for j in JOINTS]) * f
        return float(np.max(np.abs(np.asarray(b14) - np.asarray(a14)) / v))

    def tour(self, cands: list[FeasibleStance], start14: np.ndarray) -> list[int]:
        """Visit order of stances: short total motion along clear paths, approach directions of every
        leg joint balanced.

        A transition whose path is not clear (agent.safety.SafetyGuard.path_clear, both motion models) costs a
        detour penalty, so tours avoid them where they can. Nearest-neighbour tours from every start, the most
        promising improved by 2-opt; the tour minimising time x (1 + penalty for imbalanced approach directions)
        wins. Deterministic.
        """
        n = len(cands)
        if n <= 1:
            return list(range(n))
        leg = cands[0].leg
        pts = np.array([c.stances(self.parked)[0] for c in cands])
        v = np.array([self.speeds[j] for j in JOINTS]) * self.settings.speed_fraction
        f = self.settings.speed_fraction
        detour_s = 5.0
        C = np.max(np.abs(pts[:, None, :] - pts[None, :, :]) / v, axis=2)
        C0 = np.max(np.abs(pts - start14) / v, axis=1)
        # Path checks are costly: check the edges of the best tour only, penalise the blocked ones, re-plan.
        clear: dict = {}

        def blocked(a, b) -> bool:
            if (a, b) not in clear:
                clear[(a, b)] = self.paths.path_clear(start14 if a is None else pts[a], pts[b], f)
            return not clear[(a, b)]

        best = None
        for _ in range(6):
            best = self._best_tour(C, C0, pts, start14, leg)
            edges = [(None, best[0])] + list(zip(best, best[1:]))
            bad = [(a, b) for a, b in edges if blocked(a, b)]
            if not bad:
                break
            for a, b in bad:
                if a is None:
                    C0[b] += detour_s
                else:
                    C[a, b] += detour_s
        return best

    def _best_tour(self, C, C0, pts, start14, leg) -> list[int]:
        n = len(C)

        def cost(tour):
            t = np.asarray(tour)
            return C0[t[0]] + C[t[:-1], t[1:]].sum()

        def imbalance(tour):
            seq = np.vstack([start14[LEG_COLUMNS[leg]], pts[tour][:, LEG_COLUMNS[leg]]])
            return float(np.max(np.abs(np.mean(np.sign(np.diff(seq, axis=0)), axis=0))))

        def two_opt(tour):
            tour = list(tour)
            improved = True
            while improved:
                improved = False
                for i in range(0, n - 1):
                    for j in range(i + 1, n):
                        new = tour[:i] + tour[i:j + 1][::-1] + tour[j + 1:]
                        if cost(new) < cost(tour) - 1e-9:
                            tour, improved = new, True
            return tour

        def score(tour):
            return cost(tour) * (1.0 + 2.0 * max(0.0, imbalance(tour) - 0.25))

        tours = []
        for first in range(n):
            tour, left = [first], set(range(n)) - {first}
            while left:
                nxt = min(left, key=lambda b: (C[tour[-1], b], b))
                tour.append(nxt)
                left.remove(nxt)
            tours.append(tour)
        tours.sort(key=score)
        tours = tours[:3] + [two_opt(t) for t in tours[:3]]  # 2-opt only the most promising starts
        return min(tours, key=score)

    # --- the lag probe --------------------------------------------------------------------------------------
    def probe_sweep(self, cand: FeasibleStance, head: np.ndarray, rng, tries=48):
        """(start14, end14) of a slow sweep through (or near) `cand` that keeps the board visible all the way,
        or None. Every leg joint moves (random directions), all at probe_speed_fraction of their own maximum speed,
        so that the sweep takes probe_duration_s; the centre is moved off the limits where the sweep needs room."""
        s = self.settings
        names = leg_joints(cand.leg)
        vmax = np.array([self.speeds[j] for j in names])
        amplitude = vmax * s.probe_speed_fraction * s.probe_duration_s / 2.0
        lo = np.array([self.limits[j][0] for j in names]) + s.joint_margin_rad + amplitude
        hi = np.array([self.limits[j][1] for j in names]) - s.joint_margin_rad - amplitude
        centre = np.clip(cand.q_leg, lo, hi)
        for _ in range(tries):
            half = rng.choice([-1.0, 1.0], size=6) * amplitude
            path = []
            for t in np.linspace(-1.0, 1.0, 9):
                q14 = with_leg(self.parked, cand.leg, centre + t * half)
                q14[HEAD_COLUMNS] = head
                path.append(q14)
            if self.views_ok(path, cand.leg).all() and all(self.capture_ok(q, cand.leg, view_checked=True)
                                                           for q in path):
                return path[0], path[-1]
        return None

    # --- plans ----------------------------------------------------------------------------------------------
    def make_plan(self, seed: int) -> Plan:
        s = self.settings
        rng = np.random.default_rng(seed)
        if s.kind not in ("paper", "optimal"):
            raise ValueError(f"unknown plan kind {s.kind!r}: expected 'paper' or 'optimal'")
        n_pool = s.stances_per_leg if s.kind == "paper" else max(s.pool_per_leg, s.stances_per_leg)
        pools = {leg: self.candidates(leg, rng, n_pool + s.verification_per_leg) for leg in LEGS}
        verification_cands = {leg: pools[leg][n_pool:] for leg in LEGS}
        pools = {leg: pools[leg][:n_pool] for leg in LEGS}
        stats: dict = {}
        if s.kind == "paper":
            selected = pools
        else:
            selected, stats["design"] = self._optimal_selection(pools)
        return self._assemble(seed, selected, verification_cands, rng, stats)

    def information(self, cands: list[FeasibleStance]) -> np.ndarray:
        s = self.settings
        theta = np.concatenate([c.stances(self.parked) for c in cands])
        leg = np.repeat([c.leg for c in cands], [len(c.heads) for c in cands])
        stance = np.repeat(np.arange(len(cands)), [len(c.heads) for c in cands])
        return stance_information(theta, leg, stance, sigma_px=s.sigma_px,
                                  encoder_resolution_rad=np.radians(s.encoder_resolution_deg),
                                  intrinsics=s.intrinsics, registry=self.design_registry,
                                  servo_stiffness_nm_per_rad=s.servo_stiffness_nm_per_rad)

    def _optimal_selection(self, pools):
        s = self.settings
        flat = [c for leg in LEGS for c in pools[leg]]
        infos = self.information(flat)
        n_left = len(pools["L"])
        paper_idx = list(range(s.stances_per_leg)) + list(range(n_left, n_left + s.stances_per_leg))
        reference = infos[paper_idx].sum(axis=0)
        registry = self.design_registry
        order = greedy_d_optimal(infos, len(flat) if s.stances_total is None else s.stances_total)
        counts = matching_count(infos, order, reference, registry)
        reached = reaching_count(infos, order, s.target_worst_std_deg, registry)
        n = s.stances_total or (reached if s.target_worst_std_deg is not None else counts["both"]) or len(order)
        chosen = order[:n]
        total = infos[chosen].sum(axis=0)
        design = {
            "pool_stances": len(flat),
            "paper_stances": len(paper_idx),
            "selected_stances": n,
            "stances_to_match_paper": counts,
            "stances_to_reach_target": reached,
            "target_worst_std_deg": s.target_worst_std_deg,
            "paper_log_det": log_det(reference),
            "selected_log_det": log_det(total),
            "paper_predicted_std": dict(zip(registry.names, predicted_std(reference, registry).tolist())),
        }
        selected = {leg: [flat[k] for k in chosen if flat[k].leg == leg] for leg in LEGS}
        log.info("D-optimal design: %d stances match the paper plan's %d (%s)", n, len(paper_idx), counts)
        return selected, design

    def _assemble(self, seed, selected, verification_cands, rng, stats) -> Plan:
        s = self.settings
        steps: list = []
        image = 0
        position = self.parked.copy()
        all_stills: list[Still] = []
        unreachable = 0
        for leg in LEGS:
            cands = selected[leg]
            order = self.tour(cands, position)
            block_start = position
            reachable = []
            for k in order:  # every move must have a clear way (direct or a detour), else leave the stance out
                first = cands[k].stances(self.parked)[0]
                try:
                    self.paths.waypoints(position, first, s.speed_fraction, self.parked)
                except SafetyError:
                    unreachable += 1
                    log.warning("plan: no clear way to a stance of leg %s: left out", leg)
                    continue
                reachable.append(k)
                position = cands[k].stances(self.parked)[-1]
            position = block_start
            for stance, k in enumerate(reachable):
                cand = cands[k]
                heads = cand.heads[np.argsort(cand.heads[:, 0])]
                if stance % 2:
                    heads = heads[::-1]  # alternate the head's sweep direction: both approach directions
                for h, head in enumerate(heads):
                    q14 = with_leg(self.parked, leg, cand.q_leg)
                    q14[HEAD_COLUMNS] = head
                    step = Still(image, leg, stance, h, tuple(float(a) for a in q14))
                    steps.append(step)
                    all_stills.append(step)
                    image += 1
                    position = q14
            if s.probe and reachable:
                sweep = None
                for k in list(reversed(reachable))[:8]:  # prefer the last stances: the robot is near them
                    sweep = self.probe_sweep(cands[k], cands[k].heads[0], rng, tries=16)
                    if sweep is not None:
                        break
                if sweep is None:
                    log.warning("no visible sweep found for the lag probe of leg %s: probe left out", leg)
                else:
                    images = tuple(range(image, image + s.probe_images_per_leg))
                    fractions = tuple(np.linspace(0.3, 0.7, s.probe_images_per_leg).tolist())
                    steps.append(Sweep(images, leg, len(reachable), tuple(map(float, sweep[0])), tuple(map(float, sweep[1])),
                                       s.probe_speed_fraction, fractions))
                    image += len(images)
                    position = sweep[1]
            position = self._park_leg(position, leg)
        if s.top_stances_per_leg > 0:
            image, position = self._top_steps(seed, steps, image, position)
        verification = []
        for leg in LEGS:
            for k, cand in enumerate(verification_cands[leg]):
                q14 = cand.stances(self.parked)[len(cand.heads) // 2]
                verification.append(Still(len(verification), leg, k, 0, tuple(float(a) for a in q14)))
        stats["unreachable_stances_left_out"] = unreachable
        plan = Plan(seed, s.kind, asdict(s), steps, verification, tuple(float(a) for a in self.parked), stats)
        plan.stats.update(self.describe(plan))
        return plan

    def _top_steps(self, seed, steps, image, position):
        """Append the top camera's stills (after everything else: the offsets are known by then); its own random
        stream, so the bottom camera's plan of a seed stays what it was."""
        s = self.settings
        rng = np.random.default_rng([seed, 4099])
        for leg in LEGS:
            stance = 1 + max((st.stance for st in steps if st.leg == leg), default=-1)
            for cand in self.top_candidates(leg, rng, s.top_stances_per_leg):
                first = cand.stances(self.parked)[0]
                try:
                    self.paths.waypoints(position, first, s.speed_fraction, self.parked)
                except SafetyError:
                    log.warning("plan: no clear way to a top-camera stance of leg %s: left out", leg)
                    continue
                for h, q14 in enumerate(cand.stances(self.parked)):
                    steps.append(Still(image, leg, stance, h, tuple(float(a) for a in q14), camera="top"))
                    image += 1
                    position = q14
                stance += 1
            position = self._park_leg(position, leg)
        return image, position

    def _park_leg(self, position, leg):
        return with_leg(position, leg, self.parked[LEG_COLUMNS[leg]])

    # --- what a plan is worth -------------------------------------------------------------------------------
    def describe(self, plan: Plan, *, overhead_per_capture_s=None) -> dict:
        """Plan statistics: captures, stances, predicted parameter precision, approach-direction balance, gravity
        torque ranges and an estimate of the robot time (motion at speed_fraction plus a fixed overhead per
        capture for settling and the image delay)."""
        stills = [st for st in plan.stills() if st.camera == "bottom"]  # the design's model is the bottom camera's
        theta = np.array([st.angles() for st in stills])
        leg = np.array([st.leg for st in stills])
        stance = np.array([st.stance for st in stills])
        s = self.settings
        registry = self.design_registry
        info = stance_information(theta, leg, stance, sigma_px=s.sigma_px,
                                  encoder_resolution_rad=np.radians(s.encoder_resolution_deg), intrinsics=s.intrinsics,
                                  registry=registry, servo_stiffness_nm_per_rad=s.servo_stiffness_nm_per_rad)
        total = info.sum(axis=0)
        std = predicted_std(total, registry)
        balance, torque_range = {}, {}
        for lg in LEGS:
            rows = theta[leg == lg]
            legs_only = rows[:, LEG_COLUMNS[lg]]
            seq = legs_only[np.r_[True, np.any(np.diff(legs_only, axis=0) != 0, axis=1)]]
            if len(seq) > 1:
                signs = np.sign(np.diff(seq, axis=0))
                for j, name in enumerate(leg_joints(lg)):
                    balance[name] = float(np.mean(signs[:, j]))
                tau = gravity_torques(seq, lg)
                for j, name in enumerate(leg_joints(lg)):
                    torque_range[name] = [float(tau[:, j].min()), float(tau[:, j].max())]
        return {
            "n_images": plan.n_images(),
            "n_still_images": len(plan.stills()),
            "n_top_camera_images": sum(st.camera == "top" for st in plan.stills()),
            "n_stances": {lg: int(len(set(stance[leg == lg]))) for lg in LEGS},
            "n_probe_images": sum(len(sw.images) for sw in plan.sweeps()),
            "predicted_std": {name: float(v) for name, v in zip(registry.names, std)},
            "predicted_worst_joint_offset_std_deg": float(np.degrees(max(std[registry.index[f"joint_offset.{j}"]]
                                                                        for j in LEG_JOINTS))),
            "log_det_information": log_det(total),
            "approach_direction_mean": balance,
            "gravity_torque_range_nm": torque_range,
            "estimated_robot_time_s": self.estimate_robot_time_s(plan, overhead_per_capture_s),
        }

    def estimate_robot_time_s(self, plan: Plan, overhead_per_capture_s=None) -> float:
        if overhead_per_capture_s is None:
            overhead_per_capture_s = self.settings.capture_overhead_s
        position = plan.parked()
        total = 0.0
        for step in plan.steps:
            if isinstance(step, Still):
                total += self.move_time_s(position, step.angles()) + overhead_per_capture_s
                position = step.angles()
            else:
                total += self.move_time_s(position, step.start()) + overhead_per_capture_s
                total += self.move_time_s(step.start(), step.end(), step.speed_fraction) + overhead_per_capture_s
                position = step.end()
        return float(total)


def make_plan(seed: int, settings: PlanSettings = PlanSettings(), *, limits=None, speeds=None) -> Plan:
    """The plan for `seed` (see the module docstring). Deterministic: same seed and settings, same plan."""
    planner = Planner(settings, limits=limits, speeds=speeds)
    try:
        return planner.make_plan(seed)
    finally:
        planner.close()
