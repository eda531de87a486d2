"""What the service requires of the link it runs on, as the configured ``[link] kind``
declares it (:data:`firmware_bridge.links.LINKS`): a payload sink where the kind writes loads,
a wire profile where the kind is a CAN bus, whose loads travel in DBC signals. A link that
lacks what its kind declares is a configuration error, refused before anything is written.
"""

from __future__ import annotations

from deploy.config import ConfigError
from deploy.writeback.wire import wire_check_of
from firmware_bridge.links import PayloadSink


def check_sink(link, write: bool) -> None:
    """Refuse ``link`` as the load writer's sink when ``write`` and it is no payload sink.

    Raises:
        ConfigError: ``write`` with a link that is not a PayloadSink: it cannot write, and
            deciding only would take its loads as in force.
    """
    if write and not isinstance(link, PayloadSink):
        raise ConfigError(f"the link {type(link).__name__} cannot write loads: it is not a "
                          "firmware_bridge.links.PayloadSink (send, last_ack, "
                          "load_report, wait_ack, close), yet its [link] kind writes "
                          "them; give a link of that kind, or run with writes off")


def wire_check_for(link, kind: str | None = None):
    """The range check of ``link``'s load command for the gate
    (:func:`deploy.writeback.wire.wire_check_of`; None: no ranges to check).

    Raises:
        ConfigError: ``kind``, the configured ``[link] kind``, is a CAN bus, whose loads
            travel in DBC signals, but ``link`` declares no wire profile.
    """
    from firmware_bridge.links import LINKS, WireProfiled

    if not isinstance(link, WireProfiled) and kind is not None and LINKS[kind].bus:
        raise ConfigError(f"[link] kind {kind!r} sends loads in the DBC's signals, but "
                          f"the link {type(link).__name__} declares no wire profile to "
                          "check them against (firmware_bridge.links.WireProfiled: a "
                          "'profile' attribute)")
    return wire_check_of(link, kind)
