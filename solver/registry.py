"""The parameter registry: the one place that defines the solver's parameter vector.

Every model term is an *effect* owning named parameters. The base model of the paper (Kastner, Roefer, Laue,
Eq. 2-5) is `joint_offsets` + `camera_rotation` + `board_mount` (21 parameters); the other effects are the
physical terms the diagnostics can add. Parameter values are model values (alpha, beta), never compensation
offsets: the offsets file stores c = -alpha for joints (see docs/CONVENTIONS.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.errors import NaocalError
from solver.joints import HEAD_JOINTS, LEG_JOINTS, LEGS

BASE_EFFECTS = ("joint_offsets", "camera_rotation", "board_mount")
EXTRA_EFFECTS = ("elasticity", "backlash", "link_lengths", "head_offsets", "intrinsics", "distortion", "time_lag")
ALL_EFFECTS = BASE_EFFECTS + EXTRA_EFFECTS
ALLOWED_UNITS = ("rad", "m", "px", "s", "rad/(N m)", "1")


@dataclass(frozen=True)
class Parameter:
    """One scalar model parameter.

    `scale` is its typical size (conditioning of the solver: it works on value / scale).
    `joint` names the joint a joint-level term acts on (q = theta + ... + value * regressor).
    `tied_to` names the parameter whose value this one always takes.
    """

    name: str
    effect: str
    unit: str
    scale: float
    joint: str | None = None
    tied_to: str | None = None


def _effect_parameters(effect: str) -> list[Parameter]:
    if effect == "joint_offsets":
        return [Parameter(f"joint_offset.{j}", effect, "rad", 0.01, joint=j) for j in LEG_JOINTS]
    if effect == "camera_rotation":
        return [Parameter(f"camera.{a}", effect, "rad", 0.01) for a in ("roll", "pitch", "yaw")]
    if effect == "board_mount":
        return [
            Parameter(f"board.{leg}.{name}", effect, unit, scale)
            for leg in LEGS
            for name, unit, scale in (("rot_z", "rad", 0.01), ("trans_x", "m", 0.002), ("trans_y", "m", 0.002))
        ]
    if effect == "elasticity":
        return [Parameter(f"elasticity.{j}", effect, "rad/(N m)", 0.02, joint=j) for j in LEG_JOINTS]
    if effect == "backlash":
        return [Parameter(f"backlash.{j}", effect, "rad", 0.01, joint=j) for j in LEG_JOINTS]
    if effect == "link_lengths":
        return [Parameter(f"link_length.{leg}.{link}", effect, "m", 0.002) for leg in LEGS for link in ("thigh", "tibia")]
    if effect == "head_offsets":
        return [Parameter(f"head_offset.{j}", effect, "rad", 0.01, joint=j) for j in HEAD_JOINTS]
    if effect == "intrinsics":
        return [Parameter(f"intrinsics.{k}", effect, "px", 5.0) for k in ("fx", "fy", "cx", "cy")]
    if effect == "distortion":
        return [Parameter(f"distortion.{k}", effect, "1", 0.05) for k in ("k1", "k2")]
    if effect == "time_lag":
        return [Parameter("time_lag.dt", effect, "s", 0.01)]
    raise NaocalError(f"unknown effect '{effect}' (known: {', '.join(ALL_EFFECTS)})")


def parse_effects(text) -> tuple[str, ...]:
    """'elasticity,backlash' -> ('elasticity', 'backlash'), rejecting unknown and base names clearly."""
    if text is None or text == "":
        return ()
    names = [n.strip() for n in (text.split(",") if isinstance(text, str) else text) if n.strip()]
    for name in names:
        if name not in EXTRA_EFFECTS:
            hint = " (it is part of the base model)" if name in BASE_EFFECTS else ""
            raise NaocalError(f"unknown effect '{name}'{hint}; known effects: {', '.join(EXTRA_EFFECTS)}")
    return tuple(dict.fromkeys(names))


class Registry:
    """Named parameters of the active effects, and the map between the full and the free (solver) vector.

    full vector: one entry per parameter in `names`, in effect order.
    free vector: the parameters the solver moves: not fixed, not tied (a tied parameter follows its source).
    """

    def __init__(self, effects=(), *, tie_hip_yaw_pitch=False, fixed=()):
        self.effects = BASE_EFFECTS + tuple(e for e in effects if e not in BASE_EFFECTS)
        params = [p for effect in self.effects for p in _effect_parameters(effect)]
        if tie_hip_yaw_pitch:
            params = [
                Parameter(p.name, p.effect, p.unit, p.scale, p.joint, tied_to="joint_offset.LHipYawPitch")
                if p.name == "joint_offset.RHipYawPitch" else p
                for p in params
            ]
        self.parameters = tuple(params)
        self.names = tuple(p.name for p in params)
        self.index = {name: i for i, name in enumerate(self.names)}
        self.fixed = set()
        for item in fixed:
            matched = [p.name for p in params if p.name == item or p.effect == item]
            if not matched:
                raise NaocalError(f"cannot fix '{item}': no such parameter or effect in the model")
            self.fixed.update(matched)
        self.free_names = tuple(p.name for p in params if p.name not in self.fixed and p.tied_to is None)
        self.free_index = np.array([self.index[n] for n in self.free_names], dtype=int)
        # full = expand @ free + (values of fixed parameters)
        self.expand = np.zeros((len(self.names), len(self.free_names)))
        free_pos = {n: k for k, n in enumerate(self.free_names)}
        for i, p in enumerate(params):
            source = p.tied_to or p.name
            if source in free_pos and p.name not in self.fixed:
                self.expand[i, free_pos[source]] = 1.0
        self.scales = np.array([p.scale for p in params])

    def __len__(self):
        return len(self.names)

    def with_fixed(self, more) -> "Registry":
        """A copy with more parameters fixed (used to drop unidentifiable ones)."""
        fixed = set(self.fixed) | set(more)
        tie = any(p.tied_to for p in self.parameters)
        return Registry(self.effects, tie_hip_yaw_pitch=tie, fixed=sorted(fixed))

    def zeros(self) -> np.ndarray:
        return np.zeros(len(self.names))

    def pack(self, full: np.ndarray) -> np.ndarray:
        """Free vector from a full vector."""
        return np.asarray(full, dtype=float)[self.free_index]

    def unpack(self, free: np.ndarray, base: np.ndarray | None = None) -> np.ndarray:
        """Full vector from a free vector; fixed parameters keep their value in `base` (default 0)."""
        full = self.expand @ np.asarray(free, dtype=float)
        if base is not None:
            held = self.expand.sum(axis=1) == 0
            full[held] = np.asarray(base, dtype=float)[held]
        return full

    def free_jacobian(self, J_full: np.ndarray) -> np.ndarray:
        """Jacobian with respect to the free vector from the one with respect to the full vector."""
        return J_full @ self.expand

    def as_dict(self, full: np.ndarray) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.names, full)}

    def from_dict(self, values: dict) -> np.ndarray:
        full = self.zeros()
        for name, value in values.items():
            if name in self.index:
                full[self.index[name]] = value
        return full

    def unit(self, name: str) -> str:
        return self.parameters[self.index[name]].unit
