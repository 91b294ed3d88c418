"""The parameter registry: the one place that defines the solver's parameter vector.

Every model term is an *effect* (solver/effects/, one module each) owning named parameters for a setup (the robot
description, the cameras and targets the data use). The base model of the paper (Kastner, Roefer, Laue, Eq. 2-5)
is `joint_offsets` + `camera_rotation` + `board_mount` (21 parameters for the NAO with the bottom camera and two
sandals); the other effects are the physical terms the diagnostics can add. A joint offset parameter
`joint_offset.<J>` is the offset c robot code stores (q_true = theta - c; docs/CONVENTIONS.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from naocal.solver.effect import ALLOWED_UNITS, Parameter, Setup  # noqa: F401 (re-exported: the registry's vocabulary)
from naocal.solver.effects import ALL_EFFECTS, BASE_EFFECTS, EFFECTS, EXTRA_EFFECTS, effect, parse_effect_names  # noqa: F401
from naocal.solver.errors import NaocalError


class Registry:
    """Named parameters of the active effects, and the map between the full and the free (solver) vector.

    full vector: one entry per parameter in `names`, in effect order.
    free vector: the parameters the solver moves: not fixed, not tied (a tied parameter follows its source).

    setup : the robot description and the cameras and targets the parameters are for (default: the NAO's bottom
        camera and both sandals; `Registry.for_data` takes them from the data).
    tie_shared_motors : joints on one motor (the NAO's HipYawPitch pair) take one offset.
    """

    def __init__(self, effects=(), *, setup: Setup | None = None, tie_shared_motors: bool = False,
                 tie_hip_yaw_pitch: bool | None = None, fixed=()):
        if tie_hip_yaw_pitch is not None:  # the NAO's name for tying its shared motor
            tie_shared_motors = tie_hip_yaw_pitch
        self.setup = setup or Setup.default()
        for name in effects:
            effect(name)  # NaocalError for an unknown name
        self.effects = BASE_EFFECTS + tuple(e for e in dict.fromkeys(effects) if e not in BASE_EFFECTS)
        self.tie_shared_motors = bool(tie_shared_motors)
        params = [p for name in self.effects for p in EFFECTS[name].parameters(self.setup)]
        if tie_shared_motors:
            names = {p.name for p in params}
            tied = []
            for p in params:
                source = EFFECTS[p.effect].tie(p, self.setup)
                tied.append(_with_tie(p, source) if source in names else p)
            params = tied
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

    @classmethod
    def for_data(cls, data, effects=(), **kwargs) -> "Registry":
        """The registry for the cameras and targets of `data` (solver.model.ModelData)."""
        return cls(effects, setup=data.setup, **kwargs)

    def __len__(self):
        return len(self.names)

    def extended(self, effects) -> "Registry":
        """A copy with more effects, the same setup, ties and fixed parameters."""
        return Registry(self.effects + tuple(e for e in effects if e not in self.effects), setup=self.setup,
                        tie_shared_motors=self.tie_shared_motors, fixed=sorted(self.fixed))

    def untied(self) -> "Registry":
        """A copy whose shared motors' joints each have their own offset (the same effects and fixed parameters)."""
        return Registry(self.effects, setup=self.setup, tie_shared_motors=False, fixed=sorted(self.fixed))

    def with_fixed(self, more) -> "Registry":
        """A copy with more parameters fixed (used to drop unidentifiable ones)."""
        return Registry(self.effects, setup=self.setup, tie_shared_motors=self.tie_shared_motors,
                        fixed=sorted(set(self.fixed) | set(more)))

    def without(self, effect_name: str) -> "Registry":
        """A copy without one effect (its fixed parameters dropped with it)."""
        kept = tuple(e for e in self.effects if e != effect_name)
        names = {p.name for name in kept for p in EFFECTS[name].parameters(self.setup)}
        return Registry(kept, setup=self.setup, tie_shared_motors=self.tie_shared_motors,
                        fixed=sorted(n for n in self.fixed if n in names))

    def extra_effects(self) -> tuple[str, ...]:
        """The effects beyond the base model."""
        return tuple(e for e in self.effects if e not in BASE_EFFECTS)

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

    def parameter(self, name: str) -> Parameter:
        return self.parameters[self.index[name]]

    def unit(self, name: str) -> str:
        return self.parameters[self.index[name]].unit

    def display(self, name: str, value: float) -> tuple[float, str]:
        """(value, unit) of a parameter for people, as its effect shows it (degrees, mm, ms ...)."""
        p = self.parameter(name)
        return EFFECTS[p.effect].display(p, value)


def _with_tie(p: Parameter, source: str) -> Parameter:
    return dataclasses.replace(p, tied_to=source)
