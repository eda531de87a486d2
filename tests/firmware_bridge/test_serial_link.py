"""The serial link: COBS + CRC32 framing, resynchronisation, loop:// and a pty end to end."""

import msgpack
import numpy as np
import pytest
import serial
from hypothesis import given
from hypothesis import strategies as st

from deploy.simcell.controller import SimController
from firmware_bridge.errors import ControllerSilent, DecodeError, LinkError
from firmware_bridge.pty_pair import PtyPair
from firmware_bridge.serial_link import SerialControllerPort, SerialDecoder, SerialLink, open_serial
from firmware_bridge.serial_wire import cobs_decode, cobs_encode, encode_joint_state, frame, unframe
from sim.family import default_test_payload
from sim.paths import excitation_path

from .conftest import synthetic_states

# Examples from Cheshire and Baker's paper / the usual COBS test vectors.
VECTORS = [
    (b"\x00", b"\x01\x01"),
    (b"\x00\x00", b"\x01\x01\x01"),
    (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
    (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
    (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
    (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255)) + b"\x01"),
    (bytes(range(0, 255)), b"\x01\xff" + bytes(range(1, 255)) + b"\x01"),
]


@pytest.mark.parametrize(("raw", "encoded"), VECTORS)
def test_cobs_vectors(raw, encoded):
    assert cobs_encode(raw) == encoded
    assert cobs_decode(encoded) == raw


@given(st.binary(max_size=2000))
def test_cobs_round_trip_has_no_zero(data):
    enc = cobs_encode(data)
    assert b"\x00" not in enc
    assert cobs_decode(enc) == data


def test_bad_cobs_and_crc_are_decode_errors():
    with pytest.raises(DecodeError, match="runs past the end"):
        cobs_decode(b"\x05\x01")
    good = frame(b"hello")[:-1]
    bad = bytearray(cobs_decode(good))
    bad[0] ^= 1
    with pytest.raises(DecodeError) as info:
        unframe(cobs_encode(bytes(bad)))
    assert info.value.kind == "crc"


def stream(states):
    return b"".join(frame(encode_joint_state(s)) for s in states)


def test_garbage_and_lost_bytes_cost_one_message_each():
    states = synthetic_states(10)
    frames = [frame(encode_joint_state(s)) for s in states]
    data = bytearray()
    for i, f in enumerate(frames):
        if i == 2:
            f = f[:40] + f[45:]  # five bytes lost
        if i == 5:
            data += b"\x13\x37garbage\x00"  # noise between frames
        if i == 7:
            f = f[:10] + b"\x00" + f[10:]  # a spurious delimiter splits it in two
        data += f
    dec = SerialDecoder()
    got = []
    for k in range(0, len(data), 7):  # arrives in dribs and drabs
        got += dec.feed(bytes(data[k:k + 7]))
    assert [s.cycle for s in got] == [0, 1, 3, 4, 5, 6, 8, 9]
    c = dec.counters
    assert c.crc + c.malformed == 4 and c.lost == 2


def test_an_endless_frame_is_skipped_to_the_next_delimiter():
    dec = SerialDecoder()
    s0, s1 = synthetic_states(2)
    got = dec.feed(b"\x01" * 10_000) + dec.feed(b"\x01" * 10 + b"\x00" + stream([s0, s1]))
    assert [s.cycle for s in got] == [0, 1] and dec.counters.malformed == 1


@pytest.mark.parametrize("body", [
    msgpack.packb(["J", 1, 0.0, [0.0] * 6, [0.0] * 7, [0.0] * 7]),
    msgpack.packb(["J", 1, float("nan"), [0.0] * 7, [0.0] * 7, [0.0] * 7]),
    msgpack.packb(["J", -1, 0.0, [0.0] * 7, [0.0] * 7, [0.0] * 7]),
    msgpack.packb(["X", 1]),
    msgpack.packb({"J": 1}),
    b"\xc1",  # never used in msgpack
])
def test_schema_violations_are_malformed(body):
    dec = SerialDecoder()
    assert dec.feed(frame(body)) == []
    assert dec.counters.malformed == 1 and dec.last_error is not None


def test_over_loop_url_with_resync():
    port = open_serial("loop://")  # what is written is read back; its buffer holds 4 KiB
    link = SerialLink(port)
    states = synthetic_states(20)
    port.write(stream(states[:10]))
    got = [link.read(0.5) for _ in range(10)]
    port.write(b"\x42" * 33 + stream(states[10:]))  # garbage glued to the next frame
    got += [link.read(0.5) for _ in range(9)]
    assert [s.cycle for s in got] == [*range(10), *range(11, 20)]
    np.testing.assert_allclose(got[3].q, states[3].q)
    assert link.counters.malformed == 1 and link.counters.lost == 1
    with pytest.raises(ControllerSilent, match="no complete joint state for 20 ms"):
        link.read(0.02)
    link.close()


def test_open_serial_names_the_url():
    with pytest.raises(LinkError, match="cannot open serial port 'nonesuch://x'"):
        open_serial("nonesuch://x")


@pytest.mark.hil
def test_sim_controller_over_a_pty_with_the_serial_link():
    pty = PtyPair()
    controller = SimController(SerialControllerPort(pty), path=excitation_path(2.0))
    port = serial.Serial(pty.slave_path, timeout=0.01)
    link = SerialLink(port)
    try:
        controller.start()
        got = [link.read(1.0) for _ in range(300)]
        cycles = [s.cycle for s in got]
        assert cycles == sorted(cycles) and len(set(cycles)) == 300
        seq = link.send(default_test_payload())
        ack = link.wait_ack(seq, 2.0)
        assert ack.applied and ack.load.mass == pytest.approx(default_test_payload().mass)
        np.testing.assert_allclose(ack.load.inertia, default_test_payload().inertia, atol=1e-12)
        assert link.last_heartbeat is not None
        assert link.counters.crc == link.counters.malformed == 0
    finally:
        controller.stop()
        link.close()
        pty.close()
    assert controller.error is None


@pytest.mark.hil
def test_iem_sim_controller_on_a_serial_pty(tmp_path):
    from firmware_bridge.links import open_link

    from .hil import Controller

    child = Controller(["--interface", "serial-pty", "--once"], tmp_path / "controller.log",
                       announce=True)
    link = None
    try:
        link = open_link("serial", child.line)
        states = [link.read(10.0)] + [link.read(1.0) for _ in range(99)]
        cycles = [s.cycle for s in states]
        assert cycles == sorted(set(cycles))  # bytes written before we opened may be lost
        ack = link.wait_ack(link.send(default_test_payload()), 5.0)
        assert ack.applied
    finally:
        if link is not None:
            link.close()
        log = child.stop()
    assert "Traceback" not in log and "commands 1" in log
