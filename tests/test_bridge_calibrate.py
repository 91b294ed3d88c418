"""End to end: `naocal calibrate --backend bridge` against `naocal bridge serve --driver mock` on loopback gives
the same offsets as `naocal calibrate --backend mock` with the same seed.

The runs use a small plan (6 stances per leg, no lag probe): these tests check what the bridge does (the same
numbers as in-process, a restarted server, a killed agent's lease), not the precision of a full plan, which
benchmarks/mock_realism_runs.py measures."""

import json
import os
import selectors
import signal
import subprocess
import sys
import time

import pytest

from tests.cli_runner import naocal as naocal_in_process
from naocal.tools import cli  # noqa: E402

pytest.importorskip("naocal.backends.mock")
for verb_module in cli.VERB_MODULES:  # `naocal` runs only once every verb exists
    pytest.importorskip(verb_module)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED = 3
SMALL_PLAN = ("--stances-per-leg", "6", "--no-probe", "--no-progress")


def naocal(*argv):
    return [sys.executable, "-m", "naocal", *argv]


def start_server(seed, *options):
    server = subprocess.Popen(naocal("bridge", "serve", "--driver", "mock", "--mock", "ideal", "--seed", str(seed),
                                     "--bind", "tcp://127.0.0.1:0", *options), cwd=ROOT, stdout=subprocess.PIPE,
                              text=True)
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
    return {key: data[key] for key in ("body", "head", "targets")}  # naocal.offsets/2


@pytest.mark.slow
def test_calibrating_over_the_bridge_gives_the_same_offsets_as_the_direct_mock(tmp_path):
    server, endpoint = start_server(SEED)
    try:
        bridged = subprocess.run(naocal("calibrate", "--backend", "bridge", "--endpoint", endpoint, "--out",
                                        str(tmp_path / "bridge"), *SMALL_PLAN), cwd=ROOT, capture_output=True,
                                 text=True, timeout=900)
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=60)
    assert bridged.returncode == 0, bridged.stderr
    assert server.returncode == 0
    # the ideal mock: a realistic one behind the bridge cannot fault the agent's detections as in-process
    direct = naocal_in_process("calibrate", "--backend", "mock", "--mock", "ideal", "--seed", SEED, "--out",
                               tmp_path / "direct", *SMALL_PLAN)
    assert direct.returncode == 0, direct.stderr
    assert offsets(tmp_path / "bridge") == offsets(tmp_path / "direct")


@pytest.mark.slow
def test_a_server_restarted_in_the_middle_of_a_calibration_fails_cleanly_and_resume_completes(tmp_path):
    """The robot-side server dies mid-measurement and comes back on the same endpoint (a fresh mock: same seed,
    same hidden truth, new state). The agent must not take it for the robot it was talking to: it stops with a
    clear reason, nothing saved is lost, and `--resume` finishes with every capture exactly once."""
    from naocal.agent.plan import read_plan
    from naocal.backends.mock import draw_truth
    from naocal.solver.dataset import read_dataset
    from naocal.solver.joints import LEG_JOINTS

    out = tmp_path / "run"
    server, endpoint = start_server(SEED)
    try:
        agent = subprocess.Popen(naocal("calibrate", "--backend", "bridge", "--endpoint", endpoint, "--out", str(out),
                                        *SMALL_PLAN), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True)
        deadline = time.monotonic() + 300.0
        observations = out / "dataset" / "observations.csv"
        while not (observations.exists() and observations.read_text().count("\n") > 24 * 15):
            assert agent.poll() is None and time.monotonic() < deadline, "the calibration did not get going"
            time.sleep(0.2)
        server.kill()  # the robot-side server dies mid-measurement ...
        server.wait(timeout=30)
        server, endpoint_again = start_server_at(SEED, endpoint)  # ... and is started again
        stdout, stderr = agent.communicate(timeout=600)
        assert agent.returncode == 3, stderr
        assert "--resume" in stdout + stderr and "Traceback" not in stderr
        saved = len(set(read_dataset(out / "dataset").columns["image"]))
        planned = read_plan(out / "plan.json").image_indices()
        assert 15 <= saved < len(planned)
        resumed = subprocess.run(naocal("calibrate", "--backend", "bridge", "--endpoint", endpoint, "--out", str(out),
                                        "--resume", *SMALL_PLAN), cwd=ROOT, capture_output=True, text=True,
                                 timeout=900)
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=60)
    assert resumed.returncode == 0, resumed.stderr
    columns = read_dataset(out / "dataset").columns
    images = list(columns["image"])
    assert len(images) == 24 * len(set(images)) and sorted(set(images)) == sorted(planned)  # every capture once
    truth = draw_truth(SEED).alpha_rad
    stored = json.loads((out / "offsets.json").read_text())["body"]["joint_offsets_rad"]  # naocal.offsets/2
    for joint in LEG_JOINTS:
        assert abs(-stored[joint] - truth[joint]) < 0.0017, joint  # c = -alpha, within 0.1 deg


def start_server_at(seed, endpoint):
    """The mock server again on the endpoint it had (the port may take a moment to be free)."""
    for _ in range(50):
        server = subprocess.Popen(naocal("bridge", "serve", "--driver", "mock", "--mock", "ideal", "--seed", str(seed),
                                         "--bind", endpoint), cwd=ROOT, stdout=subprocess.PIPE, text=True)
        line = server.stdout.readline()
        if line.startswith("naocal bridge: serving"):
            return server, endpoint
        server.wait(timeout=30)
        time.sleep(0.2)
    pytest.fail(f"could not restart the mock server on {endpoint}")


@pytest.mark.slow
def test_an_agent_killed_with_sigkill_resumes_at_once_under_its_own_lease(tmp_path):
    """SIGKILL sends no `release`: the server keeps the lease for its timeout, here an hour. The resumed run takes
    it back with the token in DIR/bridge.token instead of failing or waiting; a stranger still cannot, though it may
    stop the robot (`naocal bridge stop`): the resumed run hears that stop before it moves, and goes on."""
    from naocal.backends.bridge import BridgeBackend
    from naocal.backends.protocol import ControlError
    from naocal.solver.dataset import read_dataset

    out = tmp_path / "run"
    server, endpoint = start_server(SEED, "--lease-timeout-s", "3600")
    try:
        agent = subprocess.Popen(naocal("calibrate", "--backend", "bridge", "--endpoint", endpoint, "--out", str(out),
                                        *SMALL_PLAN), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 300.0
        observations = out / "dataset" / "observations.csv"
        while not (observations.exists() and observations.read_text().count("\n") > 24 * 6):
            assert agent.poll() is None and time.monotonic() < deadline, "the calibration did not get going"
            time.sleep(0.2)
        agent.send_signal(signal.SIGKILL)
        agent.wait(timeout=30)
        assert (out / "bridge.token").stat().st_mode & 0o777 == 0o600
        stranger = BridgeBackend(endpoint, timeout_s=30.0)
        with pytest.raises(ControlError, match="another client controls the robot"):
            stranger.command({"HeadYaw": 0.0}, 0.1)
        stranger.stop()
        stranger.close()
        resumed = subprocess.run(naocal("calibrate", "--backend", "bridge", "--endpoint", endpoint, "--out", str(out),
                                        "--resume", *SMALL_PLAN), cwd=ROOT, capture_output=True, text=True,
                                 timeout=900)
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=60)
    assert resumed.returncode == 0, resumed.stderr
    log = (out / "calibrate.log").read_text()
    assert "took back the motion lease" in log and "was away: another client stopped the robot" in log
    images = list(read_dataset(out / "dataset").columns["image"])
    assert len(images) == 24 * len(set(images))  # every capture once
    assert not (out / "bridge.token").exists()  # released at the end
