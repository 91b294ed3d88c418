"""Link lengths: a link longer than the URDF says, by delta along its own direction.

    the origin of the joint at the link's end moves by delta along the link (its origin offset's direction)

The robot description names the links (`link_lengths`: label -> the joint at the link's end): the NAO's thigh
(hip to knee) and tibia (knee to ankle) of each leg, `link_length.L.thigh` etc. An arm (kinds.arm.model.ArmModel) has
one per joint origin (and chain tip) with an offset, named by the URDF link it ends: `link_length.panda_link4`.
"""

import numpy as np

from naocal.solver import fields
from naocal.solver.effect import ChainTerm, Effect, MockPerturbation, Parameter, signed_uniform


def _links(setup):
    """(label, joint) of the description's links on the chains in use, in the description's order."""
    on_chains = set(setup.target_joints()) | set(setup.camera_joints())
    return [(label, joint) for label, joint in setup.robot.link_lengths.items() if joint in on_chains]


class LinkLengths(Effect):
    name = "link_lengths"
    order = 30
    summary = "length error of the links the robot description names (the NAO's thigh and tibia per leg)"
    plausible_limit = 0.01  # m
    offsets_section, offsets_key = "body", "link_lengths_m"
    offsets_limit = 0.03
    mock_size_unit, mock_stream = "m", 3
    prior_size = {"m": 2e-3}  # a machined link is off by millimetres
    gauge_priority = 2

    def parameters(self, setup):
        return [Parameter(f"link_length.{label}", self.name, "m", 0.002, joint=joint, component=label)
                for label, joint in _links(setup)]

    def arm_parameters(self, arm):
        """Along each origin's offset (arm.directions; none where the origin has no offset)."""
        return [Parameter(f"link_length.{name}", self.name, "m", arm.scale,
                          joint=key[1] if key[0] == "joint" else None, component=name, index=o)
                for o, (name, key, direction) in enumerate(zip(arm.origin_names, arm.origin_keys, arm.directions))
                if direction is not None]

    def chain_terms(self, layout, values):
        terms = []
        for i, p in layout.params(self.name):
            for frame, chain in layout.chains_in_use():
                k = layout.origin_of(p, frame)  # an arm's chain: len(joint_names) is its tip's offset (T_end)
                if k is not None:
                    offset = chain.T_origin[k][:3, 3] if k < len(chain.joint_names) else chain.T_end[:3, 3]
                    terms.append(ChainTerm(i, frame, k, float(values[i]), offset / np.linalg.norm(offset)))
        return terms

    def partial_residual_panels(self, fit):
        from naocal.solver.diagnostics import apparent_errors, partial_residuals

        data = fit.model.data
        panels = []
        for p in fit.registry.parameters:
            if p.effect != self.name:
                continue
            error = apparent_errors(fit, [p.name], partial_residuals(fit, [p.name]))[:, 0]
            ok = np.isfinite(error)
            angle = data.theta[:, data.column(p.joint)]
            if ok.any():
                xs = np.array([angle[ok].min(), angle[ok].max()])
                panels.append((angle[ok], error[ok] * 1e3, f"{p.joint} angle (rad)", f"apparent {p.component} (mm)",
                               data.target[ok], (xs, np.full(2, fit.value(p.name) * 1e3))))
        return panels

    def mock_perturbation(self, rng, size, setup):
        """Each named link longer by size * U(0.5, 1) with random sign (the mock's body is built with them)."""
        # Drawn by kind, then side (the NAO's thighs, then tibias): the order the mock always drew them in.
        labels = sorted((label for label, _ in _links(setup)), key=lambda s: (s.rpartition(".")[2], s))
        deltas = {label: float(d) for label, d in zip(labels, signed_uniform(rng, 0.5, 1.0, len(labels)) * size)}
        record = {}
        for label, delta in deltas.items():
            side, _, kind = label.rpartition(".")
            record.setdefault(f"{kind}_delta_m", {})[side] = delta
        return MockPerturbation(link_deltas_m=deltas, record=record)

    def write_offsets(self, values, setup):
        return {p.component: float(values[p.name]) for p in self.parameters(setup) if p.name in values}

    def read_offsets(self, content, path, where, robot):
        fields.json_object(content, path, where, optional=tuple(robot.link_lengths))
        for label, value in content.items():
            fields.number(value, path, f"{where}.{label}", limit=self.offsets_limit, unit="m")


EFFECT = LinkLengths()
