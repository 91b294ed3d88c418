"""The Duckiebot over the bridge on loopback: round trips of `now`, `wheels` and `grab` (a frame as PNG), with the CPU
each end spends, against the same calls made directly; and the CPU per frame of checking a camera frame before it
is echoed (the ROS driver's JPEG decode and size check, robot.decoded_frame) and of the server's PNG encoding.

    python benchmarks/bench_duckiebot_bridge.py [--calls 500] [--grabs 100]

The server runs in its own process (as on a robot), serving a driver that answers at once: its frame is a rendered
frame of the calibration set-up (kinds.duckiebot.mock, ideal, seed 4: one render, kept), so the numbers are the
bridge's own cost (PNG encode on the server, msgpack, ZeroMQ, loopback TCP, PNG decode and checks on the client).
A real robot adds its camera's wait for the next frame (up to 1/30 s) and a Raspberry Pi's slower PNG encoding.
"""

import argparse
import multiprocessing
import pathlib
import resource
import statistics
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))


class InstantDuckiebot:
    """The mission's robot interface, answering at once; the clock moves only on advance."""

    def __init__(self, frame):
        self.t_s, self.frame = 0.0, frame

    def now(self):
        return self.t_s

    def command(self, left, right):
        return self.t_s

    def advance(self, duration_s):
        self.t_s += duration_s

    def grab(self):
        self.t_s += 0.02
        return self.t_s - 0.01, self.frame

    def close(self):
        pass


def rendered_frame():
    from naocal.kinds.duckiebot.mock import DuckiebotMock

    mock = DuckiebotMock(4, "ideal")
    try:
        return mock.grab()[1]
    finally:
        mock.close()


def serve(frame, ready, done, cpu):
    from naocal.backends.bridge_server import BridgeServer, keep_large_buffers_in_heap
    from naocal.kinds.duckiebot.bridge import ServedDuckiebot

    keep_large_buffers_in_heap()  # as `naocal bridge serve`
    served = ServedDuckiebot(InstantDuckiebot(frame), robot_id="bench", watchdog_s=10.0)
    server = BridgeServer(served, "tcp://127.0.0.1:0", driver="bench", clock="simulated").start_thread()
    start = resource.getrusage(resource.RUSAGE_SELF)
    ready.put(server.endpoint)
    done.wait()
    end = resource.getrusage(resource.RUSAGE_SELF)
    cpu.put((end.ru_utime + end.ru_stime) - (start.ru_utime + start.ru_stime))
    server.stop()
    served.close()


def frame_check_cpu(frame, n):
    """(CPU s per frame of the robot's check of a camera node's JPEG, CPU s per frame of the server's grab reply: its
    array check and PNG encoding), each over n frames in this process."""
    import cv2

    from naocal.kinds.duckiebot.bridge import ServedDuckiebot
    from naocal.kinds.duckiebot.robot import decoded_frame

    jpeg = bytes(cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 95])[1])  # as the camera node sends it
    cpu0 = time.process_time()
    for _ in range(n):
        image, problem = decoded_frame(jpeg)
        assert problem is None, problem
    check_s = (time.process_time() - cpu0) / n
    served = ServedDuckiebot(InstantDuckiebot(frame), robot_id="bench", watchdog_s=10.0)
    try:
        cpu0 = time.process_time()
        for _ in range(n):
            served.dispatch("grab", {})
        reply_s = (time.process_time() - cpu0) / n
    finally:
        served.close()
    return check_s, reply_s, len(jpeg)


def timed(call, n):
    """(median wall s per call, client CPU s per call)."""
    walls = []
    cpu0 = time.process_time()
    for _ in range(n):
        t0 = time.perf_counter()
        call()
        walls.append(time.perf_counter() - t0)
    return statistics.median(walls), (time.process_time() - cpu0) / n


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=500)
    parser.add_argument("--grabs", type=int, default=100)
    args = parser.parse_args()

    from naocal.kinds.duckiebot.bridge import DuckiebotBridge

    frame = rendered_frame()
    direct = InstantDuckiebot(frame)
    ctx = multiprocessing.get_context("spawn")
    ready, cpu, done = ctx.Queue(), ctx.Queue(), ctx.Event()
    process = ctx.Process(target=serve, args=(frame, ready, done, cpu))
    process.start()
    client = DuckiebotBridge(ready.get(timeout=120), timeout_s=10.0)
    try:
        client.facts()
        client.command(0.1, 0.1)  # the lease, once
        rows = []
        for name, bridged, plain, n in (("now", client.now, direct.now, args.calls),
                                        ("wheels", lambda: client.command(0.2, 0.2), lambda: direct.command(0.2, 0.2),
                                         args.calls),
                                        ("grab", client.grab, direct.grab, args.grabs)):
            wall, client_cpu = timed(bridged, n)
            direct_wall, _ = timed(plain, n)
            rows.append((name, n, wall, client_cpu, direct_wall))
        client.command(0.0, 0.0)
    finally:
        client.close()
        done.set()
    server_cpu = cpu.get(timeout=60)
    process.join(30)
    print(f"frame: {frame.shape[1]} x {frame.shape[0]} grey (a rendered calibration view)")
    print(f"{'call':8} {'n':>5} {'bridge ms':>10} {'client CPU ms':>14} {'direct ms':>10}")
    for name, n, wall, client_cpu, direct_wall in rows:
        print(f"{name:8} {n:5d} {wall * 1e3:10.3f} {client_cpu * 1e3:14.3f} {direct_wall * 1e3:10.4f}")
    requests = sum(n for _, n, *_ in rows) + 6  # and hello, facts, acquire, two commands, release
    print(f"server CPU: {server_cpu:.2f} s over its {requests} requests (mostly the grabs' PNG encoding)")
    check_s, reply_s, jpeg_bytes = frame_check_cpu(frame, args.grabs)
    print(f"frame check on the robot (a {jpeg_bytes // 1024} KiB JPEG decoded, its size checked): "
          f"{check_s * 1e3:.2f} ms CPU per frame; the server's grab reply (array check, PNG): "
          f"{reply_s * 1e3:.2f} ms CPU per frame")


if __name__ == "__main__":
    main()
