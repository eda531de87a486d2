"""The link's wire range check of a load command, for the gate: a load the wire cannot carry
is never sent."""

from __future__ import annotations


def wire_check_of(link, kind: str | None = None):
    """The range check of ``link``'s load command for the gate, as its link kind declares it
    (:attr:`firmware_bridge.links.LinkKind.load_range`, checked by
    :meth:`firmware_bridge.load_range.LoadRange.error`): a link that declares a DBC wire
    profile (:class:`firmware_bridge.links.WireProfiled`: the CAN links, a replayed CAN log)
    the profile's signals; a link of the serial, franka or ros2 kind any finite double; None
    for a link of no known kind that declares no profile, or of a kind that carries no loads.
    (A CAN kind's link that declares no profile is refused where the service opens it:
    :func:`deploy.service.capabilities.wire_check_for`.)
    """
    from firmware_bridge.links import LINKS, WireProfiled
    from firmware_bridge.load_range import FLOAT64, of_profile

    if isinstance(link, WireProfiled):
        return of_profile(link.profile.name).error
    declared = "" if kind is None else LINKS[kind].load_range
    return FLOAT64.error if declared == "float64" else None
