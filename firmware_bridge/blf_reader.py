"""Vector BLF files read within bounds: python-can's format, every size checked before use.

python-can's :class:`can.io.blf.BLFReader` trusts the sizes a file declares: an object of
size 0 inside a container loops forever, a zlib container inflates without limit, and an
object that claims more than the containers after it hold is re-joined with each of them,
in time quadratic in its size (python-can issue #1584 reports the first). A recording is a
file anybody may hand over, so :class:`BlfReader` reads the same format with every size
checked before it is used:

- the file header is at least its 72 bytes of fields and at most :data:`MAX_HEADER_BYTES`;
- every object is at least its own header, and a container at most
  :data:`MAX_CONTAINER_BYTES` on disk and inflated (zlib is asked for no more than that);
- an object inside the containers is at most :data:`MAX_CONTAINER_BYTES` too, and the part of
  it that continues in the next container is kept in one growing buffer, so a file is read
  in time linear in its size;
- every step moves forward by at least one object header: reading always ends.

A file that breaks a bound raises :class:`BlfError` (a :class:`can.io.blf.BLFParseError`)
naming the byte offset and the bound; a file that ends inside an object, a header or a
container simply ends (its ``file_size`` and ``object_count`` say how much was declared), as
python-can's reader does. It yields the same :class:`can.Message` objects python-can's
reader does, for the object types it decodes (CAN, CAN FD, CAN FD 64 and CAN error frames);
other objects are skipped.
"""

from __future__ import annotations

import os
import zlib
from collections.abc import Iterator

import can
from can.io.blf import (
    CAN_ERROR_EXT,
    CAN_ERROR_EXT_STRUCT,
    CAN_FD_MESSAGE,
    CAN_FD_MESSAGE_64,
    CAN_FD_MSG_64_STRUCT,
    CAN_FD_MSG_STRUCT,
    CAN_MESSAGE,
    CAN_MESSAGE2,
    CAN_MSG_STRUCT,
    FILE_HEADER_STRUCT,
    LOG_CONTAINER,
    LOG_CONTAINER_STRUCT,
    NO_COMPRESSION,
    OBJ_HEADER_BASE_STRUCT,
    OBJ_HEADER_V1_STRUCT,
    OBJ_HEADER_V2_STRUCT,
    ZLIB_DEFLATE,
    BLFParseError,
    systemtime_to_timestamp,
)
from can.util import dlc2len

__all__ = ["MAX_CONTAINER_BYTES", "MAX_HEADER_BYTES", "BlfError", "BlfReader"]

MAX_CONTAINER_BYTES = 64 * 1024 * 1024
"""Largest container, on disk or inflated, and largest object inside the containers (Vector's
tools and python-can's writer make 128 kB containers)."""
MAX_HEADER_BYTES = 64 * 1024
"""Largest file header (Vector's is 144 bytes)."""

_BASE = OBJ_HEADER_BASE_STRUCT.size  # signature, header size, version, object size, type
_CONTAINER = _BASE + LOG_CONTAINER_STRUCT.size
_HEADERS = {1: OBJ_HEADER_V1_STRUCT, 2: OBJ_HEADER_V2_STRUCT}
_BODY = {CAN_MESSAGE: CAN_MSG_STRUCT.size, CAN_MESSAGE2: CAN_MSG_STRUCT.size,
         CAN_ERROR_EXT: CAN_ERROR_EXT_STRUCT.size, CAN_FD_MESSAGE: CAN_FD_MSG_STRUCT.size,
         CAN_FD_MESSAGE_64: CAN_FD_MSG_64_STRUCT.size}
_EXT = 0x80000000
_TEN_MICROSECONDS = 0x1
MB = 1024 * 1024


class BlfError(BLFParseError):
    """A BLF file breaks the format or a bound: the message names the byte and the bound."""


class BlfReader:
    """The CAN frames of a BLF file, read within bounds (see the module docstring).

    ``file_size`` and ``object_count`` are what the header declares (0: not declared);
    ``start_timestamp`` is the recording's start (Unix time, s), added to every object's
    time stamp. Iterate once; :meth:`stop` closes the file.
    """

    def __init__(self, path) -> None:
        self.path = os.fspath(path)
        self.file = open(self.path, "rb")  # noqa: SIM115 (closed by stop())
        try:
            self._read_header()
        except BaseException:
            self.file.close()
            raise

    def _read_header(self) -> None:
        data = self.file.read(FILE_HEADER_STRUCT.size)
        if not data:
            raise BlfError("empty (0 bytes): a BLF file starts with its header, 'LOGG' and at "
                           f"least {FILE_HEADER_STRUCT.size} bytes")
        if len(data) < FILE_HEADER_STRUCT.size:
            raise BlfError(f"{len(data)} bytes, shorter than a BLF file's header ('LOGG' and "
                           f"at least {FILE_HEADER_STRUCT.size} bytes)")
        header = FILE_HEADER_STRUCT.unpack(data)
        if header[0] != b"LOGG":
            raise BlfError(f"starts with {header[0]!r}: not a BLF file, which starts with "
                           "'LOGG'")
        size = header[1]
        if not FILE_HEADER_STRUCT.size <= size <= MAX_HEADER_BYTES:
            raise BlfError(f"its header declares {size} bytes; valid is "
                           f"{FILE_HEADER_STRUCT.size} to {MAX_HEADER_BYTES}")
        self.file_size, self.uncompressed_size, self.object_count = header[10:13]
        self.start_timestamp = systemtime_to_timestamp(header[14:22])
        self.stop_timestamp = systemtime_to_timestamp(header[22:30])
        self.file.seek(size)
        self.offset = size
        """Byte offset in the file of the next top-level object."""

    def stop(self) -> None:
        self.file.close()

    def __enter__(self) -> BlfReader:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- the file's objects: containers ---------------------------------------------------
    def __iter__(self) -> Iterator[can.Message]:
        tail = bytearray()  # the part of an object that continues in the next container
        need = 0  # bytes the object at the start of ``tail`` needs
        read = self.file.read
        while True:
            at = self.offset
            head = read(_BASE)
            if len(head) < _BASE:
                return  # the end, or a file cut inside an object's header
            signature, _, _, size, kind = OBJ_HEADER_BASE_STRUCT.unpack(head)
            if signature != b"LOBJ":
                raise BlfError(f"byte {at}: {signature!r} where an object starts ('LOBJ')")
            if size < _BASE or (kind == LOG_CONTAINER and size < _CONTAINER):
                raise BlfError(f"byte {at}: an object of {size} bytes, less than its "
                               f"{_CONTAINER if kind == LOG_CONTAINER else _BASE}-byte header")
            if size > MAX_CONTAINER_BYTES:
                raise BlfError(f"byte {at}: an object of {size / MB:.0f} MB; valid is at most "
                               f"{MAX_CONTAINER_BYTES // MB} MB")
            self.offset = at + size + size % 4  # objects are padded as python-can pads them
            if kind != LOG_CONTAINER:
                self.file.seek(self.offset)
                continue
            body = read(size - _BASE)
            read(size % 4)
            cut = len(body) < size - _BASE  # the file ends inside this container: its
            if len(body) < LOG_CONTAINER_STRUCT.size:  # whole objects are read, as
                return  # python-can reads them, and the reading ends
            method, _ = LOG_CONTAINER_STRUCT.unpack_from(body)
            data = memoryview(body)[LOG_CONTAINER_STRUCT.size:]
            if method == ZLIB_DEFLATE:
                inflate = zlib.decompressobj()
                try:
                    data = inflate.decompress(data, MAX_CONTAINER_BYTES)
                except zlib.error as exc:
                    raise BlfError(f"byte {at}: a container that does not inflate: {exc}") \
                        from exc
                if inflate.unconsumed_tail:
                    raise BlfError(f"byte {at}: a container that inflates beyond "
                                   f"{MAX_CONTAINER_BYTES // MB} MB")
            elif method != NO_COMPRESSION:
                raise BlfError(f"byte {at}: a container of compression method {method}; "
                               f"valid are {NO_COMPRESSION} (none) and {ZLIB_DEFLATE} (zlib)")
            if tail:
                tail += data
                if len(tail) < need:
                    continue  # the object goes on in the next container: nothing to parse
                data = tail
            used, need = yield from self._objects(data, at)
            if cut:
                return
            tail = bytearray(data[used:])

    # -- the objects inside the containers: frames -----------------------------------------
    def _objects(self, data, at: int):
        """Yield the frames of the whole objects in ``data`` (the containers' contents from
        an object's start); return ``(bytes used, bytes the next object needs)``."""
        start = self.start_timestamp
        end = len(data)
        pos = 0
        while True:
            # an object starts at the next 'LOBJ' within the padding (up to 8 bytes)
            if end - pos < _BASE:
                return pos, _BASE
            found = bytes(data[pos:pos + 8]).find(b"LOBJ")
            if found < 0:
                raise BlfError(f"the container at byte {at}: no object where one should "
                               "start ('LOBJ')")
            pos += found
            if end - pos < _BASE:
                return pos, _BASE
            _, header_size, version, size, kind = OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)
            stamp = _HEADERS.get(version)
            least = _BASE + (stamp.size if stamp else 0) + _BODY.get(kind, 0)
            if size < least:
                raise BlfError(f"the container at byte {at}: an object of type {kind} of "
                               f"{size} bytes, less than the {least} its headers and fields "
                               "take")
            if size > MAX_CONTAINER_BYTES:
                raise BlfError(f"the container at byte {at}: an object of {size / MB:.0f} MB; "
                               f"valid is at most {MAX_CONTAINER_BYTES // MB} MB")
            if pos + size > end:
                return pos, size  # it continues in the next container
            if stamp is not None and kind in _BODY:
                flags, _, _, ticks = stamp.unpack_from(data, pos + _BASE)
                # the time as python-can computes it, exactly: ticks * 1e-5 or 1e-9, rounded
                # once (an int over an int is correctly rounded)
                t = ticks / (100_000 if flags == _TEN_MICROSECONDS else 1_000_000_000) + start
                yield _frame(kind, data, pos + _BASE + stamp.size, t, size, header_size)
            pos += size


def _frame(kind: int, data, pos: int, t: float, size: int, header_size: int) -> can.Message:
    """The frame of an object of ``kind`` whose fields start at ``pos``."""
    if kind in (CAN_MESSAGE, CAN_MESSAGE2):
        channel, flags, dlc, can_id, payload = CAN_MSG_STRUCT.unpack_from(data, pos)
        return can.Message(timestamp=t, arbitration_id=can_id & 0x1FFFFFFF,
                           is_extended_id=bool(can_id & _EXT), is_remote_frame=bool(flags & 0x80),
                           is_rx=not flags & 0x1, dlc=dlc, data=payload[:dlc],
                           channel=channel - 1)
    if kind == CAN_ERROR_EXT:
        fields = CAN_ERROR_EXT_STRUCT.unpack_from(data, pos)
        dlc, can_id = fields[5], fields[7]
        return can.Message(timestamp=t, is_error_frame=True, is_extended_id=bool(can_id & _EXT),
                           arbitration_id=can_id & 0x1FFFFFFF, dlc=dlc, data=fields[9][:dlc],
                           channel=fields[0] - 1)
    if kind == CAN_FD_MESSAGE:
        (channel, flags, dlc, can_id, _, _, fd_flags, valid,
         payload) = CAN_FD_MSG_STRUCT.unpack_from(data, pos)
        return can.Message(timestamp=t, arbitration_id=can_id & 0x1FFFFFFF,
                           is_extended_id=bool(can_id & _EXT), is_remote_frame=bool(flags & 0x80),
                           is_fd=bool(fd_flags & 0x1), is_rx=not flags & 0x1,
                           bitrate_switch=bool(fd_flags & 0x2),
                           error_state_indicator=bool(fd_flags & 0x4), dlc=dlc2len(dlc),
                           data=payload[:valid], channel=channel - 1)
    fields = CAN_FD_MSG_64_STRUCT.unpack_from(data, pos)  # CAN_FD_MESSAGE_64
    channel, dlc, valid, can_id, fd_flags = fields[0], fields[1], fields[2], fields[4], fields[6]
    direction, ext_offset = fields[12], fields[13]
    start = pos + CAN_FD_MSG_64_STRUCT.size
    # the data as far as the object holds it, zero-padded to its length (python-can #1905)
    length = max(0, min(valid, (ext_offset or size) - header_size - CAN_FD_MSG_64_STRUCT.size))
    payload = bytes(data[start:start + length]).ljust(valid, b"\x00")
    return can.Message(timestamp=t, arbitration_id=can_id & 0x1FFFFFFF,
                       is_extended_id=bool(can_id & _EXT), is_remote_frame=bool(fd_flags & 0x10),
                       is_fd=bool(fd_flags & 0x1000), is_rx=not direction,
                       bitrate_switch=bool(fd_flags & 0x2000),
                       error_state_indicator=bool(fd_flags & 0x4000), dlc=dlc2len(dlc),
                       data=payload, channel=channel - 1)
