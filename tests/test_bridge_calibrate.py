"""End to end: `naocal calibrate --backend bridge` against `naocal bridge serve --driver mock` on loopback gives
the same offsets as `naocal calibrate --backend mock` with the same seed."""

import json
import os
import selectors
import signal
import subprocess
import sys
import time

import pytest

from tools import cli  # noqa: E402

pytest.importorskip("backends.mock")
for verb_module in cli.VERB_MODULES:  # `naocal` runs only once every verb exists
    pytest.importorskip(verb_module)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED = 3


def naocal(*argv):
    return [sys.executable, "-m", "tools", *argv]


def start_server(seed):
    server = subprocess.Popen(naocal("bridge", "serve", "--driver", "mock", "--seed", str(seed), "--bind",
                                     "tcp://127.0.0.1:0"), cwd=ROOT, stdout=subprocess.PIPE, text=True)
    selector = selectors.DefaultSelector()
    selector.register(server.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + 120.0
    line = ""
    while not line.startswith("naocal bridge: serving"):
        if not selector.select(timeout=max(0.0, deadline - time.monotonic())):
            server.kill()
            pytest.fail("the mock bridge server did not start within 120 s")
        line = server.stdout.readline()
        if not line:
            pytest.fail(f"the mock bridge server exited with {server.wait()}")
    return server, line.split(" on ")[1].strip()


def offsets(directory):
    data = json.loads((directory / "offsets.json").read_text())
    return {key: data[key] for key in ("joint_offsets_rad", "camera_rotation_rad", "board_mount")}


@pytest.mark.slow
def test_calibrating_over_the_bridge_gives_the_same_offsets_as_the_direct_mock(tmp_path):
    server, endpoint = start_server(SEED)
    try:
        bridged = subprocess.run(naocal("calibrate", "--backend", "bridge", "--endpoint", endpoint, "--out",
                                        str(tmp_path / "bridge")), cwd=ROOT, capture_output=True, text=True,
                                 timeout=900)
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=60)
    assert bridged.returncode == 0, bridged.stderr
    assert server.returncode == 0
    direct = subprocess.run(naocal("calibrate", "--backend", "mock", "--seed", str(SEED), "--out",
                                   str(tmp_path / "direct")), cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert direct.returncode == 0, direct.stderr
    assert offsets(tmp_path / "bridge") == offsets(tmp_path / "direct")
