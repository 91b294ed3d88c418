"""Bridge overhead over loopback: read_joints round-trip latency and VGA image transfer rate, against direct calls.

    python benchmarks/bench_bridge.py [--reads 3000] [--images 300]

The server runs in its own process (as on a robot), serving a backend that answers instantly with fixed data,
so the numbers are the cost of the bridge itself: msgpack, ZeroMQ, loopback TCP and Python on both ends.
Three runs: default glibc malloc; the server with `keep_large_buffers_in_heap()` (what `naocal bridge serve`
does); both ends with it.
"""

import argparse
import multiprocessing
import pathlib
import statistics
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from naocal.backends.base import Backend, CameraImage, CameraIntrinsics, JointReading  # noqa: E402
from naocal.solver.joints import JOINTS  # noqa: E402


class InstantBackend(Backend):
    """Fixed joints and a fixed 640 x 480 x 3 image; the clock moves only on sleep."""

    name = "instant"

    def __init__(self):
        self._t_s = 0.0
        self._angles = {name: 0.1 * i for i, name in enumerate(JOINTS)}
        self._pixels = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)

    def robot_identity(self):
        return {"id": "bench", "model": "bench", "body_id": "bench", "head_id": "bench"}

    def joint_names(self):
        return JOINTS

    def joint_limits(self):
        return {name: (-1.0, 1.0) for name in JOINTS}

    def max_speeds(self):
        return {name: 5.0 for name in JOINTS}

    def command(self, targets_rad, speed_fraction):
        pass

    def read_joints(self):
        return JointReading(angles_rad=dict(self._angles), t_s=self._t_s)

    def set_stiffness(self, names, stiffness):
        pass

    def capture(self):
        return CameraImage(pixels=self._pixels.copy(), t_exposure_s=self._t_s)

    def intrinsics(self):
        return CameraIntrinsics(640, 480, 600.0, 600.0, 319.5, 239.5)

    def now(self):
        return self._t_s

    def sleep(self, duration_s):
        self._t_s += duration_s


def serve(endpoint_queue, stop_event, tune_malloc):
    from naocal.backends.bridge_server import BridgeServer, keep_large_buffers_in_heap

    if tune_malloc:
        keep_large_buffers_in_heap()  # as `naocal bridge serve` does
    server = BridgeServer(InstantBackend(), "tcp://127.0.0.1:0", driver="instant", clock="simulated").start()
    endpoint_queue.put(server.endpoint)
    import threading

    threading.Thread(target=lambda: (stop_event.wait(), server.stop()), daemon=True).start()
    server.serve_forever()


def latencies_s(call, count):
    out = []
    for _ in range(count):
        start = time.perf_counter()
        call()
        out.append(time.perf_counter() - start)
    return np.array(out)


def describe(name, samples_s):
    median_us, p95_us = np.median(samples_s) * 1e6, np.percentile(samples_s, 95) * 1e6
    print(f"  {name:<28} median {median_us:9.1f} us   p95 {p95_us:9.1f} us")


def run_config(label, tune_server, tune_client, args):
    from naocal.backends.bridge import BridgeBackend
    from naocal.backends.bridge_server import keep_large_buffers_in_heap

    context = multiprocessing.get_context("spawn")
    endpoint_queue, stop_event = context.Queue(), context.Event()
    process = context.Process(target=serve, args=(endpoint_queue, stop_event, tune_server), daemon=True)
    process.start()
    endpoint = endpoint_queue.get(timeout=30)
    if tune_client:
        keep_large_buffers_in_heap()  # process-wide and permanent: the last configuration
    try:
        direct, bridge = InstantBackend(), BridgeBackend(endpoint, timeout_s=5.0)
        for _ in range(200):  # connect and warm up both paths outside the timing
            direct.read_joints(), bridge.read_joints()
        print(f"{label} ({endpoint}, server in its own process)")
        direct_reads = latencies_s(direct.read_joints, args.reads)
        bridge_reads = latencies_s(bridge.read_joints, args.reads)
        describe("read_joints direct", direct_reads)
        describe("read_joints bridge", bridge_reads)
        print(f"  {'bridge / direct (median)':<28} {np.median(bridge_reads) / np.median(direct_reads):9.0f} x")
        image_mb = 640 * 480 * 3 / 1e6
        for name, backend in (("capture direct", direct), ("capture bridge", bridge)):
            samples = latencies_s(backend.capture, args.images)
            rate = 1.0 / statistics.mean(samples)
            print(f"  {name:<28} {rate:9.1f} images/s {rate * image_mb:9.1f} MB/s   "
                  f"median {np.median(samples) * 1e3:7.2f} ms   p95 {np.percentile(samples, 95) * 1e3:7.2f} ms")
        bridge.close()
    finally:
        stop_event.set()
        process.join(10)
        if process.is_alive():
            process.terminate()


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--reads", type=int, default=3000)
    parser.add_argument("--images", type=int, default=300)
    args = parser.parse_args()
    print("naocal bridge over loopback; images are 640 x 480 x 3 = 0.922 MB (the camera delivers 30 images/s)")
    run_config("default malloc", False, False, args)
    run_config("server with keep_large_buffers_in_heap (as `naocal bridge serve`)", True, False, args)
    run_config("server and client with keep_large_buffers_in_heap", True, True, args)


if __name__ == "__main__":
    main()
