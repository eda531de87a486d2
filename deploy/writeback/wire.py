"""The link's wire range check of a load command, for the gate: a load the wire cannot carry
is never sent."""

from __future__ import annotations

import functools


def wire_check_of(link):
    """The range check of ``link``'s load command for the gate: a link that declares a DBC
    wire profile (:class:`firmware_bridge.links.WireProfiled`: the CAN links, a replayed CAN
    log) has one (:func:`firmware_bridge.protocol.payload_wire_error`); others (serial
    msgpack floats, pylibfranka, ROS 2) have no ranges to check: None. (A CAN kind's link
    that declares no profile is refused where the service opens it:
    :func:`deploy.service.capabilities.wire_check_for`.)
    """
    from firmware_bridge.links import WireProfiled
    from firmware_bridge.protocol import payload_wire_error

    if not isinstance(link, WireProfiled):
        return None
    return functools.partial(payload_wire_error, profile=link.profile.name)
