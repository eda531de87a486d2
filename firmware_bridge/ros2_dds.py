"""Cyclone DDS set-up for the ``ros2`` link: one domain per id in this process, its XML
configuration, and the QoS profiles of ROS 2 (extra ``ros2``: the ``cyclonedds`` binding).

:func:`cyclone_config` writes the ``<General>``/``<Discovery>`` part a cell.toml asks for:
the network interface (``[ros2] interface``) and unicast peers (``[ros2] peers``; with peers,
multicast is off). With neither, no configuration is made here and Cyclone reads
``CYCLONEDDS_URI`` from the environment, as ROS 2's own nodes do.
"""

from __future__ import annotations

import threading
from xml.sax.saxutils import quoteattr

from .errors import BridgeConfigError

_lock = threading.Lock()
_domains: dict[int, tuple[object, str | None]] = {}


def cyclone_config(interface: str = "", peers: tuple[str, ...] = (),
                   max_participants: int = 32) -> str | None:
    """The Cyclone XML of a network ``interface`` (a name such as ``eth0`` or ``lo``, or an
    address) and unicast ``peers`` (addresses; multicast off when given); None for neither.

    With peers, discovery probes ``max_participants`` participant indices per peer, so that
    several participants on one host find each other without multicast.
    """
    if not interface and not peers:
        return None
    general = []
    if interface:
        general.append(f"<Interfaces><NetworkInterface name={quoteattr(interface)}/>"
                       "</Interfaces>")
    if peers:
        general.append("<AllowMulticast>false</AllowMulticast>")
    discovery = ""
    if peers:
        peer_xml = "".join(f"<Peer address={quoteattr(p)}/>" for p in peers)
        discovery = (f"<Discovery><ParticipantIndex>auto</ParticipantIndex>"
                     f"<MaxAutoParticipantIndex>{int(max_participants)}"
                     f"</MaxAutoParticipantIndex><Peers>{peer_xml}</Peers></Discovery>")
    return ('<CycloneDDS xmlns="https://cdds.io/config"><Domain id="any"><General>'
            + "".join(general) + "</General>" + discovery + "</Domain></CycloneDDS>")


def require_cyclonedds() -> None:
    """BridgeConfigError naming the extra to install if the Cyclone DDS binding is missing."""
    try:
        import cyclonedds  # noqa: F401
    except ImportError as exc:
        raise BridgeConfigError("the ros2 link needs the Cyclone DDS binding: install the "
                                "extra, pip install 'iem-payload[ros2]'") from exc


def participant(domain_id: int, config: str | None):
    """A new DomainParticipant on ``domain_id``, the domain created once per process with
    ``config`` (None: Cyclone's own, from ``CYCLONEDDS_URI``). Another configuration for a
    domain this process already uses is a BridgeConfigError: Cyclone has one per domain."""
    require_cyclonedds()
    from cyclonedds.domain import Domain, DomainParticipant

    if not 0 <= int(domain_id) <= 232:
        raise BridgeConfigError(f"ROS 2 domain id {domain_id} is out of range; valid: 0 to 232")
    with _lock:
        known = _domains.get(domain_id)
        if known is None:
            domain = Domain(domain_id, config) if config is not None else None
            _domains[domain_id] = (domain, config)
        elif known[1] != config:
            raise BridgeConfigError(
                f"ROS 2 domain {domain_id} is already in use in this process with another "
                "network configuration ([ros2] interface/peers); one process has one per domain")
        return DomainParticipant(domain_id)


def qos(*, reliable: bool, depth: int, user_data: bytes = b""):
    """A ROS 2 QoS: volatile, keep-last ``depth``, reliable or best-effort, with USER_DATA."""
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.util import duration

    policies = [
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)) if reliable
        else Policy.Reliability.BestEffort,
        Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
        Policy.WriterDataLifecycle(autodispose=False),
    ]
    if user_data:
        policies.append(Policy.Userdata(data=user_data))
    return Qos(*policies)


def user_data_of(endpoint) -> bytes:
    """The USER_DATA bytes of a discovered endpoint (``DcpsEndpoint``), b"" if none."""
    from cyclonedds.qos import Policy

    if endpoint is None or endpoint.qos is None:
        return b""
    policy = endpoint.qos[Policy.Userdata]
    return bytes(policy.data) if policy is not None else b""
