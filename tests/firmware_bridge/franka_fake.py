"""A fake of pylibfranka 0.21's API, as much of it as the link uses: the same class names,
the same exception hierarchy (every exception a RuntimeError subclass, as the real
``_pylibfranka.pyi`` declares), ``RobotState`` fields as lists (pybind11 ``std::array``), and
``Robot.set_load`` positional with fixed sizes.

``read_once()`` blocks until the test releases a state (``robot.release(n)``), as the real
one blocks until the robot's next state, and raises ``NetworkException`` after
``udp_timeout`` s without one. Each state steps a plant 1 ms (``skip_next`` more sometimes).
"""

from __future__ import annotations

import sys
import threading
import time
import types

from sim.family import default_test_payload
from sim.paths import excitation_path
from sim.plant import ArmPlant
from sim.robot import ArmModel


class FrankaException(Exception):
    pass


class CommandException(RuntimeError):
    pass


class ControlException(RuntimeError):
    pass


class InvalidOperationException(RuntimeError):
    pass


class NetworkException(RuntimeError):
    pass


class RealtimeException(RuntimeError):
    pass


class RealtimeConfig:
    kEnforce = "kEnforce"
    kIgnore = "kIgnore"


class Duration:
    def __init__(self, ms: int) -> None:
        self._ms = ms

    def to_sec(self) -> float:
        return self._ms / 1000.0


class RobotState:
    """The fields of pylibfranka.RobotState the link reads (lists, as pybind11 returns)."""

    def __init__(self, q, dq, tau_J, time_ms, m_load, F_x_Cload, I_load):
        self.q, self.dq, self.tau_J = list(q), list(dq), list(tau_J)
        self.time = Duration(time_ms)
        self.m_load, self.F_x_Cload, self.I_load = float(m_load), list(F_x_Cload), \
            list(I_load)


class Robot:
    """``pylibfranka.Robot(robot_ip_address, realtime_config)`` against a plant.

    ``refuse``: the text of the ``CommandException`` ``set_load`` raises (None: accepts);
    ``hold``: an event ``set_load`` waits for before it returns (a slow TCP command);
    ``fail``: ``"network"`` or ``"exclusive"`` makes ``read_once`` raise;
    ``stale``: states that still report the load before each ``set_load`` (the robot sent
    them before it applied the command: libfranka hands over queued states in order).
    """

    def __init__(self, robot_ip_address: str = "172.16.0.2",
                 realtime_config=RealtimeConfig.kEnforce, udp_timeout: float = 1.0,
                 free_running: bool = False) -> None:
        self.address, self.config = robot_ip_address, realtime_config
        self.kinematics = ArmModel(description="fr3")  # libfranka >= 0.10 serves the FR3
        self.path = excitation_path(2.0, model=self.kinematics)
        self.plant = ArmPlant(payload=default_test_payload(), description="fr3")
        self.plant.reset(self.path.q[0])
        self.k = 0
        self.load = (0.0, [0.0] * 3, [0.0] * 9)
        self.stale = 0
        self._old: tuple | None = None  # the load the stale states still report
        self._stale_left = 0
        self.skip_next = 0
        self.fail: str | None = None
        self.refuse: str | None = None
        self.hold: threading.Event | None = None
        self.udp_timeout = udp_timeout
        self._allow = threading.Semaphore(0)
        self.set_load_calls = 0
        self.free_running = free_running  # a state every ms, as the robot sends them

    def release(self, n: int = 1) -> None:
        """Let ``read_once`` return ``n`` more states."""
        self._allow.release(n)

    def read_once(self) -> RobotState:
        if self.free_running:
            time.sleep(1e-3)
        elif not self._allow.acquire(timeout=self.udp_timeout):
            raise NetworkException("libfranka: UDP receive: Timeout")
        if self.fail == "network":
            raise NetworkException("libfranka: UDP receive: Timeout")
        if self.fail == "exclusive":
            raise InvalidOperationException("libfranka: Cannot perform this operation while "
                                            "another control or read operation is running.")
        for _ in range(1 + self.skip_next):
            s = self.plant.step(self.path.q[self.k], self.path.dq[self.k], self.path.ddq[self.k])
            self.k += 1
        self.skip_next = 0
        m, c, i = self.load
        if self._stale_left > 0:
            self._stale_left -= 1
            m, c, i = self._old
        return RobotState(s.q, s.dq, s.tau_J, round(s.t * 1000), m, c, i)

    def set_load(self, *args) -> None:
        load_mass, F_x_Cload, load_inertia = args  # pybind11: positional, no names
        if len(F_x_Cload) != 3 or len(load_inertia) != 9:
            raise TypeError("set_load(): incompatible function arguments")
        self.set_load_calls += 1
        if self.hold is not None:
            self.hold.wait()
        if self.refuse is not None:
            raise CommandException(self.refuse)
        self._old, self._stale_left = self.load, self.stale
        self.load = (float(load_mass), list(F_x_Cload), list(load_inertia))


def install(monkeypatch, module) -> None:
    """Make ``module`` (a fake of pylibfranka, :func:`module`) the one ``open_link("franka",
    ...)`` connects through, in this process: as ``sys.modules["pylibfranka"]``, and in place of
    the child process a link opened by address runs pylibfranka in
    (:class:`firmware_bridge.franka_process.RobotProcess`), which would import the real binding
    and connect to the address."""
    import firmware_bridge.franka_link as franka_link

    def in_process(address, api, *, realtime):
        config = api.RealtimeConfig.kEnforce if realtime else api.RealtimeConfig.kIgnore
        return api.Robot(address, config)

    monkeypatch.setitem(sys.modules, "pylibfranka", module)
    monkeypatch.setattr(franka_link, "RobotProcess", in_process)


def module() -> types.SimpleNamespace:
    """The fake as a module (what ``FrankaLink(robot, api)`` takes)."""
    return types.SimpleNamespace(
        Robot=Robot, RobotState=RobotState, Duration=Duration, RealtimeConfig=RealtimeConfig,
        FrankaException=FrankaException, CommandException=CommandException,
        ControlException=ControlException, InvalidOperationException=InvalidOperationException,
        NetworkException=NetworkException, RealtimeException=RealtimeException)
