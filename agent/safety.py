"""The agent's own safety check of every command, before it is sent (the robot or the mock checks again).

A target posture must keep every joint inside the backend's limits with a margin, HeadPitch inside the
HeadPitch-vs-HeadYaw table, and be free of self-collision and ground contact on the nominal body. The way there
is checked too: joints move at their own speeds, so the path is sampled as the robot will take it; a path that
would touch is replaced by a detour through the parked posture.
"""

from __future__ import annotations

import numpy as np

from body.nao_body import BodyGeometry, BoardMount, CollisionChecker, NaoBody
from backends.errors import SafetyError
from solver.joints import JOINT_INDEX, JOINTS
from solver.limits import head_pitch_limits


class SafetyGuard:
    """Checks postures (14 angles, solver.joints.JOINTS order, rad) against limits and collisions.

    limits : {joint: (lower, upper)} as the robot enforces them (the backend's joint_limits()).
    checker : a CollisionChecker on the nominal body, with the margins the agent wants.
    speeds : {joint: max speed rad/s}, to sample paths as the robot moves.
    """

    def __init__(self, limits: dict, checker: CollisionChecker, speeds: dict, *, margin_rad: float = 0.02,
                 head_pitch_margin_rad: float = 0.01, path_step_rad: float = 0.05, random_detours: int = 40,
                 known_offset_margin_m: float = 0.008):
        missing = [j for j in JOINTS if j not in limits]
        if missing:
            raise SafetyError(f"the robot reports no limits for {', '.join(missing)}")
        self.lower = np.array([limits[j][0] for j in JOINTS]) + margin_rad
        self.upper = np.array([limits[j][1] for j in JOINTS]) - margin_rad
        self.checker = checker
        self.speeds = np.array([speeds[j] for j in JOINTS])
        self.head_pitch_margin_rad = head_pitch_margin_rad
        self.path_step_rad = path_step_rad
        self.true_offset = np.zeros(len(JOINTS))  # best estimate of true - commanded angles (alpha), rad
        self._margins_unknown = (checker.margin_m, checker.ground_margin_m)
        self.known_offset_margin_m = known_offset_margin_m
        self.random_detours = random_detours

    def set_true_offset(self, alpha14, *, known: bool | None = None) -> None:
        """Check collisions where the joints truly go: commanded + alpha14 (rad). While the offsets are unknown
        the checker keeps its wide margins; once every leg's are estimated (`known`; by default: alpha14 is not
        all zero), the smaller known_offset_margin_m suffices (the mock itself refuses at 3 mm). One leg's
        offsets do not make the other leg's position known: it may stand degrees away from its command."""
        self.true_offset = np.asarray(alpha14, dtype=float).copy()
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

    def problem(self, q14) -> str | None:
        """Why posture q14 is unsafe, or None."""
        q14 = np.asarray(q14, dtype=float)
        if q14.shape != (len(JOINTS),) or not np.all(np.isfinite(q14)):
            return f"posture must be {len(JOINTS)} finite angles"
        outside = np.flatnonzero((q14 < self.lower) | (q14 > self.upper))
        if len(outside):
            j = outside[0]
            return (f"{JOINTS[j]} = {q14[j]:.4f} rad is outside its limits with margin "
                    f"[{self.lower[j]:.4f}, {self.upper[j]:.4f}]")
        yaw, pitch = q14[JOINT_INDEX["HeadYaw"]], q14[JOINT_INDEX["HeadPitch"]]
        lo, hi = head_pitch_limits(yaw)
        m = self.head_pitch_margin_rad
        if not lo + m <= pitch <= hi - m:
            return f"HeadPitch = {pitch:.4f} rad is outside [{lo + m:.4f}, {hi - m:.4f}] allowed at HeadYaw = {yaw:.4f}"
        true14 = q14 + self.true_offset  # where the joints will truly stand, as far as the agent knows
        if self.checker.is_safe(true14):
            return None
        contacts = self.checker.contacts(true14)
        if contacts:
            c = min(contacts, key=lambda c: c.distance_m)
            return f"collision: {c.link_a} and {c.link_b} {c.distance_m * 1000:.1f} mm apart"
        return None

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
        return all(self.problem(q) is None for q in self.path(start14, target14, speed_fraction))

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
        if self.problem(start14) is not None or self.path_clear(start14, target14, speed_fraction):
            return [target14]
        vias = [v for v in self.detours(start14, target14, detour14) if self.problem(v) is None]
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
