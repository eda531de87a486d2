"""AUTOSAR E2E profile 2: the table-driven CRC equals cantools' reference."""

import pytest
from cantools.autosar.end_to_end import check_profile2_crc, compute_profile2_crc
from hypothesis import given
from hypothesis import strategies as st

from firmware_bridge.e2e import Profile2, crc8h2f
from firmware_bridge.errors import BridgeConfigError
from firmware_bridge.protocol import database, profile


@given(st.binary(min_size=2, max_size=64), st.integers(0, 255))
def test_crc_equals_cantools(data, data_id):
    assert crc8h2f(data, data_id) == compute_profile2_crc(data, data_id)


@given(st.binary(min_size=2, max_size=64), st.integers(0, 15))
def test_protect_then_check(data, counter):
    e2e = Profile2(range(16))
    buf = e2e.protect(bytearray(data), counter)
    assert buf[1] & 0x0F == counter
    assert e2e.check(buf)
    assert check_profile2_crc(bytes(buf), e2e.data_ids[counter])


@given(st.binary(min_size=2, max_size=64), st.integers(0, 15), st.data())
def test_every_single_bit_error_is_caught(data, counter, draw):
    e2e = Profile2(bytes(range(100, 116)))
    buf = e2e.protect(bytearray(data), counter)
    bit = draw.draw(st.integers(0, len(buf) * 8 - 1))
    buf[bit // 8] ^= 1 << (bit % 8)
    assert not e2e.check(buf)


def test_every_single_bit_error_of_every_dbc_frame_is_caught():
    """Counter bits included: the counter selects the DataID, so a counter flip changes the
    checked data in two places; the DBC's DataIDLists are chosen so that it still fails."""
    for name in ("fd", "classic"):
        for codec in profile(name).frames():
            for counter in range(16):
                frame = codec.e2e.protect(bytearray(range(codec.length)), counter)
                for bit in range(codec.length * 8):
                    bad = bytearray(frame)
                    bad[bit // 8] ^= 1 << (bit % 8)
                    assert not codec.e2e.check(bad), (codec.label, counter, bit)


def test_a_frame_does_not_pass_as_another_message():
    fd = profile("fd")
    js, hb = fd.joint_state.parts[0], fd.heartbeat.frame
    data = bytes(js.e2e.protect(bytearray(8), 3))
    assert js.e2e.check(data)
    assert not hb.e2e.check(data)


def test_every_dbc_message_has_sixteen_data_ids():
    for msg in database().messages:
        text = msg.dbc.attributes["E2EDataIDList"].value
        assert len(text.split()) == 16, msg.name
        assert msg.dbc.attributes["E2EProfile"].value == "P02"


def test_short_frames_never_pass_and_bad_lists_are_refused():
    e2e = Profile2(range(16))
    assert not e2e.check(b"") and not e2e.check(b"\x00")
    with pytest.raises(BridgeConfigError, match="16 entries"):
        Profile2(range(15))
    with pytest.raises(BridgeConfigError, match="16 hex bytes"):
        Profile2.from_attribute("zz " * 16, "message X")
