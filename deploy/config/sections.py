"""The sections of ``cell.toml`` as settings: a frozen dataclass per section
(:class:`CellConfig` holds them all), :class:`ConfigError`, and the tables of valid values
(choices, numeric ranges, keys that may be empty, ROS 2 names) that
:mod:`deploy.config.load` checks every key against.

Every key is documented in ``deploy/cell.toml`` (the example a cell starts from).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from deploy.writeback.settings import RANGES as GATE_RANGES
from deploy.writeback.settings import GateConfig
from firmware_bridge.links import LINKS
from firmware_bridge.protocol import PROFILES
from iem.errors import InvalidInputError
from iem.model_kinds import DEFAULT_MODEL
from iem.signals.filters import DEFAULT_CUTOFF_HZ
from iem.signals.smoothing import DEFAULT_TAU_S

DERIVED_GATE_KEYS = ("end_effector_mass_kg",)
"""``GateConfig`` fields that are not ``[gate]`` keys: the end effector's mass comes from
``[arm] end_effector``."""
BANDS = ("this gate writes when a write makes the controller's model better by its "
         "joint-torque error (write_margin, min_torque_error_nm; docs/configuration.md)")
RETIRED_GATE_KEYS = {
    "max_mass_2sigma_kg": BANDS, "max_com_2sigma_m": BANDS, "min_change_mass_kg": BANDS,
    "min_change_com_m": BANDS,
    "empty_mass_kg": ("the empty load is judged as every write is: written when the mass's "
                      "2-sigma band reaches zero and writing it makes the controller's model "
                      "better by its joint-torque error (docs/configuration.md)"),
}
"""``[gate]`` keys this gate does not have, and why: a file that sets them is refused with
that said."""


class ConfigError(InvalidInputError):
    """``cell.toml`` is missing, not TOML, or has a key with an invalid value."""


LINK_KINDS = tuple(LINKS)  # the one table of link kinds (firmware_bridge.links)
MODEL_KINDS = ("IEM", "IEM+phys")
"""The model kinds a cell runs and ``iem train`` makes: those of :data:`iem.model_kinds.
MODELS` that learn online; the default is :data:`iem.model_kinds.DEFAULT_MODEL`."""
LOG_FORMATS = ("json", "text")
LOG_LEVELS = ("debug", "info", "warning", "error")
STATUS_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class LinkConfig:
    """Where the joint states come from and the loads go (``[link]``)."""

    kind: str = "virtual"
    channel: str = "iem"
    profile: str = "fd"
    silence_timeout_s: float = 0.1


@dataclass(frozen=True)
class ModelConfig:
    """The model file and how a new model is made (``[model]``)."""

    path: str = "model.msgpack"
    kind: str = DEFAULT_MODEL
    checkpoint_period_s: float = 60.0
    train_if_missing: bool = True
    family: str = "cell"
    excitation: str = "builtin"
    seed: int = 0
    arm: str = ""
    """The arm file from ``iem calibrate`` (empty: the nominal arm); the model must have
    been trained for it (``iem train --arm``)."""


@dataclass(frozen=True)
class ArmConfig:
    """The arm the plug-in runs on (``[arm]``).

    ``model``: the arm's description (:mod:`sim.description`): "panda", "fr3" or the path of
    a URDF; "": "fr3" on the ``franka`` link (libfranka serves the FR3 only) and on
    a ``ros2`` link reading ``[ros2] joints = "fr3"``, else "panda". ``flange``: the flange
    link of a description file that does not tell it ("": the file's own).
    ``end_effector``: what the flange carries as part of the arm (:mod:`sim.end_effector`):
    "franka_hand", "none" or the path of a payload-style TOML of the tool ("": the arm
    model's default, the hand on the Panda and the FR3); the arm file and the model must be
    made for it. ``noise``: IEM+phys's equation error when it trains a
    model (:data:`deploy.model.training.NOISE_CHOICES`): "arm", the arm file's measured noise
    (a conservative default without an arm file), "sensor" (a simulated, exact arm), or
    "auto": "arm" with ``[model] arm``, else "sensor" (:func:`deploy.model.training.
    noise_for`)."""

    model: str = ""
    flange: str = ""
    end_effector: str = ""
    noise: str = "auto"

    def description(self):
        """The arm model (:func:`sim.description.arm_description`)."""
        from sim.description import arm_description

        return arm_description(self.model or None, self.flange or None)


@dataclass(frozen=True)
class EstimateConfig:
    """The online estimate (``[estimate]``)."""

    block_frames: int = 0
    """Frames per block point: the estimator works on the means of this many consecutive
    gap-free frames (:mod:`iem.signals.blocks`); 0: the link's rate over 100
    (:func:`deploy.model.setup.block_frames_of`)."""
    smoothing_tau_s: float = DEFAULT_TAU_S
    filter_cutoff_hz: float = DEFAULT_CUTOFF_HZ
    learn: bool = True
    max_lag_s: float = 0.1
    background_learning: bool = True
    """Train new bags in a worker thread, off the estimate path (a live link only)."""
    initial_payload: str = ""
    """A payload TOML file (``iem identify``'s) to start from: the first estimate and the
    prior of IEM+phys at every start; "" for none."""


@dataclass(frozen=True)
class LogConfig:
    """Logging and the terminal status line (``[log]``)."""

    level: str = "info"
    format: str = "json"
    status_line: str = "auto"
    status_period_s: float = 0.25
    status_plain_period_s: float = 10.0


@dataclass(frozen=True)
class Ros2Config:
    """The ``ros2`` link's ROS 2 side (``[ros2]``; see deploy/cell.toml for every key).

    ``domain_id`` -1: ``ROS_DOMAIN_ID`` from the environment, else 0;
    ``estimate_std_topic`` "": ``estimate_topic`` + ``_std``; ``joints``: "auto", "fr3",
    "panda" or 7 names ("auto": the arm model's, :meth:`CellConfig.link_options`);
    ``flange_frame`` "": the arm model's flange;
    ``robot_state_topic``: franka_ros2's robot state, whose ``inertia_load`` is the load in
    force; ``diagnostics_topic``: where the gate's verdict goes;
    ``interface`` "" and ``peers`` (): Cyclone's configuration from ``CYCLONEDDS_URI``."""

    domain_id: int = -1
    estimate_topic: str = "/iem/payload"
    estimate_std_topic: str = ""
    estimate_rate_hz: float = 10.0
    set_load_service: str = "/service_server/set_load"
    set_load_timeout_s: float = 2.0
    joints: str | tuple = "auto"
    flange_frame: str = ""
    robot_state_topic: str = "/franka_robot_state_broadcaster/robot_state"
    diagnostics_topic: str = "/diagnostics"
    interface: str = ""
    peers: tuple = ()

    def link_options(self) -> dict:
        """The ``ros2`` opener's options (:func:`firmware_bridge.ros2_link.open_ros2_link`)."""
        return {"domain_id": None if self.domain_id < 0 else self.domain_id,
                "joints": list(self.joints) if isinstance(self.joints, tuple) else self.joints,
                "estimate_topic": self.estimate_topic,
                "estimate_std_topic": self.estimate_std_topic,
                "estimate_rate_hz": self.estimate_rate_hz,
                "set_load_service": self.set_load_service,
                "set_load_timeout_s": self.set_load_timeout_s,
                "flange_frame": self.flange_frame,
                "robot_state_topic": self.robot_state_topic,
                "diagnostics_topic": self.diagnostics_topic, "interface": self.interface,
                "peers": list(self.peers)}


@dataclass(frozen=True)
class HostConfig:
    """What the plug-in asks of the cell PC while it runs (``[host]``).

    ``cpu_dma_latency_us``: a CPU wake-up latency limit held while the service runs
    (:mod:`deploy.service.host`); -1: none."""

    cpu_dma_latency_us: int = -1


@dataclass(frozen=True)
class CellConfig:
    """Everything ``iem run`` needs."""

    link: LinkConfig = field(default_factory=LinkConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    arm: ArmConfig = field(default_factory=ArmConfig)
    estimate: EstimateConfig = field(default_factory=EstimateConfig)
    gate: GateConfig = field(default_factory=GateConfig)
    log: LogConfig = field(default_factory=LogConfig)
    ros2: Ros2Config = field(default_factory=Ros2Config)
    host: HostConfig = field(default_factory=HostConfig)
    source: str = "<defaults>"

    def link_options(self) -> dict:
        """Options of the configured link kind's opener beyond channel, profile and silence
        timeout: ``[ros2]`` for the ``ros2`` kind (``joints`` "auto": the arm model's joint
        names; ``flange_frame`` "": its flange), none for the others."""
        if self.link.kind != "ros2":
            return {}
        out = self.ros2.link_options()
        desc = self.arm.description()
        if out["joints"] == "auto":
            out["joints"] = list(desc.joint_names)
        if not out["flange_frame"]:
            out["flange_frame"] = desc.flange
        return out


SECTIONS = {"link": LinkConfig, "model": ModelConfig, "arm": ArmConfig,
            "estimate": EstimateConfig,
            "gate": GateConfig, "log": LogConfig, "ros2": Ros2Config, "host": HostConfig}

# keys with a restricted set of values, and numeric ranges (lo, hi, lo inclusive)
CHOICES = {("link", "kind"): LINK_KINDS, ("link", "profile"): PROFILES,
           ("model", "kind"): MODEL_KINDS, ("log", "format"): LOG_FORMATS,
           ("log", "level"): LOG_LEVELS, ("log", "status_line"): STATUS_MODES,
           ("arm", "noise"): ("auto", "arm", "sensor"),
           ("ros2", "joints"): ("auto", "fr3", "panda")}
RANGES = {
    ("link", "silence_timeout_s"): (0.005, 60.0),
    ("model", "checkpoint_period_s"): (1.0, 86400.0),
    ("estimate", "smoothing_tau_s"): (0.0, 60.0),
    ("estimate", "filter_cutoff_hz"): (1.0, 499.0),
    ("estimate", "max_lag_s"): (0.0, 60.0),
    ("log", "status_period_s"): (0.05, 60.0),
    ("log", "status_plain_period_s"): (0.0, 3600.0),
    ("ros2", "estimate_rate_hz"): (0.1, 1000.0),
    ("ros2", "set_load_timeout_s"): (0.05, 4.0),  # below the unit's WatchdogSec=5
}
RANGES.update({("gate", key): valid for key, valid in GATE_RANGES.items()
               if key not in DERIVED_GATE_KEYS and not isinstance(valid[0], int)})
INT_RANGES = {
    ("estimate", "block_frames"): (0, 100),  # frames per block point; 0: the link's rate / 100
    ("model", "seed"): (0, 2**63 - 1),  # numpy's seeds are non-negative; TOML ints are int64
    ("ros2", "domain_id"): (-1, 232),  # ROS 2's valid domain ids; -1: ROS_DOMAIN_ID
    ("host", "cpu_dma_latency_us"): (-1, 1_000_000),  # µs; -1: no limit (deploy.service.host)
    **{("gate", key): valid for key, valid in GATE_RANGES.items()
       if isinstance(valid[0], int)},  # counts (max_disagreements)
}
MAY_BE_EMPTY = {("ros2", "estimate_std_topic"), ("ros2", "flange_frame"),
                ("ros2", "interface"), ("estimate", "initial_payload"), ("model", "arm"),
                ("arm", "model"), ("arm", "flange"), ("arm", "end_effector")}
"""String keys for which "" means "none" (the default the key's comment names)."""
ROS_NAMES = {("ros2", "estimate_topic"), ("ros2", "estimate_std_topic"),
             ("ros2", "set_load_service"), ("ros2", "robot_state_topic"),
             ("ros2", "diagnostics_topic")}
ROS_NAME = re.compile(r"/[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")
"""A fully qualified ROS 2 topic or service name."""
