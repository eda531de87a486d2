"""The ros2 link against independent truth: rosbags' CDR, a JointState writer and SetLoad
repliers over loopback DDS (Cyclone restricted to ``lo``, unicast peer 127.0.0.1, no
multicast: nothing leaves this machine)."""

from __future__ import annotations

import json
import logging
import struct
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ros2 link needs the 'ros2' extra (cyclonedds)")
pytest.importorskip("rosbags", reason="the ros2 tests compare with rosbags (the 'dev' extra)")

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from firmware_bridge.errors import BridgeConfigError, ControllerSilent
from firmware_bridge.ros2_dds import cyclone_config, participant, qos
from firmware_bridge.ros2_inertia import inertia_message, inertia_std, inertia_values
from firmware_bridge.ros2_link import open_ros2_link
from firmware_bridge.ros2_peers import SetLoadServer, joint_state_messages
from firmware_bridge.ros2_types import (
    JointStateMsg,
    SetLoadRequest,
    SetLoadResponse,
    csid_of,
    csid_string,
    parse_user_data,
    reply_topic,
    request_topic,
    topic_name,
)
from sim.payload import Payload

pytestmark = pytest.mark.hil

LOOPBACK = {"interface": "lo", "peers": ["127.0.0.1"]}
SETLOAD_SRV = {
    "franka_msgs/srv/msg/SetLoad_Request":
        "float64 mass\nfloat64[3] center_of_mass\nfloat64[9] load_inertia\n",
    "franka_msgs/srv/msg/SetLoad_Response": "bool success\nstring error\n",
}
TOOL = Payload("tool", 0.73, (0.01, -0.02, 0.06), (2e-3, 1e-4, -2e-4, 3e-3, 3e-4, 1.5e-3))


@pytest.fixture(scope="module")
def store():
    """rosbags' ROS 2 types, with franka_msgs' SetLoad request and response registered from
    their .srv text (rosbags names them ``franka_msgs/srv/msg/...``)."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in SETLOAD_SRV.items():
        ts.register(get_types_from_msg(text, name))
    return ts


def test_names_follow_rmw_cyclonedds():
    assert topic_name("/franka/joint_states") == "rt/franka/joint_states"
    assert request_topic("/service_server/set_load") == "rq/service_server/set_loadRequest"
    assert reply_topic("/service_server/set_load") == "rr/service_server/set_loadReply"
    assert JointStateMsg.__idl_typename__ == "sensor_msgs::msg::dds_::JointState_"
    assert SetLoadRequest.__idl_typename__ == "franka_msgs::srv::dds_::SetLoad_Request_"
    assert SetLoadResponse.__idl_typename__ == "franka_msgs::srv::dds_::SetLoad_Response_"
    # csid_to_string: hex, '.'-joined, the first byte in a width-2 field
    cid = csid_of(bytes(range(1, 17)), 0x0102)
    assert cid[:12] == bytes(range(1, 13)) and cid[12:] == b"\x00\x00\x01\x02"
    assert csid_string(cid) == " 1.2.3.4.5.6.7.8.9.a.b.c.0.0.1.2"
    assert parse_user_data(b"serviceid= 1.2.3;typehash=RIHS01_ab;junk;=x;") == \
        {"serviceid": b" 1.2.3", "typehash": b"RIHS01_ab"}
    with pytest.raises(BridgeConfigError, match="fully qualified"):
        topic_name("franka/joint_states")


def test_cdr_bytes_equal_rosbags(store):
    ours = joint_state_messages(3, 1_700_000_000.25, arm="panda")[2]
    js = store.types["sensor_msgs/msg/JointState"]
    header = store.types["std_msgs/msg/Header"]
    stamp = store.types["builtin_interfaces/msg/Time"]
    theirs = js(header=header(stamp=stamp(sec=ours.header.stamp.sec,
                                          nanosec=ours.header.stamp.nanosec), frame_id=""),
                name=list(ours.name), position=np.array(ours.position),
                velocity=np.array(ours.velocity), effort=np.array(ours.effort))
    assert ours.serialize() == bytes(store.serialize_cdr(theirs, "sensor_msgs/msg/JointState"))

    values = inertia_values(TOOL.to_phi())
    msg = inertia_message(values, "fr3_link8", 12.5)
    got = store.deserialize_cdr(msg.serialize(), "geometry_msgs/msg/InertiaStamped")
    assert got.header.frame_id == "fr3_link8" and got.header.stamp.sec == 12
    assert got.header.stamp.nanosec == 500_000_000
    i = got.inertia
    np.testing.assert_allclose([i.m, i.com.x, i.com.y, i.com.z],
                               [TOOL.mass, *TOOL.com], rtol=1e-12)
    np.testing.assert_allclose([i.ixx, i.ixy, i.ixz, i.iyy, i.iyz, i.izz], TOOL.inertia,
                               atol=1e-15)
    assert msg.serialize() == bytes(store.serialize_cdr(got, "geometry_msgs/msg/InertiaStamped"))

    # SetLoad in rmw_cyclonedds's layout: encapsulation, {uint64 guid, int64 seq}, the fields
    mass, com, inertia = TOOL.set_load_args()
    req = SetLoadRequest(guid=0xDEADBEEF01234567, seq=42, mass=mass, center_of_mass=com,
                         load_inertia=inertia)
    body = bytes(store.serialize_cdr(
        store.types["franka_msgs/srv/msg/SetLoad_Request"](
            mass=mass, center_of_mass=np.array(com), load_inertia=np.array(inertia)),
        "franka_msgs/srv/msg/SetLoad_Request"))
    head = struct.pack("<Qq", 0xDEADBEEF01234567, 42)
    assert req.serialize() == body[:4] + head + body[4:]
    rep = SetLoadResponse(guid=7, seq=42, success=False, error="command not possible")
    body = bytes(store.serialize_cdr(
        store.types["franka_msgs/srv/msg/SetLoad_Response"](success=False,
                                                        error="command not possible"),
        "franka_msgs/srv/msg/SetLoad_Response"))
    assert rep.serialize() == body[:4] + struct.pack("<Qq", 7, 42) + body[4:]
    # ... which a server without the header (rmw_fastrtps_cpp) misreads: 16 bytes off
    misread = store.deserialize_cdr(req.serialize()[:4 + 8 + 24 + 72],
                                    "franka_msgs/srv/msg/SetLoad_Request")
    assert misread.mass != mass and misread.center_of_mass[1] == pytest.approx(mass)


def test_inertia_std_propagation_is_first_order():
    phi = TOOL.to_phi()
    std = np.full(10, 1e-4)
    rng = np.random.default_rng(0)
    samples = np.array([inertia_values(phi + rng.normal(0, std)) for _ in range(4000)])
    np.testing.assert_allclose(inertia_std(phi, std), samples.std(axis=0), rtol=0.1)


def _writer(domain: int, topic: str):
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    dp = participant(domain, cyclone_config(**LOOPBACK))
    w = DataWriter(dp, Topic(dp, topic_name(topic), JointStateMsg),
                   qos=qos(reliable=True, depth=100))
    return dp, w


def _until(pred, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.01)
    return False


def test_reads_by_name_and_counts_what_it_drops():
    link = open_ros2_link("ros2", "/t1/joint_states", domain_id=91, set_load_service="",
                          estimate_topic="/t1/payload", **LOOPBACK)
    try:
        _, w = _writer(91, "/t1/joint_states")
        assert _until(lambda: w.get_matched_subscriptions())
        msgs = joint_state_messages(6, 1000.0, arm="fr3")
        order = [3, 0, 6, 1, 5, 2, 4, 7]  # shuffled, with two gripper joints
        for m in msgs:
            m.name = [*m.name, "fr3_finger_joint1", "fr3_finger_joint2"]
            m.name = [m.name[k] for k in order]
            for key in ("position", "velocity", "effort"):
                vals = [*getattr(m, key), 0.04, 0.04]
                setattr(m, key, [vals[k] for k in order])
        bad = joint_state_messages(1, 999.0, arm="panda")[0]  # not the fr3 joints: malformed
        link._names = ("fr3_joint1", "fr3_joint2", "fr3_joint3", "fr3_joint4", "fr3_joint5",
                       "fr3_joint6", "fr3_joint7")
        for m in (msgs[0], msgs[1], msgs[1], msgs[0], bad, msgs[4], msgs[5]):
            w.write(m)
        got = [link.read(5.0) for _ in range(4)]
        ref = joint_state_messages(6, 1000.0, arm="fr3")
        for state, i in zip(got, (0, 1, 4, 5), strict=True):
            np.testing.assert_array_equal(state.q, ref[i].position)
            np.testing.assert_array_equal(state.dq, ref[i].velocity)
            np.testing.assert_array_equal(state.tau_J, ref[i].effort)
            assert state.t == pytest.approx(1000.0 + i * 1e-3, abs=1e-9)
        c = link.counters
        assert (c.received, c.delivered, c.stale, c.out_of_order, c.malformed, c.lost) == \
            (7, 4, 1, 1, 1, 2)
        assert link.last_frame_time == pytest.approx(time.time(), abs=5.0)
        with pytest.raises(ControllerSilent):
            link.read(0.05)
    finally:
        link.close()


def _link(domain, service, **kw):
    return open_ros2_link("ros2", f"/d{domain}/joint_states", domain_id=domain,
                          set_load_service=service, estimate_topic=f"/d{domain}/payload",
                          set_load_timeout_s=2.0, **LOOPBACK, **kw)


def test_set_load_to_an_rmw_cyclonedds_service_success_and_refusal(caplog):
    answers = iter([(True, ""), (False, "command not possible in the current mode"),
                    (False, "command not possible in the current mode"), (True, "")])
    dp = participant(92, cyclone_config(**LOOPBACK))
    server = SetLoadServer(dp, "/d92/set_load", answer=lambda r: next(answers))
    link = _link(92, "/d92/set_load")
    try:
        assert _until(lambda: not link.set_load.replier_problem())
        caplog.set_level(logging.WARNING, logger="iem.ros2")
        acks = []
        for p in (TOOL, TOOL.with_name("b"), TOOL.with_name("c"), None):
            acks.append(link.wait_ack(link.send(p), 5.0))
        assert [a.applied for a in acks] == [True, False, False, True]
        if hasattr(acks[1], "error"):
            assert acks[1].error == "command not possible in the current mode"
        assert acks[1].load == TOOL and acks[3].load is None  # what is in force
        mass, com, inertia = TOOL.set_load_args()
        assert server.requests[0] == (mass, com, inertia)
        assert server.requests[3] == (0.0, [0.0] * 3, [0.0] * 9)
        s = link.set_load
        assert (s.requests, s.successes, s.refusals, s.timeouts) == (4, 2, 2, 0)
        refused = [r for r in caplog.records if "refused" in r.getMessage()]
        assert len(refused) == 1 and "current mode" in refused[0].getMessage()
    finally:
        link.close()
        server.close()


def test_a_replier_without_serviceid_is_refused_and_estimates_go_on(caplog):
    dp = participant(93, cyclone_config(**LOOPBACK))
    server = SetLoadServer(dp, "/d93/set_load", layout="fastrtps")
    link = _link(93, "/d93/set_load")
    try:
        assert _until(lambda: "not rmw_cyclonedds" in link.set_load.replier_problem())
        caplog.set_level(logging.WARNING, logger="iem.ros2")
        acks = [link.wait_ack(link.send(TOOL), 5.0) for _ in range(3)]
        assert not any(a.applied for a in acks)
        if hasattr(acks[0], "error"):
            assert "RMW_IMPLEMENTATION=rmw_cyclonedds_cpp" in acks[0].error
        assert server.requests == [] and link.set_load.requests == 0
        assert link.set_load.not_written == 3
        logged = [r for r in caplog.records if "not written" in r.getMessage()]
        assert len(logged) == 1  # the reason once
        from iem.types import PayloadEstimate

        assert link.publish_estimate(PayloadEstimate(t=5.0, phi=TOOL.to_phi()))
    finally:
        link.close()
        server.close()


def test_no_service_at_all_is_a_refusal_with_the_reason():
    link = _link(94, "/d94/set_load")
    try:
        ack = link.wait_ack(link.send(TOOL), 5.0)
        assert not ack.applied and link.set_load.not_written == 1
    finally:
        link.close()


def test_domain_from_the_environment_and_joints_auto(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "96")
    link = open_ros2_link("ros2", "/t2/joint_states", set_load_service="",
                          estimate_topic="/t2/payload", **LOOPBACK)
    try:
        assert link.domain_id == 96 and link.rate_hz == 1000.0
        _, w = _writer(96, "/t2/joint_states")
        assert _until(lambda: w.get_matched_subscriptions())
        msg = joint_state_messages(1, 50.0, arm="panda")[0]
        w.write(msg)
        state = link.read(5.0)
        np.testing.assert_array_equal(state.q, msg.position)
        assert link._flange_frame == "panda_link8"
    finally:
        link.close()
    monkeypatch.setenv("ROS_DOMAIN_ID", "zero")
    with pytest.raises(BridgeConfigError, match="ROS_DOMAIN_ID='zero' is not an integer"):
        open_ros2_link("ros2", "/t2/joint_states", **LOOPBACK)
    with pytest.raises(BridgeConfigError, match="joints 'ur5'"):
        open_ros2_link("ros2", "/t2/joint_states", domain_id=96, joints="ur5", **LOOPBACK)


def test_estimate_and_its_std_published_at_the_configured_rate():
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from firmware_bridge.ros2_types import InertiaStamped
    from iem.types import PayloadEstimate

    link = _link(98, "", estimate_rate_hz=0.1, flange_frame="tool0")
    dp = participant(98, cyclone_config(**LOOPBACK))
    readers = [DataReader(dp, Topic(dp, topic_name(t), InertiaStamped),
                          qos=qos(reliable=True, depth=100))
               for t in ("/d98/payload", "/d98/payload_std")]
    try:
        assert _until(lambda: all(r.get_matched_publications() for r in readers))
        phi, std = TOOL.to_phi(), np.linspace(1e-4, 1e-3, 10)
        bad = PayloadEstimate(t=2.0, phi=np.r_[-0.1, phi[1:]])  # no CoM: not published
        assert not link.publish_estimate(bad) and link.unpublishable == 1
        calls = [link.publish_estimate(PayloadEstimate(t=3.0 + k * 1e-3, phi=phi, std=std))
                 for k in range(50)]
        assert calls[0] and not any(calls[1:])  # 0.1 Hz: the next one only after 10 s
        assert link.published == 1
        assert _until(lambda: all(r.read(N=10) for r in readers))
        (est,), (sd,) = (r.take(N=10) for r in readers)
        assert est.header.frame_id == sd.header.frame_id == "tool0"
        assert est.header.stamp.sec == 3 and est.header.stamp.nanosec == 0
        np.testing.assert_allclose(
            [sd.inertia.m, sd.inertia.com.x, sd.inertia.com.y, sd.inertia.com.z,
             sd.inertia.ixx, sd.inertia.ixy, sd.inertia.ixz, sd.inertia.iyy, sd.inertia.iyz,
             sd.inertia.izz], inertia_std(phi, std), rtol=1e-12)
        assert est.inertia.m == TOOL.mass
        with pytest.raises(BridgeConfigError, match="does not write loads"):
            link.send(TOOL)
        assert link.last_ack is None
    finally:
        link.close()


# -- /diagnostics -------------------------------------------------------------------------------
VERDICT = {"reason": "over_rated", "detail": "mass 3.400 kg + end effector 0.730 kg > rated 3 kg",
           "load_in_force": None, "sent": 3, "acked": 2, "lost": 1, "in_force": 2,
           "send_errors": 0, "refusals": 0}


def test_every_gate_reason_has_a_level():
    from deploy.writeback.gate import REASONS
    from firmware_bridge.ros2_diagnostics import ERROR, LEVELS, OK, WARN, level_of

    assert set(REASONS) <= set(LEVELS), set(REASONS) - set(LEVELS)
    assert level_of("send") == level_of("no_change") == OK
    assert level_of("unstable") == level_of("uncertain") == level_of("refused") == WARN
    for reason in ("not_finite", "over_rated", "controller_silent", "ack_missing", "lost"):
        assert level_of(reason) == ERROR
    assert level_of("") == WARN  # no decision yet


def test_diagnostic_array_reads_back_with_rosbags(store):
    from firmware_bridge.ros2_diagnostics import STATUS_NAME, diagnostic_array

    verdict = {**VERDICT, "load_in_force": {"mass": 0.73, "com": [0.0, 0.0, 0.06],
                                            "inertia": [1e-3, 0, 0, 0, 1e-3, 0, 0, 0, 1e-3]}}
    msg = diagnostic_array(verdict, "ROS 2 /franka/joint_states (domain 0)", t=7.25)
    got = store.deserialize_cdr(msg.serialize(), "diagnostic_msgs/msg/DiagnosticArray")
    assert got.header.stamp.sec == 7 and got.header.stamp.nanosec == 250_000_000
    (status,) = got.status
    assert status.level == 2 and status.name == STATUS_NAME
    assert status.hardware_id == "ROS 2 /franka/joint_states (domain 0)"
    assert status.message == "over_rated: " + VERDICT["detail"]
    values = {kv.key: kv.value for kv in status.values}
    assert list(values) == list(verdict)
    assert values["reason"] == "over_rated" and values["lost"] == "1"
    assert json.loads(values["load_in_force"]) == verdict["load_in_force"]
    assert msg.serialize() == bytes(store.serialize_cdr(got,
                                                        "diagnostic_msgs/msg/DiagnosticArray"))


def test_the_verdict_goes_out_on_diagnostics():
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from firmware_bridge.links import DiagnosticsSink
    from firmware_bridge.ros2_types import DiagnosticArray

    link = _link(88, "", diagnostics_topic="/d88/diagnostics")
    dp = participant(88, cyclone_config(**LOOPBACK))
    reader = DataReader(dp, Topic(dp, topic_name("/d88/diagnostics"), DiagnosticArray),
                        qos=qos(reliable=True, depth=10))
    try:
        assert isinstance(link, DiagnosticsSink)
        assert _until(lambda: reader.get_matched_publications())
        assert link.publish_diagnostics({**VERDICT, "reason": "send", "detail": "written"})
        assert link.publish_diagnostics({**VERDICT, "reason": "unstable", "detail": ""})
        got = []
        assert _until(lambda: got.extend(reader.take(N=10)) or len(got) >= 2)
        assert [(a.status[0].level, a.status[0].message) for a in got] == \
            [(0, "send: written"), (1, "unstable")]
        assert got[0].status[0].hardware_id == link.name
    finally:
        link.close()
    quiet = _link(87, "", diagnostics_topic="")
    try:
        assert not quiet.publish_diagnostics(VERDICT)
    finally:
        quiet.close()


# -- the load in force, as franka_ros2's robot state reports it ---------------------------------
FRANKA_MSGS = {
    "franka_msgs/msg/CollisionIndicators":
        "geometry_msgs/Vector3 is_cartesian_linear_collision\n"
        "geometry_msgs/Vector3 is_cartesian_angular_collision\n"
        "geometry_msgs/Vector3 is_cartesian_linear_contact\n"
        "geometry_msgs/Vector3 is_cartesian_angular_contact\n"
        "float64[7] is_joint_collision\nfloat64[7] is_joint_contact\n",
    "franka_msgs/msg/Elbow": "float64[2] position\nfloat64[2] desired_position\n"
                             "float64[2] commanded_position\nfloat64[2] commanded_velocity\n"
                             "float64[2] commanded_acceleration\n",
    # its fields differ between releases; it comes after the load and is not read
    "franka_msgs/msg/Errors": "bool joint_position_limits_violation\nbool joint_reflex\n"
                              "string note\n",
    "franka_msgs/msg/FrankaRobotState":
        "std_msgs/Header header\nCollisionIndicators collision_indicators\n"
        "sensor_msgs/JointState measured_joint_state\n"
        "sensor_msgs/JointState desired_joint_state\n"
        "sensor_msgs/JointState measured_joint_motor_state\n"
        "float64[7] ddq_d\nfloat64[7] dtau_j\nsensor_msgs/JointState tau_ext_hat_filtered\n"
        "Elbow elbow\ngeometry_msgs/WrenchStamped k_f_ext_hat_k\n"
        "geometry_msgs/WrenchStamped o_f_ext_hat_k\n"
        "geometry_msgs/InertiaStamped inertia_ee\ngeometry_msgs/InertiaStamped inertia_load\n"
        "geometry_msgs/InertiaStamped inertia_total\ngeometry_msgs/PoseStamped o_t_ee\n"
        "geometry_msgs/PoseStamped o_t_ee_d\ngeometry_msgs/PoseStamped o_t_ee_c\n"
        "geometry_msgs/PoseStamped f_t_ee\ngeometry_msgs/PoseStamped ee_t_k\n"
        "geometry_msgs/TwistStamped o_dp_ee_d\ngeometry_msgs/TwistStamped o_dp_ee_c\n"
        "geometry_msgs/AccelStamped o_ddp_ee_c\nfloat64 time\n"
        "float64 control_command_success_rate\nuint8 ROBOT_MODE_IDLE=1\nuint8 robot_mode\n"
        "Errors current_errors\nErrors last_motion_errors\n",
}


def _robot_state_bytes(store, load: Payload | None, load_frame: str = "fr3_link9") -> bytes:
    """A full FrankaRobotState (every field after the load set too) serialised by rosbags."""
    for name, text in FRANKA_MSGS.items():
        if name not in store.types:
            store.register(get_types_from_msg(text, name))
    msg = store.types["franka_msgs/msg/FrankaRobotState"]
    t = store.types
    vec = t["geometry_msgs/msg/Vector3"]
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=5, nanosec=0),
                                      frame_id="fr3_link0")

    def js(n):
        return t["sensor_msgs/msg/JointState"](header=header, name=[f"fr3_joint{i}" for i in
                                                                    range(1, n + 1)],
                                               position=np.arange(n, dtype=float),
                                               velocity=np.ones(n), effort=np.zeros(n))

    def inertia(p, frame="fr3_link9"):
        m, c, i = (0.0, [0.0] * 3, [0.0] * 6) if p is None else (p.mass, p.com, p.inertia)
        head = t["std_msgs/msg/Header"](stamp=header.stamp, frame_id=frame)
        return t["geometry_msgs/msg/InertiaStamped"](header=head, inertia=t[
            "geometry_msgs/msg/Inertia"](m=m, com=vec(x=c[0], y=c[1], z=c[2]), ixx=i[0],
                                         ixy=i[1], ixz=i[2], iyy=i[3], iyz=i[4], izz=i[5]))

    def stamped(kind, field_name, value):
        return t[f"geometry_msgs/msg/{kind}Stamped"](header=header, **{field_name: value})

    wrench = t["geometry_msgs/msg/Wrench"](force=vec(x=1.0, y=2.0, z=3.0), torque=vec(x=0.1,
                                                                                      y=0.2,
                                                                                      z=0.3))
    pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=0.3, y=0.0,
                                                                              z=0.5),
                                       orientation=t["geometry_msgs/msg/Quaternion"](
                                           x=0.0, y=0.0, z=0.0, w=1.0))
    twist = t["geometry_msgs/msg/Twist"](linear=vec(x=0.0, y=0.0, z=0.0),
                                         angular=vec(x=0.0, y=0.0, z=0.0))
    accel = t["geometry_msgs/msg/Accel"](linear=vec(x=0.0, y=0.0, z=0.0),
                                         angular=vec(x=0.0, y=0.0, z=0.0))
    errors = t["franka_msgs/msg/Errors"](joint_position_limits_violation=False,
                                         joint_reflex=True, note="x")
    full = msg(header=header, collision_indicators=t["franka_msgs/msg/CollisionIndicators"](
        is_cartesian_linear_collision=vec(x=0.0, y=0.0, z=0.0),
        is_cartesian_angular_collision=vec(x=0.0, y=0.0, z=0.0),
        is_cartesian_linear_contact=vec(x=0.0, y=0.0, z=1.0),
        is_cartesian_angular_contact=vec(x=0.0, y=0.0, z=0.0),
        is_joint_collision=np.zeros(7), is_joint_contact=np.ones(7)),
        measured_joint_state=js(7), desired_joint_state=js(7), measured_joint_motor_state=js(7),
        ddq_d=np.full(7, 0.5), dtau_j=np.full(7, -0.5), tau_ext_hat_filtered=js(7),
        elbow=t["franka_msgs/msg/Elbow"](position=np.ones(2), desired_position=np.ones(2),
                                         commanded_position=np.ones(2),
                                         commanded_velocity=np.zeros(2),
                                         commanded_acceleration=np.zeros(2)),
        k_f_ext_hat_k=stamped("Wrench", "wrench", wrench),
        o_f_ext_hat_k=stamped("Wrench", "wrench", wrench),
        inertia_ee=inertia(Payload("hand", 0.73, (0, 0, 0.017), (1e-3, 0, 0, 2.5e-3, 0, 1.7e-3)),
                           "fr3_link8"),
        inertia_load=inertia(load, load_frame), inertia_total=inertia(None, "fr3_link8"),
        o_t_ee=stamped("Pose", "pose", pose), o_t_ee_d=stamped("Pose", "pose", pose),
        o_t_ee_c=stamped("Pose", "pose", pose), f_t_ee=stamped("Pose", "pose", pose),
        ee_t_k=stamped("Pose", "pose", pose), o_dp_ee_d=stamped("Twist", "twist", twist),
        o_dp_ee_c=stamped("Twist", "twist", twist), o_ddp_ee_c=stamped("Accel", "accel", accel),
        time=12.0, control_command_success_rate=1.0, robot_mode=1, current_errors=errors,
        last_motion_errors=errors)
    return bytes(store.serialize_cdr(full, "franka_msgs/msg/FrankaRobotState"))


def test_robot_state_is_read_up_to_the_load_whatever_follows(store):
    from firmware_bridge.ros2_inertia import load_of
    from firmware_bridge.ros2_types import FrankaRobotState

    got = FrankaRobotState.deserialize(_robot_state_bytes(store, TOOL))
    load = load_of(got.inertia_load.inertia)
    assert (load.mass, load.com, load.inertia) == (TOOL.mass, TOOL.com, TOOL.inertia)
    assert got.inertia_ee.inertia.m == 0.73 and list(got.ddq_d) == [0.5] * 7
    empty = FrankaRobotState.deserialize(_robot_state_bytes(store, None))
    assert load_of(empty.inertia_load.inertia) is None


def test_load_report_from_the_robot_state_topic(store):
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from firmware_bridge.ros2_types import FrankaRobotState

    link = _link(86, "", robot_state_topic="/d86/robot_state")
    dp = participant(86, cyclone_config(**LOOPBACK))
    writer = DataWriter(dp, Topic(dp, topic_name("/d86/robot_state"), FrankaRobotState),
                        qos=qos(reliable=True, depth=10))
    try:
        assert link.load_report is None
        assert _until(lambda: writer.get_matched_subscriptions())
        before = time.perf_counter()
        writer.write(FrankaRobotState.deserialize(_robot_state_bytes(store, TOOL)))
        assert _until(lambda: link.load_report is not None)
        report = link.load_report
        assert report.has_values and report.seq is None and report.t > before
        assert (report.load.mass, report.load.com, report.load.inertia) == \
            (TOOL.mass, TOOL.com, TOOL.inertia)
        writer.write(FrankaRobotState.deserialize(_robot_state_bytes(store, None)))
        assert _until(lambda: link.load_report.load is None)
        # one that does not read as franka_ros2's (the load in another frame): not taken
        writer.write(FrankaRobotState.deserialize(_robot_state_bytes(store, TOOL, "fr3_link0")))
        assert _until(lambda: link.load_report and link._reports.unreadable == 1)
        assert link.load_report.load is None
    finally:
        link.close()


def test_iem_set_load_through_ros2(tmp_path, capsys):
    """``iem set-load`` on a ros2 cell: it waits for the SetLoad service, and a refusal
    exits 1 with the robot's text."""
    from deploy.cli import main
    from sim.payload import save_payload

    answers = iter([(True, ""), (False, "command not possible in the current mode")])
    dp = participant(85, cyclone_config(**LOOPBACK))
    server = SetLoadServer(dp, "/d85/set_load", answer=lambda r: next(answers))
    cell = tmp_path / "cell.toml"
    cell.write_text('[link]\nkind = "ros2"\nchannel = "/d85/joint_states"\n'
                    '[ros2]\ndomain_id = 85\nset_load_service = "/d85/set_load"\n'
                    'estimate_topic = "/d85/payload"\ninterface = "lo"\n'
                    'peers = ["127.0.0.1"]\n')
    save_payload(TOOL, tmp_path / "tool.toml")
    try:
        assert main(["set-load", str(tmp_path / "tool.toml"), "--config", str(cell),
                     "--json"]) == 0
        applied = json.loads(capsys.readouterr().out)
        assert main(["set-load", "--clear", "--config", str(cell)]) == 1
        refused = capsys.readouterr().out
    finally:
        server.close()
    assert applied["applied"] and applied["load_in_force"]["mass"] == TOOL.mass
    assert server.requests[0] == TOOL.set_load_args()
    assert server.requests[1] == (0.0, [0.0] * 3, [0.0] * 9)
    assert "NOT applied" in refused and "command not possible in the current mode" in refused
