"""Bus load: the bit counts against a bit-level stuffing simulation, the profiles' loads,
and the ``iem bus-load`` command."""

import json
import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_bridge.busload import (
    classic_frame_bits,
    fd_frame_bits,
    max_standard_rate,
    profile_load,
)
from firmware_bridge.protocol import profile

from .hil import REPO


def bits(value: int, n: int) -> list[int]:
    return [(value >> (n - 1 - i)) & 1 for i in range(n)]


def crc15(stream: list[int]) -> list[int]:
    crc = 0
    for b in stream:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return bits(crc, 15)


def stuff_bits(stream: list[int]) -> int:
    """Stuff bits a transmitter inserts: after five equal bits, one of the other value (which
    itself starts the next run)."""
    count, run, last = 0, 0, None
    for b in stream:
        if b == last:
            run += 1
        else:
            last, run = b, 1
        if run == 5:
            count += 1
            last, run = 1 - b, 1
    return count


def classic_stream(ident: int, data: bytes) -> list[int]:
    head = [0, *bits(ident, 11), 0, 0, 0, *bits(len(data), 4)]
    body = head + [b for byte in data for b in bits(byte, 8)]
    return body + crc15(body)


def fd_dynamic_stream(ident: int, data: bytes, esi: int) -> list[int]:
    dlc = {12: 9, 16: 10, 20: 11, 24: 12, 32: 13, 48: 14, 64: 15}.get(len(data), len(data))
    head = [0, *bits(ident, 11), 0, 0, 1, 0, 1, esi, *bits(dlc, 4)]
    return head + [b for byte in data for b in bits(byte, 8)]


WORST = bytes([0x78, 0x3C, 0x1E, 0x0F] * 16)  # long alternating runs


def test_published_classic_figures():
    assert classic_frame_bits(8) == 135  # Davis et al. 2007: 135 bit times for 8 bytes
    assert classic_frame_bits(0) == 55
    assert classic_frame_bits(8, extended=True) == 160
    assert fd_frame_bits(64).nominal == 34 and fd_frame_bits(64).data == 678
    assert fd_frame_bits(64).seconds(1e6, 5e6) == pytest.approx(169.6e-6)


@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_classic_bound_covers_every_frame(ident, data):
    stream = classic_stream(ident, data)
    assert len(stream) == 34 + 8 * len(data)
    fixed = 8 * len(data) + 34 + 13
    assert fixed + stuff_bits(stream) <= classic_frame_bits(len(data))


@given(st.integers(0, 0x7FF), st.sampled_from([0, 1, 8, 12, 16, 20, 24, 32, 48, 64]),
       st.data(), st.integers(0, 1))
def test_fd_dynamic_stuffing_bound_covers_every_frame(ident, n, draw, esi):
    data = draw.draw(st.one_of(st.binary(min_size=n, max_size=n), st.just(WORST[:n])))
    stream = fd_dynamic_stream(ident, data, esi)
    b = fd_frame_bits(n)
    crc = 17 if n <= 16 else 21
    fixed = len(stream) + 13 + 4 + crc + -(-(4 + crc) // 4)
    assert fixed + stuff_bits(stream) <= b.total
    assert b.total - fixed == (len(stream) - 1) // 4  # exactly Davis' bound on the region


def test_the_stuffing_simulation_reaches_one_bit_in_four():
    # five equal bits, then runs of four: each run plus the stuff bit before it makes five
    stream = [0] * 5 + ([1] * 4 + [0] * 4) * 10
    assert stuff_bits(stream) == 21 == (len(stream) - 1) // 4  # Davis' bound is reached


def test_profile_loads_and_the_classic_rate():
    fd, classic = profile_load("fd"), profile_load("classic")
    assert fd["load_percent"] == pytest.approx(100 * (1000 * 169.6e-6 + 10 * 135e-6))
    assert 15 < fd["load_percent"] < 18
    assert classic["rate_hz"] == 500 and classic["frames_per_s"] == 8 * 500 + 10
    assert classic["load_percent"] == pytest.approx(100 * (4000 + 10) * 135e-6)
    assert profile_load("classic", 1000)["load_percent"] > 100
    # the DBC's classic rate is the largest standard rate under 60 %
    assert profile("classic").joint_state.rate_hz == max_standard_rate("classic") == 500
    assert max_standard_rate("fd") == 1000


def cli(*args):
    done = subprocess.run([sys.executable, "-m", "deploy.cli", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_bus_load_command():
    fig = json.loads(cli("bus-load", "--profile", "classic", "--rate", "250", "--json"))
    assert set(fig) == {"bits_per_frame", "frames_per_s", "load_percent"}
    assert fig["bits_per_frame"] == 135 and fig["frames_per_s"] == 2010
    text = cli("bus-load", "--profile", "fd")
    assert "712 bits (34 nominal + 678 data)" in text and "17.1 %" in text
