"""Random bytes and frames into every decoder: the only exception that may come out is the
project's own DecodeError (and the stream decoders, which count, raise nothing)."""

import contextlib

import can
import msgpack
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_bridge.can_link import CanDecoder
from firmware_bridge.errors import DecodeError
from firmware_bridge.protocol import PROFILES, LoadAssembler, profile
from firmware_bridge.serial_link import (
    SerialDecoder,
    cobs_decode,
    decode_message,
    frame,
    unframe,
)

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


@SETTINGS
@given(st.lists(st.binary(max_size=300), max_size=10))
def test_serial_decoder_counts_and_never_raises(chunks):
    dec = SerialDecoder()
    for chunk in chunks:
        dec.feed(chunk)


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
