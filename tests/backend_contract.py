"""Contract every Backend implementation passes (the mock, the bridge client, the NAOqi driver).

Call `check_backend_contract(backend)` from a test of that implementation. It moves only within a small
safe range around the backend's current posture.
"""

import numpy as np
import pytest

from naocal.backends.base import Backend, CameraImage, CameraIntrinsics, JointReading
from naocal.solver.errors import SafetyError
from naocal.solver.joints import JOINTS


def check_backend_contract(backend: Backend, *, settle_s: float = 2.0, tolerance_rad: float = 0.02) -> None:
    identity = backend.robot_identity()
    for key in ("id", "model", "body_id", "head_id"):
        assert isinstance(identity.get(key), str), f"robot_identity()[{key!r}] must be a str"

    names = tuple(backend.joint_names())
    assert set(JOINTS) <= set(names)
    limits = backend.joint_limits()
    speeds = backend.max_speeds()
    for joint in JOINTS:
        lower, upper = limits[joint]
        assert np.isfinite(lower) and np.isfinite(upper) and lower < upper, joint
        assert speeds[joint] > 0, joint

    intrinsics = backend.intrinsics()
    assert isinstance(intrinsics, CameraIntrinsics)
    assert intrinsics.width_px == 640 and intrinsics.height_px == 480
    assert 400 < intrinsics.fx_px < 900 and 400 < intrinsics.fy_px < 900

    t0 = backend.now()
    backend.sleep(0.05)
    assert backend.now() >= t0 + 0.05 - 1e-6, "sleep must let at least the asked time pass"

    first = backend.read_joints()
    assert isinstance(first, JointReading)
    assert set(JOINTS) <= set(first.angles_rad)
    assert all(np.isfinite(first.angles_rad[j]) for j in JOINTS)
    backend.sleep(0.05)
    second = backend.read_joints()
    assert second.t_s > first.t_s, "joint samples must carry increasing timestamps"
    assert second.t_s <= backend.now() + 1e-6

    # A small move of the head yaw, inside its limits, then back.
    start = second.angles_rad["HeadYaw"]
    target = float(np.clip(start + 0.1, limits["HeadYaw"][0] + 0.05, limits["HeadYaw"][1] - 0.05))
    backend.set_stiffness(list(JOINTS), 1.0)
    backend.command({"HeadYaw": target}, 0.3)
    backend.sleep(settle_s)
    reached = backend.read_joints().angles_rad["HeadYaw"]
    assert abs(reached - target) < tolerance_rad, f"HeadYaw went to {reached}, commanded {target}"
    backend.command({"HeadYaw": start}, 0.3)
    backend.sleep(settle_s)

    lower, upper = limits["LKneePitch"]
    with pytest.raises(SafetyError):
        backend.command({"LKneePitch": upper + 0.5}, 0.1)
    with pytest.raises(SafetyError):
        backend.command({"LKneePitch": float("nan")}, 0.1)
    with pytest.raises(SafetyError):
        backend.command({"NoSuchJoint": 0.0}, 0.1)

    image = None
    deadline = backend.now() + 2.0
    while image is None and backend.now() < deadline:
        image = backend.capture()
        if image is None:
            backend.sleep(0.02)
    assert isinstance(image, CameraImage), "no image within 2 s"
    assert image.pixels.shape == (intrinsics.height_px, intrinsics.width_px, 3)
    assert image.pixels.dtype == np.uint8
    assert image.t_exposure_s <= backend.now() + 1e-6, "an image cannot arrive before it is exposed"

    backend.close()
    backend.close()  # idempotent
