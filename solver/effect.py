"""What an effect is: one model term with everything naocal knows about it, in one module of solver/effects/.

An effect owns
- its parameters (`parameters(setup)`: names, units, scales, ties) for a setup (robot description, cameras and
  targets in use);
- its model term and exact Jacobian, through one or more of the model's five hook points (solver/model.py):
    joint_terms       q = theta + value * regressor, per image and joint column (offsets, play, lag, elasticity);
    chain_terms       a joint origin of a chain moved along a direction (link lengths);
    camera_terms      the camera's pose in its parent link: rotation (camera frame) and translation (parent frame);
    target_terms      the target's vertices moved in the frame the target is attached to (board mount);
    projection_terms  a camera's intrinsic components (focal lengths, principal point, distortion);
  each hook returns plain descriptions of the term (below); the model composes them and differentiates exactly;
  a differential drive's model (wheel speeds from duties, the ground motion from wheel speeds) takes its terms by
  `drive_parameters`: the quantities that model has a term for (dead zone, slip, wheel lag, ...), with their
  scales and start values;
- its diagnostics: plausible size, why it cannot be tested on some data, what to do when the data do not excite it,
  and the partial-residual view of the report (`partial_residual_panels`);
- its display (unit shown to people) and its section of the offsets file (`offsets_section`, `offsets_key`,
  `write_offsets`, `read_offsets`);
- its mock injection (`mock_perturbation`): what a simulated robot with the effect of a given size has, described
  as plain data (`MockPerturbation`) that backends/mock.py applies to its body, servos and camera.
Adding an effect is adding one module with an `EFFECT = SomeEffect()` in solver/effects/: it is discovered there.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import numpy as np


ALLOWED_UNITS = ("rad", "m", "px", "s", "rad/(N m)", "s/m", "1")
# A pose error's six components (an arm's Parameter.axis): along x, y, z, then about x, y, z.
POSE_COMPONENTS = (("x", "m"), ("y", "m"), ("z", "m"), ("rx", "rad"), ("ry", "rad"), ("rz", "rad"))
SECTIONS = ("body", "head", "targets")


@dataclass(frozen=True)
class Parameter:
    """One scalar model parameter.

    `scale` is its typical size (conditioning of the solver: it works on value / scale).
    `joint`, `camera`, `target` name what the parameter belongs to (None if nothing); `component` says which of
    its effect's quantities it is (e.g. 'pitch', 'fx', 'trans_x', 'L.thigh').
    `tied_to` names the parameter whose value this one always takes.
    `start` is where a fit starts it: 0, the model without the effect, unless the effect's signature vanishes there
    (a wheel lag's: Effect.drive_parameters).
    An arm's parameter (kinds.arm.model.ArmModel) that belongs to no joint says which of the arm's things it belongs to
    by `index` (the joint origin, chain, point or sensor number) and `axis` (0-2: along x, y, z; 3-5: about x, y,
    z; POSE_COMPONENTS).
    """

    name: str
    effect: str
    unit: str
    scale: float
    joint: str | None = None
    tied_to: str | None = None
    camera: str | None = None
    target: str | None = None
    component: str | None = None
    index: int | None = None
    axis: int | None = None
    start: float = 0.0


@dataclass(frozen=True)
class Setup:
    """What a model is made for: a robot description and the cameras and targets the data use."""

    robot: object  # solver.robot.RobotDescription
    cameras: tuple
    targets: tuple

    @classmethod
    def default(cls, robot=None) -> "Setup":
        """The robot's default cameras and targets (the NAO: the bottom camera and both sandals)."""
        from naocal.solver.robot import nao

        robot = robot or nao()
        return cls(robot, tuple(robot.default_cameras), tuple(robot.default_targets))

    @classmethod
    def everything(cls, robot=None) -> "Setup":
        """Every camera and every target of the robot: the names any file of this robot may hold."""
        from naocal.solver.robot import nao

        robot = robot or nao()
        return cls(robot, tuple(robot.cameras), tuple(robot.targets))

    def target_joints(self) -> tuple[str, ...]:
        """Joints of the chains to the targets, in the description's joint order, without the cameras' joints:
        the body joints whose offsets the base model identifies (the NAO's 12 leg joints)."""
        on_targets = {j for t in self.targets for j in self.robot.target_chain(t).joint_names}
        return tuple(j for j in self.robot.joints if j in on_targets and j not in self.camera_joints())

    def camera_joints(self) -> tuple[str, ...]:
        """Joints of the chains to the cameras (the NAO's HeadYaw and HeadPitch), in the description's order."""
        on_cameras = {j for c in self.cameras for j in self.robot.camera_chain(c).joint_names}
        return tuple(j for j in self.robot.joints if j in on_cameras)

    def __eq__(self, other):
        return (isinstance(other, Setup) and self.robot is other.robot and self.cameras == other.cameras
                and self.targets == other.targets)

    def __hash__(self):
        return hash((id(self.robot), self.cameras, self.targets))


# ------------------------------------------------------------------------------------------- hook results


@dataclass
class JointTerm:
    """q[:, column] += value(param) * regressor (M,). `gravity`: the regressor is the joint's gravity torque at the
    model's own angles (elasticity: the model solves q = q0 + C tau(q) and differentiates it implicitly)."""

    param: int
    column: int
    regressor: np.ndarray
    gravity: bool = False


@dataclass
class ChainTerm:
    """The origin of joint `joint` (index in the chain) of the chain to `frame` moves by `delta` along the unit
    `direction` (in the frame before that joint), carrying everything after it (an arm's chain: `joint` n, the
    number of its joints, is its tip's offset)."""

    param: int
    frame: str  # the chain's tip link (a target's or a camera's frame)
    joint: int
    delta: float
    direction: np.ndarray


@dataclass
class CameraTerm:
    """A change of one camera's pose in the link it is mounted on: T_parent_cam = Trans(translation) @
    T_parent_cam0 @ rotation. Each rotation parameter moves points as a rotation with generator `w` (3,) in the
    camera frame (dp_cam = w x p_cam per unit of the parameter); each translation parameter moves the camera along
    a unit vector (3,) of the parent frame."""

    camera: str
    rotation: np.ndarray | None = None  # (3, 3)
    rotation_params: list = field(default_factory=list)  # [(param, w (3,))]
    translation: np.ndarray | None = None  # (3,) m, in the parent link's frame
    translation_params: list = field(default_factory=list)  # [(param, unit (3,))]


@dataclass
class TargetTerm:
    """The target's vertices p (in its frame) become R p + t. Each parameter moves them by a twist in that frame:
    dp = v + w x p per unit of the parameter, given as (param, v (3,), w (3,))."""

    target: str
    R: np.ndarray
    t: np.ndarray
    params: list = field(default_factory=list)


@dataclass
class ProjectionTerm:
    """value(param) added to one intrinsic component (solver.camera.COMPONENTS) of one camera."""

    param: int
    camera: str
    component: str
    value: float


@dataclass
class MockPerturbation:
    """What a simulated robot with an effect has, in the mock's physical terms (backends/mock.py applies every
    field; docs/MOCK.md). SI units; the mock's own sign for joint offsets (alpha = -c: q_true = servo + alpha).
    Effects combine by adding (each draws from its own random stream)."""

    alpha_rad: dict = field(default_factory=dict)  # joint -> encoder offset: q_true = servo + alpha
    compliance_rad_per_nm: dict = field(default_factory=dict)  # joint -> q_true += C * tau(q_true)
    half_play_rad: dict = field(default_factory=dict)  # joint -> q_true += b * (direction of the last command)
    link_deltas_m: dict = field(default_factory=dict)  # robot description link label ('L.thigh') -> longer by
    intrinsics_px: dict = field(default_factory=dict)  # 'fx', 'fy', 'cx', 'cy' -> added to the cameras' true value
    distortion: dict = field(default_factory=dict)  # 'k1' -> the cameras' true radial distortion
    camera_translation_m: dict = field(default_factory=dict)  # camera -> (3,) mount moved by, in its parent link
    image_stamp_late_s: float = 0.0  # images stamped this much later than their exposure
    record: dict = field(default_factory=dict)  # what the effect drew, for truth_effects.json (plain JSON)


def signed_uniform(rng, low: float, high: float, size=None):
    """Random sign times U(low, high): the mock's draw of an error of unknown sign."""
    return rng.choice([-1.0, 1.0], size=size) * rng.uniform(low, high, size=size)


# ------------------------------------------------------------------------------------------- display


# How a value in an SI unit is shown to people: (shown unit, factor).
DISPLAY_UNITS = {
    "rad": ("deg", math.degrees(1.0)),
    "rad/(N m)": ("deg/(N m)", math.degrees(1.0)),
    "m": ("mm", 1e3),
    "s": ("ms", 1e3),
    "s/m": ("s/m", 1.0),
    "px": ("px", 1.0),
    "1": ("", 1.0),
}


def shown(value: float, unit: str) -> tuple[float, str]:
    """(value, unit) for people: degrees for angles, mm for lengths, ms for times."""
    label, factor = DISPLAY_UNITS.get(unit, (unit, 1.0))
    return value * factor, label


# ------------------------------------------------------------------------------------------- the effect


class Effect:
    """Base class: an effect that does nothing. Subclasses set the attributes and override the hooks they use."""

    name: str = ""
    order: int = 100  # position among the effects (registry order, tables)
    base: bool = False  # part of the paper's base model
    summary: str = ""  # one line for --help and docs
    plausible_limit: float = math.inf  # |value| beyond it (SI) a candidate is probably standing in for something else
    plausible_min: float = -math.inf  # the smallest value that is physics (SI; a play or a compliance is never < 0)
    plausible_min_why: str = ""  # why, for people ("a compliance is never negative")
    non_rigid: bool = False  # it changes the projection, not the targets' poses: the noise floor removes it
    reading_offsets: bool = False  # its parameters are offsets of the joints' readings (d r / d theta_j = -d r / dc)
    uses_velocity: bool = False  # it models captures taken while the joints move (solver.fit fits them only then)
    no_signal_hint: str = "its parameters do not change any prediction"
    # The offsets file: the section and key its values go to (None: only in model.parameters).
    offsets_section: str | None = None
    offsets_key: str | None = None
    offsets_limit: float = math.inf  # largest |value| a file may hold (SI); beyond it: damaged file or unit mix-up
    # The mock: the unit of `--effect NAME=SIZE` (None: the mock does not simulate this effect), and the number of
    # its random stream (None: one derived from the name; the older effects keep the numbers they had).
    mock_size_unit: str | None = None
    mock_stream: int | None = None
    # The arm (kinds.arm.model.ArmModel, kinds.arm.identify): the plausible size per unit, the std of the Gaussian prior
    # about the URDF's value (every correction 0; none: anywhere, a sensor's frame); the order of the gauges (of
    # parameters the data cannot tell apart, the lower priority's stay free, the later are fixed: also the order of
    # the arm's parameters); in every arm's model whatever the effects chosen (the sensors' frames).
    prior_size: dict = {}
    gauge_priority: int = 100
    arm_always: bool = False
    # Whether the arm's identifiability check may fix a parameter of it at its start value as a gauge (what the
    # data cannot tell it from, parameters kept before it take): not a sensor's frame (it may be anywhere), not
    # what is unknown until measured (a print's scale: its start is the typed size). What such a parameter leaves
    # undetermined stops the fit, naming the parameter and `undetermined_hint` ({name}: the parameter) to fix it.
    arm_gauge: bool = True
    undetermined_hint: str = ""
    # A differential drive's model: a term fitted from the fit without it (its start values that fit's; from the
    # detections' start a wheel lag went below 0, where it has no gradient, and stayed).
    drive_from_base_fit: bool = False

    @property
    def mock_size_min(self) -> float:
        """The smallest `--effect NAME=SIZE` the mock takes: the smallest value that is physics."""
        return self.plausible_min

    # -- parameters

    def parameters(self, setup: Setup) -> list[Parameter]:
        return []

    def arm_parameters(self, arm) -> list[Parameter]:
        """The effect's parameters for an arm (kinds.arm.model.ArmModel, its layout made: joint_names, prismatic,
        origin_keys, origin_names, directions, arm_chains, point_names, sensors), each of the arm's `scale` (the
        arm's solver works in mm and mrad); an effect that defines none is not one of the arm's."""
        return []

    def arm_prior_size(self, parameter: Parameter, arm) -> float:
        """The std of the Gaussian prior of one of the effect's arm parameters about the URDF's (the filed) value:
        `prior_size` of its unit (0: none), unless the effect's size depends on the parameter (a focal length's
        error is relative to it)."""
        return self.prior_size.get(parameter.unit, 0.0)

    def drive_parameters(self) -> list[Parameter]:
        """The effect's parameters of a differential drive's model, each with its scale (the solver works on
        value / scale) and `start`; the drive model's term for each is keyed by the parameter's `component`. An
        effect that defines this hook is a term of that model even without a parameter: a choice of model (a PWM
        driver between the duties and the motors)."""
        return []

    def tie(self, parameter: Parameter, setup: Setup) -> str | None:
        """The parameter this one always takes the value of when shared motors are tied (None: not tied)."""
        return None

    # -- model hooks (layout: solver.model.Layout; values: the full parameter vector)

    def joint_terms(self, layout) -> list[JointTerm]:
        return []

    def chain_terms(self, layout, values) -> list[ChainTerm]:
        return []

    def camera_terms(self, layout, values) -> list[CameraTerm]:
        return []

    def target_terms(self, layout, values) -> list[TargetTerm]:
        return []

    def projection_terms(self, layout, values) -> list[ProjectionTerm]:
        return []

    # -- diagnostics

    def implausibility(self, value: float, std: float = 0.0, z: float = 3.0) -> str:
        """Why a fitted value (SI) of one of this effect's parameters is not physics, '' when it may be: below
        plausible_min, or beyond plausible_limit, by more than z of its standard deviations (a weakly determined
        value may stray that far by chance)."""
        std = std if math.isfinite(std) else 0.0
        if value + z * std < self.plausible_min:
            return f"implausible: below {self.plausible_min:g}" + (f" ({self.plausible_min_why})"
                                                                   if self.plausible_min_why else "")
        if abs(value) - z * std > self.plausible_limit:
            params = self.parameters(Setup.default())
            limit, unit = self.display(params[0], self.plausible_limit) if params else (self.plausible_limit, "")
            return f"implausible: beyond +-{limit:.3g} {unit}".rstrip()
        return ""

    def untestable_reason(self, data) -> str:
        """Why the effect cannot be tested (or fitted) on these data ('' if it can)."""
        return ""

    def partial_residual_panels(self, fit) -> list:
        """The report's picture of a fit that has this effect: [(x, y, xlabel, ylabel, group of each point,
        (line x, line y))], the partial residuals (what the effect explains plus what nothing explains) against
        the effect's regressor, with the fitted term as a line. [] when the effect has no such picture."""
        return []

    # -- display

    def display(self, parameter: Parameter, value: float) -> tuple[float, str]:
        """(value, unit) of a parameter value for people."""
        return shown(value, parameter.unit)

    # -- offsets file

    def write_offsets(self, values: dict, setup: Setup) -> dict:
        """The content of this effect's key in its offsets section, from {parameter name: value} of its
        parameters (only those present). Default: {component-or-joint-or-camera: value}."""
        return {}

    def read_offsets(self, content, path, where: str, robot) -> None:
        """Validate the content of this effect's key of a file; DataError naming the field otherwise."""

    # -- the mock

    def mock_perturbation(self, rng, size: float, setup: Setup) -> MockPerturbation:
        """What a simulated robot with this effect of `size` (in `mock_size_unit`) has, drawn from `rng` (the
        effect's own stream): a pure description; the mock applies it through its physics (PyBullet masses, servo
        tracks, the rendered cameras). `setup`: the robot description and the cameras and targets it simulates."""
        raise NotImplementedError(f"{self.name}: the mock does not simulate this effect")

    def mock_stream_id(self) -> int:
        """The number of this effect's random stream in the mock (seeded [seed, number])."""
        return self.mock_stream if self.mock_stream is not None else zlib.crc32(self.name.encode()) & 0x7FFFFFFF
