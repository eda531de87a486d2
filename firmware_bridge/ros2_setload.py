"""franka_ros2's ``/service_server/set_load`` (``franka_msgs/srv/SetLoad``) as an
rmw_cyclonedds_cpp client, off the 1 kHz cycle (extra ``ros2``).

The client is a request writer on ``rq/<service>Request`` and a reply reader on
``rr/<service>Reply``, both with USER_DATA ``clientid=<id>;`` (an rmw_cyclonedds service
answers only once it has matched the reader of the client that wrote the request). A request
carries ``{guid: the request writer's instance handle, seq}`` ahead of the SetLoad fields, and
the reply that echoes both is the answer (``rmw_send_request``/``rmw_take_response`` in
rmw_cyclonedds's ``rmw_node.cpp``).

A request is written only if a replier matched on both topics carries ``serviceid=`` in its
USER_DATA, as rmw_cyclonedds_cpp's do (its ``rmw_service_server_is_available`` checks the
same). Any other replier (rmw_fastrtps_cpp, the default RMW of Humble and Jazzy, matches
requests and replies through the RTPS related_sample_identity and has no header: it would
read every field 16 bytes off and ask the robot for a nonsense load; rmw_cyclonedds issues
#184, #503, #577) or none at all: the command is refused at once with the reason (logged once
per reason, counted in ``not_written``), and the link keeps reading and publishing.

``send`` only queues; a worker thread writes the request and waits up to ``timeout_s`` for
the reply (well below systemd's WatchdogSec). The answer becomes ``last_ack``: applied on
``success=true``; a refusal (``applied=False``, with the robot's error text where
:class:`~firmware_bridge.protocol.LoadAck` has an ``error`` field) on ``success=false``,
counted and logged with the text (the gate retries later). No reply within ``timeout_s``:
no acknowledgement (the gate's ack timeout stops writes), counted in ``timeouts``.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time

from iem.payload import Payload, set_load_values

from .errors import AckTimeout
from .messages import LoadAck

log = logging.getLogger("iem.ros2")

_ACK_HAS_ERROR = "error" in {f.name for f in dataclasses.fields(LoadAck)}


def load_ack(seq: int, applied: bool, load, error: str = "") -> LoadAck:
    """A LoadAck with ``error`` where the dataclass has the field (the links refactor adds
    it), without it where it has not."""
    extra = {"error": error} if _ACK_HAS_ERROR else {}
    return LoadAck(seq=seq, applied=applied, load=load, t=time.perf_counter(), **extra)


def set_load_fields(payload: Payload | None) -> tuple[float, list[float], list[float]]:
    """``mass, center_of_mass, load_inertia`` (column-major, about the CoM) of ``payload``;
    zeros clear the load (None)."""
    if payload is not None:
        payload.check()
    return set_load_values(payload)


class SetLoadClient:
    """The SetLoad client of one participant (see the module docstring).

    Attributes:
        requests: requests written.
        successes: ``success=true`` replies.
        refusals: ``success=false`` replies.
        timeouts: requests without a reply within ``timeout_s``.
        not_written: commands refused here, without a request (no rmw_cyclonedds replier).
    """

    def __init__(self, participant, service: str, *, timeout_s: float = 2.0,
                 domain_id: int = 0, counters=None) -> None:
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from . import ros2_dds
        from .ros2_types import (
            SetLoadRequest,
            SetLoadResponse,
            csid_of,
            csid_string,
            reply_topic,
            request_topic,
        )

        self.service = service
        self.domain_id = domain_id
        self.timeout_s = float(timeout_s)
        self.counters = counters
        self.requests = self.successes = self.refusals = self.timeouts = self.not_written = 0
        self.last_ack: LoadAck | None = None
        self.acks: dict[int, LoadAck] = {}
        self.in_force: Payload | None = None
        self._seq = 0
        self._request_seq = 0
        self._reasons_logged: set[str] = set()
        self._errors_logged: set[str] = set()
        self._done = threading.Condition()
        guid = participant.guid.bytes
        self.client_id = csid_string(csid_of(guid, 1))
        user_data = f"clientid={self.client_id};".encode()
        self._writer = DataWriter(participant,
                                  Topic(participant, request_topic(service), SetLoadRequest),
                                  qos=ros2_dds.qos(reliable=True, depth=10, user_data=user_data))
        self._reader = DataReader(participant,
                                  Topic(participant, reply_topic(service), SetLoadResponse),
                                  qos=ros2_dds.qos(reliable=True, depth=10, user_data=user_data))
        self.guid = int(self._writer.instance_handle) & 0xFFFF_FFFF_FFFF_FFFF  # uint64
        self._waitset = WaitSet(participant)
        self._waitset.attach(ReadCondition(self._reader, SampleState.Any | ViewState.Any
                                           | InstanceState.Any))
        self._queue: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._work, name="iem-ros2-set-load",
                                        daemon=True)
        self._thread.start()

    # -- the replier ----------------------------------------------------------------------
    def replier_problem(self) -> str:
        """Why no request can be written now ("" if an rmw_cyclonedds replier matched)."""
        from .ros2_dds import user_data_of
        from .ros2_types import parse_user_data

        readers = [user_data_of(self._writer.get_matched_subscription_data(h))
                   for h in self._writer.get_matched_subscriptions()]
        writers = [user_data_of(self._reader.get_matched_publication_data(h))
                   for h in self._reader.get_matched_publications()]
        if not readers or not writers:
            return (f"no {self.service} service matched in ROS 2 domain {self.domain_id} "
                    f"({len(readers)} request readers, {len(writers)} reply writers): "
                    "franka_ros2 offers it only on a real robot")
        served = {parse_user_data(u).get("serviceid") for u in readers} - {None}
        replying = {parse_user_data(u).get("serviceid") for u in writers} - {None}
        if not served or not replying:
            return (f"the {self.service} replier is not rmw_cyclonedds_cpp (no serviceid= in "
                    "its USER_DATA, e.g. rmw_fastrtps_cpp, the default RMW): its requests "
                    "have another layout and a load sent to it would be misread; start "
                    "franka_ros2 with RMW_IMPLEMENTATION=rmw_cyclonedds_cpp")
        if not served & replying:
            return (f"the {self.service} request readers and reply writers belong to "
                    "different services (their serviceid= differ)")
        return ""

    # -- commands -------------------------------------------------------------------------
    def send(self, payload: Payload | None) -> int:
        """Queue ``payload`` (None clears the load); its sequence number (1..255)."""
        fields = set_load_fields(payload)
        self._seq = self._seq % 255 + 1
        self._queue.put((self._seq, payload, fields))
        return self._seq

    def wait_ack(self, seq: int, timeout: float = 1.0) -> LoadAck:
        """The answer to command ``seq``; AckTimeout after ``timeout`` s without one."""
        deadline = time.monotonic() + timeout
        with self._done:
            while seq not in self.acks:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AckTimeout(f"{self.service}: no answer to load command {seq} "
                                     f"within {timeout:g} s")
                self._done.wait(left)
            return self.acks[seq]

    def _answer(self, seq: int, applied: bool, error: str = "") -> None:
        ack = load_ack(seq, applied, self.in_force, error)
        with self._done:
            self.acks[seq] = ack
            self.last_ack = ack
            self._done.notify_all()
        if self.counters is not None:
            self.counters.acks += 1

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                self._call(*item)
            except Exception as exc:  # the worker outlives one bad call; the gate sees no ack
                log.error("%s: set_load failed: %s: %s", self.service, type(exc).__name__, exc,
                          extra={"event": "ros2_set_load_error"})

    def _call(self, seq: int, payload: Payload | None, fields) -> None:
        from .ros2_types import SetLoadRequest, SetLoadResponse

        problem = self.replier_problem()
        if problem:
            self.not_written += 1
            if problem.split(" (")[0] not in self._reasons_logged:
                self._reasons_logged.add(problem.split(" (")[0])
                log.warning("load command %d not written: %s; estimates are still published",
                            seq, problem, extra={"event": "ros2_set_load_not_written"})
            self._answer(seq, False, problem)
            return
        self._request_seq += 1
        mass, com, inertia = fields
        self._reader.take(N=64)  # late replies to earlier requests
        self._writer.write(SetLoadRequest(guid=self.guid, seq=self._request_seq, mass=mass,
                                          center_of_mass=com, load_inertia=inertia))
        self.requests += 1
        deadline = time.monotonic() + self.timeout_s
        while True:
            for reply in self._reader.take(N=16):
                if isinstance(reply, SetLoadResponse) and reply.guid == self.guid and \
                        reply.seq == self._request_seq:
                    self._replied(seq, payload, reply)
                    return
            left = deadline - time.monotonic()
            if left <= 0:
                self.timeouts += 1
                log.warning("%s: no reply to load command %d within %g s", self.service, seq,
                            self.timeout_s, extra={"event": "ros2_set_load_timeout"})
                return
            self._waitset.wait(max(1, int(left * 1e9)))

    def _replied(self, seq: int, payload: Payload | None, reply) -> None:
        if reply.success:
            self.successes += 1
            self.in_force = payload
            self._answer(seq, True)
            return
        self.refusals += 1
        error = reply.error or "(no error text)"
        if error not in self._errors_logged:
            self._errors_logged.add(error)
            log.warning("%s refused load command %d: %s (the robot accepts set_load only "
                        "while idle; retried later)", self.service, seq, error,
                        extra={"event": "ros2_set_load_refused", "error": error})
        self._answer(seq, False, error)

    def close(self, timeout: float = 5.0) -> None:
        self._queue.put(None)
        self._thread.join(timeout)
