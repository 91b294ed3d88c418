"""Board mount (the paper's Eq. 4): each target's board shifted and turned in the plane of its frame.

    p' = Rot_z(rot_z) @ (p + (trans_x, trans_y, 0))        p a nominal vertex in the frame the target is attached to

For the sandals the frame is the sole (rotation about the ankle's projection, as the paper); for a board on the
floor it is the support sole. `board.<target>.<rot_z|trans_x|trans_y>`, the values as they are.
"""

import math

import numpy as np

from naocal.solver.effect import Effect, Parameter, TargetTerm
from naocal.solver.effects._common import read_per_name_section
from naocal.solver.transforms import rot_z

COMPONENTS = (("rot_z", "rad", 0.01), ("trans_x", "m", 0.002), ("trans_y", "m", 0.002))
FILE_KEYS = {"rot_z": "rot_z_rad", "trans_x": "trans_x_m", "trans_y": "trans_y_m"}


class BoardMountEffect(Effect):
    name = "board_mount"
    order = 2
    base = True
    summary = "each target's board shifted (trans_x, trans_y) and turned (rot_z) in the plane of its frame"
    plausible_limit = 0.03
    offsets_section, offsets_key = "targets", "board_mount"
    limits = {"rot_z_rad": math.radians(15.0), "trans_x_m": 0.03, "trans_y_m": 0.03}

    def parameters(self, setup):
        return [Parameter(f"board.{t}.{name}", self.name, unit, scale, target=t, component=name)
                for t in setup.targets for name, unit, scale in COMPONENTS]

    def target_terms(self, layout, values):
        terms = []
        for t in layout.targets:
            index = {p.component: i for i, p in layout.params(self.name) if p.target == t}
            if not index:
                continue
            rz, tx, ty = (values[index[c]] if c in index else 0.0 for c, _, _ in COMPONENTS)
            R = rot_z(rz)
            params = []
            if "rot_z" in index:  # a turn about the frame's z axis through its origin
                params.append((index["rot_z"], np.zeros(3), np.array([0.0, 0.0, 1.0])))
            for name, axis in (("trans_x", 0), ("trans_y", 1)):
                if name in index:
                    params.append((index[name], R[:, axis].copy(), np.zeros(3)))
            terms.append(TargetTerm(t, R, R @ np.array([tx, ty, 0.0]), params))
        return terms

    def write_offsets(self, values, setup):
        out = {}
        for p in self.parameters(setup):
            if p.name in values:
                out.setdefault(p.target, {})[FILE_KEYS[p.component]] = float(values[p.name])
        return out

    def read_offsets(self, content, path, where, robot):
        keys = tuple(FILE_KEYS.values())
        read_per_name_section(content, path, where, tuple(robot.targets), keys, self.limits,
                              {k: "rad" if k.endswith("_rad") else "m" for k in keys})


EFFECT = BoardMountEffect()
