"""The bridge's errors, all under :class:`iem.errors.IemError`.

- :class:`DecodeError`: one frame or one serial message is bad. Its ``kind`` says how
  (``crc``, ``malformed``); a source catches it, counts the frame under that kind and goes on.
- :class:`EncodeError`: a value cannot be put on the wire (out of the signal's range).
- :class:`LinkError`: the bus, the serial port or the robot connection failed (open, send,
  receive); the cause is chained. :class:`ControllerSilent` (also a :class:`TimeoutError`)
  is the controller saying nothing for longer than allowed; :class:`AckTimeout` is a payload
  command that was not acknowledged in time; :class:`EndOfStream` is the end of a replayed
  log.
- :class:`BridgeConfigError`: a bus kind, channel, profile or option that does not exist.
- :class:`LogFileError`: a traffic log that cannot be written or read.
"""

from __future__ import annotations

from iem.errors import IemError, InvalidInputError


class BridgeError(IemError):
    """Root of the fieldbus bridge's errors."""


class DecodeError(BridgeError):
    """A frame or message that cannot be accepted; ``kind`` is the counter it goes to.

    Attributes:
        kind: ``"crc"`` (end-to-end or CRC32 check failed) or ``"malformed"`` (wrong
            length, layout, type or value range).
    """

    def __init__(self, message: str, kind: str = "malformed") -> None:
        super().__init__(message)
        self.kind = kind


class EncodeError(BridgeError, InvalidInputError):
    """A value does not fit the wire format (the message names the signal and its range)."""


class BridgeConfigError(BridgeError, InvalidInputError):
    """An unknown bus kind, profile or option, or a channel that cannot be used."""


class LinkError(BridgeError):
    """The bus, serial port or robot connection failed; ``__cause__`` holds the original."""


class ControllerSilent(LinkError, TimeoutError):
    """No complete joint state (or no reply) from the controller within the allowed time."""


class AckTimeout(ControllerSilent):
    """A payload command was not acknowledged within the allowed time."""


class EndOfStream(LinkError):
    """A replayed log has no more frames."""


class LogFileError(BridgeError, InvalidInputError):
    """A traffic log file cannot be written or read (format, path or content)."""
