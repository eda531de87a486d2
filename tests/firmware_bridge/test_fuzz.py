"""Random bytes and frames into every decoder: the only exception that may come out is the
project's own DecodeError (and the stream decoders, which count, raise nothing)."""

import contextlib

import can
import msgpack
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_bridge.can_link import CanDecoder
from firmware_bridge.errors import DecodeError
from firmware_bridge.links import DROP_KINDS
from firmware_bridge.protocol import PROFILES, LoadAssembler, profile
from firmware_bridge.serial_link import SerialDecoder
from firmware_bridge.serial_wire import (
    cobs_decode,
    decode_message,
    encode_joint_state,
    frame,
    unframe,
)

from .conftest import synthetic_states

ALL_IDS = sorted({f.frame_id for p in PROFILES for f in profile(p).frames()})
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
SETTINGS = settings(max_examples=300, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


CODECS = [f for p in PROFILES for f in profile(p).frames()]


@st.composite
def frames(draw):
    """Random CAN frames: half are a protocol message with random content and a valid E2E
    CRC (so they reach reassembly and field checks), half anything at all."""
    if draw(st.booleans()):
        codec = draw(st.sampled_from(CODECS))
        data = bytearray(draw(st.binary(min_size=codec.length, max_size=codec.length)))
        codec.e2e.protect(data, data[1] & 0x0F)
        return can.Message(arbitration_id=codec.frame_id, data=bytes(data),
                           is_fd=codec.is_fd, is_extended_id=False, check=False)
    fid = draw(st.one_of(st.sampled_from(ALL_IDS), st.integers(0, 0x7FF)))
    fd = draw(st.booleans())
    n = draw(st.sampled_from(FD_LENGTHS)) if fd else draw(st.integers(0, 8))
    data = bytearray(draw(st.binary(min_size=n, max_size=n)))
    if draw(st.booleans()) and n >= 2:  # give it a valid CRC for some message's DataIDs
        codec = draw(st.sampled_from(CODECS))
        codec.e2e.protect(data, data[1] & 0x0F)
    kind = draw(st.sampled_from(["data", "data", "data", "remote", "error", "extended"]))
    return can.Message(arbitration_id=fid, data=bytes(data) if kind != "remote" else b"",
                       dlc=n, is_fd=fd and kind != "remote", is_remote_frame=kind == "remote",
                       is_error_frame=kind == "error", is_extended_id=kind == "extended",
                       check=False)


@SETTINGS
@given(st.sampled_from(PROFILES), st.lists(frames(), max_size=40))
def test_can_decoder_counts_and_never_raises(name, msgs):
    dec = CanDecoder(name)
    for m in msgs:
        dec.push(m)
    c = dec.counters
    assert c.received == len(msgs)


@SETTINGS
@given(st.sampled_from(PROFILES), st.binary(max_size=64), st.data())
def test_frame_codecs_raise_only_decode_errors(name, data, draw):
    prof = profile(name)
    codec = draw.draw(st.sampled_from(prof.frames()))
    for call in (lambda: codec.check(data, draw.draw(st.booleans())),
                 lambda: codec.unpack(data.ljust(codec.length, b"\0")[:codec.length]),
                 lambda: prof.heartbeat.decode(data.ljust(8, b"\0")[:8])):
        with contextlib.suppress(DecodeError):
            call()
    for load in (prof.command, prof.ack):
        try:
            raw = LoadAssembler(load).push(data.ljust(load.frame.length, b"\0")
                                           [:load.frame.length])
            if raw is not None:
                load.values(raw)
        except DecodeError:
            pass


@st.composite
def serial_lines(draw):
    """The bytes of a serial line cut into random chunks: random garbage between frames of
    joint states (consecutive cycles) and heartbeats. Each frame follows a delimiter, so the
    garbage before it ends there. Returns the chunks, the states and the heartbeats framed."""
    pieces, states, heartbeats = [], [], 0
    cycle = draw(st.integers(0, 1000))
    for _ in range(draw(st.integers(0, 12))):
        kind = draw(st.sampled_from(["garbage", "garbage", "state", "heartbeat"]))
        if kind == "garbage":
            pieces.append(draw(st.binary(max_size=300)))
        elif kind == "state":
            state = synthetic_states(1, start=cycle + len(states))[0]
            states.append(state)
            pieces.append(b"\0" + frame(encode_joint_state(state)))
        else:
            heartbeats += 1
            pieces.append(b"\0" + frame(msgpack.packb(["H", 0, 0, cycle + len(states), 0])))
    line = b"".join(pieces)
    cuts = sorted(draw(st.lists(st.integers(0, len(line)), max_size=8)))
    chunks = [line[a:b] for a, b in zip([0, *cuts], [*cuts, len(line)], strict=True)]
    return chunks, states, heartbeats


@SETTINGS
@given(serial_lines())
def test_serial_decoder_counts_and_never_raises(line):
    chunks, sent, heartbeats = line
    dec = SerialDecoder()
    got = [state for chunk in chunks for state in dec.feed(chunk)]
    c = dec.counters
    data = b"".join(chunks)
    # every frame closed by a delimiter is received once and counted once, under what it was
    assert c.received == len([p for p in data.split(b"\0")[:-1] if p])
    outcomes = (len(got) + c.heartbeats + c.acks + c.foreign
                + sum(c.as_dict()[kind] for kind in DROP_KINDS if kind != "orphaned"))
    assert outcomes == c.received
    # the valid frames come through, exact and in order, whatever garbage lies between them
    # and wherever the chunks were cut; garbage costs no cycle
    assert [s.cycle for s in got] == [s.cycle for s in sent]
    for a, b in zip(got, sent, strict=True):
        assert a.t == b.t
        for name in ("q", "dq", "tau_J"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert c.delivered == len(sent) and c.heartbeats == heartbeats and c.lost == 0
    whole = SerialDecoder()  # the same bytes in one read: the same counts
    whole.feed(data)
    assert whole.counters.as_dict() == c.as_dict()


msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=5)
    | st.binary(max_size=5),
    lambda inner: st.lists(inner, max_size=8) | st.dictionaries(st.text(max_size=3), inner,
                                                                 max_size=4),
    max_leaves=30)


def _packable(value):
    try:
        return msgpack.packb(value)
    except (OverflowError, ValueError, TypeError):
        return msgpack.packb(None)


@SETTINGS
@given(st.one_of(
    msgpack_values.map(_packable),
    st.tuples(st.sampled_from(["J", "H", "L", "A"]), st.lists(msgpack_values, max_size=6))
    .map(lambda t: _packable([t[0], *t[1]])),
    st.binary(max_size=200)))
def test_serial_messages_raise_only_decode_errors(body):
    with contextlib.suppress(DecodeError):
        decode_message(body)
    dec = SerialDecoder()
    dec.feed(frame(body))  # a valid CRC around anything: counted, never raised
    assert dec.counters.received == 1


@SETTINGS
@given(st.binary(max_size=300))
def test_unframing_raises_only_decode_errors(data):
    for call in (cobs_decode, unframe):
        with contextlib.suppress(DecodeError):
            call(data)
