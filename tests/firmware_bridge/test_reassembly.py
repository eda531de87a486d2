"""Cycle reassembly: every kind of bad frame is dropped and counted, good cycles go through."""

import itertools

import can
import pytest

from firmware_bridge.can_link import CanDecoder, can_message
from firmware_bridge.links import LinkCounters
from firmware_bridge.protocol import profile
from firmware_bridge.reassembly import Sequencer, TimeUnwrapper

from .conftest import synthetic_states


def frames_of(name, states, counter0=0):
    """Per cycle, the list of can.Messages of the encoded state."""
    js = profile(name).joint_state
    out = []
    for i, s in enumerate(states):
        frames, _ = js.encode(s, (counter0 + i) & 0x0F)
        out.append([can_message(c, d) for c, d in frames])
    return out


def feed(decoder, messages):
    return [s for m in messages if (s := decoder.push(m)) is not None]


@pytest.mark.parametrize("name", ["fd", "classic"])
def test_a_clean_stream_is_delivered_in_order(name):
    stride = profile(name).joint_state.stride
    states = synthetic_states(40, stride)
    dec = CanDecoder(name)
    got = feed(dec, [m for c in frames_of(name, states) for m in c])
    assert [s.cycle for s in got] == [s.cycle for s in states]
    assert dec.counters.delivered == 40 and not dec.counters.dropped() and dec.counters.lost == 0


@pytest.mark.parametrize("name", ["fd", "classic"])
def test_duplicates_are_dropped_and_counted(name):
    cycles = frames_of(name, synthetic_states(5, profile(name).joint_state.stride))
    dec = CanDecoder(name)
    msgs = []
    for c in cycles:
        for m in c:
            msgs += [m, m]
    got = feed(dec, msgs)
    assert len(got) == 5
    assert dec.counters.duplicate == sum(len(c) for c in cycles)


def test_fd_late_frames_are_out_of_order_and_gaps_are_lost():
    cycles = frames_of("fd", synthetic_states(10))
    dec = CanDecoder("fd")
    order = [0, 1, 3, 2, 4, 7, 8, 9]  # 2 arrives late, 5 and 6 never
    got = feed(dec, [cycles[i][0] for i in order])
    assert [s.cycle for s in got] == [0, 1, 3, 4, 7, 8, 9]
    c = dec.counters
    assert c.out_of_order == 1 and c.lost == 1 + 2


def test_classic_late_frame_is_out_of_order_and_its_cycle_orphaned():
    cycles = frames_of("classic", synthetic_states(4, 2))
    dec = CanDecoder("classic")
    late = cycles[1][3]
    msgs = cycles[0] + [m for m in cycles[1] if m is not late] + cycles[2] + [late] + cycles[3]
    got = feed(dec, msgs)
    assert [s.cycle for s in got] == [0, 4, 6]
    c = dec.counters
    assert c.lost == 1 and c.orphaned == 7 and c.out_of_order == 1


def test_classic_frames_of_two_cycles_interleaved_still_complete():
    cycles = frames_of("classic", synthetic_states(2, 2))
    dec = CanDecoder("classic")
    a, b = cycles
    msgs = a[:4] + b[:4] + a[4:] + b[4:]
    got = feed(dec, msgs)
    assert [s.cycle for s in got] == [0, 2]
    assert not dec.counters.dropped()


def test_the_same_cycle_number_with_new_content_is_stale():
    js = profile("fd").joint_state
    s0, s1 = synthetic_states(2)
    frozen = type(s1)(t=s1.t, q=s1.q, dq=s1.dq, tau_J=s1.tau_J, cycle=0)  # cycle did not advance
    msgs = [can_message(c, d) for st_, k in ((s0, 0), (frozen, 1)) for c, d in js.encode(st_, k)[0]]
    dec = CanDecoder("fd")
    assert len(feed(dec, msgs)) == 1
    assert dec.counters.stale == 1


def test_a_repeated_alive_counter_is_stale():
    js = profile("fd").joint_state
    s0, s1, s2 = synthetic_states(3)
    frames = [can_message(c, d) for s, k in ((s0, 4), (s1, 4), (s2, 5))
              for c, d in js.encode(s, k)[0]]
    dec = CanDecoder("fd")
    assert [s.cycle for s in feed(dec, frames)] == [0, 2]
    assert dec.counters.stale == 1 and dec.counters.lost == 1


def test_much_older_cycles_are_stale_and_a_restart_is_accepted_after_a_silence():
    old = frames_of("fd", synthetic_states(1, start=10_000))[0][0]
    new = frames_of("fd", synthetic_states(3, start=20_000), counter0=5)
    restart = frames_of("fd", synthetic_states(2, start=0), counter0=9)
    dec = CanDecoder("fd")
    feed(dec, [c[0] for c in new])
    assert dec.push(old) is None and dec.counters.stale == 1
    assert feed(dec, [c[0] for c in restart]) == [] and dec.counters.stale == 3
    dec.resync()  # what the link does when it raises ControllerSilent
    got = feed(dec, [c[0] for c in frames_of("fd", synthetic_states(2), counter0=12)])
    assert [s.cycle for s in got] == [0, 1] and dec.counters.resyncs == 1


def test_crc_and_malformed_frames_are_counted_by_kind():
    cycle = frames_of("classic", synthetic_states(1))[0]
    bad_crc = cycle[2].data.copy()
    bad_crc[5] ^= 0x10
    dec = CanDecoder("classic")
    msgs = [
        can.Message(arbitration_id=0x112, data=bad_crc, is_extended_id=False),          # crc
        can.Message(arbitration_id=0x112, data=cycle[2].data[:7], is_extended_id=False),  # len
        can.Message(arbitration_id=0x112, data=cycle[2].data, is_fd=True,
                    is_extended_id=False),                                            # FD flag
        can.Message(arbitration_id=0x112, is_remote_frame=True, dlc=8,
                    is_extended_id=False),                                            # remote
        can.Message(arbitration_id=0x7FF, data=b"\x01", is_extended_id=False),       # foreign
        can.Message(arbitration_id=0x112, data=cycle[2].data, is_extended_id=True),   # foreign
        can.Message(is_error_frame=True),
    ]
    assert feed(dec, msgs) == []
    c = dec.counters
    assert (c.crc, c.malformed, c.foreign, c.error_frames, c.received) == (1, 3, 2, 1, 7)
    assert "crc" in c.summary() and "malformed 3" in c.summary()
    assert len(feed(dec, cycle)) == 1  # the good ones still complete


def test_unknown_multiplexer_value_is_malformed():
    prof = profile("classic")
    frame = prof.ack.frame
    raw = {"Seq": 1, "Mass": 0, "ComX": 0, "Status": 0}
    data = bytearray(frame.pack(raw, 0, mux=0))
    data[1] = (data[1] & 0x0F) | (7 << 4)  # Mux 7 does not exist
    data = bytes(frame.e2e.protect(data, 0))
    dec = CanDecoder("classic")
    dec.push(can.Message(arbitration_id=frame.frame_id, data=data, is_extended_id=False))
    assert dec.counters.malformed == 1
    assert "multiplexer value 7" in str(dec.last_error)


def test_sequencer_wraps_with_serial_arithmetic():
    c = LinkCounters()
    seq = Sequencer(c, stride=2)
    for cycle in (2**32 - 4, 2**32 - 2, 0, 2, 6):
        assert seq.judge(cycle) == "deliver"
        seq.deliver(cycle)
    assert c.lost == 1 and c.delivered == 5
    assert seq.judge(4) == "out_of_order" and seq.judge(6) == "stale"
    assert seq.judge(6 - 2 * 17) == "stale"  # beyond the 16-cycle window


def test_time_unwraps_across_the_wire_modulus_even_after_a_long_gap():
    clock = TimeUnwrapper(bits=20, scale=1e-6, period_us=1000)
    mod = 1 << 20
    t0 = mod - 1500  # µs, 1.5 ms before the wrap
    assert clock(t0, 100) == pytest.approx(t0 * 1e-6)
    assert clock((t0 + 2000) % mod, 102) == pytest.approx((t0 + 2000) * 1e-6)
    # 3.7 s of silence: more than three wraps of 2**20 µs; the cycle counter resolves it
    later = t0 + 2000 + 3_700_000
    assert clock(later % mod, 102 + 3700) == pytest.approx(later * 1e-6)
    assert clock(5, 0, restart=True) == pytest.approx(5e-6)


def test_classic_time_keeps_increasing_over_the_wrap():
    js = profile("classic").joint_state
    states = synthetic_states(600, 2, start=int((2**20 - 500_000) / 1000))  # crosses 2**20 µs
    dec = CanDecoder("classic")
    got = feed(dec, [m for c in frames_of("classic", states) for m in c])
    assert len(got) == 600 and js.time_bits == 20
    ts = [s.t for s in got]
    assert all(b > a for a, b in itertools.pairwise(ts))
    assert ts[-1] - ts[0] == pytest.approx(599 * 2e-3, abs=1e-6)
