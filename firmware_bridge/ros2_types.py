"""The ROS 2 wire as rmw_cyclonedds_cpp puts it on DDS, for the ``ros2`` link (extra ``ros2``).

Everything here follows ros2/rmw_cyclonedds (``rmw_cyclonedds_cpp/src``, release 3.2.0; the
same on its ``humble`` and ``jazzy`` branches):

- topic names (``namespace_prefix.hpp``, ``make_fqtopic`` in ``rmw_node.cpp``): a topic
  ``/a/b`` is the DDS topic ``rt/a/b``; a service ``/s`` is the request topic
  ``rq/sRequest`` and the reply topic ``rr/sReply``;
- type names (``MessageTypeSupport_impl.hpp``, ``ServiceTypeSupport_impl.hpp``):
  ``<pkg>::msg::dds_::<Name>_``, ``<pkg>::srv::dds_::<Name>_Request_`` and ``_Response_``;
- every request and reply starts with ``cdds_request_header_t {uint64 guid; int64 seq}``
  (``serdata.hpp``) ahead of the ROS fields; a client sets ``guid`` to its request writer's
  instance handle and ``seq`` to a counter, the service echoes both (``rmw_send_request``,
  ``rmw_send_response``, ``rmw_take_response_request``);
- a client's and a service's readers and writers carry USER_DATA ``clientid=<id>;`` or
  ``serviceid=<id>;`` (``rmw_init_cs``), ``<id>`` as ``csid_to_string`` writes it, and
  ``key=value;`` pairs are parsed as ``rmw::impl::cpp::parse_key_value`` does.

Messages are XCDR1 little-endian (encapsulation ``00 01 00 00``), the encoding ROS 2 uses;
their bytes are checked against ``rosbags`` in the tests.
"""


from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, int64, sequence, uint8, uint32, uint64

# -- messages ------------------------------------------------------------------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    """``builtin_interfaces/msg/Time``: s and ns since the epoch (ROS time)."""

    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    """``std_msgs/msg/Header``."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class JointStateMsg(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    """``sensor_msgs/msg/JointState``: rad, rad/s, N·m (franka_ros2: effort = tau_J)."""

    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    """``geometry_msgs/msg/Vector3``."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Inertia(IdlStruct, typename="geometry_msgs::msg::dds_::Inertia_"):
    """``geometry_msgs/msg/Inertia``: mass kg, CoM m, inertia about the CoM kg·m²."""

    m: float64 = 0.0
    com: Vector3 = field(default_factory=Vector3)
    ixx: float64 = 0.0
    ixy: float64 = 0.0
    ixz: float64 = 0.0
    iyy: float64 = 0.0
    iyz: float64 = 0.0
    izz: float64 = 0.0


@dataclass
class InertiaStamped(IdlStruct, typename="geometry_msgs::msg::dds_::InertiaStamped_"):
    """``geometry_msgs/msg/InertiaStamped``."""

    header: Header = field(default_factory=Header)
    inertia: Inertia = field(default_factory=Inertia)


# -- franka_msgs/srv/SetLoad ----------------------------------------------------------------


@dataclass
class SetLoadRequest(IdlStruct, typename="franka_msgs::srv::dds_::SetLoad_Request_"):
    """A SetLoad request as rmw_cyclonedds_cpp sends it: the request header, then
    ``float64 mass, float64[3] center_of_mass, float64[9] load_inertia`` (column-major,
    about the CoM; kg, m, kg·m²)."""

    guid: uint64 = 0
    seq: int64 = 0
    mass: float64 = 0.0
    center_of_mass: array[float64, 3] = field(default_factory=lambda: [0.0] * 3)
    load_inertia: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)


@dataclass
class SetLoadResponse(IdlStruct, typename="franka_msgs::srv::dds_::SetLoad_Response_"):
    """A SetLoad reply as rmw_cyclonedds_cpp sends it: the echoed request header, then
    ``bool success, string error``."""

    guid: uint64 = 0
    seq: int64 = 0
    success: bool = False
    error: str = ""


# -- names and USER_DATA ---------------------------------------------------------------------


def _ros_name(name: str, what: str) -> str:
    from .errors import BridgeConfigError

    if not name.startswith("/") or name.endswith("/") or "//" in name or \
            not all(c.isalnum() or c in "/_~" for c in name) or name[1:2].isdigit():
        raise BridgeConfigError(f"{what} {name!r} is not a fully qualified ROS 2 name; valid: "
                                "'/' then segments of letters, digits and '_' separated by "
                                "'/', e.g. '/franka/joint_states'")
    return name


def topic_name(topic: str) -> str:
    """The DDS topic of the ROS 2 topic ``topic`` (``/franka/joint_states`` ->
    ``rt/franka/joint_states``)."""
    return "rt" + _ros_name(topic, "topic")


def request_topic(service: str) -> str:
    """The DDS request topic of the ROS 2 service ``service`` (``rq/<service>Request``)."""
    return "rq" + _ros_name(service, "service") + "Request"


def reply_topic(service: str) -> str:
    """The DDS reply topic of the ROS 2 service ``service`` (``rr/<service>Reply``)."""
    return "rr" + _ros_name(service, "service") + "Reply"


def csid_string(data: bytes) -> str:
    """A client/service id as ``csid_to_string`` writes it: hex bytes joined by ``.``, the
    first one in a field of width 2 (``std::setw(2)`` with the stream's fill, a space)."""
    return f"{data[0]:>2x}" + "".join(f".{b:x}" for b in data[1:])


def csid_of(participant_guid: bytes, counter: int) -> bytes:
    """A client/service id as ``get_unique_csid`` makes one: the participant's 12-byte GUID
    prefix, then ``counter`` big-endian in 4 bytes."""
    return bytes(participant_guid[:12]) + int(counter).to_bytes(4, "big")


def parse_user_data(data: bytes) -> dict[str, bytes]:
    """USER_DATA ``key=value;key=value;`` as ``rmw::impl::cpp::parse_key_value`` reads it
    (a pair without ``=`` or with an empty key is skipped)."""
    out: dict[str, bytes] = {}
    for item in bytes(data).split(b";"):
        key, eq, value = item.partition(b"=")
        if eq and key:
            out[key.decode("utf-8", "replace")] = value
    return out


# -- diagnostic_msgs --------------------------------------------------------------------------


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    """``diagnostic_msgs/msg/KeyValue``."""

    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    """``diagnostic_msgs/msg/DiagnosticStatus``: ``level`` OK 0, WARN 1, ERROR 2, STALE 3
    (``byte``, an IDL octet)."""

    level: uint8 = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    """``diagnostic_msgs/msg/DiagnosticArray``, what ``/diagnostics`` carries."""

    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = field(default_factory=list)


# -- franka_msgs/msg/FrankaRobotState, up to the load in force --------------------------------


@dataclass
class CollisionIndicators(IdlStruct,
                          typename="franka_msgs::msg::dds_::CollisionIndicators_"):
    """``franka_msgs/msg/CollisionIndicators``."""

    is_cartesian_linear_collision: Vector3 = field(default_factory=Vector3)
    is_cartesian_angular_collision: Vector3 = field(default_factory=Vector3)
    is_cartesian_linear_contact: Vector3 = field(default_factory=Vector3)
    is_cartesian_angular_contact: Vector3 = field(default_factory=Vector3)
    is_joint_collision: array[float64, 7] = field(default_factory=lambda: [0.0] * 7)
    is_joint_contact: array[float64, 7] = field(default_factory=lambda: [0.0] * 7)


@dataclass
class Elbow(IdlStruct, typename="franka_msgs::msg::dds_::Elbow_"):
    """``franka_msgs/msg/Elbow``."""

    position: array[float64, 2] = field(default_factory=lambda: [0.0] * 2)
    desired_position: array[float64, 2] = field(default_factory=lambda: [0.0] * 2)
    commanded_position: array[float64, 2] = field(default_factory=lambda: [0.0] * 2)
    commanded_velocity: array[float64, 2] = field(default_factory=lambda: [0.0] * 2)
    commanded_acceleration: array[float64, 2] = field(default_factory=lambda: [0.0] * 2)


@dataclass
class Wrench(IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    """``geometry_msgs/msg/Wrench``."""

    force: Vector3 = field(default_factory=Vector3)
    torque: Vector3 = field(default_factory=Vector3)


@dataclass
class WrenchStamped(IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    """``geometry_msgs/msg/WrenchStamped``."""

    header: Header = field(default_factory=Header)
    wrench: Wrench = field(default_factory=Wrench)


@dataclass
class FrankaRobotState(IdlStruct, typename="franka_msgs::msg::dds_::FrankaRobotState_"):
    """``franka_msgs/msg/FrankaRobotState`` (franka_ros2's robot state broadcaster) up to
    ``inertia_load``, the load in force (libfranka's ``m_load``, ``F_x_Cload``, ``I_load``).
    The fields after it (``inertia_total``, the poses, twists, ``time``, ``robot_mode``, the
    errors) are left unread: XCDR1 is read in order, so a message read up to a field is
    read right whatever follows it, and the errors' fields differ between releases."""

    header: Header = field(default_factory=Header)
    collision_indicators: CollisionIndicators = field(default_factory=CollisionIndicators)
    measured_joint_state: JointStateMsg = field(default_factory=JointStateMsg)
    desired_joint_state: JointStateMsg = field(default_factory=JointStateMsg)
    measured_joint_motor_state: JointStateMsg = field(default_factory=JointStateMsg)
    ddq_d: array[float64, 7] = field(default_factory=lambda: [0.0] * 7)
    dtau_j: array[float64, 7] = field(default_factory=lambda: [0.0] * 7)
    tau_ext_hat_filtered: JointStateMsg = field(default_factory=JointStateMsg)
    elbow: Elbow = field(default_factory=Elbow)
    k_f_ext_hat_k: WrenchStamped = field(default_factory=WrenchStamped)
    o_f_ext_hat_k: WrenchStamped = field(default_factory=WrenchStamped)
    inertia_ee: InertiaStamped = field(default_factory=InertiaStamped)
    inertia_load: InertiaStamped = field(default_factory=InertiaStamped)
