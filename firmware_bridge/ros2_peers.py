"""Stand-ins for franka_ros2's side of the ``ros2`` link, for tests and ``iem bench bridge``.

- :func:`publish_joint_states`: ``sensor_msgs/msg/JointState`` at a fixed rate, stamped
  ``t0 + i/rate`` exactly (so gaps are countable), with franka_ros2's joint names; run in
  its own process with ``python -m firmware_bridge.ros2_peers publish ...`` (it prints
  ``matched`` when a reader matched, then ``done <n>``).
- :class:`Ros2ControllerPort`: a controller's port behind ROS 2: its joint states on
  ``/franka/joint_states``, its loads set through a :class:`SetLoadServer`; the simulated
  controller stands behind it in its own process (``python -m deploy.simcell.ros2_controller``).
- :class:`SetLoadServer`: ``/service_server/set_load`` as rmw_cyclonedds_cpp serves it
  (request header echoed, USER_DATA ``serviceid=``), or, with ``layout="fastrtps"``, a
  replier as rmw_fastrtps_cpp's looks to a Cyclone client: no ``serviceid=`` and no header
  echoed (Fast DDS announces no XTypes type information, so Cyclone matches it on the type
  name alone; here the same Python types stand in for that match). ``answer(request)``
  decides ``(success, error)``.

Cyclone is configured by the caller (:func:`firmware_bridge.ros2_dds.cyclone_config`): the
tests and the benchmark use ``lo`` with the unicast peer 127.0.0.1 and no multicast.
"""

from __future__ import annotations

import argparse
import queue
import sys
import threading
import time

import numpy as np

from iem.types import NOMINAL_RATE_HZ

from .ros2_inertia import stamp as _stamp
from .ros2_link import JOINT_SETS


def joint_state_messages(n: int, t0: float, rate_hz: float = NOMINAL_RATE_HZ, arm: str = "fr3"):
    """``n`` JointState messages of a smooth motion (rad, rad/s, N·m), stamped
    ``t0 + i/rate_hz``."""
    from .ros2_types import Header, JointStateMsg

    names = list(JOINT_SETS[arm])
    k = np.arange(n)[:, None] / rate_hz
    phase = np.arange(7)[None, :]
    q = 0.6 * np.sin(0.5 * k + phase)
    dq = 0.3 * np.cos(0.5 * k + phase)
    tau = 5.0 * np.sin(0.5 * k + phase) + np.array([0, -20, 0, 10, 0, 2, 0])
    return [JointStateMsg(header=Header(stamp=_stamp(t0 + i / rate_hz), frame_id=""),
                          name=names, position=q[i].tolist(), velocity=dq[i].tolist(),
                          effort=tau[i].tolist()) for i in range(n)]


def publish_joint_states(topic: str, n: int, *, rate_hz: float = NOMINAL_RATE_HZ,
                         domain_id: int = 0, config: str | None = None, reliable: bool = True,
                         arm: str = "fr3",
                         match_timeout: float = 20.0, out=None, pace: bool = True) -> int:
    """Publish ``n`` messages on ``topic`` at ``rate_hz`` once a reader matched (sleep most
    of each period, spin the rest; ``pace=False``: as fast as the writer takes them, the
    stamps still ``1/rate_hz`` apart); the number published."""
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from . import ros2_dds
    from .ros2_types import JointStateMsg, topic_name

    dp = ros2_dds.participant(domain_id, config)
    writer = DataWriter(dp, Topic(dp, topic_name(topic), JointStateMsg),
                        qos=ros2_dds.qos(reliable=reliable, depth=1000))
    deadline = time.monotonic() + match_timeout
    while not writer.get_matched_subscriptions():
        if time.monotonic() > deadline:
            raise TimeoutError(f"no reader of {topic} matched within {match_timeout} s")
        time.sleep(0.01)
    if out is not None:
        print("matched", file=out, flush=True)
    time.sleep(0.2)  # let the reader's side finish matching too
    messages = joint_state_messages(n, time.time(), rate_hz, arm)
    perf = time.perf_counter
    period = 1.0 / rate_hz if pace else 0.0
    start = perf() + 0.01
    for i, msg in enumerate(messages):
        due = start + i * period
        while (left := due - perf()) > 0:
            time.sleep(left * 0.5 if left > 4e-4 else 0)
        writer.write(msg)
    time.sleep(0.3)  # a reliable writer: let the last ones go out before the writer goes
    if out is not None:
        print(f"done {n}", file=out, flush=True)
    return n


class SetLoadServer:
    """A SetLoad service on ``service`` (see the module docstring); ``requests`` holds
    ``(mass, center_of_mass, load_inertia)`` of every request taken."""

    def __init__(self, participant, service: str = "/service_server/set_load", *,
                 layout: str = "cyclonedds", answer=None, service_number: int = 7) -> None:
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

        if layout not in ("cyclonedds", "fastrtps"):
            raise ValueError(f"layout {layout!r}; valid: 'cyclonedds', 'fastrtps'")
        self.layout = layout
        self.answer = answer or (lambda request: (True, ""))
        self.requests: list[tuple[float, list[float], list[float]]] = []
        cyclone = layout == "cyclonedds"
        req_t, rep_t = SetLoadRequest, SetLoadResponse
        self._reply_type = rep_t
        user_data = (f"serviceid={csid_string(csid_of(participant.guid.bytes, service_number))};"
                     .encode() if cyclone else b"")
        self._reader = DataReader(participant, Topic(participant, request_topic(service), req_t),
                                  qos=ros2_dds.qos(reliable=True, depth=10, user_data=user_data))
        self._writer = DataWriter(participant, Topic(participant, reply_topic(service), rep_t),
                                  qos=ros2_dds.qos(reliable=True, depth=10, user_data=user_data))
        self._waitset = WaitSet(participant)
        self._waitset.attach(ReadCondition(self._reader, SampleState.Any | ViewState.Any
                                           | InstanceState.Any))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="set-load-server", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            self._waitset.wait(50_000_000)
            for req in self._reader.take(N=16):
                if not hasattr(req, "mass"):
                    continue
                request = (float(req.mass), list(req.center_of_mass), list(req.load_inertia))
                self.requests.append(request)
                success, error = self.answer(request)
                if self.layout == "cyclonedds":
                    reply = self._reply_type(guid=req.guid, seq=req.seq, success=success,
                                             error=error)
                else:
                    reply = self._reply_type(success=success, error=error)  # no header
                self._writer.write(reply)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


def measure_loopback(rate_cycles: int = 20000, latency_cycles: int = 10000,
                     domain_id: int = 97) -> dict:
    """``iem bench bridge``'s ros2 row: a reliable JointState writer in another process, the
    ``ros2`` link reading in this one, over loopback (``lo``, unicast 127.0.0.1).

    - ``cycles_per_s``: ``rate_cycles`` messages written as fast as the writer takes them,
      delivered by ``read`` per second (first to last);
    - ``latency_us``: ``latency_cycles`` messages at 1 kHz, from the writer's source time
      stamp to ``read`` returning the state, p50 and p99; ``lost`` and ``delivered`` of
      that run; ``cpu_share``: this process's CPU time (the link and Cyclone's threads)
      over the run's wall time.
    """
    import os
    import subprocess

    from .errors import ControllerSilent
    from .ros2_link import open_ros2_link

    def run(n: int, paced: bool, topic: str) -> dict:
        link = open_ros2_link("ros2", topic, domain_id=domain_id, set_load_service="",
                              estimate_topic=topic + "_estimate", interface="lo",
                              peers=["127.0.0.1"], silence_timeout=2.0)
        cmd = [sys.executable, "-m", "firmware_bridge.ros2_peers", "publish", "--topic", topic,
               "--count", str(n), "--domain", str(domain_id), "--interface", "lo", "--peer",
               "127.0.0.1", *([] if paced else ["--unpaced"])]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            proc.stdout.readline()  # matched
            lat, first, last = [], None, None
            cpu0, wall0 = time.process_time(), time.perf_counter()
            while True:
                try:
                    link.read(2.0)
                except ControllerSilent:
                    break
                now = time.perf_counter()
                first = first if first is not None else now
                last = now
                lat.append(time.time() - link.last_frame_time)
            wall = time.perf_counter() - wall0 - 2.0
            cpu = time.process_time() - cpu0
        finally:
            proc.terminate()
            proc.wait(10)
            c = link.counters
            link.close()
        a = np.asarray(lat) * 1e6
        return {"delivered": c.delivered, "lost": c.lost, "sent": n,
                "span_s": (last - first) if lat else 0.0,
                "latency_us": {"p50": float(np.percentile(a, 50)) if lat else float("nan"),
                               "p99": float(np.percentile(a, 99)) if lat else float("nan")},
                "cpu_share": cpu / wall if wall > 0 else float("nan")}

    burst = run(rate_cycles, False, "/bench/burst")
    paced = run(latency_cycles, True, "/bench/joint_states")
    return {"cycles_per_s": burst["delivered"] / burst["span_s"] if burst["span_s"] else 0.0,
            "burst_lost": burst["sent"] - burst["delivered"],
            "latency_us": paced["latency_us"], "delivered": paced["delivered"],
            "lost": paced["sent"] - paced["delivered"], "cpu_share": paced["cpu_share"]}


REFUSAL = "command not possible in the current mode"
"""libfranka's CommandException text for setLoad while a motion runs (franka_ros #25)."""


class Ros2ControllerPort:
    """A controller port (``tick``, ``poll_commands``, ``publish``, ``heartbeat``,
    ``send_ack``, ``close``) over ROS 2, as franka_ros2 shows the robot: JointStates
    (effort = tau_J) stamped ``t0 + state.t`` on ``topic``, and a SetLoad service on
    ``service`` whose requests become the controller's load commands; a request is answered
    once the controller acknowledged it (``success=false`` with an error text if it refused
    the load), or after ``ack_timeout`` s without one. The first ``refuse_first`` requests
    are refused as a Franka refuses while a controller runs, with libfranka's text."""

    def __init__(self, participant, topic: str = "/franka/joint_states",
                 service: str = "/service_server/set_load", *, layout: str = "cyclonedds",
                 arm: str | tuple[str, ...] = "fr3", ack_timeout: float = 1.0,
                 refuse_first: int = 0) -> None:
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        from . import ros2_dds
        from .ros2_types import JointStateMsg, topic_name

        self._writer = DataWriter(participant,
                                  Topic(participant, topic_name(topic), JointStateMsg),
                                  qos=ros2_dds.qos(reliable=True, depth=1000))
        self._names = list(JOINT_SETS[arm] if isinstance(arm, str) else arm)  # or 7 names
        self._commands: queue.Queue = queue.Queue()
        self._waiting: dict[int, tuple[threading.Event, list]] = {}
        self._seq = 0
        self.ack_timeout = float(ack_timeout)
        self.refuse_first = int(refuse_first)
        self.t0 = time.time()
        self.sent = 0
        self.server = SetLoadServer(participant, service, layout=layout, answer=self._answer)

    def _answer(self, request) -> tuple[bool, str]:
        from iem.payload import Payload

        from .messages import LoadCommand

        if self.refuse_first > 0:
            self.refuse_first -= 1
            return False, REFUSAL
        mass, com, inertia = request
        load = None if mass == 0.0 else Payload.from_set_load(mass, com, inertia)
        self._seq = self._seq % 255 + 1
        done, box = threading.Event(), []
        self._waiting[self._seq] = (done, box)
        self._commands.put(LoadCommand(seq=self._seq, load=load))
        if not done.wait(self.ack_timeout):
            return False, "the controller did not answer"
        return (True, "") if box[0] else (False, "load refused: not a physically possible body")

    def tick(self, k: int, t: float) -> None:
        pass

    def poll_commands(self) -> list:
        out = []
        while True:
            try:
                out.append(self._commands.get_nowait())
            except queue.Empty:
                return out

    def publish(self, state) -> None:
        from .ros2_types import Header, JointStateMsg

        self._writer.write(JointStateMsg(
            header=Header(stamp=_stamp(self.t0 + state.t), frame_id=""), name=self._names,
            position=state.q.tolist(), velocity=state.dq.tolist(),
            effort=state.tau_J.tolist()))
        self.sent += 1

    def heartbeat(self, heartbeat) -> None:
        pass  # franka_ros2 has none: the link's silence timeout stands in

    def send_ack(self, ack) -> None:
        waiting = self._waiting.pop(ack.seq, None)
        if waiting is not None:
            waiting[1].append(ack.applied)
            waiting[0].set()

    def close(self) -> None:
        self.server.close()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m firmware_bridge.ros2_peers")
    sub = parser.add_subparsers(dest="command", required=True)
    pub = sub.add_parser("publish", help="publish JointStates at a fixed rate")
    pub.add_argument("--topic", default="/franka/joint_states")
    pub.add_argument("--count", type=int, default=1000)
    pub.add_argument("--rate", type=float, default=NOMINAL_RATE_HZ)
    pub.add_argument("--domain", type=int, default=0)
    pub.add_argument("--interface", default="")
    pub.add_argument("--peer", action="append", default=[])
    pub.add_argument("--best-effort", action="store_true")
    pub.add_argument("--unpaced", action="store_true", help="as fast as the writer takes them")
    pub.add_argument("--arm", choices=sorted(JOINT_SETS), default="fr3")
    args = parser.parse_args(argv)
    from .ros2_dds import cyclone_config

    publish_joint_states(args.topic, args.count, rate_hz=args.rate, domain_id=args.domain,
                         config=cyclone_config(args.interface, tuple(args.peer)),
                         reliable=not args.best_effort, arm=args.arm, out=sys.stdout,
                         pace=not args.unpaced)
    return 0


if __name__ == "__main__":
    sys.exit(main())
