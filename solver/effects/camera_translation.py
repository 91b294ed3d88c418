"""Camera translation: each camera sits off its nominal position in the link it is mounted on (the NAO's head) by
(trans_x, trans_y, trans_z).

    T_head_cam = Trans(trans_x, trans_y, trans_z) @ T_head_cam0 @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw)

Teams suspect the V6 heads' camera-to-head transforms (the URDF's are the V5's). `camera.<camera>.trans_<axis>`,
m, in the head frame (x forward, y left, z up); kept in the head's section of the offsets file, beside the
camera's rotation. Seen by the parallax it causes: a board near the camera moves more than a far one.
"""

import numpy as np

from naocal.solver.effect import CameraTerm, Effect, MockPerturbation, Parameter, signed_uniform
from naocal.solver.effects._common import per_name_section, read_per_name_section

AXES = ("trans_x", "trans_y", "trans_z")


class CameraTranslation(Effect):
    name = "camera_translation"
    order = 70
    summary = "position correction (trans_x, trans_y, trans_z) of each camera in the link it is mounted on"
    plausible_limit = 0.01  # m: a camera a centimetre off its mount is a broken head, not a calibration
    offsets_section, offsets_key = "head", "camera_translation_m"
    offsets_limit = 0.03
    mock_size_unit = "m"

    def parameters(self, setup):
        return [Parameter(f"camera.{cam}.{axis}", self.name, "m", 0.002, camera=cam, component=axis)
                for cam in setup.cameras for axis in AXES]

    def camera_terms(self, layout, values):
        terms = []
        for cam in layout.cameras:
            index = {p.component: i for i, p in layout.params(self.name) if p.camera == cam}
            if index:
                shift = np.array([values[index[a]] if a in index else 0.0 for a in AXES])
                terms.append(CameraTerm(cam, translation=shift,
                                        translation_params=[(index[a], np.eye(3)[k]) for k, a in enumerate(AXES)
                                                            if a in index]))
        return terms

    def mock_perturbation(self, rng, size, setup):
        """Each camera's mount off by size * U(0.5, 1) with random sign on each axis of the link it is on."""
        shifts = {cam: signed_uniform(rng, 0.5, 1.0, len(AXES)) * size for cam in setup.cameras}
        record = {cam: {a: float(v) for a, v in zip(AXES, shift)} for cam, shift in shifts.items()}
        return MockPerturbation(camera_translation_m={cam: s.tolist() for cam, s in shifts.items()},
                                record={"camera_translation_m": record})

    def write_offsets(self, values, setup):
        return per_name_section(values, self.parameters(setup), lambda p: p.camera)

    def read_offsets(self, content, path, where, robot):
        read_per_name_section(content, path, where, tuple(robot.cameras), AXES,
                              dict.fromkeys(AXES, self.offsets_limit), dict.fromkeys(AXES, "m"))


EFFECT = CameraTranslation()
