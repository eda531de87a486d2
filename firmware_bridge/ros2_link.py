"""The ``ros2`` link: a Franka driven by franka_ros2, through Cyclone DDS (extra ``ros2``).

No rclpy: the ``cyclonedds`` binding speaks the ROS 2 wire (:mod:`firmware_bridge.ros2_types`
has the names, types and layouts, from rmw_cyclonedds_cpp's sources).

- **Source**: ``sensor_msgs/msg/JointState`` on ``channel`` (default
  ``/franka/joint_states``, franka_ros2's 1 kHz broadcaster; ``effort`` is tau_J), read with a
  best-effort, volatile reader (it matches reliable and best-effort writers) holding up to
  ``BUFFERED_CYCLES`` messages. Joints are mapped by name (``joints``: ``"auto"`` takes
  ``fr3_joint1..7`` or ``panda_joint1..7``, whichever the message carries; ``"fr3"``,
  ``"panda"`` or seven names). ``t`` is ``header.stamp`` (s), ``cycle`` is
  ``round(t·1000)``; a message whose stamp does not advance is dropped (``stale``: the same
  stamp, ``out_of_order``: older by < 1 s; older by more is a restart of the ROS clock,
  accepted and counted in ``resyncs``), a stamp gap of k periods counts k-1 ``lost``.
  Messages without the seven joints, or without positions, velocities and efforts for them,
  or with non-finite values count as ``malformed``. ``last_frame_time`` is the writer's
  DDS source time stamp (epoch s).
- **Estimate**: :meth:`Ros2Link.publish_estimate` (the service calls it every cycle)
  publishes at most ``estimate_rate_hz`` times a second a ``geometry_msgs/msg/InertiaStamped``
  on ``estimate_topic`` (mass, CoM and inertia about the CoM in the flange frame
  ``flange_frame``, stamped with the joint state's time) and their standard deviations, in
  the same message type and fields, on ``estimate_std_topic`` (first-order propagation of
  the model's per-parameter standard deviations, taken as independent).
- **Sink**: ``franka_msgs/srv/SetLoad`` on ``set_load_service``
  (:class:`firmware_bridge.ros2_setload.SetLoadClient`), from a worker thread, never on the
  1 kHz cycle; written only to an rmw_cyclonedds_cpp replier. ``load_report`` is the load in
  force as franka_ros2's ``franka_msgs/msg/FrankaRobotState`` on ``robot_state_topic``
  reports it (:mod:`firmware_bridge.ros2_robot_state`).
- **Diagnostics**: :meth:`Ros2Link.publish_diagnostics` publishes the gate's verdict as a
  ``diagnostic_msgs/msg/DiagnosticArray`` on ``diagnostics_topic``
  (:mod:`firmware_bridge.ros2_diagnostics`).
"""

from __future__ import annotations

import collections
import logging
import math
import time

import numpy as np

from iem.types import NOMINAL_RATE_HZ, JointState

from .errors import BridgeConfigError, ControllerSilent
from .links import BUFFERED_CYCLES, LinkCounters
from .reassembly import CYCLE_MOD
from .ros2_diagnostics import DEFAULT_TOPIC as DEFAULT_DIAGNOSTICS_TOPIC
from .ros2_inertia import inertia_message, inertia_std, inertia_values
from .ros2_robot_state import DEFAULT_TOPIC as DEFAULT_ROBOT_STATE_TOPIC

log = logging.getLogger("iem.ros2")

JOINT_SETS = {"fr3": tuple(f"fr3_joint{i}" for i in range(1, 8)),
              "panda": tuple(f"panda_joint{i}" for i in range(1, 8))}
"""The joint names of franka_ros2's arms, by arm prefix."""

DEFAULT_TOPIC = "/franka/joint_states"
DEFAULT_ESTIMATE_TOPIC = "/iem/payload"
DEFAULT_SET_LOAD_SERVICE = "/service_server/set_load"
RESYNC_S = 1.0
"""A stamp this much older than the last one is a restarted ROS clock, not a late message."""


def _joint_names(joints) -> tuple[str, ...] | None:
    """None for ``"auto"``; the seven names of ``"fr3"``, ``"panda"`` or a list of seven."""
    if isinstance(joints, str):
        if joints == "auto":
            return None
        if joints in JOINT_SETS:
            return JOINT_SETS[joints]
    elif isinstance(joints, list | tuple) and len(joints) == 7 and \
            all(isinstance(n, str) and n for n in joints) and len(set(joints)) == 7:
        return tuple(joints)
    raise BridgeConfigError(f"ros2 joints {joints!r} is not valid; valid: 'auto', 'fr3', "
                            "'panda' or a list of 7 distinct joint names")


def match_joints(names, joints: tuple[str, ...] | None = None
                 ) -> tuple[tuple[int, ...], tuple[str, ...]] | None:
    """Where the seven arm joints are among a JointState's ``names``: ``(index, joint_set)``
    with ``names[index[i]] == joint_set[i]``, or None if ``names`` lacks one of them.
    ``joints``: the seven names to look for (see :func:`_joint_names`); None (``"auto"``):
    the first set of :data:`JOINT_SETS` (fr3, then panda) whose seven names all appear."""
    wanted = [joints] if joints is not None else list(JOINT_SETS.values())
    where = {n: i for i, n in enumerate(names)}
    for joint_set in wanted:
        if all(n in where for n in joint_set):
            return tuple(where[n] for n in joint_set), tuple(joint_set)
    return None


class Ros2Link:
    """Joint states from a ROS 2 topic; estimates to topics; loads to franka_ros2's set_load.

    Args:
        topic: the JointState topic.
        domain_id: the ROS 2 domain (``ROS_DOMAIN_ID``).
        joints: see the module docstring.
        estimate_topic, estimate_std_topic: where :meth:`publish_estimate` publishes ("" for
            the std topic: ``estimate_topic + "_std"``).
        estimate_rate_hz: at most this many estimates a second (> 0).
        set_load_service: franka_ros2's SetLoad service ("": no write-back).
        set_load_timeout_s: how long the worker waits for a reply.
        flange_frame: ``frame_id`` of the estimate ("": ``<arm>_link8`` of the joints read).
        robot_state_topic: franka_ros2's FrankaRobotState, the load in force ("": none).
        diagnostics_topic: where :meth:`publish_diagnostics` publishes ("": nowhere).
        config: the Cyclone XML (:func:`firmware_bridge.ros2_dds.cyclone_config`) or None.
        silence_timeout: ``read``'s default timeout, s.
    """

    rate_hz = NOMINAL_RATE_HZ
    """Joint states per second franka_ros2 publishes on ``/franka/joint_states``."""

    def __init__(self, topic: str = DEFAULT_TOPIC, *, domain_id: int = 0, joints="auto",
                 estimate_topic: str = DEFAULT_ESTIMATE_TOPIC, estimate_std_topic: str = "",
                 estimate_rate_hz: float = 10.0,
                 set_load_service: str = DEFAULT_SET_LOAD_SERVICE,
                 set_load_timeout_s: float = 2.0, flange_frame: str = "",
                 robot_state_topic: str = DEFAULT_ROBOT_STATE_TOPIC,
                 diagnostics_topic: str = DEFAULT_DIAGNOSTICS_TOPIC,
                 config: str | None = None, silence_timeout: float = 0.1) -> None:
        from . import ros2_dds
        from .ros2_types import InertiaStamped, JointStateMsg, topic_name

        self._names = _joint_names(joints)
        if not estimate_rate_hz > 0:
            raise BridgeConfigError(f"ros2 estimate_rate_hz {estimate_rate_hz!r} must be > 0")
        std_topic = estimate_std_topic or estimate_topic + "_std"
        dds_topics = [topic_name(t) for t in (topic, estimate_topic, std_topic)]
        self.name = f"ROS 2 {topic} (domain {domain_id})"
        self.topic = topic
        self.domain_id = int(domain_id)
        self.estimate_topic, self.estimate_std_topic = estimate_topic, std_topic
        self.silence_timeout = float(silence_timeout)
        self.counters = LinkCounters()
        self.last_frame_time = 0.0
        self.published = 0
        self.unpublishable = 0
        self._flange_frame = flange_frame
        self._period = 1.0 / float(estimate_rate_hz)
        self._next_publish = 0.0
        self._index: dict[tuple[str, ...], tuple[int, ...] | None] = {}
        self._pending: collections.deque[JointState] = collections.deque()
        self._last_t: float | None = None
        self._resync = False

        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self._dp = ros2_dds.participant(self.domain_id, config)
        js_topic = Topic(self._dp, dds_topics[0], JointStateMsg)
        self._reader = DataReader(self._dp, js_topic,
                                  qos=ros2_dds.qos(reliable=False, depth=BUFFERED_CYCLES))
        self._condition = ReadCondition(self._reader, SampleState.Any | ViewState.Any
                                        | InstanceState.Any)
        self._waitset = WaitSet(self._dp)
        self._waitset.attach(self._condition)
        self._estimate_writer = DataWriter(
            self._dp, Topic(self._dp, dds_topics[1], InertiaStamped),
            qos=ros2_dds.qos(reliable=True, depth=10))
        self._std_writer = DataWriter(
            self._dp, Topic(self._dp, dds_topics[2], InertiaStamped),
            qos=ros2_dds.qos(reliable=True, depth=10))
        self._client = None
        if set_load_service:
            from .ros2_setload import SetLoadClient

            self._client = SetLoadClient(self._dp, set_load_service,
                                         timeout_s=set_load_timeout_s, domain_id=domain_id,
                                         counters=self.counters)
        self._reports = self._diagnostics = None
        if robot_state_topic:
            from .ros2_robot_state import LoadReportReader

            self._reports = LoadReportReader(self._dp, robot_state_topic)
        if diagnostics_topic:
            from .ros2_diagnostics import DiagnosticsWriter

            self._diagnostics = DiagnosticsWriter(self._dp, self.name, diagnostics_topic)

    # -- source ----------------------------------------------------------------------------
    def _joint_index(self, names: tuple[str, ...]) -> tuple[int, ...] | None:
        try:
            return self._index[names]
        except KeyError:
            pass
        found = match_joints(names, self._names)
        index = None if found is None else found[0]
        if found is not None and not self._flange_frame:
            self._flange_frame = found[1][0].rsplit("_joint", 1)[0] + "_link8"
        if index is None:
            log.warning("%s: a JointState without the joints %s (it names %s): dropped, "
                        "counted as malformed; set [arm] model to the arm that publishes it, "
                        "or [ros2] joints", self.name,
                        ", ".join(self._names or ("fr3_joint1..7", "panda_joint1..7")),
                        ", ".join(names) or "none", extra={"event": "ros2_joint_names"})
        self._index[names] = index
        return index

    def _convert(self, msg) -> JointState | None:
        c = self.counters
        c.received += 1
        names = tuple(msg.name)
        index = self._joint_index(names)
        n = len(names)
        if index is None or not (len(msg.position) == len(msg.velocity) == len(msg.effort)
                                 == n):
            c.malformed += 1
            return None
        q = [msg.position[i] for i in index]
        dq = [msg.velocity[i] for i in index]
        tau = [msg.effort[i] for i in index]
        if not all(math.isfinite(v) for v in (*q, *dq, *tau)):
            c.malformed += 1
            return None
        stamp = msg.header.stamp
        t = stamp.sec + stamp.nanosec * 1e-9
        last = self._last_t
        if last is not None:
            dt = t - last
            if dt <= 0.0 and not self._resync:
                if dt == 0.0:
                    c.stale += 1
                    return None
                if dt > -RESYNC_S:
                    c.out_of_order += 1
                    return None
                c.resyncs += 1
            elif dt > 0.0:
                gap = round(dt * self.rate_hz) - 1
                if gap > 0:
                    c.lost += gap
        self._resync = False
        self._last_t = t
        c.delivered += 1
        return JointState(t=t, q=q, dq=dq, tau_J=tau, cycle=round(t * NOMINAL_RATE_HZ) % CYCLE_MOD)

    def _take(self) -> None:
        from .ros2_types import JointStateMsg

        for sample in self._reader.take(N=256):
            if not isinstance(sample, JointStateMsg):
                continue  # an instance state change (a writer gone), no data
            state = self._convert(sample)
            if state is not None:
                self._pending.append(state)
                self.last_frame_time = sample.sample_info.source_timestamp * 1e-9

    def read(self, timeout: float | None = None) -> JointState:
        """The next joint state; ControllerSilent after ``timeout`` s (None: the link's
        ``silence_timeout``) without one."""
        if not self._pending:
            timeout = self.silence_timeout if timeout is None else float(timeout)
            deadline = time.monotonic() + timeout
            self._take()
            while not self._pending:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    self.counters.silences += 1
                    self._resync = True
                    raise ControllerSilent(f"{self.name}: no JointState for {timeout:g} s")
                self._waitset.wait(max(1, int(left * 1e9)))
                self._take()
        return self._pending.popleft()

    # -- estimate --------------------------------------------------------------------------
    def publish_estimate(self, estimate, phi=None) -> bool:
        """Publish ``estimate`` (a :class:`iem.types.PayloadEstimate`; ``phi``: the values to
        publish instead of its own, e.g. the smoothed ones) if ``1/estimate_rate_hz`` s
        passed since the last one; True if published. An estimate without a positive mass
        (no CoM) or with non-finite values is counted in ``unpublishable``, not published,
        and the next one may go at once."""
        now = time.monotonic()
        if now < self._next_publish:
            return False
        phi = np.asarray(estimate.phi if phi is None else phi, dtype=float)
        try:
            values = inertia_values(phi)
        except ValueError:
            self.unpublishable += 1
            return False
        if not np.all(np.isfinite(values)):
            self.unpublishable += 1
            return False
        due = self._next_publish + self._period  # keeps the average rate ...
        self._next_publish = due if due > now else now + self._period  # ... unless behind
        frame = self._flange_frame or "fr3_link8"
        self._estimate_writer.write(inertia_message(values, frame, estimate.t))
        if getattr(estimate, "std", None) is not None:
            self._std_writer.write(inertia_message(inertia_std(phi, estimate.std), frame,
                                                   estimate.t))
        self.published += 1
        return True

    # -- sink ------------------------------------------------------------------------------
    def _sink(self):
        if self._client is None:
            raise BridgeConfigError(f"{self.name}: no [ros2] set_load_service configured: "
                                    "this link does not write loads")
        return self._client

    def send(self, payload) -> int:
        """Queue ``payload`` (None clears the load) for the set_load worker; its sequence
        number. The reply arrives as ``last_ack``."""
        return self._sink().send(payload)

    @property
    def last_ack(self):
        return None if self._client is None else self._client.last_ack

    @property
    def load_report(self):
        """The newest :class:`~firmware_bridge.messages.LoadReport` of franka_ros2's robot
        state (its values, no sequence number), or None before one arrived."""
        return None if self._reports is None else self._reports.latest()

    def wait_for_service(self, timeout: float) -> str:
        """Wait up to ``timeout`` s for an rmw_cyclonedds SetLoad replier to be discovered;
        why none can be written to ("" once one is)."""
        deadline = time.monotonic() + timeout
        while True:
            problem = self._sink().replier_problem()
            if not problem or time.monotonic() >= deadline:
                return problem
            time.sleep(0.02)

    # -- diagnostics -----------------------------------------------------------------------
    def publish_diagnostics(self, verdict: dict) -> bool:
        """Publish the gate's ``verdict`` on ``diagnostics_topic`` now (the caller paces it);
        True if published, False without a diagnostics topic."""
        if self._diagnostics is None:
            return False
        return self._diagnostics.publish(verdict)

    def wait_ack(self, seq: int, timeout: float = 1.0):
        return self._sink().wait_ack(seq, timeout)

    @property
    def set_load(self):
        """The SetLoad client (its counters and state), or None."""
        return self._client

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._waitset = self._condition = self._reader = None
        self._estimate_writer = self._std_writer = self._dp = None
        self._reports = self._diagnostics = None


def open_ros2_link(kind: str, channel: str, *, profile: str | None = None,
                   silence_timeout: float = 0.1, domain_id: int | None = None,
                   joints="auto", estimate_topic: str = DEFAULT_ESTIMATE_TOPIC,
                   estimate_std_topic: str = "", estimate_rate_hz: float = 10.0,
                   set_load_service: str = DEFAULT_SET_LOAD_SERVICE,
                   set_load_timeout_s: float = 2.0, flange_frame: str = "",
                   robot_state_topic: str = DEFAULT_ROBOT_STATE_TOPIC,
                   diagnostics_topic: str = DEFAULT_DIAGNOSTICS_TOPIC,
                   interface: str = "", peers=()) -> Ros2Link:
    """Opener for :func:`firmware_bridge.links.open_link`: ``channel`` is the JointState
    topic ("" : ``/franka/joint_states``); ``profile`` is a CAN notion and not used.
    ``domain_id`` None: ``ROS_DOMAIN_ID`` from the environment, else 0; ``interface`` and
    ``peers`` "" and (): ``CYCLONEDDS_URI`` from the environment (see
    :func:`firmware_bridge.ros2_dds.cyclone_config`)."""
    import os

    from .ros2_dds import cyclone_config, require_cyclonedds

    require_cyclonedds()  # before anything imports it: a clear error naming the extra

    if domain_id is None:
        env = os.environ.get("ROS_DOMAIN_ID", "").strip()
        try:
            domain_id = int(env) if env else 0
        except ValueError:
            raise BridgeConfigError(f"ROS_DOMAIN_ID={env!r} is not an integer; valid: 0 to "
                                    "232") from None
    return Ros2Link(channel or DEFAULT_TOPIC, domain_id=domain_id, joints=joints,
                    estimate_topic=estimate_topic, estimate_std_topic=estimate_std_topic,
                    estimate_rate_hz=estimate_rate_hz, set_load_service=set_load_service,
                    set_load_timeout_s=set_load_timeout_s, flange_frame=flange_frame,
                    robot_state_topic=robot_state_topic, diagnostics_topic=diagnostics_topic,
                    config=cyclone_config(interface, tuple(peers)),
                    silence_timeout=silence_timeout)
