"""Bus load: worst-case bits per frame, classic CAN and CAN FD, and the load of a profile.

**Classic CAN** (standard 11-bit identifier, ``n`` data bytes), worst-case bit stuffing, from
Davis, Burns, Bril and Lukkien, *Controller Area Network (CAN) schedulability analysis:
Refuted, revisited and revised*, Real-Time Systems 35(3), 2007, eq. (1)::

    bits = 8n + g + 13 + floor((g + 8n - 1) / 4),   g = 34 (11-bit ID) or 54 (29-bit ID)

``g + 8n`` bits (SOF to the end of the CRC) are subject to stuffing, at worst one stuff bit
per 4 bits after the first 5; the 13 are CRC delimiter, ACK slot and delimiter, EOF (7) and
the 3-bit interframe space, never stuffed. An 8-byte frame: 135 bits.

**CAN FD** (ISO 11898-1:2015 frame format, standard identifier, bit rate switch on), split
into the bits sent at the nominal (arbitration) bitrate and those at the data bitrate:

- nominal: SOF, 11-bit ID, RRS, IDE, FDF, res, BRS (17 bits) with their worst-case stuff
  bits ``floor((17 - 1) / 4) = 4``; then CRC delimiter, ACK slot, ACK delimiter, EOF (7) and
  interframe space (3): ``17 + 4 + 13 = 34`` bits;
- data: ESI and DLC (5 bits), the data (8n); the rest of the dynamic stuff bits, Davis'
  bound applied to the whole dynamically stuffed region (SOF to the end of the data,
  ``22 + 8n`` bits) minus the 4 counted above: ``floor((22 + 8n - 1) / 4) - 4``; the CRC
  field: stuff count (4 bits), CRC (17 bits up to 16 data bytes, 21 above) and its fixed
  stuff bits, one before the stuff count and one after every 4 bits:
  ``ceil((4 + crc) / 4)`` = 6 or 7.

The frame takes ``nominal / bitrate + data / data_bitrate`` seconds. Counting the CRC
delimiter at the nominal rate is slightly pessimistic (the switch back happens at its sample
point). A 64-byte frame: 34 + 678 bits, 169.6 µs at 1 / 5 Mbit/s.

The **load** of a profile is the fraction of time the bus is busy with its periodic
traffic: every joint-state frame at the profile's cycle rate plus the heartbeat. Payload
commands and acknowledgements are sporadic and reported per update. ``BUS_LOAD_LIMIT`` is the
design limit (60 %); :func:`max_standard_rate` picks the largest standard cycle rate under it,
and the classic profile's rate in ``protocol.dbc`` must equal it (a test checks).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

BUS_LOAD_LIMIT = 0.60
"""Largest configured bus load, as a fraction."""
STANDARD_RATES = (1000, 500, 250, 200, 125, 100, 50, 25, 10)
"""Cycle rates considered for a profile, Hz (whole divisors of the 1 kHz controller)."""


def classic_frame_bits(n_bytes: int, extended: bool = False) -> int:
    """Worst-case bits of a classic CAN data frame with ``n_bytes`` (0..8), IFS included."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"a classic CAN frame carries 0..8 data bytes, got {n_bytes}")
    g = 54 if extended else 34
    return 8 * n_bytes + g + 13 + (g + 8 * n_bytes - 1) // 4


FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@dataclass(frozen=True)
class FrameBits:
    """Worst-case bits of one frame: at the nominal and at the data bitrate."""

    nominal: int
    data: int

    @property
    def total(self) -> int:
        return self.nominal + self.data

    def seconds(self, bitrate: float, data_bitrate: float | None = None) -> float:
        return self.nominal / bitrate + self.data / (data_bitrate or bitrate)


def fd_frame_bits(n_bytes: int, extended: bool = False, brs: bool = True) -> FrameBits:
    """Worst-case bits of a CAN FD data frame with ``n_bytes`` (a valid FD length)."""
    if n_bytes not in FD_LENGTHS:
        raise ValueError(f"a CAN FD frame carries one of {FD_LENGTHS} data bytes, got {n_bytes}")
    arbitration = 36 if extended else 17  # SOF..BRS
    dynamic = arbitration + 5 + 8 * n_bytes  # SOF .. end of data
    stuff_total = (dynamic - 1) // 4
    stuff_arbitration = (arbitration - 1) // 4
    crc = 17 if n_bytes <= 16 else 21
    crc_field = 4 + crc + math.ceil((4 + crc) / 4)
    nominal = arbitration + stuff_arbitration + 13
    data = 5 + 8 * n_bytes + (stuff_total - stuff_arbitration) + crc_field
    if not brs:
        return FrameBits(nominal + data, 0)
    return FrameBits(nominal, data)


def frame_bits(length: int, is_fd: bool) -> FrameBits:
    if is_fd:
        return fd_frame_bits(length)
    return FrameBits(classic_frame_bits(length), 0)


def profile_load(name: str = "fd", rate_hz: float | None = None) -> dict:
    """Bits, frames per second and load of a profile's periodic traffic at ``rate_hz``
    joint-state cycles per second (default: the DBC's rate)."""
    from .protocol import profile

    prof = profile(name)
    js = prof.joint_state
    rate = js.rate_hz if rate_hz is None else float(rate_hz)
    if not rate > 0:
        raise ValueError(f"rate must be > 0 Hz, got {rate_hz}")
    br, dbr = prof.bitrate, prof.data_bitrate
    part_bits = [frame_bits(p.length, p.is_fd) for p in js.parts]
    hb = prof.heartbeat.frame
    hb_bits = frame_bits(hb.length, hb.is_fd)
    hb_rate = 1000.0 / hb.cycle_ms
    busy = rate * sum(b.seconds(br, dbr) for b in part_bits) + hb_rate * hb_bits.seconds(br, dbr)
    update = [frame_bits(c.frame.length, c.frame.is_fd) for c in (prof.command, prof.ack)]
    update_s = sum(n * b.seconds(br, dbr) for n, b in zip(
        (prof.command.n_frames, prof.ack.n_frames), update, strict=True))
    return {
        "profile": name, "bitrate": br, "data_bitrate": dbr, "rate_hz": rate,
        "frames_per_cycle": len(part_bits), "frame_bytes": js.parts[0].length,
        "bits_per_frame": part_bits[0].total, "nominal_bits": part_bits[0].nominal,
        "data_bits": part_bits[0].data, "frame_us": part_bits[0].seconds(br, dbr) * 1e6,
        "heartbeat_hz": hb_rate, "heartbeat_bits": hb_bits.total,
        "frames_per_s": rate * len(part_bits) + hb_rate,
        "load_percent": 100.0 * busy,
        "update_frames": prof.command.n_frames + prof.ack.n_frames,
        "update_us": update_s * 1e6,
    }


def max_standard_rate(name: str, limit: float = BUS_LOAD_LIMIT) -> int:
    """The largest of :data:`STANDARD_RATES` whose load stays under ``limit``."""
    for rate in STANDARD_RATES:
        if profile_load(name, rate)["load_percent"] < 100.0 * limit:
            return rate
    raise ValueError(f"profile {name}: no standard rate keeps the load under {limit:.0%}")


def describe(fig: dict) -> str:
    """The figures of :func:`profile_load` in words."""
    mbit = f"{fig['bitrate'] / 1e6:g} Mbit/s"
    if fig["data_bitrate"]:
        mbit += f" arbitration, {fig['data_bitrate'] / 1e6:g} Mbit/s data"
        bits = (f"{fig['bits_per_frame']} bits ({fig['nominal_bits']} nominal + "
                f"{fig['data_bits']} data), {fig['frame_us']:.1f} µs")
    else:
        bits = f"{fig['bits_per_frame']} bits, {fig['frame_us']:.1f} µs"
    state = "OK" if fig["load_percent"] < 100 * BUS_LOAD_LIMIT else "TOO HIGH"
    return "\n".join([
        f"profile {fig['profile']}: {mbit}",
        f"  joint state : {fig['frames_per_cycle']} frame(s) of {fig['frame_bytes']} bytes per "
        f"cycle at {fig['rate_hz']:g} Hz; {bits} each (worst-case stuffing)",
        f"  heartbeat   : 1 frame of 8 bytes at {fig['heartbeat_hz']:g} Hz, "
        f"{fig['heartbeat_bits']} bits",
        f"  total       : {fig['frames_per_s']:g} frames/s, bus load "
        f"{fig['load_percent']:.1f} % ({state}: limit {100 * BUS_LOAD_LIMIT:.0f} %)",
        f"  each payload update adds {fig['update_frames']} frames (command + ack), "
        f"{fig['update_us']:.0f} µs of bus time",
    ])


def configure(parser) -> None:
    from .protocol import PROFILES

    parser.add_argument("--profile", default="fd", choices=PROFILES,
                        help="wire profile (default fd)")
    parser.add_argument("--rate", type=float, metavar="HZ",
                        help="joint-state cycle rate (default: the profile's, from the DBC)")
    parser.add_argument("--json", action="store_true",
                        help='print {"bits_per_frame", "frames_per_s", "load_percent"} as JSON')


def run(args) -> int:
    from iem.errors import InvalidInputError

    try:
        fig = profile_load(args.profile, args.rate)
    except ValueError as exc:
        raise InvalidInputError(f"--rate: {exc}") from None
    if args.json:
        print(json.dumps({k: fig[k] for k in ("bits_per_frame", "frames_per_s",
                                              "load_percent")}))
    else:
        print(describe(fig))
    return 0
