"""Reassembly never splices cycles, time unwrapping follows a drifting clock and detects
timing violations, and one well-formed frame with a jumping cycle counter is not believed."""

import math

import can
import numpy as np
import pytest

from firmware_bridge.can_link import CanControllerPort, CanDecoder, CanLink, can_message, open_bus
from firmware_bridge.faults import FaultSpec
from firmware_bridge.links import LinkCounters
from firmware_bridge.protocol import Heartbeat, profile
from firmware_bridge.reassembly import TimeUnwrapper
from firmware_bridge.replay import ReplaySource
from iem.types import JointState

from .conftest import synthetic_states
from .test_faults import drain as drain_for


def encoded(name, states, counter0=0, t0=1000.0):
    """Per cycle, its frames with time stamps ``t0 + controller time``."""
    js = profile(name).joint_state
    out = []
    for i, s in enumerate(states):
        frames, _ = js.encode(s, (counter0 + i) & 0x0F)
        msgs = [can_message(c, d) for c, d in frames]
        for m in msgs:
            m.timestamp = t0 + s.t
        out.append(msgs)
    return out


def feed(decoder, messages):
    return [s for m in messages if (s := decoder.push(m)) is not None]


# -- classic reassembly: an age limit --------------------------------------------------------
def test_classic_reassembly_never_splices_two_cycles():
    """Cycle 2 lacks its q3 frame; the next 31 cycles lack their headers (nothing completes,
    nothing is delivered) and cycle 18, with cycle 2's alive counter, is lost whole; then
    cycle 34's q3 frame arrives with that alive counter again. Keyed by the alive counter
    alone, it completed cycle 2 with cycle 34's q3."""
    states = synthetic_states(33, stride=1, start=2)  # cycles 2..34
    cycles = encoded("classic", states)  # alive counters 2 -> 0, 34 -> 0 (32 steps on)
    q3 = 3  # frame index of JointState3 (after the header)
    stream = [m for k, m in enumerate(cycles[0]) if k != q3]
    for k, frames in enumerate(cycles[1:-1], start=1):
        if k != 16:  # cycle 18 lost whole
            stream += frames[1:]  # no header: never complete
    stream.append(cycles[-1][q3])
    dec = CanDecoder("classic")
    got = feed(dec, stream)
    assert got == []  # before the age limit: [cycle 2 with q3 of cycle 34]
    stream2 = [m for k, m in enumerate(cycles[-1]) if k != q3]  # the rest of cycle 34
    got = feed(dec, stream2)
    assert [s.cycle for s in got] == [34]
    np.testing.assert_allclose(got[0].q, states[-1].q, atol=1e-5)


def test_a_late_frame_newer_than_the_last_delivered_is_delivered():
    """Classic: cycle 11's q5 frame arrives after cycle 12's frames (cycle 12 lost one
    frame): cycle 11 is still newer than the last delivered (10) and is delivered. FD: a frame
    that overtook nothing newer is delivered; one older than the last delivered is not."""
    cycles = encoded("classic", synthetic_states(3, stride=2, start=20))  # 20, 22, 24
    late = cycles[1][5]
    stream = cycles[0] + [m for m in cycles[1] if m is not late] + cycles[2][:-1] + [late]
    dec = CanDecoder("classic")
    assert [s.cycle for s in feed(dec, stream)] == [20, 22]
    assert dec.counters.orphaned == 0 and dec.counters.out_of_order == 0
    fd = encoded("fd", synthetic_states(4))
    dec = CanDecoder("fd")
    got = feed(dec, [fd[0][0], fd[2][0], fd[1][0], fd[3][0]])
    assert [s.cycle for s in got] == [0, 2, 3] and dec.counters.out_of_order == 1


# -- time ----------------------------------------------------------------------------------
def test_a_drifting_controller_clock_is_unwrapped_across_a_long_gap():
    """A controller whose clock runs 0.6 % fast: after 1 s of cycles, 100 s of silence. At
    the nominal 1 ms per cycle the gap is 100.0 s and the 20-bit wrap (1.05 s) picked the
    wrong lap (99.55 s instead of 100.60 s); at the learnt rate it is exact."""
    counters = LinkCounters()
    clock = TimeUnwrapper(bits=20, scale=1e-6, period_us=1000, counters=counters)
    mod, rate = 1 << 20, 1006  # µs per cycle
    for k in range(1000):
        clock((k * rate) % mod, k)
    k = 999 + 100_000
    assert clock((k * rate) % mod, k) == pytest.approx(k * rate * 1e-6, abs=1e-6)
    assert clock(((k + 1) * rate) % mod, k + 1) == pytest.approx((k + 1) * rate * 1e-6)
    assert counters.timing == 0


def test_a_timing_violation_is_detected_counted_and_reported(caplog):
    """Time that runs at twice the cycle counter's pace breaks the protocol's requirement."""
    cycles = []
    for i, s in enumerate(synthetic_states(40)):
        t = s.t if i < 20 else s.t + (i - 19) * 1e-3  # from cycle 20 on, 2 ms per cycle
        cycles.append(JointState(t=t, q=s.q, dq=s.dq, tau_J=s.tau_J, cycle=s.cycle))
    dec = CanDecoder("classic")
    got = feed(dec, [m for c in encoded("classic", cycles) for m in c])
    assert len(got) == 40  # delivered, with the wire's time
    assert dec.counters.timing == 20
    assert "Time advanced 2.000 ms over 1 cycles" in dec._assembler.clock.last_violation
    assert "20 cycles break the timing requirement" in dec.counters.summary()
    warned = [r for r in caplog.records if getattr(r, "event", "") == "timing_violation"]
    assert len(warned) == 2 and "the protocol allows 1.000 ms" in warned[0].getMessage()


# -- a jumping cycle counter -------------------------------------------------------------------
BOGUS = 100_000


def bogus(state: JointState) -> JointState:
    return JointState(t=state.t, q=state.q, dq=state.dq, tau_J=state.tau_J,
                      cycle=state.cycle + BOGUS)


def publish_with_a_bogus_frame(port, n=300, at=150):
    """The controller's own encoder (valid CRC, alive counter in step) with one cycle whose
    cycle counter jumps ahead by BOGUS; heartbeats every 100 cycles."""
    for s in synthetic_states(n):
        port.tick(s.cycle, s.t)
        port.publish(bogus(s) if s.cycle == at else s)
        if s.cycle % 100 == 0:
            port.heartbeat(Heartbeat("running", 0, s.cycle, 0))


def drain(link):
    return drain_for(link, 0.1)


@pytest.mark.parametrize("name", ["fd", "classic"])
def test_one_bogus_frame_with_a_valid_crc_is_dropped_not_believed(name, channel):
    """5 % of the frames dropped by the fault injector, and one cycle whose counter jumps
    ahead by 100,000 (sent by the controller's own encoder: valid CRC, alive counter in
    step): before, a false silence, the next good cycles dropped as stale and lost + 99,999."""
    spec = FaultSpec(drop=0.05, seed={"fd": 3, "classic": 5}[name])
    port = CanControllerPort(open_bus("virtual", channel, name), name, spec, record_faults=True)
    link = CanLink(open_bus("virtual", channel, name), name)
    parts = profile(name).joint_state.parts
    try:
        publish_with_a_bogus_frame(port)
        got = drain(link)
    finally:
        link.close()
        port.close()
    c = link.counters
    actions = [a for key, a in port.faults.log if key in parts]  # joint frames, in order
    published = range(0, 300, port.stride)
    whole = {k for i, k in enumerate(published)
             if all(a == "ok" for a in actions[i * len(parts):(i + 1) * len(parts)])}
    assert 150 in whole  # the seed's draws: the bogus cycle goes through whole
    cycles = [s.cycle for s in got]
    assert cycles == sorted(whole - {150})
    assert c.implausible == 1 and c.stale == 0 and c.out_of_order == 0
    assert c.silences == 1  # only the final one, when the stream ended
    assert c.lost == (cycles[-1] - cycles[0]) // port.stride + 1 - len(cycles)  # not + 99,999


def test_a_bogus_serial_message_is_dropped_too():
    from firmware_bridge.serial_link import SerialDecoder
    from firmware_bridge.serial_wire import encode_joint_state, frame

    states = synthetic_states(200)
    dec = SerialDecoder()
    got = []
    for s in states:
        got += dec.feed(frame(encode_joint_state(bogus(s) if s.cycle == 120 else s)))
    assert [s.cycle for s in got] == [k for k in range(200) if k != 120]
    assert dec.counters.implausible == 1 and dec.counters.lost == 1


def test_a_real_jump_is_told_apart_from_a_bogus_frame():
    """Without a heartbeat to vouch for it, the first cycle of a jump is held back; the next
    one continuing from it confirms it (the controller really jumped). With a heartbeat at
    the new count, the jump is believed at once."""
    before = synthetic_states(50)
    after = synthetic_states(50, start=500_000)
    dec = CanDecoder("fd")
    got = feed(dec, [m for c in encoded("fd", before + after) for m in c])
    assert [s.cycle for s in got] == [*range(50), *range(500_001, 500_050)]
    assert dec.counters.implausible == 1 and dec.counters.lost == 500_001 - 49 - 1
    hb_codec = profile("fd").heartbeat
    heartbeat = can.Message(arbitration_id=hb_codec.frame.frame_id,
                            data=hb_codec.encode("running", 0, 500_000, 0, 0),
                            is_extended_id=False, timestamp=1000.0 + 499.999)
    dec = CanDecoder("fd")
    frames = encoded("fd", before + after)
    got = feed(dec, [m for c in frames[:50] for m in c] + [heartbeat]
               + [m for c in frames[50:] for m in c])
    assert [s.cycle for s in got] == [*range(50), *range(500_000, 500_050)]
    assert dec.counters.implausible == 0


def test_replay_of_a_log_with_a_bogus_frame_reads_the_whole_file(tmp_path, channel):
    log = tmp_path / "bogus.log"
    recorder = open_bus("virtual", channel, "fd")
    port = CanControllerPort(open_bus("virtual", channel, "fd"), "fd")
    try:
        publish_with_a_bogus_frame(port)
        writer = can.Logger(str(log))
        while (msg := recorder.recv(0)) is not None:
            writer.on_message_received(msg)
        writer.stop()
    finally:
        port.close()
        recorder.shutdown()
    with ReplaySource(log, "fd") as src:
        got = list(src)
    assert [s.cycle for s in got] == [k for k in range(300) if k != 150]
    assert src.counters.implausible == 1 and src.counters.lost == 1
    assert not math.isnan(got[-1].t)


def write_log(path, messages):
    writer = can.Logger(str(path))
    for m in messages:
        writer.on_message_received(m)
    writer.stop()


@pytest.mark.parametrize("gap_s", [0.5, 0.0])
def test_a_controller_restart_in_a_log_does_not_make_the_rest_stale(tmp_path, gap_s):
    """Cycles 0..299, then the controller restarts at cycle 0 (after a 0.5 s pause, or at
    once). The live link would have gone silent (no new cycle for 0.1 s) and accepted the
    restart; the replay does the same on the recorded clock instead of dropping the rest of
    the file as stale."""
    first = encoded("fd", synthetic_states(300), t0=1000.0)
    second = encoded("fd", synthetic_states(300), counter0=300, t0=1000.3 + gap_s)
    log = tmp_path / "restart.log"
    write_log(log, [m for c in first + second for m in c])
    with ReplaySource(log, "fd") as src:
        got = [s.cycle for s in src]
    assert got[:300] == list(range(300))
    resumed = got[300]
    if gap_s:
        assert resumed == 0
    else:  # at once: the ~100 ms the live link waited for a new cycle were stale
        assert 99 <= resumed <= 101
    assert got[300:] == list(range(resumed, 300))
    assert src.counters.resyncs == 1 and src.counters.silences == 1
