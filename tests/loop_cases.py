"""An independent generator of NAO calibration datasets, and the diagnose -> add -> diagnose loop run on them through
naocal's command line with its defaults (issue 12, "Must show").

Nothing of naocal's model is used to make the data: the kinematics are this file's own chain products over the
URDF's joint origins and axes (read with xml.etree, not solver.urdf), the gravity torques its own sum over every
link below a joint (masses and centres of mass from the URDF, the sandal's 0.1 kg at its centre), the camera its
own pinhole (docs/CONVENTIONS.md: u = cx - fx y / x, v = cy - fy z / x), the encoder its own rounding, and the
files are written as docs/FORMATS.md describes naocal.dataset/2. What is shared with naocal is only the robot's
published geometry (solver/data/nao_v50.urdf) and the documented conventions (offset sign, frames, board layout).

A servo's sensor (the encoder: it reads the true joint angle plus the joint's offset c) stands, for a command cmd:
  'step'      at the encoder step nearest the command (it drives its sensor to the commanded step);
  'anywhere'  anywhere inside that step (uniform): the reading is the step, the truth a quarter step away on average;
  'command'   at the command (a finer inner sensor); the reading is the command's step;
  'load'      at the command plus a steady error proportional to the gravity torque (a P controller's droop); the
              reading sees it (it is the sensor that stands off).
Effects the data may hide (the model names of docs/EFFECTS.md):
  'elasticity'  the joint yields after its sensor: q = sensor - c + C_j tau_j(q), solved at equilibrium;
  'backlash'    q = sensor - c + b_j dir_j, dir_j the side the joint was last driven from;
  'time_lag'    moving captures: the image is taken dt after the joint readings paired with it;
  'axis_tilt'   not a candidate: both knee axes tilted (a bent bracket); no effect of naocal's library models it.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

URDF_PATH = Path(__file__).resolve().parents[1] / "solver" / "data" / "nao_v50.urdf"
STEP_RAD = 2 * math.pi / 4096  # the NAO's 12-bit encoders
JOINTS = ("HeadYaw", "HeadPitch", "LHipYawPitch", "LHipRoll", "LHipPitch", "LKneePitch", "LAnklePitch",
          "LAnkleRoll", "RHipYawPitch", "RHipRoll", "RHipPitch", "RKneePitch", "RAnklePitch", "RAnkleRoll")
LEG_JOINTS = {leg: JOINTS[2:8] if leg == "L" else JOINTS[8:] for leg in "LR"}
SOLE = {"L": "l_sole", "R": "r_sole"}
CAMERA_FRAME = "CameraBottom_frame"
WIDTH_PX, HEIGHT_PX, F_PX, CX_PX, CY_PX = 640, 480, 600.0, 320.0, 240.0  # the dataset's prior, also the truth
GRAVITY = np.array([-9.81, 0.0, 0.0])  # torso frame, the robot on its back
BOARD_MASS_KG, BOARD_CENTRE = 0.1, np.array([0.17, 0.0, 0.0])  # in the sole frame
# the 24 inner vertices of a sandal, vertex row * 6 + col, in the sole frame (docs/CONVENTIONS.md)
VERTICES = np.array([[0.1075 + 0.025 * col, -0.0375 + 0.025 * row, 0.0] for row in range(4) for col in range(6)])


# ----------------------------------------------------------------------------------------- kinematics, own


def _rotation(axis, angle):
    """(N, 3, 3) rotations by `angle` (N,) about the unit `axis` (3,) (Rodrigues)."""
    angle = np.asarray(angle, dtype=float)
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


class Urdf:
    """Joints (parent, child, origin, axis, limits) and link inertials of the URDF, parsed here."""

    def __init__(self, path=URDF_PATH):
        root = ET.parse(path).getroot()
        self.joints, self.parent_joint, self.links = {}, {}, {}
        for j in root.findall("joint"):
            origin = j.find("origin")
            xyz = [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
            rpy = [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
            axis = j.find("axis")
            limit = j.find("limit")
            entry = {"parent": j.find("parent").get("link"), "child": j.find("child").get("link"),
                     "T": np.eye(4), "type": j.get("type"),
                     "axis": np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None else None,
                     "limits": (float(limit.get("lower")), float(limit.get("upper"))) if limit is not None else None}
            entry["T"][:3, :3], entry["T"][:3, 3] = _rpy(*rpy), xyz
            self.joints[j.get("name")] = entry
            self.parent_joint[entry["child"]] = j.get("name")
        for link in root.findall("link"):
            inertial = link.find("inertial")
            if inertial is not None:
                com = inertial.find("origin").get("xyz", "0 0 0") if inertial.find("origin") is not None else "0 0 0"
                self.links[link.get("name")] = (float(inertial.find("mass").get("value")),
                                                np.array([float(v) for v in com.split()]))

    def chain(self, tip, base="torso"):
        """Joint names from `base` to the link `tip`."""
        names, link = [], tip
        while link != base:
            name = self.parent_joint[link]
            names.append(name)
            link = self.joints[name]["parent"]
        return names[::-1]

    def descendants(self, link):
        out = [link]
        for j in self.joints.values():
            if j["parent"] == link:
                out += self.descendants(j["child"])
        return out


class Nao:
    """The NAO's forward kinematics, gravity torques and camera, from the URDF (vectorised over N images)."""

    def __init__(self, knee_tilt_rad=0.0):
        self.urdf = Urdf()
        self.knee_tilt_rad = knee_tilt_rad  # the 'axis_tilt' effect: knee axes turned about x

    def axis(self, name):
        a = self.urdf.joints[name]["axis"]
        if name.endswith("KneePitch") and self.knee_tilt_rad:
            a = _rotation([1.0, 0.0, 0.0], [self.knee_tilt_rad])[0] @ a
        return a / np.linalg.norm(a)

    def frames(self, tip, q):
        """{joint: (N, 4, 4) pose of the joint's child link in the torso}, and the tip's pose; q: joint -> (N,)."""
        N = len(next(iter(q.values())))
        T = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
        out = {}
        for name in self.urdf.chain(tip):
            j = self.urdf.joints[name]
            T = T @ j["T"]
            if j["type"] == "revolute":
                R = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
                R[:, :3, :3] = _rotation(self.axis(name), q[name])
                T = T @ R
            out[name] = T
        return out, T

    def gravity_torques(self, leg, q):
        """(N, 6) gravity torque about each leg joint (N m): every link below it and the sandal; + turns +q."""
        frames, T_sole = self.frames(SOLE[leg], q)
        N = len(T_sole)
        tau = np.zeros((N, 6))
        board = T_sole[:, :3, :3] @ BOARD_CENTRE + T_sole[:, :3, 3]
        for k, name in enumerate(LEG_JOINTS[leg]):
            T = frames[name]
            origin, axis = T[:, :3, 3], T[:, :3, :3] @ self.axis(name)
            moment = BOARD_MASS_KG * (board - origin)
            for link in self.urdf.descendants(self.urdf.joints[name]["child"]):
                if link not in self.urdf.links:
                    continue
                mass, com = self.urdf.links[link]
                T_link = self._link_pose(link, frames, T_sole)
                moment = moment + mass * (T_link[:, :3, :3] @ com + T_link[:, :3, 3] - origin)
            tau[:, k] = np.einsum("ni,ni->n", axis, np.cross(moment, GRAVITY))
        return tau

    def _link_pose(self, link, frames, T_sole):
        name = self.urdf.parent_joint[link]
        if name in frames:
            return frames[name]
        # a fixed child further down (the sole, sensor frames): its parent's pose and its fixed origin
        return self._link_pose(self.urdf.joints[name]["parent"], frames, T_sole) @ self.urdf.joints[name]["T"]

    def camera(self, q, rpy_rad=(0.0, 0.0, 0.0)):
        """(N, 4, 4) camera pose in the torso; rpy: the camera's roll, pitch, yaw correction (Rot_y Rot_x Rot_z)."""
        _, T = self.frames(CAMERA_FRAME, q)
        roll, pitch, yaw = rpy_rad
        C = np.eye(4)
        C[:3, :3] = (_rotation([0, 1, 0], [pitch])[0] @ _rotation([1, 0, 0], [roll])[0]
                     @ _rotation([0, 0, 1], [yaw])[0])
        return T @ C


def project(T_torso_cam, p_torso):
    """(N, V, 2) pixels and (N, V) depth of points p_torso (N, V, 3) seen by cameras T_torso_cam (N, 4, 4)."""
    R, t = T_torso_cam[:, :3, :3], T_torso_cam[:, :3, 3]
    p = np.einsum("nji,nvj->nvi", R, p_torso - t[:, None, :])  # R^T (p - t)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return np.stack([CX_PX - F_PX * y / x, CY_PX - F_PX * z / x], axis=-1), x


def mount(vertices, rot_z, dx, dy):
    """A sandal put on off its nominal place: turned by rot_z about its centre and shifted (dx, dy) in the sole."""
    c, s = math.cos(rot_z), math.sin(rot_z)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return (vertices - BOARD_CENTRE) @ R.T + BOARD_CENTRE + [dx, dy, 0.0]


# ----------------------------------------------------------------------------------------- the cases


CASES = {  # name -> generator options (every case: 12-bit encoder readings)
    "step": dict(servo="step"),
    "anywhere": dict(servo="anywhere"),
    "command": dict(servo="command"),
    "load": dict(servo="load"),
    "elasticity": dict(servo="step", effects=("elasticity",)),
    "elasticity_anywhere": dict(servo="anywhere", effects=("elasticity",)),
    "backlash": dict(servo="step", effects=("backlash",)),
    "backlash_anywhere": dict(servo="anywhere", effects=("backlash",)),
    "time_lag": dict(servo="step", effects=("time_lag",)),
    "three": dict(servo="step", effects=("elasticity", "backlash", "time_lag")),
    "partial": dict(servo="step", partial=True),
    "noise_0.25": dict(servo="step", pixel_noise_px=0.25),
    "outliers": dict(servo="step", outliers=0.015),
    "partial_outliers": dict(servo="anywhere", partial=True, outliers=0.015, pixel_noise_px=0.25),
    "not_a_candidate": dict(servo="step", effects=("axis_tilt",)),
}
CANDIDATE_EFFECTS = ("elasticity", "backlash", "time_lag")
OFFSET_TOLERANCE_DEG, OFFSET_Z = 0.05, 3.0  # of the generator's effects, those naocal has


def generate(out_dir, seed, *, servo="step", effects=(), pixel_noise_px=0.1, stances_per_leg=16, postures=3,
             moving_per_leg=6, partial=False, outliers=0.0, step_rad=STEP_RAD, lag_s=0.03,
             compliance_rad_per_nm=0.03, backlash_rad=(math.radians(0.1), math.radians(0.2)), droop_rad_per_nm=0.02,
             knee_tilt_rad=math.radians(1.5), offset_rad=math.radians(1.0)):
    """Write a naocal.dataset/2 directory `out_dir`; return the truth: {"c_rad": {joint: c}, "effects": [...], ...}.

    Stances are random leg postures within the joint limits seen from random head postures; with `partial`, a
    stance is kept when at least 10 vertices are in the image and only those are written (else all 24 must be).
    Moving captures (with 'time_lag' only): the leg sweeps at 0.3-1 rad/s per joint; the image is taken `lag_s`
    after the readings paired with it.
    """
    rng = np.random.default_rng(seed)
    nao = Nao(knee_tilt_rad if "axis_tilt" in effects else 0.0)
    c = {j: rng.uniform(-offset_rad, offset_rad) for j in JOINTS}
    c["RHipYawPitch"] = c["LHipYawPitch"]  # one motor
    c["HeadYaw"] = c["HeadPitch"] = 0.0  # head offsets (a candidate of their own) are not among these cases
    camera_rpy = tuple(rng.uniform(-math.radians(3), math.radians(3), 3))
    mounts = {leg: (rng.uniform(-0.02, 0.02), rng.uniform(-0.003, 0.003), rng.uniform(-0.003, 0.003)) for leg in "LR"}
    compliance = {j: compliance_rad_per_nm * rng.uniform(0.5, 1.5) for leg in "LR" for j in LEG_JOINTS[leg]}
    play = {j: rng.uniform(*backlash_rad) for leg in "LR" for j in LEG_JOINTS[leg]}
    # the nominal pose a stance is chosen from; the truth differs by the offsets and effects, which keep it in view
    images = []  # dicts: leg, stance, posture, cmd (14,), velocity (14,)
    for leg in "LR":
        for stance in range(stances_per_leg):
            for cmd in _visible_stance(nao, rng, leg, postures, partial):
                images.append({"leg": leg, "stance": stance, "posture": len([i for i in images if i["leg"] == leg
                               and i["stance"] == stance]), "cmd": cmd, "velocity": np.zeros(len(JOINTS))})
        if "time_lag" in effects:
            for k in range(moving_per_leg):
                cmd = _visible_stance(nao, rng, leg, 1, partial)[0]
                velocity = np.zeros(len(JOINTS))
                cols = [JOINTS.index(j) for j in LEG_JOINTS[leg]]
                velocity[cols] = rng.choice([-1.0, 1.0], 6) * rng.uniform(0.3, 1.0, 6)
                images.append({"leg": leg, "stance": stances_per_leg + k, "posture": 0, "cmd": cmd,
                               "velocity": velocity})
    M = len(images)
    cmd = np.array([i["cmd"] for i in images])
    velocity = np.array([i["velocity"] for i in images])
    moving = np.any(velocity != 0, axis=1)
    legs = np.array([i["leg"] for i in images])
    step_of = lambda a: np.round(a / step_rad) * step_rad  # noqa: E731 (the encoder)
    # where each servo's sensor stands (sensor = true + c), and what it reads
    if servo == "step":
        sensor = step_of(cmd)
    elif servo == "anywhere":
        sensor = step_of(cmd) + rng.uniform(-0.5, 0.5, cmd.shape) * step_rad
    elif servo == "command":
        sensor = cmd.copy()
    elif servo == "load":
        sensor = cmd.copy()
        for leg in "LR":
            rows = legs == leg
            cols = [JOINTS.index(j) for j in LEG_JOINTS[leg]]
            q = {j: cmd[rows, JOINTS.index(j)] - c[j] for j in JOINTS}
            sensor[np.ix_(rows, cols)] += droop_rad_per_nm * nao.gravity_torques(leg, q)
    else:
        raise ValueError(servo)
    sensor[moving] = cmd[moving]  # a sweep: the command is where the sensor is at the reading
    reading = step_of(sensor)
    if servo in ("anywhere", "command"):
        reading = step_of(cmd)
        reading[moving] = step_of(sensor[moving])
    direction = rng.choice([-1.0, 1.0], size=cmd.shape)
    direction[moving] = np.sign(velocity[moving])
    true = sensor - np.array([c[j] for j in JOINTS])
    if "backlash" in effects:
        for j, b in play.items():
            true[:, JOINTS.index(j)] += b * direction[:, JOINTS.index(j)]
    if "time_lag" in effects:
        true[moving] += velocity[moving] * lag_s
    if "elasticity" in effects:
        for leg in "LR":
            rows = legs == leg
            cols = [JOINTS.index(j) for j in LEG_JOINTS[leg]]
            C = np.array([compliance[j] for j in LEG_JOINTS[leg]])
            base = true[np.ix_(rows, cols)].copy()
            for _ in range(50):  # q = q0 + C tau(q): a contraction (C dtau/dq << 1)
                q = {j: true[rows, JOINTS.index(j)] for j in JOINTS}
                true[np.ix_(rows, cols)] = base + C * nao.gravity_torques(leg, q)
    q_all = {j: true[:, k] for k, j in enumerate(JOINTS)}
    T_cam = nao.camera(q_all, camera_rpy)
    uv = np.zeros((M, 24, 2))
    for leg in "LR":
        rows = legs == leg
        T_sole = nao.frames(SOLE[leg], {j: v[rows] for j, v in q_all.items()})[1]
        p = np.einsum("nij,vj->nvi", T_sole[:, :3, :3], mount(VERTICES, *mounts[leg])) + T_sole[:, None, :3, 3]
        uv[rows] = project(T_cam[rows], p)[0]
    uv += rng.normal(0.0, pixel_noise_px, uv.shape)
    keep = np.ones((M, 24), bool)
    margin = 5.0
    keep &= (uv[..., 0] > margin) & (uv[..., 0] < WIDTH_PX - 1 - margin)
    keep &= (uv[..., 1] > margin) & (uv[..., 1] < HEIGHT_PX - 1 - margin)
    if outliers:  # a corner found a square off or on a reflection: 3-20 px away
        bad = rng.random((M, 24)) < outliers
        angle = rng.uniform(0, 2 * np.pi, bad.sum())
        uv[bad] += rng.uniform(3.0, 20.0, bad.sum())[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    _write(out_dir, images, reading.astype(np.float32).astype(float), cmd, direction, velocity, uv, keep,
           f"tests/loop_cases.py seed {seed}")
    truth = {"c_rad": c, "camera_rpy_rad": camera_rpy, "effects": sorted(e for e in effects
                                                                       if e in CANDIDATE_EFFECTS),
             "hidden": list(effects), "servo": servo, "pixel_noise_px": pixel_noise_px,
             "n_images": M, "n_partial": int(np.sum(keep.sum(axis=1) < 24)), "n_vertices": int(keep.sum())}
    if "elasticity" in effects:
        truth["compliance_rad_per_nm"] = compliance
    if "backlash" in effects:
        truth["backlash_rad"] = play
    if "time_lag" in effects:
        truth["lag_s"] = lag_s
    return truth


def _visible_stance(nao, rng, leg, postures, partial, max_tries=5000):
    """`postures` commands (14,) of one random leg stance, each from a head posture that sees the sandal."""
    lower = np.array([nao.urdf.joints[j]["limits"][0] for j in LEG_JOINTS[leg]]) + 0.05
    upper = np.array([nao.urdf.joints[j]["limits"][1] for j in LEG_JOINTS[leg]]) - 0.05
    cols = [JOINTS.index(j) for j in LEG_JOINTS[leg]]
    need = 10 if partial else 24
    margin = 0.0 if partial else 25.0
    for _ in range(max_tries):
        cmd = np.zeros((64, len(JOINTS)))
        cmd[:, cols] = rng.uniform(lower, upper)
        if leg == "R":  # one motor: the other HipYawPitch stands at the same angle
            cmd[:, JOINTS.index("LHipYawPitch")] = cmd[:, JOINTS.index("RHipYawPitch")]
        else:
            cmd[:, JOINTS.index("RHipYawPitch")] = cmd[:, JOINTS.index("LHipYawPitch")]
        cmd[:, 0] = rng.uniform(-0.5, 0.5, 64)
        cmd[:, 1] = rng.uniform(0.1, 0.48, 64)
        q = {j: cmd[:, k] for k, j in enumerate(JOINTS)}
        T_sole = nao.frames(SOLE[leg], q)[1]
        p = np.einsum("nij,vj->nvi", T_sole[:, :3, :3], VERTICES) + T_sole[:, None, :3, 3]
        uv, depth = project(nao.camera(q), p)
        inside = ((depth > 0.05) & (uv[..., 0] > margin) & (uv[..., 0] < WIDTH_PX - 1 - margin)
                  & (uv[..., 1] > margin) & (uv[..., 1] < HEIGHT_PX - 1 - margin))
        normal = T_sole[:, :3, 2]
        facing = np.einsum("ni,ni->n", normal, p.mean(axis=1) - nao.camera(q)[:, :3, 3]) < 0
        ok = np.flatnonzero(facing & (inside.sum(axis=1) >= need) & np.all(depth > 0.05, axis=1))
        if partial:  # prefer boards cut by the image border
            ok = np.concatenate([ok[inside[ok].sum(axis=1) < 24], ok[inside[ok].sum(axis=1) == 24]])
        if len(ok) >= postures:
            return cmd[ok[:postures]]
    raise RuntimeError(f"no visible stance of leg {leg} in {max_tries} tries")


def _write(out_dir, images, reading, cmd, direction, velocity, uv, keep, source):
    """naocal.dataset/2 (docs/FORMATS.md): dataset.json and observations.csv."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"schema": "naocal.dataset/2", "robot": {"id": "loop-cases", "model": "NAO H25 V6", "description": "nao"},
            "cameras": {"bottom": {"width_px": WIDTH_PX, "height_px": HEIGHT_PX, "fx_px": F_PX, "fy_px": F_PX,
                                   "cx_px": CX_PX, "cy_px": CY_PX, "distortion": [0.0] * 5}},
            "targets": {leg: {"columns": 7, "rows": 5, "square_m": 0.025, "mass_kg": BOARD_MASS_KG,
                              "centre_m": BOARD_CENTRE.tolist()} for leg in "LR"},
            "joints": list(JOINTS), "source": source, "gravity_mps2": GRAVITY.tolist()}
    (out / "dataset.json").write_text(json.dumps(meta, indent=1) + "\n")
    moving = bool(np.any(velocity != 0))
    header = ["image", "camera", "target", "stance", "head_posture", "vertex", "u_px", "v_px", "x_mount_m",
              "y_mount_m", "z_mount_m", "t_image_s", "t_joints_s"]
    header += [p + j for j in JOINTS for p in ("", "cmd_", "dir_") + (("vel_",) if moving else ())]
    with open(out / "observations.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for m, image in enumerate(images):
            t = 2.0 * m + 1.0
            joint_cells = []
            for k in range(len(JOINTS)):
                joint_cells += [repr(float(reading[m, k])), repr(float(cmd[m, k])), int(direction[m, k])]
                if moving:
                    joint_cells.append(repr(float(velocity[m, k])))
            for v in np.flatnonzero(keep[m]):
                w.writerow([m, "bottom", image["leg"], image["stance"], image["posture"], int(v),
                            f"{uv[m, v, 0]:.4f}", f"{uv[m, v, 1]:.4f}", *VERTICES[v].tolist(), t, t] + joint_cells)


# ----------------------------------------------------------------------------------------- the loop


def naocal_json(*args) -> dict:
    """Run a naocal verb in this process (its command line: tools.cli.main) with --json; its output."""
    from naocal.tools.cli import main

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        code = main([*map(str, args), "--json"])
    assert code == 0, (args, code, buffer.getvalue()[-2000:])
    return json.loads(buffer.getvalue())


def run_loop(dataset, max_steps=4):
    """diagnose -> add the verdict's effect -> diagnose ..., with naocal's defaults; the steps' diagnose outputs.

    The effect added is the one the verdict names: the best significant candidate of plausible size.
    """
    effects, steps = [], []
    for _ in range(max_steps + 1):
        out = naocal_json("diagnose", dataset, *(["--effects", ",".join(effects)] if effects else []))
        steps.append(out)
        named = out["verdict"]["add"]
        if named is None:
            break
        effects.append(named)
    return steps


def loop_summary(steps, truth) -> dict:
    """What the loop did, against the truth: effects named, final RMS and noise, worst offset error and its z."""
    final = steps[-1]
    named = list(final["effects"])
    errors = []
    for joint, entry in final["joint_offsets_c"].items():
        if joint in truth["c_rad"] and entry.get("std_rad"):
            error = entry["c_rad"] - truth["c_rad"][joint]
            errors.append((joint, math.degrees(abs(error)), abs(error) / entry["std_rad"],
                           math.degrees(entry["std_rad"])))
    worst = max(errors, key=lambda e: e[1])
    worst_z = max(errors, key=lambda e: e[2])
    # a joint passes when within 0.05 deg of the truth, or honestly within 3 of its std
    failing = [e[0] for e in errors if e[1] > OFFSET_TOLERANCE_DEG and e[2] > OFFSET_Z]
    return {"named": named, "rms_px": final["rms_total_px"], "noise_px": final["noise_px"],
            "ratio": final["ratio_to_noise"], "pixel_noise_px": truth["pixel_noise_px"],
            "angles": final["angles"]["chosen"], "worst_error_deg": worst[1], "worst_joint": worst[0],
            "worst_std_deg": worst[3], "worst_z": worst_z[2], "n_outliers": len(final["outliers"]),
            "first_rms_px": steps[0]["rms_total_px"], "offsets_failing": failing}
