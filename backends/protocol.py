"""The naocal bridge wire protocol (version 1): msgpack maps over ZeroMQ. Specified in docs/PROTOCOL.md.

Request:  {"v": 1, "id": "<client_id>:<seq>", "cmd": str, "args": {...}[, "token": str]}
Reply:    {"v": 1, "id": <the request's id>, "ok": true, "result": ...}
          {"v": 1, "id": <id or None>, "ok": false, "error": {"type": str, "message": str}}

Only msgpack's plain types cross the wire (nil, bool, int, float, str, bin, array, map with str keys): no pickle,
no eval, no msgpack extension types. Arrays travel as raw bytes with an explicit shape and dtype. Argument keys
carry their unit (`targets_rad`, `duration_s`); unknown keys are refused, so a key in the wrong unit never passes.
Motion needs the lease: `acquire` answers the controller alone with a secret token, which every later request
carries (backends/bridge_lease.py). `stop` does not: any client may make the robot safe.

One protocol for every robot kind: the session commands (hello, acquire, release, stop) and each kind's own (COMMANDS,
the NAO's, and each other kind's, registered by the kind: register_kind_commands). A server serves one robot and answers only its kind's commands (UnknownCommand for
the others). `v` versions the framing; PROTOCOL_REVISION counts the commands added since (hello says it, and the
server's kind): adding a kind's commands changes no request or reply an older client sends or reads.
"""

from __future__ import annotations

import contextlib
import math
import re
import threading

import msgpack
import numpy as np

from naocal.backends.base import CameraImage, CameraIntrinsics, JointReading, checked_reading
from naocal.backends.errors import BridgeError
from naocal.solver import fields
from naocal.solver.camera import INTRINSICS_KEYS
from naocal.solver.errors import DataError

PROTOCOL_VERSION = 1
# Commands and hello keys added since version 1, compatibly: 1 = the NAO's commands; 2 = hello's `kind` and
# `revision`, the Duckiebot's commands (kinds/duckiebot/bridge.py); 3 = `stop` for every kind, from any client.
# hello without `revision` is a revision-1 server.
PROTOCOL_REVISION = 3
MAX_REQUEST_BYTES = 1 << 20  # larger requests get a "TooLarge" error reply
ZMQ_MAX_INBOUND_BYTES = 4 << 20  # ZMQ_MAXMSGSIZE of the server socket: libzmq drops the peer beyond this
MAX_REPLY_BYTES = 16 << 20  # ZMQ_MAXMSGSIZE of the client socket (a VGA BGR image is 0.9 MiB)
MAX_SLEEP_S = 60.0  # longest single `sleep` the server accepts
MAX_ERROR_CHARS = 500  # an error reply's message, one line (error_reply cuts it there)
MAX_IMAGE_SIDE_PX = 1 << 16

REQUEST_KEYS = frozenset({"v", "id", "cmd", "args"})
OPTIONAL_REQUEST_KEYS = frozenset({"token"})  # the lease token, on every request of the controller
REQUEST_ID_PATTERN = re.compile(r"^([A-Za-z0-9_.-]{1,64}):([0-9]{1,18})$")
SECRET_PATTERN = re.compile(r"^[A-Za-z0-9_-]{22,128}$")  # tokens and nonces: at least 128 bits in base64url
IMAGE_DTYPES = frozenset({"uint8"})

# Error types on the wire. The client re-raises SafetyError, RobotTimeout and RobotFault as themselves,
# ControlError as ControlError, everything else as BridgeError.
ERROR_TYPES = (
    "ProtocolError",  # not a well-formed request of this protocol
    "UnsupportedVersion",
    "UnknownCommand",
    "TooLarge",
    "StaleRequest",  # a request id older than the replies the server keeps: refused, not executed
    "ControlError",  # no valid lease token: another client controls motion, or this one has not acquired it
    "SafetyError",
    "RobotTimeout",
    "RobotFault",  # the robot sent a reading that cannot be trusted: the driver is in its safe state
    "NaocalError",
    "InternalError",
)


class ProtocolError(BridgeError):
    """A message that does not follow this protocol. `error_type` is the wire error type to answer with."""

    def __init__(self, message: str, error_type: str = "ProtocolError"):
        super().__init__(message)
        self.error_type = error_type


class ControlError(BridgeError):
    """A motion command refused because another client controls the robot."""


@contextlib.contextmanager
def field_checks():
    """Check a message's fields with solver.fields (the one home of the field checks and their message style,
    "WHAT, field 'F': expected ..., got ..."): its refusal raised as a ProtocolError."""
    try:
        yield
    except DataError as err:
        raise ProtocolError(str(err)) from None


# ---------------------------------------------------------------------------------------------- arguments
def finite_or_nan_float(value, key):
    # Non-finite numbers are passed through so the backend refuses them with a SafetyError, like a direct call.
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"args.{key} must be a number, got {type(value).__name__}")
    return float(value)


def _float_map(value, key):
    if not isinstance(value, dict):
        raise ProtocolError(f"args.{key} must be a map of joint name to number, got {type(value).__name__}")
    out = {}
    for name, number in value.items():
        if not isinstance(name, str):
            raise ProtocolError(f"args.{key} keys must be strings")
        out[name] = finite_or_nan_float(number, f"{key}.{name}")
    return out


def _secret(value, key):
    if not isinstance(value, str) or not SECRET_PATTERN.match(value):
        raise ProtocolError(f"{key} must be 22-128 characters of [A-Za-z0-9_-]")
    return value


def _str_list(value, key):
    if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
        raise ProtocolError(f"args.{key} must be an array of strings")
    return list(value)


CAMERA_NAMES = ("bottom", "top")


def _camera_name(value, key):
    if value not in CAMERA_NAMES:
        raise ProtocolError(f"args.{key} must be one of {', '.join(CAMERA_NAMES)}")
    return value


def time_s(value, key):
    with field_checks():
        return fields.number(value, "the request", f"args.{key}")


# Arguments a request may leave out, with the value they then take (requests of clients older than the argument).
OPTIONAL_ARGS = {"capture": {"camera": "bottom"}}

# cmd -> (argument validators, needs the motion lease). Everything not marked is a read without side effects.
COMMANDS = {
    "hello": ({}, False),
    "robot_identity": ({}, False),
    "joint_names": ({}, False),
    "joint_limits": ({}, False),
    "max_speeds": ({}, False),
    "intrinsics": ({}, False),
    "gravity_torso": ({}, False),
    "read_joints": ({}, False),
    "capture": ({"camera": _camera_name}, False),
    "now": ({}, False),
    "status": ({}, False),
    "command": ({"targets_rad": _float_map, "speed_fraction": finite_or_nan_float}, True),
    "set_stiffness": ({"names": _str_list, "stiffness": finite_or_nan_float}, True),
    "sleep": ({"duration_s": finite_or_nan_float}, True),
    "acquire": ({"nonce": _secret}, False),  # -> {"token", "lease_timeout_s"}; ControlError if another holds it
    "release": ({}, False),
    # The stop: the robot's safe state now (the kind's; it moves nothing). Any client may send it, lease or not
    # (CURVE, when on, still admits only its keys): stopping only makes the robot safer.
    "stop": ({}, False),
}
# Each robot kind's commands: kind -> {cmd: (argument validators, needs the lease)}. The NAO's are the protocol's
# first; another kind registers its own table (register_kind_commands) where its served robot and client are
# defined (kinds/<kind>/bridge.py), so the protocol names no other robot.
KIND_COMMANDS = {"nao": COMMANDS}
SESSION_COMMANDS = ("hello", "robot_identity", "now", "sleep", "acquire", "release", "stop")  # every kind's


def register_kind_commands(kind: str, commands: dict) -> dict:
    """Add robot `kind`'s command table (cmd -> (validators, needs the lease)) with the session commands; returns
    it. Registering one kind twice with another table is a programming error."""
    table = {**{cmd: COMMANDS[cmd] for cmd in SESSION_COMMANDS}, **commands}
    if KIND_COMMANDS.setdefault(kind, table) != table:
        raise ValueError(f"robot kind {kind!r} registered two command tables")
    return table


def is_motion_command(cmd: str) -> bool:
    """Whether `cmd` needs the lease in any registered kind's table (a motion: it moves the robot or its clock)."""
    return any(cmd in table and table[cmd][1] for table in KIND_COMMANDS.values())


# Motion commands whose replies the lease journal does not keep on disk: repeating one after a restart of the
# server moves nothing unasked (a sleep waits, a grab takes a new frame), and a frame is too big to fsync each time.
NOT_JOURNALED = frozenset({"sleep", "grab"})


# ---------------------------------------------------------------------------------------------- framing
_thread_local = threading.local()


def pack(message) -> bytes:
    """msgpack-encode a message built from plain Python types only (numpy values must be converted first).

    One Packer per thread keeps its buffer: packing an image into a fresh buffer each time costs 15x more.
    """
    packer = getattr(_thread_local, "packer", None)
    if packer is None:
        packer = _thread_local.packer = msgpack.Packer(use_bin_type=True, autoreset=False, datetime=False)
    try:
        packer.pack(message)
        return packer.bytes()
    finally:
        packer.reset()


def _refuse_extension(code, data):
    raise ValueError(f"msgpack extension type {code} is not allowed")


def unpack(data: bytes, *, max_bytes: int):
    """Decode one msgpack message with strict limits: str map keys only, no extension types, bounded sizes."""
    if len(data) > max_bytes:
        raise ProtocolError(f"message of {len(data)} bytes exceeds the limit of {max_bytes} bytes", "TooLarge")
    try:
        return msgpack.unpackb(
            data,
            raw=False,
            use_list=True,
            strict_map_key=True,
            max_bin_len=max_bytes,
            max_str_len=max_bytes,
            max_array_len=max_bytes,
            max_map_len=max_bytes,
            max_ext_len=0,
            ext_hook=_refuse_extension,
        )
    except Exception as err:  # msgpack raises a dozen different types for bad input
        raise ProtocolError(f"not a msgpack message: {type(err).__name__}: {err}"[:200]) from None


def parse_request_id(request_id) -> tuple[str, int]:
    """'<client_id>:<seq>' -> (client_id, seq)."""
    if not isinstance(request_id, str):
        raise ProtocolError("'id' must be a string '<client_id>:<seq>'")
    match = REQUEST_ID_PATTERN.match(request_id)
    if match is None:
        raise ProtocolError("'id' must look like '<client_id>:<seq>' (client id [A-Za-z0-9_.-]{1,64})")
    return match.group(1), int(match.group(2))


def make_request(request_id: str, cmd: str, args: dict | None = None, token: str | None = None) -> dict:
    request = {"v": PROTOCOL_VERSION, "id": request_id, "cmd": cmd, "args": dict(args or {})}
    if token is not None:
        request["token"] = token
    return request


def request_token(message: dict) -> str | None:
    """The lease token a validated request carries, or None."""
    if "token" not in message:
        return None
    return _secret(message["token"], "'token'")


def validate_request(message, kind: str = "nao") -> tuple[str, str, dict]:
    """Check a decoded request against the schema of a server of robot `kind` (its KIND_COMMANDS); return (id, cmd,
    validated args) or raise ProtocolError."""
    commands = KIND_COMMANDS[kind]
    if not isinstance(message, dict):
        raise ProtocolError(f"a request must be a map, got {type(message).__name__}")
    if type(message.get("v")) is not int or message["v"] != PROTOCOL_VERSION:
        raise ProtocolError(
            f"unsupported protocol version {message.get('v')!r}; this server speaks {PROTOCOL_VERSION}",
            "UnsupportedVersion",
        )
    missing = REQUEST_KEYS - message.keys()
    extra = message.keys() - REQUEST_KEYS - OPTIONAL_REQUEST_KEYS
    if missing or extra:
        raise ProtocolError(f"request keys must be {sorted(REQUEST_KEYS)} (and optionally 'token'); missing "
                            f"{sorted(missing)}, unexpected {sorted(map(str, extra))}")
    request_id = message["id"]
    parse_request_id(request_id)
    cmd = message["cmd"]
    if not isinstance(cmd, str):
        raise ProtocolError("'cmd' must be a string")
    if cmd not in commands:
        owners = [name for name, table in KIND_COMMANDS.items() if cmd in table]
        raise ProtocolError(f"unknown command {cmd[:64]!r}" + (
            f": a {' or '.join(owners)} command, and this server serves a {kind}" if owners else ""), "UnknownCommand")
    args = message["args"]
    if not isinstance(args, dict):
        raise ProtocolError("'args' must be a map")
    validators, _ = commands[cmd]
    args = {**OPTIONAL_ARGS.get(cmd, {}), **args}
    missing = validators.keys() - args.keys()
    extra = args.keys() - validators.keys()
    if missing or extra:
        raise ProtocolError(f"{cmd}: args must be {sorted(validators)}; missing {sorted(missing)}, "
                            f"unexpected {sorted(map(str, extra))}")
    return request_id, cmd, {key: check(args[key], key) for key, check in validators.items()}


def ok_reply(request_id, result) -> dict:
    return {"v": PROTOCOL_VERSION, "id": request_id, "ok": True, "result": result}


def error_reply(request_id, error_type: str, message: str) -> dict:
    one_line = " ".join(str(message).split())[:500]
    return {"v": PROTOCOL_VERSION, "id": request_id, "ok": False, "error": {"type": error_type, "message": one_line}}


def validate_reply(message, request_id) -> dict:
    """Check a decoded reply's shape; raises ProtocolError. Returns the reply."""
    if not isinstance(message, dict) or message.get("v") != PROTOCOL_VERSION:
        raise ProtocolError("reply is not a protocol-1 map")
    if message.get("id") != request_id:
        raise ProtocolError(f"reply id {message.get('id')!r} does not match request id {request_id!r}")
    if message.get("ok") is True and "result" in message:
        return message
    if message.get("ok") is False and "error" in message:
        checked_error(message["error"])
        return message
    raise ProtocolError("reply has neither ok+result nor an error {type, message}")


def checked_error(error) -> dict:
    """An error reply's {type, message}, checked before the client echoes it: one line of printable text each, the
    message at most MAX_ERROR_CHARS (what error_reply sends); ProtocolError otherwise."""
    with field_checks():
        fields.json_object(error, "the error reply", "error", ("type", "message"), ())
        fields.text(error["type"], "the error reply", "error.type", max_chars=64, non_empty=True)
        fields.text(error["message"], "the error reply", "error.message", max_chars=MAX_ERROR_CHARS)
    return error


# ---------------------------------------------------------------------------------------------- payloads
def joint_reading_to_wire(reading: JointReading) -> dict:
    return {"angles_rad": {name: float(v) for name, v in reading.angles_rad.items()}, "t_s": float(reading.t_s)}


def joint_reading_from_wire(data, limits) -> JointReading:
    """The server's reading, checked as every driver checks one (backends.base.checked_reading: RobotFault if it
    cannot be trusted) against `limits`, the joint limits the server reported."""
    try:
        angles, t_s = {str(name): v for name, v in data["angles_rad"].items()}, data["t_s"]
    except (TypeError, KeyError, AttributeError, ValueError) as err:
        raise ProtocolError(f"malformed joint reading: {err}") from None
    return checked_reading(angles, t_s, limits)


def image_to_wire(image: CameraImage | None):
    if image is None:
        return None
    pixels = np.ascontiguousarray(image.pixels)
    if pixels.dtype.name not in IMAGE_DTYPES:
        raise ProtocolError(f"image dtype {pixels.dtype} is not one of {sorted(IMAGE_DTYPES)}")
    return {
        "pixels": memoryview(pixels).cast("B"),  # packed as bin without an intermediate bytes copy
        "shape": [int(n) for n in pixels.shape],
        "dtype": pixels.dtype.name,
        "t_exposure_s": float(image.t_exposure_s),
        "camera": str(image.camera),
    }


def image_from_wire(data) -> CameraImage | None:
    """The server's image, each field checked (solver.fields) before it is used: ProtocolError naming it."""
    if data is None:
        return None
    what = "the image reply"
    with field_checks():
        fields.json_object(data, what, "", ("pixels", "shape", "dtype", "t_exposure_s", "camera"), ())
        raw, dtype = data["pixels"], fields.choice(data["dtype"], sorted(IMAGE_DTYPES), what, "dtype")
        if not isinstance(raw, bytes):
            fields.fail(what, f"expected bytes, got {type(raw).__name__}", "pixels")
        if not isinstance(data["shape"], list) or not 2 <= len(data["shape"]) <= 3:
            fields.fail(what, f"expected a list of 2 or 3 sizes, got {fields.shown(data['shape'])}", "shape")
        shape = [fields.count(n, what, f"shape[{i}]", 1, MAX_IMAGE_SIDE_PX) for i, n in enumerate(data["shape"])]
        t_exposure_s = fields.number(data["t_exposure_s"], what, "t_exposure_s")
        camera = fields.choice(data["camera"], CAMERA_NAMES, what, "camera")
    if math.prod(shape) * np.dtype(dtype).itemsize != len(raw):
        raise ProtocolError(f"image of shape {shape} and dtype {dtype} cannot hold {len(raw)} bytes")
    # bytearray: the array owns writable memory (consumers may draw on it).
    pixels = np.frombuffer(bytearray(raw), dtype=dtype).reshape(shape)
    return CameraImage(pixels=pixels, t_exposure_s=t_exposure_s, camera=camera)


def intrinsics_from_wire(data) -> CameraIntrinsics:
    """The server's intrinsics, each field checked by the one intrinsics check (CameraIntrinsics.from_fields, as a
    dataset's or a prior file's), five distortion coefficients required; ProtocolError naming the field."""
    what = "the intrinsics reply"
    with field_checks():
        fields.json_object(data, what, "", INTRINSICS_KEYS + ("distortion",), ("name",))
        return CameraIntrinsics.from_fields(data, what)
