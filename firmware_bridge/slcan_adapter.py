"""An emulated slcan adapter on a pty: the controller's bus for cross-process tests here.

This kernel has no AF_CAN, so two processes cannot share a vcan bus. Instead the simulated
controller owns the master of a pty and speaks the slcan (LAWICEL) ASCII protocol on it, as
a USB serial CAN adapter would; a second process opens the slave path with python-can's own
``slcan`` interface (``can.Bus(interface="slcan", channel=<slave path>,
sleep_after_open=0)``) and so exercises the real serial path of a robot-cell PC.

:class:`SlcanPtyAdapter` is a ``can.BusABC``: the controller sends frames to it (they go to
the client as ``t``/``d``/``b`` lines) and receives from it what the client transmits.

Commands understood (each ends with CR; reply CR for OK, BEL for an error):

- ``O`` open, ``L`` open listen-only, ``C`` close; frames travel only while open;
- ``S0``..``S9`` nominal bitrate (10 k .. 1 Mbit/s, 83.3 k), ``Y2``/``Y5`` CAN FD data bitrate
  (CANable 2.0), ``sXXYY`` BTR registers, an empty command (python-can sends one when no data
  bitrate is given) -- all acknowledged and remembered, not enforced;
- ``V`` version, ``N`` serial number, ``F`` status flags, ``Z0``/``Z1`` (timestamps stay off:
  python-can does not parse them), ``M``/``m`` acceptance filters (accepted, not applied);
- frames: ``tIIIL<data>``, ``TIIIIIIIIL<data>``, ``rIIIL``, ``RIIIIIIIIL``, and the FD
  forms ``d``/``D`` (no bitrate switch), ``b``/``B`` (bitrate switch) with a hex DLC code;
  a transmitted frame is answered ``z``/``Z`` as LAWICEL adapters do.

Frames sent while the client has not opened the channel are not delivered (counted in
``dropped_closed``); if the client stops reading, the pty backlog fills and further frames
are dropped whole (``pty.dropped_writes``) and ``send`` raises ``CanOperationError``, as
python-can does when an adapter's transmit queue overflows.
"""

from __future__ import annotations

import time
from collections import deque

import can
from can.util import CAN_FD_DLC, len2dlc

from .pty_pair import PtyPair

BITRATES = {"S0": 10_000, "S1": 20_000, "S2": 50_000, "S3": 100_000, "S4": 125_000,
            "S5": 250_000, "S6": 500_000, "S7": 750_000, "S8": 1_000_000, "S9": 83_300}
DATA_BITRATES = {"Y2": 2_000_000, "Y5": 5_000_000}
OK, ERROR = b"\r", b"\a"


class SlcanPtyAdapter(can.BusABC):
    """An slcan adapter whose serial side is a pty (``slave_path``)."""

    def __init__(self, channel: str = "pty", **kwargs) -> None:
        self.pty = PtyPair()
        self.slave_path = self.pty.slave_path
        self.channel_info = f"emulated slcan adapter on {self.slave_path}"
        self._buf = bytearray()
        self._rx: deque[can.Message] = deque()
        self.is_open = False
        self.listen_only = False
        self.bitrate: int | None = None
        self.data_bitrate: int | None = None
        self.dropped_closed = 0
        self.bad_commands = 0
        super().__init__(channel=channel, **kwargs)
        self._can_protocol = can.CanProtocol.CAN_FD

    # -- client -> bus ---------------------------------------------------------------------
    def _service(self) -> None:
        data = self.pty.read()
        while data:
            self._buf += data
            data = self.pty.read()
        while True:
            end = self._buf.find(b"\r")
            if end < 0:
                if len(self._buf) > 4096:  # no terminator in sight: garbage
                    self._buf.clear()
                    self.bad_commands += 1
                break
            line = bytes(self._buf[:end])
            del self._buf[:end + 1]
            self.pty.write(self._command(line.decode("ascii", "replace")))

    def _command(self, cmd: str) -> bytes:
        head = cmd[:1]
        if cmd in ("O", "L"):
            self.is_open, self.listen_only = True, cmd == "L"
        elif cmd == "C":
            self.is_open = False
        elif cmd in BITRATES:
            self.bitrate = BITRATES[cmd]
        elif cmd in DATA_BITRATES:
            self.data_bitrate = DATA_BITRATES[cmd]
        elif cmd == "" or head in ("s", "Z", "M", "m"):
            pass
        elif cmd == "V":
            return b"V0101\r"
        elif cmd == "N":
            return b"NIEM0\r"
        elif cmd == "F":
            return b"F00\r"
        elif head and head in "tTrRdDbB":
            msg = self._parse_frame(cmd)
            if msg is None or not self.is_open or self.listen_only:
                self.bad_commands += 1
                return ERROR
            self._rx.append(msg)
            return b"Z\r" if head in "TRDB" else b"z\r"
        else:
            self.bad_commands += 1
            return ERROR
        return OK

    @staticmethod
    def _parse_frame(cmd: str) -> can.Message | None:
        head = cmd[0]
        extended = head in "TRDB"
        id_len = 8 if extended else 3
        try:
            fid = int(cmd[1:1 + id_len], 16)
            code = int(cmd[1 + id_len], 16)
            fd = head in "dDbB"
            if not fd and code > 8:
                return None
            n = CAN_FD_DLC[code] if fd else code
            remote = head in "rR"
            body = cmd[2 + id_len:]
            data = b"" if remote else bytes.fromhex(body)
            if not remote and len(data) != n:
                return None
        except (ValueError, IndexError):
            return None
        return can.Message(timestamp=time.time(), arbitration_id=fid, is_extended_id=extended,
                           is_remote_frame=remote, is_fd=fd, bitrate_switch=head in "bB",
                           dlc=n, data=data, check=False)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.perf_counter() + timeout
        while True:
            if self._rx:
                return self._rx.popleft(), False
            self._service()
            self.pty.flush()
            if self._rx:
                continue
            if deadline is None:
                self.pty.wait_readable(0.05)
                continue
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                return None, False
            self.pty.wait_readable(min(remaining, 0.05))

    # -- bus -> client ---------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self.is_open:
            self.dropped_closed += 1
            return
        fid = msg.arbitration_id
        ident = f"{fid:08X}" if msg.is_extended_id else f"{fid:03X}"
        if msg.is_remote_frame:
            line = f"{'R' if msg.is_extended_id else 'r'}{ident}{msg.dlc:d}"
        elif msg.is_fd:
            head = ("B" if msg.is_extended_id else "b") if msg.bitrate_switch else (
                "D" if msg.is_extended_id else "d")
            line = f"{head}{ident}{len2dlc(len(msg.data)):X}{msg.data.hex().upper()}"
        else:
            line = f"{'T' if msg.is_extended_id else 't'}{ident}{len(msg.data):d}" \
                   f"{msg.data.hex().upper()}"
        if not self.pty.write(line.encode("ascii") + b"\r"):
            raise can.CanOperationError(
                "slcan adapter: the client does not read; its backlog is full and the frame "
                "was dropped (as a real adapter's transmit queue overflows)")

    def shutdown(self) -> None:
        super().shutdown()
        self.pty.close()
