"""`naocal bridge`: serve a robot over the network, check a server, make CURVE keys, check a calibration.

  naocal bridge serve --driver mock|naoqi|lola [--seed N] [--naoqi URL] [--lola-socket PATH] --bind URL
                      [--allow-remote] [--curve-secret-key FILE [--curve-clients DIR]] [--journal FILE]
  naocal bridge serve --robot duckiebot --driver mock|ros [--seed N] [--watchdog-s S] --bind URL ... (the same)
  naocal bridge ping --endpoint URL [--timeout-s S] [--count N] [--curve-server-key FILE]
  naocal bridge stop --endpoint URL [--timeout-s S] [--curve-server-key FILE] [--curve-client-key FILE]
  naocal bridge keygen --out DIR [--name NAME]
  naocal bridge status --endpoint URL [--offsets FILE] [--json]
  naocal bridge move --endpoint URL [--offsets FILE] [--speed F] JOINT=DEG ...

`stop` stops the robot now, from any client, without the motion lease (a Duckiebot's wheels at 0; a NAO driver's
safe state, as when control ends): it moves nothing, and the controlling agent's next motion is refused.
`serve` runs until SIGINT, SIGTERM or SIGHUP, then leaves the robot in its safe state (docs/DEPLOY.md). It binds
127.0.0.1 unless --allow-remote is given. The agent connects
with `naocal calibrate [--robot duckiebot] --backend bridge --endpoint URL`. Protocol: docs/PROTOCOL.md; deployment: docs/DEPLOY.md.
"""

import argparse

from naocal import kinds
from naocal.tools import cmd_bridge_tools

DEFAULT_BIND = "tcp://127.0.0.1:7790"  # keep in step with backends.bridge_server.DEFAULT_BIND
MAX_PING_COUNT = 10000


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "bridge", help="serve a robot (mock, NAOqi or LoLA) over the network, check a server or a calibration",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = parser.add_subparsers(dest="bridge_action", metavar="ACTION")
    actions.required = True

    serve = actions.add_parser("serve", help="serve a robot until SIGINT/SIGTERM/SIGHUP")
    served = [k for k in kinds.registered() if hasattr(k, "open_served")]  # each kind says what it serves
    serve.add_argument("--robot", choices=tuple(k.name for k in served), default=kinds.default().name,
                       help=f"the robot kind to serve (default {kinds.default().name}); its driver is --driver's")
    serve.add_argument("--driver", choices=tuple(dict.fromkeys(d for k in served for d in k.served_drivers)),
                       required=True, help="the robot to serve, by kind: " + "; ".join(
                           f"{k.name}: " + ", ".join(f"{d} ({what})" for d, what in k.served_drivers.items())
                           for k in served))
    serve.add_argument("--watchdog-s", type=float, default=None, metavar="S",
                       help="duckiebot: stop the wheels when they turn and the controlling client has sent no motion "
                            "request for this long (default 1)")
    serve.add_argument("--seed", type=int, default=0, help="mock: seed of the hidden truth (default 0)")
    serve.add_argument("--effect", action="append", default=[], metavar="NAME=SIZE",
                       help="mock: inject a physical effect (repeatable), as in `naocal simulate`")
    serve.add_argument("--mock", choices=("ideal", "realistic"), default=None,
                       help="mock: realistic (default) or ideal robot (docs/MOCK.md; its corner fault model lives "
                            "with the agent's detector and does not cross the bridge)")
    serve.add_argument("--naoqi", default="tcp://127.0.0.1:9559", metavar="URL",
                       help="naoqi: NAOqi's address (default tcp://127.0.0.1:9559, i.e. on the robot)")
    lola = serve.add_argument_group("--driver lola (docs/DEPLOY.md)")
    lola.add_argument("--lola-socket", default="/tmp/robocup", metavar="PATH",
                      help="LoLA's Unix socket (default /tmp/robocup)")
    lola.add_argument("--lola-timeout-s", type=float, default=1.0, metavar="S",
                      help="LoLA silent this long is a fault: motion refused from then on (default 1)")
    lola.add_argument("--hold-s", type=float, default=5.0, metavar="S",
                      help="when control ends, hold the joints this long ... (default 5)")
    lola.add_argument("--ramp-s", type=float, default=5.0, metavar="S",
                      help="... then ramp their stiffness to 0 over this long (default 5)")
    lola.add_argument("--camera-device", default="/dev/video-bottom", metavar="PATH",
                      help="the bottom camera's V4L2 device (default /dev/video-bottom)")
    lola.add_argument("--top-camera-device", default="/dev/video-top", metavar="PATH",
                      help="the top camera's V4L2 device (default /dev/video-top); a camera whose device is missing "
                           "at start is not offered (the agent then calibrates the other one)")
    lola.add_argument("--cameras", default="bottom,top", metavar="LIST",
                      help="the cameras to serve: bottom,top (default), bottom or top")
    lola.add_argument("--camera-resolution", default="640x480", choices=("640x480", "1280x960"),
                      help="YUYV frame size (default 640x480)")
    lola.add_argument("--camera-exposure", default="100", metavar="N|auto",
                      help="V4L2 exposure_absolute in 100 us units with auto exposure off (default 100 = 10 ms), "
                           "or 'auto' to leave the camera's setting")
    lola.add_argument("--camera-gain", type=int, metavar="N", help="V4L2 gain (default: leave it)")
    lola.add_argument("--intrinsics", metavar="FILE",
                      help="the bottom camera's prior intrinsics, JSON {width_px, height_px, fx_px, fy_px, cx_px, "
                           "cy_px[, distortion]} (default: nominal field of view)")
    lola.add_argument("--no-camera", action="store_true", help="serve the joints only")
    serve.add_argument("--bind", default=DEFAULT_BIND, metavar="URL",
                       help=f"address to serve on (default {DEFAULT_BIND})")
    serve.add_argument("--allow-remote", action="store_true",
                       help="allow a bind address other machines can reach (e.g. tcp://0.0.0.0:7790)")
    serve.add_argument("--curve-secret-key", metavar="FILE", help="server's CURVE secret key file: encrypt and "
                       "authenticate the server (clients need its .key file)")
    serve.add_argument("--curve-clients", metavar="DIR",
                       help="admit only clients whose public .key files are in DIR (needs --curve-secret-key)")
    serve.add_argument("--lease-timeout-s", type=float, default=120.0,
                       help="a controlling client idle this long loses control of motion (default 120)")
    serve.add_argument("--journal", metavar="FILE",
                       help="keep motion replies in FILE so a restarted server never repeats a motion")

    ping = actions.add_parser("ping", help="check a server: round-trip time, driver, robot id")
    ping.add_argument("--endpoint", required=True, metavar="URL", help="e.g. tcp://nao.local:7790")
    ping.add_argument("--timeout-s", type=float, default=2.0,
                      help="give up after this long (default 2, at most 3600)")
    ping.add_argument("--count", type=int, default=10, help=f"round trips to time, 1 to {MAX_PING_COUNT} (default 10)")
    ping.add_argument("--curve-server-key", metavar="FILE", help="the server's public CURVE key file")
    ping.add_argument("--curve-client-key", metavar="FILE", help="this client's CURVE secret key file")

    stop = actions.add_parser("stop", help="stop the robot now (no lease needed): its safe state, moving nothing")
    stop.add_argument("--endpoint", required=True, metavar="URL", help="e.g. tcp://duckiebot.local:7790")
    stop.add_argument("--timeout-s", type=float, default=2.0, help="give up after this long (default 2, at most 3600)")
    stop.add_argument("--curve-server-key", metavar="FILE", help="the server's public CURVE key file")
    stop.add_argument("--curve-client-key", metavar="FILE", help="this client's CURVE secret key file")

    keygen = actions.add_parser("keygen", help="write a CURVE key pair NAME.key and NAME.key_secret")
    keygen.add_argument("--out", required=True, metavar="DIR", help="directory for the key files")
    keygen.add_argument("--name", default="server", help="file name stem (default 'server')")

    cmd_bridge_tools.register(actions)
    parser.set_defaults(run=run)


def run(args) -> int:
    return {"serve": _serve, "ping": _ping, "stop": _stop, "keygen": _keygen, "status": cmd_bridge_tools.run_status,
            "move": cmd_bridge_tools.run_move}[args.bridge_action](args)


def _serve(args) -> int:
    import logging
    import signal

    from naocal.backends.bridge_guard import raise_fd_limit
    from naocal.backends.bridge_server import BridgeServer, check_bind_address, check_lease_timeout, keep_large_buffers_in_heap
    from naocal.solver.errors import NaocalError

    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    if args.curve_clients and not args.curve_secret_key:
        raise NaocalError("--curve-clients needs --curve-secret-key")
    check_bind_address(args.bind, args.allow_remote)  # before anything touches the robot
    check_lease_timeout(args.lease_timeout_s)
    keep_large_buffers_in_heap()  # 5x faster image replies
    raise_fd_limit()  # room for a flood of connections (backends/bridge_guard.py)
    backend, clock, state_persists = _open_backend(args)
    try:
        server = BridgeServer(
            backend, args.bind, driver=args.driver, clock=clock, state_persists=state_persists,
            allow_remote=args.allow_remote, curve_secret_key_file=args.curve_secret_key,
            curve_clients_dir=args.curve_clients, lease_timeout_s=args.lease_timeout_s, journal_path=args.journal,
        ).start()

        def request_stop(signum, _frame):
            logging.getLogger("naocal.bridge.server").info("signal %d: stopping", signum)
            server.stop()

        # Each ends the loop, and the robot is closed into its safe state below (a Duckiebot's wheels at 0). A closing
        # terminal's SIGHUP too, unless ignored (nohup): left to cli's handler it could interrupt that close.
        signal.signal(signal.SIGINT, request_stop)
        signal.signal(signal.SIGTERM, request_stop)
        if signal.getsignal(signal.SIGHUP) != signal.SIG_IGN:
            signal.signal(signal.SIGHUP, request_stop)
        # The first line stays "serving DRIVER on ENDPOINT" (scripts read the endpoint after " on "); the next
        # says whether CURVE is on.
        print(f"naocal bridge: serving {args.driver} on {server.endpoint}\n"
              f"naocal bridge: {server.security_summary()}", flush=True)
        server.serve_forever()
    finally:
        backend.close()
    print("naocal bridge: stopped", flush=True)
    return 0


def _open_backend(args):
    """(backend, clock, state_persists): the --robot kind's served robot for --driver (each kind's `open_served`)."""
    return kinds.named(args.robot).open_served(args)


def _ping(args) -> int:
    import statistics
    import time

    from naocal.backends.bridge import BridgeClient
    from naocal.solver.errors import NaocalError

    if not 1 <= args.count <= MAX_PING_COUNT:  # a median of no round trips means nothing
        raise NaocalError(f"--count must be within 1..{MAX_PING_COUNT}, got {args.count}")
    bridge = BridgeClient(args.endpoint, timeout_s=args.timeout_s, retries=0,
                           curve_server_key=args.curve_server_key, curve_client_key=args.curve_client_key)
    try:
        info = _shown_hello(bridge.server_info(), args.endpoint)
        round_trips_s = []
        for _ in range(args.count):
            start = time.perf_counter()
            bridge.now()
            round_trips_s.append(time.perf_counter() - start)
    finally:
        bridge.close()
    print(f"{args.endpoint}: round trip {statistics.median(round_trips_s) * 1e3:.3f} ms "
          f"(median of {len(round_trips_s)}), driver {info['driver']}, robot {info['robot_id']}, "
          f"clock {info['clock']}, server {info['server_id']}")
    return 0


def _stop(args) -> int:
    from naocal.backends.bridge import BridgeClient

    bridge = BridgeClient(args.endpoint, timeout_s=args.timeout_s, retries=1,
                          curve_server_key=args.curve_server_key, curve_client_key=args.curve_client_key)
    try:
        info = _shown_hello(bridge.server_info(), args.endpoint)
        bridge.stop()
    finally:
        bridge.close()
    print(f"{args.endpoint}: stopped the {info['kind']} {info['robot_id']} (driver {info['driver']})")
    return 0


def _shown_hello(info: dict, endpoint: str) -> dict:
    """The hello's values a command prints, checked before they are echoed: one short printable line each."""
    from naocal.solver import fields

    shown = {"kind": info.get("kind", "nao"),  # a revision-1 server serves a NAO and does not say so
             **{key: info.get(key) for key in ("driver", "robot_id", "clock", "server_id")}}
    for key, value in shown.items():
        fields.text(value, f"{endpoint}: hello", key, max_chars=100, non_empty=True)
    return {**info, **shown}


def _keygen(args) -> int:
    from naocal.backends.bridge_server import write_curve_keys

    public_path, secret_path = write_curve_keys(args.out, args.name)
    print(f"public key: {public_path}\n  give it to the other side: a server's key to its clients "
          "(--curve-server-key or $NAOCAL_CURVE_SERVER_KEY), a client's key into the server's --curve-clients DIR\n"
          f"secret key: {secret_path}\n  keep it on the machine that uses it (mode 0600) and copy it nowhere else")
    return 0
