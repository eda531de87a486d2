"""Hardware in the loop: one test case over (a) the virtual bus in-process, (b) slcan over a
pty with the simulated controller in a separate process, (c) vcan (skipped without AF_CAN)."""

import numpy as np
import pytest

from deploy.simcell.controller import SimController
from firmware_bridge.can_link import CanControllerPort, CanLink, open_bus
from sim.family import default_test_payload
from sim.paths import Q0, excitation_path

from .hil import Controller, vcan_unavailable


@pytest.fixture
def controller_link(request, tmp_path, channel):
    """``(link, stats)`` with a running simulated controller behind ``link``."""
    bus, profile = request.param
    if bus == "virtual":
        port = CanControllerPort(open_bus("virtual", channel, profile), profile)
        controller = SimController(port, path=excitation_path(4.0)).start()
        link = CanLink.open("virtual", channel, profile)
        try:
            yield link
        finally:
            link.close()
            controller.close()
        assert controller.error is None
        return
    if bus == "slcan_pty":
        child = Controller(["--interface", "slcan-pty", "--profile", profile],
                           tmp_path / "controller.log", announce=True)
        channel_ = child.line
        kind = "slcan"
    else:
        reason = vcan_unavailable()
        if reason:
            pytest.skip(reason)
        child = Controller(["--interface", "socketcan", "--channel", "vcan0", "--profile",
                            profile], tmp_path / "controller.log", announce=False)
        channel_, kind = "vcan0", "socketcan"
    link = None
    try:
        link = CanLink.open(kind, channel_, profile)
        yield link
    finally:
        if link is not None:
            link.close()
        log = child.stop()
    assert "Traceback" not in log, log


BUSES = [("virtual", "fd"), ("virtual", "classic"), ("slcan_pty", "fd"),
         ("slcan_pty", "classic"),
         pytest.param(("vcan", "fd"), marks=pytest.mark.vcan, id="vcan-fd"),
         pytest.param(("vcan", "classic"), marks=pytest.mark.vcan, id="vcan-classic")]


@pytest.mark.hil
@pytest.mark.parametrize("controller_link", BUSES, indirect=True,
                         ids=lambda p: "-".join(p) if isinstance(p, tuple) else p)
def test_joint_states_flow_and_the_payload_is_written_back(controller_link):
    link = controller_link
    stride = link.profile.joint_state.stride
    first = link.read(10.0)  # the child process needs a moment to start
    states = [first] + [link.read(1.0) for _ in range(199)]
    cycles = np.array([s.cycle for s in states])
    ts = np.array([s.t for s in states])
    assert np.all(np.diff(cycles) > 0) and np.all(cycles % stride == 0)
    np.testing.assert_allclose(np.diff(ts), np.diff(cycles) * 1e-3, atol=2e-6)
    q = np.array([s.q for s in states])
    assert np.all(np.abs(q - Q0) < 0.6)  # the excitation path stays near Q0
    assert np.all(np.isfinite([s.tau_J for s in states]))

    payload = default_test_payload()
    seq = link.send(payload)
    ack = link.wait_ack(seq, 5.0)
    assert ack.applied and ack.seq == seq
    assert ack.load.mass == pytest.approx(payload.mass, abs=1e-4)
    np.testing.assert_allclose(ack.load.com, payload.com, atol=1e-5)
    np.testing.assert_allclose(ack.load.inertia, payload.inertia, atol=1e-6)

    cleared = link.wait_ack(link.send(None), 5.0)
    assert cleared.applied and cleared.load is None

    for _ in range(400):  # a heartbeat comes every 100 ms
        link.read(1.0)
        if link.last_heartbeat is not None and link.last_heartbeat.load_seq == cleared.seq:
            break
    assert link.last_heartbeat.state == "running"
    c = link.counters
    assert c.crc == c.malformed == c.stale == 0, c.summary()
