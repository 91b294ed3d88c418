"""The NAO served by `naocal bridge serve` (tools/cmd_bridge.py): the PyBullet mock, NAOqi or LoLA with V4L2 cameras."""

from __future__ import annotations

import logging

from naocal.solver.errors import NaocalError


def open_served(args):
    """(backend, clock, state_persists) for `naocal bridge serve [--robot nao] --driver mock|naoqi|lola`."""
    if args.driver == "ros" or args.watchdog_s is not None:
        raise NaocalError("--driver ros and --watchdog-s are for --robot duckiebot")

    if args.driver == "mock":
        try:
            from naocal.backends.mock import MockBackend, parse_effect_sizes
        except ImportError as err:
            raise NaocalError(f"the PyBullet mock is not available: {err}") from None
        kwargs = {"seed": args.seed, "realism": args.mock or "realistic"}
        if args.effect:
            kwargs["effects"] = parse_effect_sizes(args.effect)
        return MockBackend(**kwargs), "simulated", False
    if args.mock is not None:
        raise NaocalError("--mock is for --driver mock")
    if args.driver == "lola":
        return _open_lola(args), "wall", True
    try:
        from naocal.backends.naoqi_driver import NaoqiBackend

        return NaoqiBackend(args.naoqi), "wall", True
    except ImportError as err:
        raise NaocalError(f"--driver naoqi needs libqi-python (pip install qi): {err}") from None


def _open_lola(args):
    """The LoLA driver with the cameras whose devices exist (each opened on first capture) for `serve --driver lola`."""
    from naocal.backends.lola_driver import LolaBackend
    from naocal.backends.base import nominal_intrinsics
    from naocal.backends import v4l2_camera
    from naocal.backends.v4l2_camera import V4L2Camera, read_intrinsics
    from naocal.solver.errors import NaocalError

    log = logging.getLogger("naocal.bridge")

    if not 0.0 <= args.hold_s <= 600.0 or not 0.0 < args.ramp_s <= 60.0:
        raise NaocalError(f"--hold-s must be within [0, 600] and --ramp-s within (0, 60], got {args.hold_s}, "
                          f"{args.ramp_s}")
    if not 0.05 <= args.lola_timeout_s <= 60.0:
        raise NaocalError(f"--lola-timeout-s must be within [0.05, 60], got {args.lola_timeout_s}")
    width, height = (int(n) for n in args.camera_resolution.split("x"))
    intrinsics = read_intrinsics(args.intrinsics) if args.intrinsics else nominal_intrinsics(width, height)
    names = [name.strip() for name in args.cameras.split(",") if name.strip()]
    if not names or len(set(names)) != len(names) or not set(names) <= {"bottom", "top"}:
        raise NaocalError(f"--cameras must list bottom and/or top, got {args.cameras!r}")
    cameras, missing = [], {}
    if not args.no_camera:
        if args.camera_exposure == "auto":
            exposure = None
        elif args.camera_exposure.isdigit() and 1 <= int(args.camera_exposure) <= 10000:
            exposure = int(args.camera_exposure)
        else:
            raise NaocalError(f"--camera-exposure must be 1..10000 (100 us units) or 'auto', got "
                              f"{args.camera_exposure!r}")
        devices = {"bottom": args.camera_device, "top": args.top_camera_device}
        for name in names:
            if not v4l2_camera.device_present(devices[name]):
                missing[name] = devices[name]
                continue
            # Same lens: the top camera starts from the bottom one's prior too.
            cameras.append(V4L2Camera(name, device=devices[name], width=width, height=height, exposure=exposure,
                                      gain=args.camera_gain, intrinsics=intrinsics))
    backend = LolaBackend(args.lola_socket, cameras=cameras, missing_cameras=missing, intrinsics=intrinsics,
                          hold_s=args.hold_s, ramp_s=args.ramp_s, silence_timeout_s=args.lola_timeout_s)
    for name, device in missing.items():  # said once connected, so that a bad start stays one line
        log.warning("%s camera: no device %s: serving without it", name, device)
    return backend
