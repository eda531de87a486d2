"""A plant rollout written as the CAN log a controller would have sent: every cycle through
the controller's own encoder (:class:`firmware_bridge.can_link.CanControllerPort`: the DBC
codec, E2E protection, heartbeats) into python-can's log writer, so that ``iem calibrate``,
``iem identify`` and ``iem replay`` read it back as they read a recording of a real bus."""

from __future__ import annotations

import can

from firmware_bridge.can_link import CanControllerPort
from firmware_bridge.protocol import Heartbeat
from iem.types import JointState


class LogBus:
    """The controller port's bus: every frame it sends goes into a python-can log writer,
    stamped with the controller time of the cycle being sent."""

    def __init__(self, path) -> None:
        self.writer = can.Logger(str(path))
        self.now = 0.0
        self.channel_info = f"log {path}"

    def send(self, msg: can.Message, timeout=None) -> None:
        msg.timestamp = self.now
        self.writer.on_message_received(msg)

    def shutdown(self) -> None:
        self.writer.stop()


def write_log(rollout, path, profile: str = "fd", t0: float = 1000.0) -> None:
    """Write ``rollout``'s measured joint states (``t, q, dq, tau``: a
    :class:`sim.plant.Rollout`) as the CAN log ``path`` (``.blf .log .asc .trc``) of the
    ``profile`` wire, frames stamped ``t0`` s plus the controller time, a heartbeat every
    100 cycles."""
    bus = LogBus(path)
    port = CanControllerPort(bus, profile, owns_bus=False)
    try:
        for k in range(len(rollout)):
            t = float(rollout.t[k])
            bus.now = t0 + t
            port.tick(k, t)
            port.publish(JointState(t=t, q=rollout.q[k], dq=rollout.dq[k],
                                    tau_J=rollout.tau[k], cycle=k))
            if k % 100 == 0:
                port.heartbeat(Heartbeat("running", 0, k, 0))
    finally:
        bus.shutdown()
    assert port.saturated == 0 and port.send_errors == 0
