"""Fault injection: with 5 % dropped and 1 % corrupted frames every bad frame is counted by
kind and every good cycle is delivered (CAN, both profiles, and the serial link)."""

import pytest

from firmware_bridge.can_link import CanControllerPort, CanLink, open_bus
from firmware_bridge.errors import BridgeConfigError, ControllerSilent
from firmware_bridge.faults import FaultInjector, FaultSpec
from firmware_bridge.protocol import Heartbeat
from firmware_bridge.serial_link import SerialControllerPort, SerialDecoder

from .conftest import synthetic_states

N_CYCLES = 3000


def drain(link, timeout: float = 0.05):
    """Every cycle the link delivers until it is silent for ``timeout`` s."""
    got = []
    while True:
        try:
            got.append(link.read(timeout))
        except ControllerSilent:
            return got


def good_cycles(log, parts: int, first_key_of_cycle) -> list[int]:
    """Indices of the published cycles whose frames all went out intact."""
    good, index, ok = [], -1, True
    for key, action in log:
        if key is first_key_of_cycle:
            if index >= 0 and ok:
                good.append(index)
            index, ok = index + 1, True
        ok = ok and action == "ok"
    if index >= 0 and ok:
        good.append(index)
    return good


@pytest.mark.parametrize("name", ["fd", "classic"])
def test_drops_and_corruption_are_counted_and_good_cycles_delivered(name, channel):
    spec = FaultSpec(drop=0.05, corrupt=0.01, seed=7)
    port = CanControllerPort(open_bus("virtual", channel, name), name, spec, record_faults=True)
    link = CanLink(open_bus("virtual", channel, name), name)
    stride = port.stride
    try:
        states = synthetic_states(N_CYCLES, stride)
        for s in states:
            port.tick(s.cycle, s.t)
            port.publish(s)
        port.tick(states[-1].cycle + stride, 0.0)
        got = drain(link)
    finally:
        link.close()
        port.close()
    log = port.faults.log
    first = port.profile.joint_state.parts[0]
    good = good_cycles(log, len(port.profile.joint_state.parts), first)
    corrupted = sum(1 for _, a in log if a == "corrupt")
    dropped = sum(1 for _, a in log if a == "drop")
    assert dropped > 0.03 * len(log) and corrupted > 0.005 * len(log)
    c = link.counters
    assert [s.cycle for s in got] == [states[i].cycle for i in good]
    assert c.crc == corrupted and c.malformed == 0
    assert c.delivered == len(good)
    # every published cycle is delivered or lost (bar bad cycles at the very end)
    last_good = good[-1]
    assert c.lost == last_good + 1 - len(good) - good[0]
    assert c.duplicate == c.out_of_order == c.stale == 0


@pytest.mark.parametrize("name", ["fd", "classic"])
def test_duplicated_and_delayed_frames_are_counted(name, channel):
    spec = FaultSpec(duplicate=0.03, delay=0.02, delay_cycles=5, seed=3)
    port = CanControllerPort(open_bus("virtual", channel, name), name, spec, record_faults=True)
    link = CanLink(open_bus("virtual", channel, name), name)
    try:
        for s in synthetic_states(1500, port.stride):
            port.tick(s.cycle, s.t)
            port.publish(s)
        got = drain(link)
    finally:
        link.close()
        port.close()
    counts = port.faults.counts
    c = link.counters
    assert c.duplicate == counts["duplicate"]
    assert c.out_of_order >= 1 and c.crc == c.malformed == 0
    cycles = [s.cycle for s in got]
    assert cycles == sorted(set(cycles))
    if name == "fd":  # one frame per cycle: every delayed frame comes too late
        assert c.out_of_order == counts["delay"]
        assert c.lost == counts["delay"]


def test_serial_drops_and_corruption_are_counted():
    class Sink:
        def __init__(self):
            self.data = bytearray()

        def write(self, b):
            self.data += b

        def close(self):
            pass

    sink = Sink()
    port = SerialControllerPort(sink, FaultSpec(drop=0.05, corrupt=0.01, seed=1),
                                record_faults=True)
    states = synthetic_states(N_CYCLES)
    for s in states:
        port.tick(s.cycle, s.t)
        port.publish(s)
    dec = SerialDecoder()
    got = dec.feed(bytes(sink.data))
    log = port.faults.log
    good = [i for i, (_, a) in enumerate(log) if a == "ok"]
    assert [s.cycle for s in got] == good
    c = dec.counters
    assert c.crc == sum(1 for _, a in log if a == "corrupt") and c.malformed == 0
    assert c.lost == good[-1] + 1 - len(good) - good[0]


def test_silence_makes_the_link_raise_and_then_recover(channel):
    spec = FaultSpec(silence_at=0.05, silence_for=0.3)
    port = CanControllerPort(open_bus("virtual", channel, "fd"), "fd", spec)
    link = CanLink(open_bus("virtual", channel, "fd"), "fd", silence_timeout=0.05)
    try:
        for s in synthetic_states(500):
            port.tick(s.cycle, s.t)
            if s.cycle % 50 == 0:  # the heartbeat first: it vouches for the jump after the gap
                port.heartbeat(Heartbeat("running", 0, s.cycle, 0))
            port.publish(s)
        got = drain(link)
        assert link.counters.silences == 1
        with pytest.raises(ControllerSilent, match="last heartbeat"):
            link.read(0.01)
    finally:
        link.close()
        port.close()
    cycles = [s.cycle for s in got]
    assert cycles[:50] == list(range(50)) and cycles[50] == 350
    assert link.counters.lost == 300 and link.counters.implausible == 0
    assert port.faults.silenced == 300 + 6


def test_fault_specs_are_checked():
    with pytest.raises(BridgeConfigError, match=r"drop = 1\.5"):
        FaultSpec(drop=1.5)
    with pytest.raises(BridgeConfigError, match=r"add up to 1\.2"):
        FaultSpec(drop=0.6, corrupt=0.6)
    inj = FaultInjector(FaultSpec(corrupt=1.0, seed=0))
    data = bytes(8)
    (out,) = inj.apply("k", data, 0)
    assert bin(int.from_bytes(out, "little")).count("1") == 1


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fd", "classic"])
def test_soak_real_time_controller_with_every_fault(name, channel):
    """20 s of the real-time controller on the virtual bus with every kind of fault."""
    from deploy.simcell.controller import SimController

    spec = FaultSpec(drop=0.02, corrupt=0.01, duplicate=0.01, delay=0.01, silence_at=8.0,
                     silence_for=0.5, seed=11)
    port = CanControllerPort(open_bus("virtual", channel, name), name, spec)
    link = CanLink(open_bus("virtual", channel, name), name, silence_timeout=0.2)
    got, silences = [], 0
    with SimController(port) as ctl:
        while ctl.cycles < 20_000:
            try:
                got.append(link.read())
            except ControllerSilent:
                silences += 1
    got += drain(link)  # what was still queued when the controller stopped
    link.close()
    assert ctl.error is None and silences >= 1
    c = link.counters
    cycles = [s.cycle for s in got]
    assert cycles == sorted(set(cycles))
    assert c.crc == port.faults.counts["corrupt"] and c.malformed == 0
    published = (cycles[-1] - cycles[0]) // port.stride + 1
    assert c.delivered + c.lost == published
