"""The pylibfranka backend against a fake with pylibfranka's signatures."""

import sys
import types

import numpy as np
import pytest

from firmware_bridge.errors import BridgeConfigError, ControllerSilent, LinkError
from firmware_bridge.franka_link import FrankaLink
from firmware_bridge.links import JointStateSource, PayloadSink, open_link
from sim.family import default_test_payload
from sim.paths import excitation_path
from sim.plant import PandaPlant


class Duration:
    def __init__(self, ms):
        self._ms = ms

    def to_sec(self):
        return self._ms / 1000.0


class RobotState:
    """The fields of pylibfranka.RobotState the link reads (NumPy arrays, as pylibfranka)."""

    def __init__(self, q, dq, tau_J, time_ms, m_load, F_x_Cload, I_load):
        self.q, self.dq, self.tau_J = np.asarray(q), np.asarray(dq), np.asarray(tau_J)
        self.time = Duration(time_ms)
        self.m_load, self.F_x_Cload, self.I_load = m_load, np.asarray(F_x_Cload), \
            np.asarray(I_load)


class CommandException(RuntimeError):
    pass


class NetworkException(RuntimeError):
    pass


class FakeRobot:
    """``read_once()`` steps a plant 1 ms per call (``skip`` extra ms sometimes);
    ``set_load(load_mass, F_x_Cload, load_inertia)`` positional, std::array sizes checked."""

    def __init__(self):
        self.path = excitation_path(2.0)
        self.plant = PandaPlant(payload=default_test_payload())
        self.plant.reset(self.path.q[0])
        self.k = 0
        self.load = (0.0, [0.0] * 3, [0.0] * 9)
        self.skip_next = 0
        self.fail = None

    def read_once(self):
        if self.fail == "network":
            raise NetworkException("libfranka: UDP receive: Timeout")
        for _ in range(1 + self.skip_next):
            s = self.plant.step(self.path.q[self.k], self.path.dq[self.k], self.path.ddq[self.k])
            self.k += 1
        self.skip_next = 0
        m, c, i = self.load
        return RobotState(s.q, s.dq, s.tau_J, round(s.t * 1000), m, c, i)

    def set_load(self, *args):
        load_mass, F_x_Cload, load_inertia = args  # pybind11: positional, no names
        if len(F_x_Cload) != 3 or len(load_inertia) != 9:
            raise TypeError("incompatible function arguments")
        if self.fail == "command":
            raise CommandException("libfranka: Set Load command rejected")
        self.load = (float(load_mass), list(F_x_Cload), list(load_inertia))


def test_states_come_from_read_once_and_skipped_cycles_are_lost():
    robot = FrankaLink(FakeRobot())
    assert isinstance(robot, JointStateSource) and isinstance(robot, PayloadSink)
    a, b = robot.read(), robot.read()
    robot.robot.skip_next = 2
    c = robot.read()
    assert (a.cycle, b.cycle, c.cycle) == (0, 1, 4)
    assert robot.counters.lost == 2 and robot.counters.delivered == 3
    np.testing.assert_allclose(b.t, 1e-3)


def test_set_load_gets_column_major_inertia_and_the_ack_reads_it_back():
    fake = FakeRobot()
    robot = FrankaLink(fake)
    p = default_test_payload()
    seq = robot.send(p)
    mass, com, inertia = fake.load
    assert mass == p.mass and com == list(p.com)
    np.testing.assert_allclose(np.reshape(inertia, (3, 3), order="F"), p.inertia_matrix)
    ack = robot.wait_ack(seq)
    assert ack.applied and ack.load.mass == p.mass
    np.testing.assert_allclose(ack.load.inertia, p.inertia)
    assert robot.read().cycle == 0  # the state read for the ack is not lost
    assert robot.wait_ack(robot.send(None)).load is None and fake.load[0] == 0.0


def test_refused_and_network_failures():
    fake = FakeRobot()
    robot = FrankaLink(fake)
    fake.fail = "command"
    ack = robot.wait_ack(robot.send(default_test_payload()))
    assert not ack.applied and ack.load is None
    robot.read()  # the state read for the ack
    fake.fail = "network"
    with pytest.raises(ControllerSilent, match="NetworkException"):
        robot.read()
    with pytest.raises(LinkError, match="no payload command 99"):
        robot.wait_ack(99)


def test_without_pylibfranka_the_extra_is_named(monkeypatch):
    monkeypatch.setitem(sys.modules, "pylibfranka", None)
    with pytest.raises(BridgeConfigError, match=r"pip install 'iem-payload\[franka\]'"):
        open_link("franka", "172.16.0.2")


def test_open_uses_pylibfranka_robot_and_realtime_config(monkeypatch):
    made = {}

    class Robot(FakeRobot):
        def __init__(self, address, config):
            super().__init__()
            made.update(address=address, config=config)

    module = types.SimpleNamespace(Robot=Robot, RealtimeConfig=types.SimpleNamespace(
        kEnforce="enforce", kIgnore="ignore"))
    monkeypatch.setitem(sys.modules, "pylibfranka", module)
    link = open_link("franka", "172.16.0.2")
    assert made == {"address": "172.16.0.2", "config": "ignore"}
    assert link.read().cycle == 0
