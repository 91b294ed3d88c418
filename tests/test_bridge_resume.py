"""A NAO's run over the bridge, resumed or cut by a restarted server (BridgeClient, the core both kinds use).

- A resumed agent takes its lease back (DIR/bridge.token) and first hears the stops the killed process missed (a
  `stop` from another client), with zero-length sleeps that move nothing, instead of failing its first motion on
  them; a refusal that persists (a driver's latched fault) ends it, nothing moved.
- A server that restarted under a run and did not keep what the run commanded (its end made the robot safe: the
  LoLA driver ramps the joints limp, and a new one starts limp) ends the run in one line (continue it with
  --resume); a server whose robot keeps the commands (NAOqi) is carried on with (tests/test_bridge_faults.py).
"""

import logging

import pytest

from naocal.backends.bridge import BridgeBackend
from naocal.backends.bridge_server import BridgeServer
from naocal.backends.errors import BridgeError, RobotFault
from naocal.backends.protocol import ControlError
from naocal.solver.joints import JOINTS
from tests.bridge_fakes import FakeBackend, serving

TARGETS = [{"HeadYaw": 0.01 * k, "LKneePitch": 0.02 * k} for k in range(1, 4)]


def sent_targets(fake):
    return [targets for targets, _ in fake.commands]


class Released(FakeBackend):
    def release_control(self):
        self.executed["release_control"] += 1


def killed_agent(endpoint, lease_file):
    """An agent that moved once under the lease kept in `lease_file`, then died (no release)."""
    agent = BridgeBackend(endpoint, timeout_s=1.0, lease_file=lease_file)
    agent.command(TARGETS[0], 0.2)
    agent._drop_socket()  # SIGKILL: the socket gone, nothing sent
    return agent


def test_a_resumed_agent_hears_the_stop_it_missed_before_moving_and_a_stranger_still_cannot(tmp_path, caplog):
    fake = Released()
    lease_file = tmp_path / "run" / "bridge.token"
    with serving(fake, lease_timeout_s=60.0) as server:
        killed_agent(server.endpoint, lease_file)
        observer = BridgeBackend(server.endpoint, timeout_s=1.0)
        observer.stop()  # `naocal bridge stop` while the agent was dead: the driver's safe state
        observer.close()
        assert fake.executed["release_control"] == 1
        stranger = BridgeBackend(server.endpoint, timeout_s=1.0)
        with pytest.raises(ControlError, match="another client controls the robot"):
            stranger.command(TARGETS[2], 0.2)  # the lease is still the killed agent's
        stranger.close()
        resumed = BridgeBackend(server.endpoint, timeout_s=1.0, lease_file=lease_file)
        with caplog.at_level(logging.WARNING, logger="naocal.bridge.client"):
            resumed.set_stiffness(list(JOINTS), 1.0)  # the resumed run's first motion (agent.states.Modelling)
        assert "while the run being resumed was away: another client stopped the robot" in caplog.text
        resumed.command(TARGETS[1], 0.2)
        resumed.close()
    assert sent_targets(fake) == TARGETS[:2] and fake.executed["set_stiffness"] == 1
    assert fake.executed["release_control"] == 2  # the stop, then the resumed run's release
    assert not lease_file.exists()


def test_a_resumed_agent_whose_robot_still_refuses_motion_ends_there_and_moves_nothing(tmp_path):
    """A driver's latched fault (NAOqi, LoLA: motion refused until the bridge restarts) is not a missed stop."""

    class Faulted(Released):
        faulted = False

        def _refuse(self):
            if self.faulted:
                raise RobotFault("HeadYaw reads nan: motion refused until the bridge is restarted")

        def sleep(self, duration_s):
            self._refuse()
            super().sleep(duration_s)

        def set_stiffness(self, names, stiffness):
            self._refuse()
            super().set_stiffness(names, stiffness)

    fake = Faulted()
    lease_file = tmp_path / "bridge.token"
    with serving(fake, lease_timeout_s=60.0) as server:
        killed_agent(server.endpoint, lease_file)
        fake.faulted = True
        resumed = BridgeBackend(server.endpoint, timeout_s=1.0, lease_file=lease_file)
        with pytest.raises(BridgeError, match="still refuses motion.*HeadYaw reads nan"):
            resumed.set_stiffness(list(JOINTS), 1.0)
        resumed.close()
    assert sent_targets(fake) == TARGETS[:1] and fake.executed["set_stiffness"] == 0


def test_a_lola_server_restarted_under_a_run_ends_it_the_robot_limp(tmp_path):
    """The LoLA bridge stopped (SIGTERM: stiffness ramped to 0) and started again (its driver starts limp) under a
    running agent: what the agent commanded no longer holds, so reading on and capturing would pair joints and
    images of a robot that sags. One line, --resume continues (its Modelling stiffens the joints again)."""
    from naocal.backends.lola_driver import LolaBackend
    from tests.lola_fakes import FakeLola

    lola_path, endpoint = str(tmp_path / "robocup"), f"ipc://{tmp_path}/bridge.sock"
    with FakeLola(lola_path) as lola:
        backend = LolaBackend(lola_path, hold_s=0.1, ramp_s=0.1)
        server = BridgeServer(backend, endpoint, driver="lola").start_thread()
        try:
            agent = BridgeBackend(endpoint, timeout_s=0.5, retries=3)
            agent.set_stiffness(list(JOINTS), 1.0)
            agent.command({"HeadYaw": 0.05}, 0.5)
        finally:
            server.stop()
            backend.close()  # what `naocal bridge serve` does as it ends
        assert lola.wait_for(lambda f: not f.connected)  # LoLA serves one client
        backend = LolaBackend(lola_path, hold_s=0.1, ramp_s=0.1)
        server = BridgeServer(backend, endpoint, driver="lola").start_thread()
        try:
            assert server.backend.status()["robot"]["control"] == "limp"
            with pytest.raises(BridgeError, match="restarted during 'read_joints'.*continue it with --resume"):
                agent.read_joints()
            agent.close()
            assert backend.status()["robot"]["control"] == "limp"  # nothing commanded
        finally:
            server.stop()
            backend.close()


@pytest.mark.parametrize("first_keeps, second_keeps, carries_on", [(True, True, True), (True, False, False),
                                                                   (False, True, False)])
def test_a_restarted_server_is_carried_on_with_only_if_both_servers_say_the_robot_kept_the_commands(
        tmp_path, first_keeps, second_keeps, carries_on):
    """The server that ended says what its end did to the robot, the new one what its start did (a LoLA driver
    starts limp): both must keep the commands (NAOqi's), else the run ends, the robot as the servers left it."""
    endpoint = f"ipc://{tmp_path}/bridge.sock"

    def fake(keeps):
        backend = FakeBackend()
        backend.keeps_commands_on_close = keeps
        return backend

    first, second = fake(first_keeps), fake(second_keeps)
    with serving(first, endpoint, state_persists=True):
        agent = BridgeBackend(endpoint, timeout_s=0.5, retries=3)
        agent.command(TARGETS[0], 0.2)
    with serving(second, endpoint, state_persists=True):
        if carries_on:
            agent.command(TARGETS[1], 0.2)
        else:
            with pytest.raises(BridgeError, match="restarted during 'command' and it made the robot safe"):
                agent.command(TARGETS[1], 0.2)
        agent.close()
    assert sent_targets(second) == (TARGETS[1:2] if carries_on else [])
