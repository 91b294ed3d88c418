"""Camera rotation (the paper's Eq. 3): each camera turned in its mount by roll, pitch and yaw.

    T_base_cam = T_base_cam(q) @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw)       (in the NAO camera frame)

`camera.<camera>.<roll|pitch|yaw>` are the values as they are (corrections, as B-Human's cameraRotationCorrections);
kept in the head's section of the offsets file: heads and bodies get swapped between robots.
"""

import math

import numpy as np

from naocal.solver.effect import CameraTerm, Effect, Parameter
from naocal.solver.effects._common import per_name_section, read_per_name_section
from naocal.solver.transforms import d_rot_x, d_rot_y, d_rot_z, rot_x, rot_y, rot_z

ANGLES = ("roll", "pitch", "yaw")


class CameraRotation(Effect):
    name = "camera_rotation"
    order = 1
    base = True
    summary = "rotation of each camera in its mount: roll, pitch, yaw"
    plausible_limit = math.radians(15.0)
    offsets_section, offsets_key = "head", "camera_rotation_rad"
    offsets_limit = math.radians(15.0)

    def parameters(self, setup):
        return [Parameter(f"camera.{cam}.{a}", self.name, "rad", 0.01, camera=cam, component=a)
                for cam in setup.cameras for a in ANGLES]

    def camera_terms(self, layout, values):
        terms = []
        for cam in layout.cameras:
            index = {p.component: i for i, p in layout.params(self.name) if p.camera == cam}
            if not index:
                continue
            roll, pitch, yaw = (values[index[a]] if a in index else 0.0 for a in ANGLES)
            Ry, Rx, Rz = rot_y(pitch), rot_x(roll), rot_z(yaw)
            R_off = Ry @ Rx @ Rz
            # p_cam = R_off^T p_cam0, so dp = dR^T R_off p_cam: a rotation with w = vee(dR^T R_off).
            generators = []
            for angle, dR in (("pitch", d_rot_y(pitch) @ Rx @ Rz), ("roll", Ry @ d_rot_x(roll) @ Rz),
                              ("yaw", Ry @ Rx @ d_rot_z(yaw))):
                if angle in index:
                    G = dR.T @ R_off
                    generators.append((index[angle], np.array([G[2, 1], G[0, 2], G[1, 0]])))
            terms.append(CameraTerm(cam, rotation=R_off, rotation_params=generators))
        return terms

    def write_offsets(self, values, setup):
        return per_name_section(values, self.parameters(setup), lambda p: p.camera)

    def read_offsets(self, content, path, where, robot):
        read_per_name_section(content, path, where, tuple(robot.cameras), ANGLES,
                              dict.fromkeys(ANGLES, self.offsets_limit), dict.fromkeys(ANGLES, "rad"))


EFFECT = CameraRotation()
