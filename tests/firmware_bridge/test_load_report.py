"""Each sink's ``load_report`` against the simulated controller's own record of the load in
force: CAN (python-can's virtual bus, both profiles) and serial (a pty pair) carry its
sequence number in the heartbeat; a command the controller lost leaves it where it was."""

import itertools
import time

import pytest

from firmware_bridge.errors import AckTimeout
from firmware_bridge.messages import LoadReport
from iem.payload import Payload

pytest.importorskip("mujoco", reason="the simulated controller needs MuJoCo")

from deploy.simcell.controller import SimController
from sim.paths import excitation_path

_channels = itertools.count()
TOOL = Payload("tool", 0.73, (0.01, -0.02, 0.06), (2e-3, 1e-4, -2e-4, 3e-3, 3e-4, 1.5e-3))


def _ends(kind: str):
    """``(controller port, link)`` of ``kind``: "fd", "classic" (virtual CAN) or "serial"."""
    if kind == "serial":
        from firmware_bridge.pty_pair import PtyPair
        from firmware_bridge.serial_link import SerialControllerPort, SerialLink, open_serial

        pty = PtyPair()
        return SerialControllerPort(pty), SerialLink(open_serial(pty.slave_path))
    from firmware_bridge.can_link import CanControllerPort, CanLink, open_bus

    channel = f"load-report-{next(_channels)}"
    return (CanControllerPort(open_bus("virtual", channel, kind), kind),
            CanLink(open_bus("virtual", channel, kind), kind))


def _drain(link) -> None:
    """Read every joint state that has arrived (the link takes heartbeats meanwhile)."""
    while True:
        try:
            link.read(0.005)
        except TimeoutError:
            return


def _run(sim, link, cycles: int) -> None:
    """The controller runs ``cycles`` cycles (a heartbeat every 100); the link reads."""
    for _ in range(cycles // 20):
        sim.run(cycles=20)
        time.sleep(0.002)  # a pty delivers in its own time
        _drain(link)


@pytest.mark.parametrize("kind", ["fd", "classic", "serial"])
def test_the_report_follows_the_heartbeat_and_ignores_a_lost_command(kind):
    port, link = _ends(kind)
    sim = SimController(port, path=excitation_path(1.0), realtime=False, drop_commands=1)
    try:
        assert link.load_report is None  # nothing heard yet
        _run(sim, link, 200)
        report = link.load_report
        assert isinstance(report, LoadReport)
        assert (report.seq, report.load, report.has_values) == (0, None, False)
        assert abs(report.t - time.perf_counter()) < 60

        lost = link.send(TOOL)
        _run(sim, link, 300)
        with pytest.raises(AckTimeout):
            link.wait_ack(lost, 0.05)
        assert link.load_report.seq == 0 and sim.stats()["dropped_commands"] == 1

        seq = link.send(TOOL)
        _run(sim, link, 300)
        assert link.wait_ack(seq, 0.5).applied
        assert link.load_report.seq == seq == sim.load_seq
        assert [a["seq"] for a in sim.stats()["applied"]] == [seq]

        cleared = link.send(None)
        _run(sim, link, 300)
        assert link.load_report.seq == cleared and sim.plant.controller_load is None
        assert sim.stats()["send_errors"] == 0
    finally:
        link.close()
        sim.close()
