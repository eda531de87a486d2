"""The safety gate's verdict on ROS 2 ``/diagnostics`` (extra ``ros2``), as ROS tools expect
it (``rqt_robot_monitor``, ``diagnostic_aggregator``): a ``diagnostic_msgs/msg/DiagnosticArray``
with one ``DiagnosticStatus``.

- ``name``: :data:`STATUS_NAME`; ``hardware_id``: the link's name;
- ``level`` (:func:`level_of`): OK (0) when the gate's last decision wrote the estimate
  (``send``) or the load in force agrees with it (``no_change``); WARN (1) while the gate
  holds for a reason that passes as the estimate converges or the robot comes to rest; ERROR
  (2) for an estimate that can never be written, a silent controller, lost commands, or an
  estimate that does not say how good it is;
- ``message``: the reason, then its detail;
- ``values``: every key of the verdict, each value as text (strings as they are, the rest as
  JSON: ``load_in_force`` is ``null`` for the empty load, ``"unknown"`` until the controller
  confirmed a load, else ``{"mass", "com", "inertia"}``).

The verdict is the dict the gate hands over (``SafetyGate.verdict()``): at least ``reason``,
``detail``, ``load_in_force`` and the counts ``sent``, ``acked``, ``lost``, ``in_force``,
``send_errors``, ``refusals``. Each call publishes; the caller paces it (the service: once a
second, diagnostic_updater's rate).
"""

from __future__ import annotations

import json
import time

OK, WARN, ERROR = 0, 1, 2
"""``DiagnosticStatus`` levels."""
STATUS_NAME = "iem: payload write-back"
DEFAULT_TOPIC = "/diagnostics"

LEVELS = {
    "send": OK, "no_change": OK,
    "unstable": WARN, "uncertain": WARN, "unverified": WARN, "data_disagree": WARN,
    "out_of_distribution": WARN, "rate_limited": WARN, "refused": WARN,
    "not_finite": ERROR, "inconsistent": ERROR, "over_rated": ERROR, "com_too_far": ERROR,
    "out_of_wire_range": ERROR, "malformed": ERROR, "stale": ERROR,
    "controller_silent": ERROR, "ack_missing": ERROR, "lost": ERROR, "unreported": ERROR,
    "controller_disagrees": ERROR,
}
"""The level of each reason of the gate. ``refused``: a Franka refuses ``setLoad`` while a
controller runs, and the gate retries; ``stale``: the estimate stopped coming."""


def level_of(reason: str) -> int:
    """The ``DiagnosticStatus`` level of a gate reason; WARN for one not in :data:`LEVELS`
    (no decision yet, or a reason this table does not know: not OK, not known to be wrong)."""
    return LEVELS.get(reason, WARN)


def text_of(value) -> str:
    """A verdict value as a KeyValue's text: a string as it is, anything else as JSON."""
    if isinstance(value, str):
        return value
    return json.dumps(value, default=float)


def diagnostic_array(verdict: dict, hardware_id: str, t: float | None = None):
    """The ``DiagnosticArray`` of ``verdict`` at ``t`` s (None: now)."""
    from .ros2_inertia import stamp
    from .ros2_types import DiagnosticArray, DiagnosticStatus, Header, KeyValue

    reason = str(verdict.get("reason", ""))
    detail = str(verdict.get("detail", ""))
    message = f"{reason}: {detail}" if detail else (reason or "no decision yet")
    status = DiagnosticStatus(level=level_of(reason), name=STATUS_NAME, message=message,
                              hardware_id=hardware_id,
                              values=[KeyValue(key=str(k), value=text_of(v))
                                      for k, v in verdict.items()])
    return DiagnosticArray(header=Header(stamp=stamp(time.time() if t is None else t)),
                           status=[status])


class DiagnosticsWriter:
    """``/diagnostics`` of one participant: :meth:`publish` a verdict."""

    def __init__(self, participant, hardware_id: str, topic: str = DEFAULT_TOPIC) -> None:
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        from . import ros2_dds
        from .ros2_types import DiagnosticArray, topic_name

        self.hardware_id = hardware_id
        self.published = 0
        self._writer = DataWriter(participant, Topic(participant, topic_name(topic),
                                                     DiagnosticArray),
                                  qos=ros2_dds.qos(reliable=True, depth=10))

    def publish(self, verdict: dict) -> bool:
        """Publish ``verdict`` now; True."""
        self._writer.write(diagnostic_array(verdict, self.hardware_id))
        self.published += 1
        return True
