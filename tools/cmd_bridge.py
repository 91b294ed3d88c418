"""`naocal bridge`: serve a robot over the network, check a server, make CURVE keys.

  naocal bridge serve --driver mock|naoqi [--seed N] [--naoqi URL] --bind URL [--allow-remote]
                      [--curve-secret-key FILE [--curve-clients DIR]] [--journal FILE]
  naocal bridge ping --endpoint URL [--timeout-s S] [--curve-server-key FILE]
  naocal bridge keygen --out DIR [--name NAME]

`serve` runs until SIGINT or SIGTERM. It binds 127.0.0.1 unless --allow-remote is given. The agent connects
with `naocal calibrate --backend bridge --endpoint URL`. Protocol: docs/PROTOCOL.md; deployment: docs/DEPLOY.md.
"""

import argparse

DEFAULT_BIND = "tcp://127.0.0.1:7790"  # keep in step with backends.bridge_server.DEFAULT_BIND


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "bridge", help="serve a robot (mock or NAOqi) over the network, or check a server",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = parser.add_subparsers(dest="bridge_action", metavar="ACTION")
    actions.required = True

    serve = actions.add_parser("serve", help="serve a robot until SIGINT/SIGTERM")
    serve.add_argument("--driver", choices=("mock", "naoqi"), required=True, help="the robot to serve")
    serve.add_argument("--seed", type=int, default=0, help="mock: seed of the hidden truth (default 0)")
    serve.add_argument("--effect", action="append", default=[], metavar="NAME=SIZE",
                       help="mock: inject a physical effect (repeatable), as in `naocal simulate`")
    serve.add_argument("--mock", choices=("ideal", "realistic"), default=None,
                       help="mock: realistic (default) or ideal robot (docs/MOCK.md; its corner fault model lives "
                            "with the agent's detector and does not cross the bridge)")
    serve.add_argument("--naoqi", default="tcp://127.0.0.1:9559", metavar="URL",
                       help="naoqi: NAOqi's address (default tcp://127.0.0.1:9559, i.e. on the robot)")
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
    ping.add_argument("--timeout-s", type=float, default=2.0, help="give up after this long (default 2)")
    ping.add_argument("--count", type=int, default=10, help="round trips to time (default 10)")
    ping.add_argument("--curve-server-key", metavar="FILE", help="the server's public CURVE key file")
    ping.add_argument("--curve-client-key", metavar="FILE", help="this client's CURVE secret key file")

    keygen = actions.add_parser("keygen", help="write a CURVE key pair NAME.key and NAME.key_secret")
    keygen.add_argument("--out", required=True, metavar="DIR", help="directory for the key files")
    keygen.add_argument("--name", default="server", help="file name stem (default 'server')")

    parser.set_defaults(run=run)


def run(args) -> int:
    return {"serve": _serve, "ping": _ping, "keygen": _keygen}[args.bridge_action](args)


def _serve(args) -> int:
    import logging
    import signal

    from backends.bridge_server import BridgeServer, check_bind_address, keep_large_buffers_in_heap
    from solver.errors import NaocalError

    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    if args.curve_clients and not args.curve_secret_key:
        raise NaocalError("--curve-clients needs --curve-secret-key")
    check_bind_address(args.bind, args.allow_remote)  # before anything touches the robot
    keep_large_buffers_in_heap()  # 5x faster image replies
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

        signal.signal(signal.SIGINT, request_stop)
        signal.signal(signal.SIGTERM, request_stop)
        print(f"naocal bridge: serving {args.driver} on {server.endpoint}", flush=True)
        server.serve_forever()
    finally:
        backend.close()
    print("naocal bridge: stopped", flush=True)
    return 0


def _open_backend(args):
    """(backend, clock, state_persists) for --driver."""
    from solver.errors import NaocalError

    if args.driver == "mock":
        try:
            from backends.mock import MockBackend, parse_effect_sizes
        except ImportError as err:
            raise NaocalError(f"the PyBullet mock is not available: {err}") from None
        kwargs = {"seed": args.seed, "realism": args.mock or "realistic"}
        if args.effect:
            kwargs["effects"] = parse_effect_sizes(args.effect)
        return MockBackend(**kwargs), "simulated", False
    if args.mock is not None:
        raise NaocalError("--mock is for --driver mock")
    try:
        from backends.naoqi_driver import NaoqiBackend

        return NaoqiBackend(args.naoqi), "wall", True
    except ImportError as err:
        raise NaocalError(f"--driver naoqi needs libqi-python (pip install qi): {err}") from None


def _ping(args) -> int:
    import statistics
    import time

    from backends.bridge import BridgeBackend

    bridge = BridgeBackend(args.endpoint, timeout_s=args.timeout_s, retries=0,
                           curve_server_key=args.curve_server_key, curve_client_key=args.curve_client_key)
    try:
        info = bridge.server_info()
        round_trips_s = []
        for _ in range(max(1, args.count)):
            start = time.perf_counter()
            bridge.now()
            round_trips_s.append(time.perf_counter() - start)
    finally:
        bridge.close()
    print(f"{args.endpoint}: round trip {statistics.median(round_trips_s) * 1e3:.3f} ms "
          f"(median of {len(round_trips_s)}), driver {info['driver']}, robot {info['robot_id']}, "
          f"clock {info['clock']}, server {info['server_id']}")
    return 0


def _keygen(args) -> int:
    from backends.bridge_server import write_curve_keys

    public_path, secret_path = write_curve_keys(args.out, args.name)
    print(f"public key (give to clients): {public_path}\nsecret key (keep on the server): {secret_path}")
    return 0
