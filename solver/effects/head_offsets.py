"""Head offsets: the encoder offset c of each joint on the chains to the cameras (the NAO's HeadYaw, HeadPitch).

    q_true = theta - c

Nearly, but not exactly, what the camera rotation already explains: the joints turn the camera about their own
axes, which pass through the neck, not the camera. Stored with the other joint offsets (the body's).
"""

import math

import numpy as np

from naocal.solver.effect import Effect, JointTerm, MockPerturbation, signed_uniform
from naocal.solver.effects._common import apparent_offset_panels, joint_section, per_joint, read_joint_section


class HeadOffsets(Effect):
    name = "head_offsets"
    order = 40
    summary = "encoder offset c of each joint on the chains to the cameras (HeadYaw, HeadPitch)"
    reading_offsets = True
    plausible_limit = math.radians(6.0)
    offsets_section, offsets_key = "body", "joint_offsets_rad"
    offsets_limit = math.radians(10.0)
    mock_size_unit, mock_stream = "rad", 4

    def parameters(self, setup):
        return per_joint(self, "head_offset", setup.camera_joints(), "rad", 0.01)

    def tie(self, parameter, setup):
        partner = setup.robot.motor_partner(parameter.joint)
        return f"head_offset.{partner}" if partner else None

    def joint_terms(self, layout):
        minus_one = -np.ones(layout.n_images)
        return [JointTerm(i, layout.column(p.joint), minus_one) for i, p in layout.params(self.name)]

    def partial_residual_panels(self, fit):
        data = fit.model.data
        joints = [p.joint for p in self.parameters(fit.registry.setup)]
        return apparent_offset_panels(fit, "head_offset", joints, lambda c: data.theta[:, c],
                                      lambda j: f"{j} angle (rad)", slope_from_value=False)

    def mock_perturbation(self, rng, size, setup):
        """An encoder offset of size * U(0.5, 1) with random sign on each joint of the chains to the cameras."""
        joints = setup.camera_joints()
        alpha = {j: float(a) for j, a in zip(joints, signed_uniform(rng, 0.5, 1.0, len(joints)) * size)}
        return MockPerturbation(alpha_rad=alpha, record={"alpha_rad": alpha})

    def write_offsets(self, values, setup):
        return joint_section(self, values, setup)

    def read_offsets(self, content, path, where, robot):
        read_joint_section(self, content, path, where, robot, "rad")


EFFECT = HeadOffsets()
