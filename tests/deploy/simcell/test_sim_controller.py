"""The simulated controller: path playback, payload commands, heartbeats, CLI checks."""

import itertools

import numpy as np
import pytest

from deploy.commands.sim_controller import configure
from deploy.simcell.controller import SimController
from deploy.simcell.path_player import PathPlayer
from firmware_bridge.can_link import CanControllerPort, CanLink, open_bus
from firmware_bridge.controller_port import fault_spec
from firmware_bridge.errors import BridgeConfigError
from firmware_bridge.protocol import LoadCommand
from sim.family import default_test_payload
from sim.paths import Q0, excitation_path, linear_path
from sim.payload import Payload

_channels = itertools.count()


@pytest.fixture
def channel():
    """A fresh virtual-bus channel name."""
    return f"test-sim-controller-{next(_channels)}"


def test_the_path_plays_forward_then_backward_smoothly():
    path = linear_path(Q0, Q0 + 0.02, 0.2)
    player = PathPlayer(path)
    n = len(path)
    q = np.array([player.at(k)[0] for k in range(3 * (n - 1) + 1)])
    dq = np.array([player.at(k)[1] for k in range(3 * (n - 1) + 1)])
    np.testing.assert_allclose(q[: n], path.q)
    np.testing.assert_allclose(q[n - 1: 2 * n - 1], path.q[::-1])
    np.testing.assert_allclose(dq[n - 1: 2 * n - 1], -path.dq[::-1], atol=1e-15)
    np.testing.assert_allclose(q[2 * (n - 1):], path.q)
    # a finite-difference check that the reversed velocity is the velocity of the reversal
    fd = np.diff(q[n - 1: 2 * n - 1], axis=0) * 1000.0
    mid = (dq[n - 1: 2 * n - 2] + dq[n: 2 * n - 1]) / 2
    np.testing.assert_allclose(fd, mid, atol=1e-3)


def test_once_holds_the_end_at_rest():
    path = linear_path(Q0, Q0 + 0.02, 0.2)
    player = PathPlayer(path, once=True)
    q, dq, ddq = player.at(10_000)
    np.testing.assert_allclose(q, path.q[-1])
    assert not dq.any() and not ddq.any() and player.holding(10_000)


class Port:
    """A controller port that records what the controller does."""

    stride = 1

    def __init__(self, commands=()):
        self.commands = list(commands)
        self.states, self.beats, self.acks = [], [], []

    def tick(self, cycle, t):
        pass

    def poll_commands(self):
        out, self.commands = self.commands, []
        return out

    def publish(self, state):
        self.states.append(state)

    def heartbeat(self, hb):
        self.beats.append(hb)

    def send_ack(self, ack):
        self.acks.append(ack)

    def close(self):
        pass


def test_consistent_loads_are_applied_and_inconsistent_ones_refused():
    good = default_test_payload()
    bad = Payload("flat", 1.0, (0, 0, 0.05), (0.001, 0, 0, 0.001, 0, 0.003))  # I1+I2 < I3
    port = Port([LoadCommand(1, good), LoadCommand(2, bad)])
    ctl = SimController(port, path=excitation_path(1.0), realtime=False)
    ctl.run(cycles=250)
    assert [(a.seq, a.applied) for a in port.acks] == [(1, True), (2, False)]
    assert port.acks[1].load is good  # the refused command leaves the previous load
    assert ctl.plant.controller_load is good and ctl.load_seq == 1
    assert [s.cycle for s in port.states] == list(range(250))
    assert [b.cycle for b in port.beats] == [0, 100, 200]
    port.commands = [LoadCommand(3, None)]
    ctl.run(cycles=1)
    assert port.acks[-1].applied and port.acks[-1].load is None
    assert ctl.plant.controller_load is None


def test_a_known_load_improves_tracking():
    """What setLoad is for: with the true load set, the plant tracks its path better."""
    errors = []
    for load in (None, default_test_payload()):
        port = Port([LoadCommand(1, load)] if load else [])
        ctl = SimController(port, path=excitation_path(2.0), realtime=False)
        ctl.run(cycles=1500)
        ref = np.array([ctl.player.at(k)[0] for k in range(1500)])
        q = np.array([s.q for s in port.states])
        errors.append(np.abs(q - ref)[500:].max())
    assert errors[1] < 0.7 * errors[0]


def test_in_process_on_the_virtual_bus_in_real_time(channel):
    port = CanControllerPort(open_bus("virtual", channel, "fd"), "fd")
    link = CanLink.open("virtual", channel, "fd")
    with SimController(port, path=excitation_path(2.0)) as ctl:
        states = [link.read(1.0) for _ in range(300)]
    link.close()
    assert ctl.error is None and ctl.cycles >= 300
    assert [s.cycle for s in states] == list(range(states[0].cycle, states[0].cycle + 300))
    stats = ctl.stats()
    assert stats["sent"] >= 300 and stats["send_errors"] == 0 and stats["saturated"] == 0


def test_cli_fault_options_are_checked():
    import argparse

    parser = argparse.ArgumentParser()
    configure(parser)
    args = parser.parse_args(["--interface", "virtual", "--drop", "0.05", "--silence", "1:0.5"])
    spec = fault_spec(args)
    assert spec.drop == 0.05 and spec.silence_at == 1.0 and spec.silence_for == 0.5
    with pytest.raises(BridgeConfigError, match="START:LENGTH"):
        fault_spec(parser.parse_args(["--interface", "virtual", "--silence", "soon"]))


@pytest.mark.parametrize("kind", ["fd", "classic", "serial"])
def test_refuse_while_moving_refuses_in_motion_and_accepts_at_rest(kind, channel):
    """A real Franka refuses setLoad while a controller runs: with refuse_while_moving the
    simulated controller acks applied=False with the error text while the path plays, and
    applies the same load once the arm holds at rest."""
    from firmware_bridge.errors import AckTimeout
    from firmware_bridge.pty_pair import PtyPair
    from firmware_bridge.serial_link import SerialControllerPort, SerialLink, open_serial

    if kind == "serial":
        pty = PtyPair()
        port, link = SerialControllerPort(pty), SerialLink(open_serial(pty.slave_path))
    else:
        port = CanControllerPort(open_bus("virtual", channel, kind), kind)
        link = CanLink(open_bus("virtual", channel, kind), kind)
    path = excitation_path(0.2)
    sim = SimController(port, path=path, once=True, realtime=False, refuse_while_moving=True)
    p = default_test_payload()

    def ack_of(seq):
        for _ in range(500):  # the controller steps until the command has arrived
            sim.step()
            if _try(seq):
                return link.decoder.acks[seq]
        raise AssertionError(f"no ack of command {seq}")

    def _try(seq):
        try:
            link.wait_ack(seq, 0.005)
            return True
        except AckTimeout:
            return False

    try:
        seq = link.send(p)
        ack = ack_of(seq)
        assert not ack.applied and ack.load is None
        assert ack.error == "command not possible in the current mode (the arm is moving)"
        sim.run(cycles=len(path))  # to the end of the path: at rest
        seq = link.send(p)
        ack = ack_of(seq)
        assert ack.applied and ack.error == "" and ack.load.mass == pytest.approx(p.mass)
        assert sim.stats()["refused_moving"] == 1
    finally:
        link.close()
        sim.close()
