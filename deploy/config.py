"""The plug-in's configuration, ``cell.toml``: read, checked, and turned into settings.

Every key is documented in ``deploy/cell.toml`` (the example a cell starts from). Any error
names the key, the value found and what would be valid; unknown keys are errors too, so a
typo never silently falls back to a default.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path as FsPath

from firmware_bridge.links import LINKS
from firmware_bridge.protocol import PROFILES
from iem.errors import InvalidInputError
from iem.model_kinds import DEFAULT_MODEL
from iem.signals.filters import DEFAULT_CUTOFF_HZ
from iem.signals.smoothing import DEFAULT_TAU_S

# the [arm] section's checks, which read the arm model (a sim module): deploy/arm_config.py
from .arm_config import arm_model_of, with_description, with_end_effector, with_rated_payload
from .gate_config import RANGES as GATE_RANGES
from .gate_config import GateConfig

DERIVED_GATE_KEYS = ("end_effector_mass_kg",)
"""``GateConfig`` fields that are not ``[gate]`` keys: the end effector's mass comes from
``[arm] end_effector``."""
RETIRED_GATE_KEYS = ("max_mass_2sigma_kg", "max_com_2sigma_m", "min_change_mass_kg",
                     "min_change_com_m")
"""``[gate]`` keys of a gate with fixed bands, which this gate does not have: it writes when a
write helps (``write_margin``, ``min_torque_error_nm``); a file that sets them is refused with
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
    model (:data:`deploy.training.NOISE_SOURCES`): "arm", the arm file's measured noise (a
    conservative default without an arm file), or "sensor" (a simulated, exact arm)."""

    model: str = ""
    flange: str = ""
    end_effector: str = ""
    noise: str = "arm"

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
    (:func:`deploy.model_setup.block_frames_of`)."""
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
    (:mod:`deploy.host`); -1: none."""

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
           ("arm", "noise"): ("arm", "sensor"),
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
               if key not in DERIVED_GATE_KEYS})
INT_RANGES = {
    ("estimate", "block_frames"): (0, 100),  # frames per block point; 0: the link's rate / 100
    ("model", "seed"): (0, 2**63 - 1),  # numpy's seeds are non-negative; TOML ints are int64
    ("ros2", "domain_id"): (-1, 232),  # ROS 2's valid domain ids; -1: ROS_DOMAIN_ID
    ("host", "cpu_dma_latency_us"): (-1, 1_000_000),  # µs; -1: no limit (deploy.host)
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


def _ros_name_error(name: str, value: str) -> str | None:
    if ROS_NAME.fullmatch(value):
        return None
    return (f"{name} = {value!r} is not a fully qualified ROS 2 name; valid: '/' then "
            "segments of letters, digits and '_' (not starting with a digit) separated by "
            "'/', e.g. '/franka/joint_states'")


def _check(section: str, key: str, value, default, where: str):
    name = f"{where}: [{section}] {key}"
    expected = type(default)
    if expected is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} = {value!r} must be true or false")
        return value
    if expected is int:
        lo, hi = INT_RANGES.get((section, key), (-(2**63), 2**63 - 1))
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name} = {value!r} must be an integer from {lo} to {hi}")
        if not lo <= value <= hi:
            raise ConfigError(f"{name} = {value!r} is out of range; valid is an integer "
                              f"from {lo} to {hi}")
        return value
    if expected is float:
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value):
            raise ConfigError(f"{name} = {value!r} must be a finite number")
        value = float(value)
        lo, hi = RANGES.get((section, key), (-math.inf, math.inf))
        if not lo <= value <= hi:
            raise ConfigError(f"{name} = {value!r} is out of range; valid is [{lo:g}, {hi:g}]")
        return value
    if expected is tuple or ((section, key) == ("ros2", "joints") and isinstance(value, list)):
        n = 7 if (section, key) == ("ros2", "joints") else None
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value) \
                or (n is not None and (len(value) != n or len(set(value)) != n)):
            what = f"{n} distinct non-empty strings" if n else "non-empty strings"
            raise ConfigError(f"{name} = {value!r} must be a list of {what}")
        return tuple(value)
    if expected is str:
        if isinstance(value, str) and not value and (section, key) in MAY_BE_EMPTY:
            return value
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{name} = {value!r} must be a non-empty string")
        if (section, key) in ROS_NAMES and (error := _ros_name_error(name, value)):
            raise ConfigError(error)
        choices = CHOICES.get((section, key))
        if choices and value not in choices:
            raise ConfigError(f"{name} = {value!r} is not valid; valid values are "
                              f"{', '.join(repr(c) for c in choices)}")
        return value
    raise ConfigError(f"{name}: unsupported setting type")  # pragma: no cover


def config_from_dict(doc: dict, where: str = "config") -> CellConfig:
    """Check a parsed ``cell.toml`` and build the settings (missing keys take defaults)."""
    unknown = sorted(set(doc) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"{where}: unknown section(s) {unknown}; valid sections are "
                          f"{', '.join(f'[{s}]' for s in SECTIONS)}")
    built = {}
    for section, cls in SECTIONS.items():
        table = doc.get(section, {})
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: [{section}] must be a table, got {table!r}")
        defaults = cls()
        names = {f.name for f in fields(cls)} - (set(DERIVED_GATE_KEYS) if section == "gate"
                                                 else set())
        retired = sorted(set(table) & set(RETIRED_GATE_KEYS)) if section == "gate" else []
        if retired:
            raise ConfigError(f"{where}: [gate] {', '.join(retired)}: not a setting of this gate, "
                              "which writes when a write makes the controller's model better "
                              "by its joint-torque error (write_margin, min_torque_error_nm; "
                              "docs/configuration.md); remove them")
        bad = sorted(set(table) - names)
        if bad:
            raise ConfigError(f"{where}: unknown key(s) {bad} in [{section}]; valid keys are "
                              f"{', '.join(sorted(names))}")
        values = {k: _check(section, k, v, getattr(defaults, k), where)
                  for k, v in table.items()}
        try:
            built[section] = cls(**{**{f.name: getattr(defaults, f.name) for f in fields(cls)},
                                    **values})
        except InvalidInputError as exc:  # a check across keys (GateConfig's own)
            raise ConfigError(f"{where}: [{section}] {exc}") from exc
    link = built["link"]
    if link.kind == "ros2" and "channel" not in doc.get("link", {}):
        link = built["link"] = replace(link, channel="/franka/joint_states")
    if link.kind == "ros2" and (error := _ros_name_error(f"{where}: [link] channel",
                                                         link.channel)):
        raise ConfigError(error + " (for kind 'ros2' the channel is the JointState topic)")
    if link.kind == "replay" and not FsPath(link.channel).suffix:
        raise ConfigError(f"{where}: [link] channel = {link.channel!r}: a replay channel is "
                          "a log file (.blf, .log, .asc or .trc)")
    built["arm"] = arm_model_of(built["arm"], link, built["ros2"], where)
    ee = built["arm"].end_effector
    if ee not in ("", "franka_hand", "none") and not ee.endswith(".toml"):
        raise ConfigError(f"{where}: [arm] end_effector = {ee!r} is not valid; valid are "
                          "'franka_hand', 'none' or the path of a payload-style .toml file of "
                          "the tool on the flange")
    cfg = CellConfig(**built, source=where)
    if "rated_mass_kg" not in doc.get("gate", {}):
        cfg = with_rated_payload(cfg)
    if not FsPath(cfg.arm.model).suffix or FsPath(cfg.arm.model).is_absolute():
        cfg = with_description(cfg)  # a relative description file: once load_config found it
    return cfg


def load_config(path) -> CellConfig:
    """Read and check ``cell.toml``; relative model paths are taken from the file's folder."""
    path = FsPath(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the configuration: "
                          f"{exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        line = exc.object.count(b"\n", 0, exc.start) + 1
        raise ConfigError(f"{path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} on "
                          f"line {line}, offset {exc.start}); a cell.toml must be UTF-8, as "
                          "TOML requires") from exc
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    cfg = config_from_dict(doc, where=str(path))
    model_path = FsPath(cfg.model.path)
    arm_path = FsPath(cfg.model.arm)
    if not model_path.is_absolute() or (cfg.model.arm and not arm_path.is_absolute()):
        model = ModelConfig(**{**{f.name: getattr(cfg.model, f.name)
                                  for f in fields(ModelConfig)},
                               "path": str(path.parent / model_path),
                               "arm": str(path.parent / arm_path) if cfg.model.arm else ""})
        cfg = replace(cfg, model=model)
    model = cfg.arm.model
    if FsPath(model).suffix and not FsPath(model).is_absolute():
        cfg = replace(cfg, arm=replace(cfg.arm, model=str(path.parent / model)))
        cfg = with_description(cfg)  # the description file, found from the file's folder
    ee = cfg.arm.end_effector
    if ee not in ("franka_hand", "none") and not FsPath(ee).is_absolute():
        cfg = replace(cfg, arm=replace(cfg.arm, end_effector=str(path.parent / ee)))
    if ee not in ("franka_hand", "none"):
        cfg = with_end_effector(cfg)  # the tool file, found from the file's folder
    initial = cfg.estimate.initial_payload
    if initial and not FsPath(initial).is_absolute():
        cfg = replace(cfg, estimate=replace(cfg.estimate,
                                            initial_payload=str(path.parent / initial)))
    return cfg
