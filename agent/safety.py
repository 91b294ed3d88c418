"""The agent's own safety check of every command, before it is sent (the robot or the mock checks again).

A target posture must keep every joint inside the backend's limits with a margin, HeadPitch inside the
HeadPitch-vs-HeadYaw table, and be free of self-collision and ground contact on the nominal body. The way there
is checked too: joints move at their own speeds, so the path is sampled as the robot will take it; a path that
would touch is replaced by a detour through the parked posture.

Where the joints truly stand is uncertain until the offsets are estimated, and real robots' offsets are large
(HipYawPitch up to about 12 deg, centimetres at the foot). The guard therefore checks what it does not know: with a
covariance of the joint offsets (`set_true_offset`: plausible bounds read as 3 standard deviations before a fit,
the fit's own covariance after), every pair of parts must keep its margin 3 standard deviations of its distance
away, to first order (distance - 3 sqrt(g' C g), g the distance's gradient with respect to the joint angles) and,
at the offsets first order names the worst, exactly.
"""

from __future__ import annotations

import numpy as np

from naocal.body.nao_body import BodyGeometry, BoardMount, CollisionChecker, NaoBody
from naocal.solver.errors import SafetyError
from naocal.solver.joints import JOINT_INDEX, JOINTS
from naocal.solver.limits import command_limits, head_pitch_problem


REACH_M = 0.5  # farther than any part of the robot from a leg joint's axis (a leg with its sandal: about 0.45 m)
N_SIGMA = 3.0
SLACK_M = 0.004  # displacement (3 sigma) the plain check's margins absorb: 8 mm margins against the robot's own 3 mm
KNOWN_OFFSET_MARGIN_M = 0.008  # every pair's margin where the joints truly stand (the mock refuses at 3 mm); the
# planner's stances keep it for any plausible offsets (agent.planner.Planner.robust_ok)


def worst_case_clearance(checker: CollisionChecker, q14, covariance14) -> tuple[float, str]:
    """(smallest clearance beyond the margins, m, and the pair it concerns) at posture q14, three standard
    deviations of each pair's distance away: distance - 3 sqrt(g' C g) - margin, C the covariance (14, 14) of the
    joint offsets (rad^2) and g the distance's gradient with respect to the joint angles (closest points and joint
    axes, CollisionChecker.distance_gradients). Then each of the two most critical pairs is checked exactly at the
    offsets first order names its worst, 3 C g / sqrt(g' C g) away (distances are not linear over degrees).
    Negative: some plausible offset may bring a pair inside its margin."""
    q14 = np.asarray(q14, dtype=float)
    C = np.asarray(covariance14, dtype=float)
    joints = np.flatnonzero(np.diag(C) > 0)
    if not len(joints):
        return float("inf"), ""
    C = C[np.ix_(joints, joints)]
    # No point of the robot lies more than REACH_M from a joint axis: pairs farther apart than the margin plus what
    # 3 sigma of the offsets may move both parts cannot come within the margin.
    reach = N_SIGMA * REACH_M * np.sqrt(np.sum(np.abs(C)))
    query = max(checker.margin_m, checker.ground_margin_m) + 2.0 * reach + 0.005
    pairs, d0, grads = checker.distance_gradients(q14, query, [[j] for j in joints])
    if not pairs:
        return query, ""
    Cg = C @ grads  # (J, P)
    sigma = np.sqrt(np.maximum(np.einsum("jp,jp->p", grads, Cg), 0.0))
    margins = np.array([checker.margin_for(p) for p in pairs])
    linear = d0 - N_SIGMA * sigma - margins
    worst = float(np.min(linear))
    worst_pair = pairs[int(np.argmin(linear))]
    for i in np.argsort(linear)[:2]:  # check the first-order worst offsets exactly
        q = q14.copy()
        q[joints] -= N_SIGMA * Cg[:, i] / max(sigma[i], 1e-12)
        exact = checker.distances(q, query + 0.1, [pairs[i]]).get(pairs[i], query + 0.1) - margins[i]
        if exact < worst:
            worst, worst_pair = exact, pairs[i]
    return worst, f"{worst_pair[0]} and {worst_pair[1]}"


def prior_covariance(hip_yaw_pitch_rad: float, leg_rad: float, *, unknown_legs=("L", "R"),
                     hip_yaw_pitch_unknown: bool = True) -> np.ndarray:
    """(14, 14) covariance of the joint offsets before they are estimated, the plausible sizes read as 3 standard
    deviations: leg_rad for the joints of the `unknown_legs`, hip_yaw_pitch_rad for the one HipYawPitch motor while
    it is unknown (both joints move together: fully correlated), nothing for the head (the camera rotation takes the
    head's errors)."""
    C = np.zeros((len(JOINTS), len(JOINTS)))
    for leg in unknown_legs:
        for joint in ("HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll"):
            C[JOINT_INDEX[leg + joint], JOINT_INDEX[leg + joint]] = (leg_rad / N_SIGMA) ** 2
    if hip_yaw_pitch_unknown:
        hyp = [JOINT_INDEX["LHipYawPitch"], JOINT_INDEX["RHipYawPitch"]]
        C[np.ix_(hyp, hyp)] = (hip_yaw_pitch_rad / N_SIGMA) ** 2
    return C


class SafetyGuard:
    """Checks postures (14 angles, solver.joints.JOINTS order, rad) against limits and collisions.

    limits : {joint: (lower, upper)} as the robot enforces them (the backend's joint_limits()).
    checker : a CollisionChecker on the nominal body, with the margins the agent wants.
    speeds : {joint: max speed rad/s}, to sample paths as the robot moves.
    """

    def __init__(self, limits: dict, checker: CollisionChecker, speeds: dict, *, margin_rad: float = 0.02,
                 head_pitch_margin_rad: float = 0.01, path_step_rad: float = 0.05, random_detours: int = 40,
                 known_offset_margin_m: float = KNOWN_OFFSET_MARGIN_M):
        missing = [j for j in JOINTS if j not in limits]
        if missing:
            raise SafetyError(f"the robot reports no limits for {', '.join(missing)}")
        # the robot's limits with a margin, and never beyond the range the agent commands a joint in (HeadYaw)
        narrow = command_limits()
        self.lower = np.maximum(np.array([limits[j][0] for j in JOINTS]) + margin_rad,
                                [narrow.get(j, (-np.inf, np.inf))[0] for j in JOINTS])
        self.upper = np.minimum(np.array([limits[j][1] for j in JOINTS]) - margin_rad,
                                [narrow.get(j, (-np.inf, np.inf))[1] for j in JOINTS])
        self.checker = checker
        self.speeds = np.array([speeds[j] for j in JOINTS])
        self.head_pitch_margin_rad = head_pitch_margin_rad
        self.path_step_rad = path_step_rad
        self.true_offset = np.zeros(len(JOINTS))  # best estimate of true - commanded angles (alpha), rad
        self.covariance = np.zeros((len(JOINTS), len(JOINTS)))  # of alpha around that estimate, rad^2
        self._uncertain = False
        self._margins_unknown = (checker.margin_m, checker.ground_margin_m)
        self.known_offset_margin_m = known_offset_margin_m
        self.random_detours = random_detours

    def set_true_offset(self, alpha14, *, known: bool | None = None, covariance14=None) -> None:
        """Check collisions where the joints truly go: commanded + alpha14 (rad). While the offsets are unknown
        the checker keeps its wide margins; once every leg's are estimated (`known`; by default: alpha14 is not
        all zero), the smaller known_offset_margin_m suffices (the mock itself refuses at 3 mm). One leg's
        offsets do not make the other leg's position known: it may stand degrees away from its command.
        `covariance14` (14, 14) rad^2, default 0: how uncertain alpha14 is; while 3 standard deviations of it may
        move a part by more than SLACK_M, every posture must also keep the known-offset margins 3 standard
        deviations away (module docstring)."""
        self.true_offset = np.asarray(alpha14, dtype=float).copy()
        self.covariance = (np.zeros((len(JOINTS), len(JOINTS))) if covariance14 is None
                           else np.asarray(covariance14, dtype=float).copy())
        self._uncertain = bool(N_SIGMA * REACH_M * np.sqrt(np.sum(np.abs(self.covariance))) > SLACK_M)
        known = bool(np.any(self.true_offset)) if known is None else bool(known)
        margin = self.known_offset_margin_m
        self.checker.margin_m, self.checker.ground_margin_m = (
            (min(margin, self._margins_unknown[0]), min(margin, self._margins_unknown[1])) if known
            else self._margins_unknown)

    def set_board_mounts(self, mounts: dict, *, tolerance_m: float = 0.0005) -> bool:
        """Check against sandals mounted as estimated: {leg: (rot_z rad, trans_x m, trans_y m)} (Eq. 4). A sandal
        turned by a degree moves its far end by several millimetres, as much as the margins. Rebuilds the checker's
        body (about half a second) only when a mount moved by more than `tolerance_m` (0.2 m lever for rot_z).
        Returns whether it rebuilt."""
        current = getattr(self, "_mounts", {leg: (0.0, 0.0, 0.0) for leg in ("L", "R")})
        change = max(max(abs(a - b) * (0.2 if k == 0 else 1.0) for k, (a, b) in enumerate(zip(mounts[leg], current[leg])))
                     for leg in ("L", "R"))
        if change <= tolerance_m:
            return False
        body = NaoBody(BodyGeometry(board_mount={leg: BoardMount(*map(float, mounts[leg])) for leg in ("L", "R")}))
        old = self.checker
        self.checker = CollisionChecker(body, margin_m=old.margin_m, ground_margin_m=old.ground_margin_m)
        if getattr(self, "_owned_body", None) is not None:
            self._owned_body.close()
        self._owned_body = body
        self._mounts = {leg: tuple(map(float, mounts[leg])) for leg in ("L", "R")}
        return True

    def close(self) -> None:
        """Release a body this guard built itself (set_board_mounts)."""
        if getattr(self, "_owned_body", None) is not None:
            self._owned_body.close()
            self._owned_body = None

    def problem(self, q14, *, tolerate_m: float = 0.0) -> str | None:
        """Why posture q14 is unsafe, or None. `tolerate_m`: how far the worst case over the offsets' uncertainty
        may fall short of the margins (a path may not get closer to a possible collision than where it starts)."""
        q14 = np.asarray(q14, dtype=float)
        if q14.shape != (len(JOINTS),) or not np.all(np.isfinite(q14)):
            return f"posture must be {len(JOINTS)} finite angles"
        outside = np.flatnonzero((q14 < self.lower) | (q14 > self.upper))
        if len(outside):
            j = outside[0]
            return (f"{JOINTS[j]} = {q14[j]:.4f} rad is outside its limits with margin "
                    f"[{self.lower[j]:.4f}, {self.upper[j]:.4f}]")
        head = head_pitch_problem(q14[JOINT_INDEX["HeadYaw"]], q14[JOINT_INDEX["HeadPitch"]],
                                  margin_rad=self.head_pitch_margin_rad)
        if head is not None:
            return f"{head} with margin"
        true14 = q14 + self.true_offset  # where the joints will truly stand, as far as the agent knows
        if not self.checker.is_safe(true14):
            contacts = self.checker.contacts(true14)
            if contacts:
                c = min(contacts, key=lambda c: c.distance_m)
                if c.distance_m < 0:
                    return f"collision: {c.link_a} and {c.link_b} overlap by {-c.distance_m * 1000:.1f} mm"
                margin = self.checker.ground_margin_m if c.link_b == "ground" else self.checker.margin_m
                return (f"{c.link_a} and {c.link_b} closer than the {margin * 1000:g} mm margin "
                        f"({c.distance_m * 1000:.1f} mm)")
        if self.uncertain():
            clearance, pair = self.worst_case(q14)
            if clearance < -tolerate_m:
                worst_deg = np.degrees(N_SIGMA * np.sqrt(np.max(np.diag(self.covariance))))
                return (f"collision possible: {pair} within {self.known_offset_margin_m * 1000:.0f} mm for an "
                        f"offset within 3 standard deviations (up to {worst_deg:.1f} deg; short by "
                        f"{-clearance * 1000:.1f} mm)")
        return None

    def uncertain(self) -> bool:
        """Whether the offsets are uncertain enough for the worst-case check (3 sigma may move a part > SLACK_M)."""
        return self._uncertain

    def worst_case(self, q14) -> tuple[float, str]:
        """worst_case_clearance of commanded posture q14 (at the known-offset margins), cached per posture."""
        key = (tuple(np.round(np.asarray(q14, dtype=float), 9)), tuple(self.true_offset),
               tuple(self.covariance.ravel()), id(self.checker))
        cache = self.__dict__.setdefault("_worst_cache", {})
        if key not in cache:
            saved = self.checker.margin_m, self.checker.ground_margin_m
            m = self.known_offset_margin_m
            self.checker.margin_m, self.checker.ground_margin_m = min(m, saved[0]), min(m, saved[1])
            try:
                cache[key] = worst_case_clearance(self.checker, np.asarray(q14, dtype=float) + self.true_offset,
                                                  self.covariance)
            finally:
                self.checker.margin_m, self.checker.ground_margin_m = saved
            if len(cache) > 4096:
                cache.pop(next(iter(cache)))
        return cache[key]

    def plain_problem(self, q14) -> str | None:
        """problem() without the worst case over the uncertainty: limits and collisions at commanded + alpha."""
        saved = self._uncertain
        self._uncertain = False
        try:
            return self.problem(q14)
        finally:
            self._uncertain = saved

    def check(self, q14) -> None:
        """Raise SafetyError if posture q14 is unsafe."""
        why = self.problem(q14)
        if why is not None:
            raise SafetyError(f"refusing to command an unsafe posture: {why}")

    def path(self, start14, target14, speed_fraction: float) -> np.ndarray:
        """Postures the robot may pass through from start to target (target included), one per path_step_rad of
        the largest joint motion (at most 40 per motion model).

        Two motion models, so that a path is clear whichever the robot uses: every joint at speed_fraction of its
        own maximum speed (NAOqi's setAngles: joints arrive at different times), and all joints arriving together
        (a straight line in joint space).
        """
        start14, target14 = np.asarray(start14, dtype=float), np.asarray(target14, dtype=float)
        delta = target14 - start14
        duration = np.abs(delta) / (self.speeds * speed_fraction)
        t_end = float(np.max(duration))
        if t_end == 0.0:
            return target14[None]
        n = int(np.clip(np.ceil(np.max(np.abs(delta)) / self.path_step_rad), 2, 40))
        fractions = np.linspace(1.0 / n, 1.0, n)
        progress = np.clip(fractions[:, None] * t_end / np.maximum(duration, 1e-12), 0.0, 1.0)
        own_speeds = start14 + progress * delta
        straight = start14 + fractions[:, None] * delta
        return np.vstack([own_speeds, straight])

    def path_clear(self, start14, target14, speed_fraction: float) -> bool:
        """Every posture on the way is safe; while the offsets are uncertain, none comes closer to a possible
        collision than the start (where the robot stands, or will) already is."""
        path = self.path(start14, target14, speed_fraction)
        if not self.uncertain():
            return all(self.problem(q) is None for q in path)
        if any(self.plain_problem(q) is not None for q in path):  # the cheap check first
            return False
        tolerate = max(0.0, -self.worst_case(start14)[0]) + 1e-3
        return all(self.worst_case(q)[0] >= -tolerate for q in path)

    @staticmethod
    def _lifted(q14, legs, d_hip, d_knee, d_roll) -> np.ndarray:
        v = np.array(q14, dtype=float)
        for leg in legs:
            outward = 1.0 if leg == "L" else -1.0
            v[JOINT_INDEX[leg + "HipPitch"]] += d_hip
            v[JOINT_INDEX[leg + "KneePitch"]] += d_knee
            v[JOINT_INDEX[leg + "HipRoll"]] += outward * d_roll
        return v

    def detours(self, start14, target14, detour14) -> list[np.ndarray]:
        """Candidate via-postures, in a fixed order: the detour posture with the head where it is, the detour
        posture itself, then the start, the midpoint and the target with the moving legs lifted or spread, then
        random postures near the way (deterministic)."""
        start14, target14 = np.asarray(start14, dtype=float), np.asarray(target14, dtype=float)
        head = [JOINT_INDEX["HeadYaw"], JOINT_INDEX["HeadPitch"]]
        legs_parked = np.asarray(detour14, dtype=float).copy()
        legs_parked[head] = start14[head]
        vias = [legs_parked, np.asarray(detour14, dtype=float)]
        moving = [leg for leg in ("L", "R") if np.any(np.abs(
            (target14 - start14)[[JOINT_INDEX[leg + s] for s in ("HipRoll", "HipPitch", "KneePitch")]]) > 1e-9)]
        lifts = ((-0.2, 0.3, 0.0), (-0.4, 0.6, 0.0), (0.0, 0.0, 0.15), (-0.3, 0.4, 0.15))
        for base in ((start14 + target14) / 2.0, start14, target14, legs_parked):
            for lift in lifts:
                vias.append(self._lifted(base, moving or ["L", "R"], *lift))
        # Then random postures along the way with the moving legs perturbed; the generator is seeded by the
        # move itself, so the same move always gets the same detour.
        key = np.round(np.concatenate([start14, target14]) * 1e4).astype(np.int64)
        rng = np.random.default_rng(np.abs(key) % (2 ** 31))
        cols = [JOINT_INDEX[leg + s] for leg in (moving or ["L", "R"]) for s in
                ("HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")]
        for _ in range(self.random_detours):
            v = start14 + rng.uniform(0.0, 1.0) * (target14 - start14)
            v[cols] += rng.normal(0.0, 0.35, len(cols))
            vias.append(np.clip(v, self.lower, self.upper))
        return vias

    def waypoints(self, start14, target14, speed_fraction: float, detour14) -> list[np.ndarray]:
        """Postures to command in turn to get from start to target safely: [target], [via, target] or
        [via, via, target].

        Raises SafetyError if the target is unsafe or neither the direct path nor any detour is clear. A start
        that is itself in contact (a robot lying at rest touches the ground) is not held against the path.
        """
        target14 = np.asarray(target14, dtype=float)
        self.check(target14)
        if self.plain_problem(start14) is not None or self.path_clear(start14, target14, speed_fraction):
            return [target14]
        vias = self.detours(start14, target14, detour14)
        if self.uncertain():  # worst-case checks are costly: the fixed detours only
            vias = vias[:len(vias) - self.random_detours]
        vias = [v for v in vias if self.plain_problem(v) is None and self.problem(v) is None]
        for via in vias:
            if self.path_clear(start14, via, speed_fraction) and self.path_clear(via, target14, speed_fraction):
                return [via, target14]
        first = [v for v in vias if self.path_clear(start14, v, speed_fraction)]
        last = [v for v in vias if self.path_clear(v, target14, speed_fraction)]
        for a in first:
            for b in last:
                if self.path_clear(a, b, speed_fraction):
                    return [a, b, target14]
        raise SafetyError("no collision-free way to the next posture (direct or through up to two detours)")
