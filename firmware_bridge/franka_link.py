"""The pylibfranka backend (extra ``franka``): a real Franka robot as source and sink.

- Source: ``Robot.read_once()`` returns a ``RobotState``; the joint state is its ``q``,
  ``dq`` and ``tau_J`` (link-side torques), ``t = state.time.to_sec()`` and, since Franka
  states carry no cycle counter, ``cycle = round(t * 1000)`` (the robot's clock counts 1 ms
  cycles). Cycles skipped between two reads count as ``lost``.
- Sink: ``Robot.set_load(load_mass, F_x_Cload, load_inertia)`` (positional: the binding
  names no arguments), CoM in the flange frame, inertia about the CoM column-major, exactly
  :meth:`sim.payload.Payload.set_load_args`; clearing the load sends mass 0. The
  acknowledgement is the load the robot reports afterwards (``m_load``, ``F_x_Cload``,
  ``I_load`` of the next state), refused (``applied=False``) if ``set_load`` raised a
  ``CommandException``.

``read_once`` cannot run while another control loop holds the robot (libfranka raises
``InvalidOperationException``); the plug-in reads beside the robot's own motion, not inside
a libfranka control loop. pylibfranka is imported only when a robot is opened.
"""

from __future__ import annotations

import time

from iem.types import JointState
from sim.payload import Payload

from .errors import AckTimeout, BridgeConfigError, ControllerSilent, LinkError
from .links import LinkCounters
from .protocol import LoadAck
from .reassembly import CYCLE_MOD, Sequencer


def _franka_error(exc: Exception, name: str, what: str) -> LinkError:
    """pylibfranka raises RuntimeError subclasses named ``NetworkException`` etc."""
    kind = type(exc).__name__
    cls = ControllerSilent if kind == "NetworkException" else LinkError
    return cls(f"{name}: {what} failed: {kind}: {exc}")


class FrankaLink:
    """Source and sink over a ``pylibfranka.Robot`` (or an object with its signatures)."""

    def __init__(self, robot, *, name: str = "Franka robot", owns_robot: bool = True) -> None:
        self.robot = robot
        self.name = name
        self.counters = LinkCounters()
        self._seq_order = Sequencer(self.counters)
        self._seq = 0
        self._pending: JointState | None = None
        self.last_ack: LoadAck | None = None
        self.acks: dict[int, LoadAck] = {}
        self.last_heartbeat = None
        self._owns_robot = owns_robot

    @classmethod
    def open(cls, address: str, realtime: bool = False) -> FrankaLink:
        """Connect to the robot at ``address``. ``realtime=False`` passes
        ``RealtimeConfig.kIgnore``: reading states needs no real-time kernel."""
        try:
            import pylibfranka
        except ImportError as exc:
            raise BridgeConfigError("the franka link needs pylibfranka: install the extra, "
                                    "pip install 'iem-payload[franka]'") from exc
        config = pylibfranka.RealtimeConfig.kEnforce if realtime else \
            pylibfranka.RealtimeConfig.kIgnore
        try:
            robot = pylibfranka.Robot(address, config)
        except Exception as exc:
            raise _franka_error(exc, f"Franka robot {address!r}", "connecting") from exc
        return cls(robot, name=f"Franka robot {address!r}")

    # -- source ----------------------------------------------------------------------------
    def _read_state(self):
        try:
            return self.robot.read_once()
        except Exception as exc:
            raise _franka_error(exc, self.name, "read_once") from exc

    def _joint_state(self, rs) -> JointState | None:
        self.counters.received += 1
        t = float(rs.time.to_sec())
        cycle = round(t * 1000.0) % CYCLE_MOD
        verdict = self._seq_order.judge(cycle)
        if verdict != "deliver":
            setattr(self.counters, verdict, getattr(self.counters, verdict) + 1)
            return None
        self._seq_order.deliver(cycle)
        return JointState(t=t, q=rs.q, dq=rs.dq, tau_J=rs.tau_J, cycle=cycle)

    def read(self, timeout: float | None = None) -> JointState:
        """The next robot state; ``timeout`` is libfranka's own (its network timeout)."""
        if self._pending is not None:
            state, self._pending = self._pending, None
            return state
        while True:
            state = self._joint_state(self._read_state())
            if state is not None:
                return state

    # -- sink ------------------------------------------------------------------------------
    def send(self, payload: Payload | None) -> int:
        if payload is not None:
            payload.check()
            mass, com, inertia = payload.set_load_args()
        else:
            mass, com, inertia = 0.0, [0.0, 0.0, 0.0], [0.0] * 9
        self._seq = self._seq % 255 + 1
        applied = True
        try:
            self.robot.set_load(float(mass), [float(v) for v in com],
                                [float(v) for v in inertia])
        except Exception as exc:
            if type(exc).__name__ != "CommandException":
                raise _franka_error(exc, self.name, "set_load") from exc
            applied = False
        rs = self._read_state()
        self._pending = self._joint_state(rs)
        m = float(rs.m_load)
        load = None if m == 0.0 else Payload.from_set_load(m, list(rs.F_x_Cload),
                                                          list(rs.I_load), name="robot")
        ack = LoadAck(seq=self._seq, applied=applied, load=load, t=time.perf_counter())
        self.last_ack = self.acks[self._seq] = ack
        self.counters.acks += 1
        return self._seq

    def wait_ack(self, seq: int, timeout: float = 1.0) -> LoadAck:
        """``set_load`` is synchronous: the ack exists as soon as ``send`` returned."""
        try:
            return self.acks[seq]
        except KeyError:
            raise AckTimeout(f"{self.name}: no payload command {seq} was sent") from None

    def close(self) -> None:
        if self._owns_robot:
            self.robot = None


def open_franka_link(kind: str, channel: str, profile: str | None = None,
                     realtime: bool = False) -> FrankaLink:
    """Opener for :func:`firmware_bridge.links.open_link`: ``channel`` is the robot's IP
    (``profile`` is a CAN notion and not used)."""
    return FrankaLink.open(channel, realtime=realtime)
