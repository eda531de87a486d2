"""The load in force as franka_ros2 reports it, for the ``ros2`` link (extra ``ros2``).

franka_ros2's ``franka_robot_state_broadcaster`` publishes ``franka_msgs/msg/FrankaRobotState``
on ``~/robot_state`` (``/franka_robot_state_broadcaster/robot_state`` without a namespace),
once per control cycle. Its ``inertia_load`` is libfranka's ``m_load``, ``F_x_Cload`` and
``I_load``: the load the robot holds now, whoever set it (mass, CoM in the flange frame,
inertia about the CoM; mass 0 for none). :class:`LoadReportReader` keeps the newest as a
:class:`~firmware_bridge.messages.LoadReport` with ``has_values`` and no sequence number.

The message is read up to ``inertia_load`` (:class:`firmware_bridge.ros2_types.FrankaRobotState`,
the layout of franka_ros2's ``franka_msgs`` at frankaemika/franka_ros2 429b37a). A release
that moved a field before it would be misread, so a sample is taken only if it reads as
franka_ros2 fills it: seven measured joints, ``inertia_load`` in the ``<arm>_link9`` frame
(franka_semantic_components names the load frame so), finite values, mass >= 0. Any other is
dropped, counted in ``unreadable`` and logged once: the link then has no report, as if the
robot said nothing.
"""

from __future__ import annotations

import logging
import math
import time

from .messages import LoadReport

log = logging.getLogger("iem.ros2")

DEFAULT_TOPIC = "/franka_robot_state_broadcaster/robot_state"


class LoadReportReader:
    """A best-effort reader of FrankaRobotState keeping the latest sample only."""

    def __init__(self, participant, topic: str = DEFAULT_TOPIC) -> None:
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from . import ros2_dds
        from .ros2_types import FrankaRobotState, topic_name

        self.topic = topic
        self.received = 0
        self.unreadable = 0
        self._report: LoadReport | None = None
        self._reader = DataReader(participant, Topic(participant, topic_name(topic),
                                                     FrankaRobotState),
                                  qos=ros2_dds.qos(reliable=False, depth=1))

    def latest(self) -> LoadReport | None:
        """The newest report (taking what arrived since the last call), or None before any."""
        from .ros2_inertia import load_of
        from .ros2_types import FrankaRobotState

        newest = None
        for sample in self._reader.take(N=64):
            if not isinstance(sample, FrankaRobotState):  # an instance state change
                continue
            self.received += 1
            if readable(sample):
                newest = sample
            else:
                self.unreadable += 1
                if self.unreadable == 1:
                    log.warning("%s: a FrankaRobotState that does not read as franka_ros2's "
                                "(another franka_msgs release?): the load in force is not "
                                "taken from it", self.topic,
                                extra={"event": "ros2_robot_state_unreadable"})
        if newest is not None:
            self._report = LoadReport(t=time.perf_counter(), seq=None,
                                      load=load_of(newest.inertia_load.inertia),
                                      has_values=True)
        return self._report

    def close(self) -> None:
        self._reader = None


def readable(msg) -> bool:
    """True if ``msg`` reads as franka_ros2 fills a FrankaRobotState (see the module
    docstring)."""
    inertia = msg.inertia_load.inertia
    values = (inertia.m, inertia.com.x, inertia.com.y, inertia.com.z, inertia.ixx, inertia.ixy,
              inertia.ixz, inertia.iyy, inertia.iyz, inertia.izz)
    return (len(msg.measured_joint_state.name) == 7
            and msg.inertia_load.header.frame_id.endswith("_link9")
            and all(math.isfinite(v) for v in values) and inertia.m >= 0.0)
