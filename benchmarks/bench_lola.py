"""The LoLA driver's real-time budget: what it spends of LoLA's 12 ms cycle, against straightforward versions.

    python benchmarks/bench_lola.py [--repeat 2000]

1. `JointControl.step` (numpy over the 25 joints) against the same step written joint by joint in plain Python.
2. The head-path check of a command, which runs while the driver holds the lock LoLA's answer waits for:
   vectorised over 401 samples against one `solver.limits.head_pitch_problem` call per sample.
3. `parse_sensor_message` on one whole LoLA message (every value's type, finiteness and limit check), which runs
   before each answer.
4. The answer delay through a real Unix socket: from the moment a sensor message has been received to the moment
   its answer is sent (a fake LoLA in this process, `tests/lola_fakes.py`), median and 99th percentile.
"""

import argparse
import pathlib
import statistics
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from naocal.backends import lola_driver  # noqa: E402
from naocal.backends.lola_driver import CALIBRATED_MOTORS, LOLA_INDEX, N_LOLA, JointControl, LolaFrame  # noqa: E402
from naocal.solver import limits  # noqa: E402


def frame(position):
    return LolaFrame(0.0, tuple(position), (0.0,) * N_LOLA, (40.0,) * N_LOLA, (0.0,) * N_LOLA, (0,) * N_LOLA,
                     ("b", "6", "h", "6"))


def plain_step(state, measured):
    """The interpolation and stiffness update of one cycle, joint by joint (what step() does, without numpy)."""
    for i in range(N_LOLA):
        if state["moving"][i]:
            state["elapsed"][i] += 0.012
            frac = min(1.0, state["elapsed"][i] / state["duration"][i])
            state["setpoint"][i] = state["start"][i] + (state["target"][i] - state["start"][i]) * frac
            state["moving"][i] = frac < 1.0
        target = state["stiffness_target"][i] if i in CALIBRATED_MOTORS else 0.0
        s = state["stiffness"][i]
        state["stiffness"][i] = min(max(target, s - 0.012 / 5.0), s + 0.012 / 0.5)
        if state["stiffness"][i] <= 0.0:
            state["setpoint"][i] = measured[i]
    return list(state["setpoint"]), list(state["stiffness"])


def best_of(fn, repeat):
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(repeat):
            fn()
        times.append((time.perf_counter() - t0) / repeat)
    return min(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=2000)
    args = parser.parse_args()
    speeds = {i: 6.0 for i in CALIBRATED_MOTORS}
    measured = np.linspace(-0.5, 0.5, N_LOLA)

    control = JointControl(speeds)
    control.step(frame(measured))
    control.set_stiffness(CALIBRATED_MOTORS, 1.0)
    for _ in range(50):
        control.step(frame(measured))
    control.command({i: 0.3 for i in CALIBRATED_MOTORS}, 0.01)  # a long motion: every step interpolates
    f = frame(measured)
    numpy_s = best_of(lambda: control.step(f), args.repeat)
    state = {"moving": [i in CALIBRATED_MOTORS for i in range(N_LOLA)], "elapsed": [0.0] * N_LOLA,
             "duration": [1e9] * N_LOLA, "start": list(measured), "target": [0.3] * N_LOLA,
             "setpoint": list(measured), "stiffness": [1.0] * N_LOLA, "stiffness_target": [1.0] * N_LOLA}
    plain_s = best_of(lambda: plain_step(state, measured), args.repeat)
    print(f"JointControl.step: numpy {numpy_s * 1e6:.1f} us, plain Python {plain_s * 1e6:.1f} us "
          f"(ratio {plain_s / numpy_s:.2f}); {numpy_s / 0.012 * 100:.2f} % of a 12 ms cycle")

    # 2. Head path: yaw 0.9 -> 2.0 at pitch 0.3 passes yaw 1.527 where pitch may not exceed 0.2.
    head = JointControl(speeds)
    start = measured.copy()
    start[LOLA_INDEX["HeadYaw"]], start[LOLA_INDEX["HeadPitch"]] = 0.9, 0.1
    head.step(frame(start))
    targets = {LOLA_INDEX["HeadYaw"]: -0.9}

    def vectorised():
        head._check_head_path(targets, 1.0)

    def per_sample():
        yaw = np.linspace(0.9, -0.9, 401)
        for y in yaw:
            limits.head_pitch_problem(y, 0.1, margin_rad=-1e-9)

    vec_s, loop_s = best_of(vectorised, args.repeat // 20), best_of(per_sample, args.repeat // 20)
    print(f"head path check (401 samples): vectorised {vec_s * 1e3:.3f} ms, per sample {loop_s * 1e3:.2f} ms "
          f"(ratio {loop_s / vec_s:.1f})")

    # 3. Parsing and checking one message, as received (msgpack-decoded).
    import msgpack

    from tests.lola_fakes import FakeLola, sensor_message

    message = msgpack.unpackb(sensor_message(measured, np.ones(N_LOLA), np.full(N_LOLA, 40.0), np.zeros(N_LOLA)))
    cpu0 = time.process_time()
    parse_s = best_of(lambda: lola_driver.parse_sensor_message(message, 0.0), args.repeat)
    cpu_s = (time.process_time() - cpu0) / (5 * args.repeat)
    print(f"parse_sensor_message: {parse_s * 1e6:.1f} us wall (best of 5), {cpu_s * 1e6:.1f} us CPU (mean); "
          f"{parse_s / 0.012 * 100:.2f} % of a 12 ms cycle")

    # 4. Answer delay through a real socket.

    delays = []
    original = lola_driver.LolaBackend._answer

    def timed_answer(self, frame_):
        original(self, frame_)
        delays.append(time.monotonic() - frame_.t_s)

    lola_driver.LolaBackend._answer = timed_answer
    with tempfile.TemporaryDirectory() as tmp, FakeLola(f"{tmp}/robocup") as fake:
        backend = lola_driver.LolaBackend(f"{tmp}/robocup")
        backend.set_stiffness(["HeadYaw"], 1.0)
        backend.command({"HeadYaw": 0.5}, 0.05)
        backend.wait_cycles(500, timeout_s=30.0)
        backend.close()
        late = fake.late_cycles
    lola_driver.LolaBackend._answer = original
    delays_ms = np.array(delays[10:]) * 1e3
    print(f"answer delay over {len(delays_ms)} cycles: median {statistics.median(delays_ms):.3f} ms, "
          f"99th percentile {np.percentile(delays_ms, 99):.3f} ms, max {delays_ms.max():.3f} ms "
          f"(fake LoLA late cycles: {late})")


if __name__ == "__main__":
    main()
